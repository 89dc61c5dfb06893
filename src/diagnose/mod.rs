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

pub mod counterpart;
pub(crate) mod data;
pub(crate) mod discover;
pub(crate) mod fields;
pub mod hypotheses;
pub(crate) mod locate;
pub mod report;
pub(crate) mod select;
pub(crate) mod stats;
pub(crate) mod summary;
#[cfg(test)]
mod testkit;
pub(crate) mod torque;

use std::path::PathBuf;

use anyhow::{Result, bail};

pub use crate::trial::{Phase, TrialWindow};
pub use discover::{Discovery, DiscoveryReport};
pub use fields::FieldSource;
pub use locate::{Breakdown, Correlate, Group, TrialResidual};
pub use select::{Confounded, HypothesisScore, MechanismForms, Param};
pub use torque::{ArmModel, TorqueComparison};

use crate::N_PARAMS;
use crate::power::PowerModel;
use crate::robot::{ArmDynamics, RobotModel};
use crate::signals::Recording;
pub use crate::signals::Target;
use crate::trial::{Cascade, Rejection, TrialStat};
use data::{Rows, TrialMeta, build_rows, trial_meta};
use hypotheses::{LATENCY_ID, POWER_HYPOTHESES};
use select::{PowerData, Rule, r2_rmse};

/// Version of the `diagnosis.json` layout.
pub const SCHEMA_VERSION: u32 = 1;

/// Settings of a diagnosis.
#[derive(Debug, Clone)]
pub struct DiagnoseOptions {
    /// The twin's power model (e.g. a model.json identified earlier, or the paper's model). When
    /// given, the base model is held at it and the hypotheses explain the recording's departure
    /// from the twin (an effect that shifts every reading, like a warm motor, is visible). When
    /// absent, the base model is refitted on the training trials of every fold and the hypotheses
    /// must explain structure the 49 base parameters cannot absorb.
    pub reference: Option<PowerModel>,
    /// Power target.
    pub target: Target,
    /// Number of cross-validation folds (by trial).
    pub folds: usize,
    /// Significance level of the paired held-out test.
    pub alpha: f64,
    /// ΔBIC a hypothesis must beat (negative).
    pub bic_threshold: f64,
    /// Minimum relative held-out RMSE improvement.
    pub min_improvement: f64,
    /// Power sensor averaging window W [s] (a reading stamped t averages [t − W, t]).
    pub sensor_window_s: f64,
    /// Largest sensor latency scanned [s] (0 disables the latency hypothesis).
    pub max_lag_s: f64,
    /// IMU filter: reject trials whose σ_ω exceeds this multiple of the median.
    pub imu_threshold: f64,
    /// Passes of 3σ per-trial residual rejection.
    pub outlier_passes: usize,
    /// Cap on torque samples used at the torque level (evenly thinned beyond it).
    pub max_torque_samples: usize,
    /// URDF for the torque level (default: the shipped G1 left arm with hand).
    pub urdf: Option<PathBuf>,
    /// Compare torques and score the payload hypothesis.
    pub torque_level: bool,
    /// Search beyond the library ([`discover`]) when the library is done.
    pub discover: bool,
    /// Files whose every numeric field discovery reads (empty: the recording's own source when
    /// it is a file; joined recordings give one entry per part, see [`join_recordings_with_sources`]).
    pub field_sources: Vec<FieldSource>,
    /// SDK motor index of each arm joint (whose `motor_state[k]` fields belong to joint i).
    pub arm_motors: [usize; crate::N_JOINTS],
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        DiagnoseOptions {
            reference: None,
            target: Target::Mbs,
            folds: 10,
            alpha: 1e-3,
            bic_threshold: -10.0,
            min_improvement: 0.02,
            sensor_window_s: 0.2,
            max_lag_s: 1.0,
            imu_threshold: 2.5,
            outlier_passes: 2,
            max_torque_samples: 60_000,
            urdf: None,
            torque_level: true,
            discover: true,
            field_sources: Vec::new(),
            arm_motors: std::array::from_fn(|i| crate::signals::G1_LEFT_ARM_BASE + i),
        }
    }
}

/// Held-out quality of a model.
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
pub struct Quality {
    /// Coefficient of determination.
    pub r2: f64,
    /// Root-mean-square error [W].
    pub rmse_w: f64,
}

/// One point of the sensor-lag scan.
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
pub struct LagPoint {
    /// Assumed latency [s].
    pub lag_s: f64,
    /// In-sample RMSE of the base model refitted at this lag [W].
    pub rmse_w: f64,
}

/// The model refitted with the accepted hypotheses.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct FinalModel {
    /// Accepted hypotheses, in the order they were added.
    pub hypotheses: Vec<String>,
    /// Their physical parameters with standard errors (jackknife over the folds).
    pub params: Vec<Param>,
    /// Base power-model θ (49) of the final refit (a, b, c, d, e order).
    pub theta: Vec<f64>,
    /// Held-out quality of the base model (per reading).
    pub before: Quality,
    /// Held-out quality with the accepted hypotheses (per reading).
    pub after: Quality,
    /// The same per trial (mean of each trial's readings), before.
    pub before_per_trial: Quality,
    /// The same per trial, after.
    pub after_per_trial: Quality,
}

