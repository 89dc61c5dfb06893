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
//! Selection: forward (best held-out improvement that passes every gate at the Holm-corrected
//! level α/(m − j), m = candidates tried), never more terms than one per 20 trials; whether each
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

use anyhow::Result;

use super::Quality;
use super::family::{Shape, Term};
use super::fields::FieldTable;
use super::parsimony::{arm_drives, drives, knots, shape_cols, unit_rms};
use super::reading_rows::Rows;
use super::select::{
    Param, PowerData, Rule, State, bic, bounds_for, design_map_for, jackknife_se, r2_rmse,
    solve_bounded_for, trial_sse,
};
use super::stats::{improvement_p_value, pearson, span, step_threshold};
use crate::lsq::Gram;
use crate::{N_JOINTS, N_PARAMS};

/// Correlation with the readings above which a field counts as a meter of the power itself.
const METER_CORRELATION: f64 = 0.5;
/// Within-trial share of a field's variance below which it is a slow state signal.
const SLOW_SHARE: f64 = 0.1;
/// At most one discovered term per this many trials.
const TRIALS_PER_TERM: usize = 20;
/// How candidate names call session time.
const TIME_NAME: &str = "session time";
/// Hard cap on discovered terms.
const MAX_TERMS: usize = 4;
/// Partial correlation (given the library design) above which two terms are confounded.
const CONFOUNDED_R: f64 = 0.9;

/// A slow state signal a loss term may depend on.
#[derive(Debug, Clone)]
pub(crate) enum Signal {
    /// One field for all joints.
    Field(usize),
    /// A field of each joint's own motor (field indices per joint).
    Family(String, [usize; N_JOINTS]),
    /// Session time [h].
    Time,
    /// A field left out as a meter of the power that falls as the power rises (a supply
    /// voltage sagging under the load's current), at rest: its mean over the trial's pre-idle
    /// readings, where it reads the state it stands at (the charge).
    Rest(usize),
}

/// A generated candidate term.
#[derive(Debug, Clone)]
pub(crate) enum Kind {
    /// W per unit of the field (and the field's 5–95 % span, to state the load it swings).
    Additive(usize, f64),
    /// W while the field is above `threshold`.
    Step(usize, f64),
    /// Σ_i term_i · g(signal_i), beside the term's level (a family member, [`super::family`]).
    Product(Term, Signal, Shape),
    /// One coefficient per joint on term_i (held base model only).
    PerJoint(Term),
    /// One coefficient on Σ_i term_i (held base model only).
    Pooled(Term),
}

/// A term found beyond the library.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Discovery {
    /// What it is, in physical words (from the term's structure).
    pub name: String,
    /// Its form as a formula.
    pub form: String,
    /// The recorded field(s) it follows (empty for a base-term correction).
    pub fields: Vec<String>,
    /// Its parameter(s) with standard errors (delete-a-fold jackknife).
    pub params: Vec<Param>,
    /// One-sided paired p-value of the held-out improvement by trial.
    pub p_value: f64,
    /// Level it had to beat (Holm over the candidates tried).
    pub alpha: f64,
    /// ΔBIC of adding it.
    pub delta_bic: f64,
    /// 1 − held-out RMSE after / before.
    pub rel_improvement: f64,
    /// Held-out quality before adding it (per reading).
    pub before: Quality,
    /// Held-out quality after adding it.
    pub after: Quality,
    /// Selection step (1 = first term found).
    pub step: usize,
    /// Why accepted or rejected.
    pub verdict: String,
    /// Candidates on other recorded fields that the data cannot tell from this one at its step
    /// (not significantly worse by the paired held-out test, and of the same structure or with
    /// a collinear contribution): the term is claimed as a mechanism with its field confounded,
    /// and none of them is claimed as a term of its own.
    #[serde(default)]
    pub tied: Vec<TiedTerm>,
    /// What the rail's other meter shows of it: a load or an artefact of the meter it was
    /// found on ([`super::meters`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub meter: Option<super::meters::MeterCheck>,
    /// Share of resamples of the trials (with replacement) in which it passed
    /// [`super::parsimony`]'s test (absent: not measured).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stability: Option<f64>,
    /// The library mechanism this term is a form of (its hypothesis id: a one-sided or
    /// state-switched braking asymmetry, drive-electronics loss, …), if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mechanism: Option<String>,
    /// What it adds to the power, per reading (the final joint fit's coefficients).
    #[serde(skip)]
    pub contribution: Vec<f64>,
    /// Its flexible variant's columns, per reading ([`super::parsimony`]).
    #[serde(skip)]
    pub flexible: Vec<Vec<f64>>,
}

/// A candidate on other field(s) that fits as well as a found term (see [`Discovery::tied`]).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct TiedTerm {
    /// What it is, in physical words (from the term's structure).
    pub name: String,
    /// Its form as a formula.
    pub form: String,
    /// The recorded field(s) it follows (empty for session time).
    pub fields: Vec<String>,
    /// Its parameter(s) fitted in the found term's place, with standard errors.
    pub params: Vec<Param>,
    /// Held-out RMSE (W) with the found term and with this one in its place.
    pub rmse_w: [f64; 2],
    /// One-sided paired p-value (held-out error by trial) that the found term fits better:
    /// at least the acceptance α, so not significantly.
    pub p_value: f64,
    /// Correlation over the readings of what each adds to the held-out prediction.
    pub correlation: f64,
    /// The same structure as the found term (the same base loss term × a signal, or the same
    /// kind of rail load) on another field; otherwise a term whose contribution is collinear
    /// with the found term's (r ≥ 0.9).
    pub same_structure: bool,
}

/// What discovery tried and found.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct DiscoveryReport {
    /// Numeric fields read / kept as candidates (non-constant, complete, distinct, not a meter).
    pub fields_read: usize,
    /// Fields kept.
    pub fields_used: usize,
    /// Candidate terms tried (m of the Holm correction).
    pub n_candidates: usize,
    /// Family-wise false-discovery level across all candidates.
    pub alpha: f64,
    /// Terms found, in the order accepted.
    pub accepted: Vec<Discovery>,
    /// The best candidate that was not accepted (for the report), if any was tried.
    pub best_rejected: Option<Discovery>,
    /// Terms found but located, not claimed: the remainder of another term's form (kept in the
    /// model as the best approximation; [`super::parsimony`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub located: Vec<Discovery>,
    /// Held-out quality before discovery (the library model) and after it.
    pub before: Option<Quality>,
    /// After the discovered terms.
    pub after: Option<Quality>,
    /// Held-out predictions with the discovered terms (per reading, same order as the rows).
    #[serde(skip)]
    pub pred: Vec<f64>,
    /// Regressor columns of the kept terms (per reading), to test library terms given them.
    #[serde(skip)]
    pub cols: Vec<Vec<f64>>,
    /// The trials' rest power explained with the fields at rest (absent with too few trials).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rest: Option<super::rest::RestPower>,
    /// A change over the session of the diagnosed meter's rest reading that the rail's other
    /// meter does not show: a meter artefact (see `meters::compare`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub meter_drift: Option<super::meters::MeterDrift>,
    /// Notes (fields left out as meters of the power, unreadable files).
    pub notes: Vec<String>,
    /// Fields left out by a rule on their own data (constant, counter or clock, hash-/CRC-like),
    /// each with its reason.
    #[serde(default)]
    pub excluded: Vec<super::fields::ExcludedField>,
}

/// Everything discovery needs about the recording beyond the power data.
pub(crate) struct Inputs<'a> {
    /// Field table over the rows' and the baseline readings' windows.
    pub fields: &'a FieldTable,
    /// Window of each row in the table.
    pub row_window: &'a [usize],
    /// Baseline (pre-idle) reading windows of each trial (position in the trial list).
    pub base_windows: &'a [Vec<usize>],
    /// Rest power of each trial: the mean of its baseline readings [W] (NaN without any).
    pub base_power: &'a [f64],
    /// Start of each trial on the session clock [s].
    pub trial_start: &'a [f64],
    /// Per joint: the motor index whose fields belong to it (`motor_state[k]`).
    pub arm_motors: [usize; N_JOINTS],
    /// Fields that meter the rail's current ([`super::DiagnoseOptions::meter_flows`]).
    pub meter_flows: &'a [String],
}

