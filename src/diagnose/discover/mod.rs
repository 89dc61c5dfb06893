//! Discovery beyond the hypothesis library: when the library is done, search a generated set
//! of candidate terms with the same gates as the hypotheses and a hard cap on false
//! discoveries across everything tried.
//!
//! Candidates (each one or a few extra regressors, net of the trial's pre-idle baseline like
//! the target):
//! - every non-constant numeric field of every topic ([`super::fields`]), as an additive term
//!   (W per unit) and, for fields that switch between levels, as a step (W while above the
//!   midpoint of its range);
//! - products of each pooled base loss term (Σ τq̇, Σ Δτ², Σ |q̇|, Σ q̇²) with each slow state
//!   signal (fields that change little within a trial, and session time), and with each
//!   per-motor field family taken joint by joint (Σ_i term_i · s_i, s_i = the field of joint
//!   i's own motor), with the plain pooled term as a second column (the level); the pooled
//!   drive current Σ |τ_i|/K_i (the library's drive-electronics loss per ampere) times each
//!   signal common to all joints likewise (a drive loss that follows a state: the switching
//!   loss follows the supply voltage);
//! - against a held base model, each base loss term per joint (one coefficient per joint) and
//!   pooled (one coefficient): a friction or efficiency the twin has wrong.
//!
//! Selection: forward (best held-out improvement that passes every gate at its family-first
//! level, [`Search::member_level`]: Holm over the mechanism families, each loss term's block
//! test opening its family), never more terms than one per 20 trials; whether each
//! is claimed beside the others is [`super::parsimony`]'s rule. A chosen term's
//! rivals at its step — candidates on other fields it does not fit significantly better than,
//! of the same structure or with a collinear contribution ([`tie_of`]) — are named with it as
//! confounded and never claimed. Fields that track
//! the measured power itself (the rail's current meters named by the signal map, and any field
//! with |r| ≥ 0.5 with the readings: another meter of the same flow) are
//! consequences of the power, not causes, and are left out with a note; those that fall as the
//! power rises (a battery voltage sagging under the load) are still slow state signals at rest
//! (their mean over each trial's pre-idle readings: the charge). Names come from the
//! term's structure only ([`describe`]).

mod candidates;
mod fit;
mod found;
mod rival;
mod search;
#[cfg(test)]
mod tests;
mod ties;
mod words;

use anyhow::Result;

pub(crate) use candidates::Inputs;
use candidates::{Kind, TIME_NAME, base_mean};
pub(crate) use fit::Base;
pub use found::{Discovery, DiscoveryReport, TiedTerm};
pub(crate) use rival::rival_of;
use search::{Scored, Search, simpler_nested, to_discovery};
use ties::{Tie, claim_rivals_found_beside, name_with_ties, stays_open, ties_at_step};
use words::describe;

use super::family::Term;
use super::select::{PowerData, Rule, State, jackknife_se};
use super::stepwise;

/// At most one discovered term per this many trials.
const TRIALS_PER_TERM: usize = 20;

/// Hard cap on discovered terms.
const MAX_TERMS: usize = 4;

