//! Reader and signal tests: the shared smoke recording (written by the Python mcap-ros2 library)
//! against its truth JSON and an independent Python read, and damaged/odd inputs.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use g1viz::read::decode::decode;
use g1viz::read::mcap::McapSource;
use g1viz::read::{Encoding, FieldExtractor, FieldPath, MessageSource, OpenOptions, Session};
use g1viz::signals::{SignalMap, load_recording};

/// The shared folder (`G1VIZ_SHARED` or `<crate>/../shared`), if present.
fn shared() -> Option<PathBuf> {
    let dir = std::env::var_os("G1VIZ_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared"));
    let ok = dir.join("recordings/g1_smoke.mcap").is_file();
    if !ok {
        eprintln!(
            "note: {} not found; skipping test that needs the shared recordings",
            dir.display()
        );
    }
    ok.then_some(dir)
}

fn smoke() -> Option<(PathBuf, serde_json::Value)> {
    let dir = shared()?;
    let truth: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("recordings/g1_smoke.truth.json")).ok()?,
    )
    .ok()?;
    Some((dir.join("recordings/g1_smoke.mcap"), truth))
}

/// Truth `message_counts` keyed by topic name.
fn truth_counts(truth: &serde_json::Value) -> BTreeMap<String, u64> {
    let topics = truth["topics"].as_object().expect("truth topics");
    truth["message_counts"]
        .as_object()
        .expect("truth message_counts")
        .iter()
        .map(|(k, v)| {
            (
                topics[k]["topic"].as_str().expect("topic").to_string(),
                v.as_u64().expect("count"),
            )
        })
        .collect()
}

#[test]
fn smoke_info_matches_truth_counts_and_rates() {
    let Some((path, truth)) = smoke() else { return };
    let mut session = Session::open(&path, &OpenOptions::default()).unwrap();
    let info = session.info().unwrap();
    assert_eq!(info.format, "mcap");
    let counts: BTreeMap<String, u64> = info
        .topics
        .iter()
        .map(|t| (t.topic.clone(), t.count))
        .collect();
    assert_eq!(counts, truth_counts(&truth));
    for t in &info.topics {
        let expected = if t.topic == "/lowstate" || t.topic == "/arm_sdk" {
            100.0
        } else {
            1.0
        };
        assert!(
            (t.rate_hz - expected).abs() < 0.02 * expected,
            "{}: rate {} Hz",
            t.topic,
            t.rate_hz
        );
        assert_eq!(t.encoding, "cdr");
        assert!(
            t.type_name.starts_with("unitree_hg/msg/"),
            "{}",
            t.type_name
        );
    }
    let duration = (info.end_ns - info.start_ns) as f64 * 1e-9;
    let truth_duration = truth["session"]["duration_s"].as_f64().unwrap();
    assert!(
        (duration - truth_duration).abs() < 0.05,
        "duration {duration} vs {truth_duration}"
    );

    // Counting by actually reading every message must agree too (independent of the statistics).
    let mut read_counts = BTreeMap::<String, u64>::new();
    let mut last = 0u64;
    let summary = session
        .read(None, &mut |m| {
            *read_counts.entry(m.channel.topic.clone()).or_default() += 1;
            assert!(m.log_time_ns >= last, "messages out of log-time order");
            last = m.log_time_ns;
            Ok(())
        })
        .unwrap();
    assert!(
        summary.complete && summary.warnings.is_empty(),
        "{:?}",
        summary.warnings
    );
    assert_eq!(read_counts, truth_counts(&truth));
}

