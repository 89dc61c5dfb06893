//! Bound-constrained linear least squares: min ‖Φθ − y‖² subject to lower ≤ θ ≤ upper.
//!
//! Solved by the interior-point QP solver clarabel on P = ΦᵀΦ, q = −Φᵀy with the bounds as a
//! nonnegative cone (the paper solved the same QP with IPOPT); the tests cross-check it against
//! the exact active-set method of [`super::bounded_quadratic`].
//!
//! It solves in scaled variables: every column of Φ is scaled to unit norm and y to unit norm, so solver
//! tolerances mean the same thing whatever the units of the regressors. Columns that are identically zero
//! carry no information; their parameter is pinned to the feasible value closest to 0 and reported as
//! unidentifiable. [`kkt_check`] verifies any solution against the optimality conditions.

use std::time::Instant;

use anyhow::{Result, anyhow, bail, ensure};
use nalgebra::{DMatrix, DVector};

use super::Gram;
use crate::N_PARAMS;

/// The solver a fit used (recorded in model files).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// clarabel interior-point QP.
    Clarabel,
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("clarabel")
    }
}

/// How a solver finished (only finishes that leave a usable solution; anything else is an error).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Status {
    /// Converged to the requested accuracy.
    Solved,
    /// Converged to the reduced accuracy clarabel accepts.
    AlmostSolved,
    /// Stopped at the iteration limit with primal and dual residuals below 1e-6.
    MaxIterations,
    /// Stopped for lack of progress with primal and dual residuals below 1e-6.
    InsufficientProgress,
}

impl std::fmt::Display for Status {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        std::fmt::Debug::fmt(self, f)
    }
}

/// A bound-constrained least-squares problem's constraints and regularisation.
#[derive(Debug, Clone, PartialEq)]
pub struct Bounds {
    /// Lower bound per column (`f64::NEG_INFINITY` = unbounded below).
    pub lower: Vec<f64>,
    /// Upper bound per column (`f64::INFINITY` = unbounded above).
    pub upper: Vec<f64>,
    /// Ridge weight λ ≥ 0: adds λ Σ_j ‖φ_j‖² θ_j² to the objective (‖φ_j‖ = column norm), i.e. λ‖x‖² in the
    /// unit-column scaled variables, so λ is dimensionless and independent of the regressors' units.
    pub ridge: f64,
}

impl Bounds {
    /// Lower bounds only, no ridge.
    pub fn lower(lower: &[f64]) -> Self {
        Bounds {
            lower: lower.to_vec(),
            upper: vec![f64::INFINITY; lower.len()],
            ridge: 0.0,
        }
    }
}

/// How the solver ran.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SolverInfo {
    /// Solver.
    pub method: Method,
    /// Final status.
    pub status: Status,
    /// Interior-point iterations.
    pub iterations: u32,
    /// Wall time of the whole fit including preparation [s].
    pub time_s: f64,
}

/// Result of a constrained fit.
#[derive(Debug, Clone, PartialEq)]
pub struct Fit {
    /// Estimated parameters θ, one per column of Φ.
    pub theta: Vec<f64>,
    /// Standard error of each parameter from the residual variance and (Φ_FᵀΦ_F)⁻¹ on the free set F;
    /// `None` for parameters held at a bound (or pinned because their column is zero).
    pub std_err: Vec<Option<f64>>,
    /// True where the parameter sits at one of its bounds (an active constraint).
    pub at_bound: Vec<bool>,
    /// Columns that are identically zero (no data excites them); their θ is pinned, not estimated.
    pub unidentifiable: Vec<usize>,
    /// Residual sum of squares ‖Φθ − y‖² (without the ridge term).
    pub rss: f64,
    /// Number of rows used.
    pub n_rows: usize,
    /// Solver status, iterations and time.
    pub solver: SolverInfo,
}

impl Fit {
    /// θ as the 49-vector of the power model (errors if the fit had another number of columns).
    pub fn theta49(&self) -> Result<[f64; N_PARAMS]> {
        self.theta.as_slice().try_into().map_err(|_| {
            anyhow!(
                "fit has {} parameters, the power model needs {N_PARAMS}",
                self.theta.len()
            )
        })
    }
}

/// The paper's constraints: a_i ≥ 1 (inverse gear efficiency), every other parameter ≥ 0.
pub fn paper_lower_bounds() -> [f64; N_PARAMS] {
    let mut lower = [0.0; N_PARAMS];
    lower[..crate::N_JOINTS].fill(1.0);
    lower
}

