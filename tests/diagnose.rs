//! Acceptance matrix of the diagnosis on simulated sessions with one concealed effect each (the
//! simulator writes MCAP + truth; the diagnosis reads only the MCAP), two effects at once, null
//! sessions, an effect outside the library (harness drag), and the shared recordings of the
//! independent generator (nothing concealed).
//!
//! Sessions: three `smoke` sessions (different seeds, ≈ 24 trials each) read back and joined
//! end to end (≈ 72 trials), six (≈ 140 trials) for the faint effects (Stribeck, balance leak,
//! thermal drift under a refit), small enough for CI. Expected values come from the simulator's
//! configuration (the concealed parameters), never from the code under test.

mod common;

use std::path::PathBuf;

use g1viz::diagnose::{self, DiagnoseOptions, Diagnosis};
use g1viz::power::PowerModel;
use g1viz::read::OpenOptions;
use g1viz::robot::Payload;
use g1viz::signals::{self, Recording, SignalMap};
use g1viz::sim::{self, Effects, Preset, SimConfig};

/// Truth trial windows on the joined timeline: (joints moved, trajectory start, return end).
type TruthTrials = Vec<(Vec<usize>, f64, f64)>;

/// The simulated files behind a joined recording (kept until dropped: discovery reads every
/// recorded field from them).
struct Files {
    _dir: tempfile::TempDir,
    sources: Vec<diagnose::FieldSource>,
}

impl Files {
    /// `opts` reading every recorded field of these files.
    fn opts(&self, opts: DiagnoseOptions) -> DiagnoseOptions {
        DiagnoseOptions {
            field_sources: self.sources.clone(),
            ..opts
        }
    }
}

/// Simulate `parts` smoke sessions with `effects` and join them into one recording; also return
/// the truth trial windows (joined timeline) as (joints moved, traj start, return end), and the
/// files.
fn session(
    effects: &Effects,
    seed: u64,
    parts: u64,
    t_start_c: &[f64],
) -> (Recording, TruthTrials, Files) {
    session_with(effects, seed, parts, t_start_c, &[])
}

/// [`session`] with the housings started at `housing_c` (cycled; empty: settled).
fn session_with(
    effects: &Effects,
    seed: u64,
    parts: u64,
    t_start_c: &[f64],
    housing_c: &[f64],
) -> (Recording, TruthTrials, Files) {
    let window = SimConfig::default().sensor_window_s;
    session_window(effects, seed, parts, t_start_c, housing_c, window)
}

/// [`session_with`] with power sensors averaging `window_s`.
fn session_window(
    effects: &Effects,
    seed: u64,
    parts: u64,
    t_start_c: &[f64],
    housing_c: &[f64],
    window_s: f64,
) -> (Recording, TruthTrials, Files) {
    session_cfg(effects, seed, parts, &|part, cfg| {
        cfg.t_start_c = t_start_c[part as usize % t_start_c.len()];
        cfg.housing_start_c =
            (!housing_c.is_empty()).then(|| housing_c[part as usize % housing_c.len()]);
        cfg.sensor_window_s = window_s;
    })
}

/// `parts` smoke sessions with `effects`, each part's configuration set by `part_cfg(part, cfg)`,
/// joined as [`session`] does.
fn session_cfg(
    effects: &Effects,
    seed: u64,
    parts: u64,
    part_cfg: &dyn Fn(u64, &mut SimConfig),
) -> (Recording, TruthTrials, Files) {
    let dir = tempfile::tempdir().unwrap();
    let mut recs = Vec::new();
    let mut truth_trials = Vec::new();
    let mut end = None::<f64>;
    for part in 0..parts {
        let mut cfg = SimConfig {
            preset: Preset::Smoke,
            seed: seed * 100 + part,
            effects: *effects,
            progress: false,
            ..SimConfig::default()
        };
        part_cfg(part, &mut cfg);
        let out = dir.path().join(format!("s{part}.mcap"));
        let truth = sim::simulate(&cfg, &out).unwrap();
        let rec = signals::load_recording(&out, &SignalMap::g1_left_arm(), &OpenOptions::default())
            .unwrap();
        // The same shift join_recordings applies.
        let first = rec.state.t.first().copied().unwrap_or(0.0);
        let offset = end.map_or(0.0, |e| e + GAP_S - first);
        for t in &truth.trials {
            let s = |ns: u64| (ns as f64 - rec.start_ns as f64) * 1e-9 + offset;
            truth_trials.push((
                t.joints_moved.clone(),
                s(t.t_traj_start_ns),
                s(t.t_return_end_ns),
            ));
        }
        end = Some(rec.state.t.last().copied().unwrap_or(0.0) + offset);
        recs.push(rec);
    }
    let (rec, sources) = diagnose::join_recordings_with_sources(recs, GAP_S);
    (rec, truth_trials, Files { _dir: dir, sources })
}

const GAP_S: f64 = 5.0;

fn refit() -> DiagnoseOptions {
    DiagnoseOptions::default()
}

/// The twin: the simulator's base plant is the paper's model.
fn twin() -> DiagnoseOptions {
    DiagnoseOptions {
        reference: Some(PowerModel::PAPER),
        ..DiagnoseOptions::default()
    }
}

fn show(name: &str, d: &Diagnosis) {
    eprintln!("== {name}\n{}", d.summary);
    for h in &d.hypotheses {
        let p = &h.params[0];
        eprintln!(
            "  {:>2} {:>13} {}={:.5}±{:.5} p={:.1e} dBIC={:.1} rmse {:.4}→{:.4} {}",
            h.rank,
            h.id,
            p.symbol,
            p.value,
            p.std_err,
            h.p_value,
            h.delta_bic,
            h.rmse_before,
            h.rmse_after,
            h.accepted
        );
    }
}

/// Everything a diagnosis claims: accepted hypotheses and terms found beyond the library.
fn claims(d: &Diagnosis) -> Vec<String> {
    let mut c: Vec<String> = d.accepted.iter().map(|h| h.id.clone()).collect();
    if let Some(r) = &d.discovery {
        c.extend(
            r.accepted
                .iter()
                .map(|t| format!("found: {} {:?}", t.form, t.fields)),
        );
    }
    c
}

fn param(d: &Diagnosis, symbol: &str) -> f64 {
    d.final_model
        .params
        .iter()
        .find(|p| p.symbol == symbol)
        .map(|p| p.value)
        .unwrap_or(f64::NAN)
}

/// Where and how a single-effect session is made: start temperatures of its parts (cycled) and
/// the number of smoke sessions joined (faint effects need more trials).
struct Sessions {
    t_start_c: &'static [f64],
    parts: u64,
}

const SMALL: Sessions = Sessions {
    t_start_c: &[30.0],
    parts: 3,
};
/// ≈ 140 trials: what the matrix in docs/diagnosis-results.md uses for the faint effects.
const DOUBLE: Sessions = Sessions {
    t_start_c: &[30.0],
    parts: 6,
};

