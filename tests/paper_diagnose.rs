//! Paper-scale diagnosis: a 1000-trial simulated session with a concealed winding-resistance
//! temperature drift (α = 0.00393 /K, the copper value), diagnosed with the base model refitted
//! inside every fold. docs/diagnosis-results.md states the drift is found at paper scale even where a short
//! session confounds it with b_i (α = 0.00382 ± 0.00012); this test holds that figure. The
//! truth is the simulator's α; the estimate is this code's result, held at its printed precision.
//! Its bus-loss detection limit at paper scale is held here too, and its paper-scale
//! rows for the effect forms the diagnosis does not fit (below).

mod common;

/// The documentation page that prints the figures this file holds.
const PAGE: &str = "docs/diagnosis-results.md";

use g1viz::diagnose::{self, DiagnoseOptions};
use g1viz::signals::{SignalMap, load_recording};
use g1viz::sim::{self, Effects, Preset, SimConfig};

#[test]
fn paper_scale_thermal_drift_is_found_under_a_refit() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("paper_thermal.mcap");
    let mut effects = Effects::default();
    effects.enable("thermal").expect("thermal effect");
    let cfg = SimConfig {
        preset: Preset::Paper,
        seed: 21,
        effects,
        progress: false,
        ..SimConfig::default()
    };
    sim::simulate(&cfg, &path).expect("simulate");
    let rec = load_recording(&path, &SignalMap::g1_left_arm(), &Default::default()).expect("read");
    drop(dir);
    let d = diagnose::diagnose(&rec, &DiagnoseOptions::default()).expect("diagnose");
    print!("{}", d.summary);
    let ids: Vec<&str> = d.accepted.iter().map(|h| h.id.as_str()).collect();
    assert_eq!(ids, ["thermal"], "accepted: {ids:?}");
    let alpha = &d.accepted[0].params[0];
    println!("α = {} ± {}", alpha.value, alpha.std_err);
    common::assert_figure(PAGE, "paper-scale α [1/K]", alpha.value, "0.00382");
    common::assert_figure(PAGE, "paper-scale α s.e. [1/K]", alpha.std_err, "0.00012");
}

/// Diagnose a paper-scale session (seed 21, refit) with a shared DC-bus loss of `r_ohm`.
fn paper_bus_loss(r_ohm: f64) -> diagnose::Diagnosis {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("paper_bus.mcap");
    let mut effects = Effects::default();
    effects
        .enable(&format!("bus_loss={r_ohm}"))
        .expect("bus_loss effect");
    let cfg = SimConfig {
        preset: Preset::Paper,
        seed: 21,
        effects,
        progress: false,
        ..SimConfig::default()
    };
    sim::simulate(&cfg, &path).expect("simulate");
    let rec = load_recording(&path, &SignalMap::g1_left_arm(), &Default::default()).expect("read");
    drop(dir);
    diagnose::diagnose(&rec, &DiagnoseOptions::default()).expect("diagnose")
}

