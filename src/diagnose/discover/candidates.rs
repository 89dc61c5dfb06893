//! The candidates discovery tries: every recorded field as a rail load (linear, and a step
//! for a field that switches between levels), each loss term × each slow state signal, and
//! the base-term corrections; fields that meter the power itself left out with a note.

use crate::N_JOINTS;
use crate::diagnose::family::{KEPT_PER_TERM, Screen, Shape, Term, step_levels};
use crate::diagnose::fields::FieldTable;
use crate::diagnose::locate::trial_means;
use crate::diagnose::reading_rows::Rows;
use crate::diagnose::stats::{pearson, span, step_threshold};

/// Correlation with the readings above which a field counts as a meter of the power itself.
pub(super) const METER_CORRELATION: f64 = 0.5;
/// Significance at which a field falling as the readings rise is a sag of the supply, left out
/// of the rest power's candidates.
const SAG_P: f64 = 1e-3;

/// Within-trial share of a field's variance below which it is a slow state signal.
pub(super) const SLOW_SHARE: f64 = 0.1;

/// Quantiles of a continuous field at which a rail load's step is tried (a load that switches on
/// past a joint angle anywhere in its range is within a tenth of the readings of one).
const LOAD_STEP_QUANTILES: [f64; 9] = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9];

/// How candidate names call session time.
pub(super) const TIME_NAME: &str = "session time";

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
    /// Σ_i term_i · g(signal_i), beside the term's level (a family member, [`crate::diagnose::family`]).
    Product(Term, Signal, Shape),
    /// One coefficient per joint on term_i (held base model only).
    PerJoint(Term),
    /// One coefficient on Σ_i term_i (held base model only).
    Pooled(Term),
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
    /// Fields that meter the rail's current ([`crate::diagnose::DiagnoseOptions::meter_flows`]).
    pub meter_flows: &'a [String],
}

/// Field values on the rows: raw window value and the mean over the row's trial baseline.
pub(super) struct RowValues {
    pub(super) raw: Vec<Vec<f64>>,
    pub(super) baseline: Vec<Vec<f64>>,
    pub(super) hours: Vec<f64>,
    /// Per term of [`Term::ALL`]: its pooled value Σ_i term_i on each row.
    pub(super) pooled: Vec<Vec<f64>>,
}

impl RowValues {
    pub(super) fn new(inp: &Inputs, rows: &Rows) -> RowValues {
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
        let pooled = (Term::ALL.iter())
            .map(|t| rows.x.iter().map(|x| t.sum(x, &|_| 1.0)).collect())
            .collect();
        RowValues {
            raw,
            baseline,
            hours: rows.t.iter().map(|t| t / 3600.0).collect(),
            pooled,
        }
    }

    /// Term `t` pooled on each row.
    pub(super) fn pooled(&self, t: Term) -> &Vec<f64> {
        &self.pooled[Term::ALL.iter().position(|u| *u == t).unwrap_or(0)]
    }
}

/// Mean of `f` over a trial's baseline windows (0 without any).
pub(super) fn base_mean(windows: &[usize], f: impl Fn(usize) -> f64) -> f64 {
    if windows.is_empty() {
        return 0.0;
    }
    windows.iter().map(|&w| f(w)).sum::<f64>() / windows.len() as f64
}

/// A candidate and the group it competes in (forms of one mechanism: at most one accepted).
pub(super) struct Cand {
    pub(super) kind: Kind,
    pub(super) group: String,
    /// Its weight in the weighted Holm correction ([`crate::diagnose::family::weights`]).
    pub(super) weight: f64,
    /// Its mechanism family ([`family_of`]).
    pub(super) family: usize,
}

/// The mechanism family of a candidate, the unit the search's Holm runs over: the position in
/// [`Term::ALL`] of the loss term it changes, or [`LOADS`] for a load on a recorded field.
pub(super) fn family_of(kind: &Kind) -> usize {
    match kind {
        Kind::Product(t, ..) | Kind::PerJoint(t) | Kind::Pooled(t) => {
            Term::ALL.iter().position(|u| u == t).unwrap_or(LOADS)
        }
        Kind::Additive(..) | Kind::Step(..) => LOADS,
    }
}

