//! MCAP reader: streams messages chunk by chunk (zstd, lz4 or uncompressed chunks), using the
//! summary section (statistics, schema/channel records, chunk indexes) when it is there and a
//! linear scan of the data section when it is not. Records are framed here so every warning can
//! name its byte offset; record bodies are parsed with the `mcap` crate.
//!
//! Memory holds at most the chunks whose time ranges overlap (normally one chunk), never the file.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use ::mcap::records::{self, op};

use super::msgdef::MsgType;
use super::{
    Channel, Encoding, MessageRef, MessageSource, MsgSchema, OpenOptions, ReadError, ReadSummary,
    SessionInfo, TopicInfo,
};

/// The 8 bytes every MCAP file starts and ends with.
pub const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// Opcode (1) + record length (8).
const RECORD_PREFIX: u64 = 9;
/// Footer record plus the closing magic.
const FOOTER_TOTAL: u64 = RECORD_PREFIX + 20 + 8;
/// Chunks (compressed or not) larger than this are treated as damage rather than allocated.
const MAX_CHUNK_BYTES: u64 = 1 << 30;
/// Summary sections larger than this are ignored (linear scan instead).
const MAX_SUMMARY_BYTES: u64 = 256 << 20;

#[derive(Debug, Clone)]
struct SchemaRec {
    name: String,
    encoding: String,
    data: Vec<u8>,
}

#[derive(Debug, Clone)]
struct ChannelRec {
    topic: String,
    schema_id: u16,
    message_encoding: String,
}

/// Schemas and channels seen so far (from the summary or the data section).
#[derive(Debug, Default)]
struct Registry {
    schemas: HashMap<u16, SchemaRec>,
    channels: HashMap<u16, ChannelRec>,
}

impl Registry {
    fn add(&mut self, record: records::Record<'_>) {
        match record {
            records::Record::Schema { header, data } => {
                self.schemas.insert(
                    header.id,
                    SchemaRec {
                        name: header.name,
                        encoding: header.encoding,
                        data: data.into_owned(),
                    },
                );
            }
            records::Record::Channel(c) => {
                self.channels.insert(
                    c.id,
                    ChannelRec {
                        topic: c.topic,
                        schema_id: c.schema_id,
                        message_encoding: c.message_encoding,
                    },
                );
            }
            _ => {}
        }
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
    chunks: Vec<records::ChunkIndex>,
    stats: Option<records::Statistics>,
}

/// Damage found while reading: where and what. Turned into a warning; the read stops there.
struct Damage {
    offset: u64,
    what: String,
}

/// A message located in a buffer, before delivery.
struct RawMsg {
    channel_id: u16,
    log_time: u64,
    publish_time: u64,
    /// Which buffer (chunk) holds it and where.
    buf: usize,
    start: usize,
    end: usize,
    file_offset: u64,
}

/// Receives each wanted message with the source (for channel lookups) and its payload.
type RawSink<'a> = dyn FnMut(&mut McapSource, &RawMsg, &[u8]) -> Result<(), ReadError> + 'a;

/// An MCAP file opened for streaming.
pub struct McapSource {
    path: PathBuf,
    file: File,
    file_len: u64,
    opts: OpenOptions,
    registry: Registry,
    summary: Option<Summary>,
    /// Problems met while opening (e.g. an unreadable summary), repeated in every read's summary.
    open_warnings: Vec<String>,
    /// Decoded channels by id, built when first needed.
    resolved: HashMap<u16, Arc<Channel>>,
}

impl McapSource {
    /// Open `path`: checks the magic and header record, and loads the summary section when the
    /// footer points to a readable one. A file that is not MCAP → [`ReadError::Format`].
    pub fn open(path: &Path, opts: &OpenOptions) -> Result<McapSource, ReadError> {
        let io = |source| ReadError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut file = File::open(path).map_err(io)?;
        let file_len = file.metadata().map_err(io)?.len();
        let format = |offset, what: &str| ReadError::Format {
            path: path.to_path_buf(),
            offset,
            what: what.to_string(),
        };
        let mut magic = [0u8; 8];
        if file.read_exact(&mut magic).is_err() || &magic != MAGIC {
            return Err(format(0, "not an MCAP file (bad magic bytes)"));
        }
        let mut prefix = [0u8; 9];
        file.read_exact(&mut prefix)
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
            path: path.to_path_buf(),
            file,
            file_len,
            opts: opts.clone(),
            registry: Registry::default(),
            summary: None,
            open_warnings: Vec::new(),
            resolved: HashMap::new(),
        };
        match source.load_summary() {
            Ok(summary) => source.summary = summary,
            Err(d) => {
                source.registry = Registry::default();
                source.open_warnings.push(format!(
                    "{}: summary section unreadable at byte offset {} ({}); reading the data section linearly",
                    path.display(),
                    d.offset,
                    d.what
                ));
            }
        }
        Ok(source)
    }

