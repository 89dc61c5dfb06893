//! Walks over a session file after its segmentation pass, holding about one trial's samples:
//! the trials' windows only ([`trial_windows`], behind [`super::FileTrials`]), the held trials of
//! the sensor-timing search ([`hold_pass`]), and the whole session with its batches
//! ([`for_each_trial_with_batches`], [`TrialWalk`]). Each reads the spill when the segmentation
//! pass made one, else the file.

use std::path::PathBuf;

use anyhow::Result;

use super::{MARGIN_S, SessionFile, TrialSource};
use crate::signals::{Recording, StateSeries, stream_recording};
use crate::trial::TrialWindow;

/// End of the part of `t` a trial walk reads (before the margin).
fn trial_end(t: &TrialWindow) -> f64 {
    t.t_post_end.max(t.t_return_end)
}

/// Trials handed over as a session's samples go by: [`Self::push`] each batch (in time order, on
/// one clock), and each of the planned trials (in time order) reaches `on_trial` with a recording
/// holding at least its joint states (all columns, pre-idle start − [`MARGIN_S`] to its end) and
/// the power readings pushed so far; [`Self::finish`] hands over the rest. Earlier samples are
/// dropped, so memory stays about one trial's. A streamed replay logs its model's series through
/// one as it reads.
pub struct TrialWalk {
    buf: Recording,
    trials: Vec<TrialWindow>,
    next: usize,
    /// Samples (or readings) up to this long after a trial's end still belong to it [s].
    after_s: f64,
}

impl TrialWalk {
    /// A walk over `trials` (in time order) that hands a trial over once a sample 2 s past its
    /// end has come (a reading stamped that late can still belong to it: sensor lag).
    pub fn new(source: PathBuf, joint_names: &[String], trials: Vec<TrialWindow>) -> Self {
        let buf = Recording {
            source,
            joint_names: joint_names.to_vec(),
            ..Recording::default()
        };
        TrialWalk {
            buf,
            trials,
            next: 0,
            after_s: 2.0,
        }
    }

    /// Takes in the next batch's joint states and power readings; hands over every trial it
    /// completes.
    pub fn push(
        &mut self,
        batch: &Recording,
        on_trial: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
    ) -> Result<()> {
        self.buf.start_ns = batch.start_ns;
        for (to, from) in [
            (&mut self.buf.mbs, &batch.mbs),
            (&mut self.buf.bms, &batch.bms),
        ] {
            to.t.extend_from_slice(&from.t);
            to.watts.extend_from_slice(&from.watts);
            to.sort_by_time();
        }
        self.push_state(&batch.state, on_trial)
    }

    /// Takes in joint states only.
    fn push_state(
        &mut self,
        state: &StateSeries,
        on_trial: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
    ) -> Result<()> {
        self.buf.state.extend_range(state, 0..usize::MAX);
        self.buf.state.sort_by_time();
        self.step(false, on_trial)
    }

    /// Hands over the trials left, once the session has ended.
    pub fn finish(
        mut self,
        on_trial: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
    ) -> Result<()> {
        self.step(true, on_trial)
    }

    /// Hand `on_trial` every trial whose window the buffer now holds whole (all that are left
    /// when `done`), then drop the samples no later trial needs.
    fn step(
        &mut self,
        done: bool,
        on_trial: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
    ) -> Result<()> {
        let buf = &mut self.buf;
        let last_t = buf.state.t.last().copied().unwrap_or(f64::NEG_INFINITY);
        while let Some(t) = self.trials.get(self.next) {
            if !done && last_t <= trial_end(t) + self.after_s {
                break;
            }
            on_trial(buf, t)?;
            self.next += 1;
        }
        let keep_from = self
            .trials
            .get(self.next)
            .map_or(f64::INFINITY, |t| t.t_pre_start - MARGIN_S);
        let i = buf.state.t.partition_point(|&x| x < keep_from);
        buf.state.drain_front(i);
        Ok(())
    }
}