/// Field values on the rows: raw window value and the mean over the row's trial baseline.
struct RowValues {
    raw: Vec<Vec<f64>>,
    baseline: Vec<Vec<f64>>,
    hours: Vec<f64>,
}

impl RowValues {
    fn new(inp: &Inputs, rows: &Rows) -> RowValues {
        let mut raw = Vec::new();
        let mut baseline = Vec::new();
        for vals in &inp.fields.values {
            raw.push((0..rows.len()).map(|r| vals[inp.row_window[r]]).collect());
            baseline.push(
                rows.trial
                    .iter()
                    .map(|&ti| base_mean(&inp.base_windows[ti], |w| vals[w]))
                    .collect(),
            );
        }
        RowValues {
            raw,
            baseline,
            hours: rows.t.iter().map(|t| t / 3600.0).collect(),
        }
    }
}

/// Mean of `f` over a trial's baseline windows (0 without any).
fn base_mean(windows: &[usize], f: impl Fn(usize) -> f64) -> f64 {
    if windows.is_empty() {
        return 0.0;
    }
    windows.iter().map(|&w| f(w)).sum::<f64>() / windows.len() as f64
}

/// A candidate and the group it competes in (forms of one mechanism: at most one accepted).
struct Cand {
    kind: Kind,
    group: String,
    /// Its weight in the weighted Holm correction ([`super::family::weights`]).
    weight: f64,
}

/// Result of fitting the current model plus extra columns.
pub(crate) struct ExtFit {
    /// Held-out prediction per reading.
    pub(crate) pred: Vec<f64>,
    /// Coefficients of the extra columns per fold.
    fold_gamma: Vec<Vec<f64>>,
    /// Coefficients of the extra columns on all data.
    gamma: Vec<f64>,
    bic: f64,
}

/// The library model's design on each row (x_raw · M), fold Grams of it, and the data.
pub(crate) struct Base<'a, 'd> {
    data: &'a PowerData<'d>,
    cur: &'a State,
    rows: &'a Rows,
    xm: Vec<Vec<f64>>,
    /// The normal equations of each fold's rows.
    fold: Vec<Gram>,
    p: usize,
}

impl<'a, 'd> Base<'a, 'd> {
    /// The design of model `cur` on its rows.
    pub(crate) fn new(data: &'a PowerData<'d>, cur: &'a State) -> Result<Base<'a, 'd>> {
        let rows = data.rows(cur.lag)?;
        let m = design_map_for(&cur.spec, &cur.full.theta);
        let p = m.ncols();
        let xm: Vec<Vec<f64>> = rows
            .x
            .iter()
            .map(|x| {
                (0..p)
                    .map(|c| (0..x.len()).map(|r| x[r] * m[(r, c)]).sum())
                    .collect()
            })
            .collect();
        let k = data.folds.k;
        let mut fold = vec![Gram::zeros(p); k];
        for (r, x) in xm.iter().enumerate() {
            fold[data.folds.of_trial[rows.trial[r]]].add_row(x, rows.y[r]);
        }
        Ok(Base {
            data,
            cur,
            rows,
            xm,
            fold,
            p,
        })
    }

    /// Cross-validated and full fit of the library model plus `cols`.
    pub(crate) fn fit(&self, cols: &[&Vec<f64>]) -> Result<ExtFit> {
        let (p, q, k) = (self.p, cols.len(), self.data.folds.k);
        let n = p + q;
        // Per fold Gram of the extended design.
        let mut fg: Vec<Gram> = self.fold.iter().map(|g| g.widened(q)).collect();
        for (r, x) in self.xm.iter().enumerate() {
            let f = self.data.folds.of_trial[self.rows.trial[r]];
            let Gram { g, h, .. } = &mut fg[f];
            let y = self.rows.y[r];
            for (j, c) in cols.iter().enumerate() {
                let e = c[r];
                if e == 0.0 {
                    continue;
                }
                h[p + j] += e * y;
                for a in 0..p {
                    g[(a, p + j)] += x[a] * e;
                }
                for (l, c2) in cols.iter().enumerate() {
                    g[(p + l, p + j)] += c2[r] * e;
                }
            }
        }
        for Gram { g, .. } in fg.iter_mut() {
            for j in p..n {
                for a in 0..p {
                    g[(j, a)] = g[(a, j)];
                }
            }
        }
        let mut total = Gram::zeros(n);
        for g in &fg {
            total.add(g);
        }
        let (lo, hi) = bounds_for(n, self.data.reference.as_deref());
        let mut fold_theta = Vec::with_capacity(k);
        for g in &fg {
            let train = total.minus(g);
            fold_theta.push(solve_bounded_for(&train.g, &train.h, &lo, &hi)?);
        }
        let full = solve_bounded_for(&total.g, &total.h, &lo, &hi)?;
        let pred = (0..self.rows.len())
            .map(|r| {
                let th = &fold_theta[self.data.folds.of_trial[self.rows.trial[r]]];
                let base: f64 = self.xm[r].iter().zip(th.iter()).map(|(a, b)| a * b).sum();
                base + cols
                    .iter()
                    .enumerate()
                    .map(|(j, c)| c[r] * th[p + j])
                    .sum::<f64>()
            })
            .collect();
        let sse = total.sse(&full);
        let n_free = if self.data.reference.is_some() {
            0
        } else {
            N_PARAMS
        } + self.cur.spec.len()
            + usize::from(self.cur.lag != 0)
            + q;
        Ok(ExtFit {
            pred,
            fold_gamma: fold_theta
                .iter()
                .map(|t| t.iter().skip(p).copied().collect())
                .collect(),
            gamma: full.iter().skip(p).copied().collect(),
            bic: bic(sse, total.n, n_free),
        })
    }

    /// Compare predictions `after` with `before`: (p, rel improvement, before, after quality).
    fn compare(&self, before: &[f64], after: &[f64]) -> (f64, f64, Quality, Quality) {
        let y = &self.rows.y;
        let nt = self.data.n_trials;
        let eb = trial_sse(y, before, &self.rows.trial, nt);
        let ea = trial_sse(y, after, &self.rows.trial, nt);
        let d: Vec<f64> = eb.iter().zip(&ea).map(|(a, b)| a - b).collect();
        let (r2b, rb) = r2_rmse(y, before);
        let (r2a, ra) = r2_rmse(y, after);
        (
            improvement_p_value(&d),
            1.0 - ra / rb.max(1e-300),
            Quality {
                r2: r2b,
                rmse_w: rb,
            },
            Quality {
                r2: r2a,
                rmse_w: ra,
            },
        )
    }
}

/// Share of a series' variance that lies within trials.
fn within_share(v: &[f64], trial: &[usize], n_trials: usize) -> f64 {
    let mut s = vec![0.0; n_trials];
    let mut c = vec![0usize; n_trials];
    for (x, &t) in v.iter().zip(trial) {
        s[t] += x;
        c[t] += 1;
    }
    let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
    let (mut within, mut total) = (0.0, 0.0);
    for (x, &t) in v.iter().zip(trial) {
        let m = s[t] / c[t] as f64;
        within += (x - m).powi(2);
        total += (x - mean).powi(2);
    }
    within / total.max(1e-300)
}

/// Per-motor families: fields `…motor_state[k].rest` present for every arm motor.
fn families(names: &[String], arm: &[usize; N_JOINTS]) -> Vec<(String, [usize; N_JOINTS])> {
    use std::collections::BTreeMap;
    let mut by_key: BTreeMap<String, [Option<usize>; N_JOINTS]> = BTreeMap::new();
    for (f, name) in names.iter().enumerate() {
        for (j, &k) in arm.iter().enumerate() {
            let tag = format!("[{k}].");
            if let Some(pos) = name.find(&tag) {
                let key = format!("{}[*].{}", &name[..pos], &name[pos + tag.len()..]);
                by_key.entry(key).or_insert([None; N_JOINTS])[j] = Some(f);
            }
        }
    }
    by_key
        .into_iter()
        .filter_map(|(k, v)| {
            let all: Option<Vec<usize>> = v.iter().copied().collect();
            all.map(|a| (k, std::array::from_fn(|j| a[j])))
        })
        .collect()
}

