//! Decode throughput of the ROS 2 bag (.db3) and ROS 1 bag (.bag) readers, beside the MCAP
//! reader, on the same generated 1-hour 100 Hz `/lowstate` session: messages per second through container reading plus
//! extraction of the 7 left-arm joints' q, dq, tau_est and winding temperature, and the peak
//! RSS of the reading process (measured in a child process so generation does not count).
//!
//! ```text
//! cargo run --release --no-default-features --example bench_bags [-- --minutes 60]
//! ```

use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use g1viz::read::McapSource;
use g1viz::read::Ros1BagSource;
use g1viz::read::Ros2BagSource;
use g1viz::read::{
    Channel, FieldExtractor, FieldPath, MessageSource, OpenOptions, builtin_definition,
};

const RATE_HZ: u64 = 100;
const START_NS: u64 = 1_773_482_400_000_000_000;
const LOWSTATE: &str = "unitree_hg/msg/LowState";

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    if let [_, flag, path] = args.as_slice()
        && flag == "--read"
    {
        return read_child(Path::new(path));
    }
    let minutes: u64 = match args.iter().position(|a| a == "--minutes") {
        Some(i) => args
            .get(i + 1)
            .context("--minutes needs a value")?
            .parse()?,
        None => 60,
    };
    let n = minutes * 60 * RATE_HZ;
    let dir = tempfile::tempdir()?;
    let definition = lowstate_definition()?;

    let t = Instant::now();
    let bag_dir = dir.path().join("session_db3");
    write_db3(&bag_dir, n, &definition)?;
    let bag1 = dir.path().join("session.bag");
    write_bag1(&bag1, n, &definition)?;
    let mcap = dir.path().join("session.mcap");
    write_mcap(&mcap, n, &definition)?;
    eprintln!(
        "generated {n} LowState messages ({minutes} min at {RATE_HZ} Hz) as .db3 ({:.0} MB), .bag ({:.0} MB) \
         and .mcap ({:.0} MB, zstd chunks) in {:.1} s",
        dir_size(&bag_dir)? as f64 / 1e6,
        std::fs::metadata(&bag1)?.len() as f64 / 1e6,
        std::fs::metadata(&mcap)?.len() as f64 / 1e6,
        t.elapsed().as_secs_f64()
    );
    for path in [bag_dir, bag1, mcap] {
        let out = std::process::Command::new(std::env::current_exe()?)
            .arg("--read")
            .arg(&path)
            .output()?;
        if !out.status.success() {
            bail!("reader failed: {}", String::from_utf8_lossy(&out.stderr));
        }
        print!("{}", String::from_utf8_lossy(&out.stdout));
    }
    Ok(())
}

/// Child process: read one file, extract the arm signals, report throughput and peak RSS.
fn read_child(path: &Path) -> Result<()> {
    const RUNS: usize = 3;
    let fields: Vec<FieldPath> = (15..22)
        .flat_map(|k| {
            ["q", "dq", "tau_est", "temperature[0]"].map(|f| format!("motor_state[{k}].{f}"))
        })
        .map(|p| FieldPath::parse(&p))
        .collect::<Result<_, _>>()?;
    let mut out = vec![0.0; fields.len()];
    // The machine is shared: report the median of a few runs (page cache warm after the first).
    let mut secs = Vec::with_capacity(RUNS);
    let (mut messages, mut checksum, mut format) = (0, 0.0, "");
    for _ in 0..RUNS {
        let t = Instant::now();
        let opts = OpenOptions::default();
        let mut source: Box<dyn MessageSource> = match path.extension().and_then(|e| e.to_str()) {
            Some("bag") => Box::new(Ros1BagSource::open(path, &opts)?),
            Some("mcap") => Box::new(McapSource::open(path, &opts)?),
            _ => Box::new(Ros2BagSource::open(path, &opts)?),
        };
        let mut extractor: Option<(Arc<Channel>, FieldExtractor)> = None;
        checksum = 0.0;
        let summary = source.read(Some(&["/lowstate"]), &mut |m| {
            let ex = match &extractor {
                Some((c, ex)) if Arc::ptr_eq(c, m.channel) => ex,
                _ => {
                    let ex =
                        FieldExtractor::compile(&m.channel.schema, m.channel.encoding, &fields)
                            .map_err(|e| g1viz::read::ReadError::Other(e.to_string()))?;
                    &extractor.insert((m.channel.clone(), ex)).1
                }
            };
            ex.extract(m.data, &mut out)
                .map_err(|e| g1viz::read::ReadError::Other(e.to_string()))?;
            checksum += out[0];
            Ok(())
        })?;
        secs.push(t.elapsed().as_secs_f64());
        messages = summary.messages;
        format = source.format();
        if secs.len() == RUNS {
            let t_info = Instant::now();
            let info = source.info()?;
            println!(
                "{format:>12}: info() {} msgs in {:.2} s",
                info.messages,
                t_info.elapsed().as_secs_f64()
            );
        }
    }
    secs.sort_by(f64::total_cmp);
    let median = secs[RUNS / 2];
    println!(
        "{format:>12}: {messages} msgs in {median:.2} s (median of {RUNS}) = {:.0} LowState msgs/s \
         (open + read + extract 28 fields), peak RSS {:.0} MB (checksum {checksum:.3})",
        messages as f64 / median,
        peak_rss_mb()?
    );
    Ok(())
}