/// Data for the replay: per power reading, measured and predicted net power.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct ReplayData {
    /// Reading time stamp [s, Recording time].
    pub t: Vec<f64>,
    /// Trial index of each reading (segmentation numbering).
    pub trial: Vec<usize>,
    /// Measured net power [W].
    pub measured_w: Vec<f64>,
    /// Held-out prediction of the base model [W].
    pub before_w: Vec<f64>,
    /// Held-out prediction with the accepted hypotheses [W].
    pub after_w: Vec<f64>,
    /// Trials to highlight (worst residuals, carriers of unexplained structure).
    pub highlighted: Vec<HighlightedTrial>,
    /// Held-out prediction with the terms found beyond the library [W] (empty when none).
    #[serde(default)]
    pub found_w: Vec<f64>,
    /// The recorded fields the found terms follow, per reading (window values), to plot beside
    /// the residual.
    #[serde(default)]
    pub located: Vec<LocatedField>,
}

/// A recorded field a found term follows, sampled on the readings' windows.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct LocatedField {
    /// `topic.field.path`.
    pub name: String,
    /// Window value per reading (same order as [`ReplayData::t`]).
    pub values: Vec<f64>,
}

/// A trial the replay should point the user to.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct HighlightedTrial {
    /// Trial index (segmentation numbering).
    pub trial: usize,
    /// Trajectory start [s, Recording time].
    pub t_start: f64,
    /// Return end [s].
    pub t_end: f64,
    /// Why it is highlighted.
    pub reason: String,
}

/// Everything a diagnosis found (serialised as diagnosis.json).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Diagnosis {
    /// Layout version ([`SCHEMA_VERSION`]).
    pub schema_version: u32,
    /// Recording diagnosed.
    pub source: String,
    /// Power target.
    pub target: Target,
    /// URDF joint names.
    pub joint_names: Vec<String>,
    /// Trials used.
    pub n_trials: usize,
    /// Power readings used.
    pub n_readings: usize,
    /// Trials left out, with reasons.
    pub rejected: Vec<Rejection>,
    /// Torque level (absent without a robot model or torque data).
    pub torque: Option<TorqueComparison>,
    /// How the base model was obtained: `reference` (held at the twin's model) or `refit` (per fold).
    pub base_model: String,
    /// Sensor-lag scan of the base model.
    pub lag_scan: Vec<LagPoint>,
    /// Residual breakdowns of the base model (held out).
    pub breakdowns: Vec<Breakdown>,
    /// Where the base model is worst: (breakdown, group).
    pub worst: Option<(String, Group)>,
    /// Trials with the largest held-out base residual.
    pub worst_trials: Vec<TrialResidual>,
    /// Every hypothesis scored against the base model, ranked (1 = best).
    pub hypotheses: Vec<HypothesisScore>,
    /// Accepted hypotheses in selection order, scored at their step.
    pub accepted: Vec<HypothesisScore>,
    /// The refit with the accepted hypotheses.
    pub final_model: FinalModel,
    /// Residual structure left after the final model: strongest correlates.
    pub unexplained: Vec<Correlate>,
    /// Forms of each mechanism with several, compared with the same cross-validation.
    #[serde(default)]
    pub forms: Vec<MechanismForms>,
    /// Hypotheses forward selection accepted together that the data cannot tell apart.
    #[serde(default)]
    pub confounded: Vec<Confounded>,
    /// Discovery beyond the library (absent when switched off).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub discovery: Option<DiscoveryReport>,
    /// Mean motor supply voltage the bus-current form used [V] (recorded, or nominal).
    #[serde(default)]
    pub bus_volts: f64,
    /// Plain-language summary.
    pub summary: String,
    /// Per-reading data for the replay.
    pub replay: ReplayData,
    /// Sample-by-sample comparison with a simulated counterpart, when one was given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub counterpart: Option<counterpart::CounterpartComparison>,
}

impl Diagnosis {
    /// Write diagnosis.json (atomic).
    pub fn save_json(&self, path: &std::path::Path) -> Result<()> {
        let text = serde_json::to_string_pretty(self)?;
        crate::util::write_atomic(path, text.as_bytes())
    }
}

