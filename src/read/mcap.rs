//! MCAP reader: streams messages chunk by chunk (zstd, lz4 or uncompressed chunks), using the
//! summary section (statistics, schema/channel records, chunk indexes) when it is there. Unless
//! the summary's CRC vouches for its index, the data section is also walked record header by
//! record header (chunk bodies are not read): chunks the index leaves out and records stored
//! outside chunks are read too (a warning names each when there is an index), and a file
//! without an index is read in log-time order from that walk like an indexed one, so the
//! messages come out the same whatever the storage order. Records are framed here so every
//! warning can name its byte offset.
//!
//! Indexed chunks are decompressed by a pool of two worker threads while the caller's thread
//! reads the next raw chunks and decodes the last. Memory holds the groups of chunks (whose time
//! ranges overlap) sent ahead to the workers, up to 2 MiB of them decompressed or one per
//! worker, and the group being delivered, never the file.

use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::mcap_records::{self as rec, ChunkIndex, Statistics};
use super::msgdef::MsgType;
use super::shared::{Inflater, MAX_CHUNK_BYTES, MAX_DETAILED, Orphans, TopicStat, capped};
use super::{
    Channel, Encoding, MessageRef, MessageSource, MsgSchema, OpenOptions, ReadError, ReadSummary,
    SessionInfo, TopicInfo,
};

/// The 8 bytes every MCAP file starts and ends with.
pub const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// MCAP record opcodes the reader handles.
mod op {
    pub const HEADER: u8 = 0x01;
    pub const FOOTER: u8 = 0x02;
    pub const SCHEMA: u8 = 0x03;
    pub const CHANNEL: u8 = 0x04;
    pub const MESSAGE: u8 = 0x05;
    pub const CHUNK: u8 = 0x06;
    pub const MESSAGE_INDEX: u8 = 0x07;
    pub const CHUNK_INDEX: u8 = 0x08;
    pub const STATISTICS: u8 = 0x0B;
    pub const DATA_END: u8 = 0x0F;
}

/// Opcode (1) + record length (8).
const RECORD_PREFIX: u64 = 9;
/// Footer record plus the closing magic.
const FOOTER_TOTAL: u64 = RECORD_PREFIX + 20 + 8;
/// Summary sections larger than this are ignored (linear scan instead).
const MAX_SUMMARY_BYTES: u64 = 64 << 20;
/// Records stored outside chunks are read in spans of at most this many bytes.
const SPAN_BYTES: u64 = 4 << 20;
/// Most chunks (and spans) the walk over the data section keeps track of (about 80 bytes each).
const MAX_CHUNKS: usize = 1 << 20;
/// Most decompressed bytes held at once for chunks whose time ranges overlap; beyond it the
/// chunks are delivered one after the other (with a warning) instead of merged. With the raw
/// chunk bytes and three groups in flight (and [`AHEAD_BYTES`] more), hostile input stays under 512 MB.
const GROUP_BUDGET_BYTES: u64 = 64 << 20;

/// Schemas and channels seen so far (from the summary or the data section), and messages met on
/// channel ids that have no channel record.
#[derive(Debug, Default)]
struct Registry {
    schemas: HashMap<u16, rec::SchemaRecord>,
    channels: HashMap<u16, rec::ChannelRecord>,
    /// Messages on channel ids without a channel record.
    orphans: Orphans,
}

/// What a scan does with one channel id's messages.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Route {
    /// Not met yet in this walk, or its channel record just changed: decide on the next message.
    Undecided,
    /// No channel record: counted as an orphan.
    Orphan,
    /// A topic the read does not want.
    Skip,
    /// Delivered.
    Keep,
}

/// Per channel id, what one walk does with its messages, decided on the id's first message
/// (and again after a channel record for it), so a message costs one vector index instead of
/// map lookups and topic comparisons; and the ids met in the current chunk.
struct Routes {
    route: Vec<Route>,
    /// Per channel id: the number of the last chunk that held one of its messages.
    met_in: Vec<u32>,
    chunk: u32,
    /// Channel ids of the messages in the current chunk (to check a chunk index against it).
    seen: BTreeSet<u16>,
}

impl Routes {
    fn new() -> Routes {
        let ids = usize::from(u16::MAX) + 1;
        Routes {
            route: vec![Route::Undecided; ids],
            met_in: vec![0; ids],
            chunk: 1,
            seen: BTreeSet::new(),
        }
    }

    /// Start noting the channel ids of a new chunk.
    fn next_chunk(&mut self) {
        self.seen.clear();
        self.chunk = self.chunk.wrapping_add(1).max(1);
    }

    /// The route of `id`'s messages, noting the id as met in this chunk.
    fn of(&mut self, id: u16, registry: &Registry, topics: Option<&[&str]>) -> Route {
        let i = usize::from(id);
        if self.met_in[i] != self.chunk {
            self.met_in[i] = self.chunk;
            self.seen.insert(id);
        }
        if self.route[i] == Route::Undecided {
            self.route[i] = match registry.channels.contains_key(&id) {
                false => Route::Orphan,
                true if registry.wanted(id, topics) => Route::Keep,
                true => Route::Skip,
            };
        }
        self.route[i]
    }
}

impl Registry {
    /// Register a schema or channel record body; other opcodes are ignored.
    fn add(&mut self, opcode: u8, body: &[u8]) -> Result<(), String> {
        match opcode {
            op::SCHEMA => {
                let s = rec::schema(body)?;
                self.schemas.insert(s.id, s);
            }
            op::CHANNEL => {
                let c = rec::channel(body)?;
                self.channels.insert(c.id, c);
            }
            _ => {}
        }
        Ok(())
    }

    fn wanted(&self, channel_id: u16, topics: Option<&[&str]>) -> bool {
        match (topics, self.channels.get(&channel_id)) {
            (None, _) => true,
            (Some(t), Some(c)) => t.contains(&c.topic.as_str()),
            (Some(_), None) => false,
        }
    }
}

#[derive(Debug)]
struct Summary {
    /// Byte offset of the summary section (the data section ends before it).
    start: u64,
    chunks: Vec<ChunkIndex>,
    stats: Option<Statistics>,
    /// Byte offset of the statistics record.
    stats_offset: u64,
    /// The footer's summary CRC was set and matched: the index is what the writer wrote, so
    /// chunks may be skipped on its word. Without it (CRC 0, which the spec allows) every
    /// indexed chunk is read and the index is checked against what the chunks hold.
    verified: bool,
}

