//! ROS 1 bag files (format 2.0): connection records carry each topic's message definition,
//! messages live in chunks (uncompressed, bz2 or lz4), and an index at the end of the file lists
//! connections and chunks.
//!
//! The index is used when present; a bag that was not closed properly (no index, or an index
//! past the end of a truncated file) is scanned record by record instead. Reading streams chunk
//! by chunk: each chunk's messages are sorted by time and chunks whose time ranges overlap are
//! merged, so messages come out in time order while only the overlapping chunks are in memory.
//! A damaged or truncated file is read up to the damage, with a warning naming the byte offset.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::msgdef::MsgSchema;
use super::shared::{
    Inflater, MAX_CHUNK_BYTES, Orphans, TopicStat, by_topic, capped, select_topics,
};
use super::{
    Channel, Encoding, MessageRef, MessageSource, OpenOptions, ReadError, ReadSummary, SessionInfo,
    read_up_to, session_info,
};

/// First bytes of a ROS 1 bag (format 2.0).
pub(crate) const MAGIC: &[u8] = b"#ROSBAG V2.0\n";
const OP_MESSAGE_DATA: u8 = 0x02;
const OP_BAG_HEADER: u8 = 0x03;
const OP_INDEX_DATA: u8 = 0x04;
const OP_CHUNK: u8 = 0x05;
const OP_CHUNK_INFO: u8 = 0x06;
const OP_CONNECTION: u8 = 0x07;
/// Most decompressed bytes held at once for chunks whose time ranges overlap; beyond it the
/// next chunk waits until the loaded ones are delivered (with a warning: order may break).
const OVERLAP_BUDGET_BYTES: usize = 128 << 20;

/// A ROS 1 bag (a file, or any seekable byte source) opened for reading.
pub struct Ros1BagSource<R = File> {
    path: PathBuf,
    file: R,
    file_len: u64,
    connections: BTreeMap<u32, Connection>,
    /// Chunks sorted by start time.
    chunks: Vec<ChunkMeta>,
    /// Exact per-connection statistics, known after a scan (the index gives them on demand).
    scanned_stats: Option<BTreeMap<u32, TopicStat>>,
    /// Damage and fallbacks found while opening, repeated in every read's summary.
    open_warnings: Vec<String>,
    /// The scan stopped at damage: reads cannot be complete.
    damaged: bool,
    opts: OpenOptions,
}

struct Connection {
    topic: String,
    type_name: String,
    channel: Result<Arc<Channel>, String>,
}

#[derive(Debug, Clone)]
struct ChunkMeta {
    /// Offset of the chunk record.
    pos: u64,
    start_ns: u64,
    end_ns: u64,
    /// Messages per connection id.
    counts: Vec<(u32, u32)>,
    /// For a chunk cut off by the end of the file: how many data bytes are present.
    available: Option<u64>,
    /// Offset of the chunk info record that lists this chunk (0 for a chunk found by a scan).
    info_pos: u64,
}

/// What the index data records after one chunk say (see `Ros1BagSource::chunk_index`).
#[derive(Default)]
struct ChunkIndex {
    offsets: Vec<usize>,
    listed: BTreeMap<u32, u64>,
    first: Option<u64>,
    damaged_at: Option<u64>,
}

/// A record's header fields (`name=value`) and where its data lies in the file.
struct RecordAt {
    header: Vec<u8>,
    data_offset: u64,
    data_len: u64,
}

impl RecordAt {
    fn end(&self) -> u64 {
        self.data_offset + self.data_len
    }
}

/// Why a record could not be read.
enum RecordError {
    /// The file ends inside the record header.
    Truncated,
    /// An I/O error.
    Io(std::io::Error),
}

/// Iterate the `name=value` fields of a record header.
fn header_fields(header: &[u8]) -> impl Iterator<Item = Result<(&[u8], &[u8]), String>> {
    let mut rest = header;
    std::iter::from_fn(move || {
        if rest.is_empty() {
            return None;
        }
        let Some((len, tail)) = rest.split_first_chunk::<4>() else {
            rest = &[];
            return Some(Err("header field length cut off".into()));
        };
        let len = u32::from_le_bytes(*len) as usize;
        let Some((field, tail)) = tail.split_at_checked(len) else {
            rest = &[];
            return Some(Err(format!(
                "header field of {len} bytes overruns the header"
            )));
        };
        rest = tail;
        Some(match field.iter().position(|&b| b == b'=') {
            Some(eq) => Ok((&field[..eq], &field[eq + 1..])),
            None => Err("header field without '='".into()),
        })
    })
}

/// Parsed header fields with typed lookups.
struct Fields<'a>(Vec<(&'a [u8], &'a [u8])>);