/// Run discovery on the library's final model `cur`; candidates of the groups in `blocked`
/// (alternatives to a library term the data could not tell from it, [`rival_of`]) are not
/// tried.
pub(crate) fn discover(
    data: &PowerData,
    cur: &State,
    inp: &Inputs,
    rule: &Rule,
    joint_names: &[String],
    blocked: &[String],
) -> Result<DiscoveryReport> {
    let mut report = DiscoveryReport {
        fields_read: inp.fields.n_read,
        fields_used: inp.fields.names.len(),
        alpha: rule.alpha,
        notes: inp.fields.notes.clone(),
        excluded: inp.fields.excluded.clone(),
        ..Default::default()
    };
    let (search, usable) = Search::new(data, cur, inp, rule, &mut report.notes)?;
    report.rest = rest_power_of(inp, usable, rule);
    report.n_candidates = search.m;
    report.fields_used = (0..inp.fields.names.len())
        .filter(|&f| !inp.fields.duplicate.get(f).copied().unwrap_or(false))
        .count();
    let y_rms = search.y_rms();
    let mut fw = Forward {
        chosen: Vec::new(),
        cols: Vec::new(),
        pred: cur.cv.pred.clone(),
        bic: cur.bic,
        closed: blocked.to_vec(),
        accepted: Vec::new(),
        tied: Vec::new(),
        open: Vec::new(),
        changing: None,
    };
    report.before = Some(search.base.compare(&fw.pred, &fw.pred).2);
    stepwise::forward(
        &mut Stepping {
            search: &search,
            fw: &mut fw,
            report: &mut report,
            joint_names,
            y_rms,
        },
        search.cands.len(),
        MAX_TERMS.min(data.n_trials / TRIALS_PER_TERM),
    )?;
    claim_rivals_found_beside(&search, &fw.chosen, &mut fw.tied, &mut report.notes);
    let on_time = fw
        .chosen
        .iter()
        .any(|&i| search.cands[i].group.contains(TIME_NAME));
    if let Some(note) = on_time
        .then(|| clock_stand_ins(&search.inp.fields.excluded))
        .flatten()
    {
        report.notes.push(note);
    }
    finish(&search, &mut fw, cur, joint_names, &mut report)?;
    if report.accepted.is_empty() && report.located.is_empty() {
        report
            .located
            .extend(changing_term(&search, fw.changing, &cur.cv.pred));
    }
    Ok(report)
}

/// A loss term whose coefficient changes during the session, following a state no candidate
/// named (an unrecorded one, or a recorded one no member of its family reached the level with):
/// the family's block test at step 1 ([`Search::block`], at its family-first level) with the
/// gates of a claim, the best that passes located, never claimed; `pred` is the model's
/// held-out prediction without it.
fn changing_term(search: &Search, best: Option<(Term, Scored)>, pred: &[f64]) -> Option<Discovery> {
    let (t, s) = best?;
    let level = search.family_level(1) / 2.0;
    let (_, _, all_before, all_after) = search.base.compare(pred, &s.fit.pred);
    let words = t.words();
    Some(Discovery {
        name: format!(
            "{}{} changes during the session, following a state not identified (its coefficient \
             drifts with session time; which recorded field, if any, it follows is not resolved), \
             form not identified",
            words[..1].to_uppercase(),
            &words[1..]
        ),
        form: format!("Σ {} · (k0 + piecewise-linear(session time))", t.symbol()),
        p_value: s.p,
        alpha: level,
        delta_bic: s.d_bic,
        rel_improvement: s.rel,
        before: all_before,
        after: all_after,
        step: 1,
        verdict: format!(
            "located — not claimed: beside the term alone, held-out RMSE −{:.1} % (p = {:.1e} < \
             {level:.1e}, the family's block test, Holm over {} mechanism families), ΔBIC = {:.1}",
            100.0 * s.rel,
            s.p,
            search.n_families(),
            s.d_bic
        ),
        mechanism: t.library_id().map(String::from),
        ..Default::default()
    })
}

/// Forward selection's state: the terms chosen so far and the model they make.
struct Forward {
    /// Candidates accepted, in order.
    chosen: Vec<usize>,
    /// Their columns.
    cols: Vec<Vec<f64>>,
    /// Held-out prediction and BIC of the model with them.
    pred: Vec<f64>,
    bic: f64,
    /// Groups no longer tried: blocked, chosen, or tied with a chosen term.
    closed: Vec<String>,
    /// Each accepted candidate's step, level and score.
    accepted: Vec<(usize, f64, Scored)>,
    /// At the current step, per mechanism family: whether its block test passed.
    open: Vec<bool>,
    /// At step 1, the best block test that passed with a claim's gates ([`changing_term`]).
    changing: Option<(Term, Scored)>,
    /// Each chosen candidate's ties.
    tied: Vec<(usize, Vec<Tie>)>,
}

