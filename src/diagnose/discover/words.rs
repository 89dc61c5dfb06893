//! A found term in words: its name, formula, fields and named parameters, from its
//! structure only.

use super::candidates::{Kind, Signal, followed};
use crate::N_JOINTS;
use crate::diagnose::family::{Shape, Term};
use crate::diagnose::hypotheses::joint_name;
use crate::diagnose::select::Param;

/// Fitted coefficients of a candidate and their standard errors, turned into named parameters.
pub(super) struct Fitted<'a> {
    pub(super) gamma: &'a [f64],
    pub(super) se: &'a [f64],
}

impl Fitted<'_> {
    pub(super) fn param(
        &self,
        name: impl Into<String>,
        symbol: &str,
        j: usize,
        unit: impl Into<String>,
    ) -> Param {
        let at = |v: &[f64]| v.get(j).copied().unwrap_or(f64::NAN);
        Param::new(name, symbol, at(self.gamma), at(self.se), unit)
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
    let gamma0 = gamma.first().copied().unwrap_or(0.0);
    // The fields it follows (session time is no recorded field).
    let fields = match kind {
        Kind::Product(_, Signal::Time, _) => Vec::new(),
        _ => followed(kind, names),
    };
    let (name, form, params) = match kind {
        Kind::Additive(f, sp) => {
            let mut swing = fit.param("load change over the field's 5–95 % range", "ΔP", 0, "W");
            swing.value *= sp;
            swing.std_err *= sp;
            let k = fit.param("load per unit of the field", "k", 0, "W per unit");
            (
                format!(
                    "a load on the power rail that {}",
                    predicate(kind, names, gamma0)
                ),
                format!("P += k·{}", names[*f]),
                vec![swing, k],
            )
        }
        Kind::Step(f, thr) => (
            format!("a rail load that {}", predicate(kind, names, gamma0)),
            format!("P += P_on·[{} > {thr:.4}]", names[*f]),
            vec![fit.param("power while on", "P_on", 0, "W")],
        ),
        Kind::Product(t, s, shape) => describe_product(*t, s, *shape, names, &fit),
        Kind::PerJoint(t) => {
            let ks = (0..N_JOINTS).map(|i| {
                fit.param(
                    format!("excess on {}", joint_name(joint_names, i)),
                    &format!("k_{i}"),
                    i,
                    t.unit(),
                )
            });
            (
                format!(
                    "{} differs joint by joint from the model",
                    capitalise(t.words())
                ),
                format!("P += Σ_i k_i·{}", t.symbol()),
                identified_or_pooled(ks.collect()),
            )
        }
        Kind::Pooled(t) if t.level_is_new() => (
            format!("{} is missing from the model", capitalise(t.words())),
            format!("P += k·Σ_i {}", t.symbol()),
            vec![fit.param("coefficient", "k", 0, t.unit())],
        ),
        Kind::Pooled(t) => (
            format!(
                "{} of all joints is {} than the model's",
                capitalise(t.words()),
                if gamma0 >= 0.0 { "larger" } else { "smaller" }
            ),
            format!("P += k·Σ_i {}", t.symbol()),
            vec![fit.param("common excess", "k", 0, t.unit())],
        ),
    };
    (name, form, fields, params)
}

/// [`describe`] of a loss term or library mechanism times a slow state signal in a shape.
pub(super) fn describe_product(
    t: Term,
    s: &Signal,
    shape: Shape,
    names: &[String],
    fit: &Fitted,
) -> (String, String, Vec<Param>) {
    let sname = match s {
        Signal::Rest(f) => format!(
            "{} at rest (its mean over each trial's pre-idle readings)",
            names[*f]
        ),
        _ => signal_words(s, names),
    };
    let k = format!("change of {} per unit of the signal", t.words());
    let mut ps = vec![fit.param(k, "k", 0, format!("{} per unit", t.unit()))];
    if fit.gamma.len() > 1 {
        ps.push(fit.param("level at signal 0", "k0", 1, t.unit()));
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
        ps,
    )
}

/// Largest standard error, as a fraction of |k_i|, of a per-joint coefficient reported on its
/// own: at 4 % a 10 % error is 2.5 standard errors.
pub const IDENTIFIED_REL_SE: f64 = 0.04;

/// Per-joint coefficients: those the data identify (s.e. ≤ [`IDENTIFIED_REL_SE`]·|k_i|) are
/// reported one by one; the others are pooled into one inverse-variance weighted coefficient
/// `k_pooled` (named after the joints it covers), since the data do not tell them apart.
pub(super) fn identified_or_pooled(params: Vec<Param>) -> Vec<Param> {
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
        let name = format!(
            "common excess on {} (not identified joint by joint: s.e. > {:.0} % of the value)",
            joints.join(", "),
            100.0 * IDENTIFIED_REL_SE
        );
        let value = rest.iter().zip(&w).map(|(p, w)| p.value * w).sum::<f64>() / sw;
        out.push(Param::new(
            name,
            "k_pooled",
            value,
            1.0 / sw.sqrt(),
            &first.unit,
        ));
    }
    out
}

pub(super) fn capitalise(s: &str) -> String {
    let mut c = s.chars();
    c.next()
        .map(|f| f.to_uppercase().collect::<String>() + c.as_str())
        .unwrap_or_default()
}

/// How a candidate's signal enters its name (the words after the subject): "rises with X",
/// "falls as it rises: X", "switches with X (…)". Empty for a correction.
pub(super) fn predicate(kind: &Kind, names: &[String], gamma0: f64) -> String {
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
pub(super) fn signal_words(s: &Signal, names: &[String]) -> String {
    match s {
        Signal::Field(f) => names[*f].clone(),
        Signal::Rest(f) => format!("{} at rest", names[*f]),
        Signal::Family(k, _) => format!("{k} of each joint's own motor"),
        Signal::Time => "session time [h]".into(),
    }
}