/// Damage found while reading: where and what. Turned into a warning; the read stops there.
#[derive(Debug, Clone)]
struct Damage {
    offset: u64,
    what: String,
}

/// The raw bytes of one chunk record, or of a span of records stored outside chunks (`loose`).
struct RawChunk {
    offset: u64,
    bytes: Vec<u8>,
    loose: bool,
}

/// A message located in a buffer, before delivery.
struct RawMsg {
    channel_id: u16,
    log_time: u64,
    /// Which buffer (chunk) holds it and where.
    buf: usize,
    start: usize,
    end: usize,
    file_offset: u64,
}

/// Receives each wanted message with the source (for channel lookups) and its payload.
type RawSink<'a, R> = dyn FnMut(&mut McapSource<R>, &RawMsg, &[u8]) -> Result<(), ReadError> + 'a;

/// An MCAP file (or any seekable byte source) opened for streaming.
pub struct McapSource<R = File> {
    path: PathBuf,
    file: BufReader<R>,
    file_len: u64,
    opts: OpenOptions,
    registry: Registry,
    summary: Option<Summary>,
    /// Problems met while opening (e.g. an unreadable summary), repeated in every read's summary.
    open_warnings: Vec<String>,
    /// Decoded channels by id, built when first needed.
    resolved: Vec<Option<Arc<Channel>>>,
    /// Log-time ranges the next reads need ([`MessageSource::set_time_ranges`]): indexed
    /// chunks wholly outside them are skipped.
    time_ranges: Option<Vec<(u64, u64)>>,
    /// Chunks and spans of loose records in the data section that the chunk index does not
    /// list (all of them when there is no index): read with the indexed ones.
    unindexed: Vec<ChunkIndex>,
    /// Damage that stopped the walk over the data section of a file without a chunk index:
    /// every read stops there.
    scan_damage: Option<Damage>,
}

impl McapSource<File> {
    /// Open `path`: checks the magic and header record, and loads the summary section when the
    /// footer points to a readable one. A file that is not MCAP → [`ReadError::Format`].
    pub fn open(path: &Path, opts: &OpenOptions) -> Result<McapSource<File>, ReadError> {
        let file = File::open(path).map_err(ReadError::io(path))?;
        McapSource::from_reader(file, path, opts)
    }
}

impl<R: Read + Seek> McapSource<R> {
    /// What errors and warnings call this source (the file name given when opening).
    pub fn name(&self) -> &Path {
        &self.path
    }

    /// Read MCAP from any seekable byte source (a file, a `Cursor` over bytes); `name` is what
    /// errors and warnings call it. Same checks as [`McapSource::open`].
    pub fn from_reader(
        mut reader: R,
        name: &Path,
        opts: &OpenOptions,
    ) -> Result<McapSource<R>, ReadError> {
        let io = ReadError::io(name);
        let file_len = reader.seek(SeekFrom::End(0)).map_err(&io)?;
        reader.seek(SeekFrom::Start(0)).map_err(&io)?;
        let format = |offset, what: &str| ReadError::format(name, offset, what);
        let mut magic = [0u8; 8];
        if reader.read_exact(&mut magic).is_err() || &magic != MAGIC {
            return Err(format(0, "not an MCAP file (bad magic bytes)"));
        }
        let mut prefix = [0u8; 9];
        reader
            .read_exact(&mut prefix)
            .map_err(|_| format(8, "file ends inside the header record"))?;
        let len = u64::from_le_bytes(prefix[1..9].try_into().unwrap_or_default());
        if prefix[0] != op::HEADER
            || len > file_len.saturating_sub(8 + RECORD_PREFIX)
            || len > 1 << 20
        {
            return Err(format(
                8,
                "the first record is not a valid MCAP header record",
            ));
        }
        let mut source = McapSource {
            path: name.to_path_buf(),
            file: BufReader::with_capacity(1 << 16, reader),
            file_len,
            opts: opts.clone(),
            registry: Registry::default(),
            summary: None,
            open_warnings: Vec::new(),
            resolved: Vec::new(),
            time_ranges: None,
            unindexed: Vec::new(),
            scan_damage: None,
        };
        match source.load_summary() {
            Ok(summary) => source.summary = summary,
            Err(d) => {
                source.registry = Registry::default();
                source.open_warnings.push(format!(
                    "{}: summary section unreadable at byte offset {} ({}); reading the data section linearly",
                    name.display(),
                    d.offset,
                    d.what
                ));
            }
        }
        // A chunk index vouched for by the summary CRC is taken as the layout of the file.
        if !source.summary.as_ref().is_some_and(|s| s.verified) || !source.has_index() {
            source.find_unindexed();
        }
        source.learn_missing_channels();
        Ok(source)
    }

    /// True when the file has a usable summary with chunk indexes (indexed, time-ordered reads).
    pub fn has_index(&self) -> bool {
        self.summary.as_ref().is_some_and(|s| !s.chunks.is_empty())
    }

    fn read_at(&mut self, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
        self.file.seek(SeekFrom::Start(offset))?;
        self.file.read_exact(buf)
    }

    fn load_summary(&mut self) -> Result<Option<Summary>, Damage> {
        if self.file_len < 8 + FOOTER_TOTAL + 8 {
            return Ok(None);
        }
        let footer_at = self.file_len - FOOTER_TOTAL;
        let mut tail = [0u8; FOOTER_TOTAL as usize];
        if self.read_at(footer_at, &mut tail).is_err()
            || &tail[29..] != MAGIC
            || tail[0] != op::FOOTER
        {
            return Ok(None); // no footer: truncated or still being written; the linear scan reports it
        }
        let footer = rec::footer(&tail[9..29]).map_err(|what| Damage {
            offset: footer_at,
            what,
        })?;
        if footer.summary_start == 0 {
            return Ok(None);
        }
        if footer.summary_start < 8
            || footer.summary_start > footer_at
            || footer_at - footer.summary_start > MAX_SUMMARY_BYTES
        {
            return Err(Damage {
                offset: footer_at,
                what: format!("footer points to summary at {}", footer.summary_start),
            });
        }
        let mut bytes = vec![0u8; (footer_at - footer.summary_start) as usize];
        self.read_at(footer.summary_start, &mut bytes)
            .map_err(|e| Damage {
                offset: footer.summary_start,
                what: e.to_string(),
            })?;
        if footer.summary_crc != 0 {
            let mut hasher = crc32fast::Hasher::new();
            hasher.update(&bytes);
            hasher.update(&tail[..25]);
            if hasher.finalize() != footer.summary_crc {
                return Err(Damage {
                    offset: footer.summary_start,
                    what: "summary CRC mismatch".into(),
                });
            }
        }
        let mut summary = self.parse_summary(&bytes, footer.summary_start)?;
        summary.verified = footer.summary_crc != 0;
        Ok(Some(summary))
    }