/// One concealed effect: top-ranked = it, accepted, parameter within 10 %, held-out fit improves.
fn check_single(
    name: &str,
    effects: Effects,
    opts: &DiagnoseOptions,
    sessions: Sessions,
    id: &str,
    symbol: &str,
    truth: f64,
) {
    let (rec, _, files) = session(&effects, 3, sessions.parts, sessions.t_start_c);
    let d = diagnose::diagnose(&rec, &files.opts(opts.clone())).unwrap();
    show(name, &d);
    assert_eq!(d.hypotheses[0].id, id, "{name}: top-ranked hypothesis");
    assert!(
        d.hypotheses[0].accepted,
        "{name}: not accepted: {}",
        d.hypotheses[0].verdict
    );
    let v = param(&d, symbol);
    assert!(
        (v - truth).abs() <= 0.1 * truth.abs(),
        "{name}: {symbol} = {v}, truth {truth}"
    );
    let top = &d.hypotheses[0];
    assert!(
        top.rmse_after < top.rmse_before && top.r2_after > top.r2_before,
        "{name}: held-out fit does not improve"
    );
    assert_eq!(claims(&d), [id], "{name}: nothing else may be claimed");
    nominal_window(name, &d);
    // Where the effect's mechanism has several forms, its own form is the one claimed, or the
    // forms are reported as confounded (the margin is not significant) with it among them.
    if let Some(f) = form_of(&d, id) {
        assert!(
            f.accepted && (f.winner == id || f.confounded && f.runner_up == id),
            "{name}: wrong form claimed: {f:?}"
        );
    }
}

/// The window the diagnosis estimated (the default) on a session simulated with the G1's 0.2 s
/// sensor window: within ±0.05 s (two steps of the scan's fine grid).
fn nominal_window(name: &str, d: &Diagnosis) {
    let sw = d.sensor_window;
    assert!(
        sw.estimated && (sw.window_s - 0.2).abs() <= 0.05,
        "{name}: sensor window {sw:?}"
    );
}

/// The form comparison of the mechanism whose winning or runner-up form is `id`.
fn form_of<'a>(d: &'a Diagnosis, id: &str) -> Option<&'a diagnose::MechanismForms> {
    d.forms.iter().find(|f| f.winner == id || f.runner_up == id)
}

/// Every library term reported as confounded stays in the ranking, not accepted, marked with
/// what it is confounded with (one tied with a term beyond the library stays accepted, the
/// other named in its verdict).
fn confounded_stay_ranked(name: &str, d: &Diagnosis) {
    for c in &d.confounded {
        let h = d.hypotheses.iter().find(|h| h.id == c.dropped);
        let ok = if c.tied {
            h.is_some_and(|h| h.accepted && h.verdict.contains("not told apart from "))
        } else {
            h.is_some_and(|h| !h.accepted && h.verdict.starts_with("confounded with "))
        };
        assert!(
            ok,
            "{name}: {} confounded (tied: {}) but ranked as {h:?}",
            c.dropped, c.tied
        );
    }
}

#[test]
fn thermal_drift_tied_with_the_housing_temperature_stays_claimed_with_the_tie_named() {
    // Parts started at 30, 50, 70 °C with the housings settled with the windings: the housing
    // temperature (a field the library does not read) follows the winding's, and on this session
    // the copper loss × housing temperature explains the drift as well. The data cannot tell the
    // two temperatures apart; the library's physical mechanism (copper resistance follows the
    // winding) stays claimed and the tie is named, with its evidence.
    let mut e = Effects::default();
    e.enable("thermal=0.00393").unwrap();
    let (rec, _, files) = session(&e, 6, 6, &[30.0, 50.0, 70.0]);
    let d = diagnose::diagnose(&rec, &files.opts(refit())).unwrap();
    show("thermal refit seed 6", &d);
    assert_eq!(claims(&d), ["thermal"], "only the drift may be claimed");
    let v = param(&d, "α");
    assert!((v - 0.00393).abs() <= 0.1 * 0.00393, "α = {v}");
    let tie = d
        .confounded
        .iter()
        .find(|c| c.tied && c.dropped == "thermal")
        .unwrap_or_else(|| panic!("no tie named: {:?}", d.confounded));
    assert!(tie.kept.contains("temperature[1]"), "{tie:?}");
    assert!(tie.correlation.abs() >= 0.9, "{tie:?}");
    assert!(
        d.summary
            .contains("the library's physical mechanism, is claimed"),
        "{}",
        d.summary
    );
    confounded_stay_ranked("thermal refit seed 6", &d);
}

#[test]
fn thermal_drift_is_found_against_the_twin() {
    // A warm robot (70 °C windings at the start): the twin's copper loss is 25 °C-based.
    let mut e = Effects::default();
    e.enable("thermal=0.00393").unwrap();
    check_single(
        "thermal",
        e,
        &twin(),
        Sessions {
            t_start_c: &[70.0],
            parts: 3,
        },
        "thermal",
        "α",
        0.00393,
    );
}

#[test]
fn braking_asymmetry_is_found() {
    let mut e = Effects::default();
    e.enable("braking=0.25").unwrap();
    // The matrix row's 144 trials, both modes (seed 3: twin −4.2 %, refit +0.5 %).
    check_single("braking", e, &twin(), DOUBLE, "braking", "r", 0.25);
    check_single("braking refit", e, &refit(), DOUBLE, "braking", "r", 0.25);
}

#[test]
fn bus_loss_is_found() {
    let mut e = Effects::default();
    e.enable("bus_loss=0.05").unwrap();
    check_single("bus_loss", e, &refit(), SMALL, "bus_loss", "R_bus", 0.05);
}

#[test]
fn sensor_latency_is_found() {
    let mut e = Effects::default();
    e.enable("latency=0.3").unwrap();
    check_single("latency", e, &refit(), SMALL, "latency", "L", 0.3);
}

#[test]
fn off_grid_sensor_latency_is_refined_between_scan_points() {
    // 0.27 s lies between the 0.05 s scan points: the fine scan and the parabola refine it.
    let mut e = Effects::default();
    e.enable("latency=0.27").unwrap();
    let (rec, _, files) = session(&e, 6, 3, &[30.0]);
    let d = diagnose::diagnose(&rec, &files.opts(refit())).unwrap();
    show("latency 0.27", &d);
    assert_eq!(claims(&d), ["latency"]);
    nominal_window("latency 0.27", &d);
    let l = param(&d, "L");
    assert!((l - 0.27).abs() <= 0.01, "L = {l}");
}

#[test]
fn payload_is_found_at_the_torque_level() {
    let e = Effects {
        payload: Some(Payload {
            mass_kg: 0.5,
            com_m: [0.1, 0.0, 0.0],
        }),
        ..Effects::default()
    };
    check_single("payload", e, &refit(), SMALL, "payload", "m", 0.5);
}

#[test]
fn thermal_drift_is_found_by_a_refit_across_temperatures() {
    // Without the twin a refitted b_i absorbs any constant temperature offset: the drift is
    // identifiable only when the session spans temperatures (parts started at 30, 50, 70 °C).
    let mut e = Effects::default();
    e.enable("thermal=0.00393").unwrap();
    let sessions = Sessions {
        t_start_c: &[30.0, 50.0, 70.0],
        parts: 6,
    };
    check_single(
        "thermal refit",
        e,
        &refit(),
        sessions,
        "thermal",
        "α",
        0.00393,
    );
}

#[test]
fn gear_friction_is_found_against_the_twin() {
    // μ·Σ|τq̇| = μ·Σ(τq̇ − 2·min(τq̇, 0)): a refitted a_i and the braking term span most of it,
    // so a refit rarely resolves it (the matrix in docs/diagnosis-results.md); against the twin μ is recovered. On the
    // matrix row's 144 trials.
    let mut e = Effects::default();
    e.enable("gear_friction=0.15").unwrap();
    check_single(
        "gear_friction",
        e,
        &twin(),
        DOUBLE,
        "gear_friction",
        "μ",
        0.15,
    );
}

