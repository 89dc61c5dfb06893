use super::*;
use crate::diagnose::hypotheses::{POWER_HYPOTHESES, Sample, power_hypothesis, raw_row};
use crate::diagnose::reading_rows::Rows;
use crate::power::PowerModel;
use rand::RngExt;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

/// Synthetic rows: each row one random arm state of 1–3 moving joints; the truth is the
/// paper's model plus `effect(sample)`; trials heat up from 30 to 60 °C.
pub(crate) fn synth(
    seed: u64,
    n_trials: usize,
    effect: &dyn Fn(&Sample) -> f64,
) -> PowerData<'static> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.3).unwrap();
    let mut rows = Rows::default();
    for t in 0..n_trials {
        let temp_level = 30.0 + 30.0 * t as f64 / n_trials as f64;
        let moved: Vec<usize> = (0..rng.random_range(1..4))
            .map(|_| rng.random_range(0..7))
            .collect();
        let tau0_sq = [1.0; 7];
        for _ in 0..8 {
            let mut q = [0.0; 7];
            let mut dq = [0.0; 7];
            let mut tau = [1.0; 7];
            for &j in &moved {
                q[j] = rng.random_range(-1.0..1.0);
                dq[j] = rng.random_range(-2.5..2.5);
                tau[j] = rng.random_range(-6.0..6.0);
            }
            let temp = [temp_level; 7];
            let gyro = [0.0; 3];
            let s = Sample {
                q: &q,
                dq: &dq,
                tau: &tau,
                temp: &temp,
                gyro: &gyro,
                tau0_sq: &tau0_sq,
                bus_amps: PowerModel::PAPER.predict(&tau, &dq, &tau0_sq) / 50.0,
            };
            let x = raw_row(&s);
            let y = PowerModel::PAPER.predict(&tau, &dq, &tau0_sq)
                + effect(&s)
                + noise.sample(&mut rng);
            rows.trial.push(t);
            rows.t.push(t as f64);
            rows.phase.push(crate::trial::Phase::Trajectory);
            rows.y.push(y);
            rows.x.push(x);
        }
    }
    PowerData::new(vec![0.0], vec![rows], n_trials, 5, None)
}

pub(crate) const RULE: Rule = Rule {
    alpha: 1e-3,
    bic_threshold: -10.0,
    min_improvement: 0.01,
};

fn all() -> Vec<&'static Hypothesis> {
    POWER_HYPOTHESES.iter().collect()
}

#[test]
fn null_data_accepts_nothing() {
    for seed in 0..3 {
        let sel = select(&synth(seed, 60, &|_| 0.0), &all(), &RULE).unwrap();
        assert!(
            sel.accepted.is_empty(),
            "seed {seed}: accepted {:?}",
            sel.accepted.iter().map(|s| &s.id).collect::<Vec<_>>()
        );
    }
}

/// A score that passes every statistical gate at an implausible size is "only implausible"
/// (the summary locates it); one that also fails a gate, or is plausible, is not.
#[test]
fn only_an_implausible_size_is_told_from_a_failed_gate() {
    let judged = |p_value: f64, plausible: bool| {
        let quality = |r2: f64, rmse_w: f64| crate::diagnose::Quality { r2, rmse_w };
        let (before, after) = (quality(0.9, 1.0), quality(0.95, 0.6));
        let held = Held {
            p_value,
            before,
            after,
        };
        let mut s = HypothesisScore {
            delta_bic: -700.0,
            plausible,
            step: 1,
            ..held.score("stribeck", "", "power", Vec::new())
        };
        let (ok, why) = RULE.judge(&s);
        (s.accepted, s.verdict) = (ok, why);
        s
    };
    assert!(judged(1e-11, false).only_implausible());
    assert!(!judged(0.5, false).only_implausible(), "a failed gate too");
    assert!(!judged(1e-11, true).only_implausible(), "accepted");
}

#[test]
fn braking_return_fraction_is_recovered() {
    // mech_i = r·τq̇ when braking: P += (r − 1)·Σ min(τ_i q̇_i, 0), r = 0.3 (a_i = 1 in the paper).
    let r = 0.3;
    let effect =
        move |s: &Sample| (r - 1.0) * (0..7).map(|i| (s.tau[i] * s.dq[i]).min(0.0)).sum::<f64>();
    let sel = select(&synth(7, 60, &effect), &all(), &RULE).unwrap();
    assert_eq!(sel.first_step[0].id, "braking");
    assert_eq!(sel.accepted.len(), 1);
    let v = sel.accepted[0].params[0].value;
    assert!((v - r).abs() < 0.1 * r, "r = {v}");
}

/// The drive-electronics mechanism of `effect` data: (forms entry, accepted ids).
fn electronics_forms(seed: u64, effect: &dyn Fn(&Sample) -> f64) -> MechanismForms {
    let sel = select(&synth(seed, 120, effect), &all(), &RULE).unwrap();
    let f = sel
        .forms
        .iter()
        .find(|f| f.mechanism == "drive-electronics loss")
        .cloned()
        .expect("forms compared");
    assert_eq!(sel.accepted.len(), 1, "{:?}", sel.accepted);
    assert_eq!(sel.accepted[0].id, f.winner);
    f
}

