//! A candidate scored against the current model: its held-out comparison (the paired test by
//! trial), its parameter with a jackknife standard error, the significance rule's verdict, and
//! the latency candidate's nested lag scan.

use anyhow::Result;

use super::fit::*;
use crate::N_PARAMS;
use crate::diagnose::Quality;
use crate::diagnose::hypotheses::{Hypothesis, LATENCY_ID};
use crate::diagnose::stats::EXTENDS;
use crate::diagnose::stepwise::{Gated, Rule};

/// A named physical parameter with its uncertainty.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Param {
    /// What it is.
    pub name: String,
    /// Symbol.
    pub symbol: String,
    /// Estimate.
    pub value: f64,
    /// Standard error (delete-a-fold jackknife over the cross-validation folds).
    pub std_err: f64,
    /// Unit.
    pub unit: String,
}

impl Param {
    /// Inside the physical limits `(lo, hi)`: outside only where the estimate is, by two
    /// standard errors (noise at a limit does not turn a true effect into a location).
    pub(crate) fn within(&self, (lo, hi): (f64, f64)) -> bool {
        let e = 2.0 * self.std_err.max(0.0);
        self.value + e >= lo && self.value - e <= hi
    }

    /// `name` (`symbol`) = `value` ± `std_err` `unit`.
    pub fn new(
        name: impl Into<String>,
        symbol: impl Into<String>,
        value: f64,
        std_err: f64,
        unit: impl Into<String>,
    ) -> Param {
        let (name, symbol, unit) = (name.into(), symbol.into(), unit.into());
        Param {
            name,
            symbol,
            value,
            std_err,
            unit,
        }
    }
}

/// How one hypothesis scored.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct HypothesisScore {
    /// Identifier (`thermal`, `braking`, `bus_loss`, `payload`, `latency`, …).
    pub id: String,
    /// What it is, in words.
    pub title: String,
    /// `power` or `torque`: the comparison level it is scored on.
    pub level: String,
    /// The physical parameter(s), first = the headline parameter.
    pub params: Vec<Param>,
    /// One-sided p-value that the held-out per-trial squared error improves ([`crate::diagnose::stats::improvement_p_value`]).
    pub p_value: f64,
    /// BIC(with hypothesis) − BIC(without), full data; negative favours the hypothesis.
    pub delta_bic: f64,
    /// Held-out RMSE without → with the hypothesis (W at power level, Nm at torque level).
    pub rmse_before: f64,
    /// Held-out RMSE with the hypothesis.
    pub rmse_after: f64,
    /// Held-out R² without the hypothesis.
    pub r2_before: f64,
    /// Held-out R² with the hypothesis.
    pub r2_after: f64,
    /// 1 − rmse_after / rmse_before.
    pub rel_improvement: f64,
    /// Parameter inside its physically plausible range.
    pub plausible: bool,
    /// Accepted by the significance rule (at the selection step it was scored in).
    pub accepted: bool,
    /// Rank among all hypotheses at the first selection step (1 = best).
    pub rank: usize,
    /// Selection step it was scored at (1 = against the base model).
    pub step: usize,
    /// Why it was accepted or rejected.
    pub verdict: String,
    /// For a claim: the share of trial resamples in which [`crate::diagnose::parsimony`]'s test passed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stability: Option<f64>,
}

impl HypothesisScore {
    /// Rejected only for its size: every statistical gate passed, the parameter is implausible.
    pub fn only_implausible(&self) -> bool {
        !self.accepted && self.verdict.strip_prefix("rejected: ") == Some(IMPLAUSIBLE)
    }
}

/// The rule's words for a parameter outside its plausible range: a verdict that is only this is
/// a structure the data support in a size no such mechanism has ([`HypothesisScore::only_implausible`]).
pub(crate) const IMPLAUSIBLE: &str = "parameter outside its physically plausible range";