/// Discovery's side of the stepwise search ([`stepwise::forward`]).
struct Stepping<'s, 'a, 'd> {
    search: &'s Search<'a, 'd>,
    fw: &'s mut Forward,
    report: &'s mut DiscoveryReport,
    joint_names: &'s [String],
    y_rms: f64,
}

impl Stepping<'_, '_, '_> {
    /// Candidate `i`'s level at `step` ([`Search::member_level`]).
    fn level(&self, i: usize, step: usize) -> f64 {
        let open = self.fw.open.get(self.search.cands[i].family) == Some(&true);
        self.search.member_level(i, step, open)
    }
}

impl stepwise::Stage for Stepping<'_, '_, '_> {
    type Scored = Scored;

    /// Each loss-term family's block test on the model so far, at half the family's Holm level.
    fn begin(&mut self, step: usize) {
        let (search, fw) = (self.search, &mut *self.fw);
        let level = search.family_level(step) / 2.0;
        let mut blocks: Vec<(Term, Scored)> = (Term::ALL.iter().enumerate())
            .filter(|&(f, _)| search.fam_total[f] > 0.0)
            .filter_map(|(_, &t)| Some((t, search.block(t, &fw.cols)?)))
            .collect();
        fw.open = Term::ALL
            .iter()
            .map(|t| blocks.iter().any(|(u, s)| u == t && s.p < level))
            .collect();
        if step > 1 {
            return;
        }
        blocks.sort_by(|a, b| a.1.p.total_cmp(&b.1.p));
        let smallest: Vec<String> = (blocks.iter().take(3))
            .map(|(t, s)| format!("{} p = {:.1e}", t.words(), s.p))
            .collect();
        self.report.notes.push(format!(
            "family first: Holm over {} mechanism families at α = {}; each loss term's block test \
             (the term × a piecewise-linear function of session time, against the term alone) at \
             {level:.1e}, smallest p: {}",
            search.n_families(),
            search.rule.alpha,
            smallest.join(", ")
        ));
        blocks.retain(|(_, s)| stepwise::passes(&search.rule, s, level));
        fw.changing = blocks
            .into_iter()
            .max_by(|a, b| a.1.rel.total_cmp(&b.1.rel));
    }

    fn score(&self, i: usize, step: usize) -> Result<Option<Scored>> {
        let (search, fw) = (self.search, &self.fw);
        super::report(super::Progress::Candidates {
            step,
            done: i + 1,
            total: search.cands.len(),
        });
        if fw.chosen.contains(&i) || fw.closed.contains(&search.cands[i].group) {
            return Ok(None);
        }
        Ok(search.score(i, &fw.cols, (&fw.pred, fw.bic), self.y_rms))
    }

    fn passes(&self, i: usize, s: &Scored, step: usize) -> bool {
        self.search.passes(s, self.level(i, step))
    }

    /// The best of the `passing` candidates by held-out gain — or, when it is a term × signal
    /// not significantly better than the plain pooled term it contains, that pooled term: the
    /// signal is not what the data support.
    fn choose(&self, passing: &[Scored]) -> Option<usize> {
        let k = stepwise::best(passing, false)?;
        let refs: Vec<&Scored> = passing.iter().collect();
        Some(simpler_nested(self.search, &passing[k], &refs).unwrap_or(k))
    }

    fn rejected(&mut self, f: &Scored, winner: Option<&Scored>) {
        if winner.is_none_or(|b| f.rel > b.rel) {
            let search = self.search;
            let lv = self.level(f.idx, 1);
            let verdict = verdict_of(f, lv, &search.rule);
            let d = to_discovery(f, search, self.joint_names, lv, 1, verdict);
            self.report.best_rejected = Some(d);
        }
    }

    /// Take `b` into the model at `step` with its ties — rivals on other fields the data cannot
    /// tell from it, named with it and never claimed — closing its group and those of the ties
    /// that do not stay open; a term × signal whose dependence is not resolved is located and
    /// closed instead.
    fn accept(&mut self, step: usize, b: Scored, passing: Vec<Scored>) {
        let (search, names) = (self.search, self.joint_names);
        let lv = self.level(b.idx, step);
        if dependence_unresolved(search, &b, names, lv, step, self.report) {
            self.fw.closed.push(search.cands[b.idx].group.clone());
            return;
        }
        let ties = ties_at_step(search, &b, &passing, &self.fw.pred, names, lv);
        let fw = &mut *self.fw;
        for t in &ties {
            // A rival of the same structure whose contribution is not collinear with the chosen
            // one's may be a second effect of the same kind: it stays open and is tried beside
            // the chosen term at the next steps; only if it does not pass there is it a tie.
            if stays_open(&t.term) {
                continue;
            }
            let g = &search.cands[t.idx].group;
            if !fw.closed.contains(g) {
                fw.closed.push(g.clone());
            }
        }
        fw.tied.push((b.idx, ties));
        fw.chosen.push(b.idx);
        fw.cols.extend(search.cols(b.idx));
        fw.closed.push(search.cands[b.idx].group.clone());
        fw.pred = b.fit.pred.clone();
        fw.bic = b.fit.bic;
        fw.accepted.push((step, lv, b));
    }
}

