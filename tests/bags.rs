//! ROS 2 bag (.db3) and ROS 1 bag (.bag) readers against recordings written by the Python
//! `rosbags` library (shared fixtures, and compressed variants generated at run time when that
//! library is importable), compared with the same session's MCAP read by the `mcap` crate.
//!
//! Shared data: `$G1VIZ_SHARED` or `<crate>/../shared`; tests print a note and return when it is
//! absent. Inputs are never modified: tests fingerprint them before and after.

mod common;

use std::collections::BTreeMap;
use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};
use std::process::Command;

use g1viz::read::Ros1BagSource;
use g1viz::read::Ros2BagSource;
use g1viz::read::{Encoding, MessageSource, OpenOptions, ReadError, ReadSummary};

fn shared() -> Option<PathBuf> {
    common::shared_dir()
}

/// Size, mtime and content hash of every file under `path`, and the list of names (so a
/// `-wal`/`-shm` file appearing next to a database is caught too).
fn fingerprint(path: &Path) -> Vec<(PathBuf, u64, std::time::SystemTime, u64)> {
    let mut out = Vec::new();
    let entries: Vec<PathBuf> = if path.is_dir() {
        let mut v: Vec<PathBuf> = std::fs::read_dir(path)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        v.sort();
        v
    } else {
        vec![path.to_path_buf()]
    };
    for p in entries {
        let meta = std::fs::metadata(&p).unwrap();
        let mut h = std::collections::hash_map::DefaultHasher::new();
        std::fs::read(&p).unwrap().hash(&mut h);
        out.push((p, meta.len(), meta.modified().unwrap(), h.finish()));
    }
    out
}

/// One delivered message: topic, log time, payload.
type Msg = (String, u64, Vec<u8>);

fn read_all(source: &mut dyn MessageSource, topics: Option<&[&str]>) -> (Vec<Msg>, ReadSummary) {
    let mut msgs = Vec::new();
    let summary = source
        .read(topics, &mut |m| {
            msgs.push((m.channel.topic.clone(), m.log_time_ns, m.data.to_vec()));
            Ok(())
        })
        .unwrap();
    (msgs, summary)
}

/// The MCAP's messages up to `end_ns` in log-time order, read with the `mcap` crate.
fn mcap_messages(shared: &Path, end_ns: u64) -> Vec<Msg> {
    let bytes = std::fs::read(shared.join("recordings/g1_smoke.mcap")).unwrap();
    let mut msgs: Vec<Msg> = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap())
        .filter(|m| m.log_time <= end_ns)
        .map(|m| (m.channel.topic.clone(), m.log_time, m.data.to_vec()))
        .collect();
    msgs.sort_by_key(|m| m.1);
    msgs
}

/// `files.db3.end_ns` of the truth file: the db3 and bag hold the session up to there.
fn prefix_end_ns(shared: &Path) -> u64 {
    let text = std::fs::read_to_string(shared.join("recordings/g1_smoke.truth.json")).unwrap();
    let truth: serde_json::Value = serde_json::from_str(&text).unwrap();
    truth["files"]["db3"]["end_ns"].as_u64().unwrap()
}

fn counts(msgs: &[Msg]) -> BTreeMap<String, usize> {
    let mut c = BTreeMap::new();
    for m in msgs {
        *c.entry(m.0.clone()).or_default() += 1;
    }
    c
}

#[test]
fn db3_payloads_equal_the_mcap_ones() {
    let Some(shared) = shared() else { return };
    let bag = shared.join("recordings/g1_smoke_db3");
    let before = fingerprint(&bag);
    let expected = mcap_messages(&shared, prefix_end_ns(&shared));
    for path in [
        bag.clone(),
        bag.join("metadata.yaml"),
        bag.join("g1_smoke_db3.db3"),
    ] {
        let mut source = Ros2BagSource::open(&path, &OpenOptions::default()).unwrap();
        assert_eq!(source.format(), "ros2-sqlite3");
        let (msgs, summary) = read_all(&mut source, None);
        assert!(
            summary.complete && summary.warnings.is_empty(),
            "{summary:?}"
        );
        assert_eq!(counts(&msgs), counts(&expected));
        assert_eq!(msgs.len(), expected.len());
        // Same order, same stamps, byte-identical CDR.
        for (got, want) in msgs.iter().zip(&expected) {
            assert_eq!(got, want, "message at {} differs", want.1);
        }
        let info = source.info().unwrap();
        let lowstate = info.topics.iter().find(|t| t.topic == "/lowstate").unwrap();
        assert_eq!(lowstate.count, counts(&expected)["/lowstate"] as u64);
        assert_eq!(lowstate.type_name, "unitree_hg/msg/LowState");
        assert!(
            (lowstate.rate_hz - 100.0).abs() < 1.0,
            "{}",
            lowstate.rate_hz
        );
        assert_eq!(info.start_ns, expected[0].1);
        assert_eq!(info.end_ns, expected.last().unwrap().1);
    }
    // Topic filter.
    let mut source = Ros2BagSource::open(&bag, &OpenOptions::default()).unwrap();
    let (msgs, _) = read_all(&mut source, Some(&["/lf/bmsstate"]));
    assert_eq!(msgs.len(), counts(&expected)["/lf/bmsstate"]);
    assert_eq!(fingerprint(&bag), before, "the bag folder changed");
}

