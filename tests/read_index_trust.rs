//! The readers do not take an index on its word, and the figures do not depend on how a file
//! stores its topics. Inputs are built from the shipped `examples/g1_example.mcap` (expected
//! counts from the `mcap` crate's own reader, not from g1viz): a summary with its CRC set to 0
//! (the spec allows it) whose chunk index lists the wrong channel ids must still deliver every
//! sample, with a warning naming the index record; a CRC-0 summary whose chunk index leaves a
//! chunk out still delivers that chunk, with a warning naming its offset; the same session
//! written in other layouts (time-interleaved; one topic after another; chunked or not; indexed
//! or not — the unindexed ones by the Python `mcap` library) gives bit-identical counts, rates,
//! sample times, trial windows and identification. ROS 1: the index data records after a chunk
//! are checked against the messages read from it (a changed connection id or count is a
//! warning; the counts shown do not move), and a chunk info start time later than the chunk's
//! first message is a warning.

mod common;

use std::path::Path;

use g1viz::identify::{self, IdentifyOptions};
use g1viz::read::{OpenOptions, Session};
use g1viz::session::{SessionFile, StreamOptions};
use g1viz::signals::{self, Recording, SignalMap};

fn example_bytes() -> Vec<u8> {
    std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap")).unwrap()
}

/// Messages on `topic` in `bytes`, counted by the `mcap` crate.
fn count_with_mcap_crate(bytes: &[u8], topic: &str) -> usize {
    mcap::MessageStream::new(bytes)
        .unwrap()
        .filter(|m| m.as_ref().unwrap().channel.topic == topic)
        .count()
}

/// `bytes` with the footer's summary CRC zeroed and every chunk index entry's channel ids
/// replaced by ids no channel has (900, 901, ...). Returns the number of entries changed.
fn wrong_chunk_index_ids(bytes: &mut [u8]) -> usize {
    let u64_at = |b: &[u8], at: usize| u64::from_le_bytes(b[at..at + 8].try_into().unwrap());
    let footer = bytes.len() - 8 - 29; // footer record (9 + 20) before the closing magic
    assert_eq!(bytes[footer], 0x02, "footer opcode");
    let summary_start = u64_at(bytes, footer + 9) as usize;
    bytes[footer + 25..footer + 29].copy_from_slice(&0u32.to_le_bytes());
    let mut pos = summary_start;
    let mut changed = 0;
    while pos < footer {
        let (opcode, len) = (bytes[pos], u64_at(bytes, pos + 1) as usize);
        let body = pos + 9;
        if opcode == 0x08 {
            // start, end, chunk offset, chunk length (4 × u64), then the id → offset map.
            let map_len = u32::from_le_bytes(bytes[body + 32..body + 36].try_into().unwrap());
            let entries = body + 36;
            for (k, e) in (entries..entries + map_len as usize)
                .step_by(10)
                .enumerate()
            {
                bytes[e..e + 2].copy_from_slice(&(900 + k as u16).to_le_bytes());
                changed += 1;
            }
        }
        pos = body + len;
    }
    changed
}

#[test]
fn a_wrong_chunk_index_without_crc_loses_no_sample_and_is_reported() {
    let mut bytes = example_bytes();
    let expected = count_with_mcap_crate(&bytes, "/lowstate");
    assert_eq!(expected, 8248, "the example's joint states");
    assert!(wrong_chunk_index_ids(&mut bytes) > 0);
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("crc0_wrong_ids.mcap");
    std::fs::write(&file, &bytes).unwrap();

    let rec =
        signals::load_recording(&file, &SignalMap::g1_left_arm(), &OpenOptions::default()).unwrap();
    assert_eq!(rec.state.t.len(), expected);
    assert_eq!(
        rec.command.t.len(),
        count_with_mcap_crate(&bytes, "/arm_sdk")
    );
    assert!(
        rec.warnings.iter().any(
            |w| w.contains("chunk index record at byte offset") && w.contains("crc0_wrong_ids")
        ),
        "{:?}",
        rec.warnings
    );

    let info = Session::open(&file, &OpenOptions::default())
        .unwrap()
        .info()
        .unwrap();
    let lowstate = info.topics.iter().find(|t| t.topic == "/lowstate").unwrap();
    assert_eq!(lowstate.count as usize, expected);
}

