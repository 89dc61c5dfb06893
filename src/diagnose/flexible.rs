//! The flexible forms [`super::parsimony`]'s rule and discovery fit a term's remainder with: a
//! term's regressor times a piecewise-linear function of the state it follows, its driving
//! share, an exponent and a threshold of it, each column scaled to unit RMS.

use crate::N_JOINTS;

/// Quantiles of a state at which its piecewise-linear function may bend.
const KNOTS: [f64; 3] = [0.25, 0.5, 0.75];

/// Whether joint `i` drives on raw row `x` (τ_i q̇_i > 0).
pub(crate) fn drives(x: &[f64], i: usize) -> bool {
    x[i] > 0.0
}

/// Whether the arm as a whole drives on raw row `x` (Σ τ_i q̇_i > 0).
pub(crate) fn arm_drives(x: &[f64]) -> bool {
    (0..N_JOINTS).map(|i| x[i]).sum::<f64>() > 0.0
}

/// The flexible columns of a term with regressor `g` (per reading), its driving share `driving`
/// and the state `s` it follows (per reading), each scaled to unit RMS; columns that are zero
/// everywhere are left out.
pub(crate) fn shape_cols(g: &[f64], driving: Vec<f64>, s: &[f64]) -> Vec<Vec<f64>> {
    let n = g.len().max(1) as f64;
    let g_bar = g.iter().map(|v| v.abs()).sum::<f64>() / n;
    let sign = g.iter().sum::<f64>().signum();
    let exponent = g.iter().map(|&v| match v.abs() / g_bar {
        r if r > 0.0 && r.is_finite() => v * r.ln(),
        _ => 0.0,
    });
    let threshold = g.iter().map(|v| sign * (v.abs() - g_bar).max(0.0));
    let mut cols = vec![driving, exponent.collect(), threshold.collect()];
    cols.extend(state_cols(g, s));
    unit_rms(&mut cols);
    cols
}

/// `g` times a piecewise-linear function of the state `s` without its constant: g·(s − mid) and
/// g·(s − k)₊ at the [`knots`] k (none for a constant state).
pub(crate) fn state_cols(g: &[f64], s: &[f64]) -> Vec<Vec<f64>> {
    let Some((mid, knots)) = knots(s) else {
        return Vec::new();
    };
    let mut cols = vec![g.iter().zip(s).map(|(v, x)| v * (x - mid)).collect()];
    for k in knots {
        cols.push(g.iter().zip(s).map(|(v, x)| v * (x - k).max(0.0)).collect());
    }
    cols
}

/// The midpoint of state `s`'s range and its distinct [`KNOTS`] strictly inside it (a knot at
/// an end would repeat the linear column); `None` for a constant state.
pub(crate) fn knots(s: &[f64]) -> Option<(f64, Vec<f64>)> {
    let mut sorted: Vec<f64> = s.iter().copied().filter(|v| v.is_finite()).collect();
    sorted.sort_by(f64::total_cmp);
    let (&lo, &hi) = (sorted.first()?, sorted.last()?);
    let mut k: Vec<f64> = KNOTS
        .map(|q| sorted[((sorted.len() - 1) as f64 * q) as usize])
        .to_vec();
    k.retain(|&v| v > lo && v < hi);
    k.dedup();
    (hi > lo).then_some((0.5 * (lo + hi), k))
}

/// Scale each column to unit RMS (non-finite values set to 0); columns zero everywhere are
/// left out.
pub(crate) fn unit_rms(cols: &mut Vec<Vec<f64>>) {
    for c in cols.iter_mut() {
        let n = c.len().max(1) as f64;
        c.iter_mut()
            .filter(|v| !v.is_finite())
            .for_each(|v| *v = 0.0);
        let rms = (c.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
        if rms > 0.0 {
            c.iter_mut().for_each(|v| *v /= rms);
        }
    }
    cols.retain(|c| c.iter().any(|v| *v != 0.0));
}