impl<'a> Fields<'a> {
    fn parse(header: &'a [u8]) -> Result<Fields<'a>, String> {
        header_fields(header)
            .collect::<Result<Vec<_>, _>>()
            .map(Fields)
    }

    fn bytes(&self, name: &str) -> Result<&'a [u8], String> {
        self.0
            .iter()
            .find(|(n, _)| *n == name.as_bytes())
            .map(|(_, v)| *v)
            .ok_or_else(|| format!("record has no field {name:?}"))
    }

    fn string(&self, name: &str) -> Result<String, String> {
        Ok(String::from_utf8_lossy(self.bytes(name)?).into_owned())
    }

    fn op(&self) -> Result<u8, String> {
        match self.bytes("op")? {
            [op] => Ok(*op),
            other => Err(format!("op field has {} bytes, expected 1", other.len())),
        }
    }

    /// The field `name`, exactly `N` bytes long.
    fn array<const N: usize>(&self, name: &str) -> Result<[u8; N], String> {
        let b = self.bytes(name)?;
        (b.try_into()).map_err(|_| format!("field {name:?} has {} bytes, expected {N}", b.len()))
    }

    fn u32(&self, name: &str) -> Result<u32, String> {
        self.array(name).map(u32::from_le_bytes)
    }

    fn u64(&self, name: &str) -> Result<u64, String> {
        self.array(name).map(u64::from_le_bytes)
    }

    /// A ROS 1 `time` (u32 seconds, u32 nanoseconds) as nanoseconds.
    fn time_ns(&self, name: &str) -> Result<u64, String> {
        let [s0, s1, s2, s3, n0, n1, n2, n3] = self.array(name)?;
        let (sec, nsec) = ([s0, s1, s2, s3], [n0, n1, n2, n3]);
        Ok(u32::from_le_bytes(sec) as u64 * 1_000_000_000 + u32::from_le_bytes(nsec) as u64)
    }
}

impl Ros1BagSource<File> {
    /// Open a ROS 1 bag (format 2.0). Fails only when the file is not a bag or its bag header
    /// is unreadable; later damage becomes warnings.
    pub fn open(path: &Path, opts: &OpenOptions) -> Result<Ros1BagSource<File>, ReadError> {
        let file = File::open(path).map_err(ReadError::io(path))?;
        Ros1BagSource::from_reader(file, path, opts)
    }
}

impl<R: Read + Seek> Ros1BagSource<R> {
    /// Read a ROS 1 bag from any seekable byte source (a file, a `Cursor` over bytes); `path`
    /// is what errors and warnings call it. Same checks as [`Ros1BagSource::open`].
    pub fn from_reader(
        mut file: R,
        path: &Path,
        opts: &OpenOptions,
    ) -> Result<Ros1BagSource<R>, ReadError> {
        let io = ReadError::io(path);
        let file_len = file.seek(SeekFrom::End(0)).map_err(&io)?;
        file.seek(SeekFrom::Start(0)).map_err(&io)?;
        let mut magic = [0u8; 13];
        let got = read_up_to(&mut file, &mut magic).map_err(&io)?;
        if magic[..got] != *MAGIC {
            let what = if magic.starts_with(b"#ROSBAG V") {
                let version = String::from_utf8_lossy(&magic[9..got]).trim().to_string();
                format!("ROS bag format version {version} is not supported (supported: 2.0)")
            } else {
                "not a ROS 1 bag (no `#ROSBAG V2.0` line)".to_string()
            };
            return Err(ReadError::format(path, 0, what));
        }
        let mut bag = Ros1BagSource {
            path: path.to_path_buf(),
            file,
            file_len,
            connections: BTreeMap::new(),
            chunks: Vec::new(),
            scanned_stats: None,
            open_warnings: Vec::new(),
            damaged: false,
            opts: opts.clone(),
        };
        let header_pos = MAGIC.len() as u64;
        let format_error = |what: String| ReadError::format(path, header_pos, what);
        let header = match bag.record_at(header_pos) {
            Ok(r) => r,
            Err(RecordError::Io(e)) => return Err(io(e)),
            Err(RecordError::Truncated) => {
                return Err(format_error(
                    "file ends inside the bag header record".into(),
                ));
            }
        };
        let fields = Fields::parse(&header.header).map_err(&format_error)?;
        if fields.op().map_err(&format_error)? != OP_BAG_HEADER {
            return Err(format_error("first record is not a bag header".into()));
        }
        if let Ok(encryptor) = fields.bytes("encryptor")
            && !encryptor.is_empty()
        {
            return Err(format_error(format!(
                "the bag is encrypted (encryptor {}); g1viz cannot read encrypted bags: decrypt \
                 it first (`rosbag decrypt`)",
                String::from_utf8_lossy(encryptor)
            )));
        }
        let index_pos = fields.u64("index_pos").map_err(&format_error)?;
        let conn_count = fields.u32("conn_count").map_err(&format_error)?;
        let chunk_count = fields.u32("chunk_count").map_err(&format_error)?;
        let first_record = header.end();

        let indexed = if index_pos == 0 {
            bag.open_warnings.push(format!(
                "{}: bag was not closed properly (no index); scanned the whole file",
                path.display()
            ));
            false
        } else if index_pos == file_len && conn_count == 0 && chunk_count == 0 {
            true // a bag closed with nothing recorded: its (empty) index ends the file
        } else if index_pos >= file_len {
            bag.open_warnings.push(format!(
                "{}: index position {index_pos} is beyond the end of the file ({file_len} bytes): \
                 file truncated? scanned the file instead",
                path.display()
            ));
            false
        } else {
            match bag.read_index(index_pos, conn_count, chunk_count) {
                Ok(()) => true,
                Err(e) => {
                    bag.open_warnings.push(format!(
                        "{}: index at offset {index_pos} is unreadable ({e}); scanned the file instead",
                        path.display()
                    ));
                    bag.connections.clear();
                    bag.chunks.clear();
                    false
                }
            }
        };
        if !indexed {
            bag.scan(first_record).map_err(&io)?;
        }
        bag.chunks.sort_by_key(|c| (c.start_ns, c.pos));
        Ok(bag)
    }

