//! A library term's rival beyond the library: a candidate that does the term's work on the
//! model without it, and beats it or ties with it.

use anyhow::Result;

use super::candidates::{Inputs, Kind, TIME_NAME, followed};
use super::fit::Base;
use super::search::{Scored, Search, p_better, simpler_nested, to_discovery};
use super::ties::CONFOUNDED_R;
use crate::N_JOINTS;
use crate::diagnose::family::Term;
use crate::diagnose::select::{PowerData, Rule, State, r2_rmse, trial_sse};
use crate::diagnose::stats::{improvement_p_value, pearson};
use crate::diagnose::stepwise::not_significant;

/// A candidate beyond the library that explains what an accepted library term explains, on the
/// model without that term ([`rival_of`]).
pub(crate) struct Rival {
    /// The rival's name (from its structure) and form.
    pub name: String,
    /// The rival is not significantly worse than the library term (a tie): the library term stays claimed, the rival named beside it.
    /// Otherwise the rival is significantly better and replaces the library term.
    pub tied: bool,
    /// Paired one-sided p-value (by trial, held out) that the library term fits better.
    pub p_library: f64,
    /// Held-out RMSE [W] with the library term and with the rival instead.
    pub rmse: [f64; 2],
    /// Correlation over the readings of what each adds to the held-out prediction of the
    /// model without the library term (their regressors as the fits weight them).
    pub correlation: f64,
    /// Groups of the candidates that explain the same as the library term (they pass the gates
    /// without it and not beside it): on a tie none of them may be claimed in its place.
    pub blocked: Vec<String>,
}

/// A candidate that explains what a library term explains ([`rival_of`]).
pub(super) struct Same {
    /// Its score on the model without the term.
    pub(super) s: Scored,
    /// Paired one-sided p-value that the library term fits the held-out trials better.
    pub(super) p_lib: f64,
    /// The same, that the candidate fits better.
    pub(super) p_riv: f64,
    /// Correlation of what each adds to the prediction of the model without the term.
    pub(super) r: f64,
    /// Its held-out RMSE gain over the model with the term (1 − RMSE_rival / RMSE_with).
    pub(super) gain: f64,
}

/// Whether the library itself reads recorded field `name`: the arm motors' position, velocity,
/// torque estimate and winding temperature (`temperature[0]`), and the IMU.
pub(super) fn library_reads(name: &str, arm_motors: &[usize; N_JOINTS]) -> bool {
    name.contains("imu_state.")
        || arm_motors.iter().any(|k| {
            let tag = format!("motor_state[{k}].");
            name.find(&tag).is_some_and(|pos| {
                matches!(
                    &name[pos + tag.len()..],
                    "q" | "dq" | "tau_est" | "temperature[0]"
                )
            })
        })
}

/// Whether candidate `kind` may stand in for a library term as a rival: it follows recorded
/// fields, none of which the library reads ([`library_reads`]). A term on session time or a
/// correction of a base loss term is not another mechanism the data could name instead.
pub(super) fn may_rival(kind: &Kind, names: &[String], arm_motors: &[usize; N_JOINTS]) -> bool {
    let fields = followed(kind, names);
    !fields.is_empty() && (fields.iter()).all(|f| f != TIME_NAME && !library_reads(f, arm_motors))
}

