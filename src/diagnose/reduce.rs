//! Where the diagnosis' stages get each trial's joint states: a whole [`Recording`] in memory
//! ([`InMemory`]), or session files streamed trial by trial ([`Streamed`], memory bounded
//! whatever the session's length). Both hand the same per-trial reductions (trial quantities,
//! rows at each lag, torque rows, the sensor-window scan's held trials) a recording that holds
//! at least the trial's span ([`span`]), so the stages after them are one code path.
//!
//! A streamed diagnosis reads each file several times: the segmentation pass
//! ([`crate::identify::segment_file`]), the per-trial quantities (with the power series and the
//! clock), the sensor-window scan's trials (only when the window is estimated), the rows at the
//! coarse lags, the rows at the fine lags with the torque rows, and discovery's fields
//! (`fields.rs`, one streamed pass per selected lag). Only the reductions stay in memory.

use anyhow::{Result, bail};

use crate::identify::{
    SessionFile, StreamOptions, for_each_trial_and_batch_no_commands, for_each_trial_state,
    segment_file,
};
use crate::signals::{PowerSeries, Recording, StateSeries, Target};
use crate::trial::{SegmentOptions, TrialWindow};

use super::FieldSource;
use super::data::{BusModel, TrialMeta, trial_meta};

/// Margin before a trial's pre-idle start whose samples belong to the trial [s]: a window
/// reaching further back is cut there. The streamed reader keeps at least 0.5 s before the
/// pre-idle of the trial it is reading; this stays inside it.
pub(crate) const SPAN_MARGIN_S: f64 = 0.4;

/// Samples per decoded batch of the streamed passes.
const BATCH_SAMPLES: usize = 4096;

/// Time span of `w` whose joint states the per-trial reductions look at: from
/// [`SPAN_MARGIN_S`] before the pre-idle to the end of the return home.
pub(crate) fn span(w: &TrialWindow) -> (f64, f64) {
    (w.t_pre_start - SPAN_MARGIN_S, w.t_return_end)
}

/// A source of each trial's joint states.
pub(crate) trait TrialSamples {
    /// Call `f` for each of `trials` (in time order) with a recording whose joint states cover at
    /// least the trial's [`span`] (plus a few samples either side), on the diagnosis' clock.
    fn for_each(
        &mut self,
        trials: &[TrialWindow],
        f: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
    ) -> Result<()>;
}

/// A whole recording in memory: every trial sees all of it.
pub(crate) struct InMemory<'a>(pub &'a Recording);

impl TrialSamples for InMemory<'_> {
    fn for_each(
        &mut self,
        trials: &[TrialWindow],
        f: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
    ) -> Result<()> {
        trials.iter().try_for_each(|t| f(self.0, t))
    }
}

/// What the diagnosis knows about the session besides the trials' samples.
pub(crate) struct SessionInfo {
    /// File (or first file) diagnosed.
    pub source: std::path::PathBuf,
    /// Time origin of the session [ns since the Unix epoch].
    pub start_ns: u64,
    /// URDF joint names of the arm joints.
    pub joint_names: Vec<String>,
    /// The target's power readings, whole (about one a second).
    pub power: PowerSeries,
    /// The other meter of the same rail (the battery's for the main board's, and the other way
    /// round), whole: what a finding is checked against ([`super::meters`]).
    pub other: PowerSeries,
    /// The target meter.
    pub target: Target,
}

/// The other meter's series of a recording or batch.
fn other_series(rec: &Recording, target: Target) -> &PowerSeries {
    match target {
        Target::Mbs => &rec.bms,
        Target::Bms => &rec.mbs,
    }
}

impl SessionInfo {
    /// The session facts of a recording in memory.
    pub(crate) fn of(rec: &Recording, target: Target) -> SessionInfo {
        SessionInfo {
            source: rec.source.clone(),
            start_ns: rec.start_ns,
            joint_names: rec.joint_names.clone(),
            power: target.series(rec).clone(),
            other: other_series(rec, target).clone(),
            target,
        }
    }
}

/// Per-trial quantities of every trial ([`trial_meta`] on each trial's samples); trials without
/// pre-idle samples are returned in the second list.
pub(crate) fn trial_metas(
    samples: &mut dyn TrialSamples,
    windows: &[TrialWindow],
    bus: BusModel,
) -> Result<(Vec<TrialMeta>, super::data::Skipped)> {
    let mut metas = Vec::new();
    let mut skipped = Vec::new();
    samples.for_each(windows, &mut |rec, w| {
        let (m, s) = trial_meta(rec, std::slice::from_ref(w), bus);
        metas.extend(m);
        skipped.extend(s);
        Ok(())
    })?;
    Ok((metas, skipped))
}