    /// Read the record starting at `offset` (its header; the data is left in the file).
    fn record_at(&mut self, offset: u64) -> Result<RecordAt, RecordError> {
        let mut len = [0u8; 4];
        self.read_exact_at(offset, &mut len)?;
        let header_len = u32::from_le_bytes(len) as u64;
        if offset + 8 + header_len > self.file_len {
            return Err(RecordError::Truncated);
        }
        let mut header = vec![0u8; header_len as usize];
        self.read_exact_at(offset + 4, &mut header)?;
        self.read_exact_at(offset + 4 + header_len, &mut len)?;
        Ok(RecordAt {
            header,
            data_offset: offset + 8 + header_len,
            data_len: u32::from_le_bytes(len) as u64,
        })
    }

    fn read_exact_at(&mut self, offset: u64, buf: &mut [u8]) -> Result<(), RecordError> {
        if offset + buf.len() as u64 > self.file_len {
            return Err(RecordError::Truncated);
        }
        self.file
            .seek(SeekFrom::Start(offset))
            .and_then(|_| self.file.read_exact(buf))
            .map_err(RecordError::Io)
    }

    /// Read `len` bytes at `offset` (bounded by the file length, so a damaged length cannot
    /// allocate more than the file holds).
    fn read_data(&mut self, offset: u64, len: u64) -> Result<Vec<u8>, RecordError> {
        if offset + len > self.file_len {
            return Err(RecordError::Truncated);
        }
        let mut buf = vec![0u8; len as usize];
        self.read_exact_at(offset, &mut buf)?;
        Ok(buf)
    }

    /// Read the connection and chunk-info records at the end of a closed bag.
    fn read_index(
        &mut self,
        index_pos: u64,
        conn_count: u32,
        chunk_count: u32,
    ) -> Result<(), String> {
        let mut offset = index_pos;
        let mut seen_chunks = std::collections::HashSet::new();
        let mut duplicates = 0u64;
        for _ in 0..(conn_count as u64 + chunk_count as u64) {
            let record = self
                .record_at(offset)
                .map_err(|e| record_error_text(e, offset))?;
            let fields =
                Fields::parse(&record.header).map_err(|e| format!("{e} at offset {offset}"))?;
            match fields.op()? {
                OP_CONNECTION => {
                    let data = self
                        .read_data(record.data_offset, record.data_len)
                        .map_err(|e| record_error_text(e, offset))?;
                    self.add_connection(&fields, &data)?;
                }
                OP_CHUNK_INFO => {
                    let data = self
                        .read_data(record.data_offset, record.data_len)
                        .map_err(|e| record_error_text(e, offset))?;
                    let pos = fields.u64("chunk_pos")?;
                    if pos >= self.file_len {
                        return Err(format!(
                            "chunk position {pos} is beyond the end of the file"
                        ));
                    }
                    if !seen_chunks.insert(pos) {
                        duplicates += 1;
                        offset = record.end();
                        continue;
                    }
                    let counts = data
                        .chunks_exact(8)
                        .map(|c| {
                            (
                                u32::from_le_bytes([c[0], c[1], c[2], c[3]]),
                                u32::from_le_bytes([c[4], c[5], c[6], c[7]]),
                            )
                        })
                        .collect();
                    self.chunks.push(ChunkMeta {
                        pos,
                        start_ns: fields.time_ns("start_time")?,
                        end_ns: fields.time_ns("end_time")?,
                        counts,
                        available: None,
                        info_pos: offset,
                    });
                }
                op => return Err(format!("unexpected record op {op:#04x} at offset {offset}")),
            }
            offset = record.end();
        }
        if duplicates > 0 {
            self.open_warnings.push(format!(
                "{}: the index lists {duplicates} chunk-info records more than once (same chunk \
                 position); each chunk is read once",
                self.path.display()
            ));
        }
        Ok(())
    }

