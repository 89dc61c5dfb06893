//! Scoring and greedy selection of hypotheses with validation that adding parameters cannot game:
//! k-fold cross-validation by TRIAL (all readings of a trial are held out together), a one-sided
//! paired test (t and signed-rank) of the per-trial held-out squared error (base vs base + hypothesis), the
//! Bayesian information criterion on the full data, and a physical-plausibility check.
//!
//! All fits of all subsets of hypotheses come from one Gram matrix per fold (the extra regressors
//! are linear maps of the pre-computed raw features), so scoring the whole library is cheap.

use anyhow::Result;
use nalgebra::{DMatrix, DVector};
use rand::SeedableRng;
use rand::seq::SliceRandom;

use super::Quality;
use super::hypotheses::{Combine, Hypothesis, LATENCY_ID, N_RAW};
use super::reading_rows::Rows;
use super::stats::improvement_p_value;
use crate::lsq::{Gram, Metrics, bounded_quadratic};
use crate::power::PowerModel;
use crate::{N_JOINTS, N_PARAMS};

/// Assignment of trials to cross-validation folds (shuffled with a fixed seed: reproducible).
#[derive(Debug, Clone)]
pub(crate) struct Folds {
    pub of_trial: Vec<usize>,
    pub k: usize,
}

impl Folds {
    pub fn new(n_trials: usize, k: usize, seed: u64) -> Folds {
        let k = k.clamp(2, n_trials.max(2));
        let mut order: Vec<usize> = (0..n_trials).collect();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        order.shuffle(&mut rng);
        let mut of_trial = vec![0; n_trials];
        for (pos, &t) in order.iter().enumerate() {
            of_trial[t] = pos % k;
        }
        Folds { of_trial, k }
    }
}

/// Per-fold and total Gram matrices of one set of rows.
#[derive(Debug, Clone)]
pub(crate) struct FoldGrams {
    pub total: Gram,
    pub fold: Vec<Gram>,
}

impl FoldGrams {
    pub fn new(rows: &Rows, folds: &Folds) -> FoldGrams {
        let mut b = FoldGramsBuilder::new(folds.k);
        b.add_rows(rows, folds);
        b.finish()
    }

    fn train(&self, f: usize) -> Gram {
        self.total.minus(&self.fold[f])
    }
}

/// [`FoldGrams`] accumulated from rows given piece by piece (a trial at a time): the same sums,
/// in the same order, as [`FoldGrams::new`] on all the rows at once.
pub(crate) struct FoldGramsBuilder {
    fold: Vec<Gram>,
}

impl FoldGramsBuilder {
    pub fn new(k: usize) -> FoldGramsBuilder {
        FoldGramsBuilder {
            fold: (0..k).map(|_| Gram::zeros(N_RAW)).collect(),
        }
    }

    /// Add `rows` (their `trial` indexes `folds`).
    pub fn add_rows(&mut self, rows: &Rows, folds: &Folds) {
        for r in 0..rows.len() {
            self.fold[folds.of_trial[rows.trial[r]]].add_row(&rows.x[r], rows.y[r]);
        }
    }

    pub fn finish(self) -> FoldGrams {
        let mut total = Gram::zeros(N_RAW);
        for f in &self.fold {
            total.add(f);
        }
        FoldGrams {
            total,
            fold: self.fold,
        }
    }
}

/// A model: the base regressors plus these hypotheses' regressors.
pub(crate) type Spec = Vec<&'static Hypothesis>;

/// A fitted model: coefficients θ (base 49, then one per hypothesis) and the equivalent
/// coefficients on the raw layout (for predictions).
#[derive(Debug, Clone)]
pub(crate) struct Fitted {
    pub theta: Vec<f64>,
    pub beta: DVector<f64>,
}

/// Raw layout → model coefficients map for `spec`, weights of pooled terms from `theta`.
fn design_map(spec: &[&Hypothesis], theta: &[f64]) -> DMatrix<f64> {
    let p = N_PARAMS + spec.len();
    let mut m = DMatrix::zeros(N_RAW, p);
    for i in 0..N_PARAMS {
        m[(i, i)] = 1.0;
    }
    for (j, h) in spec.iter().enumerate() {
        let (off, len) = h.raw;
        for i in 0..len {
            let w = match h.combine {
                Combine::Single => 1.0,
                Combine::WeightedByBase(base) => theta.get(base + i).copied().unwrap_or(1.0),
            };
            m[(N_PARAMS + off + i, N_PARAMS + j)] = w;
        }
    }
    m
}

/// Bounds of the base model: the paper's constraints (a ≥ 1, all other base parameters ≥ 0), or
/// lo = hi = the reference θ when the base is held at a reference (twin) model. Hypothesis
/// coefficients are free (their physical plausibility is judged after the fit, so a wrong-signed
/// fit is visible).
fn bounds(p: usize, reference: Option<&[f64]>) -> (Vec<f64>, Vec<f64>) {
    let mut lo = vec![f64::NEG_INFINITY; p];
    let mut hi = vec![f64::INFINITY; p];
    for i in 0..N_PARAMS {
        match reference {
            Some(r) => {
                lo[i] = r[i];
                hi[i] = r[i];
            }
            None => lo[i] = if i < N_JOINTS { 1.0 } else { 0.0 },
        }
    }
    (lo, hi)
}

/// Weight [W²] of a weak Gaussian prior on every base parameter, θ_j ~ N(θ_paper,j, 1) in the
/// paper's units (all its parameters are O(1)), relative to a reading noise of (0.5 W)². The
/// protocol makes some base regressors nearly collinear or barely excited (joints moving together
/// share one velocity profile; a pair of joints may move together in only one trial of a short
/// session, and sensor noise alone makes |q̇_i||q̇_j| slightly non-zero), so the training trials of
/// a fold can leave a direction free: without the prior it takes any value (e₄₅ = 60 was seen)
/// and wrecks the held-out prediction; with it the direction falls back to the published value.
/// A well-excited parameter's data curvature is hundreds of times larger, so it is unaffected.
/// Hypothesis coefficients have no prior.
const BASE_PRIOR_WEIGHT: f64 = 0.25;