/// The family of the rail loads on recorded fields.
pub(super) const LOADS: usize = Term::ALL.len();

/// Share of a series' variance that lies within trials.
pub(super) fn within_share(v: &[f64], trial: &[usize], n_trials: usize) -> f64 {
    let means = trial_means(trial.iter().copied().zip(v.iter().copied()), n_trials);
    let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
    let (mut within, mut total) = (0.0, 0.0);
    for (x, &t) in v.iter().zip(trial) {
        // Some: trial t holds x.
        let m = means[t].unwrap_or_default();
        within += (x - m).powi(2);
        total += (x - mean).powi(2);
    }
    within / total.max(1e-300)
}

/// Per-motor families: fields `…motor_state[k].rest` present for every arm motor.
pub(super) fn families(
    names: &[String],
    arm: &[usize; N_JOINTS],
) -> Vec<(String, [usize; N_JOINTS])> {
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
pub(super) fn columns(kind: &Kind, inp: &Inputs, rv: &RowValues, rows: &Rows) -> Vec<Vec<f64>> {
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
            let g = |r: usize| {
                let s = match sig {
                    Signal::Family(_, fs) => {
                        return t.sum(&rows.x[r], &|i| shape.g(rv.raw[fs[i]][r]));
                    }
                    Signal::Field(f) => rv.raw[*f][r],
                    Signal::Time => rv.hours[r],
                    Signal::Rest(f) => rv.baseline[*f][r],
                };
                // One signal for every joint: g(s) once.
                let g = shape.g(s);
                t.sum(&rows.x[r], &|_| g)
            };
            // The level column lets the term's coefficient at signal 0 take any sign (the base
            // coefficients it would otherwise shift are bounded at 0).
            vec![(0..n).map(g).collect(), rv.pooled(*t).clone()]
        }
        Kind::PerJoint(t) => (0..N_JOINTS)
            .map(|i| (0..n).map(|r| t.value(&rows.x[r], i)).collect())
            .collect(),
        Kind::Pooled(t) => vec![rv.pooled(*t).clone()],
    }
}

/// A signal's values on the rows (every member's, for a family).
pub(super) fn signal_values(s: &Signal, rv: &RowValues) -> Vec<f64> {
    match s {
        Signal::Field(f) => rv.raw[*f].clone(),
        Signal::Family(_, fs) => fs.iter().flat_map(|&f| rv.raw[f].iter().copied()).collect(),
        Signal::Time => rv.hours.clone(),
        Signal::Rest(f) => rv.baseline[*f].clone(),
    }
}

/// Which fields meter the power itself (left out of discovery, noted), which of those sag under
/// the load, and which fall significantly as the power rises.
struct Meters {
    usable: Vec<bool>,
    sags: Vec<bool>,
    falls: Vec<bool>,
}

