//! The least-squares steps identification applies to its rows: the paper's constrained fit of
//! any number of rows, fit quality, κ(ΦᵀΦ), per-trial mean residuals and term means.

use anyhow::Result;

use super::dataset::Row;
use crate::N_PARAMS;
use crate::lsq::{self, Gram, Metrics};
use crate::power::{PowerModel, TermMeans};
use crate::trial::TrialStat;

/// θᵀφ.
pub(crate) fn predict(theta: &[f64; N_PARAMS], phi: &[f64; N_PARAMS]) -> f64 {
    theta.iter().zip(phi).map(|(t, v)| t * v).sum()
}

/// Normal equations of the rows.
fn gram(rows: &[Row]) -> Gram {
    let mut g = Gram::zeros(N_PARAMS);
    for row in rows {
        g.add_row(&row.phi, row.y);
    }
    g
}

/// κ(ΦᵀΦ) of the rows' raw (unscaled) regressors; ∞ when singular.
pub fn kappa(rows: &[Row]) -> f64 {
    gram(rows).condition_number()
}

/// The paper's constrained fit (a ≥ 1, the rest ≥ 0) of any number of rows, from their normal
/// equations ([`fit_normal`]), and κ(ΦᵀΦ) ([`kappa`]) from the same.
pub(crate) fn fit_rows(rows: &[Row]) -> Result<(lsq::Fit, f64)> {
    let normal = gram(rows);
    Ok((fit_normal(&normal)?, normal.condition_number()))
}

/// The paper's constrained fit from the normal equations of the rows ([`lsq::fit_gram`]: the
/// same minimiser; the residual sum of squares and standard errors are those of the rows).
pub(crate) fn fit_normal(normal: &Gram) -> Result<lsq::Fit> {
    lsq::fit_gram(normal, &lsq::Bounds::lower(&lsq::paper_lower_bounds()))
}

/// Fit quality of θ on the rows.
pub(crate) fn quality(theta: &[f64; N_PARAMS], rows: &[Row]) -> Metrics {
    let y: Vec<f64> = rows.iter().map(|r| r.y).collect();
    let yhat: Vec<f64> = rows.iter().map(|r| predict(theta, &r.phi)).collect();
    Metrics::compute(&y, &yhat)
}

/// Mean residual per (session, trial) of `rows` (session, row), grouped by session and trial.
pub(crate) fn trial_residuals<'r>(
    theta: &[f64; N_PARAMS],
    rows: impl IntoIterator<Item = (usize, &'r Row)>,
) -> Vec<TrialStat> {
    let mut out: Vec<TrialStat> = Vec::new();
    let mut count = 0usize;
    for (session, row) in rows {
        let r = row.y - predict(theta, &row.phi);
        match out.last_mut() {
            Some(last) if last.session == session && last.trial == row.trial => {
                count += 1;
                last.value += (r - last.value) / count as f64;
            }
            _ => {
                out.push(TrialStat::new(session, row.trial, r));
                count = 1;
            }
        }
    }
    out
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
