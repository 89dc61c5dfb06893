//! Sim-to-real mismatch diagnosis: compare the twin (URDF dynamics + identified power model)
//! with a recording at the torque and power levels, locate where they disagree, name the
//! missing physics from a library of hypotheses scored by trial-wise cross-validation, model it
//! (refit with the accepted hypotheses), and report it in words, figures and JSON.
//!
//! Pipeline of [`diagnose_trials`]: trial windows → per-reading rows (φ, hypothesis features,
//! descriptors over each reading's own sensor window) → IMU and 3σ trial filters → rows at every
//! scanned sensor lag → greedy forward selection at the power level ([`select`]) and the payload
//! hypothesis at the torque level ([`torque`]) → final refit → breakdowns and correlates of
//! the held-out residuals ([`locate`]) → plain-language summary ([`summary`]).

pub(crate) mod counterpart;
pub(crate) mod data;
pub(crate) mod discover;
pub(crate) mod fields;
pub(crate) mod hypotheses;
pub(crate) mod locate;
mod options;
mod outcome;
mod replay;
pub(crate) mod report;
mod result;
pub(crate) mod select;
mod select_discover;
mod stages;
pub(crate) mod stats;
pub(crate) mod summary;
#[cfg(test)]
mod testkit;
#[cfg(test)]
mod tests;
pub(crate) mod torque;
mod window;

use anyhow::{Result, bail};

pub use crate::signals::Target;
pub use crate::trial::{Phase, TrialWindow};
pub use counterpart::{
    CounterpartComparison, CounterpartSeries, JointDifference, TrialDifference,
    compare as compare_counterpart,
};
pub use discover::{Discovery, DiscoveryReport};
pub use fields::{ExcludedField, FieldSource};
pub use locate::{Breakdown, Correlate, Group, TrialResidual};
pub use options::DiagnoseOptions;
pub use replay::{HighlightedTrial, LocatedField, ReplayData};
pub use report::{FIGURES as REPORT_FIGURES, write_report};
pub use result::{Diagnosis, FinalModel, LagPoint, Quality, SCHEMA_VERSION, SensorWindow};
pub use select::{Confounded, HypothesisScore, MechanismForms, Param};
pub use torque::{ArmModel, TorqueComparison};

use crate::N_PARAMS;
use crate::robot::{ArmDynamics, RobotModel};
use crate::signals::Recording;
use outcome::{locate_residuals, rank_hypotheses, refit_final, rescale_bus};
use replay::{replay_data, show_found};
use select::{PowerData, Rule};
use select_discover::select_and_discover;
use stages::{filter_trials, lag_scan, scan_lags};
use window::sensor_window;

/// [`crate::signals::join_recordings`], plus where each part's file lies on the joined time line (for
/// [`DiagnoseOptions::field_sources`]).
pub fn join_recordings_with_sources(
    parts: Vec<Recording>,
    gap_s: f64,
) -> (Recording, Vec<FieldSource>) {
    let mut sources = Vec::new();
    let mut end = None::<f64>;
    for r in &parts {
        let offset = match end {
            None => 0.0,
            Some(e) => e + gap_s - r.state.t.first().copied().unwrap_or(0.0),
        };
        sources.push(FieldSource {
            path: r.source.clone(),
            start_ns: r.start_ns,
            offset_s: offset,
        });
        end = Some(r.state.t.last().copied().unwrap_or(0.0) + offset);
    }
    (crate::signals::join_recordings(parts, gap_s), sources)
}

/// Diagnose a recording: segment its trials from the data (the identification's segmentation),
/// load the robot model for the torque level, and run [`diagnose_trials`].
pub fn diagnose(rec: &Recording, opts: &DiagnoseOptions) -> Result<Diagnosis> {
    let seg = crate::trial::segment(rec, &crate::trial::SegmentOptions::default());
    if seg.trials.is_empty() {
        let why: Vec<String> = seg
            .unmatched
            .iter()
            .take(5)
            .map(|s| format!("{:.1}–{:.1} s: {}", s.t0, s.t1, s.reason))
            .collect();
        bail!(
            "{}: no protocol trials found ({})",
            rec.source.display(),
            why.join("; ")
        );
    }
    let arm = if opts.torque_level && rec.state.tau.iter().any(|t| t.iter().any(|v| *v != 0.0)) {
        let model = RobotModel::load(opts.urdf.as_deref())?;
        let joints = model.arm(&rec.joint_names)?;
        Some(ArmDynamics::new(&model, &joints)?)
    } else {
        None
    };
    diagnose_trials(
        rec,
        &seg.trials,
        arm.as_ref().map(|a| a as &dyn ArmModel),
        opts,
    )
}