/// The rest-power stage on the fields discovery may try (not meters of the power, not
/// duplicates), each field at rest per trial ([`super::rest`]).
fn rest_power_of(inp: &Inputs, usable: Vec<bool>, rule: &Rule) -> Option<super::rest::RestPower> {
    let fields = inp
        .fields
        .values
        .iter()
        .map(|vals| {
            inp.base_windows
                .iter()
                .map(|ws| {
                    if ws.is_empty() {
                        f64::NAN
                    } else {
                        base_mean(ws, |w| vals[w])
                    }
                })
                .collect()
        })
        .collect();
    let r = super::rest::RestInputs {
        power: inp.base_power,
        start: inp.trial_start,
        fields,
        names: &inp.fields.names,
        usable,
    };
    super::rest::rest_power(&r, rule)
}

/// A note naming the recorded fields left out because they follow session time (the clock
/// rule): when a discovered term uses session time, any of them may be the quantity the effect
/// really follows (a battery voltage that falls steadily, say) — the data cannot tell them from
/// the clock, so they are named beside it instead of being dropped silently.
fn clock_stand_ins(excluded: &[super::fields::ExcludedField]) -> Option<String> {
    let names: Vec<&str> = excluded
        .iter()
        .filter(|e| e.reason.starts_with(super::field_rules::CLOCK_REASON))
        .map(|e| e.name.as_str())
        .collect();
    (!names.is_empty()).then(|| {
        format!(
            "{TIME_NAME} stands for any recorded field that follows it as closely: {} (left out of the search as clock-like); the data cannot tell them from the clock",
            names.join(", ")
        )
    })
}

