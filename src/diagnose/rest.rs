//! Rest power: what the power rail draws while the arm stands still, trial by trial.
//!
//! The net-power model subtracts each trial's pre-idle baseline, so a load that changes only
//! between trials (a fan stepping with the board temperature, a light switched on) never
//! reaches it, however large. This stage explains the baselines themselves with every usable
//! recorded field's value at rest (its mean over the trial's pre-idle readings) in discovery's
//! shapes (linear, a step at a level chosen from the data, exponential), under discovery's
//! gates: held-out improvement, Holm over every candidate, BIC and a minimum gain. The rest
//! power drifts slowly, so neighbouring trials are not independent: the folds are contiguous
//! blocks of trials, and the test is of what a candidate adds beside the drift, fitted
//! piecewise linear in time over every [`DRIFT_TRIALS`] trials (a step or a switching
//! field is seen where it changes, a field that only follows the clock cannot be told from
//! the drift). A field that falls as the power rises (a supply sagging under the load) reads
//! the rest load and is not a candidate.

use super::family::{Shape, dot, orthonormal_add, residual};
use super::select::{FoldGramsBuilder, Param, RIVAL_ALPHA, Rule, bic, jackknife_se};
use super::stats::{
    STABILITY_DRAWS, encompassing, improvement_p_value, resampled_stability, span, t_upper_tail,
};
use super::stepwise::{self, Gated, holm_level, not_significant};

/// Most trials per block of the held-out test (≈ 4–5 minutes of the protocol); a shorter session
/// has blocks of [`MIN_BLOCK_TRIALS`] or more, enough for [`MIN_BLOCKS`] of them.
const BLOCK_TRIALS: usize = 20;
/// Fewest trials per block (≈ 1 minute of the protocol).
const MIN_BLOCK_TRIALS: usize = 4;
/// Trials per segment of the rail's drift (≈ 2 minutes of the protocol).
pub(crate) const DRIFT_TRIALS: usize = 8;
/// Cross-validation folds (blocks assigned round-robin).
const FOLDS: usize = 10;
/// Most terms found on the rest power.
const MAX_TERMS: usize = 3;
/// Fewest blocks for the test to run.
const MIN_BLOCKS: usize = 10;

/// What the rest-power stage found.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct RestPower {
    /// Trials with a baseline (pre-idle readings).
    pub n_trials: usize,
    /// Blocks of the held-out test.
    pub n_blocks: usize,
    /// Candidates tried (m of the Holm correction).
    pub n_candidates: usize,
    /// Mean rest power over the trials [W].
    pub mean_w: f64,
    /// Held-out RMSE of the trials' rest power with a constant [W].
    pub rmse_before_w: f64,
    /// The same with the terms found [W].
    pub rmse_after_w: f64,
    /// Terms found, in the order accepted.
    pub found: Vec<RestTerm>,
    /// Terms found but located, not claimed: the remainder of the other terms' form (kept in
    /// the model as the best approximation; [`super::parsimony`]'s rule within these rows).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub located: Vec<RestTerm>,
    /// The best candidate not accepted at the first step.
    pub best_rejected: Option<RestTerm>,
    /// Held-out rest power with the terms found, per trial of the stage's input (NaN for the
    /// trials it did not use); empty when nothing was found.
    #[serde(skip)]
    pub trial_pred: Vec<f64>,
    /// Per found term: what it adds to the rest power per trial of the stage's input (NaN where
    /// unknown); what the other meter is checked against.
    #[serde(skip)]
    pub term_cols: Vec<Vec<f64>>,
}

impl RestPower {
    /// Trials per block of the held-out test.
    pub fn block_trials(&self) -> usize {
        self.n_trials / self.n_blocks.max(1)
    }
}

