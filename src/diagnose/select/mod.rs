//! Scoring and greedy selection of hypotheses with validation that adding parameters cannot game:
//! k-fold cross-validation by TRIAL (all readings of a trial are held out together), a one-sided
//! paired test (t and signed-rank) of the per-trial held-out squared error (base vs base + hypothesis), the
//! Bayesian information criterion on the full data, and a physical-plausibility check.
//!
//! All fits of all subsets of hypotheses come from one Gram matrix per fold (the extra regressors
//! are linear maps of the pre-computed raw features), so scoring the whole library is cheap.

mod fit;
mod score;

pub(crate) use super::stepwise::Rule;
pub(crate) use fit::*;
pub(crate) use score::*;
pub use score::{HypothesisScore, Param};

use anyhow::Result;

use super::stepwise;

use super::hypotheses::{Hypothesis, LATENCY_ID, N_RAW, power_hypothesis};
use crate::N_PARAMS;

/// How the forms of one mechanism compared at the selection step that decided between them.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct MechanismForms {
    /// The mechanism.
    pub mechanism: String,
    /// Identifier of the best-scoring form.
    pub winner: String,
    /// Identifier of the second-best form.
    pub runner_up: String,
    /// Held-out RMSE with the winner and with the runner-up [W].
    pub rmse_w: [f64; 2],
    /// Margin: 1 − RMSE(winner)/RMSE(runner-up).
    pub margin: f64,
    /// One-sided paired p-value that the winner's per-trial held-out error is below the
    /// runner-up's.
    pub p_value: f64,
    /// Whether the winning form was accepted.
    pub accepted: bool,
    /// The winner's and the runner-up's form in words (e.g. `per-Nm`, `per-ampere`).
    #[serde(default)]
    pub form_words: [String; 2],
    /// The parameter(s) of the winner and of the runner-up, each fitted in its own form.
    #[serde(default)]
    pub params: [Vec<Param>; 2],
    /// The data do not tell the forms apart: the winner's margin is not significant (p at or
    /// above the significance level of the rule). The mechanism is then claimed with its form
    /// left open ("form: confounded — X or Y"), not the winning form.
    #[serde(default)]
    pub confounded: bool,
    /// The runner-up is a form of ANOTHER mechanism that the winner does not beat significantly
    /// (`mechanism` then reads "X or Y"): the structure is located, no mechanism is named — the
    /// winner stays in the model (its structure explained) but is not claimed.
    #[serde(default)]
    pub unnamed: bool,
    /// For a claim [`super::parsimony`]'s rule located: the share of trial resamples in which
    /// its test passed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stability: Option<f64>,
    /// The level `p_value` had to fall below ([`RIVAL_ALPHA`] between mechanisms; the rule's
    /// level for a claim tested against the model without it).
    #[serde(default = "rival_alpha")]
    pub level: f64,
}

fn rival_alpha() -> f64 {
    RIVAL_ALPHA
}

impl MechanismForms {
    /// "W vs R: held-out RMSE a vs b W, p = … that W fits better": the evidence of the pairing.
    pub fn evidence(&self) -> String {
        let test = format!(
            "{w} vs {r}: held-out RMSE {:.3} vs {:.3} W, p = {:.3} that {w} fits better",
            self.rmse_w[0],
            self.rmse_w[1],
            self.p_value,
            w = self.winner,
            r = self.runner_up,
        );
        match self.stability {
            Some(s) => format!(
                "{test} (needed < {}); held in {:.0} % of trial resamples (needed ≥ {:.0} %)",
                self.level,
                100.0 * s,
                100.0 * super::stepwise::STABLE
            ),
            None => format!("{test} (needed < {})", self.level),
        }
    }

    /// "per-Nm or per-ampere" (winner first).
    pub fn either(&self) -> String {
        let w = |i: usize, id: &str| {
            if self.form_words[i].is_empty() {
                id.to_string()
            } else {
                self.form_words[i].clone()
            }
        };
        format!("{} or {}", w(0, &self.winner), w(1, &self.runner_up))
    }
}

/// Two hypotheses the data cannot tell apart: forward selection accepted both, but one is not
/// significant given the other.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Confounded {
    /// The one kept (significant given the other).
    pub kept: String,
    /// The library term dropped in its place.
    pub dropped: String,
    /// Correlation of their regressors over the readings.
    pub correlation: f64,
    /// p-value of the dropped one given all the others (paired held-out test).
    pub p_value: f64,
    /// Relative held-out RMSE change from dropping it.
    pub rel_change: f64,
    /// The data do not tell the two apart in either direction (a library term, `dropped`, and a
    /// term beyond the library, `kept`, on a recorded field the library does not read, that
    /// explains the same part of the power). The library term — a mechanism written from physics
    /// — stays claimed, and the other is named beside it as an explanation the data cannot
    /// exclude. Then `p_value` is that of the library term fitting the held-out trials better
    /// than the other, and `rel_change` is 1 − its held-out RMSE / the other's.
    #[serde(default)]
    pub tied: bool,
}