    /// The records of the summary section: schemas and channels registered, chunk indexes
    /// (each chunk once, however often it is listed) and statistics kept.
    fn parse_summary(&mut self, bytes: &[u8], summary_start: u64) -> Result<Summary, Damage> {
        let mut summary = Summary {
            start: summary_start,
            chunks: Vec::new(),
            stats: None,
            stats_offset: 0,
            verified: false,
        };
        let mut seen_chunks = HashSet::new();
        let mut duplicates = 0u64;
        let mut pos = 0usize;
        while pos < bytes.len() {
            let offset = summary_start + pos as u64;
            let damage = |what| Damage { offset, what };
            let (opcode, body, next) = frame(bytes, pos).map_err(damage)?;
            pos = next;
            match opcode {
                op::SCHEMA | op::CHANNEL => self.registry.add(opcode, body).map_err(damage)?,
                op::CHUNK_INDEX => {
                    let mut ci = rec::chunk_index(body).map_err(damage)?;
                    ci.record_offset = offset;
                    if seen_chunks.insert(ci.chunk_start_offset) {
                        summary.chunks.push(ci);
                    } else {
                        duplicates += 1;
                    }
                }
                op::STATISTICS => {
                    summary.stats = Some(rec::statistics(body).map_err(damage)?);
                    summary.stats_offset = offset;
                }
                _ => {}
            }
        }
        if duplicates > 0 {
            self.open_warnings.push(format!(
                "{}: the summary lists {duplicates} chunk index entries more than once (same chunk \
                 offset); each chunk is read once",
                self.path.display()
            ));
        }
        Ok(summary)
    }

    /// Writers may leave the Channel (and Schema) records out of the summary and write them
    /// only in the data section (`repeat_channels=False`, rosbag2's `noRepeatedChannels`): learn
    /// the channels the statistics or chunk indexes name from the data section, reading only as
    /// far as needed.
    fn learn_missing_channels(&mut self) {
        let Some(summary) = &self.summary else {
            return;
        };
        let mut needed: BTreeSet<u16> = summary
            .chunks
            .iter()
            .flat_map(|c| c.message_index_offsets.keys().copied())
            .collect();
        if let Some(stats) = &summary.stats {
            needed.extend(stats.channel_message_counts.keys().copied());
        }
        needed.retain(|id| !self.registry.channels.contains_key(id));
        if needed.is_empty() {
            return;
        }
        let mut inflater = Inflater::default();
        let mut routes = Routes::new();
        let (layout, mut damage) = self.scan_layout();
        for ci in layout {
            if needed
                .iter()
                .all(|id| self.registry.channels.contains_key(id))
            {
                damage = None;
                break;
            }
            let raw = self.read_group(std::slice::from_ref(&ci), Vec::new());
            let scanned = raw.chunks.into_iter().try_for_each(|raw| {
                let buf = inflater.entry(raw, Vec::new())?;
                let (at, registry) = (ci.chunk_start_offset, &mut self.registry);
                scan_records(
                    &buf,
                    at,
                    0,
                    registry,
                    &mut routes,
                    Some(&[]),
                    &mut Vec::new(),
                )
            });
            if let Err(d) = scanned {
                damage = Some(d);
                break;
            }
        }
        self.registry.orphans = Orphans::default();
        if let Some(d) = damage {
            self.open_warnings.push(format!(
                "{}: looking for channel records in the data section: damaged at byte offset {}: {}",
                self.path.display(),
                d.offset,
                d.what
            ));
        }
    }

    /// Walk the data section and keep what the chunk index does not cover: the chunks it leaves
    /// out and the records stored outside chunks (everything, when there is no index). With an
    /// index, each piece it leaves out is a warning naming its byte offset.
    fn find_unindexed(&mut self) {
        let (layout, damage) = self.scan_layout();
        let indexed: HashSet<u64> = (self.summary.iter())
            .flat_map(|s| &s.chunks)
            .map(|c| c.chunk_start_offset)
            .collect();
        if indexed.is_empty() {
            self.unindexed = layout;
            self.scan_damage = damage;
            return;
        }
        let path = self.path.display();
        if let Some(d) = damage {
            self.open_warnings.push(format!(
                "{path}: the data section cannot be walked past byte offset {} ({}); the chunks \
                 the index lists after it are read",
                d.offset, d.what
            ));
        }
        self.unindexed = (layout.into_iter())
            .filter(|c| !indexed.contains(&c.chunk_start_offset))
            .collect();
        let detailed = self.unindexed.iter().map(|c| {
            let (at, end) = (c.chunk_start_offset, c.chunk_start_offset + c.chunk_length);
            let what = match c.loose {
                true => format!("the records at byte offsets {at}..{end} lie outside every chunk"),
                false => format!("the chunk at byte offset {at} is missing from the chunk index"),
            };
            format!(
                "{path}: {what} (the summary has no CRC to vouch for the index); read from the \
                 data section"
            )
        });
        capped(&mut self.open_warnings, detailed.collect(), |more| {
            format!(
                "{path}: {more} more chunks or spans of records are missing from the chunk index"
            )
        });
    }

