//! Edge cases of the readers found by the peer suites and the robustness review: an empty ROS 1
//! bag (written by the Python `rosbags` library) reads without warnings and `info --json` says
//! why its signals are null; pre-release (2018) rosbag2 bags and a storage file listed twice
//! are refused clearly; a truncated `.db3` is read up to the damage; a payload whose length does
//! not fit its fixed-size definition is dropped with a warning instead of decoded as garbage.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use g1viz::read::{OpenOptions, Session};

fn open_err(path: &Path) -> String {
    match Session::open(path, &OpenOptions::default()) {
        Ok(_) => panic!("{} opened", path.display()),
        Err(e) => e.to_string(),
    }
}

#[test]
fn empty_ros1_bag_reads_without_warnings_and_json_info_gives_the_reason() {
    if !common::python_module("rosbags", "rosbags==0.11.9") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let bag = tmp.path().join("empty.bag");
    let out = Command::new("python3")
        .args([
            "-c",
            "import sys\nfrom rosbags.rosbag1 import Writer\nwith Writer(sys.argv[1]) as w: pass",
        ])
        .arg(&bag)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut session = Session::open(&bag, &OpenOptions::default()).unwrap();
    let info = session.info().unwrap();
    assert_eq!((info.messages, info.topics.len()), (0, 0));
    assert!(info.warnings.is_empty(), "{:?}", info.warnings);
    let summary = session.read(None, &mut |_| Ok(())).unwrap();
    assert!(
        summary.complete && summary.warnings.is_empty(),
        "{summary:?}"
    );

    let out = Command::new(env!("CARGO_BIN_EXE_g1viz"))
        .args(["info", "--json"])
        .arg(&bag)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(json["signals"].is_null());
    let reason = json["signals_error"].as_str().unwrap();
    assert!(
        reason.contains("required topic /lowstate has no readable messages"),
        "{reason}"
    );
}

/// A database with rosbag2's 2018 pre-release tables (topics without serialization_format).
fn prerelease_db(path: &Path) {
    let conn = rusqlite::Connection::open(path).unwrap();
    conn.execute_batch(
        "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL);
         CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
           timestamp INTEGER NOT NULL, data BLOB NOT NULL);
         INSERT INTO topics VALUES (1, '/chatter', 'std_msgs/String');
         INSERT INTO messages VALUES (1, 1, 5, x'0001000003000000686900');",
    )
    .unwrap();
}

#[test]
fn prerelease_rosbag2_and_doubly_listed_files_are_refused_clearly() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("old_bag");
    std::fs::create_dir(&dir).unwrap();
    prerelease_db(&dir.join("old_bag.db3"));
    // The database alone, and the folder with a version-less metadata.yaml.
    let err = open_err(&dir.join("old_bag.db3"));
    assert!(err.contains("pre-release (2018) rosbag2 database"), "{err}");
    assert!(err.contains("old_bag.db3"), "{err}");
    std::fs::write(
        dir.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  storage_identifier: sqlite3\n  relative_file_paths:\n    - old_bag.db3\n",
    )
    .unwrap();
    let err = open_err(&dir);
    assert!(err.contains("metadata.yaml: no version"), "{err}");
    assert!(err.contains("pre-release (2018)"), "{err}");
    assert!(!err.contains("byte offset"), "{err}");

    // The shared bag's metadata listing its database twice.
    let Some(shared) = common::shared_dir() else {
        return;
    };
    let src = shared.join("recordings/g1_smoke_db3");
    let twice = tmp.path().join("twice");
    std::fs::create_dir(&twice).unwrap();
    std::fs::copy(src.join("g1_smoke_db3.db3"), twice.join("g1_smoke_db3.db3")).unwrap();
    let yaml = std::fs::read_to_string(src.join("metadata.yaml")).unwrap();
    let line = yaml
        .lines()
        .find(|l| l.trim_start().starts_with("- g1_smoke_db3.db3"))
        .unwrap();
    let yaml = yaml.replacen(
        line,
        &format!(
            "{line}\n{}",
            line.replace("g1_smoke_db3.db3", "./g1_smoke_db3.db3")
        ),
        1,
    );
    std::fs::write(twice.join("metadata.yaml"), yaml).unwrap();
    let err = open_err(&twice);
    assert!(err.contains("listed twice"), "{err}");

    // A YAML syntax error names the file and line, not a byte offset.
    std::fs::write(
        twice.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: \"sqlite3\n",
    )
    .unwrap();
    let err = open_err(&twice);
    assert!(err.contains("metadata.yaml: "), "{err}");
    assert!(err.contains("quoted scalar at line 3"), "{err}");
    assert!(!err.contains("byte offset"), "{err}");
}

