//! `g1viz identify`: the paper's identification as a short sequence of named stages —
//! segment → IMU filter → sensor timing → rows → constrained fit with n·σ rejection → the three
//! row pairings compared → per-trial table — on one or more recordings.
//!
//! The rows are per trial (the paper), per power reading (default; many more rows, each aligned
//! with the sensor's own averaging window) or per sample (degenerate, for comparison). The trial
//! and sample pairings are also fitted on the same retained trials, with κ(ΦᵀΦ) and R² of each,
//! reproducing the paper's case for aggregation.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};

use super::dataset::{
    self, Alignment, AlignmentEstimate, Dataset, DatasetOptions, Mode, Row, Skipped,
};
use super::fit::{fit_rows, kappa, quality, term_means, trial_residuals};
use super::table::{TrialPrediction, trial_metrics, trial_predictions};
use crate::lsq::{Metrics, SolverInfo};
use crate::power::{LossTerm, PowerModel, TermMeans};
use crate::signals::{Recording, Target};
use crate::trial::{
    self, Cascade, RejectReason, Rejection, SegmentOptions, Segmentation, TrialStat, TrialWindow,
};
use crate::{N_JOINTS, N_PARAMS};

/// Sensor timing for the per-reading rows.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum AlignmentChoice {
    /// Estimate W and lag from the data ([`dataset::estimate_alignment`]).
    Auto,
    /// Use the given timing.
    Given(Alignment),
}

/// Options of [`identify`] and [`super::validate`].
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct IdentifyOptions {
    /// Power sensor (`--target mbs|bms`).
    pub target: Target,
    /// Row pairing (`--mode trial|reading|sample`).
    pub mode: Mode,
    /// Segmenter tuning.
    pub segment: SegmentOptions,
    /// The IMU filter and the residual-rejection passes.
    pub filters: Cascade,
    /// Power-sensor window and lag.
    pub alignment: AlignmentChoice,
}

impl Default for IdentifyOptions {
    fn default() -> Self {
        IdentifyOptions {
            target: Target::Mbs,
            mode: Mode::Reading,
            segment: SegmentOptions::default(),
            filters: Cascade::default(),
            alignment: AlignmentChoice::Auto,
        }
    }
}

/// One row pairing fitted on the retained trials: the paper's aggregation argument in numbers.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ModeFit {
    /// Pairing.
    pub mode: Mode,
    /// Condition number κ(ΦᵀΦ) of the raw (unscaled) regressors; ∞ when rank-deficient.
    pub kappa: f64,
    /// Fit quality of that pairing's own constrained fit, on its own rows.
    pub quality: Metrics,
}

/// What happened to one input session.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct SessionSummary {
    /// File.
    pub source: PathBuf,
    /// Trials and unmatched stretches.
    pub segmentation: Segmentation,
    /// Trials without rows and why.
    pub skipped: Vec<Skipped>,
}

/// Result of [`identify`].
#[derive(Debug, Clone, serde::Serialize)]
pub struct Identification {
    /// The identified parameters.
    pub model: PowerModel,
    /// Options used.
    pub options: IdentifyOptions,
    /// Per input session: segmentation and skipped trials.
    pub sessions: Vec<SessionSummary>,
    /// Sensor timing used for rows and baselines.
    pub alignment: Alignment,
    /// The timing search (when `AlignmentChoice::Auto`).
    pub alignment_estimate: Option<AlignmentEstimate>,
    /// Every rejected trial, filter by filter.
    pub rejections: Vec<Rejection>,
    /// Trials retained for the final fit.
    pub trials_used: usize,
    /// Fit quality of the final fit on its rows (mode of the options).
    pub fit: Metrics,
    /// The final model at trial level on the retained trials, the paper's way: φ averaged over
    /// the whole trajectory window vs the mean of the readings in it.
    pub trial_level: Metrics,
    /// The final model at trial level on the retained trials, like for like: prediction averaged
    /// over the readings' own windows vs the mean of the readings.
    pub trial_level_aligned: Metrics,
    /// Trial, reading and sample pairings fitted on the retained trials (κ, R²).
    pub modes: Vec<ModeFit>,
    /// Dominant loss term per joint (argmax of b, c, d; None when all are zero).
    pub dominant: Vec<Option<LossTerm>>,
    /// Mean term contributions on the retained trials' trajectory windows.
    #[serde(skip)]
    pub terms: TermMeans,
    /// The same as % of the mean total predicted power (mechanical, copper, Coulomb, viscous, interaction).
    pub shares_percent: [f64; 5],
    /// Standard error of each parameter of the final fit (None: at a bound or not excited).
    pub std_err: Vec<Option<f64>>,
    /// Solver of the final fit.
    pub solver: SolverInfo,
    /// Per-trial measured vs predicted (all trials with rows, rejected ones flagged).
    pub per_trial: Vec<TrialPrediction>,
}

