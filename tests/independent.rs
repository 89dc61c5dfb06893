//! The diagnosis on sessions this project's simulator did not write: `tests/py/indgen`, a
//! generator in Python (numpy, the `mcap` writer) with its own URDF inverse dynamics, plant,
//! sensor clock and concealed effects in standard physical forms, written from the shared
//! recordings' README and the paper — not from `src/sim`. Each session of its suite is
//! diagnosed the way a new user would (`g1viz diagnose SESSION --json`, the base model refitted)
//! and scored against the generator's truth file: every concealed effect named by a claim of its
//! mechanism (or located on the field it follows), and nothing else claimed. The table this
//! prints is docs/diagnosis-results.md's "Sessions from an independent generator"; the test holds each row.

mod common;

/// The documentation page that prints the figures this file holds.
const PAGE: &str = "docs/diagnosis-results.md";

use std::path::{Path, PathBuf};
use std::process::Command;

use g1viz::diagnose::Diagnosis;

/// One claim of a diagnosis, as scored: a library mechanism by its id, or a term found beyond
/// the library with the recorded fields it follows (its own and those of its named ties).
#[derive(Debug)]
enum Claim {
    Library(String),
    Found { name: String, fields: Vec<String> },
}

impl std::fmt::Display for Claim {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Claim::Library(id) => write!(f, "{id}"),
            Claim::Found { name, .. } => write!(f, "found: {name}"),
        }
    }
}

fn claims(d: &Diagnosis) -> Vec<Claim> {
    let mut c: Vec<Claim> = d
        .accepted
        .iter()
        .map(|h| Claim::Library(h.id.clone()))
        .collect();
    if let Some(r) = &d.discovery {
        for t in &r.accepted {
            let mut fields = t.fields.clone();
            fields.extend(t.tied.iter().flat_map(|r| r.fields.clone()));
            c.push(Claim::Found {
                name: t.name.clone(),
                fields,
            });
        }
        for t in r.rest.iter().flat_map(|r| &r.found) {
            let mut fields = vec![t.field.clone()];
            fields.extend(t.tied.iter().cloned());
            c.push(Claim::Found {
                name: t.name.clone(),
                fields,
            });
        }
    }
    c
}

/// The generator's parameter of a concealed effect and the diagnosis' parameter of the same
/// form: (truth-file key, parameter key, hypothesis id, symbol). Only where the winning form is
/// the generator's formula; other forms (and the effects outside the library) have no common
/// parameter.
const SAME_FORM: [(&str, &str, &str, &str); 7] = [
    ("thermal", "alpha_per_K", "thermal", "α"),
    ("braking", "eta", "braking", "r"),
    ("latency", "L_s", "latency", "L"),
    ("payload", "mass_kg", "payload", "m"),
    ("electronics_nm", "k_W_per_Nm", "electronics_nm", "k_el"),
    ("gear_friction", "mu", "gear_friction", "μ"),
    ("bus_power", "R_bus_ohm", "bus_power", "R_bus"),
];

/// (effect, true value, estimate, s.e.) of every claimed library term in its generator's form.
fn same_form_params(truth: &serde_json::Value, d: &Diagnosis) -> Vec<(String, f64, f64, f64)> {
    let mut out = Vec::new();
    for (effect, key, id, symbol) in SAME_FORM {
        let Some(v) = truth["effects"][effect]["params"][key].as_f64() else {
            continue;
        };
        let Some(h) = d.accepted.iter().find(|h| h.id == id) else {
            continue;
        };
        if let Some(p) = h.params.iter().find(|p| p.symbol == symbol) {
            out.push((effect.to_string(), v, p.value, p.std_err));
        }
    }
    out
}

/// Whether `claim` names concealed effect `effect` of the generator (its truth-file key). An
/// effect outside the library counts when a term found follows one of the recorded fields the
/// truth file says it follows (`fields`; its own field or one named with it as not told apart).
/// Library mechanisms count by mechanism, whatever form won (the form is reported beside).
fn names_effect(claim: &Claim, effect: &str, fields: &[String]) -> bool {
    let lib = |ids: &[&str]| matches!(claim, Claim::Library(id) if ids.contains(&id.as_str()));
    let found_on = |pred: &dyn Fn(&str) -> bool| matches!(claim, Claim::Found { fields, .. } if fields.iter().any(|f| pred(f)));
    let arm_field =
        |f: &str, leaf: &str| (15..=21).any(|k| f == format!("/lowstate.motor_state[{k}].{leaf}"));
    match effect {
        // Copper-loss drift with the winding temperature: the library's mechanism, or a term
        // found on the arm's winding temperatures.
        "thermal" => lib(&["thermal"]) || found_on(&|f| arm_field(f, "temperature[0]")),
        "braking" => lib(&["braking"]),
        "latency" => lib(&["latency"]),
        "payload" => lib(&["payload"]),
        "bus_power" => lib(&["bus_power", "bus_loss"]),
        "electronics_nm" => lib(&["electronics_nm", "drive_loss"]),
        "gear_friction" => lib(&["gear_friction"]),
        // Outside the library: located on a field it follows.
        _ => found_on(&|f| fields.iter().any(|t| t == f)),
    }
}

