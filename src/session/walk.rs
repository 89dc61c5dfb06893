//! Walks over a session file after its segmentation pass, holding about one trial's samples:
//! the trials' windows only ([`trial_windows`], behind [`super::FileTrials`]), the held trials of
//! the sensor-timing search ([`hold_pass`]), and the whole session with its batches
//! ([`for_each_trial_with_batches`]). Each reads the spill when the segmentation pass made one,
//! else the file.

use anyhow::Result;

use super::{MARGIN_S, SessionFile, TrialSource};
use crate::signals::{Recording, StateSeries, stream_recording};
use crate::trial::TrialWindow;

/// End of the part of `t` a trial walk reads (before the margin).
fn trial_end(t: &TrialWindow) -> f64 {
    t.t_post_end.max(t.t_return_end)
}

/// The trials of a walk not yet handed over, and how long after a trial's end the walk waits.
struct Handover<'a> {
    trials: &'a [TrialWindow],
    next: usize,
    /// Samples (or readings) up to this long after a trial's end still belong to it [s].
    after_s: f64,
}

impl Handover<'_> {
    /// Hand `on_trial` every trial whose window `buf` now holds whole (all that are left when
    /// `done`), then drop the samples no later trial needs.
    fn step(
        &mut self,
        buf: &mut Recording,
        done: bool,
        on_trial: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
    ) -> Result<()> {
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
    let mut buf = Recording {
        source: file.path.clone(),
        joint_names: file.map.joint_names.clone(),
        ..super::clock_of(clock)
    };
    let mut walk = Handover {
        trials,
        next: 0,
        after_s: MARGIN_S,
    };
    let mut on_state = |state: &StateSeries| {
        buf.state.extend_range(state, 0..usize::MAX);
        buf.state.sort_by_time();
        walk.step(&mut buf, false, on_trial)
    };
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
    walk.step(&mut buf, true, on_trial)
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
/// the session, on the segmentation pass's clock; no commands) and `on_trial` each of `trials`
/// (in time order) with a recording holding at least its joint states (all columns, pre-idle
/// start to return end) and every power reading up to a few seconds past it. Earlier samples
/// are dropped, so memory stays bounded.
pub fn for_each_trial_with_batches(
    file: &SessionFile,
    trials: &[TrialWindow],
    batch_samples: usize,
    on_batch: &mut dyn FnMut(&Recording),
    on_trial: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
) -> Result<()> {
    let mut buf = Recording {
        source: file.path.clone(),
        joint_names: file.map.joint_names.clone(),
        ..Recording::default()
    };
    let mut walk = Handover {
        trials,
        next: 0,
        // A reading stamped up to this long after the window can still belong to it (sensor lag).
        after_s: 2.0,
    };
    let mut on_recording = |batch: &Recording| {
        on_batch(batch);
        buf.start_ns = batch.start_ns;
        buf.state.extend_range(&batch.state, 0..usize::MAX);
        buf.state.sort_by_time();
        for (to, from) in [(&mut buf.mbs, &batch.mbs), (&mut buf.bms, &batch.bms)] {
            to.t.extend_from_slice(&from.t);
            to.watts.extend_from_slice(&from.watts);
            to.sort_by_time();
        }
        walk.step(&mut buf, false, on_trial)
    };
    match file.spill.get() {
        Some(spill) if spill.power.is_some() => {
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
    walk.step(&mut buf, true, on_trial)
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
