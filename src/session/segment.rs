//! The segmentation pass: a session file read once, in pieces of about
//! [`StreamOptions::chunk_s`] seconds (memory does not grow with the session's length). Each piece
//! is segmented, the trials it completes are kept (σ_ω of each taken on the spot) and the buffer is
//! cut at the last one's return, so the next piece starts with that return and the home idle
//! before the next trial. With a command stream every trial boundary depends only on the samples
//! around it, so the trials equal those of segmenting the whole session at once (tested); the
//! measured-state segmenter's noise threshold is estimated per piece. The power series are kept
//! whole (~1 Hz), and the joint states are spilled to a temporary file for the passes after it.
//! The joint states of the sensor-timing search's trials are held: every n-th trial, n a power
//! of two that doubles whenever more than [`StreamOptions::hold_trials`] would be held, which is
//! the search's own choice of trials without knowing the session's length ([`search_stride`]).
//! Only with `hold_trials` below the search's cap are the search's trials read in an extra
//! streamed pass ([`super::hold_pass`] with [`copy_window`]).

use std::path::{Path, PathBuf};

use anyhow::Result;

#[cfg(doc)]
use super::search_stride;
use super::{MARGIN_S, SessionFile, StreamOptions};
use crate::N_JOINTS;
use crate::signals::{Recording, SpillWriter, StateSeries, StreamSummary, stream_recording};
use crate::trial::{self, SegmentOptions, Segmentation, TrialWindow};

/// What the segmentation pass found.
pub(crate) struct Pass1 {
    /// The session's file (its first, or the recording's source).
    pub source: PathBuf,
    pub seg: Segmentation,
    /// σ_ω over each trial's analysis window, in `seg.trials` order.
    pub sigmas: Vec<f64>,
    /// Joint states (t, τ, q̇) of `held_trials`' windows plus the whole power series.
    pub held: Recording,
    /// The trials held (every n-th, [`Holder`]).
    pub held_trials: Vec<TrialWindow>,
    /// Winding temperatures of the first joint-state sample.
    pub first_temp_c: Option<[f64; N_JOINTS]>,
    /// The session has joint-state samples.
    pub has_state: bool,
    /// Problems met while reading a file.
    pub warnings: Vec<String>,
}

/// The joint states of every `stride`-th trial (by index) for the sensor-timing search, at most
/// `max` trials: when one more would exceed it, the stride doubles and the trials off the new
/// stride are dropped. The set is then the one [`super::search_stride`] picks for a
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
pub(crate) fn copy_window(to: &mut StateSeries, from: &StateSeries, trial: &TrialWindow) {
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
        self.buf.state.extend_range(&batch.state, 0..usize::MAX);
        self.buf.state.sort_by_time();
        let c = &mut self.buf.command;
        c.t.extend_from_slice(&batch.command.t);
        c.q.extend_from_slice(&batch.command.q);
        c.dq.extend_from_slice(&batch.command.dq);
        c.sort_by_time();
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
            self.buf.state.drain_front(i);
            let c = &mut self.buf.command;
            let i = c.t.partition_point(|&x| x < cut);
            c.t.drain(..i);
            c.q.drain(..i.min(c.q.len()));
            c.dq.drain(..i.min(c.dq.len()));
        }
    }
}

/// Pass 1 over a session file: segment it piece by piece, σ_ω per trial, the held samples and
/// the power series, spilling its joint states ([`StreamOptions::spill_states`]).
pub(crate) fn segmentation_pass(
    file: &SessionFile,
    opts: &SegmentOptions,
    so: &StreamOptions,
) -> Result<Pass1> {
    let mut spill = if so.spill_states && file.spill.get().is_none() {
        // Without a temporary file the later passes read the recording again.
        SpillWriter::new().ok()
    } else {
        None
    };
    let p1 = pass(
        opts,
        so,
        &file.path,
        &file.map.joint_names,
        &mut |on_batch| {
            stream_recording(
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
                    on_batch(batch)
                },
            )
        },
    )?;
    if let Some(mut s) = spill.and_then(|w| w.finish(p1.held.start_ns).ok()) {
        s.power = Some([p1.held.mbs.clone(), p1.held.bms.clone()]);
        file.spill.fill(s);
    }
    Ok(p1)
}

/// Pass 1 over a recording in memory: the same pass, fed the recording as one batch (as
/// [`crate::signals::load_recording`] reads a file).
pub(crate) fn segment_recording(
    rec: &Recording,
    opts: &SegmentOptions,
    so: &StreamOptions,
) -> Result<Pass1> {
    pass(opts, so, &rec.source, &rec.joint_names, &mut |on_batch| {
        on_batch(rec)?;
        Ok(StreamSummary {
            start_ns: rec.start_ns,
            ..StreamSummary::default()
        })
    })
}

/// A read of a session: hands each batch to the callback, returns the read's summary.
type ReadBatches<'a> =
    dyn FnMut(&mut dyn FnMut(&Recording) -> Result<()>) -> Result<StreamSummary> + 'a;

/// The segmentation pass over the batches `read` hands its callback (returning the read's
/// summary): the session of `source` with the arm's `joint_names`.
fn pass(
    opts: &SegmentOptions,
    so: &StreamOptions,
    source: &Path,
    joint_names: &[String],
    read: &mut ReadBatches,
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
    let mut held = Recording {
        source: source.to_path_buf(),
        joint_names: joint_names.to_vec(),
        ..Recording::default()
    };
    let (mut first_temp_c, mut has_state) = (None, false);
    let summary = read(&mut |batch| {
        if first_temp_c.is_none() {
            first_temp_c = batch.state.temp.first().copied();
        }
        has_state |= !batch.state.t.is_empty();
        for (to, from) in [(&mut held.mbs, &batch.mbs), (&mut held.bms, &batch.bms)] {
            to.t.extend_from_slice(&from.t);
            to.watts.extend_from_slice(&from.watts);
        }
        ch.push(batch);
        if ch.span() >= ch.chunk_s {
            ch.process(false);
        }
        Ok(())
    })?;
    ch.process(true);
    held.mbs.sort_by_time();
    held.bms.sort_by_time();
    held.start_ns = summary.start_ns;
    held.state = ch.hold.rec.state;
    Ok(Pass1 {
        source: source.to_path_buf(),
        seg: ch.seg,
        sigmas: ch.sigmas,
        held,
        held_trials: ch.hold.trials,
        first_temp_c,
        has_state,
        warnings: summary.warnings,
    })
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::session::search_stride;

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