/// Columns of a candidate on the rows.
fn columns(kind: &Kind, inp: &Inputs, rv: &RowValues, rows: &Rows) -> Vec<Vec<f64>> {
    let n = rows.len();
    match kind {
        Kind::Additive(f, _) => vec![(0..n).map(|r| rv.raw[*f][r] - rv.baseline[*f][r]).collect()],
        Kind::Step(f, thr) => {
            let vals = &inp.fields.values[*f];
            let on = |v: f64| f64::from(u8::from(v > *thr));
            vec![
                (0..n)
                    .map(|r| {
                        on(rv.raw[*f][r])
                            - base_mean(&inp.base_windows[rows.trial[r]], |w| on(vals[w]))
                    })
                    .collect(),
            ]
        }
        Kind::Product(t, sig, shape) => {
            let s = |r: usize, i: usize| match sig {
                Signal::Field(f) => rv.raw[*f][r],
                Signal::Family(_, fs) => rv.raw[fs[i]][r],
                Signal::Time => rv.hours[r],
                Signal::Rest(f) => rv.baseline[*f][r],
            };
            // The level column lets the term's coefficient at signal 0 take any sign (the base
            // coefficients it would otherwise shift are bounded at 0).
            vec![
                (0..n)
                    .map(|r| t.sum(&rows.x[r], &|i| shape.g(s(r, i))))
                    .collect(),
                (0..n).map(|r| t.sum(&rows.x[r], &|_| 1.0)).collect(),
            ]
        }
        Kind::PerJoint(t) => (0..N_JOINTS)
            .map(|i| (0..n).map(|r| t.value(&rows.x[r], i)).collect())
            .collect(),
        Kind::Pooled(t) => vec![(0..n).map(|r| t.sum(&rows.x[r], &|_| 1.0)).collect()],
    }
}

/// A signal's values on the rows (every member's, for a family).
fn signal_values(s: &Signal, rv: &RowValues) -> Vec<f64> {
    match s {
        Signal::Field(f) => rv.raw[*f].clone(),
        Signal::Family(_, fs) => fs.iter().flat_map(|&f| rv.raw[f].iter().copied()).collect(),
        Signal::Time => rv.hours.clone(),
        Signal::Rest(f) => rv.baseline[*f].clone(),
    }
}

/// Generate every candidate, fields that meter the power itself left out (noted), and keep
/// those [`super::family::screen`] passes on the current model's residual `resid`; the
/// weighted Holm correction over all generated is returned last.
fn generate(
    inp: &Inputs,
    rows: &Rows,
    n_trials: usize,
    twin: bool,
    resid: &[f64],
    notes: &mut Vec<String>,
) -> (Vec<Cand>, RowValues, Vec<bool>, Holm) {
    let names = &inp.fields.names;
    let rv = RowValues::new(inp, rows);
    let mut meters = Vec::new();
    let mut usable = vec![true; names.len()];
    // Meters that fall as the power rises: a supply sagging under the load.
    let mut sags = vec![false; names.len()];
    let single: Vec<bool> = (0..names.len())
        .map(|f| !inp.fields.duplicate.get(f).copied().unwrap_or(false))
        .collect();
    for f in 0..names.len() {
        let net: Vec<f64> = (0..rows.len())
            .map(|r| rv.raw[f][r] - rv.baseline[f][r])
            .collect();
        let (r, _) = pearson(&net, &rows.y);
        // A current meter of the rail is left out whatever its correlation: sampled on its own
        // clock, or beside a large unmodelled effect, it can track the readings loosely and
        // still follow every residual the rail carries.
        let flow = inp.meter_flows.contains(&names[f]);
        if flow || r.abs() >= METER_CORRELATION {
            usable[f] = false;
            sags[f] = !flow && r < 0.0;
            if single[f] {
                meters.push(format!("{} (r = {r:+.2})", names[f]));
            }
        }
    }
    if !meters.is_empty() {
        notes.push(format!(
            "left out as meters of the power itself (the rail's current meters, and fields with |r| ≥ {METER_CORRELATION} with the readings): {}; those that fall as it rises (a supply sagging under the load) are tried at rest (their mean over each trial's pre-idle readings) as slow state signals",
            meters.join(", ")
        ));
    }
    let mut kinds: Vec<(Kind, String)> = Vec::new();
    let mut slow = vec![Signal::Time];
    // A meter that falls as the power rises is the supply sagging under the load (a battery
    // voltage): at rest it reads the source's state (the charge), a slow state signal when it
    // changes from trial to trial. One that rises with the power is the flow itself, at rest
    // the rest load: not a state.
    for f in (0..names.len()).filter(|&f| sags[f] && single[f]) {
        let rest = &rv.baseline[f];
        let first = rest.first().copied().unwrap_or(0.0);
        if rest.iter().all(|v| v.is_finite()) && rest.iter().any(|&v| v != first) {
            slow.push(Signal::Rest(f));
        }
    }
    for f in (0..names.len()).filter(|&f| usable[f] && single[f]) {
        kinds.push((
            Kind::Additive(f, span(&rv.raw[f])),
            format!("field {}", names[f]),
        ));
        if let Some(thr) = step_threshold(&rv.raw[f]) {
            kinds.push((Kind::Step(f, thr), format!("field {}", names[f])));
        }
        if within_share(&rv.raw[f], &rows.trial, n_trials) < SLOW_SHARE {
            slow.push(Signal::Field(f));
        }
    }
    for (key, fs) in families(names, &inp.arm_motors) {
        let ok = fs.iter().all(|&f| usable[f])
            && fs
                .iter()
                .all(|&f| within_share(&rv.raw[f], &rows.trial, n_trials) < SLOW_SHARE);
        if ok {
            slow.push(Signal::Family(key, fs));
        }
    }
    // The family: every term × every slow signal it can pair with × every shape; the linear
    // forms of the base terms and the drive current always scored, the rest screened.
    let mut family: Vec<Option<Term>> = vec![None; kinds.len()];
    for t in Term::ALL {
        for s in slow
            .iter()
            .filter(|s| t.per_joint() || !matches!(s, Signal::Family(..)))
        {
            let g = format!("{t:?} × {}", signal_name(s, names));
            for shape in Shape::all_for(&signal_values(s, &rv)) {
                family.push(super::family::screened(t, shape).then_some(t));
                kinds.push((Kind::Product(t, s.clone(), shape), g.clone()));
            }
        }
        // A one-sided form of a library mechanism the library does not hold, on its own.
        if t.level_is_new() || (twin && Term::BASE.contains(&t)) {
            family.push(None);
            kinds.push((Kind::Pooled(t), format!("{t:?} correction")));
        }
        if twin && Term::BASE.contains(&t) {
            family.push(None);
            kinds.push((Kind::PerJoint(t), format!("{t:?} correction")));
        }
    }
    let m = kinds.len();
    let is_screened: Vec<bool> = family.iter().map(Option::is_some).collect();
    let weights = super::family::weights(&is_screened);
    let keep = super::family::screen(&family, &|i| columns(&kinds[i].0, inp, &rv, rows), resid);
    let w_min = weights.iter().copied().fold(1.0, f64::min);
    let holm = Holm {
        m,
        total: weights.iter().sum(),
        w_min,
    };
    let cands = keep
        .into_iter()
        .map(|i| Cand {
            kind: kinds[i].0.clone(),
            group: kinds[i].1.clone(),
            weight: weights[i],
        })
        .collect();
    let tried: Vec<bool> = (0..names.len()).map(|f| usable[f] && single[f]).collect();
    (cands, rv, tried, holm)
}

/// The weighted Holm correction over every candidate generated.
#[derive(Debug, Clone, Copy)]
struct Holm {
    /// Candidates generated.
    m: usize,
    /// Their total weight.
    total: f64,
    /// The smallest weight (what an accepted term removes at least).
    w_min: f64,
}

fn signal_name(s: &Signal, names: &[String]) -> String {
    match s {
        Signal::Field(f) => names[*f].clone(),
        Signal::Family(k, _) => format!("{k} (each joint's own motor)"),
        Signal::Time => TIME_NAME.into(),
        Signal::Rest(f) => format!("{} at rest", names[*f]),
    }
}