/// Diagnose a recording whose trials are already segmented. `arm` enables the torque level.
///
/// Stages: usable trials ([`filter_trials`]) → rows at every scanned lag ([`scan_lags`]) →
/// library selection and discovery ([`select_and_discover`]) → torque level → ranking
/// ([`rank_hypotheses`]) → final refit ([`refit_final`]) → locate ([`locate_residuals`]) →
/// lag scan, replay data and assembly.
pub fn diagnose_trials(
    rec: &Recording,
    windows: &[TrialWindow],
    arm: Option<&dyn ArmModel>,
    opts: &DiagnoseOptions,
) -> Result<Diagnosis> {
    let power = opts.target.series(rec);
    if power.t.is_empty() {
        bail!(
            "{}: no {:?} power readings to diagnose",
            rec.source.display(),
            opts.target
        );
    }
    let sensor = sensor_window(rec, windows, opts)?;
    let w = sensor.window_s;
    let resolved = DiagnoseOptions {
        sensor_window_s: Some(w),
        ..opts.clone()
    };
    let opts = &resolved;
    let reference: Option<Vec<f64>> = opts.reference.map(|m| m.to_vector().to_vec());
    let (metas, rejected) = filter_trials(rec, windows, opts, w, reference.clone())?;
    if metas.len() < 2 * opts.folds.max(2) {
        bail!(
            "{}: only {} usable trials (need at least {} for {}-fold cross-validation by trial)",
            rec.source.display(),
            metas.len(),
            2 * opts.folds.max(2),
            opts.folds
        );
    }
    let scan = scan_lags(rec, power, &metas, opts, reference.clone())?;
    if scan.rows[0].len() < 3 * (N_PARAMS + 10) / 2 {
        bail!(
            "{}: only {} power readings inside usable trials; too few to diagnose a {N_PARAMS}-parameter model",
            rec.source.display(),
            scan.rows[0].len()
        );
    }
    let data = PowerData::new(scan.lags, scan.rows, metas.len(), opts.folds, reference);
    let rule = Rule {
        alpha: opts.alpha,
        bic_threshold: opts.bic_threshold,
        min_improvement: opts.min_improvement,
    };
    let (sel, discovery, fields) = select_and_discover(rec, power, &metas, &data, &rule, opts)?;

    // Torque level.
    let torque = match arm {
        Some(a) => torque::torque_level(rec, &metas, a, &data.folds, opts.max_torque_samples)?,
        None => None,
    };
    let ranking = rank_hypotheses(&sel, torque.as_ref(), &rule);
    let final_model = refit_final(
        &sel,
        &ranking.accepted,
        torque.as_ref(),
        &data.rows[0],
        metas.len(),
    );
    let located = locate_residuals(rec, &metas, &data, &sel, discovery.as_ref());
    let lag_scan = lag_scan(&data)?;
    let replay = replay_data(&metas, &data.rows[0], &sel, &located);
    let mut diag = Diagnosis {
        schema_version: SCHEMA_VERSION,
        source: rec.source.display().to_string(),
        target: opts.target,
        joint_names: rec.joint_names.clone(),
        n_trials: metas.len(),
        n_readings: data.rows[0].len(),
        rejected,
        torque: torque.map(|t| t.comparison),
        base_model: if data.reference.is_some() {
            "reference".into()
        } else {
            "refit".into()
        },
        lag_scan,
        breakdowns: located.breakdowns,
        worst: located.worst,
        worst_trials: located.worst_trials,
        hypotheses: ranking.ranked,
        accepted: ranking.accepted,
        final_model,
        unexplained: located.unexplained,
        forms: sel.forms.clone(),
        confounded: sel.confounded.clone(),
        discovery,
        bus_volts: hypotheses::NOMINAL_BUS_VOLTS,
        sensor_window: sensor,
        summary: String::new(),
        replay,
        counterpart: None,
    };
    if let Some(v) = fields.table.bus_volts {
        rescale_bus(&mut diag, v);
    }
    show_found(&mut diag, &fields, &data.rows[sel.last.lag], &metas);
    diag.summary = summary::summarise(&diag);
    Ok(diag)
}
