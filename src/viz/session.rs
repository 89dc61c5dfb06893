//! Replaying a session file, the way `g1viz replay` does: the plain replay (the file read in
//! batches) or the model replay (the streamed validation, then the file replayed, the model's
//! series logged trial by trial as it is read) — memory bounded whatever the session's length
//! either way — the part of the session
//! to log (`--from/--to` in session seconds, `--trials A-B`, `--max-rate` for the series), and
//! the size estimate printed before anything is written.

use std::path::Path;

use anyhow::{Context, Result, bail};

use super::replay::{ReplayExtras, ReplayOptions, ReplaySummary};
use super::slice::Slice;
use super::{OutputKind, Sink, open_stream, recording_id_for_source};
use crate::identify::{IdentifyOptions, validate_file};
use crate::power::PowerModel;
use crate::read::OpenOptions;
use crate::robot::RobotModel;
use crate::session::SessionFile;
use crate::signals::{Group, SignalMap};
use crate::trial::Segmentation;

/// The part of the session to replay, as the user asks for it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Window {
    /// Start [s since the session start].
    pub from_s: Option<f64>,
    /// End [s since the session start].
    pub to_s: Option<f64>,
    /// Trials A to B (inclusive, by index): from A's pre-idle to B's return.
    pub trials: Option<(usize, usize)>,
    /// At most this many samples per second of every per-sample series.
    pub max_rate_hz: Option<f64>,
}

/// One replay of a session file.
pub struct SessionReplay<'a> {
    /// The recording.
    pub session: &'a Path,
    /// Which topics and fields the arm signals come from.
    pub map: &'a SignalMap,
    /// Reader options (message definition paths).
    pub read: &'a OpenOptions,
    /// The robot drawn in 3D.
    pub robot: &'a RobotModel,
    /// The identified model, with the name it is shown under (`None`: plain replay).
    pub model: Option<(&'a str, &'a PowerModel)>,
    /// Segmentation and filters (the model overlay, `--trials`).
    pub fit: IdentifyOptions,
    /// Where the recording goes.
    pub sink: &'a Sink,
    /// Files the output must not overwrite.
    pub inputs: &'a [&'a Path],
    /// The part to log.
    pub window: Window,
    /// Layout, pose rate, properties…
    pub opts: ReplayOptions,
}

/// What a replay tells its user while it runs (printed by the CLI).
#[derive(Debug, Clone, PartialEq)]
pub enum Notice {
    /// A note of the validation behind the model overlay.
    Note(String),
    /// The model's fit on this session.
    ModelFit {
        /// Per-trajectory R².
        r2: f64,
        /// Per-trajectory RMSE [W].
        rmse: f64,
        /// Trials scored.
        trials: usize,
    },
    /// The expected size of the output, before it is written.
    Estimate(SizeEstimate),
    /// No `--max-rate` was given and the whole session at its recorded rate would exceed the
    /// output's budget ([`OutputKind::budget`], bytes, the second value): every per-sample series
    /// is capped at this rate [Hz].
    Capped(f64, f64),
}

/// The largest replay a user gets without asking [bytes]: past it, a replay with no `--max-rate`
/// caps its per-sample series at the highest rate that keeps the estimate within it. A paper-scale
/// session (3–4 h) at the recorded rate is 1.5–4 GB, more than the web viewer holds; a file of
/// this size opens in it whole (docs/viewer.md).
pub const DEFAULT_REPLAY_BYTES: f64 = 150e6;
/// The same for a diagnosis' `.rrd`, an overview of its per-reading findings: small enough that
/// a paper-scale one opens in the web viewer within a minute (docs/benchmarks.md).
pub const DEFAULT_DIAGNOSIS_BYTES: f64 = 15e6;

impl OutputKind {
    /// The default size of this kind of output [bytes] (the cap's budget, [`Notice::Capped`]).
    pub fn budget(self) -> f64 {
        match self {
            OutputKind::Diagnosis => DEFAULT_DIAGNOSIS_BYTES,
            _ => DEFAULT_REPLAY_BYTES,
        }
    }
}

