//! `g1viz replay`: a session in the Rerun viewer (or an .rrd file) — the animated arm, joint
//! signals and power; with `--model` the model's prediction, error and loss terms.

use std::path::{Path, PathBuf};

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
    /// Replay from this session time [s since the session start] (times keep their place on
    /// the `session` timeline).
    #[arg(long, value_name = "S", value_parser = non_negative)]
    from: Option<f64>,
    /// Replay up to this session time [s].
    #[arg(long, value_name = "S", value_parser = non_negative)]
    to: Option<f64>,
    /// Replay trials A to B only (e.g. `3-7`, or `5`): from A's pre-idle to B's return home.
    /// Without --model the session is read once more first, to find the trials.
    #[arg(long, value_name = "A-B", value_parser = trial_range)]
    trials: Option<(usize, usize)>,
    /// At most this many samples per second of every joint, IMU and model series. Default: all
    /// recorded samples, unless the replay would exceed 150 MB (at 100 Hz, a plain replay of
    /// over 20 min): then the highest rate that fits, printed; 0 keeps every sample. See the
    /// size estimate printed before writing.
    #[arg(long, value_name = "HZ", value_parser = non_negative)]
    max_rate: Option<f64>,
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
    use g1viz::viz::{self, SessionReplay, Sink, Window, replay_session};
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
    let model_path = a.model.as_deref();
    let inputs: Vec<&Path> = [Some(a.session.as_path()), model_path.filter(|m| m.exists())]
        .into_iter()
        .flatten()
        .collect();
    let map = a.read.signal_map()?;
    let target = a.fit.options().target;
    let model = (model_path.map(|m| load_model_for(m, &map.joint_names, target))).transpose()?;
    let name = model_path.map(|m| m.display().to_string());
    let replay = SessionReplay {
        session: &a.session,
        map: &map,
        read: &a.read.open_options(),
        robot: &RobotModel::load(a.urdf.as_deref())?,
        model: name.as_deref().zip(model.as_ref()),
        fit: a.fit.options(),
        sink: &sink,
        inputs: &inputs,
        window: Window {
            from_s: a.from,
            to_s: a.to,
            trials: a.trials,
            max_rate_hz: a.max_rate,
        },
        opts: viz::ReplayOptions {
            blueprint: !a.no_blueprint,
            ..options(a.pose_rate, a.open_tab.clone(), model_path)
        },
    };
    let busy = match model {
        Some(_) => "reading the session and applying the model",
        None => "opening the session",
    };
    let save = a.save.as_deref();
    let wrote = write(busy, name.as_deref(), save, |n| replay_session(&replay, n))?;
    if save.is_some() {
        eprintln!("{wrote}");
    }
    Ok(())
}

/// A replay's options: `pose_rate` [Hz] (0: every sample), the tab it opens on, and the
/// recording's properties naming the command and the `model`.
#[cfg(feature = "viz")]
pub(super) fn options(
    pose_rate: f64,
    open_tab: Option<String>,
    model: Option<&Path>,
) -> g1viz::viz::ReplayOptions {
    let mut properties = vec![("command".to_owned(), super::command_line())];
    properties.extend(model.map(|m| ("model".to_owned(), m.display().to_string())));
    g1viz::viz::ReplayOptions {
        pose_rate_hz: (pose_rate > 0.0).then_some(pose_rate),
        properties,
        open_tab,
        ..Default::default()
    }
}

/// Where a replay tells what it says while it runs.
#[cfg(feature = "viz")]
type Notify<'a> = &'a mut dyn FnMut(g1viz::viz::Notice);

/// Writes a replay with `write`, telling the user what it says while it runs (the notes and
/// fit of the `model`, the default cap, the expected size of a file `save`d) and its warnings;
/// returns the line that says what it wrote (empty without `save`).
#[cfg(feature = "viz")]
pub(super) fn write(
    busy: &str,
    model: Option<&str>,
    save: Option<&Path>,
    write: impl FnOnce(Notify<'_>) -> Result<g1viz::viz::ReplaySummary>,
) -> Result<String> {
    use g1viz::viz::Notice;
    let busy = super::spinner(busy);
    let summary = write(&mut |notice| match notice {
        Notice::Note(n) => busy.suspend(|| eprintln!("note: {n}")),
        Notice::ModelFit { r2, rmse, trials } => busy.suspend(|| {
            eprintln!(
                "model {}: per-trajectory R² {r2:.3}, RMSE {rmse:.2} W on {trials} trials",
                model.unwrap_or("")
            )
        }),
        Notice::Capped(hz, budget) => busy.suspend(|| {
            eprintln!(
                "replay: at most {hz} samples per second of every joint, IMU and model series, to \
                 keep the recording near {:.0} MB (--max-rate 0 keeps every sample)",
                budget / 1e6
            )
        }),
        Notice::Estimate(e) => busy.suspend(|| {
            if save.is_some() {
                eprintln!("expected size: {e}");
            }
        }),
    });
    busy.finish_and_clear();
    let summary = summary?;
    super::warn(&summary.warnings);
    Ok(save.map_or(String::new(), |path| {
        let size = std::fs::metadata(path).map_or(0, |m| m.len());
        let (samples, mb) = (summary.samples, size as f64 / 1e6);
        format!("wrote {} ({samples} samples, {mb:.1} MB)", path.display())
    }))
}

/// `A-B` or `A` (trial indices, A ≤ B) for `--trials`.
fn trial_range(s: &str) -> Result<(usize, usize), String> {
    let parse = |x: &str| {
        x.trim()
            .parse::<usize>()
            .map_err(|_| format!("{s:?} is not a trial range like 3-7 or 5"))
    };
    let (a, b) = s.split_once('-').unwrap_or((s, s));
    let (a, b) = (parse(a)?, parse(b)?);
    if b < a {
        return Err(format!("{s:?}: the range ends before it starts"));
    }
    Ok((a, b))
}

/// Without the `viz` feature there is no Rerun output.
#[cfg(not(feature = "viz"))]
pub fn run(_: ReplayArgs) -> Result<()> {
    bail!(
        "this g1viz was built without the `viz` feature (Rerun output); rebuild with default features"
    )
}
