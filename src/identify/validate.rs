//! `g1viz validate`: a model applied to a hold-out session — per-trial metrics the paper's way and
//! like for like, per-reading metrics, the term breakdown, and the trials the identification's
//! filters would reject (with the model held fixed), so every consumer shows the same ones.

use anyhow::Result;

use super::dataset::{self, Alignment, DatasetOptions, Mode};
use super::fit::{quality, term_means};
use super::pipeline::{
    IdentifyOptions, Segmented, SessionSummary, no_usable_trials, resolve_alignment,
};
use super::table::{TrialPrediction, trial_metrics, trial_predictions};
use crate::lsq::Metrics;
use crate::power::{PowerModel, TermMeans};
use crate::signals::Recording;
use crate::trial::{self, RejectReason, Rejection, TrialStat};

/// Result of [`validate`].
#[derive(Debug, Clone, serde::Serialize)]
pub struct Validation {
    /// The session.
    pub session: SessionSummary,
    /// Sensor timing used.
    pub alignment: Alignment,
    /// Per-trial metrics over all usable trials, the paper's way (φ averaged over the trajectory
    /// window vs the mean of its readings) — the paper's hold-out table.
    pub trial_level: Metrics,
    /// Per-trial metrics, like for like (prediction averaged over the readings' own windows).
    pub trial_level_aligned: Metrics,
    /// `trial_level_aligned` over the trials the IMU criterion keeps (None when the filter is off).
    pub trial_level_aligned_imu_kept: Option<Metrics>,
    /// Per-reading metrics over all usable trials.
    pub reading_level: Metrics,
    /// Per-trial measured vs predicted (`rejected` set for the trials in `rejections`).
    pub per_trial: Vec<TrialPrediction>,
    /// The trials the identification's filters reject on this session with the model held
    /// fixed: the IMU criterion, then the n·σ passes on the like-for-like per-trial residuals.
    /// Reported, not removed: the metrics above cover every usable trial (the paper's hold-out
    /// set is unfiltered).
    pub rejections: Vec<Rejection>,
    /// Mean term contributions on the session's trajectory windows.
    #[serde(skip)]
    pub terms: TermMeans,
    /// The same as % of the mean total predicted power.
    pub shares_percent: [f64; 5],
    /// Remarks on how the validation was done (e.g. nominal sensor timing for a short session).
    pub notes: Vec<String>,
}

/// Apply `model` to a hold-out session. No filter removes trials (the paper's hold-out set is
/// unfiltered); the filters are evaluated and reported separately.
pub fn validate(model: &PowerModel, rec: &Recording, opts: &IdentifyOptions) -> Result<Validation> {
    let seg = trial::segment(rec, &opts.segment);
    if seg.trials.is_empty() {
        return Err(no_usable_trials(rec, &seg, &[]));
    }
    let prepared = [Segmented { rec, seg }];
    let mut notes = Vec::new();
    // A model is being applied, not fitted: a session too short to estimate the sensor timing
    // from still validates, at the sensor's nominal timing (said in the notes).
    let alignment = match resolve_alignment(
        &prepared,
        std::slice::from_ref(&prepared[0].seg.trials),
        opts,
    ) {
        Ok((a, _)) => a,
        Err(e) => {
            notes.push(format!(
                "sensor timing not estimated ({e:#}); using the nominal window {} s, lag {} s",
                Alignment::NOMINAL.window_s,
                Alignment::NOMINAL.lag_s
            ));
            Alignment::NOMINAL
        }
    };
    let [Segmented { seg, .. }] = prepared;
    let theta = model.to_vector();
    let trial_set = dataset::build(
        rec,
        &seg.trials,
        &DatasetOptions {
            mode: Mode::Trial,
            target: opts.target,
            alignment,
        },
    );
    if trial_set.rows.is_empty() {
        return Err(no_usable_trials(rec, &seg, &trial_set.skipped));
    }
    let reading_set = dataset::build(
        rec,
        &seg.trials,
        &DatasetOptions {
            mode: Mode::Reading,
            target: opts.target,
            alignment,
        },
    );
    let mut per_trial = trial_predictions(0, &seg, &reading_set, &trial_set, &theta, |_| false);
    let sigmas: Vec<TrialStat> = trial_set
        .trials
        .iter()
        .map(|b| TrialStat::new(0, b.trial, b.sigma_omega))
        .collect();
    let rejections = fixed_model_rejections(&sigmas, &per_trial, opts);
    for p in &mut per_trial {
        p.rejected = trial::is_rejected(&rejections, 0, p.trial);
    }
    let all: Vec<&TrialPrediction> = per_trial.iter().collect();
    let imu_calm: Vec<&TrialPrediction> = per_trial
        .iter()
        .filter(|p| {
            !rejections
                .iter()
                .any(|r| r.trial == p.trial && r.reason == RejectReason::ImuSway)
        })
        .collect();
    Ok(Validation {
        notes,
        trial_level: trial_metrics(&all, |p| p.predicted_window_w),
        trial_level_aligned: trial_metrics(&all, |p| p.predicted_w),
        trial_level_aligned_imu_kept: opts
            .filters
            .imu_k
            .map(|_| trial_metrics(&imu_calm, |p| p.predicted_w)),
        rejections,
        reading_level: quality(&theta, &reading_set.rows),
        terms: term_means(model, &trial_set.rows),
        shares_percent: term_means(model, &trial_set.rows).shares_percent(),
        per_trial,
        alignment,
        session: SessionSummary {
            source: rec.source.clone(),
            segmentation: seg,
            skipped: trial_set.skipped,
        },
    })
}

/// The filter cascade with the model held fixed: the IMU filter on `sigmas`, then n·σ passes on
/// the like-for-like per-trial residuals of the trials not yet rejected.
fn fixed_model_rejections(
    sigmas: &[TrialStat],
    per_trial: &[TrialPrediction],
    opts: &IdentifyOptions,
) -> Vec<Rejection> {
    let residuals = |rejected: &[Rejection]| {
        Ok::<_, std::convert::Infallible>(
            per_trial
                .iter()
                .filter(|p| !trial::is_rejected(rejected, 0, p.trial))
                .map(|p| TrialStat::new(0, p.trial, p.measured_w - p.predicted_w))
                .collect(),
        )
    };
    match opts.filters.run(sigmas, residuals) {
        Ok(r) => r,
        Err(never) => match never {},
    }
}
