//! Reader and signal tests: the shared smoke recording (written by the Python mcap-ros2 library)
//! against its truth JSON and an independent Python read, and damaged/odd inputs.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use g1viz::read::McapSource;
use g1viz::read::decode;
use g1viz::read::{Encoding, FieldExtractor, FieldPath, MessageSource, OpenOptions, Session};
use g1viz::signals::{SignalMap, load_recording};

fn smoke() -> Option<(PathBuf, serde_json::Value)> {
    let truth_path = common::shared_recording("g1_smoke.truth.json")?;
    let truth: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(&truth_path).expect("g1_smoke.truth.json readable"),
    )
    .expect("g1_smoke.truth.json is JSON");
    Some((common::shared_recording("g1_smoke.mcap")?, truth))
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
    let out = common::output_within(
        Command::new("python3")
            .arg(script)
            .arg(path)
            .arg(topic)
            .arg(idx.join(","))
            .args(fields),
        common::TOOL_LIMIT,
    );
    match out {
        Ok(o) if o.status.success() => {
            Some(serde_json::from_slice(&o.stdout).expect("python JSON"))
        }
        // Exit status 3: the python packages are missing; anything else is a failed read.
        Ok(o) if o.status.code() == Some(3) => {
            common::skip(&format!(
                "python reference read: {}",
                String::from_utf8_lossy(&o.stderr).trim()
            ));
            None
        }
        Ok(o) => panic!(
            "python reference read of {} failed: {}",
            path.display(),
            String::from_utf8_lossy(&o.stderr).trim()
        ),
        Err(e) => {
            common::skip(&format!("python3 not runnable ({e}): reference read"));
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

// ---------------------------------------------------------------------------------------------
// Damaged and unusual files, written from the smoke recording's payloads with the mcap crate.

struct Msg {
    topic: String,
    type_name: String,
    log_time: u64,
    data: Vec<u8>,
}

/// The first `n` messages of each topic of the smoke file.
fn smoke_messages(n: usize) -> Option<Vec<Msg>> {
    let (path, _) = smoke()?;
    let mut session = Session::open(&path, &OpenOptions::default()).unwrap();
    let mut per_topic = BTreeMap::<String, usize>::new();
    let mut out = Vec::new();
    session
        .read(None, &mut |m| {
            let c = per_topic.entry(m.channel.topic.clone()).or_default();
            if *c < n {
                *c += 1;
                out.push(Msg {
                    topic: m.channel.topic.clone(),
                    type_name: m.channel.type_name.clone(),
                    log_time: m.log_time_ns,
                    data: m.data.to_vec(),
                });
            }
            Ok(())
        })
        .unwrap();
    Some(out)
}

/// ROS 2 concatenated schema text of a unitree_hg type from the built-in .msg texts.
fn ros2msg_text(type_name: &str) -> String {
    let root = g1viz::read::builtin_definition(type_name)
        .unwrap()
        .to_string();
    let mut text = root;
    for dep in ["IMUState", "MotorState", "MotorCmd"] {
        text.push_str(&format!("\n{}\nMSG: unitree_hg/{dep}\n", "=".repeat(80)));
        text.push_str(g1viz::read::builtin_definition(&format!("unitree_hg/{dep}")).unwrap());
    }
    text
}

struct Layout<'a> {
    compression: Option<mcap::Compression>,
    summary: bool,
    /// Per topic: (schema encoding, schema text, message encoding) overrides.
    schema: &'a dyn Fn(&Msg) -> (String, String, String),
    mutate: &'a dyn Fn(&Msg) -> Option<Vec<u8>>,
}

fn default_schema(m: &Msg) -> (String, String, String) {
    ("ros2msg".into(), ros2msg_text(&m.type_name), "cdr".into())
}

fn write_mcap(path: &Path, msgs: &[Msg], layout: &Layout) {
    let mut opts = mcap::WriteOptions::new()
        .compression(layout.compression)
        .chunk_size(Some(64 * 1024));
    if !layout.summary {
        opts = opts
            .emit_summary_records(false)
            .emit_statistics(false)
            .emit_chunk_indexes(false)
            .emit_summary_offsets(false)
            .emit_message_indexes(false);
    }
    let mut w = opts
        .create(std::io::BufWriter::new(
            std::fs::File::create(path).unwrap(),
        ))
        .unwrap();
    let mut channels = BTreeMap::<String, u16>::new();
    for (seq, m) in msgs.iter().enumerate() {
        let id = *channels.entry(m.topic.clone()).or_insert_with(|| {
            let (senc, text, menc) = (layout.schema)(m);
            let sid = w.add_schema(&m.type_name, &senc, text.as_bytes()).unwrap();
            w.add_channel(sid, &m.topic, &menc, &BTreeMap::new())
                .unwrap()
        });
        let data = (layout.mutate)(m).unwrap_or_else(|| m.data.clone());
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: seq as u32,
            log_time: m.log_time,
            publish_time: m.log_time,
        };
        w.write_to_known_channel(&header, &data).unwrap();
    }
    w.finish().unwrap();
}