fn peak_rss_mb() -> Result<f64> {
    let status = std::fs::read_to_string("/proc/self/status")?;
    let kb: f64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .context("no VmHWM")?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()?;
    Ok(kb / 1024.0)
}

fn dir_size(dir: &Path) -> Result<u64> {
    let mut total = 0;
    for e in std::fs::read_dir(dir)? {
        total += e?.metadata()?.len();
    }
    Ok(total)
}

/// LowState's definition with its dependencies in the concatenated form bags embed.
fn lowstate_definition() -> Result<String> {
    let mut text = builtin_definition(LOWSTATE)
        .context("LowState is built in")?
        .to_string();
    for dep in ["IMUState", "MotorState"] {
        let body = builtin_definition(&format!("unitree_hg/msg/{dep}"))
            .context("dependency is built in")?;
        text.push_str(&format!(
            "{}\nMSG: unitree_hg/{dep}\n{body}",
            "=".repeat(80)
        ));
    }
    Ok(text)
}

/// Serialiser for the two wire formats: CDR aligns each primitive to its size (relative to
/// the end of the 4-byte encapsulation header), ROS 1 packs.
struct Wire {
    buf: Vec<u8>,
    cdr: bool,
}

impl Wire {
    fn new(cdr: bool) -> Wire {
        let buf = if cdr { vec![0, 1, 0, 0] } else { Vec::new() };
        Wire { buf, cdr }
    }

    fn put(&mut self, bytes: &[u8]) {
        if self.cdr {
            while !(self.buf.len() - 4).is_multiple_of(bytes.len()) {
                self.buf.push(0);
            }
        }
        self.buf.extend_from_slice(bytes);
    }
}

/// One LowState sample: arm joints on slow sinusoids, everything else constant.
fn lowstate(i: u64, cdr: bool) -> Vec<u8> {
    let t = i as f64 / RATE_HZ as f64;
    let mut w = Wire::new(cdr);
    w.put(&1u32.to_le_bytes());
    w.put(&0u32.to_le_bytes());
    w.put(&[0]);
    w.put(&[0]);
    w.put(&((i * 10) as u32).to_le_bytes());
    for v in [
        1.0f32, 0.0, 0.0, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 9.81, 0.0, 0.0, 0.0,
    ] {
        w.put(&v.to_le_bytes());
    }
    w.put(&35i16.to_le_bytes());
    for k in 0..35u32 {
        let phase = k as f64 * 0.3;
        let q = if (15..22).contains(&k) {
            0.5 * (0.4 * t + phase).sin()
        } else {
            0.0
        };
        let dq = if (15..22).contains(&k) {
            0.2 * (0.4 * t + phase).cos()
        } else {
            0.0
        };
        w.put(&[1]);
        for v in [q, dq, 0.0, 2.0 * q] {
            w.put(&(v as f32).to_le_bytes());
        }
        w.put(&40i16.to_le_bytes());
        w.put(&35i16.to_le_bytes());
        w.put(&53.0f32.to_le_bytes());
        for v in [0u32; 7] {
            w.put(&v.to_le_bytes());
        }
    }
    w.buf.extend_from_slice(&[0; 40]); // uint8[40]: no alignment
    for v in [0u32; 5] {
        w.put(&v.to_le_bytes());
    }
    w.buf
}

