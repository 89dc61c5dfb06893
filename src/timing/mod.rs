//! The power sensors' timing: each reading is the average power over its own window
//! [t − lag − W, t − lag] ([`Alignment`]), and the (W, lag) scan that estimates that timing from
//! the data ([`scan_alignment`]) by how well per-reading regressors averaged over each candidate
//! window explain the readings ([`ridge_r2`]).
//!
//! The scan knows nothing of how rows are built: identification scores its own per-reading rows
//! (`identify::estimate_alignment`), diagnosis its own.

use crate::N_PARAMS;
use crate::lsq::{Gram, GramSum};

/// Timing of a power reading: it is the average power over [t − lag − window, t − lag].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Alignment {
    /// Averaging window W [s].
    pub window_s: f64,
    /// Lag of the window's end behind the reading's timestamp [s].
    pub lag_s: f64,
}

impl Alignment {
    /// The G1 power sensors' nominal timing: each reading averages the 0.2 s before its stamp.
    pub const NOMINAL: Alignment = Alignment {
        window_s: 0.2,
        lag_s: 0.0,
    };

    /// The window of a reading stamped `t`.
    pub fn window_of(&self, t: f64) -> (f64, f64) {
        (t - self.lag_s - self.window_s, t - self.lag_s)
    }

    /// The centre of the window of a reading stamped `t`.
    pub fn centre_of(&self, t: f64) -> f64 {
        t - self.lag_s - 0.5 * self.window_s
    }
}

/// One point of the alignment search.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AlignmentScore {
    /// Candidate timing.
    pub alignment: Alignment,
    /// Rows the fit used.
    pub rows: usize,
    /// R² of the least-squares fit of the per-reading rows.
    pub r2: f64,
}

/// Result of [`scan_alignment`].
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct AlignmentEstimate {
    /// Best timing (highest R²).
    pub best: Alignment,
    /// R² at the best timing.
    pub r2: f64,
    /// Every candidate tried (coarse grid, then a finer grid around the best).
    pub grid: Vec<AlignmentScore>,
}

/// The candidates of a scan: a coarse grid, then a fine grid of ±4 steps around the coarse best.
#[derive(Debug, Clone, Copy)]
pub struct ScanGrid<'a> {
    /// Coarse windows W [s].
    pub windows: &'a [f64],
    /// Coarse lags [s].
    pub lags: &'a [f64],
    /// Step of the fine grid [s] (both axes).
    pub step: f64,
    /// Smallest lag tried on the fine grid [s].
    pub min_lag: f64,
}

impl ScanGrid<'static> {
    /// The identification's grid: W 0.05–1.0 s, lag −0.3–0.5 s, then 0.025 s steps.
    pub const IDENTIFY: ScanGrid<'static> = ScanGrid {
        windows: &[0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0],
        lags: &[-0.3, -0.2, -0.1, 0.0, 0.1, 0.2, 0.3, 0.5],
        step: 0.025,
        min_lag: f64::NEG_INFINITY,
    };
}

/// Scan the timing on `grid`: `score(alignment)` fits the rows built for that candidate and
/// returns (rows, R²), or None when it cannot (too few rows); the candidate with the highest
/// R² wins. Regressors averaged over the wrong window are a noisy version of the right ones, so
/// the fit degrades away from the true timing. None when no coarse candidate could be scored.
pub fn scan_alignment(
    grid: &ScanGrid,
    mut score: impl FnMut(Alignment) -> Option<(usize, f64)>,
) -> Option<AlignmentEstimate> {
    scan_alignment_batch(grid, |cands| cands.iter().map(|&a| score(a)).collect())
}

/// [`scan_alignment`] with the candidates of each stage (the coarse grid, then the fine grid
/// around its best) scored together: `score(candidates)` returns one entry per candidate, so a
/// caller can read its data once per stage for all of them.
pub fn scan_alignment_batch(
    grid: &ScanGrid,
    mut score: impl FnMut(&[Alignment]) -> Vec<Option<(usize, f64)>>,
) -> Option<AlignmentEstimate> {
    let mut scores = Vec::new();
    let mut run = |cands: Vec<Alignment>, scores: &mut Vec<AlignmentScore>| {
        for (&alignment, s) in cands.iter().zip(score(&cands)) {
            if let Some((rows, r2)) = s {
                scores.push(AlignmentScore {
                    alignment,
                    rows,
                    r2,
                });
            }
        }
    };
    let best_of = |g: &[AlignmentScore]| g.iter().copied().max_by(|a, b| a.r2.total_cmp(&b.r2));
    let at = |window_s, lag_s| Alignment { window_s, lag_s };
    let coarse_grid = grid
        .windows
        .iter()
        .flat_map(|&w| grid.lags.iter().map(move |&l| at(w, l)));
    run(coarse_grid.collect(), &mut scores);
    let coarse = best_of(&scores)?;
    let (w0, l0) = (coarse.alignment.window_s, coarse.alignment.lag_s);
    let fine = (-4..=4i32)
        .flat_map(|dw| (-4..=4i32).map(move |dl| (dw, dl)))
        .filter(|&(dw, dl)| dw != 0 || dl != 0)
        .map(|(dw, dl)| at(w0 + dw as f64 * grid.step, l0 + dl as f64 * grid.step))
        .filter(|a| a.window_s > 0.0 && a.lag_s >= grid.min_lag - 1e-9);
    run(fine.collect(), &mut scores);
    let best = best_of(&scores).unwrap_or(coarse);
    Some(AlignmentEstimate {
        best: best.alignment,
        r2: best.r2,
        grid: scores,
    })
}

/// R² of an unconstrained least-squares fit of `y` on the 49 regressors (the first
/// [`N_PARAMS`] values of each row of `phi`)
/// with a tiny ridge (unexcited columns, e.g. joint pairs that never move together, make ΦᵀΦ
/// singular). None with no more rows than parameters.
pub fn ridge_r2<'a>(phi: impl ExactSizeIterator<Item = &'a [f64]>, y: &[f64]) -> Option<f64> {
    if y.len() <= N_PARAMS || phi.len() != y.len() {
        return None;
    }
    let mut gram = GramSum::zeros(N_PARAMS);
    for (row, &yv) in phi.zip(y) {
        gram.add_row(row.get(..N_PARAMS)?, yv);
    }
    ridge_r2_of(&gram.finish(), y)
}

/// [`ridge_r2`] from the normal equations of the rows and their targets `y` (in row order).
pub fn ridge_r2_of(gram: &Gram, y: &[f64]) -> Option<f64> {
    let n = y.len();
    if n <= N_PARAMS {
        return None;
    }
    let theta = gram.solve(1e-9)?;
    let mean = y.iter().sum::<f64>() / n as f64;
    let total: f64 = y.iter().map(|v| (v - mean).powi(2)).sum();
    (total > 0.0).then(|| 1.0 - gram.sse(&theta) / total)
}