/// Decoded values of every message of the ROS 1 bag equal those of the MCAP's CDR payloads.
#[test]
fn bag1_decodes_to_the_mcap_values() {
    let Some(shared) = shared() else { return };
    let path = shared.join("recordings/g1_smoke.bag");
    let before = fingerprint(&path);
    let expected = mcap_messages(&shared, prefix_end_ns(&shared));
    let mut source = Ros1BagSource::open(&path, &OpenOptions::default()).unwrap();
    let info = source.info().unwrap();
    assert!(info.warnings.is_empty(), "{:?}", info.warnings);
    let info_counts: BTreeMap<String, usize> = info
        .topics
        .iter()
        .map(|t| (t.topic.clone(), t.count as usize))
        .collect();
    assert_eq!(info_counts, counts(&expected));
    assert_eq!(info.start_ns, expected[0].1);
    assert_eq!(info.end_ns, expected.last().unwrap().1);

    // The CDR side is decoded with schemas from the shared .msg files, the ROS 1 side with the
    // definitions the bag's connection records carry.
    let msg_dir = vec![shared.join("msg")];
    let mut cdr_schemas = std::collections::HashMap::new();
    let mut n = 0;
    let mut i = 0;
    let summary = source
        .read(None, &mut |m| {
            let want = &expected[i];
            i += 1;
            assert_eq!(
                (m.channel.topic.as_str(), m.log_time_ns),
                (want.0.as_str(), want.1)
            );
            assert_eq!(m.channel.encoding, Encoding::Ros1);
            let ros1 = g1viz::read::decode(&m.channel.schema, Encoding::Ros1, m.data)
                .map_err(|e| ReadError::Other(e.to_string()))?;
            if !cdr_schemas.contains_key(&m.channel.type_name) {
                let schema = g1viz::read::MsgSchema::from_msg_files(&m.channel.type_name, &msg_dir)
                    .map_err(|e| ReadError::Other(e.to_string()))?;
                cdr_schemas.insert(m.channel.type_name.clone(), schema);
            }
            let cdr_schema = &cdr_schemas[&m.channel.type_name];
            let cdr = g1viz::read::decode(cdr_schema, Encoding::Cdr, &want.2)
                .map_err(|e| ReadError::Other(e.to_string()))?;
            assert_eq!(ros1, cdr, "{} at {}", want.0, want.1);
            n += 1;
            Ok(())
        })
        .unwrap();
    assert!(summary.complete, "{summary:?}");
    assert_eq!(n, expected.len());
    assert_eq!(fingerprint(&path), before, "the bag changed");
}

fn db3_copy(shared: &Path, dir: &Path) -> PathBuf {
    let db = dir.join("copy.db3");
    std::fs::copy(shared.join("recordings/g1_smoke_db3/g1_smoke_db3.db3"), &db).unwrap();
    db
}

#[test]
fn missing_split_file_is_named() {
    let Some(shared) = shared() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let yaml =
        std::fs::read_to_string(shared.join("recordings/g1_smoke_db3/metadata.yaml")).unwrap();
    let yaml = yaml.replace(
        "relative_file_paths:\n  - g1_smoke_db3.db3\n",
        "relative_file_paths:\n  - g1_smoke_db3.db3\n  - g1_smoke_db3_1.db3\n",
    );
    assert!(yaml.contains("g1_smoke_db3_1.db3"));
    std::fs::write(tmp.path().join("metadata.yaml"), yaml).unwrap();
    std::fs::copy(
        shared.join("recordings/g1_smoke_db3/g1_smoke_db3.db3"),
        tmp.path().join("g1_smoke_db3.db3"),
    )
    .unwrap();
    let err = Ros2BagSource::open(tmp.path(), &OpenOptions::default())
        .err()
        .expect("a missing split must fail")
        .to_string();
    assert!(
        err.contains("g1_smoke_db3_1.db3") && err.contains("missing"),
        "{err}"
    );
    assert!(err.contains(&tmp.path().display().to_string()), "{err}");
}