/// The bus-loss detection limit at paper scale (docs/diagnosis-results.md): R_bus = 0.01 Ω is found (nothing else
/// claimed, within 10 %), so is 0.0075 Ω (the limit), and 0.005 Ω is not claimed: its fit is
/// significant, but it improves the held-out RMSE by less than the 2 % minimum improvement.
#[test]
fn paper_scale_bus_loss_detection_limit() {
    let mut outcome = Vec::new();
    for r in [0.01, 0.0075, 0.005] {
        let d = paper_bus_loss(r);
        let ids: Vec<String> = d.accepted.iter().map(|h| h.id.clone()).collect();
        let h = d
            .hypotheses
            .iter()
            .find(|h| h.id == "bus_loss")
            .expect("scored");
        println!(
            "R_bus {r} Ω: accepted {ids:?}; bus_loss {:.5} ± {:.5} Ω, p {:.1e}, ΔBIC {:.1}, held-out RMSE {:+.2} %: {}",
            h.params[0].value,
            h.params[0].std_err,
            h.p_value,
            h.delta_bic,
            -100.0 * h.rel_improvement,
            h.verdict
        );
        if r >= 0.0075 {
            // 0.0075 Ω sits at the limit: held-out RMSE −2.03 % against the 2 % minimum.
            assert_eq!(ids, ["bus_loss"], "R_bus {r}");
            assert!(
                (h.params[0].value - r).abs() <= 0.1 * r,
                "{:?}",
                h.params[0]
            );
        }
        if r == 0.005 {
            assert!(ids.is_empty(), "R_bus {r}: claimed {ids:?}");
            assert!(h.p_value < 1e-3 && h.rel_improvement < 0.02, "{h:?}");
        }
        // The figures of docs/diagnosis-results.md, at their printed precision.
        let stated = match r {
            0.01 => ("0.0099", "0.0005", "-3.5"),
            0.0075 => ("0.0074", "0.0004", "-2.0"),
            _ => ("0.0048", "0.0005", "-0.9"),
        };
        common::assert_figure(PAGE, &format!("R_bus {r}"), h.params[0].value, stated.0);
        common::assert_figure(
            PAGE,
            &format!("R_bus {r} s.e."),
            h.params[0].std_err,
            stated.1,
        );
        common::assert_figure(
            PAGE,
            &format!("R_bus {r} held-out RMSE change [%]"),
            -100.0 * h.rel_improvement,
            stated.2,
        );
        if r == 0.005 {
            common::assert_figure(PAGE, "R_bus 0.005 p", h.p_value, "1.4e-13");
        }
        outcome.push((r, ids));
    }
    println!("{outcome:?}");
}

// ---------------------------------------------------------------------------------------------
// Paper scale for the effect forms the diagnosis does not fit (issue: "stop testing formulas
// against themselves"): each a 1000-trial session (seed 21) with one concealed effect whose form
// differs from every fitted hypothesis form. The bar: the right mechanism or a discovered term on
// the right field, the parameter of the matching form within 10 % of the simulator's value, and
// nothing else claimed (library terms reported as confounded with a found term are not claims).
// The paper-scale figures of docs/diagnosis-results.md for these rows are held at their printed precision.

/// A simulated paper-scale session, kept on disk while it is diagnosed: discovery reads every
/// recorded field from the file.
struct Paper {
    _dir: tempfile::TempDir,
    rec: g1viz::signals::Recording,
}

/// Simulate a paper-scale session (seed 21, default start temperatures) with `effect` concealed.
fn paper_session(effect: &str) -> Paper {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("paper_form.mcap");
    let mut effects = Effects::default();
    effects.enable(effect).expect("effect");
    let cfg = SimConfig {
        preset: Preset::Paper,
        seed: 21,
        effects,
        progress: false,
        ..SimConfig::default()
    };
    sim::simulate(&cfg, &path).expect("simulate");
    let rec = load_recording(&path, &SignalMap::g1_left_arm(), &Default::default()).expect("read");
    Paper { _dir: dir, rec }
}

/// The twin: the base model held at the paper's parameters (the simulator's base plant).
fn twin() -> DiagnoseOptions {
    DiagnoseOptions {
        reference: Some(g1viz::power::PowerModel::PAPER),
        ..DiagnoseOptions::default()
    }
}

/// Everything a diagnosis claims: accepted library hypotheses, terms found beyond it and loads
/// found on the rest power.
fn claims(d: &diagnose::Diagnosis) -> Vec<String> {
    let mut c: Vec<String> = d.accepted.iter().map(|h| h.id.clone()).collect();
    if let Some(r) = &d.discovery {
        c.extend(r.accepted.iter().map(|t| format!("found: {}", t.name)));
        c.extend(
            r.rest
                .iter()
                .flat_map(|r| &r.found)
                .map(|t| format!("rest: {}", t.name)),
        );
    }
    c
}

/// The final model's parameter `symbol`.
fn final_param<'a>(d: &'a diagnose::Diagnosis, symbol: &str) -> &'a diagnose::Param {
    d.final_model
        .params
        .iter()
        .find(|p| p.symbol == symbol)
        .unwrap_or_else(|| panic!("{symbol} not in the final model: {:?}", d.final_model))
}

/// `v` within 10 % of `truth`.
#[track_caller]
fn within_10_percent(what: &str, v: f64, truth: f64) {
    assert!(
        (v - truth).abs() <= 0.1 * truth.abs(),
        "{what} = {v}, truth {truth} ({:+.1} %)",
        100.0 * (v / truth - 1.0)
    );
}

