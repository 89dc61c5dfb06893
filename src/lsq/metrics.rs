//! Goodness-of-fit metrics (R², RMSE, MAE, bias, residual skewness and kurtosis) and the condition number
//! κ(ΦᵀΦ) of a regressor matrix, as the paper reports them.
//!
//! Conventions: residual e_k = y_k − ŷ_k (measured − predicted); bias = mean(ŷ − y), so a negative bias is
//! under-prediction (the paper's "bias of −0.72 W (slight under-prediction)"). Skewness and kurtosis are the
//! population (biased) moment ratios of the residuals, m3/m2^{3/2} and m4/m2² — Pearson's kurtosis, 3 for a
//! normal distribution (the paper's 2.97), the same as `scipy.stats.kurtosis(e, fisher=False, bias=True)`.

use nalgebra::{DMatrix, SymmetricEigen};
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
    /// Compute the metrics of `yhat` against `y`. Uses the first min(len) pairs if the lengths differ
    /// (callers pass equal lengths); everything is NaN when there are no rows.
    pub fn compute(y: &[f64], yhat: &[f64]) -> Metrics {
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
}

/// κ(ΦᵀΦ) = λ_max/λ_min of the Gram matrix of 49-wide regressor rows. The Gram matrix is accumulated row by
/// row, so millions of per-sample rows need no big matrix. `f64::INFINITY` when ΦᵀΦ is singular. Values
/// above ~1e13 are at the limit of double precision (λ_min is then rounding noise) and mean "degenerate".
pub fn condition_number(phi: &[[f64; N_PARAMS]]) -> f64 {
    let mut gram = DMatrix::<f64>::zeros(N_PARAMS, N_PARAMS);
    for row in phi {
        for i in 0..N_PARAMS {
            if row[i] == 0.0 {
                continue;
            }
            for j in i..N_PARAMS {
                gram[(i, j)] += row[i] * row[j];
            }
        }
    }
    gram.fill_lower_triangle_with_upper_triangle();
    condition_number_gram(&gram)
}

/// κ(ΦᵀΦ) of any matrix Φ (from its singular values, κ = (σ_max/σ_min)²; fewer rows than columns → ∞).
pub fn condition_number_matrix(phi: &DMatrix<f64>) -> f64 {
    if phi.nrows() < phi.ncols() || phi.ncols() == 0 {
        return f64::INFINITY;
    }
    let sv = phi.singular_values();
    ratio(sv.max(), sv.min()).powi(2)
}

/// κ of a symmetric positive semi-definite matrix (λ_max/λ_min of its eigenvalues).
pub fn condition_number_gram(gram: &DMatrix<f64>) -> f64 {
    if gram.nrows() == 0 {
        return f64::INFINITY;
    }
    let eig = SymmetricEigen::new(gram.clone()).eigenvalues;
    ratio(eig.max(), eig.min())
}

fn ratio(max: f64, min: f64) -> f64 {
    if !(max.is_finite() && min.is_finite()) || min <= 0.0 {
        f64::INFINITY
    } else {
        max / min
    }
}
