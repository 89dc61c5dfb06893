//! `g1viz replay`: a [`Recording`] (plus whatever identification and diagnosis add, as
//! [`ReplayExtras`]) logged to Rerun.
//!
//! Entity paths are listed in [`super::paths`] (all scalars are `Scalars` with a static
//! `SeriesLines`/`SeriesPoints` style naming and colouring them, see [`super::style`]). The
//! recording names itself after the input file, carries the session's real start time and
//! properties (input, command, model, version) under `__properties`.
//!
//! Timelines: `session` (duration since the session start; the layout opens on it) and `time`
//! (timestamp: recording start + t). Long series are sent column-wise in chunks of
//! [`ReplayOptions::chunk_rows`] samples, so memory stays bounded whatever the session length.

use anyhow::{Context, Result, bail};
use rerun::{AnyValues, RecordingInfo, RecordingStream, Scalars};

use super::blueprint::{self, LayoutParts};
use super::slice::{Decimator, Slice};
use super::{ChunkWriter, layers, paths, robot3d, short_joint_name, style};
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
    /// Also send the viewer layout (blueprint).
    pub blueprint: bool,
    /// Recording properties beside the input and g1viz version, e.g. `("command", "replay")`,
    /// `("model", "paper")`; shown in the viewer's recording properties.
    pub properties: Vec<(String, String)>,
    /// The tab the layout opens on, by name (`None`: the first; see
    /// [`blueprint::Node::tab_names`]).
    pub open_tab: Option<String>,
    /// The part of the session to log (time window, rate cap of the series; default: all).
    pub slice: Slice,
    /// How a model replay reads the session file (piece length, batch size).
    pub stream: crate::session::StreamOptions,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        ReplayOptions {
            chunk_rows: 4096,
            pose_rate_hz: None,
            motion_threshold_rad: 0.02,
            blueprint: true,
            properties: Vec::new(),
            open_tab: None,
            slice: Slice::default(),
            stream: crate::session::StreamOptions::default(),
        }
    }
}

/// Each power reading next to the model's prediction averaged over the reading's own window
/// [t − lag − window, t − lag]: like for like, the error `validate` reports per reading.
#[derive(Debug, Clone, Default)]
pub struct ReadingPrediction {
    /// Reading stamps [s since recording start].
    pub t: Vec<f64>,
    /// Trial of each reading.
    pub trial: Vec<usize>,
    /// Measured net power (reading minus its trial's pre-idle mean) [W].
    pub measured: Vec<f64>,
    /// Prediction averaged over the reading's window [W].
    pub predicted: Vec<f64>,
    /// Whether the reading's trial was rejected by a filter.
    pub rejected: Vec<bool>,
    /// Sensor averaging window used [s].
    pub window_s: f64,
    /// Sensor lag used [s].
    pub lag_s: f64,
}

pub use crate::trial::ImuFilterMarks;

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
    /// Whether a filter rejected the trial.
    pub rejected: bool,
    /// The trial's rest power (its pre-idle mean) [W].
    pub rest_w: f64,
}

/// The model's series [W] per sample: its breakdown into loss terms per joint, and its
/// instantaneous prediction.
#[derive(Debug, Clone, Default)]
pub struct TermSeries {
    /// Time [s since recording start].
    pub t: Vec<f64>,
    /// Predicted net power: context only, since a power reading is a window average and
    /// compares with [`ReadingPrediction`] (empty where only the terms are known).
    pub predicted: Vec<f64>,
    /// Per sample, each joint's mechanical a_i τ_i q̇_i, copper b_i (τ_i² − τ̄0_i²), Coulomb
    /// c_i |q̇_i| and viscous d_i q̇_i² ([`super::paths::TERMS`] order).
    pub per_joint: [Vec<[f64; N_JOINTS]>; 4],
    /// Σ e_ij |q̇_i||q̇_j|.
    pub interaction: Vec<f64>,
}

impl TermSeries {
    /// Samples every series holds (the shortest one's length).
    pub(super) fn len(&self) -> usize {
        let lens = self.per_joint.iter().map(Vec::len);
        (lens.chain([self.t.len(), self.interaction.len()]).min()).unwrap_or(0)
    }

    /// Appends the samples of `other`.
    pub(super) fn extend(&mut self, other: &TermSeries) {
        self.t.extend_from_slice(&other.t);
        self.predicted.extend_from_slice(&other.predicted);
        for (mine, theirs) in self.per_joint.iter_mut().zip(&other.per_joint) {
            mine.extend_from_slice(theirs);
        }
        self.interaction.extend_from_slice(&other.interaction);
    }