/// Stage: the trials usable for the diagnosis — per-trial quantities (trials without a pre-idle
/// are unusable), the identification's IMU filter, then n·σ passes on the per-trial mean
/// residuals of the base model (hardware-event outliers).
fn filter_trials(
    rec: &Recording,
    windows: &[TrialWindow],
    opts: &DiagnoseOptions,
    reference: Option<Vec<f64>>,
) -> Result<(Vec<TrialMeta>, Vec<Rejection>)> {
    let power = opts.target.series(rec);
    let bus = data::BusModel {
        model: opts.reference.unwrap_or(PowerModel::PAPER),
        volts: hypotheses::NOMINAL_BUS_VOLTS,
    };
    let (metas, skipped) = trial_meta(rec, windows, bus);
    let cascade = Cascade {
        imu_k: Some(opts.imu_threshold),
        passes: opts.outlier_passes,
        n_sigma: 3.0,
        min_trials: 10,
    };
    let sigmas: Vec<TrialStat> = metas
        .iter()
        .map(|m| TrialStat::new(0, m.window.index, m.sigma_omega))
        .collect();
    let mut rejected: Vec<Rejection> = skipped
        .into_iter()
        .map(|(trial, reason)| Rejection::unusable(0, trial, reason))
        .collect();
    rejected.extend(cascade.run(&sigmas, |rej| {
        let kept: Vec<TrialMeta> = metas
            .iter()
            .filter(|m| !crate::trial::is_rejected(rej, 0, m.window.index))
            .cloned()
            .collect();
        let rows = build_rows(rec, power, &kept, 0.0, opts.sensor_window_s, false);
        let res = base_trial_residuals(&rows, kept.len(), opts.folds, reference.clone())?;
        Ok::<_, anyhow::Error>(
            kept.iter()
                .zip(&res)
                .map(|(m, r)| TrialStat::new(0, m.window.index, r.unwrap_or(f64::NAN)))
                .collect(),
        )
    })?);
    let metas = metas
        .into_iter()
        .filter(|m| !crate::trial::is_rejected(&rejected, 0, m.window.index))
        .collect();
    Ok((metas, rejected))
}

/// Per-trial mean in-sample residual of the base model fitted to `rows`.
fn base_trial_residuals(
    rows: &Rows,
    n_trials: usize,
    folds: usize,
    reference: Option<Vec<f64>>,
) -> Result<Vec<Option<f64>>> {
    let data = PowerData::new(vec![0.0], vec![rows.clone()], n_trials, folds, reference);
    let fit = data.fit_all(&[], 0)?;
    let mut sum = vec![0.0; n_trials];
    let mut cnt = vec![0usize; n_trials];
    for r in 0..rows.len() {
        let p: f64 = rows.x[r]
            .iter()
            .zip(fit.beta.iter())
            .map(|(a, b)| a * b)
            .sum();
        sum[rows.trial[r]] += rows.y[r] - p;
        cnt[rows.trial[r]] += 1;
    }
    Ok((0..n_trials)
        .map(|t| (cnt[t] > 0).then(|| sum[t] / cnt[t] as f64))
        .collect())
}

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
    let reference: Option<Vec<f64>> = opts.reference.map(|m| m.to_vector().to_vec());
    let (metas, rejected) = filter_trials(rec, windows, opts, reference.clone())?;
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

/// Power rows of the usable trials at every scanned sensor lag (ascending; index 0 = no lag),
/// restricted to the readings present at all lags (same readings everywhere).
struct LagRows {
    lags: Vec<f64>,
    rows: Vec<Rows>,
}

/// Stage: rows at every coarse lag (0.05 s steps up to [`DiagnoseOptions::max_lag_s`]), then a
/// fine scan (0.01 s) around the base model's best coarse lag.
fn scan_lags(
    rec: &Recording,
    power: &crate::signals::PowerSeries,
    metas: &[TrialMeta],
    opts: &DiagnoseOptions,
    reference: Option<Vec<f64>>,
) -> Result<LagRows> {
    let w = opts.sensor_window_s;
    // Rows at every scanned lag; keep only readings present at all lags (same readings everywhere).
    let mut lags = vec![0.0];
    if opts.max_lag_s > 0.0 {
        let coarse = (opts.max_lag_s / 0.05).round() as usize;
        lags.extend((1..=coarse).map(|k| k as f64 * 0.05));
    }
    let mut all_rows: Vec<Rows> = lags
        .iter()
        .map(|&l| build_rows(rec, power, metas, l, w, l == 0.0))
        .collect();
    // Fine scan (0.01 s) around the base model's best coarse lag.
    if lags.len() >= 3 {
        // The rows move into the scan and back out of it: at paper scale one copy of all lags'
        // rows is ~100 MB.
        let data = PowerData::new(
            lags.clone(),
            std::mem::take(&mut all_rows),
            metas.len(),
            opts.folds,
            reference,
        );
        let sse: Vec<f64> = (0..lags.len())
            .map(|l| {
                data.fit_all(&[], l)
                    .map(|f| data.grams[l].total.sse(&f.beta))
            })
            .collect::<Result<_>>()?;
        let best = (0..lags.len())
            .min_by(|&a, &b| sse[a].total_cmp(&sse[b]))
            .unwrap_or(0);
        all_rows = data.rows;
        let centre = lags[best];
        for k in -4i32..=4 {
            let l = centre + 0.01 * k as f64;
            if l > 0.0 && l <= opts.max_lag_s && lags.iter().all(|x| (x - l).abs() > 1e-6) {
                lags.push(l);
                all_rows.push(build_rows(rec, power, metas, l, w, false));
            }
        }
        let mut by_lag: Vec<(f64, Rows)> = lags.into_iter().zip(all_rows).collect();
        by_lag.sort_by(|a, b| a.0.total_cmp(&b.0));
        (lags, all_rows) = by_lag.into_iter().unzip();
    }
    common_readings(&mut all_rows);
    Ok(LagRows {
        lags,
        rows: all_rows,
    })
}

