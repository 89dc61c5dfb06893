//! `g1viz replay`: a [`Recording`] (plus whatever identification and diagnosis add, as
//! [`ReplayExtras`]) logged to Rerun.
//!
//! Entity paths (all scalars are `Scalars` with a static `SeriesLines`/`SeriesPoints` style):
//! - `robot/<link>` (+ `/visual<k>`): the arm, see [`super::robot3d`]
//! - `joints/<j>/{q, q_cmd, dq, tau, temperature}`, `<j>` = [`super::short_joint_name`]
//! - `power/{mbs,bms}/{raw,net}` [W] (net = minus the mean of the readings before the arm first
//!   moves), `imu/gyro_norm` [rad/s]
//! - `model/power/{measured_net,predicted}`, `model/error/{sample,trajectory}`,
//!   `model/terms/<j>/{mechanical,copper,coulomb,viscous}`, `model/terms/interaction/total`
//! - `trials/log` (TextLog per trial, WARN for rejected ones), `trials/{active,rejected}` (0/1 bands)
//! - `diagnosis/power/{measured,before,after}`, `diagnosis/error/{before,after}`,
//!   `diagnosis/trials`, `diagnosis/summary` (TextDocument); with a counterpart
//!   `diagnosis/power/twin` and `diagnosis/torque/<j>` (τ recording − twin)
//!
//! Timelines: `time` (timestamp: recording start + t) and `session` (duration since start).
//! Long series are sent column-wise in chunks of [`ReplayOptions::chunk_rows`] samples, so memory
//! stays bounded whatever the session length.

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rerun::components::TextLogLevel;
use rerun::{Color, RecordingStream, Scalars, SeriesLines, SeriesPoints, TextDocument, TextLog};

use super::blueprint::{self, LayoutParts};
use super::{ChunkWriter, robot3d, short_joint_name};
use crate::N_JOINTS;
use crate::robot::{ArmJoints, RobotModel};
use crate::signals::{PowerSeries, Recording};

/// How to log a replay.
#[derive(Debug, Clone)]
pub struct ReplayOptions {
    /// Samples per Rerun chunk (bounds memory; a few thousand keeps chunks near 100 kB).
    pub chunk_rows: usize,
    /// Log arm poses at most this often [Hz]; `None` = every recorded sample.
    pub pose_rate_hz: Option<f64>,
    /// The arm counts as moving once any joint is this far [rad] from its first sample; power
    /// readings before that are the idle baseline.
    pub motion_threshold_rad: f64,
    /// Progress bar on stderr (shown only when stderr is a terminal).
    pub progress: bool,
    /// Also send the viewer layout (blueprint).
    pub blueprint: bool,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        ReplayOptions {
            chunk_rows: 4096,
            pose_rate_hz: None,
            motion_threshold_rad: 0.02,
            progress: true,
            blueprint: true,
        }
    }
}

/// Per-sample predictions of the identified power model (filled by identify/validate).
#[derive(Debug, Clone, Default)]
pub struct PowerPrediction {
    /// Time [s since recording start].
    pub t: Vec<f64>,
    /// Measured net power [W] (the model's target).
    pub measured_net: Vec<f64>,
    /// Predicted net power [W].
    pub predicted: Vec<f64>,
}

/// Per-trajectory (aggregated) prediction, one per trial.
#[derive(Debug, Clone)]
pub struct TrajectoryPoint {
    /// Trial index.
    pub trial: usize,
    /// Where to show it [s since recording start] (e.g. trajectory end).
    pub t: f64,
    /// Measured mean net power over the trajectory window [W].
    pub measured: f64,
    /// Predicted mean net power [W].
    pub predicted: f64,
}