#[test]
fn drive_loss_is_found() {
    let mut e = Effects::default();
    e.enable("drive_loss=0.5").unwrap();
    check_single(
        "drive_loss",
        e,
        &refit(),
        SMALL,
        "drive_loss",
        "V_drop",
        0.5,
    );
}

#[test]
fn stribeck_friction_is_found() {
    let mut e = Effects::default();
    e.enable("stribeck=10").unwrap();
    check_single("stribeck", e, &refit(), DOUBLE, "stribeck", "F_s", 10.0);
}

#[test]
fn balance_leak_is_found() {
    // The default: 500/9 W/(rad/s)² with a continuous 0.05 rad/s body sway per axis.
    let mut e = Effects::default();
    e.enable("balance_leak").unwrap();
    check_single(
        "balance_leak",
        e,
        &refit(),
        DOUBLE,
        "balance_leak",
        "k_leak",
        500.0 / 9.0,
    );
}

#[test]
fn bus_loss_from_total_electrical_power_wins_over_the_current_form() {
    // The bus carries P_elec / V_bus; the library's older form is (Σ|τ_i|/K_i)². Both are
    // scored as forms of one mechanism: the right one wins and only it is claimed. The arm's net
    // electrical power is tens of W, so at a realistic 50 mΩ the loss is a few mW, far below
    // what 1 Hz readings resolve: the test uses a deliberately strong 10 Ω.
    let mut e = Effects::default();
    e.enable("bus_power=10").unwrap();
    check_single("bus_power", e, &twin(), SMALL, "bus_power", "R_bus", 10.0);
}

#[test]
fn electronics_loss_per_newton_metre_is_found_against_the_twin() {
    let mut e = Effects::default();
    e.enable("electronics_nm=0.5").unwrap();
    check_single(
        "electronics_nm",
        e,
        &twin(),
        SMALL,
        "electronics_nm",
        "k_el",
        0.5,
    );
}

/// The forms of the drive-electronics mechanism on a refit: the mechanism is claimed (its
/// winning form's parameter within 10 %), its form left open when the margin is not
/// significant — never one form claimed on a margin the data do not support.
fn electronics_forms_on_a_refit(effect: &str, seed: u64, truth_id: &str, truth: Option<f64>) {
    let mut e = Effects::default();
    e.enable(effect).unwrap();
    let (rec, _, files) = session(&e, seed, 3, &[30.0]);
    let d = diagnose::diagnose(&rec, &files.opts(refit())).unwrap();
    show(&format!("{effect} seed {seed} refit"), &d);
    let ids = ["drive_loss", "electronics_nm"];
    let c = claims(&d);
    assert!(c.len() == 1 && ids.contains(&c[0].as_str()), "claims {c:?}");
    let f = form_of(&d, truth_id).expect("forms compared");
    assert!(
        f.accepted && f.confounded && ids.contains(&f.winner.as_str()),
        "{f:?}"
    );
    assert!(f.p_value >= 1e-3, "{f:?}");
    assert!(
        d.summary
            .contains("Form: drive-electronics loss: confounded — per-Nm or per-ampere")
            || d.summary
                .contains("Form: drive-electronics loss: confounded — per-ampere or per-Nm"),
        "{}",
        d.summary
    );
    assert!(d.summary.contains("(form: confounded — "), "{}", d.summary);
    // The true form's own fit, reported as evidence beside the winner's.
    let i = usize::from(f.winner != truth_id);
    assert!(f.params.iter().all(|p| p.len() == 1), "{f:?}");
    if let Some(truth) = truth {
        let v = f.params[i][0].value;
        assert!((v - truth).abs() <= 0.1 * truth, "{truth_id}: {v}");
    }
    // Both forms' parameters in the report's JSON.
    let json = serde_json::to_string(&d).unwrap();
    assert!(json.contains("\"confounded\":true"), "{json:.200}");
}

#[test]
fn electronics_forms_a_refit_cannot_tell_are_reported_as_confounded() {
    // Per-Nm truth, seed 3: per-Nm wins by 1.4 % (p ≈ 0.09), k_el within 10 %.
    electronics_forms_on_a_refit("electronics_nm=0.5", 3, "electronics_nm", Some(0.5));
    // Per-ampere truth, seed 6: per-Nm wins by 0.3 % (p ≈ 0.44); the per-ampere fit's V_drop
    // is +12 % (1.8 s.e.; the matrix in docs/diagnosis-results.md), so only the confounded form is asserted.
    electronics_forms_on_a_refit("drive_loss=0.5", 6, "drive_loss", None);
}

/// The discovered terms of a session; exactly one expected.
fn only_discovery(name: &str, d: &Diagnosis) -> diagnose::Discovery {
    let found = d
        .discovery
        .as_ref()
        .map(|r| r.accepted.clone())
        .unwrap_or_default();
    assert!(
        d.accepted.is_empty(),
        "{name}: library claims {:?}",
        claims(d)
    );
    assert_eq!(found.len(), 1, "{name}: claims {:?}", claims(d));
    let t = found.into_iter().next().unwrap();
    assert!(
        t.after.r2 > t.before.r2 && t.after.rmse_w < t.before.rmse_w,
        "{name}: held-out fit does not improve: {t:?}"
    );
    t
}

#[test]
fn friction_following_the_housing_temperature_is_discovered_on_that_field() {
    // P += k·Σ(T_housing,i − 25 °C)·|q̇_i|, T_housing = motor_state[k].temperature[1], a field the
    // library never reads. Windings started at 30, 50, 70 °C and housings at unrelated 50, 30,
    // 40, 35 °C (a motor worked hard just before has a hot winding in a cool housing), so the two
    // temperatures can be told apart.
    let mut e = Effects::default();
    e.enable("housing_friction=0.05").unwrap();
    let (rec, _, files) = session_with(&e, 3, 6, &[30.0, 50.0, 70.0], &[50.0, 30.0, 40.0, 35.0]);
    let d = diagnose::diagnose(&rec, &files.opts(refit())).unwrap();
    show("housing_friction", &d);
    let t = only_discovery("housing_friction", &d);
    // The joints' own housings (one per joint) or one of them: the housings move together.
    assert!(
        !t.fields.is_empty()
            && t
                .fields
                .iter()
                .all(|f| f.starts_with("/lowstate.motor_state[") && f.ends_with("].temperature[1]")),
        "{t:?}"
    );
    assert!(t.name.contains("Coulomb"), "{}", t.name);
    let k = t.params[0].value;
    assert!((k - 0.05).abs() <= 0.005, "k = {k}");
}

/// Seed of the related-start housing session on which the two temperatures tie.
const RELATED_HOUSING_SEED: u64 = 3;