/// A recording and its segmentation.
pub(crate) struct Segmented<'a> {
    pub rec: &'a Recording,
    pub seg: Segmentation,
}

/// Explain why a session gave no rows.
pub(crate) fn no_usable_trials(
    rec: &Recording,
    seg: &Segmentation,
    skipped: &[Skipped],
) -> anyhow::Error {
    let mut why: Vec<String> = Vec::new();
    if seg.trials.is_empty() {
        why.push(format!(
            "no trial matched the protocol in the {} stream",
            if seg.source.is_empty() {
                "(empty)"
            } else {
                &seg.source
            }
        ));
    }
    why.extend(
        seg.unmatched
            .iter()
            .take(5)
            .map(|s| format!("{:.2}–{:.2} s: {}", s.t0, s.t1, s.reason)),
    );
    why.extend(
        skipped
            .iter()
            .take(5)
            .map(|s| format!("trial {}: {}", s.trial, s.reason)),
    );
    if rec.state.t.is_empty() {
        why.push("no joint-state samples".into());
    }
    anyhow::anyhow!(
        "no usable trials in {}: {}",
        rec.source.display(),
        why.join("; ")
    )
}

/// Stage 1: segment every session; a session without a single trial is an error.
fn segment_sessions<'a>(
    recs: &'a [Recording],
    opts: &IdentifyOptions,
) -> Result<Vec<Segmented<'a>>> {
    recs.iter()
        .map(|rec| {
            let seg = trial::segment(rec, &opts.segment);
            if seg.trials.is_empty() {
                Err(no_usable_trials(rec, &seg, &[]))
            } else {
                Ok(Segmented { rec, seg })
            }
        })
        .collect()
}

/// σ_ω of every trial of every session, the IMU filter's statistic.
fn imu_statistics(sessions: &[Segmented]) -> Vec<TrialStat> {
    sessions
        .iter()
        .enumerate()
        .flat_map(|(s, p)| {
            p.seg.trials.iter().map(move |t| {
                let (a, b) = t.analysis_window();
                TrialStat::new(s, t.index, trial::sigma_omega(p.rec, a, b))
            })
        })
        .collect()
}

/// Each session's trials that no rejection names.
fn trials_kept(sessions: &[Segmented], rejections: &[Rejection]) -> Vec<Vec<TrialWindow>> {
    sessions
        .iter()
        .enumerate()
        .map(|(s, p)| {
            p.seg
                .trials
                .iter()
                .filter(|t| !trial::is_rejected(rejections, s, t.index))
                .cloned()
                .collect()
        })
        .collect()
}

/// Stage 3: the power sensor's window and lag, given or estimated from (at most ~300 of) the
/// kept trials.
pub(crate) fn resolve_alignment(
    sessions: &[Segmented],
    kept: &[Vec<TrialWindow>],
    opts: &IdentifyOptions,
) -> Result<(Alignment, Option<AlignmentEstimate>)> {
    match opts.alignment {
        AlignmentChoice::Given(a) => Ok((a, None)),
        AlignmentChoice::Auto => {
            let total: usize = kept.iter().map(Vec::len).sum();
            let stride = total.div_ceil(300).max(1);
            let thinned: Vec<Vec<TrialWindow>> = kept
                .iter()
                .map(|t| t.iter().step_by(stride).cloned().collect())
                .collect();
            let pairs: Vec<(&Recording, &[TrialWindow])> = sessions
                .iter()
                .zip(&thinned)
                .map(|(p, t)| (p.rec, t.as_slice()))
                .collect();
            let est = dataset::estimate_alignment(&pairs, opts.target)?;
            Ok((est.best, Some(est)))
        }
    }
}

/// Stage 4: the rows of the options' pairing, one data set per session.
fn build_sets(
    sessions: &[Segmented],
    kept: &[Vec<TrialWindow>],
    opts: &IdentifyOptions,
    alignment: Alignment,
) -> Result<Vec<Dataset>> {
    let dopts = DatasetOptions {
        mode: opts.mode,
        target: opts.target,
        alignment,
    };
    sessions
        .iter()
        .zip(kept)
        .map(|(p, trials)| {
            let d = dataset::build(p.rec, trials, &dopts);
            if d.rows.is_empty() && !trials.is_empty() {
                Err(no_usable_trials(p.rec, &p.seg, &d.skipped))
            } else {
                Ok(d)
            }
        })
        .collect()
}

