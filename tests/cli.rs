//! The `g1viz` binary end to end, as a user runs it: the README's commands (the main job on the
//! shipped example, and the tour whose output the README quotes), the
//! simulate → identify → validate → diagnose workflow with its output files, the shared session
//! written by an independent generator, and bad input that must end in a clear error (exit
//! status 1, the file named, no panic).

mod common;

/// The documentation page that prints the figures this file holds.
const PAGE: &str = "docs/model.md";

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn crate_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn run(dir: &Path, args: &[&str]) -> Output {
    common::output_within(
        Command::new(env!("CARGO_BIN_EXE_g1viz"))
            .current_dir(dir)
            .args(args),
        common::G1VIZ_LIMIT,
    )
    .expect("g1viz runs")
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// Run and expect success; returns (stdout, stderr).
fn ok(dir: &Path, args: &[&str]) -> (String, String) {
    let o = run(dir, args);
    let (out, err) = text(&o);
    assert!(
        o.status.success() && !err.contains("panicked"),
        "g1viz {args:?} failed ({}):\n{out}\n{err}",
        o.status
    );
    (out, err)
}

/// Run and expect the error path: exit status 1, a one-line `error:` on stderr, no panic.
fn fails(dir: &Path, args: &[&str]) -> String {
    let o = run(dir, args);
    let (out, err) = text(&o);
    assert_eq!(
        o.status.code(),
        Some(1),
        "g1viz {args:?} should fail:\n{out}\n{err}"
    );
    assert!(!err.contains("panicked"), "g1viz {args:?} panicked:\n{err}");
    assert!(err.contains("error: "), "g1viz {args:?}: {err}");
    err
}

/// `/lowstate` messages of the shipped example, as the container itself counts them (`info --json`).
fn example_lowstate_messages() -> u64 {
    let (info, _) = ok(
        &crate_dir(),
        &["info", "examples/g1_example.mcap", "--json"],
    );
    let info: serde_json::Value = serde_json::from_str(&info).unwrap();
    info["container"]["topics"]
        .as_array()
        .unwrap()
        .iter()
        .find(|t| t["topic"] == "/lowstate")
        .unwrap()["count"]
        .as_u64()
        .unwrap()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn example() -> PathBuf {
    crate_dir().join("examples/g1_example.mcap")
}

#[test]
fn help_lists_every_subcommand_with_examples() {
    let (out, _) = ok(&crate_dir(), &["--help"]);
    for sub in [
        "info", "replay", "identify", "validate", "simulate", "diagnose",
    ] {
        assert!(out.contains(sub), "--help lacks {sub}:\n{out}");
        assert!(
            out.contains(&format!("g1viz {sub} ")),
            "--help has no example of {sub}:\n{out}"
        );
    }
}

/// The README's main command (first `cargo run -- …` line), run by the built binary on the
/// shipped example with its output redirected to a scratch folder: an .rrd with one arm sample
/// per `/lowstate` message, which the stock CLI verifies when it is installed.
#[cfg(feature = "viz")]
#[test]
fn readme_main_command_replays_the_shipped_example() {
    let line = common::doc_blocks("README.md", "sh")
        .into_iter()
        .flatten()
        .find(|l| l.starts_with("cargo run -- "))
        .expect("README has a `cargo run -- …` main command");
    let mut args: Vec<String> = line["cargo run -- ".len()..]
        .split_whitespace()
        .map(str::to_owned)
        .collect();
    assert_eq!(args[0], "replay", "{line}");
    let tmp = tempfile::tempdir().unwrap();
    let save = args
        .iter()
        .position(|a| a == "--save")
        .expect("the main command saves an .rrd");
    let out = tmp.path().join(&args[save + 1]);
    args[save + 1] = out.display().to_string();
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let (_, err) = ok(&crate_dir(), &args);

    let lowstate = example_lowstate_messages();
    assert!(
        err.contains(&format!("({lowstate} samples, ")),
        "one sample per /lowstate message ({lowstate}):\n{err}"
    );
    let bytes = std::fs::read(&out).unwrap();
    assert!(bytes.starts_with(b"RRF2"), "not an .rrd stream");
    assert!(bytes.len() > 100_000, "{} bytes", bytes.len());

    match common::output_within(Command::new("rerun").arg("--version"), common::TOOL_LIMIT) {
        Ok(_) => {
            let v = common::output_within(
                Command::new("rerun").args(["rrd", "verify"]).arg(&out),
                common::TOOL_LIMIT,
            )
            .unwrap();
            assert!(
                v.status.success(),
                "rerun rrd verify: {}",
                String::from_utf8_lossy(&v.stderr)
            );
        }
        Err(_) => {
            common::skip("`rerun` not on PATH: `rerun rrd verify` of the main command's output")
        }
    }
}

/// The README's tour, run as printed: its ```text blocks that start with `$ g1viz …` run in
/// order in one scratch folder holding `examples/g1_example.mcap` (a later block may use what an
/// earlier one wrote), and every line shown under a command, but `…`, is a line that command
/// prints (on stdout or stderr) today.
#[test]
fn readme_tour_prints_what_the_readme_shows() {
    let blocks: Vec<_> = common::doc_blocks("README.md", "text")
        .into_iter()
        .filter(|b| b.first().is_some_and(|l| l.starts_with("$ g1viz ")))
        .collect();
    assert!(
        blocks.len() >= 5,
        "the README's tour has {} blocks",
        blocks.len()
    );
    let tmp = tempfile::tempdir().unwrap();
    std::fs::create_dir(tmp.path().join("examples")).unwrap();
    std::fs::copy(example(), tmp.path().join("examples/g1_example.mcap")).unwrap();
    let mut shown = 0;
    for block in &blocks {
        let mut printed = String::new();
        for line in block {
            if let Some(cmd) = line.strip_prefix("$ g1viz ") {
                let args: Vec<&str> = cmd.split_whitespace().collect();
                let (out, err) = ok(tmp.path(), &args);
                printed = format!("{out}{err}");
            } else if !line.trim().is_empty() && line != "…" {
                shown += 1;
                assert!(
                    printed.lines().any(|l| l == line),
                    "the README shows a line the command does not print:\n  {line}\noutput:\n{printed}"
                );
            }
        }
    }
    assert!(shown >= 20, "{shown} lines shown");
}

/// The whole workflow through the binary: simulate an identification and a hold-out session,
/// identify (with hold-out and report), validate, simulate the hold-out's twin, diagnose it
/// against the identified model with every output.
#[test]
fn workflow_simulate_identify_validate_diagnose() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    ok(
        d,
        &[
            "simulate", "--preset", "smoke", "--seed", "5", "-o", "id.mcap",
        ],
    );
    ok(
        d,
        &[
            "simulate", "--preset", "holdout", "--seed", "6", "-o", "ho.mcap",
        ],
    );
    let truth = json(&d.join("ho.truth.json"));
    assert_eq!(truth["trials"].as_array().unwrap().len(), 46);

    ok(
        d,
        &[
            "identify",
            "id.mcap",
            "-o",
            "model.json",
            "--holdout",
            "ho.mcap",
            "--report",
            "id_report",
        ],
    );
    let model = json(&d.join("model.json"));
    assert_eq!(model["schema_version"], 1);
    let theta: Vec<f64> = model["theta"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(theta.len(), 49);
    // The constraints of the paper's least squares hold in the written model.
    assert!(theta[..7].iter().all(|a| *a >= 1.0 - 1e-9), "a: {theta:?}");
    assert!(theta[7..].iter().all(|x| *x >= -1e-9), "b..e: {theta:?}");
    let report = std::fs::read_to_string(d.join("id_report/report.md")).unwrap();
    for img in report
        .lines()
        .filter_map(|l| l.split("](").nth(1))
        .filter_map(|rest| rest.split(')').next())
        .filter(|p| p.ends_with(".png"))
    {
        assert!(
            d.join("id_report").join(img).is_file(),
            "report links missing {img}"
        );
    }
    assert!(report.contains(".png"), "identification report has figures");
    assert_verdict_first(&report, &["## Result"], "## Fit quality");
    assert!(report.contains("Where the power goes"), "{report}");

    let (out, _) = ok(
        d,
        &["validate", "--model", "model.json", "ho.mcap", "--json"],
    );
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let r2 = v["trial_level_aligned"]["r2"].as_f64().unwrap();
    assert!(r2 > 0.9, "hold-out per-trajectory R² {r2}");

    ok(d, &["simulate", "--like", "ho.mcap", "-o", "twin.mcap"]);
    let mut args = vec![
        "diagnose",
        "ho.mcap",
        "--model",
        "model.json",
        "--json",
        "diag.json",
        "--report",
        "diag_report",
        "--counterpart",
        "twin.mcap",
    ];
    if cfg!(feature = "viz") {
        // Every sample (a session this long is capped by default).
        args.extend(["--save", "diag.rrd", "--max-rate", "0"]);
    }
    let (out, _) = ok(d, &args);
    assert!(out.contains("Counterpart (twin.mcap"), "{out}");
    let diag = json(&d.join("diag.json"));
    // Every hypothesis of the library is scored; nothing was concealed, so nothing is claimed.
    assert!(diag["hypotheses"].as_array().unwrap().len() >= 9, "{diag}");
    assert_eq!(
        diag["accepted"].as_array().unwrap().len(),
        0,
        "null session: {out}"
    );
    assert!(diag["counterpart"]["matched_samples"].as_u64().unwrap() > 10_000);
    let report = std::fs::read_to_string(d.join("diag_report/report.md")).unwrap();
    // At least one verdict section; none empty here: "Supporting figures" always has the
    // base model's quality.
    assert_verdict_first(
        &report,
        &["## Supporting figures"],
        "## Where the model is wrong",
    );
    assert_diagnosis_json_verdict_first(&d.join("diag.json"));
    if cfg!(feature = "viz") {
        assert!(
            std::fs::read(d.join("diag.rrd"))
                .unwrap()
                .starts_with(b"RRF2")
        );
    }
    if cfg!(feature = "viz") {
        // Two sessions joined: the .rrd is streamed part by part on the joined clock.
        let (out, _) = ok(
            d,
            &[
                "diagnose",
                "ho.mcap",
                "twin.mcap",
                "--model",
                "model.json",
                "--save",
                "joined.rrd",
                "--max-rate",
                "0",
            ],
        );
        assert!(out.contains("wrote joined.rrd"), "{out}");
        let joined = std::fs::metadata(d.join("joined.rrd")).unwrap().len();
        let single = std::fs::metadata(d.join("diag.rrd")).unwrap().len();
        assert!(
            joined > single * 3 / 2,
            "two sessions' replay {joined} B, one session's {single} B"
        );
        // A rate cap keeps a long session's .rrd small enough for the web viewer.
        let (out, _) = ok(
            d,
            &[
                "diagnose",
                "ho.mcap",
                "--model",
                "model.json",
                "--save",
                "small.rrd",
                "--max-rate",
                "5",
                "--pose-rate",
                "2",
                "--open-tab",
                "Diagnosis",
            ],
        );
        assert!(out.contains("wrote small.rrd"), "{out}");
        let small = std::fs::metadata(d.join("small.rrd")).unwrap().len();
        assert!(
            small * 4 < single,
            "capped replay {small} B, full one {single} B"
        );
        // The replay options need --save (a usage error, exit status 2).
        let o = run(d, &["diagnose", "ho.mcap", "--open-tab", "Diagnosis"]);
        let (_, err) = text(&o);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(err.contains("--save"), "{err}");
    }
    // Inputs are never modified; outputs do not leave temporary files behind.
    let names: Vec<String> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        names.iter().all(|n| !n.contains(".tmp")),
        "leftover temporary files: {names:?}"
    );
}

/// `info --json` on the shared session (written by the independent Python generator): message
/// counts per topic as its truth file states them.
#[test]
fn info_json_counts_match_the_independent_generator() {
    let (Some(mcap), Some(truth)) = (
        common::shared_recording("g1_smoke.mcap"),
        common::shared_recording("g1_smoke.truth.json"),
    ) else {
        return;
    };
    let truth = json(&truth);
    let (out, _) = ok(&crate_dir(), &["info", mcap.to_str().unwrap(), "--json"]);
    let info: serde_json::Value = serde_json::from_str(&out).unwrap();
    let count = |topic: &str| {
        info["container"]["topics"]
            .as_array()
            .unwrap()
            .iter()
            .find(|t| t["topic"] == topic)
            .unwrap_or_else(|| panic!("{topic} listed"))["count"]
            .as_u64()
            .unwrap()
    };
    let counts = &truth["message_counts"];
    for (topic, key) in [
        ("/lowstate", "lowstate"),
        ("/arm_sdk", "arm_sdk"),
        ("/lf/bmsstate", "bms"),
        ("/lf/mainboardstate", "mbs"),
    ] {
        assert_eq!(Some(count(topic)), counts[key].as_u64(), "{topic}");
    }
    // The arm signals, counted in one streamed pass: one per message of each topic.
    for (series, key) in [
        ("state", "lowstate"),
        ("command", "arm_sdk"),
        ("mbs_power", "mbs"),
        ("bms_power", "bms"),
    ] {
        assert_eq!(
            info["signals"][series]["count"].as_u64(),
            counts[key].as_u64(),
            "{series}"
        );
    }
    assert!((info["signals"]["state"]["rate_hz"].as_f64().unwrap() - 100.0).abs() < 0.5);
}

#[test]
fn bad_input_ends_in_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();

    let err = fails(d, &["info", "missing.mcap"]);
    assert!(err.contains("missing.mcap"), "{err}");

    std::fs::write(d.join("garbage.mcap"), b"this is not a recording at all").unwrap();
    let err = fails(d, &["info", "garbage.mcap"]);
    assert!(
        err.contains("garbage.mcap") && err.contains("byte offset 0"),
        "{err}"
    );
    let err = fails(d, &["identify", "garbage.mcap", "-o", "g.json"]);
    assert!(err.contains("garbage.mcap"), "{err}");
    assert!(!d.join("g.json").exists(), "no output from a failed run");

    // Cut inside the first chunk: nothing is readable. `info` reports the empty file and the
    // damage; reading it for a job fails and says where the damage is.
    let bytes = std::fs::read(example()).unwrap();
    std::fs::write(d.join("cut.mcap"), &bytes[..bytes.len() / 10]).unwrap();
    let (out, _) = ok(d, &["info", "cut.mcap"]);
    assert!(
        out.contains("messages:   0") && out.contains("warning: cut.mcap: damaged at byte offset"),
        "{out}"
    );
    let err = fails(d, &["identify", "cut.mcap", "-o", "cut.json"]);
    assert!(
        err.contains("cut.mcap") && err.contains("byte offset"),
        "{err}"
    );
    if cfg!(feature = "viz") {
        let err = fails(d, &["replay", "cut.mcap", "--save", "cut.rrd"]);
        assert!(
            err.contains("cut.mcap") && err.contains("byte offset"),
            "{err}"
        );
        assert!(!d.join("cut.rrd").exists());
        let err = fails(d, &["replay", example().to_str().unwrap()]);
        assert!(err.contains("--save"), "no sink named: {err}");
        std::fs::write(d.join("garbage.rrd"), b"old").unwrap();
        let err = fails(d, &["replay", "garbage.mcap", "--save", "garbage.rrd"]);
        assert!(err.contains("byte offset 0"), "{err}");
        assert_eq!(
            std::fs::read(d.join("garbage.rrd")).unwrap(),
            b"old",
            "a failed replay leaves an existing output alone"
        );
    }

    let err = fails(
        d,
        &[
            "simulate", "--preset", "tiny", "--effect", "bogus=1", "-o", "x.mcap",
        ],
    );
    assert!(err.contains("bogus") && err.contains("braking"), "{err}");

    std::fs::write(
        d.join("bad.toml"),
        "[[signal]]\nname = \"tau.elbow\"\ntopic = \"/lowstate\"\nfield = \"motor_state[18].no_such_field\"\n",
    )
    .unwrap();
    let err = fails(
        d,
        &[
            "identify",
            example().to_str().unwrap(),
            "--signals",
            "bad.toml",
            "-o",
            "m.json",
        ],
    );
    assert!(
        err.contains("no_such_field") && err.contains("/lowstate"),
        "{err}"
    );
    assert!(!d.join("m.json").exists());

    let err = fails(
        d,
        &[
            "validate",
            "--model",
            "missing.json",
            example().to_str().unwrap(),
        ],
    );
    assert!(err.contains("missing.json"), "{err}");

    std::fs::write(
        d.join("base.toml"),
        "sdk_index_base = 18446744073709551615\n",
    )
    .unwrap();
    let err = fails(
        d,
        &[
            "identify",
            example().to_str().unwrap(),
            "--signals",
            "base.toml",
        ],
    );
    assert!(err.contains("sdk_index_base"), "{err}");
}