/// `bytes` (an indexed MCAP file) with its `k`-th chunk index record left out of the summary,
/// the summary offset records dropped (they would point past it) and the summary CRC set to 0
/// (which the spec allows). Returns the new bytes and the left-out chunk's byte offset.
fn without_chunk_index(bytes: &[u8], k: usize) -> (Vec<u8>, u64) {
    let u64_at = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
    let footer = bytes.len() - 8 - 29;
    assert_eq!(bytes[footer], 0x02, "footer opcode");
    let summary_start = u64_at(footer + 9) as usize;
    let mut out = bytes[..summary_start].to_vec();
    let (mut pos, mut seen, mut left_out) = (summary_start, 0, None);
    while pos < footer {
        let (opcode, end) = (bytes[pos], pos + 9 + u64_at(pos + 1) as usize);
        if opcode == 0x08 {
            seen += 1;
            if seen == k + 1 {
                left_out = Some(u64_at(pos + 9 + 16)); // start, end time, then the chunk offset
                pos = end;
                continue;
            }
        }
        if opcode != 0x0E {
            out.extend_from_slice(&bytes[pos..end]);
        }
        pos = end;
    }
    out.push(0x02);
    out.extend_from_slice(&20u64.to_le_bytes());
    out.extend_from_slice(&(summary_start as u64).to_le_bytes());
    out.extend_from_slice(&[0; 12]); // no summary offsets, CRC 0
    out.extend_from_slice(&bytes[bytes.len() - 8..]);
    (
        out,
        left_out.expect("the example has that many chunk indexes"),
    )
}

#[test]
fn a_chunk_left_out_of_an_unchecked_index_is_read_from_the_data_section() {
    let bytes = example_bytes();
    let (damaged, chunk_at) = without_chunk_index(&bytes, 3);
    let tmp = tempfile::tempdir().unwrap();
    let (good, bad) = (
        tmp.path().join("good.mcap"),
        tmp.path().join("left_out.mcap"),
    );
    std::fs::write(&good, &bytes).unwrap();
    std::fs::write(&bad, &damaged).unwrap();

    let (map, opts) = (SignalMap::g1_left_arm(), OpenOptions::default());
    let (a, b) = (
        signals::load_recording(&good, &map, &opts).unwrap(),
        signals::load_recording(&bad, &map, &opts).unwrap(),
    );
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let rows = |v: &[[f64; 7]]| bits(&v.concat());
    assert_eq!(a.start_ns, b.start_ns);
    assert_eq!(bits(&a.state.t), bits(&b.state.t));
    assert_eq!(rows(&a.state.q), rows(&b.state.q));
    assert_eq!(rows(&a.state.tau), rows(&b.state.tau));
    assert_eq!(bits(&a.command.t), bits(&b.command.t));
    assert_eq!(bits(&a.mbs.watts), bits(&b.mbs.watts));
    assert_eq!(bits(&a.bms.t), bits(&b.bms.t));
    assert_eq!(b.state.t.len(), count_with_mcap_crate(&bytes, "/lowstate"));
    let warned = |w: &[String]| {
        w.iter().any(|w| {
            w.contains("left_out.mcap")
                && w.contains(&format!(
                    "chunk at byte offset {chunk_at} is missing from the chunk index"
                ))
        })
    };
    assert!(a.warnings.is_empty(), "{:?}", a.warnings);
    assert!(warned(&b.warnings), "{:?}", b.warnings);

    // `info` counts what was read, agrees with the statistics record, and says the same.
    let info = Session::open(&bad, &opts).unwrap().info().unwrap();
    for t in &info.topics {
        assert_eq!(
            t.count as usize,
            count_with_mcap_crate(&bytes, &t.topic),
            "{}",
            t.topic
        );
    }
    assert!(warned(&info.warnings), "{:?}", info.warnings);
    assert!(
        !info.warnings.iter().any(|w| w.contains("statistics")),
        "{:?}",
        info.warnings
    );
}