/// Stack 49-wide regressor rows into a matrix.
pub fn rows_to_matrix(phi: &[[f64; N_PARAMS]]) -> DMatrix<f64> {
    DMatrix::from_fn(phi.len(), N_PARAMS, |i, j| phi[i][j])
}

/// The paper's fit: min ‖Φθ − y‖² s.t. θ ≥ lower.
pub fn fit_constrained(phi: &[[f64; N_PARAMS]], y: &[f64], lower: &[f64; N_PARAMS]) -> Result<Fit> {
    fit_general(
        &rows_to_matrix(phi),
        &DVector::from_column_slice(y),
        &Bounds::lower(lower),
    )
}

/// The general fit: any number of columns, lower/upper bounds, optional ridge.
pub fn fit_general(phi: &DMatrix<f64>, y: &DVector<f64>, bounds: &Bounds) -> Result<Fit> {
    let start = Instant::now();
    let prep = Prepared::new(phi, y, bounds)?;
    solve(&prep, bounds, phi.nrows(), start, |theta, x| {
        let rss = (phi * DVector::from_column_slice(theta) - y).norm_squared();
        (rss, prep.rss_scaled(x))
    })
}

/// The same problem as [`fit_general`] given only the normal equations of the rows (ΦᵀΦ, Φᵀy,
/// yᵀy, n: a [`Gram`]), so rows that were never held together can be fitted. The Gram matrix is
/// turned into at most p rows with the same normal equations (ΦᵀΦ = RᵀR, Φᵀy = Rᵀz from its
/// eigen-decomposition; eigenvalues below 1e-14 of the largest are dropped) and those are solved;
/// the residual sum of squares, the row count and the standard errors are those of the original
/// rows (from yᵀy and n), not of the compressed ones.
pub fn fit_gram(gram: &Gram, bounds: &Bounds) -> Result<Fit> {
    let start = Instant::now();
    let p = gram.columns();
    ensure!(
        gram.n > 0,
        "empty least-squares problem (0 rows, {p} columns)"
    );
    let (phi, y) = compress_gram(gram);
    let prep = Prepared::new(&phi, &y, bounds)?;
    solve(&prep, bounds, gram.n, start, |theta, _| {
        let rss = gram.sse(&DVector::from_column_slice(theta));
        // The original rows' residuals in the compressed problem's y scale.
        (rss, rss / (prep.y_norm * prep.y_norm))
    })
}

/// At most p rows (R, z) with RᵀR = ΦᵀΦ and Rᵀz = Φᵀy of the rows behind `gram`. A column that
/// is identically zero (ΦᵀΦ_jj = 0) stays exactly zero, so it is pinned as unidentifiable.
fn compress_gram(gram: &Gram) -> (DMatrix<f64>, DVector<f64>) {
    let p = gram.columns();
    let eig = nalgebra::SymmetricEigen::new(gram.g.clone());
    let cutoff = eig.eigenvalues.max().max(0.0) * 1e-14;
    let keep: Vec<usize> = (0..p).filter(|&k| eig.eigenvalues[k] > cutoff).collect();
    let zero: Vec<bool> = (0..p).map(|j| gram.g[(j, j)] == 0.0).collect();
    let mut phi = DMatrix::zeros(keep.len().max(1), p);
    let mut y = DVector::zeros(keep.len().max(1));
    for (i, &k) in keep.iter().enumerate() {
        let v = eig.eigenvectors.column(k);
        let s = eig.eigenvalues[k].sqrt();
        for j in 0..p {
            if !zero[j] {
                phi[(i, j)] = s * v[j];
            }
        }
        y[i] = v.dot(&gram.h) / s;
    }
    (phi, y)
}

