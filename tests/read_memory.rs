//! Peak memory on the largest valid inputs the MCAP and ROS 1 readers accept: a file whose chunk
//! declares (and really holds) an uncompressed size within 1 MiB of the 64 MiB chunk limit — a
//! session's messages plus padding messages on another topic; the MCAP written with the `mcap`
//! crate, the ROS 1 bag (lz4) with the Python `rosbags` library — is read by `g1viz info`
//! (summary, then the arm signals streamed through that chunk) in a child limited to 2 GiB of
//! address space (`ulimit -v 2097152`) with a peak RSS under 512 MB. A real chunk of 256 MiB
//! (the earlier cap, which then peaked at 531 MB) is refused with a message naming the limit and
//! the chunk's byte offset, under the same limits.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// The reader's largest accepted chunk (decompressed) [bytes].
const MAX_CHUNK_BYTES: u64 = 64 << 20;
/// Peak RSS budget of the child [KiB].
const MAX_RSS_KIB: i64 = 512 * 1024;
/// Size of one padding message [bytes].
const PAD: usize = 64 << 10;

/// Write the example's messages plus padding into one chunk of just under `size` bytes.
fn write_big_chunk(path: &Path, size: u64) {
    let msgs = common::example_messages();
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .chunk_size(Some(2 * size))
        .create(std::io::BufWriter::new(
            std::fs::File::create(path).unwrap(),
        ))
        .unwrap();
    let mut written = common::write_messages(&mut w, &msgs);
    let first_time = msgs.first().map(|m| m.log_time);
    let sid = w
        .add_schema("pad/msg/Blob", "ros2msg", b"uint8[] data")
        .unwrap();
    let pad = w
        .add_channel(sid, "/padding", "cdr", &BTreeMap::new())
        .unwrap();
    let blob = vec![0u8; PAD];
    let target = size as usize - (256 << 10);
    let mut seq = 0u32;
    while written + PAD + 31 < target {
        let header = mcap::records::MessageHeader {
            channel_id: pad,
            sequence: seq,
            log_time: first_time.unwrap(),
            publish_time: 0,
        };
        w.write_to_known_channel(&header, &blob).unwrap();
        written += PAD + 31;
        seq += 1;
    }
    w.finish().unwrap();
}

/// Run `g1viz info FILE` under `ulimit -v 2097152`; returns its stdout and the peak RSS of the
/// largest child waited for so far [KiB].
fn info_under_ulimit(file: &Path) -> (String, i64) {
    let out = common::output_within(
        Command::new("sh")
            .arg("-c")
            .arg("ulimit -v 2097152 && exec \"$0\" info \"$1\"")
            .arg(env!("CARGO_BIN_EXE_g1viz"))
            .arg(file),
        common::G1VIZ_LIMIT,
    )
    .unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // SAFETY: getrusage only writes the struct it is given.
    let peak_kib = unsafe {
        let mut usage: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage);
        usage.ru_maxrss
    };
    (text, peak_kib)
}

// One test per binary run would keep RUSAGE_CHILDREN per file; both files are checked in one
// test so the maximum is over both children, each of which must be under the budget.
#[test]
fn chunks_of_the_largest_accepted_size_are_read_in_under_512_mb() {
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("big_chunk.mcap");
    write_big_chunk(&file, MAX_CHUNK_BYTES);
    // The file is what it claims: one chunk, declared within 1 MiB of the limit.
    let bytes = std::fs::read(&file).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    assert_eq!(summary.chunk_indexes.len(), 1);
    let declared = summary.chunk_indexes[0].uncompressed_size;
    assert!(
        declared <= MAX_CHUNK_BYTES && declared > MAX_CHUNK_BYTES - (1 << 20),
        "declared {declared}"
    );
    drop(bytes);
    let (text, peak_kib) = info_under_ulimit(&file);
    assert!(
        text.contains("/lowstate") && text.contains("/padding"),
        "{text}"
    );
    eprintln!("peak RSS of g1viz info (MCAP): {} MiB", peak_kib >> 10);
    assert!(
        peak_kib < MAX_RSS_KIB,
        "peak RSS {peak_kib} KiB on a {declared}-byte MCAP chunk"
    );

    let Some(bag) = common::shared_recording("g1_smoke.bag") else {
        return;
    };
    if !common::python_module("rosbags", "rosbags==0.11.9") {
        return;
    }
    let big = tmp.path().join("big_chunk.bag");
    let out = common::output_within(
        Command::new("python3")
            .args(["-c", ROS1_BIG_CHUNK])
            .arg(&bag)
            .arg(&big)
            .arg(MAX_CHUNK_BYTES.to_string()),
        common::TOOL_LIMIT,
    )
    .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let sizes = ros1_chunk_sizes(&std::fs::read(&big).unwrap());
    let largest = sizes.iter().copied().max().unwrap();
    assert!(
        largest <= MAX_CHUNK_BYTES && largest > MAX_CHUNK_BYTES - (1 << 20),
        "chunk sizes {sizes:?}"
    );
    let (text, peak_kib) = info_under_ulimit(&big);
    assert!(
        text.contains("/lowstate") && text.contains("/padding"),
        "{text}"
    );
    eprintln!("peak RSS of g1viz info (both): {} MiB", peak_kib >> 10);
    assert!(
        peak_kib < MAX_RSS_KIB,
        "peak RSS {peak_kib} KiB on a {largest}-byte ROS 1 chunk"
    );
}

