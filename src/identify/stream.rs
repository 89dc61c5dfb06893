//! Bounded-memory reading of a session file for identification and validation, in two streamed
//! passes (memory does not grow with the session's length):
//!
//! 1. **Segmentation pass** (every arm topic): the samples are buffered in pieces of about
//!    [`StreamOptions::chunk_s`] seconds; each piece is segmented, the trials it completes are
//!    kept (σ_ω of each taken on the spot) and the buffer is cut at the last one's return, so the
//!    next piece starts with that return and the home idle before the next trial. With a
//!    command stream every trial boundary depends only on the samples around it, so the trials
//!    equal those of segmenting the whole session at once (tested); the measured-state
//!    segmenter's noise threshold is estimated per piece. The power series are kept whole
//!    (~1 Hz). The joint states of the sensor-timing search's trials are held: every n-th trial,
//!    n a power of two that doubles whenever more than [`StreamOptions::hold_trials`] would be
//!    held, which is the search's own choice of trials without knowing the session's length
//!    ([`super::pipeline::search_stride`]). Only with `hold_trials` below the search's cap are
//!    the search's trials read in an extra streamed pass ([`hold_pass`]).
//! 2. **Row pass** (joint states only, same clock): a buffer holds the samples from the current
//!    trial's pre-idle to its post-idle end; each trial's rows (per reading, per trial, thinned
//!    per sample) are built there and the buffer is emptied before the next trial.

use std::path::PathBuf;

use anyhow::Result;

use super::dataset::{self, Dataset, DatasetOptions, Mode, Row};
use super::sample::SampleSums;
use crate::N_JOINTS;
use crate::read::OpenOptions;
use crate::signals::{
    PowerSeries, Recording, SignalMap, SpillSlot, SpillWriter, StateSeries, Target,
    stream_recording,
};
use crate::trial::{self, SegmentOptions, Segmentation, TrialWindow};

/// Tuning of the streamed read.
#[derive(Debug, Clone, Copy)]
pub struct StreamOptions {
    /// Length of the pieces the segmentation pass buffers [s] (a session shorter than this is
    /// segmented in one piece, exactly as in memory).
    pub chunk_s: f64,
    /// Most trials whose joint states pass 1 holds for the sensor-timing search (every n-th,
    /// n a power of two). At or above [`super::pipeline::IdentifyOptions::search_trials`] they
    /// include the search's trials; below it the search's trials are read in an extra pass.
    pub hold_trials: usize,
    /// Samples per decoded batch.
    pub batch_samples: usize,
    /// Whether the segmentation pass keeps the session's joint states in a temporary file
    /// (about 150 bytes per sample) for the passes after it ([`SessionFile::spill`]): they then
    /// read no more of the recording than those samples, bit for bit the same.
    pub spill_states: bool,
}

impl Default for StreamOptions {
    fn default() -> Self {
        StreamOptions {
            chunk_s: 300.0,
            hold_trials: super::pipeline::SEARCH_TRIALS,
            batch_samples: 4096,
            spill_states: true,
        }
    }
}

/// A session file and how to read it.
#[derive(Debug, Clone)]
pub struct SessionFile {
    /// File or bag folder.
    pub path: PathBuf,
    /// Topics and fields of the arm signals.
    pub map: SignalMap,
    /// Reader options (message definitions).
    pub read: OpenOptions,
    /// The joint states the first full pass spilled to a temporary file
    /// ([`StreamOptions::spill_states`]); the passes after it read their trials' samples from
    /// there. Empty (`Default`): every pass reads the file. Shared by clones.
    pub spill: SpillSlot,
}

/// Margin around a trial's window whose samples are kept [s] (rows only read inside it).
const MARGIN_S: f64 = 0.5;

/// What the segmentation pass found.
pub(crate) struct Pass1 {
    pub source: PathBuf,
    pub seg: Segmentation,
    /// σ_ω over each trial's analysis window, in `seg.trials` order.
    pub sigmas: Vec<f64>,
    /// Joint states (t, τ, q̇) of `held_trials`' windows plus the whole power series.
    pub held: Recording,
    pub held_trials: Vec<TrialWindow>,
    /// Winding temperatures of the first joint-state sample.
    pub first_temp_c: Option<[f64; N_JOINTS]>,
    pub warnings: Vec<String>,
}