/// A rosbag2 (metadata version 9, sqlite3) bag with one `/lowstate` topic.
fn write_db3(dir: &Path, n: u64, definition: &str) -> Result<()> {
    std::fs::create_dir_all(dir)?;
    let db = dir.join("session_db3_0.db3");
    let conn = rusqlite::Connection::open(&db)?;
    conn.execute_batch(
        "PRAGMA journal_mode = OFF; PRAGMA synchronous = OFF;
         CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
         CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL, metadata TEXT NOT NULL);
         CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
             serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL, type_description_hash TEXT NOT NULL);
         CREATE TABLE message_definitions(id INTEGER PRIMARY KEY, topic_type TEXT NOT NULL, encoding TEXT NOT NULL,
             encoded_message_definition TEXT NOT NULL, type_description_hash TEXT NOT NULL);
         CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, timestamp INTEGER NOT NULL, data BLOB NOT NULL);
         CREATE INDEX timestamp_idx ON messages (timestamp ASC);",
    )?;
    conn.execute(
        "INSERT INTO topics VALUES (1, '/lowstate', ?1, 'cdr', '[]', '')",
        [LOWSTATE],
    )?;
    conn.execute(
        "INSERT INTO message_definitions VALUES (1, ?1, 'ros2msg', ?2, '')",
        [LOWSTATE, definition],
    )?;
    conn.execute("BEGIN", [])?;
    {
        let mut insert =
            conn.prepare("INSERT INTO messages (topic_id, timestamp, data) VALUES (1, ?1, ?2)")?;
        for i in 0..n {
            insert.execute(rusqlite::params![
                (START_NS + i * 10_000_000) as i64,
                lowstate(i, true)
            ])?;
        }
    }
    conn.execute("COMMIT", [])?;
    std::fs::write(
        dir.join("metadata.yaml"),
        format!(
            "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: sqlite3\n  \
             relative_file_paths:\n  - session_db3_0.db3\n  message_count: {n}\n  \
             compression_format: ''\n  compression_mode: ''\n"
        ),
    )?;
    Ok(())
}

/// The same session as MCAP (the crate's default zstd chunks), for comparison.
fn write_mcap(path: &Path, n: u64, definition: &str) -> Result<()> {
    let mut w = mcap::Writer::new(std::io::BufWriter::new(std::fs::File::create(path)?))?;
    let schema = w.add_schema(LOWSTATE, "ros2msg", definition.as_bytes())?;
    let channel = w.add_channel(schema, "/lowstate", "cdr", &Default::default())?;
    for i in 0..n {
        let t = START_NS + i * 10_000_000;
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: i as u32,
            log_time: t,
            publish_time: t,
        };
        w.write_to_known_channel(&header, &lowstate(i, true))?;
    }
    w.finish()?;
    Ok(())
}

/// ROS 1 record: header fields, then data.
fn record(out: &mut Vec<u8>, fields: &[(&str, &[u8])], data: &[u8]) {
    let mut header = Vec::new();
    record_fields(&mut header, fields);
    out.extend_from_slice(&(header.len() as u32).to_le_bytes());
    out.extend_from_slice(&header);
    out.extend_from_slice(&(data.len() as u32).to_le_bytes());
    out.extend_from_slice(data);
}

fn ros_time(ns: u64) -> [u8; 8] {
    let mut t = [0u8; 8];
    t[..4].copy_from_slice(&((ns / 1_000_000_000) as u32).to_le_bytes());
    t[4..].copy_from_slice(&((ns % 1_000_000_000) as u32).to_le_bytes());
    t
}