/// No command writes over what it reads: a session, a model, a bag folder's files, another
/// output of the same run; a session given twice is refused (it would count double).
#[test]
fn outputs_never_overwrite_inputs() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    std::fs::copy(example(), d.join("s.mcap")).unwrap();
    std::fs::write(d.join("m.json"), "not read before the check").unwrap();
    let before = std::fs::read(d.join("s.mcap")).unwrap();
    for (args, said) in [
        (
            &["identify", "s.mcap", "-o", "s.mcap"][..],
            "model file s.mcap",
        ),
        (
            &["identify", "s.mcap", "-o", "x.json", "--report", "./s.mcap"],
            "report folder",
        ),
        (
            &["identify", "s.mcap", "./s.mcap", "-o", "x.json"],
            "same recording",
        ),
        (
            &["identify", "s.mcap", "--holdout", "s.mcap", "-o", "x.json"],
            "same recording",
        ),
        (
            &[
                "diagnose", "s.mcap", "--model", "m.json", "--json", "m.json",
            ],
            "diagnosis JSON m.json",
        ),
        (
            &["diagnose", "s.mcap", "--json", "o.json", "--save", "o.json"],
            "same file",
        ),
        (
            &["diagnose", "s.mcap", "--counterpart", "s.mcap"],
            "same recording",
        ),
        (
            &[
                "simulate", "--preset", "tiny", "--model", "m.json", "-o", "m.json",
            ],
            "simulated session m.json",
        ),
        (
            &["simulate", "--like", "s.mcap", "-o", "s.mcap"],
            "over the input",
        ),
    ] {
        let err = fails(d, args);
        assert!(err.contains(said), "{args:?}: {err}");
    }
    assert_eq!(std::fs::read(d.join("s.mcap")).unwrap(), before);
    assert_eq!(
        std::fs::read_to_string(d.join("m.json")).unwrap(),
        "not read before the check"
    );
    assert!(!d.join("x.json").exists() && !d.join("o.json").exists());

    // A ROS 2 bag folder: its metadata.yaml and .db3 files are inputs too.
    let Some(db3) = common::shared_recording("g1_smoke_db3") else {
        return;
    };
    let bag = d.join("bag");
    std::fs::create_dir(&bag).unwrap();
    for e in std::fs::read_dir(&db3).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), bag.join(e.file_name())).unwrap();
    }
    let metadata = std::fs::read(bag.join("metadata.yaml")).unwrap();
    let db3_file = std::fs::read_dir(&bag)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|x| x == "db3"))
        .unwrap();
    for input in [bag.clone(), db3_file] {
        let err = fails(
            d,
            &[
                "identify",
                input.to_str().unwrap(),
                "-o",
                "bag/metadata.yaml",
            ],
        );
        assert!(err.contains("over the input"), "{err}");
    }
    assert_eq!(std::fs::read(bag.join("metadata.yaml")).unwrap(), metadata);
}