/// Append the samples of `from` (all of its columns that `to` keeps) to `to`.
fn append_state(to: &mut StateSeries, from: &StateSeries, full: bool) {
    to.t.extend_from_slice(&from.t);
    to.tau.extend_from_slice(&from.tau);
    to.dq.extend_from_slice(&from.dq);
    to.gyro.extend_from_slice(&from.gyro);
    if full {
        to.q.extend_from_slice(&from.q);
        to.temp.extend_from_slice(&from.temp);
        to.quat.extend_from_slice(&from.quat);
    }
}

/// Drop the samples before index `i` of every non-empty column.
fn drain_state(s: &mut StateSeries, i: usize) {
    fn d<T>(v: &mut Vec<T>, i: usize) {
        v.drain(..i.min(v.len()));
    }
    d(&mut s.t, i);
    d(&mut s.q, i);
    d(&mut s.dq, i);
    d(&mut s.tau, i);
    d(&mut s.temp, i);
    d(&mut s.gyro, i);
    d(&mut s.quat, i);
}

/// Sort every column of `s` by time (a file without an index may deliver a batch earlier than
/// the previous one).
fn sort_state(s: &mut StateSeries) {
    if s.t.is_sorted() {
        return;
    }
    let mut order: Vec<usize> = (0..s.t.len()).collect();
    order.sort_by(|&a, &b| s.t[a].total_cmp(&s.t[b]));
    fn p<T: Copy>(v: &mut Vec<T>, o: &[usize]) {
        if v.len() == o.len() {
            *v = o.iter().map(|&i| v[i]).collect();
        }
    }
    p(&mut s.t, &order);
    p(&mut s.q, &order);
    p(&mut s.dq, &order);
    p(&mut s.tau, &order);
    p(&mut s.temp, &order);
    p(&mut s.gyro, &order);
    p(&mut s.quat, &order);
}

/// The joint states of every `stride`-th trial (by index) for the sensor-timing search, at most
/// `max` trials: when one more would exceed it, the stride doubles and the trials off the new
/// stride are dropped. The set is then the one [`super::pipeline::search_stride`] picks for a
/// session of that length with cap `max`, and holds the search's trials for any smaller cap.
struct Holder {
    max: usize,
    stride: usize,
    rec: Recording,
    trials: Vec<TrialWindow>,
}

impl Holder {
    fn new(max: usize) -> Holder {
        Holder {
            max: max.max(1),
            stride: 1,
            rec: Recording::default(),
            trials: Vec::new(),
        }
    }

    /// Copy the samples of `trial`'s window from `from` when its index is on the stride.
    fn offer(&mut self, from: &StateSeries, trial: &TrialWindow) {
        if !trial.index.is_multiple_of(self.stride) {
            return;
        }
        copy_window(&mut self.rec.state, from, trial);
        self.trials.push(trial.clone());
        while self.trials.len() > self.max {
            self.stride *= 2;
            let old = std::mem::take(&mut self.rec.state);
            let stride = self.stride;
            self.trials.retain(|t| t.index.is_multiple_of(stride));
            // The old set is the union of its trials' windows: every kept window is in it.
            for t in &self.trials {
                copy_window(&mut self.rec.state, &old, t);
            }
        }
    }
}

/// Append `from`'s (t, τ, q̇) samples inside `trial`'s window (with margins) that are later than
/// the last sample of `to`.
fn copy_window(to: &mut StateSeries, from: &StateSeries, trial: &TrialWindow) {
    let after = to.t.last().copied().unwrap_or(f64::NEG_INFINITY);
    let lo = (trial.t_pre_start - MARGIN_S).max(after);
    let n = from.t.len().min(from.tau.len()).min(from.dq.len());
    let i0 = from.t[..n].partition_point(|&x| x <= lo);
    let i1 = from.t[..n].partition_point(|&x| x <= trial.t_post_end + MARGIN_S);
    if i0 < i1 {
        to.t.extend_from_slice(&from.t[i0..i1]);
        to.tau.extend_from_slice(&from.tau[i0..i1]);
        to.dq.extend_from_slice(&from.dq[i0..i1]);
    }
}