/// Bounded least squares on normal equations: minimise θᵀGθ − 2θᵀh subject to lo ≤ θ ≤ hi,
/// with the weak Gaussian prior (mean `prior`) on the first [`N_PARAMS`] (base) coefficients. Solved in Gram space
/// by [`super::qp`] (thousands of small fits per diagnosis; checked against the
/// identification's row-space BVLS in the tests).
fn solve_bounded(
    g: &DMatrix<f64>,
    h: &DVector<f64>,
    lo: &[f64],
    hi: &[f64],
    prior: &[f64; N_PARAMS],
) -> Result<DVector<f64>> {
    let p = h.len();
    let mut g = g.clone();
    let mut h = h.clone();
    for i in 0..N_PARAMS.min(p) {
        g[(i, i)] += BASE_PRIOR_WEIGHT;
        h[i] += BASE_PRIOR_WEIGHT * prior[i];
    }
    let s: Vec<f64> = (0..p)
        .map(|i| {
            if g[(i, i)] > 0.0 {
                g[(i, i)].sqrt()
            } else {
                1.0
            }
        })
        .collect();
    let mut gs = DMatrix::from_fn(p, p, |i, j| g[(i, j)] / (s[i] * s[j]));
    for i in 0..p {
        gs[(i, i)] += 1e-12;
    }
    let hs = DVector::from_fn(p, |i, _| h[i] / s[i]);
    let los: Vec<f64> = lo.iter().zip(&s).map(|(l, si)| l * si).collect();
    let his: Vec<f64> = hi.iter().zip(&s).map(|(u, si)| u * si).collect();
    let z = bounded_quadratic(&gs, &hs, &los, &his)?;
    Ok(DVector::from_fn(p, |i, _| z[i] / s[i]))
}

/// [`design_map`] for discovery: the library model's columns on the raw layout.
pub(crate) fn design_map_for(spec: &[&Hypothesis], theta: &[f64]) -> DMatrix<f64> {
    design_map(spec, theta)
}

/// [`bounds`] for `p` coefficients (base first, the rest free).
pub(crate) fn bounds_for(p: usize, reference: Option<&[f64]>) -> (Vec<f64>, Vec<f64>) {
    bounds(p, reference)
}

/// [`solve_bounded`] with the paper's θ as the prior mean.
pub(crate) fn solve_bounded_for(
    g: &DMatrix<f64>,
    h: &DVector<f64>,
    lo: &[f64],
    hi: &[f64],
) -> Result<DVector<f64>> {
    solve_bounded(g, h, lo, hi, &PowerModel::PAPER.to_vector())
}

fn fit_once(
    spec: &[&Hypothesis],
    gram: &Gram,
    weights: &[f64],
    reference: Option<&[f64]>,
) -> Result<Fitted> {
    let m = design_map(spec, weights);
    let g = m.transpose() * &gram.g * &m;
    let h = m.transpose() * &gram.h;
    let (lo, hi) = bounds(m.ncols(), reference);
    let theta = solve_bounded(&g, &h, &lo, &hi, &PowerModel::PAPER.to_vector())?;
    let beta = &m * &theta;
    Ok(Fitted {
        theta: theta.iter().copied().collect(),
        beta,
    })
}

/// Fit `spec` to the rows summarised by `gram` (base refitted, or held at `reference`). Pooled
/// per-joint terms are refitted until their weights (the base parameters they scale) are
/// self-consistent.
pub(crate) fn fit(
    spec: &[&'static Hypothesis],
    gram: &Gram,
    reference: Option<&[f64]>,
) -> Result<Fitted> {
    let pooled = spec
        .iter()
        .any(|h| matches!(h.combine, Combine::WeightedByBase(_)));
    if !pooled {
        return fit_once(spec, gram, &[], reference);
    }
    let plain: Vec<&Hypothesis> = spec
        .iter()
        .copied()
        .filter(|h| h.combine == Combine::Single)
        .collect();
    let mut weights = fit_once(&plain, gram, &[], reference)?.theta;
    let mut fitted = fit_once(spec, gram, &weights, reference)?;
    for _ in 0..8 {
        let change = fitted.theta[..N_PARAMS]
            .iter()
            .zip(&weights[..N_PARAMS])
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        if change < 1e-9 {
            break;
        }
        weights = fitted.theta.clone();
        fitted = fit_once(spec, gram, &weights, reference)?;
    }
    Ok(fitted)
}

/// Held-out predictions of every row and the per-fold coefficient vectors.
#[derive(Debug, Clone)]
pub(crate) struct CvOut {
    pub pred: Vec<f64>,
    pub fold_theta: Vec<Vec<f64>>,
}

/// K-fold cross-validation by trial of `spec` on `rows`.
pub(crate) fn cross_validate(
    spec: &[&'static Hypothesis],
    rows: &Rows,
    folds: &Folds,
    fg: &FoldGrams,
    reference: Option<&[f64]>,
) -> Result<CvOut> {
    let mut fitted = Vec::with_capacity(folds.k);
    for f in 0..folds.k {
        fitted.push(fit(spec, &fg.train(f), reference)?);
    }
    let pred = (0..rows.len())
        .map(|r| {
            let beta = &fitted[folds.of_trial[rows.trial[r]]].beta;
            rows.x[r].iter().zip(beta.iter()).map(|(a, b)| a * b).sum()
        })
        .collect();
    Ok(CvOut {
        pred,
        fold_theta: fitted.into_iter().map(|f| f.theta).collect(),
    })
}

/// Per-trial sum of squared errors.
pub(crate) fn trial_sse(y: &[f64], pred: &[f64], trial: &[usize], n_trials: usize) -> Vec<f64> {
    let mut out = vec![0.0; n_trials];
    for ((yv, pv), &t) in y.iter().zip(pred).zip(trial) {
        out[t] += (yv - pv).powi(2);
    }
    out
}

/// R² and RMSE of predictions (the identification's metrics).
pub(crate) fn r2_rmse(y: &[f64], pred: &[f64]) -> (f64, f64) {
    let m = Metrics::compute(y, pred);
    (m.r2, m.rmse)
}

/// Bayesian information criterion of a Gaussian least-squares fit.
pub(crate) fn bic(sse: f64, n: usize, p: usize) -> f64 {
    let n = n.max(1) as f64;
    n * (sse.max(1e-300) / n).ln() + p as f64 * n.ln()
}

/// Delete-a-group jackknife standard error from the per-fold estimates.
pub(crate) fn jackknife_se(values: &[f64]) -> f64 {
    let k = values.len();
    if k < 2 {
        return f64::NAN;
    }
    let mean = values.iter().sum::<f64>() / k as f64;
    ((k - 1) as f64 / k as f64 * values.iter().map(|v| (v - mean).powi(2)).sum::<f64>()).sqrt()
}

/// A named physical parameter with its uncertainty.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Param {
    /// What it is.
    pub name: String,
    /// Symbol.
    pub symbol: String,
    /// Estimate.
    pub value: f64,
    /// Standard error (delete-a-fold jackknife over the cross-validation folds).
    pub std_err: f64,
    /// Unit.
    pub unit: String,
}

/// How one hypothesis scored.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct HypothesisScore {
    /// Identifier (`thermal`, `braking`, `bus_loss`, `payload`, `latency`, …).
    pub id: String,
    /// What it is, in words.
    pub title: String,
    /// `power` or `torque`: the comparison level it is scored on.
    pub level: String,
    /// The physical parameter(s), first = the headline parameter.
    pub params: Vec<Param>,
    /// One-sided p-value that the held-out per-trial squared error improves ([`super::stats::improvement_p_value`]).
    pub p_value: f64,
    /// BIC(with hypothesis) − BIC(without), full data; negative favours the hypothesis.
    pub delta_bic: f64,
    /// Held-out RMSE without → with the hypothesis (W at power level, Nm at torque level).
    pub rmse_before: f64,
    /// Held-out RMSE with the hypothesis.
    pub rmse_after: f64,
    /// Held-out R² without the hypothesis.
    pub r2_before: f64,
    /// Held-out R² with the hypothesis.
    pub r2_after: f64,
    /// 1 − rmse_after / rmse_before.
    pub rel_improvement: f64,
    /// Parameter inside its physically plausible range.
    pub plausible: bool,
    /// Accepted by the significance rule (at the selection step it was scored in).
    pub accepted: bool,
    /// Rank among all hypotheses at the first selection step (1 = best).
    pub rank: usize,
    /// Selection step it was scored at (1 = against the base model).
    pub step: usize,
    /// Why it was accepted or rejected.
    pub verdict: String,
    /// For a claim: the share of trial resamples in which [`super::parsimony`]'s test passed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stability: Option<f64>,
}