/// A metadata.yaml that is valid YAML but holds a field of the wrong type, or nests flow
/// collections deeper than any writer does: the error names the file, the field and the line.
#[test]
fn malformed_metadata_fields_are_named_with_their_line() {
    let tmp = tempfile::tempdir().unwrap();
    let bag = tmp.path().join("bag");
    std::fs::create_dir(&bag).unwrap();
    std::fs::write(bag.join("bag.db3"), b"").unwrap();
    let head = "rosbag2_bagfile_information:\n  storage_identifier: sqlite3\n";
    for (body, needles) in [
        (
            "  version: five\n  relative_file_paths:\n  - bag.db3\n".to_string(),
            &[
                "rosbag2_bagfile_information.version: invalid type: string \"five\"",
                "line 3",
            ][..],
        ),
        (
            "  version: 5\n  relative_file_paths:\n    a: bag.db3\n".to_string(),
            &[
                "rosbag2_bagfile_information.relative_file_paths: invalid type: map",
                "line 5",
            ],
        ),
        (
            "  version: 12\n  relative_file_paths: [bag.db3]\n".to_string(),
            &["metadata version 12 is not supported"],
        ),
        (
            format!(
                "  version: 5\n  custom_data: {}{}\n",
                "[".repeat(65),
                "]".repeat(65)
            ),
            &["nested more than 64 levels deep"],
        ),
    ] {
        std::fs::write(bag.join("metadata.yaml"), format!("{head}{body}")).unwrap();
        let err = open_err(&bag);
        assert!(err.contains("bag/metadata.yaml: "), "{err}");
        for n in needles {
            assert!(err.contains(n), "{body}: {err}");
        }
    }
}

#[test]
fn truncated_db3_is_read_up_to_the_damage() {
    let Some(shared) = common::shared_dir() else {
        return;
    };
    let src = shared.join("recordings/g1_smoke_db3/g1_smoke_db3.db3");
    let all = read_topics(&src);
    let total: usize = all.values().map(Vec::len).sum();
    let tmp = tempfile::tempdir().unwrap();
    let cut = tmp.path().join("cut.db3");
    let bytes = std::fs::read(&src).unwrap();
    std::fs::write(&cut, &bytes[..bytes.len() * 6 / 10]).unwrap();
    let mut session = Session::open(&cut, &OpenOptions::default()).unwrap();
    let mut got: BTreeMap<String, Vec<(u64, Vec<u8>)>> = BTreeMap::new();
    let summary = session
        .read(None, &mut |m| {
            got.entry(m.channel.topic.clone())
                .or_default()
                .push((m.log_time_ns, m.data.to_vec()));
            Ok(())
        })
        .unwrap();
    assert!(!summary.complete, "{summary:?}");
    assert!(
        summary
            .warnings
            .iter()
            .any(|w| w.contains("cut.db3") && w.contains("database damaged")),
        "{summary:?}"
    );
    let n: usize = got.values().map(Vec::len).sum();
    assert!(n > total / 3 && n < total, "{n} of {total} messages");
    // What was read is exactly the start of each topic of the intact file.
    for (topic, msgs) in &got {
        assert_eq!(msgs[..], all[topic][..msgs.len()], "{topic}");
    }
}