/// A closed ROS 1 bag (format 2.0, uncompressed 768 KiB chunks, index) with `/lowstate`.
fn write_bag1(path: &PathBuf, n: u64, definition: &str) -> Result<()> {
    let mut file = std::io::BufWriter::new(std::fs::File::create(path)?);
    let conn_header = |out: &mut Vec<u8>| {
        let mut data = Vec::new();
        record_fields(
            &mut data,
            &[
                ("topic", b"/lowstate"),
                ("type", b"unitree_hg/LowState"),
                ("md5sum", b"00000000000000000000000000000000"),
                ("message_definition", definition.as_bytes()),
            ],
        );
        record(
            out,
            &[
                ("op", &[7]),
                ("conn", &0u32.to_le_bytes()),
                ("topic", b"/lowstate"),
            ],
            &data,
        );
    };
    let bag_header = |index_pos: u64, chunks: u32| {
        let mut out = b"#ROSBAG V2.0\n".to_vec();
        let fields: [(&str, &[u8]); 4] = [
            ("op", &[3]),
            ("index_pos", &index_pos.to_le_bytes()),
            ("conn_count", &1u32.to_le_bytes()),
            ("chunk_count", &chunks.to_le_bytes()),
        ];
        let mut rec = Vec::new();
        record(&mut rec, &fields, &[]);
        // Pad the bag header record to 4096 bytes, as rosbag does, so it can be rewritten in place.
        let pad = 4096 - rec.len();
        rec.clear();
        record(&mut rec, &fields, &vec![b' '; pad]);
        out.extend_from_slice(&rec);
        out
    };
    file.write_all(&bag_header(0, 0))?;
    let mut pos = file.stream_position()?;
    let mut chunk_infos: Vec<(u64, u64, u64, u32)> = Vec::new();
    let mut i = 0;
    while i < n {
        let mut chunk = Vec::new();
        conn_header(&mut chunk);
        let mut index = Vec::new();
        let start = START_NS + i * 10_000_000;
        let mut count = 0u32;
        while i < n && chunk.len() < 768 * 1024 {
            let t = START_NS + i * 10_000_000;
            index.extend_from_slice(&ros_time(t));
            index.extend_from_slice(&(chunk.len() as u32).to_le_bytes());
            record(
                &mut chunk,
                &[
                    ("op", &[2]),
                    ("conn", &0u32.to_le_bytes()),
                    ("time", &ros_time(t)),
                ],
                &lowstate(i, false),
            );
            i += 1;
            count += 1;
        }
        let end = START_NS + (i - 1) * 10_000_000;
        let mut out = Vec::new();
        record(
            &mut out,
            &[
                ("op", &[5]),
                ("compression", b"none"),
                ("size", &(chunk.len() as u32).to_le_bytes()),
            ],
            &chunk,
        );
        record(
            &mut out,
            &[
                ("op", &[4]),
                ("ver", &1u32.to_le_bytes()),
                ("conn", &0u32.to_le_bytes()),
                ("count", &count.to_le_bytes()),
            ],
            &index,
        );
        file.write_all(&out)?;
        chunk_infos.push((pos, start, end, count));
        pos += out.len() as u64;
    }
    let index_pos = pos;
    let mut out = Vec::new();
    conn_header(&mut out);
    for (chunk_pos, start, end, count) in &chunk_infos {
        let mut data = 0u32.to_le_bytes().to_vec();
        data.extend_from_slice(&count.to_le_bytes());
        record(
            &mut out,
            &[
                ("op", &[6]),
                ("ver", &1u32.to_le_bytes()),
                ("chunk_pos", &chunk_pos.to_le_bytes()),
                ("start_time", &ros_time(*start)),
                ("end_time", &ros_time(*end)),
                ("count", &1u32.to_le_bytes()),
            ],
            &data,
        );
    }
    file.write_all(&out)?;
    file.seek(SeekFrom::Start(0))?;
    file.write_all(&bag_header(index_pos, chunk_infos.len() as u32))?;
    file.flush()?;
    Ok(())
}

/// The `name=value` field list of a connection record's data.
fn record_fields(out: &mut Vec<u8>, fields: &[(&str, &[u8])]) {
    for (name, value) in fields {
        out.extend_from_slice(&((name.len() + 1 + value.len()) as u32).to_le_bytes());
        out.extend_from_slice(name.as_bytes());
        out.push(b'=');
        out.extend_from_slice(value);
    }
}