/// Result of stage 5.
struct FinalFit {
    fit: crate::lsq::Fit,
    theta: [f64; N_PARAMS],
    rows: Vec<Row>,
}

/// Stage 5: the constrained fit with iterative n·σ rejection by trial (each pass refits without
/// the trials rejected so far), then the final fit on what remains.
fn fit_with_rejection(
    sets: &[Dataset],
    rejections: &mut Vec<Rejection>,
    opts: &IdentifyOptions,
) -> Result<FinalFit> {
    let rows_kept = |rej: &[Rejection]| -> Vec<Row> {
        sets.iter()
            .enumerate()
            .flat_map(|(s, d)| {
                d.rows
                    .iter()
                    .filter(move |r| !trial::is_rejected(rej, s, r.trial))
                    .cloned()
            })
            .collect()
    };
    let min_rows = if opts.mode == Mode::Trial {
        1
    } else {
        N_PARAMS
    };
    let fit_kept = |rej: &[Rejection]| -> Result<(crate::lsq::Fit, Vec<Row>)> {
        let rows = rows_kept(rej);
        let after_residual_rejection = rej.iter().any(|r| r.reason == RejectReason::Residual);
        if after_residual_rejection && rows.len() < min_rows {
            bail!(
                "residual rejection left {} rows, too few to fit",
                rows.len()
            );
        }
        let fit = fit_rows(&rows).context("constrained least squares")?;
        Ok((fit, rows))
    };
    opts.filters.residual_passes(rejections, |rej| {
        let (fit, rows) = fit_kept(rej)?;
        let theta = fit.theta49()?;
        let mut views: Vec<(usize, &[Row])> = Vec::new();
        let mut start = 0;
        for (s, d) in sets.iter().enumerate() {
            let n = d
                .rows
                .iter()
                .filter(|r| !trial::is_rejected(rej, s, r.trial))
                .count();
            views.push((s, &rows[start..start + n]));
            start += n;
        }
        Ok::<_, anyhow::Error>(trial_residuals(&theta, &views))
    })?;
    let (fit, rows) = fit_kept(rejections)?;
    if rows.is_empty() {
        bail!("no rows left after filtering");
    }
    let theta = fit.theta49()?;
    Ok(FinalFit { fit, theta, rows })
}

/// Stage 6: the trial, reading and sample pairings on the same retained trials, each with its
/// own constrained fit (the options' pairing reuses the final fit). Also returns the trial rows.
fn compare_pairings(
    sessions: &[Segmented],
    retained: &[Vec<TrialWindow>],
    opts: &IdentifyOptions,
    alignment: Alignment,
    final_fit: &FinalFit,
) -> Result<(Vec<ModeFit>, Vec<Row>)> {
    // Sample rows of a paper-scale session would take ~0.5 GB (1e6 × 49 f64): the comparison
    // thins them trial by trial to at most SAMPLE_ROWS_MAX, which keeps the zero-order-hold
    // structure that makes them degenerate.
    const SAMPLE_ROWS_MAX: f64 = 100_000.0;
    let traj_seconds: f64 = retained
        .iter()
        .flatten()
        .map(|t| t.t_post_end - t.t_traj_start)
        .sum();
    let stride = ((traj_seconds * 100.0 / SAMPLE_ROWS_MAX).ceil() as usize).max(1);
    let mode_rows = |mode: Mode| -> Vec<Row> {
        let dopts = DatasetOptions {
            mode,
            target: opts.target,
            alignment,
        };
        let step = if mode == Mode::Sample { stride } else { 1 };
        let mut rows = Vec::new();
        for (p, ts) in sessions.iter().zip(retained) {
            for trial in ts {
                let set = dataset::build(p.rec, std::slice::from_ref(trial), &dopts);
                rows.extend(set.rows.into_iter().step_by(step));
            }
        }
        rows
    };
    let mut modes = Vec::new();
    let mut trial_rows = Vec::new();
    for mode in [Mode::Trial, Mode::Reading, Mode::Sample] {
        let (rows, theta) = if mode == opts.mode {
            (final_fit.rows.clone(), final_fit.theta)
        } else {
            let rows = mode_rows(mode);
            let theta = fit_rows(&rows)?.theta49()?;
            (rows, theta)
        };
        modes.push(ModeFit {
            mode,
            kappa: kappa(&rows),
            quality: quality(&theta, &rows),
        });
        if mode == Mode::Trial {
            trial_rows = rows;
        }
    }
    Ok((modes, trial_rows))
}

