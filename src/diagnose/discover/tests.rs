//! Unit tests of discovery's rules.

use super::candidates::{Kind, Signal, TIME_NAME, families, within_share};
use super::clock_stand_ins;
use super::found::TiedTerm;
use super::ties::{Tie, name_with_ties, tie_of};
use super::words::identified_or_pooled;
use crate::N_JOINTS;
use crate::diagnose::family::{Shape, Term};
use crate::diagnose::select::Param;
use crate::diagnose::stats::step_threshold;

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

/// Structure that stays in the final residual per trial and follows a slow state is located
/// with discovery's best rejected candidate as its best approximation, and never claimed; a
/// correlate with a joint's position (where the base model's own misfit shows), one that is not
/// significant, or a term already found leaves the report as it was.
#[test]
fn slow_structure_no_candidate_passes_is_located_not_claimed() {
    let q = serde_json::json!({"r2": 0.9, "rmse_w": 1.0});
    let best: super::Discovery = serde_json::from_value(serde_json::json!({
        "name": "The copper loss Δτ² of the arm's joints rises with /m[16].temperature[1]",
        "form": "k·Σ Δτ_i²·s_i", "fields": ["/m[16].temperature[1]"], "params": [],
        "p_value": 1e-2, "alpha": 1e-7, "delta_bic": -20.0, "rel_improvement": 0.05,
        "before": q, "after": q, "step": 1, "verdict": "rejected: p = 1.0e-2 ≥ 1.0e-7 (Holm)"
    }))
    .unwrap();
    let corr = |feature: &str, significant| crate::diagnose::Correlate {
        feature: feature.into(),
        r: 0.5,
        p_adjusted: 4.8e-3,
        significant,
        trials: Vec::new(),
        slow: !feature.ends_with("position q"),
    };
    let mut r = super::DiscoveryReport {
        best_rejected: Some(best.clone()),
        ..Default::default()
    };
    r.locate_unexplained(&[corr("left_wrist_roll_joint position q", true)]);
    r.locate_unexplained(&[corr("session time", false)]);
    assert!(r.located.is_empty());
    let t = "left_shoulder_roll_joint motor temperature T";
    r.locate_unexplained(&[
        corr("left_wrist_roll_joint position q", true),
        corr(t, true),
    ]);
    assert_eq!(r.located.len(), 1);
    let l = &r.located[0];
    assert!(
        l.name.contains(t) && l.name.contains(&best.name),
        "{}",
        l.name
    );
    assert!(l.name.contains("form not identified") && r.accepted.is_empty());
    assert_eq!(l.fields, best.fields);
    let mut found = super::DiscoveryReport {
        accepted: vec![best.clone()],
        best_rejected: Some(best),
        ..Default::default()
    };
    found.locate_unexplained(&[corr(t, true)]);
    assert!(found.located.is_empty());
}