/// The lowest rate the default cap goes to [Hz] (one sample per 10 s), even when the output is
/// then larger than its budget (its chunks alone can be, at 500 Hz over many hours: the
/// estimate printed says so).
const MIN_DEFAULT_HZ: f64 = 0.1;

/// Expected size of a replay's `.rrd`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SizeEstimate {
    /// Session seconds the replay covers.
    pub seconds: f64,
    /// Expected file size [bytes].
    pub bytes: f64,
}

/// Bytes per logged scalar row (one value of one series: row id, two time stamps, the value),
/// measured on the shipped example (82.5 s, 8248 state and command samples: 8.37 MB with poses
/// at 1 Hz, 9.96 MB at 30 Hz; 237 chunks for 21 s of it at 20 Hz, 1.3 MB).
const BYTES_PER_SCALAR: f64 = 24.9;
/// Bytes per logged pose of one moving link (translation + rotation, two time stamps).
const BYTES_PER_LINK_POSE: f64 = 41.7;
/// Bytes per chunk (one entity's rows of one batch: its schema and index), same measurement.
const BYTES_PER_CHUNK: f64 = 2800.0;
/// Fixed part: layout, robot geometry, properties, series styles (≈ 90 static chunks).
const BYTES_FIXED: f64 = 300_000.0;
/// Samples per batch of a replayed file (its chunk size): one chunk per entity and batch.
const BATCH_SAMPLES: f64 = super::replay::STREAMED_CHUNK_ROWS as f64;
/// Scalar series per state sample (q, q̇, τ, temperature of 7 joints, |ω|).
const STATE_SERIES: f64 = 29.0;
/// Scalar series per command sample (q_cmd of 7 joints).
const COMMAND_SERIES: f64 = 7.0;
/// Scalar series per state sample the model adds (instantaneous prediction, 28 joint terms,
/// interaction, 5 per-term and 7 per-joint sums) and links coloured at 10 Hz.
const MODEL_SERIES: f64 = 42.0;
/// Temporal entities besides the joints' and the links': raw and net power of two sensors.
const POWER_ENTITIES: f64 = 4.0;
/// Temporal entities a model adds (its series, bars, readings, errors, trial marks, colours).
const MODEL_ENTITIES: f64 = 80.0;

impl std::fmt::Display for SizeEstimate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mb = self.bytes / 1e6;
        let per_hour = if self.seconds > 0.0 {
            mb * 3600.0 / self.seconds
        } else {
            0.0
        };
        write!(
            f,
            "≈ {mb:.1} MB for {:.0} s of session (≈ {per_hour:.0} MB per hour at these settings)",
            self.seconds
        )
    }
}

impl Window {
    /// Whether the whole session is logged at full rate.
    pub fn is_all(&self) -> bool {
        *self == Window::default()
    }

    /// The slice of the session at `source` (with its trials `seg`, for `--trials`) this window
    /// covers; an error names a trial range the session does not have.
    pub fn resolve(&self, seg: Option<&Segmentation>, source: &Path) -> Result<Slice> {
        let mut slice = Slice {
            max_rate_hz: self.max_rate_hz.filter(|r| *r > 0.0),
            ..Slice::default()
        };
        if let Some((a, b)) = self.trials {
            let seg = seg.context("--trials needs the session's trial segmentation")?;
            let pick: Vec<_> = seg
                .trials
                .iter()
                .filter(|t| t.index >= a && t.index <= b)
                .collect();
            let (Some(first), Some(last)) = (pick.first(), pick.last()) else {
                bail!(
                    "{}: no trials {a}-{b} (the session has {} trials, 0-{})",
                    source.display(),
                    seg.trials.len(),
                    seg.trials.len().saturating_sub(1)
                );
            };
            slice.from_s = first.t_pre_start;
            slice.to_s = last.t_return_end;
        }
        if let Some(from) = self.from_s {
            slice.from_s = slice.from_s.max(from);
        }
        if let Some(to) = self.to_s {
            slice.to_s = slice.to_s.min(to);
        }
        if slice.to_s < slice.from_s {
            bail!(
                "empty replay window: from {:.3} s to {:.3} s",
                slice.from_s,
                slice.to_s
            );
        }
        Ok(slice)
    }
}