    /// True when the file has a usable summary with chunk indexes (indexed, time-ordered reads).
    pub fn has_index(&self) -> bool {
        self.summary.as_ref().is_some_and(|s| !s.chunks.is_empty())
    }

    fn load_summary(&mut self) -> Result<Option<Summary>, Damage> {
        if self.file_len < 8 + FOOTER_TOTAL + 8 {
            return Ok(None);
        }
        let footer_at = self.file_len - FOOTER_TOTAL;
        let mut tail = [0u8; FOOTER_TOTAL as usize];
        let read = self
            .file
            .seek(SeekFrom::Start(footer_at))
            .and_then(|_| self.file.read_exact(&mut tail));
        if read.is_err() || &tail[29..] != MAGIC || tail[0] != op::FOOTER {
            return Ok(None); // no footer: truncated or still being written; the linear scan reports it
        }
        let footer = match ::mcap::parse_record(op::FOOTER, &tail[9..29]) {
            Ok(records::Record::Footer(f)) => f,
            _ => {
                return Err(Damage {
                    offset: footer_at,
                    what: "bad footer record".into(),
                });
            }
        };
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
        self.file
            .seek(SeekFrom::Start(footer.summary_start))
            .and_then(|_| self.file.read_exact(&mut bytes))
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
        let mut summary = Summary {
            chunks: Vec::new(),
            stats: None,
        };
        let mut pos = 0usize;
        while pos < bytes.len() {
            let offset = footer.summary_start + pos as u64;
            let (opcode, body, next) =
                frame(&bytes, pos).map_err(|what| Damage { offset, what })?;
            pos = next;
            let parsed = || {
                ::mcap::parse_record(opcode, body).map_err(|e| Damage {
                    offset,
                    what: e.to_string(),
                })
            };
            match opcode {
                op::SCHEMA | op::CHANNEL => self.registry.add(parsed()?),
                op::CHUNK_INDEX => {
                    if let records::Record::ChunkIndex(ci) = parsed()? {
                        summary.chunks.push(ci);
                    }
                }
                op::STATISTICS => {
                    if let records::Record::Statistics(s) = parsed()? {
                        summary.stats = Some(s);
                    }
                }
                _ => {}
            }
        }
        Ok(Some(summary))
    }

    /// The decoded channel for `id`, parsing its schema on first use.
    fn channel(&mut self, id: u16) -> Result<Arc<Channel>, ReadError> {
        if let Some(c) = self.resolved.get(&id) {
            return Ok(c.clone());
        }
        let c = Arc::new(resolve_channel(&self.path, &self.registry, &self.opts, id)?);
        self.resolved.insert(id, c.clone());
        Ok(c)
    }

