//! The model fitting of the selection stages: trials assigned to cross-validation folds, one
//! Gram matrix per fold, the bounded fit of the base model plus hypotheses, its held-out
//! predictions, and the power-level data (rows and Grams at each scanned sensor lag).

use anyhow::Result;
use nalgebra::{DMatrix, DVector};
use rand::SeedableRng;
use rand::seq::SliceRandom;

use crate::diagnose::hypotheses::{Combine, Hypothesis, N_RAW};
use crate::diagnose::reading_rows::Rows;
use crate::diagnose::stats::{encompassing, improvement_p_value};
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
        let mut b = FoldGramsBuilder::new(N_RAW, folds.k);
        b.add_rows(rows, folds);
        b.finish()
    }

    pub(crate) fn train(&self, f: usize) -> Gram {
        self.total.minus(&self.fold[f])
    }

    /// `spec` fitted on each fold's training rows (base refitted, or held at `reference`).
    pub(crate) fn fits(
        &self,
        spec: &[&'static Hypothesis],
        reference: Option<&[f64]>,
    ) -> Result<Vec<Fitted>> {
        (0..self.fold.len())
            .map(|f| fit(spec, &self.train(f), reference))
            .collect()
    }
}

/// [`FoldGrams`] of `p` columns accumulated from rows given piece by piece (a trial at a time):
/// the same sums, in the same order, as [`FoldGrams::new`] on all the rows at once. Every
/// held-out fit by folds (the power rows, the torque rows, the rest power's blocks) sums here.
pub(crate) struct FoldGramsBuilder {
    fold: Vec<Gram>,
}

impl FoldGramsBuilder {
    pub fn new(p: usize, k: usize) -> FoldGramsBuilder {
        FoldGramsBuilder {
            fold: vec![Gram::zeros(p); k],
        }
    }

    /// Add row `x` with target `y` to fold `f`.
    pub fn add(&mut self, f: usize, x: &[f64], y: f64) {
        self.fold[f].add_row(x, y);
    }

    /// Add `rows` (their `trial` indexes `folds`).
    pub fn add_rows(&mut self, rows: &Rows, folds: &Folds) {
        for r in 0..rows.len() {
            self.add(folds.of_trial[rows.trial[r]], &rows.x[r], rows.y[r]);
        }
    }

    pub fn finish(self) -> FoldGrams {
        let mut total = Gram::zeros(self.fold[0].columns());
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

impl Fitted {
    /// The prediction of raw row `x`.
    pub fn predict(&self, x: &[f64]) -> f64 {
        crate::diagnose::family::dot(x, self.beta.as_slice())
    }
}

/// Raw layout → model coefficients map for `spec`, weights of pooled terms from `theta`.
pub(crate) fn design_map(spec: &[&Hypothesis], theta: &[f64]) -> DMatrix<f64> {
    let p = N_PARAMS + spec.len();
    let mut m = DMatrix::zeros(N_RAW, p);
    for i in 0..N_PARAMS {
        m[(i, i)] = 1.0;
    }
    for (j, h) in spec.iter().enumerate() {
        let (off, len) = h.raw;
        for i in 0..len {
            m[(N_PARAMS + off + i, N_PARAMS + j)] = h.weight(theta, i);
        }
    }
    m
}

/// Bounds of the base model: the paper's constraints (a ≥ 1, all other base parameters ≥ 0), or
/// lo = hi = the reference θ when the base is held at a reference (twin) model. Hypothesis
/// coefficients are free (their physical plausibility is judged after the fit, so a wrong-signed
/// fit is visible).
pub(crate) fn bounds(p: usize, reference: Option<&[f64]>) -> (Vec<f64>, Vec<f64>) {
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
/// with the weak Gaussian prior (mean: the paper's θ) on the first [`N_PARAMS`] (base) coefficients. Solved in Gram space
/// by [`bounded_quadratic`] (thousands of small fits per diagnosis; checked against the
/// identification's clarabel fit in the tests).
pub(crate) fn solve_bounded(
    g: &DMatrix<f64>,
    h: &DVector<f64>,
    lo: &[f64],
    hi: &[f64],
) -> Result<DVector<f64>> {
    let prior = PowerModel::PAPER.to_vector();
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
    let theta = solve_bounded(&g, &h, &lo, &hi)?;
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
    let fitted = fg.fits(spec, reference)?;
    let pred = (0..rows.len())
        .map(|r| fitted[folds.of_trial[rows.trial[r]]].predict(&rows.x[r]))
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

/// The paired one-sided p-value by trial ([`improvement_p_value`] of the per-trial
/// [`encompassing`] evidence at `lambda`) that predictions `a` of readings `y` improve on `b`:
/// `lambda` [`EXTENDS`](crate::diagnose::stats::EXTENDS) when `a`'s model extends `b`'s, ½ (the squared-error difference) when
/// they are alternatives ([`p_better`]).
pub(crate) fn p_improves(
    y: &[f64],
    (a, b): (&[f64], &[f64]),
    trial: &[usize],
    n: usize,
    lambda: f64,
) -> f64 {
    improvement_p_value(&encompassing(y, (a, b), trial, n, lambda))
}

/// [`p_improves`] of two alternatives: that predictions `a` fit readings `y` better than `b`.
pub(crate) fn p_better(y: &[f64], a: &[f64], b: &[f64], trial: &[usize], n_trials: usize) -> f64 {
    p_improves(y, (a, b), trial, n_trials, 0.5)
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

    pub(crate) fn reference(&self) -> Option<&[f64]> {
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