/// A bag split into two files whose messages interleave in time reads like the original.
#[test]
fn split_bag_is_merged_by_time() {
    let Some(shared) = shared() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let original = shared.join("recordings/g1_smoke_db3");
    for (name, parity) in [("part_0.db3", 0), ("part_1.db3", 1)] {
        let db = tmp.path().join(name);
        std::fs::copy(original.join("g1_smoke_db3.db3"), &db).unwrap();
        let conn = rusqlite::Connection::open(&db).unwrap();
        conn.execute("DELETE FROM messages WHERE id % 2 = ?1", [parity])
            .unwrap();
    }
    let yaml = std::fs::read_to_string(original.join("metadata.yaml"))
        .unwrap()
        .replace(
            "relative_file_paths:\n  - g1_smoke_db3.db3\n",
            "relative_file_paths:\n  - part_0.db3\n  - part_1.db3\n",
        );
    std::fs::write(tmp.path().join("metadata.yaml"), yaml).unwrap();
    let (want, _) = read_all(
        &mut Ros2BagSource::open(&original, &OpenOptions::default()).unwrap(),
        None,
    );
    let mut split = Ros2BagSource::open(tmp.path(), &OpenOptions::default()).unwrap();
    let (got, summary) = read_all(&mut split, None);
    assert!(summary.complete);
    assert_eq!(got.len(), want.len());
    assert!(got == want, "merged split bag differs from the original");
    let info = split.info().unwrap();
    assert_eq!(info.messages as usize, want.len());
}

/// Without `message_definitions`, unitree_hg types come from the built-in definitions, other
/// types from `--msg-path`; an unknown type without definition is an error naming type, topic
/// and where to put the .msg file.
#[test]
fn definitions_from_msg_path_builtin_or_a_clear_error() {
    let Some(shared) = shared() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let db = db3_copy(&shared, tmp.path());
    {
        let conn = rusqlite::Connection::open(&db).unwrap();
        conn.execute("DROP TABLE message_definitions", []).unwrap();
        conn.execute(
            "UPDATE topics SET type = 'acme_msgs/msg/BatteryState' WHERE name = '/lf/bmsstate'",
            [],
        )
        .unwrap();
    }
    let (want, _) = read_all(
        &mut Ros2BagSource::open(
            &shared.join("recordings/g1_smoke_db3"),
            &OpenOptions::default(),
        )
        .unwrap(),
        None,
    );

    // No definition anywhere for acme_msgs/msg/BatteryState.
    let mut source = Ros2BagSource::open(&db, &OpenOptions::default()).unwrap();
    let err = read_all_err(&mut source, Some(&["/lf/bmsstate"]));
    for needle in [
        "acme_msgs/msg/BatteryState",
        "/lf/bmsstate",
        "--msg-path",
        "acme_msgs/msg/BatteryState.msg",
    ] {
        assert!(err.contains(needle), "{needle:?} missing in: {err}");
    }
    // All topics: the others (built-in unitree_hg definitions) still read, with a warning.
    let (msgs, summary) = read_all(&mut source, None);
    assert!(
        summary
            .warnings
            .iter()
            .any(|w| w.contains("acme_msgs/msg/BatteryState"))
    );
    let without_bms: Vec<&Msg> = want.iter().filter(|m| m.0 != "/lf/bmsstate").collect();
    assert_eq!(msgs.iter().collect::<Vec<_>>(), without_bms);

    // With --msg-path holding acme_msgs/msg/BatteryState.msg (the BmsState text).
    let msg_dir = tmp.path().join("msgs");
    std::fs::create_dir_all(msg_dir.join("acme_msgs/msg")).unwrap();
    std::fs::copy(
        shared.join("msg/unitree_hg/BmsState.msg"),
        msg_dir.join("acme_msgs/msg/BatteryState.msg"),
    )
    .unwrap();
    let opts = OpenOptions {
        msg_paths: vec![msg_dir],
    };
    let mut source = Ros2BagSource::open(&db, &opts).unwrap();
    let mut decoded = 0;
    source
        .read(Some(&["/lf/bmsstate"]), &mut |m| {
            let v = g1viz::read::decode(&m.channel.schema, Encoding::Cdr, m.data)
                .map_err(|e| ReadError::Other(e.to_string()))?;
            let mv = v
                .get(&g1viz::read::FieldPath::parse("bmsvoltage[0]").unwrap())
                .and_then(|x| x.as_f64())
                .unwrap();
            // Pack voltage in mV: a G1 pack is around 50 V.
            assert!((40_000.0..60_000.0).contains(&mv), "{mv}");
            decoded += 1;
            Ok(())
        })
        .unwrap();
    assert_eq!(
        decoded,
        want.iter().filter(|m| m.0 == "/lf/bmsstate").count()
    );
}

