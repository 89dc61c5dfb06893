//! Box-constrained convex quadratic programme on normal equations (the diagnosis fits are
//! ≤ 60 parameters on a pre-computed Gram matrix): an exact primal active-set method. It works in
//! Gram space, where the identification's solvers work on rows; a diagnosis runs thousands of
//! these fits, and this form is several times faster. Checked against the identification's clarabel fit.

use anyhow::{Result, bail};
use nalgebra::{DMatrix, DVector};

/// Minimise ½θᵀGθ − hᵀθ subject to lo ≤ θ ≤ hi (infinite bounds allowed; lo = hi fixes a
/// variable). G must be symmetric positive definite. Exact (finite active-set iterations, each a Cholesky solve of the free block).
pub fn bounded_quadratic(
    g: &DMatrix<f64>,
    h: &DVector<f64>,
    lo: &[f64],
    hi: &[f64],
) -> Result<Vec<f64>> {
    let p = h.len();
    // Feasible start: 0 clamped into the box; variables starting on a finite bound are held there.
    let mut x: Vec<f64> = (0..p).map(|i| 0.0f64.clamp(lo[i], hi[i])).collect();
    let mut free: Vec<bool> = (0..p).map(|i| x[i] > lo[i] && x[i] < hi[i]).collect();
    for _ in 0..10 * p + 20 {
        // Solve for the free variables with the bound ones fixed.
        let idx: Vec<usize> = (0..p).filter(|&i| free[i]).collect();
        let mut target = x.clone();
        if !idx.is_empty() {
            let gff = DMatrix::from_fn(idx.len(), idx.len(), |a, b| g[(idx[a], idx[b])]);
            let rhs = DVector::from_fn(idx.len(), |a, _| {
                let i = idx[a];
                h[i] - (0..p)
                    .filter(|&j| !free[j])
                    .map(|j| g[(i, j)] * x[j])
                    .sum::<f64>()
            });
            let Some(ch) = gff.cholesky() else {
                bail!("normal equations are not positive definite")
            };
            let sol = ch.solve(&rhs);
            for (a, &i) in idx.iter().enumerate() {
                target[i] = sol[a];
            }
        }
        // Step towards the target until the first bound is hit.
        let mut step = 1.0f64;
        let mut blocking = None;
        for &i in &idx {
            let d = target[i] - x[i];
            let room = if d < 0.0 {
                (lo[i] - x[i]) / d
            } else if d > 0.0 {
                (hi[i] - x[i]) / d
            } else {
                f64::INFINITY
            };
            if room < step {
                step = room.max(0.0);
                blocking = Some((i, d < 0.0));
            }
        }
        for &i in &idx {
            x[i] += step * (target[i] - x[i]);
        }
        if let Some((i, hit_lo)) = blocking {
            x[i] = if hit_lo { lo[i] } else { hi[i] };
            free[i] = false;
            continue;
        }
        // Optimal on the free set: release the bound variable whose gradient most wants inside.
        let grad: Vec<f64> = (0..p)
            .map(|i| g.row(i).iter().zip(&x).map(|(a, b)| a * b).sum::<f64>() - h[i])
            .collect();
        let scale = (0..p).map(|i| h[i].abs()).fold(0.0, f64::max).max(1e-300);
        let mut worst = None;
        let mut worst_v = 1e-12 * scale;
        for i in (0..p).filter(|&i| !free[i] && lo[i] < hi[i]) {
            let at_lo = x[i] <= lo[i];
            let v = if at_lo { -grad[i] } else { grad[i] };
            if v > worst_v {
                worst_v = v;
                worst = Some(i);
            }
        }
        match worst {
            Some(i) => free[i] = true,
            None => return Ok(x),
        }
    }
    bail!("bounded least squares did not converge")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_hand_solved_box_problems() {
        // min ½(x² + y²) − (2x − 3y), 0 ≤ x ≤ 1, y ≥ −1: unconstrained (2, −3) → (1, −1).
        let g = DMatrix::identity(2, 2);
        let h = DVector::from_vec(vec![2.0, -3.0]);
        let x = bounded_quadratic(&g, &h, &[0.0, -1.0], &[1.0, f64::INFINITY]).unwrap();
        assert!((x[0] - 1.0).abs() < 1e-12 && (x[1] + 1.0).abs() < 1e-12);
        // Coupled: G = [[2,1],[1,2]], h = [1, −4], x ≥ 0 → y at 0, x = ½.
        let g = DMatrix::from_row_slice(2, 2, &[2.0, 1.0, 1.0, 2.0]);
        let h = DVector::from_vec(vec![1.0, -4.0]);
        let x = bounded_quadratic(&g, &h, &[0.0, 0.0], &[f64::INFINITY; 2]).unwrap();
        assert!((x[0] - 0.5).abs() < 1e-12 && x[1].abs() < 1e-12);
        // Free problem = linear solve.
        let x = bounded_quadratic(&g, &h, &[f64::NEG_INFINITY; 2], &[f64::INFINITY; 2]).unwrap();
        assert!((2.0 * x[0] + x[1] - 1.0).abs() < 1e-12 && (x[0] + 2.0 * x[1] + 4.0).abs() < 1e-12);
    }

    #[test]
    fn agrees_with_the_identification_clarabel_fit_on_random_problems() {
        use crate::lsq::{Bounds, fit_general};
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        for _ in 0..20 {
            let (m, p) = (40, 12);
            let phi = DMatrix::from_fn(m, p, |_, _| rng.random_range(-1.0..1.0));
            let y = DVector::from_fn(m, |_, _| rng.random_range(-2.0..2.0));
            let lo: Vec<f64> = (0..p)
                .map(|j| if j % 3 == 0 { f64::NEG_INFINITY } else { 0.0 })
                .collect();
            let hi: Vec<f64> = (0..p)
                .map(|j| if j % 4 == 0 { 0.2 } else { f64::INFINITY })
                .collect();
            let g = phi.transpose() * &phi;
            let h = phi.transpose() * &y;
            let ours = bounded_quadratic(&g, &h, &lo, &hi).unwrap();
            let bounds = Bounds {
                lower: lo.clone(),
                upper: hi.clone(),
                ridge: 0.0,
            };
            let theirs = fit_general(&phi, &y, &bounds).unwrap().theta;
            for j in 0..p {
                assert!(
                    (ours[j] - theirs[j]).abs() < 1e-7,
                    "θ{j}: {} vs {}",
                    ours[j],
                    theirs[j]
                );
            }
        }
    }
}