/// Fitted coefficients of a candidate and their standard errors, turned into named parameters.
struct Fitted<'a> {
    gamma: &'a [f64],
    se: &'a [f64],
}

impl Fitted<'_> {
    fn param(&self, name: String, symbol: &str, j: usize, unit: String) -> Param {
        Param {
            name,
            symbol: symbol.into(),
            value: self.gamma.get(j).copied().unwrap_or(f64::NAN),
            std_err: self.se.get(j).copied().unwrap_or(f64::NAN),
            unit,
        }
    }

    /// `up` when the first coefficient is ≥ 0, `down` otherwise.
    fn sign(&self, up: &str, down: &str) -> String {
        if self.gamma.first().copied().unwrap_or(0.0) >= 0.0 {
            up.to_string()
        } else {
            down.to_string()
        }
    }
}

/// Name, formula, fields and parameters of a fitted candidate, from its structure only.
pub(crate) fn describe(
    kind: &Kind,
    names: &[String],
    joint_names: &[String],
    gamma: &[f64],
    se: &[f64],
) -> (String, String, Vec<String>, Vec<Param>) {
    let fit = Fitted { gamma, se };
    match kind {
        Kind::Additive(f, sp) => {
            let mut swing = fit.param(
                "load change over the field's 5–95 % range".into(),
                "ΔP",
                0,
                "W".into(),
            );
            swing.value *= sp;
            swing.std_err *= sp;
            (
                format!(
                    "a load on the power rail that {} {}",
                    fit.sign("rises with", "falls as it rises:"),
                    names[*f]
                ),
                format!("P += k·{}", names[*f]),
                vec![names[*f].clone()],
                vec![
                    swing,
                    fit.param(
                        "load per unit of the field".into(),
                        "k",
                        0,
                        "W per unit".into(),
                    ),
                ],
            )
        }
        Kind::Step(f, thr) => (
            format!(
                "a rail load that switches with {} (drawn while it reads above {thr:.4})",
                names[*f]
            ),
            format!("P += P_on·[{} > {thr:.4}]", names[*f]),
            vec![names[*f].clone()],
            vec![fit.param("power while on".into(), "P_on", 0, "W".into())],
        ),
        Kind::Product(t, s, shape) => describe_product(*t, s, *shape, names, &fit),
        Kind::PerJoint(t) => (
            format!(
                "{} differs joint by joint from the model",
                capitalise(t.words())
            ),
            format!("P += Σ_i k_i·{}", t.symbol()),
            Vec::new(),
            identified_or_pooled(
                (0..N_JOINTS)
                    .map(|i| {
                        let j = joint_names
                            .get(i)
                            .cloned()
                            .unwrap_or_else(|| format!("joint {i}"));
                        fit.param(
                            format!("excess on {j}"),
                            &format!("k_{i}"),
                            i,
                            t.unit().into(),
                        )
                    })
                    .collect(),
            ),
        ),
        Kind::Pooled(t) if t.level_is_new() => (
            format!("{} is missing from the model", capitalise(t.words())),
            format!("P += k·Σ_i {}", t.symbol()),
            Vec::new(),
            vec![fit.param("coefficient".into(), "k", 0, t.unit().into())],
        ),
        Kind::Pooled(t) => (
            format!(
                "{} of all joints is {} than the model's",
                capitalise(t.words()),
                fit.sign("larger", "smaller")
            ),
            format!("P += k·Σ_i {}", t.symbol()),
            Vec::new(),
            vec![fit.param("common excess".into(), "k", 0, t.unit().into())],
        ),
    }
}

/// [`describe`] of a loss term or library mechanism times a slow state signal in a shape.
fn describe_product(
    t: Term,
    s: &Signal,
    shape: Shape,
    names: &[String],
    fit: &Fitted,
) -> (String, String, Vec<String>, Vec<Param>) {
    let fields = match s {
        Signal::Field(f) | Signal::Rest(f) => vec![names[*f].clone()],
        Signal::Family(_, fs) => fs.iter().map(|&f| names[f].clone()).collect(),
        Signal::Time => Vec::new(),
    };
    let sname = match s {
        Signal::Rest(f) => format!(
            "{} at rest (its mean over each trial's pre-idle readings)",
            names[*f]
        ),
        _ => signal_words(s, names),
    };
    let mut ps = vec![fit.param(
        format!("change of {} per unit of the signal", t.words()),
        "k",
        0,
        format!("{} per unit", t.unit()),
    )];
    if fit.gamma.len() > 1 {
        ps.push(fit.param("level at signal 0".into(), "k0", 1, t.unit().into()));
    }
    (
        format!(
            "{} of the arm's joints {}",
            capitalise(t.words()),
            shape.predicate(&sname, fit.gamma.first().copied().unwrap_or(0.0))
        ),
        format!(
            "P += Σ_i {}·(k·{}{})",
            t.symbol(),
            shape.formula(),
            if fit.gamma.len() > 1 { " + k0" } else { "" }
        ),
        fields,
        ps,
    )
}

/// Largest standard error, as a fraction of |k_i|, of a per-joint coefficient reported on its
/// own: at 4 % a 10 % error is 2.5 standard errors.
pub const IDENTIFIED_REL_SE: f64 = 0.04;

/// Per-joint coefficients: those the data identify (s.e. ≤ [`IDENTIFIED_REL_SE`]·|k_i|) are
/// reported one by one; the others are pooled into one inverse-variance weighted coefficient
/// `k_pooled` (named after the joints it covers), since the data do not tell them apart.
fn identified_or_pooled(params: Vec<Param>) -> Vec<Param> {
    let ok = |p: &Param| p.std_err.is_finite() && p.std_err <= IDENTIFIED_REL_SE * p.value.abs();
    let (mut out, rest): (Vec<Param>, Vec<Param>) = params.into_iter().partition(ok);
    let w: Vec<f64> = rest
        .iter()
        .map(|p| 1.0 / p.std_err.max(1e-12).powi(2))
        .collect();
    let sw: f64 = w.iter().sum();
    if let Some(first) = rest.first() {
        let joints: Vec<&str> = rest
            .iter()
            .map(|p| p.name.trim_start_matches("excess on "))
            .collect();
        out.push(Param {
            name: format!(
                "common excess on {} (not identified joint by joint: s.e. > {:.0} % of the value)",
                joints.join(", "),
                100.0 * IDENTIFIED_REL_SE
            ),
            symbol: "k_pooled".into(),
            value: rest.iter().zip(&w).map(|(p, w)| p.value * w).sum::<f64>() / sw,
            std_err: 1.0 / sw.sqrt(),
            unit: first.unit.clone(),
        });
    }
    out
}

fn capitalise(s: &str) -> String {
    let mut c = s.chars();
    c.next()
        .map(|f| f.to_uppercase().collect::<String>() + c.as_str())
        .unwrap_or_default()
}

/// A scored candidate.
struct Scored {
    idx: usize,
    fit: ExtFit,
    p: f64,
    rel: f64,
    d_bic: f64,
    before: Quality,
    after: Quality,
    plausible: bool,
}

/// Forward selection over the candidates at the Holm level; returns the accepted (step,
/// score) pairs and the best rejected candidate of the first step.
struct Search<'a, 'd> {
    base: Base<'a, 'd>,
    cands: Vec<Cand>,
    rv: RowValues,
    inp: &'a Inputs<'a>,
    rule: Rule,
    holm: Holm,
}

impl Search<'_, '_> {
    fn cols(&self, i: usize) -> Vec<Vec<f64>> {
        columns(&self.cands[i].kind, self.inp, &self.rv, self.base.rows)
    }

    /// The weighted Holm level of a candidate of weight 1 at `step` (a candidate's own level is
    /// this times its weight).
    fn level(&self, step: usize) -> f64 {
        let h = self.holm;
        self.rule.alpha / (h.total - (step - 1) as f64 * h.w_min).max(1.0)
    }

