//! The judging stages of [`super::diagnose_trials`]: ranking every hypothesis, the final refit
//! with the accepted ones, where the held-out residuals lie, and the bus-loss rescaling to the
//! recorded supply voltage.

use crate::N_PARAMS;

use super::hypotheses::LATENCY_ID;
use super::reading_rows::{Rows, TrialMeta};
use super::select::{self, PowerData, Rule, r2_rmse};
use super::{
    Breakdown, Confounded, Correlate, DiscoveryReport, FinalModel, Group, HypothesisScore, Param,
    Quality, TrialResidual, locate, torque,
};

/// Every hypothesis scored against the base model, ranked, and the accepted ones in order.
pub(crate) struct Ranking {
    pub(crate) ranked: Vec<HypothesisScore>,
    pub(crate) accepted: Vec<HypothesisScore>,
}

/// Stage: the torque level's payload hypothesis judged by the power level's rule, then every
/// hypothesis ranked (accepted first, then by held-out improvement).
pub(crate) fn rank_hypotheses(
    sel: &select::Selection,
    torque: Option<&torque::TorqueLevel>,
    rule: &Rule,
) -> Ranking {
    let mut ranked = sel.first_step.clone();
    let mut accepted = sel.accepted.clone();
    if let Some(t) = torque {
        let mut p = t.payload.clone();
        let (ok, why) = rule.judge(&p);
        p.accepted = ok;
        p.verdict = why;
        if ok {
            accepted.push(p.clone());
        }
        ranked.push(p);
    }
    mark_confounded(&mut ranked, &sel.confounded);
    ranked.sort_by(|a, b| {
        (b.accepted, b.rel_improvement)
            .partial_cmp(&(a.accepted, a.rel_improvement))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    for (i, s) in ranked.iter_mut().enumerate() {
        s.rank = i + 1;
    }
    Ranking { ranked, accepted }
}

/// Stage: the final model — the physical parameters of the accepted hypotheses (jackknife
/// standard errors over the folds) and the held-out quality before and after them, per reading
/// and per trial (`rows0`: the rows at no lag).
pub(crate) fn refit_final(
    sel: &select::Selection,
    accepted: &[HypothesisScore],
    torque: Option<&torque::TorqueLevel>,
    rows0: &Rows,
    n_trials: usize,
) -> FinalModel {
    let last = &sel.last;
    let mut params: Vec<Param> = (0..last.spec.len())
        .map(|k| select::term_param(last, k))
        .collect();
    if let Some(lat) = accepted.iter().find(|s| s.id == LATENCY_ID) {
        params.extend(lat.params.iter().cloned());
    }
    if let Some(t) = torque.filter(|t| accepted.iter().any(|s| s.id == t.payload.id)) {
        params.extend(t.payload.params.iter().cloned());
    }
    let y = &rows0.y;
    let quality = |pred: &[f64]| {
        let (r2, rmse_w) = r2_rmse(y, pred);
        Quality { r2, rmse_w }
    };
    let per_trial = |pred: &[f64]| {
        let means = |v: &[f64]| {
            locate::trial_means(rows0.trial.iter().copied().zip(v.iter().copied()), n_trials)
        };
        // The trials with readings.
        let (yt, pt): (Vec<f64>, Vec<f64>) = (means(y).into_iter().zip(means(pred)))
            .filter_map(|(y, p)| y.zip(p))
            .unzip();
        let (r2, rmse_w) = r2_rmse(&yt, &pt);
        Quality { r2, rmse_w }
    };
    FinalModel {
        hypotheses: accepted.iter().map(|s| s.id.clone()).collect(),
        params,
        theta: last.full.theta[..N_PARAMS].to_vec(),
        before: quality(&sel.base.cv.pred),
        after: quality(&last.cv.pred),
        before_per_trial: per_trial(&sel.base.cv.pred),
        after_per_trial: per_trial(&last.cv.pred),
    }
}

/// Where the base model's held-out residuals lie, and the structure the final model leaves.
pub(crate) struct Located {
    pub(crate) breakdowns: Vec<Breakdown>,
    pub(crate) worst: Option<(String, Group)>,
    pub(crate) worst_trials: Vec<TrialResidual>,
    pub(crate) unexplained: Vec<Correlate>,
}

/// Stage: locate with the base model's held-out residuals; correlate what the final model
/// leaves (with the terms found beyond the library when there are any).
pub(crate) fn locate_residuals(
    joint_names: &[String],
    metas: &[TrialMeta],
    data: &PowerData,
    sel: &select::Selection,
    discovery: Option<&DiscoveryReport>,
) -> Located {
    let last = &sel.last;
    let rows0 = data.rows0();
    let resid_base: Vec<f64> = rows0
        .y
        .iter()
        .zip(&sel.base.cv.pred)
        .map(|(a, b)| a - b)
        .collect();
    // What the final model leaves: with the terms found beyond the library when there are any.
    let final_pred = match discovery {
        Some(r) if !r.accepted.is_empty() && r.pred.len() == last.cv.pred.len() => &r.pred,
        _ => &last.cv.pred,
    };
    // Every lag's rows are the same readings (same y).
    let resid_final: Vec<f64> = rows0.y.iter().zip(final_pred).map(|(a, b)| a - b).collect();
    let breakdowns = locate::breakdowns(rows0, metas, &resid_base, joint_names);
    let worst = locate::worst(&breakdowns);
    let worst_trials: Vec<TrialResidual> = locate::trial_residuals(rows0, metas, &resid_base)
        .into_iter()
        .take(10)
        .collect();
    let unexplained = locate::correlates(
        rows0,
        metas,
        &resid_final,
        joint_names,
        data.reference.is_none(),
        0.01,
        6,
    );
    Located {
        breakdowns,
        worst,
        worst_trials,
        unexplained,
    }
}

/// A term dropped as confounded stays in the ranking, not accepted, its verdict saying with what;
/// a library term tied with a term beyond the library stays accepted, the other named.
pub(crate) fn mark_confounded(ranked: &mut [HypothesisScore], confounded: &[Confounded]) {
    for c in confounded {
        for s in ranked.iter_mut().filter(|s| s.id == c.dropped) {
            if c.tied {
                s.verdict = format!(
                    "{}; not told apart from {} (this term fits the held-out trials {:+.1} % better, p = {:.1e} ≥ the test's α; regressor r = {:+.2}): claimed as the library's physical mechanism, the other not excluded",
                    s.verdict,
                    c.kept,
                    100.0 * c.rel_change,
                    c.p_value,
                    c.correlation,
                );
                continue;
            }
            s.accepted = false;
            s.verdict = format!(
                "confounded with {}: not significant given it (p = {:.1e}, held-out RMSE change {:+.1} %, regressor r = {:+.2}); scored alone: {}",
                c.kept,
                c.p_value,
                -100.0 * c.rel_change,
                c.correlation,
                s.verdict
            );
        }
    }
}