#[test]
fn housing_friction_with_housings_following_their_windings_is_claimed_with_its_field_confounded() {
    // The same friction ∝ housing temperature[1], but as on a real robot: the housings start
    // settled with their windings (30, 50, 70 °C over the parts), so housing and winding
    // temperatures move together and the Coulomb loss × either fits as well. One mechanism is
    // claimed with its field confounded — both temperature fields named, with the evidence —
    // never a wrong field alone, and never a second term.
    let mut e = Effects::default();
    e.enable("housing_friction=0.05").unwrap();
    let (rec, _, files) = session(&e, RELATED_HOUSING_SEED, 6, &[30.0, 50.0, 70.0]);
    let d = diagnose::diagnose(&rec, &files.opts(refit())).unwrap();
    show("housing_friction related start", &d);
    let t = only_discovery("housing_friction related start", &d);
    assert!(
        t.name.contains("Coulomb")
            && t.name.contains("temperature[0]")
            && t.name.contains("temperature[1]")
            && t.name.contains("confounded"),
        "{}",
        t.name
    );
    let json = serde_json::to_value(&d).unwrap();
    let found = &json["discovery"]["accepted"][0];
    let tied = found["tied"].as_array().cloned().unwrap_or_default();
    let mut named: Vec<String> = t.fields.clone();
    for o in &tied {
        for f in o["fields"].as_array().into_iter().flatten() {
            named.extend(f.as_str().map(String::from));
        }
        // Not significantly worse than the found term, by the acceptance test's α, and a
        // rival by structure or collinearity; both RMSEs and its own parameter given.
        let p = o["p_value"].as_f64().unwrap_or(f64::NAN);
        assert!(p >= 1e-3, "{o}");
        let r = o["correlation"].as_f64().unwrap_or(f64::NAN);
        assert!(o["same_structure"] == true || r >= 0.9, "{o}");
        let rmse = o["rmse_w"].as_array().expect("rmse_w");
        assert!(
            rmse.len() == 2 && rmse.iter().all(|v| v.as_f64().is_some_and(|v| v > 0.0)),
            "{o}"
        );
        let p0 = &o["params"][0];
        assert!(p0["value"].is_f64() && p0["std_err"].is_f64(), "{o}");
    }
    let temp = |i: u8| {
        named.iter().any(|f| {
            f.starts_with("/lowstate.motor_state[") && f.ends_with(&format!("].temperature[{i}]"))
        })
    };
    assert!(temp(0) && temp(1), "fields named: {named:?}");
    assert!(
        d.summary.contains("Not told apart from it: "),
        "{}",
        d.summary
    );
    found_term_shown(&d);
    // The report lists every rival with its evidence.
    let dir = tempfile::tempdir().unwrap();
    diagnose::write_report(dir.path(), &d).unwrap();
    let md = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    let section = md
        .split("### Not told apart from a found term")
        .nth(1)
        .unwrap_or_else(|| panic!("no rival section in the report"));
    let rows = section
        .lines()
        .skip_while(|l| !l.starts_with("|---"))
        .skip(1)
        .take_while(|l| l.starts_with("| "))
        .count();
    assert_eq!(rows, tied.len(), "{section}");
}

/// A found term is shown like a hypothesis: diagnosis.json carries its name, form, field(s),
/// parameter ± s.e. and held-out before/after; the replay carries the located field's value per
/// reading (plotted beside the residual in `--save`) and marks the trials that carry it.
fn found_term_shown(d: &Diagnosis) {
    let json: serde_json::Value = serde_json::to_value(d).unwrap();
    let t = &json["discovery"]["accepted"][0];
    for key in ["name", "form"] {
        assert!(t[key].as_str().is_some_and(|s| !s.is_empty()), "{key}: {t}");
    }
    let field = t["fields"][0].as_str().expect("field");
    let p = &t["params"][0];
    assert!(
        p["value"].is_f64() && p["std_err"].as_f64().is_some_and(|v| v > 0.0),
        "{p}"
    );
    for q in ["before", "after"] {
        assert!(t[q]["r2"].is_f64() && t[q]["rmse_w"].is_f64(), "{q}: {t}");
    }
    assert!(t["after"]["r2"].as_f64() > t["before"]["r2"].as_f64());
    let located = &json["replay"]["located"][0];
    assert_eq!(located["name"].as_str(), Some(field));
    assert_eq!(
        located["values"].as_array().map(Vec::len),
        Some(d.replay.t.len()),
        "one value per reading"
    );
    assert_eq!(d.replay.found_w.len(), d.replay.t.len());
    assert!(
        d.replay.highlighted.iter().any(|h| h
            .reason
            .starts_with("carries what was found beyond the library")),
        "{:?}",
        d.replay.highlighted
    );
}

/// The simulated session's junk fields are left out of discovery by the data-driven rules,
/// each with its reason, and nothing physical is: the message tick is a counter, the CRCs are
/// hash-like, and no temperature, voltage, fan or joint field is left out except as constant (a
/// heading that drifts at a steady rate may go as a clock: it duplicates session time).
fn junk_fields_left_out(d: &Diagnosis) {
    let r = d.discovery.as_ref().expect("discovery ran");
    for e in &r.excluded {
        eprintln!("  left out: {} — {}", e.name, e.reason);
    }
    let reason = |name: &str| {
        r.excluded
            .iter()
            .find(|e| e.name == name)
            .map(|e| e.reason.as_str())
    };
    assert!(
        reason("/lowstate.tick").is_some_and(|r| r.starts_with("counter")),
        "tick: {:?}",
        reason("/lowstate.tick")
    );
    for crc in ["/lowstate.crc", "/arm_sdk.crc"] {
        assert!(
            reason(crc).is_some_and(|r| r.starts_with("hash")),
            "{crc}: {:?}",
            reason(crc)
        );
    }
    for e in r
        .excluded
        .iter()
        .filter(|e| !e.reason.starts_with("constant"))
    {
        assert!(
            !["temperature", "vol", "fan_state", "q", "dq", "tau_est"]
                .iter()
                .any(|w| e.name.ends_with(w) || e.name.contains(&format!(".{w}["))),
            "physical field left out: {e:?}"
        );
    }
    assert!(
        d.summary
            .contains("Left out of discovery as counters, clocks or hash-like: "),
        "{}",
        d.summary
    );
}