/// Stream `file`'s joint states (all columns) inside `trials`' windows (± the margin, merged where
/// they touch) and hand each of `trials` (in time order) to `on_trial` once its whole window has
/// been read, with `clock`'s origin and power series. Samples no later trial needs are dropped.
pub(super) fn trial_windows(
    file: &SessionFile,
    clock: &Recording,
    trials: &[TrialWindow],
    on_trial: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
) -> Result<()> {
    let mut windows: Vec<(f64, f64)> = trials
        .iter()
        .map(|t| (t.t_pre_start - MARGIN_S, trial_end(t) + MARGIN_S))
        .collect();
    windows.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut ranges: Vec<(f64, f64)> = Vec::with_capacity(windows.len());
    for (a, b) in windows {
        match ranges.last_mut() {
            Some(last) if a <= last.1 => last.1 = last.1.max(b),
            _ => ranges.push((a, b)),
        }
    }
    // On `clock`'s origin, with its power series; a sample within the margin still belongs.
    let mut walk = TrialWalk::new(file.path.clone(), &file.map.joint_names, trials.to_vec());
    let b = &mut walk.buf;
    (b.start_ns, b.mbs, b.bms) = (clock.start_ns, clock.mbs.clone(), clock.bms.clone());
    walk.after_s = MARGIN_S;
    let mut on_state = |state: &StateSeries| walk.push_state(state, on_trial);
    match file.spill.get().filter(|s| s.origin_ns == clock.start_ns) {
        Some(spill) => spill.stream(Some(&ranges), &mut on_state)?,
        None => {
            crate::signals::stream_state(
                &file.path,
                &file.map,
                &file.read,
                clock.start_ns,
                super::StreamOptions::default().batch_samples,
                Some(&ranges),
                &mut |batch| on_state(&batch.state),
            )?;
        }
    }
    walk.finish(on_trial)
}

/// `held` with the joint states of `trials`' windows (in time order) appended by `copy`, read in
/// one walk over `source`: the sensor-timing search's trials ([`super::copy_window`]) when the
/// segmentation pass could not hold every trial, and the diagnosis' sensor-window scan's.
pub(crate) fn hold_pass(
    source: &mut dyn TrialSource,
    mut held: Recording,
    trials: &[TrialWindow],
    copy: fn(&mut StateSeries, &StateSeries, &TrialWindow),
) -> Result<Recording> {
    source.for_each(trials, &mut |buf, t| {
        copy(&mut held.state, &buf.state, t);
        Ok(())
    })?;
    Ok(held)
}

/// Walk the whole session once more — from the spill when the segmentation pass made one with
/// the power readings, else by reading every arm topic of the file (`batch_samples` per batch) —
/// showing `on_batch` every batch as it arrives (every joint-state sample and power reading of
/// the session, on the segmentation pass's clock; no commands) and handing `on_trial` each of
/// `trials` (in time order) as a [`TrialWalk`] does.
pub fn for_each_trial_with_batches(
    file: &SessionFile,
    trials: &[TrialWindow],
    batch_samples: usize,
    on_batch: &mut dyn FnMut(&Recording),
    on_trial: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
) -> Result<()> {
    let mut walk = TrialWalk::new(file.path.clone(), &file.map.joint_names, trials.to_vec());
    let mut on_recording = |batch: &Recording| {
        on_batch(batch);
        walk.push(batch, on_trial)
    };
    match file.spill.get().and_then(|s| Some((s, s.power.clone()?))) {
        // The spill's blocks of joint states, the power readings (whole) with the first.
        Some((spill, [mbs, bms])) => {
            let (mut power, mut blocks) = (Some((mbs, bms)), 0);
            let mut rec = Recording {
                start_ns: spill.origin_ns,
                joint_names: file.map.joint_names.clone(),
                ..Recording::default()
            };
            let mut send = |state: StateSeries| {
                rec.state = state;
                (rec.mbs, rec.bms) = power.take().unwrap_or_default();
                on_recording(&rec)
            };
            spill.stream(None, &mut |s| {
                blocks += 1;
                send(s.clone())
            })?;
            if blocks == 0 {
                send(StateSeries::default())?;
            }
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
    walk.finish(on_trial)
}
