//! `g1viz diagnose`: sim-to-real mismatch — where, why, fitted — with a report, diagnosis.json and
//! an .rrd of before/after.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use clap::Args;

use super::{ReadArgs, TargetArg};
use g1viz::power::load_model_for;

#[derive(Args)]
pub struct DiagnoseArgs {
    /// Recording(s) to diagnose: files, bag folders, or folders of recordings. Several sessions
    /// of one robot are diagnosed as one data set (joined end to end on one clock; each keeps its
    /// own trials and baselines).
    #[arg(required = true, value_name = "SESSION")]
    sessions: Vec<PathBuf>,
    /// The twin's power model (model.json, or `paper` for the paper's parameters); without it
    /// the model is refitted inside each fold.
    #[arg(long, value_name = "M")]
    model: Option<PathBuf>,
    /// URDF for the torque-level comparison (default: the shipped one).
    #[arg(long, value_name = "URDF")]
    urdf: Option<PathBuf>,
    /// Power sensor.
    #[arg(long, value_enum, default_value = "mbs")]
    target: TargetArg,
    /// The power sensor's averaging window W in seconds, or `auto` to estimate it from the data
    /// (the (W, lag) alignment scan, the lag left to the latency hypothesis).
    #[arg(long, value_name = "SECONDS|auto", default_value = "auto")]
    sensor_window: String,
    /// Write a markdown report with figures into DIR.
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    /// Write the machine-readable diagnosis here.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Write an .rrd with before/after predictions, residuals and the located trials.
    #[arg(long, value_name = "OUT")]
    save: Option<PathBuf>,
    /// With --save: open the layout on this tab (e.g. "Joints", "IMU and trials").
    #[arg(
        long,
        value_name = "TAB",
        default_value = "Diagnosis",
        requires = "save"
    )]
    open_tab: String,
    /// With --save: arm poses per second in the 3D view, 30 Hz by default as in replay (0 =
    /// every sample kept).
    #[arg(long, value_name = "HZ", default_value_t = 30.0, value_parser = super::non_negative, requires = "save")]
    pose_rate: f64,
    /// With --save: at most this many samples per second of every joint and IMU series (default:
    /// every sample, unless the .rrd would exceed 15 MB — at 100 Hz, a session of over about 90 s:
    /// then the highest rate that fits, printed, so that the web viewer opens it within about a
    /// minute; 0 = every sample). The diagnosis' per-reading series are always kept whole.
    #[arg(long, value_name = "HZ", value_parser = super::non_negative, requires = "save")]
    max_rate: Option<f64>,
    /// Also compare sample by sample with the twin driven by the same commands on the same
    /// timeline (made with `g1viz simulate --like SESSION -o TWIN`).
    #[arg(long, value_name = "TWIN")]
    counterpart: Option<PathBuf>,
    #[command(flatten)]
    read: ReadArgs,
}

