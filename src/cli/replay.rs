//! `g1viz replay`: a session in the Rerun viewer (or an .rrd file) — the animated arm, joint
//! signals and power; with `--model` the model's prediction, error and loss terms.

use std::path::PathBuf;

#[cfg(feature = "viz")]
use anyhow::Context;
use anyhow::{Result, bail};
use clap::Args;

use super::{FitArgs, ReadArgs, non_negative};

#[derive(Args)]
pub struct ReplayArgs {
    /// Recording to replay.
    session: PathBuf,
    /// Identified model (model.json, or `paper` for the paper's parameters): adds predicted vs
    /// measured power, error and loss terms.
    #[arg(long, value_name = "M")]
    model: Option<PathBuf>,
    /// Robot description (default: the shipped G1 left-arm URDF; Unitree's official URDF shows its meshes).
    #[arg(long, value_name = "URDF")]
    urdf: Option<PathBuf>,
    /// Write an .rrd file (atomically; refuses to overwrite the input).
    #[arg(long, value_name = "OUT", group = "sink")]
    save: Option<PathBuf>,
    /// Stream to a running viewer (default address rerun+http://127.0.0.1:9876/proxy).
    #[arg(long, value_name = "ADDR", group = "sink", num_args = 0..=1, default_missing_value = "")]
    connect: Option<String>,
    /// Start a viewer (`rerun` on PATH: pip install rerun-sdk==0.36.3) and stream to it.
    #[arg(long, group = "sink")]
    spawn: bool,
    /// Memory limit of the spawned viewer (e.g. 2GB or 25%).
    #[arg(long, default_value = "25%")]
    memory_limit: String,
    /// Arm poses per second in the 3D view (0 = every recorded sample). Joint and power series
    /// are always logged at full rate; 30 Hz keeps hour-long .rrd files a fraction of the size.
    #[arg(long, value_name = "HZ", default_value_t = 30.0, value_parser = non_negative)]
    pose_rate: f64,
    /// Do not send the viewer layout (keep the viewer's own).
    #[arg(long)]
    no_blueprint: bool,
    /// Open the layout on this tab (e.g. "Joints", "IMU and trials"; default: the first).
    #[arg(long, value_name = "TAB")]
    open_tab: Option<String>,
    #[command(flatten)]
    fit: FitArgs,
    #[command(flatten)]
    read: ReadArgs,
}

/// Replay the session to the chosen sink.
#[cfg(feature = "viz")]
pub fn run(a: ReplayArgs) -> Result<()> {
    use g1viz::power::load_model_for;
    use g1viz::robot::RobotModel;
    use g1viz::viz::{self, OutputKind, Sink};
    use std::path::Path;

    let robot = RobotModel::load(a.urdf.as_deref())?;
    let sink = if let Some(out) = &a.save {
        Sink::Save(out.clone())
    } else if let Some(addr) = &a.connect {
        Sink::Connect((!addr.is_empty()).then(|| addr.clone()))
    } else if a.spawn {
        Sink::Spawn {
            memory_limit: a.memory_limit.clone(),
        }
    } else {
        bail!("say where the replay goes: --save OUT.rrd, --connect [ADDR] or --spawn");
    };
    let mut inputs: Vec<&Path> = vec![&a.session];
    if let Some(m) = a.model.as_deref().filter(|m| m.exists()) {
        inputs.push(m);
    }
    let mut properties = vec![("command".to_owned(), super::command_line())];
    if let Some(m) = &a.model {
        properties.push(("model".to_owned(), m.display().to_string()));
    }
    let opts = viz::replay::ReplayOptions {
        pose_rate_hz: (a.pose_rate > 0.0).then_some(a.pose_rate),
        blueprint: !a.no_blueprint,
        properties,
        open_tab: a.open_tab.clone(),
        ..Default::default()
    };
    let summary = match &a.model {
        // The model overlay needs the whole session (trial segmentation, fitted windows).
        Some(m) => {
            let rec = a.read.load(&a.session)?;
            let arm = robot.arm(&rec.joint_names)?;
            let model = load_model_for(m, &rec.joint_names, a.fit.options().target)?;
            let busy = super::spinner("applying the model");
            let extras = viz::overlay::model_extras(&rec, &model, &a.fit.options());
            busy.finish_and_clear();
            let (extras, v) = extras?;
            for n in &v.notes {
                eprintln!("note: {n}");
            }
            eprintln!(
                "model {}: per-trajectory R² {:.3}, RMSE {:.2} W on {} trials",
                m.display(),
                v.trial_level_aligned.r2,
                v.trial_level_aligned.rmse,
                v.per_trial.len()
            );
            let kind = OutputKind::ModelReplay;
            let id = kind.recording_id(&viz::recording_id_for(&rec));
            let out = viz::open_stream(&kind.app_id(), &id, &sink, &inputs)?;
            let summary =
                viz::replay::log_replay(&rec, &robot, &arm, &extras, &opts, out.stream())?;
            out.finish()?;
            summary
        }
        // A plain replay streams the file: memory does not grow with its length.
        None => {
            let map = a.read.signal_map()?;
            let arm = robot.arm(&map.joint_names)?;
            let kind = OutputKind::Replay;
            let id = viz::recording_id_for_source(&a.session)
                .with_context(|| format!("cannot read {}", a.session.display()))?;
            let out = viz::open_stream(&kind.app_id(), &kind.recording_id(&id), &sink, &inputs)?;
            let summary = viz::replay::replay_file(
                &a.session,
                &map,
                &a.read.open_options(),
                &robot,
                &arm,
                &opts,
                out.stream(),
            )
            .with_context(|| format!("replaying {}", a.session.display()))?;
            out.finish()?;
            summary
        }
    };
    for w in &summary.warnings {
        eprintln!("warning: {w}");
    }
    if let Some(path) = &a.save {
        eprintln!("wrote {} ({} samples)", path.display(), summary.samples);
    }
    Ok(())
}

/// Without the `viz` feature there is no Rerun output.
#[cfg(not(feature = "viz"))]
pub fn run(_: ReplayArgs) -> Result<()> {
    bail!(
        "this g1viz was built without the `viz` feature (Rerun output); rebuild with default features"
    )
}
