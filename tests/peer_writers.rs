//! Files written at test time by independent writers, in the layouts their options allow, read
//! back through `Session`: the Python `mcap` writer (summary without repeated channels, no
//! statistics, unchunked, no index, lz4) re-writing `examples/g1_example.mcap`, and the Python
//! `rosbags` writer with MCAP storage and zstd file/message compression re-writing the shared
//! `g1_smoke_db3`. The expected topics, counts, first/last times and a CRC of every topic's
//! messages come from the Python readers (a manifest the generator writes), not from this crate.
//! Skipped (via `tests/common`) when python3 lacks `mcap` / `rosbags`.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use g1viz::read::{OpenOptions, Session};

/// Per topic: count, first and last log time [ns], CRC32 of the messages.
type Manifest = BTreeMap<String, BTreeMap<String, (u64, u64, u64, u32)>>;

fn python_has(modules: &str) -> bool {
    let ok = Command::new("python3")
        .args(["-c", &format!("import {modules}")])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        common::skip(&format!(
            "python3 cannot import {modules} (pip install mcap==1.6.0 rosbags==0.11.9)"
        ));
    }
    ok
}

fn generate(script: &str, args: &[&Path]) -> Manifest {
    let out = Command::new("python3")
        .arg("-c")
        .arg(script)
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// The same digest as the generator's: messages sorted by (log time, payload), each as
/// log time (u64 LE) + payload length (u32 LE) + payload, through CRC32.
fn digest(mut msgs: Vec<(u64, Vec<u8>)>) -> u32 {
    msgs.sort();
    let mut h = crc32fast::Hasher::new();
    for (t, d) in &msgs {
        h.update(&t.to_le_bytes());
        h.update(&(d.len() as u32).to_le_bytes());
        h.update(d);
    }
    h.finalize()
}

/// Read `path` and compare `info` and the delivered messages with the manifest entry.
fn check(path: &Path, want: &BTreeMap<String, (u64, u64, u64, u32)>) {
    let name = path.display();
    let mut session = Session::open(path, &OpenOptions::default()).unwrap();
    let info = session.info().unwrap();
    assert!(info.warnings.is_empty(), "{name}: {:?}", info.warnings);
    let listed: BTreeMap<String, (u64, u64, u64)> = info
        .topics
        .iter()
        .map(|t| (t.topic.clone(), (t.count, t.first_ns, t.last_ns)))
        .collect();
    let expected: BTreeMap<String, (u64, u64, u64)> = want
        .iter()
        .map(|(k, v)| (k.clone(), (v.0, v.1, v.2)))
        .collect();
    assert_eq!(listed, expected, "{name}: info topics");
    let first = want.values().map(|v| v.1).min().unwrap();
    let last = want.values().map(|v| v.2).max().unwrap();
    assert_eq!((info.start_ns, info.end_ns), (first, last), "{name}: span");
    for t in &info.topics {
        let rate = (t.count - 1) as f64 / ((t.last_ns - t.first_ns) as f64 * 1e-9);
        assert!(
            (t.rate_hz - rate).abs() < 1e-9 * rate,
            "{name}: {}",
            t.topic
        );
        assert!(!t.type_name.is_empty(), "{name}: {} has no type", t.topic);
    }
    let mut got: BTreeMap<String, Vec<(u64, Vec<u8>)>> = BTreeMap::new();
    let mut last_t = 0;
    let summary = session
        .read(None, &mut |m| {
            assert!(m.log_time_ns >= last_t, "{name}: out of time order");
            last_t = m.log_time_ns;
            got.entry(m.channel.topic.clone())
                .or_default()
                .push((m.log_time_ns, m.data.to_vec()));
            Ok(())
        })
        .unwrap();
    assert!(
        summary.complete && summary.warnings.is_empty(),
        "{name}: {summary:?}"
    );
    let got: BTreeMap<String, u32> = got.into_iter().map(|(k, v)| (k, digest(v))).collect();
    let want: BTreeMap<String, u32> = want.iter().map(|(k, v)| (k.clone(), v.3)).collect();
    assert_eq!(got, want, "{name}: message digests");
}

const MCAP_LAYOUTS: &str = r#"
import sys, json, zlib
from mcap.reader import make_reader
from mcap.writer import Writer, CompressionType, IndexType

src, out = sys.argv[1], sys.argv[2]
with open(src, 'rb') as f:
    items = [(s, c, m) for s, c, m in make_reader(f).iter_messages(log_time_order=False)]

layouts = {
    'no_repeated_channels': dict(repeat_channels=False, repeat_schemas=False),
    'no_statistics': dict(use_statistics=False),
    'unchunked': dict(use_chunking=False),
    'no_index': dict(index_types=IndexType.NONE),
    'unchunked_no_repeated_channels': dict(use_chunking=False, repeat_channels=False, repeat_schemas=False),
    'no_statistics_no_index': dict(use_statistics=False, index_types=IndexType.NONE),
    'lz4_small_chunks': dict(compression=CompressionType.LZ4, chunk_size=64 * 1024),
}
for name, opts in layouts.items():
    with open(f'{out}/{name}.mcap', 'wb') as f:
        w = Writer(f, **opts)
        w.start(profile='ros2', library='python-mcap-test')
        schemas, channels = {}, {}
        for s, c, m in items:
            if s.id not in schemas:
                schemas[s.id] = w.register_schema(s.name, s.encoding, s.data)
            if c.id not in channels:
                channels[c.id] = w.register_channel(c.topic, c.message_encoding, schemas[s.id], c.metadata)
            w.add_message(channels[c.id], m.log_time, m.data, m.publish_time, m.sequence)
        w.finish()

topics = {}
for s, c, m in items:
    topics.setdefault(c.topic, []).append((m.log_time, m.data))
manifest = {}
for topic, msgs in topics.items():
    msgs.sort()
    crc = 0
    for t, d in msgs:
        crc = zlib.crc32(t.to_bytes(8, 'little') + len(d).to_bytes(4, 'little') + d, crc)
    manifest[topic] = [len(msgs), msgs[0][0], msgs[-1][0], crc]
print(json.dumps({name: manifest for name in layouts}))
"#;

/// Every layout the Python `mcap` writer offers reads like the Python reader reads its source.
#[test]
fn mcap_layouts_written_by_the_python_writer() {
    if !python_has("mcap") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap");
    let manifest = generate(MCAP_LAYOUTS, &[&src, tmp.path()]);
    assert_eq!(manifest.len(), 7);
    for (layout, want) in &manifest {
        check(&tmp.path().join(format!("{layout}.mcap")), want);
    }
}

/// A session whose summary does not repeat its channels replays: the signals equal those of
/// the original file.
#[test]
fn signals_of_a_summary_without_channels_equal_the_original() {
    if !python_has("mcap") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap");
    generate(MCAP_LAYOUTS, &[&src, tmp.path()]);
    let map = g1viz::signals::SignalMap::g1_left_arm();
    let opts = OpenOptions::default();
    let original = g1viz::signals::load_recording(&src, &map, &opts).unwrap();
    for layout in ["no_repeated_channels", "unchunked_no_repeated_channels"] {
        let path = tmp.path().join(format!("{layout}.mcap"));
        let r = g1viz::signals::load_recording(&path, &map, &opts).unwrap();
        assert_eq!(r.state.t, original.state.t, "{layout}");
        assert_eq!(r.state.tau, original.state.tau, "{layout}");
        assert_eq!(r.command.q, original.command.q, "{layout}");
        assert_eq!(r.mbs.watts, original.mbs.watts, "{layout}");
        assert_eq!(r.bms.watts, original.bms.watts, "{layout}");
    }
}

const ROSBAGS_MCAP: &str = r#"
import sys, json, zlib
from pathlib import Path
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.writer import CompressionMode, CompressionFormat, StoragePlugin

src, out = Path(sys.argv[1]), Path(sys.argv[2])
n = 3000
manifest = {}
for name, mode in [('mcap_zstd_file', CompressionMode.FILE), ('mcap_zstd_message', CompressionMode.MESSAGE), ('mcap_plain', None)]:
    topics = {}
    with Reader(src) as r:
        w = Writer(out / name, version=9, storage_plugin=StoragePlugin.MCAP)
        if mode is not None:
            w.set_compression(mode, CompressionFormat.ZSTD)
        with w:
            conns = {}
            for c in r.connections:
                conns[c.id] = w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, rihs01=c.digest)
            for i, (c, t, d) in enumerate(r.messages()):
                if i >= n:
                    break
                w.write(conns[c.id], t, d)
                topics.setdefault(c.topic, []).append((t, bytes(d)))
    m = {}
    for topic, msgs in topics.items():
        msgs.sort()
        crc = 0
        for t, d in msgs:
            crc = zlib.crc32(t.to_bytes(8, 'little') + len(d).to_bytes(4, 'little') + d, crc)
        m[topic] = [len(msgs), msgs[0][0], msgs[-1][0], crc]
    manifest[name] = m
print(json.dumps(manifest))
"#;

/// rosbag2 bags with MCAP storage and zstd file or message compression, as `rosbags` writes them.
#[test]
fn rosbag2_mcap_storage_with_zstd_compression() {
    let Some(shared) = common::shared_dir() else {
        return;
    };
    if !python_has("rosbags") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let src: PathBuf = shared.join("recordings/g1_smoke_db3");
    let manifest = generate(ROSBAGS_MCAP, &[&src, tmp.path()]);
    assert_eq!(manifest.len(), 3);
    for (bag, want) in &manifest {
        check(&tmp.path().join(bag), want);
    }
}
