//! Structure-aware mutation of recorded sessions, for fuzzing the readers on stable Rust.
//!
//! Seeds: the first messages of a valid MCAP session re-written in every container and
//! compression the readers support (MCAP zstd / lz4 / uncompressed chunks / unchunked / without
//! summary, written by the `mcap` crate; ROS 1 bags with none / bz2 / lz4 chunks, indexed or
//! not; rosbag2 sqlite bags plain, zstd-message and zstd-file). Mutators know each container's
//! framing: MCAP records (length prefixes, duplicated or dropped records, schema text), ROS 1
//! records (header fields, lengths, records inside uncompressed chunks), rosbag2 (metadata.yaml
//! lines and nesting, SQL edits of the database), plus plain byte havoc on any file.
//!
//! Shared by `examples/fuzz_readers.rs` (long campaigns, one child process per input) and
//! `tests/fuzz_short.rs` (a short in-process campaign in `cargo test`).

#![allow(dead_code)] // each includer uses a different part

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

use g1viz::read::{ArrayKind, FieldType, Primitive};
use g1viz::read::{Encoding, MsgSchema, OpenOptions, Session};
use g1viz::read::{Value, decode};

/// A small deterministic PRNG (xorshift64*): reproducible campaigns without API churn.
pub struct Rng(u64);

impl Rng {
    /// Seeded generator (any seed; 0 is remapped).
    pub fn new(seed: u64) -> Rng {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    /// Next 64 random bits.
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in `0..n` (0 when n is 0).
    pub fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next() % n as u64) as usize
        }
    }
    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64 <= p
    }
    /// An integer value that tends to break length and count fields.
    pub fn interesting(&mut self, old: u64, file_len: u64) -> u64 {
        match self.below(10) {
            0 => 0,
            1 => old.wrapping_add(1),
            2 => old.wrapping_sub(1),
            3 => u32::MAX as u64,
            4 => u64::MAX,
            5 => file_len,
            6 => old.wrapping_mul(2),
            7 => 1 << self.below(40),
            8 => old ^ (1 << self.below(64)),
            _ => self.next(),
        }
    }
}

/// Which reader a seed is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Kind {
    /// An MCAP file.
    Mcap,
    /// A ROS 1 bag.
    Bag1,
    /// A rosbag2 folder (metadata.yaml + storage file).
    Db3,
}

/// One input: its files (name → bytes; a single file for MCAP and ROS 1, a folder's files for
/// rosbag2) and what produced it.
#[derive(Debug, Clone)]
pub struct Input {
    /// Reader it targets.
    pub kind: Kind,
    /// Seed name and the mutations applied, for the findings report.
    pub label: String,
    /// File name → content.
    pub files: BTreeMap<String, Vec<u8>>,
}

impl Input {
    /// Write the input under `dir`; returns the path to open (the file, or the bag folder).
    pub fn write_to(&self, dir: &Path) -> std::io::Result<std::path::PathBuf> {
        let target = match self.kind {
            Kind::Db3 => dir.join("bag"),
            _ => dir.to_path_buf(),
        };
        std::fs::create_dir_all(&target)?;
        for (name, bytes) in &self.files {
            std::fs::write(target.join(name), bytes)?;
        }
        Ok(match self.kind {
            Kind::Db3 => target,
            _ => target.join(self.files.keys().next().map_or("x", |k| k.as_str())),
        })
    }
}

/// One message of the seed session: topic, schema (name, encoding, text), time, CDR payload.
#[derive(Debug, Clone)]
pub struct SeedMsg {
    pub topic: String,
    pub schema_name: String,
    pub schema_encoding: String,
    pub schema_text: Vec<u8>,
    pub log_time: u64,
    pub data: Vec<u8>,
}

/// The first `n` messages of a valid MCAP session (CDR, ros2msg schemas).
pub fn seed_messages(mcap_bytes: &[u8], n: usize) -> Vec<SeedMsg> {
    let mut out = Vec::new();
    for m in mcap::MessageStream::new(mcap_bytes)
        .expect("seed MCAP")
        .take(n)
    {
        let m = m.expect("seed MCAP message");
        let Some(schema) = m.channel.schema.as_ref() else {
            continue;
        };
        out.push(SeedMsg {
            topic: m.channel.topic.clone(),
            schema_name: schema.name.clone(),
            schema_encoding: schema.encoding.clone(),
            schema_text: schema.data.to_vec(),
            log_time: m.log_time,
            data: m.data.to_vec(),
        });
    }
    out
}