/// The joint states of `trials`' spans (with two samples either side), copied into one
/// recording (the sensor-window scan's trials).
pub(crate) fn hold(samples: &mut dyn TrialSamples, trials: &[TrialWindow]) -> Result<Recording> {
    let mut held = Recording::default();
    samples.for_each(trials, &mut |rec, w| {
        let (a, b) = span(w);
        let s = &rec.state;
        let n = s.t.len();
        let after = held.state.t.last().copied().unwrap_or(f64::NEG_INFINITY);
        let i0 = s.t.partition_point(|&x| x < a).saturating_sub(2);
        let i0 = i0.max(s.t.partition_point(|&x| x <= after));
        let i1 = (s.t.partition_point(|&x| x < b) + 2).min(n);
        if i0 < i1 {
            append_range(&mut held.state, s, i0..i1);
        }
        Ok(())
    })?;
    Ok(held)
}

/// Append samples `r` of every column of `from` that has them.
fn append_range(to: &mut StateSeries, from: &StateSeries, r: std::ops::Range<usize>) {
    fn ext<T: Copy>(to: &mut Vec<T>, from: &[T], r: &std::ops::Range<usize>) {
        if let Some(s) = from.get(r.clone()) {
            to.extend_from_slice(s);
        }
    }
    ext(&mut to.t, &from.t, &r);
    ext(&mut to.q, &from.q, &r);
    ext(&mut to.dq, &from.dq, &r);
    ext(&mut to.tau, &from.tau, &r);
    ext(&mut to.temp, &from.temp, &r);
    ext(&mut to.gyro, &from.gyro, &r);
    ext(&mut to.quat, &from.quat, &r);
}

/// One session file of a streamed diagnosis and where its trials lie on the joined clock.
struct Part {
    file: SessionFile,
    /// Its trials on its own clock.
    local: Vec<TrialWindow>,
    /// Index (on the joined list) of its first trial.
    first: usize,
    /// Shift of its times on the joined clock [s].
    offset_s: f64,
    /// Its own clock's origin (the first pass's earliest message) [ns].
    start_ns: u64,
}

/// Session files streamed trial by trial, joined end to end on one clock as
/// [`super::join_recordings_with_sources`] joins recordings (each part starts `gap_s` after the
/// previous part's last joint sample).
pub(crate) struct Streamed {
    parts: Vec<Part>,
}

/// What the first streamed pass over every file finds besides the per-trial quantities.
pub(crate) struct StreamedSession {
    pub info: SessionInfo,
    /// Every trial on the joined clock (indices count over all files).
    pub windows: Vec<TrialWindow>,
    /// Per-trial quantities of the trials with a pre-idle.
    pub metas: Vec<TrialMeta>,
    /// Trials without pre-idle samples, with the reason.
    pub skipped: Vec<(usize, String)>,
    /// Whether any joint torque is non-zero (the torque level needs recorded torques).
    pub has_torque: bool,
    /// Each file with its clock and its shift on the joined clock (discovery reads their fields).
    pub field_sources: Vec<FieldSource>,
}