/// Piecewise segmentation state of pass 1.
struct Chunker<'o> {
    opts: &'o SegmentOptions,
    chunk_s: f64,
    /// Joint states and commands of the current piece.
    buf: Recording,
    /// Return end of the last accepted trial (−∞ before the first).
    until: f64,
    /// Trajectory start of the last accepted trial.
    last_traj: f64,
    seg: Segmentation,
    sigmas: Vec<f64>,
    hold: Holder,
}

impl Chunker<'_> {
    fn span(&self) -> f64 {
        let span = |t: &[f64]| match (t.first(), t.last()) {
            (Some(a), Some(b)) => b - a,
            _ => 0.0,
        };
        span(&self.buf.state.t).max(span(&self.buf.command.t))
    }

    fn push(&mut self, batch: &Recording) {
        append_state(&mut self.buf.state, &batch.state, true);
        sort_state(&mut self.buf.state);
        let c = &mut self.buf.command;
        c.t.extend_from_slice(&batch.command.t);
        c.q.extend_from_slice(&batch.command.q);
        c.dq.extend_from_slice(&batch.command.dq);
        if !c.t.is_sorted() {
            let mut o: Vec<usize> = (0..c.t.len()).collect();
            o.sort_by(|&a, &b| c.t[a].total_cmp(&c.t[b]));
            c.t = o.iter().map(|&i| c.t[i]).collect();
            if c.q.len() == o.len() {
                c.q = o.iter().map(|&i| c.q[i]).collect();
            }
            if c.dq.len() == o.len() {
                c.dq = o.iter().map(|&i| c.dq[i]).collect();
            }
        }
    }

    /// Segment the buffer, keep the trials it completes (all of them when `last`), and cut the
    /// buffer at the return of the last one kept.
    fn process(&mut self, last: bool) {
        let seg = trial::segment(&self.buf, self.opts);
        if self.seg.source.is_empty() {
            self.seg.source = seg.source.clone();
        }
        let fresh: Vec<&TrialWindow> = seg
            .trials
            .iter()
            .filter(|t| t.t_traj_start > self.last_traj)
            .collect();
        // The newest trial of a piece may still be cut off by the piece's end: the next piece
        // segments it again.
        let take = if last {
            fresh.len()
        } else {
            fresh.len().saturating_sub(1)
        };
        let before = self.until;
        for t in &fresh[..take] {
            let mut t = (*t).clone();
            t.index = self.seg.trials.len();
            let (a, b) = t.analysis_window();
            self.sigmas.push(trial::sigma_omega(&self.buf, a, b));
            self.hold.offer(&self.buf.state, &t);
            self.until = t.t_return_end;
            self.last_traj = t.t_traj_start;
            self.seg.trials.push(t);
        }
        let mut cut = fresh[..take].last().map(|t| t.t_post_end);
        if !last && cut.is_none() && self.span() > 2.0 * self.chunk_s {
            // No trial completed in two pieces' time: keep only the last piece (bounded memory
            // on a session that does not follow the protocol), reporting what came before.
            let end = self.buf.state.t.last().copied().unwrap_or(0.0);
            let mut c = end - self.chunk_s;
            if let Some(t) = fresh.first() {
                c = c.min(t.t_pre_start - MARGIN_S);
            }
            let start = self.buf.state.t.first().copied().unwrap_or(0.0);
            if c <= start {
                c = end - self.chunk_s;
            }
            self.until = self.until.max(c);
            cut = Some(c);
        }
        let upto = if last { f64::INFINITY } else { self.until };
        for s in seg.unmatched {
            if s.t0 >= before && s.t0 < upto {
                self.seg.unmatched.push(s);
            }
        }
        if let (false, Some(cut)) = (last, cut) {
            let i = self.buf.state.t.partition_point(|&x| x < cut);
            drain_state(&mut self.buf.state, i);
            let c = &mut self.buf.command;
            let i = c.t.partition_point(|&x| x < cut);
            c.t.drain(..i);
            c.q.drain(..i.min(c.q.len()));
            c.dq.drain(..i.min(c.dq.len()));
        }
    }
}