impl Rule {
    /// Apply the rule: accepted or not, and why.
    pub fn judge(&self, s: &HypothesisScore) -> (bool, String) {
        let mut fails = Vec::new();
        if s.p_value >= self.alpha {
            fails.push(format!(
                "held-out improvement not significant (p = {:.2e} ≥ {:.0e})",
                s.p_value, self.alpha
            ));
        }
        if s.delta_bic >= self.bic_threshold {
            fails.push(format!(
                "ΔBIC = {:.1} ≥ {:.0}",
                s.delta_bic, self.bic_threshold
            ));
        }
        if s.rel_improvement < self.min_improvement {
            fails.push(format!(
                "held-out RMSE improves by {:.2} % < {:.1} %",
                100.0 * s.rel_improvement,
                100.0 * self.min_improvement
            ));
        }
        if !s.plausible {
            fails.push(IMPLAUSIBLE.into());
        }
        if fails.is_empty() {
            (
                true,
                format!(
                    "accepted: held-out RMSE −{:.1} % (p = {:.1e}), ΔBIC = {:.1}, plausible parameter",
                    100.0 * s.rel_improvement,
                    s.p_value,
                    s.delta_bic
                ),
            )
        } else {
            (false, format!("rejected: {}", fails.join("; ")))
        }
    }
}

/// Vertex of the parabola through three points (x sorted), clamped to their span.
fn parabola_vertex(x: [f64; 3], y: [f64; 3]) -> f64 {
    let d1 = (y[1] - y[0]) / (x[1] - x[0]);
    let d2 = (y[2] - y[1]) / (x[2] - x[1]);
    let curv = (d2 - d1) / (x[2] - x[0]);
    if curv <= 0.0 {
        return x[1];
    }
    (0.5 * (x[0] + x[1]) - d1 / (2.0 * curv)).clamp(x[0], x[2])
}

/// Refine the lag of minimal `sse` (indexed like `lags`, sorted ascending) by a parabola.
fn refine_lag(lags: &[f64], sse: &[f64]) -> (usize, f64) {
    let best = (0..lags.len())
        .min_by(|&a, &b| sse[a].total_cmp(&sse[b]))
        .unwrap_or(0);
    if best == 0 || best + 1 >= lags.len() {
        return (best, lags[best]);
    }
    let v = parabola_vertex(
        [lags[best - 1], lags[best], lags[best + 1]],
        [sse[best - 1], sse[best], sse[best + 1]],
    );
    (best, v)
}

/// The outcome of the comparison of a candidate with the current model.
pub(super) struct Candidate {
    pub(super) score: HypothesisScore,
    pub(super) next: State,
}

impl Gated for Candidate {
    fn gated(&self) -> (f64, f64, f64) {
        let s = &self.score;
        (s.p_value, s.delta_bic, s.rel_improvement)
    }
}

fn compare(data: &PowerData, cur: &State, next_pred: &[f64]) -> Held {
    // Every lag's rows are the same readings: y and trial are the lag-0 rows'.
    let rows = data.rows0();
    crate::diagnose::stats::log_p(
        "library",
        &rows.y,
        next_pred,
        &cur.cv.pred,
        &rows.trial,
        data.n_trials,
    );
    Held::new(&rows.y, &cur.cv.pred, next_pred, &rows.trial, data.n_trials)
}

/// Held-out predictions `after` of a model extending `before`'s, compared with `before`: the
/// paired one-sided p-value by trial that `after` improves on it ([`p_improves`] at
/// [`EXTENDS`]), and each one's quality.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Held {
    pub p_value: f64,
    pub before: Quality,
    pub after: Quality,
}

impl Held {
    /// Compare `after` with `before` on readings `y` of trials `trial` (of `n_trials`).
    pub fn new(y: &[f64], before: &[f64], after: &[f64], trial: &[usize], n_trials: usize) -> Held {
        let quality = |pred: &[f64]| {
            let (r2, rmse_w) = r2_rmse(y, pred);
            Quality { r2, rmse_w }
        };
        Held {
            p_value: p_improves(y, (after, before), trial, n_trials, EXTENDS),
            before: quality(before),
            after: quality(after),
        }
    }

    /// 1 − held-out RMSE after / before.
    pub fn gain(&self) -> f64 {
        1.0 - self.after.rmse_w / self.before.rmse_w.max(1e-300)
    }