    /// Register a connection record (header `conn`, `topic`; data = fields with `type` and
    /// `message_definition`) and resolve its definition. Repeated records are ignored.
    fn add_connection(&mut self, fields: &Fields, data: &[u8]) -> Result<(), String> {
        let id = fields.u32("conn")?;
        if self.connections.contains_key(&id) {
            return Ok(());
        }
        let topic = fields.string("topic")?;
        let info = Fields::parse(data)?;
        let type_name = info.string("type")?;
        let definition = info.string("message_definition").unwrap_or_default();
        let embedded = (!definition.trim().is_empty())
            .then(|| MsgSchema::parse_ros1msg(&type_name, &definition));
        let channel = super::resolve_schema(&self.path, &topic, &type_name, embedded, &self.opts)
            .map(|schema| Channel::new(&topic, &type_name, Encoding::Ros1, schema));
        self.connections.insert(
            id,
            Connection {
                topic,
                type_name,
                channel,
            },
        );
        Ok(())
    }

    /// Walk every record from `offset` (bag not closed, or index unusable): collect connections,
    /// chunk time ranges and per-connection statistics; stop at the first damage with a warning.
    fn scan(&mut self, mut offset: u64) -> Result<(), std::io::Error> {
        let mut stats: BTreeMap<u32, TopicStat> = BTreeMap::new();
        let mut orphans = Orphans::default();
        while offset < self.file_len {
            let record = match self.record_at(offset) {
                Ok(r) => r,
                Err(RecordError::Io(e)) => return Err(e),
                Err(RecordError::Truncated) => {
                    self.warn_truncated(offset, "record header");
                    break;
                }
            };
            let fields = match Fields::parse(&record.header).and_then(|f| f.op().map(|op| (f, op)))
            {
                Ok(f) => f,
                Err(e) => {
                    self.warn_damaged(offset, &e);
                    break;
                }
            };
            let (fields, op) = fields;
            let cut = record.end() > self.file_len;
            match op {
                OP_CHUNK => {
                    let available = record.data_len.min(self.file_len - record.data_offset);
                    let chunk = ChunkMeta {
                        pos: offset,
                        start_ns: u64::MAX,
                        end_ns: 0,
                        counts: Vec::new(),
                        available: cut.then_some(available),
                        info_pos: 0,
                    };
                    match self.load_chunk(&chunk, None) {
                        Ok(loaded) => {
                            self.damaged |= !loaded.damage.is_empty();
                            let warnings = self.chunk_warnings(offset, &loaded);
                            self.open_warnings.extend(warnings);
                            orphans.merge(&loaded.orphans);
                            let mut meta = chunk;
                            let mut counts: BTreeMap<u32, u32> = BTreeMap::new();
                            for m in &loaded.messages {
                                meta.start_ns = meta.start_ns.min(m.time_ns);
                                meta.end_ns = meta.end_ns.max(m.time_ns);
                                *counts.entry(m.conn).or_default() += 1;
                                stats.entry(m.conn).or_default().add(m.time_ns, 1);
                            }
                            meta.counts = counts.into_iter().collect();
                            if cut {
                                self.damaged = true;
                                self.open_warnings.push(format!(
                                    "{}: file truncated inside the chunk at byte offset {offset} \
                                     ({available} of its {} bytes present): {} messages recovered from it, \
                                     the rest of the file is lost",
                                    self.path.display(),
                                    record.data_len,
                                    loaded.messages.len()
                                ));
                            }
                            if !loaded.messages.is_empty() {
                                self.chunks.push(meta);
                            }
                        }
                        Err(e) => {
                            self.warn_damaged(offset, &e);
                            break;
                        }
                    }
                }
                OP_CONNECTION if !cut => {
                    let data = match self.read_data(record.data_offset, record.data_len) {
                        Ok(d) => d,
                        Err(RecordError::Io(e)) => return Err(e),
                        Err(RecordError::Truncated) => Vec::new(),
                    };
                    if let Err(e) = self.add_connection(&fields, &data) {
                        self.warn_damaged(offset, &e);
                        break;
                    }
                }
                OP_INDEX_DATA | OP_CHUNK_INFO | OP_CONNECTION | OP_MESSAGE_DATA | OP_BAG_HEADER => {
                }
                other => {
                    self.warn_damaged(offset, &format!("unknown record op {other:#04x}"));
                    break;
                }
            }
            if cut {
                if op != OP_CHUNK {
                    self.warn_truncated(offset, "record");
                }
                break;
            }
            offset = record.end();
        }
        let warnings = self.orphan_warnings(&orphans);
        self.open_warnings.extend(warnings);
        self.scanned_stats = Some(stats);
        Ok(())
    }

    /// Warnings for bad records inside a loaded chunk.
    fn chunk_warnings(&self, pos: u64, chunk: &LoadedChunk) -> Vec<String> {
        chunk
            .damage
            .iter()
            .map(|(_, what)| {
                format!(
                    "{}: chunk at byte offset {pos}: {what}",
                    self.path.display()
                )
            })
            .collect()
    }