/// The one library hypothesis `id` claimed and nothing else; the form comparison of its
/// mechanism decided for it (winner `id` over `runner_up`, paired held-out p < 1e-3, not
/// confounded). Returns the final model's parameter `symbol` and the form comparison.
fn library_form_claimed<'a>(
    mode: &str,
    d: &'a diagnose::Diagnosis,
    id: &str,
    runner_up: &str,
    symbol: &str,
) -> (&'a diagnose::Param, &'a diagnose::MechanismForms) {
    print!("== {mode}\n{}", d.summary);
    assert_eq!(claims(d), [id], "{mode}: nothing else may be claimed");
    let f = d
        .forms
        .iter()
        .find(|f| f.winner == id)
        .unwrap_or_else(|| panic!("{mode}: no form comparison won by {id}: {:?}", d.forms));
    assert!(
        f.accepted && !f.confounded && f.runner_up == runner_up && f.p_value < 1e-3,
        "{mode}: {f:?}"
    );
    // The form comparison reports the winner's parameter as the ranking does (same units and
    // bus-voltage scaling).
    let scored = d
        .accepted
        .iter()
        .find(|h| h.id == id)
        .map(|h| h.params[0].value)
        .unwrap_or(f64::NAN);
    let in_forms = f.params[0].first().map_or(f64::NAN, |p| p.value);
    assert!(
        (in_forms - scored).abs() <= 1e-9 * scored.abs(),
        "{mode}: the form comparison gives {symbol} = {in_forms}, the ranking {scored}"
    );
    let p = final_param(d, symbol);
    println!(
        "{mode}: {symbol} = {} ± {}; form margin {:.1} % (p = {:.1e})",
        p.value,
        p.std_err,
        100.0 * f.margin,
        f.p_value
    );
    (p, f)
}

/// The bus loss from total electrical power (P += R·(P_elec/V_bus)², deliberately strong 10 Ω:
/// the arm's net electrical power is tens of W, so a realistic 50 mΩ is a few mW — fitted at
/// paper scale with an s.e. of ≈ 0.07 Ω and not claimed, see docs/diagnosis-results.md). Both modes: only
/// `bus_power` claimed, its form beats the phase-current form, R_bus within 10 %.
#[test]
fn paper_scale_bus_loss_from_electrical_power_is_found_in_its_form() {
    let truth = 10.0;
    let s = paper_session(&format!("bus_power={truth}"));
    for (mode, opts, stated) in [
        ("refit", DiagnoseOptions::default(), ("9.80", "0.15", "23")),
        ("twin", twin(), ("10.10", "0.10", "36")),
    ] {
        let d = diagnose::diagnose(&s.rec, &opts).expect("diagnose");
        let (p, f) = library_form_claimed(mode, &d, "bus_power", "bus_loss", "R_bus");
        within_10_percent(&format!("{mode} R_bus"), p.value, truth);
        common::assert_figure(PAGE, &format!("{mode} R_bus [Ω]"), p.value, stated.0);
        common::assert_figure(PAGE, &format!("{mode} R_bus s.e. [Ω]"), p.std_err, stated.1);
        common::assert_figure(
            PAGE,
            &format!("{mode} form margin [%]"),
            100.0 * f.margin,
            stated.2,
        );
    }
}

/// The same form at a realistic 50 mΩ (refit): the loss is a few mW, R_bus is fitted with an s.e.
/// of ≈ 0.08 Ω and nothing is claimed. The truth lies within 3 s.e., not 2: the refit's R_bus sits
/// ≈ 0.2 Ω low at paper scale (−0.12 here; 9.80 for the 10 Ω session), an offset not yet explained.
#[test]
fn paper_scale_bus_loss_from_electrical_power_at_a_realistic_resistance_is_not_claimed() {
    let truth = 0.05;
    let s = paper_session(&format!("bus_power={truth}"));
    let d = diagnose::diagnose(&s.rec, &DiagnoseOptions::default()).expect("diagnose");
    print!("{}", d.summary);
    assert!(claims(&d).is_empty(), "claimed {:?}", claims(&d));
    let h = d
        .hypotheses
        .iter()
        .find(|h| h.id == "bus_power")
        .expect("scored");
    let p = &h.params[0];
    println!("R_bus = {} ± {} Ω: {}", p.value, p.std_err, h.verdict);
    assert!(
        !h.accepted && (p.value - truth).abs() <= 3.0 * p.std_err,
        "{h:?}"
    );
    common::assert_figure(PAGE, "R_bus s.e. at 50 mΩ [Ω]", p.std_err, "0.08");
}