/// Every seed: the messages in each container layout and compression.
pub fn seeds(msgs: &[SeedMsg]) -> Vec<Input> {
    let mut out = Vec::new();
    for (name, compression, chunked, summary) in [
        ("mcap-zstd", Some(mcap::Compression::Zstd), true, true),
        ("mcap-lz4", Some(mcap::Compression::Lz4), true, true),
        ("mcap-none", None, true, true),
        ("mcap-unchunked", None, false, true),
        ("mcap-nosummary", None, true, false),
    ] {
        out.push(single(
            Kind::Mcap,
            name,
            "in.mcap",
            write_mcap(msgs, compression, chunked, summary),
        ));
    }
    for (name, compression, indexed) in [
        ("bag1-none", "none", true),
        ("bag1-bz2", "bz2", true),
        ("bag1-lz4", "lz4", true),
        ("bag1-unindexed", "none", false),
    ] {
        out.push(single(
            Kind::Bag1,
            name,
            "in.bag",
            write_bag1(msgs, compression, indexed),
        ));
    }
    for mode in ["none", "message", "file"] {
        out.push(write_db3(msgs, mode));
    }
    out
}

fn single(kind: Kind, label: &str, file: &str, bytes: Vec<u8>) -> Input {
    Input {
        kind,
        label: label.to_string(),
        files: [(file.to_string(), bytes)].into_iter().collect(),
    }
}

fn write_mcap(
    msgs: &[SeedMsg],
    compression: Option<mcap::Compression>,
    chunked: bool,
    summary: bool,
) -> Vec<u8> {
    let opts = mcap::WriteOptions::new()
        .compression(compression)
        .use_chunks(chunked)
        .chunk_size(Some(16 * 1024))
        .emit_summary_records(summary)
        .emit_summary_offsets(summary);
    let mut w = opts
        .create(std::io::Cursor::new(Vec::new()))
        .expect("mcap writer");
    let mut channels: BTreeMap<String, u16> = BTreeMap::new();
    for (seq, m) in msgs.iter().enumerate() {
        let id = match channels.get(&m.topic) {
            Some(id) => *id,
            None => {
                let schema = w
                    .add_schema(&m.schema_name, &m.schema_encoding, &m.schema_text)
                    .expect("schema");
                let id = w
                    .add_channel(schema, &m.topic, "cdr", &BTreeMap::new())
                    .expect("channel");
                channels.insert(m.topic.clone(), id);
                id
            }
        };
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: seq as u32,
            log_time: m.log_time,
            publish_time: m.log_time,
        };
        w.write_to_known_channel(&header, &m.data).expect("message");
    }
    w.finish().expect("finish");
    w.into_inner().into_inner()
}

/// Re-encode a decoded CDR message in ROS 1 serialisation (packed little endian, u32 lengths).
fn ros1_encode(schema: &MsgSchema, value: &Value, out: &mut Vec<u8>) {
    fn prim(p: Primitive, v: &Value, out: &mut Vec<u8>) {
        let f = v.as_f64().unwrap_or(0.0);
        match (p, v) {
            (Primitive::String, Value::String(s)) => {
                out.extend((s.len() as u32).to_le_bytes());
                out.extend(s.as_bytes());
            }
            (Primitive::Bool | Primitive::U8, _) => out.push(f as u8),
            (Primitive::I8, _) => out.push(f as i8 as u8),
            (Primitive::I16, _) => out.extend((f as i16).to_le_bytes()),
            (Primitive::U16, _) => out.extend((f as u16).to_le_bytes()),
            (Primitive::I32, _) => out.extend((f as i32).to_le_bytes()),
            (Primitive::U32, _) => out.extend((f as u32).to_le_bytes()),
            (Primitive::I64, Value::Int(i)) => out.extend(i.to_le_bytes()),
            (Primitive::U64, Value::UInt(u)) => out.extend(u.to_le_bytes()),
            (Primitive::I64 | Primitive::U64, _) => out.extend((f as i64).to_le_bytes()),
            (Primitive::F32, _) => out.extend((f as f32).to_le_bytes()),
            (Primitive::F64, _) => out.extend(f.to_le_bytes()),
            _ => out.extend([0u8; 8]),
        }
    }
    fn one(schema: &MsgSchema, ty: &FieldType, v: &Value, out: &mut Vec<u8>) {
        match (ty, v) {
            (FieldType::Primitive(p), v) => prim(*p, v, out),
            (FieldType::Message(name), Value::Struct(fields)) => {
                let Ok(t) = schema.get(name) else { return };
                for (f, (_, fv)) in t.fields.iter().zip(fields) {
                    match (f.array, fv) {
                        (ArrayKind::Single, v) => one(schema, &f.ty, v, out),
                        (ArrayKind::Fixed(_), Value::Array(items)) => {
                            items.iter().for_each(|i| one(schema, &f.ty, i, out))
                        }
                        (_, Value::Array(items)) => {
                            out.extend((items.len() as u32).to_le_bytes());
                            items.iter().for_each(|i| one(schema, &f.ty, i, out));
                        }
                        _ => {}
                    }
                }
            }
            _ => {}
        }
    }
    one(schema, &FieldType::Message(schema.root.clone()), value, out);
}