    /// Score candidate `i` on top of the chosen columns `prev` (current predictions and BIC).
    fn score(&self, i: usize, prev: &[Vec<f64>], cur: (&[f64], f64), y_rms: f64) -> Option<Scored> {
        let own = self.cols(i);
        let mut cols: Vec<&Vec<f64>> = prev.iter().collect();
        cols.extend(own.iter());
        // A candidate whose fit fails (a degenerate column) is not a discovery.
        let fit = self.base.fit(&cols).ok()?;
        let (p, rel, before, after) = self.base.compare(cur.0, &fit.pred);
        let n = self.base.rows.len().max(1) as f64;
        let contrib: f64 = (0..self.base.rows.len())
            .map(|r| {
                own.iter()
                    .enumerate()
                    .map(|(j, c)| c[r] * fit.gamma[prev.len() + j])
                    .sum::<f64>()
                    .powi(2)
            })
            .sum();
        // A loss the model lacks (a one-sided form of a library mechanism, on its own) draws
        // power: a negative coefficient is another term's remainder, not that loss.
        let loss_sign = match self.cands[i].kind {
            Kind::Pooled(t) if t.level_is_new() => fit.gamma[prev.len()] > 0.0,
            _ => true,
        };
        let plausible =
            fit.gamma.iter().all(|g| g.is_finite()) && (contrib / n).sqrt() <= y_rms && loss_sign;
        Some(Scored {
            idx: i,
            d_bic: fit.bic - cur.1,
            fit,
            p,
            rel,
            before,
            after,
            plausible,
        })
    }

    /// The flexible variant of candidate `i` ([`super::parsimony`]): its own columns, then for
    /// a loss term its value per joint and [`shape_cols`] of it over the signal it follows
    /// (session time for none; a family's mean over the joints), for a rail load a
    /// piecewise-linear function of its field (net of the trial's pre-idle value).
    fn flexible(&self, i: usize) -> Vec<Vec<f64>> {
        let (rows, rv) = (self.base.rows, &self.rv);
        let mut cols = self.cols(i);
        let (t, s) = match &self.cands[i].kind {
            Kind::Additive(f, _) | Kind::Step(f, _) => {
                let (raw, base) = (&rv.raw[*f], &rv.baseline[*f]);
                let Some((_, knots)) = knots(raw) else {
                    return cols;
                };
                let hinge = |k: f64| {
                    raw.iter()
                        .zip(base)
                        .map(move |(a, b)| (a - k).max(0.0) - (b - k).max(0.0))
                };
                cols.push(raw.iter().zip(base).map(|(a, b)| a - b).collect());
                cols.extend(knots.into_iter().map(|k| hinge(k).collect()));
                unit_rms(&mut cols);
                return cols;
            }
            Kind::Product(t, Signal::Family(_, fs), _) => {
                let mean = (0..rows.len())
                    .map(|r| fs.iter().map(|&f| rv.raw[f][r]).sum::<f64>() / N_JOINTS as f64);
                (*t, mean.collect())
            }
            Kind::Product(t, sig, _) => (*t, signal_values(sig, rv)),
            Kind::PerJoint(t) | Kind::Pooled(t) => (*t, rv.hours.clone()),
        };
        let g: Vec<f64> = rows.x.iter().map(|x| t.sum(x, &|_| 1.0)).collect();
        let driving = rows.x.iter().zip(&g).map(|(x, v)| match t.per_joint() {
            true => (0..N_JOINTS)
                .filter(|&i| drives(x, i))
                .map(|i| t.value(x, i))
                .sum(),
            false => v * f64::from(u8::from(arm_drives(x))),
        });
        if t.per_joint() {
            cols.extend((0..N_JOINTS).map(|i| rows.x.iter().map(|x| t.value(x, i)).collect()));
        }
        cols.extend(shape_cols(&g, driving.collect(), &s));
        unit_rms(&mut cols);
        cols
    }

    fn passes(&self, s: &Scored, level: f64) -> bool {
        s.p < level
            && s.d_bic < self.rule.bic_threshold
            && s.rel >= self.rule.min_improvement
            && s.plausible
    }
}

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
    let base = Base::new(data, cur)?;
    let rows = base.rows;
    let twin = data.reference.is_some();
    let mut report = DiscoveryReport {
        fields_read: inp.fields.n_read,
        fields_used: inp.fields.names.len(),
        alpha: rule.alpha,
        notes: inp.fields.notes.clone(),
        excluded: inp.fields.excluded.clone(),
        ..Default::default()
    };
    let resid: Vec<f64> = rows
        .y
        .iter()
        .zip(&cur.cv.pred)
        .map(|(y, p)| y - p)
        .collect();
    let (cands, rv, usable, holm) =
        generate(inp, rows, data.n_trials, twin, &resid, &mut report.notes);
    report.rest = rest_power_of(inp, usable, rule);
    report.n_candidates = holm.m;
    report.fields_used = (0..inp.fields.names.len())
        .filter(|&f| !inp.fields.duplicate.get(f).copied().unwrap_or(false))
        .count();
    let search = Search {
        base,
        cands,
        rv,
        inp,
        rule: *rule,
        holm,
    };
    let y_rms = (rows.y.iter().map(|v| v * v).sum::<f64>() / rows.len().max(1) as f64).sqrt();
    let max_terms = MAX_TERMS.min(data.n_trials / TRIALS_PER_TERM);
    let mut chosen: Vec<usize> = Vec::new();
    let mut chosen_cols: Vec<Vec<f64>> = Vec::new();
    let mut cur_pred = cur.cv.pred.clone();
    let mut cur_bic = cur.bic;
    let mut closed: Vec<String> = blocked.to_vec();
    report.before = Some(search.base.compare(&cur_pred, &cur_pred).2);
    let mut accepted: Vec<(usize, Scored)> = Vec::new();
    let mut tied: Vec<(usize, Vec<Tie>)> = Vec::new();
    for step in 1..=max_terms {
        let level = search.level(step);
        let mut best_fail: Option<Scored> = None;
        let mut passing: Vec<Scored> = Vec::new();
        let total = search.cands.len();
        for i in 0..total {
            super::report(super::Progress::Candidates {
                step,
                done: i + 1,
                total,
            });
            if chosen.contains(&i) || closed.contains(&search.cands[i].group) {
                continue;
            }
            let Some(s) = search.score(i, &chosen_cols, (&cur_pred, cur_bic), y_rms) else {
                continue;
            };
            if search.passes(&s, level * search.cands[i].weight) {
                passing.push(s);
            } else if best_fail.as_ref().is_none_or(|b| s.rel > b.rel) {
                best_fail = Some(s);
            }
        }
        let best = (0..passing.len())
            .max_by(|&a, &b| passing[a].rel.total_cmp(&passing[b].rel))
            .map(|k| {
                let b = &passing[k];
                let refs: Vec<&Scored> = passing.iter().collect();
                // The plain pooled term when the term × signal containing it is not
                // significantly better: the signal is not what the data support.
                let k = simpler_nested(&search, b, &refs).unwrap_or(k);
                passing.swap_remove(k)
            });
        if step == 1
            && let Some(f) = &best_fail
            && best.as_ref().is_none_or(|b| f.rel > b.rel)
        {
            let lv = level * search.cands[f.idx].weight;
            let verdict = verdict_of(f, lv, rule);
            let d = to_discovery(f, &search, joint_names, lv, step, verdict);
            report.best_rejected = Some(d);
        }
        let Some(b) = best else { break };
        let lv = level * search.cands[b.idx].weight;
        // A term × signal says the loss changes with the signal: that needs its dependence
        // k resolved, not only the term's gain (a slow signal nearly constant over the session
        // lets k·s + k0 act as a free level, e.g. an efficiency below the base model's a ≥ 1).
        if let Some((d, k)) = unresolved_dependence(&search, &b, joint_names, lv, step) {
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
            report.notes.push(format!("{}: {verdict}", d.name));
            if report.best_rejected.is_none() || step == 1 {
                report.best_rejected = Some(Discovery { verdict, ..d });
            }
            closed.push(search.cands[b.idx].group.clone());
            continue;
        }
        // Rivals on other fields the data cannot tell from it: named with it, never claimed.
        let ties = ties_at_step(&search, &b, &passing, &cur_pred, joint_names, level);
        for t in &ties {
            // A rival of the same structure whose contribution is not collinear with the chosen
            // one's may be a second effect of the same kind: it stays open and is tried beside
            // the chosen term at the next steps; only if it does not pass there is it a tie.
            if stays_open(&t.term) {
                continue;
            }
            let g = &search.cands[t.idx].group;
            if !closed.contains(g) {
                closed.push(g.clone());
            }
        }
        tied.push((b.idx, ties));
        chosen.push(b.idx);
        chosen_cols.extend(search.cols(b.idx));
        closed.push(search.cands[b.idx].group.clone());
        cur_pred = b.fit.pred.clone();
        cur_bic = b.fit.bic;
        accepted.push((step, b));
    }
    claim_rivals_found_beside(&search, &chosen, &mut tied, &mut report.notes);
    let on_time = chosen
        .iter()
        .any(|&i| search.cands[i].group.contains(TIME_NAME));
    if let Some(note) = on_time
        .then(|| clock_stand_ins(&search.inp.fields.excluded))
        .flatten()
    {
        report.notes.push(note);
    }
    finish(
        &search,
        &chosen,
        &accepted,
        &mut tied,
        cur,
        joint_names,
        &mut report,
    )?;
    Ok(report)
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