/// A term of the rest power on one recorded field (or session time).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct RestTerm {
    /// In words, from its structure.
    pub name: String,
    /// The field it follows (`topic.field.path`).
    pub field: String,
    /// `P_rest += k·g(x)` or `P_rest += P_on·[x > threshold]`.
    pub form: String,
    /// Its parameters (fitted with the other terms found) ± s.e. (jackknife over folds).
    pub params: Vec<Param>,
    /// p-value of what it adds beside the rail's drift at its step.
    pub p_value: f64,
    /// Holm level it was judged at.
    pub alpha: f64,
    /// ΔBIC of adding it.
    pub delta_bic: f64,
    /// Relative held-out RMSE improvement at its step.
    pub rel_improvement: f64,
    /// Other fields that pass at its step and do not fit significantly worse: the data cannot
    /// tell them from it (named, not claimed).
    pub tied: Vec<String>,
    /// Accepted or rejected, and why.
    pub verdict: String,
    /// What the rail's other meter shows of it ([`super::meters`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub meter: Option<super::meters::MeterCheck>,
    /// For a term found: the share of block resamples in which [`super::parsimony`]'s test
    /// passed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stability: Option<f64>,
}

/// A candidate column: a field in one shape.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Cand {
    field: usize,
    shape: Shape,
}

/// The inputs of the stage, per trial with a baseline.
pub(crate) struct RestInputs<'a> {
    /// Rest power of each trial [W] (NaN: no baseline reading).
    pub power: &'a [f64],
    /// Start of each trial [s].
    pub start: &'a [f64],
    /// Per field: its value at rest per trial.
    pub fields: Vec<Vec<f64>>,
    /// Field names.
    pub names: &'a [String],
    /// Fields that may be tried (not meters of the power, not duplicates).
    pub usable: Vec<bool>,
}

#[derive(Clone)]
struct Fit {
    /// Held-out prediction per trial.
    pred: Vec<f64>,
    /// Coefficients per fold (train fits).
    fold_coef: Vec<Vec<f64>>,
    /// Coefficients on all trials.
    coef: Vec<f64>,
    bic: f64,
}

struct Scored {
    cand: usize,
    fit: Fit,
    p: f64,
    rel: f64,
    d_bic: f64,
}

impl Gated for Scored {
    fn gated(&self) -> (f64, f64, f64) {
        (self.p, self.d_bic, self.rel)
    }
}

struct Search<'a> {
    y: Vec<f64>,
    block: Vec<usize>,
    n_blocks: usize,
    cols: Vec<Vec<f64>>,
    /// Orthonormal basis of the rail's drift (piecewise linear in time).
    drift: Vec<Vec<f64>>,
    cands: Vec<Cand>,
    names: &'a [String],
    rule: Rule,
    /// The projector of the last chosen set [`Search::score`] was called with.
    beside: std::cell::RefCell<Option<(Vec<usize>, Projector)>>,
}

/// An orthonormal basis (the drift and other columns) and the rest power's residual on it.
type Projector = (Vec<Vec<f64>>, Vec<f64>);

fn predict(coef: &[f64], x: &[&[f64]], r: usize) -> f64 {
    coef[0] + x.iter().zip(&coef[1..]).map(|(c, k)| c[r] * k).sum::<f64>()
}

