//! Least-squares sufficient statistics: the normal equations of a row set, accumulated row by row.
//!
//! A [`Gram`] holds ΦᵀΦ, Φᵀy, yᵀy and the row count; two of them add and subtract (the fold
//! complement of a cross-validation is `total − fold`), any coefficient vector's residual sum of
//! squares follows without the rows, and so does κ(ΦᵀΦ). Millions of rows never need a matrix.

use nalgebra::{DMatrix, DVector};

/// ΦᵀΦ, Φᵀy, yᵀy and n of a set of rows with `p` columns.
#[derive(Debug, Clone, PartialEq)]
pub struct Gram {
    /// ΦᵀΦ (p × p, symmetric).
    pub g: DMatrix<f64>,
    /// Φᵀy.
    pub h: DVector<f64>,
    /// yᵀy.
    pub yy: f64,
    /// Rows accumulated.
    pub n: usize,
}

impl Gram {
    /// The statistics of no rows.
    pub fn zeros(p: usize) -> Gram {
        Gram {
            g: DMatrix::zeros(p, p),
            h: DVector::zeros(p),
            yy: 0.0,
            n: 0,
        }
    }

    /// Number of columns.
    pub fn columns(&self) -> usize {
        self.h.len()
    }

    /// Add one row `x` with target `y` (x.len() = p; zero entries are skipped).
    pub fn add_row(&mut self, x: &[f64], y: f64) {
        let p = x.len();
        let g = self.g.as_mut_slice();
        for (c, &xc) in x.iter().enumerate() {
            if xc == 0.0 {
                continue;
            }
            let col = &mut g[c * p..(c + 1) * p];
            for (gv, &xr) in col.iter_mut().zip(x) {
                *gv += xr * xc;
            }
        }
        for (hv, &xr) in self.h.iter_mut().zip(x) {
            *hv += xr * y;
        }
        self.yy += y * y;
        self.n += 1;
    }

    /// Add another row set's statistics (same columns).
    pub fn add(&mut self, other: &Gram) {
        self.g += &other.g;
        self.h += &other.h;
        self.yy += other.yy;
        self.n += other.n;
    }

    /// The statistics of `self`'s rows without `other`'s (which must be a subset of them).
    pub fn minus(&self, other: &Gram) -> Gram {
        Gram {
            g: &self.g - &other.g,
            h: &self.h - &other.h,
            yy: self.yy - other.yy,
            n: self.n - other.n,
        }
    }

    /// Sum of squared residuals ‖Φβ − y‖² of coefficients `beta`.
    pub fn sse(&self, beta: &DVector<f64>) -> f64 {
        (self.yy - 2.0 * beta.dot(&self.h) + beta.dot(&(&self.g * beta))).max(0.0)
    }

    /// The least-squares coefficients (Cholesky of ΦᵀΦ, SVD when it is singular); `None` when
    /// they are not finite.
    pub fn solve(&self) -> Option<DVector<f64>> {
        let sol = match self.g.clone().cholesky() {
            Some(ch) => ch.solve(&self.h),
            None => self.g.clone().svd(true, true).solve(&self.h, 1e-10).ok()?,
        };
        sol.iter().all(|v| v.is_finite()).then_some(sol)
    }

    /// The coefficients and their classical standard errors (residual variance × (ΦᵀΦ)⁻¹ᵢᵢ,
    /// n − p degrees of freedom); `None` when ΦᵀΦ is singular or n ≤ p.
    pub fn solve_with_se(&self) -> Option<(DVector<f64>, DVector<f64>)> {
        let p = self.columns();
        let inv = self.g.clone().cholesky()?.inverse();
        let beta = &inv * &self.h;
        let dof = self.n.checked_sub(p).filter(|&d| d > 0)? as f64;
        let s2 = self.sse(&beta) / dof;
        let se = DVector::from_iterator(p, (0..p).map(|i| (s2 * inv[(i, i)]).max(0.0).sqrt()));
        beta.iter().all(|v| v.is_finite()).then_some((beta, se))
    }

    /// κ(ΦᵀΦ) = λ_max/λ_min; ∞ when singular (see [`super::condition_number_gram`]).
    pub fn condition_number(&self) -> f64 {
        super::condition_number_gram(&self.g)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn statistics_match_the_rows() {
        let rows = [
            ([1.0, 0.0, 2.0], 1.0),
            ([0.5, -1.0, 0.0], 2.0),
            ([3.0, 1.0, 1.0], -1.0),
        ];
        let mut all = Gram::zeros(3);
        let mut first = Gram::zeros(3);
        for (k, (x, y)) in rows.iter().enumerate() {
            all.add_row(x, *y);
            if k == 0 {
                first.add_row(x, *y);
            }
        }
        let phi = DMatrix::from_fn(3, 3, |r, c| rows[r].0[c]);
        let y = DVector::from_fn(3, |r, _| rows[r].1);
        assert!((&all.g - phi.transpose() * &phi).norm() < 1e-12);
        assert!((&all.h - phi.transpose() * &y).norm() < 1e-12);
        let beta = DVector::from_vec(vec![0.3, -0.2, 0.1]);
        assert!((all.sse(&beta) - (&phi * &beta - &y).norm_squared()).abs() < 1e-12);
        let rest = all.minus(&first);
        assert_eq!(rest.n, 2);
        let mut back = rest.clone();
        back.add(&first);
        assert!((&back.g - &all.g).norm() < 1e-12);
    }
}