/// The [`Fit`] of `prep` solved: `rss(θ, x)` gives the residual sum of squares of the `n_rows`
/// rows behind it, as is and in the scaled variables x.
fn solve(
    prep: &Prepared,
    bounds: &Bounds,
    n_rows: usize,
    start: Instant,
    rss: impl FnOnce(&[f64], &[f64]) -> (f64, f64),
) -> Result<Fit> {
    let (x, free, status, iterations) = solve_clarabel(prep)?;
    let theta = prep.unscale(&x);
    let (rss, rss_scaled) = rss(&theta, &x);
    let n = theta.len();
    let mut at_bound = vec![false; n];
    let mut std_err = vec![None; n];
    let dof = n_rows.saturating_sub(free.iter().filter(|&&f| f).count());
    let se_scaled = if dof > 0 {
        std_errors_scaled(&prep.r, &free, rss_scaled / dof as f64)
    } else {
        None
    };
    for (k, &col) in prep.cols.iter().enumerate() {
        at_bound[col] = !free[k];
        if free[k] {
            std_err[col] = se_scaled
                .as_ref()
                .and_then(|se| se[k])
                .map(|s| s * prep.y_norm / prep.col_norm[k]);
        }
    }
    for &col in &prep.zero_cols {
        at_bound[col] = theta[col] == bounds.lower[col] || theta[col] == bounds.upper[col];
    }
    Ok(Fit {
        theta,
        std_err,
        at_bound,
        unidentifiable: prep.zero_cols.clone(),
        rss,
        n_rows,
        solver: SolverInfo {
            method: Method::Clarabel,
            status,
            iterations,
            time_s: start.elapsed().as_secs_f64(),
        },
    })
}

/// The problem in scaled variables x_k = ‖φ_k‖ θ_k / ‖y‖ over the non-zero columns, reduced by a thin QR of
/// the (ridge-augmented) scaled matrix to the square-ish system ‖R x − c‖ (same minimiser, same conditioning
/// as Φ rather than the squared conditioning of the normal equations).
struct Prepared {
    /// Columns of Φ that take part (non-zero).
    cols: Vec<usize>,
    /// Columns of Φ that are identically zero.
    zero_cols: Vec<usize>,
    /// Norm of each participating column.
    col_norm: Vec<f64>,
    /// ‖y‖ (1 when y = 0).
    y_norm: f64,
    /// Scaled bounds of the participating columns.
    lo: Vec<f64>,
    hi: Vec<f64>,
    /// Scaled ridge weight.
    ridge: f64,
    r: DMatrix<f64>,
    c: DVector<f64>,
    /// ‖b‖² − ‖c‖²: the part of the scaled objective no x can reduce.
    rss_floor: f64,
    /// Full θ with the pinned values of zero columns (the rest is overwritten by `unscale`).
    pinned: Vec<f64>,
}

impl Prepared {
    fn new(phi: &DMatrix<f64>, y: &DVector<f64>, bounds: &Bounds) -> Result<Self> {
        let (m, n) = phi.shape();
        ensure!(
            m > 0 && n > 0,
            "empty least-squares problem ({m} rows, {n} columns)"
        );
        ensure!(y.len() == m, "y has {} values but Φ has {m} rows", y.len());
        ensure!(
            bounds.lower.len() == n && bounds.upper.len() == n,
            "bounds have {} lower and {} upper values for {n} columns",
            bounds.lower.len(),
            bounds.upper.len()
        );
        ensure!(
            bounds.ridge.is_finite() && bounds.ridge >= 0.0,
            "ridge weight {} must be finite and ≥ 0",
            bounds.ridge
        );
        for j in 0..n {
            let (lo, hi) = (bounds.lower[j], bounds.upper[j]);
            ensure!(
                !lo.is_nan()
                    && !hi.is_nan()
                    && lo <= hi
                    && lo < f64::INFINITY
                    && hi > f64::NEG_INFINITY,
                "invalid bounds for column {j}: [{lo}, {hi}]"
            );
        }
        if let Some(i) = y.iter().position(|v| !v.is_finite()) {
            bail!("target y[{i}] = {} is not finite", y[i]);
        }
        let mut cols = Vec::new();
        let mut zero_cols = Vec::new();
        let mut col_norm = Vec::new();
        let mut pinned = vec![0.0; n];
        for (j, pin) in pinned.iter_mut().enumerate() {
            let col = phi.column(j);
            if let Some(i) = col.iter().position(|v| !v.is_finite()) {
                bail!("regressor Φ[{i}][{j}] = {} is not finite", col[i]);
            }
            let norm = col.norm();
            if norm > 0.0 {
                cols.push(j);
                col_norm.push(norm);
            } else {
                zero_cols.push(j);
                *pin = 0.0f64.clamp(bounds.lower[j], bounds.upper[j]);
            }
        }
        ensure!(
            !cols.is_empty(),
            "every regressor column is zero: nothing to fit"
        );
        let y_norm = if y.norm() > 0.0 { y.norm() } else { 1.0 };
        let k = cols.len();
        let ridge_rows = if bounds.ridge > 0.0 { k } else { 0 };
        let mut a = DMatrix::zeros(m + ridge_rows, k);
        for (kk, &j) in cols.iter().enumerate() {
            for i in 0..m {
                a[(i, kk)] = phi[(i, j)] / col_norm[kk];
            }
            if ridge_rows > 0 {
                a[(m + kk, kk)] = bounds.ridge.sqrt();
            }
        }
        let mut b = DVector::zeros(m + ridge_rows);
        for i in 0..m {
            b[i] = y[i] / y_norm;
        }
        let scale = |v: f64, kk: usize| {
            if v.is_finite() {
                v * col_norm[kk] / y_norm
            } else {
                v
            }
        };
        let scaled =
            |b: &[f64]| (cols.iter().enumerate().map(|(kk, &j)| scale(b[j], kk))).collect();
        let (lo, hi) = (scaled(&bounds.lower), scaled(&bounds.upper));
        let qr = a.qr();
        let c = qr.q().transpose() * &b;
        let r = qr.r();
        let rss_floor = (b.norm_squared() - c.norm_squared()).max(0.0);
        Ok(Prepared {
            cols,
            zero_cols,
            col_norm,
            y_norm,
            lo,
            hi,
            ridge: bounds.ridge,
            r,
            c,
            rss_floor,
            pinned,
        })
    }

