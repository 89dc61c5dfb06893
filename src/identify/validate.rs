//! `g1viz validate`: a model applied to a hold-out session — per-trial metrics the paper's way and
//! like for like, per-reading metrics, the term breakdown, and the trials the identification's
//! filters would reject (with the model held fixed), so every consumer shows the same ones.

use anyhow::Result;

use super::dataset::Alignment;
use super::fit::predict;
use super::fit::{quality, term_means};
use super::pipeline::{IdentifyOptions, Prepared, SessionSummary, resolve_alignment};
use super::sets::RowPlan;
use super::table::{ReadingFit, TrialPrediction, trial_metrics, trial_predictions};
use crate::lsq::Metrics;
use crate::power::{PowerModel, TermMeans};
use crate::session::{SessionFile, StreamOptions};
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
    /// Their signed shares [%] of the energy turnover ([`crate::power::shares_percent`]).
    pub shares_percent: [f64; 5],
    /// Every reading of the usable trials with its like-for-like prediction (the rows
    /// `reading_level` scores), in session order.
    #[serde(skip)]
    pub readings: Vec<ReadingFit>,
    /// The copper-term baseline of every usable trial, in session order (what a per-sample
    /// prediction over the trial's samples needs).
    #[serde(skip)]
    pub baselines: Vec<super::TrialBasis>,
    /// Remarks on how the validation was done (e.g. nominal sensor timing for a short session).
    pub notes: Vec<String>,
}

/// Apply `model` to a hold-out session in memory. No filter removes trials (the paper's hold-out
/// set is unfiltered); the filters are evaluated and reported separately.
pub fn validate(model: &PowerModel, rec: &Recording, opts: &IdentifyOptions) -> Result<Validation> {
    validate_prepared(
        model,
        Prepared::from_recording(rec, &opts.segment, StreamOptions::default())?,
        opts,
    )
}

/// [`validate`] on a session file read in two streamed passes (memory bounded whatever the
/// session's length).
pub fn validate_file(
    model: &PowerModel,
    file: &SessionFile,
    opts: &IdentifyOptions,
    stream: &StreamOptions,
) -> Result<Validation> {
    validate_prepared(
        model,
        Prepared::from_file(file.clone(), &opts.segment, *stream)?,
        opts,
    )
}

fn validate_prepared(
    model: &PowerModel,
    prepared: Prepared,
    opts: &IdentifyOptions,
) -> Result<Validation> {
    if prepared.pass.seg.trials.is_empty() {
        return Err(prepared.no_usable_trials(&[]));
    }
    let prepared = [prepared];
    let mut notes = Vec::new();
    // A model is being applied, not fitted: a session too short to estimate the sensor timing
    // from still validates, at the sensor's nominal timing (said in the notes).
    let all = std::slice::from_ref(&prepared[0].pass.seg.trials);
    let alignment = match resolve_alignment(&prepared, all, opts) {
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
    let [mut p] = prepared;
    p.release_subset();
    let sets = p.rows(&RowPlan {
        target: opts.target,
        alignment,
        trials: &p.pass.seg.trials,
        sample_trials: &[],
        sample_stride: 1,
        full_sample_trials: &[],
    })?;
    let theta = model.to_vector();
    let (trial_set, reading_set) = (&sets.trial, &sets.reading);
    if trial_set.rows.is_empty() {
        return Err(p.no_usable_trials(&trial_set.skipped));
    }
    let seg = &p.pass.seg;
    let mut per_trial = trial_predictions(0, seg, reading_set, trial_set, &theta, |_| false);
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
    let terms = term_means(model, &trial_set.rows);
    let readings = reading_set
        .rows
        .iter()
        .map(|r| ReadingFit {
            trial: r.trial,
            t: r.t,
            measured_w: r.y,
            predicted_w: predict(&theta, &r.phi),
        })
        .collect();
    Ok(Validation {
        readings,
        baselines: trial_set.trials.clone(),
        notes,
        trial_level: trial_metrics(&all, |p| p.predicted_window_w),
        trial_level_aligned: trial_metrics(&all, |p| p.predicted_w),
        trial_level_aligned_imu_kept: opts
            .filters
            .imu_k
            .map(|_| trial_metrics(&imu_calm, |p| p.predicted_w)),
        rejections,
        reading_level: quality(&theta, &reading_set.rows),
        terms,
        shares_percent: terms.shares_percent(),
        alignment,
        session: p.summary(sets.trial.skipped.clone()),
        per_trial,
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