impl super::stepwise::Gated for HypothesisScore {
    fn gated(&self) -> (f64, f64, f64) {
        (self.p_value, self.delta_bic, self.rel_improvement)
    }
}

impl HypothesisScore {
    /// Rejected only for its size: every statistical gate passed, the parameter is implausible.
    pub fn only_implausible(&self) -> bool {
        !self.accepted && self.verdict.strip_prefix("rejected: ") == Some(IMPLAUSIBLE)
    }
}

/// The rule's words for a parameter outside its plausible range: a verdict that is only this is
/// a structure the data support in a size no such mechanism has ([`HypothesisScore::only_implausible`]).
pub(crate) const IMPLAUSIBLE: &str = "parameter outside its physically plausible range";

/// Thresholds of the significance rule.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Rule {
    pub alpha: f64,
    pub bic_threshold: f64,
    pub min_improvement: f64,
}

impl Rule {
    /// Apply the rule: accepted or not, and why.
    /// Whether the data support `s` — the statistical gates of [`Rule::judge`] without the
    /// plausibility of its parameter. A rival mechanism that fits as well is a rival even at an
    /// implausible value: the form, not the size, is what the pairing decides.
    pub fn supports(&self, s: &HypothesisScore) -> bool {
        super::stepwise::passes(self, s, self.alpha)
    }

    pub fn judge(&self, s: &HypothesisScore) -> (bool, String) {
        let mut fails = Vec::new();
        if s.p_value >= self.alpha {
            fails.push(format!(
                "held-out improvement not significant (p = {:.2e} ≥ {:.0e})",
                s.p_value, self.alpha
            ));
        }
        if s.delta_bic >= self.bic_threshold {
            fails.push(format!(
                "ΔBIC = {:.1} ≥ {:.0}",
                s.delta_bic, self.bic_threshold
            ));
        }
        if s.rel_improvement < self.min_improvement {
            fails.push(format!(
                "held-out RMSE improves by {:.2} % < {:.1} %",
                100.0 * s.rel_improvement,
                100.0 * self.min_improvement
            ));
        }
        if !s.plausible {
            fails.push(IMPLAUSIBLE.into());
        }
        if fails.is_empty() {
            (
                true,
                format!(
                    "accepted: held-out RMSE −{:.1} % (p = {:.1e}), ΔBIC = {:.1}, plausible parameter",
                    100.0 * s.rel_improvement,
                    s.p_value,
                    s.delta_bic
                ),
            )
        } else {
            (false, format!("rejected: {}", fails.join("; ")))
        }
    }
}

/// Builds the rows at the given lag indices on demand (one more pass over the trials' samples).
pub(crate) type LagRowSource<'a> = Box<dyn FnMut(&[usize]) -> Result<Vec<Rows>> + 'a>;

/// Seed of the cross-validation folds: every stage uses the same assignment of trials to folds.
pub(crate) const FOLD_SEED: u64 = 0x67_3176_697a;

/// Power-level data: Gram matrices at each scanned sensor lag (index 0 = no lag), the rows at
/// lag 0, the rows at other lags as far as they are needed (built on first use when a
/// [`LagRowSource`] is given: a long session's rows at every lag would not fit in memory), and
/// the reference θ when the base model is held at the twin's model instead of refitted.
///
/// Every lag's rows are the same readings (same `t`, `y`, `trial`, `phase`); only `x` differs.
pub(crate) struct PowerData<'a> {
    pub lags: Vec<f64>,
    rows: Vec<std::cell::OnceCell<Rows>>,
    pub grams: Vec<FoldGrams>,
    pub folds: Folds,
    pub n_trials: usize,
    pub reference: Option<Vec<f64>>,
    /// Whether the sensor-window scan found a lag that beats every window at lag 0 (false: the
    /// latency hypothesis is scored but never claimed; see `diagnose/window.rs`).
    pub lag_claimable: bool,
    source: Option<std::cell::RefCell<LagRowSource<'a>>>,
}

impl<'a> PowerData<'a> {
    /// From the rows at every lag.
    pub fn new(
        lags: Vec<f64>,
        rows: Vec<Rows>,
        n_trials: usize,
        k: usize,
        reference: Option<Vec<f64>>,
    ) -> PowerData<'a> {
        let folds = Folds::new(n_trials, k, FOLD_SEED);
        let grams = rows.iter().map(|r| FoldGrams::new(r, &folds)).collect();
        PowerData {
            lags,
            rows: rows.into_iter().map(std::cell::OnceCell::from).collect(),
            grams,
            folds,
            n_trials,
            reference,
            lag_claimable: true,
            source: None,
        }
    }

    /// From the Gram matrices at every lag, the rows at lag 0 and a source of the other lags'
    /// rows (`grams` built with `folds`).
    pub fn with_source(
        lags: Vec<f64>,
        rows0: Rows,
        grams: Vec<FoldGrams>,
        folds: Folds,
        reference: Option<Vec<f64>>,
        source: LagRowSource<'a>,
    ) -> PowerData<'a> {
        let n_trials = folds.of_trial.len();
        let rows: Vec<std::cell::OnceCell<Rows>> = (0..lags.len())
            .map(|_| std::cell::OnceCell::new())
            .collect();
        let _ = rows[0].set(rows0);
        PowerData {
            lags,
            rows,
            grams,
            folds,
            n_trials,
            reference,
            lag_claimable: true,
            source: Some(std::cell::RefCell::new(source)),
        }
    }

    /// The rows at lag 0 (always held).
    pub fn rows0(&self) -> &Rows {
        self.rows[0].get().expect("lag 0 rows are always held")
    }

    /// The rows at lag index `lag`, built on first use.
    pub fn rows(&self, lag: usize) -> Result<&Rows> {
        if self.rows[lag].get().is_none() {
            self.load(&[lag])?;
        }
        self.rows[lag]
            .get()
            .ok_or_else(|| anyhow::anyhow!("no power rows at the sensor lag {} s", self.lags[lag]))
    }

    /// Build the rows of those of `lags` (indices) not held yet, in one pass.
    pub fn load(&self, lags: &[usize]) -> Result<()> {
        let mut missing: Vec<usize> = lags
            .iter()
            .copied()
            .filter(|&l| self.rows[l].get().is_none())
            .collect();
        missing.sort_unstable();
        missing.dedup();
        if missing.is_empty() {
            return Ok(());
        }
        let Some(src) = &self.source else {
            anyhow::bail!("power rows at lag indices {missing:?} are not held");
        };
        let built = (src.borrow_mut())(&missing)?;
        for (l, r) in missing.into_iter().zip(built) {
            let _ = self.rows[l].set(r);
        }
        Ok(())
    }

    fn reference(&self) -> Option<&[f64]> {
        self.reference.as_deref()
    }

    /// Number of free base parameters (0 when held at the reference).
    fn base_params(&self) -> usize {
        if self.reference.is_some() {
            0
        } else {
            N_PARAMS
        }
    }

    /// Fit `spec` on all rows of lag index `lag`.
    pub fn fit_all(&self, spec: &[&'static Hypothesis], lag: usize) -> Result<Fitted> {
        fit(spec, &self.grams[lag].total, self.reference())
    }
}