/// The best candidate beyond the library that does the library term's work: every candidate is
/// scored on `without` (the model `with` without the term) with discovery's gates at the first
/// Holm step; those that pass there and no longer pass beside the term explain the same. Of
/// them, one that fits the held-out trials significantly better than `with` (paired test by
/// trial at the rule's α) beats the term — a term on recorded fields the library does not read
/// ([`may_rival`]) or a correction of a base loss term. Otherwise the best term on such fields
/// that is not significantly worse and whose contribution to the prediction is collinear with
/// the term's (r ≥ [`CONFOUNDED_R`]) ties with it. A loss term × signal counts as a term on its
/// field only when it fits significantly better than its level alone (any slow signal would do
/// otherwise), and one whose plain pooled term fits as well is that pooled term. `None` when no
/// rival beats or ties, and always when no recorded field lies beyond the library's.
pub(crate) fn rival_of(
    data: &PowerData,
    with: &State,
    without: &State,
    inp: &Inputs,
    rule: &Rule,
    joint_names: &[String],
) -> Result<Option<Rival>> {
    let (search, _) = Search::new(data, without, inp, rule, &mut Vec::new())?;
    let names = &inp.fields.names;
    if !(search.cands.iter()).any(|c| may_rival(&c.kind, names, &inp.arm_motors)) {
        return Ok(None);
    }
    let same = explaining_same(&search, with, without)?;
    let Some((k, tied)) = pick(&search, &same, with, without) else {
        return Ok(None);
    };
    let c = &same[k];
    let mut blocked: Vec<String> = Vec::new();
    if tied {
        for o in &same {
            let group = &search.cands[o.s.idx].group;
            if !blocked.contains(group) {
                blocked.push(group.clone());
            }
        }
    }
    let rows = search.base.rows;
    let (_, rmse_with) = r2_rmse(&rows.y, &with.cv.pred);
    let (_, rmse_riv) = r2_rmse(&rows.y, &c.s.fit.pred);
    let d = to_discovery(
        &c.s,
        &search,
        joint_names,
        search.flat_level(c.s.idx),
        1,
        String::new(),
    );
    Ok(Some(Rival {
        name: format!("{} ({})", d.name, d.form),
        tied,
        p_library: c.p_lib,
        rmse: [rmse_with, rmse_riv],
        correlation: c.r,
        blocked,
    }))
}

/// The candidates that explain what the term explains: scored on `without` (the search's
/// model), they pass discovery's gates at the first Holm step, and beside the term (on `with`)
/// they no longer pass.
fn explaining_same(search: &Search, with: &State, without: &State) -> Result<Vec<Same>> {
    let (rows, rule) = (search.base.rows, &search.rule);
    let (y_rms, nt) = (search.y_rms(), search.base.data.n_trials);
    let e_with = trial_sse(&rows.y, &with.cv.pred, &rows.trial, nt);
    // What a candidate still adds beside the term: one that no longer passes there explains
    // the same — by the squared-error test (λ = ½): whether it still fits better, not whether
    // it still carries something (the encompassing test finds a rival's remainder).
    let beside = Base::new(search.base.data, with)?;
    let explains_same = |i: usize| {
        let cols = search.cols(i);
        let refs: Vec<&Vec<f64>> = cols.iter().collect();
        !beside.fit(&refs).ok().is_some_and(|fit| {
            let (_, rel, _, _) = beside.compare(&with.cv.pred, &fit.pred);
            let p = p_better(search, &fit.pred, &with.cv.pred);
            p < search.flat_level(i)
                && fit.bic - with.bic < rule.bic_threshold
                && rel >= rule.min_improvement
        })
    };
    // What the term (a candidate) adds to the held-out prediction.
    let add =
        |p: &[f64]| -> Vec<f64> { p.iter().zip(&without.cv.pred).map(|(a, b)| a - b).collect() };
    let lib_add = add(&with.cv.pred);
    let mut same: Vec<Same> = Vec::new();
    for i in 0..search.cands.len() {
        let Some(s) = search.score(i, &[], (&without.cv.pred, without.bic), y_rms) else {
            continue;
        };
        if !search.passes(&s, search.flat_level(i)) || !explains_same(i) {
            continue;
        }
        let e_riv = trial_sse(&rows.y, &s.fit.pred, &rows.trial, nt);
        let d_lib: Vec<f64> = e_riv.iter().zip(&e_with).map(|(a, b)| a - b).collect();
        let d_riv: Vec<f64> = d_lib.iter().map(|v| -v).collect();
        let riv_add = add(&s.fit.pred);
        let sse = |e: &[f64]| e.iter().sum::<f64>();
        same.push(Same {
            p_lib: improvement_p_value(&d_lib),
            p_riv: improvement_p_value(&d_riv),
            r: pearson(&lib_add, &riv_add).0,
            gain: 1.0 - (sse(&e_riv) / sse(&e_with).max(1e-300)).sqrt(),
            s,
        });
    }
    Ok(same)
}

