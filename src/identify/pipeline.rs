//! `g1viz identify` / `g1viz validate`: segmentation → regressors → filters → constrained fit →
//! metrics, on one or more recordings.
//!
//! [`identify`] follows the paper: IMU balance-contamination rejection, constrained least squares
//! (a_i ≥ 1, all other parameters ≥ 0), iterative n·σ residual rejection by trial, then the final
//! fit. The rows are per trial (the paper), per power reading (default; many more rows, each
//! aligned with the sensor's own averaging window) or per sample (degenerate, for comparison).
//! It also fits the trial and sample pairings on the same retained trials and reports κ(ΦᵀΦ) and
//! R² of each, reproducing the paper's case for aggregation.
//!
//! [`validate`] applies a model to a hold-out session: metrics on per-trial rows (the paper's
//! hold-out table) and per-reading rows, per-trial predicted vs measured, term breakdown.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use nalgebra::{DMatrix, SymmetricEigen};

use super::dataset::{
    self, Alignment, AlignmentEstimate, Dataset, DatasetOptions, Mode, Row, Skipped, Target,
};
use super::filters::{self, RejectReason, Rejection, TrialStat};
use super::metrics::{self, Metrics};
use super::report::{AggregationRow, PredictionSet, ReportInput, TermContributions};
use super::segment::{self, SegmentOptions, Segmentation};
use super::solve;
use crate::power::{
    DatasetMetrics, FilterRecord, LossTerm, ModelFile, ModelMetrics, PowerModel, Provenance,
    RejectedTrial, SessionRef, SolverRecord, TERM_NAMES, TermMeans, TrialCounts,
};
use crate::signals::Recording;
use crate::{N_JOINTS, N_PARAMS};

/// Sensor timing for the per-reading rows.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum AlignmentChoice {
    /// Estimate W and lag from the data ([`dataset::estimate_alignment`]).
    Auto,
    /// Use the given timing.
    Given(Alignment),
}

/// Options of [`identify`] and [`validate`].
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct IdentifyOptions {
    /// Power sensor (`--target mbs|bms`).
    pub target: Target,
    /// Row pairing (`--mode trial|reading|sample`).
    pub mode: Mode,
    /// Segmenter tuning.
    pub segment: SegmentOptions,
    /// IMU filter factor k (reject σ_ω > k·median); None disables the filter.
    pub imu_k: Option<f64>,
    /// Residual-rejection passes (0 disables).
    pub sigma_passes: usize,
    /// Residual-rejection width n (reject |r − mean| > n·σ̂).
    pub n_sigma: f64,
    /// Power-sensor window and lag.
    pub alignment: AlignmentChoice,
}