/// Parameters of the kept terms fitted together, their ties named with them, and the final
/// held-out predictions.
fn finish(
    search: &Search,
    fw: &mut Forward,
    cur: &State,
    joint_names: &[String],
    report: &mut DiscoveryReport,
) -> Result<()> {
    let (chosen, accepted, tied) = (&fw.chosen, &fw.accepted, &mut fw.tied);
    let all: Vec<Vec<f64>> = chosen.iter().flat_map(|&k| search.cols(k)).collect();
    let final_fit = if chosen.is_empty() {
        None
    } else {
        Some(search.base.fit(&all.iter().collect::<Vec<_>>())?)
    };
    let mut off = 0;
    for &k in chosen {
        let Some(&(step, level, ref s)) = accepted.iter().find(|(.., s)| s.idx == k) else {
            continue;
        };
        let ncols = search.cols(k).len();
        let verdict = format!(
            "accepted: held-out RMSE −{:.1} % (p = {:.1e} < {:.1e}, family first: Holm over {} \
             mechanism families of {} candidates), ΔBIC = {:.1}",
            100.0 * s.rel,
            s.p,
            level,
            search.n_families(),
            search.m,
            s.d_bic
        );
        let mut d = to_discovery(s, search, joint_names, level, step, verdict);
        if let Some(f) = &final_fit {
            let g: Vec<f64> = f.gamma[off..off + ncols].to_vec();
            let se: Vec<f64> = (0..ncols)
                .map(|j| {
                    let per: Vec<f64> = f.fold_gamma.iter().map(|t| t[off + j]).collect();
                    jackknife_se(&per)
                })
                .collect();
            d.contribution = (0..all.first().map_or(0, Vec::len))
                .map(|r| (0..ncols).map(|j| g[j] * all[off + j][r]).sum())
                .collect();
            d.params = describe(
                &search.cands[k].kind,
                &search.inp.fields.names,
                joint_names,
                &g,
                &se,
            )
            .3;
        }
        off += ncols;
        (d.flexible, d.follows) = search.flexible(k);
        if let Some((_, ties)) = tied.iter_mut().find(|(i, _)| *i == k) {
            d.name = name_with_ties(&d.name, ties);
            d.tied = ties.drain(..).map(|t| t.term).collect();
        }
        report.accepted.push(d);
    }
    report.cols = all;
    report.pred = final_fit.map_or_else(|| cur.cv.pred.clone(), |f| f.pred);
    report.after = Some(search.base.compare(&cur.cv.pred, &report.pred).3);
    Ok(())
}

/// Standard errors its dependence coefficient must clear for a term × signal to be claimed.
const DEPENDENCE_Z: f64 = 3.0;

/// Whether `b`, the best candidate at `step` (at `level`), is a term × signal whose dependence
/// coefficient k is not resolved (|k| < [`DEPENDENCE_Z`] s.e.): a term × signal says the loss
/// changes with the signal, which needs k resolved, not only the term's gain (a slow signal
/// nearly constant over the session lets k·s + k0 act as a free level, e.g. an efficiency below
/// the base model's a ≥ 1). Such a term is not claimed: it is located (its verdict says why)
/// and it is the best rejected at step 1 or when there is none.
fn dependence_unresolved(
    search: &Search,
    b: &Scored,
    joint_names: &[String],
    level: f64,
    step: usize,
    report: &mut DiscoveryReport,
) -> bool {
    if !matches!(search.cands[b.idx].kind, Kind::Product(..)) {
        return false;
    }
    let d = to_discovery(b, search, joint_names, level, step, String::new());
    let Some(k) = d.params.first().cloned() else {
        return false;
    };
    let unresolved = k.value.abs() < DEPENDENCE_Z * k.std_err || !k.std_err.is_finite();
    if !unresolved {
        return false;
    }
    let verdict = format!(
        "not claimed: it improves the held-out RMSE by {:.1} % (p = {:.1e}), but its \
         dependence on the signal is not resolved (k = {:.3} ± {:.3}, under {} standard \
         errors): unexplained structure, best approximation this term, form not identified",
        100.0 * b.rel,
        b.p,
        k.value,
        k.std_err,
        DEPENDENCE_Z
    );
    // It passed every gate: significant structure, located (never dropped), not claimed.
    let d = Discovery { verdict, ..d };
    report.located.push(d.clone());
    if report.best_rejected.is_none() || step == 1 {
        report.best_rejected = Some(d);
    }
    true
}

fn verdict_of(s: &Scored, level: f64, rule: &Rule) -> String {
    let mut why = Vec::new();
    if s.p >= level {
        why.push(format!("p = {:.1e} ≥ {:.1e} (Holm)", s.p, level));
    }
    if s.d_bic >= rule.bic_threshold {
        why.push(format!("ΔBIC = {:.1}", s.d_bic));
    }
    if s.rel < rule.min_improvement {
        why.push(format!("held-out RMSE improves by {:.2} %", 100.0 * s.rel));
    }
    if !s.plausible {
        why.push("explains more than the signal there is".into());
    }
    format!("rejected: {}", why.join("; "))
}