#[test]
fn housing_friction_with_default_start_temperatures_is_a_coulomb_excess_not_gear_friction() {
    // What holds without special start temperatures (windings at 30 °C, housings settled with
    // them): the housings barely change over the session — every arm housing's recorded
    // temperature[1] (whole °C) reads the same value in every reading window, so discovery leaves
    // it out as constant and no field can carry the effect. k·(T_housing − 25 °C)·|q̇| is then a
    // constant Coulomb excess. A refit absorbs it into c_i and claims nothing. Against the twin,
    // the library's load-dependent gear friction (and the terms after it) explains part of it,
    // but the plain Coulomb excess fits the held-out trials significantly better: each library
    // term is reported as confounded with it, not claimed, and the excess is what is found.
    let mut e = Effects::default();
    e.enable("housing_friction=0.05").unwrap();
    let (rec, _, files) = session(&e, 3, 6, &[30.0]);
    let d = diagnose::diagnose(&rec, &files.opts(refit())).unwrap();
    show("housing_friction default start refit", &d);
    assert!(claims(&d).is_empty(), "refit: {:?}", claims(&d));
    let d = diagnose::diagnose(&rec, &files.opts(twin())).unwrap();
    show("housing_friction default start twin", &d);
    let r = d.discovery.as_ref().expect("discovery ran");
    // The recorded housing temperature: one whole-°C value, the same in every reading window.
    let housing: Vec<f64> = (0..7)
        .map(|i| {
            let name = format!("/lowstate.motor_state[{}].temperature[1]", 15 + i);
            let e = r.excluded.iter().find(|e| e.name == name);
            let v = e
                .filter(|e| e.reason.starts_with("constant"))
                .and_then(|e| e.reason.rsplit('(').next())
                .and_then(|v| v.trim_end_matches(')').parse::<f64>().ok());
            v.unwrap_or_else(|| panic!("{name} not left out as constant: {e:?}"))
        })
        .collect();
    assert!(
        housing.iter().all(|&t| t == housing[0]),
        "housings: {housing:?}"
    );
    assert!(
        d.accepted.is_empty(),
        "twin: library claims {:?}",
        claims(&d)
    );
    assert!(
        d.hypotheses
            .iter()
            .any(|h| h.id == "gear_friction" && h.verdict.starts_with("confounded with ")),
        "gear_friction not reported as confounded"
    );
    assert!(
        d.confounded.iter().any(|c| c.dropped == "gear_friction"),
        "{:?}",
        d.confounded
    );
    assert!(d.summary.contains("Confounded: "), "{}", d.summary);
    confounded_stay_ranked("housing_friction default start twin", &d);
    let t = only_discovery("housing_friction default start twin", &d);
    assert!(
        t.name.contains("Coulomb") && t.fields.is_empty() && t.params.len() == 1,
        "{t:?}"
    );
    // The true excess per joint is 0.05·(T − 25 °C) W·s/rad with T within ±0.5 °C of the
    // recorded whole degree; the found excess lies in that band (± 2.5 s.e.).
    let (k, se) = (t.params[0].value, t.params[0].std_err);
    let (lo, hi) = (
        0.05 * (housing[0] - 0.5 - 25.0),
        0.05 * (housing[0] + 0.5 - 25.0),
    );
    assert!(
        k >= lo - 2.5 * se && k <= hi + 2.5 * se,
        "k = {k} ± {se}, band [{lo}, {hi}]"
    );
    let json = serde_json::to_value(&d).unwrap();
    assert!(
        json["confounded"].as_array().is_some_and(|c| c
            .iter()
            .any(|c| c["dropped"] == "gear_friction"
                && c["correlation"].is_f64()
                && c["tied"].is_boolean())),
        "{}",
        json["confounded"]
    );
}

#[test]
fn a_rail_load_switching_with_a_board_status_field_is_discovered() {
    // A 3 W fan on the main-board rail, on and off during the session; the board's fan_state[1]
    // says when. Nothing in the library follows a board field.
    let mut e = Effects::default();
    e.enable("fan_load=3").unwrap();
    for (mode, opts) in [("refit", refit()), ("twin", twin())] {
        let (rec, _, files) = session(&e, 3, 3, &[30.0]);
        let d = diagnose::diagnose(&rec, &files.opts(opts)).unwrap();
        show(&format!("fan_load {mode}"), &d);
        junk_fields_left_out(&d);
        found_term_shown(&d);
        let t = only_discovery("fan_load", &d);
        assert_eq!(
            t.fields,
            ["/lf/mainboardstate.fan_state[1]"],
            "{mode}: {t:?}"
        );
        // Step form: P_on [W]; linear form: ΔP over the field's range [W].
        let p = &t.params[0];
        assert!(
            (p.value - 3.0).abs() <= 0.3,
            "{mode}: {} = {}",
            p.symbol,
            p.value
        );
    }
}

/// A library mechanism in a one-sided form (issue 28): a drive-electronics loss drawn only while
/// a joint drives (τq̇ > 0). The library's two-sided drive-loss forms do not fit it (before the
/// generated family nothing was claimed); the family's driving-current split does, and the claim
/// says which library mechanism it is a form of, with V_drop near the truth.
#[test]
fn a_one_sided_drive_loss_is_found_as_the_drive_loss_of_the_driving_joints() {
    let mut e = Effects::default();
    e.enable("driving_loss=1.0").unwrap();
    let (rec, _, files) = session(&e, 3, 3, &[30.0]);
    let d = diagnose::diagnose(&rec, &files.opts(refit())).unwrap();
    show("driving_loss refit", &d);
    let t = only_discovery("driving_loss", &d);
    assert_eq!(t.mechanism.as_deref(), Some("drive_loss"), "{t:?}");
    assert!(t.name.contains("driving joints"), "{}", t.name);
    let k = t.params[0].value;
    assert!((k - 1.0).abs() <= 0.15, "V_drop = {k}");
}

#[test]
fn two_equal_fans_on_two_board_fields_are_both_claimed_not_tied() {
    // Two 3 W fans on the main-board rail, switching independently; fan_state[0] and [1] say
    // when. The two loads have the same structure on two fields, so when the first is found the
    // other cannot be shown to fit worse: a tie by the rival rule. Tried beside the first, it
    // passes on its own — a second effect, to be claimed, not named as a confounder.
    let mut e = Effects::default();
    e.enable("fan_load=3").unwrap();
    e.enable("fan0_load=3").unwrap();
    let (rec, _, files) = session(&e, 3, 6, &[30.0]);
    let d = diagnose::diagnose(&rec, &files.opts(refit())).unwrap();
    show("two fans", &d);
    assert!(d.accepted.is_empty(), "library claims {:?}", claims(&d));
    let found = d.discovery.as_ref().unwrap().accepted.clone();
    let mut fields: Vec<String> = found.iter().flat_map(|t| t.fields.clone()).collect();
    fields.sort();
    assert_eq!(
        fields,
        [
            "/lf/mainboardstate.fan_state[0]",
            "/lf/mainboardstate.fan_state[1]"
        ],
        "claims {:?}",
        claims(&d)
    );
    for t in &found {
        assert!(
            t.tied.iter().all(|r| !r.fields[0].contains("fan_state")),
            "{}: the other fan named as a tie: {:?}",
            t.name,
            t.tied.iter().map(|r| &r.name).collect::<Vec<_>>()
        );
        let p = &t.params[0];
        assert!(
            (p.value - 3.0).abs() <= 0.3,
            "{}: {} = {}",
            t.name,
            p.symbol,
            p.value
        );
    }
}

#[test]
fn unequal_joint_friction_is_found_per_joint_against_the_twin() {
    // Coulomb excess F·w_i per joint (w = JOINT_FRICTION_PATTERN): against the twin it is a
    // per-joint correction of c_i; a refit absorbs it into c_i (nothing to claim).
    let mut e = Effects::default();
    e.enable("joint_friction=1").unwrap();
    let (rec, _, files) = session(&e, 3, 3, &[30.0]);
    let d = diagnose::diagnose(&rec, &files.opts(twin())).unwrap();
    show("joint_friction twin", &d);
    let t = only_discovery("joint_friction", &d);
    confounded_stay_ranked("joint_friction twin", &d);
    assert!(t.name.contains("Coulomb"), "{t:?}");
    // Joints the data identify (s.e. ≤ 4 % of the value) are reported one by one, each within
    // 10 % of its excess F·w_i; the rest share one pooled coefficient, which lies within the
    // range of their true excesses (± 2.5 s.e.). The well-moved shoulder pitch (0), elbow (3)
    // and wrist pitch (5) must be among the identified.
    let w = g1viz::sim::JOINT_FRICTION_PATTERN;
    let mut identified = Vec::new();
    for p in &t.params {
        eprintln!("  {} = {} ± {} ({})", p.symbol, p.value, p.std_err, p.name);
        if let Some(i) = p
            .symbol
            .strip_prefix("k_")
            .and_then(|i| i.parse::<usize>().ok())
        {
            assert!(p.std_err <= 0.04 * p.value.abs(), "{p:?}");
            assert!(
                (p.value - w[i]).abs() <= 0.1 * w[i],
                "{}: {} vs {}",
                p.name,
                p.value,
                w[i]
            );
            identified.push(i);
        }
    }
    let pooled: Vec<&diagnose::Param> =
        t.params.iter().filter(|p| p.symbol == "k_pooled").collect();
    assert!(pooled.len() <= 1 && identified.len() + pooled.len() == t.params.len());
    if let Some(p) = pooled.first() {
        let rest: Vec<f64> = (0..7)
            .filter(|i| !identified.contains(i))
            .map(|i| w[i])
            .collect();
        let (lo, hi) = rest
            .iter()
            .fold((f64::INFINITY, 0.0f64), |a, &v| (a.0.min(v), a.1.max(v)));
        assert!(
            p.value >= lo - 2.5 * p.std_err && p.value <= hi + 2.5 * p.std_err,
            "{p:?} vs {rest:?}"
        );
    }
    let d = diagnose::diagnose(&rec, &files.opts(refit())).unwrap();
    show("joint_friction refit", &d);
    assert!(claims(&d).is_empty(), "refit: {:?}", claims(&d));
}