/// Stage 7: per-trial measured vs predicted over every trial with rows, rejected ones flagged.
fn per_trial_table(
    sessions: &[Segmented],
    opts: &IdentifyOptions,
    alignment: Alignment,
    theta: &[f64; N_PARAMS],
    rejections: &[Rejection],
) -> Vec<TrialPrediction> {
    let mut per_trial = Vec::new();
    for (s, p) in sessions.iter().enumerate() {
        let set = |mode| {
            dataset::build(
                p.rec,
                &p.seg.trials,
                &DatasetOptions {
                    mode,
                    target: opts.target,
                    alignment,
                },
            )
        };
        per_trial.extend(trial_predictions(
            s,
            &p.seg,
            &set(Mode::Reading),
            &set(Mode::Trial),
            theta,
            |t| trial::is_rejected(rejections, s, t),
        ));
    }
    per_trial
}

/// Identify the power model from one or more recordings.
pub fn identify(recs: &[Recording], opts: &IdentifyOptions) -> Result<Identification> {
    if recs.is_empty() {
        bail!("identify needs at least one recording");
    }
    let sessions = segment_sessions(recs, opts)?;
    let mut rejections = opts.filters.imu(&imu_statistics(&sessions));
    let kept = trials_kept(&sessions, &rejections);
    let (alignment, alignment_estimate) = resolve_alignment(&sessions, &kept, opts)?;
    let sets = build_sets(&sessions, &kept, opts, alignment)?;
    let final_fit = fit_with_rejection(&sets, &mut rejections, opts)?;
    let retained = trials_kept(&sessions, &rejections);
    let (modes, trial_rows) = compare_pairings(&sessions, &retained, opts, alignment, &final_fit)?;
    let per_trial = per_trial_table(&sessions, opts, alignment, &final_fit.theta, &rejections);

    let model = PowerModel::from_vector(&final_fit.theta);
    let terms = term_means(&model, &trial_rows);
    let retained_table: Vec<&TrialPrediction> = per_trial.iter().filter(|p| !p.rejected).collect();
    let sessions = sessions
        .into_iter()
        .zip(sets)
        .map(|(p, d)| SessionSummary {
            source: p.rec.source.clone(),
            segmentation: p.seg,
            skipped: d.skipped,
        })
        .collect();
    Ok(Identification {
        model,
        options: opts.clone(),
        sessions,
        alignment,
        alignment_estimate,
        trials_used: retained.iter().map(Vec::len).sum(),
        fit: quality(&final_fit.theta, &final_fit.rows),
        trial_level: trial_metrics(&retained_table, |p| p.predicted_window_w),
        trial_level_aligned: trial_metrics(&retained_table, |p| p.predicted_w),
        modes,
        dominant: (0..N_JOINTS).map(|j| model.dominant_term(j)).collect(),
        terms,
        shares_percent: terms.shares_percent(),
        std_err: final_fit.fit.std_err.clone(),
        solver: final_fit.fit.solver.clone(),
        rejections,
        per_trial,
    })
}

/// A fit of rows that were built elsewhere (e.g. read back from a row table): the paper's
/// constrained fit and its quality on those rows.
#[derive(Debug, Clone)]
pub struct RowsFit {
    /// The fitted model.
    pub model: PowerModel,
    /// Fit quality on the rows.
    pub fit: Metrics,
    /// κ(ΦᵀΦ) of the rows.
    pub kappa: f64,
    /// Standard error of each parameter (None: at a bound or not excited).
    pub std_err: Vec<Option<f64>>,
    /// Solver run.
    pub solver: SolverInfo,
}

/// Fit the power model to given rows (no segmentation or filtering: the rows are taken as they
/// are; leave out rejected trials before calling).
pub fn fit_given_rows(rows: &[Row]) -> Result<RowsFit> {
    if rows.len() < N_PARAMS {
        bail!(
            "{} rows, fewer than the {N_PARAMS} parameters of the model",
            rows.len()
        );
    }
    let fit = fit_rows(rows).context("constrained least squares")?;
    let theta = fit.theta49()?;
    Ok(RowsFit {
        model: PowerModel::from_vector(&theta),
        fit: quality(&theta, rows),
        kappa: kappa(rows),
        std_err: fit.std_err.clone(),
        solver: fit.solver,
    })
}