/// Per-joint loss-term time series [W] (the model's breakdown per sample).
#[derive(Debug, Clone, Default)]
pub struct TermSeries {
    /// Time [s since recording start].
    pub t: Vec<f64>,
    /// a_i τ_i q̇_i.
    pub mechanical: Vec<[f64; N_JOINTS]>,
    /// b_i (τ_i² − τ̄0_i²).
    pub copper: Vec<[f64; N_JOINTS]>,
    /// c_i |q̇_i|.
    pub coulomb: Vec<[f64; N_JOINTS]>,
    /// d_i q̇_i².
    pub viscous: Vec<[f64; N_JOINTS]>,
    /// Σ e_ij |q̇_i||q̇_j|.
    pub interaction: Vec<f64>,
}

/// A trial's time window and status.
#[derive(Debug, Clone)]
pub struct TrialMark {
    /// Trial index.
    pub index: usize,
    /// Window start [s since recording start].
    pub t_start: f64,
    /// Window end [s].
    pub t_end: f64,
    /// Free text shown in the log (joints moved, speed…).
    pub label: String,
    /// Set when a filter rejected the trial.
    pub rejected: Option<crate::trial::Rejection>,
    /// Set when a diagnosis located its mismatch in the trial: why.
    pub highlight: Option<String>,
}

/// Diagnosis overlay: the power prediction before and after adding the accepted hypotheses.
#[derive(Debug, Clone, Default)]
pub struct DiagnosisOverlay {
    /// Time [s since recording start].
    pub t: Vec<f64>,
    /// Measured net power [W].
    pub measured: Vec<f64>,
    /// Base-model prediction [W].
    pub before: Vec<f64>,
    /// Prediction with the accepted hypotheses [W].
    pub after: Vec<f64>,
    /// Trials where the mismatch is located (shown as WARN lines).
    pub highlighted: Vec<TrialMark>,
    /// Plain-language summary (markdown).
    pub summary: String,
    /// The twin re-run on the recording's commands (`diagnose --counterpart`).
    pub counterpart: Option<crate::diagnose::counterpart::CounterpartSeries>,
    /// Prediction with the terms found beyond the library [W] (empty when none was found).
    pub found: Vec<f64>,
    /// The recorded fields the found terms follow, per reading: (field name, values).
    pub located: Vec<(String, Vec<f64>)>,
}

/// What later stages add to a replay. Plain data so identify/diagnose need no Rerun types.
#[derive(Debug, Clone, Default)]
pub struct ReplayExtras {
    /// Identified-model predictions per sample.
    pub prediction: Option<PowerPrediction>,
    /// Identified-model predictions per trajectory.
    pub trajectories: Vec<TrajectoryPoint>,
    /// Loss terms per joint.
    pub terms: Option<TermSeries>,
    /// Trial windows with rejection marks.
    pub trials: Vec<TrialMark>,
    /// Diagnosis before/after.
    pub diagnosis: Option<DiagnosisOverlay>,
}

/// What a replay logged.
#[derive(Debug, Clone, Default)]
pub struct ReplaySummary {
    /// Joint-state samples logged.
    pub samples: usize,
    /// Idle baselines subtracted for the net power [W] (MBS, BMS), when there were readings before motion.
    pub baseline_w: [Option<f64>; 2],
    /// Problems that did not stop the replay (missing meshes, no idle readings…).
    pub warnings: Vec<String>,
}

/// Tuid namespace of the replay's own rows (other writers on the same stream use others).
const REPLAY_NAMESPACE: u64 = 0x0001_0000_0000_0000;

/// Eight distinguishable colours (one per joint, then reused).
const PALETTE: [[u8; 3]; 8] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
];

fn color(i: usize) -> Color {
    let [r, g, b] = PALETTE[i % PALETTE.len()];
    Color::from_rgb(r, g, b)
}