/// A damaged recording replays up to the damage with a warning naming the byte offset; a replay
/// never overwrites its input.
#[cfg(feature = "viz")]
#[test]
fn damaged_recording_replays_up_to_the_damage_and_input_is_protected() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let bytes = std::fs::read(example()).unwrap();
    std::fs::write(d.join("half.mcap"), &bytes[..bytes.len() / 2]).unwrap();
    let (_, err) = ok(d, &["replay", "half.mcap", "--save", "half.rrd"]);
    assert!(
        err.contains("warning: ") && err.contains("half.mcap") && err.contains("byte offset"),
        "{err}"
    );
    let samples: usize = err
        .split("half.rrd (")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("sample count in {err}"));
    assert!(samples > 1000 && samples < 8248, "{samples} samples");

    let before = std::fs::read(d.join("half.mcap")).unwrap();
    let err = fails(d, &["replay", "half.mcap", "--save", "./half.mcap"]);
    assert!(err.contains("half.mcap"), "{err}");
    assert_eq!(std::fs::read(d.join("half.mcap")).unwrap(), before);
}

/// `diagnose --counterpart` with a session that is not the recording's twin is refused.
#[test]
fn counterpart_of_another_session_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    ok(
        d,
        &[
            "simulate", "--preset", "holdout", "--seed", "8", "-o", "a.mcap",
        ],
    );
    ok(
        d,
        &[
            "simulate", "--preset", "tiny", "--seed", "9", "-o", "b.mcap",
        ],
    );
    let err = fails(
        d,
        &[
            "diagnose",
            "a.mcap",
            "--model",
            "paper",
            "--counterpart",
            "b.mcap",
        ],
    );
    assert!(
        err.contains("b.mcap") && err.contains("simulate --like"),
        "{err}"
    );
}