/// The drive-electronics loss per newton-metre (P += k·Σ|τ_i|, 0.5 W/Nm). At 72 trials its form
/// and the per-ampere form are confounded; at paper scale the per-Nm form wins significantly in
/// both modes and k_el is within 10 %.
#[test]
fn paper_scale_electronics_loss_per_newton_metre_is_told_from_per_ampere() {
    let truth = 0.5;
    let s = paper_session(&format!("electronics_nm={truth}"));
    for (mode, opts, stated) in [
        (
            "refit",
            DiagnoseOptions::default(),
            ("0.508", "0.0039", "2.2"),
        ),
        ("twin", twin(), ("0.512", "0.0029", "2.6")),
    ] {
        let d = diagnose::diagnose(&s.rec, &opts).expect("diagnose");
        let (p, f) = library_form_claimed(mode, &d, "electronics_nm", "drive_loss", "k_el");
        within_10_percent(&format!("{mode} k_el"), p.value, truth);
        common::assert_figure(PAGE, &format!("{mode} k_el [W/Nm]"), p.value, stated.0);
        common::assert_figure(
            PAGE,
            &format!("{mode} k_el s.e. [W/Nm]"),
            p.std_err,
            stated.1,
        );
        common::assert_figure(
            PAGE,
            &format!("{mode} form margin [%]"),
            100.0 * f.margin,
            stated.2,
        );
    }
}

/// The one term found beyond the library and nothing else claimed; library terms dropped as
/// confounded with it stay unclaimed.
fn only_found(mode: &str, d: &diagnose::Diagnosis) -> diagnose::Discovery {
    print!("== {mode}\n{}", d.summary);
    let found = d
        .discovery
        .as_ref()
        .map(|r| r.accepted.clone())
        .unwrap_or_default();
    assert!(
        d.accepted.is_empty() && found.len() == 1,
        "{mode}: claims {:?}",
        claims(d)
    );
    for c in &d.confounded {
        assert!(
            !d.accepted.iter().any(|h| h.id == c.dropped),
            "{mode}: {c:?}"
        );
    }
    let t = found.into_iter().next().expect("one found term");
    for p in &t.params {
        println!(
            "{mode}: {} = {} ± {} ({})",
            p.symbol, p.value, p.std_err, p.name
        );
    }
    t
}

/// The found term's parameter `symbol`.
fn found_param<'a>(t: &'a diagnose::Discovery, symbol: &str) -> &'a diagnose::Param {
    t.params
        .iter()
        .find(|p| p.symbol == symbol)
        .unwrap_or_else(|| panic!("{symbol} not in {t:?}"))
}