    /// The first `n` samples, taken out.
    fn take_head(&mut self, n: usize) -> TermSeries {
        TermSeries {
            t: self.t.drain(..n).collect(),
            predicted: self.predicted.drain(..n).collect(),
            per_joint: self.per_joint.each_mut().map(|f| f.drain(..n).collect()),
            interaction: self.interaction.drain(..n).collect(),
        }
    }
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

/// Diagnosis overlay: the diagnosis' per-reading data (measured, the predictions before and
/// after the accepted hypotheses and with the found terms, the fields those follow, the rest
/// power), its trial marks, its summary and the twin.
#[derive(Debug, Clone, Default)]
pub struct DiagnosisOverlay {
    /// Per reading, as the diagnosis holds it (its own marks and IMU filter are not read here).
    pub data: crate::diagnose::ReplayData,
    /// Trials where the mismatch is located (shown as WARN lines) and trials a filter rejected.
    pub highlighted: Vec<TrialMark>,
    /// Plain-language summary (markdown).
    pub summary: String,
    /// The twin re-run on the recording's commands (`diagnose --counterpart`).
    pub counterpart: Option<crate::diagnose::counterpart::CounterpartSeries>,
    /// The meter's averaging window, where the diagnosis found it drifting.
    pub window: Option<crate::diagnose::SensorWindow>,
}

/// What later stages add to a replay. Plain data so identify/diagnose need no Rerun types.
#[derive(Debug, Clone, Default)]
pub struct ReplayExtras {
    /// The identified model, whose per-sample series the replay computes trial by trial.
    pub model: Option<ModelSeries>,
    /// Identified-model predictions at the power readings, like for like.
    pub readings: Option<ReadingPrediction>,
    /// Identified-model predictions per trajectory.
    pub trajectories: Vec<TrajectoryPoint>,
    /// Trial windows with rejection marks.
    pub trials: Vec<TrialMark>,
    /// The IMU filter's statistic and threshold.
    pub imu_filter: Option<ImuFilterMarks>,
    /// Diagnosis before/after.
    pub diagnosis: Option<DiagnosisOverlay>,
}

/// An identified model's per-sample series, never held whole: the replay computes them trial by
/// trial ([`ReplayLogger::log_model_trial`]) from the session in memory or as the replay reads it.
#[derive(Debug, Clone)]
pub struct ModelSeries {
    /// The model.
    pub model: crate::power::PowerModel,
    /// The usable trials (those with a copper baseline), in session order, with it.
    pub plan: Vec<(crate::trial::TrialWindow, [f64; N_JOINTS])>,
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

/// How often the arm links' loss colours are updated [Hz].
pub(crate) const LINK_COLOUR_RATE_HZ: f64 = 10.0;

/// Tuid namespace of the replay's own rows (other writers on the same stream use others).
const REPLAY_NAMESPACE: u64 = 0x0001_0000_0000_0000;

/// Where the 3D camera looks: the mean position of the links that move with the arm, at the
/// zero pose (the model root if none moves).
fn arm_center(robot: &RobotModel, arm: &ArmJoints) -> [f32; 3] {
    let home = robot.link_poses(arm, &[0.0; N_JOINTS]);
    let moving = robot3d::moving_links(robot, arm);
    if moving.is_empty() {
        return [0.0; 3];
    }
    let sum: nalgebra::Vector3<f64> = moving.iter().map(|&i| home[i].translation.vector).sum();
    let mean = sum / moving.len() as f64;
    [mean.x as f32, mean.y as f32, mean.z as f32]
}

/// The viewer layout of a replay with `extras` (`joints`: the short joint names); its plots are
/// fitted to their data once it is logged ([`blueprint::Node::fit`]).
pub fn layout(
    robot: &RobotModel,
    arm: &ArmJoints,
    joints: &[String],
    extras: &ReplayExtras,
) -> blueprint::Node {
    let diagnosis_power_series = extras.diagnosis.as_ref().map_or(0, |d| {
        3 + usize::from(!d.data.found_w.is_empty()) + usize::from(d.counterpart.is_some())
    });
    let starts = trial_starts(extras);
    let window_s = blueprint::opening_window(&starts);
    let diagnosis = |f: fn(&DiagnosisOverlay) -> bool| extras.diagnosis.as_ref().is_some_and(f);
    let parts = LayoutParts {
        model: extras.model.is_some()
            || extras.readings.is_some()
            || !extras.trajectories.is_empty(),
        diagnosis: extras.diagnosis.is_some(),
        counterpart: diagnosis(|d| d.counterpart.is_some()),
        trials: !extras.trials.is_empty(),
        imu_filter: extras.imu_filter.is_some(),
        located: diagnosis(|d| !d.data.located.is_empty()),
        rest: diagnosis(|d| !d.data.rest_w.is_empty()),
        window_drift: diagnosis(|d| d.window.is_some()),
        diagnosis_power_series,
        hypotheses: diagnosis(|d| d.data.after_w != d.data.before_w),
        error_typical: error_typical(extras),
        imu_per_trial: extras
            .imu_filter
            .as_ref()
            .map(|f| [0.0, 4.0 * f.threshold])
            .filter(|r| r[1].is_finite() && r[1] > 0.0),
        window_s,
        trial_counts: trial_counts(extras),
        trial_rest: extras.trajectories.iter().any(|p| p.rest_w.is_finite()),
        shares: extras.model.is_some() || diagnosis(|d| !d.data.terms_w.is_empty()),
        // The last trial ends about one spacing after it starts.
        span_s: window_s
            .zip(super::data_range(starts))
            .map(|(w, [a, b])| [a, b + w / blueprint::WINDOW_TRIALS]),
    };
    blueprint::replay_layout(joints, parts, arm_center(robot, arm))
}

/// The 95th percentile of the finite values' size (`None` without any): of the kept trials'
/// errors, the windowed error plot's bound (the rejected trials' run off it).
fn typical_size(values: &[f64]) -> Option<f64> {
    let mut size: Vec<f64> = values
        .iter()
        .filter(|v| v.is_finite())
        .map(|v| v.abs())
        .collect();
    size.sort_by(f64::total_cmp);
    size.get(size.len() * 95 / 100).or(size.last()).copied()
}

/// When each trial starts: the trial marks of a model replay, else each trial's first reading
/// in a diagnosis.
fn trial_starts(extras: &ReplayExtras) -> Vec<f64> {
    if !extras.trials.is_empty() {
        return extras.trials.iter().map(|m| m.t_start).collect();
    }
    extras
        .diagnosis
        .iter()
        .flat_map(|d| layers::per_trial_mean(&d.data.t, &d.data.trial, &d.data.measured_w).0)
        .collect()
}

/// How many trials `extras` cover, and how many are rejected and located.
fn trial_counts(extras: &ReplayExtras) -> blueprint::TrialCounts {
    let rejected = |m: &&TrialMark| m.rejected.is_some();
    match &extras.diagnosis {
        None => blueprint::TrialCounts {
            total: extras.trials.len(),
            rejected: extras.trials.iter().filter(rejected).count(),
            located: 0,
        },
        Some(d) => {
            let mut all: Vec<usize> = d.data.trial.clone();
            all.extend(d.highlighted.iter().map(|m| m.index));
            all.sort_unstable();
            all.dedup();
            blueprint::TrialCounts {
                total: all.len(),
                rejected: d.highlighted.iter().filter(rejected).count(),
                located: d
                    .highlighted
                    .iter()
                    .filter(|m| m.highlight.is_some())
                    .count(),
            }
        }
    }
}

/// ± the 95th percentile of the size of the kept trials' errors (the model's per reading and per
/// trajectory, the diagnosis'): the windowed error plot's range.
fn error_typical(extras: &ReplayExtras) -> Option<[f64; 2]> {
    let per_reading = extras.readings.iter().flat_map(|rd| {
        let kept = |i: usize| !rd.rejected.get(i).copied().unwrap_or(false);
        let errors = rd.measured.iter().zip(&rd.predicted).map(|(m, p)| m - p);
        errors
            .enumerate()
            .filter(move |(i, _)| kept(*i))
            .map(|e| e.1)
    });
    let per_trajectory = (extras.trajectories.iter())
        .filter(|p| !p.rejected)
        .map(|p| p.measured - p.predicted);
    let diagnosis = extras.diagnosis.iter().flat_map(|d| {
        let d = &d.data;
        [&d.before_w, &d.after_w, &d.found_w]
            .into_iter()
            .flat_map(|p| d.measured_w.iter().zip(p).map(|(m, p)| m - p))
    });
    let kept: Vec<f64> = per_reading.chain(per_trajectory).chain(diagnosis).collect();
    typical_size(&kept).map(|e| [-e, e])
}

/// Logs `rec` (and `extras`) to `stream`: arm animation, joint and power series, model/diagnosis
/// overlays, and the viewer layout — the streamed replay of [`replay_files_with`] fed the
/// recording, already in memory, as one batch.
pub fn log_replay(
    rec: &Recording,
    robot: &RobotModel,
    arm: &ArmJoints,
    extras: &ReplayExtras,
    opts: &ReplayOptions,
    stream: &RecordingStream,
) -> Result<ReplaySummary> {
    use crate::signals::RecordingSink;
    streamed_replay(robot, arm, extras, opts, stream, &mut |sink| {
        sink.begin(&crate::signals::StreamHeader {
            source: &rec.source,
            start_ns: rec.start_ns,
            joint_names: &rec.joint_names,
        })?;
        sink.batch(rec)
    })
}

/// Samples per Rerun chunk of a streamed replay (plain or with a model), at least (the replay's own
/// [`ReplayOptions::chunk_rows`] when larger). The `.rrd` footer indexes every chunk, in memory
/// until the file is finished, and is built at the end: at 4096 rows that took ~100 MB at the
/// end of a 10 h session's model replay (peak 286 MB); at 16384 the peak was 182 MB.
pub(crate) const STREAMED_CHUNK_ROWS: usize = 16_384;

/// A streamed replay into `stream`: `read` drives the sink over the recording(s); with a model,
/// its series are logged trial by trial as the reading completes each trial, beside the trial's
/// joint signals in the file (so a viewer loading it shows the session's start whole first).
pub(super) fn streamed_replay(
    robot: &RobotModel,
    arm: &ArmJoints,
    extras: &ReplayExtras,
    opts: &ReplayOptions,
    stream: &RecordingStream,
    read: &mut dyn FnMut(&mut StreamedReplay<'_, '_>) -> Result<()>,
) -> Result<ReplaySummary> {
    let mut sink = StreamedReplay {
        stream,
        robot,
        arm,
        opts,
        extras,
        logger: None,
        model_trials: None,
        warnings: Vec::new(),
    };
    read(&mut sink)?;
    let mut logger = sink.logger.context("the recording delivered no samples")?;
    if let Some(walk) = sink.model_trials {
        walk.finish(&mut |rec, _| logger.log_model_trial(&rec.state))?;
    }
    let mut summary = logger.finish()?;
    sink.warnings.append(&mut summary.warnings);
    summary.warnings = sink.warnings;
    Ok(summary)
}

/// Streams the recording(s) at `paths` into `stream` in batches of [`ReplayOptions::chunk_rows`]
/// samples: memory stays bounded whatever the file length (the ~1 Hz power readings are kept
/// until the end, where the idle baseline is known). Returns the replay summary with the
/// reader's warnings. `extras`: overlays known before the files are read (a diagnosis': they
/// hold per reading and per trial values, not per sample series, so they need not the whole
/// session; none for a plain replay). Several files are joined end to end into one session, each
/// part starting `gap_s` after the previous one ends, as [`crate::signals::join_recordings`]
/// joins them loaded (the clock and header are the first file's): the replay of a diagnosis of
/// several sessions, streamed part by part.
#[allow(clippy::too_many_arguments)]
pub fn replay_files_with(
    paths: &[&std::path::Path],
    gap_s: f64,
    map: &crate::signals::SignalMap,
    read_opts: &crate::read::OpenOptions,
    robot: &RobotModel,
    arm: &ArmJoints,
    extras: ReplayExtras,
    opts: &ReplayOptions,
    stream: &RecordingStream,
) -> Result<ReplaySummary> {
    let rows = opts.chunk_rows.max(1);
    let opts = &ReplayOptions {
        chunk_rows: opts.chunk_rows.max(STREAMED_CHUNK_ROWS),
        ..opts.clone()
    };
    streamed_replay(robot, arm, &extras, opts, stream, &mut |sink| {
        crate::signals::stream_joined_into(paths, map, read_opts, rows, gap_s, sink).map(drop)
    })
}

/// The streamed replay as a [`crate::signals::RecordingSink`]: `begin` sends the layout and the
/// static robot (the header gives the clock origin and joints), `batch` logs each stretch and,
/// with a model, the series of every trial it completes; the logger is left open for the caller
/// to finish, and the reader's warnings are kept.
pub(super) struct StreamedReplay<'a, 'e> {
    stream: &'a RecordingStream,
    robot: &'a RobotModel,
    arm: &'a ArmJoints,
    opts: &'a ReplayOptions,
    extras: &'e ReplayExtras,
    /// The logger, once the header came.
    pub(super) logger: Option<ReplayLogger<'a>>,
    /// The model's planned trials, handed over as the batches complete them.
    model_trials: Option<crate::session::TrialWalk>,
    /// The reader's warnings.
    pub(super) warnings: Vec<String>,
}

impl crate::signals::RecordingSink for StreamedReplay<'_, '_> {
    fn begin(&mut self, header: &crate::signals::StreamHeader<'_>) -> Result<()> {
        self.logger = Some(ReplayLogger::begin(
            self.stream,
            self.robot,
            self.arm,
            header.source,
            header.joint_names,
            header.start_ns,
            self.extras,
            self.opts,
        )?);
        self.model_trials = self.extras.model.as_ref().map(|m| {
            let plan = m.plan.iter().map(|(t, _)| t.clone()).collect();
            crate::session::TrialWalk::new(header.source.to_path_buf(), header.joint_names, plan)
        });
        Ok(())
    }