    /// The data section in file order: its chunks (times and sizes from their headers) and
    /// spans of the records stored outside chunks, found by stepping over record headers (chunk
    /// bodies are not read); and the damage that stopped the walk, if any.
    fn scan_layout(&mut self) -> (Vec<ChunkIndex>, Option<Damage>) {
        let end = self.summary.as_ref().map_or(self.file_len, |s| s.start);
        let mut out: Vec<ChunkIndex> = Vec::new();
        let mut pos = 8u64;
        let mut head = [0u8; 33];
        let walked = self
            .file
            .seek(SeekFrom::Start(pos))
            .map_err(|e| e.to_string());
        let damage = walked.and_then(|_| {
            loop {
                let rest = self.file_len.saturating_sub(pos);
                if out.len() > MAX_CHUNKS {
                    break Err(format!("more than {MAX_CHUNKS} chunks or spans of records"));
                }
                if pos >= end {
                    break match rest {
                        0 => Err("file ends without a footer (truncated?)".into()),
                        _ => Ok(()),
                    };
                }
                if rest < RECORD_PREFIX {
                    break Err("file ends inside a record header (truncated)".into());
                }
                let n = rest.min(head.len() as u64) as usize;
                if let Err(e) = self.file.read_exact(&mut head[..n]) {
                    break Err(e.to_string());
                }
                let (opcode, len) = (head[0], u64_at(&head, 1).unwrap_or_default());
                if len > rest - RECORD_PREFIX {
                    break Err(format!(
                        "record (opcode 0x{opcode:02x}) claims {len} bytes but only {} remain \
                     (truncated file or bad record length)",
                        rest - RECORD_PREFIX
                    ));
                }
                let size = RECORD_PREFIX + len;
                let field = |at: usize| u64_at(&head[..n.min(size as usize)], 9 + at);
                match opcode {
                    op::DATA_END | op::FOOTER => break Ok(()),
                    op::CHUNK => out.push(ChunkIndex {
                        message_start_time: field(0).unwrap_or(0),
                        message_end_time: field(8).unwrap_or(0),
                        chunk_start_offset: pos,
                        chunk_length: size,
                        uncompressed_size: field(16).unwrap_or(0),
                        ..ChunkIndex::default()
                    }),
                    op::MESSAGE | op::SCHEMA | op::CHANNEL => {
                        let time = field(6).filter(|_| opcode == op::MESSAGE);
                        extend_span(&mut out, pos, size, time);
                    }
                    _ => {}
                }
                pos += size;
                if let Err(e) = self.file.seek_relative(size as i64 - n as i64) {
                    break Err(e.to_string());
                }
            }
        });
        for s in out
            .iter_mut()
            .filter(|s| s.message_start_time > s.message_end_time)
        {
            (s.message_start_time, s.message_end_time) = (0, 0); // a span without messages
        }
        (out, damage.err().map(|what| Damage { offset: pos, what }))
    }

    /// The decoded channel for `id`, parsing its schema on first use.
    fn channel(&mut self, id: u16) -> Result<Arc<Channel>, ReadError> {
        let i = usize::from(id);
        if let Some(Some(c)) = self.resolved.get(i) {
            return Ok(c.clone());
        }
        let c = resolve_channel(&self.path, &self.registry, &self.opts, id)?;
        if self.resolved.len() <= i {
            self.resolved.resize(i + 1, None);
        }
        self.resolved[i] = Some(c.clone());
        Ok(c)
    }

    /// Stream raw messages of wanted channels to `sink`, in log-time order (but where more
    /// chunks overlap in time than the memory budget allows, with a warning).
    fn walk(
        &mut self,
        topics: Option<&[&str]>,
        sink: &mut RawSink<'_, R>,
    ) -> Result<ReadSummary, ReadError> {
        let mut summary = ReadSummary::starting(&self.open_warnings, true);
        self.registry.orphans = Orphans::default();
        let mut result = self.walk_indexed(topics, sink, &mut summary.warnings)?;
        if let (Ok(()), Some(d)) = (&result, &self.scan_damage) {
            result = Err(d.clone());
        }
        let orphans =
            self.registry
                .orphans
                .warnings(&self.path, "channel", "in the record at byte offset");
        summary.warnings.extend(orphans);
        if let Err(d) = result {
            summary.complete = false;
            summary.warnings.push(format!(
                "{}: damaged at byte offset {}: {}; read stopped there (every message before it was delivered)",
                self.path.display(),
                d.offset,
                d.what
            ));
        }
        Ok(summary)
    }

    /// The chunk indexes to read for `topics`, by start time, in groups of chunks whose time
    /// ranges overlap (merged so delivery stays time-ordered). A group stops growing at
    /// [`GROUP_BUDGET_BYTES`] of decompressed data (with a warning: order may then break).
    fn chunk_groups(
        &self,
        topics: Option<&[&str]>,
        warnings: &mut Vec<String>,
    ) -> Vec<Vec<ChunkIndex>> {
        let indexed = self.summary.iter().flat_map(|s| &s.chunks);
        let mut chunks: Vec<ChunkIndex> = indexed.chain(&self.unindexed).cloned().collect();
        // Chunks are skipped on the index's word only when its CRC vouches for it.
        let trusted = self.summary.as_ref().is_some_and(|s| s.verified);
        chunks.retain(|c| {
            !trusted
                || topics.is_none()
                || c.message_index_offsets.is_empty()
                || c.message_index_offsets
                    .keys()
                    .any(|id| self.registry.wanted(*id, topics))
        });
        if let Some(ranges) = self.time_ranges.as_ref().filter(|_| trusted) {
            chunks.retain(|c| super::overlaps(ranges, c.message_start_time, c.message_end_time));
        }
        chunks.sort_by_key(|c| (c.message_start_time, c.chunk_start_offset));
        let mut groups: Vec<Vec<ChunkIndex>> = Vec::new();
        let mut end = 0u64;
        let mut bytes = 0u64;
        let mut over_budget = false;
        for c in chunks {
            let size = c.uncompressed_size.min(MAX_CHUNK_BYTES);
            let joins = groups.last().is_some_and(|_| c.message_start_time < end);
            if joins && bytes + size > GROUP_BUDGET_BYTES {
                over_budget = true;
            }
            match groups.last_mut() {
                Some(g) if joins && bytes + size <= GROUP_BUDGET_BYTES => {
                    end = end.max(c.message_end_time);
                    bytes += size;
                    g.push(c);
                }
                _ => {
                    end = c.message_end_time;
                    bytes = size;
                    groups.push(vec![c]);
                }
            }
        }
        if over_budget {
            warnings.push(format!(
                "{}: more chunks overlap in time than fit the {} MiB memory budget; they are read \
                 one after the other, so messages may come out of time order",
                self.path.display(),
                GROUP_BUDGET_BYTES >> 20
            ));
        }
        // Each group is read and scanned in file order: channel records come before their use.
        for g in &mut groups {
            g.sort_by_key(|c| c.chunk_start_offset);
        }
        groups
    }

