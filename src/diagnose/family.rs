//! Discovery's generated family of mechanism × slow state × form candidates.
//!
//! Every base loss term of the paper's model and every pooled regressor of the library's
//! mechanisms ([`Term`]), split where physics splits it (the transmitted power and the drive
//! current into the joints that drive and those that brake), is tried times every slow state
//! signal in one of a few forms ([`Shape`]): linear, a step above a level chosen from the data
//! (three levels, each a candidate, so the search's multiplicity is counted), or exponential
//! rising or falling. The linear forms of the four base terms and of the drive current are
//! always scored; the rest of the family is screened on the current model's held-out residual
//! (per term, the few best by the variance their two columns explain), since scoring every
//! member with cross-validation would cost thousands of fits. Every member generated counts in
//! the Holm correction whether screened out or not: a weighted Holm, in which the screened
//! members together weigh as much as the candidates always scored (each always-scored one
//! weighs 1, so its level is that of a Holm over twice their number; see [`weights`]).

use super::hypotheses::{
    DRIVE_CURRENT, RAW_BRAKING, RAW_BUS_POWER, RAW_DRIVING_CURRENT, RAW_DRIVING_TORQUE,
    RAW_STRIBECK, RAW_TORQUE,
};
use crate::N_JOINTS;

/// One loss term or library mechanism regressor (per joint, or pooled over the arm).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Term {
    /// τ_i q̇_i (mechanical power: transmission efficiency).
    Mech,
    /// τ_i² − τ0_i² (copper loss).
    Copper,
    /// |q̇_i| (Coulomb friction).
    Coulomb,
    /// q̇_i² (viscous friction).
    Viscous,
    /// min(τ_i q̇_i, 0): the braking (regenerated) power — the braking asymmetry's regressor
    /// (its driving counterpart is τq̇ less this).
    Braking,
    /// Σ|τ_i|/K_i (the phase current: drive-electronics loss per ampere), pooled.
    Current,
    /// The phase current of the joints that drive (τ_i q̇_i > 0), pooled.
    DrivingCurrent,
    /// The phase current of the joints that brake or hold, pooled.
    BrakingCurrent,
    /// Σ|τ_i| of the joints that drive (drive-electronics loss per Nm), pooled.
    DrivingTorque,
    /// Σ|τ_i| of the joints that brake or hold, pooled.
    BrakingTorque,
    /// Σ|q̇_i|·exp(−(q̇_i/v_s)²) (Stribeck friction), pooled.
    Stribeck,
    /// (P_elec/V_bus)² (shared DC-bus loss), pooled.
    BusPower,
}

impl Term {
    /// The base loss terms (per joint; twin corrections and per-motor families).
    pub(crate) const BASE: [Term; 4] = [Term::Mech, Term::Copper, Term::Coulomb, Term::Viscous];
    /// Every term of the family, in generation order.
    pub(crate) const ALL: [Term; 12] = [
        Term::Mech,
        Term::Copper,
        Term::Coulomb,
        Term::Viscous,
        Term::Current,
        Term::Braking,
        Term::DrivingCurrent,
        Term::BrakingCurrent,
        Term::DrivingTorque,
        Term::BrakingTorque,
        Term::Stribeck,
        Term::BusPower,
    ];

    /// Whether the term has a value per joint (it may pair with a per-motor field family).
    pub(crate) fn per_joint(self) -> bool {
        matches!(
            self,
            Term::Mech | Term::Copper | Term::Coulomb | Term::Viscous | Term::Braking
        )
    }

    /// Whether its linear × signal form is always scored (the rest of the family is screened).
    fn always_scored(self) -> bool {
        matches!(
            self,
            Term::Mech | Term::Copper | Term::Coulomb | Term::Viscous | Term::Current
        )
    }

    /// Whether its level alone is a candidate in a refitted model: a one-sided form of a library
    /// mechanism the library does not hold (the others are base terms or library hypotheses).
    pub(crate) fn level_is_new(self) -> bool {
        matches!(
            self,
            Term::DrivingCurrent | Term::BrakingCurrent | Term::DrivingTorque | Term::BrakingTorque
        )
    }