#[test]
fn two_effects_at_once_are_both_found() {
    let mut e = Effects::default();
    e.enable("braking=0.25").unwrap();
    e.enable("latency=0.3").unwrap();
    let (rec, _, files) = session(&e, 4, 3, &[30.0]);
    let d = diagnose::diagnose(&rec, &files.opts(refit())).unwrap();
    show("braking + latency", &d);
    let ids: Vec<&str> = d.accepted.iter().map(|h| h.id.as_str()).collect();
    assert!(
        ids.contains(&"braking") && ids.contains(&"latency"),
        "accepted {ids:?}"
    );
    assert!(
        (param(&d, "r") - 0.25).abs() <= 0.025,
        "r = {}",
        param(&d, "r")
    );
    assert!(
        (param(&d, "L") - 0.3).abs() <= 0.03,
        "L = {}",
        param(&d, "L")
    );
    assert!(d.final_model.after.r2 > d.final_model.before.r2);
}

#[test]
fn a_sensor_window_other_than_the_nominal_is_estimated_and_nothing_claimed() {
    // Power sensors averaging 0.5 s instead of the G1's 0.2 s; nothing concealed. The window is
    // estimated by default (0.025 s fine grid): within ±0.05 s.
    let (rec, _, files) = session_window(&Effects::default(), 3, 3, &[30.0], &[], 0.5);
    for (mode, opts) in [("refit", refit()), ("twin", twin())] {
        assert_eq!(opts.sensor_window_s, None, "estimated by default");
        let d = diagnose::diagnose(&rec, &files.opts(opts)).unwrap();
        show(&format!("W = 0.5 s {mode}"), &d);
        let sw = d.sensor_window;
        assert!(sw.estimated, "{sw:?}");
        assert!(
            (sw.window_s - 0.5).abs() <= 0.05,
            "{mode}: W = {}",
            sw.window_s
        );
        assert!(
            d.summary
                .contains("Sensor window: each reading averages the")
        );
        assert!(claims(&d).is_empty(), "{mode}: claimed {:?}", claims(&d));
    }
    // Given, the window is used as it is and says so.
    let given = DiagnoseOptions {
        sensor_window_s: Some(0.5),
        ..refit()
    };
    let d = diagnose::diagnose(&rec, &files.opts(given)).unwrap();
    assert!(!d.sensor_window.estimated && d.sensor_window.window_s == 0.5);
    assert!(
        claims(&d).is_empty(),
        "given 0.5 s: claimed {:?}",
        claims(&d)
    );
}

#[test]
fn null_sessions_accept_nothing() {
    for seed in [11, 12, 13, 14, 15] {
        let (rec, _, files) = session(&Effects::default(), seed, 3, &[30.0]);
        for (mode, opts) in [("refit", refit()), ("twin", twin())] {
            let d = diagnose::diagnose(&rec, &files.opts(opts)).unwrap();
            show(&format!("null seed {seed} {mode}"), &d);
            nominal_window(&format!("null seed {seed} {mode}"), &d);
            assert!(
                claims(&d).is_empty(),
                "seed {seed} {mode}: claimed {:?}",
                claims(&d)
            );
        }
    }
}

#[test]
fn harness_drag_outside_the_library_is_located() {
    // A stiff harness (15 W·s/rad): the simulator's default 4 W·s/rad adds ~0.1 W to an elbow
    // trial's mean power, below what ~70 trials resolve (the matrix in docs/diagnosis-results.md reports both).
    let mut e = Effects::default();
    e.enable("harness_drag=15").unwrap();
    let (rec, truth, files) = session(&e, 5, 3, &[30.0]);
    // Against the twin: a refitted base model absorbs most of the drag into the elbow's Coulomb
    // and interaction terms (the matrix shows both).
    let d = diagnose::diagnose(&rec, &files.opts(twin())).unwrap();
    show("harness_drag", &d);
    let top = d.unexplained.first().expect("a correlate");
    assert!(top.significant, "{top:?}");
    assert!(
        top.feature.starts_with("left_elbow_joint")
            && (top.feature.contains("position") || top.feature.contains("speed")),
        "top correlate {top:?}"
    );
    // The trials it names moved the elbow (truth windows, matched by time).
    for &t in &top.trials {
        let h = d
            .replay
            .highlighted
            .iter()
            .find(|h| h.trial == t)
            .expect("named trial is highlighted");
        let moved = truth
            .iter()
            .find(|w| (w.1 - h.t_start).abs() < 0.5)
            .map(|w| w.0.contains(&3))
            .unwrap_or(false);
        assert!(
            moved,
            "trial {t} named for the elbow correlate did not move the elbow"
        );
    }
}

fn shared(name: &str) -> Option<PathBuf> {
    common::shared_recording(name)
}

#[test]
fn shared_recordings_claim_no_missing_physics() {
    for name in ["g1_smoke.mcap", "g1_holdout.mcap"] {
        let Some(path) = shared(name) else {
            continue;
        };
        let rec =
            signals::load_recording(&path, &SignalMap::g1_left_arm(), &OpenOptions::default())
                .unwrap();
        // The independent generator used Unitree's official URDF with hands.
        let urdf = path
            .parent()
            .unwrap()
            .join("../g1_description/g1_29dof_with_hand_rev_1_0.urdf");
        if !urdf.exists() {
            common::skip(&format!(
                "{} not found (the torque level would fall back to the built-in URDF)",
                urdf.display()
            ));
            continue;
        }
        for (mode, opts) in [("refit", refit()), ("twin", twin())] {
            let opts = DiagnoseOptions {
                urdf: Some(urdf.clone()),
                ..opts
            };
            let d = diagnose::diagnose(&rec, &opts).unwrap();
            show(&format!("{name} {mode}"), &d);
            assert!(
                claims(&d).is_empty(),
                "{name} {mode}: claimed {:?}",
                claims(&d)
            );
        }
    }
}