    /// Deliver the indexed chunks group by group. Decompression runs on the worker pool, ahead
    /// of the scan and delivery here by up to [`AHEAD_BYTES`] (at least one group per worker);
    /// the raw chunk bytes are read here, in file order, so the byte source needs no sharing.
    fn walk_indexed(
        &mut self,
        topics: Option<&[&str]>,
        sink: &mut RawSink<'_, R>,
        warnings: &mut Vec<String>,
    ) -> Result<Result<(), Damage>, ReadError> {
        let groups = self.chunk_groups(topics, warnings);
        if groups.is_empty() {
            return Ok(Ok(()));
        }
        let mut mismatched = 0usize;
        let mut routes = Routes::new();
        let mut msgs = Vec::new();
        let bytes = |g: &[ChunkIndex]| -> u64 {
            g.iter()
                .map(|c| c.uncompressed_size.min(MAX_CHUNK_BYTES))
                .sum()
        };
        std::thread::scope(|scope| {
            // A pool of decompression workers, group g going to worker g % INFLATE_WORKERS. The
            // groups are sent ahead of delivery up to AHEAD_BYTES (at least one per worker), so
            // no worker waits for this thread between two groups.
            let mut workers = Vec::new();
            for _ in 0..INFLATE_WORKERS.min(groups.len()) {
                let (jobs, job_rx) = std::sync::mpsc::channel::<InflateJob>();
                let (done_tx, done) = std::sync::mpsc::channel::<Inflated>();
                scope.spawn(move || inflate_jobs(job_rx, done_tx));
                workers.push((jobs, done));
            }
            let (mut sent, mut ahead) = (0usize, 0u64);
            let mut spare: Vec<Vec<u8>> = Vec::new();
            for (g, group) in groups.iter().enumerate() {
                while let Some(next) = groups
                    .get(sent)
                    .filter(|n| sent < g + workers.len() || ahead + bytes(n) <= AHEAD_BYTES)
                {
                    let keep = spare.len().saturating_sub(next.len());
                    let job = self.read_group(next, spare.split_off(keep));
                    if workers[sent % workers.len()].0.send(job).is_err() {
                        return Ok(Err(worker_gone(next)));
                    }
                    ahead += bytes(next);
                    sent += 1;
                }
                let Ok(buffers) = workers[g % workers.len()].1.recv() else {
                    return Ok(Err(worker_gone(group)));
                };
                ahead -= bytes(group);
                msgs.clear();
                let mut damage = None;
                for (k, (ci, buf)) in group.iter().zip(&buffers).enumerate() {
                    routes.next_chunk();
                    let loaded = buf.as_ref().map_err(Damage::clone).and_then(|b| {
                        scan_records(
                            b,
                            ci.chunk_start_offset,
                            k,
                            &mut self.registry,
                            &mut routes,
                            topics,
                            &mut msgs,
                        )
                    });
                    if let Err(mut d) = loaded {
                        d.what = match ci.loose {
                            true => format!("{} (records stored outside chunks)", d.what),
                            false => format!("{} (chunk with {})", d.what, self.topics_of(ci)),
                        };
                        // Deliver what is certainly earlier than the damaged chunk, then stop.
                        msgs.retain(|m| m.log_time < ci.message_start_time && m.buf < k);
                        damage = Some(d);
                        break;
                    }
                    mismatched += self.check_chunk_channels(ci, &routes.seen, mismatched, warnings);
                }
                msgs.sort_by_key(|m| m.log_time);
                for m in &msgs {
                    let data = buffers
                        .get(m.buf)
                        .and_then(|b| b.as_ref().ok())
                        .and_then(|b| b.get(m.start..m.end))
                        .unwrap_or(&[]);
                    sink(self, m, data)?;
                }
                if let Some(d) = damage {
                    return Ok(Err(d));
                }
                spare.extend(buffers.into_iter().filter_map(Result::ok));
            }
            if mismatched > MAX_DETAILED {
                warnings.push(format!(
                    "{}: {} more chunk index entries disagree with their chunks",
                    self.path.display(),
                    mismatched - MAX_DETAILED
                ));
            }
            Ok(Ok(()))
        })
    }

    /// Compare the channels the chunk index entry `ci` lists with those of the chunk just
    /// scanned (`registry.seen`); a difference is a warning (the first [`MAX_DETAILED`]
    /// in detail). Returns 1 when they differ.
    fn check_chunk_channels(
        &self,
        ci: &ChunkIndex,
        seen: &BTreeSet<u16>,
        before: usize,
        warnings: &mut Vec<String>,
    ) -> usize {
        let listed: BTreeSet<u16> = ci.message_index_offsets.keys().copied().collect();
        // An index without message indexes makes no claim about the chunk's channels.
        if listed.is_empty() || listed == *seen {
            return 0;
        }
        if before < MAX_DETAILED {
            warnings.push(format!(
                "{}: the chunk index record at byte offset {} lists channel ids {:?} for the chunk \
                 at byte offset {}, which holds messages on channel ids {:?}; the chunk was read \
                 whole (the data wins over the index)",
                self.path.display(),
                ci.record_offset,
                listed,
                ci.chunk_start_offset,
                seen
            ));
        }
        1
    }

    /// The raw chunk records of `group`, read in file order and checked against the file's
    /// length (a chunk that cannot be read is carried as its damage, reported when reached).
    fn read_group(&mut self, group: &[ChunkIndex], spare: Vec<Vec<u8>>) -> InflateJob {
        let chunks = group
            .iter()
            .map(|ci| {
                let offset = ci.chunk_start_offset;
                let damage = |what: String| Damage { offset, what };
                if ci.chunk_length < RECORD_PREFIX
                    || ci.chunk_length > MAX_CHUNK_BYTES
                    || offset.saturating_add(ci.chunk_length) > self.file_len
                {
                    return Err(damage(format!(
                        "chunk index points beyond the file or to an oversized chunk (length {})",
                        ci.chunk_length
                    )));
                }
                let mut bytes = vec![0; ci.chunk_length as usize];
                self.read_at(offset, &mut bytes)
                    .map_err(|e| damage(e.to_string()))?;
                let loose = ci.loose;
                Ok(RawChunk {
                    offset,
                    bytes,
                    loose,
                })
            })
            .collect();
        InflateJob { chunks, spare }
    }

    fn topics_of(&self, ci: &ChunkIndex) -> String {
        let names: Vec<&str> = ci
            .message_index_offsets
            .keys()
            .filter_map(|id| self.registry.channels.get(id).map(|c| c.topic.as_str()))
            .collect();
        if names.is_empty() {
            "topics unknown".into()
        } else {
            format!("topics {}", names.join(", "))
        }
    }