/// Of the candidates in `same`, the one that beats the term (`Some((k, false))`) or, when none
/// does, the one that ties with it (`Some((k, true))`), by the rules of [`rival_of`].
fn pick(search: &Search, same: &[Same], with: &State, without: &State) -> Option<(usize, bool)> {
    let (rule, names, arm) = (
        &search.rule,
        &search.inp.fields.names,
        &search.inp.arm_motors,
    );
    let correction = |c: &Same| {
        matches!(
            search.cands[c.s.idx].kind,
            Kind::PerJoint(_) | Kind::Pooled(_)
        )
    };
    let level_pred = level_predictions(search, same);
    let carried = |c: &Same| match search.cands[c.s.idx].kind {
        Kind::Product(t, ..) => level_pred
            .iter()
            .any(|(u, pred)| *u == t && p_better(search, &c.s.fit.pred, pred) < rule.alpha),
        _ => true,
    };
    let field = |c: &Same| may_rival(&search.cands[c.s.idx].kind, names, arm) && carried(c);
    // A product whose pooled term fits as well is that pooled term.
    let simpler = |k: usize| {
        let refs: Vec<&Scored> = same.iter().map(|c| &c.s).collect();
        simpler_nested(search, &same[k].s, &refs).unwrap_or(k)
    };
    let best_of = |pick: &dyn Fn(&Same) -> bool| {
        (0..same.len())
            .filter(|&k| pick(&same[k]))
            .max_by(|&a, &b| same[a].s.rel.total_cmp(&same[b].s.rel))
            .map(simpler)
    };
    // A state-modulated form of the term under test nests it, so it always fits at least as
    // well: it replaces the term only with the held-out gain every candidate must show (a
    // constant 5 Ω bus loss was otherwise told as "rising with the battery temperature" by a
    // 0.5 % margin of a slightly different form).
    let tested: Vec<&str> = with
        .spec
        .iter()
        .map(|h| h.id)
        .filter(|id| !without.spec.iter().any(|h| h.id == *id))
        .collect();
    let material = |c: &Same| match search.cands[c.s.idx].kind {
        Kind::Product(t, ..) | Kind::Pooled(t)
            if t.library_id().is_some_and(|id| tested.contains(&id)) =>
        {
            c.gain >= rule.min_improvement
        }
        _ => true,
    };
    // Significantly better: a term on a field the library does not read, or a correction of a
    // base loss term (the twin's friction or efficiency is what is wrong).
    let better = best_of(&|c| (field(c) || correction(c)) && c.p_riv < rule.alpha && material(c))
        .filter(|&k| same[k].p_riv < rule.alpha && material(&same[k]));
    // A tie: a term on such a field, not significantly worse, whose contribution is collinear
    // with the term's — another mechanism the data cannot tell apart.
    let tie = || {
        best_of(&|c| field(c) && not_significant(c.p_lib, rule.alpha) && c.r >= CONFOUNDED_R)
            .filter(|&k| field(&same[k]))
    };
    match better {
        Some(k) => Some((k, false)),
        None => tie().map(|k| (k, true)),
    }
}

/// For each loss term among the products in `same`, the held-out prediction with its level
/// alone (the plain pooled term with a free coefficient): a loss term × signal carries its
/// field only when it fits significantly better than that — otherwise any slow signal would
/// do, and the field names nothing.
fn level_predictions(search: &Search, same: &[Same]) -> Vec<(Term, Vec<f64>)> {
    let mut level_pred: Vec<(Term, Vec<f64>)> = Vec::new();
    for c in same {
        if let Kind::Product(t, ..) = search.cands[c.s.idx].kind
            && !level_pred.iter().any(|(u, _)| *u == t)
        {
            let level = search.cols(c.s.idx).swap_remove(1);
            if let Ok(fit) = search.base.fit(&[&level]) {
                level_pred.push((t, fit.pred));
            }
        }
    }
    level_pred
}