/// `diagnose --counterpart`: the twin re-run on the recording's own commands and timeline
/// (`simulate --like`). A payload the twin lacks shows as a torque difference far above the
/// null session's (which is sensor noise only); a counterpart on another timeline is refused.
#[test]
fn counterpart_comparison_shows_what_the_twin_lacks() {
    use g1viz::diagnose::compare_counterpart;
    let dir = tempfile::tempdir().unwrap();
    let map = SignalMap::g1_left_arm();
    let load =
        |p: &std::path::Path| signals::load_recording(p, &map, &OpenOptions::default()).unwrap();
    // One smoke session has ≈ 20 trials: enough for 5 folds (the hypothesis scoring is not under
    // test here, the comparison is).
    let five_fold_twin = || DiagnoseOptions { folds: 5, ..twin() };
    let mut shoulder_rms = Vec::new();
    for (name, effects) in [
        ("null", Effects::default()),
        ("payload", {
            let mut e = Effects::default();
            e.enable("payload=0.5").unwrap();
            e
        }),
    ] {
        let real_path = dir.path().join(format!("{name}.mcap"));
        let cfg = SimConfig {
            preset: Preset::Smoke,
            seed: 21,
            effects,
            progress: false,
            ..SimConfig::default()
        };
        sim::simulate(&cfg, &real_path).unwrap();
        let real = load(&real_path);
        let twin_path = dir.path().join(format!("{name}_twin.mcap"));
        let twin_cfg = SimConfig {
            seed: 22,
            progress: false,
            ..SimConfig::default()
        };
        sim::simulate_like(&real, &twin_cfg, &twin_path).unwrap();
        let counterpart_rec = load(&twin_path);
        let mut d = diagnose::diagnose(&real, &five_fold_twin()).unwrap();
        let c = compare_counterpart(&real, &counterpart_rec, &d).unwrap();
        // The two files read side by side (streamed) give the same figures, bit for bit, and
        // the same per-sample series when asked for them.
        let file = |p: &std::path::Path| g1viz::session::SessionFile {
            path: p.to_path_buf(),
            map: map.clone(),
            read: OpenOptions::default(),
            spill: Default::default(),
        };
        for keep in [true, false] {
            let s = g1viz::diagnose::compare_counterpart_files(
                &file(&real_path),
                &file(&twin_path),
                &d,
                keep,
            )
            .unwrap();
            let mut want = c.clone();
            if !keep {
                want.series.tau_t.clear();
                want.series.tau_diff.clear();
            }
            assert_eq!(
                format!("{want:?}"),
                format!("{s:?}"),
                "{name}, series {keep}"
            );
            assert_eq!(
                s.series.tau_t.len(),
                if keep { s.matched_samples } else { 0 }
            );
        }
        assert_eq!(
            c.matched_samples,
            real.state.t.len(),
            "{name}: same timeline"
        );
        assert_eq!(c.joints.len(), 7);
        assert!(c.power_r2.is_finite() && c.worst_trials.len() == 5, "{c:?}");
        shoulder_rms.push(c.joints[0].tau_rms_nm);
        d.attach_counterpart(c);
        assert!(d.summary.contains("Counterpart"), "{}", d.summary);
        let json = serde_json::to_string(&d).unwrap();
        assert!(json.contains("\"counterpart\""));
    }
    // Null: both sides carry 0.05 Nm of torque noise → ≈ 0.07 Nm rms; a 0.5 kg payload at the
    // hand adds its gravity torque (≥ 0.5 kg · 9.81 m/s² · 0.1 m ≈ 0.5 Nm when the arm is level).
    assert!(shoulder_rms[0] < 0.15, "null: {shoulder_rms:?}");
    assert!(shoulder_rms[1] > 5.0 * shoulder_rms[0], "{shoulder_rms:?}");

    // A counterpart of another session does not share the timeline.
    let other = dir.path().join("other.mcap");
    let cfg = SimConfig {
        preset: Preset::Smoke,
        seed: 23,
        progress: false,
        ..SimConfig::default()
    };
    sim::simulate(&cfg, &other).unwrap();
    let real = load(&dir.path().join("null.mcap"));
    let d = diagnose::diagnose(&real, &five_fold_twin()).unwrap();
    let err = compare_counterpart(&real, &load(&other), &d).unwrap_err();
    assert!(err.to_string().contains("simulate --like"), "{err}");
    let file = |p: std::path::PathBuf| g1viz::session::SessionFile {
        path: p,
        map: map.clone(),
        read: OpenOptions::default(),
        spill: Default::default(),
    };
    let err = g1viz::diagnose::compare_counterpart_files(
        &file(dir.path().join("null.mcap")),
        &file(other.clone()),
        &d,
        false,
    )
    .unwrap_err();
    assert_eq!(
        err.to_string(),
        compare_counterpart(&real, &load(&other), &d)
            .unwrap_err()
            .to_string()
    );
}

/// Parts started at descending states of charge (sessions through a day, the pack running down
/// between them): the supply voltage falls from part to part as session time rises.
const SOC_DESCENDING: [f64; 3] = [0.95, 0.6, 0.3];
/// Parts started at states of charge in no order with time: the voltage does not follow
/// session time from part to part.
const SOC_SHUFFLED: [f64; 6] = [0.95, 0.3, 0.75, 0.5, 0.6, 0.4];

/// Smoke sessions with `battery`, one per start charge in `soc` (joined in that order).
fn battery_session(
    effects: &Effects,
    seed: u64,
    battery: sim::Battery,
    soc: &'static [f64],
) -> (Recording, TruthTrials, Files) {
    session_cfg(effects, seed, soc.len() as u64, &|part, cfg| {
        cfg.battery = battery;
        cfg.soc_start = Some(soc[part as usize]);
    })
}

/// The recorded supply voltages (the writer's fields and units): the motors' `vol` [V], the
/// main board's rail voltage `value[0]` [V], the BMS pack voltage [mV] and cell voltages [mV].
/// Volts per unit of the field, or `None` for any other field.
fn volts_per_unit(field: &str) -> Option<f64> {
    let motor = field.starts_with("/lowstate.motor_state[") && field.ends_with("].vol");
    if motor || field == "/lf/mainboardstate.value[0]" {
        Some(1.0)
    } else if field == "/lf/bmsstate.bmsvoltage[0]" {
        Some(1e-3)
    } else if field.starts_with("/lf/bmsstate.cell_vol[") {
        Some(13.0 * 1e-3)
    } else {
        None
    }
}

/// Forms of a found term: the fields each follows and, on a supply voltage, its per-volt
/// coefficient k ± s.e. [W/(V·A)].
type Forms = Vec<(Vec<String>, Option<(f64, f64)>)>;

/// The one discovered term of a switching-loss session, and every form the data cannot tell
/// from it (itself first) as (fields, k ± s.e. in W/(V·A) when the field is a supply voltage).
fn switching_forms(name: &str, d: &Diagnosis) -> (diagnose::Discovery, Forms) {
    eprintln!("  claims: {:?}", claims(d));
    let t = only_discovery(name, d);
    let per_volt = |fields: &[String], params: &[diagnose::Param]| {
        let u = fields.first().and_then(|f| volts_per_unit(f))?;
        let k = params.iter().find(|p| p.symbol == "k")?;
        Some((k.value / u, k.std_err / u))
    };
    let mut forms = vec![(t.fields.clone(), per_volt(&t.fields, &t.params))];
    for s in &t.tied {
        eprintln!(
            "    or {:?}: held-out RMSE {:.4} vs {:.4} W, p(found better) {:.2}, r {:.3}, {:?}",
            s.fields,
            s.rmse_w[1],
            s.rmse_w[0],
            s.p_value,
            s.correlation,
            per_volt(&s.fields, &s.params)
        );
        forms.push((s.fields.clone(), per_volt(&s.fields, &s.params)));
    }
    assert!(
        t.name.contains("drive-electronics loss per ampere"),
        "{name}: {}",
        t.name
    );
    // The library's per-ampere loss, taken first, is dropped as confounded with the found term.
    assert!(
        d.confounded
            .iter()
            .any(|c| c.dropped == "drive_loss" && !c.tied),
        "{name}: {:?}",
        d.confounded
    );
    assert!(
        d.summary.contains("Not told apart from it: "),
        "{name}: {}",
        d.summary
    );
    // The BMS charge is named too (the voltage is a function of it).
    assert!(
        forms
            .iter()
            .any(|(f, _)| f.iter().any(|f| f == "/lf/bmsstate.soc")),
        "{name}: {forms:?}"
    );
    (t, forms)
}

