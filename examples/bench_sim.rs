//! Benchmark of the digital twin: time to simulate and write a preset session, file size and
//! throughput. Also how the shipped example session is produced.
//!
//! ```text
//! cargo run --release --no-default-features --example bench_sim                 # paper preset → temp dir
//! cargo run --release --no-default-features --example bench_sim -- smoke OUT.mcap [EFFECT…]
//! cargo run --no-default-features --example bench_sim -- example examples/g1_example.mcap
//! cargo run --release --no-default-features --example bench_sim -- effects   # effect table
//! ```
//!
//! `effects` simulates the hold-out preset once per switchable effect (defaults; thermal with the
//! windings starting at 70 °C, no contamination/outliers) and validates the paper's true base
//! model on each: how much each missing piece of physics degrades the base model's fit.

use std::time::Instant;

use anyhow::Context;
use g1viz::sim::{Preset, SimConfig, simulate};

fn effects_table() -> anyhow::Result<()> {
    use g1viz::identify::{IdentifyOptions, validate};
    use g1viz::sim::Artefacts;
    let tmp = tempfile::tempdir()?;
    println!(
        "| effect (default parameter) | trial R² | RMSE [W] | bias [W] | aligned R² | aligned RMSE [W] | mean effect power [W] |"
    );
    println!("|---|---|---|---|---|---|---|");
    for effect in std::iter::once("none").chain(g1viz::sim::EFFECT_NAMES) {
        let mut cfg = SimConfig {
            preset: Preset::Holdout,
            seed: 3,
            progress: false,
            artefacts: Artefacts::NONE,
            ..SimConfig::default()
        };
        if effect != "none" {
            cfg.effects.enable(effect)?;
        }
        if effect == "thermal" {
            cfg.t_start_c = 70.0;
        }
        let out = tmp.path().join(format!("{effect}.mcap"));
        let truth = simulate(&cfg, &out)?;
        let map = g1viz::signals::SignalMap::g1_left_arm();
        let rec = g1viz::signals::load_recording(&out, &map, &Default::default())?;
        let v = validate(&cfg.truth, &rec, &IdentifyOptions::default())?;
        let (m, a) = (v.trial_level, v.trial_level_aligned);
        let eff = truth
            .trials
            .iter()
            .map(|t| t.effect_power_traj_mean_w)
            .sum::<f64>()
            / truth.trials.len().max(1) as f64;
        let params = serde_json::to_string(&cfg.effects)?;
        println!(
            "| {effect} {params} | {:.3} | {:.2} | {:+.2} | {:.3} | {:.2} | {eff:+.2} |",
            m.r2, m.rmse, m.bias, a.r2, a.rmse
        );
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().map(String::as_str) == Some("effects") {
        return effects_table();
    }
    let preset: Preset = args.first().map_or(Ok(Preset::Paper), |s| s.parse())?;
    let tmp = tempfile::tempdir()?;
    let out = args
        .get(1)
        .map_or_else(|| tmp.path().join("bench.mcap"), std::path::PathBuf::from);
    let mut cfg = SimConfig {
        preset,
        seed: 1,
        ..SimConfig::default()
    };
    for e in args.iter().skip(2) {
        cfg.effects.enable(e)?;
    }
    let t0 = Instant::now();
    let truth = simulate(&cfg, &out)?;
    let secs = t0.elapsed().as_secs_f64();
    let bytes = std::fs::metadata(&out)
        .with_context(|| format!("reading size of {}", out.display()))?
        .len();
    let c = truth.message_counts;
    let msgs = c.lowstate + c.arm_sdk + c.bms + c.mbs;
    println!(
        "preset {}: {} trials, {:.0} s of robot time",
        preset.name(),
        truth.trials.len(),
        truth.session.duration_s
    );
    println!(
        "  messages: {} (/lowstate {}, /arm_sdk {}, MBS {}, BMS {})",
        msgs, c.lowstate, c.arm_sdk, c.mbs, c.bms
    );
    println!(
        "  generation {secs:.2} s ({:.0} robot-s per s, {:.0} k msgs/s), file {:.1} MB",
        truth.session.duration_s / secs,
        msgs as f64 / secs / 1e3,
        bytes as f64 / 1e6
    );
    println!(
        "  contaminated trials {}, outlier trials {}, winding temperature {:.1}–{:.1} °C",
        truth.artefacts.contamination.n_trials,
        truth.artefacts.outliers.n_trials,
        truth.plant.thermal.winding_temp_range_c[0],
        truth.plant.thermal.winding_temp_range_c[1]
    );
    Ok(())
}