/// A ROS 1 record: header fields, data.
fn bag1_record(fields: &[(&str, Vec<u8>)], data: &[u8], out: &mut Vec<u8>) {
    let mut header = Vec::new();
    for (k, v) in fields {
        header.extend(((k.len() + 1 + v.len()) as u32).to_le_bytes());
        header.extend(k.as_bytes());
        header.push(b'=');
        header.extend(v);
    }
    out.extend((header.len() as u32).to_le_bytes());
    out.extend(&header);
    out.extend((data.len() as u32).to_le_bytes());
    out.extend(data);
}

fn ros1_time(ns: u64) -> Vec<u8> {
    let mut b = ((ns / 1_000_000_000) as u32).to_le_bytes().to_vec();
    b.extend(((ns % 1_000_000_000) as u32).to_le_bytes());
    b
}

fn write_bag1(msgs: &[SeedMsg], compression: &str, indexed: bool) -> Vec<u8> {
    // Connections: one per topic, ROS 1 type name and the definition text.
    let mut conns: BTreeMap<String, (u32, String, String, MsgSchema)> = BTreeMap::new();
    for m in msgs {
        if conns.contains_key(&m.topic) {
            continue;
        }
        let text = String::from_utf8_lossy(&m.schema_text).into_owned();
        let Ok(schema) = MsgSchema::parse(&m.schema_encoding, &m.schema_name, &text) else {
            continue;
        };
        let ty = m.schema_name.replace("/msg/", "/");
        let id = conns.len() as u32;
        conns.insert(m.topic.clone(), (id, ty, text, schema));
    }
    let conn_record =
        |topic: &str, (id, ty, text, _): &(u32, String, String, MsgSchema), out: &mut Vec<u8>| {
            let mut data = Vec::new();
            bag1_record(
                &[
                    ("topic", topic.as_bytes().to_vec()),
                    ("type", ty.as_bytes().to_vec()),
                    ("md5sum", b"*".to_vec()),
                    ("message_definition", text.as_bytes().to_vec()),
                ],
                &[],
                &mut data,
            );
            // The connection's data is the field list itself (without the record framing).
            let fields = data[4..data.len() - 4].to_vec();
            bag1_record(
                &[
                    ("op", vec![0x07]),
                    ("conn", id.to_le_bytes().to_vec()),
                    ("topic", topic.as_bytes().to_vec()),
                ],
                &fields,
                out,
            );
        };
    let mut body = Vec::new();
    let mut chunk_infos = Vec::new();
    let mut start = 13 + 4096 + 8; // magic + padded bag header record
    for group in msgs.chunks(40) {
        let mut raw = Vec::new();
        let mut index: BTreeMap<u32, Vec<(u64, u32)>> = BTreeMap::new();
        let mut written = std::collections::BTreeSet::new();
        for m in group {
            let Some(c) = conns.get(&m.topic) else {
                continue;
            };
            if written.insert(c.0) {
                conn_record(&m.topic, c, &mut raw);
            }
            let Ok(v) = decode(&c.3, Encoding::Cdr, &m.data) else {
                continue;
            };
            let mut payload = Vec::new();
            ros1_encode(&c.3, &v, &mut payload);
            index
                .entry(c.0)
                .or_default()
                .push((m.log_time, raw.len() as u32));
            bag1_record(
                &[
                    ("op", vec![0x02]),
                    ("conn", c.0.to_le_bytes().to_vec()),
                    ("time", ros1_time(m.log_time)),
                ],
                &payload,
                &mut raw,
            );
        }
        let data = match compression {
            "bz2" => {
                let mut e = bzip2::write::BzEncoder::new(Vec::new(), bzip2::Compression::fast());
                e.write_all(&raw).unwrap();
                e.finish().unwrap()
            }
            "lz4" => {
                let mut e = lz4_flex::frame::FrameEncoder::new(Vec::new());
                e.write_all(&raw).unwrap();
                e.finish().unwrap()
            }
            _ => raw.clone(),
        };
        let pos = start + body.len() as u64;
        bag1_record(
            &[
                ("op", vec![0x05]),
                ("compression", compression.as_bytes().to_vec()),
                ("size", (raw.len() as u32).to_le_bytes().to_vec()),
            ],
            &data,
            &mut body,
        );
        for (conn, entries) in &index {
            let mut d = Vec::new();
            for (t, off) in entries {
                d.extend(ros1_time(*t));
                d.extend(off.to_le_bytes());
            }
            bag1_record(
                &[
                    ("op", vec![0x04]),
                    ("ver", 1u32.to_le_bytes().to_vec()),
                    ("conn", conn.to_le_bytes().to_vec()),
                    ("count", (entries.len() as u32).to_le_bytes().to_vec()),
                ],
                &d,
                &mut body,
            );
        }
        let t0 = group.first().map_or(0, |m| m.log_time);
        let t1 = group.iter().map(|m| m.log_time).max().unwrap_or(0);
        let counts: Vec<(u32, u32)> = index.iter().map(|(c, e)| (*c, e.len() as u32)).collect();
        chunk_infos.push((pos, t0, t1, counts));
    }
    let index_pos = start + body.len() as u64;
    if indexed {
        for (topic, c) in &conns {
            conn_record(topic, c, &mut body);
        }
        for (pos, t0, t1, counts) in &chunk_infos {
            let d: Vec<u8> = counts
                .iter()
                .flat_map(|(c, n)| c.to_le_bytes().into_iter().chain(n.to_le_bytes()))
                .collect();
            bag1_record(
                &[
                    ("op", vec![0x06]),
                    ("ver", 1u32.to_le_bytes().to_vec()),
                    ("chunk_pos", pos.to_le_bytes().to_vec()),
                    ("start_time", ros1_time(*t0)),
                    ("end_time", ros1_time(*t1)),
                    ("count", (counts.len() as u32).to_le_bytes().to_vec()),
                ],
                &d,
                &mut body,
            );
        }
    }
    let mut out = b"#ROSBAG V2.0\n".to_vec();
    let mut header = Vec::new();
    let fields = [
        ("op", vec![0x03]),
        (
            "index_pos",
            (if indexed { index_pos } else { 0 }).to_le_bytes().to_vec(),
        ),
        (
            "conn_count",
            (if indexed { conns.len() as u32 } else { 0 })
                .to_le_bytes()
                .to_vec(),
        ),
        (
            "chunk_count",
            (if indexed { chunk_infos.len() as u32 } else { 0 })
                .to_le_bytes()
                .to_vec(),
        ),
    ];
    bag1_record(&fields, &[], &mut header);
    // Pad the bag header record to 4096 bytes of header + data, as rosbag does.
    let header_len = u32::from_le_bytes(header[..4].try_into().unwrap()) as usize;
    let pad = 4096 - header_len;
    header.truncate(4 + header_len);
    header.extend((pad as u32).to_le_bytes());
    header.extend(vec![b' '; pad]);
    out.extend(header);
    start = out.len() as u64;
    debug_assert_eq!(start, 13 + 4096 + 8);
    out.extend(body);
    out
}

