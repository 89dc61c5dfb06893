//! The fit of the library model plus a candidate's columns: cross-validated by fold of
//! trials and on all data, from the library design's fold Grams.

use anyhow::Result;

use crate::N_PARAMS;
use crate::diagnose::Quality;
use crate::diagnose::reading_rows::Rows;
use crate::diagnose::select::{Held, PowerData, State, bic, bounds, design_map, solve_bounded};
use crate::lsq::Gram;

/// Result of fitting the current model plus extra columns.
pub(crate) struct ExtFit {
    /// Held-out prediction per reading.
    pub(crate) pred: Vec<f64>,
    /// Coefficients of the extra columns per fold.
    pub(super) fold_gamma: Vec<Vec<f64>>,
    /// Coefficients of the extra columns on all data.
    pub(super) gamma: Vec<f64>,
    pub(super) bic: f64,
}

/// The library model's design on each row (x_raw · M), fold Grams of it, and the data.
pub(crate) struct Base<'a, 'd> {
    pub(super) data: &'a PowerData<'d>,
    pub(super) cur: &'a State,
    pub(super) rows: &'a Rows,
    pub(super) xm: Vec<Vec<f64>>,
    /// The normal equations of each fold's rows.
    pub(super) fold: Vec<Gram>,
    pub(super) p: usize,
}

impl<'a, 'd> Base<'a, 'd> {
    /// The design of model `cur` on its rows.
    pub(crate) fn new(data: &'a PowerData<'d>, cur: &'a State) -> Result<Base<'a, 'd>> {
        let rows = data.rows(cur.lag)?;
        let m = design_map(&cur.spec, &cur.full.theta);
        let p = m.ncols();
        let xm: Vec<Vec<f64>> = rows
            .x
            .iter()
            .map(|x| {
                (0..p)
                    .map(|c| (0..x.len()).map(|r| x[r] * m[(r, c)]).sum())
                    .collect()
            })
            .collect();
        let k = data.folds.k;
        let mut fold = vec![Gram::zeros(p); k];
        for (r, x) in xm.iter().enumerate() {
            fold[data.folds.of_trial[rows.trial[r]]].add_row(x, rows.y[r]);
        }
        Ok(Base {
            data,
            cur,
            rows,
            xm,
            fold,
            p,
        })
    }

    /// Cross-validated and full fit of the library model plus `cols`.
    pub(crate) fn fit(&self, cols: &[&Vec<f64>]) -> Result<ExtFit> {
        let (p, q, k) = (self.p, cols.len(), self.data.folds.k);
        let n = p + q;
        // Per fold Gram of the extended design.
        let mut fg: Vec<Gram> = self.fold.iter().map(|g| g.widened(q)).collect();
        for (r, x) in self.xm.iter().enumerate() {
            let f = self.data.folds.of_trial[self.rows.trial[r]];
            let Gram { g, h, .. } = &mut fg[f];
            let y = self.rows.y[r];
            for (j, c) in cols.iter().enumerate() {
                let e = c[r];
                if e == 0.0 {
                    continue;
                }
                h[p + j] += e * y;
                // Column p + j of the (column-major) Gram: the base design, then the columns.
                let col = &mut g.as_mut_slice()[(p + j) * n..(p + j + 1) * n];
                let (base, ext) = col.split_at_mut(p);
                base.iter_mut().zip(x).for_each(|(v, xa)| *v += xa * e);
                ext.iter_mut().zip(cols).for_each(|(v, c2)| *v += c2[r] * e);
            }
        }
        for Gram { g, .. } in fg.iter_mut() {
            for j in p..n {
                for a in 0..p {
                    g[(j, a)] = g[(a, j)];
                }
            }
        }
        let mut total = Gram::zeros(n);
        for g in &fg {
            total.add(g);
        }
        let (lo, hi) = bounds(n, self.data.reference.as_deref());
        let mut fold_theta = Vec::with_capacity(k);
        for g in &fg {
            let train = total.minus(g);
            fold_theta.push(solve_bounded(&train.g, &train.h, &lo, &hi)?);
        }
        let full = solve_bounded(&total.g, &total.h, &lo, &hi)?;
        let pred = (0..self.rows.len())
            .map(|r| {
                let th = &fold_theta[self.data.folds.of_trial[self.rows.trial[r]]];
                let base: f64 = self.xm[r].iter().zip(th.iter()).map(|(a, b)| a * b).sum();
                base + cols
                    .iter()
                    .enumerate()
                    .map(|(j, c)| c[r] * th[p + j])
                    .sum::<f64>()
            })
            .collect();
        let sse = total.sse(&full);
        let n_free = if self.data.reference.is_some() {
            0
        } else {
            N_PARAMS
        } + self.cur.spec.len()
            + usize::from(self.cur.lag != 0)
            + q;
        Ok(ExtFit {
            pred,
            fold_gamma: fold_theta
                .iter()
                .map(|t| t.iter().skip(p).copied().collect())
                .collect(),
            gamma: full.iter().skip(p).copied().collect(),
            bic: bic(sse, total.n, n_free),
        })
    }

    /// Compare predictions `after` with `before`: (p, rel improvement, before, after quality).
    pub(super) fn compare(&self, before: &[f64], after: &[f64]) -> (f64, f64, Quality, Quality) {
        let (rows, nt) = (self.rows, self.data.n_trials);
        crate::diagnose::stats::log_p("discovery", &rows.y, after, before, &rows.trial, nt);
        let h = Held::new(&rows.y, before, after, &rows.trial, nt);
        (h.p_value, h.gain(), h.before, h.after)
    }
}