/// Pass 1: segment `file` piece by piece, σ_ω per trial, the held samples and the power series.
pub(crate) fn segmentation_pass(
    file: &SessionFile,
    opts: &SegmentOptions,
    so: &StreamOptions,
) -> Result<Pass1> {
    let mut ch = Chunker {
        opts,
        chunk_s: so.chunk_s.max(1.0),
        buf: Recording::default(),
        until: f64::NEG_INFINITY,
        last_traj: f64::NEG_INFINITY,
        seg: Segmentation::default(),
        sigmas: Vec::new(),
        hold: Holder::new(so.hold_trials),
    };
    let mut mbs = PowerSeries::default();
    let mut bms = PowerSeries::default();
    let mut first_temp_c = None;
    let mut spill = if so.spill_states && file.spill.get().is_none() {
        // Without a temporary file the later passes read the recording again.
        SpillWriter::new().ok()
    } else {
        None
    };
    let summary = stream_recording(
        &file.path,
        &file.map,
        &file.read,
        so.batch_samples,
        &mut |batch| {
            // A full disk drops the spill, not the read: the later passes read the file.
            if let Some(w) = &mut spill
                && w.push(&batch.state).is_err()
            {
                spill = None;
            }
            if first_temp_c.is_none() {
                first_temp_c = batch.state.temp.first().copied();
            }
            mbs.t.extend_from_slice(&batch.mbs.t);
            mbs.watts.extend_from_slice(&batch.mbs.watts);
            bms.t.extend_from_slice(&batch.bms.t);
            bms.watts.extend_from_slice(&batch.bms.watts);
            ch.push(batch);
            if ch.span() >= ch.chunk_s {
                ch.process(false);
            }
            Ok(())
        },
    )?;
    ch.process(true);
    mbs.sort_by_time();
    bms.sort_by_time();
    if let Some(mut s) = spill.and_then(|w| w.finish(summary.start_ns).ok()) {
        s.power = Some([mbs.clone(), bms.clone()]);
        file.spill.fill(s);
    }
    let mut held = ch.hold.rec;
    held.source = file.path.clone();
    held.start_ns = summary.start_ns;
    held.joint_names = file.map.joint_names.clone();
    held.mbs = mbs;
    held.bms = bms;
    Ok(Pass1 {
        source: file.path.clone(),
        seg: ch.seg,
        sigmas: ch.sigmas,
        held,
        held_trials: ch.hold.trials,
        first_temp_c,
        warnings: summary.warnings,
    })
}

/// What pass 2 builds.
pub(crate) struct RowPlan<'a> {
    pub target: Target,
    pub alignment: dataset::Alignment,
    /// Every trial of the session (reading and trial rows are built for each).
    pub trials: &'a [TrialWindow],
    /// Trials whose sample rows are built (thinned by `sample_stride`).
    pub sample_trials: &'a [usize],
    pub sample_stride: usize,
    /// Trials whose sample rows are reduced to per-trial statistics (only when the fit itself
    /// is per sample).
    pub full_sample_trials: &'a [usize],
}

/// The rows of one session (every trial's reading and trial rows; sample rows as planned).
pub(crate) struct SessionSets {
    pub reading: Dataset,
    pub trial: Dataset,
    /// Thinned sample rows of the planned trials.
    pub sample_thin: Vec<Row>,
    /// The sample rows of the planned trials reduced to per-trial statistics (empty unless
    /// planned: only the per-sample fit needs them).
    pub sample_sums: SampleSums,
}

fn empty_set(mode: Mode, plan: &RowPlan) -> Dataset {
    Dataset {
        mode,
        target: plan.target,
        alignment: plan.alignment,
        rows: Vec::new(),
        trials: Vec::new(),
        skipped: Vec::new(),
    }
}

