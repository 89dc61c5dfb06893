//! Box-constrained convex quadratic programme, the solver behind every diagnosis fit.
//! (Private stand-in until `identify::solve::fit_constrained_general` lands on main.)

use anyhow::{Result, bail};
use clarabel::algebra::CscMatrix;
use clarabel::solver::{DefaultSettingsBuilder, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus};
use nalgebra::{DMatrix, DVector};

/// Minimise ½θᵀGθ − hᵀθ subject to lo ≤ θ ≤ hi (infinite bounds are dropped). G must be
/// symmetric positive definite.
pub(crate) fn bounded_quadratic(g: &DMatrix<f64>, h: &DVector<f64>, lo: &[f64], hi: &[f64]) -> Result<Vec<f64>> {
    let p = h.len();
    // Upper triangle of G in compressed-column form.
    let mut colptr = vec![0usize];
    let mut rowval = Vec::new();
    let mut nzval = Vec::new();
    for j in 0..p {
        for i in 0..=j {
            let v = g[(i, j)];
            if v != 0.0 {
                rowval.push(i);
                nzval.push(v);
            }
        }
        colptr.push(rowval.len());
    }
    let pm = CscMatrix::new(p, p, colptr, rowval, nzval);
    let q: Vec<f64> = h.iter().map(|v| -v).collect();
    // Rows of A: −θ_i ≤ −lo_i and θ_i ≤ hi_i for the finite bounds.
    let mut entries: Vec<(usize, f64, f64)> = Vec::new(); // (column, coefficient, rhs)
    for i in 0..p {
        if lo[i].is_finite() {
            entries.push((i, -1.0, -lo[i]));
        }
        if hi[i].is_finite() {
            entries.push((i, 1.0, hi[i]));
        }
    }
    let m = entries.len();
    let mut by_col: Vec<Vec<(usize, f64)>> = vec![Vec::new(); p];
    let mut b = Vec::with_capacity(m);
    for (row, &(col, coef, rhs)) in entries.iter().enumerate() {
        by_col[col].push((row, coef));
        b.push(rhs);
    }
    let mut colptr = vec![0usize];
    let mut rowval = Vec::new();
    let mut nzval = Vec::new();
    for col in &by_col {
        for &(r, v) in col {
            rowval.push(r);
            nzval.push(v);
        }
        colptr.push(rowval.len());
    }
    let a = CscMatrix::new(m, p, colptr, rowval, nzval);
    let cones = [NonnegativeConeT(m)];
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .max_iter(200)
        .tol_gap_abs(1e-10)
        .tol_gap_rel(1e-10)
        .tol_feas(1e-10)
        .build()
        .map_err(|e| anyhow::anyhow!("solver settings: {e:?}"))?;
    let mut solver = DefaultSolver::new(&pm, &q, &a, &b, &cones, settings)
        .map_err(|e| anyhow::anyhow!("setting up the quadratic programme: {e:?}"))?;
    solver.solve();
    match solver.solution.status {
        SolverStatus::Solved | SolverStatus::AlmostSolved => Ok(solver.solution.x.clone()),
        s => bail!("quadratic programme not solved: {s:?}"),
    }
}