/// The result of greedy forward selection at the power level.
pub(crate) struct Selection {
    /// Every candidate scored against the base model (step 1), ranked.
    pub first_step: Vec<HypothesisScore>,
    /// The accepted hypotheses in the order they were added, with their score at that step.
    pub accepted: Vec<HypothesisScore>,
    /// Forms of each mechanism with more than one, compared where they were decided.
    pub forms: Vec<MechanismForms>,
    /// Library terms and the terms beyond the library that do their work
    /// ([`super::select_discover::library_rivals`]).
    pub confounded: Vec<Confounded>,
    /// Base model state (no hypothesis, no lag).
    pub base: State,
    /// Final model state.
    pub last: State,
    /// Per accepted hypothesis id: the best other library mechanism the data also supported at
    /// its step (the rule's statistical gates, not the plausibility) — its rival in [`super::parsimony`]'s rule.
    pub rivals: Vec<(String, &'static Hypothesis)>,
}

/// Mechanism of candidate `id` (latency's own for none of the library's).
fn mechanism(id: &str) -> &'static str {
    power_hypothesis(id).map_or(LATENCY_ID, |h| h.mechanism)
}

/// Compare the two best forms of every mechanism with more than one form among `ranked` (of
/// `only`, if given); the forms are confounded when the winner's per-trial margin is not
/// significant at `alpha`.
fn compare_forms(
    data: &PowerData,
    ranked: &[(bool, &Candidate)],
    alpha: f64,
    only: Option<&str>,
) -> Vec<MechanismForms> {
    let mut mechs: Vec<&str> = ranked.iter().map(|c| mechanism(&c.1.score.id)).collect();
    mechs.sort_unstable();
    mechs.dedup();
    mechs.retain(|m| only.is_none_or(|o| o == *m));
    let mut decided = Vec::new();
    for m in mechs {
        let forms: Vec<&Candidate> = (ranked.iter().map(|c| c.1))
            .filter(|c| mechanism(&c.score.id) == m)
            .collect();
        if let [w, r, ..] = forms[..] {
            decided.push(versus(data, m.into(), (w, r), alpha));
        }
    }
    decided
}

/// The winner `w` against the runner-up `r`: the paired held-out test by trial, their scores,
/// forms and parameters; confounded when the winner was accepted but its margin is not significant.
fn versus(
    data: &PowerData,
    mechanism: String,
    (w, r): (&Candidate, &Candidate),
    alpha: f64,
) -> MechanismForms {
    // Every lag's rows are the same readings: y and trial are the lag-0 rows'.
    let y = &data.rows0().y;
    let trial = &data.rows0().trial;
    let p_value = p_better(y, &w.next.cv.pred, &r.next.cv.pred, trial, data.n_trials);
    MechanismForms {
        mechanism,
        winner: w.score.id.clone(),
        runner_up: r.score.id.clone(),
        rmse_w: [w.score.rmse_after, r.score.rmse_after],
        margin: 1.0 - w.score.rmse_after / r.score.rmse_after.max(1e-300),
        p_value,
        accepted: w.score.accepted,
        form_words: [w, r].map(|c| power_hypothesis(&c.score.id).map_or("", |h| h.form).into()),
        params: [w.score.params.clone(), r.score.params.clone()],
        confounded: w.score.accepted && (p_value >= alpha || p_value.is_nan()),
        unnamed: false,
        stability: None,
        level: RIVAL_ALPHA,
    }
}

/// Level of the paired test by which a library mechanism must beat another that also passes at
/// its step. Measured: the project's own 72-trial bus-loss, drive-loss and per-Nm sessions beat
/// their rival mechanism at p = 0.002–0.02 (margins 7–11 %); the campaign's two wrong names were
/// ahead by p = 0.79 and 0.15 (margins 0.2 %, 0.5 %). At the rule's 0.001 the true ones would be
/// left unnamed.
pub(crate) const RIVAL_ALPHA: f64 = 0.05;

/// Greedy forward selection ([`stepwise::forward`]): at each step score every remaining
/// candidate against the current model, add the best one that passes the rule (the other forms
/// of its mechanism leave the race), stop when none passes. Whether each is claimed beside the
/// others and against its rival mechanism is [`super::parsimony`]'s rule, applied after every
/// stage.
pub(crate) fn select(
    data: &PowerData,
    candidates: &[&'static Hypothesis],
    rule: &Rule,
) -> Result<Selection> {
    let base = state(data, Vec::new(), 0)?;
    // The last (past `candidates`) is latency.
    let n = candidates.len() + usize::from(data.lags.len() >= 3);
    let mut lib = Library {
        data,
        rule,
        cands: candidates,
        sel: Selection {
            first_step: Vec::new(),
            accepted: Vec::new(),
            forms: Vec::new(),
            confounded: Vec::new(),
            base: base.clone(),
            last: base,
            rivals: Vec::new(),
        },
    };
    stepwise::forward(&mut lib, n, n)?;
    let mut sel = lib.sel;
    for f in sel.forms.iter().filter(|f| f.confounded) {
        for s in sel.accepted.iter_mut().chain(sel.first_step.iter_mut()) {
            if s.id == f.winner {
                s.verdict = format!(
                    "{}; form: confounded — {} (margin {:.1} %, p = {:.2})",
                    s.verdict,
                    f.either(),
                    100.0 * f.margin,
                    f.p_value
                );
            }
        }
    }
    Ok(sel)
}

/// The library's side of the stepwise search: every candidate (past `cands`: latency) scored and
/// judged by the rule, and the selection made so far.
struct Library<'a, 'd> {
    data: &'a PowerData<'d>,
    rule: &'a Rule,
    cands: &'a [&'static Hypothesis],
    sel: Selection,
}