fn extend(to: &mut Dataset, from: Dataset) {
    to.rows.extend(from.rows);
    to.trials.extend(from.trials);
    to.skipped.extend(from.skipped);
}

impl SessionSets {
    pub(crate) fn new(plan: &RowPlan) -> SessionSets {
        SessionSets {
            reading: empty_set(Mode::Reading, plan),
            trial: empty_set(Mode::Trial, plan),
            sample_thin: Vec::new(),
            sample_sums: SampleSums::default(),
        }
    }

    /// Add the rows of `trial` built on `rec` (which holds at least the trial's window).
    pub(crate) fn add_trial(&mut self, rec: &Recording, trial: &TrialWindow, plan: &RowPlan) {
        let opts = |mode| DatasetOptions {
            mode,
            target: plan.target,
            alignment: plan.alignment,
        };
        let one = std::slice::from_ref(trial);
        extend(
            &mut self.reading,
            dataset::build(rec, one, &opts(Mode::Reading)),
        );
        extend(
            &mut self.trial,
            dataset::build(rec, one, &opts(Mode::Trial)),
        );
        if plan.sample_trials.contains(&trial.index) {
            self.sample_thin.extend(dataset::sample_rows_thinned(
                rec,
                trial,
                &opts(Mode::Sample),
                plan.sample_stride,
            ));
        }
        if plan.full_sample_trials.contains(&trial.index) {
            self.sample_sums
                .add(dataset::build(rec, one, &opts(Mode::Sample)));
        }
    }
}

/// The trials of `file`, found by the streamed segmentation pass (memory bounded whatever the
/// session's length; the trials equal those of segmenting the whole session when it has a
/// command stream).
pub fn segment_file(
    file: &SessionFile,
    opts: &SegmentOptions,
    so: &StreamOptions,
) -> Result<Segmentation> {
    let mut so = *so;
    so.hold_trials = 1;
    Ok(segmentation_pass(file, opts, &so)?.seg)
}

/// The joint states (t, τ, q̇) of `trials`' windows (in time order), read in one streamed pass
/// over `file`'s joint states, with the clock and power series of `power` (those of pass 1):
/// the sensor-timing search's trials when pass 1 could not hold every trial.
pub(crate) fn hold_pass(
    file: &SessionFile,
    power: &Recording,
    trials: &[TrialWindow],
    so: &StreamOptions,
) -> Result<Recording> {
    let mut held = Recording {
        source: file.path.clone(),
        start_ns: power.start_ns,
        joint_names: file.map.joint_names.clone(),
        mbs: power.mbs.clone(),
        bms: power.bms.clone(),
        ..Recording::default()
    };
    let mut buf = Recording::default();
    stream_trial_windows(file, power.start_ns, trials, so, &mut buf, &mut |buf, t| {
        copy_window(&mut held.state, &buf.state, t)
    })?;
    Ok(held)
}

/// Pass 2 (and the sample-mode scoring pass): stream the joint states of `file` (clock of
/// pass 1) and call `on_trial` for each of `trials` (in time order) with a recording holding
/// that trial's window and the power series, holding only about one trial's samples.
///
/// `power` gives the clock (`start_ns`) and the power series (those of pass 1).
pub(crate) fn trial_pass(
    file: &SessionFile,
    power: &Recording,
    trials: &[TrialWindow],
    so: &StreamOptions,
    on_trial: &mut dyn FnMut(&Recording, &TrialWindow),
) -> Result<()> {
    let mut buf = Recording {
        source: file.path.clone(),
        start_ns: power.start_ns,
        joint_names: file.map.joint_names.clone(),
        mbs: power.mbs.clone(),
        bms: power.bms.clone(),
        ..Recording::default()
    };
    stream_trial_windows(file, power.start_ns, trials, so, &mut buf, on_trial)
}