/// Replays `r.session` as `g1viz replay` does; `notify` hears the notes, the model's fit and
/// the size estimate (before the output is opened). With a model, the streamed validation gives
/// the overlay (readings, trials, rejections) and the trials for `--trials`; the file is then
/// replayed, the model's series logged trial by trial as the replay reads each trial
/// ([`super::ReplayLogger::log_model_trial`]), never held whole. Without, the file is streamed;
/// `--trials` reads it once more first, in a streamed segmentation pass, to find the trials.
pub fn replay_session(
    r: &SessionReplay<'_>,
    notify: &mut dyn FnMut(Notice),
) -> Result<ReplaySummary> {
    let file = SessionFile {
        path: r.session.to_path_buf(),
        map: r.map.clone(),
        read: r.read.clone(),
        spill: Default::default(),
    };
    let reading = || format!("reading {}", r.session.display());
    let (slice, extras) = match r.model {
        Some((_, model)) => {
            let v = validate_file(model, &file, &r.fit, &r.opts.stream).with_context(reading)?;
            for n in &v.notes {
                notify(Notice::Note(n.clone()));
            }
            notify(Notice::ModelFit {
                r2: v.trial_level_aligned.r2,
                rmse: v.trial_level_aligned.rmse,
                trials: v.per_trial.len(),
            });
            let slice = r.window.resolve(Some(&v.session.segmentation), r.session)?;
            let joints = &r.map.joint_names;
            (
                slice,
                super::overlay::validation_extras(&v, &r.fit, joints, model),
            )
        }
        None if r.window.trials.is_some() => {
            // Only the trials are wanted of this pass: no joint states are kept for later ones.
            let so = crate::session::StreamOptions {
                spill_states: false,
                ..r.opts.stream
            };
            let seg =
                crate::session::segment_file(&file, &r.fit.segment, &so).with_context(reading)?;
            (
                r.window.resolve(Some(&seg), r.session)?,
                ReplayExtras::default(),
            )
        }
        None => (r.window.resolve(None, r.session)?, ReplayExtras::default()),
    };
    let kind = [OutputKind::Replay, OutputKind::ModelReplay][usize::from(extras.model.is_some())];
    write_replay(r, &[r.session], 0.0, extras, slice, kind, notify)
}

/// Replays the sessions at `paths` with a diagnosis' overlay `extras`, as `g1viz diagnose
/// --save` does: joined end to end on the first one's clock, each part starting `gap_s` after the
/// previous one ends, streamed part by part; `r` gives the rest (`r.model` and `r.fit` unused).
pub fn replay_diagnosis(
    r: &SessionReplay<'_>,
    paths: &[&Path],
    gap_s: f64,
    extras: ReplayExtras,
    notify: &mut dyn FnMut(Notice),
) -> Result<ReplaySummary> {
    let slice = r.window.resolve(None, r.session)?;
    write_replay(
        r,
        paths,
        gap_s,
        extras,
        slice,
        OutputKind::Diagnosis,
        notify,
    )
}