fn write_db3(msgs: &[SeedMsg], mode: &str) -> Input {
    let tmp = tempfile::tempdir().expect("tempdir");
    let db = tmp.path().join("in.db3");
    {
        let conn = rusqlite::Connection::open(&db).expect("sqlite");
        // No fsync and one transaction: the seed is rebuilt by every campaign child.
        conn.execute_batch("PRAGMA synchronous = OFF; PRAGMA journal_mode = MEMORY;")
            .expect("pragmas");
        conn.execute_batch(
            "CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
             INSERT INTO schema VALUES (4, 'humble');
             CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
               serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
             CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
               timestamp INTEGER NOT NULL, data BLOB NOT NULL);
             CREATE INDEX timestamp_idx ON messages (timestamp ASC);
             CREATE TABLE message_definitions(id INTEGER PRIMARY KEY, topic_type TEXT NOT NULL,
               encoding TEXT NOT NULL, encoded_message_definition TEXT NOT NULL,
               type_description_hash TEXT NOT NULL);",
        )
        .expect("tables");
        conn.execute_batch("BEGIN").expect("begin");
        let mut topics: BTreeMap<String, i64> = BTreeMap::new();
        for m in msgs {
            let id = match topics.get(&m.topic) {
                Some(id) => *id,
                None => {
                    let id = topics.len() as i64 + 1;
                    conn.execute(
                        "INSERT INTO topics VALUES (?1, ?2, ?3, 'cdr', '')",
                        rusqlite::params![id, m.topic, m.schema_name],
                    )
                    .expect("topic");
                    conn.execute("INSERT INTO message_definitions (topic_type, encoding, encoded_message_definition, type_description_hash) VALUES (?1, ?2, ?3, '')", rusqlite::params![m.schema_name, m.schema_encoding, String::from_utf8_lossy(&m.schema_text)]).expect("definition");
                    topics.insert(m.topic.clone(), id);
                    id
                }
            };
            let data = if mode == "message" {
                zstd::bulk::compress(&m.data, 3).expect("zstd")
            } else {
                m.data.clone()
            };
            conn.execute(
                "INSERT INTO messages (topic_id, timestamp, data) VALUES (?1, ?2, ?3)",
                rusqlite::params![id, m.log_time as i64, data],
            )
            .expect("message");
        }
        conn.execute_batch("COMMIT").expect("commit");
    }
    let bytes = std::fs::read(&db).expect("db");
    let (file, bytes) = if mode == "file" {
        (
            "in.db3.zstd".to_string(),
            zstd::bulk::compress(&bytes, 3).expect("zstd"),
        )
    } else {
        ("in.db3".to_string(), bytes)
    };
    let (cmode, cfmt) = match mode {
        "none" => ("", ""),
        "message" => ("MESSAGE", "zstd"),
        _ => ("FILE", "zstd"),
    };
    let yaml = format!(
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: sqlite3\n  relative_file_paths:\n    - {file}\n  \
         duration:\n    nanoseconds: 1\n  starting_time:\n    nanoseconds_since_epoch: 0\n  message_count: {}\n  \
         topics_with_message_count: []\n  compression_format: \"{cfmt}\"\n  compression_mode: \"{cmode}\"\n",
        msgs.len()
    );
    Input {
        kind: Kind::Db3,
        label: format!("db3-{mode}"),
        files: [
            (file, bytes),
            ("metadata.yaml".to_string(), yaml.into_bytes()),
        ]
        .into_iter()
        .collect(),
    }
}