/// Unequal Coulomb friction excess per joint (P += F·Σ w_i·|q̇_i|, F = 1, w =
/// JOINT_FRICTION_PATTERN) against the twin. At 72 trials no joint is identified (only a pooled
/// excess); at paper scale the shoulder pitch, shoulder yaw, elbow and wrist pitch are reported
/// one by one, each within 10 % of F·w_i, and the three least-moved joints share one pooled
/// coefficient inside the range of their true excesses (± 2.5 s.e.). A refit absorbs the excess
/// into its per-joint c_i (the same regressor) and claims nothing, at paper scale too.
#[test]
fn paper_scale_joint_friction_is_identified_joint_by_joint_against_the_twin() {
    let f = 1.0;
    let s = paper_session(&format!("joint_friction={f}"));
    let d = diagnose::diagnose(&s.rec, &twin()).expect("diagnose");
    let t = only_found("twin", &d);
    assert!(
        t.name.contains("Coulomb") && t.name.contains("joint by joint"),
        "{}",
        t.name
    );
    let w = g1viz::sim::JOINT_FRICTION_PATTERN;
    let mut identified = Vec::new();
    for p in &t.params {
        if let Some(i) = p
            .symbol
            .strip_prefix("k_")
            .and_then(|i| i.parse::<usize>().ok())
        {
            within_10_percent(&format!("k_{i}"), p.value, f * w[i]);
            identified.push(i);
        }
    }
    assert_eq!(identified, [0, 2, 3, 5], "{t:?}");
    let pooled = found_param(&t, "k_pooled");
    assert_eq!(t.params.len(), identified.len() + 1, "{t:?}");
    let rest: Vec<f64> = [1, 4, 6].iter().map(|&i| f * w[i]).collect();
    let (lo, hi) = rest
        .iter()
        .fold((f64::INFINITY, 0.0f64), |a, &v| (a.0.min(v), a.1.max(v)));
    assert!(
        pooled.value >= lo - 2.5 * pooled.std_err && pooled.value <= hi + 2.5 * pooled.std_err,
        "{pooled:?} vs {rest:?}"
    );
    for (sym, stated) in [
        ("k_0", ["1.00", "0.014"]),
        ("k_2", ["0.50", "0.015"]),
        ("k_3", ["1.48", "0.023"]),
        ("k_5", ["0.74", "0.022"]),
        ("k_pooled", ["0.27", "0.012"]),
    ] {
        let p = found_param(&t, sym);
        common::assert_figure(PAGE, sym, p.value, stated[0]);
        common::assert_figure(PAGE, &format!("{sym} s.e."), p.std_err, stated[1]);
    }
    let d = diagnose::diagnose(&s.rec, &DiagnoseOptions::default()).expect("diagnose");
    print!("== refit\n{}", d.summary);
    assert!(claims(&d).is_empty(), "refit: claimed {:?}", claims(&d));
}

/// Friction that follows the housing temperature (P += k·Σ(T_housing,i − 25 °C)·|q̇_i|,
/// k = 0.05 W/(K·rad/s)) with the default start temperatures (windings at 30 °C, housings settled
/// with them). At 72–144 trials this is an almost constant Coulomb excess (nothing claimed by a
/// refit, gear friction claimed against the twin); over a paper session the housings warm, and
/// both modes find it on the seven arm motors' `temperature[1]`, k within 10 %, and its level
/// k0 = −25 °C·k (the 25 °C reference) within 10 %.
#[test]
fn paper_scale_housing_friction_is_found_on_the_housing_field_at_default_start() {
    let k = 0.05;
    let s = paper_session(&format!("housing_friction={k}"));
    for (mode, opts, stated) in [
        ("refit", DiagnoseOptions::default(), ("0.0485", "0.0008")),
        ("twin", twin(), ("0.0478", "0.0021")),
    ] {
        let d = diagnose::diagnose(&s.rec, &opts).expect("diagnose");
        let t = only_found(mode, &d);
        let housings: Vec<String> = (15..22)
            .map(|m| format!("/lowstate.motor_state[{m}].temperature[1]"))
            .collect();
        assert_eq!(t.fields, housings, "{mode}: {t:?}");
        // Over a paper session the housings are told from the windings: no rival field named.
        assert!(t.tied.is_empty(), "{mode}: {:?}", t.tied);
        assert!(t.name.contains("Coulomb"), "{mode}: {}", t.name);
        let kf = found_param(&t, "k");
        within_10_percent(&format!("{mode} k"), kf.value, k);
        within_10_percent(
            &format!("{mode} k0"),
            found_param(&t, "k0").value,
            -25.0 * k,
        );
        common::assert_figure(PAGE, &format!("{mode} k"), kf.value, stated.0);
        common::assert_figure(PAGE, &format!("{mode} k s.e."), kf.std_err, stated.1);
    }
}