/// Every hypothesis scored against the base model, ranked, and the accepted ones in order.
struct Ranking {
    ranked: Vec<HypothesisScore>,
    accepted: Vec<HypothesisScore>,
}

/// Stage: the torque level's payload hypothesis judged by the power level's rule, then every
/// hypothesis ranked (accepted first, then by held-out improvement).
fn rank_hypotheses(
    sel: &select::Selection,
    torque: Option<&torque::TorqueLevel>,
    rule: &Rule,
) -> Ranking {
    let mut ranked = sel.first_step.clone();
    let mut accepted = sel.accepted.clone();
    if let Some(t) = torque {
        let mut p = t.payload.clone();
        let (ok, why) = rule.judge(&p);
        p.accepted = ok;
        p.verdict = why;
        if ok {
            accepted.push(p.clone());
        }
        ranked.push(p);
    }
    ranked.sort_by(|a, b| {
        (b.accepted, b.rel_improvement)
            .partial_cmp(&(a.accepted, a.rel_improvement))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    for (i, s) in ranked.iter_mut().enumerate() {
        s.rank = i + 1;
    }
    Ranking { ranked, accepted }
}

/// Stage: the final model — the physical parameters of the accepted hypotheses (jackknife
/// standard errors over the folds) and the held-out quality before and after them, per reading
/// and per trial (`rows0`: the rows at no lag).
fn refit_final(
    sel: &select::Selection,
    accepted: &[HypothesisScore],
    torque: Option<&torque::TorqueLevel>,
    rows0: &Rows,
    n_trials: usize,
) -> FinalModel {
    let last = &sel.last;
    let mut params = Vec::new();
    for (j, h) in last.spec.iter().enumerate() {
        let c = N_PARAMS + j;
        let per_fold: Vec<f64> = last
            .cv
            .fold_theta
            .iter()
            .map(|t| (h.to_physical)(t[c]))
            .collect();
        params.push(Param {
            name: h.title.into(),
            symbol: h.symbol.into(),
            value: (h.to_physical)(last.full.theta[c]),
            std_err: select::jackknife_se(&per_fold),
            unit: h.unit.into(),
        });
    }
    if let Some(lat) = accepted.iter().find(|s| s.id == LATENCY_ID) {
        params.extend(lat.params.iter().cloned());
    }
    if let Some(t) = torque.filter(|t| accepted.iter().any(|s| s.id == t.payload.id)) {
        params.extend(t.payload.params.iter().cloned());
    }
    let y = &rows0.y;
    let quality = |pred: &[f64]| {
        let (r2, rmse_w) = r2_rmse(y, pred);
        Quality { r2, rmse_w }
    };
    let per_trial = |pred: &[f64]| {
        let n = n_trials;
        let (mut ys, mut ps, mut c) = (vec![0.0; n], vec![0.0; n], vec![0usize; n]);
        for r in 0..y.len() {
            let t = rows0.trial[r];
            ys[t] += y[r];
            ps[t] += pred[r];
            c[t] += 1;
        }
        let keep: Vec<usize> = (0..n).filter(|&t| c[t] > 0).collect();
        let yt: Vec<f64> = keep.iter().map(|&t| ys[t] / c[t] as f64).collect();
        let pt: Vec<f64> = keep.iter().map(|&t| ps[t] / c[t] as f64).collect();
        let (r2, rmse_w) = r2_rmse(&yt, &pt);
        Quality { r2, rmse_w }
    };
    FinalModel {
        hypotheses: accepted.iter().map(|s| s.id.clone()).collect(),
        params,
        theta: last.full.theta[..N_PARAMS].to_vec(),
        before: quality(&sel.base.cv.pred),
        after: quality(&last.cv.pred),
        before_per_trial: per_trial(&sel.base.cv.pred),
        after_per_trial: per_trial(&last.cv.pred),
    }
}

/// Where the base model's held-out residuals lie, and the structure the final model leaves.
struct Located {
    breakdowns: Vec<Breakdown>,
    worst: Option<(String, Group)>,
    worst_trials: Vec<TrialResidual>,
    unexplained: Vec<Correlate>,
}

/// Stage: locate with the base model's held-out residuals; correlate what the final model
/// leaves (with the terms found beyond the library when there are any).
fn locate_residuals(
    rec: &Recording,
    metas: &[TrialMeta],
    data: &PowerData,
    sel: &select::Selection,
    discovery: Option<&DiscoveryReport>,
) -> Located {
    let last = &sel.last;
    let rows0 = &data.rows[0];
    let resid_base: Vec<f64> = rows0
        .y
        .iter()
        .zip(&sel.base.cv.pred)
        .map(|(a, b)| a - b)
        .collect();
    // What the final model leaves: with the terms found beyond the library when there are any.
    let final_pred = match discovery {
        Some(r) if !r.accepted.is_empty() && r.pred.len() == last.cv.pred.len() => &r.pred,
        _ => &last.cv.pred,
    };
    let resid_final: Vec<f64> = data.rows[last.lag]
        .y
        .iter()
        .zip(final_pred)
        .map(|(a, b)| a - b)
        .collect();
    let breakdowns = locate::breakdowns(rows0, metas, &resid_base, &rec.joint_names);
    let worst = locate::worst(&breakdowns);
    let worst_trials: Vec<TrialResidual> = locate::trial_residuals(rows0, metas, &resid_base)
        .into_iter()
        .take(10)
        .collect();
    let unexplained = locate::correlates(
        rows0,
        metas,
        &resid_final,
        &rec.joint_names,
        data.reference.is_none(),
        0.01,
        6,
    );
    Located {
        breakdowns,
        worst,
        worst_trials,
        unexplained,
    }
}

/// Stage: the base model's in-sample RMSE refitted at every scanned lag.
fn lag_scan(data: &PowerData) -> Result<Vec<LagPoint>> {
    (0..data.lags.len())
        .map(|l| {
            let g = &data.grams[l].total;
            data.fit_all(&[], l).map(|f| LagPoint {
                lag_s: data.lags[l],
                rmse_w: (g.sse(&f.beta) / g.n.max(1) as f64).sqrt(),
            })
        })
        .collect()
}

/// Stage: per-reading data for the replay, with the trials to point the user to (largest
/// held-out base residuals, carriers of unexplained structure).
fn replay_data(
    metas: &[TrialMeta],
    rows0: &Rows,
    sel: &select::Selection,
    located: &Located,
) -> ReplayData {
    let mark = |trial: usize, reason: String| {
        let w = metas
            .iter()
            .find(|m| m.window.index == trial)
            .map(|m| &m.window);
        HighlightedTrial {
            trial,
            t_start: w.map_or(0.0, |w| w.t_traj_start),
            t_end: w.map_or(0.0, |w| w.t_return_end),
            reason,
        }
    };
    let mut highlighted: Vec<HighlightedTrial> = located
        .worst_trials
        .iter()
        .take(5)
        .map(|t| {
            mark(
                t.trial,
                format!(
                    "largest held-out residual of the base model: {:+.2} W",
                    t.mean_w
                ),
            )
        })
        .collect();
    for c in located.unexplained.iter().filter(|c| c.significant) {
        for &t in &c.trials {
            if !highlighted.iter().any(|h| h.trial == t) {
                highlighted.push(mark(
                    t,
                    format!("carries unexplained structure ({})", c.feature),
                ));
            }
        }
    }
    ReplayData {
        t: rows0.t.clone(),
        trial: rows0.trial.iter().map(|&t| metas[t].window.index).collect(),
        measured_w: rows0.y.clone(),
        before_w: sel.base.cv.pred.clone(),
        after_w: sel.last.cv.pred.clone(),
        highlighted,
        found_w: Vec::new(),
        located: Vec::new(),
    }
}

/// The bus-current form was fitted at the nominal voltage: R = c·V_nom² / ... rescaled to the
/// recorded mean supply voltage V̄ (R ∝ V̄², since the feature is (P/V_nom)²).
fn rescale_bus(d: &mut Diagnosis, volts: f64) {
    let k = (volts / hypotheses::NOMINAL_BUS_VOLTS).powi(2);
    let title = hypotheses::power_hypothesis("bus_power").map_or("", |h| h.title);
    let scale = |p: &mut Param| {
        p.value *= k;
        p.std_err *= k;
    };
    for s in d.hypotheses.iter_mut().chain(d.accepted.iter_mut()) {
        if s.id == "bus_power" {
            s.params.iter_mut().for_each(scale);
        }
    }
    d.final_model
        .params
        .iter_mut()
        .filter(|p| p.name == title)
        .for_each(scale);
    d.bus_volts = volts;
}

/// Stage: library selection, then discovery beyond it; a library term that is not significant
/// given what discovery found is confounded with it: it is dropped, reported, and the library
/// selection re-run without it.
fn select_and_discover(
    rec: &Recording,
    power: &crate::signals::PowerSeries,
    metas: &[TrialMeta],
    data: &PowerData,
    rule: &Rule,
    opts: &DiagnoseOptions,
) -> Result<(select::Selection, Option<DiscoveryReport>, RowFields)> {
    let mut excluded: Vec<&str> = Vec::new();
    let mut confounded = Vec::new();
    let mut fields: Option<(usize, RowFields)> = None;
    loop {
        let candidates: Vec<&'static hypotheses::Hypothesis> = POWER_HYPOTHESES
            .iter()
            .filter(|h| !excluded.contains(&h.id))
            .collect();
        let mut sel = select::select(data, &candidates, rule)?;
        let lag = sel.last.lag;
        if fields.as_ref().is_none_or(|(l, _)| *l != lag) {
            let f = run_fields(rec, power, metas, &data.rows[lag], data.lags[lag], opts);
            fields = Some((lag, f));
        }
        let Some((_, f)) = &fields else {
            unreachable!("fields were just read")
        };
        if !opts.discover {
            return Ok((sel, None, fields.map(|f| f.1).unwrap_or_default()));
        }
        let report = discover::discover(
            data,
            &sel.last,
            &field_inputs(f, opts),
            rule,
            &rec.joint_names,
        )?;
        let dropped = library_given_found(data, &sel.last, &report, rule)?;
        if dropped.is_empty() {
            sel.confounded.extend(confounded);
            sel.accepted.retain(|a| !excluded.contains(&a.id.as_str()));
            let f = fields.map(|f| f.1).unwrap_or_default();
            return Ok((sel, Some(report), f));
        }
        for c in dropped {
            if let Some(h) = hypotheses::power_hypothesis(&c.dropped) {
                excluded.push(h.id);
            }
            confounded.push(c);
        }
    }
}

/// Library terms of `cur` that are not significant given the found terms (all at once).
fn library_given_found(
    data: &PowerData,
    cur: &select::State,
    report: &DiscoveryReport,
    rule: &Rule,
) -> Result<Vec<Confounded>> {
    let mut out = Vec::new();
    if report.cols.is_empty() {
        return Ok(out);
    }
    let found: Vec<&str> = report.accepted.iter().map(|t| t.name.as_str()).collect();
    let rows = &data.rows[cur.lag];
    for (j, h) in cur.spec.iter().enumerate() {
        let mut spec = cur.spec.clone();
        spec.remove(j);
        let without = select::state(data, spec, cur.lag)?;
        let (p, rel, d_bic) =
            discover::library_term_given_found(data, cur, &without, &report.cols)?;
        if p < rule.alpha && d_bic < rule.bic_threshold && rel >= rule.min_improvement {
            continue;
        }
        let mine: Vec<f64> = rows
            .x
            .iter()
            .map(|x| select::regressor(h, x, &cur.full.theta))
            .collect();
        out.push(Confounded {
            kept: found.join("; "),
            dropped: h.id.into(),
            correlation: select::correlation(&mine, &report.cols[0]),
            p_value: p,
            rel_change: rel,
        });
    }
    Ok(out)
}

/// Stage: what the replay shows of the found terms: their fields beside the residual, the
/// prediction with them, and the trials they improve most.
fn show_found(d: &mut Diagnosis, f: &RowFields, rows: &Rows, metas: &[TrialMeta]) {
    let Some(r) = &d.discovery else {
        return;
    };
    if r.accepted.is_empty() || r.pred.len() != rows.len() {
        return;
    }
    for t in &r.accepted {
        for name in &t.fields {
            if let Some(k) = f.table.names.iter().position(|n| n == name) {
                let vals = &f.table.values[k];
                d.replay.located.push(LocatedField {
                    name: name.clone(),
                    values: f.row_window.iter().map(|&w| vals[w]).collect(),
                });
            }
        }
    }
    d.replay.found_w = r.pred.clone();
    let n = metas.len();
    let before = select::trial_sse(&rows.y, &d.replay.after_w, &rows.trial, n);
    let after = select::trial_sse(&rows.y, &r.pred, &rows.trial, n);
    let mut gain: Vec<(usize, f64)> = (0..n).map(|t| (t, before[t] - after[t])).collect();
    gain.sort_by(|a, b| b.1.total_cmp(&a.1));
    let names: Vec<&str> = r.accepted.iter().map(|t| t.name.as_str()).collect();
    for &(t, g) in gain.iter().take(5).filter(|(_, g)| *g > 0.0) {
        let w = &metas[t].window;
        if d.replay.highlighted.iter().any(|h| h.trial == w.index) {
            continue;
        }
        d.replay.highlighted.push(HighlightedTrial {
            trial: w.index,
            t_start: w.t_traj_start,
            t_end: w.t_return_end,
            reason: format!(
                "carries what was found beyond the library ({}): held-out squared error −{g:.2} W²",
                names.join("; ")
            ),
        });
    }
}

/// The recorded fields over the final rows' windows and every trial's baseline windows.
#[derive(Default)]
struct RowFields {
    table: fields::FieldTable,
    /// Index into the table's windows of each row.
    row_window: Vec<usize>,
    /// Per trial (position in the trial list): indices of its baseline windows.
    base_windows: Vec<Vec<usize>>,
}

/// Stage: read every numeric field of the recording's files over the rows' windows.
fn run_fields(
    rec: &Recording,
    power: &crate::signals::PowerSeries,
    metas: &[TrialMeta],
    rows: &Rows,
    lag: f64,
    opts: &DiagnoseOptions,
) -> RowFields {
    let w = opts.sensor_window_s;
    let window = |t: f64| fields::Window {
        start: t - lag - w,
        end: t - lag,
    };
    // (window, tag): tag < rows.len() = row, otherwise baseline of trial tag − rows.len().
    let mut all: Vec<(fields::Window, usize)> = rows
        .t
        .iter()
        .enumerate()
        .map(|(r, &t)| (window(t), r))
        .collect();
    for (ti, m) in metas.iter().enumerate() {
        let lo = power.t.partition_point(|&x| x < m.window.t_pre_start + w);
        let hi = power
            .t
            .partition_point(|&x| x < m.window.t_traj_start + 1e-9);
        for k in lo..hi.max(lo) {
            if power.watts.get(k).is_some_and(|v| v.is_finite()) {
                all.push((window(power.t[k]), rows.len() + ti));
            }
        }
    }
    all.sort_by(|a, b| a.0.start.total_cmp(&b.0.start));
    let mut row_window = vec![0; rows.len()];
    let mut base_windows = vec![Vec::new(); metas.len()];
    for (i, (_, tag)) in all.iter().enumerate() {
        if *tag < rows.len() {
            row_window[*tag] = i;
        } else {
            base_windows[tag - rows.len()].push(i);
        }
    }
    let windows: Vec<fields::Window> = all.iter().map(|a| a.0).collect();
    let sources: Vec<FieldSource> = if opts.field_sources.is_empty() {
        if rec.source.exists() {
            vec![FieldSource {
                path: rec.source.clone(),
                start_ns: rec.start_ns,
                offset_s: 0.0,
            }]
        } else {
            Vec::new()
        }
    } else {
        opts.field_sources.clone()
    };
    let table = if opts.discover && !sources.is_empty() {
        fields::read_fields(&sources, &windows)
    } else {
        fields::FieldTable::default()
    };
    RowFields {
        table,
        row_window,
        base_windows,
    }
}

/// Stage: discovery inputs (the field table and where the rows' and baselines' windows are).
fn field_inputs<'a>(f: &'a RowFields, opts: &DiagnoseOptions) -> discover::Inputs<'a> {
    discover::Inputs {
        fields: &f.table,
        row_window: &f.row_window,
        base_windows: &f.base_windows,
        arm_motors: opts.arm_motors,
    }
}