/// The current model during selection.
#[derive(Debug, Clone)]
pub(crate) struct State {
    pub spec: Spec,
    pub lag: usize,
    pub cv: CvOut,
    pub full: Fitted,
    pub bic: f64,
}

pub(crate) fn state(data: &PowerData, spec: Spec, lag: usize) -> Result<State> {
    let cv = cross_validate(
        &spec,
        data.rows(lag)?,
        &data.folds,
        &data.grams[lag],
        data.reference(),
    )?;
    let full = data.fit_all(&spec, lag)?;
    let g = &data.grams[lag].total;
    let p = data.base_params() + spec.len() + usize::from(lag != 0);
    let bic = bic(g.sse(&full.beta), g.n, p);
    Ok(State {
        spec,
        lag,
        cv,
        full,
        bic,
    })
}

/// Vertex of the parabola through three points (x sorted), clamped to their span.
fn parabola_vertex(x: [f64; 3], y: [f64; 3]) -> f64 {
    let d1 = (y[1] - y[0]) / (x[1] - x[0]);
    let d2 = (y[2] - y[1]) / (x[2] - x[1]);
    let curv = (d2 - d1) / (x[2] - x[0]);
    if curv <= 0.0 {
        return x[1];
    }
    (0.5 * (x[0] + x[1]) - d1 / (2.0 * curv)).clamp(x[0], x[2])
}

/// Refine the lag of minimal `sse` (indexed like `lags`, sorted ascending) by a parabola.
fn refine_lag(lags: &[f64], sse: &[f64]) -> (usize, f64) {
    let best = (0..lags.len())
        .min_by(|&a, &b| sse[a].total_cmp(&sse[b]))
        .unwrap_or(0);
    if best == 0 || best + 1 >= lags.len() {
        return (best, lags[best]);
    }
    let v = parabola_vertex(
        [lags[best - 1], lags[best], lags[best + 1]],
        [sse[best - 1], sse[best], sse[best + 1]],
    );
    (best, v)
}

/// The outcome of the comparison of a candidate with the current model.
struct Candidate {
    score: HypothesisScore,
    next: State,
}

fn compare(data: &PowerData, cur: &State, next_pred: &[f64]) -> Held {
    // Every lag's rows are the same readings: y and trial are the lag-0 rows'.
    let rows = data.rows0();
    Held::new(&rows.y, &cur.cv.pred, next_pred, &rows.trial, data.n_trials)
}

/// Held-out predictions `after` compared with `before`: the paired one-sided p-value by trial
/// that `after` fits better, and each one's quality.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Held {
    pub p_value: f64,
    pub before: Quality,
    pub after: Quality,
}

impl Held {
    /// Compare `after` with `before` on readings `y` of trials `trial` (of `n_trials`).
    pub fn new(y: &[f64], before: &[f64], after: &[f64], trial: &[usize], n_trials: usize) -> Held {
        let eb = trial_sse(y, before, trial, n_trials);
        let ea = trial_sse(y, after, trial, n_trials);
        let d: Vec<f64> = eb.iter().zip(&ea).map(|(a, b)| a - b).collect();
        let quality = |pred: &[f64]| {
            let (r2, rmse_w) = r2_rmse(y, pred);
            Quality { r2, rmse_w }
        };
        Held {
            p_value: improvement_p_value(&d),
            before: quality(before),
            after: quality(after),
        }
    }

    /// 1 − held-out RMSE after / before.
    pub fn gain(&self) -> f64 {
        1.0 - self.after.rmse_w / self.before.rmse_w.max(1e-300)
    }

    /// An unjudged score of candidate `id` (`title`) at `level` ("power", "torque") with
    /// `params`: not accepted, not ranked, no verdict; ΔBIC, plausibility and step unset.
    pub fn score(&self, id: &str, title: &str, level: &str, params: Vec<Param>) -> HypothesisScore {
        HypothesisScore {
            id: id.into(),
            title: title.into(),
            level: level.into(),
            params,
            p_value: self.p_value,
            delta_bic: 0.0,
            rmse_before: self.before.rmse_w,
            rmse_after: self.after.rmse_w,
            r2_before: self.before.r2,
            r2_after: self.after.r2,
            rel_improvement: self.gain(),
            plausible: false,
            accepted: false,
            rank: 0,
            step: 0,
            verdict: String::new(),
            stability: None,
        }
    }
}

fn score_term(
    data: &PowerData,
    cur: &State,
    h: &'static Hypothesis,
    step: usize,
) -> Result<Candidate> {
    let mut spec = cur.spec.clone();
    spec.push(h);
    let next = state(data, spec, cur.lag)?;
    let j = N_PARAMS + next.spec.len() - 1;
    let value = (h.to_physical)(next.full.theta[j]);
    let per_fold: Vec<f64> = next
        .cv
        .fold_theta
        .iter()
        .map(|t| (h.to_physical)(t[j]))
        .collect();
    let param = Param {
        name: h.title.into(),
        symbol: h.symbol.into(),
        value,
        std_err: jackknife_se(&per_fold),
        unit: h.unit.into(),
    };
    let held = compare(data, cur, &next.cv.pred);
    let score = HypothesisScore {
        delta_bic: next.bic - cur.bic,
        plausible: value >= h.plausible.0 && value <= h.plausible.1,
        step,
        ..held.score(h.id, h.title, "power", vec![param])
    };
    Ok(Candidate { score, next })
}