fn plain<'a>() -> Layout<'a> {
    Layout {
        compression: Some(mcap::Compression::Zstd),
        summary: true,
        schema: &default_schema,
        mutate: &|_| None,
    }
}

fn load(path: &Path) -> anyhow::Result<g1viz::signals::Recording> {
    load_recording(path, &SignalMap::g1_left_arm(), &OpenOptions::default())
}

/// Payload offset of `motor_state[15].q` in a LowState CDR message, computed by hand:
/// 4 (encapsulation) + 72 (version, modes, tick, IMUState, first MotorState's mode + padding)
/// + 15 × 56 (MotorState stride).
const LEFT_SHOULDER_Q_OFFSET: usize = 4 + 72 + 15 * 56;

#[test]
fn compressions_and_linear_scan_give_identical_signals() {
    let Some(msgs) = smoke_messages(400) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let reference = {
        let p = dir.path().join("zstd.mcap");
        write_mcap(&p, &msgs, &plain());
        let rec = load(&p).unwrap();
        assert!(
            McapSource::open(&p, &OpenOptions::default())
                .unwrap()
                .has_index()
        );
        rec
    };
    assert_eq!(reference.state.t.len(), 400);
    // The hand-computed byte offset agrees with the schema-driven extractor.
    let first = msgs.iter().find(|m| m.topic == "/lowstate").unwrap();
    let raw = f32::from_le_bytes(
        first.data[LEFT_SHOULDER_Q_OFFSET..LEFT_SHOULDER_Q_OFFSET + 4]
            .try_into()
            .unwrap(),
    );
    assert_eq!(reference.state.q[0][0], raw as f64);
    for (name, compression, summary) in [
        ("lz4.mcap", Some(mcap::Compression::Lz4), true),
        ("none.mcap", None, true),
        ("nosummary.mcap", Some(mcap::Compression::Zstd), false),
    ] {
        let p = dir.path().join(name);
        write_mcap(
            &p,
            &msgs,
            &Layout {
                compression,
                summary,
                ..plain()
            },
        );
        assert_eq!(
            McapSource::open(&p, &OpenOptions::default())
                .unwrap()
                .has_index(),
            summary,
            "{name}"
        );
        let rec = load(&p).unwrap();
        assert!(rec.warnings.is_empty(), "{name}: {:?}", rec.warnings);
        assert_eq!(rec.state.q, reference.state.q, "{name}");
        assert_eq!(rec.state.t, reference.state.t, "{name}");
        assert_eq!(rec.mbs.watts, reference.mbs.watts, "{name}");
        let info = Session::open(&p, &OpenOptions::default())
            .unwrap()
            .info()
            .unwrap();
        assert_eq!(
            info.topics
                .iter()
                .find(|t| t.topic == "/lowstate")
                .unwrap()
                .count,
            400,
            "{name}"
        );
    }
}

#[test]
fn truncated_file_replays_up_to_the_damage() {
    let Some(msgs) = smoke_messages(1000) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("cut.mcap");
    write_mcap(&p, &msgs, &plain());
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() * 6 / 10]).unwrap();
    let rec = load(&p).unwrap();
    let n = rec.state.t.len();
    assert!(n > 300 && n < 1000, "{n} samples before the damage");
    let w = rec.warnings.join("\n");
    assert!(w.contains("cut.mcap") && w.contains("byte offset"), "{w}");
    // Everything delivered equals the intact file's first n samples.
    let full = dir.path().join("full.mcap");
    std::fs::write(&full, &bytes).unwrap();
    assert_eq!(load(&full).unwrap().state.q[..n], rec.state.q[..]);
}

#[test]
fn flipped_bytes_in_a_chunk_stop_with_a_warning() {
    let Some(msgs) = smoke_messages(1000) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("flip.mcap");
    write_mcap(&p, &msgs, &plain());
    let mut bytes = std::fs::read(&p).unwrap();
    let mid = bytes.len() / 3;
    for b in &mut bytes[mid..mid + 16] {
        *b ^= 0x5a;
    }
    std::fs::write(&p, &bytes).unwrap();
    let mut s = Session::open(&p, &OpenOptions::default()).unwrap();
    let mut n = 0;
    let summary = s.read(None, &mut |_| {
        n += 1;
        Ok(())
    });
    let summary = summary.unwrap();
    assert!(!summary.complete);
    let w = summary.warnings.join("\n");
    assert!(
        w.contains("flip.mcap") && w.contains("byte offset") && w.contains("/lowstate"),
        "{w}"
    );
    assert!(n > 0 && n < msgs.len());
    let rec = load(&p).unwrap();
    assert!(!rec.warnings.is_empty() && !rec.state.t.is_empty());
}