// ---------------------------------------------------------------------------------------------
// Mutation

/// The generator of input `i` of campaign seed `seed`: a pure function of both (splitmix64 of
/// the pair), so any input of a campaign can be rebuilt alone.
fn campaign_rng(seed: u64, i: u64) -> Rng {
    let mut z = seed
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(i.wrapping_mul(0xBF58_476D_1CE4_E5B9));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    Rng::new(z ^ (z >> 31))
}

/// Input `i` of campaign seed `seed` (`examples/fuzz_readers.rs` runs these).
pub fn input_for(seeds: &[Input], seed: u64, i: u64) -> Input {
    let mut rng = campaign_rng(seed, i);
    let base = &seeds[rng.below(seeds.len())];
    mutate(base, &mut rng)
}

/// The container input `i` of campaign seed `seed` targets, without building it (a mutation
/// keeps its seed's container).
pub fn campaign_kind(seeds: &[Input], seed: u64, i: u64) -> Kind {
    seeds[campaign_rng(seed, i).below(seeds.len())].kind
}

/// Apply 1–4 mutations (structure-aware for the input's container, or byte havoc).
pub fn mutate(seed: &Input, rng: &mut Rng) -> Input {
    let mut input = seed.clone();
    let rounds = 1 + rng.below(4);
    for _ in 0..rounds {
        let what = match (input.kind, rng.below(10)) {
            (_, 0 | 1) => havoc(&mut input, rng),
            (Kind::Mcap, _) => mutate_mcap(&mut input, rng),
            (Kind::Bag1, _) => mutate_bag1(&mut input, rng),
            (Kind::Db3, _) => mutate_db3(&mut input, rng),
        };
        input.label.push(' ');
        input.label.push_str(&what);
    }
    input
}

fn pick_file<'a>(input: &'a mut Input, rng: &mut Rng) -> (&'a str, &'a mut Vec<u8>) {
    let n = input.files.len();
    let (k, v) = input.files.iter_mut().nth(rng.below(n)).expect("a file");
    (k.as_str(), v)
}

/// Byte-level havoc on one file: flips, interesting bytes, inserted/deleted/duplicated ranges, truncation.
fn havoc(input: &mut Input, rng: &mut Rng) -> String {
    let choice = rng.below(6);
    let (name, b) = pick_file(input, rng);
    let name = name.to_string();
    if b.is_empty() {
        return format!("havoc({name}:empty)");
    }
    let at = rng.below(b.len());
    match choice {
        0 => b[at] ^= 1 << rng.below(8),
        1 => b[at] = [0, 0xFF, 0x7F, 0x80, b'-', b'[', b'{'][rng.below(7)],
        2 => {
            let n = 1 + rng.below(64);
            let bytes: Vec<u8> = (0..n).map(|_| rng.next() as u8).collect();
            b.splice(at..at, bytes);
        }
        3 => {
            let end = (at + 1 + rng.below(256)).min(b.len());
            b.drain(at..end);
        }
        4 => {
            let end = (at + 1 + rng.below(4096)).min(b.len());
            let copy = b[at..end].to_vec();
            let to = rng.below(b.len());
            b.splice(to..to, copy);
        }
        _ => b.truncate(at),
    }
    format!("havoc{choice}({name}@{at})")
}

/// Top-level MCAP records: (offset, opcode, length).
fn mcap_records(b: &[u8]) -> Vec<(usize, u8, u64)> {
    let mut out = Vec::new();
    let mut pos = 8;
    while pos + 9 <= b.len() {
        let len = u64::from_le_bytes(b[pos + 1..pos + 9].try_into().unwrap());
        out.push((pos, b[pos], len));
        match usize::try_from(len)
            .ok()
            .and_then(|l| (pos + 9).checked_add(l))
        {
            Some(next) if next <= b.len() => pos = next,
            _ => break,
        }
    }
    out
}