    /// Per-channel first/last log time from the message indexes of the chunks (reads only the
    /// chunks at the ends of each channel's span).
    fn channel_spans(&mut self) -> HashMap<u16, (u64, u64)> {
        let Some(summary) = &self.summary else {
            return HashMap::new();
        };
        let mut by_start = summary.chunks.clone();
        by_start.sort_by_key(|c| c.message_start_time);
        let mut by_end = by_start.clone();
        by_end.sort_by_key(|c| std::cmp::Reverse(c.message_end_time));
        let ids: HashSet<u16> = by_start
            .iter()
            .flat_map(|c| c.message_index_offsets.keys().copied())
            .collect();
        let mut spans = HashMap::new();
        for id in ids {
            let has = |c: &&ChunkIndex| c.message_index_offsets.contains_key(&id);
            let mut bounds = |c: &ChunkIndex| {
                let offset = c.message_index_offsets.get(&id)?;
                self.index_bounds(*offset)
            };
            let mut first = u64::MAX;
            for c in by_start.iter().filter(has) {
                if c.message_start_time > first {
                    break;
                }
                first = bounds(c).map_or(first, |(lo, _)| first.min(lo));
            }
            let mut last = 0u64;
            for c in by_end.iter().filter(has) {
                if c.message_end_time < last {
                    break;
                }
                last = bounds(c).map_or(last, |(_, hi)| last.max(hi));
            }
            if first <= last {
                spans.insert(id, (first, last));
            }
        }
        spans
    }

    /// Earliest and latest log time listed in the message index record at `offset`.
    fn index_bounds(&mut self, offset: u64) -> Option<(u64, u64)> {
        let mut prefix = [0u8; 9];
        self.read_at(offset, &mut prefix).ok()?;
        let len = u64::from_le_bytes(prefix[1..].try_into().ok()?);
        if prefix[0] != op::MESSAGE_INDEX
            || len > MAX_CHUNK_BYTES
            || offset.checked_add(RECORD_PREFIX + len)? > self.file_len
        {
            return None;
        }
        let mut body = vec![0u8; len as usize];
        self.file.read_exact(&mut body).ok()?;
        // channel id (2), then a u32 byte length, then (log time, offset) pairs.
        let entries = body.get(6..)?;
        entries
            .chunks_exact(16)
            .filter_map(|e| e.get(..8)?.try_into().ok().map(u64::from_le_bytes))
            .fold(None, |acc, t| {
                Some(acc.map_or((t, t), |(lo, hi): (u64, u64)| (lo.min(t), hi.max(t))))
            })
    }

    fn topic_info(&self, id: u16, stat: &TopicStat) -> TopicInfo {
        let Some(c) = self.registry.channels.get(&id) else {
            return stat.info(&format!("<channel {id}>"), "", "");
        };
        let schema = self.registry.schemas.get(&c.schema_id);
        let type_name = schema.map_or("", |s| s.name.as_str());
        stat.info(&c.topic, type_name, &c.message_encoding)
    }

    /// Per-channel (count, first, last) from the statistics and message indexes, when the
    /// summary's CRC vouches for them and they cover every channel; `None` when the messages
    /// must be counted (no statistics, no CRC, no chunk or message index for some channel, or
    /// counts that cannot be true: a warning says which).
    fn indexed_counts(&mut self, warnings: &mut Vec<String>) -> Option<BTreeMap<u16, TopicStat>> {
        let summary = self.summary.as_ref().filter(|s| s.verified)?;
        let stats = summary.stats.clone()?;
        let stats_offset = summary.stats_offset;
        if !self.has_index() {
            return None;
        }
        // A message record takes at least its prefix and 22 header bytes of a chunk.
        let capacity = summary
            .chunks
            .iter()
            .fold(0u64, |a, c| a.saturating_add(c.uncompressed_size))
            / (RECORD_PREFIX + 22);
        let total = stats
            .channel_message_counts
            .values()
            .try_fold(0u64, |a, n| a.checked_add(*n));
        if total.is_none_or(|t| t > capacity) {
            warnings.push(format!(
                "{}: the statistics record at byte offset {stats_offset} lists more messages than \
                 the indexed chunks can hold ({} bytes); the messages were counted instead",
                self.path.display(),
                capacity * (RECORD_PREFIX + 22)
            ));
            return None;
        }
        let spans = self.channel_spans();
        let mut per_channel = BTreeMap::new();
        for (id, count) in &stats.channel_message_counts {
            if *count == 0 {
                continue;
            }
            let (first, last) = spans.get(id).copied()?;
            let (count, first_ns, last_ns) = (*count, first, last);
            per_channel.insert(
                *id,
                TopicStat {
                    count,
                    first_ns,
                    last_ns,
                },
            );
        }
        Some(per_channel)
    }

    /// Warnings where the statistics record disagrees with the messages counted (`read`:
    /// channel id → count, first, last); `complete` is whether the whole file was read.
    fn check_statistics(
        &self,
        read: &BTreeMap<u16, TopicStat>,
        complete: bool,
        warnings: &mut Vec<String>,
    ) {
        let Some(summary) = &self.summary else { return };
        let Some(stats) = &summary.stats else { return };
        let at = summary.stats_offset;
        let path = self.path.display();
        let ids: BTreeSet<u16> = read
            .keys()
            .chain(stats.channel_message_counts.keys())
            .copied()
            .collect();
        let mut differ = Vec::new();
        for id in ids {
            let got = read.get(&id).map_or(0, |r| r.count);
            let listed = stats.channel_message_counts.get(&id).copied();
            match listed {
                Some(n) if n == got => continue,
                // The read stopped at damage (its own warning says so): fewer is expected.
                Some(n) if !complete && n > got => continue,
                None if got == 0 || stats.channel_message_counts.is_empty() => continue,
                _ => {}
            }
            let listed = listed.map_or("no".to_string(), |n| n.to_string());
            differ.push(format!(
                "{path}: the statistics record at byte offset {at} lists {listed} messages on \
                 channel {id} ({}) but {got} were read; the counts shown are the ones read",
                self.topic_info(id, &TopicStat::default()).topic
            ));
        }
        capped(warnings, differ, |more| {
            format!(
                "{path}: the statistics record disagrees with the messages read on {more} more channels"
            )
        });
        let total = read.values().fold(0u64, |a, r| a.saturating_add(r.count));
        if complete && stats.message_count != total {
            warnings.push(format!(
                "{path}: the statistics record at byte offset {at} lists {} messages in all but \
                 {total} were read",
                stats.message_count
            ));
        }
    }
}

