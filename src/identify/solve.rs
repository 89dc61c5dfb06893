//! TEMPORARY stand-in for IDENT-A's solver (same API subset) so the pipeline builds before it
//! lands: Lawson–Hanson active-set NNLS on θ − lower. Take IDENT-A's file on merge.
#![allow(missing_docs)]
use crate::{N_JOINTS, N_PARAMS};
use anyhow::Result;
use nalgebra::{DMatrix, DVector};

pub struct Fit {
    pub theta: Vec<f64>,
}

impl Fit {
    pub fn theta49(&self) -> Result<[f64; N_PARAMS]> {
        let mut out = [0.0; N_PARAMS];
        out.copy_from_slice(&self.theta);
        Ok(out)
    }
}

pub fn paper_lower_bounds() -> [f64; N_PARAMS] {
    std::array::from_fn(|p| if p < N_JOINTS { 1.0 } else { 0.0 })
}

pub fn fit_constrained(phi: &[[f64; N_PARAMS]], y: &[f64], lower: &[f64; N_PARAMS]) -> Result<Fit> {
    let m = phi.len();
    let a = DMatrix::from_fn(m, N_PARAMS, |r, c| phi[r][c]);
    let l = DVector::from_column_slice(lower);
    let b = DVector::from_column_slice(y) - &a * &l;
    let ata = a.transpose() * &a;
    let atb = a.transpose() * &b;
    let mut x = DVector::zeros(N_PARAMS);
    let mut passive = [false; N_PARAMS];
    for _ in 0..500 {
        let w = &atb - &ata * &x;
        let cand = (0..N_PARAMS)
            .filter(|&j| !passive[j] && w[j] > 1e-10 * (1.0 + atb.amax()))
            .max_by(|&i, &j| w[i].total_cmp(&w[j]));
        let Some(j) = cand else { break };
        passive[j] = true;
        loop {
            let idx: Vec<usize> = (0..N_PARAMS).filter(|&k| passive[k]).collect();
            let sub = DMatrix::from_fn(idx.len(), idx.len(), |r, c| {
                ata[(idx[r], idx[c])]
                    + if r == c {
                        1e-12 * (1.0 + ata[(idx[r], idx[r])])
                    } else {
                        0.0
                    }
            });
            let rhs = DVector::from_iterator(idx.len(), idx.iter().map(|&k| atb[k]));
            let z = sub
                .lu()
                .solve(&rhs)
                .unwrap_or_else(|| DVector::zeros(idx.len()));
            if z.iter().all(|&v| v > 0.0) {
                for (p, &k) in idx.iter().enumerate() {
                    x[k] = z[p];
                }
                break;
            }
            let mut alpha: f64 = 1.0;
            for (p, &k) in idx.iter().enumerate() {
                if z[p] <= 0.0 {
                    alpha = alpha.min(x[k] / (x[k] - z[p]));
                }
            }
            for (p, &k) in idx.iter().enumerate() {
                x[k] += alpha * (z[p] - x[k]);
            }
            for &k in &idx {
                if x[k] <= 1e-14 {
                    passive[k] = false;
                    x[k] = 0.0;
                }
            }
        }
    }
    Ok(Fit {
        theta: (0..N_PARAMS).map(|k| x[k] + lower[k]).collect(),
    })
}