/// A 3 W fan on the main-board rail switching on and off, `/lf/mainboardstate.fan_state[1]`
/// reading its speed (refit): found on that field, its load within 10 % of 3 W (the step form's
/// P_on, or the linear form's load change over the field's 5–95 % range, which spans off to on).
#[test]
fn paper_scale_fan_load_is_found_on_the_board_field() {
    let watts = 3.0;
    let s = paper_session(&format!("fan_load={watts}"));
    let d = diagnose::diagnose(&s.rec, &DiagnoseOptions::default()).expect("diagnose");
    let t = only_found("refit", &d);
    assert_eq!(t.fields, ["/lf/mainboardstate.fan_state[1]"], "{t:?}");
    let p = &t.params[0];
    assert!(p.symbol == "P_on" || p.symbol == "ΔP", "{p:?}");
    within_10_percent(&p.symbol, p.value, watts);
    common::assert_figure(PAGE, &p.symbol, p.value, "2.95");
    common::assert_figure(PAGE, &format!("{} s.e.", p.symbol), p.std_err, "0.026");
    // The fan is on or off in each trial's pre-idle too: the rest power steps with it.
    let rest = d
        .discovery
        .as_ref()
        .and_then(|r| r.rest.as_ref())
        .expect("rest power");
    println!("rest: {rest:?}");
    assert_eq!(rest.found.len(), 1, "{rest:?}");
    assert_eq!(rest.found[0].field, "/lf/mainboardstate.fan_state[1]");
    let p = &rest.found[0].params[0];
    within_10_percent(&format!("rest {}", p.symbol), p.value, watts);
    // A load on the rail: the battery meter shows it too.
    for m in [&t.meter, &rest.found[0].meter] {
        let m = m.as_ref().expect("checked against the battery meter");
        assert_eq!(m.verdict, diagnose::MeterVerdict::Load, "{m:?}");
    }
}

/// The same fan cycling, drawing nothing, while the main-board meter's reading shifts by 3 W
/// (`fan_meter`, a one-meter artefact): found on the same field, and named an artefact of the
/// main-board meter (the battery meter shows none of it), not a load on the rail (issue 28).
#[test]
fn paper_scale_one_meter_artefact_is_named_a_correction_of_that_meter() {
    let s = paper_session("fan_meter=3");
    let d = diagnose::diagnose(&s.rec, &DiagnoseOptions::default()).expect("diagnose");
    print!("{}", d.summary);
    let t = only_found("refit", &d);
    assert_eq!(t.fields, ["/lf/mainboardstate.fan_state[1]"], "{t:?}");
    let rest = d.discovery.as_ref().and_then(|r| r.rest.as_ref());
    let rest = &rest.expect("rest power").found;
    assert_eq!(rest.len(), 1, "{rest:?}");
    for (name, m) in [(&t.name, &t.meter), (&rest[0].name, &rest[0].meter)] {
        let m = m.as_ref().expect("checked against the battery meter");
        assert_eq!(m.verdict, diagnose::MeterVerdict::Artefact, "{m:?}");
        assert!(m.share.abs() < 0.25, "{m:?}");
        assert!(
            name.contains("main-board meter") && !name.contains("rail load"),
            "{name}"
        );
    }
    assert!(
        d.summary.contains("an artefact of the main-board meter"),
        "{}",
        d.summary
    );
}

/// A power sensor lagging 0.8 s and nothing else (seed 3, refit): the latency is the one claim.
/// The rest power reads each trial's baseline readings at the lag the selection found (their
/// windows inside the pre-idle); read at lag 0 the first ones averaged the end of the previous
/// trial's return, and the rest power claimed two arm joint velocities (issue 28).
#[test]
fn paper_scale_latency_alone_claims_nothing_on_the_rest_power() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("paper_latency.mcap");
    let mut effects = Effects::default();
    effects.enable("latency=0.8").expect("latency effect");
    let cfg = SimConfig {
        preset: Preset::Paper,
        seed: 3,
        effects,
        progress: false,
        ..SimConfig::default()
    };
    sim::simulate(&cfg, &path).expect("simulate");
    let rec = load_recording(&path, &SignalMap::g1_left_arm(), &Default::default()).expect("read");
    let d = diagnose::diagnose(&rec, &DiagnoseOptions::default()).expect("diagnose");
    print!("{}", d.summary);
    assert_eq!(claims(&d), ["latency"]);
    within_10_percent("L", d.accepted[0].params[0].value, 0.8);
    let rest = d.discovery.as_ref().and_then(|r| r.rest.as_ref());
    assert!(rest.is_some_and(|r| r.n_trials >= 200), "{rest:?}");
}