    fn batch(&mut self, batch: &Recording) -> Result<()> {
        let Some(logger) = self.logger.as_mut() else {
            bail!("a batch came before the session header");
        };
        logger.add(batch)?;
        if let Some(walk) = self.model_trials.as_mut() {
            walk.push(batch, &mut |rec, _| logger.log_model_trial(&rec.state))?;
        }
        Ok(())
    }

    fn finish(&mut self, read: &crate::signals::StreamSummary, _begun: bool) -> Result<()> {
        self.warnings = read.warnings.clone();
        Ok(())
    }
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
    /// Yaw of the first IMU orientation (removed, so the body starts facing +X).
    yaw0: Option<f64>,
    /// The ~1 Hz power readings of MBS and BMS not yet logged ([`Self::log_power`]).
    power: [PowerSeries; 2],
    /// Each sensor's idle baseline once known (`Some(None)`: no reading before the motion).
    baseline: [Option<Option<f64>>; 2],
    summary: ReplaySummary,
    slice: Slice,
    /// Rate caps of the state and command series, across batches.
    decimators: [Decimator; 2],
    /// The model whose series [`Self::log_model_trial`] logs, and its next trial.
    model: Option<(ModelSeries, usize)>,
    /// The rate cap of the model's series, across trials.
    model_decimator: Decimator,
    /// What the bars, the note and the link colours take of the model's series.
    stats: layers::ModelStats,
    /// Model samples gathered into the next chunk ([`Self::log_model_trial`]).
    pending: TermSeries,
    /// Samples kept, gathered into chunks of [`Self::chunk`] ([`Self::add`]).
    kept: Recording,
    /// The layout sent by [`Self::begin`] (when it sends one): [`Self::finish`] sends it again
    /// with every plot fitted to the data logged.
    layout: Option<blueprint::Node>,
    /// What later stages add, inside the slice ([`Slice::extras`]): logged by [`Self::begin`],
    /// but for what the model's series give, logged by [`Self::finish`].
    extras: ReplayExtras,
}

/// Power readings per chunk of a sensor's series (≈ 17 min at 1 Hz; [`ReplayLogger::log_power`]).
const POWER_ROWS: usize = 1024;

impl<'a> ReplayLogger<'a> {
    /// Sends the viewer layout (when [`ReplayOptions::blueprint`]), the static robot and the
    /// series styles. `joint_names` are the 7 arm joints' URDF names; `extras` are sliced as the
    /// session is ([`ReplayOptions::slice`]), once, here.
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
    ) -> Result<Self> {
        let joints: Vec<String> = joint_names.iter().map(|n| short_joint_name(n)).collect();
        let mut sent_layout = None;
        if joints.len() != N_JOINTS {
            bail!(
                "{}: expected {N_JOINTS} arm joint names, got {}",
                source.display(),
                joints.len()
            );
        }
        let mut summary = ReplaySummary::default();
        let mut w = ChunkWriter::new(stream, REPLAY_NAMESPACE, start_ns);
        let extras = opts.slice.extras(extras);
        if opts.blueprint {
            let mut layout = layout(robot, arm, &joints, &extras);
            if let Some(tab) = &opts.open_tab
                && !layout
                    .resolve_tab(tab)
                    .is_some_and(|name| layout.open_tab(&name))
            {
                bail!(
                    "no tab {tab:?} in the layout (tabs: {})",
                    layout.tab_names().join(", ")
                );
            }
            blueprint::send_blueprint(stream, &layout)?;
            // The blueprint bypasses the batcher: flush so it reaches the sink before any data
            // chunk (a fixed message order is part of the reproducible output).
            stream
                .flush_blocking()
                .context("sending the viewer layout")?;
            sent_layout = Some(layout);
        }
        log_recording_info(&mut w, source, start_ns, &opts.properties)?;
        let scene = robot3d::log_static_robot(
            &mut w,
            robot,
            arm,
            extras.model.is_some(),
            &mut summary.warnings,
        )?;
        log_styles(&mut w, &joints)?;
        layers::log_known(&mut w, &joints, &extras, opts.chunk_rows.max(1))?;
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
            yaw0: None,
            power: Default::default(),
            baseline: [None; 2],
            summary,
            slice: opts.slice,
            decimators: [Decimator::default(); 2],
            model: extras.model.clone().map(|m| (m, 0)),
            model_decimator: Decimator::default(),
            stats: Default::default(),
            pending: Default::default(),
            kept: Recording::default(),
            layout: sent_layout,
            extras,
        })
    }

    /// Logs the joint, IMU, pose and command samples of `part` (the next stretch of the session,
    /// times relative to the same start), gathered into chunks of [`Self::chunk`] samples (a rate
    /// cap keeps a few samples of each of the reader's batches: logged batch by batch, a
    /// paper-scale session became 16 000 chunks of a dozen rows, which the web viewer ingests
    /// slowly), and its power readings once the idle baseline is known ([`Self::log_power`]).
    /// Series of unequal lengths are an error naming the field.
    pub fn add(&mut self, part: &Recording) -> Result<()> {
        check_lengths(part)?;
        self.track_motion(part);
        for (mine, theirs) in self.power.iter_mut().zip([&part.mbs, &part.bms]) {
            mine.t.extend_from_slice(&theirs.t);
            mine.watts.extend_from_slice(&theirs.watts);
        }
        self.log_power(false)?;
        let [state, cmd] = &mut self.decimators;
        let kept = self.slice.recording(part, state, cmd);
        self.kept.append(kept, 0.0);
        if self.kept.state.t.len().max(self.kept.command.t.len()) >= self.chunk {
            self.add_kept()?;
        }
        Ok(())
    }

    /// Logs the power readings gathered so far, raw and net of the idle baseline (the mean of
    /// the readings before the arm first moves), once the baseline is known: as soon as the arm
    /// has moved, or at the `end` — so a viewer opening a long file shows the power from its
    /// start. A sensor without readings before the motion gets a warning and no net power.
    fn log_power(&mut self, end: bool) -> Result<()> {
        for (k, label) in ["mbs", "bms"].into_iter().enumerate() {
            // Known once a reading at or past the motion came (readings arrive in time order).
            let last = self.power[k].t.last().copied();
            let known = end || self.baseline[k].is_some() || last >= Some(self.motion_t);
            if last.is_none() || !known || !end && self.power[k].t.len() < POWER_ROWS {
                continue;
            }
            let series = std::mem::take(&mut self.power[k]);
            let base =
                *self.baseline[k].get_or_insert_with(|| idle_baseline(&series, self.motion_t));
            let (t, watts): (Vec<f64>, Vec<f64>) = (series.t.iter().zip(&series.watts))
                .filter(|(t, _)| self.slice.contains(**t))
                .unzip();
            let w = &mut self.w;
            scalars_chunked(w, &paths::power_raw(label), &t, &watts, self.chunk)?;
            if let Some(base) = base {
                let net: Vec<f64> = watts.iter().map(|p| p - base).collect();
                scalars_chunked(w, &paths::power_net(label), &t, &net, self.chunk)?;
            }
        }
        Ok(())
    }

    /// Logs the gathered kept samples ([`Self::kept`]), then waits for the sink: the samples are
    /// turned into chunks far faster than it encodes and writes them, and without a wait the
    /// chunks in flight pile up (1 h session: peak RSS 175 MB without the waits, 79 MB with them).
    fn add_kept(&mut self) -> Result<()> {
        let kept = std::mem::take(&mut self.kept);
        self.add_samples(&kept)?;
        self.w.flush()
    }

    /// Motion start: the first sample any joint is more than the threshold from the first (over
    /// the whole session, whatever the slice, so the idle baseline is the same).
    fn track_motion(&mut self, part: &Recording) {
        if self.motion_t.is_infinite() {
            for (q, &t) in part.state.q.iter().zip(&part.state.t) {
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
    }

    /// Logs the joint, IMU, pose and command samples of `part`.
    fn add_samples(&mut self, part: &Recording) -> Result<()> {
        let st = &part.state;
        let n = st.t.len().min(st.q.len());
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
                        &paths::joint(name, signal),
                        t,
                        data[start..end].iter().map(|v| v[j]),
                    )?;
                }
            }
            scalars(
                &mut self.w,
                paths::IMU_GYRO_NORM,
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
            if st.quat.len() == st.t.len() {
                let quats: Vec<[f64; 4]> = pose_idx.iter().map(|&i| st.quat[i]).collect();
                robot3d::log_body_orientation(&mut self.w, &mut self.yaw0, &pose_t, &quats)?;
            }
        }
        self.summary.samples += n;

        let cmd = &part.command;
        if !cmd.t.is_empty() && !self.command_style_sent {
            for (j, name) in self.joints.iter().enumerate() {
                // Named like the joint's q: the plot's legend has one entry per joint (its
                // colour the measured q's), which shows or hides both lines.
                style::line(
                    &mut self.w,
                    &paths::joint(name, "q_cmd"),
                    name,
                    style::joint_command(j),
                    0.75,
                )?;
            }
            self.command_style_sent = true;
        }
        for start in (0..cmd.t.len()).step_by(self.chunk) {
            let end = (start + self.chunk).min(cmd.t.len());
            for (j, name) in self.joints.iter().enumerate() {
                scalars(
                    &mut self.w,
                    &paths::joint(name, "q_cmd"),
                    &cmd.t[start..end],
                    cmd.q[start..end].iter().map(|v| v[j]),
                )?;
            }
        }
        Ok(())
    }

    /// Logs the model's series over its next planned trial (its instantaneous prediction and
    /// loss terms at the samples of `state` in the trial's window, sliced as the replay is) and
    /// adds them to the statistics the bars, the note and the link colours are drawn from: how
    /// every model replay logs them, whether the session is held whole or read trial by trial.
    /// Stretches are gathered into chunks of [`ReplayOptions::chunk_rows`] samples (few large
    /// chunks keep the file's index small).
    pub fn log_model_trial(&mut self, state: &crate::signals::StateSeries) -> Result<()> {
        let Some((m, next)) = &mut self.model else {
            bail!("a model trial was logged without a model");
        };
        let (trial, tau0_sq) = m
            .plan
            .get(*next)
            .context("more model trials than planned")?;
        *next += 1;
        let mut s = super::overlay::trial_series(state, trial, tau0_sq, &m.model);
        if !self.slice.is_all() {
            s = s.pick(&self.slice.keep(&s.t, &mut self.model_decimator));
        }
        self.stats.add(trial, &s);
        self.pending.extend(&s);
        let full = self.pending.len() / self.chunk * self.chunk;
        if full > 0 {
            self.write_pending(full)?;
        }
        Ok(())
    }

    /// Logs the first `n` gathered model samples and drops them from the gathering buffer.
    fn write_pending(&mut self, n: usize) -> Result<()> {
        let head = self.pending.take_head(n);
        let w = &mut self.w;
        let (t, predicted) = (&head.t, &head.predicted);
        scalars_chunked(w, paths::MODEL_PREDICTED, t, predicted, self.chunk)?;
        layers::log_term_data(w, &self.joints, &head, self.chunk)?;
        layers::log_breakdown_data(w, &self.joints, &head, self.chunk)?;
        // Computed far faster than the sink writes them: wait for it.
        w.flush()
    }

    /// Logs the power readings left, what the model's series give (shares, note, trial log, link
    /// colours) and the fitted layout; returns what was logged.
    pub fn finish(mut self) -> Result<ReplaySummary> {
        let extras = &std::mem::take(&mut self.extras);
        self.add_kept()?;
        let rest = self.pending.t.len();
        if rest > 0 {
            self.write_pending(rest)?;
        }
        if extras.model.is_some() {
            self.w.flush()?;
        }
        self.log_power(true)?;
        for (k, label) in ["MBS", "BMS"].into_iter().enumerate() {
            match self.baseline[k] {
                Some(None) => self.summary.warnings.push(format!(
                    "{}: no {label} power reading before the arm first moves (t = {:.2} s); net power not logged",
                    self.source.display(),
                    self.motion_t
                )),
                base => self.summary.baseline_w[k] = base.flatten(),
            }
        }
        let w = &mut self.w;
        let scale = self.stats.colour_scale();
        layers::log_model_stats(w, &self.joints, extras, &self.stats)?;
        if extras.model.is_some() {
            // In chunks (a long session has hundreds of thousands of colours per link).
            let (t, power) = (&self.stats.link_t, &self.stats.link_power);
            for (t, power) in t.chunks(self.chunk).zip(power.chunks(self.chunk)) {
                robot3d::log_link_colors(w, self.robot, self.arm, &self.scene, t, power, scale)?;
                w.flush()?;
            }
        }
        if let Some(mut layout) = self.layout.take() {
            // Now every plot's data range is known:
            // the layout again, each plot opening on its data with readable ticks and, where
            // it fits, its legend above the data. After the data, in a fixed message order.
            w.flush()?;
            layout.fit(&|queries, origin| w.range_of(queries, origin));
            blueprint::send_blueprint_generation(w.stream(), &layout, 1)?;
            w.flush().context("sending the fitted viewer layout")?;
        }
        Ok(self.summary)
    }
}