impl Default for IdentifyOptions {
    fn default() -> Self {
        IdentifyOptions {
            target: Target::Mbs,
            mode: Mode::Reading,
            segment: SegmentOptions::default(),
            imu_k: Some(2.5),
            sigma_passes: 2,
            n_sigma: 3.0,
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

/// Mean term contributions of a model over rows (the model is linear, so the breakdown of an
/// averaged row is the mean of its samples' breakdowns).
pub fn term_means(model: &PowerModel, rows: &[Row]) -> TermMeans {
    let mut means = TermMeans::default();
    for row in rows {
        means.add(&model.breakdown_from_regressor(&row.phi));
    }
    means
}

/// Per-trial measured vs predicted mean net power over the trajectory window.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TrialPrediction {
    /// Session index in the input list.
    pub session: usize,
    /// Trial index.
    pub trial: usize,
    /// Trajectory window [s].
    pub window: (f64, f64),
    /// Joints moved.
    pub joints_moved: Vec<usize>,
    /// Peak commanded speed [rad/s].
    pub qdot_max_cmd: f64,
    /// Mean measured net power of the readings inside the trajectory window [W].
    pub measured_w: f64,
    /// Predicted net power averaged over those readings' own windows [W] (like for like with `measured_w`).
    pub predicted_w: f64,
    /// Predicted mean net power over the whole trajectory window [W] (the paper's aggregate).
    pub predicted_window_w: f64,
    /// σ_ω [rad/s].
    pub sigma_omega: f64,
    /// Rejected by a filter (identification) or flagged by the IMU criterion (validation).
    pub rejected: bool,
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
    /// Solver of the final fit: method, status, iterations.
    pub solver: (String, String, u32),
    /// Per-trial measured vs predicted (all trials with rows, rejected ones flagged).
    pub per_trial: Vec<TrialPrediction>,
}

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
    /// Per-trial measured vs predicted.
    pub per_trial: Vec<TrialPrediction>,
    /// Mean term contributions on the session's trajectory windows.
    #[serde(skip)]
    pub terms: TermMeans,
    /// The same as % of the mean total predicted power.
    pub shares_percent: [f64; 5],
    /// Remarks on how the validation was done (e.g. nominal sensor timing for a short session).
    pub notes: Vec<String>,
}

fn predict(theta: &[f64; N_PARAMS], phi: &[f64; N_PARAMS]) -> f64 {
    theta.iter().zip(phi).map(|(t, v)| t * v).sum()
}

/// κ(ΦᵀΦ) of the rows' raw (unscaled) regressors; ∞ when singular.
pub fn kappa(rows: &[Row]) -> f64 {
    metrics::condition_number_gram(&normal_matrix(rows))
}

fn normal_matrix(rows: &[Row]) -> DMatrix<f64> {
    let mut m = DMatrix::zeros(N_PARAMS, N_PARAMS);
    for row in rows {
        for a in 0..N_PARAMS {
            if row.phi[a] == 0.0 {
                continue;
            }
            for b in a..N_PARAMS {
                m[(a, b)] += row.phi[a] * row.phi[b];
            }
        }
    }
    for a in 0..N_PARAMS {
        for b in 0..a {
            m[(a, b)] = m[(b, a)];
        }
    }
    m
}

/// Constrained fit of any number of rows. Large row sets are first compressed to 49 rows with
/// the same normal equations (ΦᵀΦ = RᵀR, Φᵀy = Rᵀz from the eigen-decomposition), which leaves
/// the least-squares objective unchanged up to a constant (standard errors of a compressed fit
/// are meaningless; only the degenerate sample-row comparison is that large).
fn fit_rows(rows: &[Row]) -> Result<solve::Fit> {
    const COMPRESS_ABOVE: usize = 20_000;
    let lower = solve::paper_lower_bounds();
    let fit = if rows.len() <= COMPRESS_ABOVE {
        let phi: Vec<[f64; N_PARAMS]> = rows.iter().map(|r| r.phi).collect();
        let y: Vec<f64> = rows.iter().map(|r| r.y).collect();
        solve::fit_constrained(&phi, &y, &lower)?
    } else {
        let eig = SymmetricEigen::new(normal_matrix(rows));
        let mut phty = [0.0; N_PARAMS];
        for row in rows {
            for (acc, v) in phty.iter_mut().zip(&row.phi) {
                *acc += v * row.y;
            }
        }
        let cutoff = eig.eigenvalues.max().max(0.0) * 1e-14;
        let mut phi = Vec::with_capacity(N_PARAMS);
        let mut y = Vec::with_capacity(N_PARAMS);
        for (k, &lambda) in eig.eigenvalues.iter().enumerate() {
            if lambda <= cutoff {
                continue;
            }
            let v = eig.eigenvectors.column(k);
            let s = lambda.sqrt();
            phi.push(std::array::from_fn(|p| s * v[p]));
            y.push(v.iter().zip(&phty).map(|(a, b)| a * b).sum::<f64>() / s);
        }
        solve::fit_constrained(&phi, &y, &lower)?
    };
    Ok(fit)
}

fn quality(theta: &[f64; N_PARAMS], rows: &[Row]) -> Metrics {
    let y: Vec<f64> = rows.iter().map(|r| r.y).collect();
    let yhat: Vec<f64> = rows.iter().map(|r| predict(theta, &r.phi)).collect();
    Metrics::compute(&y, &yhat)
}

/// Mean residual per (session, trial) of the rows.
fn trial_residuals(theta: &[f64; N_PARAMS], sets: &[(usize, &[Row])]) -> Vec<TrialStat> {
    let mut out: Vec<TrialStat> = Vec::new();
    let mut count = 0usize;
    for &(session, rows) in sets {
        for row in rows {
            let r = row.y - predict(theta, &row.phi);
            match out.last_mut() {
                Some(last) if last.0 == session && last.1 == row.trial => {
                    count += 1;
                    last.2 += (r - last.2) / count as f64;
                }
                _ => {
                    out.push((session, row.trial, r));
                    count = 1;
                }
            }
        }
    }
    out
}

fn session_name(rec: &Recording) -> String {
    rec.source.display().to_string()
}

/// Explain why a session gave no rows.
fn no_usable_trials(rec: &Recording, seg: &Segmentation, skipped: &[Skipped]) -> anyhow::Error {
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
        session_name(rec),
        why.join("; ")
    )
}