fn read_all_err(source: &mut dyn MessageSource, topics: Option<&[&str]>) -> String {
    source
        .read(topics, &mut |_| Ok(()))
        .expect_err("expected an error")
        .to_string()
}

#[test]
fn truncated_bag_replays_up_to_the_damage() {
    let Some(shared) = shared() else { return };
    let path = shared.join("recordings/g1_smoke.bag");
    let bytes = std::fs::read(&path).unwrap();
    let (full, _) = read_all(
        &mut Ros1BagSource::open(&path, &OpenOptions::default()).unwrap(),
        None,
    );
    let tmp = tempfile::tempdir().unwrap();
    let cut = tmp.path().join("cut.bag");
    let cut_at = bytes.len() / 2 + 12_345;
    std::fs::write(&cut, &bytes[..cut_at]).unwrap();
    let mut source = Ros1BagSource::open(&cut, &OpenOptions::default()).unwrap();
    let (msgs, summary) = read_all(&mut source, None);
    assert!(!summary.complete);
    assert!(
        summary
            .warnings
            .iter()
            .any(|w| w.contains("truncated") && w.contains("byte offset")),
        "{:?}",
        summary.warnings
    );
    // Everything before the damage, in order: the uncompressed chunk cut in the middle gives
    // up its complete records too, so well over 40 % of the messages survive.
    assert!(
        msgs.len() > full.len() * 2 / 5,
        "{} of {}",
        msgs.len(),
        full.len()
    );
    assert!(msgs.len() < full.len());
    assert_eq!(msgs[..], full[..msgs.len()]);
    // info() works on the damaged file and reports the damage.
    let info = source.info().unwrap();
    assert_eq!(info.messages as usize, msgs.len());
    assert!(!info.warnings.is_empty());
}

#[test]
fn unindexed_bag_is_scanned() {
    let Some(shared) = shared() else { return };
    let path = shared.join("recordings/g1_smoke.bag");
    let mut bytes = std::fs::read(&path).unwrap();
    let (full, _) = read_all(
        &mut Ros1BagSource::open(&path, &OpenOptions::default()).unwrap(),
        None,
    );
    // Zero the bag header's index_pos field, as in a bag whose recorder died.
    let field = bytes[..100]
        .windows(10)
        .position(|w| w == b"index_pos=")
        .unwrap()
        + 10;
    bytes[field..field + 8].copy_from_slice(&0u64.to_le_bytes());
    let tmp = tempfile::tempdir().unwrap();
    let open = tmp.path().join("unclosed.bag");
    std::fs::write(&open, &bytes).unwrap();
    let mut source = Ros1BagSource::open(&open, &OpenOptions::default()).unwrap();
    let (msgs, summary) = read_all(&mut source, None);
    assert!(summary.complete);
    assert!(
        summary
            .warnings
            .iter()
            .any(|w| w.contains("not closed properly"))
    );
    assert!(msgs == full, "scan differs from the indexed read");
}

#[test]
fn not_a_bag_is_a_format_error() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("x.bag");
    std::fs::write(&path, b"#ROSBAG V1.2\nsomething").unwrap();
    let err = Ros1BagSource::open(&path, &OpenOptions::default())
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("1.2") && err.contains("not supported"),
        "{err}"
    );
    std::fs::write(&path, b"hello").unwrap();
    assert!(Ros1BagSource::open(&path, &OpenOptions::default()).is_err());
    let db = tmp.path().join("x.db3");
    std::fs::write(
        &db,
        b"not sqlite at all, not sqlite at all, not sqlite at all",
    )
    .unwrap();
    assert!(Ros2BagSource::open(&db, &OpenOptions::default()).is_err());
}