/// Every per-sample vector of a series must be as long as its time vector.
fn check_lengths(rec: &Recording) -> Result<()> {
    let (s, c) = (&rec.state, &rec.command);
    let n = s.t.len();
    for (field, len, stamps) in [
        ("state.q", s.q.len(), n),
        ("state.dq", s.dq.len(), n),
        ("state.tau", s.tau.len(), n),
        ("state.temp", s.temp.len(), n),
        ("state.gyro", s.gyro.len(), n),
        ("command.q", c.q.len(), c.t.len()),
        ("mbs.watts", rec.mbs.watts.len(), rec.mbs.t.len()),
        ("bms.watts", rec.bms.watts.len(), rec.bms.t.len()),
    ] {
        if len != stamps {
            let source = rec.source.display();
            bail!("{source}: {field} has {len} samples but {stamps} time stamps");
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

pub(super) fn scalars(
    w: &mut ChunkWriter<'_>,
    path: &str,
    t: &[f64],
    values: impl Iterator<Item = f64>,
) -> Result<()> {
    if t.is_empty() {
        return Ok(());
    }
    let values: Vec<f64> = values.collect();
    w.note_values(path, &values);
    w.send_columns(path, t, Scalars::new(values).columns_of_unit_batches()?)
}

pub(super) fn scalars_chunked(
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

/// Static legend names and colours of the recorded series (the command's are sent with its
/// first samples, since a streamed session only shows whether it has any when they arrive).
fn log_styles(w: &mut ChunkWriter<'_>, joints: &[String]) -> Result<()> {
    for (j, name) in joints.iter().enumerate() {
        for signal in ["q", "dq", "tau", "temperature"] {
            style::line(w, &paths::joint(name, signal), name, style::joint(j), 1.5)?;
        }
    }
    style::line(w, paths::IMU_GYRO_NORM, "|ω| body", style::NEUTRAL, 1.0)?;
    style::line(w, &paths::power_raw("mbs"), "MBS raw", style::MBS, 1.5)?;
    style::line(w, &paths::power_net("mbs"), "MBS net", style::MBS, 1.5)?;
    style::line(w, &paths::power_raw("bms"), "BMS raw", style::BMS, 1.5)?;
    style::line(w, &paths::power_net("bms"), "BMS net", style::BMS, 1.5)
}

/// The recording's name (the input file's), its real start time, and its properties (input,
/// g1viz version, and `extra`, e.g. command and model), as the viewer's recording properties.
fn log_recording_info(
    w: &mut ChunkWriter<'_>,
    source: &std::path::Path,
    start_ns: u64,
    extra: &[(String, String)],
) -> Result<()> {
    let name = source.file_name().map_or_else(
        || source.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    let start = rerun::components::Timestamp((start_ns.min(i64::MAX as u64) as i64).into());
    w.send_static(
        paths::PROPERTIES,
        &RecordingInfo::new().with_name(name).with_start_time(start),
    )?;
    let mut props = vec![
        ("input".to_owned(), source.display().to_string()),
        (
            "version".to_owned(),
            format!("g1viz {}", env!("CARGO_PKG_VERSION")),
        ),
    ];
    props.extend(extra.iter().cloned());
    let mut values = AnyValues::default();
    for (k, text) in &props {
        let field = rerun::ComponentIdentifier::try_new(k.as_str())
            .with_context(|| format!("recording property name {k:?}"))?;
        values = values.with_component::<rerun::components::Text>(field, [text.as_str()]);
    }
    w.send_static(&format!("{}/g1viz", paths::PROPERTIES), &values)
}