/// Inputs that are not regular files (a device, a FIFO) are refused at once instead of being read
/// without end; option values outside their physical range are refused by the parser (exit 2).
#[cfg(unix)]
#[test]
fn devices_and_out_of_range_options_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let ex = example();
    let ex = ex.to_str().unwrap();
    let err = fails(d, &["validate", "--model", "/dev/zero", ex]);
    assert!(
        err.contains("/dev/zero") && err.contains("not a regular file"),
        "{err}"
    );
    let err = fails(d, &["info", "/dev/null"]);
    assert!(err.contains("not a regular file"), "{err}");
    for args in [
        &[
            "simulate",
            "--preset",
            "tiny",
            "-o",
            "x.mcap",
            "--t-start=NaN",
        ][..],
        &[
            "simulate",
            "--preset",
            "tiny",
            "-o",
            "x.mcap",
            "--t-start=-300",
        ],
        &["replay", ex, "--save", "x.rrd", "--pose-rate=-5"],
        &["identify", ex, "--imu-threshold=NaN"],
        &["identify", ex, "--n-sigma=0"],
    ] {
        let o = run(d, args);
        let (_, err) = text(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains("invalid value"), "{args:?}: {err}");
    }
    let err = fails(
        d,
        &[
            "simulate",
            "--preset",
            "tiny",
            "--effect",
            "braking=5",
            "-o",
            "x.mcap",
        ],
    );
    assert!(err.contains("at most 1"), "{err}");
    assert!(!d.join("x.mcap").exists() && !d.join("x.rrd").exists());
}