/// Variants written by the Python `rosbags` library (bz2 and lz4 ROS 1 chunks, overlapping
/// chunks, zstd file- and message-compressed rosbag2) read like their sources; a connection of
/// an unknown type without definition is a clear error until `--msg-path` supplies it.
#[test]
fn bags_written_by_rosbags_at_run_time() {
    let Some(shared) = shared() else { return };
    if !common::python_module("rosbags", "rosbags==0.11.9") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let n = 1500;
    let out = common::output_within(
        Command::new("python3")
            .args(["-c", GENERATOR])
            .arg(shared.join("recordings/g1_smoke.bag"))
            .arg(shared.join("recordings/g1_smoke_db3"))
            .arg(tmp.path())
            .arg(n.to_string()),
        common::TOOL_LIMIT,
    )
    .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    let (bag_all, _) = read_all(
        &mut Ros1BagSource::open(
            &shared.join("recordings/g1_smoke.bag"),
            &OpenOptions::default(),
        )
        .unwrap(),
        None,
    );
    let mut first_n = bag_all[..n].to_vec();
    for name in ["bz2.bag", "lz4.bag", "overlap.bag"] {
        let mut source =
            Ros1BagSource::open(&tmp.path().join(name), &OpenOptions::default()).unwrap();
        let (msgs, summary) = read_all(&mut source, None);
        assert!(
            summary.complete && summary.warnings.is_empty(),
            "{name}: {summary:?}"
        );
        // The overlap bag holds the same messages written in shuffled order: read back sorted.
        first_n.sort_by_key(|m| m.1);
        assert!(msgs == first_n, "{name} differs from its source");
        assert_eq!(source.info().unwrap().messages as usize, n);
    }

    // A connection without definition and of a type that is not built in.
    let unknown = tmp.path().join("unknown.bag");
    let mut source = Ros1BagSource::open(&unknown, &OpenOptions::default()).unwrap();
    let err = read_all_err(&mut source, Some(&["/lf/bmsstate"]));
    for needle in [
        "acme_msgs/BatteryState",
        "/lf/bmsstate",
        "--msg-path",
        "acme_msgs/msg/BatteryState.msg",
    ] {
        assert!(err.contains(needle), "{needle:?} missing in: {err}");
    }
    let (msgs, summary) = read_all(&mut source, None);
    assert!(
        summary
            .warnings
            .iter()
            .any(|w| w.contains("acme_msgs/BatteryState"))
    );
    let known: Vec<&Msg> = first_n.iter().filter(|m| m.0 != "/lf/bmsstate").collect();
    assert_eq!(msgs.iter().collect::<Vec<_>>(), known);
    let msg_dir = tmp.path().join("msgs");
    std::fs::create_dir_all(msg_dir.join("acme_msgs/msg")).unwrap();
    std::fs::copy(
        shared.join("msg/unitree_hg/BmsState.msg"),
        msg_dir.join("acme_msgs/msg/BatteryState.msg"),
    )
    .unwrap();
    let opts = OpenOptions {
        msg_paths: vec![msg_dir],
    };
    let mut source = Ros1BagSource::open(&unknown, &opts).unwrap();
    let mut volts = Vec::new();
    source
        .read(Some(&["/lf/bmsstate"]), &mut |m| {
            let v = g1viz::read::decode(&m.channel.schema, Encoding::Ros1, m.data)
                .map_err(|e| ReadError::Other(e.to_string()))?;
            let path = g1viz::read::FieldPath::parse("bmsvoltage[0]").unwrap();
            volts.push(v.get(&path).and_then(|x| x.as_f64()).unwrap());
            Ok(())
        })
        .unwrap();
    assert_eq!(
        volts.len(),
        first_n.iter().filter(|m| m.0 == "/lf/bmsstate").count()
    );
    assert!(
        volts.iter().all(|mv| (40_000.0..60_000.0).contains(mv)),
        "{volts:?}"
    );

    let (db3_all, _) = read_all(
        &mut Ros2BagSource::open(
            &shared.join("recordings/g1_smoke_db3"),
            &OpenOptions::default(),
        )
        .unwrap(),
        None,
    );
    for name in ["zstd_file", "zstd_message"] {
        let dir = tmp.path().join(name);
        let before = fingerprint(&dir);
        let mut source = Ros2BagSource::open(&dir, &OpenOptions::default()).unwrap();
        let (msgs, summary) = read_all(&mut source, None);
        assert!(summary.complete, "{name}");
        assert!(msgs[..] == db3_all[..n], "{name} differs from its source");
        assert_eq!(source.info().unwrap().messages as usize, n);
        drop(source);
        assert_eq!(fingerprint(&dir), before, "{name} changed");
    }
}