fn meters_of_the_power(
    inp: &Inputs,
    rows: &Rows,
    rv: &RowValues,
    single: &[bool],
    notes: &mut Vec<String>,
) -> Meters {
    let names = &inp.fields.names;
    let mut meters = Vec::new();
    let mut usable = vec![true; names.len()];
    // Meters that fall as the power rises: a supply sagging under the load; `falls`: any field
    // that does so significantly (at rest it reads the rest load, it does not cause it).
    let mut sags = vec![false; names.len()];
    let mut falls = vec![false; names.len()];
    for f in 0..names.len() {
        let net: Vec<f64> = (0..rows.len())
            .map(|r| rv.raw[f][r] - rv.baseline[f][r])
            .collect();
        let (r, p) = pearson(&net, &rows.y);
        falls[f] = r < 0.0 && p < SAG_P;
        // A current meter of the rail is left out whatever its correlation: sampled on its own
        // clock, or beside a large unmodelled effect, it can track the readings loosely and
        // still follow every residual the rail carries.
        let flow = inp.meter_flows.contains(&names[f]);
        if flow || r.abs() >= METER_CORRELATION {
            usable[f] = false;
            sags[f] = !flow && falls[f];
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
    Meters {
        usable,
        sags,
        falls,
    }
}

/// Generate every candidate, fields that meter the power itself left out (noted), and keep
/// those [`crate::diagnose::family::screen`] passes on the current model's residual `resid`; the
/// number generated and each family's total weight ([`super::candidates::family_of`]) returned last.
pub(super) fn generate(
    inp: &Inputs,
    rows: &Rows,
    n_trials: usize,
    twin: bool,
    resid: &[f64],
    notes: &mut Vec<String>,
) -> (Vec<Cand>, RowValues, Vec<bool>, usize, Vec<f64>) {
    let names = &inp.fields.names;
    let rv = RowValues::new(inp, rows);
    let single: Vec<bool> = (0..names.len())
        .map(|f| !inp.fields.duplicate.get(f).copied().unwrap_or(false))
        .collect();
    let Meters {
        usable,
        sags,
        falls,
    } = meters_of_the_power(inp, rows, &rv, &single, notes);
    // Each candidate, its group name and its place in the screen.
    let mut kinds: Vec<(Kind, String, Screen)> = Vec::new();
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
        let group = format!("field {}", names[f]);
        kinds.push((Kind::Additive(f, span(&rv.raw[f])), group.clone(), None));
        // A field that switches between levels steps at its midpoint; any other at a level
        // chosen from the data (a load that switches on past a joint angle or a temperature):
        // each level a screened member, the best of each field's scored (so a step on one field
        // meets its rivals on the others, a command and the position that follows it).
        match step_threshold(&rv.raw[f]) {
            Some(thr) => {
                kinds.push((Kind::Step(f, thr), group, None));
            }
            None => {
                let levels = step_levels(&rv.raw[f], &LOAD_STEP_QUANTILES);
                for level in levels.map(|l| l.0).unwrap_or_default() {
                    let screen = Some((LOADS + 1 + f, 1));
                    kinds.push((Kind::Step(f, level), group.clone(), screen));
                }
            }
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
    for (ti, t) in Term::ALL.into_iter().enumerate() {
        for s in slow
            .iter()
            .filter(|s| t.per_joint() || !matches!(s, Signal::Family(..)))
        {
            let g = format!("{t:?} × {}", signal_name(s, names));
            for shape in Shape::all_for(&signal_values(s, &rv)) {
                let screened = crate::diagnose::family::screened(t, shape);
                let screen = screened.then_some((ti, KEPT_PER_TERM));
                kinds.push((Kind::Product(t, s.clone(), shape), g.clone(), screen));
            }
        }
        // A one-sided form of a library mechanism the library does not hold, on its own.
        if t.level_is_new() || (twin && Term::BASE.contains(&t)) {
            kinds.push((Kind::Pooled(t), format!("{t:?} correction"), None));
        }
        if twin && Term::BASE.contains(&t) {
            kinds.push((Kind::PerJoint(t), format!("{t:?} correction"), None));
        }
    }
    let m = kinds.len();
    let family: Vec<Screen> = kinds.iter().map(|k| k.2).collect();
    let is_screened: Vec<bool> = family.iter().map(Option::is_some).collect();
    let weights = crate::diagnose::family::weights(&is_screened);
    let keep =
        crate::diagnose::family::screen(&family, &|i| columns(&kinds[i].0, inp, &rv, rows), resid);
    let mut fam_total = vec![0.0; LOADS + 1];
    for (k, w) in kinds.iter().zip(&weights) {
        fam_total[family_of(&k.0)] += w;
    }
    let cands = keep
        .into_iter()
        .map(|i| Cand {
            kind: kinds[i].0.clone(),
            group: kinds[i].1.clone(),
            weight: weights[i],
            family: family_of(&kinds[i].0),
        })
        .collect();
    let tried: Vec<bool> = (0..names.len())
        .map(|f| usable[f] && single[f] && !falls[f])
        .collect();
    (cands, rv, tried, m, fam_total)
}

pub(super) fn signal_name(s: &Signal, names: &[String]) -> String {
    match s {
        Signal::Field(f) => names[*f].clone(),
        Signal::Family(k, _) => format!("{k} (each joint's own motor)"),
        Signal::Time => TIME_NAME.into(),
        Signal::Rest(f) => format!("{} at rest", names[*f]),
    }
}

/// The signal(s) a candidate follows, by name: its recorded field(s), or session time; empty
/// for a correction of a base loss term (it follows no signal).
pub(super) fn followed(kind: &Kind, names: &[String]) -> Vec<String> {
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