/// Stream `file`'s joint states into `buf.state` and hand each of `trials` (in time order) to
/// `on_trial` once its whole window (pre-idle start to post-idle end, ± the margin) has been
/// read; samples no later trial needs are dropped, so `buf` holds about one trial at a time.
fn stream_trial_windows(
    file: &SessionFile,
    start_ns: u64,
    trials: &[TrialWindow],
    so: &StreamOptions,
    buf: &mut Recording,
    on_trial: &mut dyn FnMut(&Recording, &TrialWindow),
) -> Result<()> {
    let span = TrialSpan {
        end: &|t| t.t_post_end,
        all_columns: false,
    };
    stream_trial_spans(
        file,
        start_ns,
        trials,
        so.batch_samples,
        &span,
        buf,
        on_trial,
    )
}

/// Which part of each trial a streamed trial walk reads, and which joint-state columns it keeps.
struct TrialSpan<'a> {
    /// End of a trial's window (before the margin).
    end: &'a dyn Fn(&TrialWindow) -> f64,
    /// Keep every column (q, temperatures, quaternion too), not only t, τ, q̇ and the gyro.
    all_columns: bool,
}

/// [`stream_trial_windows`] with each trial's window ending at `end(trial)` (+ the margin).
fn stream_trial_spans(
    file: &SessionFile,
    start_ns: u64,
    trials: &[TrialWindow],
    batch_samples: usize,
    span: &TrialSpan<'_>,
    buf: &mut Recording,
    on_trial: &mut dyn FnMut(&Recording, &TrialWindow),
) -> Result<()> {
    // Only the trials' windows are read (an indexed MCAP skips the chunks between them): the
    // windows ± the margin, merged where they touch.
    let mut windows: Vec<(f64, f64)> = trials
        .iter()
        .map(|t| (t.t_pre_start - MARGIN_S, (span.end)(t) + MARGIN_S))
        .collect();
    windows.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut ranges: Vec<(f64, f64)> = Vec::with_capacity(windows.len());
    for (a, b) in windows {
        match ranges.last_mut() {
            Some(last) if a <= last.1 => last.1 = last.1.max(b),
            _ => ranges.push((a, b)),
        }
    }
    let mut next = 0usize;
    let mut step = |buf: &mut Recording, done: bool| {
        let last_t = buf.state.t.last().copied().unwrap_or(f64::NEG_INFINITY);
        while let Some(t) = trials.get(next) {
            if !done && last_t <= (span.end)(t) + MARGIN_S {
                break;
            }
            on_trial(buf, t);
            next += 1;
        }
        let keep_from = trials
            .get(next)
            .map_or(f64::INFINITY, |t| t.t_pre_start - MARGIN_S);
        let i = buf.state.t.partition_point(|&x| x < keep_from);
        drain_state(&mut buf.state, i);
    };
    let mut on_state = |state: &StateSeries| {
        append_state(&mut buf.state, state, span.all_columns);
        sort_state(&mut buf.state);
        step(buf, false);
        Ok(())
    };
    match file.spill.get().filter(|s| s.origin_ns == start_ns) {
        Some(spill) => spill.stream(Some(&ranges), &mut on_state)?,
        None => {
            crate::signals::stream_state(
                &file.path,
                &file.map,
                &file.read,
                start_ns,
                batch_samples,
                Some(&ranges),
                &mut |batch| on_state(&batch.state),
            )?;
        }
    }
    step(buf, true);
    Ok(())
}

/// Stream only the joint states of `file` inside `trials`' whole windows (pre-idle start to the
/// later of post-idle end and return end, ± half a second; an indexed MCAP skips the chunks
/// between them) and call `on_trial` for each of `trials` (in time order) with a recording
/// holding at least that window's joint states and nothing else. `start_ns` is the clock's
/// origin: the [`crate::signals::StreamSummary::start_ns`] of the pass that found the trials.
pub fn for_each_trial_state(
    file: &SessionFile,
    start_ns: u64,
    trials: &[TrialWindow],
    batch_samples: usize,
    on_trial: &mut dyn FnMut(&Recording, &TrialWindow),
) -> Result<()> {
    let mut buf = Recording {
        source: file.path.clone(),
        start_ns,
        joint_names: file.map.joint_names.clone(),
        ..Recording::default()
    };
    stream_trial_spans(
        file,
        start_ns,
        trials,
        batch_samples,
        &TrialSpan {
            end: &|t| t.t_post_end.max(t.t_return_end),
            all_columns: true,
        },
        &mut buf,
        on_trial,
    )
}