/// A session of the suite: file stem, concealed effects (truth keys).
struct Scored {
    stem: String,
    effects: Vec<String>,
    claims: Vec<String>,
    missed: Vec<String>,
    spurious: Vec<String>,
    rmse: [f64; 2],
    params: Vec<(String, f64, f64, f64)>,
    /// Mean concealed-effect power per trial, net of the trial's pre-idle (truth file) [W].
    effect_w: f64,
    /// Rest-power terms found: (field, first parameter, fields named with it).
    rest: Vec<(String, f64, Vec<String>)>,
}

impl Scored {
    fn right(&self) -> bool {
        self.missed.is_empty() && self.spurious.is_empty()
    }
}

/// Score diagnosis `d` of a session whose truth file is `truth`.
fn score(stem: &str, truth: &serde_json::Value, d: &Diagnosis) -> Scored {
    let effects: Vec<(String, Vec<String>)> = truth["effects"]
        .as_object()
        .map(|m| {
            m.iter()
                .map(|(k, v)| {
                    let fields = v["fields"]
                        .as_array()
                        .map(|a| {
                            a.iter()
                                .filter_map(|f| f.as_str().map(str::to_string))
                                .collect()
                        })
                        .unwrap_or_default();
                    (k.clone(), fields)
                })
                .collect()
        })
        .unwrap_or_default();
    let cs = claims(d);
    let mut used = vec![false; cs.len()];
    let mut missed = Vec::new();
    for (e, fields) in &effects {
        match (0..cs.len()).find(|&i| !used[i] && names_effect(&cs[i], e, fields)) {
            Some(i) => used[i] = true,
            None => missed.push(e.clone()),
        }
    }
    let spurious = (0..cs.len())
        .filter(|&i| !used[i])
        .map(|i| cs[i].to_string())
        .collect();
    let final_rmse = d
        .discovery
        .as_ref()
        .and_then(|r| r.accepted.last().map(|t| t.after.rmse_w))
        .unwrap_or(d.final_model.after.rmse_w);
    Scored {
        stem: stem.to_string(),
        effects: effects.into_iter().map(|(e, _)| e).collect(),
        claims: cs.iter().map(|c| c.to_string()).collect(),
        missed,
        spurious,
        rmse: [d.final_model.before.rmse_w, final_rmse],
        params: same_form_params(truth, d),
        effect_w: {
            let v: Vec<f64> = truth["trials"]
                .as_array()
                .map(|a| {
                    a.iter()
                        .filter_map(|t| t["effect_power_net_traj_mean_W"].as_f64())
                        .collect()
                })
                .unwrap_or_default();
            v.iter().sum::<f64>() / v.len().max(1) as f64
        },
        rest: d
            .discovery
            .iter()
            .flat_map(|r| r.rest.iter().flat_map(|r| &r.found))
            .map(|t| (t.field.clone(), t.params[0].value, t.tied.clone()))
            .collect(),
    }
}

fn g1viz() -> Command {
    Command::new(env!("CARGO_BIN_EXE_g1viz"))
}

fn python_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/py")
}

/// Paper scale, as in the experiment docs/diagnosis-results.md reports (≈ 1000 trials per session).
const HOURS: f64 = 4.4;

/// Sessions of the suite (`python3 -m indgen suite --list`), in order.
const SUITE: [&str; 16] = [
    "01_null",
    "02_null",
    "03_null",
    "04_thermal",
    "05_braking",
    "06_latency",
    "07_payload",
    "08_thermal+braking",
    "09_bus_power",
    "10_bus_power+latency",
    "11_electronics_nm",
    "12_gear_friction",
    "13_grease",
    "14_rail_load",
    "15_bus_power5ohm",
    "16_bus_power5ohm+latency",
];