    fn unscale(&self, x: &[f64]) -> Vec<f64> {
        let mut theta = self.pinned.clone();
        for (kk, &j) in self.cols.iter().enumerate() {
            theta[j] = x[kk] * self.y_norm / self.col_norm[kk];
        }
        theta
    }

    /// Scaled residual sum of squares of the data rows only (ridge excluded).
    fn rss_scaled(&self, x: &[f64]) -> f64 {
        let xv = DVector::from_column_slice(x);
        let total = (&self.r * &xv - &self.c).norm_squared() + self.rss_floor;
        (total - self.ridge * xv.norm_squared()).max(0.0)
    }
}

/// clarabel on ½xᵀ(RᵀR)x − (Rᵀc)ᵀx with each finite bound as one row of a nonnegative cone.
fn solve_clarabel(p: &Prepared) -> Result<(Vec<f64>, Vec<bool>, Status, u32)> {
    use clarabel::algebra::CscMatrix;
    use clarabel::solver::{
        DefaultSettings, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
    };

    let k = p.r.ncols();
    let gram = p.r.transpose() * &p.r;
    let q: Vec<f64> = (-(p.r.transpose() * &p.c)).iter().copied().collect();
    // Upper triangle of P in compressed-column form.
    let mut colptr = vec![0usize];
    let mut rowval = Vec::with_capacity(k * (k + 1) / 2);
    let mut nzval = Vec::with_capacity(k * (k + 1) / 2);
    for j in 0..k {
        for i in 0..=j {
            rowval.push(i);
            nzval.push(gram[(i, j)]);
        }
        colptr.push(rowval.len());
    }
    let pmat = CscMatrix::new(k, k, colptr, rowval, nzval);
    // A x + s = b, s ≥ 0: −x_j ≤ −lo_j and x_j ≤ hi_j. `rows` remembers (variable, is_lower) per row.
    let mut triplets = (Vec::new(), Vec::new(), Vec::new());
    let mut bvec = Vec::new();
    let mut rows = Vec::new();
    for j in 0..k {
        for (bound, sign, is_lower) in [(p.lo[j], -1.0, true), (p.hi[j], 1.0, false)] {
            if bound.is_finite() {
                triplets.0.push(bvec.len());
                triplets.1.push(j);
                triplets.2.push(sign);
                bvec.push(sign * bound);
                rows.push((j, is_lower));
            }
        }
    }
    let amat = CscMatrix::new_from_triplets(bvec.len(), k, triplets.0, triplets.1, triplets.2);
    let cones = if bvec.is_empty() {
        vec![]
    } else {
        vec![SupportedConeT::NonnegativeConeT(bvec.len())]
    };
    let settings = DefaultSettings::<f64> {
        verbose: false,
        tol_gap_abs: 1e-12,
        tol_gap_rel: 1e-12,
        tol_feas: 1e-12,
        tol_ktratio: 1e-9,
        max_iter: 100,
        ..DefaultSettings::default()
    };
    let mut solver = DefaultSolver::new(&pmat, &q, &amat, &bvec, &cones, settings)
        .map_err(|e| anyhow!("clarabel rejected the problem: {e:?}"))?;
    solver.solve();
    let sol = &solver.solution;
    let status = match sol.status {
        SolverStatus::Solved => Status::Solved,
        SolverStatus::AlmostSolved => Status::AlmostSolved,
        // Iteration/progress limits still leave a usable point when the gap is already small.
        SolverStatus::MaxIterations if sol.r_prim < 1e-6 && sol.r_dual < 1e-6 => {
            Status::MaxIterations
        }
        SolverStatus::InsufficientProgress if sol.r_prim < 1e-6 && sol.r_dual < 1e-6 => {
            Status::InsufficientProgress
        }
        other => bail!("clarabel did not solve the least-squares problem: status {other:?}"),
    };
    // A bound is active when its slack is smaller than its multiplier (the interior-point iterate's
    // complementarity pairs s·z → 0 from opposite sides).
    let mut free = vec![true; k];
    let mut x = sol.x.clone();
    for (row, &(j, is_lower)) in rows.iter().enumerate() {
        if sol.s[row] < sol.z[row] {
            free[j] = false;
            x[j] = if is_lower { p.lo[j] } else { p.hi[j] };
        }
    }
    Ok((x, free, status, sol.iterations))
}