/// Where the 3D camera looks: the mean position of the links that move with the arm, at the
/// zero pose (the model root if none moves).
fn arm_center(robot: &RobotModel, arm: &ArmJoints) -> [f32; 3] {
    let home = robot.link_poses(arm, &[0.0; N_JOINTS]);
    let probe = robot.link_poses(arm, &[0.5, -0.4, 0.3, -0.6, 0.7, -0.5, 0.4]);
    let moving: Vec<_> = home
        .iter()
        .zip(&probe)
        .filter(|(a, b)| (a.translation.vector - b.translation.vector).norm() > 1e-6)
        .map(|(a, _)| a.translation.vector)
        .collect();
    if moving.is_empty() {
        return [0.0; 3];
    }
    let mean = moving.iter().sum::<nalgebra::Vector3<f64>>() / moving.len() as f64;
    [mean.x as f32, mean.y as f32, mean.z as f32]
}

/// Logs `rec` (and `extras`) to `stream`: arm animation, joint and power series, model/diagnosis
/// overlays, and the viewer layout. The recording is already in memory; to replay a file of any
/// length in bounded memory use [`replay_file`].
pub fn log_replay(
    rec: &Recording,
    robot: &RobotModel,
    arm: &ArmJoints,
    extras: &ReplayExtras,
    opts: &ReplayOptions,
    stream: &RecordingStream,
) -> Result<ReplaySummary> {
    let mut logger = ReplayLogger::begin(
        stream,
        robot,
        arm,
        &rec.source,
        &rec.joint_names,
        rec.start_ns,
        extras,
        opts,
        rec.state.t.len() as u64,
    )?;
    logger.add(rec)?;
    logger.finish(extras)
}

/// Streams the recording at `path` into `stream` in batches of [`ReplayOptions::chunk_rows`]
/// samples: memory stays bounded whatever the file length (the ~1 Hz power readings are kept
/// until the end, where the idle baseline is known). No model or diagnosis overlay (those need
/// the whole session; see [`log_replay`]). Returns the replay summary with the reader's warnings.
pub fn replay_file(
    path: &std::path::Path,
    map: &crate::signals::SignalMap,
    read_opts: &crate::read::OpenOptions,
    robot: &RobotModel,
    arm: &ArmJoints,
    opts: &ReplayOptions,
    stream: &RecordingStream,
) -> Result<ReplaySummary> {
    let extras = ReplayExtras::default();
    // The reader shows its own progress bar (messages read); one bar is enough.
    let quiet = ReplayOptions {
        progress: false,
        ..opts.clone()
    };
    let mut logger: Option<ReplayLogger<'_>> = None;
    let read = crate::signals::stream_recording(
        path,
        map,
        read_opts,
        opts.chunk_rows.max(1),
        &mut |batch| {
            if logger.is_none() {
                logger = Some(ReplayLogger::begin(
                    stream,
                    robot,
                    arm,
                    path,
                    &batch.joint_names,
                    batch.start_ns,
                    &extras,
                    &quiet,
                    0,
                )?);
            }
            match logger.as_mut() {
                Some(l) => l.add(batch),
                None => Ok(()),
            }
        },
    )?;
    let logger = logger.context("the recording delivered no samples")?;
    let mut summary = logger.finish(&extras)?;
    let mut warnings = read.warnings;
    warnings.append(&mut summary.warnings);
    summary.warnings = warnings;
    Ok(summary)
}

/// Incremental replay: [`ReplayLogger::begin`] sends the layout and the static robot,
/// [`ReplayLogger::add`] logs one stretch of samples (any number of times, in time order),
/// [`ReplayLogger::finish`] logs the power series (net of the idle baseline, known only once the
/// arm has moved) and the overlays.
pub struct ReplayLogger<'a> {
    w: ChunkWriter<'a>,
    robot: &'a RobotModel,
    arm: &'a ArmJoints,
    source: std::path::PathBuf,
    joints: Vec<String>,
    scene: robot3d::ArmScene,
    chunk: usize,
    pose_rate_hz: Option<f64>,
    motion_threshold_rad: f64,
    next_pose_t: f64,
    /// First joint sample, and the time the arm first moved away from it.
    q0: Option<[f64; N_JOINTS]>,
    motion_t: f64,
    command_style_sent: bool,
    /// The ~1 Hz power readings (≈ 60 kB per hour), logged by `finish`.
    mbs: PowerSeries,
    bms: PowerSeries,
    progress: ProgressBar,
    summary: ReplaySummary,
}