    /// An unjudged score of candidate `id` (`title`) at `level` ("power", "torque") with
    /// `params`: not accepted, not ranked, no verdict; ΔBIC, plausibility and step unset.
    pub fn score(&self, id: &str, title: &str, level: &str, params: Vec<Param>) -> HypothesisScore {
        HypothesisScore {
            id: id.into(),
            title: title.into(),
            level: level.into(),
            params,
            p_value: self.p_value,
            delta_bic: 0.0,
            rmse_before: self.before.rmse_w,
            rmse_after: self.after.rmse_w,
            r2_before: self.before.r2,
            r2_after: self.after.r2,
            rel_improvement: self.gain(),
            plausible: false,
            accepted: false,
            rank: 0,
            step: 0,
            verdict: String::new(),
            stability: None,
        }
    }
}

pub(super) fn score_term(
    data: &PowerData,
    cur: &State,
    h: &'static Hypothesis,
    step: usize,
) -> Result<Candidate> {
    let mut spec = cur.spec.clone();
    spec.push(h);
    let next = state(data, spec, cur.lag)?;
    let param = term_param(&next, next.spec.len() - 1);
    let held = compare(data, cur, &next.cv.pred);
    let score = HypothesisScore {
        delta_bic: next.bic - cur.bic,
        plausible: param.within(h.plausible),
        step,
        ..held.score(h.id, h.title, "power", vec![param])
    };
    Ok(Candidate { score, next })
}

/// The physical parameter of `st`'s `k`-th term, with its jackknife standard error over the folds.
pub(crate) fn term_param(st: &State, k: usize) -> Param {
    let h = st.spec[k];
    let phys = |t: &[f64]| h.offset + t[N_PARAMS + k];
    let se = jackknife_se(&st.cv.fold_theta.iter().map(|t| phys(t)).collect::<Vec<_>>());
    Param::new(h.title, h.symbol, phys(&st.full.theta), se, h.unit)
}

/// Latency: in each fold the lag is chosen on the training trials only (nested), then judged on
/// the held-out trials, so the scan itself cannot buy a better held-out score.
pub(super) fn score_latency(data: &PowerData, cur: &State, step: usize) -> Result<Candidate> {
    let nl = data.lags.len();
    let fold_fits: Vec<Vec<Fitted>> = (data.grams.iter())
        .map(|fg| fg.fits(&cur.spec, data.reference()))
        .collect::<Result<_>>()?;
    let mut pred = vec![0.0; data.rows0().len()];
    let mut fold_lag = Vec::with_capacity(data.folds.k);
    let mut chosen = vec![0usize; data.folds.k];
    for f in 0..data.folds.k {
        let sse: Vec<f64> = (0..nl)
            .map(|l| data.grams[l].train(f).sse(&fold_fits[l][f].beta))
            .collect();
        let (best, refined) = refine_lag(&data.lags, &sse);
        chosen[f] = best;
        fold_lag.push(refined);
    }
    let full_sse: Vec<f64> = (0..nl)
        .map(|l| {
            data.fit_all(&cur.spec, l)
                .map(|f| data.grams[l].total.sse(&f.beta))
        })
        .collect::<Result<_>>()?;
    let (best, lag) = refine_lag(&data.lags, &full_sse);
    // The chosen lags' rows in one pass (when they are built on demand).
    let mut needed = chosen.clone();
    needed.push(best);
    data.load(&needed)?;
    for (r, p) in pred.iter_mut().enumerate() {
        let f = data.folds.of_trial[data.rows0().trial[r]];
        let l = chosen[f];
        *p = fold_fits[l][f].predict(&data.rows(l)?.x[r]);
    }
    let next = state(data, cur.spec.clone(), best)?;
    // Rows are the same readings at every lag, so per-trial errors compare directly.
    let param = Param::new("sensor latency", "L", lag, jackknife_se(&fold_lag), "s");
    let title = "power-sensor latency (reading averages an earlier window)";
    let score = HypothesisScore {
        delta_bic: next.bic - cur.bic,
        plausible: best > 0 && lag <= 2.0,
        step,
        ..compare(data, cur, &pred).score(LATENCY_ID, title, "power", vec![param])
    };
    Ok(Candidate { score, next })
}