    /// One warning per unknown connection id that carried messages.
    fn orphan_warnings(&self, orphans: &Orphans) -> Vec<String> {
        orphans.warnings(&self.path, "connection", "at byte offset")
    }

    /// Load chunk `c` for a read and queue it with its warnings; on damage warn and return
    /// false (the read stops there).
    fn load_for_read(
        &mut self,
        c: &ChunkMeta,
        wanted: &[u32],
        loaded: &mut Vec<LoadedChunk>,
        state: &mut ReadState,
    ) -> bool {
        match self.load_chunk(c, Some(wanted)) {
            Ok(chunk) => {
                if !chunk.damage.is_empty() {
                    state.summary.complete = false;
                }
                for w in self.chunk_warnings(c.pos, &chunk) {
                    if !state.known.contains(&w) {
                        state.summary.warnings.push(w);
                    }
                }
                state.orphans.merge(&chunk.orphans);
                let first = chunk.messages.iter().map(|m| m.time_ns).min();
                if let Some(t) = first.filter(|&t| t < c.start_ns) {
                    state.summary.warnings.push(format!(
                        "{}: the chunk info record at byte offset {} says the chunk at byte offset \
                         {} starts at {} ns, but it holds a message at {t} ns; messages may come \
                         out of time order",
                        self.path.display(),
                        c.info_pos,
                        c.pos,
                        c.start_ns
                    ));
                }
                if chunk.head_time().is_some() {
                    loaded.push(chunk);
                }
                true
            }
            Err(e) => {
                state.summary.warnings.push(format!(
                    "{}: damaged chunk at byte offset {} ({e}); read stopped there, \
                     messages before it were delivered",
                    self.path.display(),
                    c.pos
                ));
                state.summary.complete = false;
                false
            }
        }
    }

    fn warn_truncated(&mut self, offset: u64, what: &str) {
        self.damaged = true;
        self.open_warnings.push(format!(
            "{}: file truncated: {what} at byte offset {offset} is cut off by the end of the file \
             ({} bytes); messages before it were read",
            self.path.display(),
            self.file_len
        ));
    }

    fn warn_damaged(&mut self, offset: u64, what: &str) {
        self.damaged = true;
        self.open_warnings.push(format!(
            "{}: damaged record at byte offset {offset} ({what}); messages before it were read, \
             the rest of the file ({} bytes) is skipped",
            self.path.display(),
            self.file_len.saturating_sub(offset)
        ));
    }

    /// Read and decompress the chunk `meta` points to: (uncompressed records, compression,
    /// offset of the chunk data in the file). Output is capped at the declared size.
    fn chunk_bytes(&mut self, meta: &ChunkMeta) -> Result<(Vec<u8>, String, u64), String> {
        let record = self
            .record_at(meta.pos)
            .map_err(|e| record_error_text(e, meta.pos))?;
        let fields = Fields::parse(&record.header)?;
        if fields.op()? != OP_CHUNK {
            return Err(format!("record at offset {} is not a chunk", meta.pos));
        }
        let compression = fields.string("compression")?;
        let size = fields.u32("size")?.into();
        let len = meta.available.unwrap_or(record.data_len);
        let raw = self
            .read_data(record.data_offset, len)
            .map_err(|e| record_error_text(e, record.data_offset))?;
        // A whole stored chunk is used as read (a copy costs a fifth of reading it).
        if compression == "none" && raw.len() as u64 == size && size <= MAX_CHUNK_BYTES {
            return Ok((raw, compression, record.data_offset));
        }
        let mut data = Vec::new();
        let partial = meta.available.is_some();
        Inflater::default().chunk(&compression, &raw, size, partial, &mut data)?;
        Ok((data, compression, record.data_offset))
    }