/// The example written with the `mcap` crate, its messages in `msgs` order.
fn write_layout(path: &Path, msgs: &[common::McapMsg]) {
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .chunk_size(Some(256 << 10))
        .create(std::io::BufWriter::new(
            std::fs::File::create(path).unwrap(),
        ))
        .unwrap();
    common::write_messages(&mut w, msgs);
    w.finish().unwrap();
}

#[test]
fn two_storage_layouts_of_one_session_give_identical_figures() {
    let tmp = tempfile::tempdir().unwrap();
    let mut msgs = common::example_messages();
    let interleaved = tmp.path().join("interleaved.mcap");
    write_layout(&interleaved, &msgs);
    // One topic after another, the power topics first (they start later than the states).
    msgs.sort_by(|a, b| b.topic.cmp(&a.topic).then(a.log_time.cmp(&b.log_time)));
    let by_topic = tmp.path().join("by_topic.mcap");
    write_layout(&by_topic, &msgs);

    let map = SignalMap::g1_left_arm();
    let opts = OpenOptions::default();
    let stats = |p: &Path| signals::signal_stats(p, &map, &opts).unwrap();
    let (a, b) = (stats(&interleaved), stats(&by_topic));
    assert_eq!(a.state.count, 8248);
    for (x, y) in [
        (a.state, b.state),
        (a.command, b.command),
        (a.mbs_power, b.mbs_power),
        (a.bms_power, b.bms_power),
    ] {
        assert_eq!(x.count, y.count);
        assert_eq!(x.rate_hz.to_bits(), y.rate_hz.to_bits(), "{x:?} vs {y:?}");
    }
    let info = |p: &Path| Session::open(p, &opts).unwrap().info().unwrap();
    let (ia, ib) = (info(&interleaved), info(&by_topic));
    assert_eq!((ia.start_ns, ia.end_ns), (ib.start_ns, ib.end_ns));
    for (x, y) in ia.topics.iter().zip(&ib.topics) {
        assert_eq!((&x.topic, x.count), (&y.topic, y.count));
        assert_eq!(x.rate_hz.to_bits(), y.rate_hz.to_bits(), "{}", x.topic);
    }
    let load = |p: &Path| signals::load_recording(p, &map, &opts).unwrap();
    let (ra, rb) = (load(&interleaved), load(&by_topic));
    assert_eq!(ra.start_ns, rb.start_ns);
    let bits = |t: &[f64]| t.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&ra.state.t), bits(&rb.state.t));
    assert_eq!(bits(&ra.command.t), bits(&rb.command.t));
    assert_eq!(bits(&ra.mbs.t), bits(&rb.mbs.t));
}

