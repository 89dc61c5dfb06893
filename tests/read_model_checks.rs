//! Model files are checked against the session before use, through the `g1viz` binary: a model
//! of the other arm, of the same joints in another order, or of the other power sensor is
//! refused naming the file, the field and its value; so are a negative inverse gear efficiency
//! and absurd loss coefficients; and a validation whose R² is undefined exits non-zero instead
//! of printing NaN with exit 0.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use g1viz::power::{ModelFile, ModelMetrics, PowerModel, Provenance};
use g1viz::signals::SignalMap;

fn example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap")
}

/// The paper's parameters as a model file of the left arm's MBS sensor, as JSON.
fn paper_model_json() -> serde_json::Value {
    let provenance = Provenance {
        target: "mbs".into(),
        ..Provenance::default()
    };
    let file = ModelFile::new(
        &PowerModel::PAPER,
        &SignalMap::g1_left_arm().joint_names,
        ModelMetrics::default(),
        provenance,
    )
    .unwrap();
    serde_json::from_str(&file.to_json().unwrap()).unwrap()
}

fn write(dir: &Path, name: &str, json: &serde_json::Value) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, serde_json::to_string_pretty(json).unwrap()).unwrap();
    path
}

/// Run `g1viz ARGS`; (exit code, stderr).
fn g1viz(args: &[&std::ffi::OsStr]) -> (Option<i32>, String) {
    let out = common::output_within(
        Command::new(env!("CARGO_BIN_EXE_g1viz")).args(args),
        common::G1VIZ_LIMIT,
    )
    .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn validate(model: &Path, extra: &[&str]) -> (Option<i32>, String) {
    let mut args: Vec<&std::ffi::OsStr> = vec!["validate".as_ref(), "--model".as_ref()];
    args.push(model.as_os_str());
    args.extend(extra.iter().map(|s| std::ffi::OsStr::new(*s)));
    let ex = example();
    args.push(ex.as_os_str());
    g1viz(&args)
}

fn assert_refused(result: (Option<i32>, String), needles: &[&str]) {
    let (code, stderr) = result;
    assert_eq!(code, Some(1), "{stderr}");
    for needle in needles {
        assert!(stderr.contains(needle), "{needle:?} missing in: {stderr}");
    }
}

#[test]
fn a_model_that_fits_the_session_validates() {
    let tmp = tempfile::tempdir().unwrap();
    let good = write(tmp.path(), "good.json", &paper_model_json());
    let (code, stderr) = validate(&good, &[]);
    assert_eq!(code, Some(0), "{stderr}");
}

#[test]
fn a_model_of_other_joints_or_another_sensor_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let good = write(tmp.path(), "left_mbs.json", &paper_model_json());

    // The right arm's signals (a signal map with `arm = "right"`) with a left-arm model.
    let right = tmp.path().join("right.toml");
    std::fs::write(&right, "arm = \"right\"\n").unwrap();
    assert_refused(
        validate(&good, &["--signals", right.to_str().unwrap()]),
        &[
            "left_mbs.json",
            "joint_names[0]",
            "\"left_shoulder_pitch_joint\"",
            "\"right_shoulder_pitch_joint\"",
            "identified on the left arm, the session is the right arm's",
        ],
    );

    // The same joints in another order.
    let mut json = paper_model_json();
    let names = json["joint_names"].as_array_mut().unwrap();
    names.swap(0, 1);
    let swapped = write(tmp.path(), "swapped.json", &json);
    assert_refused(
        validate(&swapped, &[]),
        &["swapped.json", "joint_names[0]", "another order"],
    );

    // A BMS model used on the MBS sensor (the default target), and accepted with --target bms.
    let mut json = paper_model_json();
    json["provenance"]["target"] = "bms".into();
    let bms = write(tmp.path(), "bms.json", &json);
    assert_refused(
        validate(&bms, &[]),
        &["bms.json", "provenance.target", "\"bms\"", "--target bms"],
    );
    let (code, stderr) = validate(&bms, &["--target", "bms"]);
    assert_eq!(code, Some(0), "{stderr}");

    // The same checks guard `diagnose --model`.
    let ex = example();
    assert_refused(
        g1viz(&[
            "diagnose".as_ref(),
            ex.as_os_str(),
            "--model".as_ref(),
            swapped.as_os_str(),
        ]),
        &["swapped.json", "another order"],
    );
}

/// Set parameter `p` in θ and in its named copy.
fn set_param(json: &mut serde_json::Value, p: usize, v: f64) {
    json["theta"][p] = v.into();
    let (group, i) = (["a", "b", "c", "d"][p / 7], p % 7);
    json[group][i] = v.into();
}

#[test]
fn negative_or_absurd_parameters_are_refused_naming_field_and_value() {
    let tmp = tempfile::tempdir().unwrap();
    let mut json = paper_model_json();
    set_param(&mut json, 0, -1.0);
    let negative = write(tmp.path(), "negative_a.json", &json);
    assert_refused(
        validate(&negative, &[]),
        &[
            "negative_a.json",
            "theta[0]",
            "(a0) = -1",
            "negative",
            "inverse gear efficiency",
        ],
    );

    let mut json = paper_model_json();
    set_param(&mut json, 21, 3e38);
    let absurd = write(tmp.path(), "absurd_d.json", &json);
    assert_refused(
        validate(&absurd, &[]),
        &[
            "absurd_d.json",
            "theta[21]",
            "(d0) = 300000000000000000000000000000000000000",
            "absurd",
        ],
    );
    // Also where a model is only simulated, not checked against a session.
    let out = tmp.path().join("sim.mcap");
    assert_refused(
        g1viz(&[
            "simulate".as_ref(),
            "--preset".as_ref(),
            "tiny".as_ref(),
            "--model".as_ref(),
            absurd.as_os_str(),
            "-o".as_ref(),
            out.as_os_str(),
        ]),
        &["absurd_d.json", "theta[21]"],
    );
    assert!(!out.exists());
}

#[test]
fn a_validation_with_undefined_r2_exits_non_zero() {
    // MBS voltage scaled to 0: the measured power is constant, so R² is undefined.
    let tmp = tempfile::tempdir().unwrap();
    let model = write(tmp.path(), "m.json", &paper_model_json());
    let map = tmp.path().join("flat.toml");
    std::fs::write(&map, "[[signal]]\nname = \"mbs.voltage\"\nscale = 0.0\n").unwrap();
    assert_refused(
        validate(&model, &["--signals", map.to_str().unwrap()]),
        &["m.json", "g1_example.mcap", "R² is not a number"],
    );
}