/// A session too short to estimate the power sensor's timing (the shipped example: 6 trials)
/// says how many readings it found and what it needs; given the timing it identifies, and says
/// the model is not identifiable from so few rows.
#[test]
fn identify_on_a_short_session_names_counts_and_a_way_out() {
    let dir = tempfile::tempdir().unwrap();
    let example = crate_dir().join("examples/g1_example.mcap");
    let example = example.to_str().unwrap();
    let err = fails(dir.path(), &["identify", example, "-o", "m.json"]);
    assert!(
        err.contains("only 42 MBS power readings inside the 6 trajectory windows")
            && err.contains("needs more than 49")
            && err.contains("--window"),
        "{err}"
    );
    assert!(!dir.path().join("m.json").exists());
    let (out, _) = ok(
        dir.path(),
        &[
            "identify", example, "-o", "m.json", "--window", "0.2", "--lag", "0",
        ],
    );
    assert!(out.contains("42 rows for 49 parameters"), "{out}");
    assert_eq!(json(&dir.path().join("m.json"))["schema_version"], 1);
    // Half the timing is refused by the parser.
    let o = run(dir.path(), &["identify", example, "--window", "0.2"]);
    assert_eq!(o.status.code(), Some(2));
}

/// `diagnose` on the shipped example (7 trials) says at once that the session is too short for
/// the cross-validation, whether or not the sensor window is given (it used to ask for
/// `--sensor-window` first, then refuse the trial count).
#[test]
fn diagnose_on_the_example_names_the_trial_count_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let example = crate_dir().join("examples/g1_example.mcap");
    let example = example.to_str().unwrap();
    for extra in [&[][..], &["--sensor-window", "0.2"][..]] {
        let args = [&["diagnose", example][..], extra].concat();
        let err = fails(dir.path(), &args);
        assert!(
            err.contains("only 7 trials with a pre-idle (need at least 20 usable for 10-fold")
                && !err.contains("--sensor-window"),
            "{err}"
        );
    }
}

/// `simulate --help` lists every effect the simulator accepts (the simulator's own list, which
/// its unit test ties to `--effect`'s parser), not a hand-kept subset (it listed 11 of 17).
#[test]
fn simulate_help_lists_every_effect() {
    let (out, _) = ok(&crate_dir(), &["simulate", "--help"]);
    for name in g1viz::sim::EFFECT_NAMES {
        assert!(out.contains(name), "{name} missing from:\n{out}");
    }
}

