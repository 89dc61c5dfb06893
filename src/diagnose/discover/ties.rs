//! The rival rule at a step: candidates on other fields the data cannot tell from the chosen
//! term are named with it as confounded, and never claimed.

use super::candidates::{Kind, Signal, TIME_NAME, followed};
use super::found::TiedTerm;
use super::search::{Scored, Search, p_better, simpler_nested, to_discovery};
use super::words::predicate;
use crate::N_JOINTS;
use crate::diagnose::select::r2_rmse;
use crate::diagnose::stats::pearson;
use crate::diagnose::stepwise::not_significant;

/// Partial correlation (given the library design) above which two terms are confounded.
pub(super) const CONFOUNDED_R: f64 = 0.9;

/// Whether a rival tied with a chosen term stays open to be tried beside it at the later steps
/// of forward selection: one of the same structure whose contribution is not collinear with the
/// chosen one's (r < [`CONFOUNDED_R`]). Such a rival is either a stand-in for the chosen term's
/// signal (beside it, it adds nothing and fails the gates) or a second effect of the same kind
/// (beside it, it passes and is claimed on its own).
pub(super) fn stays_open(t: &TiedTerm) -> bool {
    t.same_structure && t.correlation < CONFOUNDED_R
}

/// Rivals that were tried beside the term they tied with and were accepted themselves are second
/// effects, not ties: taken out of the tie lists, with a note.
pub(super) fn claim_rivals_found_beside(
    search: &Search,
    chosen: &[usize],
    tied: &mut [(usize, Vec<Tie>)],
    notes: &mut Vec<String>,
) {
    let groups: Vec<&String> = chosen.iter().map(|&k| &search.cands[k].group).collect();
    for (k, ties) in tied.iter_mut() {
        if !chosen.contains(k) {
            continue;
        }
        ties.retain(|t| {
            let g = &search.cands[t.idx].group;
            let claimed = groups.contains(&g);
            if claimed {
                notes.push(format!(
                    "tried beside {}, which it tied with when that was found, {g} stays significant: a second effect of the same kind, claimed on its own",
                    search.cands[*k].group
                ));
            }
            !claimed
        });
    }
}

/// Whether two candidates differ only in the signal they follow: both additive loads, both
/// steps, or the same base loss term × a signal.
pub(super) fn same_structure(a: &Kind, b: &Kind) -> bool {
    match (a, b) {
        (Kind::Additive(..), Kind::Additive(..)) | (Kind::Step(..), Kind::Step(..)) => true,
        (Kind::Product(t, ..), Kind::Product(u, ..)) => t == u,
        _ => false,
    }
}

/// The rival rule of discovery: whether `rival`, a candidate that passes the gates at the step
/// where `chosen` is accepted, ties with it. Both must follow a signal (a correction of a base
/// loss term names no field to confound); a rival sharing a field with the chosen term is the
/// same field in another form (a step and a linear load on one field, a loss term × a joint
/// family and × one member of it), not a tie. Otherwise it ties when the chosen term does not
/// fit the held-out trials significantly better (`p_chosen_better` ≥ `alpha`, the paired test
/// by trial) and it has the same structure on another field or a contribution to the
/// prediction collinear with the chosen one's (`r` ≥ [`CONFOUNDED_R`]). `Some(same structure)`
/// for a tie.
pub(super) fn tie_of(
    chosen: &Kind,
    rival: &Kind,
    names: &[String],
    p_chosen_better: f64,
    r: f64,
    alpha: f64,
) -> Option<bool> {
    let (mine, theirs) = (followed(chosen, names), followed(rival, names));
    if mine.is_empty() || theirs.is_empty() || theirs.iter().any(|f| mine.contains(f)) {
        return None;
    }
    let same = same_structure(chosen, rival);
    let not_worse = not_significant(p_chosen_better, alpha);
    (not_worse && (same || r >= CONFOUNDED_R)).then_some(same)
}

/// A rival of a chosen term at its step ([`tie_of`]), as reported, and how its signal reads.
pub(super) struct Tie {
    pub(super) idx: usize,
    pub(super) term: TiedTerm,
    pub(super) predicate: String,
    /// The signal with each arm motor's index as `[*]`: fields of one family across the
    /// motors (they move together) are named as one group.
    pub(super) pattern: String,
}

/// A candidate's signal with the arm motors' indices as `[*]` (a family's key, a member of it,
/// session time, or the field itself).
pub(super) fn pattern(kind: &Kind, names: &[String], arm: &[usize; N_JOINTS]) -> String {
    match kind {
        Kind::Product(_, Signal::Family(k, _), _) => k.clone(),
        Kind::Product(_, Signal::Time, _) => TIME_NAME.into(),
        _ => {
            let mut f = followed(kind, names).join(", ");
            for k in arm {
                f = f.replace(&format!("motor_state[{k}]."), "motor_state[*].");
            }
            f
        }
    }
}

