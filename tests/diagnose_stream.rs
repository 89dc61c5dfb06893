//! The streamed diagnosis (`diagnose::diagnose_files`: session files read trial by trial, never
//! held whole) gives the diagnosis of the files loaded into memory (`diagnose::diagnose` on the
//! recordings joined by `join_recordings_with_sources`): every number of diagnosis.json equal to
//! 1e-9 relative (also for joined files, whose trials the streamed read segments per file and
//! shifts onto the joined clock), every text and verdict the same.

mod common;

use std::path::{Path, PathBuf};

use g1viz::diagnose::{self, DiagnoseOptions, Diagnosis};
use g1viz::power::PowerModel;
use g1viz::read::OpenOptions;
use g1viz::session::SessionFile;
use g1viz::signals::{SignalMap, load_recording};
use g1viz::sim::{self, Effects, Preset, SimConfig};
use serde_json::Value;

const GAP_S: f64 = 5.0;

fn file(path: &Path) -> SessionFile {
    SessionFile {
        path: path.to_path_buf(),
        map: SignalMap::g1_left_arm(),
        read: OpenOptions::default(),
        spill: Default::default(),
    }
}

/// The diagnosis of `paths` loaded into memory and joined.
fn in_memory(paths: &[PathBuf], opts: &DiagnoseOptions) -> anyhow::Result<Diagnosis> {
    let recs = paths
        .iter()
        .map(|p| load_recording(p, &SignalMap::g1_left_arm(), &OpenOptions::default()))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let (rec, field_sources) = diagnose::join_recordings_with_sources(recs, GAP_S);
    diagnose::diagnose(
        &rec,
        &DiagnoseOptions {
            field_sources,
            ..opts.clone()
        },
    )
}

/// The diagnosis of `paths` streamed.
fn streamed(paths: &[PathBuf], opts: &DiagnoseOptions) -> anyhow::Result<Diagnosis> {
    let files: Vec<SessionFile> = paths.iter().map(|p| file(p)).collect();
    diagnose::diagnose_files(&files, opts, GAP_S)
}

/// Walk two JSON values together: numbers within `rel` (relative to the larger magnitude, with
/// an absolute floor of `rel` × 1e-6 for values that should be zero), everything else equal.
fn same(path: &str, a: &Value, b: &Value, rel: f64, diffs: &mut Vec<String>) {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            let tol = rel * x.abs().max(y.abs()) + rel * 1e-6;
            if (x - y).abs() > tol {
                diffs.push(format!("{path}: {x} vs {y}"));
            }
        }
        (Value::Array(x), Value::Array(y)) => {
            if x.len() != y.len() {
                diffs.push(format!("{path}: {} vs {} elements", x.len(), y.len()));
                return;
            }
            for (i, (p, q)) in x.iter().zip(y).enumerate() {
                same(&format!("{path}[{i}]"), p, q, rel, diffs);
            }
        }
        (Value::Object(x), Value::Object(y)) => {
            let kx: Vec<&String> = x.keys().collect();
            let ky: Vec<&String> = y.keys().collect();
            if kx != ky {
                diffs.push(format!("{path}: keys {kx:?} vs {ky:?}"));
                return;
            }
            for (k, v) in x {
                same(&format!("{path}.{k}"), v, &y[k], rel, diffs);
            }
        }
        (x, y) if x == y => {}
        (x, y) => diffs.push(format!("{path}: {x} vs {y}")),
    }
}

fn assert_same(what: &str, memory: &Diagnosis, stream: &Diagnosis, rel: f64) {
    let a = serde_json::to_value(memory).unwrap();
    let b = serde_json::to_value(stream).unwrap();
    let mut diffs = Vec::new();
    same("", &a, &b, rel, &mut diffs);
    assert!(
        diffs.is_empty(),
        "{what}: streamed diagnosis differs from the in-memory one in {} places:\n{}",
        diffs.len(),
        diffs
            .iter()
            .take(20)
            .cloned()
            .collect::<Vec<_>>()
            .join("\n")
    );
}

/// Everything a diagnosis claims (accepted hypotheses, terms found beyond the library) and what it
/// locates without claiming ("X or Y").
fn claims(d: &Diagnosis) -> Vec<String> {
    let mut c: Vec<String> = d.accepted.iter().map(|h| h.id.clone()).collect();
    c.extend(
        d.forms
            .iter()
            .filter(|f| f.unnamed)
            .map(|f| format!("located: {}", f.mechanism)),
    );
    if let Some(r) = &d.discovery {
        c.extend(r.accepted.iter().map(|t| format!("found: {}", t.form)));
        c.extend(r.located.iter().map(|t| format!("located: {}", t.form)));
    }
    c
}

fn simulate(dir: &Path, name: &str, cfg: SimConfig) -> PathBuf {
    let out = dir.join(name);
    sim::simulate(&cfg, &out).unwrap();
    out
}

#[test]
fn example_session_streamed_equals_in_memory() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap");
    // 7 trials, 55 readings: too few for the 49-parameter model. Both reads stop there alike.
    let opts = DiagnoseOptions {
        folds: 3,
        sensor_window_s: Some(0.2),
        ..DiagnoseOptions::default()
    };
    let one = std::slice::from_ref(&path);
    let m = in_memory(one, &opts).map(|_| ()).unwrap_err();
    let s = streamed(one, &opts).map(|_| ()).unwrap_err();
    assert_eq!(format!("{m:#}"), format!("{s:#}"));
    assert!(format!("{m:#}").contains("only 55 power readings"), "{m:#}");
    // The example joined end to end three times (21 trials, three clocks): a whole diagnosis.
    let opts = DiagnoseOptions {
        folds: 5,
        ..DiagnoseOptions::default()
    };
    let three = [path.clone(), path.clone(), path];
    let m = in_memory(&three, &opts).unwrap();
    let s = streamed(&three, &opts).unwrap();
    assert_eq!(m.n_trials + m.rejected.len(), 21);
    assert!(m.torque.is_some(), "the torque level ran");
    assert_same("example × 3", &m, &s, 1e-9);
}