/// `diagnose --save` draws the arm at replay's pose rate by default, 30 Hz (issue 30: it kept
/// every sample), and both `--help`s give that default.
#[test]
fn diagnose_and_replay_share_the_pose_rate_default() {
    let default_of = |command: &str| {
        let (out, _) = ok(&crate_dir(), &[command, "--help"]);
        let option = out.split("--pose-rate <HZ>").nth(1).unwrap_or_default();
        let option = option.split("\n  -").next().unwrap_or_default();
        let default = option.split("[default: ").nth(1).unwrap_or_default();
        default.split(']').next().unwrap_or_default().to_owned()
    };
    assert_eq!(default_of("replay"), "30");
    assert_eq!(default_of("diagnose"), "30");
}

/// A missing input gives the operating system's reason, whichever command reads it.
#[test]
fn a_missing_file_gives_the_os_reason() {
    let dir = tempfile::tempdir().unwrap();
    for args in [
        &["info", "missing.mcap"][..],
        &["replay", "missing.mcap", "--save", "x.rrd"][..],
        &["identify", "missing.mcap", "-o", "m.json"][..],
        &["diagnose", "missing.mcap"][..],
    ] {
        let err = fails(dir.path(), args);
        assert!(
            err.contains("missing.mcap") && err.contains("No such file or directory"),
            "{args:?}: {err}"
        );
    }
}

/// docs/simulation.md: "The example session … was made with `g1viz simulate --preset example --seed 1 -o
/// examples/g1_example.mcap` and is reproduced byte for byte by that command" — the command as
/// printed, into a scratch folder: the session and its truth sidecar equal the shipped files.
#[test]
fn readme_example_session_is_reproduced_byte_for_byte() {
    let page = common::doc_page("docs/simulation.md");
    let command = "g1viz simulate --preset example --seed 1 -o examples/g1_example.mcap";
    assert!(
        page.contains(&format!("`{command}`")),
        "docs/simulation.md no longer names {command:?}"
    );
    let tmp = tempfile::tempdir().unwrap();
    std::fs::create_dir(tmp.path().join("examples")).unwrap();
    let args: Vec<&str> = command.split_whitespace().skip(1).collect();
    ok(tmp.path(), &args);
    for name in ["g1_example.mcap", "g1_example.truth.json"] {
        let (made, shipped) = (
            std::fs::read(tmp.path().join("examples").join(name)).unwrap(),
            std::fs::read(crate_dir().join("examples").join(name)).unwrap(),
        );
        let first_difference = made.iter().zip(&shipped).position(|(a, b)| a != b);
        assert!(
            made == shipped,
            "examples/{name}: regenerated {} bytes vs shipped {}, first difference at byte {:?}",
            made.len(),
            shipped.len(),
            first_difference
        );
    }
}

/// The identification table of docs/model.md through the binary, as a user runs it on the shared files:
/// `identify g1_smoke.mcap --holdout g1_holdout.mcap`, then `validate --json` of the written model
/// on the hold-out — per reading R² 0.987, per trajectory like for like R² 0.973, the paper's way
/// R² 0.826 (tests/identify.rs holds the same figures through the library).
#[test]
fn readme_identification_figures_through_the_binary() {
    let (Some(smoke), Some(holdout)) = (
        common::shared_recording("g1_smoke.mcap"),
        common::shared_recording("g1_holdout.mcap"),
    ) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (smoke, holdout) = (smoke.to_str().unwrap(), holdout.to_str().unwrap());
    ok(
        tmp.path(),
        &["identify", smoke, "-o", "model.json", "--holdout", holdout],
    );
    let (out, _) = ok(
        tmp.path(),
        &["validate", "--model", "model.json", holdout, "--json"],
    );
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let r2 = |level: &str| {
        v[level]["r2"]
            .as_f64()
            .unwrap_or_else(|| panic!("{level}: {v}"))
    };
    common::assert_figure(
        PAGE,
        "hold-out R² per reading",
        r2("reading_level"),
        "0.987",
    );
    common::assert_figure(
        PAGE,
        "hold-out R² like for like",
        r2("trial_level_aligned"),
        "0.973",
    );
    common::assert_figure(
        PAGE,
        "hold-out R² the paper's way",
        r2("trial_level"),
        "0.826",
    );
}