struct Prepared<'a> {
    rec: &'a Recording,
    seg: Segmentation,
}

fn resolve_alignment(
    prepared: &[Prepared],
    kept: &[Vec<segment::Trial>],
    opts: &IdentifyOptions,
) -> Result<(Alignment, Option<AlignmentEstimate>)> {
    match opts.alignment {
        AlignmentChoice::Given(a) => Ok((a, None)),
        AlignmentChoice::Auto => {
            // The search needs a few hundred trials at most; thin out long sessions to stay fast.
            let total: usize = kept.iter().map(Vec::len).sum();
            let stride = total.div_ceil(300).max(1);
            let thinned: Vec<Vec<segment::Trial>> = kept
                .iter()
                .map(|t| t.iter().step_by(stride).cloned().collect())
                .collect();
            let sessions: Vec<(&Recording, &[segment::Trial])> = prepared
                .iter()
                .zip(&thinned)
                .map(|(p, t)| (p.rec, t.as_slice()))
                .collect();
            let est = dataset::estimate_alignment(&sessions, opts.target)?;
            Ok((est.best, Some(est)))
        }
    }
}

/// Identify the power model from one or more recordings.
pub fn identify(recs: &[Recording], opts: &IdentifyOptions) -> Result<Identification> {
    if recs.is_empty() {
        bail!("identify needs at least one recording");
    }
    let prepared: Vec<Prepared> = recs
        .iter()
        .map(|rec| Prepared {
            rec,
            seg: segment::segment(rec, &opts.segment),
        })
        .collect();
    for p in &prepared {
        if p.seg.trials.is_empty() {
            return Err(no_usable_trials(p.rec, &p.seg, &[]));
        }
    }

    // IMU balance-contamination filter over all sessions' trials together.
    let sigmas: Vec<TrialStat> = prepared
        .iter()
        .enumerate()
        .flat_map(|(s, p)| {
            p.seg.trials.iter().map(move |t| {
                (
                    s,
                    t.index,
                    filters::sigma_omega(p.rec, t.t_traj_start, t.t_post_end),
                )
            })
        })
        .collect();
    let mut rejections = opts
        .imu_k
        .map(|k| filters::imu_sway(&sigmas, k))
        .unwrap_or_default();
    let is_rejected =
        |rej: &[Rejection], s: usize, t: usize| rej.iter().any(|r| r.session == s && r.trial == t);
    let kept: Vec<Vec<segment::Trial>> = prepared
        .iter()
        .enumerate()
        .map(|(s, p)| {
            p.seg
                .trials
                .iter()
                .filter(|t| !is_rejected(&rejections, s, t.index))
                .cloned()
                .collect()
        })
        .collect();

    let (alignment, alignment_estimate) = resolve_alignment(&prepared, &kept, opts)?;
    let build = |mode: Mode, s: usize| {
        dataset::build(
            prepared[s].rec,
            &kept[s],
            &DatasetOptions {
                mode,
                target: opts.target,
                alignment,
            },
        )
    };
    let main_sets: Vec<Dataset> = (0..prepared.len()).map(|s| build(opts.mode, s)).collect();
    for (s, d) in main_sets.iter().enumerate() {
        if d.rows.is_empty() && !kept[s].is_empty() {
            return Err(no_usable_trials(
                prepared[s].rec,
                &prepared[s].seg,
                &d.skipped,
            ));
        }
    }

    // Constrained fit with iterative residual rejection by trial.
    let rows_kept = |rej: &[Rejection]| -> Vec<Row> {
        main_sets
            .iter()
            .enumerate()
            .flat_map(|(s, d)| {
                d.rows
                    .iter()
                    .filter(move |r| !is_rejected(rej, s, r.trial))
                    .cloned()
            })
            .collect()
    };
    let min_rows = if opts.mode == Mode::Trial {
        1
    } else {
        N_PARAMS
    };
    let mut final_fit = fit_rows(&rows_kept(&rejections)).context("constrained least squares")?;
    let mut theta = final_fit.theta49()?;
    for pass in 1..=opts.sigma_passes {
        let sets: Vec<(usize, Vec<Row>)> = main_sets
            .iter()
            .enumerate()
            .map(|(s, d)| {
                (
                    s,
                    d.rows
                        .iter()
                        .filter(|r| !is_rejected(&rejections, s, r.trial))
                        .cloned()
                        .collect(),
                )
            })
            .collect();
        let views: Vec<(usize, &[Row])> = sets.iter().map(|(s, r)| (*s, r.as_slice())).collect();
        let new = filters::three_sigma(&trial_residuals(&theta, &views), opts.n_sigma, pass);
        if new.is_empty() {
            break;
        }
        rejections.extend(new);
        let rows = rows_kept(&rejections);
        if rows.len() < min_rows {
            bail!(
                "residual rejection left {} rows, too few to fit",
                rows.len()
            );
        }
        final_fit = fit_rows(&rows).context("constrained least squares")?;
        theta = final_fit.theta49()?;
    }
    let final_rows = rows_kept(&rejections);
    if final_rows.is_empty() {
        bail!("no rows left after filtering");
    }
    let model = PowerModel::from_vector(&theta);
    let fit = quality(&theta, &final_rows);

    // The three pairings on the same retained trials.
    let retained: Vec<Vec<segment::Trial>> = kept
        .iter()
        .enumerate()
        .map(|(s, ts)| {
            ts.iter()
                .filter(|t| !is_rejected(&rejections, s, t.index))
                .cloned()
                .collect()
        })
        .collect();
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
        let mut rows = Vec::new();
        for (p, ts) in prepared.iter().zip(&retained) {
            for trial in ts {
                let set = dataset::build(
                    p.rec,
                    std::slice::from_ref(trial),
                    &DatasetOptions {
                        mode,
                        target: opts.target,
                        alignment,
                    },
                );
                let step = if mode == Mode::Sample { stride } else { 1 };
                rows.extend(set.rows.into_iter().step_by(step));
            }
        }
        rows
    };
    let mut modes = Vec::new();
    let mut trial_rows = Vec::new();
    for mode in [Mode::Trial, Mode::Reading, Mode::Sample] {
        let rows = if mode == opts.mode {
            final_rows.clone()
        } else {
            mode_rows(mode)
        };
        let theta_mode = if mode == opts.mode {
            theta
        } else {
            fit_rows(&rows)?.theta49()?
        };
        modes.push(ModeFit {
            mode,
            kappa: kappa(&rows),
            quality: quality(&theta_mode, &rows),
        });
        if mode == Mode::Trial {
            trial_rows = rows;
        }
    }
    let terms = term_means(&model, &trial_rows);

    // Per-trial table over every trial with rows, rejected ones flagged.
    let mut per_trial = Vec::new();
    for (s, p) in prepared.iter().enumerate() {
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
            &theta,
            |t| is_rejected(&rejections, s, t),
        ));
    }
    let retained_table: Vec<&TrialPrediction> = per_trial.iter().filter(|p| !p.rejected).collect();
    let trial_level = trial_metrics(&retained_table, |p| p.predicted_window_w);
    let trial_level_aligned = trial_metrics(&retained_table, |p| p.predicted_w);
    let sessions = prepared
        .iter()
        .zip(&main_sets)
        .map(|(p, d)| SessionSummary {
            source: p.rec.source.clone(),
            segmentation: p.seg.clone(),
            skipped: d.skipped.clone(),
        })
        .collect();
    Ok(Identification {
        model,
        options: opts.clone(),
        sessions,
        alignment,
        alignment_estimate,
        rejections,
        trials_used: retained.iter().map(Vec::len).sum(),
        fit,
        trial_level,
        trial_level_aligned,
        modes,
        dominant: (0..N_JOINTS).map(|j| model.dominant_term(j)).collect(),
        terms,
        shares_percent: terms.shares_percent(),
        std_err: final_fit.std_err.clone(),
        solver: (
            final_fit.solver.method.to_string(),
            final_fit.solver.status.clone(),
            final_fit.solver.iterations,
        ),
        per_trial,
    })
}

