//! The stepwise search of every selection stage — the library's hypotheses, discovery's
//! candidates and the rest power's fields: each open candidate scored on top of the terms
//! chosen so far, gated (significant held-out improvement at its Holm level, BIC, a
//! minimum gain), and the best passing one by held-out gain taken.

use anyhow::Result;

/// Thresholds of the significance rule: the gates every candidate of every stage passes.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Rule {
    /// Significance level before the Holm correction.
    pub alpha: f64,
    /// Largest ΔBIC of adding a candidate.
    pub bic_threshold: f64,
    /// Smallest held-out gain (1 − RMSE after / before).
    pub min_improvement: f64,
}

/// Share of the trial resamples in which a claim must pass the rule's test to be claimed.
pub(crate) const STABLE: f64 = 0.8;

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

/// Holm's level at `step` over `m` tests: α / (m − (step − 1)).
pub(crate) fn holm_level(alpha: f64, m: usize, step: usize) -> f64 {
    alpha / (m as f64 - (step - 1) as f64).max(1.0)
}

/// A stage's side of the one stepwise search ([`forward`]): its candidates, how one is scored on
/// the model so far and gated, and what taking one in does.
pub(crate) trait Stage {
    /// A scored candidate.
    type Scored: Gated;
    /// Of passing candidates of equal held-out gain, the first wins (the library selection)
    /// rather than the last (discovery, the rest power).
    const FIRST_OF_EQUALS: bool = false;
    /// Whether [`Stage::ranked`] reads every scored candidate: otherwise a failing one is dropped
    /// once scored (discovery scores thousands, each with a prediction per reading).
    const RANKS: bool = false;
    /// Called before `step`'s candidates are scored (discovery's family tests run here).
    fn begin(&mut self, _step: usize) {}
    /// Candidate `i` scored on the current model at `step` (`None`: closed, or no fit).
    fn score(&self, i: usize, step: usize) -> Result<Option<Self::Scored>>;
    /// Whether `s`, candidate `i`, passes the gates at `step`'s Holm level.
    fn passes(&self, i: usize, s: &Self::Scored, step: usize) -> bool;
    /// Every candidate scored at `step` with whether it passes, best first: those that pass,
    /// then by held-out gain, equals in candidate order; and the step's winner (the library's
    /// ranking, its forms and its rivals read them).
    fn ranked(&mut self, _: usize, _: &[(bool, &Self::Scored)], _: Option<&Self::Scored>) {}
    /// The step's winner among `passing`: the best by held-out gain ([`best`]).
    fn choose(&self, passing: &[Self::Scored]) -> Option<usize> {
        best(passing, Self::FIRST_OF_EQUALS)
    }
    /// At step 1: the best candidate by gain that failed the gates, beside the winner if any.
    fn rejected(&mut self, _failed: &Self::Scored, _winner: Option<&Self::Scored>) {}
    /// Take `winner` into the model at `step` (or close it); `passing` holds the other
    /// candidates that passed, among which its rivals are.
    fn accept(&mut self, step: usize, winner: Self::Scored, passing: Vec<Self::Scored>);
}

/// The stepwise search of every selection stage: at each step up to `max_steps`, every open
/// candidate of `0..n` scored on top of the terms chosen so far and gated at the step's Holm
/// level; the winner among those that pass taken in with its rivals; stop when none passes.
/// (Backward elimination is [`super::parsimony`]'s rule.)
pub(crate) fn forward<S: Stage>(stage: &mut S, n: usize, max_steps: usize) -> Result<()> {
    for k in 1..=max_steps {
        stage.begin(k);
        // The best failing candidate by gain, the first of equals in candidate order.
        let (mut passing, mut failing, mut failed) = (Vec::new(), Vec::new(), None);
        let mut fail = |s: S::Scored| {
            if failed
                .as_ref()
                .is_none_or(|b: &S::Scored| s.gain() > b.gain())
            {
                failed = Some(s);
            }
        };
        for i in 0..n {
            if let Some(s) = stage.score(i, k)? {
                match stage.passes(i, &s, k) {
                    true => passing.push(s),
                    false if S::RANKS => failing.push(s),
                    false => fail(s),
                }
            }
        }
        let w = stage.choose(&passing);
        if S::RANKS {
            // Each part in candidate order: the sort keeps equals so.
            let mut ranked: Vec<(bool, &S::Scored)> = (passing.iter().map(|s| (true, s)))
                .chain(failing.iter().map(|s| (false, s)))
                .collect();
            ranked.sort_by(|a, b| {
                (b.0, b.1.gain())
                    .partial_cmp(&(a.0, a.1.gain()))
                    .unwrap_or(std::cmp::Ordering::Equal)
            });
            stage.ranked(k, &ranked, w.map(|w| &passing[w]));
        }
        failing.into_iter().for_each(fail);
        let winner = w.map(|w| passing.swap_remove(w));
        if k == 1
            && let Some(f) = &failed
        {
            stage.rejected(f, winner.as_ref());
        }
        let Some(w) = winner else { break };
        stage.accept(k, w, passing);
    }
    Ok(())
}

/// The best of `passing` by held-out gain: the last of equals, or the first with `first`.
pub(crate) fn best<S: Gated>(passing: &[S], first: bool) -> Option<usize> {
    let by_gain = |a: &usize, b: &usize| passing[*a].gain().total_cmp(&passing[*b].gain());
    match first {
        true => (0..passing.len()).rev().max_by(by_gain),
        false => (0..passing.len()).max_by(by_gain),
    }
}

/// Whether a paired p-value that one fit beats another leaves them tied: not significant at
/// `alpha` (or not computable).
pub(crate) fn not_significant(p: f64, alpha: f64) -> bool {
    p >= alpha || p.is_nan()
}