#[test]
fn forms_are_told_apart_only_on_a_significant_margin() {
    let k = crate::power::JOINT_TORQUE_CONSTANT;
    let amps = move |s: &Sample| (0..7).map(|j| s.tau[j].abs() / k[j]).sum::<f64>();
    // Per ampere, strong: the per-ampere form wins significantly and is claimed.
    let f = electronics_forms(3, &|s: &Sample| 1.0 * amps(s));
    assert!(
        f.accepted && !f.confounded && f.winner == "drive_loss",
        "{f:?}"
    );
    assert!(f.p_value < RULE.alpha, "{f:?}");
    assert_eq!(f.form_words, ["per-ampere", "per-Nm"]);
    // The same form, weak (V = 0.15 V): the loss is found but its form is not told.
    let weak = move |s: &Sample| 0.15 * amps(s);
    let f = electronics_forms(3, &weak);
    assert!(f.accepted && f.confounded, "{f:?}");
    assert!(f.p_value >= RULE.alpha, "{f:?}");
    assert_eq!(
        f.either(),
        format!("{} or {}", f.form_words[0], f.form_words[1])
    );
    let sel = select(&synth(3, 120, &weak), &all(), &RULE).unwrap();
    assert!(sel.accepted[0].verdict.contains("form: confounded — "));
}

/// Issue 28's class of wrong claims, on data this module did not write the form of: a
/// mechanism in a form the library does not fit, which two library mechanisms approximate
/// about equally. Neither may be named; the structure is located with both.
#[test]
fn a_mechanism_another_fits_as_well_is_located_not_named() {
    // Gear friction only above a threshold of |τq̇| (campaign seed 275145867 was named the
    // braking asymmetry).
    let gear = |s: &Sample| {
        0.2 * (0..7)
            .map(|i| (s.tau[i] * s.dq[i]).abs())
            .filter(|p| *p > 3.0)
            .sum::<f64>()
    };
    // A drive-electronics loss with per-joint weights (seed 791979931: named the bus loss).
    let k = crate::power::JOINT_TORQUE_CONSTANT;
    let w = [0.0, 0.4, 1.9, 1.5, 1.0, 1.4, 0.9];
    let drive = move |s: &Sample| (0..7).map(|j| 0.3 * w[j] * s.tau[j].abs() / k[j]).sum();
    for (what, effect, wrong) in [
        ("gear", &gear as &dyn Fn(&Sample) -> f64, "braking"),
        ("drive", &drive, "bus_loss"),
    ] {
        let data = synth(5, 60, effect);
        let mut sel = select(&data, &all(), &RULE).unwrap();
        super::super::parsimony::apply(&data, &mut sel, None, &RULE).unwrap();
        let ids: Vec<&str> = sel.accepted.iter().map(|s| s.id.as_str()).collect();
        let unnamed: Vec<&MechanismForms> = sel.forms.iter().filter(|f| f.unnamed).collect();
        eprintln!("{what}: accepted {ids:?}, unnamed {unnamed:?}");
        assert!(!ids.contains(&wrong), "{what}: named {ids:?}");
    }
}

#[test]
fn bus_loss_and_thermal_together_are_both_found() {
    let (rb, alpha) = (0.05, 0.004);
    let k = crate::power::JOINT_TORQUE_CONSTANT;
    let b = PowerModel::PAPER.b;
    let effect = move |s: &Sample| {
        let i: f64 = (0..7).map(|j| s.tau[j].abs() / k[j]).sum();
        let thermal: f64 = (0..7)
            .map(|j| b[j] * alpha * (s.temp[j] - 25.0) * (s.tau[j] * s.tau[j] - s.tau0_sq[j]))
            .sum();
        rb * i * i + thermal
    };
    let data = synth(11, 80, &effect);
    let mut sel = select(&data, &all(), &RULE).unwrap();
    // Each beats the other in flexible form (the rule after all stages).
    super::super::parsimony::apply(&data, &mut sel, None, &RULE).unwrap();
    let ids: Vec<&str> = sel.accepted.iter().map(|s| s.id.as_str()).collect();
    assert!(
        ids.contains(&"bus_loss") && ids.contains(&"thermal"),
        "accepted {ids:?}"
    );
    // Every claim carries its stability, at or above the gate.
    let stable = super::super::stepwise::STABLE;
    assert!(
        (sel.accepted.iter()).all(|a| a.stability.is_some_and(|s| s >= stable)),
        "{:?}",
        sel.accepted.iter().map(|a| a.stability).collect::<Vec<_>>()
    );
    let final_theta = &sel.last.full.theta;
    let pos = |id: &str| sel.last.spec.iter().position(|h| h.id == id).unwrap() + N_PARAMS;
    assert!((final_theta[pos("bus_loss")] - rb).abs() < 0.1 * rb);
    assert!(
        (final_theta[pos("thermal")] - alpha).abs() < 0.1 * alpha,
        "α = {}",
        final_theta[pos("thermal")]
    );
    assert!(power_hypothesis("thermal").is_some());
}