/// Latency: in each fold the lag is chosen on the training trials only (nested), then judged on
/// the held-out trials, so the scan itself cannot buy a better held-out score.
fn score_latency(data: &PowerData, cur: &State, step: usize) -> Result<Candidate> {
    let nl = data.lags.len();
    let mut fold_fits: Vec<Vec<Fitted>> = Vec::with_capacity(nl);
    for fg in &data.grams {
        let mut per = Vec::with_capacity(data.folds.k);
        for f in 0..data.folds.k {
            per.push(fit(&cur.spec, &fg.train(f), data.reference())?);
        }
        fold_fits.push(per);
    }
    let mut pred = vec![0.0; data.rows0().len()];
    let mut fold_lag = Vec::with_capacity(data.folds.k);
    let mut chosen = vec![0usize; data.folds.k];
    for f in 0..data.folds.k {
        let sse: Vec<f64> = (0..nl)
            .map(|l| data.grams[l].train(f).sse(&fold_fits[l][f].beta))
            .collect();
        let (best, refined) = refine_lag(&data.lags, &sse);
        chosen[f] = best;
        fold_lag.push(refined);
    }
    let full_sse: Vec<f64> = (0..nl)
        .map(|l| {
            data.fit_all(&cur.spec, l)
                .map(|f| data.grams[l].total.sse(&f.beta))
        })
        .collect::<Result<_>>()?;
    let (best, lag) = refine_lag(&data.lags, &full_sse);
    // The chosen lags' rows in one pass (when they are built on demand).
    let mut needed = chosen.clone();
    needed.push(best);
    data.load(&needed)?;
    for (r, p) in pred.iter_mut().enumerate() {
        let f = data.folds.of_trial[data.rows0().trial[r]];
        let l = chosen[f];
        *p = data.rows(l)?.x[r]
            .iter()
            .zip(fold_fits[l][f].beta.iter())
            .map(|(a, b)| a * b)
            .sum();
    }
    let next = state(data, cur.spec.clone(), best)?;
    // Rows are the same readings at every lag, so per-trial errors compare directly.
    let param = Param {
        name: "sensor latency".into(),
        symbol: "L".into(),
        value: lag,
        std_err: jackknife_se(&fold_lag),
        unit: "s".into(),
    };
    let title = "power-sensor latency (reading averages an earlier window)";
    let score = HypothesisScore {
        delta_bic: next.bic - cur.bic,
        plausible: best > 0 && lag <= 2.0,
        step,
        ..compare(data, cur, &pred).score(LATENCY_ID, title, "power", vec![param])
    };
    Ok(Candidate { score, next })
}

/// How the forms of one mechanism compared at the selection step that decided between them.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct MechanismForms {
    /// The mechanism.
    pub mechanism: String,
    /// Identifier of the best-scoring form.
    pub winner: String,
    /// Identifier of the second-best form.
    pub runner_up: String,
    /// Held-out RMSE with the winner and with the runner-up [W].
    pub rmse_w: [f64; 2],
    /// Margin: 1 − RMSE(winner)/RMSE(runner-up).
    pub margin: f64,
    /// One-sided paired p-value that the winner's per-trial held-out error is below the
    /// runner-up's.
    pub p_value: f64,
    /// Whether the winning form was accepted.
    pub accepted: bool,
    /// The winner's and the runner-up's form in words (e.g. `per-Nm`, `per-ampere`).
    #[serde(default)]
    pub form_words: [String; 2],
    /// The parameter(s) of the winner and of the runner-up, each fitted in its own form.
    #[serde(default)]
    pub params: [Vec<Param>; 2],
    /// The data do not tell the forms apart: the winner's margin is not significant (p at or
    /// above the significance level of the rule). The mechanism is then claimed with its form
    /// left open ("form: confounded — X or Y"), not the winning form.
    #[serde(default)]
    pub confounded: bool,
    /// The runner-up is a form of ANOTHER mechanism that the winner does not beat significantly
    /// (`mechanism` then reads "X or Y"): the structure is located, no mechanism is named — the
    /// winner stays in the model (its structure explained) but is not claimed.
    #[serde(default)]
    pub unnamed: bool,
    /// For a claim [`super::parsimony`]'s rule located: the share of trial resamples in which
    /// its test passed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stability: Option<f64>,
}

impl MechanismForms {
    /// "W vs R: held-out RMSE a vs b W, p = … that W fits better": the evidence of the pairing.
    pub fn evidence(&self) -> String {
        let test = format!(
            "{w} vs {r}: held-out RMSE {:.3} vs {:.3} W, p = {:.3} that {w} fits better",
            self.rmse_w[0],
            self.rmse_w[1],
            self.p_value,
            w = self.winner,
            r = self.runner_up,
        );
        match self.stability {
            Some(s) => format!(
                "{test} (needed < {RIVAL_ALPHA}); held in {:.0} % of trial resamples (needed ≥ {:.0} %)",
                100.0 * s,
                100.0 * super::parsimony::STABLE
            ),
            None => format!("{test} (needed < {RIVAL_ALPHA})"),
        }
    }

    /// "per-Nm or per-ampere" (winner first).
    pub fn either(&self) -> String {
        let w = |i: usize, id: &str| {
            if self.form_words[i].is_empty() {
                id.to_string()
            } else {
                self.form_words[i].clone()
            }
        };
        format!("{} or {}", w(0, &self.winner), w(1, &self.runner_up))
    }
}

/// Two hypotheses the data cannot tell apart: forward selection accepted both, but one is not
/// significant given the other.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Confounded {
    /// The one kept (significant given the other).
    pub kept: String,
    /// The library term dropped in its place.
    pub dropped: String,
    /// Correlation of their regressors over the readings.
    pub correlation: f64,
    /// p-value of the dropped one given all the others (paired held-out test).
    pub p_value: f64,
    /// Relative held-out RMSE change from dropping it.
    pub rel_change: f64,
    /// The data do not tell the two apart in either direction (a library term, `dropped`, and a
    /// term beyond the library, `kept`, on a recorded field the library does not read, that
    /// explains the same part of the power). The library term — a mechanism written from physics
    /// — stays claimed, and the other is named beside it as an explanation the data cannot
    /// exclude. Then `p_value` is that of the library term fitting the held-out trials better
    /// than the other, and `rel_change` is 1 − its held-out RMSE / the other's.
    #[serde(default)]
    pub tied: bool,
}