impl Search<'_> {
    fn fit(&self, x: &[&[f64]]) -> Option<Fit> {
        let n = self.y.len();
        let p = x.len() + 1;
        // Each fold's normal equations once; a fold's training set is the total minus it.
        let mut b = FoldGramsBuilder::new(p, FOLDS);
        let mut row = vec![1.0; p];
        for r in 0..n {
            for (c, col) in x.iter().enumerate() {
                row[c + 1] = col[r];
            }
            b.add(self.block[r] % FOLDS, &row, self.y[r]);
        }
        let fg = b.finish();
        let mut pred = vec![f64::NAN; n];
        let mut fold_coef = Vec::new();
        for f in 0..FOLDS {
            let coef: Vec<f64> = fg.train(f).solve(0.0)?.iter().copied().collect();
            for r in (0..n).filter(|&r| self.block[r] % FOLDS == f) {
                pred[r] = predict(&coef, x, r);
            }
            fold_coef.push(coef);
        }
        let coef: Vec<f64> = fg.total.solve(0.0)?.iter().copied().collect();
        let sse: f64 = (0..n)
            .map(|r| (self.y[r] - predict(&coef, x, r)).powi(2))
            .sum();
        let bic = bic(sse, n, p);
        Some(Fit {
            pred,
            fold_coef,
            coef,
            bic,
        })
    }

    fn rmse(&self, pred: &[f64]) -> f64 {
        super::select::r2_rmse(&self.y, pred).1
    }

    fn score(&self, i: usize, chosen: &[usize], cur: &Fit) -> Option<Scored> {
        let mut x: Vec<&[f64]> = chosen.iter().map(|&c| self.cols[c].as_slice()).collect();
        x.push(&self.cols[i]);
        let fit = self.fit(&x)?;
        let mut memo = self.beside.borrow_mut();
        if memo.as_ref().is_some_and(|m| m.0 != chosen) {
            *memo = None;
        }
        let (_, proj) = memo.get_or_insert_with(|| {
            let others: Vec<Vec<f64>> = chosen.iter().map(|&c| self.cols[c].clone()).collect();
            (chosen.to_vec(), self.projector(&others))
        });
        let p = self.beside_drift(proj, &self.cols[i]).0;
        let rel = 1.0 - self.rmse(&fit.pred) / self.rmse(&cur.pred).max(1e-300);
        let d_bic = fit.bic - cur.bic;
        Some(Scored {
            cand: i,
            fit,
            p,
            rel,
            d_bic,
        })
    }

    fn level(&self, step: usize) -> f64 {
        holm_level(self.rule.alpha, self.cands.len(), step)
    }

    /// The drift's basis with the columns `others` added, and the rest power's residual on it.
    fn projector(&self, others: &[Vec<f64>]) -> Projector {
        let mut q = self.drift.clone();
        others.iter().for_each(|c| orthonormal_add(&mut q, c));
        let e = residual(&q, &self.y);
        (q, e)
    }

    /// What `x` adds to the rest power beside the drift and other columns (`projector`): (two-sided
    /// p-value of its coefficient by the t test on the rows with all of them projected out,
    /// squared residuals per trial without it, with it).
    fn beside_drift(&self, (q, e0): &Projector, x: &[f64]) -> (f64, Vec<f64>, Vec<f64>) {
        let xr = residual(q, x);
        let (xx, xe) = (dot(&xr, &xr), dot(&xr, e0));
        let e1: Vec<f64> = e0.iter().zip(&xr).map(|(e, v)| e - xe / xx * v).collect();
        let df = self.y.len() as f64 - q.len() as f64 - 1.0;
        let sq = |e: &[f64]| e.iter().map(|v| v * v).collect::<Vec<_>>();
        let centred = residual(&self.drift[..1], x);
        if xx.is_nan() || xx <= 1e-9 * dot(&centred, &centred) || df < 1.0 {
            return (1.0, sq(e0), sq(e0));
        }
        let t = xe / (dot(&e1, &e1) / df * xx).sqrt();
        let p = (2.0 * t_upper_tail(t.abs(), df)).min(1.0);
        (p, sq(e0), sq(&e1))
    }

    /// Candidate `s` as a term: its coefficient the `j`-th of `fit` (± its jackknife s.e.).
    fn term(&self, s: &Scored, level: f64, verdict: String, (fit, j): (&Fit, usize)) -> RestTerm {
        let (c, field) = (self.cands[s.cand], self.field_of(s.cand));
        let k = fit.coef[j];
        let se = jackknife_se(&fit.fold_coef.iter().map(|c| c[j]).collect::<Vec<_>>());
        let step = matches!(c.shape, Shape::Above(_));
        let name = format!("the rail's rest power {}", c.shape.predicate(&field, k));
        let g = c.shape.formula().replace("s_i", &field);
        let form = format!("P_rest += {}·{g}", if step { "P_on" } else { "k" });
        let param = |name: &str, symbol: &str, scale: f64, unit: &str| {
            Param::new(name, symbol, k * scale, se * scale, unit)
        };
        let params = if step {
            vec![param(
                "load while the field reads above the threshold",
                "P_on",
                1.0,
                "W",
            )]
        } else {
            vec![
                param(
                    "rest-power change over the field's 5–95 % range",
                    "ΔP",
                    span(&self.cols[s.cand]),
                    "W",
                ),
                param("rest power per unit of g(field)", "k", 1.0, "W per unit"),
            ]
        };
        RestTerm {
            name,
            field,
            form,
            params,
            p_value: s.p,
            alpha: level,
            delta_bic: s.d_bic,
            rel_improvement: s.rel,
            tied: Vec::new(),
            verdict,
            meter: None,
            stability: None,
        }
    }
}