/// Writes the replay of `paths` (one session, or several joined `gap_s` apart) with `extras`,
/// `slice` of it, as a `kind` output: the one size rule (without `--max-rate`, the highest rate
/// that keeps the estimate within the kind's budget, [`OutputKind::budget`]), the estimate, and
/// the one streamed replay ([`super::replay_files_with`]).
fn write_replay(
    r: &SessionReplay<'_>,
    paths: &[&Path],
    gap_s: f64,
    extras: ReplayExtras,
    mut slice: Slice,
    kind: OutputKind,
    notify: &mut dyn FnMut(Notice),
) -> Result<ReplaySummary> {
    let arm = r.robot.arm(&r.map.joint_names)?;
    let links = super::robot3d::moving_links(r.robot, &arm).len();
    if let Some(size) = topic_rates(r, paths, &slice, links, extras.model.is_some()) {
        if r.window.max_rate_hz.is_none()
            && let Some(rate) = size.default_cap(kind.budget())
        {
            slice.max_rate_hz = Some(rate);
            notify(Notice::Capped(rate, kind.budget()));
        }
        notify(Notice::Estimate(size.estimate(slice.max_rate_hz)));
    }
    let first = paths.first().context("no session to replay")?;
    let id = recording_id_for_source(first)?;
    let out = open_stream(&kind.app_id(), &kind.recording_id(&id), r.sink, r.inputs)?;
    let opts = ReplayOptions {
        slice,
        ..r.opts.clone()
    };
    let stream = out.stream();
    let (map, read, robot) = (r.map, r.read, r.robot);
    let summary =
        super::replay_files_with(paths, gap_s, map, read, robot, &arm, extras, &opts, stream)
            .with_context(|| format!("replaying {}", first.display()))?;
    out.finish()?;
    Ok(summary)
}

/// What a replay's size depends on: the seconds of session logged, the state and command rates
/// (commands 0 when none), the pose rate of the moving links, and whether a model is shown.
struct ReplaySize {
    seconds: f64,
    state_hz: f64,
    command_hz: f64,
    pose_hz: Option<f64>,
    links: usize,
    model: bool,
}

impl ReplaySize {
    /// The expected size with every per-sample series capped at `max_rate_hz`.
    fn estimate(&self, max_rate_hz: Option<f64>) -> SizeEstimate {
        let (seconds, model) = (self.seconds, self.model);
        let cap = |hz: f64| max_rate_hz.map_or(hz, |m| hz.min(m));
        let state = cap(self.state_hz) * seconds;
        let command = cap(self.command_hz) * seconds;
        let poses = self
            .pose_hz
            .map_or(cap(self.state_hz), |p| p.min(cap(self.state_hz)))
            * seconds;
        let model_rows = if model { MODEL_SERIES * state } else { 0.0 };
        let scalars = STATE_SERIES * state + COMMAND_SERIES * command + model_rows;
        let links = self.links as f64 + 1.0;
        let entities = STATE_SERIES
            + COMMAND_SERIES
            + links
            + POWER_ENTITIES
            + if model { MODEL_ENTITIES } else { 0.0 };
        // Counted per recorded batch, as if each were a chunk (+1: a window starts and ends
        // inside batches). Capped, fewer chunks are written (kept samples are gathered), but a
        // decimated row costs more than the example's (irregular stamps compress worse): counted
        // so, the capped paper replay (3.4 h at 3.7 Hz) is estimated at 149 MB, written 157 MB.
        let batches = (self.state_hz * seconds / BATCH_SAMPLES).ceil() + 1.0;
        SizeEstimate {
            seconds,
            bytes: BYTES_FIXED
                + BYTES_PER_CHUNK * entities * batches
                + BYTES_PER_SCALAR * scalars
                + BYTES_PER_LINK_POSE * links * poses,
        }
    }

    /// The rate cap that keeps the replay within `budget` bytes (two significant digits, rounded
    /// down), `None` when the recorded rate does.
    fn default_cap(&self, budget: f64) -> Option<f64> {
        let fits = |hz: f64| self.estimate(Some(hz)).bytes <= budget;
        if self.estimate(None).bytes <= budget {
            return None;
        }
        if !fits(MIN_DEFAULT_HZ) {
            return Some(MIN_DEFAULT_HZ);
        }
        let (mut lo, mut hi) = (MIN_DEFAULT_HZ, self.state_hz);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if fits(mid) { lo = mid } else { hi = mid }
        }
        let step = 10f64.powf(lo.log10().floor() - 1.0);
        let hz = ((lo / step).floor() * step * 1e3).round() / 1e3; // 2.3, not 2.3000000000000003
        Some(hz.max(MIN_DEFAULT_HZ))
    }
}

