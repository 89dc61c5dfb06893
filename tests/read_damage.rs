//! Message- and table-level damage in rosbag2 bags: a message whose zstd payload does not
//! decompress is skipped with one warning per file naming the file and the first row id (or
//! byte offset), and the read goes on; a `.db3` whose `topics` table is damaged is read for the
//! topics that can be read (the others' messages skipped with a warning), or refused with an
//! error naming the file and the table when not one topic is readable. The damaged files are
//! made by hand from bags the Python `rosbags` library or the `mcap` crate wrote.

mod common;

use std::collections::BTreeMap;
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::process::Command;

use g1viz::read::{OpenOptions, ReadSummary, Session};

/// (topic, log time, row id or byte offset, payload) of every message, and the summary.
type Msgs = Vec<(String, u64, u64, Vec<u8>)>;

fn read_all(path: &Path) -> (Msgs, ReadSummary) {
    let mut session = Session::open(path, &OpenOptions::default()).unwrap();
    let mut out = Vec::new();
    let summary = session
        .read(None, &mut |m| {
            out.push((
                m.channel.topic.clone(),
                m.log_time_ns,
                m.file_offset,
                m.data.to_vec(),
            ));
            Ok(())
        })
        .unwrap();
    (out, summary)
}

fn rosbags_importable() -> bool {
    common::python_module("rosbags", "rosbags==0.11.9")
}

/// Copies the first N messages of a rosbag2 bag into a zstd message-compressed one:
/// argv = source bag, destination folder, N.
const MESSAGE_ZSTD_COPY: &str = r#"
import sys
from pathlib import Path
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.writer import CompressionMode, CompressionFormat

src, dst, n = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3])
with Reader(src) as r:
    w = Writer(dst, version=9)
    w.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with w:
        conns = {c.id: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, rihs01=c.digest)
                 for c in r.connections}
        for i, (c, t, d) in enumerate(r.messages()):
            if i >= n:
                break
            w.write(conns[c.id], t, d)
"#;

fn only_db3(dir: &Path) -> PathBuf {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "db3"))
        .unwrap()
}

#[test]
fn undecompressible_db3_messages_are_skipped_with_a_warning() {
    let Some(src) = common::shared_recording("g1_smoke_db3") else {
        return;
    };
    if !rosbags_importable() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let bag = tmp.path().join("zstd_message");
    let n = 400;
    let out = common::output_within(
        Command::new("python3")
            .args(["-c", MESSAGE_ZSTD_COPY])
            .arg(&src)
            .arg(&bag)
            .arg(n.to_string()),
        common::TOOL_LIMIT,
    )
    .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (intact, summary) = read_all(&bag);
    assert_eq!(intact.len(), n);
    assert!(summary.warnings.is_empty(), "{summary:?}");

    // Three payloads that are not zstd frames any more: a damaged frame and two garbage blobs.
    let db3 = only_db3(&bag);
    let damaged_rows = [7u64, 100, 101];
    let conn = rusqlite::Connection::open(&db3).unwrap();
    conn.execute_batch(
        "UPDATE messages SET data = x'28b52ffd2064ffffffffffffffff' WHERE id = 7;
         UPDATE messages SET data = x'00112233445566778899' WHERE id IN (100, 101);",
    )
    .unwrap();
    drop(conn);

    let (got, summary) = read_all(&bag);
    let expected: Msgs = intact
        .into_iter()
        .filter(|m| !damaged_rows.contains(&m.2))
        .collect();
    assert_eq!(got.len(), n - 3);
    assert!(got == expected, "the other messages changed");
    let name = db3.file_name().unwrap().to_string_lossy().into_owned();
    let warning = summary
        .warnings
        .iter()
        .find(|w| w.contains("does not decompress"))
        .unwrap_or_else(|| panic!("no warning: {summary:?}"));
    for needle in [
        name.as_str(),
        "3 messages",
        "skipped",
        "message row id 7",
        "topic /",
    ] {
        assert!(warning.contains(needle), "{needle:?} missing in: {warning}");
    }
    assert_eq!(summary.warnings.len(), 1, "{summary:?}");
}