#[test]
fn missing_required_topic_names_file_and_topics() {
    let Some(msgs) = smoke_messages(50) else {
        return;
    };
    let only_bms: Vec<Msg> = msgs
        .into_iter()
        .filter(|m| m.topic == "/lf/bmsstate")
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("nolow.mcap");
    write_mcap(&p, &only_bms, &plain());
    let err = load(&p).unwrap_err().to_string();
    assert!(
        err.contains("nolow.mcap") && err.contains("/lowstate") && err.contains("/lf/bmsstate"),
        "{err}"
    );
}

#[test]
fn optional_topics_missing_is_a_warning() {
    let Some(msgs) = smoke_messages(50) else {
        return;
    };
    let only_state: Vec<Msg> = msgs
        .into_iter()
        .filter(|m| m.topic == "/lowstate")
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("state.mcap");
    write_mcap(&p, &only_state, &plain());
    let rec = load(&p).unwrap();
    assert_eq!(rec.state.t.len(), 50);
    assert!(
        rec.warnings.iter().any(|w| w.contains("/arm_sdk")),
        "{:?}",
        rec.warnings
    );
    assert!(
        rec.warnings
            .iter()
            .any(|w| w.contains("/lf/mainboardstate")),
        "{:?}",
        rec.warnings
    );
}

#[test]
fn schema_that_does_not_match_is_an_error() {
    let Some(msgs) = smoke_messages(20) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("mismatch.mcap");
    let schema = |m: &Msg| {
        if m.topic == "/lowstate" {
            (
                "ros2msg".into(),
                "uint32 tick\nfloat32[4] quaternion\n".into(),
                "cdr".into(),
            )
        } else {
            default_schema(m)
        }
    };
    write_mcap(
        &p,
        &msgs,
        &Layout {
            schema: &schema,
            ..plain()
        },
    );
    let err = format!("{:#}", load(&p).unwrap_err());
    assert!(
        err.contains("/lowstate")
            && err.contains("schema does not match")
            && err.contains("motor_state"),
        "{err}"
    );
}

#[test]
fn unknown_encoding_is_an_error_naming_topic_and_encoding() {
    let Some(msgs) = smoke_messages(20) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("proto.mcap");
    let schema = |m: &Msg| {
        let (s, t, e) = default_schema(m);
        if m.topic == "/lowstate" {
            ("protobuf".into(), t, "protobuf".into())
        } else {
            (s, t, e)
        }
    };
    write_mcap(
        &p,
        &msgs,
        &Layout {
            schema: &schema,
            ..plain()
        },
    );
    let err = format!("{:#}", load(&p).unwrap_err());
    assert!(
        err.contains("/lowstate") && err.contains("protobuf") && err.contains("proto.mcap"),
        "{err}"
    );
}

#[test]
fn nan_values_are_dropped_with_a_warning() {
    let Some(msgs) = smoke_messages(100) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("nan.mcap");
    let poisoned = msgs
        .iter()
        .filter(|m| m.topic == "/lowstate")
        .nth(10)
        .unwrap()
        .log_time;
    let mutate = move |m: &Msg| {
        (m.topic == "/lowstate" && m.log_time == poisoned).then(|| {
            let mut d = m.data.clone();
            d[LEFT_SHOULDER_Q_OFFSET..LEFT_SHOULDER_Q_OFFSET + 4]
                .copy_from_slice(&f32::NAN.to_le_bytes());
            d
        })
    };
    write_mcap(
        &p,
        &msgs,
        &Layout {
            mutate: &mutate,
            ..plain()
        },
    );
    let rec = load(&p).unwrap();
    assert_eq!(rec.state.t.len(), 99);
    assert!(rec.state.q.iter().flatten().all(|v| v.is_finite()));
    let w = rec.warnings.join("\n");
    assert!(
        w.contains("motor_state[15].q") && w.contains("NaN") && w.contains(&poisoned.to_string()),
        "{w}"
    );
}