/// Several sessions of one robot as one data set: a folder stands for the recordings in it;
/// identify gives the same model from the folder as from the files listed, and diagnose joins
/// the sessions keeping every trial (the truth files' 2 × 24 trials are all accounted for).
#[test]
fn a_folder_of_sessions_is_one_data_set() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    std::fs::create_dir(d.join("robot")).unwrap();
    for seed in ["11", "12"] {
        let out = format!("robot/s{seed}.mcap");
        ok(
            d,
            &["simulate", "--preset", "smoke", "--seed", seed, "-o", &out],
        );
    }
    let (from_folder, _) = ok(d, &["identify", "robot", "-o", "a.json"]);
    let (from_files, _) = ok(
        d,
        &[
            "identify",
            "robot/s11.mcap",
            "robot/s12.mcap",
            "-o",
            "b.json",
        ],
    );
    assert_eq!(
        json(&d.join("a.json"))["theta"],
        json(&d.join("b.json"))["theta"]
    );
    assert!(from_folder.contains("robot/s11.mcap") && from_folder.contains("robot/s12.mcap"));
    assert_eq!(
        from_folder
            .lines()
            .filter(|l| l.contains("trials ("))
            .count(),
        from_files
            .lines()
            .filter(|l| l.contains("trials ("))
            .count()
    );

    ok(d, &["diagnose", "robot", "--json", "diag.json"]);
    let diag = json(&d.join("diag.json"));
    let truth_trials: usize = ["s11", "s12"]
        .iter()
        .map(|s| {
            json(&d.join(format!("robot/{s}.truth.json")))["trials"]
                .as_array()
                .unwrap()
                .len()
        })
        .sum();
    assert_eq!(truth_trials, 48);
    let used = diag["n_trials"].as_u64().unwrap() as usize;
    let left_out = diag["rejected"].as_array().unwrap().len();
    assert_eq!(used + left_out, truth_trials, "{diag}");

    std::fs::create_dir(d.join("empty")).unwrap();
    let err = fails(d, &["identify", "empty"]);
    assert!(err.contains("no recordings in it"), "{err}");
}

/// `examples/predict_power.rs`, the library's front door, runs on the shipped example with the
/// paper's model: one prediction per `/lowstate` message (the container's own count), a finite,
/// positive mean net power; a missing model is a clean error.
#[test]
fn predict_power_example_runs() {
    let exe = std::env::current_exe().unwrap();
    let example = exe
        .parent()
        .and_then(Path::parent)
        .map(|d| d.join("examples").join("predict_power"))
        .unwrap();
    if !example.exists() {
        // `cargo test` builds the examples; a run of this test binary alone may not have.
        common::skip("examples/predict_power not built (run `cargo test`)");
        return;
    }
    let o = Command::new(&example)
        .current_dir(crate_dir())
        .args(["paper", "examples/g1_example.mcap"])
        .output()
        .unwrap();
    let (out, err) = text(&o);
    assert!(o.status.success(), "{out}\n{err}");
    let lowstate = example_lowstate_messages();
    assert!(out.starts_with(&format!("{lowstate} samples")), "{out}");
    let mean: f64 = out
        .split("mean ")
        .nth(1)
        .and_then(|m| m.trim().trim_end_matches('W').trim().parse().ok())
        .unwrap_or_else(|| panic!("no mean in {out}"));
    assert!(mean.is_finite() && mean > 0.0, "{out}");
    let o = Command::new(&example)
        .current_dir(crate_dir())
        .args(["absent.json", "examples/g1_example.mcap"])
        .output()
        .unwrap();
    assert!(!o.status.success() && text(&o).1.contains("absent.json"));
}

/// Fleet rows: `export rows` of two robots' sessions, read back by the independent Python
/// `pyarrow` (schema, row counts, an aggregation across robots equal to ours), and
/// `identify --rows` gives the model `identify` gives from the sessions themselves (same rows,
/// same rejected trials).
#[test]
fn exported_rows_are_read_by_pyarrow_and_refit_to_the_same_model() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    for (robot, seed) in [("a", "11"), ("b", "12")] {
        std::fs::create_dir(d.join(robot)).unwrap();
        let out = format!("{robot}/s{seed}.mcap");
        ok(
            d,
            &["simulate", "--preset", "smoke", "--seed", seed, "-o", &out],
        );
        let (said, _) = ok(
            d,
            &[
                "export",
                "rows",
                robot,
                "-o",
                &format!("{robot}.parquet"),
                "--robot",
                robot,
            ],
        );
        assert!(said.contains(&format!("robot {robot}")), "{said}");
    }
    ok(d, &["identify", "a", "-o", "from_session.json"]);
    ok(
        d,
        &["identify", "--rows", "a.parquet", "-o", "from_rows.json"],
    );
    let theta = |f: &str| -> Vec<f64> {
        serde_json::from_value(json(&d.join(f))["theta"].clone()).unwrap()
    };
    for (s, r) in theta("from_session.json")
        .iter()
        .zip(theta("from_rows.json"))
    {
        assert!((s - r).abs() <= 1e-9 * s.abs().max(1.0), "{s} vs {r}");
    }
    // The table names its joints: a signal map of the other arm refuses it, naming both.
    std::fs::write(d.join("right.toml"), "arm = \"right\"\n").unwrap();
    let err = fails(
        d,
        &[
            "identify",
            "--rows",
            "a.parquet",
            "--signals",
            "right.toml",
            "-o",
            "r.json",
        ],
    );
    assert!(
        err.contains("left_elbow_joint")
            && err.contains("right_elbow_joint")
            && err.contains("a.parquet"),
        "{err}"
    );
    assert!(!d.join("r.json").exists());

    let ours: Vec<(String, usize, f64)> = ["a", "b"]
        .iter()
        .map(|robot| {
            let rows = g1viz::rows::read_table(&d.join(format!("{robot}.parquet")))
                .unwrap()
                .rows;
            let kept: Vec<_> = rows.iter().filter(|r| r.rejected_by.is_none()).collect();
            let mean = kept.iter().map(|r| r.row.y).sum::<f64>() / kept.len() as f64;
            (robot.to_string(), kept.len(), mean)
        })
        .collect();
    let script = r#"