/// Every voltage form's per-volt coefficient k (there is one at least) lies within 20 % of
/// `k_sw`, its relative error within `rel` (the range docs/diagnosis-results.md prints). Not within 2.5 of its
/// s.e.: the jackknife over trial folds does not see that the slope on the voltage rests on the
/// few parts' levels (−13.9 % is 2.9 s.e. in the linear refit).
fn volt_forms_within(name: &str, forms: &Forms, k_sw: f64, rel: [f64; 2]) {
    let volt_k: Vec<(f64, f64)> = forms.iter().filter_map(|(_, k)| *k).collect();
    assert!(!volt_k.is_empty(), "{name}: no voltage form: {forms:?}");
    for (k, se) in volt_k {
        let e = k / k_sw - 1.0;
        assert!(
            e.abs() <= 0.2 && e >= rel[0] && e <= rel[1],
            "{name}: k = {k} ± {se} ({:+.1} %), truth {k_sw}",
            100.0 * e
        );
    }
}

#[test]
fn switching_loss_on_the_linear_battery_found_on_session_time_names_the_voltages_beside_it() {
    // P_sw = k_sw·V_bus·Σ|τ_i|/K_i on the twin's linear battery, three parts started at
    // descending charge: the supply voltage falls as session time rises, so time, every
    // recorded voltage, the charge and the rail current at rest all carry the effect about
    // equally well. Against the twin the term is found on session time; whatever it is found
    // on, the recorded voltages are named beside it as what the data cannot tell from it.
    let k_sw = 0.05;
    let mut e = Effects::default();
    e.enable(&format!("switching={k_sw}")).unwrap();
    let (rec, _, files) = battery_session(&e, 3, sim::Battery::Linear, &SOC_DESCENDING);
    for (mode, opts) in [("refit", refit()), ("twin", twin())] {
        let name = format!("switching linear {mode}");
        let d = diagnose::diagnose(&rec, &files.opts(opts)).unwrap();
        show(&name, &d);
        // At this scale the linear pack's quantised voltages are not clock-like (docs/diagnosis-results.md).
        let r = d.discovery.as_ref().expect("discovery ran");
        assert!(
            !r.excluded
                .iter()
                .any(|x| volts_per_unit(&x.name).is_some() && x.reason.starts_with("clock")),
            "{name}: a voltage left out as clock-like: {:?}",
            r.excluded
        );
        let (t, forms) = switching_forms(&name, &d);
        let on_time = t.fields.is_empty() && t.name.contains("session time");
        if mode == "twin" {
            assert!(on_time, "{name}: not on session time: {}", t.name);
        } else {
            // Refitted, time and the voltages fit equally well (r = 1.00, p ≈ 0.4 between them):
            // which one leads is a tie-break (it moved from a voltage to time when the sensor
            // window became 0.225 s at lag 0 instead of 0.2 s + 0.0125 s); the voltages must be
            // named beside it either way (below).
            assert!(
                on_time
                    || t.fields
                        .first()
                        .is_some_and(|f| volts_per_unit(f).is_some()),
                "{name}: neither on session time nor on a recorded voltage: {} {:?}",
                t.name,
                t.fields
            );
        }
        let named =
            |pick: &dyn Fn(&str) -> bool| forms.iter().any(|(f, _)| f.iter().any(|f| pick(f)));
        assert!(
            named(&|f| f.starts_with("/lowstate.motor_state[") && f.ends_with("].vol"))
                && named(&|f| f == "/lf/bmsstate.bmsvoltage[0]")
                && named(&|f| f == "/lf/mainboardstate.value[0]"),
            "{name}: the supply voltages are not named: {forms:?}"
        );
        // Session time is the found signal or named beside it.
        assert!(forms.iter().any(|(f, _)| f.is_empty()), "{name}: {forms:?}");
        // The per-volt coefficient of every voltage form: 11–14 % below k_sw (docs/diagnosis-results.md).
        volt_forms_within(&name, &forms, k_sw, [-0.145, -0.105]);
        if on_time {
            // The found term's own name says its signal is confounded (the rivals above).
            assert!(
                t.name
                    .contains("(confounded: the data cannot tell these fields apart)"),
                "{name}: {}",
                t.name
            );
        }
    }
}

#[test]
fn switching_loss_on_the_realistic_battery_is_confounded_with_the_supply_voltage() {
    // The same loss on the realistic battery (NMC cell curve, 0.15 Ω pack resistance), six parts
    // started at charges in no order with time: the voltages sag under load, so they are no
    // longer clock-like; within a trial they meter the power (left out as such) and at rest
    // they read the charge. The term is found on a voltage at rest or on a signal the data
    // cannot tell from it, with the voltages named beside it; the per-volt coefficient of the
    // voltage forms is k_sw within 20 %: the slope on the voltage rests on six parts' levels
    // (docs/diagnosis-results.md).
    let k_sw = 0.05;
    let mut e = Effects::default();
    e.enable(&format!("switching={k_sw}")).unwrap();
    let (rec, _, files) = battery_session(&e, 3, sim::Battery::Realistic, &SOC_SHUFFLED);
    for (mode, opts) in [("refit", refit()), ("twin", twin())] {
        let name = format!("switching realistic {mode}");
        let d = diagnose::diagnose(&rec, &files.opts(opts)).unwrap();
        show(&name, &d);
        let r = d.discovery.as_ref().expect("discovery ran");
        assert!(
            !r.excluded
                .iter()
                .any(|x| volts_per_unit(&x.name).is_some() && x.reason.starts_with("clock")),
            "{name}: a voltage left out as clock-like: {:?}",
            r.excluded
        );
        // Within a trial the sagging voltages meter the power.
        assert!(
            r.notes.iter().any(|n| n.starts_with("left out as meters")
                && n.contains("/lf/bmsstate.bmsvoltage[0]")
                && n.contains("].vol")),
            "{name}: {:?}",
            r.notes
        );
        let (_, forms) = switching_forms(&name, &d);
        volt_forms_within(&name, &forms, k_sw, [-0.145, -0.115]);
    }
}

#[test]
fn null_sessions_on_the_realistic_battery_claim_nothing() {
    // Nothing concealed; the realistic battery's voltages sag under load and the parts start at
    // different charges.
    for seed in [11, 12] {
        let (rec, _, files) = battery_session(
            &Effects::default(),
            seed,
            sim::Battery::Realistic,
            &SOC_DESCENDING,
        );
        for (mode, opts) in [("refit", refit()), ("twin", twin())] {
            let d = diagnose::diagnose(&rec, &files.opts(opts)).unwrap();
            show(&format!("null realistic seed {seed} {mode}"), &d);
            assert!(
                claims(&d).is_empty(),
                "seed {seed} {mode}: claimed {:?}",
                claims(&d)
            );
        }
    }
}