/// Split the record at `pos` in `buf`: (opcode, body, position after it).
fn frame(buf: &[u8], pos: usize) -> Result<(u8, &[u8], usize), String> {
    let prefix = buf
        .get(pos..pos.saturating_add(9))
        .ok_or("record header cut off")?;
    let len = u64::from_le_bytes(
        prefix[1..]
            .try_into()
            .map_err(|_| "record header cut off")?,
    );
    let start = pos + 9;
    let end = usize::try_from(len)
        .ok()
        .and_then(|l| start.checked_add(l))
        .filter(|e| *e <= buf.len())
        .ok_or_else(|| {
            format!(
                "record (opcode 0x{:02x}) length {len} runs past its container",
                prefix[0]
            )
        })?;
    Ok((prefix[0], &buf[start..end], end))
}

/// The little-endian u64 at `at` in `buf`, if it is all there.
fn u64_at(buf: &[u8], at: usize) -> Option<u64> {
    let b = buf.get(at..at.checked_add(8)?)?;
    b.try_into().ok().map(u64::from_le_bytes)
}

/// Add the record of `size` bytes at `pos` (stored outside chunks; `time`: a message's log
/// time) to the last span of `layout` when it ends there and has room, else start a span.
fn extend_span(layout: &mut Vec<ChunkIndex>, pos: u64, size: u64, time: Option<u64>) {
    let joins = layout.last().is_some_and(|s| {
        s.loose
            && s.chunk_start_offset + s.chunk_length == pos
            && s.chunk_length + size <= SPAN_BYTES
    });
    if !joins {
        layout.push(ChunkIndex {
            message_start_time: u64::MAX,
            chunk_start_offset: pos,
            loose: true,
            ..ChunkIndex::default()
        });
    }
    if let Some(s) = layout.last_mut() {
        s.chunk_length += size;
        s.uncompressed_size = s.chunk_length;
        if let Some(t) = time {
            s.message_start_time = s.message_start_time.min(t);
            s.message_end_time = s.message_end_time.max(t);
        }
    }
}

/// Raw chunk records of one group for the decompression thread (with the file offset each
/// came from, or the damage met reading it), and spent buffers to decompress into.
struct InflateJob {
    chunks: Vec<Result<RawChunk, Damage>>,
    spare: Vec<Vec<u8>>,
}

/// Most decompressed bytes of the groups sent to the workers and not yet delivered, beyond one
/// group per worker: enough that a worker never waits for the next group while this thread
/// delivers, few enough that a group is still in the cache when it is delivered (16 MiB ahead
/// made the delivery's reads of the decompressed bytes 3× slower).
const AHEAD_BYTES: u64 = 2 << 20;

/// Decompression workers of an indexed read (the machine this was tuned on has two cores; the
/// caller's thread reads the raw chunks and decodes the messages).
const INFLATE_WORKERS: usize = 2;

/// One group's decompressed chunks (or the damage met in each).
type Inflated = Vec<Result<Vec<u8>, Damage>>;

/// A decompression worker: inflate each job's chunks into its spare buffers, until either
/// channel closes (the reader stopped on damage or a sink error).
fn inflate_jobs(
    jobs: std::sync::mpsc::Receiver<InflateJob>,
    done: std::sync::mpsc::Sender<Inflated>,
) {
    let mut inflater = Inflater::default();
    for mut job in jobs {
        let out = job
            .chunks
            .into_iter()
            .map(|raw| inflater.entry(raw, job.spare.pop().unwrap_or_default()))
            .collect();
        if done.send(out).is_err() {
            break;
        }
    }
}

/// The damage reported when the decompression thread is gone (it only stops early on a bug).
fn worker_gone(group: &[ChunkIndex]) -> Damage {
    Damage {
        offset: group.first().map_or(0, |c| c.chunk_start_offset),
        what: "the chunk decompression thread stopped unexpectedly".into(),
    }
}

impl Inflater {
    /// The records of one entry read from the file: a chunk decompressed into `buf` (sizes and
    /// CRC checked), or a span of loose records as it is.
    fn entry(
        &mut self,
        raw: Result<RawChunk, Damage>,
        mut buf: Vec<u8>,
    ) -> Result<Vec<u8>, Damage> {
        let raw = raw?;
        if raw.loose {
            return Ok(raw.bytes);
        }
        let damage = |what: String| Damage {
            offset: raw.offset,
            what,
        };
        let (opcode, body, _) = frame(&raw.bytes, 0).map_err(damage)?;
        if opcode != op::CHUNK {
            let what = format!("expected a chunk record, found opcode 0x{opcode:02x}");
            return Err(damage(what));
        }
        let chunk = rec::chunk(body).map_err(damage)?;
        let (compression, size) = (chunk.compression.as_str(), chunk.uncompressed_size);
        (self.chunk(compression, chunk.records, size, false, &mut buf)).map_err(damage)?;
        if chunk.uncompressed_crc != 0 && crc32fast::hash(&buf) != chunk.uncompressed_crc {
            return Err(damage("chunk CRC mismatch (corrupted data)".into()));
        }
        Ok(buf)
    }
}

/// Walk the records in `buf` (a decompressed chunk, or one framed record): register schemas and
/// channels, collect wanted messages; messages on unknown channel ids are counted as orphans.
fn scan_records(
    buf: &[u8],
    file_offset: u64,
    buf_index: usize,
    registry: &mut Registry,
    routes: &mut Routes,
    topics: Option<&[&str]>,
    msgs: &mut Vec<RawMsg>,
) -> Result<(), Damage> {
    let mut pos = 0;
    while pos < buf.len() {
        let damage = |what| Damage {
            offset: file_offset,
            what,
        };
        let (opcode, body, next) = frame(buf, pos).map_err(damage)?;
        let body_start = pos + 9;
        pos = next;
        match opcode {
            op::MESSAGE => {
                let Some(h) = body.get(..22) else {
                    return Err(damage("message record shorter than its header".into()));
                };
                let channel_id = u16::from_le_bytes([h[0], h[1]]);
                match routes.of(channel_id, registry, topics) {
                    Route::Keep => {}
                    Route::Skip | Route::Undecided => continue,
                    Route::Orphan => {
                        registry.orphans.add(channel_id.into(), file_offset);
                        continue;
                    }
                }
                msgs.push(RawMsg {
                    channel_id,
                    log_time: u64::from_le_bytes(h[6..14].try_into().unwrap_or_default()),
                    buf: buf_index,
                    start: body_start + 22,
                    end: next,
                    file_offset,
                });
            }
            op::SCHEMA | op::CHANNEL => {
                registry
                    .add(opcode, body)
                    .map_err(|e| damage(format!("bad schema/channel record: {e}")))?;
                if let (op::CHANNEL, Some(id)) = (opcode, body.get(..2)) {
                    routes.route[usize::from(u16::from_le_bytes([id[0], id[1]]))] =
                        Route::Undecided;
                }
            }
            _ => {}
        }
    }
    Ok(())
}