import sys
try:
    import pyarrow as pa, pyarrow.parquet as pq, pyarrow.compute as pc
except ImportError:
    sys.exit(3)
import json
for p in sys.argv[1:]:
    print("names", p, " ".join(json.loads(pq.read_metadata(p).metadata[b"g1viz:joint_names"])))
t = pa.concat_tables([pq.read_table(p) for p in sys.argv[1:]])
for name in ["robot", "session", "trial", "t_s", "y_w", "phi_a0", "phi_e56", "temp_c_3", "sigma_omega", "rejected"]:
    assert name in t.column_names, name
kept = t.filter(pc.invert(t["rejected"]))
g = kept.group_by("robot").aggregate([("y_w", "count"), ("y_w", "mean")]).sort_by("robot")
for r, n, m in zip(g["robot"].to_pylist(), g["y_w_count"].to_pylist(), g["y_w_mean"].to_pylist()):
    print(f"{r} {n} {m!r}")
"#;
    let mut cmd = Command::new("python3");
    cmd.current_dir(d)
        .args(["-c", script, "a.parquet", "b.parquet"]);
    let o = common::output_within(&mut cmd, common::TOOL_LIMIT).unwrap();
    if o.status.code() == Some(3) {
        common::skip("python3 has no pyarrow (pip install pyarrow)");
        return;
    }
    let (out, err) = text(&o);
    assert!(o.status.success(), "{out}\n{err}");
    let names = g1viz::signals::SignalMap::g1_left_arm()
        .joint_names
        .join(" ");
    for robot in ["a", "b"] {
        let line = format!("names {robot}.parquet {names}");
        assert!(out.lines().any(|l| l == line), "{out}");
    }
    let theirs: Vec<(String, usize, f64)> = out
        .lines()
        .filter(|l| !l.starts_with("names "))
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            (
                f[0].to_string(),
                f[1].parse().unwrap(),
                f[2].parse().unwrap(),
            )
        })
        .collect();
    assert_eq!(theirs.len(), 2, "{out}");
    for ((r1, n1, m1), (r2, n2, m2)) in ours.iter().zip(&theirs) {
        assert_eq!((r1, n1), (r2, n2));
        assert!((m1 - m2).abs() < 1e-9, "{r1}: {m1} vs {m2}");
    }
}

/// The report opens with its verdict: each of `verdict` headings comes before the first table
/// and before `tables` (the first table section); no line of a code block is wider than 100
/// characters (the page cuts them), and no markdown line is cut mid-word by the writer.
fn assert_verdict_first(report: &str, verdict: &[&str], tables: &str) {
    let first_table = report
        .lines()
        .position(|l| l.starts_with('|'))
        .expect("the report has tables");
    let line_of = |h: &str| report.lines().position(|l| l.starts_with(h));
    for h in verdict {
        let at = line_of(h).unwrap_or_else(|| panic!("no {h:?} in\n{report}"));
        assert!(at < first_table, "{h:?} after the first table:\n{report}");
    }
    let t = line_of(tables).unwrap_or_else(|| panic!("no {tables:?} in\n{report}"));
    assert!(verdict.iter().all(|h| line_of(h).unwrap() < t), "{report}");
    let mut in_code = false;
    for line in report.lines() {
        if line.starts_with("```") {
            in_code = !in_code;
        } else if in_code {
            assert!(
                line.chars().count() <= 100,
                "code line cut by the page: {line}"
            );
        }
    }
}

/// `diagnosis.json` lists its top-level fields verdict first: the summary, what was accepted,
/// the refit and what was found beyond the library before the hypotheses' scores, the counts,
/// the tables and the replay data (read from the file's text: a JSON map has no order).
fn assert_diagnosis_json_verdict_first(path: &std::path::Path) {
    let text = std::fs::read_to_string(path).unwrap();
    let keys: Vec<&str> = text
        .lines()
        .filter_map(|l| l.strip_prefix("  \""))
        .filter_map(|l| l.split('"').next())
        .collect();
    let at = |k: &str| {
        keys.iter()
            .position(|x| *x == k)
            .unwrap_or_else(|| panic!("no top-level {k:?} in {keys:?}"))
    };
    // `discovery` is absent when discovery is switched off.
    let verdict: Vec<&str> = [
        "summary",
        "accepted",
        "final_model",
        "forms",
        "confounded",
        "discovery",
    ]
    .into_iter()
    .filter(|k| *k != "discovery" || keys.contains(k))
    .collect();
    let support = [
        "hypotheses",
        "unexplained",
        "n_trials",
        "breakdowns",
        "worst_trials",
        "replay",
    ];
    for w in verdict.windows(2).chain(support.windows(2)) {
        assert!(at(w[0]) < at(w[1]), "{} before {}: {keys:?}", w[0], w[1]);
    }
    assert!(at(verdict[verdict.len() - 1]) < at(support[0]), "{keys:?}");
}