/// `examples/g1_example.mcap` rewritten by `tests/py/mcap_layouts.py` (the Python `mcap`
/// library) into `out` with the given arguments.
fn python_layout(out: &Path, args: &[&str]) -> bool {
    if !common::python_module("mcap", "mcap") {
        return false;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let status = std::process::Command::new("python3")
        .arg(root.join("tests/py/mcap_layouts.py"))
        .arg(root.join("examples/g1_example.mcap"))
        .arg(out)
        .args(args)
        .status()
        .expect("python3 runs");
    assert!(status.success(), "mcap_layouts.py {args:?}");
    true
}

/// Everything a streamed read in batches of 500 samples hands over, as bits: the clock origin
/// and per group the sample times and values, batch by batch concatenated.
fn streamed_bits(path: &Path) -> (u64, Vec<Vec<u64>>) {
    let mut groups = vec![Vec::new(); 4];
    let summary = signals::stream_recording(
        path,
        &SignalMap::g1_left_arm(),
        &OpenOptions::default(),
        500,
        &mut |b: &Recording| {
            let s = &b.state;
            let g = &mut groups;
            g[0].extend(
                s.t.iter()
                    .chain(s.q.iter().chain(&s.tau).flatten())
                    .map(|v| v.to_bits()),
            );
            g[1].extend(
                b.command
                    .t
                    .iter()
                    .chain(b.command.q.iter().flatten())
                    .map(|v| v.to_bits()),
            );
            g[2].extend(b.mbs.t.iter().chain(&b.mbs.watts).map(|v| v.to_bits()));
            g[3].extend(b.bms.t.iter().chain(&b.bms.watts).map(|v| v.to_bits()));
            Ok(())
        },
    )
    .unwrap();
    (summary.start_ns, groups)
}

#[test]
fn unindexed_layouts_give_the_figures_of_the_indexed_file() {
    let tmp = tempfile::tempdir().unwrap();
    let layouts: [(&str, &[&str]); 3] = [
        (
            "time_chunked.mcap",
            &["--order", "time", "--chunk-size", "262144"],
        ),
        (
            "topic_chunked.mcap",
            &["--order", "topic", "--chunk-size", "65536"],
        ),
        (
            "topic_unchunked.mcap",
            &["--order", "topic", "--chunk-size", "0"],
        ),
    ];
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap");
    let opts = OpenOptions::default();
    let map = SignalMap::g1_left_arm();
    let reference = streamed_bits(&example);
    let ref_stats = signals::signal_stats(&example, &map, &opts).unwrap();
    let ref_info = Session::open(&example, &opts).unwrap().info().unwrap();
    let session = |p: &Path| SessionFile {
        path: p.to_path_buf(),
        map: map.clone(),
        read: Default::default(),
        spill: Default::default(),
    };
    // The example is too short for the timing search; pieces of 15 s and batches of 500 make
    // the streamed passes take many batches.
    let id_opts = IdentifyOptions {
        alignment: identify::AlignmentChoice::Given(identify::Alignment::NOMINAL),
        ..IdentifyOptions::default()
    };
    let so = StreamOptions {
        chunk_s: 15.0,
        batch_samples: 500,
        ..StreamOptions::default()
    };
    let ref_id = identify::identify_files(&[session(&example)], &id_opts, &so).unwrap();
    assert_eq!(ref_id.sessions[0].segmentation.trials.len(), 7);
    for (name, args) in layouts {
        let path = tmp.path().join(name);
        if !python_layout(&path, args) {
            return;
        }
        let src = Session::open(&path, &opts).unwrap();
        assert!(!src.info_is_cheap(), "{name} has no index");
        let (start, groups) = streamed_bits(&path);
        assert_eq!(start, reference.0, "{name}: clock origin");
        for (g, (a, b)) in groups.iter().zip(&reference.1).enumerate() {
            assert!(
                a == b,
                "{name}: group {g} differs ({} vs {} values)",
                a.len(),
                b.len()
            );
        }
        let stats = signals::signal_stats(&path, &map, &opts).unwrap();
        assert_eq!(stats, ref_stats, "{name}");
        let info = Session::open(&path, &opts).unwrap().info().unwrap();
        assert_eq!(
            (info.start_ns, info.end_ns),
            (ref_info.start_ns, ref_info.end_ns)
        );
        for (x, y) in info.topics.iter().zip(&ref_info.topics) {
            assert_eq!((&x.topic, x.count), (&y.topic, y.count), "{name}");
            assert_eq!(
                x.rate_hz.to_bits(),
                y.rate_hz.to_bits(),
                "{name}: {}",
                x.topic
            );
        }
        let id = identify::identify_files(&[session(&path)], &id_opts, &so).unwrap();
        let (x, y) = (&id.sessions[0], &ref_id.sessions[0]);
        assert_eq!(
            x.segmentation.trials, y.segmentation.trials,
            "{name}: trial windows"
        );
        assert_eq!(id.model.to_vector(), ref_id.model.to_vector(), "{name}: θ");
        assert_eq!(id.per_trial, ref_id.per_trial, "{name}");
        assert_eq!(id.fit, ref_id.fit, "{name}");
        assert!(
            info.warnings.is_empty() && stats.warnings.is_empty(),
            "{name}: {:?} {:?}",
            info.warnings,
            stats.warnings
        );
    }
}

/// Byte offset of the value of header field `name` in the first ROS 1 record with op `op`
/// (walking the records of `g1_smoke.bag` as the format lays them out).
fn ros1_field_at(b: &[u8], op: u8, name: &[u8]) -> usize {
    let u32_at = |at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) as usize;
    let mut at = 13;
    while at + 8 <= b.len() {
        let header_len = u32_at(at);
        let (header, mut q) = (at + 4..at + 4 + header_len, at + 4);
        let mut found = (None, None);
        while q < header.end {
            let len = u32_at(q);
            let field = &b[q + 4..q + 4 + len];
            let eq = field.iter().position(|&c| c == b'=').unwrap();
            if &field[..eq] == b"op" {
                found.0 = Some(field[eq + 1]);
            } else if &field[..eq] == name {
                found.1 = Some(q + 4 + eq + 1);
            }
            q += 4 + len;
        }
        if let (Some(o), Some(v)) = found
            && o == op
        {
            return v;
        }
        at = header.end + 4 + u32_at(header.end);
    }
    panic!("no record with op {op} and field {name:?}");
}