/// Most rivals named in a found term's name (all are listed in the report and the JSON).
pub(super) const TIES_NAMED: usize = 3;

/// The candidates among `passing` (the other candidates that pass the gates at `b`'s step) that
/// tie with the chosen `b` ([`tie_of`]), best held-out fit first. A loss term × signal counts
/// only when it carries its field (no plain pooled term among `passing` fits as well).
pub(super) fn ties_at_step(
    search: &Search,
    b: &Scored,
    passing: &[Scored],
    cur_pred: &[f64],
    joint_names: &[String],
    level: f64,
) -> Vec<Tie> {
    let names = &search.inp.fields.names;
    let chosen = &search.cands[b.idx].kind;
    if followed(chosen, names).is_empty() {
        return Vec::new();
    }
    let add = |p: &[f64]| -> Vec<f64> { p.iter().zip(cur_pred).map(|(a, c)| a - c).collect() };
    let mine = add(&b.fit.pred);
    let refs: Vec<&Scored> = passing.iter().collect();
    let (_, rmse_b) = r2_rmse(&search.base.rows.y, &b.fit.pred);
    let mut ties: Vec<Tie> = Vec::new();
    for s in passing {
        let kind = &search.cands[s.idx].kind;
        if followed(kind, names).is_empty() || simpler_nested(search, s, &refs).is_some() {
            continue;
        }
        let p = p_better(search, &b.fit.pred, &s.fit.pred);
        let (r, _) = pearson(&mine, &add(&s.fit.pred));
        let Some(same) = tie_of(chosen, kind, names, p, r, search.rule.alpha) else {
            continue;
        };
        let n = search.cols(s.idx).len();
        let gamma0 = s
            .fit
            .gamma
            .get(s.fit.gamma.len() - n)
            .copied()
            .unwrap_or(0.0);
        let d = to_discovery(s, search, joint_names, level, 0, String::new());
        let (_, rmse_s) = r2_rmse(&search.base.rows.y, &s.fit.pred);
        ties.push(Tie {
            idx: s.idx,
            predicate: predicate(kind, names, gamma0),
            pattern: pattern(kind, names, &search.inp.arm_motors),
            term: TiedTerm {
                name: d.name,
                form: d.form,
                fields: d.fields,
                params: d.params,
                rmse_w: [rmse_b, rmse_s],
                p_value: p,
                correlation: r,
                same_structure: same,
            },
        });
    }
    ties.sort_by(|a, c| a.term.rmse_w[1].total_cmp(&c.term.rmse_w[1]));
    // Forms of one term × signal are one candidate: its best form is the tie.
    let mut seen: Vec<&String> = Vec::new();
    ties.retain(|t| {
        let g = &search.cands[t.idx].group;
        let product = matches!(search.cands[t.idx].kind, Kind::Product(..));
        let keep = !product || !seen.contains(&g);
        if product {
            seen.push(g);
        }
        keep
    });
    // The best of each group first, so that the first listed are different signals.
    let mut first: Vec<Tie> = Vec::new();
    let mut rest: Vec<Tie> = Vec::new();
    for t in ties {
        if first.iter().any(|f| f.pattern == t.pattern) {
            rest.push(t);
        } else {
            first.push(t);
        }
    }
    first.extend(rest);
    first
}

/// The name of a found term with its ties: "<name>, or <rival> … (confounded: the data cannot
/// tell these fields apart)" — a rival of the same structure by its signal alone, another by
/// its own name. Rivals on one field pattern across the arm motors (`[*]`) are one group, named
/// by its best member with the count of the others; at most [`TIES_NAMED`] groups are named,
/// the rest counted. `ties` lists each group's best member first ([`ties_at_step`]).
pub(super) fn name_with_ties(name: &str, ties: &[Tie]) -> String {
    if ties.is_empty() {
        return name.to_string();
    }
    let mut groups: Vec<(&Tie, usize)> = Vec::new();
    for t in ties {
        match groups.iter_mut().find(|(g, _)| g.pattern == t.pattern) {
            Some((_, n)) => *n += 1,
            None => groups.push((t, 1)),
        }
    }
    let mut alt: Vec<String> = groups
        .iter()
        .take(TIES_NAMED)
        .map(|(t, n)| {
            let head = if t.term.same_structure && !t.predicate.is_empty() {
                t.predicate.clone()
            } else {
                let mut c = t.term.name.chars();
                c.next()
                    .map(|f| f.to_lowercase().collect::<String>() + c.as_str())
                    .unwrap_or_default()
            };
            if *n > 1 {
                format!("{head} (and {} more on {})", n - 1, t.pattern)
            } else {
                head
            }
        })
        .collect();
    if groups.len() > TIES_NAMED {
        let more: usize = groups.iter().skip(TIES_NAMED).map(|(_, n)| n).sum();
        alt.push(format!("{more} other candidate(s) listed with it"));
    }
    format!(
        "{name}, or {} (confounded: the data cannot tell these fields apart)",
        alt.join(", or ")
    )
}