/// The unitree_hg LowState definition written as OMG IDL by hand.
const LOWSTATE_IDL: &str = r#"
// generated-style IDL as DDS recorders emit it
#include "unitree_hg/msg/MotorState.idl"
module unitree_hg { module msg {
  typedef float float__4[4];
  struct IMUState { float__4 quaternion; float gyroscope[3]; float accelerometer[3]; float rpy[3]; int16 temperature; };
};};
================================================================================
IDL: unitree_hg/msg/MotorState
module unitree_hg {
  module msg {
    @verbatim (language="comment", text="one motor")
    struct MotorState {
      octet mode;
      float q, dq;
      float ddq;
      float tau_est;
      short temperature[2];
      float vol;
      unsigned long sensor[2];
      uint32 motorstate;
      uint32 reserve[4];
    };
  };
};
================================================================================
IDL: unitree_hg/msg/LowState
module unitree_hg { module msg {
  const long UNUSED = 3;
  struct LowState {
    uint32 version[2]; uint8 mode_pr; uint8 mode_machine; unsigned long tick;
    unitree_hg::msg::IMUState imu_state;
    MotorState motor_state[35];
    octet wireless_remote[40]; uint32 reserve[4]; uint32 crc;
  };
}; };
"#;

#[test]
fn idl_schema_and_json_encoding_decode_like_ros2msg() {
    let Some(msgs) = smoke_messages(100) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let reference = {
        let p = dir.path().join("ref.mcap");
        write_mcap(&p, &msgs, &plain());
        load(&p).unwrap()
    };
    let p = dir.path().join("idl_json.mcap");
    let schema = |m: &Msg| match m.topic.as_str() {
        "/lowstate" => ("ros2idl".into(), LOWSTATE_IDL.into(), "cdr".into()),
        "/lf/mainboardstate" => (
            "jsonschema".into(),
            r#"{"type":"object"}"#.into(),
            "json".into(),
        ),
        _ => default_schema(m),
    };
    let mbs_schema = g1viz::read::MsgSchema::parse_ros2msg(
        "unitree_hg/msg/MainBoardState",
        &ros2msg_text("unitree_hg/MainBoardState"),
    )
    .unwrap();
    let mutate = move |m: &Msg| {
        (m.topic == "/lf/mainboardstate").then(|| {
            // Re-encode as JSON from our decoded CDR value (numbers as JSON numbers).
            let v = decode(&mbs_schema, Encoding::Cdr, &m.data).unwrap();
            let value: Vec<f64> = (0..6)
                .map(|i| {
                    v.get(&FieldPath::parse(&format!("value[{i}]")).unwrap())
                        .unwrap()
                        .as_f64()
                        .unwrap()
                })
                .collect();
            serde_json::to_vec(&serde_json::json!({"fan_state": [0,0,0,0,0,0], "value": value}))
                .unwrap()
        })
    };
    write_mcap(
        &p,
        &msgs,
        &Layout {
            schema: &schema,
            mutate: &mutate,
            ..plain()
        },
    );
    let rec = load(&p).unwrap();
    assert!(rec.warnings.is_empty(), "{:?}", rec.warnings);
    assert_eq!(rec.state.q, reference.state.q);
    assert_eq!(rec.state.temp, reference.state.temp);
    assert_eq!(rec.state.quat, reference.state.quat);
    assert_eq!(rec.mbs.watts, reference.mbs.watts);
    assert!(!rec.mbs.watts.is_empty());
}

#[test]
fn big_endian_cdr_and_sequences_by_hand() {
    use g1viz::read::MsgSchema;
    let schema = MsgSchema::parse_ros2msg(
        "test_pkg/msg/T",
        "uint8 a\nfloat64 x\nint16[] s\nstring name\nfloat32 tail\n",
    )
    .unwrap();
    // Big-endian CDR, hand-laid: header 00 00; a @0; pad to 8; x @8; len @16; 3×i16 @20;
    // pad to 28; string len 3 ("hi\0") @28; "hi\0" @32; pad to 36; tail @36.
    let mut d = vec![0u8, 0, 0, 0];
    d.push(7);
    d.extend([0; 7]);
    d.extend(2.5f64.to_be_bytes());
    d.extend(3u32.to_be_bytes());
    for v in [-1i16, 2, 300] {
        d.extend(v.to_be_bytes());
    }
    d.extend([0; 2]);
    d.extend(3u32.to_be_bytes());
    d.extend(b"hi\0");
    d.extend([0; 1]);
    d.extend(1.5f32.to_be_bytes());
    let paths: Vec<FieldPath> = ["a", "x", "s[2]", "tail"]
        .iter()
        .map(|p| FieldPath::parse(p).unwrap())
        .collect();
    let ex = FieldExtractor::compile(&schema, Encoding::Cdr, &paths).unwrap();
    assert!(!ex.is_constant_offset());
    let mut out = [0.0; 4];
    ex.extract(&d, &mut out).unwrap();
    assert_eq!(out, [7.0, 2.5, 300.0, 1.5]);
    let v = decode(&schema, Encoding::Cdr, &d).unwrap();
    assert_eq!(
        v.get(&FieldPath::parse("name").unwrap()),
        Some(&g1viz::read::Value::String("hi".into()))
    );
    // The same bytes little-endian-flagged decode differently but do not panic; cut payloads error.
    for cut in 0..d.len() {
        assert!(ex.extract(&d[..cut], &mut out).is_err() || cut >= 40);
        let _ = decode(&schema, Encoding::Cdr, &d[..cut]);
    }
    let mut pl = d.clone();
    pl[1] = 3;
    assert!(
        ex.extract(&pl, &mut out)
            .unwrap_err()
            .to_string()
            .contains("PL_CDR")
    );
}