    /// Its value on a raw row for joint `i` (pooled terms ignore `i`).
    pub(crate) fn value(self, x: &[f64], i: usize) -> f64 {
        match self {
            Term::Mech => x[i],
            Term::Copper => x[N_JOINTS + i],
            Term::Coulomb => x[2 * N_JOINTS + i],
            Term::Viscous => x[3 * N_JOINTS + i],
            Term::Braking => x[RAW_BRAKING + i],
            Term::Current => x[DRIVE_CURRENT],
            Term::DrivingCurrent => x[RAW_DRIVING_CURRENT],
            Term::BrakingCurrent => x[DRIVE_CURRENT] - x[RAW_DRIVING_CURRENT],
            Term::DrivingTorque => x[RAW_DRIVING_TORQUE],
            Term::BrakingTorque => x[RAW_TORQUE] - x[RAW_DRIVING_TORQUE],
            Term::Stribeck => x[RAW_STRIBECK],
            Term::BusPower => x[RAW_BUS_POWER],
        }
    }

    /// Σ_i term_i · w(i) on a raw row (a pooled term: its value · w(0)).
    pub(crate) fn sum(self, x: &[f64], w: &dyn Fn(usize) -> f64) -> f64 {
        if self.per_joint() {
            (0..N_JOINTS).map(|i| self.value(x, i) * w(i)).sum()
        } else {
            self.value(x, 0) * w(0)
        }
    }

    /// The library mechanism this term is a form of (its hypothesis id), if any.
    pub(crate) fn library_id(self) -> Option<&'static str> {
        self.table().0
    }

    /// What it is, in words.
    pub(crate) fn words(self) -> &'static str {
        self.table().1
    }

    /// Its symbol in a formula.
    pub(crate) fn symbol(self) -> &'static str {
        self.table().2
    }

    /// Unit of its coefficient.
    pub(crate) fn unit(self) -> &'static str {
        self.table().3
    }

    /// (library mechanism, words, symbol, unit), one row per term.
    #[rustfmt::skip]
    fn table(self) -> (Option<&'static str>, &'static str, &'static str, &'static str) {
        match self {
            Term::Mech => (None, "the transmitted mechanical power τq̇ (efficiency)", "τ_i q̇_i", "-"),
            Term::Copper => (None, "the copper loss Δτ²", "Δτ_i²", "W/Nm²"),
            Term::Coulomb => (None, "the Coulomb friction loss |q̇|", "|q̇_i|", "W·s/rad"),
            Term::Viscous => (None, "the viscous friction loss q̇²", "q̇_i²", "W·s²/rad²"),
            Term::Braking => (Some("braking"), "the braking asymmetry (regenerated power τq̇ < 0 not returned)", "min(τ_i q̇_i, 0)", "-"),
            Term::Current => (Some("drive_loss"), "the drive-electronics loss per ampere of phase current |τ|/K", "|τ_i|/K_i", "V"),
            Term::DrivingCurrent => (Some("drive_loss"), "the drive-electronics loss per ampere of the driving joints' current (τq̇ > 0)", "|τ_i|/K_i·[τ_i q̇_i > 0]", "V"),
            Term::BrakingCurrent => (Some("drive_loss"), "the drive-electronics loss per ampere of the braking or holding joints' current (τq̇ ≤ 0)", "|τ_i|/K_i·[τ_i q̇_i ≤ 0]", "V"),
            Term::DrivingTorque => (Some("electronics_nm"), "the drive-electronics loss per Nm of the driving joints (τq̇ > 0)", "|τ_i|·[τ_i q̇_i > 0]", "W/Nm"),
            Term::BrakingTorque => (Some("electronics_nm"), "the drive-electronics loss per Nm of the braking or holding joints (τq̇ ≤ 0)", "|τ_i|·[τ_i q̇_i ≤ 0]", "W/Nm"),
            Term::Stribeck => (Some("stribeck"), "the Stribeck friction Σ|q̇|·exp(−(q̇/v_s)²)", "|q̇_i|·exp(−(q̇_i/v_s)²)", "W·s/rad"),
            Term::BusPower => (Some("bus_power"), "the shared DC-bus loss (P_elec/V_bus)²", "(P_elec/V_bus)²", "Ω"),
        }
    }
}

/// How a term follows its signal s: g(s) multiplies the term (beside its level).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Shape {
    /// g = s.
    Linear,
    /// g = [s > level] (a level chosen from the data).
    Above(f64),
    /// g = exp(rate·(s − lo)/span): rises (rate > 0) or falls away (rate < 0) over the
    /// signal's 5–95 % range [lo, lo + span].
    Exp { rate: f64, lo: f64, span: f64 },
}

/// Quantiles of a signal's values at which a step's level is tried.
const STEP_QUANTILES: [f64; 3] = [0.25, 0.5, 0.75];
/// Rates of the exponential forms (over the 5–95 % range of the signal).
const EXP_RATES: [f64; 2] = [3.0, -3.0];
/// Family members kept per term by the screen (beside the always-scored linear forms).
pub(crate) const KEPT_PER_TERM: usize = 4;