#[test]
fn a_256_mib_chunk_is_refused_under_512_mb() {
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("chunk_256_mib.mcap");
    write_big_chunk(&file, 256 << 20);
    let bytes = std::fs::read(&file).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let chunk = &summary.chunk_indexes[0];
    assert!(chunk.uncompressed_size > 255 << 20, "{chunk:?}");
    drop(bytes);
    let out = common::output_within(
        Command::new("sh")
            .arg("-c")
            .arg("ulimit -v 2097152 && exec \"$0\" info \"$1\"")
            .arg(env!("CARGO_BIN_EXE_g1viz"))
            .arg(&file),
        common::G1VIZ_LIMIT,
    )
    .unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(
        matches!(out.status.code(), Some(0 | 1)),
        "{:?}\n{text}",
        out.status
    );
    let needle = format!("damaged at byte offset {}", chunk.chunk_start_offset);
    assert!(
        text.contains(&needle) && text.contains("64 MiB limit"),
        "{text}"
    );
    // SAFETY: getrusage only writes the struct it is given.
    let peak_kib = unsafe {
        let mut usage: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage);
        usage.ru_maxrss
    };
    assert!(peak_kib < MAX_RSS_KIB, "peak RSS {peak_kib} KiB");
}

/// Copies a ROS 1 bag's messages into one lz4 chunk and pads it with 64 KiB messages on
/// `/padding` until the writer closes the chunk just under the limit:
/// argv = source bag, destination, chunk limit [bytes].
const ROS1_BIG_CHUNK: &str = r#"
import sys
from rosbags.rosbag1 import Reader, Writer
src, dst, limit = sys.argv[1], sys.argv[2], int(sys.argv[3])
w = Writer(dst)
w.set_compression(Writer.CompressionFormat.LZ4)
w.chunk_threshold = limit - (192 << 10)
with Reader(src) as r, w:
    conns, last, pad_conn = {}, 0, None
    for c in r.connections:
        conns[c.id] = w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
        if pad_conn is None:
            pad_conn = w.add_connection('/padding', c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
    for c, t, d in r.messages():
        w.write(conns[c.id], t, d)
        last = t
    blob = bytes(64 << 10)
    while len(w.chunks) == 1:
        w.write(pad_conn, last, blob)
"#;

/// The declared uncompressed size of every chunk record of a ROS 1 bag.
fn ros1_chunk_sizes(b: &[u8]) -> Vec<u64> {
    let u32_at = |at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) as usize;
    let mut out = Vec::new();
    let mut pos = 13;
    while pos + 4 <= b.len() {
        let header_len = u32_at(pos);
        let header = &b[pos + 4..pos + 4 + header_len];
        let (mut op, mut size) = (0u8, None);
        let mut f = 0;
        while f + 4 <= header.len() {
            let len = u32::from_le_bytes(header[f..f + 4].try_into().unwrap()) as usize;
            let field = &header[f + 4..f + 4 + len];
            if let Some(v) = field.strip_prefix(b"op=") {
                op = v[0];
            } else if let Some(v) = field.strip_prefix(b"size=") {
                size = Some(u64::from(u32::from_le_bytes(v[..4].try_into().unwrap())));
            }
            f += 4 + len;
        }
        if op == 0x05 {
            out.extend(size);
        }
        let data_at = pos + 4 + header_len;
        pos = data_at + 4 + u32_at(data_at);
    }
    out
}