    /// Read, decompress and parse one chunk: its connection records are registered, its
    /// messages (of `wanted` connections, or all) returned sorted by time. A bad record inside
    /// the chunk does not lose the rest when the chunk's index data gives the offsets of the
    /// messages after it; what was lost is in [`LoadedChunk::damage`].
    fn load_chunk(
        &mut self,
        meta: &ChunkMeta,
        wanted: Option<&[u32]>,
    ) -> Result<LoadedChunk, String> {
        let (data, compression, data_offset) = self.chunk_bytes(meta)?;
        // Offsets of uncompressed chunks point at the message record itself.
        let base = (compression == "none").then_some(data_offset);
        let mut chunk = LoadedChunk {
            data: Vec::new(),
            messages: Vec::new(),
            next: 0,
            parsed: 0,
            damage: Vec::new(),
            orphans: Orphans::default(),
        };
        let mut at = 0usize;
        let mut resync: Option<Vec<usize>> = None;
        while let Err((bad_at, what)) =
            self.parse_chunk_records(&data, at, meta, base, wanted, &mut chunk)
        {
            chunk.damage.push((bad_at, what));
            let offsets = resync.get_or_insert_with(|| self.chunk_index(meta).offsets);
            match offsets.iter().find(|&&o| o > bad_at) {
                Some(&o) => at = o,
                None => break,
            }
        }
        if !chunk.damage.is_empty() {
            let expected: u64 = meta.counts.iter().map(|(_, n)| *n as u64).sum();
            let indexed = resync.as_ref().map_or(0, |o| o.len() as u64);
            let expected = expected.max(indexed);
            let lost = if expected > chunk.parsed {
                format!(
                    "{} of its {expected} messages lost",
                    expected - chunk.parsed
                )
            } else {
                "messages after it lost unless the chunk index lists them".to_string()
            };
            let (bad_at, what) = &chunk.damage[0];
            chunk.damage = vec![(
                *bad_at,
                format!(
                    "{what}; {} bad record(s) in the chunk, {} messages read from it, {lost}",
                    chunk.damage.len(),
                    chunk.parsed
                ),
            )];
        }
        // Stable: messages with equal stamps keep their recorded order.
        chunk.messages.sort_by_key(|m| m.time_ns);
        chunk.data = data;
        Ok(chunk)
    }

    /// Parse the records of a decompressed chunk from byte `at`; on a bad record, its position
    /// in the chunk and what is wrong.
    fn parse_chunk_records(
        &mut self,
        data: &[u8],
        mut at: usize,
        meta: &ChunkMeta,
        base: Option<u64>,
        wanted: Option<&[u32]>,
        chunk: &mut LoadedChunk,
    ) -> Result<(), (usize, String)> {
        let truncated = meta.available.is_some();
        while at < data.len() {
            let bad = |what: String| (at, format!("record at byte {at} of the chunk: {what}"));
            let Some(framed) = frame_in(data, at) else {
                if truncated {
                    return Ok(()); // the end of the file cut the chunk: reported by the caller
                }
                return Err(bad(format!(
                    "its lengths overrun the chunk ({} bytes)",
                    data.len()
                )));
            };
            let (header, data_start, data_end) = framed;
            let fields = Fields::parse(header).map_err(&bad)?;
            match fields.op().map_err(&bad)? {
                OP_MESSAGE_DATA => {
                    let conn = fields.u32("conn").map_err(&bad)?;
                    let time_ns = fields.time_ns("time").map_err(&bad)?;
                    chunk.parsed += 1;
                    let file_offset = base.map_or(meta.pos, |b| b + at as u64);
                    if !self.connections.contains_key(&conn) {
                        chunk.orphans.add(conn, file_offset);
                    } else if wanted.is_none_or(|w| w.contains(&conn)) {
                        chunk.messages.push(ChunkMessage {
                            time_ns,
                            conn,
                            start: data_start,
                            end: data_end,
                            file_offset,
                        });
                    }
                }
                OP_CONNECTION => self
                    .add_connection(&fields, &data[data_start..data_end])
                    .map_err(&bad)?,
                op => {
                    return Err(bad(format!(
                        "record op {op:#04x} is neither a message nor a connection record"
                    )));
                }
            }
            at = data_end;
        }
        Ok(())
    }

    /// The index data records after chunk `meta`: their message offsets (in the uncompressed
    /// chunk, sorted), messages listed per connection, the first record's byte offset, and the
    /// byte offset of the first one that is unreadable or whose entries do not match its count.
    fn chunk_index(&mut self, meta: &ChunkMeta) -> ChunkIndex {
        let mut out = ChunkIndex::default();
        let mut offset = self.record_at(meta.pos).map_or(self.file_len, |c| c.end());
        while offset < self.file_len {
            match self.index_data_at(offset) {
                Ok(Some((conn, d, end))) => {
                    out.first.get_or_insert(offset);
                    *out.listed.entry(conn).or_default() += d.len() as u64 / 12;
                    out.offsets.extend(
                        d.chunks_exact(12)
                            .map(|e| u32::from_le_bytes([e[8], e[9], e[10], e[11]]) as usize),
                    );
                    offset = end;
                }
                Ok(None) => break,
                Err(()) => {
                    out.damaged_at = Some(offset);
                    break;
                }
            }
        }
        out.offsets.sort_unstable();
        out.offsets.dedup();
        out
    }

    /// The index data record at `offset` as (connection, entries, end); `None` for another
    /// record, `Err` when damaged or its entries do not match its count.
    fn index_data_at(&mut self, offset: u64) -> Result<Option<(u32, Vec<u8>, u64)>, ()> {
        let r = self.record_at(offset).map_err(drop)?;
        let f = Fields::parse(&r.header).map_err(drop)?;
        if f.op() != Ok(OP_INDEX_DATA) {
            return Ok(None);
        }
        let (conn, count) = (f.u32("conn").map_err(drop)?, f.u32("count").map_err(drop)?);
        let d = self.read_data(r.data_offset, r.data_len).map_err(drop)?;
        let fits = d.len() as u64 == u64::from(count) * 12;
        fits.then_some(Some((conn, d, r.end()))).ok_or(())
    }