/// Keep, at every lag, only the readings present at all lags (a gap can drop a window at one lag).
fn common_readings(all: &mut [Rows]) {
    use std::collections::HashMap;
    let mut count: HashMap<u64, usize> = HashMap::new();
    for rows in all.iter() {
        for t in &rows.t {
            *count.entry(t.to_bits()).or_default() += 1;
        }
    }
    let n = all.len();
    for rows in all.iter_mut() {
        let keep: Vec<bool> = rows
            .t
            .iter()
            .map(|t| count.get(&t.to_bits()) == Some(&n))
            .collect();
        if keep.iter().all(|k| *k) {
            continue;
        }
        let mut i = 0;
        let mut filt = Rows::default();
        for (r, k) in keep.iter().enumerate() {
            if *k {
                filt.trial.push(rows.trial[r]);
                filt.t.push(rows.t[r]);
                filt.phase.push(rows.phase[r]);
                filt.y.push(rows.y[r]);
                filt.x.push(rows.x[r]);
                if let Some(l) = rows.locate.get(r) {
                    filt.locate.push(*l);
                }
                i += 1;
            }
        }
        debug_assert_eq!(i, filt.len());
        *rows = filt;
    }
}

#[cfg(test)]
mod tests {
    use super::testkit::{Effects, session};
    use super::*;