#[test]
fn simulated_effect_session_streamed_equals_in_memory() {
    // One 46-trial file with a shared bus loss and a warm start against the twin: the
    // diagnosis claims something, and both reads claim it with the same numbers.
    let dir = tempfile::tempdir().unwrap();
    let mut effects = Effects::default();
    effects.enable("bus_loss=0.05").unwrap();
    effects.enable("thermal=0.00393").unwrap();
    let path = simulate(
        dir.path(),
        "effects.mcap",
        SimConfig {
            preset: Preset::Holdout,
            seed: 11,
            effects,
            t_start_c: 70.0,
            progress: false,
            ..SimConfig::default()
        },
    );
    let twin = DiagnoseOptions {
        reference: Some(PowerModel::PAPER),
        ..DiagnoseOptions::default()
    };
    let paths = [path];
    let m = in_memory(&paths, &twin).unwrap();
    let s = streamed(&paths, &twin).unwrap();
    assert!(
        !claims(&m).is_empty(),
        "nothing claimed or located:\n{}",
        m.summary
    );
    assert_eq!(claims(&m), claims(&s));
    assert!(m.torque.is_some(), "the torque level ran");
    assert_same("bus loss + thermal, twin", &m, &s, 1e-9);
}

#[test]
fn joined_sessions_streamed_equal_in_memory() {
    // Three files joined on one clock (each keeps its own, shifted), sensor latency concealed,
    // refitted base model.
    let dir = tempfile::tempdir().unwrap();
    let mut effects = Effects::default();
    effects.enable("latency=0.3").unwrap();
    let paths: Vec<PathBuf> = (0..3)
        .map(|part| {
            simulate(
                dir.path(),
                &format!("s{part}.mcap"),
                SimConfig {
                    preset: Preset::Smoke,
                    seed: 500 + part,
                    effects,
                    progress: false,
                    ..SimConfig::default()
                },
            )
        })
        .collect();
    let opts = DiagnoseOptions::default();
    let m = in_memory(&paths, &opts).unwrap();
    let s = streamed(&paths, &opts).unwrap();
    assert!(claims(&m).contains(&"latency".to_string()), "{}", m.summary);
    assert_eq!(claims(&m), claims(&s));
    assert_same("joined, latency, refit", &m, &s, 1e-9);
}

#[test]
fn shared_smoke_recordings_streamed_equal_in_memory() {
    let Some(path) = common::shared_recording("g1_smoke.mcap") else {
        return;
    };
    let urdf = path
        .parent()
        .unwrap()
        .join("../g1_description/g1_29dof_with_hand_rev_1_0.urdf");
    for reference in [None, Some(PowerModel::PAPER)] {
        let opts = DiagnoseOptions {
            urdf: urdf.exists().then(|| urdf.clone()),
            reference,
            ..DiagnoseOptions::default()
        };
        let paths = [path.clone()];
        let m = in_memory(&paths, &opts).unwrap();
        let s = streamed(&paths, &opts).unwrap();
        assert!(m.torque.is_some(), "the torque level ran");
        assert_same("g1_smoke.mcap", &m, &s, 1e-9);
    }
}

#[test]
fn shared_smoke_bags_are_read_alike() {
    // The ROS 1 and ROS 2 bags hold the smoke session's first 3 trials: too few to diagnose.
    // Both reads find the same trials and stop at the same point with the same words.
    for name in ["g1_smoke.bag", "g1_smoke_db3"] {
        let Some(path) = common::shared_recording(name) else {
            continue;
        };
        for window in [None, Some(0.2)] {
            let opts = DiagnoseOptions {
                sensor_window_s: window,
                ..DiagnoseOptions::default()
            };
            let paths = [path.clone()];
            let m = in_memory(&paths, &opts).map(|_| ()).unwrap_err();
            let s = streamed(&paths, &opts).map(|_| ()).unwrap_err();
            assert_eq!(format!("{m:#}"), format!("{s:#}"), "{name}");
            let why = format!("{m:#}");
            assert!(
                why.contains("only 3 trials with a pre-idle (need at least 20 usable"),
                "{name}: {why}"
            );
        }
    }
}

#[test]
fn the_comparison_sees_a_small_difference() {
    let a: Value = serde_json::json!({"x": [1.0, 2.0], "s": "a"});
    let mut diffs = Vec::new();
    same(
        "",
        &a,
        &serde_json::json!({"x": [1.0, 2.0], "s": "a"}),
        1e-9,
        &mut diffs,
    );
    assert!(diffs.is_empty());
    same(
        "",
        &a,
        &serde_json::json!({"x": [1.0, 2.000001], "s": "a"}),
        1e-9,
        &mut diffs,
    );
    same(
        "",
        &a,
        &serde_json::json!({"x": [1.0, 2.0], "s": "b"}),
        1e-9,
        &mut diffs,
    );
    same(
        "",
        &a,
        &serde_json::json!({"x": [1.0], "s": "a"}),
        1e-9,
        &mut diffs,
    );
    assert_eq!(diffs.len(), 3, "{diffs:?}");
}