/// The candidate columns over `trials`: each usable field in every shape ([`Shape::all_for`]).
fn candidates(inp: &RestInputs, trials: &[usize]) -> (Vec<Vec<f64>>, Vec<Cand>) {
    let mut cols = Vec::new();
    let mut cands = Vec::new();
    for (field, vals) in inp.fields.iter().enumerate() {
        if !inp.usable.get(field).copied().unwrap_or(false) {
            continue;
        }
        let v: Vec<f64> = trials.iter().map(|&t| vals[t]).collect();
        if v.iter().any(|x| !x.is_finite()) || span(&v) <= 0.0 {
            continue;
        }
        for shape in Shape::all_for(&v) {
            let col: Vec<f64> = v.iter().map(|&x| shape.g(x)).collect();
            if span(&col) > 0.0 {
                cols.push(col);
                cands.push(Cand { field, shape });
            }
        }
    }
    (cols, cands)
}

/// Orthonormal basis of the rail's drift over trials starting at `start`: a constant, time, and
/// a hinge at the start of every `seg`-th trial (piecewise linear, continuous).
pub(crate) fn drift_basis(start: &[f64], seg: usize) -> Vec<Vec<f64>> {
    let mut q = Vec::new();
    orthonormal_add(&mut q, &vec![1.0; start.len()]);
    orthonormal_add(&mut q, start);
    for k in (seg..start.len().saturating_sub(seg / 2)).step_by(seg) {
        let hinge: Vec<f64> = start.iter().map(|t| (t - start[k]).max(0.0)).collect();
        orthonormal_add(&mut q, &hinge);
    }
    q
}

/// One accepted step of the forward search: the winner, its Holm level and its rivals' fields.
type Step = (Scored, f64, Vec<String>);

/// Explain the trials' rest power with the fields at rest; `None` when there are too few trials
/// with a baseline for the block test.
pub(crate) fn rest_power(inp: &RestInputs, rule: &Rule) -> Option<RestPower> {
    let trials: Vec<usize> = (0..inp.power.len())
        .filter(|&t| inp.power[t].is_finite() && inp.start[t].is_finite())
        .collect();
    let size = (trials.len() / MIN_BLOCKS).clamp(MIN_BLOCK_TRIALS, BLOCK_TRIALS);
    let n_blocks = trials.len() / size;
    if n_blocks < MIN_BLOCKS {
        return None;
    }
    let n = n_blocks * size;
    let trials = &trials[..n];
    let (cols, cands) = candidates(inp, trials);
    let start: Vec<f64> = trials.iter().map(|&t| inp.start[t]).collect();
    let search = Search {
        y: trials.iter().map(|&t| inp.power[t]).collect(),
        block: (0..n).map(|r| r / size).collect(),
        n_blocks,
        cols,
        drift: drift_basis(&start, DRIFT_TRIALS),
        cands,
        names: inp.names,
        rule: *rule,
        beside: Default::default(),
    };
    let base = search.fit(&[])?;
    let mut out = RestPower {
        n_trials: n,
        n_blocks,
        n_candidates: search.cands.len(),
        mean_w: search.y.iter().sum::<f64>() / n as f64,
        rmse_before_w: search.rmse(&base.pred),
        ..Default::default()
    };
    let mut fw = Forward {
        search: &search,
        chosen: Vec::new(),
        steps: Vec::new(),
        cur: base,
        best_rejected: None,
    };
    stepwise::forward(&mut fw, search.cands.len(), MAX_TERMS).ok()?;
    let (chosen, steps, cur) = (fw.chosen, fw.steps, fw.cur);
    out.best_rejected = fw.best_rejected;
    // A rival found later as a term of its own is not a tie of the earlier ones.
    let found_fields: Vec<String> = chosen.iter().map(|&c| search.field_of(c)).collect();
    for (k, (s, level, tied)) in steps.iter().enumerate() {
        let verdict = format!(
            "accepted: held-out RMSE −{:.1} % (p = {:.1e} < {:.1e} beside the rail's drift piecewise linear over every {DRIFT_TRIALS} trials, Holm over {} candidates), ΔBIC = {:.1}",
            100.0 * s.rel,
            s.p,
            level,
            search.cands.len(),
            s.d_bic
        );
        let mut t = search.term(s, *level, verdict, (&cur, k + 1));
        t.tied = tied
            .iter()
            .filter(|f| !found_fields.contains(f))
            .cloned()
            .collect();
        out.found.push(t);
    }
    out.rmse_after_w = search.rmse(&cur.pred);
    if !out.found.is_empty() {
        search.per_trial(inp, trials, &chosen, &cur, &mut out);
    }
    let tests = search.remainders(&chosen);
    for (k, &(p, held)) in tests.iter().enumerate().rev() {
        out.found[k].stability = Some(held);
        if p < RIVAL_ALPHA && held >= stepwise::STABLE {
            continue;
        }
        let mut t = out.found.remove(k);
        if k < out.term_cols.len() {
            out.term_cols.remove(k);
        }
        t.verdict = format!(
            "located — not claimed: without it (the other rest-power terms piecewise-linear in \
             their fields, and the best step in time) the rest power beside its drift fits at p = {p:.2} (needed < {RIVAL_ALPHA} with a \
             {:.0} % gain), held in {:.0} % of {STABILITY_DRAWS} resamples of the trials (needed \
             ≥ {:.0} %); {}",
            100.0 * rule.min_improvement,
            100.0 * held,
            100.0 * stepwise::STABLE,
            t.verdict
        );
        out.located.insert(0, t);
    }
    Some(out)
}