    fn run(fx: Effects, seed: u64) -> Diagnosis {
        run_with(fx, seed, &DiagnoseOptions::default())
    }

    fn run_with(fx: Effects, seed: u64, opts: &DiagnoseOptions) -> Diagnosis {
        let (rec, windows) = session(60, seed, fx);
        let d = diagnose_trials(&rec, &windows, None, opts).unwrap();
        eprintln!("{}", d.summary);
        for h in &d.hypotheses {
            eprintln!(
                "  {:>14} {:>10.4} p={:.1e} dBIC={:7.1} rel={:+.3} {}",
                h.id, h.params[0].value, h.p_value, h.delta_bic, h.rel_improvement, h.verdict
            );
        }
        d
    }

    #[test]
    fn null_session_accepts_nothing() {
        let d = run(Effects::default(), 1);
        assert!(d.accepted.is_empty());
        assert!(d.unexplained.iter().all(|c| !c.significant));
    }

    #[test]
    fn braking_session_names_braking() {
        let d = run(
            Effects {
                braking_r: Some(0.4),
                ..Default::default()
            },
            2,
        );
        assert_eq!(d.hypotheses[0].id, "braking");
        let r = d
            .final_model
            .params
            .iter()
            .find(|p| p.symbol == "r")
            .unwrap()
            .value;
        assert!((r - 0.4).abs() < 0.04, "r = {r}");
        assert!(d.final_model.after.r2 > d.final_model.before.r2);
        let dir = std::env::var("DIAG_REPORT_DIR")
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|_| {
                std::env::temp_dir().join(format!("g1viz-diag-{}", std::process::id()))
            });
        report::write_report(&dir, &d).unwrap();
        let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
        assert!(md.contains("| 1 | braking |"));
        for f in report::FIGURES.iter().take(4) {
            assert!(dir.join(f).metadata().unwrap().len() > 1000, "{f}");
        }
        let back: Diagnosis =
            serde_json::from_str(&std::fs::read_to_string(dir.join("diagnosis.json")).unwrap())
                .unwrap();
        assert_eq!(back.accepted.len(), d.accepted.len());
    }

    #[test]
    fn latency_session_finds_the_lag() {
        let d = run(
            Effects {
                latency_s: Some(0.3),
                ..Default::default()
            },
            3,
        );
        assert_eq!(d.hypotheses[0].id, "latency");
        let l = d
            .final_model
            .params
            .iter()
            .find(|p| p.symbol == "L")
            .unwrap()
            .value;
        assert!((l - 0.3).abs() < 0.03, "L = {l}");
    }

    #[test]
    fn harness_drag_is_located_at_the_elbow() {
        let d = run(
            Effects {
                harness_k: Some(4.0),
                ..Default::default()
            },
            4,
        );
        let top = &d.unexplained[0];
        assert!(top.significant && top.feature.starts_with("j3"), "{top:?}");
    }
}

