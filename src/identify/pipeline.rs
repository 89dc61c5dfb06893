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

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use nalgebra::{DMatrix, SymmetricEigen};

use super::dataset::{
    self, Alignment, AlignmentEstimate, Dataset, DatasetOptions, Mode, Row, Skipped, Target,
};
use super::filters::{self, Rejection, TrialStat};
use super::metrics::{self, Metrics};
use super::segment::{self, SegmentOptions, Segmentation};
use super::solve;
use crate::power::{PAIRS, PowerModel};
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

/// Mean contribution of each term family, in % of the total predicted net power (the paper's
/// breakdown figure: mechanical, copper, Coulomb, viscous, interaction).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TermShares {
    /// a·τq̇ [%].
    pub mechanical: f64,
    /// b·Δτ² [%].
    pub copper: f64,
    /// c·|q̇| [%].
    pub coulomb: f64,
    /// d·q̇² [%].
    pub viscous: f64,
    /// e·|q̇_i||q̇_j| [%].
    pub interaction: f64,
}

impl TermShares {
    /// Shares over a set of rows: each family's mean contribution over the sum of the means.
    pub fn of(model: &PowerModel, rows: &[Row]) -> TermShares {
        let theta = model.to_vector();
        let mut sums = [0.0; 5];
        for row in rows {
            for (p, (t, v)) in theta.iter().zip(&row.phi).enumerate() {
                sums[(p / N_JOINTS).min(4)] += t * v;
            }
        }
        let total: f64 = sums.iter().sum();
        let pct = |v: f64| 100.0 * v / total;
        TermShares {
            mechanical: pct(sums[0]),
            copper: pct(sums[1]),
            coulomb: pct(sums[2]),
            viscous: pct(sums[3]),
            interaction: pct(sums[4]),
        }
    }
}

/// The dominant loss mechanism of a joint: argmax(b_i, c_i, d_i) as in the paper's table.
pub fn dominant_terms(model: &PowerModel) -> Vec<&'static str> {
    (0..N_JOINTS)
        .map(|i| {
            let (b, c, d) = (model.b[i], model.c[i], model.d[i]);
            if b >= c && b >= d {
                "copper"
            } else if c >= d {
                "Coulomb"
            } else {
                "viscous"
            }
        })
        .collect()
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
    /// Dominant term per joint.
    pub dominant: Vec<String>,
    /// Term shares on the retained trials' trajectory windows.
    pub shares: TermShares,
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
    /// Term shares on the session's trajectory windows.
    pub shares: TermShares,
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
/// the least-squares objective unchanged up to a constant.
fn fit_rows(rows: &[Row]) -> Result<[f64; N_PARAMS]> {
    const COMPRESS_ABOVE: usize = 2000;
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
    fit.theta49()
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
    let mut theta = fit_rows(&rows_kept(&rejections)).context("constrained least squares")?;
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
        theta = fit_rows(&rows).context("constrained least squares")?;
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
            fit_rows(&rows)?
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
    let shares = TermShares::of(&model, &trial_rows);

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
        dominant: dominant_terms(&model)
            .into_iter()
            .map(String::from)
            .collect(),
        shares,
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
    let (alignment, _) = resolve_alignment(
        &prepared,
        std::slice::from_ref(&prepared[0].seg.trials),
        opts,
    )?;
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
        trial_level: trial_metrics(&all, |p| p.predicted_window_w),
        trial_level_aligned: trial_metrics(&all, |p| p.predicted_w),
        trial_level_aligned_imu_kept: flagged
            .as_ref()
            .map(|_| trial_metrics(&kept, |p| p.predicted_w)),
        reading_level: quality(&theta, &reading_set.rows),
        shares: TermShares::of(model, &trial_set.rows),
        per_trial,
        alignment,
        session: SessionSummary {
            source: rec.source.clone(),
            segmentation: seg,
            skipped: trial_set.skipped,
        },
    })
}

/// Names of the 49 parameters in θ order (a0..a6, b0..b6, c0..c6, d0..d6, e01..e56).
pub fn parameter_names() -> Vec<String> {
    let mut names = Vec::with_capacity(N_PARAMS);
    for family in ["a", "b", "c", "d"] {
        names.extend((0..N_JOINTS).map(|i| format!("{family}{i}")));
    }
    names.extend(PAIRS.iter().map(|(i, j)| format!("e{i}{j}")));
    names
}