impl Shape {
    /// g(s).
    pub(crate) fn g(self, s: f64) -> f64 {
        match self {
            Shape::Linear => s,
            Shape::Above(level) => f64::from(u8::from(s > level)),
            Shape::Exp { rate, lo, span } => (rate * (s - lo) / span).exp(),
        }
    }

    /// Every shape tried for a signal with these values (steps at [`STEP_QUANTILES`], exponentials
    /// over its 5–95 % range).
    pub(crate) fn all_for(values: &[f64]) -> Vec<Shape> {
        let mut out = vec![Shape::Linear];
        let Some((levels, lo, hi)) = step_levels(values, &STEP_QUANTILES) else {
            return out;
        };
        out.extend(levels.into_iter().map(Shape::Above));
        for rate in EXP_RATES {
            out.push(Shape::Exp {
                rate,
                lo,
                span: hi - lo,
            });
        }
        out
    }

    /// The words after the subject: how it follows `sname` given the sign of its coefficient.
    pub(crate) fn predicate(self, sname: &str, gamma0: f64) -> String {
        let rises = |up: bool| {
            if up {
                format!("rises with {sname}")
            } else {
                format!("falls as it rises: {sname}")
            }
        };
        match self {
            Shape::Linear => rises(gamma0 >= 0.0),
            Shape::Exp { rate, .. } => format!(
                "{} ({})",
                rises((gamma0 >= 0.0) == (rate > 0.0)),
                if rate > 0.0 {
                    "exponentially, most at its high end"
                } else {
                    "exponentially, most at its low end"
                }
            ),
            Shape::Above(level) => format!(
                "changes with {sname} ({} while it reads above {level:.4})",
                if gamma0 >= 0.0 { "larger" } else { "smaller" }
            ),
        }
    }

    /// g(s) in a formula.
    pub(crate) fn formula(self) -> String {
        match self {
            Shape::Linear => "s_i".into(),
            Shape::Above(level) => format!("[s_i > {level:.4}]"),
            Shape::Exp { rate, lo, span } => {
                format!("exp({rate:+.1}·(s_i − {lo:.4})/{span:.4})")
            }
        }
    }
}

/// Levels at quantiles `at` of a signal's values, each with at least 5 % of the values on either
/// side and distinct, and the signal's 5–95 % range; `None` for fewer than 20 values or no range.
pub(crate) fn step_levels(values: &[f64], at: &[f64]) -> Option<(Vec<f64>, f64, f64)> {
    let mut s: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    s.sort_by(f64::total_cmp);
    if s.len() < 20 {
        return None;
    }
    let q = |p: f64| s[((s.len() - 1) as f64 * p).round() as usize];
    let (lo, hi) = (q(0.05), q(0.95));
    if hi - lo <= 0.0 {
        return None;
    }
    let mut levels: Vec<f64> = Vec::new();
    for &p in at {
        let level = q(p);
        let share = s.iter().filter(|&&v| v > level).count() as f64 / s.len() as f64;
        if (0.05..=0.95).contains(&share) && !levels.contains(&level) {
            levels.push(level);
        }
    }
    Some((levels, lo, hi))
}

/// A candidate's place in the screen: its screening group and how many of that group are scored;
/// `None` for one always scored.
pub(crate) type Screen = Option<(usize, usize)>;

/// Indices of the candidates to score: every candidate that is not a screened member, and per
/// screening group the members (at most the group's cap) whose columns (e.g. term × g(s), term)
/// explain most of the residual `resid` by least squares. `family` gives, per candidate, its
/// group and the group's cap when it is a screened member (`None` for the rest), `cols` its
/// columns.
pub(crate) fn screen(
    family: &[Screen],
    cols: &dyn Fn(usize) -> Vec<Vec<f64>>,
    resid: &[f64],
) -> Vec<usize> {
    let mut keep: Vec<usize> = Vec::new();
    let mut scored: Vec<((usize, usize), f64, usize)> = Vec::new();
    for (i, f) in family.iter().enumerate() {
        match f {
            None => keep.push(i),
            Some(f) => scored.push((*f, explained(&cols(i), resid), i)),
        }
    }
    scored.sort_by(|a, b| b.1.total_cmp(&a.1));
    let mut taken = std::collections::HashMap::new();
    for ((group, cap), _, i) in scored {
        let n = taken.entry(group).or_insert(0usize);
        if *n < cap {
            *n += 1;
            keep.push(i);
        }
    }
    keep.sort_unstable();
    keep
}