/// Standard errors of the free variables in scaled units: sqrt(σ² [(R_FᵀR_F)⁻¹]_jj). `None` per variable when
/// the free columns are rank deficient (that parameter is not identifiable from these rows).
fn std_errors_scaled(r: &DMatrix<f64>, free: &[bool], sigma2: f64) -> Option<Vec<Option<f64>>> {
    let free_idx: Vec<usize> = (0..free.len()).filter(|&j| free[j]).collect();
    let mut out = vec![None; free.len()];
    if free_idx.is_empty() {
        return Some(out);
    }
    let svd = r.select_columns(free_idx.iter()).svd(false, true);
    let v_t = svd.v_t.as_ref()?;
    let smax = svd.singular_values.max();
    for (k, &j) in free_idx.iter().enumerate() {
        // [(RᵀR)⁻¹]_kk = Σ_i V_ki² / s_i²; a (numerically) zero singular value with weight on k makes it unbounded.
        let mut var = 0.0;
        let mut bounded = true;
        for (i, &s) in svd.singular_values.iter().enumerate() {
            let v = v_t[(i, k)];
            if s <= 1e-13 * smax {
                if v.abs() > 1e-8 {
                    bounded = false;
                }
            } else {
                var += v * v / (s * s);
            }
        }
        if bounded {
            out[j] = Some((sigma2 * var).sqrt());
        }
    }
    Some(out)
}

/// How far a candidate θ is from satisfying the optimality (KKT) conditions of the bound-constrained
/// problem, in the unit-column, unit-y scaling (so 1e-8 means the same for any units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KktReport {
    /// Largest bound violation.
    pub primal_infeasibility: f64,
    /// Largest gradient of the wrong sign: positive gradient where the lower bound is −∞ or the variable is
    /// not at it, negative where the upper bound is +∞ (unbounded directions must have zero gradient).
    pub dual_infeasibility: f64,
    /// Largest multiplier × slack product (a bound with a nonzero multiplier must be active).
    pub complementarity: f64,
    /// Largest component of the natural residual x − clip(x − ∇, lo, hi); zero exactly at the optimum.
    pub natural_residual: f64,
}

impl KktReport {
    /// The largest of the four measures.
    pub fn max_violation(&self) -> f64 {
        self.primal_infeasibility
            .max(self.dual_infeasibility)
            .max(self.complementarity)
            .max(self.natural_residual)
    }
}

