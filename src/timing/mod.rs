//! The power sensors' timing: each reading is the average power over its own window
//! [t − lag − W, t − lag] ([`Alignment`]), and the (W, lag) search that estimates that timing
//! from the data ([`scan_alignment`]) by how well per-reading regressors averaged over each
//! candidate window explain the readings ([`SearchFits`], [`ridge_r2_of`]).
//!
//! The search knows nothing of how rows are built: identification gives its own per-reading rows
//! (`identify::estimate_alignment`), diagnosis its own (`diagnose/window.rs`).

use crate::N_PARAMS;
use std::ops::Range;

use crate::lsq::Gram;
use crate::trial::MIN_WINDOW_SAMPLES;

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

/// Scan the timing on `grid`, the candidates of each stage (the coarse grid, then the fine grid
/// around its best) scored together: `score(candidates)` returns one entry per candidate, (rows,
/// R²) of the fit of the rows built for it ([`SearchFits`]), or None when it cannot (too few
/// rows), so a caller reads its data once per stage for all of them. The candidate with the
/// highest R² wins: regressors averaged over the wrong window are a noisy version of the right
/// ones, so the fit degrades away from the true timing. None when no coarse candidate could be
/// scored.
pub fn scan_alignment(
    grid: &ScanGrid,
    mut score: impl FnMut(&[Alignment]) -> Scores,
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

/// Each candidate's (rows, R²), None where it could not be fitted.
pub type Scores = Vec<Option<(usize, f64)>>;

/// One reading of a search: the candidate it is scored for, the samples its window averages
/// (indices into the caller's joint-state samples) and its target.
#[derive(Debug, Clone)]
pub struct SearchRow {
    /// Position of the candidate in the scored list.
    pub cand: usize,
    /// The samples in the reading's window.
    pub samples: Range<usize>,
    /// The reading's target (net power).
    pub y: f64,
}

/// Rows a candidate holds before they enter its normal equations.
const BLOCK: usize = 256;

/// The normal equations of every candidate's per-reading rows, built trial by trial: a trial's
/// per-sample regressors are computed once, over the span every window of its rows covers, into
/// running sums shared by all candidates (a window's mean is the difference of two), and each
/// candidate's rows enter its normal equations [`BLOCK`] at a time ([`Gram::add_rows`]). The
/// window means equal the samples' own means up to the rounding of the running sums. `W`
/// regressors per sample: the paper's 49 by default; the diagnosis scans with every library
/// mechanism's regressor beside them.
pub struct SearchFits<const W: usize = N_PARAMS> {
    /// Per candidate: normal equations, rows not yet in them, every row's target.
    acc: Vec<(Gram, Vec<f64>, Vec<f64>)>,
    /// Σφ over the span's first k samples, k = 0..=len (samples without a regressor left out).
    sums: Vec<[f64; W]>,
    /// How many of the span's first k samples have no (finite) regressor.
    bad: Vec<usize>,
}

impl<const W: usize> SearchFits<W> {
    /// No rows yet for `candidates` candidates.
    pub fn new(candidates: usize) -> SearchFits<W> {
        SearchFits {
            acc: (0..candidates)
                .map(|_| (Gram::zeros(W), Vec::new(), Vec::new()))
                .collect(),
            sums: Vec::new(),
            bad: Vec::new(),
        }
    }

    /// Add one trial's `rows`; `phi(k)` is sample k's regressor row (None, or not finite: missing
    /// data, and no window holding the sample gives a row). A window with fewer than
    /// [`MIN_WINDOW_SAMPLES`] gives no row, nor does a target or window mean that is not finite.
    pub fn add_trial(
        &mut self,
        rows: &[SearchRow],
        mut phi: impl FnMut(usize) -> Option<[f64; W]>,
    ) {
        let live = || {
            rows.iter()
                .filter(|r| r.samples.len() >= MIN_WINDOW_SAMPLES)
        };
        let (Some(start), Some(end)) = (
            live().map(|r| r.samples.start).min(),
            live().map(|r| r.samples.end).max(),
        ) else {
            return;
        };
        let (mut run, mut bad) = ([0.0; W], 0);
        self.sums.clear();
        self.bad.clear();
        self.sums.push(run);
        self.bad.push(bad);
        for k in start..end {
            match phi(k).filter(|p| p.iter().all(|v| v.is_finite())) {
                Some(p) => run.iter_mut().zip(&p).for_each(|(r, v)| *r += v),
                None => bad += 1,
            }
            self.sums.push(run);
            self.bad.push(bad);
        }
        for r in live() {
            let (i, j) = (r.samples.start - start, r.samples.end - start);
            let n = r.samples.len() as f64;
            let mean: [f64; W] = std::array::from_fn(|c| (self.sums[j][c] - self.sums[i][c]) / n);
            if self.bad[j] != self.bad[i] || !r.y.is_finite() || mean.iter().any(|v| !v.is_finite())
            {
                continue;
            }
            let c = &mut self.acc[r.cand];
            c.1.extend_from_slice(&mean);
            c.2.push(r.y);
            if c.1.len() >= BLOCK * W {
                Self::flush(c);
            }
        }
    }

    /// Each candidate's normal equations of the rows added since the last call, which leaves them
    /// empty: one trial's fits, for per-trial held-out evidence.
    pub fn take(&mut self) -> Vec<Gram> {
        (self.acc.iter_mut())
            .map(|c| {
                Self::flush(c);
                c.2.clear();
                std::mem::replace(&mut c.0, Gram::zeros(W))
            })
            .collect()
    }

    fn flush((gram, rows, ys): &mut (Gram, Vec<f64>, Vec<f64>)) {
        gram.add_rows(rows, &ys[gram.n..]);
        rows.clear();
    }

    /// Each candidate's (rows, R²) ([`ridge_r2_of`]), None where it cannot be fitted.
    pub fn scores(mut self) -> Scores {
        self.acc
            .iter_mut()
            .map(|c| {
                Self::flush(c);
                Some((c.2.len(), ridge_r2_of(&c.0, &c.2)?))
            })
            .collect()
    }
}

/// R² of an unconstrained least-squares fit of the rows' targets `y` (in row order) on the
/// regressors from their normal equations, with a tiny ridge (unexcited columns, e.g. joint
/// pairs that never move together, make ΦᵀΦ singular). None with no more rows than parameters.
pub fn ridge_r2_of(gram: &Gram, y: &[f64]) -> Option<f64> {
    let n = y.len();
    if n <= gram.g.nrows() {
        return None;
    }
    let theta = gram.solve(1e-9)?;
    let mean = y.iter().sum::<f64>() / n as f64;
    let total: f64 = y.iter().map(|v| (v - mean).powi(2)).sum();
    (total > 0.0).then(|| 1.0 - gram.sse(&theta) / total)
}