#[test]
fn smoke_recording_signals_and_power() {
    let Some((path, truth)) = smoke() else { return };
    let rec = load_recording(&path, &SignalMap::g1_left_arm(), &OpenOptions::default()).unwrap();
    assert!(rec.warnings.is_empty(), "{:?}", rec.warnings);
    let counts = truth_counts(&truth);
    assert_eq!(rec.state.t.len() as u64, counts["/lowstate"]);
    assert_eq!(rec.state.q.len(), rec.state.t.len());
    assert_eq!(rec.command.t.len() as u64, counts["/arm_sdk"]);
    assert_eq!(rec.mbs.t.len() as u64, counts["/lf/mainboardstate"]);
    assert_eq!(rec.bms.t.len() as u64, counts["/lf/bmsstate"]);
    assert_eq!(rec.start_ns, truth["session"]["start_ns"].as_u64().unwrap());
    assert_eq!(rec.joint_names[3], "left_elbow_joint");
    // First trial's pre-idle (2 s at home): MBS ≈ 120 W rest, BMS ≈ 135 W (truth plant).
    let rest = |p: &g1viz::signals::PowerSeries| {
        let v: Vec<f64> =
            p.t.iter()
                .zip(&p.watts)
                .filter(|(t, _)| **t < 2.0)
                .map(|(_, w)| *w)
                .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    let rest_w = truth["plant"]["P_rest_W"].as_f64().unwrap();
    assert!(
        (rest(&rec.mbs) - rest_w).abs() < 6.0,
        "MBS rest {}",
        rest(&rec.mbs)
    );
    assert!(
        (rest(&rec.bms) - 135.0).abs() < 8.0,
        "BMS rest {}",
        rest(&rec.bms)
    );
    // Rates of the 1 Hz sensors from the Recording's own times.
    let span = rec.mbs.t.last().unwrap() - rec.mbs.t[0];
    assert!(((rec.mbs.t.len() - 1) as f64 / span - 1.0).abs() < 0.02);
    // Temperatures are whole degrees; quaternion has unit norm.
    assert!(
        rec.state
            .temp
            .iter()
            .flatten()
            .all(|t| t.fract() == 0.0 && *t > 0.0 && *t < 120.0)
    );
    let q = rec.state.quat[100];
    assert!(((q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt() - 1.0).abs() < 1e-3);
}

/// Values of the Python reference read (None when python or its packages are missing).
fn python_dump(
    path: &Path,
    topic: &str,
    indices: &[usize],
    fields: &[&str],
) -> Option<serde_json::Value> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/py/dump_mcap.py");
    let idx: Vec<String> = indices.iter().map(ToString::to_string).collect();
    let out = Command::new("python3")
        .arg(script)
        .arg(path)
        .arg(topic)
        .arg(idx.join(","))
        .args(fields)
        .output();
    match out {
        Ok(o) if o.status.success() => {
            Some(serde_json::from_slice(&o.stdout).expect("python JSON"))
        }
        Ok(o) => {
            eprintln!(
                "note: python reference read skipped: {}",
                String::from_utf8_lossy(&o.stderr).trim()
            );
            None
        }
        Err(e) => {
            eprintln!("note: python3 not runnable ({e}); reference read skipped");
            None
        }
    }
}

#[test]
fn smoke_values_equal_independent_python_read() {
    let Some((path, _)) = smoke() else { return };
    let indices = [0usize, 7, 1234];
    let cases: [(&str, &[&str]); 3] = [
        (
            "/lowstate",
            &[
                "motor_state[15].q",
                "motor_state[18].tau_est",
                "motor_state[21].dq",
                "motor_state[16].temperature[0]",
                "imu_state.quaternion[0]",
                "imu_state.gyroscope[2]",
                "tick",
            ],
        ),
        (
            "/arm_sdk",
            &["motor_cmd[17].q", "motor_cmd[29].q", "motor_cmd[15].kp"],
        ),
        (
            "/lf/bmsstate",
            &["bmsvoltage[0]", "current", "cell_vol[3]", "temperature[1]"],
        ),
    ];
    for (topic, fields) in cases {
        let Some(reference) = python_dump(&path, topic, &indices, fields) else {
            return;
        };
        let paths: Vec<FieldPath> = fields
            .iter()
            .map(|f| FieldPath::parse(f).unwrap())
            .collect();
        let mut session = Session::open(&path, &OpenOptions::default()).unwrap();
        let mut ours = Vec::new();
        let mut i = 0;
        session
            .read(Some(&[topic]), &mut |m| {
                if indices.contains(&i) {
                    let ex = FieldExtractor::compile(&m.channel.schema, m.channel.encoding, &paths)
                        .unwrap();
                    assert!(ex.is_constant_offset());
                    let mut fast = vec![0.0; paths.len()];
                    ex.extract(m.data, &mut fast).unwrap();
                    let value = decode(&m.channel.schema, m.channel.encoding, m.data).unwrap();
                    let slow: Vec<f64> = paths
                        .iter()
                        .map(|p| value.get(p).unwrap().as_f64().unwrap())
                        .collect();
                    ours.push((i, m.log_time_ns, fast, slow));
                }
                i += 1;
                Ok(())
            })
            .unwrap();
        let reference = reference.as_array().unwrap();
        assert_eq!(reference.len(), ours.len());
        for (r, (i, t, fast, slow)) in reference.iter().zip(&ours) {
            assert_eq!(r["index"].as_u64().unwrap() as usize, *i);
            assert_eq!(r["log_time"].as_u64().unwrap(), *t, "{topic} #{i} log time");
            for (k, f) in fields.iter().enumerate() {
                let expected = r["values"][*f].as_f64().unwrap();
                assert_eq!(fast[k], expected, "{topic} #{i} {f} (extractor)");
                assert_eq!(slow[k], expected, "{topic} #{i} {f} (full decode)");
            }
        }
    }
}

#[test]
fn not_mcap_is_format_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.mcap");
    std::fs::write(&p, b"hello world, not an mcap").unwrap();
    let err = Session::open(&p, &OpenOptions::default()).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("x.mcap") && msg.contains("magic"), "{msg}");
    assert!(McapSource::open(&p, &OpenOptions::default()).is_err());
    let _ = Encoding::Cdr;
    let _: Option<&dyn MessageSource> = None;
}