/// The rest power's side of the stepwise search: the fields chosen, each step's winner with its
/// level and rivals (other fields that pass and do not fit significantly worse), the model they
/// make, and the first step's best failing candidate when none passes there.
struct Forward<'s, 'a> {
    search: &'s Search<'a>,
    chosen: Vec<usize>,
    steps: Vec<Step>,
    cur: Fit,
    best_rejected: Option<RestTerm>,
}

impl stepwise::Stage for Forward<'_, '_> {
    type Scored = Scored;

    fn score(&self, i: usize, _: usize) -> anyhow::Result<Option<Scored>> {
        let s = self.search;
        let open = self.chosen.iter().all(|&c| s.field_of(c) != s.field_of(i));
        Ok(open.then(|| s.score(i, &self.chosen, &self.cur)).flatten())
    }

    fn passes(&self, _: usize, s: &Scored, step: usize) -> bool {
        stepwise::passes(&self.search.rule, s, self.search.level(step))
    }

    fn rejected(&mut self, f: &Scored, winner: Option<&Scored>) {
        if winner.is_none() {
            let mut r = self.search.rejected(f, self.search.level(1));
            r.tied = self.search.ties_of_rejected(f, &self.cur);
            self.best_rejected = Some(r);
        }
    }

    fn accept(&mut self, step: usize, b: Scored, passing: Vec<Scored>) {
        let names = self.search.rivals(&b, &passing, self.search.rule.alpha);
        self.chosen.push(b.cand);
        self.cur = b.fit.clone();
        self.steps.push((b, self.search.level(step), names));
    }
}