/// Sum of squares of `e` explained by least squares on `cols`.
fn explained(cols: &[Vec<f64>], e: &[f64]) -> f64 {
    let mut q = Vec::new();
    cols.iter().for_each(|c| orthonormal_add(&mut q, c));
    q.iter().map(|c| dot(c, e).powi(2)).sum()
}

pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// `x` less its projection on the orthonormal columns `q`.
pub(crate) fn residual(q: &[Vec<f64>], x: &[f64]) -> Vec<f64> {
    let mut r = x.to_vec();
    for c in q {
        let k = dot(c, &r);
        r.iter_mut().zip(c).for_each(|(v, u)| *v -= k * u);
    }
    r
}

/// Adds `x` to the orthonormal columns `q` (Gram–Schmidt) unless it lies in their span.
pub(crate) fn orthonormal_add(q: &mut Vec<Vec<f64>>, x: &[f64]) {
    let r = residual(q, x);
    let norm = dot(&r, &r).sqrt();
    if norm > 1e-9 * dot(x, x).sqrt() {
        q.push(r.iter().map(|v| v / norm).collect());
    }
}

/// Weights of the weighted Holm correction, per generated candidate (`screened[i]`: a screened
/// family member): 1 for a candidate always scored, and the screened members share the same
/// total. Their sum is the correction's total weight.
pub(crate) fn weights(screened: &[bool]) -> Vec<f64> {
    let n_screened = screened.iter().filter(|&&s| s).count();
    let n_core = screened.len() - n_screened;
    let w = n_core.max(1) as f64 / n_screened.max(1) as f64;
    screened.iter().map(|&s| if s { w } else { 1.0 }).collect()
}

/// Whether a term × signal candidate in `shape` is screened (not always scored).
pub(crate) fn screened(t: Term, shape: Shape) -> bool {
    !(t.always_scored() && shape == Shape::Linear)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_step_at_distinct_levels_and_exponentials_span_the_range() {
        let v: Vec<f64> = (0..100).map(f64::from).collect();
        let s = Shape::all_for(&v);
        assert_eq!(s[0], Shape::Linear);
        let steps = s.iter().filter(|x| matches!(x, Shape::Above(_))).count();
        assert_eq!(steps, 3);
        assert_eq!(s.len(), 6);
        // A signal with two levels only: one distinct step level survives.
        let two: Vec<f64> = (0..100).map(|k| f64::from(u8::from(k >= 70))).collect();
        let s2 = Shape::all_for(&two);
        assert_eq!(
            s2.iter().filter(|x| matches!(x, Shape::Above(_))).count(),
            1
        );
        let e = Shape::Exp {
            rate: 3.0,
            lo: 0.0,
            span: 10.0,
        };
        assert!((e.g(10.0) - 3f64.exp()).abs() < 1e-12);
        assert_eq!(Shape::Above(0.5).g(0.6), 1.0);
    }

    #[test]
    fn screened_members_weigh_as_much_as_the_core_together() {
        let w = weights(&[false, false, true, true, true, true]);
        assert_eq!(&w[..2], &[1.0, 1.0]);
        assert!((w[2..].iter().sum::<f64>() - 2.0).abs() < 1e-12);
    }

    #[test]
    fn split_terms_add_up_to_the_whole() {
        let mut x = vec![0.0; crate::diagnose::hypotheses::N_RAW];
        x[0] = 2.0; // τq̇ of joint 0
        x[RAW_BRAKING] = -0.5;
        x[DRIVE_CURRENT] = 3.0;
        x[RAW_DRIVING_CURRENT] = 1.0;
        assert_eq!(Term::Braking.value(&x, 0), -0.5);
        assert_eq!(
            Term::DrivingCurrent.value(&x, 0) + Term::BrakingCurrent.value(&x, 0),
            Term::Current.value(&x, 0)
        );
    }

    #[test]
    fn the_screen_keeps_unscreened_candidates_and_the_best_members() {
        let e: Vec<f64> = (0..50).map(|k| f64::from(k % 7) - 3.0).collect();
        let fam = vec![
            None,
            Some((0, 2)),
            Some((0, 2)),
            Some((0, 2)),
            Some((1, 1)),
            Some((1, 1)),
        ];
        let cols = |i: usize| -> Vec<Vec<f64>> {
            match i {
                1 | 5 => vec![e.clone()],
                2 => vec![
                    e.iter()
                        .zip(0..)
                        .map(|(v, k)| v + f64::from(k % 3))
                        .collect(),
                ],
                _ => vec![(0..50).map(f64::from).collect()],
            }
        };
        // Group 0 keeps its best two, group 1 its best one.
        assert_eq!(screen(&fam, &cols, &e), vec![0, 1, 2, 5]);
    }
}