/// Stream every arm topic of `file` once and call `on_trial` for each of `trials` (in time
/// order) with a recording holding at least that trial's joint states (all columns, from its
/// pre-idle start to its return end) and every power reading up to a few seconds past the
/// trial's window; earlier samples are dropped, so
/// memory stays bounded. Times share the clock of [`segmentation_pass`] (the same earliest
/// message). Used by the row export, which needs the temperatures too.
pub fn for_each_trial(
    file: &SessionFile,
    trials: &[TrialWindow],
    batch_samples: usize,
    on_trial: &mut dyn FnMut(&Recording, &TrialWindow),
) -> Result<()> {
    for_each_trial_and_batch(file, trials, batch_samples, &mut |_| {}, on_trial)
}

/// [`for_each_trial`], also showing `on_batch` every decoded batch as it arrives (every sample
/// of the session, on the same clock), e.g. for statistics over the whole session.
pub fn for_each_trial_and_batch(
    file: &SessionFile,
    trials: &[TrialWindow],
    batch_samples: usize,
    on_batch: &mut dyn FnMut(&Recording),
    on_trial: &mut dyn FnMut(&Recording, &TrialWindow),
) -> Result<()> {
    trials_and_batches(file, trials, batch_samples, false, on_batch, on_trial)
}

/// [`for_each_trial_and_batch`] for a caller that needs joint states and power only (no
/// commands): when the first pass spilled the session ([`SessionFile::spill`]), the batches come
/// from the spill and the recording is not read again.
pub fn for_each_trial_and_batch_no_commands(
    file: &SessionFile,
    trials: &[TrialWindow],
    batch_samples: usize,
    on_batch: &mut dyn FnMut(&Recording),
    on_trial: &mut dyn FnMut(&Recording, &TrialWindow),
) -> Result<()> {
    trials_and_batches(file, trials, batch_samples, true, on_batch, on_trial)
}

fn trials_and_batches(
    file: &SessionFile,
    trials: &[TrialWindow],
    batch_samples: usize,
    spilled_only: bool,
    on_batch: &mut dyn FnMut(&Recording),
    on_trial: &mut dyn FnMut(&Recording, &TrialWindow),
) -> Result<()> {
    // A reading stamped up to this long after the window can still belong to it (sensor lag).
    const AFTER_S: f64 = 2.0;
    let mut buf = Recording {
        source: file.path.clone(),
        joint_names: file.map.joint_names.clone(),
        ..Recording::default()
    };
    let mut next = 0usize;
    let mut step = |buf: &mut Recording, done: bool| {
        let last_t = buf.state.t.last().copied().unwrap_or(f64::NEG_INFINITY);
        while let Some(t) = trials.get(next) {
            if !done && last_t <= t.t_post_end.max(t.t_return_end) + AFTER_S {
                break;
            }
            on_trial(buf, t);
            next += 1;
        }
        let keep_from = trials
            .get(next)
            .map_or(f64::INFINITY, |t| t.t_pre_start - MARGIN_S);
        let i = buf.state.t.partition_point(|&x| x < keep_from);
        drain_state(&mut buf.state, i);
    };
    let mut on_recording = |batch: &Recording| {
        on_batch(batch);
        buf.start_ns = batch.start_ns;
        append_state(&mut buf.state, &batch.state, true);
        sort_state(&mut buf.state);
        for (to, from) in [(&mut buf.mbs, &batch.mbs), (&mut buf.bms, &batch.bms)] {
            to.t.extend_from_slice(&from.t);
            to.watts.extend_from_slice(&from.watts);
            to.sort_by_time();
        }
        step(&mut buf, false);
        Ok(())
    };
    match (file.spill.get(), spilled_only) {
        (Some(spill), true) if spill.power.is_some() => {
            replay_spill(spill, &file.map.joint_names, &mut on_recording)?
        }
        _ => {
            stream_recording(
                &file.path,
                &file.map,
                &file.read,
                batch_samples,
                &mut on_recording,
            )?;
        }
    }
    step(&mut buf, true);
    Ok(())
}