fn read_topics(path: &Path) -> BTreeMap<String, Vec<(u64, Vec<u8>)>> {
    let mut out: BTreeMap<String, Vec<(u64, Vec<u8>)>> = BTreeMap::new();
    let mut session = Session::open(path, &OpenOptions::default()).unwrap();
    session
        .read(None, &mut |m| {
            out.entry(m.channel.topic.clone())
                .or_default()
                .push((m.log_time_ns, m.data.to_vec()));
            Ok(())
        })
        .unwrap();
    out
}

#[test]
fn payloads_that_do_not_fit_a_fixed_size_definition_are_dropped_with_a_warning() {
    // The example session re-written with 8 bytes appended to every /lf/bmsstate payload.
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap");
    let bytes = std::fs::read(&src).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("longer.mcap");
    let mut w = mcap::Writer::new(std::io::BufWriter::new(
        std::fs::File::create(&out).unwrap(),
    ))
    .unwrap();
    let mut bms = 0;
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let mut m = m.unwrap();
        if m.channel.topic == "/lf/bmsstate" {
            let mut data = m.data.to_vec();
            data.extend([0u8; 8]);
            m.data = data.into();
            bms += 1;
        }
        w.write(&m).unwrap();
    }
    w.finish().unwrap();
    drop(w);
    let map = g1viz::signals::SignalMap::g1_left_arm();
    let opts = OpenOptions::default();
    let original = g1viz::signals::load_recording(&src, &map, &opts).unwrap();
    let r = g1viz::signals::load_recording(&out, &map, &opts).unwrap();
    assert!(bms > 10);
    assert_eq!(
        r.bms.t.len(),
        0,
        "BMS readings decoded from payloads of the wrong size"
    );
    assert_eq!(r.state.t, original.state.t);
    assert!(
        r.warnings
            .iter()
            .any(|w| w.contains("/lf/bmsstate") && w.contains("does not match the payload")),
        "{:?}",
        r.warnings
    );
}

/// Every message as (topic, log time, payload), in delivery order.
fn all_messages(source: &mut dyn g1viz::read::MessageSource) -> Vec<(String, u64, Vec<u8>)> {
    let mut out = Vec::new();
    let summary = source
        .read(None, &mut |m| {
            out.push((m.channel.topic.clone(), m.log_time_ns, m.data.to_vec()));
            Ok(())
        })
        .unwrap();
    assert!(summary.complete, "{summary:?}");
    out
}

#[test]
fn mcap_and_ros1_readers_run_from_memory_like_from_files() {
    use g1viz::read::McapSource;
    use g1viz::read::Ros1BagSource;
    use std::io::Cursor;
    let opts = OpenOptions::default();
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap");
    let bytes = std::fs::read(&example).unwrap();
    let from_file = all_messages(&mut McapSource::open(&example, &opts).unwrap());
    let mut in_memory =
        McapSource::from_reader(Cursor::new(bytes), Path::new("memory"), &opts).unwrap();
    assert!(from_file.len() > 1000);
    assert!(all_messages(&mut in_memory) == from_file);
    let err = McapSource::from_reader(
        Cursor::new(b"not mcap".to_vec()),
        Path::new("memory"),
        &opts,
    )
    .err()
    .unwrap()
    .to_string();
    assert!(err.starts_with("memory: not an MCAP file"), "{err}");

    let Some(shared) = common::shared_dir() else {
        return;
    };
    let bag = shared.join("recordings/g1_smoke.bag");
    let from_file = all_messages(&mut Ros1BagSource::open(&bag, &opts).unwrap());
    let bytes = std::fs::read(&bag).unwrap();
    let mut in_memory =
        Ros1BagSource::from_reader(Cursor::new(bytes), Path::new("memory"), &opts).unwrap();
    assert!(from_file.len() > 1000);
    assert!(all_messages(&mut in_memory) == from_file);
}