impl<'a> ReplayLogger<'a> {
    /// Sends the viewer layout (when [`ReplayOptions::blueprint`]), the static robot and the
    /// series styles. `joint_names` are the 7 arm joints' URDF names; `expected_samples` sizes the
    /// progress bar (0: no bar).
    #[allow(clippy::too_many_arguments)]
    pub fn begin(
        stream: &'a RecordingStream,
        robot: &'a RobotModel,
        arm: &'a ArmJoints,
        source: &std::path::Path,
        joint_names: &[String],
        start_ns: u64,
        extras: &ReplayExtras,
        opts: &ReplayOptions,
        expected_samples: u64,
    ) -> Result<Self> {
        let joints: Vec<String> = joint_names.iter().map(|n| short_joint_name(n)).collect();
        if joints.len() != N_JOINTS {
            bail!(
                "{}: expected {N_JOINTS} arm joint names, got {}",
                source.display(),
                joints.len()
            );
        }
        let mut summary = ReplaySummary::default();
        let mut w = ChunkWriter::new(stream, REPLAY_NAMESPACE, start_ns);
        if opts.blueprint {
            let parts = LayoutParts {
                model: extras.prediction.is_some()
                    || extras.terms.is_some()
                    || !extras.trajectories.is_empty(),
                diagnosis: extras.diagnosis.is_some(),
                counterpart: extras
                    .diagnosis
                    .as_ref()
                    .is_some_and(|d| d.counterpart.is_some()),
                trials: !extras.trials.is_empty(),
                located: extras
                    .diagnosis
                    .as_ref()
                    .is_some_and(|d| !d.located.is_empty()),
            };
            let layout = blueprint::replay_layout(&joints, parts, arm_center(robot, arm));
            blueprint::send_blueprint(stream, &layout)?;
            // The blueprint bypasses the batcher: flush so it reaches the sink before any data
            // chunk (a fixed message order is part of the reproducible output).
            stream
                .flush_blocking()
                .context("sending the viewer layout")?;
        }
        let scene = robot3d::log_static_robot(&mut w, robot, arm, &mut summary.warnings)?;
        log_styles(&mut w, &joints)?;
        let progress = if expected_samples > 0 {
            progress_bar(opts.progress, expected_samples)
        } else {
            ProgressBar::hidden()
        };
        Ok(ReplayLogger {
            w,
            robot,
            arm,
            source: source.to_path_buf(),
            joints,
            scene,
            chunk: opts.chunk_rows.max(1),
            pose_rate_hz: opts.pose_rate_hz.filter(|r| *r > 0.0),
            motion_threshold_rad: opts.motion_threshold_rad,
            next_pose_t: f64::NEG_INFINITY,
            q0: None,
            motion_t: f64::INFINITY,
            command_style_sent: false,
            mbs: PowerSeries::default(),
            bms: PowerSeries::default(),
            progress,
            summary,
        })
    }