/// The part of the sessions at `paths` logged and their rates, from the files' topic statistics
/// (summary or index when the container has them; the rates are the first file's, the seconds
/// summed over the files, each clipped to `slice`); `None` when they cannot be read (the replay
/// itself then reports the problem).
fn topic_rates(
    r: &SessionReplay<'_>,
    paths: &[&Path],
    slice: &Slice,
    links: usize,
    model: bool,
) -> Option<ReplaySize> {
    let (state, command) = (
        r.map.group_topic(Group::State),
        r.map.group_topic(Group::Command),
    );
    let mut size = ReplaySize {
        seconds: 0.0,
        state_hz: 0.0,
        command_hz: 0.0,
        pose_hz: r.opts.pose_rate_hz,
        links,
        model,
    };
    for (k, path) in paths.iter().enumerate() {
        let info = crate::read::Session::open(path, r.read).ok()?.info().ok()?;
        let of = |topic: Option<&str>| info.topics.iter().find(|t| Some(t.topic.as_str()) == topic);
        if let Some(t) = of(state) {
            let s = |ns: u64| ns.saturating_sub(info.start_ns) as f64 * 1e-9;
            size.seconds +=
                (s(t.last_ns).min(slice.to_s) - s(t.first_ns).max(slice.from_s)).max(0.0);
            size.state_hz = [t.rate_hz, size.state_hz][usize::from(k > 0)];
        }
        if k == 0 {
            size.command_hz = of(command).map_or(0.0, |t| t.rate_hz);
        }
    }
    Some(size)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn size(seconds: f64, model: bool) -> ReplaySize {
        let (state_hz, command_hz, pose_hz, links) = (100.0, 100.0, Some(30.0), 16);
        ReplaySize {
            seconds,
            state_hz,
            command_hz,
            pose_hz,
            links,
            model,
        }
    }

    /// A short session replays whole; a paper-scale one is capped at the highest two-digit rate
    /// whose estimate fits the default size, and one step more would not fit.
    #[test]
    fn the_default_cap_keeps_a_replay_within_its_size() {
        assert_eq!(size(82.5, true).default_cap(DEFAULT_REPLAY_BYTES), None);
        for (seconds, model) in [
            (3_600.0, false),
            (12_336.0, false),
            (12_336.0, true),
            (36_000.0, true),
        ] {
            let s = size(seconds, model);
            let hz = s
                .default_cap(DEFAULT_REPLAY_BYTES)
                .expect("a paper-scale replay is capped");
            assert!(
                s.estimate(Some(hz)).bytes <= DEFAULT_REPLAY_BYTES,
                "{seconds} s: {hz} Hz: {:?} / {:?}",
                s.estimate(Some(hz)),
                s.estimate(Some(1.0))
            );
            let step = 10f64.powf(hz.log10().floor() - 1.0);
            let more = s.estimate(Some(hz + step)).bytes;
            assert!(
                more > DEFAULT_REPLAY_BYTES,
                "{seconds} s: {hz} Hz, {more} B at +{step}"
            );
        }
        // 10 h at 500 Hz with the model: its chunks alone pass the size; the cap stops at its floor.
        let long = ReplaySize {
            state_hz: 500.0,
            ..size(36_000.0, true)
        };
        assert!(long.estimate(Some(MIN_DEFAULT_HZ)).bytes > DEFAULT_REPLAY_BYTES);
        assert_eq!(long.default_cap(DEFAULT_REPLAY_BYTES), Some(MIN_DEFAULT_HZ));
    }
}