/// Generate session `index` (1-based) of the suite into `dir`, diagnose it and score it; the
/// recording is deleted afterwards (≈ 0.6 GB each at paper scale).
fn run_one(dir: &Path, shared: &Path, index: usize) -> Scored {
    let stem = SUITE[index - 1];
    let gen_out = common::output_within(
        Command::new("python3")
            .args(["-m", "indgen", "suite", "--out"])
            .arg(dir)
            .args(["--hours", &HOURS.to_string(), "--only", &index.to_string()])
            .env("PYTHONPATH", python_dir())
            .env("G1VIZ_SHARED", shared),
        common::TOOL_LIMIT,
    )
    .expect("python3 runs");
    assert!(
        gen_out.status.success(),
        "indgen {stem}: {}",
        String::from_utf8_lossy(&gen_out.stderr)
    );
    let mcap = dir.join(format!("{stem}.mcap"));
    let json = dir.join(format!("{stem}.diagnosis.json"));
    let out = common::output_within(
        g1viz()
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .arg("diagnose")
            .arg(&mcap)
            .arg("--json")
            .arg(&json),
        common::G1VIZ_LIMIT,
    )
    .expect("g1viz runs");
    assert!(
        out.status.success(),
        "diagnose {stem}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!("== {stem}\n{}", String::from_utf8_lossy(&out.stdout));
    let d: Diagnosis = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let truth: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join(format!("{stem}.truth.json"))).unwrap())
            .unwrap();
    let _ = std::fs::remove_file(&mcap);
    score(stem, &truth, &d)
}

/// The table of docs/diagnosis-results.md, row by row: session, right (every effect named, nothing else claimed).
/// Sessions 09 and 10 carry the generator's physical 0.1 Ω bus loss (≈ 0.006 W per trial):
/// no claim of it is possible, so they count as missed.
const README_ROWS: [(&str, bool); 16] = [
    ("01_null", true),
    ("02_null", true),
    ("03_null", true),
    ("04_thermal", true),
    ("05_braking", true),
    ("06_latency", true),
    ("07_payload", true),
    ("08_thermal+braking", true),
    ("09_bus_power", false),
    ("10_bus_power+latency", false),
    ("11_electronics_nm", true),
    ("12_gear_friction", false),
    ("13_grease", true),
    ("14_rail_load", true),
    ("15_bus_power5ohm", true),
    ("16_bus_power5ohm+latency", true),
];

/// The whole claim set of the sessions whose bus loss (0.1 Ω, ≈ 0.006 W per trial) no 1 Hz
/// reading can show: nothing beyond the latency that session 10 also carries (measured on this
/// generator's sessions with the diagnoser of the commit that wrote this).
const WHOLE_CLAIMS: [(&str, &[&str]); 2] = [
    ("09_bus_power", &[]),
    ("10_bus_power+latency", &["latency"]),
];

/// Parameters of the claimed terms in the generator's own form are within this of the truth
/// (docs/diagnosis-results.md).
const PARAM_TOLERANCE: f64 = 0.10;

/// The estimates in the table of docs/diagnosis-results.md: session, effect, value as printed.
const README_PARAMS: [(&str, &str, &str); 9] = [
    ("04_thermal", "thermal", "0.00379"),
    ("05_braking", "braking", "0.680"),
    ("06_latency", "latency", "0.3001"),
    ("07_payload", "payload", "0.4966"),
    ("08_thermal+braking", "braking", "0.672"),
    ("08_thermal+braking", "thermal", "0.00394"),
    ("11_electronics_nm", "electronics_nm", "0.407"),
    ("15_bus_power5ohm", "bus_power", "5.09"),
    ("16_bus_power5ohm+latency", "bus_power", "5.16"),
];