/// Per-trial measured vs predicted from a trial's reading rows (like for like) and its trial row
/// (the paper's whole-window aggregate).
fn trial_predictions(
    session: usize,
    seg: &Segmentation,
    readings: &Dataset,
    windows: &Dataset,
    theta: &[f64; N_PARAMS],
    rejected: impl Fn(usize) -> bool,
) -> Vec<TrialPrediction> {
    let mut out: Vec<TrialPrediction> = Vec::new();
    for basis in &readings.trials {
        let rows: Vec<&Row> = readings
            .rows
            .iter()
            .filter(|r| r.trial == basis.trial)
            .collect();
        let (Some(trial), Some(window_row)) = (
            seg.trials.iter().find(|t| t.index == basis.trial),
            windows.rows.iter().find(|r| r.trial == basis.trial),
        ) else {
            continue;
        };
        let n = rows.len().max(1) as f64;
        out.push(TrialPrediction {
            session,
            trial: basis.trial,
            window: basis.window,
            joints_moved: trial.joints_moved.clone(),
            qdot_max_cmd: trial.qdot_max_cmd,
            measured_w: rows.iter().map(|r| r.y).sum::<f64>() / n,
            predicted_w: rows.iter().map(|r| predict(theta, &r.phi)).sum::<f64>() / n,
            predicted_window_w: predict(theta, &window_row.phi),
            sigma_omega: basis.sigma_omega,
            rejected: rejected(basis.trial),
        });
    }
    out
}

