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

    /// Add a block of rows at once (`rows` holds them one after another, p values each, `y` their
    /// targets) by one matrix product: the statistics of [`Gram::add_row`] on each up to
    /// rounding (the products are summed in another order), at a fraction of its cost.
    pub fn add_rows(&mut self, rows: &[f64], y: &[f64]) {
        let x = DMatrix::from_column_slice(self.columns(), y.len(), rows);
        let y = DVector::from_column_slice(y);
        self.g.gemm(1.0, &x, &x.transpose(), 1.0);
        self.h.gemv(1.0, &x, &y, 1.0);
        self.yy += y.dot(&y);
        self.n += y.len();
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

    /// κ(ΦᵀΦ) = λ_max/λ_min of the eigenvalues; ∞ when singular.
    pub fn condition_number(&self) -> f64 {
        if self.g.nrows() == 0 {
            return f64::INFINITY;
        }
        let eig = nalgebra::SymmetricEigen::new(self.g.clone()).eigenvalues;
        super::metrics::ratio(eig.max(), eig.min())
    }

    /// The same rows with `extra` more columns, all zero for now (a design being extended:
    /// the new columns' sums are added by the caller).
    pub fn widened(&self, extra: usize) -> Gram {
        let p = self.columns();
        let mut w = Gram::zeros(p + extra);
        w.g.view_mut((0, 0), (p, p)).copy_from(&self.g);
        w.h.rows_mut(0, p).copy_from(&self.h);
        w.yy = self.yy;
        w.n = self.n;
        w
    }

    /// The unconstrained least-squares coefficients (see [`solve_normal`]), with a ridge of
    /// `ridge` × the largest diagonal entry for columns that never moved.
    pub fn solve(&self, ridge: f64) -> Option<DVector<f64>> {
        solve_normal(&self.g, &self.h, ridge)
    }

    /// [`Gram::solve`] on the first `p` columns only (a nested model), padded with zeros.
    pub fn solve_leading(&self, p: usize, ridge: f64) -> Option<DVector<f64>> {
        let g = self.g.view((0, 0), (p, p)).into_owned();
        let h = self.h.rows(0, p).into_owned();
        let sol = solve_normal(&g, &h, ridge)?;
        let mut full = DVector::zeros(self.columns());
        full.rows_mut(0, p).copy_from(&sol);
        Some(full)
    }
}

/// The one unconstrained solve of the crate: `(G + ridge·max diag(G)·I) β = rhs` by Cholesky,
/// and by SVD (least-norm) when the system is singular. `rhs` may have several columns. None
/// only when the result is not finite.
pub fn solve_normal<C: nalgebra::Dim, S: nalgebra::storage::Storage<f64, nalgebra::Dyn, C>>(
    g: &DMatrix<f64>,
    rhs: &nalgebra::Matrix<f64, nalgebra::Dyn, C, S>,
    ridge: f64,
) -> Option<nalgebra::OMatrix<f64, nalgebra::Dyn, C>>
where
    nalgebra::DefaultAllocator: nalgebra::allocator::Allocator<nalgebra::Dyn, C>,
{
    let mut a = g.clone();
    if ridge > 0.0 {
        let scale = a.diagonal().iter().copied().fold(0.0, f64::max).max(1e-300);
        for i in 0..a.nrows() {
            a[(i, i)] += ridge * scale;
        }
    }
    let sol = match a.clone().cholesky() {
        Some(ch) => ch.solve(rhs),
        None => a.svd(true, true).solve(rhs, 1e-10).ok()?,
    };
    sol.iter().all(|v| v.is_finite()).then_some(sol)
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
        // The block product gives the same statistics up to rounding.
        let mut block = Gram::zeros(3);
        let flat: Vec<f64> = rows.iter().flat_map(|(x, _)| *x).collect();
        block.add_rows(&flat, &rows.map(|(_, y)| y));
        assert!((&block.g - &all.g).norm() + (&block.h - &all.h).norm() < 1e-12);
        assert!((block.yy - all.yy).abs() < 1e-12 && block.n == all.n);
        assert!((&all.h - phi.transpose() * &y).norm() < 1e-12);
        let beta = DVector::from_vec(vec![0.3, -0.2, 0.1]);
        assert!((all.sse(&beta) - (&phi * &beta - &y).norm_squared()).abs() < 1e-12);
        let rest = all.minus(&first);
        assert_eq!(rest.n, 2);
        let mut back = rest.clone();
        back.add(&first);
        assert!((&back.g - &all.g).norm() < 1e-12);
    }

    #[test]
    fn solve_agrees_with_an_independent_qr_and_falls_back_when_singular() {
        // Well-posed: the Cholesky path against an SVD least-squares solve of the rows themselves.
        let x = DMatrix::from_row_slice(4, 2, &[1.0, 0.5, 2.0, -1.0, 0.0, 3.0, 1.5, 1.0]);
        let y = DVector::from_vec(vec![1.0, -2.0, 0.5, 4.0]);
        let mut gram = Gram::zeros(2);
        for r in 0..4 {
            gram.add_row(&[x[(r, 0)], x[(r, 1)]], y[r]);
        }
        let rows = x.clone().svd(true, true).solve(&y, 1e-12).expect("svd");
        let beta = gram.solve(0.0).expect("well-posed");
        assert!((beta - &rows).norm() < 1e-10);
        // Singular (a column that never moved): SVD gives the least-norm solution, the dead
        // column's coefficient 0 and the live one's exact.
        let mut dead = Gram::zeros(2);
        for r in 0..4 {
            dead.add_row(&[x[(r, 0)], 0.0], y[r]);
        }
        let b = dead.solve(0.0).expect("least-norm");
        let exact = dead.h[0] / dead.g[(0, 0)];
        assert!(b[1].abs() < 1e-12 && (b[0] - exact).abs() < 1e-10);
        let lead = gram.solve_leading(1, 0.0).expect("nested");
        assert!((lead[0] - gram.h[0] / gram.g[(0, 0)]).abs() < 1e-12 && lead[1] == 0.0);
        let wide = gram.widened(1);
        assert_eq!((wide.columns(), wide.n), (3, 4));
        assert_eq!(wide.g[(2, 2)], 0.0);
    }
}