impl Streamed {
    /// Segment every file (one streamed pass each) and read each trial's quantities, the power
    /// series and the clock (one more), keeping no joint states beyond the current trial's.
    pub(crate) fn open(
        files: &[SessionFile],
        target: Target,
        bus: BusModel,
        gap_s: f64,
    ) -> Result<(Streamed, StreamedSession)> {
        let Some(first_file) = files.first() else {
            bail!("no session to diagnose");
        };
        let mut parts = Vec::new();
        let mut out = StreamedSession {
            info: SessionInfo {
                source: first_file.path.clone(),
                start_ns: 0,
                joint_names: first_file.map.joint_names.clone(),
                power: PowerSeries::default(),
                other: PowerSeries::default(),
                target,
            },
            windows: Vec::new(),
            metas: Vec::new(),
            skipped: Vec::new(),
            has_torque: false,
            field_sources: Vec::new(),
        };
        let mut unmatched = Vec::new();
        let mut end = None::<f64>;
        for (i, file) in files.iter().enumerate() {
            let seg = segment_file(file, &SegmentOptions::default(), &StreamOptions::default())?;
            unmatched.extend(seg.unmatched.iter().take(5).map(|s| {
                format!(
                    "{}: {:.1}–{:.1} s: {}",
                    file.path.display(),
                    s.t0,
                    s.t1,
                    s.reason
                )
            }));
            let mut part = Part {
                file: file.clone(),
                local: seg.trials,
                first: out.windows.len(),
                offset_s: 0.0,
                start_ns: 0,
            };
            // The clock: a part starts `gap_s` after the previous part's last joint sample (set
            // at its first joint sample, before any trial is handed over).
            let offset = std::cell::Cell::new(None::<f64>);
            let mut last_t = None::<f64>;
            let mut start_ns = 0u64;
            let mut power = PowerSeries::default();
            let mut other = PowerSeries::default();
            let mut has_torque = false;
            let mut metas = Vec::new();
            let mut skipped = Vec::new();
            let mut k = 0usize;
            let first = part.first;
            for_each_trial_and_batch_no_commands(
                file,
                &part.local,
                BATCH_SAMPLES,
                &mut |batch| {
                    start_ns = batch.start_ns;
                    if offset.get().is_none()
                        && let Some(&t0) = batch.state.t.first()
                    {
                        offset.set(Some(match end {
                            None => 0.0,
                            Some(e) => e + gap_s - t0,
                        }));
                    }
                    if let Some(&t) = batch.state.t.last() {
                        last_t = Some(t);
                    }
                    let p = target.series(batch);
                    power.t.extend_from_slice(&p.t);
                    power.watts.extend_from_slice(&p.watts);
                    let o = other_series(batch, target);
                    other.t.extend_from_slice(&o.t);
                    other.watts.extend_from_slice(&o.watts);
                    has_torque |= batch.state.tau.iter().any(|t| t.iter().any(|v| *v != 0.0));
                },
                &mut |buf, w| {
                    let off = offset.get().unwrap_or(0.0);
                    let g = global(w, off, first + k);
                    k += 1;
                    let shifted = (off != 0.0).then(|| shift(buf, off));
                    let (m, s) = trial_meta(shifted.as_ref().unwrap_or(buf), &[g], bus);
                    metas.extend(m);
                    skipped.extend(s);
                },
            )?;
            out.metas.extend(metas);
            out.skipped.extend(skipped);
            out.has_torque |= has_torque;
            let off = offset.get().unwrap_or(0.0);
            part.offset_s = off;
            part.start_ns = start_ns;
            end = Some(last_t.unwrap_or(0.0) + off);
            if i == 0 {
                out.info.start_ns = start_ns;
            }
            out.field_sources.push(FieldSource {
                path: file.path.clone(),
                start_ns,
                offset_s: off,
            });
            for (p, to) in [
                (&mut power, &mut out.info.power),
                (&mut other, &mut out.info.other),
            ] {
                p.sort_by_time();
                to.t.extend(p.t.iter().map(|t| t + off));
                to.watts.extend_from_slice(&p.watts);
            }
            out.windows.extend(
                part.local
                    .iter()
                    .enumerate()
                    .map(|(j, w)| global(w, off, part.first + j)),
            );
            parts.push(part);
        }
        if out.windows.is_empty() {
            bail!(
                "{}: no protocol trials found ({})",
                first_file.path.display(),
                unmatched.join("; ")
            );
        }
        Ok((Streamed { parts }, out))
    }
}

impl TrialSamples for Streamed {
    fn for_each(
        &mut self,
        trials: &[TrialWindow],
        f: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
    ) -> Result<()> {
        for part in &self.parts {
            let range = part.first..part.first + part.local.len();
            let mine: Vec<&TrialWindow> =
                trials.iter().filter(|t| range.contains(&t.index)).collect();
            if mine.is_empty() {
                continue;
            }
            let local: Vec<TrialWindow> = mine
                .iter()
                .map(|t| part.local[t.index - part.first].clone())
                .collect();
            let mut k = 0usize;
            let mut err = None;
            // Joint states only, and only inside the trials' windows.
            for_each_trial_state(
                &part.file,
                part.start_ns,
                &local,
                BATCH_SAMPLES,
                &mut |buf, _| {
                    let g = mine[k];
                    k += 1;
                    if err.is_some() {
                        return;
                    }
                    let r = if part.offset_s != 0.0 {
                        f(&shift(buf, part.offset_s), g)
                    } else {
                        f(buf, g)
                    };
                    if let Err(e) = r {
                        err = Some(e);
                    }
                },
            )?;
            if let Some(e) = err {
                return Err(e);
            }
        }
        Ok(())
    }
}

/// A trial window of a part moved onto the joined clock, with its joined index.
fn global(w: &TrialWindow, off: f64, index: usize) -> TrialWindow {
    TrialWindow {
        index,
        t_pre_start: w.t_pre_start + off,
        t_traj_start: w.t_traj_start + off,
        t_traj_end: w.t_traj_end + off,
        t_post_end: w.t_post_end + off,
        t_return_end: w.t_return_end + off,
        ..w.clone()
    }
}

/// The joint states of `rec` with their times shifted by `off` (a part of joined files).
fn shift(rec: &Recording, off: f64) -> Recording {
    let mut out = Recording {
        state: rec.state.clone(),
        ..Recording::default()
    };
    out.state.t.iter_mut().for_each(|t| *t += off);
    out
}