impl Search<'_> {
    /// The field a candidate follows: its step and linear forms are one group.
    fn field_of(&self, i: usize) -> String {
        self.names[self.cands[i].field].clone()
    }

    /// [`super::parsimony`]'s rule within the rest power's rows: per term in `chosen`, the test
    /// of what it adds beside the drift, every other term as a piecewise-linear function of its
    /// field and the best step in time ([`Search::best_step`]: a field that changes once cannot
    /// be told from a change of an unrecorded state then) — (p-value, share of resamples of the
    /// trials in which it passes).
    fn remainders(&self, chosen: &[usize]) -> Vec<(f64, f64)> {
        let flex = |c: usize| -> Vec<Vec<f64>> {
            let field = self.cands[c].field;
            let linear = Cand {
                field,
                shape: Shape::Linear,
            };
            let v = (self.cands.iter().position(|d| *d == linear))
                .map_or(&self.cols[c], |i| &self.cols[i]);
            let mut out = vec![v.clone(), self.cols[c].clone()];
            let knots = super::flexible::knots(v).map_or(Vec::new(), |k| k.1);
            out.extend(
                knots
                    .iter()
                    .map(|k| v.iter().map(|x| (x - k).max(0.0)).collect()),
            );
            out
        };
        let sum = |e: &[f64]| e.iter().sum::<f64>();
        (0..chosen.len())
            .map(|k| {
                let others = chosen.iter().enumerate().filter(|(j, _)| *j != k);
                let mut cols: Vec<Vec<f64>> = others.flat_map(|(_, &c)| flex(c)).collect();
                cols.push(self.best_step(&cols));
                let (p, e, e_cur) =
                    self.beside_drift(&self.projector(&cols), &self.cols[chosen[k]]);
                let d: Vec<f64> = e.iter().zip(&e_cur).map(|(a, b)| a - b).collect();
                let seed = 0x5eed_0000 + k as u64;
                let level = (RIVAL_ALPHA, self.rule.min_improvement);
                let held = resampled_stability((&e, &e_cur, &d), level, STABILITY_DRAWS, seed);
                let gain = 1.0 - (sum(&e_cur) / sum(&e).max(1e-300)).sqrt();
                (if gain >= level.1 { p } else { 1.0 }, held)
            })
            .collect()
    }

    /// The step in time (at a trial, at least [`MIN_BLOCK_TRIALS`] on each side) that explains
    /// most of the rest power beside the drift and `others`.
    fn best_step(&self, others: &[Vec<f64>]) -> Vec<f64> {
        let n = self.y.len();
        let (q, e) = self.projector(others);
        let step = |b: usize| {
            (0..n)
                .map(|r| f64::from(u8::from(r >= b)))
                .collect::<Vec<_>>()
        };
        let explained = |b: usize| {
            let x = residual(&q, &step(b));
            dot(&x, &e).powi(2) / dot(&x, &x).max(1e-300)
        };
        let best = (MIN_BLOCK_TRIALS..n.saturating_sub(MIN_BLOCK_TRIALS))
            .map(|b| (b, explained(b)))
            .max_by(|a, b| a.1.total_cmp(&b.1));
        step(best.map_or(0, |b| b.0))
    }

    /// The first step's best candidate, rejected, with why.
    fn rejected(&self, f: &Scored, level: f64) -> RestTerm {
        let verdict = format!(
            "rejected: p = {:.1e} {} {:.1e} (Holm); ΔBIC = {:.1}; held-out RMSE improves by {:.1} %",
            f.p,
            if f.p < level { "<" } else { "≥" },
            level,
            f.d_bic,
            100.0 * f.rel
        );
        self.term(f, level, verdict, (&f.fit, f.fit.coef.len() - 1))
    }

    /// The fields the first step's best candidate `b`, rejected, cannot be told from: every
    /// other candidate that meets the BIC and minimum-gain gates and that `b` does not beat at
    /// [`RIVAL_ALPHA`] (what a location of the rest power names as "X or Y").
    fn ties_of_rejected(&self, b: &Scored, cur: &Fit) -> Vec<String> {
        let gated: Vec<Scored> = (0..self.cands.len())
            .filter_map(|i| self.score(i, &[], cur))
            .filter(|s| s.d_bic < self.rule.bic_threshold && s.rel >= self.rule.min_improvement)
            .collect();
        self.rivals(b, &gated, RIVAL_ALPHA)
    }

    /// Rivals of the step's winner `b`: other fields of `passing` that `b` does not beat at
    /// `alpha`, best first. They stay open (tried beside it at the next step: a second load
    /// passes there, a stand-in not).
    fn rivals(&self, b: &Scored, passing: &[Scored], alpha: f64) -> Vec<String> {
        let mut tied: Vec<(f64, String)> = passing
            .iter()
            .filter(|s| self.field_of(s.cand) != self.field_of(b.cand))
            .filter(|s| {
                let p = improvement_p_value(&encompassing(
                    &self.y,
                    (&b.fit.pred, &s.fit.pred),
                    &self.block,
                    self.n_blocks,
                    0.5,
                ));
                not_significant(p, alpha)
            })
            .map(|s| (self.rmse(&s.fit.pred), self.field_of(s.cand)))
            .collect();
        tied.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut names: Vec<String> = Vec::new();
        for (_, f) in tied {
            if !names.contains(&f) {
                names.push(f);
            }
        }
        names
    }

    /// Per trial of the stage's input: the held-out rest power (`trial_pred`; trials past the
    /// last whole block were not in the test: the fit on all trials) and what each found term
    /// adds (`term_cols`).
    fn per_trial(
        &self,
        inp: &RestInputs,
        trials: &[usize],
        chosen: &[usize],
        cur: &Fit,
        out: &mut RestPower,
    ) {
        let x_of = |c: usize, t: usize| {
            let Cand { field, shape } = self.cands[c];
            shape.g(inp.fields[field][t])
        };
        let all = 0..inp.power.len();
        out.term_cols = chosen
            .iter()
            .enumerate()
            .map(|(k, &c)| all.clone().map(|t| cur.coef[k + 1] * x_of(c, t)).collect())
            .collect();
        out.trial_pred = all
            .map(|t| {
                let terms = chosen.iter().zip(&cur.coef[1..]);
                cur.coef[0] + terms.map(|(&c, k)| x_of(c, t) * k).sum::<f64>()
            })
            .collect();
        for (r, &t) in trials.iter().enumerate() {
            out.trial_pred[t] = cur.pred[r];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rule() -> Rule {
        Rule {
            alpha: 1e-3,
            bic_threshold: -10.0,
            min_improvement: 0.02,
        }
    }

    /// A fan stepping between levels between trials, a drifting rest power, two unrelated
    /// fields and a copy of the fan's level with noise.
    fn inputs(fan_w: f64, seed: u64, n: usize) -> (Vec<f64>, Vec<f64>, Vec<Vec<f64>>, Vec<String>) {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut drift: f64 = 0.0;
        let mut fan = 2000.0;
        let (mut p, mut t, mut f0, mut f1, mut f2) = (vec![], vec![], vec![], vec![], vec![]);
        for i in 0..n {
            drift = 0.95 * drift + 0.1 * (rng.random::<f64>() - 0.5);
            if rng.random::<f64>() < 6.0 / n as f64 {
                fan = [1800.0, 2600.0, 3400.0, 4200.0][rng.random_range(0..4usize)];
            }
            let load = fan_w * (fan / 4200.0f64).powi(3);
            p.push(120.0 + drift + load + 0.2 * (rng.random::<f64>() - 0.5));
            t.push(13.0 * i as f64);
            f0.push(fan + 10.0 * (rng.random::<f64>() - 0.5));
            f1.push(30.0 + rng.random::<f64>());
            f2.push((i as f64 * 0.37).sin());
        }
        let names = vec!["/mb.fan".to_string(), "/x.a".into(), "/x.b".into()];
        (p, t, vec![f0, f1, f2], names)
    }

    #[test]
    fn a_fan_stepping_between_trials_is_found_and_nothing_on_a_quiet_rail() {
        let rest = |fan_w: f64, seed: u64, n: usize| {
            let (p, t, fields, names) = inputs(fan_w, seed, n);
            let inp = RestInputs {
                power: &p,
                start: &t,
                fields,
                names: &names,
                usable: vec![true; 3],
            };
            rest_power(&inp, &rule())
        };
        let run = |fan_w: f64, seed: u64, n: usize| {
            let r = rest(fan_w, seed, n).unwrap();
            // diagnosis.json reads back (a NaN would be written as null).
            let back: RestPower =
                serde_json::from_str(&serde_json::to_string(&r).unwrap()).unwrap();
            assert_eq!(back.found.len(), r.found.len());
            r
        };
        // A paper-scale session finds the fan; in a 15-minute one (55 trials) it is the best
        // candidate, found, located (a fan that changes once is a step in time) or rejected.
        let mut tried = 0;
        for (n, seeds) in [(600, 1..3), (55, 3..23)] {
            for seed in seeds {
                let r = run(5.0, seed, n);
                if n == 600 {
                    assert_eq!(r.found.len(), 1, "{r:?}");
                    assert_eq!(r.found[0].field, "/mb.fan");
                    assert!(r.rmse_after_w < 0.5 * r.rmse_before_w, "{r:?}");
                } else if r.rmse_before_w > 0.5 {
                    tried += 1;
                    assert_eq!(r.n_blocks, 11);
                    let best = (r.found.first().or(r.located.first()))
                        .or(r.best_rejected.as_ref())
                        .unwrap();
                    assert_eq!(best.field, "/mb.fan", "{r:?}");
                }
                let r = run(0.0, seed + 100, n);
                assert!(r.found.is_empty(), "{r:?}");
                assert!(r.best_rejected.is_some());
            }
        }
        assert!(tried >= 12, "the fan changed in {tried} sessions");
        assert!(rest(0.0, 1, 39).is_none(), "fewer than 10 blocks of 4");
    }
}