#[test]
fn undecompressible_mcap_storage_messages_are_skipped_with_a_warning() {
    // A rosbag2 bag with MCAP storage and per-message zstd, written with the `mcap` crate; the
    // 4th of 10 payloads is not a zstd frame.
    let tmp = tempfile::tempdir().unwrap();
    let bag = tmp.path().join("bag");
    std::fs::create_dir(&bag).unwrap();
    let file = bag.join("bag_0.mcap");
    let mut w = mcap::WriteOptions::new()
        .compression(None)
        .create(std::io::BufWriter::new(
            std::fs::File::create(&file).unwrap(),
        ))
        .unwrap();
    let schema = w
        .add_schema("std_msgs/msg/String", "ros2msg", b"string data")
        .unwrap();
    let channel = w
        .add_channel(schema, "/chatter", "cdr", &BTreeMap::new())
        .unwrap();
    let mut payloads = Vec::new();
    for i in 0..10u32 {
        let text = format!("hello {i}");
        let mut cdr = vec![0, 1, 0, 0];
        cdr.extend((text.len() as u32 + 1).to_le_bytes());
        cdr.extend(text.as_bytes());
        cdr.push(0);
        let data = if i == 3 {
            b"not a zstd frame".to_vec()
        } else {
            zstd::bulk::compress(&cdr, 3).unwrap()
        };
        payloads.push(cdr);
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: i,
            log_time: 1_700_000_000_000_000_000 + u64::from(i) * 1_000_000,
            publish_time: 0,
        };
        w.write_to_known_channel(&header, &data).unwrap();
    }
    w.finish().unwrap();
    drop(w);
    std::fs::write(
        bag.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n  \
         relative_file_paths:\n    - bag_0.mcap\n  compression_format: zstd\n  \
         compression_mode: MESSAGE\n",
    )
    .unwrap();
    let (got, summary) = read_all(&bag);
    let texts: Vec<Vec<u8>> = got.into_iter().map(|m| m.3).collect();
    payloads.remove(3);
    assert_eq!(texts, payloads);
    assert_eq!(summary.warnings.len(), 1, "{summary:?}");
    let warning = &summary.warnings[0];
    for needle in [
        "bag_0.mcap",
        "1 message whose zstd payload does not decompress skipped",
        "topic /chatter",
        "byte offset",
    ] {
        assert!(warning.contains(needle), "{needle:?} missing in: {warning}");
    }
}

/// Root page number and page size of `table` in the database at `path`.
fn root_page(path: &Path, table: &str) -> (u64, u64) {
    let conn = rusqlite::Connection::open(path).unwrap();
    let root: i64 = conn
        .query_row(
            "SELECT rootpage FROM sqlite_master WHERE name = ?1",
            [table],
            |r| r.get(0),
        )
        .unwrap();
    let size: i64 = conn
        .query_row("PRAGMA page_size", [], |r| r.get(0))
        .unwrap();
    (root as u64, size as u64)
}

/// Overwrite page `page` (1-based) of a database file with garbage.
fn smash_page(path: &Path, page: u64, page_size: u64) {
    let mut f = std::fs::OpenOptions::new().write(true).open(path).unwrap();
    f.seek(SeekFrom::Start((page - 1) * page_size)).unwrap();
    let garbage: Vec<u8> = (0..page_size).map(|i| (i * 151 % 251) as u8 | 1).collect();
    f.write_all(&garbage).unwrap();
}

#[test]
fn db3_whose_topics_table_is_unreadable_is_refused_naming_file_and_table() {
    let Some(src) = common::shared_recording("g1_smoke_db3/g1_smoke_db3.db3") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let db3 = tmp.path().join("smashed.db3");
    std::fs::copy(&src, &db3).unwrap();
    let (root, page_size) = root_page(&db3, "topics");
    assert!(root > 1);
    smash_page(&db3, root, page_size);
    let err = match Session::open(&db3, &OpenOptions::default()) {
        Ok(_) => panic!("opened a database without readable topics"),
        Err(e) => e.to_string(),
    };
    for needle in [
        "smashed.db3",
        "table topics damaged",
        "no topic is readable",
    ] {
        assert!(err.contains(needle), "{needle:?} missing in: {err}");
    }
    // The CLI says the same and exits 1 (not a panic, not a signal).
    let out = common::output_within(
        Command::new(env!("CARGO_BIN_EXE_g1viz"))
            .arg("info")
            .arg(&db3),
        common::G1VIZ_LIMIT,
    )
    .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("table topics damaged"), "{stderr}");
}

/// CDR of a `std_msgs/msg/String`.
fn cdr_string(text: &str) -> Vec<u8> {
    let mut cdr = vec![0, 1, 0, 0];
    cdr.extend((text.len() as u32 + 1).to_le_bytes());
    cdr.extend(text.as_bytes());
    cdr.push(0);
    cdr
}