fn mutate_mcap(input: &mut Input, rng: &mut Rng) -> String {
    let (_, b) = pick_file(input, rng);
    let recs = mcap_records(b);
    if recs.is_empty() {
        return "mcap:none".into();
    }
    let (pos, opcode, len) = recs[rng.below(recs.len())];
    let end = usize::try_from(len)
        .ok()
        .and_then(|l| (pos + 9).checked_add(l))
        .map_or(b.len(), |e| e.min(b.len()));
    let file_len = b.len() as u64;
    match rng.below(6) {
        0 => {
            let v = rng.interesting(len, file_len);
            b[pos + 1..pos + 9].copy_from_slice(&v.to_le_bytes());
            format!("mcap:len(op{opcode:#x}@{pos}={v})")
        }
        1 => {
            let many = rng.chance(0.2);
            let copies = 1 + rng.below(if many { 3000 } else { 4 });
            // At most 8 MB more: the watchdog is for hangs, not for big inputs.
            let copies = copies.min((8 << 20) / (end - pos).max(1));
            let rec = b[pos..end].to_vec();
            let at = end;
            b.splice(
                at..at,
                rec.iter()
                    .copied()
                    .cycle()
                    .take(rec.len() * copies)
                    .collect::<Vec<_>>(),
            );
            format!("mcap:dup(op{opcode:#x}@{pos}x{copies})")
        }
        2 => {
            b.drain(pos..end);
            format!("mcap:drop(op{opcode:#x}@{pos})")
        }
        3 => {
            // An integer field inside the body: 2, 4 or 8 bytes at a random body offset.
            let width = [2usize, 4, 8][rng.below(3)];
            if end < pos + 9 + width {
                return "mcap:short".into();
            }
            let at = pos + 9 + rng.below(end - pos - 9 - width + 1);
            let mut old = [0u8; 8];
            old[..width].copy_from_slice(&b[at..at + width]);
            let v = rng
                .interesting(u64::from_le_bytes(old), file_len)
                .to_le_bytes();
            b[at..at + width].copy_from_slice(&v[..width]);
            format!("mcap:int{width}(op{opcode:#x}@{at})")
        }
        4 if opcode == 0x03 => mutate_schema_record(b, pos, end, rng),
        _ => {
            // Message times and channel ids (inside uncompressed data only).
            let at = pos + 9;
            if opcode == 0x05 && end >= at + 22 {
                let field = [0usize, 6, 14][rng.below(3)];
                let width = if field == 0 { 2 } else { 8 };
                let v = rng.interesting(0, file_len).to_le_bytes();
                b[at + field..at + field + width].copy_from_slice(&v[..width]);
                format!("mcap:msgfield{field}@{pos}")
            } else {
                b[pos] = [0x05, 0x03, 0x04, 0x06, 0x08, 0x0B, 0x0F, 0x02, 0x80][rng.below(9)];
                format!("mcap:opcode@{pos}")
            }
        }
    }
}

/// Rewrite the text of a schema record (deep nesting, huge array sizes, dropped lines) and fix
/// up its length prefixes so the parser reaches the text.
fn mutate_schema_record(b: &mut Vec<u8>, pos: usize, end: usize, rng: &mut Rng) -> String {
    let body = &b[pos + 9..end];
    let Some(text_at) = (|| {
        let name_len = u32::from_le_bytes(body.get(2..6)?.try_into().ok()?) as usize;
        let enc_at = 6 + name_len;
        let enc_len = u32::from_le_bytes(body.get(enc_at..enc_at + 4)?.try_into().ok()?) as usize;
        let data_at = enc_at + 4 + enc_len;
        body.get(data_at..data_at + 4)?;
        Some(data_at)
    })() else {
        return "schema:unparsed".into();
    };
    let text = String::from_utf8_lossy(&body[text_at + 4..]).into_owned();
    let (new, what) = mutate_definition(&text, rng);
    let mut new_body = body[..text_at].to_vec();
    new_body.extend((new.len() as u32).to_le_bytes());
    new_body.extend(new.as_bytes());
    let mut rec = vec![0x03];
    rec.extend((new_body.len() as u64).to_le_bytes());
    rec.extend(new_body);
    b.splice(pos..end, rec);
    format!("schema:{what}@{pos}")
}