/// The batches of a spilled session ([`SessionFile::spill`]) as the recording's full read
/// delivers them, without the commands: each block of joint states with the power readings
/// stamped up to its last sample (the rest with the last block).
fn replay_spill(
    spill: &crate::signals::StateSpill,
    joint_names: &[String],
    on_batch: &mut dyn FnMut(&Recording) -> Result<()>,
) -> Result<()> {
    let Some([mbs, bms]) = &spill.power else {
        anyhow::bail!("the spill holds no power readings");
    };
    let mut from = [0usize; 2];
    let mut pending: Option<StateSeries> = None;
    let mut emit = |state: StateSeries, last: bool, from: &mut [usize; 2]| {
        let t_max = state.t.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let mut rec = Recording {
            start_ns: spill.origin_ns,
            joint_names: joint_names.to_vec(),
            state,
            ..Recording::default()
        };
        for (k, (p, to)) in [(mbs, &mut rec.mbs), (bms, &mut rec.bms)]
            .into_iter()
            .enumerate()
        {
            let end = if last {
                p.t.len()
            } else {
                from[k] + p.t[from[k]..].partition_point(|&t| t <= t_max)
            };
            to.t.extend_from_slice(&p.t[from[k]..end]);
            to.watts.extend_from_slice(&p.watts[from[k]..end]);
            from[k] = end;
        }
        on_batch(&rec)
    };
    // One block behind, so that the last one also takes the readings after it.
    spill.stream(None, &mut |s| {
        if let Some(prev) = pending.replace(s.clone()) {
            emit(prev, false, &mut from)?;
        }
        Ok(())
    })?;
    emit(pending.unwrap_or_default(), true, &mut from)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::search_stride;

    /// Trials 10 s apart with one sample per 0.1 s in each window (q̇ = the trial index, so a
    /// sample says which trial it came from).
    fn session(n: usize) -> (StateSeries, Vec<TrialWindow>) {
        let mut s = StateSeries::default();
        let mut trials = Vec::new();
        for i in 0..n {
            let t0 = 10.0 * i as f64;
            trials.push(TrialWindow {
                index: i,
                t_pre_start: t0 + 1.0,
                t_traj_start: t0 + 2.0,
                t_traj_end: t0 + 4.0,
                t_post_end: t0 + 5.0,
                t_return_end: t0 + 7.0,
                joints_moved: vec![0],
                qdot_max_cmd: 1.0,
                qdot_max_meas: 1.0,
            });
        }
        for k in 0..(100 * n) {
            s.t.push(0.1 * k as f64);
            s.tau.push([0.0; N_JOINTS]);
            s.dq.push([(k / 100) as f64; N_JOINTS]);
        }
        (s, trials)
    }

    #[test]
    fn the_held_trials_are_the_search_stride_of_the_session_length() {
        for n in [1, 2, 5, 7, 8, 9, 24, 33, 64, 65] {
            let (s, trials) = session(n);
            for max in [1, 2, 3, 5, 6, 12, 100] {
                let mut h = Holder::new(max);
                for t in &trials {
                    h.offer(&s, t);
                }
                let stride = search_stride(&[n], max);
                let want: Vec<usize> = (0..n).filter(|i| i % stride == 0).collect();
                let got: Vec<usize> = h.trials.iter().map(|t| t.index).collect();
                assert_eq!(got, want, "{n} trials, cap {max}");
                assert!(got.len() <= max);
                // Exactly the held trials' windows (± the margin) are kept, once each.
                let from: Vec<usize> = h.rec.state.dq.iter().map(|d| d[0] as usize).collect();
                let mut expect = Vec::new();
                for &i in &want {
                    let w = &trials[i];
                    for (k, &t) in s.t.iter().enumerate() {
                        if t > w.t_pre_start - MARGIN_S && t <= w.t_post_end + MARGIN_S {
                            expect.push(k / 100);
                        }
                    }
                }
                assert_eq!(from, expect, "{n} trials, cap {max}");
                assert!(h.rec.state.t.is_sorted());
            }
        }
    }
}