/// ROS 1 `info` counts come from the messages read; the index data records after a chunk are
/// checked against them: one naming a connection that is not in the chunk, or whose count
/// does not match its entries, is a warning naming its byte offset, and no count moves.
#[test]
fn ros1_index_data_records_are_checked_against_the_chunk() {
    let Some(src) = common::shared_recording("g1_smoke.bag") else {
        return;
    };
    let clean = std::fs::read(&src).unwrap();
    let counts = |path: &Path| {
        let info = Session::open(path, &OpenOptions::default())
            .unwrap()
            .info()
            .unwrap();
        let c: Vec<(String, u64)> = info
            .topics
            .iter()
            .map(|t| (t.topic.clone(), t.count))
            .collect();
        (c, info.warnings)
    };
    let tmp = tempfile::tempdir().unwrap();
    let (truth, warnings) = counts(&src);
    assert!(warnings.is_empty(), "{warnings:?}");
    for (field, change) in [(&b"conn"[..], 0xFFFF_FF00u32), (&b"count"[..], 1)] {
        let mut bytes = clean.clone();
        let at = ros1_field_at(&bytes, 0x04, field);
        let value = u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) ^ change;
        bytes[at..at + 4].copy_from_slice(&value.to_le_bytes());
        let path = tmp.path().join("damaged.bag");
        std::fs::write(&path, &bytes).unwrap();
        let (c, warnings) = counts(&path);
        assert_eq!(c, truth, "{field:?}");
        assert!(
            warnings.iter().any(|w| w.contains("index data record")
                && w.contains("byte offset")
                && w.contains("the counts shown are the ones read")),
            "{field:?} at byte {at}: {warnings:?}"
        );
    }
}

/// A ROS 1 chunk info record whose start time is later than the chunk's first message (so the
/// chunk is read late and its messages may come out of time order) is a warning naming the
/// record; every message is still delivered.
#[test]
fn a_ros1_chunk_info_start_later_than_its_messages_is_reported() {
    let Some(src) = common::shared_recording("g1_smoke.bag") else {
        return;
    };
    let read = |path: &Path| {
        let mut n = 0u64;
        let summary = Session::open(path, &OpenOptions::default())
            .unwrap()
            .read(None, &mut |_| {
                n += 1;
                Ok(())
            })
            .unwrap();
        (n, summary.warnings)
    };
    let (clean_n, clean_warnings) = read(&src);
    assert!(clean_warnings.is_empty(), "{clean_warnings:?}");
    let mut bytes = std::fs::read(&src).unwrap();
    // The first chunk info record's start time, seconds field: 100 s later.
    let at = ros1_field_at(&bytes, 0x06, b"start_time");
    let sec = u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) + 100;
    bytes[at..at + 4].copy_from_slice(&sec.to_le_bytes());
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("late_start.bag");
    std::fs::write(&path, &bytes).unwrap();
    let (n, warnings) = read(&path);
    assert_eq!(n, clean_n);
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("the chunk info record at byte offset")
                && w.contains("out of time order")),
        "{warnings:?}"
    );
}