    /// Stream raw messages of wanted channels to `sink`, in log-time order when the file is
    /// indexed (file order otherwise, sorted within each chunk).
    fn walk(
        &mut self,
        topics: Option<&[&str]>,
        sink: &mut RawSink<'_>,
    ) -> Result<ReadSummary, ReadError> {
        let mut summary = ReadSummary {
            messages: 0,
            warnings: self.open_warnings.clone(),
            complete: true,
        };
        let result = if self.has_index() {
            self.walk_indexed(topics, sink)?
        } else {
            self.walk_linear(topics, sink)?
        };
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

    fn walk_indexed(
        &mut self,
        topics: Option<&[&str]>,
        sink: &mut RawSink<'_>,
    ) -> Result<Result<(), Damage>, ReadError> {
        let mut chunks = self
            .summary
            .as_ref()
            .map(|s| s.chunks.clone())
            .unwrap_or_default();
        chunks.retain(|c| {
            topics.is_none()
                || c.message_index_offsets.is_empty()
                || c.message_index_offsets
                    .keys()
                    .any(|id| self.registry.wanted(*id, topics))
        });
        chunks.sort_by_key(|c| (c.message_start_time, c.chunk_start_offset));
        let mut buffers: Vec<Vec<u8>> = Vec::new();
        let mut scratch = Vec::new();
        let mut i = 0;
        while i < chunks.len() {
            // A group: chunks whose time ranges overlap, merged so delivery stays time-ordered.
            let mut end = chunks[i].message_end_time;
            let mut j = i + 1;
            while j < chunks.len() && chunks[j].message_start_time < end {
                end = end.max(chunks[j].message_end_time);
                j += 1;
            }
            let mut msgs = Vec::new();
            let mut damage = None;
            for (k, ci) in chunks[i..j].iter().enumerate() {
                if buffers.len() <= k {
                    buffers.push(Vec::new());
                }
                let loaded = self.read_chunk_at(ci, &mut scratch, &mut buffers[k]);
                let loaded = loaded.and_then(|()| {
                    scan_records(
                        &buffers[k],
                        ci.chunk_start_offset,
                        k,
                        &mut self.registry,
                        topics,
                        &mut msgs,
                    )
                });
                if let Err(mut d) = loaded {
                    d.what = format!("{} (chunk with {})", d.what, self.topics_of(ci));
                    // Deliver what is certainly earlier than the damaged chunk, then stop.
                    msgs.retain(|m| m.log_time < ci.message_start_time && m.buf < k);
                    damage = Some(d);
                    break;
                }
            }
            msgs.sort_by_key(|m| m.log_time);
            for m in &msgs {
                let data = buffers
                    .get(m.buf)
                    .and_then(|b| b.get(m.start..m.end))
                    .unwrap_or(&[]);
                sink(self, m, data)?;
            }
            if let Some(d) = damage {
                return Ok(Err(d));
            }
            i = j;
        }
        Ok(Ok(()))
    }

    fn topics_of(&self, ci: &records::ChunkIndex) -> String {
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

    /// Read and decompress the chunk an index entry points to into `out`.
    fn read_chunk_at(
        &mut self,
        ci: &records::ChunkIndex,
        scratch: &mut Vec<u8>,
        out: &mut Vec<u8>,
    ) -> Result<(), Damage> {
        let offset = ci.chunk_start_offset;
        let damage = |what: String| Damage { offset, what };
        if ci.chunk_length < RECORD_PREFIX
            || ci.chunk_length > MAX_CHUNK_BYTES
            || offset.saturating_add(ci.chunk_length) > self.file_len
        {
            return Err(damage(format!(
                "chunk index points beyond the file (length {})",
                ci.chunk_length
            )));
        }
        scratch.resize(ci.chunk_length as usize, 0);
        self.file
            .seek(SeekFrom::Start(offset))
            .and_then(|_| self.file.read_exact(scratch))
            .map_err(|e| damage(e.to_string()))?;
        let (opcode, body, _) = frame(scratch, 0).map_err(damage)?;
        if opcode != op::CHUNK {
            return Err(damage(format!(
                "expected a chunk record, found opcode 0x{opcode:02x}"
            )));
        }
        decompress_chunk(body, out).map_err(damage)
    }

    fn walk_linear(
        &mut self,
        topics: Option<&[&str]>,
        sink: &mut RawSink<'_>,
    ) -> Result<Result<(), Damage>, ReadError> {
        let path = self.path.clone();
        let io = |e: std::io::Error| ReadError::Io {
            path: path.clone(),
            source: e,
        };
        let file = self.file.try_clone().map_err(io)?;
        let mut reader = BufReader::with_capacity(1 << 20, file);
        reader.seek(SeekFrom::Start(8)).map_err(io)?;
        let mut pos = 8u64;
        let mut body = Vec::new();
        let mut chunk = Vec::new();
        loop {
            let offset = pos;
            let damage = |what: String| Damage { offset, what };
            if pos == self.file_len {
                return Ok(Err(damage(
                    "file ends without a footer (truncated?)".into(),
                )));
            }
            if pos + RECORD_PREFIX > self.file_len {
                return Ok(Err(damage(
                    "file ends inside a record header (truncated)".into(),
                )));
            }
            let mut prefix = [0u8; 9];
            if let Err(e) = reader.read_exact(&mut prefix) {
                return Ok(Err(damage(e.to_string())));
            }
            let opcode = prefix[0];
            let len = u64::from_le_bytes(prefix[1..].try_into().unwrap_or_default());
            let remaining = self.file_len - pos - RECORD_PREFIX;
            if len > remaining {
                return Ok(Err(damage(format!(
                    "record (opcode 0x{opcode:02x}) claims {len} bytes but only {remaining} remain (truncated file or bad record length)"
                ))));
            }
            pos += RECORD_PREFIX + len;
            match opcode {
                op::DATA_END | op::FOOTER => return Ok(Ok(())),
                op::CHUNK | op::SCHEMA | op::CHANNEL | op::MESSAGE => {
                    if len > MAX_CHUNK_BYTES {
                        return Ok(Err(damage(format!("record of {len} bytes is too large"))));
                    }
                    body.resize(len as usize, 0);
                    if let Err(e) = reader.read_exact(&mut body) {
                        return Ok(Err(damage(e.to_string())));
                    }
                }
                _ => {
                    reader.seek_relative(len as i64).map_err(io)?;
                    continue;
                }
            }
            let mut msgs = Vec::new();
            let scanned = if opcode == op::CHUNK {
                decompress_chunk(&body, &mut chunk)
                    .map_err(|what| Damage { offset, what })
                    .and_then(|()| {
                        scan_records(&chunk, offset, 0, &mut self.registry, topics, &mut msgs)
                    })
            } else {
                let mut framed = Vec::with_capacity(body.len() + 9);
                framed.push(opcode);
                framed.extend_from_slice(&(len).to_le_bytes());
                framed.extend_from_slice(&body);
                std::mem::swap(&mut framed, &mut chunk);
                scan_records(&chunk, offset, 0, &mut self.registry, topics, &mut msgs)
            };
            if let Err(d) = scanned {
                return Ok(Err(Damage {
                    offset,
                    what: d.what,
                }));
            }
            msgs.sort_by_key(|m| m.log_time);
            for m in &msgs {
                sink(self, m, chunk.get(m.start..m.end).unwrap_or(&[]))?;
            }
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
            let mut first = u64::MAX;
            for c in by_start
                .iter()
                .filter(|c| c.message_index_offsets.contains_key(&id))
            {
                if c.message_start_time > first {
                    break;
                }
                if let Some((lo, _)) = c
                    .message_index_offsets
                    .get(&id)
                    .and_then(|o| self.index_bounds(*o))
                {
                    first = first.min(lo);
                }
            }
            let mut last = 0u64;
            for c in by_end
                .iter()
                .filter(|c| c.message_index_offsets.contains_key(&id))
            {
                if c.message_end_time < last {
                    break;
                }
                if let Some((_, hi)) = c
                    .message_index_offsets
                    .get(&id)
                    .and_then(|o| self.index_bounds(*o))
                {
                    last = last.max(hi);
                }
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
        self.file.seek(SeekFrom::Start(offset)).ok()?;
        self.file.read_exact(&mut prefix).ok()?;
        let len = u64::from_le_bytes(prefix[1..].try_into().ok()?);
        if prefix[0] != op::MESSAGE_INDEX
            || len > MAX_CHUNK_BYTES
            || offset + RECORD_PREFIX + len > self.file_len
        {
            return None;
        }
        let mut body = vec![0u8; len as usize];
        self.file.read_exact(&mut body).ok()?;
        let entries = body.get(6..)?;
        entries
            .chunks_exact(16)
            .filter_map(|e| e.get(..8)?.try_into().ok().map(u64::from_le_bytes))
            .fold(None, |acc, t| {
                Some(acc.map_or((t, t), |(lo, hi): (u64, u64)| (lo.min(t), hi.max(t))))
            })
    }

    fn topic_info(&self, id: u16, count: u64, first: u64, last: u64) -> TopicInfo {
        let (topic, type_name, encoding) = match self.registry.channels.get(&id) {
            Some(c) => (
                c.topic.clone(),
                self.registry
                    .schemas
                    .get(&c.schema_id)
                    .map(|s| s.name.clone())
                    .unwrap_or_default(),
                c.message_encoding.clone(),
            ),
            None => (format!("<channel {id}>"), String::new(), String::new()),
        };
        TopicInfo {
            topic,
            type_name,
            encoding,
            count,
            first_ns: first,
            last_ns: last,
            rate_hz: rate(count, first, last),
        }
    }
}

/// Mean rate [Hz] of `count` messages spread over [first, last] ns.
pub fn rate(count: u64, first: u64, last: u64) -> f64 {
    if count > 1 && last > first {
        (count - 1) as f64 / ((last - first) as f64 * 1e-9)
    } else {
        0.0
    }
}

/// Split the record at `pos` in `buf`: (opcode, body, position after it).
fn frame(buf: &[u8], pos: usize) -> Result<(u8, &[u8], usize), String> {
    let prefix = buf.get(pos..pos + 9).ok_or("record header cut off")?;
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

/// Decompress a chunk record body into `out`, checking sizes and the CRC.
fn decompress_chunk(body: &[u8], out: &mut Vec<u8>) -> Result<(), String> {
    let (header, data) = match ::mcap::parse_record(op::CHUNK, body) {
        Ok(records::Record::Chunk { header, data }) => (header, data),
        Ok(_) => return Err("not a chunk".into()),
        Err(e) => return Err(format!("bad chunk record: {e}")),
    };
    if header.uncompressed_size > MAX_CHUNK_BYTES {
        return Err(format!(
            "chunk claims {} uncompressed bytes",
            header.uncompressed_size
        ));
    }
    let size = header.uncompressed_size as usize;
    out.clear();
    match header.compression.as_str() {
        "" => out.extend_from_slice(&data),
        "zstd" => {
            out.reserve(size);
            // A Vec destination is bounded by its capacity (reserved above).
            zstd::bulk::Decompressor::new()
                .and_then(|mut d| d.decompress_to_buffer(&data[..], out))
                .map_err(|e| format!("zstd decompression failed: {e}"))?;
        }
        "lz4" => {
            out.reserve(size);
            lz4_flex::frame::FrameDecoder::new(&data[..])
                .read_to_end(out)
                .map_err(|e| format!("lz4 decompression failed: {e}"))?;
        }
        other => {
            return Err(format!(
                "unsupported chunk compression {other:?} (supported: zstd, lz4, none)"
            ));
        }
    }
    if out.len() != size {
        return Err(format!(
            "chunk decompressed to {} bytes, header says {size}",
            out.len()
        ));
    }
    if header.uncompressed_crc != 0 && crc32fast::hash(out) != header.uncompressed_crc {
        return Err("chunk CRC mismatch (corrupted data)".into());
    }
    Ok(())
}

/// Walk the records in `buf` (a decompressed chunk, or one framed record): register schemas and
/// channels, collect wanted messages.
fn scan_records(
    buf: &[u8],
    file_offset: u64,
    buf_index: usize,
    registry: &mut Registry,
    topics: Option<&[&str]>,
    msgs: &mut Vec<RawMsg>,
) -> Result<(), Damage> {
    let mut pos = 0;
    while pos < buf.len() {
        let (opcode, body, next) = frame(buf, pos).map_err(|what| Damage {
            offset: file_offset,
            what,
        })?;
        let body_start = pos + 9;
        pos = next;
        match opcode {
            op::MESSAGE => {
                let Some(h) = body.get(..22) else {
                    return Err(Damage {
                        offset: file_offset,
                        what: "message record shorter than its header".into(),
                    });
                };
                let channel_id = u16::from_le_bytes([h[0], h[1]]);
                if !registry.wanted(channel_id, topics) {
                    continue;
                }
                msgs.push(RawMsg {
                    channel_id,
                    log_time: u64::from_le_bytes(h[6..14].try_into().unwrap_or_default()),
                    publish_time: u64::from_le_bytes(h[14..22].try_into().unwrap_or_default()),
                    buf: buf_index,
                    start: body_start + 22,
                    end: next,
                    file_offset,
                });
            }
            op::SCHEMA | op::CHANNEL => {
                let record = ::mcap::parse_record(opcode, body).map_err(|e| Damage {
                    offset: file_offset,
                    what: format!("bad schema/channel record: {e}"),
                })?;
                registry.add(record);
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
) -> Result<Channel, ReadError> {
    let rec = registry.channels.get(&id).ok_or_else(|| {
        ReadError::Other(format!(
            "{}: message on channel {id}, which has no channel record",
            path.display()
        ))
    })?;
    let schema_err = |error| ReadError::Schema {
        path: path.to_path_buf(),
        topic: rec.topic.clone(),
        error,
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
    Ok(Channel {
        topic: rec.topic.clone(),
        type_name,
        encoding,
        schema: Arc::new(schema),
    })
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

impl MessageSource for McapSource {
    fn format(&self) -> &'static str {
        "mcap"
    }

    fn info(&mut self) -> Result<SessionInfo, ReadError> {
        let stats = self.summary.as_ref().and_then(|s| s.stats.clone());
        let mut warnings = self.open_warnings.clone();
        let mut per_channel: BTreeMap<u16, (u64, u64, u64)> = BTreeMap::new();
        let (start_ns, end_ns, messages) = match stats {
            Some(stats) => {
                let spans = self.channel_spans();
                for (id, count) in &stats.channel_message_counts {
                    let (first, last) = spans
                        .get(id)
                        .copied()
                        .unwrap_or((stats.message_start_time, stats.message_end_time));
                    per_channel.insert(*id, (*count, first, last));
                }
                (
                    stats.message_start_time,
                    stats.message_end_time,
                    stats.message_count,
                )
            }
            None => {
                let mut bounds = (u64::MAX, 0u64, 0u64);
                let summary = self.walk(None, &mut |_, m, _| {
                    let e = per_channel.entry(m.channel_id).or_insert((0, u64::MAX, 0));
                    *e = (e.0 + 1, e.1.min(m.log_time), e.2.max(m.log_time));
                    bounds = (
                        bounds.0.min(m.log_time),
                        bounds.1.max(m.log_time),
                        bounds.2 + 1,
                    );
                    Ok(())
                })?;
                warnings = summary.warnings;
                (if bounds.2 == 0 { 0 } else { bounds.0 }, bounds.1, bounds.2)
            }
        };
        let mut topics: Vec<TopicInfo> = per_channel
            .iter()
            .filter(|(_, (count, _, _))| *count > 0)
            .map(|(id, (count, first, last))| self.topic_info(*id, *count, *first, *last))
            .collect();
        topics.sort_by(|a, b| a.topic.cmp(&b.topic));
        Ok(SessionInfo {
            path: self.path.clone(),
            format: "mcap".into(),
            start_ns,
            end_ns,
            messages,
            topics,
            warnings,
        })
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
                publish_time_ns: m.publish_time,
                data,
                file_offset: m.file_offset,
            })
        })?;
        summary.messages = delivered;
        if summary.complete && topics.is_none() {
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
