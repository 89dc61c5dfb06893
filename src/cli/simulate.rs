//! `g1viz simulate`: a session from the digital twin (MCAP + truth JSON), optionally with
//! concealed effects, or the twin re-run on a recording's commands (`--like`).

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use super::{ReadArgs, winding_temperature};
use g1viz::power::load_model;
use g1viz::util::check_outputs;

#[derive(Args)]
pub struct SimulateArgs {
    /// Output MCAP file (the truth sidecar goes beside it as NAME.truth.json).
    #[arg(short, long, value_name = "OUT")]
    output: PathBuf,
    /// Trial set: tiny, example, smoke, paper, holdout.
    #[arg(long, default_value = "smoke")]
    preset: String,
    /// Random seed (same seed, same file).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Switch on a concealed effect (the list is the simulator's own: [`effect_help`]).
    #[arg(long = "effect", value_name = "NAME=VALUE", help = effect_help())]
    effects: Vec<String>,
    /// Re-run this recording's commanded trajectory through the twin (same timeline).
    #[arg(long, value_name = "SESSION")]
    like: Option<PathBuf>,
    /// True power model (model.json, or `paper`; default: the paper's tables).
    #[arg(long, value_name = "M")]
    model: Option<PathBuf>,
    /// URDF for the dynamics (default: the shipped one).
    #[arg(long, value_name = "URDF")]
    urdf: Option<PathBuf>,
    /// Simulate without the Dex3-1 hand.
    #[arg(long)]
    no_hand: bool,
    /// Winding temperature at session start [°C].
    #[arg(long, value_name = "C", value_parser = winding_temperature)]
    t_start: Option<f64>,
    /// Battery model: linear (open-circuit voltage linear in charge, no internal resistance;
    /// every recorded voltage follows the charge alone) or realistic (NMC cell curve and 0.15 Ω
    /// pack resistance: the voltages sag under load).
    #[arg(long, default_value = "linear", value_name = "MODEL")]
    battery: String,
    /// State of charge at session start, 0–1 (default: a freshly charged pack, 0.96–0.98).
    #[arg(long, value_name = "SOC")]
    soc_start: Option<f64>,
    /// No balance contamination and no hardware-event outliers.
    #[arg(long)]
    clean: bool,
    /// Start the session this many days after the simulator's epoch (2026-03-14), e.g. one
    /// session a day of a synthetic fleet.
    #[arg(long, default_value_t = 0, value_name = "N")]
    day: u64,
    #[command(flatten)]
    read: ReadArgs,
}

/// `--effect`'s help: every effect the simulator accepts, from its own list.
fn effect_help() -> String {
    format!(
        "Switch on a concealed effect, e.g. braking=0.3 (repeatable; a bare NAME uses the default \
         value). NAME is one of: {}",
        g1viz::sim::EFFECT_NAMES.join(", ")
    )
}

/// Simulate and write the session and its truth file.
pub fn run(a: SimulateArgs) -> Result<()> {
    use g1viz::sim::{Artefacts, SimConfig};
    let truth_out = g1viz::sim::truth_path(&a.output);
    check_outputs(
        &[
            ("simulated session", Some(&a.output)),
            ("truth file", Some(&truth_out)),
        ],
        &[
            a.like.as_deref(),
            a.model.as_deref(),
            a.urdf.as_deref(),
            a.read.signals.as_deref(),
        ],
    )?;
    let defaults = SimConfig::default();
    let mut cfg = SimConfig {
        preset: a.preset.parse()?,
        seed: a.seed,
        // The cheap checks before the model's load.
        battery: a.battery.parse()?,
        truth: (a.model.as_deref().map(load_model).transpose()?).unwrap_or(defaults.truth),
        urdf: a.urdf.clone(),
        with_hand: !a.no_hand,
        t_start_c: a.t_start.unwrap_or(defaults.t_start_c),
        soc_start: a.soc_start,
        artefacts: if a.clean {
            Artefacts::NONE
        } else {
            defaults.artefacts
        },
        start_day: a.day,
        ..defaults
    };
    for e in &a.effects {
        cfg.effects.enable(e)?;
    }
    let truth = match &a.like {
        // Streamed: the recording is read twice (its stamps, then its trajectory as the twin
        // reaches it), never held whole.
        Some(p) => {
            let (truth, warnings) = g1viz::sim::simulate_like_file(
                p,
                &a.read.signal_map()?,
                &a.read.open_options(),
                &cfg,
                &a.output,
            )?;
            super::warn(&warnings);
            truth
        }
        None => g1viz::sim::simulate(&cfg, &a.output)?,
    };
    let what = match &a.like {
        // The twin follows the recording's commands; it knows no trial windows.
        Some(p) => format!("the twin of {} on its timeline", p.display()),
        None => format!("{} trials", truth.trials.len()),
    };
    println!(
        "wrote {} and {} ({what})",
        a.output.display(),
        truth_out.display()
    );
    Ok(())
}