#[test]
fn independent_generator_suite_is_diagnosed_as_the_readme_says() {
    let modules = [
        ("numpy", "numpy==2.4.6"),
        ("zstandard", "zstandard==0.25.0"),
        ("mcap", "mcap==1.6.0"),
    ];
    if !modules.iter().all(|(m, pip)| common::python_module(m, pip)) {
        return;
    }
    // The generator reads the URDF and the message definitions there.
    let Some(shared) = common::shared_dir() else {
        return;
    };
    let list = common::output_within(
        Command::new("python3")
            .args(["-m", "indgen", "suite", "--out", ".", "--list"])
            .env("PYTHONPATH", python_dir()),
        common::TOOL_LIMIT,
    )
    .expect("python3 runs");
    let stems: Vec<String> = String::from_utf8_lossy(&list.stdout)
        .lines()
        .filter_map(|l| l.split_whitespace().nth(1).map(str::to_string))
        .collect();
    assert_eq!(stems, SUITE, "the generator's suite changed");
    let dir = tempfile::tempdir().unwrap();
    // Two sessions at a time (one core generates while the other diagnoses).
    let next = std::sync::atomic::AtomicUsize::new(1);
    let results = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..2 {
            s.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                    if i > SUITE.len() {
                        break;
                    }
                    let r = run_one(dir.path(), &shared, i);
                    results.lock().unwrap().push(r);
                }
            });
        }
    });
    let mut results = results.into_inner().unwrap();
    results.sort_by(|a, b| a.stem.cmp(&b.stem));
    eprintln!("| session | concealed | claimed | right | held-out RMSE before → after |");
    for r in &results {
        eprintln!(
            "| {} | {} | {} | {} | {:.3} → {:.3} W |{}{}",
            r.stem,
            if r.effects.is_empty() {
                "—".into()
            } else {
                r.effects.join(" + ")
            },
            if r.claims.is_empty() {
                "nothing".into()
            } else {
                r.claims.join("; ")
            },
            if r.right() { "yes" } else { "no" },
            r.rmse[0],
            r.rmse[1],
            if r.missed.is_empty() {
                String::new()
            } else {
                format!(" missed {:?}", r.missed)
            },
            if r.spurious.is_empty() {
                String::new()
            } else {
                format!(" spurious {:?}", r.spurious)
            },
        );
    }
    let right = results.iter().filter(|r| r.right()).count();
    eprintln!("right: {right} of {}", results.len());
    let mut worst = (String::new(), 0.0f64);
    for r in &results {
        for (effect, truth, got, se) in &r.params {
            if (got / truth - 1.0).abs() > worst.1.abs() {
                worst = (format!("{} {effect}", r.stem), got / truth - 1.0);
            }
            let rel = got / truth - 1.0;
            eprintln!(
                "{}: {effect} {got:.5} ± {se:.5} vs {truth} ({:+.1} %)",
                r.stem,
                100.0 * rel
            );
            assert!(
                rel.abs() <= PARAM_TOLERANCE,
                "{}: {effect} {got} vs {truth}",
                r.stem
            );
        }
    }
    let by_stem = |stem: &str| results.iter().find(|r| r.stem == stem).unwrap();
    for (stem, effect, stated) in README_PARAMS {
        let got = by_stem(stem)
            .params
            .iter()
            .find(|p| p.0 == effect)
            .map_or(f64::NAN, |p| p.2);
        common::assert_figure(PAGE, &format!("{stem} {effect}"), got, stated);
    }
    // The bus loss at the generator's physical 0.1 Ω and at 5 Ω, per trial (truth files).
    common::assert_figure(
        PAGE,
        "09 bus loss per trial [W]",
        by_stem("09_bus_power").effect_w,
        "0.006",
    );
    common::assert_figure(
        PAGE,
        "15 bus loss per trial [W]",
        by_stem("15_bus_power5ohm").effect_w,
        "0.3",
    );
    // The fans on the rest power: one term, on a fan field, ≈ 5 W over its range.
    let fans = &by_stem("14_rail_load").rest;
    assert!(
        fans.len() == 1 && fans[0].0.starts_with("/lf/mainboardstate.fan_state["),
        "{fans:?}"
    );
    common::assert_figure(PAGE, "14 rest-power ΔP [W]", fans[0].1, "5");
    // Named beside it: the other fan (docs/diagnosis-results.md); the board temperatures, which
    // rise with the fans but also with the session, are not told from the rail's drift.
    let tied = &fans[0].2;
    assert!(
        tied.iter()
            .any(|f| f.starts_with("/lf/mainboardstate.fan_state[")),
        "{tied:?}"
    );
    // The grease: the viscous loss, falling as a housing temperature rises (docs/diagnosis-results.md).
    let grease = &by_stem("13_grease").claims;
    assert!(
        grease.len() == 1
            && grease[0].starts_with("found: The viscous friction loss")
            && grease[0]
                .split(", or")
                .next()
                .is_some_and(|head| head.contains("falls") && head.ends_with(".temperature[1]")),
        "{grease:?}"
    );
    for r in results.iter().filter(|r| r.stem != "14_rail_load") {
        assert!(r.rest.is_empty(), "{}: rest power {:?}", r.stem, r.rest);
    }
    common::assert_figure(
        PAGE,
        &format!("largest parameter deviation ({}) [%]", worst.0),
        100.0 * worst.1,
        "-3.5",
    );
    for (stem, want) in WHOLE_CLAIMS {
        assert_eq!(by_stem(stem).claims, want, "{stem}: the whole claim set");
    }
    for (r, (stem, want)) in results.iter().zip(README_ROWS) {
        assert_eq!(r.stem, stem);
        assert_eq!(
            r.right(),
            want,
            "{stem}: docs/diagnosis-results.md says {}; claims {:?}, missed {:?}, spurious {:?}",
            if want { "right" } else { "wrong" },
            r.claims,
            r.missed,
            r.spurious
        );
    }
}