/// Mutate message definition text (.msg or IDL).
pub fn mutate_definition(text: &str, rng: &mut Rng) -> (String, String) {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    if lines.is_empty() {
        lines.push(String::new());
    }
    let i = rng.below(lines.len());
    let what = match rng.below(6) {
        0 => {
            let depth = 1 + rng.below(20_000);
            let nest = if text.contains("module") {
                "sequence<"
            } else {
                ""
            };
            lines[i] = format!("{}{}", nest.repeat(depth), lines[i]);
            "deep-nest"
        }
        1 => {
            lines[i] = lines[i]
                .chars()
                .map(|c| {
                    if c.is_ascii_digit() {
                        char::from(b'0' + rng.below(10) as u8)
                    } else {
                        c
                    }
                })
                .collect::<String>()
                + if rng.chance(0.5) { "99999999999" } else { "" };
            "digits"
        }
        2 => {
            lines.remove(i);
            "drop-line"
        }
        3 => {
            let l = lines[i].clone();
            lines.insert(i, l);
            "dup-line"
        }
        4 => {
            lines[i] = format!(
                "{}[{}] huge",
                lines[i].split_whitespace().next().unwrap_or("uint8"),
                1u64 << rng.below(40)
            );
            "huge-array"
        }
        _ => {
            let n = 1 + rng.below(50_000);
            lines.insert(i, "module m {".repeat(n));
            "deep-module"
        }
    };
    (lines.join("\n"), what.to_string())
}

/// Top-level ROS 1 records after the magic: (offset, header length, data length).
fn bag1_records(b: &[u8]) -> Vec<(usize, usize, usize)> {
    let mut out = Vec::new();
    let mut pos = 13;
    while pos + 4 <= b.len() {
        let hl = u32::from_le_bytes(b[pos..pos + 4].try_into().unwrap()) as usize;
        let Some(dl_at) = (pos + 4).checked_add(hl).filter(|e| e + 4 <= b.len()) else {
            break;
        };
        let dl = u32::from_le_bytes(b[dl_at..dl_at + 4].try_into().unwrap()) as usize;
        out.push((pos, hl, dl));
        pos = dl_at + 4 + dl;
    }
    out
}

fn mutate_bag1(input: &mut Input, rng: &mut Rng) -> String {
    let (_, b) = pick_file(input, rng);
    let recs = bag1_records(b);
    if recs.is_empty() {
        return "bag1:none".into();
    }
    let (pos, hl, dl) = recs[rng.below(recs.len())];
    let end = (pos + 8 + hl).saturating_add(dl).min(b.len());
    let file_len = b.len() as u64;
    match rng.below(5) {
        0 => {
            let at = if rng.chance(0.5) { pos } else { pos + 4 + hl };
            let old = u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) as u64;
            let v = rng.interesting(old, file_len) as u32;
            b[at..at + 4].copy_from_slice(&v.to_le_bytes());
            format!("bag1:len@{at}={v}")
        }
        1 => {
            // A header field value: the bytes after a `name=`.
            let header = &b[pos + 4..pos + 4 + hl];
            let eqs: Vec<usize> = header
                .iter()
                .enumerate()
                .filter(|(_, c)| **c == b'=')
                .map(|(i, _)| i)
                .collect();
            if eqs.is_empty() {
                return "bag1:noeq".into();
            }
            let at = pos + 4 + eqs[rng.below(eqs.len())] + 1;
            let width = [1usize, 4, 8][rng.below(3)].min(b.len() - at);
            let mut old = [0u8; 8];
            old[..width].copy_from_slice(&b[at..at + width]);
            let v = rng
                .interesting(u64::from_le_bytes(old), file_len)
                .to_le_bytes();
            b[at..at + width].copy_from_slice(&v[..width]);
            format!("bag1:field@{at}")
        }
        2 => {
            let many = rng.chance(0.2);
            let copies = 1 + rng.below(if many { 3000 } else { 4 });
            // At most 8 MB more: the watchdog is for hangs, not for big inputs.
            let copies = copies.min((8 << 20) / (end - pos).max(1));
            let rec = b[pos..end].to_vec();
            b.splice(
                end..end,
                rec.iter()
                    .copied()
                    .cycle()
                    .take(rec.len() * copies)
                    .collect::<Vec<_>>(),
            );
            format!("bag1:dup@{pos}x{copies}")
        }
        3 => {
            b.drain(pos..end);
            format!("bag1:drop@{pos}")
        }
        _ => {
            // A record inside an uncompressed chunk: its length fields.
            let data_at = pos + 8 + hl;
            let inner = bag1_records_at(&b[data_at..end]);
            if inner.is_empty() {
                return "bag1:noinner".into();
            }
            let (ip, ihl, _) = inner[rng.below(inner.len())];
            let at = data_at + if rng.chance(0.5) { ip } else { ip + 4 + ihl };
            let old = u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) as u64;
            let v = rng.interesting(old, file_len) as u32;
            b[at..at + 4].copy_from_slice(&v.to_le_bytes());
            format!("bag1:inner-len@{at}={v}")
        }
    }
}

