//! The diagnosis' per-trial reductions over a [`TrialSource`] (a recording in memory, or session
//! files joined end to end and read trial by trial: [`open_streamed`]): each trial's quantities
//! and the sensor-window scan's held trials, from a recording that holds at least the trial's
//! span ([`span`]), so the stages after them are one code path.
//!
//! A streamed diagnosis reads each file twice: the segmentation pass
//! ([`crate::session::segment_file`], which spills the joint states) and discovery's fields
//! (`fields.rs`); the per-trial passes between them (the trial quantities with the power series
//! and the clock, the sensor-window scan's trials, the rows at the coarse and fine lags with the
//! torque rows) read the spill. Only the reductions stay in memory.

use anyhow::{Result, bail};

use crate::session::{
    Joined, JoinedPart, SessionFile, StreamOptions, TrialSource, for_each_trial_with_batches,
    segment_file,
};
use crate::signals::{PowerSeries, Recording, StateSeries, Target};
use crate::trial::{SegmentOptions, TrialWindow};

use super::FieldSource;
use super::reading_rows::{BusModel, TrialMeta, span, trial_meta};

/// Samples per decoded batch of the streamed passes.
const BATCH_SAMPLES: usize = 4096;

/// What the diagnosis knows about the session besides the trials' samples.
#[derive(Clone)]
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
    samples: &mut dyn TrialSource,
    windows: &[TrialWindow],
    bus: BusModel,
) -> Result<(Vec<TrialMeta>, super::reading_rows::Skipped)> {
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

/// Append `from`'s samples (every column) of `w`'s span ([`span`]), with two samples either
/// side, that are later than the last sample of `to`: the sensor-window scan's trials.
pub(crate) fn copy_span(to: &mut StateSeries, from: &StateSeries, w: &TrialWindow) {
    let (a, b) = span(w);
    let after = to.t.last().copied().unwrap_or(f64::NEG_INFINITY);
    let i0 = from.t.partition_point(|&x| x < a).saturating_sub(2);
    let i0 = i0.max(from.t.partition_point(|&x| x <= after));
    let i1 = (from.t.partition_point(|&x| x < b) + 2).min(from.t.len());
    if i0 < i1 {
        to.extend_range(from, i0..i1);
    }
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

/// Session files diagnosed without holding them, joined end to end on one clock as
/// [`super::join_recordings_with_sources`] joins recordings (each part starts `gap_s` after the
/// previous part's last joint sample): segment every file (one streamed pass each, spilling its
/// joint states) and read each trial's quantities, the power series and the clock (from the
/// spill), keeping no joint states beyond the current trial's.
pub(crate) fn open_streamed(
    files: &[SessionFile],
    target: Target,
    bus: BusModel,
    gap_s: f64,
) -> Result<(Joined, StreamedSession)> {
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
        let mut part = JoinedPart {
            file: file.clone(),
            local: seg.trials,
            first: out.windows.len(),
            offset_s: 0.0,
            clock: Recording::default(),
        };
        end = Some(read_part(&mut part, end, gap_s, bus, &mut out)?);
        if i == 0 {
            out.info.start_ns = part.clock.start_ns;
        }
        out.windows.extend(
            part.local
                .iter()
                .enumerate()
                .map(|(j, w)| part.global(w, j)),
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
    Ok((Joined { parts }, out))
}

/// Read one part of a streamed diagnosis (already segmented) from its spill: each trial's
/// quantities, the power series and the clock, with its shift onto the joined clock (`end`: the
/// previous part's last joint sample there). Returns this part's last joint sample on the
/// joined clock.
fn read_part(
    part: &mut JoinedPart,
    end: Option<f64>,
    gap_s: f64,
    bus: BusModel,
    out: &mut StreamedSession,
) -> Result<f64> {
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
    let target = out.info.target;
    for_each_trial_with_batches(
        &part.file,
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
            let g = crate::session::global(w, off, first + k);
            k += 1;
            let shifted = (off != 0.0).then(|| crate::session::shift(buf, off));
            let (m, s) = trial_meta(shifted.as_ref().unwrap_or(buf), &[g], bus);
            metas.extend(m);
            skipped.extend(s);
            Ok(())
        },
    )?;
    out.metas.extend(metas);
    out.skipped.extend(skipped);
    out.has_torque |= has_torque;
    let off = offset.get().unwrap_or(0.0);
    part.offset_s = off;
    part.clock.start_ns = start_ns;
    out.field_sources.push(FieldSource {
        path: part.file.path.clone(),
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
    Ok(last_t.unwrap_or(0.0) + off)
}