#[cfg(test)]
mod twin_tests {
    use super::testkit::{Effects, session};
    use super::*;

    fn twin() -> DiagnoseOptions {
        DiagnoseOptions {
            reference: Some(PowerModel::PAPER),
            ..Default::default()
        }
    }

    #[test]
    fn twin_mode_recovers_thermal_drift_and_accepts_nothing_on_null() {
        let (rec, w) = session(
            60,
            5,
            Effects {
                thermal_alpha: Some(0.00393),
                ..Default::default()
            },
        );
        let d = diagnose_trials(&rec, &w, None, &twin()).unwrap();
        eprintln!("{}", d.summary);
        for h in &d.hypotheses {
            eprintln!(
                "  {:>14} {:>10.5} ± {:.5} p={:.1e} dBIC={:7.1} rel={:+.3}",
                h.id,
                h.params[0].value,
                h.params[0].std_err,
                h.p_value,
                h.delta_bic,
                h.rel_improvement
            );
        }
        assert_eq!(d.hypotheses[0].id, "thermal");
        let a = d
            .final_model
            .params
            .iter()
            .find(|p| p.symbol == "α")
            .unwrap()
            .value;
        assert!((a - 0.00393).abs() < 0.1 * 0.00393, "α = {a}");
        let (rec, w) = session(60, 6, Effects::default());
        let d = diagnose_trials(&rec, &w, None, &twin()).unwrap();
        eprintln!("{}", d.summary);
        assert!(d.accepted.is_empty());
    }
}