/// The result of greedy forward selection at the power level.
pub(crate) struct Selection {
    /// Every candidate scored against the base model (step 1), ranked.
    pub first_step: Vec<HypothesisScore>,
    /// The accepted hypotheses in the order they were added, with their score at that step.
    pub accepted: Vec<HypothesisScore>,
    /// Forms of each mechanism with more than one, compared where they were decided.
    pub forms: Vec<MechanismForms>,
    /// Library terms and the terms beyond the library that do their work
    /// ([`super::select_discover::library_rivals`]).
    pub confounded: Vec<Confounded>,
    /// Base model state (no hypothesis, no lag).
    pub base: State,
    /// Final model state.
    pub last: State,
    /// Per accepted hypothesis id: the best other library mechanism the data also supported at
    /// its step ([`Rule::supports`]) — its rival in [`super::parsimony`]'s rule.
    pub rivals: Vec<(String, &'static Hypothesis)>,
}

/// Mechanism of a candidate (`None` = latency).
fn mechanism(c: &Option<&'static Hypothesis>) -> &'static str {
    c.map_or(LATENCY_ID, |h| h.mechanism)
}

/// Form of a candidate in words (empty for latency).
fn form_words(c: &Option<&'static Hypothesis>) -> String {
    c.map_or(String::new(), |h| h.form.to_string())
}

/// Compare the two best forms of every mechanism with more than one form among `scored`; the
/// forms are confounded when the winner's per-trial margin is not significant at `alpha`.
fn compare_forms(
    data: &PowerData,
    scored: &[(usize, Candidate)],
    remaining: &[Option<&'static Hypothesis>],
    alpha: f64,
    decided: &mut Vec<MechanismForms>,
) {
    let mut mechs: Vec<&str> = remaining.iter().map(mechanism).collect();
    mechs.sort_unstable();
    mechs.dedup();
    for m in mechs {
        if decided.iter().any(|d| d.mechanism == m) {
            continue;
        }
        let forms: Vec<(usize, &Candidate)> = scored
            .iter()
            .filter(|(i, _)| mechanism(&remaining[*i]) == m)
            .map(|(i, c)| (*i, c))
            .collect();
        if forms.len() < 2 {
            continue;
        }
        // `scored` is sorted best first.
        let ((wi, w), (ri, r)) = (forms[0], forms[1]);
        let words = [form_words(&remaining[wi]), form_words(&remaining[ri])];
        decided.push(versus(data, m.into(), (w, r), words, alpha));
    }
}

/// The winner `w` against the runner-up `r`: the paired held-out test by trial, their scores and
/// parameters; confounded when the winner was accepted but its margin is not significant.
fn versus(
    data: &PowerData,
    mechanism: String,
    (w, r): (&Candidate, &Candidate),
    form_words: [String; 2],
    alpha: f64,
) -> MechanismForms {
    // Every lag's rows are the same readings: y and trial are the lag-0 rows'.
    let y = &data.rows0().y;
    let trial = &data.rows0().trial;
    let ew = trial_sse(y, &w.next.cv.pred, trial, data.n_trials);
    let er = trial_sse(y, &r.next.cv.pred, trial, data.n_trials);
    let d: Vec<f64> = er.iter().zip(&ew).map(|(a, b)| a - b).collect();
    let p_value = improvement_p_value(&d);
    MechanismForms {
        mechanism,
        winner: w.score.id.clone(),
        runner_up: r.score.id.clone(),
        rmse_w: [w.score.rmse_after, r.score.rmse_after],
        margin: 1.0 - w.score.rmse_after / r.score.rmse_after.max(1e-300),
        p_value,
        accepted: w.score.accepted,
        form_words,
        params: [w.score.params.clone(), r.score.params.clone()],
        confounded: w.score.accepted && (p_value >= alpha || p_value.is_nan()),
        unnamed: false,
        stability: None,
    }
}

/// Level of the paired test by which a library mechanism must beat another that also passes at
/// its step. Measured: the project's own 72-trial bus-loss, drive-loss and per-Nm sessions beat
/// their rival mechanism at p = 0.002–0.02 (margins 7–11 %); the campaign's two wrong names were
/// ahead by p = 0.79 and 0.15 (margins 0.2 %, 0.5 %). At the rule's 0.001 the true ones would be
/// left unnamed.
pub(crate) const RIVAL_ALPHA: f64 = 0.05;

/// Greedy forward selection: at each step score every remaining candidate against the current
/// model, add the best one that passes the rule (the other forms of its mechanism leave the
/// race), stop when none passes. Whether each is claimed beside the others and against its rival
/// mechanism is [`super::parsimony`]'s rule, applied after every stage.
pub(crate) fn select(
    data: &PowerData,
    candidates: &[&'static Hypothesis],
    rule: &Rule,
) -> Result<Selection> {
    let base = state(data, Vec::new(), 0)?;
    let mut cur = base.clone();
    let mut remaining: Vec<Option<&'static Hypothesis>> =
        candidates.iter().map(|&h| Some(h)).collect();
    if data.lags.len() >= 3 {
        remaining.push(None); // None = latency
    }
    let mut first_step: Vec<HypothesisScore> = Vec::new();
    let mut accepted = Vec::new();
    let mut forms: Vec<MechanismForms> = Vec::new();
    let mut rivals = Vec::new();
    for step in 1.. {
        let mut scored: Vec<(usize, Candidate)> = Vec::new();
        for (i, c) in remaining.iter().enumerate() {
            let mut cand = match c {
                Some(h) => score_term(data, &cur, h, step)?,
                None => score_latency(data, &cur, step)?,
            };
            let (mut ok, mut why) = rule.judge(&cand.score);
            if c.is_none() && !data.lag_claimable {
                why = format!(
                    "not claimed: the sensor-window scan finds no lag that beats every window at \
                     lag 0 ({why})"
                );
                ok = false;
            }
            cand.score.accepted = ok;
            cand.score.verdict = why;
            scored.push((i, cand));
        }
        scored.sort_by(|a, b| {
            (b.1.score.accepted, b.1.score.rel_improvement)
                .partial_cmp(&(a.1.score.accepted, a.1.score.rel_improvement))
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        if step == 1 {
            first_step = scored.iter().map(|(_, c)| c.score.clone()).collect();
        }
        let winner = scored
            .first()
            .filter(|(_, c)| c.score.accepted)
            .map(|(i, _)| mechanism(&remaining[*i]));
        // A mechanism's forms are compared at the step that accepts one of them (or at the
        // first step when none is ever accepted: replaced below).
        if let Some(m) = winner {
            let mut here = Vec::new();
            compare_forms(data, &scored, &remaining, rule.alpha, &mut here);
            forms.retain(|f: &MechanismForms| f.mechanism != m);
            forms.extend(here.into_iter().filter(|f| f.mechanism == m));
        } else if step == 1 {
            compare_forms(data, &scored, &remaining, rule.alpha, &mut forms);
        }
        let Some((idx, best)) = scored.first().filter(|(_, c)| c.score.accepted) else {
            break;
        };
        let m = mechanism(&remaining[*idx]);
        // Its rival: the best candidate of another library mechanism the data also support, at
        // any value of its parameter (the form, not the size, is what the rule pairs).
        let rival = scored.iter().find_map(|(i, c)| {
            remaining[*i].filter(|h| h.mechanism != m && rule.supports(&c.score))
        });
        if let Some(r) = rival {
            rivals.push((best.score.id.clone(), r));
        }
        accepted.push(best.score.clone());
        cur = best.next.clone();
        remaining.retain(|c| mechanism(c) != m);
        if remaining.is_empty() {
            break;
        }
    }
    for f in forms.iter().filter(|f| f.confounded) {
        for s in accepted.iter_mut().chain(first_step.iter_mut()) {
            if s.id == f.winner {
                s.verdict = format!(
                    "{}; form: confounded — {} (margin {:.1} %, p = {:.2})",
                    s.verdict,
                    f.either(),
                    100.0 * f.margin,
                    f.p_value
                );
            }
        }
    }
    Ok(Selection {
        first_step,
        accepted,
        forms,
        confounded: Vec::new(),
        base,
        last: cur,
        rivals,
    })
}

/// [`unname`] on a selection's own forms, claims and first-step scores.
pub(crate) fn unname_all(sel: &mut Selection) {
    unname(&mut sel.forms, &mut sel.accepted, &mut sel.first_step);
}

/// A winner [`super::parsimony`]'s rule locates is not claimed: it leaves
/// `accepted` (it stays in the model) and its first-step score says why.
fn unname(
    forms: &mut [MechanismForms],
    accepted: &mut Vec<HypothesisScore>,
    first_step: &mut [HypothesisScore],
) {
    let unnamed: Vec<MechanismForms> = forms
        .iter()
        .filter(|f| f.unnamed && accepted.iter().any(|s| s.id == f.winner))
        .cloned()
        .collect();
    for f in &unnamed {
        accepted.retain(|s| s.id != f.winner);
        // Neither mechanism is claimed in any form.
        for g in forms.iter_mut().filter(|g| g.winner == f.winner) {
            g.accepted = false;
        }
        let of_either = |id: &str| {
            id == f.winner
                || super::hypotheses::power_hypothesis(id)
                    .is_some_and(|h| f.form_words.iter().any(|m| m == h.mechanism))
        };
        for s in first_step.iter_mut().filter(|s| of_either(&s.id)) {
            s.accepted = false;
            s.verdict = format!(
                "located, not named: {} — form not identified ({}); {}",
                f.mechanism,
                f.evidence(),
                s.verdict
            );
        }
    }
}

/// The regressor of hypothesis `h` on row `r` (pooled terms weighted by `theta`).
pub(crate) fn regressor(h: &Hypothesis, x: &[f64; N_RAW], theta: &[f64]) -> f64 {
    let (off, len) = h.raw;
    (0..len)
        .map(|i| {
            let w = match h.combine {
                Combine::Single => 1.0,
                Combine::WeightedByBase(b) => theta.get(b + i).copied().unwrap_or(1.0),
            };
            w * x[N_PARAMS + off + i]
        })
        .sum()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::diagnose::hypotheses::{POWER_HYPOTHESES, Sample, extras_into, power_hypothesis};
    use crate::power::{PowerModel, regressor_into};
    use rand::RngExt;
    use rand_distr::{Distribution, Normal};

    /// Synthetic rows: each row one random arm state of 1–3 moving joints; the truth is the
    /// paper's model plus `effect(sample)`; trials heat up from 30 to 60 °C.
    pub(crate) fn synth(
        seed: u64,
        n_trials: usize,
        effect: &dyn Fn(&Sample) -> f64,
    ) -> PowerData<'static> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, 0.3).unwrap();
        let mut rows = Rows::default();
        for t in 0..n_trials {
            let temp_level = 30.0 + 30.0 * t as f64 / n_trials as f64;
            let moved: Vec<usize> = (0..rng.random_range(1..4))
                .map(|_| rng.random_range(0..7))
                .collect();
            let tau0_sq = [1.0; 7];
            for _ in 0..8 {
                let mut q = [0.0; 7];
                let mut dq = [0.0; 7];
                let mut tau = [1.0; 7];
                for &j in &moved {
                    q[j] = rng.random_range(-1.0..1.0);
                    dq[j] = rng.random_range(-2.5..2.5);
                    tau[j] = rng.random_range(-6.0..6.0);
                }
                let temp = [temp_level; 7];
                let gyro = [0.0; 3];
                let s = Sample {
                    q: &q,
                    dq: &dq,
                    tau: &tau,
                    temp: &temp,
                    gyro: &gyro,
                    tau0_sq: &tau0_sq,
                    bus_amps: PowerModel::PAPER.predict(&tau, &dq, &tau0_sq) / 50.0,
                };
                let mut phi = [0.0; N_PARAMS];
                regressor_into(&tau, &dq, &tau0_sq, &mut phi);
                let mut ex = [0.0; super::super::hypotheses::N_EXTRA];
                extras_into(&s, &mut ex);
                let mut x = [0.0; N_RAW];
                x[..N_PARAMS].copy_from_slice(&phi);
                x[N_PARAMS..].copy_from_slice(&ex);
                let y = PowerModel::PAPER.predict(&tau, &dq, &tau0_sq)
                    + effect(&s)
                    + noise.sample(&mut rng);
                rows.trial.push(t);
                rows.t.push(t as f64);
                rows.phase.push(crate::trial::Phase::Trajectory);
                rows.y.push(y);
                rows.x.push(x);
            }
        }
        PowerData::new(vec![0.0], vec![rows], n_trials, 5, None)
    }

    pub(crate) const RULE: Rule = Rule {
        alpha: 1e-3,
        bic_threshold: -10.0,
        min_improvement: 0.01,
    };

    fn all() -> Vec<&'static Hypothesis> {
        POWER_HYPOTHESES.iter().collect()
    }

    #[test]
    fn null_data_accepts_nothing() {
        for seed in 0..3 {
            let sel = select(&synth(seed, 60, &|_| 0.0), &all(), &RULE).unwrap();
            assert!(
                sel.accepted.is_empty(),
                "seed {seed}: accepted {:?}",
                sel.accepted.iter().map(|s| &s.id).collect::<Vec<_>>()
            );
        }
    }

    /// A score that passes every statistical gate at an implausible size is "only implausible"
    /// (the summary locates it); one that also fails a gate, or is plausible, is not.
    #[test]
    fn only_an_implausible_size_is_told_from_a_failed_gate() {
        let judged = |p_value: f64, plausible: bool| {
            let mut s = HypothesisScore {
                id: "stribeck".into(),
                title: String::new(),
                level: "power".into(),
                params: Vec::new(),
                p_value,
                delta_bic: -700.0,
                rmse_before: 1.0,
                rmse_after: 0.6,
                r2_before: 0.9,
                r2_after: 0.95,
                rel_improvement: 0.4,
                plausible,
                accepted: false,
                rank: 0,
                step: 1,
                verdict: String::new(),
                stability: None,
            };
            let (ok, why) = RULE.judge(&s);
            (s.accepted, s.verdict) = (ok, why);
            s
        };
        assert!(judged(1e-11, false).only_implausible());
        assert!(!judged(0.5, false).only_implausible(), "a failed gate too");
        assert!(!judged(1e-11, true).only_implausible(), "accepted");
    }

    #[test]
    fn braking_return_fraction_is_recovered() {
        // mech_i = r·τq̇ when braking: P += (r − 1)·Σ min(τ_i q̇_i, 0), r = 0.3 (a_i = 1 in the paper).
        let r = 0.3;
        let effect = move |s: &Sample| {
            (r - 1.0) * (0..7).map(|i| (s.tau[i] * s.dq[i]).min(0.0)).sum::<f64>()
        };
        let sel = select(&synth(7, 60, &effect), &all(), &RULE).unwrap();
        assert_eq!(sel.first_step[0].id, "braking");
        assert_eq!(sel.accepted.len(), 1);
        let v = sel.accepted[0].params[0].value;
        assert!((v - r).abs() < 0.1 * r, "r = {v}");
    }

    /// The drive-electronics mechanism of `effect` data: (forms entry, accepted ids).
    fn electronics_forms(seed: u64, effect: &dyn Fn(&Sample) -> f64) -> MechanismForms {
        let sel = select(&synth(seed, 120, effect), &all(), &RULE).unwrap();
        let f = sel
            .forms
            .iter()
            .find(|f| f.mechanism == "drive-electronics loss")
            .cloned()
            .expect("forms compared");
        assert_eq!(sel.accepted.len(), 1, "{:?}", sel.accepted);
        assert_eq!(sel.accepted[0].id, f.winner);
        f
    }

    #[test]
    fn forms_are_told_apart_only_on_a_significant_margin() {
        let k = crate::power::JOINT_TORQUE_CONSTANT;
        let amps = move |s: &Sample| (0..7).map(|j| s.tau[j].abs() / k[j]).sum::<f64>();
        // Per ampere, strong: the per-ampere form wins significantly and is claimed.
        let f = electronics_forms(3, &|s: &Sample| 1.0 * amps(s));
        assert!(
            f.accepted && !f.confounded && f.winner == "drive_loss",
            "{f:?}"
        );
        assert!(f.p_value < RULE.alpha, "{f:?}");
        assert_eq!(f.form_words, ["per-ampere", "per-Nm"]);
        // The same form, weak (V = 0.15 V): the loss is found but its form is not told.
        let weak = move |s: &Sample| 0.15 * amps(s);
        let f = electronics_forms(3, &weak);
        assert!(f.accepted && f.confounded, "{f:?}");
        assert!(f.p_value >= RULE.alpha, "{f:?}");
        assert_eq!(
            f.either(),
            format!("{} or {}", f.form_words[0], f.form_words[1])
        );
        let sel = select(&synth(3, 120, &weak), &all(), &RULE).unwrap();
        assert!(sel.accepted[0].verdict.contains("form: confounded — "));
    }

    /// Issue 28's class of wrong claims, on data this module did not write the form of: a
    /// mechanism in a form the library does not fit, which two library mechanisms approximate
    /// about equally. Neither may be named; the structure is located with both.
    #[test]
    fn a_mechanism_another_fits_as_well_is_located_not_named() {
        // Gear friction only above a threshold of |τq̇| (campaign seed 275145867 was named the
        // braking asymmetry).
        let gear = |s: &Sample| {
            0.2 * (0..7)
                .map(|i| (s.tau[i] * s.dq[i]).abs())
                .filter(|p| *p > 3.0)
                .sum::<f64>()
        };
        // A drive-electronics loss with per-joint weights (seed 791979931: named the bus loss).
        let k = crate::power::JOINT_TORQUE_CONSTANT;
        let w = [0.0, 0.4, 1.9, 1.5, 1.0, 1.4, 0.9];
        let drive = move |s: &Sample| (0..7).map(|j| 0.3 * w[j] * s.tau[j].abs() / k[j]).sum();
        for (what, effect, wrong) in [
            ("gear", &gear as &dyn Fn(&Sample) -> f64, "braking"),
            ("drive", &drive, "bus_loss"),
        ] {
            let data = synth(5, 60, effect);
            let mut sel = select(&data, &all(), &RULE).unwrap();
            super::super::parsimony::apply(&data, &mut sel, None, &RULE).unwrap();
            let ids: Vec<&str> = sel.accepted.iter().map(|s| s.id.as_str()).collect();
            let unnamed: Vec<&MechanismForms> = sel.forms.iter().filter(|f| f.unnamed).collect();
            eprintln!("{what}: accepted {ids:?}, unnamed {unnamed:?}");
            assert!(!ids.contains(&wrong), "{what}: named {ids:?}");
        }
    }

    #[test]
    fn bus_loss_and_thermal_together_are_both_found() {
        let (rb, alpha) = (0.05, 0.004);
        let k = crate::power::JOINT_TORQUE_CONSTANT;
        let b = PowerModel::PAPER.b;
        let effect = move |s: &Sample| {
            let i: f64 = (0..7).map(|j| s.tau[j].abs() / k[j]).sum();
            let thermal: f64 = (0..7)
                .map(|j| b[j] * alpha * (s.temp[j] - 25.0) * (s.tau[j] * s.tau[j] - s.tau0_sq[j]))
                .sum();
            rb * i * i + thermal
        };
        let data = synth(11, 80, &effect);
        let mut sel = select(&data, &all(), &RULE).unwrap();
        // Each beats the other in flexible form (the rule after all stages).
        super::super::parsimony::apply(&data, &mut sel, None, &RULE).unwrap();
        let ids: Vec<&str> = sel.accepted.iter().map(|s| s.id.as_str()).collect();
        assert!(
            ids.contains(&"bus_loss") && ids.contains(&"thermal"),
            "accepted {ids:?}"
        );
        // Every claim carries its stability, at or above the gate.
        let stable = super::super::parsimony::STABLE;
        assert!(
            (sel.accepted.iter()).all(|a| a.stability.is_some_and(|s| s >= stable)),
            "{:?}",
            sel.accepted.iter().map(|a| a.stability).collect::<Vec<_>>()
        );
        let final_theta = &sel.last.full.theta;
        let pos = |id: &str| sel.last.spec.iter().position(|h| h.id == id).unwrap() + N_PARAMS;
        assert!((final_theta[pos("bus_loss")] - rb).abs() < 0.1 * rb);
        assert!(
            (final_theta[pos("thermal")] - alpha).abs() < 0.1 * alpha,
            "α = {}",
            final_theta[pos("thermal")]
        );
        assert!(power_hypothesis("thermal").is_some());
    }
}