/// Build the decoded-channel description for channel `id` (schema parsed, encoding checked).
fn resolve_channel(
    path: &Path,
    registry: &Registry,
    opts: &OpenOptions,
    id: u16,
) -> Result<Arc<Channel>, ReadError> {
    let rec = registry.channels.get(&id).ok_or_else(|| {
        ReadError::Other(format!(
            "{}: message on channel {id}, which has no channel record",
            path.display()
        ))
    })?;
    let schema_err = |error: super::SchemaError| {
        ReadError::Other(format!("{}: topic {}: {error}", path.display(), rec.topic))
    };
    let encoding = match rec.message_encoding.as_str() {
        "cdr" => Encoding::Cdr,
        "ros1" => Encoding::Ros1,
        "json" => Encoding::Json,
        other => {
            return Err(ReadError::Other(format!(
                "{}: topic {}: message encoding {other:?} is not supported (supported: cdr, ros1, json)",
                path.display(),
                rec.topic
            )));
        }
    };
    let schema_rec = registry.schemas.get(&rec.schema_id);
    let (type_name, schema) = match schema_rec {
        Some(s) if matches!(s.encoding.as_str(), "ros2msg" | "ros2idl" | "ros1msg") => {
            let text = String::from_utf8_lossy(&s.data);
            let schema = if text.trim().is_empty() {
                MsgSchema::from_msg_files(&s.name, &opts.msg_paths)
            } else {
                MsgSchema::parse(&s.encoding, &s.name, &text)
            };
            (s.name.clone(), schema.map_err(schema_err)?)
        }
        Some(s)
            if encoding == Encoding::Json && matches!(s.encoding.as_str(), "jsonschema" | "") =>
        {
            (s.name.clone(), schemaless(&s.name))
        }
        None if encoding == Encoding::Json => (rec.topic.clone(), schemaless(&rec.topic)),
        Some(s) => {
            return Err(schema_err(super::SchemaError::UnsupportedEncoding(
                s.encoding.clone(),
            )));
        }
        None => {
            return Err(ReadError::Other(format!(
                "{}: topic {}: channel has no schema; cannot decode {} messages",
                path.display(),
                rec.topic,
                rec.message_encoding
            )));
        }
    };
    Ok(Channel::new(&rec.topic, &type_name, encoding, schema))
}

/// A schema without fields, for JSON channels that carry no message definition: fields are
/// then looked up by name in each message.
fn schemaless(name: &str) -> MsgSchema {
    let root = name.to_string();
    let types = [(
        root.clone(),
        MsgType {
            name: root.clone(),
            fields: Vec::new(),
        },
    )]
    .into_iter()
    .collect();
    MsgSchema { root, types }
}

impl<R: Read + Seek> MessageSource for McapSource<R> {
    fn info_is_cheap(&self) -> bool {
        self.has_index()
    }

    fn latest_time_hint(&self) -> Option<u64> {
        self.unindexed.iter().map(|c| c.message_end_time).max()
    }

    fn format(&self) -> &'static str {
        "mcap"
    }

    fn info(&mut self) -> Result<SessionInfo, ReadError> {
        let mut warnings = self.open_warnings.clone();
        // Statistics and indexes when a CRC vouches for them and they cover every channel with
        // plausible counts; otherwise the messages themselves are counted and the statistics
        // (if any) checked against them.
        let per_channel = match self.indexed_counts(&mut warnings) {
            Some(p) => p,
            None => {
                let mut per_channel: BTreeMap<u16, TopicStat> = BTreeMap::new();
                let summary = self.walk(None, &mut |_, m, _| {
                    per_channel
                        .entry(m.channel_id)
                        .or_default()
                        .add(m.log_time, 1);
                    Ok(())
                })?;
                warnings.extend(
                    summary
                        .warnings
                        .into_iter()
                        .filter(|w| !self.open_warnings.contains(w)),
                );
                self.check_statistics(&per_channel, summary.complete, &mut warnings);
                per_channel
            }
        };
        let topics: Vec<TopicInfo> = per_channel
            .iter()
            .filter(|(_, s)| s.count > 0)
            .map(|(id, s)| self.topic_info(*id, s))
            .collect();
        Ok(super::session_info(&self.path, "mcap", topics, warnings))
    }

    fn set_time_ranges(&mut self, ranges: Option<Vec<(u64, u64)>>) {
        self.time_ranges = ranges;
    }

    fn read(
        &mut self,
        topics: Option<&[&str]>,
        visit: &mut dyn FnMut(MessageRef<'_>) -> Result<(), ReadError>,
    ) -> Result<ReadSummary, ReadError> {
        let mut delivered = 0u64;
        let mut summary = self.walk(topics, &mut |source, m, data| {
            let channel = source.channel(m.channel_id)?;
            delivered += 1;
            visit(MessageRef {
                channel: &channel,
                log_time_ns: m.log_time,
                data,
                file_offset: m.file_offset,
                row_id: false,
            })
        })?;
        summary.messages = delivered;
        if summary.complete && topics.is_none() && self.time_ranges.is_none() {
            let expected = self
                .summary
                .as_ref()
                .and_then(|s| s.stats.as_ref())
                .map(|s| s.message_count);
            if let Some(expected) = expected.filter(|e| *e != delivered) {
                summary.warnings.push(format!(
                    "{}: statistics list {expected} messages but {delivered} were read (messages outside indexed chunks?)",
                    self.path.display()
                ));
            }
        }
        Ok(summary)
    }
}