#[cfg(test)]
mod torque_tests {
    use super::testkit::{Effects, session};
    use super::*;
    use crate::robot::Payload;

    /// Replace the miniature session's torques by the shipped URDF's inverse dynamics (with an
    /// optional payload) plus joint friction and noise.
    fn with_urdf_torques(rec: &mut Recording, payload: Option<Payload>) -> ArmDynamics {
        let model = RobotModel::builtin();
        let joints = model.g1_left_arm().unwrap();
        let urdf = ArmDynamics::new(&model, &joints).unwrap();
        let plant = payload.map_or_else(|| urdf.clone(), |p| urdf.with_payload(&p));
        let s = &mut rec.state;
        let n = s.t.len();
        for k in 0..n {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
            let ddq: [f64; 7] =
                std::array::from_fn(|j| (s.dq[b][j] - s.dq[a][j]) / (s.t[b] - s.t[a]).max(1e-9));
            let tau = plant.inverse_dynamics(&s.q[k], &s.dq[k], &ddq);
            let noise = ((k * 7919) % 1000) as f64 / 1000.0 - 0.5;
            s.tau[k] = std::array::from_fn(|j| {
                tau[j] + 0.3 * (s.dq[k][j] / 0.01).tanh() + 0.1 * s.dq[k][j] + 0.05 * noise
            });
        }
        urdf
    }

    #[test]
    fn payload_is_recovered_at_the_torque_level_and_absent_when_there_is_none() {
        let (mut rec, w) = session(40, 8, Effects::default());
        let urdf = with_urdf_torques(
            &mut rec,
            Some(Payload {
                mass_kg: 0.5,
                com_m: [0.1, 0.0, 0.0],
            }),
        );
        let d = diagnose_trials(&rec, &w, Some(&urdf), &DiagnoseOptions::default()).unwrap();
        eprintln!("{}", d.summary);
        let p = d.hypotheses.iter().find(|h| h.id == "payload").unwrap();
        assert!(p.accepted && p.rank == 1, "{p:?}");
        assert!(
            (p.params[0].value - 0.5).abs() < 0.05,
            "m = {}",
            p.params[0].value
        );
        assert!(
            (p.params[1].value - 0.1).abs() < 0.01,
            "cx = {}",
            p.params[1].value
        );

        let (mut rec, w) = session(40, 9, Effects::default());
        let urdf = with_urdf_torques(&mut rec, None);
        let d = diagnose_trials(&rec, &w, Some(&urdf), &DiagnoseOptions::default()).unwrap();
        let p = d.hypotheses.iter().find(|h| h.id == "payload").unwrap();
        assert!(!p.accepted, "{p:?}");
    }
}