#[test]
fn db3_whose_topics_table_is_damaged_part_way_reads_the_readable_topics() {
    // 300 topics with long names, written last so the table's last leaf page is the file's
    // last page; messages on topic 1 and topic 300. Smashing that page leaves topic 1 readable.
    let tmp = tempfile::tempdir().unwrap();
    let db3 = tmp.path().join("partial.db3");
    {
        let conn = rusqlite::Connection::open(&db3).unwrap();
        conn.execute_batch(
            "CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
               timestamp INTEGER NOT NULL, data BLOB NOT NULL);
             CREATE TABLE message_definitions(id INTEGER PRIMARY KEY, topic_type TEXT NOT NULL,
               encoding TEXT NOT NULL, encoded_message_definition TEXT NOT NULL,
               type_description_hash TEXT NOT NULL);
             INSERT INTO message_definitions VALUES (1, 'std_msgs/msg/String', 'ros2msg', 'string data', '');
             CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
               serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);",
        )
        .unwrap();
        for i in 0..20i64 {
            let topic = if i % 2 == 0 { 1 } else { 300 };
            conn.execute(
                "INSERT INTO messages (topic_id, timestamp, data) VALUES (?1, ?2, ?3)",
                rusqlite::params![topic, 1_700_000_000_000_000_000i64 + i, cdr_string("hi")],
            )
            .unwrap();
        }
        for id in 1..=300i64 {
            conn.execute(
                "INSERT INTO topics VALUES (?1, ?2, 'std_msgs/msg/String', 'cdr', '')",
                rusqlite::params![id, format!("/t{id:03}/{}", "x".repeat(200))],
            )
            .unwrap();
        }
    }
    let (_, page_size) = root_page(&db3, "topics");
    let pages = std::fs::metadata(&db3).unwrap().len() / page_size;
    smash_page(&db3, pages, page_size);

    let (got, summary) = read_all(&db3);
    assert_eq!(got.len(), 10, "{summary:?}");
    assert!(got.iter().all(|m| m.0.starts_with("/t001/")));
    assert!(!summary.complete);
    let damage = summary
        .warnings
        .iter()
        .find(|w| w.contains("table topics damaged after topic id"))
        .unwrap_or_else(|| panic!("{summary:?}"));
    assert!(damage.contains("partial.db3"), "{damage}");
    assert!(
        summary
            .warnings
            .iter()
            .any(|w| w.contains("10 messages on topic id 300") && w.contains("skipped")),
        "{summary:?}"
    );
}

/// A rosbag2 bag in `compression_mode: FILE` whose storage file is a zstd bomb (1 GiB of zeros in
/// a few tens of kB): `info` refuses it with exit 1 and a message naming the file, and the scratch
/// copy it writes stays within the stated bound (100 × the input + 64 MiB) — the child runs under
/// RLIMIT_FSIZE at that bound, so one byte more would kill it with SIGXFSZ — and is removed.
#[test]
fn a_file_compressed_bag_bomb_is_refused_within_its_scratch_bound() {
    use std::os::unix::process::{CommandExt, ExitStatusExt};
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("bomb");
    std::fs::create_dir(&bag).unwrap();
    let stored = bag.join("bag_0.mcap.zstd");
    {
        let mut enc =
            zstd::stream::write::Encoder::new(std::fs::File::create(&stored).unwrap(), 3).unwrap();
        let zeros = vec![0u8; 1 << 20];
        for _ in 0..1024 {
            enc.write_all(&zeros).unwrap();
        }
        enc.finish().unwrap();
    }
    std::fs::write(
        bag.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n  \
         relative_file_paths:\n    - bag_0.mcap.zstd\n  compression_format: zstd\n  \
         compression_mode: FILE\n",
    )
    .unwrap();
    let size = std::fs::metadata(&stored).unwrap().len();
    let bound = 100 * size + (64 << 20);
    assert!(
        bound < 1 << 30,
        "the bomb must inflate past the bound ({size} bytes)"
    );
    let tmp = tempfile::tempdir().unwrap();
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_g1viz"));
    cmd.arg("info").arg(&bag).env("TMPDIR", tmp.path());
    // SAFETY: only an async-signal-safe setrlimit call between fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            let lim = libc::rlimit {
                rlim_cur: bound as libc::rlim_t,
                rlim_max: bound as libc::rlim_t,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let out = cmd.output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        out.status.signal(),
        None,
        "killed (scratch file over the bound?): {err}"
    );
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("bag_0.mcap.zstd") && err.contains("decompression bomb"),
        "{err}"
    );
    assert_eq!(
        std::fs::read_dir(tmp.path()).unwrap().count(),
        0,
        "scratch copy left behind"
    );
}