impl stepwise::Stage for Library<'_, '_> {
    type Scored = Candidate;
    const FIRST_OF_EQUALS: bool = true;
    const RANKS: bool = true;

    fn score(&self, i: usize, step: usize) -> Result<Option<Candidate>> {
        let (c, data, cur) = (self.cands.get(i).copied(), self.data, &self.sel.last);
        // A mechanism taken in: its other forms have left the race.
        let m = c.map_or(LATENCY_ID, |h| h.mechanism);
        if self.sel.accepted.iter().any(|a| mechanism(&a.id) == m) {
            return Ok(None);
        }
        let mut cand = match c {
            Some(h) => score_term(data, cur, h, step)?,
            None => score_latency(data, cur, step)?,
        };
        let (mut ok, mut why) = self.rule.judge(&cand.score);
        if c.is_none() && !data.lag_claimable {
            why = format!(
                "not claimed: the sensor-window scan finds no lag that beats every window at \
                 lag 0 ({why})"
            );
            ok = false;
        }
        (cand.score.accepted, cand.score.verdict) = (ok, why);
        Ok(Some(cand))
    }

    fn passes(&self, _: usize, c: &Candidate, _: usize) -> bool {
        c.score.accepted
    }

    /// The first step's ranking; the forms of the winner's mechanism compared at the step that
    /// accepts one of them (of every mechanism at the first step when none is accepted); the
    /// winner's rival ([`Selection::rivals`]).
    fn ranked(&mut self, step: usize, ranked: &[(bool, &Candidate)], w: Option<&Candidate>) {
        if step == 1 {
            self.sel.first_step = ranked.iter().map(|c| c.1.score.clone()).collect();
        }
        let winner = w.map(|c| &c.score.id);
        let m = winner.map(|id| mechanism(id));
        if winner.is_some() || step == 1 {
            let forms = compare_forms(self.data, ranked, self.rule.alpha, m);
            self.sel.forms.extend(forms);
        }
        // Its rival: the best candidate of another library mechanism the data also support (the
        // statistical gates of the rule without the plausibility of its parameter: a rival
        // mechanism that fits as well is a rival at any value, the form, not the size, is what
        // the rule pairs).
        let (Some(id), Some(m)) = (winner, m) else {
            return;
        };
        let supported = |c: &Candidate| {
            power_hypothesis(&c.score.id)
                .filter(|h| h.mechanism != m && stepwise::passes(self.rule, c, self.rule.alpha))
        };
        if let Some(r) = ranked.iter().find_map(|c| supported(c.1)) {
            self.sel.rivals.push((id.clone(), r));
        }
    }

    fn accept(&mut self, _: usize, w: Candidate, _: Vec<Candidate>) {
        self.sel.accepted.push(w.score);
        self.sel.last = w.next;
    }
}

/// A winner [`super::parsimony`]'s rule locates is not claimed: it leaves
/// `accepted` (it stays in the model) and its first-step score says why.
pub(crate) fn unname(
    forms: &mut [MechanismForms],
    accepted: &mut Vec<HypothesisScore>,
    first_step: &mut [HypothesisScore],
) {
    let unnamed: Vec<MechanismForms> = forms
        .iter()
        .filter(|f| f.unnamed && accepted.iter().any(|s| s.id == f.winner))
        .cloned()
        .collect();
    for f in &unnamed {
        accepted.retain(|s| s.id != f.winner);
        // Neither mechanism is claimed in any form.
        for g in forms.iter_mut().filter(|g| g.winner == f.winner) {
            g.accepted = false;
        }
        let of_either = |id: &str| {
            id == f.winner
                || power_hypothesis(id)
                    .is_some_and(|h| f.form_words.iter().any(|m| m == h.mechanism))
        };
        for s in first_step.iter_mut().filter(|s| of_either(&s.id)) {
            s.accepted = false;
            s.verdict = format!(
                "located, not named: {} — form not identified ({}); {}",
                f.mechanism,
                f.evidence(),
                s.verdict
            );
        }
    }
}

/// The regressor of hypothesis `h` on row `r` (pooled terms weighted by `theta`).
pub(crate) fn regressor(h: &Hypothesis, x: &[f64; N_RAW], theta: &[f64]) -> f64 {
    let (off, len) = h.raw;
    (0..len)
        .map(|i| h.weight(theta, i) * x[N_PARAMS + off + i])
        .sum()
}

#[cfg(test)]
pub(crate) mod tests;