/// Diagnose and write what was asked for.
pub fn run(a: DiagnoseArgs) -> Result<()> {
    use g1viz::diagnose::{self, DiagnoseOptions};
    let outputs = [
        ("diagnosis JSON", a.json.as_deref()),
        ("report folder", a.report.as_deref()),
        ("Rerun output", a.save.as_deref()),
    ];
    let why = "its trials would count twice (and the counterpart must be its twin)";
    let inputs = [a.model.as_deref(), a.urdf.as_deref()];
    // Streamed: the sessions are read trial by trial, never held whole; the .rrd is streamed too
    // (the diagnosis' overlays are per reading and per trial; several sessions are replayed part
    // by part on the diagnosis' joined clock), and the counterpart is read beside the session
    // sample by sample.
    let (files, map) = (a.read).sessions(
        &a.sessions,
        a.counterpart.as_deref(),
        why,
        &outputs,
        &inputs,
    )?;
    if a.counterpart.is_some() && files.len() > 1 {
        bail!("--counterpart compares one session with its twin; give one session");
    }
    let sensor_window_s = match a.sensor_window.as_str() {
        "auto" => None,
        w => Some(w.parse::<f64>().ok().filter(|w| *w > 0.0).ok_or_else(|| {
            anyhow::anyhow!("--sensor-window {w}: expected a positive number of seconds or `auto`")
        })?),
    };
    let opts = DiagnoseOptions {
        reference: (a.model.as_deref())
            .map(|m| load_model_for(m, &map.joint_names, a.target.into()))
            .transpose()?,
        target: a.target.into(),
        urdf: a.urdf.clone(),
        sensor_window_s,
        ..DiagnoseOptions::default()
    };
    let busy = super::spinner("diagnosing");
    let bar = busy.clone();
    // The stage's number and name; each progress message goes between them, so a terminal
    // narrower than a long stage name cuts the name, never the progress.
    let stage = std::sync::Mutex::new((String::new(), String::new()));
    diagnose::on_stage(Some(Box::new(move |p| {
        let Ok(mut stage) = stage.lock() else { return };
        let progress = match p {
            diagnose::Progress::Stage { k, of, name } => {
                *stage = (format!("diagnosing, stage {k} of {of}"), name.to_owned());
                bar.set_message(format!("{}: {}", stage.0, stage.1));
                return;
            }
            diagnose::Progress::Trials { done, total } => format!("trial {done} of {total}"),
            diagnose::Progress::Seconds { done_s, total_s } => {
                format!("{done_s:.0} s of {total_s:.0} s read")
            }
            diagnose::Progress::Candidates { step, done, total } => {
                format!("discovery, term {step}: candidate {done} of {total}")
            }
        };
        bar.set_message(format!("{}: {progress} — {}", stage.0, stage.1));
    })));
    let d = diagnose::diagnose_files(&files, &opts, JOIN_GAP_S);
    diagnose::on_stage(None);
    busy.finish_and_clear();
    let mut d = d?;
    if let (Some(p), [file]) = (&a.counterpart, files.as_slice()) {
        let busy = super::spinner("comparing with the counterpart");
        let twin = a.read.session_file(p, &map);
        // The viewer plots the per-sample torque differences: kept only for --save.
        let c = diagnose::compare_counterpart_files(file, &twin, &d, a.save.is_some());
        busy.finish_and_clear();
        d.attach_counterpart(c?);
    }
    write_outputs(&a, &d)?;
    if let Some(out) = &a.save {
        save_streamed_rrd(&files, &a, &d, out)?;
    }
    Ok(())
}

/// Gap between joined sessions [s]: each part starts this long after the previous one ends, so
/// trials and their baselines stay apart.
const JOIN_GAP_S: f64 = 5.0;

/// Print the summary and write the JSON and the report when asked for.
fn write_outputs(a: &DiagnoseArgs, d: &g1viz::diagnose::Diagnosis) -> Result<()> {
    println!("{}", d.summary);
    if let Some(p) = &a.json {
        d.save_json(p)?;
        println!("wrote {}", p.display());
    }
    if let Some(dir) = &a.report {
        g1viz::diagnose::write_report(dir, d)?;
        println!("wrote {}", dir.join("report.md").display());
    }
    Ok(())
}

/// The `.rrd` of a diagnosis, the sessions streamed from their files (several joined end to end
/// on the diagnosis' clock; the recording id is the first file's).
#[cfg(feature = "viz")]
fn save_streamed_rrd(
    files: &[g1viz::session::SessionFile],
    a: &DiagnoseArgs,
    d: &g1viz::diagnose::Diagnosis,
    out: &Path,
) -> Result<()> {
    use g1viz::viz::{self, Sink, Window};
    let paths: Vec<&Path> = files.iter().map(|f| f.path.as_path()).collect();
    let [first, ..] = files else {
        bail!("no session to replay");
    };
    let replay = viz::SessionReplay {
        session: &first.path,
        map: &first.map,
        read: &first.read,
        robot: &g1viz::robot::RobotModel::load(a.urdf.as_deref())?,
        model: None,
        fit: Default::default(),
        sink: &Sink::Save(out.to_path_buf()),
        inputs: &paths,
        window: Window {
            max_rate_hz: a.max_rate,
            ..Window::default()
        },
        opts: super::replay::options(a.pose_rate, Some(a.open_tab.clone()), a.model.as_deref()),
    };
    let extras = viz::diagnosis_extras(d);
    let wrote = super::replay::write("writing the replay", None, Some(out), |n| {
        viz::replay_diagnosis(&replay, &paths, JOIN_GAP_S, extras.clone(), n)
    })?;
    println!("{wrote}");
    Ok(())
}

#[cfg(not(feature = "viz"))]
fn save_streamed_rrd(
    _: &[g1viz::session::SessionFile],
    _: &DiagnoseArgs,
    _: &g1viz::diagnose::Diagnosis,
    _: &Path,
) -> Result<()> {
    bail!("--save needs the `viz` feature (Rerun output); rebuild with default features")
}
