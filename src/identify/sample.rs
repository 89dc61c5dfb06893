//! The per-sample fit (`--mode sample`) in bounded memory: each trial's sample rows are reduced,
//! as soon as they are built, to their sufficient statistics — ΦᵀΦ, Φᵀy, yᵀy, n and the sums Σφ,
//! Σy — which is all the constrained fit (from the normal equations, [`crate::lsq::fit_gram`]) and
//! the rejection by trial (a trial's mean residual is (Σy − θ·Σφ)/n) need. A paper-scale session
//! has ~1e6 sample rows (~0.5 GB as rows); its statistics take ~20 kB per trial. The fit's quality
//! (residual moments, mean absolute residual) needs the final θ, so the sample rows of the
//! retained trials are built once more and scored one at a time
//! ([`crate::lsq::MetricsAccumulator`]).

use std::collections::HashSet;

use super::dataset::{Dataset, Row, Skipped, TrialBasis};
use super::fit::predict;
use crate::N_PARAMS;
use crate::lsq::{Gram, MetricsAccumulator};

/// The sufficient statistics of one trial's sample rows.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct TrialSums {
    /// Trial index.
    pub trial: usize,
    /// ΦᵀΦ, Φᵀy, yᵀy and n.
    gram: Gram,
    /// Σφ over the rows.
    sum_phi: [f64; N_PARAMS],
    /// Σy.
    sum_y: f64,
}

impl TrialSums {
    /// The statistics of one trial's rows (all of trial `trial`).
    pub(crate) fn from_rows(trial: usize, rows: &[Row]) -> TrialSums {
        let mut s = TrialSums {
            trial,
            gram: Gram::zeros(N_PARAMS),
            sum_phi: [0.0; N_PARAMS],
            sum_y: 0.0,
        };
        for row in rows {
            s.gram.add_row(&row.phi, row.y);
            for (s, &x) in s.sum_phi.iter_mut().zip(&row.phi) {
                *s += x;
            }
            s.sum_y += row.y;
        }
        s
    }

    /// Add these statistics to `g`.
    pub(crate) fn add_to(&self, g: &mut Gram) {
        g.add(&self.gram);
    }

    /// The trial's mean residual y − θᵀφ over its rows (NaN without rows).
    pub(crate) fn mean_residual(&self, theta: &[f64; N_PARAMS]) -> f64 {
        (self.sum_y - predict(theta, &self.sum_phi)) / self.gram.n as f64
    }
}

/// The sample-mode rows of a session, reduced trial by trial.
#[derive(Debug, Clone, Default)]
pub(crate) struct SampleSums {
    /// Per-trial statistics of every trial that has rows, in session order.
    pub sums: Vec<TrialSums>,
    /// Per-trial baselines of those trials.
    pub trials: Vec<TrialBasis>,
    /// Trials without rows.
    pub skipped: Vec<Skipped>,
}

impl SampleSums {
    /// Reduce one trial's data set (built in sample mode) and keep its statistics.
    pub(crate) fn add(&mut self, set: Dataset) {
        if let Some(basis) = set.trials.first() {
            self.sums.push(TrialSums::from_rows(basis.trial, &set.rows));
        }
        self.trials.extend(set.trials);
        self.skipped.extend(set.skipped);
    }

    /// The part that belongs to the trials with the given indices.
    pub(crate) fn restrict(&self, keep: &HashSet<usize>) -> SampleSums {
        SampleSums {
            sums: of_trials(&self.sums, keep, |s| s.trial),
            trials: of_trials(&self.trials, keep, |b| b.trial),
            skipped: of_trials(&self.skipped, keep, |s| s.trial),
        }
    }
}

/// The items of `items` whose trial (`trial_of`) is in `keep`.
pub(crate) fn of_trials<T: Clone>(
    items: &[T],
    keep: &HashSet<usize>,
    trial_of: impl Fn(&T) -> usize,
) -> Vec<T> {
    let kept = items.iter().filter(|x| keep.contains(&trial_of(x)));
    kept.cloned().collect()
}

/// Score `theta` on sample rows handed over trial by trial.
pub(crate) fn score_rows(acc: &mut MetricsAccumulator, theta: &[f64; N_PARAMS], rows: &[Row]) {
    for row in rows {
        acc.add(row.y, predict(theta, &row.phi));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(trial: usize, k: usize) -> Row {
        let x = k as f64;
        Row {
            trial,
            t: x,
            t0: x,
            t1: x,
            phi: std::array::from_fn(|p| {
                if p % 5 == 3 {
                    0.0
                } else {
                    ((p * 7 + k * 3) % 11) as f64 - 4.0 + 0.1 * x
                }
            }),
            y: 3.0 * x - 1.0,
            sigma_omega: 0.0,
            tau0_sq: [0.0; crate::N_JOINTS],
        }
    }

    #[test]
    fn trial_statistics_equal_the_normal_equations_of_the_rows() {
        let rows: Vec<Row> = (0..40).map(|k| row(2, k)).collect();
        let sums = TrialSums::from_rows(2, &rows);
        let mut direct = Gram::zeros(N_PARAMS);
        for r in &rows {
            direct.add_row(&r.phi, r.y);
        }
        let mut from_sums = Gram::zeros(N_PARAMS);
        sums.add_to(&mut from_sums);
        assert_eq!(from_sums.n, 40);
        assert!((&from_sums.g - &direct.g).norm() <= 1e-12 * direct.g.norm());
        assert!((&from_sums.h - &direct.h).norm() <= 1e-12 * direct.h.norm());
        assert!((from_sums.yy - direct.yy).abs() <= 1e-12 * direct.yy);
        let theta: [f64; N_PARAMS] = std::array::from_fn(|p| 0.01 * p as f64);
        let mean = rows
            .iter()
            .map(|r| r.y - predict(&theta, &r.phi))
            .sum::<f64>()
            / 40.0;
        assert!((sums.mean_residual(&theta) - mean).abs() < 1e-9);
        assert!(TrialSums::from_rows(0, &[]).mean_residual(&theta).is_nan());
    }
}