/// Writes the compressed fixtures with `rosbags` from the shared bags:
/// argv = source .bag, source db3 folder, output folder, message count.
const GENERATOR: &str = r#"
import sys
from pathlib import Path
from rosbags.rosbag1 import Reader as Reader1, Writer as Writer1
from rosbags.rosbag2 import Reader as Reader2, Writer as Writer2
from rosbags.rosbag2.writer import CompressionMode, CompressionFormat

bag1, db3, out, n = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]), int(sys.argv[4])

def ros1_copy(dst, compression=None, reorder=False):
    with Reader1(bag1) as r:
        msgs = []
        for c, t, d in r.messages():
            msgs.append((c, t, d))
            if len(msgs) >= n:
                break
        if reorder:
            # reversed blocks of 50: chunks overlap in time and hold out-of-order stamps
            msgs = [m for i in range(0, len(msgs), 50) for m in reversed(msgs[i:i + 50])]
        w = Writer1(dst)
        if compression:
            w.set_compression(compression)
        w.chunk_threshold = 100 * 1024
        with w:
            conns = {}
            for c in r.connections:
                conns[c.id] = w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
            for c, t, d in msgs:
                w.write(conns[c.id], t, d)

def ros1_unknown_type(dst):
    # /lf/bmsstate as a type nobody knows, without a message definition
    with Reader1(bag1) as r:
        with Writer1(dst) as w:
            conns = {}
            for c in r.connections:
                unknown = c.topic == '/lf/bmsstate'
                conns[c.id] = w.add_connection(
                    c.topic, 'acme_msgs/msg/BatteryState' if unknown else c.msgtype,
                    msgdef='' if unknown else c.msgdef.data, md5sum=c.digest)
            for i, (c, t, d) in enumerate(r.messages()):
                if i >= n:
                    break
                w.write(conns[c.id], t, d)

ros1_unknown_type(out / 'unknown.bag')
ros1_copy(out / 'bz2.bag', Writer1.CompressionFormat.BZ2)
ros1_copy(out / 'lz4.bag', Writer1.CompressionFormat.LZ4)
ros1_copy(out / 'overlap.bag', reorder=True)

def ros2_copy(dst, mode):
    with Reader2(db3) as r:
        w = Writer2(dst, version=9)
        w.set_compression(mode, CompressionFormat.ZSTD)
        with w:
            conns = {}
            for c in r.connections:
                conns[c.id] = w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, rihs01=c.digest)
            for i, (c, t, d) in enumerate(r.messages()):
                if i >= n:
                    break
                w.write(conns[c.id], t, d)

ros2_copy(out / 'zstd_file', CompressionMode.FILE)
ros2_copy(out / 'zstd_message', CompressionMode.MESSAGE)
"#;