    /// Per-connection statistics counted from the messages of every chunk (an index is not
    /// taken on its word: ROS 1 bags carry no checksum), each chunk's counts checked against its
    /// chunk info record and the index data records after it; disagreements and damage go to
    /// `warnings`.
    fn counted_stats(&mut self, warnings: &mut Vec<String>) -> BTreeMap<u32, TopicStat> {
        let mut stats: BTreeMap<u32, TopicStat> = BTreeMap::new();
        let mut orphans = Orphans::default();
        let mut differ = Vec::new();
        let path = self.path.display().to_string();
        for meta in self.chunks.clone() {
            let chunk = match self.load_chunk(&meta, None) {
                Ok(c) => c,
                Err(e) => {
                    warnings.push(format!(
                        "{path}: damaged chunk at byte offset {} ({e}); messages counted up to it",
                        meta.pos
                    ));
                    break;
                }
            };
            warnings.extend(self.chunk_warnings(meta.pos, &chunk));
            orphans.merge(&chunk.orphans);
            let mut read: BTreeMap<u32, u64> = BTreeMap::new();
            for m in &chunk.messages {
                *read.entry(m.conn).or_default() += 1;
                stats.entry(m.conn).or_default().add(m.time_ns, 1);
            }
            for (conn, (n, _)) in &chunk.orphans.0 {
                *read.entry(*conn).or_default() += n;
            }
            if !chunk.damage.is_empty() {
                continue;
            }
            let mut info: BTreeMap<u32, u64> = BTreeMap::new();
            for &(conn, n) in meta.counts.iter().filter(|(_, n)| *n > 0) {
                let e = info.entry(conn).or_default();
                *e = e.saturating_add(n.into());
            }
            let index = self.chunk_index(&meta);
            if let Some(at) = index.damaged_at {
                differ.push(format!(
                    "{path}: the index data record at byte offset {at} (after the chunk at byte \
                     offset {}) is damaged; the counts shown are the ones read",
                    meta.pos
                ));
            }
            let by_index = (index.first)
                .filter(|_| index.damaged_at.is_none())
                .map(|at| (at, "index data records from", index.listed));
            for (at, what, listed) in [(meta.info_pos, "chunk info record at", info)]
                .into_iter()
                .chain(by_index)
                .filter(|l| l.2 != read)
            {
                differ.push(format!(
                    "{path}: the {what} byte offset {at} say {} for the chunk at byte offset {}, \
                     which holds {}; the counts shown are the ones read",
                    self.per_topic(&listed),
                    meta.pos,
                    self.per_topic(&read)
                ));
            }
        }
        capped(warnings, differ, |more| {
            format!("{path}: {more} more index records disagree with their chunks")
        });
        warnings.extend(self.orphan_warnings(&orphans));
        stats
    }

    /// `N messages on TOPIC (connection C), ...` for messages per connection id.
    fn per_topic(&self, counts: &BTreeMap<u32, u64>) -> String {
        if counts.is_empty() {
            return "no messages".into();
        }
        let parts: Vec<String> = counts
            .iter()
            .map(|(conn, n)| {
                let topic = self
                    .connections
                    .get(conn)
                    .map_or("an unknown topic", |c| c.topic.as_str());
                format!("{n} messages on {topic} (connection {conn})")
            })
            .collect();
        parts.join(", ")
    }

    /// Connection ids to deliver for `wanted` topics; errors for an explicitly requested topic
    /// without a definition, warnings for those that only come along with "all topics".
    fn select(
        &self,
        wanted: Option<&[&str]>,
        warnings: &mut Vec<String>,
    ) -> Result<Vec<u32>, ReadError> {
        let topics = (self.connections.values()).map(|c| (c.topic.as_str(), &c.channel));
        let selected = select_topics(topics, wanted, warnings)?;
        let ids = self.connections.keys().zip(selected);
        Ok(ids.filter(|(_, s)| *s).map(|(id, _)| *id).collect())
    }
}

/// What a read accumulates besides the delivered messages.
struct ReadState {
    summary: ReadSummary,
    /// Warnings already given when the bag was opened (not repeated).
    known: std::collections::HashSet<String>,
    /// Messages on unknown connection ids.
    orphans: Orphans,
}

struct ChunkMessage {
    time_ns: u64,
    conn: u32,
    start: usize,
    end: usize,
    file_offset: u64,
}

struct LoadedChunk {
    data: Vec<u8>,
    messages: Vec<ChunkMessage>,
    next: usize,
    /// Message records parsed (of every connection, wanted or not).
    parsed: u64,
    /// Bad records inside the chunk: (byte in the chunk, what); at most one summary entry.
    damage: Vec<(usize, String)>,
    /// Messages on connection ids without a connection record.
    orphans: Orphans,
}

