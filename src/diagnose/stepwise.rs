//! The stepwise search of every selection stage — the library's hypotheses, discovery's
//! candidates and the rest power's fields: each open candidate scored on top of the terms
//! chosen so far, gated (significant held-out improvement at its weighted Holm level, BIC, a
//! minimum gain), and the best passing one by held-out gain taken.

use super::select::Rule;

/// What the gates read of a scored candidate.
pub(crate) trait Gated {
    /// The paired one-sided p-value of its held-out improvement, the ΔBIC of adding it, and its
    /// held-out gain (1 − RMSE after / before).
    fn gated(&self) -> (f64, f64, f64);

    /// Its held-out gain.
    fn gain(&self) -> f64 {
        self.gated().2
    }
}

/// Whether `s` passes `rule`'s gates with its p-value below `level`.
pub(crate) fn passes(rule: &Rule, s: &impl Gated, level: f64) -> bool {
    let (p, d_bic, gain) = s.gated();
    p < level && d_bic < rule.bic_threshold && gain >= rule.min_improvement
}

/// The weighted Holm correction over every candidate generated: at step j a candidate of
/// weight w is judged at α·w / (W − (j − 1)·w_min), W the total weight.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Holm {
    /// Candidates generated.
    pub m: usize,
    /// Their total weight.
    pub total: f64,
    /// The smallest weight (what an accepted term removes at least).
    pub w_min: f64,
}

impl Holm {
    /// Plain Holm over `m` candidates (every weight 1).
    pub fn equal(m: usize) -> Holm {
        Holm {
            m,
            total: m as f64,
            w_min: 1.0,
        }
    }

    /// The level of a candidate of weight 1 at `step` (a candidate's own level is this times
    /// its weight).
    pub fn level(&self, alpha: f64, step: usize) -> f64 {
        alpha / (self.total - (step - 1) as f64 * self.w_min).max(1.0)
    }
}

/// One step over candidates `0..n`: each one `score` returns (`None`: closed, or no fit)
/// either passes (`pass`) or fails; the passing ones, and the best failing one by gain.
pub(crate) fn step<S: Gated>(
    n: usize,
    mut score: impl FnMut(usize) -> Option<S>,
    pass: impl Fn(usize, &S) -> bool,
) -> (Vec<S>, Option<S>) {
    let mut passing = Vec::new();
    let mut best_fail: Option<S> = None;
    for i in 0..n {
        let Some(s) = score(i) else {
            continue;
        };
        if pass(i, &s) {
            passing.push(s);
        } else if best_fail.as_ref().is_none_or(|b| s.gain() > b.gain()) {
            best_fail = Some(s);
        }
    }
    (passing, best_fail)
}

/// The best of `passing` by held-out gain (the last of equals).
pub(crate) fn best<S: Gated>(passing: &[S]) -> Option<usize> {
    (0..passing.len()).max_by(|&a, &b| passing[a].gain().total_cmp(&passing[b].gain()))
}

/// Whether a paired p-value that one fit beats another leaves them tied: not significant at
/// `alpha` (or not computable).
pub(crate) fn not_significant(p: f64, alpha: f64) -> bool {
    p >= alpha || p.is_nan()
}