/// Check θ against the KKT conditions of min ‖Φθ − y‖² + ridge term s.t. bounds.
pub fn kkt_check(
    phi: &DMatrix<f64>,
    y: &DVector<f64>,
    theta: &[f64],
    bounds: &Bounds,
) -> Result<KktReport> {
    let n = phi.ncols();
    ensure!(
        theta.len() == n && bounds.lower.len() == n && bounds.upper.len() == n,
        "dimension mismatch in kkt_check"
    );
    let y_norm = if y.norm() > 0.0 { y.norm() } else { 1.0 };
    let th = DVector::from_column_slice(theta);
    let grad_raw = phi.transpose() * (phi * &th - y);
    let mut rep = KktReport {
        primal_infeasibility: 0.0,
        dual_infeasibility: 0.0,
        complementarity: 0.0,
        natural_residual: 0.0,
    };
    for j in 0..n {
        let norm = phi.column(j).norm();
        if norm == 0.0 {
            continue;
        }
        // Scaled variable x = ‖φ_j‖θ/‖y‖; gradient of the scaled objective ½‖Ax − b‖² + ½λ‖x‖².
        let s = norm / y_norm;
        let x = theta[j] * s;
        let (lo, hi) = (bounds.lower[j] * s, bounds.upper[j] * s);
        let g = grad_raw[j] / (norm * y_norm) + bounds.ridge * x;
        rep.primal_infeasibility = rep.primal_infeasibility.max(lo - x).max(x - hi);
        let (mult_lo, mult_hi) = (g.max(0.0), (-g).max(0.0));
        let slack_lo = x - lo;
        let slack_hi = hi - x;
        if !lo.is_finite() {
            rep.dual_infeasibility = rep.dual_infeasibility.max(mult_lo);
        } else {
            rep.complementarity = rep.complementarity.max(mult_lo * slack_lo.max(0.0));
        }
        if !hi.is_finite() {
            rep.dual_infeasibility = rep.dual_infeasibility.max(mult_hi);
        } else {
            rep.complementarity = rep.complementarity.max(mult_hi * slack_hi.max(0.0));
        }
        rep.natural_residual = rep.natural_residual.max((x - (x - g).clamp(lo, hi)).abs());
    }
    Ok(rep)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rows with correlated columns, one column identically zero and one parameter pushed
    /// against its bound, plus noise (a fixed linear congruential sequence).
    fn problem() -> (DMatrix<f64>, DVector<f64>) {
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let m = 300;
        let phi = DMatrix::from_fn(m, 5, |_, j| if j == 3 { 0.0 } else { next() });
        let phi = DMatrix::from_fn(m, 5, |i, j| match j {
            1 => phi[(i, 1)] + 0.9 * phi[(i, 0)],
            _ => phi[(i, j)],
        });
        let truth = [2.0, -0.5, 1.5, 0.0, 0.7];
        let y = DVector::from_fn(m, |i, _| {
            (0..5).map(|j| phi[(i, j)] * truth[j]).sum::<f64>() + 0.05 * next()
        });
        (phi, y)
    }

    #[test]
    fn fit_from_the_normal_equations_equals_the_fit_of_the_rows() {
        let (phi, y) = problem();
        let mut gram = Gram::zeros(5);
        for i in 0..phi.nrows() {
            let row: Vec<f64> = phi.row(i).iter().copied().collect();
            gram.add_row(&row, y[i]);
        }
        let bounds = Bounds::lower(&[1.0, 0.0, 0.0, 0.0, 0.0]);
        let rows = fit_general(&phi, &y, &bounds).unwrap();
        let normal = fit_gram(&gram, &bounds).unwrap();
        assert_eq!(normal.n_rows, phi.nrows());
        assert_eq!(normal.unidentifiable, vec![3]);
        assert_eq!(normal.at_bound, rows.at_bound);
        assert!(
            rows.at_bound[1],
            "the second parameter is held at its bound"
        );
        for (a, b) in rows.theta.iter().zip(&normal.theta) {
            assert!((a - b).abs() < 1e-6, "θ {a} vs {b}");
        }
        assert!((rows.rss - normal.rss).abs() < 1e-9 * rows.rss, "rss");
        for (a, b) in rows.std_err.iter().zip(&normal.std_err) {
            match (a, b) {
                (Some(a), Some(b)) => {
                    assert!((a - b).abs() < 1e-6 * a, "std err {a} vs {b}")
                }
                _ => assert_eq!(a.is_some(), b.is_some(), "std err"),
            }
        }
        assert!(normal.std_err[0].is_some() && normal.std_err[1].is_none());
    }

    #[test]
    fn fit_from_empty_normal_equations_is_an_error() {
        let err = fit_gram(&Gram::zeros(3), &Bounds::lower(&[0.0; 3]));
        assert!(err.unwrap_err().to_string().contains("0 rows"));
    }
}