#[test]
fn signal_map_toml_overrides_and_right_arm() {
    let m = SignalMap::from_toml_str(
        "arm = \"right\"\n[[signal]]\nname = \"tau.elbow\"\nfield = \"motor_state[25].tau_est\"\nscale = 2.0\n",
    )
    .unwrap();
    assert_eq!(m.joint_names[0], "right_shoulder_pitch_joint");
    assert_eq!(
        m.signals["q.sh_pitch"].field.to_string(),
        "motor_state[22].q"
    );
    assert_eq!(m.signals["q.wr_yaw"].field.to_string(), "motor_state[28].q");
    assert_eq!(m.signals["tau.elbow"].scale, 2.0);
    assert_eq!(m.signals["bms.voltage"].scale, 1e-3);
    let err = SignalMap::from_toml_str("[[signal]]\nname = \"q.nope\"\n")
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("q.nope") && err.contains("q.sh_pitch"),
        "{err}"
    );
    let err = format!(
        "{:#}",
        SignalMap::from_toml_str("[[signal]]\nname = \"q.elbow\"\ntopic = \"/other\"\n")
            .unwrap_err()
    );
    assert!(err.contains("share a topic"), "{err}");
    // Right arm on the smoke file: right-arm joints are at rest (standing posture).
    let Some((path, _)) = smoke() else { return };
    let rec = load_recording(&path, &m, &OpenOptions::default()).unwrap();
    let q0 = rec.state.q[0];
    assert!(
        rec.state
            .q
            .iter()
            .take(3000)
            .all(|q| (q[0] - q0[0]).abs() < 0.05)
    );
}

/// (topic, log time, payload) of every message `session` delivers.
fn all_messages(session: &mut Session) -> Vec<(String, u64, Vec<u8>)> {
    let mut out = Vec::new();
    session
        .read(None, &mut |m| {
            out.push((m.channel.topic.clone(), m.log_time_ns, m.data.to_vec()));
            Ok(())
        })
        .unwrap();
    out
}

/// Time ranges are a hint the MCAP reader uses to skip whole chunks: on the smoke file (written
/// by the Python mcap library, 30 chunks) a ranged read delivers every message inside the ranges
/// exactly as a full read does, in the same order, and reads fewer messages in all.
#[test]
fn time_ranges_skip_chunks_and_keep_every_message_inside() {
    let Some((path, _)) = smoke() else { return };
    let mut session = Session::open(&path, &OpenOptions::default()).unwrap();
    let full = all_messages(&mut session);
    let (t0, t1) = (full.first().unwrap().1, full.last().unwrap().1);
    let at = |f: f64| t0 + ((t1 - t0) as f64 * f) as u64;
    let ranges = vec![(at(0.10), at(0.20)), (at(0.60), at(0.65))];
    let inside = |t: u64| ranges.iter().any(|&(a, b)| a <= t && t <= b);

    let mut ranged_session = Session::open(&path, &OpenOptions::default()).unwrap();
    ranged_session.set_time_ranges(Some(ranges.clone()));
    let ranged = all_messages(&mut ranged_session);
    let want: Vec<_> = full.iter().filter(|m| inside(m.1)).collect();
    let got: Vec<_> = ranged.iter().filter(|m| inside(m.1)).collect();
    assert!(!want.is_empty());
    assert_eq!(got, want, "messages inside the ranges");
    assert!(
        ranged.len() < full.len() / 2,
        "{} of {} messages read: chunks outside the ranges were not skipped",
        ranged.len(),
        full.len()
    );
    // Clearing the hint reads everything again.
    ranged_session.set_time_ranges(None);
    assert_eq!(all_messages(&mut ranged_session), full);
}