fn bag1_records_at(b: &[u8]) -> Vec<(usize, usize, usize)> {
    let mut padded = vec![0u8; 13];
    padded.extend_from_slice(b);
    bag1_records(&padded)
        .into_iter()
        .map(|(p, h, d)| (p - 13, h, d))
        .collect()
}

fn mutate_db3(input: &mut Input, rng: &mut Rng) -> String {
    if rng.chance(0.4) {
        let yaml = input.files.get_mut("metadata.yaml").expect("metadata.yaml");
        let text = String::from_utf8_lossy(yaml).into_owned();
        let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
        if lines.is_empty() {
            lines.push(String::new()); // a metadata.yaml emptied by earlier mutations
        }
        let i = rng.below(lines.len());
        let what = match rng.below(5) {
            0 => {
                lines.remove(i);
                "yaml:drop-line"
            }
            1 => {
                let l = lines[i].clone();
                lines.insert(i, l);
                "yaml:dup-line"
            }
            2 => {
                lines.insert(
                    i,
                    format!("  x:\n  {}", "- ".repeat(1 + rng.below(100_000))),
                );
                "yaml:deep-seq"
            }
            3 => {
                let indent = " ".repeat(rng.below(40));
                lines[i] = format!("{indent}{}", lines[i].trim_start());
                "yaml:indent"
            }
            _ => {
                lines[i] = lines[i].replace(|c: char| c.is_ascii_digit(), "9");
                "yaml:digits"
            }
        };
        *yaml = lines.join("\n").into_bytes();
        return what.into();
    }
    let name = input
        .files
        .keys()
        .find(|k| k.as_str() != "metadata.yaml")
        .cloned()
        .expect("db file");
    if name.ends_with(".zstd") {
        return havoc(input, rng);
    }
    let tmp = tempfile::tempdir().expect("tempdir");
    let db = tmp.path().join("m.db3");
    std::fs::write(&db, &input.files[&name]).expect("write db");
    let sql = match rng.below(6) {
        0 => format!(
            "UPDATE messages SET topic_id = {} WHERE id % {} = 0",
            rng.below(10) as i64 - 2,
            1 + rng.below(20)
        ),
        1 => format!(
            "UPDATE messages SET data = substr(data, 1, {}) WHERE id % {} = 0",
            rng.below(400),
            1 + rng.below(20)
        ),
        2 => format!(
            "UPDATE messages SET timestamp = {} WHERE id = {}",
            rng.next() as i64,
            1 + rng.below(200)
        ),
        3 => format!("DELETE FROM topics WHERE id = {}", 1 + rng.below(4)),
        4 => {
            let (text, _) = mutate_definition("uint8 a\nfloat32[4] b\n", rng);
            format!(
                "UPDATE message_definitions SET encoded_message_definition = '{}' WHERE id = {}",
                text.replace('\'', "''"),
                1 + rng.below(4)
            )
        }
        _ => format!(
            "UPDATE messages SET data = zeroblob({}) WHERE id % {} = 0",
            rng.below(4000),
            1 + rng.below(20)
        ),
    };
    let ok = rusqlite::Connection::open(&db)
        .and_then(|c| {
            c.execute_batch("PRAGMA synchronous = OFF; PRAGMA journal_mode = MEMORY;")?;
            c.execute_batch(&sql)
        })
        .is_ok();
    if ok {
        input
            .files
            .insert(name, std::fs::read(&db).expect("read db"));
    }
    format!("sql({})", sql.chars().take(60).collect::<String>())
}

// ---------------------------------------------------------------------------------------------
// Running

/// Run everything a user's `g1viz info` does on `path`: open, container info, read every
/// message, decode every payload generically, load the arm signals. Returns a short outcome
/// text; errors are fine (they are values), panics are findings (the caller catches them).
pub fn exercise(path: &Path) -> String {
    let opts = OpenOptions::default();
    let mut session = match Session::open(path, &opts) {
        Ok(s) => s,
        Err(e) => return format!("open error: {e}"),
    };
    let info = session.info().map(|i| i.messages);
    let mut decoded = 0u64;
    let read = session.read(None, &mut |m| {
        if decode(&m.channel.schema, m.channel.encoding, m.data).is_ok() {
            decoded += 1;
        }
        Ok(())
    });
    let map = g1viz::signals::SignalMap::g1_left_arm();
    let signals = g1viz::signals::load_recording(path, &map, &opts).map(|r| r.state.t.len());
    format!(
        "info {:?}, read {:?}, {decoded} decoded, signals {:?}",
        info.map_err(|e| e.to_string()),
        read.map(|s| s.messages).map_err(|e| e.to_string()),
        signals.map_err(|e| e.to_string())
    )
}
