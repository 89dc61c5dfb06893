//! Goodness-of-fit metrics (R², RMSE, MAE, bias, residual skewness and kurtosis) and the condition number
//! κ(ΦᵀΦ) of a regressor matrix, as the paper reports them.
//!
//! Conventions: residual e_k = y_k − ŷ_k (measured − predicted); bias = mean(ŷ − y), so a negative bias is
//! under-prediction (the paper's "bias of −0.72 W (slight under-prediction)"). Skewness and kurtosis are the
//! population (biased) moment ratios of the residuals, m3/m2^{3/2} and m4/m2² — Pearson's kurtosis, 3 for a
//! normal distribution (the paper's 2.97), the same as `scipy.stats.kurtosis(e, fisher=False, bias=True)`.

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use crate::N_PARAMS;

/// Fit quality of predictions ŷ against measurements y.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    /// Number of rows.
    pub n: usize,
    /// Coefficient of determination 1 − SS_res/SS_tot (NaN when y is constant or n = 0).
    #[serde(with = "crate::util::nan_as_null")]
    pub r2: f64,
    /// Root-mean-square residual [W].
    #[serde(with = "crate::util::nan_as_null")]
    pub rmse: f64,
    /// Mean absolute residual [W].
    #[serde(with = "crate::util::nan_as_null")]
    pub mae: f64,
    /// Mean of ŷ − y [W] (negative = under-prediction).
    #[serde(with = "crate::util::nan_as_null")]
    pub bias: f64,
    /// Residual skewness m3/m2^{3/2} (NaN when the residuals are constant).
    #[serde(with = "crate::util::nan_as_null")]
    pub skewness: f64,
    /// Residual kurtosis m4/m2² (Pearson; 3 for a normal distribution; NaN when the residuals are constant).
    #[serde(with = "crate::util::nan_as_null")]
    pub kurtosis: f64,
}

impl Metrics {
    /// Compute the metrics of `yhat` against `y` ([`MetricsAccumulator`] over the pairs). Uses
    /// the first min(len) pairs if the lengths differ (callers pass equal lengths); everything is
    /// NaN when there are no rows.
    pub fn compute(y: &[f64], yhat: &[f64]) -> Metrics {
        let mut acc = MetricsAccumulator::default();
        y.iter().zip(yhat).for_each(|(&y, &p)| acc.add(y, p));
        acc.finish()
    }
}

/// [`Metrics`] accumulated one (y, ŷ) pair at a time, so rows that are never held together can
/// be scored: running means with Welford's update of the sum of squares and Pébay's of the third
/// and fourth central moments of the residuals (the one computation of [`Metrics`]).
#[derive(Debug, Clone, Default)]
pub struct MetricsAccumulator {
    n: usize,
    mean_y: f64,
    ss_tot: f64,
    ss_res: f64,
    abs_sum: f64,
    mean_e: f64,
    m2: f64,
    m3: f64,
    m4: f64,
}

impl MetricsAccumulator {
    /// Add one measurement `y` and its prediction `yhat`.
    pub fn add(&mut self, y: f64, yhat: f64) {
        let n0 = self.n as f64;
        self.n += 1;
        let n = self.n as f64;
        let dy = y - self.mean_y;
        self.mean_y += dy / n;
        self.ss_tot += dy * (y - self.mean_y);
        let e = y - yhat;
        self.ss_res += e * e;
        self.abs_sum += e.abs();
        let delta = e - self.mean_e;
        let dn = delta / n;
        let dn2 = dn * dn;
        let term = delta * dn * n0;
        self.mean_e += dn;
        self.m4 += term * dn2 * (n * n - 3.0 * n + 3.0) + 6.0 * dn2 * self.m2 - 4.0 * dn * self.m3;
        self.m3 += term * dn * (n - 2.0) - 3.0 * dn * self.m2;
        self.m2 += term;
    }

    /// The metrics of the pairs added so far (everything NaN without any).
    pub fn finish(&self) -> Metrics {
        let nf = self.n as f64;
        let (m2, m3, m4) = (self.m2 / nf, self.m3 / nf, self.m4 / nf);
        let nan_if_zero = |den: f64, v: f64| if den > 0.0 { v } else { f64::NAN };
        Metrics {
            n: self.n,
            r2: nan_if_zero(self.ss_tot, 1.0 - self.ss_res / self.ss_tot),
            rmse: (self.ss_res / nf).sqrt(),
            mae: self.abs_sum / nf,
            bias: if self.n == 0 { f64::NAN } else { -self.mean_e },
            skewness: nan_if_zero(m2, m3 / m2.powf(1.5)),
            kurtosis: nan_if_zero(m2, m4 / (m2 * m2)),
        }
    }
}