    /// Logs the joint, IMU, pose and command samples of `part` (the next stretch of the session,
    /// times relative to the same start) and keeps its power readings for [`Self::finish`].
    /// Series of unequal lengths are an error naming the field.
    pub fn add(&mut self, part: &Recording) -> Result<()> {
        check_lengths(part)?;
        let st = &part.state;
        let n = st.t.len().min(st.q.len());
        // Motion start: the first sample any joint is more than the threshold from the first.
        if self.motion_t.is_infinite() {
            for (q, &t) in st.q.iter().zip(&st.t) {
                let q0 = *self.q0.get_or_insert(*q);
                if q.iter()
                    .zip(&q0)
                    .any(|(a, b)| (a - b).abs() > self.motion_threshold_rad)
                {
                    self.motion_t = t;
                    break;
                }
            }
        }
        let mut pose_idx: Vec<usize> = Vec::with_capacity(self.chunk);
        for start in (0..n).step_by(self.chunk) {
            let end = (start + self.chunk).min(n);
            let t = &st.t[start..end];
            for (j, name) in self.joints.iter().enumerate() {
                for (signal, data) in [
                    ("q", &st.q),
                    ("dq", &st.dq),
                    ("tau", &st.tau),
                    ("temperature", &st.temp),
                ] {
                    scalars(
                        &mut self.w,
                        &format!("joints/{name}/{signal}"),
                        t,
                        data[start..end].iter().map(|v| v[j]),
                    )?;
                }
            }
            scalars(
                &mut self.w,
                "imu/gyro_norm",
                t,
                st.gyro[start..end]
                    .iter()
                    .map(|g| (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt()),
            )?;

            // Poses: every sample, or decimated to pose_rate_hz.
            pose_idx.clear();
            for (k, &ti) in t.iter().enumerate() {
                if ti >= self.next_pose_t {
                    pose_idx.push(start + k);
                    if let Some(rate) = self.pose_rate_hz {
                        self.next_pose_t = ti + 1.0 / rate;
                    }
                }
            }
            let pose_t: Vec<f64> = pose_idx.iter().map(|&i| st.t[i]).collect();
            let pose_q: Vec<[f64; N_JOINTS]> = pose_idx.iter().map(|&i| st.q[i]).collect();
            robot3d::log_link_poses(
                &mut self.w,
                self.robot,
                self.arm,
                &self.scene,
                &pose_t,
                &pose_q,
            )?;
            self.progress.inc((end - start) as u64);
        }
        self.summary.samples += n;

        let cmd = &part.command;
        if !cmd.t.is_empty() && !self.command_style_sent {
            for (j, name) in self.joints.iter().enumerate() {
                let style = SeriesLines::new()
                    .with_names([format!("{name} cmd")])
                    .with_colors([color(j)])
                    .with_widths([0.5]);
                self.w
                    .send_static(&format!("joints/{name}/q_cmd"), &style)?;
            }
            self.command_style_sent = true;
        }
        for start in (0..cmd.t.len()).step_by(self.chunk) {
            let end = (start + self.chunk).min(cmd.t.len());
            for (j, name) in self.joints.iter().enumerate() {
                scalars(
                    &mut self.w,
                    &format!("joints/{name}/q_cmd"),
                    &cmd.t[start..end],
                    cmd.q[start..end].iter().map(|v| v[j]),
                )?;
            }
        }
        for (mine, theirs) in [(&mut self.mbs, &part.mbs), (&mut self.bms, &part.bms)] {
            mine.t.extend_from_slice(&theirs.t);
            mine.watts.extend_from_slice(&theirs.watts);
        }
        Ok(())
    }

    /// Logs the power series (raw, and net of the readings before the arm first moved) and
    /// `extras`; returns what was logged.
    pub fn finish(mut self, extras: &ReplayExtras) -> Result<ReplaySummary> {
        self.progress.finish_and_clear();
        let w = &mut self.w;
        for (k, (label, series)) in [("mbs", &self.mbs), ("bms", &self.bms)]
            .into_iter()
            .enumerate()
        {
            if series.t.is_empty() {
                continue;
            }
            scalars_chunked(
                w,
                &format!("power/{label}/raw"),
                &series.t,
                &series.watts,
                self.chunk,
            )?;
            match idle_baseline(series, self.motion_t) {
                Some(base) => {
                    self.summary.baseline_w[k] = Some(base);
                    let net: Vec<f64> = series.watts.iter().map(|p| p - base).collect();
                    scalars_chunked(
                        w,
                        &format!("power/{label}/net"),
                        &series.t,
                        &net,
                        self.chunk,
                    )?;
                }
                None => self.summary.warnings.push(format!(
                    "{}: no {} power reading before the arm first moves (t = {:.2} s); net power not logged",
                    self.source.display(),
                    label.to_uppercase(),
                    self.motion_t
                )),
            }
        }
        log_extras(w, &self.joints, extras, self.chunk)?;
        Ok(self.summary)
    }
}

/// Every per-sample vector of a series must be as long as its time vector.
fn check_lengths(rec: &Recording) -> Result<()> {
    let s = &rec.state;
    let n = s.t.len();
    for (field, len) in [
        ("q", s.q.len()),
        ("dq", s.dq.len()),
        ("tau", s.tau.len()),
        ("temp", s.temp.len()),
        ("gyro", s.gyro.len()),
    ] {
        if len != n {
            bail!(
                "{}: state.{field} has {len} samples but state.t has {n}",
                rec.source.display()
            );
        }
    }
    if rec.command.q.len() != rec.command.t.len() {
        bail!(
            "{}: command.q and command.t differ in length",
            rec.source.display()
        );
    }
    for (label, p) in [("mbs", &rec.mbs), ("bms", &rec.bms)] {
        if p.watts.len() != p.t.len() {
            bail!(
                "{}: {label}.watts and {label}.t differ in length",
                rec.source.display()
            );
        }
    }
    Ok(())
}

/// Mean of the finite readings stamped before `motion_t`; `None` when there are none.
pub fn idle_baseline(series: &PowerSeries, motion_t: f64) -> Option<f64> {
    let idle: Vec<f64> = series
        .t
        .iter()
        .zip(&series.watts)
        .filter(|(t, w)| **t < motion_t && w.is_finite())
        .map(|(_, &w)| w)
        .collect();
    (!idle.is_empty()).then(|| idle.iter().sum::<f64>() / idle.len() as f64)
}

fn scalars(
    w: &mut ChunkWriter<'_>,
    path: &str,
    t: &[f64],
    values: impl Iterator<Item = f64>,
) -> Result<()> {
    if t.is_empty() {
        return Ok(());
    }
    w.send_columns(path, t, Scalars::new(values).columns_of_unit_batches()?)
}

fn scalars_chunked(
    w: &mut ChunkWriter<'_>,
    path: &str,
    t: &[f64],
    v: &[f64],
    chunk: usize,
) -> Result<()> {
    let n = t.len().min(v.len());
    for start in (0..n).step_by(chunk) {
        let end = (start + chunk).min(n);
        scalars(w, path, &t[start..end], v[start..end].iter().copied())?;
    }
    Ok(())
}

fn line(w: &mut ChunkWriter<'_>, path: &str, name: &str, c: Color) -> Result<()> {
    w.send_static(
        path,
        &SeriesLines::new().with_names([name]).with_colors([c]),
    )
}

/// Static legend names and colours of every series (the command's are sent with its first
/// samples, since a streamed session only shows whether it has any when they arrive).
fn log_styles(w: &mut ChunkWriter<'_>, joints: &[String]) -> Result<()> {
    for (j, name) in joints.iter().enumerate() {
        for signal in ["q", "dq", "tau", "temperature"] {
            line(w, &format!("joints/{name}/{signal}"), name, color(j))?;
        }
    }
    line(w, "imu/gyro_norm", "|ω| body", color(7))?;
    line(w, "power/mbs/raw", "MBS raw", color(0))?;
    line(w, "power/mbs/net", "MBS net", color(1))?;
    line(w, "power/bms/raw", "BMS raw", color(2))?;
    line(w, "power/bms/net", "BMS net", color(3))
}

fn log_extras(
    w: &mut ChunkWriter<'_>,
    joints: &[String],
    extras: &ReplayExtras,
    chunk: usize,
) -> Result<()> {
    if let Some(p) = &extras.prediction {
        line(w, "model/power/measured_net", "measured net", color(1))?;
        line(w, "model/power/predicted", "predicted", color(4))?;
        line(
            w,
            "model/error/sample",
            "error (measured − predicted)",
            color(3),
        )?;
        scalars_chunked(w, "model/power/measured_net", &p.t, &p.measured_net, chunk)?;
        scalars_chunked(w, "model/power/predicted", &p.t, &p.predicted, chunk)?;
        let err: Vec<f64> = p
            .measured_net
            .iter()
            .zip(&p.predicted)
            .map(|(m, q)| m - q)
            .collect();
        scalars_chunked(w, "model/error/sample", &p.t, &err, chunk)?;
    }
    if !extras.trajectories.is_empty() {
        w.send_static(
            "model/error/trajectory",
            &SeriesPoints::new()
                .with_names(["error per trajectory"])
                .with_colors([color(6)])
                .with_marker_sizes([4.0]),
        )?;
        let t: Vec<f64> = extras.trajectories.iter().map(|p| p.t).collect();
        let e: Vec<f64> = extras
            .trajectories
            .iter()
            .map(|p| p.measured - p.predicted)
            .collect();
        scalars_chunked(w, "model/error/trajectory", &t, &e, chunk)?;
    }
    if let Some(terms) = &extras.terms {
        for (j, name) in joints.iter().enumerate() {
            for (k, (term, data)) in [
                ("mechanical", &terms.mechanical),
                ("copper", &terms.copper),
                ("coulomb", &terms.coulomb),
                ("viscous", &terms.viscous),
            ]
            .into_iter()
            .enumerate()
            {
                let path = format!("model/terms/{name}/{term}");
                line(w, &path, term, color(k))?;
                let n = terms.t.len().min(data.len());
                for start in (0..n).step_by(chunk) {
                    let end = (start + chunk).min(n);
                    scalars(
                        w,
                        &path,
                        &terms.t[start..end],
                        data[start..end].iter().map(|v| v[j]),
                    )?;
                }
            }
        }
        line(
            w,
            "model/terms/interaction/total",
            "interaction total",
            color(4),
        )?;
        scalars_chunked(
            w,
            "model/terms/interaction/total",
            &terms.t,
            &terms.interaction,
            chunk,
        )?;
    }
    log_trials(w, "trials", &extras.trials)?;
    if let Some(d) = &extras.diagnosis {
        line(w, "diagnosis/power/measured", "measured net", color(1))?;
        line(w, "diagnosis/power/before", "base model", color(7))?;
        line(
            w,
            "diagnosis/power/after",
            "with accepted hypotheses",
            color(2),
        )?;
        line(w, "diagnosis/error/before", "error base model", color(7))?;
        line(
            w,
            "diagnosis/error/after",
            "error with hypotheses",
            color(2),
        )?;
        scalars_chunked(w, "diagnosis/power/measured", &d.t, &d.measured, chunk)?;
        scalars_chunked(w, "diagnosis/power/before", &d.t, &d.before, chunk)?;
        scalars_chunked(w, "diagnosis/power/after", &d.t, &d.after, chunk)?;
        let eb: Vec<f64> = d
            .measured
            .iter()
            .zip(&d.before)
            .map(|(m, p)| m - p)
            .collect();
        let ea: Vec<f64> = d
            .measured
            .iter()
            .zip(&d.after)
            .map(|(m, p)| m - p)
            .collect();
        scalars_chunked(w, "diagnosis/error/before", &d.t, &eb, chunk)?;
        scalars_chunked(w, "diagnosis/error/after", &d.t, &ea, chunk)?;
        log_trials(w, "diagnosis/trials", &d.highlighted)?;
        if d.found.len() == d.t.len() && !d.found.is_empty() {
            line(
                w,
                "diagnosis/power/found",
                "with terms found beyond the library",
                color(3),
            )?;
            line(
                w,
                "diagnosis/error/found",
                "error with found terms",
                color(3),
            )?;
            scalars_chunked(w, "diagnosis/power/found", &d.t, &d.found, chunk)?;
            let ef: Vec<f64> = d
                .measured
                .iter()
                .zip(&d.found)
                .map(|(m, p)| m - p)
                .collect();
            scalars_chunked(w, "diagnosis/error/found", &d.t, &ef, chunk)?;
        }
        for (k, (name, values)) in d.located.iter().enumerate() {
            let path = format!("diagnosis/located/{k}");
            line(w, &path, name, color(k))?;
            scalars_chunked(w, &path, &d.t, values, chunk)?;
        }
        if let Some(cp) = &d.counterpart {
            line(
                w,
                "diagnosis/power/twin",
                "twin on the same commands",
                color(4),
            )?;
            scalars_chunked(w, "diagnosis/power/twin", &cp.power_t, &cp.power_w, chunk)?;
            for (j, name) in joints.iter().enumerate() {
                let path = format!("diagnosis/torque/{name}");
                line(w, &path, &format!("{name} τ recording − twin"), color(j))?;
                let v: Vec<f64> = cp.tau_diff.iter().map(|x| x[j]).collect();
                scalars_chunked(w, &path, &cp.tau_t, &v, chunk)?;
            }
        }
        w.send_static(
            "diagnosis/summary",
            &TextDocument::from_markdown(d.summary.clone()),
        )?;
    }
    Ok(())
}

/// A log line per trial at its start and 0/1 bands (`<prefix>/active`, `<prefix>/rejected`).
fn log_trials(w: &mut ChunkWriter<'_>, prefix: &str, trials: &[TrialMark]) -> Result<()> {
    if trials.is_empty() {
        return Ok(());
    }
    let mut order: Vec<&TrialMark> = trials.iter().collect();
    order.sort_by(|a, b| a.t_start.total_cmp(&b.t_start).then(a.index.cmp(&b.index)));
    let t: Vec<f64> = order.iter().map(|m| m.t_start).collect();
    let texts: Vec<String> = order
        .iter()
        .map(|m| match (&m.rejected, &m.highlight) {
            (Some(r), _) => format!(
                "trial {}: REJECTED by {} ({r}) {}",
                m.index,
                r.reason.name(),
                m.label
            ),
            (None, Some(why)) => format!("trial {}: {why} {}", m.index, m.label),
            (None, None) => format!("trial {}: {}", m.index, m.label),
        })
        .collect();
    let levels: Vec<TextLogLevel> = order
        .iter()
        .map(|m| {
            if m.rejected.is_some() || m.highlight.is_some() {
                TextLogLevel::WARN.into()
            } else {
                TextLogLevel::INFO.into()
            }
        })
        .collect();
    let columns = TextLog::update_fields()
        .with_many_text(texts)
        .with_many_level(levels)
        .columns_of_unit_batches()?;
    w.send_columns(&format!("{prefix}/log"), &t, columns)?;

    // Bands: 1 inside a window, 0 outside (two points per edge so the step is sharp).
    for (band, keep) in [("active", false), ("rejected", true)] {
        let mut bt = Vec::new();
        let mut bv = Vec::new();
        for m in order
            .iter()
            .filter(|m| !keep || m.rejected.is_some() || m.highlight.is_some())
        {
            bt.extend([m.t_start, m.t_start, m.t_end, m.t_end]);
            bv.extend([0.0, 1.0, 1.0, 0.0]);
        }
        if bt.is_empty() {
            continue;
        }
        let path = format!("{prefix}/{band}");
        line(w, &path, band, if keep { color(3) } else { color(7) })?;
        w.send_columns(&path, &bt, Scalars::new(bv).columns_of_unit_batches()?)?;
    }
    Ok(())
}

fn progress_bar(enabled: bool, len: u64) -> ProgressBar {
    if !enabled || !std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
    if let Ok(style) = ProgressStyle::with_template("replay {bar:40} {pos}/{len} samples ({eta})") {
        bar.set_style(style);
    }
    bar
}