fn trial_metrics(
    table: &[&TrialPrediction],
    predicted: impl Fn(&TrialPrediction) -> f64,
) -> Metrics {
    let y: Vec<f64> = table.iter().map(|p| p.measured_w).collect();
    let yhat: Vec<f64> = table.iter().map(|p| predicted(p)).collect();
    Metrics::compute(&y, &yhat)
}

/// Apply `model` to a hold-out session. No filter removes trials (the paper's hold-out set is
/// unfiltered); the IMU criterion is evaluated and reported separately.
pub fn validate(model: &PowerModel, rec: &Recording, opts: &IdentifyOptions) -> Result<Validation> {
    let seg = segment::segment(rec, &opts.segment);
    if seg.trials.is_empty() {
        return Err(no_usable_trials(rec, &seg, &[]));
    }
    let prepared = [Prepared { rec, seg }];
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
    let [Prepared { seg, .. }] = prepared;
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
    let sigmas: Vec<TrialStat> = trial_set
        .trials
        .iter()
        .map(|b| (0, b.trial, b.sigma_omega))
        .collect();
    let flagged = opts.imu_k.map(|k| filters::imu_sway(&sigmas, k));
    let is_flagged = |t: usize| {
        flagged
            .as_ref()
            .is_some_and(|f| f.iter().any(|r| r.trial == t))
    };
    let per_trial = trial_predictions(0, &seg, &reading_set, &trial_set, &theta, is_flagged);
    let all: Vec<&TrialPrediction> = per_trial.iter().collect();
    let kept: Vec<&TrialPrediction> = per_trial.iter().filter(|p| !p.rejected).collect();
    Ok(Validation {
        notes,
        trial_level: trial_metrics(&all, |p| p.predicted_window_w),
        trial_level_aligned: trial_metrics(&all, |p| p.predicted_w),
        trial_level_aligned_imu_kept: flagged
            .as_ref()
            .map(|_| trial_metrics(&kept, |p| p.predicted_w)),
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

impl Identification {
    /// The model file (`model.json`) of this identification: θ, metrics on the fitted rows (with
    /// their κ), optional hold-out metrics, and provenance (sessions, target, rows, filters with
    /// their settings, trial counts, every rejected trial, solver). `joint_names` are the URDF
    /// names in model order (the recording's); `created` is written as given (reproducible output).
    pub fn model_file(
        &self,
        joint_names: &[String],
        validation: Option<&Validation>,
        created: &str,
    ) -> Result<ModelFile> {
        let rows = match self.options.mode {
            Mode::Trial => "trajectory",
            Mode::Reading => "per_reading",
            Mode::Sample => "per_sample",
        };
        let kappa = self
            .modes
            .iter()
            .find(|m| m.mode == self.options.mode)
            .map_or(f64::NAN, |m| m.kappa);
        let identification = DatasetMetrics {
            dataset: format!(
                "{} rows of {} retained trials (filtered)",
                rows.replace('_', "-"),
                self.trials_used
            ),
            fit: self.fit,
            condition_number: kappa,
        };
        let validation_metrics = validation.map(|v| DatasetMetrics {
            dataset: format!(
                "{}: per-reading rows, all usable trials",
                v.session.source.display()
            ),
            fit: v.reading_level,
            condition_number: f64::NAN,
        });
        let mut sessions: Vec<SessionRef> = self
            .sessions
            .iter()
            .map(|s| session_ref(&s.source, "identification"))
            .collect();
        if let Some(v) = validation {
            sessions.push(session_ref(&v.session.source, "validation"));
        }
        let count = |reason: RejectReason| {
            self.rejections
                .iter()
                .filter(|r| r.reason == reason)
                .count()
        };
        let mut filters = Vec::new();
        if let Some(k) = self.options.imu_k {
            filters.push(FilterRecord {
                name: "imu_sigma".into(),
                parameters: [("k_median".to_string(), k)].into(),
                rejected: count(RejectReason::ImuSway),
            });
        }
        if self.options.sigma_passes > 0 {
            filters.push(FilterRecord {
                name: "residual_3sigma".into(),
                parameters: [
                    ("k_sigma".to_string(), self.options.n_sigma),
                    ("passes".to_string(), self.options.sigma_passes as f64),
                ]
                .into(),
                rejected: count(RejectReason::Residual),
            });
        }
        let rejected_trials = self
            .rejections
            .iter()
            .map(|r| RejectedTrial {
                session: self
                    .sessions
                    .get(r.session)
                    .map_or_else(String::new, |s| s.source.display().to_string()),
                trial: r.trial,
                filter: match r.reason {
                    RejectReason::ImuSway => "imu_sigma".into(),
                    RejectReason::Residual => "residual_3sigma".into(),
                },
                statistic: r.statistic,
                threshold: r.threshold,
                reason: r.describe(),
            })
            .collect();
        let mut notes = vec![format!(
            "power readings treated as averages over [t − {:.3} s − {:.3} s, t − {:.3} s]{}",
            self.alignment.lag_s,
            self.alignment.window_s,
            self.alignment.lag_s,
            if self.alignment_estimate.is_some() {
                " (window and lag estimated from the data)"
            } else {
                ""
            }
        )];
        notes.extend(self.modes.iter().map(|m| {
            format!(
                "{} rows: n = {}, κ(ΦᵀΦ) = {:.3e}, R² = {:.4}",
                m.mode.name(),
                m.quality.n,
                m.kappa,
                m.quality.r2
            )
        }));
        let provenance = Provenance {
            created: created.to_string(),
            sessions,
            target: self.options.target.name().into(),
            rows: rows.into(),
            filters,
            trials: TrialCounts {
                segmented: self
                    .sessions
                    .iter()
                    .map(|s| s.segmentation.trials.len())
                    .sum(),
                used: self.trials_used,
                rejected: self.rejections.len(),
            },
            rejected_trials,
            solver: Some(SolverRecord {
                method: self.solver.0.clone(),
                status: self.solver.1.clone(),
                iterations: self.solver.2,
            }),
            notes,
            ..Provenance::default()
        };
        let mut file = ModelFile::new(
            &self.model,
            joint_names,
            ModelMetrics {
                identification: Some(identification),
                validation: validation_metrics,
            },
            provenance,
        )?;
        file.theta_std_err = Some(self.std_err.clone());
        Ok(file)
    }

    /// Everything the markdown report shows: the model file, per-trial measured vs predicted on
    /// the retained trials (and on the hold-out session), term contributions (hold-out set when
    /// given, as in the paper), the row-pairing comparison, and the truth θ for simulated sessions.
    pub fn report_input(
        &self,
        model_file: ModelFile,
        validation: Option<&Validation>,
        truth: Option<PowerModel>,
    ) -> ReportInput {
        let set = |label: String, table: &[TrialPrediction]| PredictionSet {
            label,
            measured: table.iter().map(|p| p.measured_w).collect(),
            predicted: table.iter().map(|p| p.predicted_w).collect(),
        };
        let retained: Vec<TrialPrediction> = self
            .per_trial
            .iter()
            .filter(|p| !p.rejected)
            .cloned()
            .collect();
        let terms = match validation {
            Some(v) => TermContributions::from_means(
                &format!("hold-out trajectories ({})", v.session.source.display()),
                &v.terms,
            ),
            None => {
                TermContributions::from_means("identification trajectories (retained)", &self.terms)
            }
        };
        ReportInput {
            title: "Arm power model identification".into(),
            model: model_file,
            identification: Some(set(
                format!("identification: {} retained trials", retained.len()),
                &retained,
            )),
            validation: validation.map(|v| {
                set(
                    format!("hold-out: {} trials", v.per_trial.len()),
                    &v.per_trial,
                )
            }),
            terms: Some(terms),
            aggregation: self
                .modes
                .iter()
                .map(|m| AggregationRow {
                    rows: m.mode.name().into(),
                    n: m.quality.n,
                    condition_number: m.kappa,
                    r2: m.quality.r2,
                })
                .collect(),
            truth,
            notes: Vec::new(),
        }
    }
}

/// A session reference for provenance; a path that cannot be read (e.g. an in-memory recording)
/// is recorded with size 0 rather than failing the model file.
fn session_ref(path: &Path, role: &str) -> SessionRef {
    SessionRef::from_path(path, role).unwrap_or_else(|_| SessionRef {
        path: path.display().to_string(),
        size_bytes: 0,
        role: role.into(),
    })
}

fn metrics_line(label: &str, m: &Metrics) -> String {
    format!(
        "{label}: n {}, R² {:.4}, RMSE {:.3} W, MAE {:.3} W, bias {:+.3} W, skewness {:.2}, kurtosis {:.2}",
        m.n, m.r2, m.rmse, m.mae, m.bias, m.skewness, m.kurtosis
    )
}

fn shares_line(shares: &[f64; 5]) -> String {
    let parts: Vec<String> = TERM_NAMES
        .iter()
        .zip(shares)
        .map(|(name, v)| format!("{name} {v:.1} %"))
        .collect();
    format!("term shares: {}", parts.join(", "))
}

fn segmentation_lines(out: &mut Vec<String>, s: &SessionSummary) {
    out.push(format!(
        "{}: {} trials ({} stream), {} stretches not matching the protocol",
        s.source.display(),
        s.segmentation.trials.len(),
        s.segmentation.source,
        s.segmentation.unmatched.len()
    ));
    out.extend(
        s.segmentation
            .unmatched
            .iter()
            .map(|u| format!("  {:.2}–{:.2} s: {}", u.t0, u.t1, u.reason)),
    );
    out.extend(
        s.skipped
            .iter()
            .map(|k| format!("  trial {} skipped: {}", k.trial, k.reason)),
    );
}

impl Identification {
    /// Plain-text summary for the terminal: sessions and segmentation, rejected trials, sensor
    /// timing, fit quality, the row-pairing comparison, dominant terms and term shares.
    pub fn summary(&self) -> String {
        let mut out = Vec::new();
        for s in &self.sessions {
            segmentation_lines(&mut out, s);
        }
        out.extend(
            self.rejections
                .iter()
                .map(|r| format!("rejected {}", r.describe())),
        );
        out.push(format!(
            "power readings = averages over [t − {:.3} s − {:.3} s, t − {:.3} s]{}",
            self.alignment.lag_s,
            self.alignment.window_s,
            self.alignment.lag_s,
            if self.alignment_estimate.is_some() {
                " (estimated)"
            } else {
                ""
            }
        ));
        out.push(format!(
            "{} trials used, target {}, {} rows",
            self.trials_used,
            self.options.target.name(),
            self.options.mode.name()
        ));
        out.push(metrics_line("fit", &self.fit));
        out.push(metrics_line(
            "trial level (like for like)",
            &self.trial_level_aligned,
        ));
        out.push(metrics_line(
            "trial level (paper: whole-window regressors)",
            &self.trial_level,
        ));
        out.extend(self.modes.iter().map(|m| {
            format!(
                "{:>7} rows: n {:>7}, κ(ΦᵀΦ) {:.3e}, R² {:.4}",
                m.mode.name(),
                m.quality.n,
                m.kappa,
                m.quality.r2
            )
        }));
        let dominant: Vec<String> = self
            .dominant
            .iter()
            .enumerate()
            .map(|(j, d)| format!("{j}: {}", d.map_or("none", LossTerm::name)))
            .collect();
        out.push(format!("dominant term per joint: {}", dominant.join(", ")));
        out.push(shares_line(&self.shares_percent));
        out.join("\n")
    }
}

impl Validation {
    /// Plain-text summary for the terminal: segmentation, metrics at reading and trial level,
    /// term shares.
    pub fn summary(&self) -> String {
        let mut out = Vec::new();
        segmentation_lines(&mut out, &self.session);
        out.push(metrics_line("per reading", &self.reading_level));
        out.push(metrics_line(
            "per trial (like for like)",
            &self.trial_level_aligned,
        ));
        if let Some(m) = &self.trial_level_aligned_imu_kept {
            out.push(metrics_line("per trial, IMU-calm trials only", m));
        }
        out.push(metrics_line(
            "per trial (paper: whole-window regressors)",
            &self.trial_level,
        ));
        out.push(shares_line(&self.shares_percent));
        out.join("\n")
    }
}