/// κ(ΦᵀΦ) = λ_max/λ_min of the Gram matrix of 49-wide regressor rows. The Gram matrix is accumulated row by
/// row, so millions of per-sample rows need no big matrix. `f64::INFINITY` when ΦᵀΦ is singular. Values
/// above ~1e13 are at the limit of double precision (λ_min is then rounding noise) and mean "degenerate".
pub fn condition_number(phi: &[[f64; N_PARAMS]]) -> f64 {
    let mut gram = super::Gram::zeros(N_PARAMS);
    for row in phi {
        gram.add_row(row, 0.0);
    }
    gram.condition_number()
}

/// κ(ΦᵀΦ) of any matrix Φ (from its singular values, κ = (σ_max/σ_min)²; fewer rows than columns → ∞).
pub fn condition_number_matrix(phi: &DMatrix<f64>) -> f64 {
    if phi.nrows() < phi.ncols() || phi.ncols() == 0 {
        return f64::INFINITY;
    }
    let sv = phi.singular_values();
    ratio(sv.max(), sv.min()).powi(2)
}

pub(super) fn ratio(max: f64, min: f64) -> f64 {
    if !(max.is_finite() && min.is_finite()) || min <= 0.0 {
        f64::INFINITY
    } else {
        max / min
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The textbook two-pass metrics, the reference the one-pass accumulator is checked against.
    fn two_pass(y: &[f64], yhat: &[f64]) -> Metrics {
        let n = y.len().min(yhat.len());
        let nf = n as f64;
        let pairs = || y.iter().zip(yhat).take(n);
        let mean_y = pairs().map(|(y, _)| y).sum::<f64>() / nf;
        let mean_e = pairs().map(|(y, p)| y - p).sum::<f64>() / nf;
        let (mut ss_res, mut ss_tot, mut abs_sum) = (0.0, 0.0, 0.0);
        let (mut m2, mut m3, mut m4) = (0.0, 0.0, 0.0);
        for (y, p) in pairs() {
            let e = y - p;
            ss_res += e * e;
            ss_tot += (y - mean_y) * (y - mean_y);
            abs_sum += e.abs();
            let d = e - mean_e;
            m2 += d * d;
            m3 += d * d * d;
            m4 += d * d * d * d;
        }
        let (m2, m3, m4) = (m2 / nf, m3 / nf, m4 / nf);
        let nan_if_zero = |den: f64, v: f64| if den > 0.0 { v } else { f64::NAN };
        Metrics {
            n,
            r2: nan_if_zero(ss_tot, 1.0 - ss_res / ss_tot),
            rmse: (ss_res / nf).sqrt(),
            mae: abs_sum / nf,
            bias: -mean_e,
            skewness: nan_if_zero(m2, m3 / m2.powf(1.5)),
            kurtosis: nan_if_zero(m2, m4 / (m2 * m2)),
        }
    }

    #[test]
    fn accumulated_metrics_equal_the_metrics_of_the_whole_set() {
        // Skewed residuals around a non-zero bias, y with a large offset (cancellation-prone).
        let y: Vec<f64> = (0..5000)
            .map(|i| 1000.0 + (i as f64 * 0.37).sin() * 20.0)
            .collect();
        let yhat: Vec<f64> = y
            .iter()
            .enumerate()
            .map(|(i, v)| v - 0.8 - ((i as f64 * 1.3).cos() + 1.0).powi(3))
            .collect();
        let whole = two_pass(&y, &yhat);
        let mut acc = MetricsAccumulator::default();
        for (a, b) in y.iter().zip(&yhat) {
            acc.add(*a, *b);
        }
        let part = acc.finish();
        assert_eq!(part.n, whole.n);
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1e-12);
        for (name, a, b) in [
            ("r2", part.r2, whole.r2),
            ("rmse", part.rmse, whole.rmse),
            ("mae", part.mae, whole.mae),
            ("bias", part.bias, whole.bias),
            ("skewness", part.skewness, whole.skewness),
            ("kurtosis", part.kurtosis, whole.kurtosis),
        ] {
            assert!(close(a, b), "{name}: {a} vs {b}");
        }
        assert!(whole.skewness > 0.1, "the residuals are skewed");
    }

    #[test]
    fn accumulated_metrics_of_constant_or_no_pairs_are_nan_like_the_whole_set() {
        let acc = MetricsAccumulator::default();
        let m = acc.finish();
        assert_eq!(m.n, 0);
        assert!(m.r2.is_nan() && m.rmse.is_nan() && m.bias.is_nan() && m.kurtosis.is_nan());
        let mut acc = MetricsAccumulator::default();
        for _ in 0..4 {
            acc.add(2.0, 1.5);
        }
        let (a, b) = (acc.finish(), two_pass(&[2.0; 4], &[1.5; 4]));
        assert!(a.r2.is_nan() && b.r2.is_nan() && a.skewness.is_nan() && b.skewness.is_nan());
        assert_eq!((a.rmse, a.mae, a.bias), (b.rmse, b.mae, b.bias));
    }
}
