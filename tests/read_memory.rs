//! Peak memory on the largest valid input the MCAP reader accepts: a file whose one zstd chunk
//! declares (and really holds) an uncompressed size within 1 MiB of the 256 MiB chunk limit —
//! the example session's messages plus padding messages on another topic — is read by
//! `g1viz info` (summary, then the arm signals streamed through that chunk) in a child limited
//! to 2 GiB of address space (`ulimit -v 2097152`) with a peak RSS under 512 MB.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// The reader's largest accepted chunk (decompressed) [bytes].
const MAX_CHUNK_BYTES: u64 = 256 << 20;
/// Peak RSS budget of the child [KiB].
const MAX_RSS_KIB: i64 = 512 * 1024;
/// Size of one padding message [bytes].
const PAD: usize = 64 << 10;

/// Write the example's messages plus padding into one chunk of just under `MAX_CHUNK_BYTES`.
fn write_big_chunk(path: &Path) {
    let bytes =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap"))
            .unwrap();
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .chunk_size(Some(2 * MAX_CHUNK_BYTES))
        .create(std::io::BufWriter::new(
            std::fs::File::create(path).unwrap(),
        ))
        .unwrap();
    let mut channels = BTreeMap::<String, u16>::new();
    let mut written = 0usize;
    let mut first_time = None;
    for (seq, m) in mcap::MessageStream::new(&bytes).unwrap().enumerate() {
        let m = m.unwrap();
        let id = *channels.entry(m.channel.topic.clone()).or_insert_with(|| {
            let s = m.channel.schema.as_ref().unwrap();
            let sid = w.add_schema(&s.name, &s.encoding, &s.data).unwrap();
            w.add_channel(sid, &m.channel.topic, "cdr", &BTreeMap::new())
                .unwrap()
        });
        first_time.get_or_insert(m.log_time);
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: seq as u32,
            log_time: m.log_time,
            publish_time: m.log_time,
        };
        w.write_to_known_channel(&header, &m.data).unwrap();
        written += m.data.len() + 31;
    }
    let sid = w
        .add_schema("pad/msg/Blob", "ros2msg", b"uint8[] data")
        .unwrap();
    let pad = w
        .add_channel(sid, "/padding", "cdr", &BTreeMap::new())
        .unwrap();
    let blob = vec![0u8; PAD];
    let target = MAX_CHUNK_BYTES as usize - (256 << 10);
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

#[test]
fn a_chunk_of_the_largest_accepted_size_is_read_in_under_512_mb() {
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("big_chunk.mcap");
    write_big_chunk(&file);
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

    let out = common::output_within(
        Command::new("sh")
            .arg("-c")
            .arg("ulimit -v 2097152 && exec \"$0\" info \"$1\"")
            .arg(env!("CARGO_BIN_EXE_g1viz"))
            .arg(&file),
        common::G1VIZ_LIMIT,
    )
    .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("/lowstate") && text.contains("/padding"),
        "{text}"
    );
    // SAFETY: getrusage only writes the struct it is given.
    let peak_kib = unsafe {
        let mut usage: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage);
        usage.ru_maxrss
    };
    eprintln!("peak RSS of g1viz info: {} MiB", peak_kib >> 10);
    assert!(
        peak_kib < MAX_RSS_KIB,
        "peak RSS {peak_kib} KiB on a {declared}-byte chunk"
    );
}