impl LoadedChunk {
    fn head_time(&self) -> Option<u64> {
        self.messages.get(self.next).map(|m| m.time_ns)
    }
}

/// The record framed at `at` in a chunk: (header, data start, data end), `None` when its
/// lengths run past the chunk.
fn frame_in(data: &[u8], at: usize) -> Option<(&[u8], usize, usize)> {
    let header_len =
        u32::from_le_bytes(data.get(at..at.checked_add(4)?)?.try_into().ok()?) as usize;
    let header_end = at.checked_add(4)?.checked_add(header_len)?;
    let data_len = u32::from_le_bytes(
        data.get(header_end..header_end.checked_add(4)?)?
            .try_into()
            .ok()?,
    ) as usize;
    let data_start = header_end + 4;
    let data_end = data_start.checked_add(data_len)?;
    (data_end <= data.len()).then(|| (&data[at + 4..header_end], data_start, data_end))
}

fn record_error_text(e: RecordError, offset: u64) -> String {
    match e {
        RecordError::Truncated => {
            format!("record at offset {offset} is cut off by the end of the file")
        }
        RecordError::Io(e) => format!("read error at offset {offset}: {e}"),
    }
}

impl<R: Read + Seek> MessageSource for Ros1BagSource<R> {
    fn format(&self) -> &'static str {
        "ros1-bag"
    }

    fn info(&mut self) -> Result<SessionInfo, ReadError> {
        let mut warnings = self.open_warnings.clone();
        let stats = match &self.scanned_stats {
            Some(s) => s.clone(),
            None => self.counted_stats(&mut warnings),
        };
        warnings.extend(
            self.connections
                .values()
                .filter_map(|c| c.channel.clone().err()),
        );
        let topics = by_topic(self.connections.iter().map(|(id, c)| {
            let s = stats.get(id).copied().unwrap_or_default();
            (c.topic.as_str(), c.type_name.as_str(), "ros1", s)
        }));
        Ok(session_info(&self.path, "ros1-bag", topics, warnings))
    }

    fn read(
        &mut self,
        topics: Option<&[&str]>,
        visit: &mut dyn FnMut(MessageRef<'_>) -> Result<(), ReadError>,
    ) -> Result<ReadSummary, ReadError> {
        let mut summary = ReadSummary::starting(&self.open_warnings, !self.damaged);
        let wanted = self.select(topics, &mut summary.warnings)?;
        // Every chunk is read: the chunk info counts are not taken on their word (no checksum).
        let chunks = self.chunks.clone();
        let mut next_chunk = 0;
        let mut loaded: Vec<LoadedChunk> = Vec::new();
        let mut over_budget = false;
        let mut state = ReadState {
            known: self.open_warnings.iter().cloned().collect(),
            summary,
            orphans: Orphans::default(),
        };
        loop {
            // The loaded chunk with the earliest pending message.
            let head = loaded
                .iter()
                .enumerate()
                .filter_map(|(i, c)| c.head_time().map(|t| (t, i)))
                .min();
            let held: usize = loaded.iter().map(|c| c.data.len()).sum();
            // Load the next chunk first if it may hold a message at or before that one (and
            // the chunks already held leave room for it).
            if let Some(c) = chunks.get(next_chunk)
                && head.is_none_or(|(t, _)| c.start_ns <= t)
            {
                if head.is_some() && held >= OVERLAP_BUDGET_BYTES {
                    over_budget = true;
                } else {
                    next_chunk += 1;
                    if !self.load_for_read(c, &wanted, &mut loaded, &mut state) {
                        next_chunk = chunks.len();
                    }
                    continue;
                }
            }
            let Some((_, i)) = head else { break };
            let chunk = &mut loaded[i];
            let m = &chunk.messages[chunk.next];
            chunk.next += 1;
            if let Some(Ok(channel)) = self.connections.get(&m.conn).map(|c| &c.channel) {
                visit(MessageRef {
                    channel,
                    log_time_ns: m.time_ns,
                    data: &chunk.data[m.start..m.end],
                    file_offset: m.file_offset,
                    row_id: false,
                })?;
                state.summary.messages += 1;
            }
            if chunk.head_time().is_none() {
                // `remove`, not `swap_remove`: equal stamps go to the earlier chunk first.
                loaded.remove(i);
            }
        }
        let ReadState {
            mut summary,
            orphans,
            ..
        } = state;
        summary.warnings.extend(self.orphan_warnings(&orphans));
        if over_budget {
            summary.warnings.push(format!(
                "{}: more chunks overlap in time than fit the {} MiB memory budget; they were read \
                 one after the other, so messages may come out of time order",
                self.path.display(),
                OVERLAP_BUDGET_BYTES >> 20
            ));
        }
        Ok(summary)
    }
}