/// The arm signals (`signals::load_recording` through `Session`) of the db3 and the ROS 1 bag
/// equal those of the MCAP over the prefix both hold.
#[test]
fn signals_equal_the_mcap_ones() {
    let Some(shared) = shared() else { return };
    let map = g1viz::signals::SignalMap::g1_left_arm();
    let opts = OpenOptions::default();
    let rec = |p: &str| g1viz::signals::load_recording(&shared.join(p), &map, &opts).unwrap();
    let mcap = rec("recordings/g1_smoke.mcap");
    let end_s = (prefix_end_ns(&shared) - mcap.start_ns) as f64 * 1e-9;
    let n = |t: &[f64]| t.iter().take_while(|&&t| t <= end_s + 1e-9).count();
    for bag in ["recordings/g1_smoke_db3", "recordings/g1_smoke.bag"] {
        let r = rec(bag);
        assert!(r.warnings.is_empty(), "{bag}: {:?}", r.warnings);
        assert_eq!(r.start_ns, mcap.start_ns, "{bag}");
        assert_eq!(r.joint_names, mcap.joint_names);
        let ns = n(&mcap.state.t);
        assert_eq!(r.state.t.len(), ns, "{bag}: /lowstate samples");
        assert_eq!(r.state.t[..], mcap.state.t[..ns]);
        assert_eq!(r.state.q[..], mcap.state.q[..ns], "{bag}: q");
        assert_eq!(r.state.dq[..], mcap.state.dq[..ns], "{bag}: dq");
        assert_eq!(r.state.tau[..], mcap.state.tau[..ns], "{bag}: tau");
        assert_eq!(
            r.state.temp[..],
            mcap.state.temp[..ns],
            "{bag}: temperature"
        );
        assert_eq!(r.state.gyro[..], mcap.state.gyro[..ns], "{bag}: gyro");
        assert_eq!(r.state.quat[..], mcap.state.quat[..ns], "{bag}: quaternion");
        let nc = n(&mcap.command.t);
        assert_eq!(r.command.t[..], mcap.command.t[..nc], "{bag}: /arm_sdk");
        assert_eq!(r.command.q[..], mcap.command.q[..nc]);
        assert_eq!(r.command.dq[..], mcap.command.dq[..nc]);
        for (got, want, name) in [(&r.mbs, &mcap.mbs, "MBS"), (&r.bms, &mcap.bms, "BMS")] {
            let np = n(&want.t);
            assert!(np > 30, "{name}: {np} readings");
            assert_eq!(got.t[..], want.t[..np], "{bag}: {name} times");
            assert_eq!(got.watts[..], want.watts[..np], "{bag}: {name} power");
        }
    }
}

/// A rosbag2 folder whose metadata names MCAP storage is read by the MCAP reader.
#[test]
fn mcap_storage_bag_is_delegated() {
    let Some(shared) = shared() else { return };
    let tmp = tempfile::tempdir().unwrap();
    std::fs::copy(
        shared.join("recordings/g1_smoke.mcap"),
        tmp.path().join("smoke_0.mcap"),
    )
    .unwrap();
    std::fs::write(
        tmp.path().join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n  \
         relative_file_paths:\n  - smoke_0.mcap\n  compression_format: ''\n  compression_mode: ''\n",
    )
    .unwrap();
    let mut bag = Ros2BagSource::open(tmp.path(), &OpenOptions::default()).unwrap();
    assert_eq!(bag.format(), "ros2-mcap");
    let mut direct = g1viz::read::McapSource::open(
        &shared.join("recordings/g1_smoke.mcap"),
        &OpenOptions::default(),
    )
    .unwrap();
    let (want, _) = read_all(&mut direct, None);
    let (got, summary) = read_all(&mut bag, None);
    assert!(summary.complete);
    assert!(got == want, "MCAP-storage bag differs from the MCAP");
    assert_eq!(bag.info().unwrap().messages as usize, want.len());
}

/// A damaged chunk in an indexed bag stops the read there with a warning naming its offset;
/// the chunks before it are delivered.
#[test]
fn damaged_chunk_stops_the_read_with_its_offset() {
    let Some(shared) = shared() else { return };
    let path = shared.join("recordings/g1_smoke.bag");
    let mut bytes = std::fs::read(&path).unwrap();
    let (full, _) = read_all(
        &mut Ros1BagSource::open(&path, &OpenOptions::default()).unwrap(),
        None,
    );
    // Spoil the compression field of the 4th chunk record.
    let needle = b"compression=none";
    let at = bytes
        .windows(needle.len())
        .enumerate()
        .filter(|(_, w)| *w == needle)
        .nth(3)
        .unwrap()
        .0;
    bytes[at + 12..at + 16].copy_from_slice(b"zzzz");
    let tmp = tempfile::tempdir().unwrap();
    let bad = tmp.path().join("bad.bag");
    std::fs::write(&bad, &bytes).unwrap();
    let mut source = Ros1BagSource::open(&bad, &OpenOptions::default()).unwrap();
    let (msgs, summary) = read_all(&mut source, None);
    assert!(!summary.complete);
    let warning = summary.warnings.join("\n");
    assert!(
        warning.contains("zzzz") && warning.contains("byte offset"),
        "{warning}"
    );
    // Three whole chunks (~350 messages each) came through, in order.
    assert!(
        msgs.len() > 900 && msgs.len() < full.len(),
        "{}",
        msgs.len()
    );
    assert_eq!(msgs[..], full[..msgs.len()]);
}