/// Whether a rival tied with a chosen term stays open to be tried beside it at the later steps
/// of forward selection: one of the same structure whose contribution is not collinear with the
/// chosen one's (r < [`CONFOUNDED_R`]). Such a rival is either a stand-in for the chosen term's
/// signal (beside it, it adds nothing and fails the gates) or a second effect of the same kind
/// (beside it, it passes and is claimed on its own).
fn stays_open(t: &TiedTerm) -> bool {
    t.same_structure && t.correlation < CONFOUNDED_R
}

/// Rivals that were tried beside the term they tied with and were accepted themselves are second
/// effects, not ties: taken out of the tie lists, with a note.
fn claim_rivals_found_beside(
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

/// Paired one-sided p-value (held-out error by trial) that predictions `a` fit better than `b`.
fn p_better(search: &Search, a: &[f64], b: &[f64]) -> f64 {
    let rows = search.base.rows;
    let nt = search.base.data.n_trials;
    let ea = trial_sse(&rows.y, a, &rows.trial, nt);
    let eb = trial_sse(&rows.y, b, &rows.trial, nt);
    let d: Vec<f64> = eb.iter().zip(&ea).map(|(x, y)| x - y).collect();
    improvement_p_value(&d)
}

/// The signal(s) a candidate follows, by name: its recorded field(s), or session time; empty
/// for a correction of a base loss term (it follows no signal).
fn followed(kind: &Kind, names: &[String]) -> Vec<String> {
    match kind {
        Kind::Additive(f, _)
        | Kind::Step(f, _)
        | Kind::Product(_, Signal::Field(f), _)
        | Kind::Product(_, Signal::Rest(f), _) => {
            vec![names[*f].clone()]
        }
        Kind::Product(_, Signal::Family(_, fs), _) => {
            fs.iter().map(|&f| names[f].clone()).collect()
        }
        Kind::Product(_, Signal::Time, _) => vec![TIME_NAME.into()],
        Kind::PerJoint(_) | Kind::Pooled(_) => Vec::new(),
    }
}

/// Whether two candidates differ only in the signal they follow: both additive loads, both
/// steps, or the same base loss term × a signal.
fn same_structure(a: &Kind, b: &Kind) -> bool {
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
fn tie_of(
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
    let not_worse = p_chosen_better >= alpha || p_chosen_better.is_nan();
    (not_worse && (same || r >= CONFOUNDED_R)).then_some(same)
}

/// How a candidate's signal enters its name (the words after the subject): "rises with X",
/// "falls as it rises: X", "switches with X (…)". Empty for a correction.
fn predicate(kind: &Kind, names: &[String], gamma0: f64) -> String {
    match kind {
        Kind::Additive(f, _) => Shape::Linear.predicate(&names[*f], gamma0),
        Kind::Product(_, s, shape) => shape.predicate(&signal_words(s, names), gamma0),
        Kind::Step(f, thr) => format!(
            "switches with {} (drawn while it reads above {thr:.4})",
            names[*f]
        ),
        Kind::PerJoint(_) | Kind::Pooled(_) => String::new(),
    }
}

/// How a signal reads in a name.
fn signal_words(s: &Signal, names: &[String]) -> String {
    match s {
        Signal::Field(f) => names[*f].clone(),
        Signal::Rest(f) => format!("{} at rest", names[*f]),
        Signal::Family(k, _) => format!("{k} of each joint's own motor"),
        Signal::Time => "session time [h]".into(),
    }
}

/// A rival of a chosen term at its step ([`tie_of`]), as reported, and how its signal reads.
struct Tie {
    idx: usize,
    term: TiedTerm,
    predicate: String,
    /// The signal with each arm motor's index as `[*]`: fields of one family across the
    /// motors (they move together) are named as one group.
    pattern: String,
}

/// A candidate's signal with the arm motors' indices as `[*]` (a family's key, a member of it,
/// session time, or the field itself).
fn pattern(kind: &Kind, names: &[String], arm: &[usize; N_JOINTS]) -> String {
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
const TIES_NAMED: usize = 3;

/// The candidates among `passing` (the other candidates that pass the gates at `b`'s step) that
/// tie with the chosen `b` ([`tie_of`]), best held-out fit first. A loss term × signal counts
/// only when it carries its field (no plain pooled term among `passing` fits as well).
fn ties_at_step(
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
fn name_with_ties(name: &str, ties: &[Tie]) -> String {
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

/// A base loss term times a signal (with its level) contains the plain pooled term: when it
/// does not fit significantly better than that pooled term (paired held-out test by trial at the
/// rule's α), the simpler one is what the data support — its position in `among`.
fn simpler_nested(search: &Search, b: &Scored, among: &[&Scored]) -> Option<usize> {
    let Kind::Product(t, ..) = search.cands[b.idx].kind else {
        return None;
    };
    among.iter().position(|o| {
        matches!(search.cands[o.idx].kind, Kind::Pooled(u) if u == t) && {
            let p = p_better(search, &b.fit.pred, &o.fit.pred);
            p >= search.rule.alpha || p.is_nan()
        }
    })
}

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
struct Same {
    /// Its score on the model without the term.
    s: Scored,
    /// Paired one-sided p-value that the library term fits the held-out trials better.
    p_lib: f64,
    /// The same, that the candidate fits better.
    p_riv: f64,
    /// Correlation of what each adds to the prediction of the model without the term.
    r: f64,
    /// Its held-out RMSE gain over the model with the term (1 − RMSE_rival / RMSE_with).
    gain: f64,
}

/// Whether the library itself reads recorded field `name`: the arm motors' position, velocity,
/// torque estimate and winding temperature (`temperature[0]`), and the IMU.
fn library_reads(name: &str, arm_motors: &[usize; N_JOINTS]) -> bool {
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
fn may_rival(kind: &Kind, names: &[String], arm_motors: &[usize; N_JOINTS]) -> bool {
    let fields: Vec<usize> = match kind {
        Kind::Additive(f, _) | Kind::Step(f, _) => vec![*f],
        Kind::Product(_, Signal::Field(f) | Signal::Rest(f), _) => vec![*f],
        Kind::Product(_, Signal::Family(_, fs), _) => fs.to_vec(),
        Kind::Product(_, Signal::Time, _) | Kind::PerJoint(_) | Kind::Pooled(_) => Vec::new(),
    };
    !fields.is_empty()
        && fields
            .iter()
            .all(|&f| !library_reads(&names[f], arm_motors))
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
    let base = Base::new(data, without)?;
    let rows = base.rows;
    let twin = data.reference.is_some();
    let mut notes = Vec::new();
    let resid: Vec<f64> = rows
        .y
        .iter()
        .zip(&without.cv.pred)
        .map(|(y, p)| y - p)
        .collect();
    let (cands, rv, _, holm) = generate(inp, rows, data.n_trials, twin, &resid, &mut notes);
    let m = cands.len();
    let search = Search {
        base,
        cands,
        rv,
        inp,
        rule: *rule,
        holm,
    };
    let names = &inp.fields.names;
    if !(0..m).any(|i| may_rival(&search.cands[i].kind, names, &inp.arm_motors)) {
        return Ok(None);
    }
    let y_rms = (rows.y.iter().map(|v| v * v).sum::<f64>() / rows.len().max(1) as f64).sqrt();
    let level = search.level(1);
    let nt = data.n_trials;
    let e_with = trial_sse(&rows.y, &with.cv.pred, &rows.trial, nt);
    let (_, rmse_with) = r2_rmse(&rows.y, &with.cv.pred);
    // What a candidate still adds beside the term: one that no longer passes there explains
    // the same.
    let beside = Base::new(data, with)?;
    let explains_same = |i: usize| {
        let cols = search.cols(i);
        let refs: Vec<&Vec<f64>> = cols.iter().collect();
        !beside.fit(&refs).ok().is_some_and(|fit| {
            let (p, rel, _, _) = beside.compare(&with.cv.pred, &fit.pred);
            p < level * search.cands[i].weight
                && fit.bic - with.bic < rule.bic_threshold
                && rel >= rule.min_improvement
        })
    };
    // What the term adds to the held-out prediction.
    let lib_add: Vec<f64> = with
        .cv
        .pred
        .iter()
        .zip(&without.cv.pred)
        .map(|(a, b)| a - b)
        .collect();
    let mut same: Vec<Same> = Vec::new();
    for i in 0..m {
        let Some(s) = search.score(i, &[], (&without.cv.pred, without.bic), y_rms) else {
            continue;
        };
        if !search.passes(&s, level * search.cands[i].weight) || !explains_same(i) {
            continue;
        }
        let e_riv = trial_sse(&rows.y, &s.fit.pred, &rows.trial, nt);
        let d_lib: Vec<f64> = e_riv.iter().zip(&e_with).map(|(a, b)| a - b).collect();
        let d_riv: Vec<f64> = d_lib.iter().map(|v| -v).collect();
        let riv_add: Vec<f64> = s
            .fit
            .pred
            .iter()
            .zip(&without.cv.pred)
            .map(|(a, b)| a - b)
            .collect();
        let sse = |e: &[f64]| e.iter().sum::<f64>();
        same.push(Same {
            p_lib: improvement_p_value(&d_lib),
            p_riv: improvement_p_value(&d_riv),
            r: pearson(&lib_add, &riv_add).0,
            gain: 1.0 - (sse(&e_riv) / sse(&e_with).max(1e-300)).sqrt(),
            s,
        });
    }
    let correction = |c: &Same| {
        matches!(
            search.cands[c.s.idx].kind,
            Kind::PerJoint(_) | Kind::Pooled(_)
        )
    };
    // A loss term × signal carries its field only when it fits significantly better than its
    // level alone (the plain pooled term with a free coefficient): otherwise any slow signal
    // would do, and the field names nothing.
    let mut level_pred: Vec<(Term, Vec<f64>)> = Vec::new();
    for c in &same {
        if let Kind::Product(t, ..) = search.cands[c.s.idx].kind
            && !level_pred.iter().any(|(u, _)| *u == t)
        {
            let level = search.cols(c.s.idx).swap_remove(1);
            if let Ok(fit) = search.base.fit(&[&level]) {
                level_pred.push((t, fit.pred));
            }
        }
    }
    let carried = |c: &Same| match search.cands[c.s.idx].kind {
        Kind::Product(t, ..) => level_pred
            .iter()
            .any(|(u, pred)| *u == t && p_better(&search, &c.s.fit.pred, pred) < rule.alpha),
        _ => true,
    };
    let field =
        |c: &Same| may_rival(&search.cands[c.s.idx].kind, names, &inp.arm_motors) && carried(c);
    // A product whose pooled term fits as well is that pooled term.
    let simpler = |k: usize| {
        let refs: Vec<&Scored> = same.iter().map(|c| &c.s).collect();
        simpler_nested(&search, &same[k].s, &refs).unwrap_or(k)
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
        best_of(&|c| field(c) && (c.p_lib >= rule.alpha || c.p_lib.is_nan()) && c.r >= CONFOUNDED_R)
            .filter(|&k| field(&same[k]))
    };
    let tied = better.is_none();
    let Some(k) = better.or_else(tie) else {
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
    let (_, rmse_riv) = r2_rmse(&rows.y, &c.s.fit.pred);
    let s = &c.s;
    let d = to_discovery(s, &search, joint_names, level, 1, String::new());
    Ok(Some(Rival {
        name: format!("{} ({})", d.name, d.form),
        tied,
        p_library: c.p_lib,
        rmse: [rmse_with, rmse_riv],
        correlation: c.r,
        blocked,
    }))
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
    chosen: &[usize],
    accepted: &[(usize, Scored)],
    tied: &mut [(usize, Vec<Tie>)],
    cur: &State,
    joint_names: &[String],
    report: &mut DiscoveryReport,
) -> Result<()> {
    let all: Vec<Vec<f64>> = chosen.iter().flat_map(|&k| search.cols(k)).collect();
    let final_fit = if chosen.is_empty() {
        None
    } else {
        Some(search.base.fit(&all.iter().collect::<Vec<_>>())?)
    };
    let mut off = 0;
    for &k in chosen {
        let Some((step, s)) = accepted.iter().find(|(_, s)| s.idx == k) else {
            continue;
        };
        let ncols = search.cols(k).len();
        let level = search.level(*step) * search.cands[k].weight;
        let verdict = format!(
            "accepted: held-out RMSE −{:.1} % (p = {:.1e} < {:.1e}, weighted Holm over {} candidates), ΔBIC = {:.1}",
            100.0 * s.rel,
            s.p,
            level,
            search.holm.m,
            s.d_bic
        );
        let mut d = to_discovery(s, search, joint_names, level, *step, verdict);
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
        d.flexible = search.flexible(k);
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

/// A term × signal candidate whose dependence coefficient k is not resolved (|k| <
/// [`DEPENDENCE_Z`] s.e.): its description (at `level`, `step`) and k; `None` for other
/// candidates or a resolved k.
fn unresolved_dependence(
    search: &Search,
    s: &Scored,
    joint_names: &[String],
    level: f64,
    step: usize,
) -> Option<(Discovery, Param)> {
    if !matches!(search.cands[s.idx].kind, Kind::Product(..)) {
        return None;
    }
    let d = to_discovery(s, search, joint_names, level, step, String::new());
    let k = d.params.first()?.clone();
    (k.value.abs() < DEPENDENCE_Z * k.std_err || !k.std_err.is_finite()).then_some((d, k))
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

fn to_discovery(
    s: &Scored,
    search: &Search,
    joint_names: &[String],
    level: f64,
    step: usize,
    verdict: String,
) -> Discovery {
    let n = search.cols(s.idx).len();
    let g: Vec<f64> = s.fit.gamma.iter().rev().take(n).rev().copied().collect();
    let se: Vec<f64> = (0..n)
        .map(|j| {
            let per: Vec<f64> = s
                .fit
                .fold_gamma
                .iter()
                .map(|t| t[t.len() - n + j])
                .collect();
            jackknife_se(&per)
        })
        .collect();
    let (name, form, fields, params) = describe(
        &search.cands[s.idx].kind,
        &search.inp.fields.names,
        joint_names,
        &g,
        &se,
    );
    Discovery {
        name,
        form,
        fields,
        params,
        p_value: s.p,
        alpha: level,
        delta_bic: s.d_bic,
        rel_improvement: s.rel,
        before: s.before,
        after: s.after,
        step,
        verdict,
        tied: Vec::new(),
        meter: None,
        stability: None,
        mechanism: match &search.cands[s.idx].kind {
            Kind::Product(t, ..) | Kind::Pooled(t) => t.library_id().map(String::from),
            _ => None,
        },
        contribution: Vec::new(),
        flexible: Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clock_like_fields_are_named_beside_session_time() {
        let ex = |name: &str, reason: &str| super::super::fields::ExcludedField {
            name: name.into(),
            reason: reason.into(),
        };
        assert_eq!(clock_stand_ins(&[]), None);
        let counter_only = [ex(
            "/lowstate.tick",
            "counter: steps the same way in 100.0 %",
        )];
        assert_eq!(clock_stand_ins(&counter_only), None);
        let clock = format!("{}: r = +0.99995", super::super::field_rules::CLOCK_REASON);
        let note = clock_stand_ins(&[
            ex("/lf/bmsstate.bmsvoltage[0]", &clock),
            ex("/lowstate.tick", "counter: steps the same way in 100.0 %"),
            ex("/lf/bmsstate.cell_vol[3]", &clock),
        ])
        .unwrap();
        assert!(note.starts_with(TIME_NAME), "{note}");
        assert!(
            note.contains("/lf/bmsstate.bmsvoltage[0], /lf/bmsstate.cell_vol[3]"),
            "{note}"
        );
        assert!(!note.contains("tick"), "{note}");
    }

    #[test]
    fn per_joint_coefficients_identified_or_pooled() {
        let p = |i: usize, v: f64, se: f64| Param {
            name: format!("excess on j{i}"),
            symbol: format!("k_{i}"),
            value: v,
            std_err: se,
            unit: "W·s/rad".into(),
        };
        // j0 and j2 identified (s.e. 2 % and 4 %); j1 (s.e. 50 %) and j3 (10 %) pooled with
        // inverse-variance weights 1/0.25² = 16 and 1/0.1² = 100.
        let out = identified_or_pooled(vec![
            p(0, 1.0, 0.02),
            p(1, 0.5, 0.25),
            p(2, 2.0, 0.08),
            p(3, 1.0, 0.1),
        ]);
        let syms: Vec<&str> = out.iter().map(|p| p.symbol.as_str()).collect();
        assert_eq!(syms, ["k_0", "k_2", "k_pooled"]);
        let pooled = &out[2];
        assert!((pooled.value - (16.0 * 0.5 + 100.0 * 1.0) / 116.0).abs() < 1e-12);
        assert!((pooled.std_err - 1.0 / 116f64.sqrt()).abs() < 1e-12);
        assert!(pooled.name.contains("j1, j3"), "{}", pooled.name);
        // All identified: nothing pooled.
        assert_eq!(identified_or_pooled(vec![p(0, 1.0, 0.01)]).len(), 1);
    }

    #[test]
    fn rival_rule_ties_other_fields_only() {
        let names: Vec<String> = [
            "/lowstate.motor_state[15].temperature[0]",
            "/lowstate.motor_state[16].temperature[0]",
            "/lowstate.motor_state[15].temperature[1]",
            "/lowstate.motor_state[16].temperature[1]",
            "/lf/mainboardstate.fan_state[1]",
            "/lf/bmsstate.cell_vol[0]",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let fam = |a: usize, key: &str| {
            let mut fs = [a; N_JOINTS];
            fs[1] = a + 1;
            Signal::Family(key.into(), fs)
        };
        let winding = Kind::Product(Term::Coulomb, fam(0, "winding"), Shape::Linear);
        let housing = Kind::Product(Term::Coulomb, fam(2, "housing"), Shape::Linear);
        let alpha = 1e-3;
        // Same structure on another field, not significantly worse: a tie whatever r.
        assert_eq!(
            tie_of(&winding, &housing, &names, 0.2, 0.1, alpha),
            Some(true)
        );
        assert_eq!(
            tie_of(&winding, &housing, &names, f64::NAN, 0.1, alpha),
            Some(true)
        );
        // Significantly worse: no tie, even collinear.
        assert_eq!(tie_of(&winding, &housing, &names, 1e-4, 0.99, alpha), None);
        // Another structure: a tie only when collinear.
        let viscous = Kind::Product(Term::Viscous, fam(2, "housing"), Shape::Linear);
        assert_eq!(tie_of(&winding, &viscous, &names, 0.2, 0.5, alpha), None);
        assert_eq!(
            tie_of(&winding, &viscous, &names, 0.2, 0.95, alpha),
            Some(false)
        );
        // A field of the chosen family in another form is the same field, not a tie.
        let one = Kind::Product(Term::Coulomb, Signal::Field(2), Shape::Linear);
        assert_eq!(tie_of(&housing, &one, &names, 0.5, 0.99, alpha), None);
        // A step and a linear load on one field: the same field.
        let lin = Kind::Additive(4, 1.0);
        let step = Kind::Step(4, 0.5);
        assert_eq!(tie_of(&lin, &step, &names, 0.5, 0.99, alpha), None);
        // Another field: the same structure ties, a step vs a linear load only when collinear.
        let other = Kind::Additive(5, 1.0);
        assert_eq!(tie_of(&lin, &other, &names, 0.5, 0.0, alpha), Some(true));
        assert_eq!(tie_of(&step, &other, &names, 0.5, 0.5, alpha), None);
        // Session time is a signal too; a base-term correction follows none.
        let time = Kind::Product(Term::Coulomb, Signal::Time, Shape::Linear);
        assert_eq!(tie_of(&winding, &time, &names, 0.5, 0.0, alpha), Some(true));
        let pooled = Kind::Pooled(Term::Coulomb);
        assert_eq!(tie_of(&winding, &pooled, &names, 0.5, 0.99, alpha), None);
        assert_eq!(tie_of(&pooled, &winding, &names, 0.5, 0.99, alpha), None);
    }

    #[test]
    fn a_found_name_with_ties_names_every_field_as_confounded() {
        let tie = |name: &str, predicate: &str, pattern: &str, same: bool| Tie {
            idx: 0,
            predicate: predicate.into(),
            pattern: pattern.into(),
            term: TiedTerm {
                name: name.into(),
                form: String::new(),
                fields: Vec::new(),
                params: Vec::new(),
                rmse_w: [1.0, 1.0],
                p_value: 0.3,
                correlation: 0.95,
                same_structure: same,
            },
        };
        assert_eq!(name_with_ties("A rises with x", &[]), "A rises with x");
        let n = name_with_ties(
            "A rises with x",
            &[
                tie("A rises with y", "rises with y", "y", true),
                tie("B falls as it rises: z", "falls as it rises: z", "z", false),
            ],
        );
        assert_eq!(
            n,
            "A rises with x, or rises with y, or b falls as it rises: z (confounded: the data cannot tell these fields apart)"
        );
        // One pattern over several motors is one group; past three groups, a count.
        let mut many: Vec<Tie> = (0..5)
            .map(|i| tie("A", &format!("rises with f{i}"), &format!("p{i}"), true))
            .collect();
        many.push(tie("A", "rises with g", "p0", true));
        many.push(tie("A", "rises with h", "p0", true));
        let n = name_with_ties("A rises with x", &many);
        assert!(n.contains("rises with f0 (and 2 more on p0), or rises with f1, or rises with f2, or 2 other candidate(s) listed with it"), "{n}");
        assert!(!n.contains("f3") && !n.contains(" g"), "{n}");
    }

    #[test]
    fn step_threshold_needs_two_levels() {
        let two: Vec<f64> = (0..100)
            .map(|k| if k % 3 == 0 { 3000.0 } else { 0.0 })
            .collect();
        assert_eq!(step_threshold(&two), Some(1500.0));
        let ramp: Vec<f64> = (0..100).map(f64::from).collect();
        assert_eq!(step_threshold(&ramp), None);
    }

    #[test]
    fn families_need_every_arm_motor() {
        let mut names: Vec<String> = (0..35)
            .map(|k| format!("/lowstate.motor_state[{k}].temperature[1]"))
            .collect();
        names.push("/lowstate.motor_state[16].vol".into());
        let arm = [15, 16, 17, 18, 19, 20, 21];
        let f = families(&names, &arm);
        assert_eq!(f.len(), 1);
        assert_eq!(f[0].0, "/lowstate.motor_state[*].temperature[1]");
        assert_eq!(f[0].1, [15, 16, 17, 18, 19, 20, 21]);
    }

    #[test]
    fn within_share_of_a_slow_and_a_fast_signal() {
        let trial: Vec<usize> = (0..40).map(|r| r / 10).collect();
        let slow: Vec<f64> = trial.iter().map(|&t| t as f64).collect();
        let fast: Vec<f64> = (0..40).map(|r| (r % 2) as f64).collect();
        assert!(within_share(&slow, &trial, 4) < 1e-12);
        assert!(within_share(&fast, &trial, 4) > 0.9);
    }
}
