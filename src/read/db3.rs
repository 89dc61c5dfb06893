//! ROS 2 bag directories (rosbag2): `metadata.yaml` plus one or more sqlite3 `.db3` files.
//!
//! Topics and types come from each database's `topics` table, message definitions from its
//! `message_definitions` table when present, otherwise from `.msg` files on `--msg-path`, otherwise
//! from the definitions built into the binary. Split bags are merged by timestamp across their
//! files. Databases are opened read-only and `immutable`, so reading never writes next to the
//! input (no `-wal`/`-shm` files). zstd-compressed bags (file or message mode) are decompressed
//! on the fly; bags whose storage is MCAP are handed to the MCAP reader.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use rusqlite::fallible_streaming_iterator::FallibleStreamingIterator;
use rusqlite::{Connection, OpenFlags};

use super::mcap::McapSource;
use super::msgdef::MsgSchema;
use super::shared::{TopicStat, by_topic, select_topics};
use super::{
    Channel, Encoding, MessageRef, MessageSource, OpenOptions, ReadError, ReadSummary, SessionInfo,
    session_info,
};

/// A ROS 2 bag (sqlite3 storage, or MCAP storage delegated to the MCAP reader).
pub struct Ros2BagSource {
    inner: Inner,
}

enum Inner {
    Sqlite(SqliteBag),
    /// MCAP storage: one reader per split file, read one after the other (rosbag2 splits by
    /// size or duration, so the files follow each other in time).
    Mcap {
        bag: PathBuf,
        files: Vec<McapSource>,
        /// Payloads are individually zstd-compressed (`compression_mode: MESSAGE`).
        message_zstd: bool,
        /// Decompressed copies of `compression_mode: FILE` files; removed on drop.
        _scratch: Option<Scratch>,
    },
}

/// The sqlite3 storage of a bag.
struct SqliteBag {
    /// What the user named (folder, metadata.yaml or .db3), for messages.
    bag: PathBuf,
    files: Vec<DbFile>,
    /// One entry per topic name, in order of first appearance.
    topics: Vec<BagTopic>,
    /// Payloads are individually zstd-compressed (`compression_mode: MESSAGE`).
    message_compression: bool,
    /// Decompressed copies of `compression_mode: FILE` databases; removed on drop.
    _scratch: Option<Scratch>,
    /// Damage found when opening (truncated databases), repeated in info and every read.
    notes: Vec<String>,
}

struct DbFile {
    /// The file as the bag names it (for messages).
    path: PathBuf,
    /// The sqlite database actually opened (a decompressed copy for file-compressed bags).
    db_path: PathBuf,
    /// `topics.id` of this file → index into `SqliteBag::topics`.
    topic_ids: HashMap<i64, usize>,
}

struct BagTopic {
    name: String,
    type_name: String,
    /// The channel, or why its definition could not be found (reported when it is read).
    channel: Result<Arc<Channel>, String>,
}

impl Ros2BagSource {
    /// Open a ROS 2 bag: its folder, its `metadata.yaml`, or a single `.db3` file (then only that
    /// file is read, with or without a `metadata.yaml` next to it).
    pub fn open(dir_or_yaml: &Path, opts: &OpenOptions) -> Result<Ros2BagSource, ReadError> {
        let is_db3_file = dir_or_yaml.is_file()
            && dir_or_yaml.extension().and_then(|e| e.to_str()) != Some("yaml");
        if is_db3_file {
            let db = SqliteBag::open(
                dir_or_yaml,
                vec![dir_or_yaml.to_path_buf()],
                Compression::None,
                opts,
            )?;
            return Ok(Ros2BagSource {
                inner: Inner::Sqlite(db),
            });
        }
        let (dir, yaml_path) = if dir_or_yaml.is_dir() {
            let yaml = dir_or_yaml.join("metadata.yaml");
            if !yaml.exists() {
                return Self::open_without_metadata(dir_or_yaml, opts);
            }
            (dir_or_yaml.to_path_buf(), yaml)
        } else {
            let dir = dir_or_yaml.parent().unwrap_or(Path::new(".")).to_path_buf();
            (dir, dir_or_yaml.to_path_buf())
        };
        let text = crate::util::read_text_input(&yaml_path).map_err(ReadError::io(&yaml_path))?;
        let meta = BagMetadata::parse(&text)
            .map_err(|what| ReadError::Other(format!("{}: {what}", yaml_path.display())))?;
        if meta.relative_file_paths.is_empty() {
            return Err(ReadError::Other(format!(
                "{}: lists no storage files (relative_file_paths is empty)",
                yaml_path.display()
            )));
        }
        let mut listed = std::collections::HashSet::new();
        if let Some(twice) = meta.relative_file_paths.iter().find(|f| {
            let path = dir.join(f.as_str());
            !listed.insert(std::fs::canonicalize(&path).unwrap_or(path))
        }) {
            return Err(ReadError::Other(format!(
                "{}: storage file {twice} is listed twice in relative_file_paths (its messages would be read twice)",
                yaml_path.display()
            )));
        }
        let files: Vec<PathBuf> = meta
            .relative_file_paths
            .iter()
            .map(|f| dir.join(f))
            .collect();
        if let Some(missing) = files.iter().find(|f| !f.is_file()) {
            return Err(ReadError::Other(format!(
                "{}: storage file {} listed in metadata.yaml is missing ({} of the bag's {} files present)",
                dir.display(),
                missing.display(),
                files.iter().filter(|f| f.is_file()).count(),
                files.len()
            )));
        }
        let compression = Compression::from_metadata(&meta, &yaml_path)?;
        match meta.storage_identifier.as_str() {
            "sqlite3" | "" => {
                let db = SqliteBag::open(&dir, files, compression, opts)?;
                Ok(Ros2BagSource {
                    inner: Inner::Sqlite(db),
                })
            }
            "mcap" => Ok(Ros2BagSource {
                inner: open_mcap_storage(&dir, &files, compression, opts)?,
            }),
            other => Err(ReadError::Other(format!(
                "{}: unsupported rosbag2 storage {other:?} (supported: sqlite3, mcap)",
                yaml_path.display()
            ))),
        }
    }
}

impl Ros2BagSource {
    /// A bag folder without `metadata.yaml` (lost, or a recorder that died): its `.db3` files
    /// in name order, which is rosbag2's split order (`name_0.db3`, `name_1.db3`, …).
    fn open_without_metadata(dir: &Path, opts: &OpenOptions) -> Result<Ros2BagSource, ReadError> {
        let io = ReadError::io(dir);
        let mut files = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(&io)? {
            let path = entry.map_err(&io)?.path();
            if path.extension().and_then(|e| e.to_str()) == Some("db3") {
                files.push(path);
            }
        }
        // Natural order so that name_10.db3 follows name_9.db3.
        files.sort_by_key(|p| {
            let stem = p
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            let split: u64 = stem
                .rsplit('_')
                .next()
                .and_then(|n| n.parse().ok())
                .unwrap_or(0);
            (split, stem)
        });
        if files.is_empty() {
            return Err(ReadError::Other(format!(
                "{}: not a ROS 2 bag (no metadata.yaml and no .db3 files)",
                dir.display()
            )));
        }
        let db = SqliteBag::open(dir, files, Compression::None, opts)?;
        Ok(Ros2BagSource {
            inner: Inner::Sqlite(db),
        })
    }
}

impl MessageSource for Ros2BagSource {
    fn info_is_cheap(&self) -> bool {
        match &self.inner {
            Inner::Sqlite(_) => true,
            Inner::Mcap { files, .. } => files.iter().all(McapSource::has_index),
        }
    }

    fn format(&self) -> &'static str {
        match &self.inner {
            Inner::Sqlite(_) => "ros2-sqlite3",
            Inner::Mcap { .. } => "ros2-mcap",
        }
    }

    fn info(&mut self) -> Result<SessionInfo, ReadError> {
        match &mut self.inner {
            Inner::Sqlite(db) => db.info(),
            Inner::Mcap { bag, files, .. } => {
                let mut infos = Vec::with_capacity(files.len());
                for f in files.iter_mut() {
                    infos.push(f.info()?);
                }
                Ok(merge_infos(bag, "ros2-mcap", infos))
            }
        }
    }

    fn read(
        &mut self,
        topics: Option<&[&str]>,
        visit: &mut dyn FnMut(MessageRef<'_>) -> Result<(), ReadError>,
    ) -> Result<ReadSummary, ReadError> {
        match &mut self.inner {
            Inner::Sqlite(db) => db.read(topics, visit),
            Inner::Mcap {
                files,
                message_zstd,
                ..
            } => {
                let mut total = ReadSummary {
                    complete: true,
                    ..ReadSummary::default()
                };
                let mut scratch = Vec::new();
                let compressed = *message_zstd;
                for f in files.iter_mut() {
                    let name = f.name().to_path_buf();
                    let mut skipped = Skipped::default();
                    let mut inflate = |m: MessageRef<'_>| match inflated(
                        m,
                        compressed,
                        &mut scratch,
                        &name,
                        &mut skipped,
                    ) {
                        Some(m) => visit(m),
                        None => Ok(()),
                    };
                    let s = f.read(topics, &mut inflate)?;
                    total.messages += s.messages.saturating_sub(skipped.count());
                    total.warnings.extend(s.warnings);
                    total.warnings.extend(skipped.warnings());
                    if !s.complete {
                        total.complete = false;
                        break;
                    }
                }
                Ok(total)
            }
        }
    }
}

/// Messages skipped because their zstd payload does not decompress: counted per storage file,
/// reported as one warning per file naming the first one (the read goes on past them).
#[derive(Default)]
struct Skipped {
    /// (file, count, the first one: topic, row id or byte offset, error).
    per_file: Vec<(PathBuf, u64, String)>,
}

impl Skipped {
    fn add(&mut self, file: &Path, first: impl FnOnce() -> String) {
        match self.per_file.iter_mut().find(|(f, _, _)| f == file) {
            Some((_, n, _)) => *n += 1,
            None => self.per_file.push((file.to_path_buf(), 1, first())),
        }
    }

    fn count(&self) -> u64 {
        self.per_file.iter().map(|(_, n, _)| n).sum()
    }

    fn warnings(self) -> impl Iterator<Item = String> {
        self.per_file.into_iter().map(|(file, n, first)| {
            format!(
                "{}: {n} message{} whose zstd payload does not decompress skipped (first: {first})",
                file.display(),
                if n == 1 { "" } else { "s" }
            )
        })
    }
}

/// `m` as delivered: with its payload decompressed into `scratch` when the bag compresses each
/// message (`compressed`); `None` (counted in `skipped` for `file`) when it does not decompress.
fn inflated<'a>(
    m: MessageRef<'a>,
    compressed: bool,
    scratch: &'a mut Vec<u8>,
    file: &Path,
    skipped: &mut Skipped,
) -> Option<MessageRef<'a>> {
    if !compressed {
        return Some(m);
    }
    if let Err(e) = decompress_message(m.data, scratch) {
        let first = || format!("topic {}, {}: {e}", m.channel.topic, m.location());
        skipped.add(file, first);
        return None;
    }
    Some(MessageRef { data: scratch, ..m })
}

/// Combine the infos of consecutive split files into one.
fn merge_infos(path: &Path, format: &str, infos: Vec<SessionInfo>) -> SessionInfo {
    let stats = infos.iter().flat_map(|i| &i.topics).map(|t| {
        let mut s = TopicStat::default();
        s.add(t.first_ns, t.count);
        s.add(t.last_ns, 0);
        let [topic, type_name, encoding] =
            [&t.topic, &t.type_name, &t.encoding].map(String::as_str);
        (topic, type_name, encoding, s)
    });
    let topics = by_topic(stats);
    let warnings = infos.into_iter().flat_map(|i| i.warnings).collect();
    session_info(path, format, topics, warnings)
}

/// rosbag2 compression of the storage files.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Compression {
    None,
    /// Each storage file is one zstd stream (`x.db3.zstd`).
    FileZstd,
    /// Each message payload is one zstd frame.
    MessageZstd,
}

impl Compression {
    fn from_metadata(meta: &BagMetadata, yaml_path: &Path) -> Result<Compression, ReadError> {
        let mode = meta.compression_mode.to_ascii_lowercase();
        let format = meta.compression_format.to_ascii_lowercase();
        if mode.is_empty() || mode == "none" {
            return Ok(Compression::None);
        }
        if format != "zstd" {
            return Err(ReadError::format(
                yaml_path,
                0,
                format!("unsupported rosbag2 compression format {format:?} (supported: zstd)"),
            ));
        }
        match mode.as_str() {
            "file" => Ok(Compression::FileZstd),
            "message" => Ok(Compression::MessageZstd),
            other => Err(ReadError::format(
                yaml_path,
                0,
                format!(
                    "unsupported rosbag2 compression mode {other:?} (supported: file, message)"
                ),
            )),
        }
    }
}

fn sql_error(path: &Path, e: rusqlite::Error) -> ReadError {
    ReadError::Other(format!("{}: sqlite: {e}", path.display()))
}

/// Open a database strictly read-only: the `immutable` URI flag also keeps sqlite from
/// creating journal files beside it or taking locks.
fn open_db(path: &Path) -> Result<Connection, ReadError> {
    let abs = std::path::absolute(path).map_err(ReadError::io(path))?;
    let mut uri = String::from("file:");
    for b in abs.to_string_lossy().bytes() {
        match b {
            b'a'..=b'z' | b'A'..=b'Z' | b'0'..=b'9' | b'/' | b'-' | b'_' | b'.' | b'~' => {
                uri.push(b as char)
            }
            _ => uri.push_str(&format!("%{b:02X}")),
        }
    }
    uri.push_str("?immutable=1");
    let conn = Connection::open_with_flags(
        &uri,
        OpenFlags::SQLITE_OPEN_READ_ONLY
            | OpenFlags::SQLITE_OPEN_URI
            | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(|e| sql_error(path, e))?;
    if truncation(path).is_some() {
        // sqlite refuses a file shorter than its header says outright; with this (read-only)
        // flag it reads the pages that are there and reports the missing ones when reached.
        conn.execute_batch("PRAGMA writable_schema = ON")
            .map_err(|e| sql_error(path, e))?;
    }
    Ok(conn)
}

/// For a database file shorter than its header says (a truncated copy, a recorder that died):
/// a warning with how many pages are present.
fn truncation(path: &Path) -> Option<String> {
    let mut header = [0u8; 100];
    let mut file = std::fs::File::open(path).ok()?;
    std::io::Read::read_exact(&mut file, &mut header).ok()?;
    let len = file.metadata().ok()?.len();
    let page_size = match u16::from_be_bytes([header[16], header[17]]) {
        1 => 65536,
        n => u64::from(n),
    };
    let pages = u64::from(u32::from_be_bytes(header[28..32].try_into().ok()?));
    (page_size > 0 && pages * page_size > len).then(|| {
        format!(
            "{}: database truncated: {} of its {pages} pages present; messages are read up to the damage",
            path.display(),
            len / page_size
        )
    })
}

fn has_table(conn: &Connection, table: &str) -> rusqlite::Result<bool> {
    conn.query_row(
        "SELECT count(*) FROM sqlite_master WHERE type = 'table' AND name = ?1",
        [table],
        |r| r.get::<_, i64>(0),
    )
    .map(|n| n > 0)
}

impl SqliteBag {
    fn open(
        bag: &Path,
        files: Vec<PathBuf>,
        compression: Compression,
        opts: &OpenOptions,
    ) -> Result<SqliteBag, ReadError> {
        let scratch = scratch_dir(compression)?;
        let mut topics: Vec<BagTopic> = Vec::new();
        let mut db_files = Vec::with_capacity(files.len());
        let mut notes = Vec::new();
        for (index, path) in files.into_iter().enumerate() {
            let db_path = match &scratch {
                Some(dir) => decompress_file(&path, &dir.path().join(format!("{index}.db3")))?,
                None => path.clone(),
            };
            let conn = open_db(&db_path)?;
            notes.extend(
                truncation(&db_path).map(|w| {
                    w.replace(&db_path.display().to_string(), &path.display().to_string())
                }),
            );
            let topic_ids = read_topics(&conn, &path, &mut topics, opts, &mut notes)?;
            db_files.push(DbFile {
                path,
                db_path,
                topic_ids,
            });
        }
        Ok(SqliteBag {
            bag: bag.to_path_buf(),
            files: db_files,
            topics,
            message_compression: compression == Compression::MessageZstd,
            _scratch: scratch,
            notes,
        })
    }

    fn info(&mut self) -> Result<SessionInfo, ReadError> {
        let mut stats = vec![TopicStat::default(); self.topics.len()];
        let mut notes = self.notes.clone();
        for f in &self.files {
            let conn = open_db(&f.db_path)?;
            let rows = match topic_counts(&conn) {
                Ok(rows) => rows,
                Err(e) => {
                    notes.push(format!(
                        "{}: database damaged (sqlite: {e}); its messages are not counted",
                        f.path.display()
                    ));
                    continue;
                }
            };
            for (id, n, first, last) in rows {
                let Some(&t) = f.topic_ids.get(&id) else {
                    notes.push(format!(
                        "{}: {n} messages on topic id {id}, which is not in the topics table, are not listed",
                        f.path.display()
                    ));
                    continue;
                };
                stats[t].add(first.max(0) as u64, n.max(0) as u64);
                stats[t].add(last.max(0) as u64, 0);
            }
        }
        let mut warnings = Vec::new();
        let topics = (self.topics.iter().zip(stats))
            .map(|(t, s)| {
                if let Err(e) = &t.channel {
                    warnings.push(e.clone());
                }
                s.info(&t.name, &t.type_name, "cdr")
            })
            .collect();
        warnings.extend(notes);
        Ok(session_info(&self.bag, "ros2-sqlite3", topics, warnings))
    }

    fn read(
        &mut self,
        wanted: Option<&[&str]>,
        visit: &mut dyn FnMut(MessageRef<'_>) -> Result<(), ReadError>,
    ) -> Result<ReadSummary, ReadError> {
        let mut summary = ReadSummary::starting(&self.notes, self.notes.is_empty());
        let topics = self.topics.iter().map(|t| (t.name.as_str(), &t.channel));
        let selected = select_topics(topics, wanted, &mut summary.warnings)?;
        let conns = self
            .files
            .iter()
            .map(|f| open_db(&f.db_path))
            .collect::<Result<Vec<_>, _>>()?;
        // Per file: the time-ordered query, and a rowid-order one for a database too damaged
        // to sort (it then yields the rows up to the damage).
        let mut sorted = Vec::with_capacity(conns.len());
        let mut by_row = Vec::with_capacity(conns.len());
        let mut files = Vec::with_capacity(conns.len());
        for (conn, f) in conns.iter().zip(&self.files) {
            summary.warnings.extend(orphan_rows(conn, f));
            let ids: Vec<String> = f
                .topic_ids
                .iter()
                .filter(|&(_, &t)| selected[t])
                .map(|(id, _)| id.to_string())
                .collect();
            if ids.is_empty() {
                continue;
            }
            let sql = format!(
                "SELECT topic_id, timestamp, data, id FROM messages WHERE topic_id IN ({})",
                ids.join(",")
            );
            // Ties in time keep insertion (rowid) order, which the timestamp index also gives.
            let prepare = |order: &str| conn.prepare(&format!("{sql} ORDER BY {order}"));
            sorted.push(prepare("timestamp, id").map_err(|e| sql_error(&f.path, e))?);
            by_row.push(prepare("id").map_err(|e| sql_error(&f.path, e))?);
            files.push(f);
        }
        let mut streams = Vec::with_capacity(files.len());
        for ((s, r), f) in sorted.iter_mut().zip(by_row.iter_mut()).zip(files) {
            if let Some(stream) = Stream::start(s, r, f, &mut summary) {
                streams.push(stream);
            }
        }
        self.merge(streams, visit, &mut summary)?;
        Ok(summary)
    }

    /// Deliver the rows of every stream in time order (k-way merge: k is the number of split
    /// files, small, so a linear pick beats a heap).
    fn merge(
        &self,
        mut streams: Vec<Stream<'_>>,
        visit: &mut dyn FnMut(MessageRef<'_>) -> Result<(), ReadError>,
        summary: &mut ReadSummary,
    ) -> Result<(), ReadError> {
        let mut scratch = Vec::new();
        let mut skipped = Skipped::default();
        loop {
            let best = streams
                .iter()
                .enumerate()
                .filter_map(|(k, s)| s.cur.map(|c| (c.ts, k)))
                .min();
            let Some((ts, k)) = best else { break };
            let stream = &mut streams[k];
            let Some(cur) = stream.cur else { break };
            let f = stream.file;
            let channel = f
                .topic_ids
                .get(&cur.topic_id)
                .and_then(|&t| self.topics[t].channel.as_ref().ok());
            let data = stream
                .rows
                .get()
                .map(|row| row.get_ref(2).and_then(|v| v.as_blob().map_err(Into::into)));
            match (channel, data) {
                (Some(channel), Some(Ok(data))) => {
                    let time = ts.max(0) as u64;
                    let m = MessageRef {
                        channel,
                        log_time_ns: time,
                        data,
                        file_offset: cur.rowid.max(0) as u64,
                        row_id: true,
                    };
                    let compressed = self.message_compression;
                    if let Some(m) = inflated(m, compressed, &mut scratch, &f.path, &mut skipped) {
                        visit(m)?;
                        summary.messages += 1;
                    }
                }
                (_, Some(Err(e))) => {
                    stream.damaged(&e, summary);
                    continue;
                }
                _ => {}
            }
            stream.advance(summary);
        }
        summary.warnings.extend(skipped.warnings());
        Ok(())
    }
}

/// The current row of a stream: topic id, timestamp, row id.
#[derive(Debug, Clone, Copy)]
struct RowHead {
    topic_id: i64,
    ts: i64,
    rowid: i64,
}

/// The rows of one storage file, one at a time; damage ends the stream with a warning.
struct Stream<'s> {
    rows: rusqlite::Rows<'s>,
    file: &'s DbFile,
    cur: Option<RowHead>,
}

impl<'s> Stream<'s> {
    /// Run the time-ordered query; when the database is too damaged for it, the rowid-order
    /// one (rows up to the damage, with a warning).
    fn start(
        sorted: &'s mut rusqlite::Statement<'_>,
        by_row: &'s mut rusqlite::Statement<'_>,
        file: &'s DbFile,
        summary: &mut ReadSummary,
    ) -> Option<Stream<'s>> {
        let first = |stmt: &'s mut rusqlite::Statement<'_>| {
            let mut rows = stmt.query([])?;
            rows.advance()?;
            let cur = rows.get().map(RowHead::of).transpose()?;
            Ok::<_, rusqlite::Error>(Stream { rows, file, cur })
        };
        match first(sorted) {
            Ok(s) => Some(s),
            Err(e) => {
                summary.complete = false;
                summary.warnings.push(format!(
                    "{}: database damaged (sqlite: {e}); its messages are read in row order up to the damage",
                    file.path.display()
                ));
                match first(by_row) {
                    Ok(s) => Some(s),
                    Err(e) => {
                        summary.warnings.push(format!(
                            "{}: no message of this file is readable (sqlite: {e})",
                            file.path.display()
                        ));
                        None
                    }
                }
            }
        }
    }

    fn advance(&mut self, summary: &mut ReadSummary) {
        let step = self
            .rows
            .advance()
            .and_then(|()| self.rows.get().map(RowHead::of).transpose());
        match step {
            Ok(cur) => self.cur = cur,
            Err(e) => self.damaged(&e, summary),
        }
    }

    fn damaged(&mut self, e: &rusqlite::Error, summary: &mut ReadSummary) {
        summary.complete = false;
        summary.warnings.push(format!(
            "{}: database damaged after message row id {} (sqlite: {e}); the rest of this file is not read",
            self.file.path.display(),
            self.cur.map_or(0, |c| c.rowid)
        ));
        self.cur = None;
    }
}

impl RowHead {
    fn of(row: &rusqlite::Row<'_>) -> rusqlite::Result<RowHead> {
        Ok(RowHead {
            topic_id: row.get(0)?,
            ts: row.get(1)?,
            rowid: row.get(3)?,
        })
    }
}

/// (topic id, count, first, last timestamp) per topic id of one database.
fn topic_counts(conn: &Connection) -> rusqlite::Result<Vec<(i64, i64, i64, i64)>> {
    conn.prepare(
        "SELECT topic_id, count(*), min(timestamp), max(timestamp) FROM messages GROUP BY topic_id",
    )?
    .query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?)))?
    .collect()
}

/// Warnings for messages whose topic id is not in the file's topics table (never delivered).
fn orphan_rows(conn: &Connection, f: &DbFile) -> Vec<String> {
    let known: Vec<String> = f.topic_ids.keys().map(i64::to_string).collect();
    let sql = format!(
        "SELECT topic_id, count(*), min(id) FROM messages WHERE topic_id NOT IN ({}) GROUP BY topic_id",
        known.join(",")
    );
    let rows = conn.prepare(&sql).and_then(|mut stmt| {
        stmt.query_map([], |r| {
            Ok((
                r.get::<_, i64>(0)?,
                r.get::<_, i64>(1)?,
                r.get::<_, i64>(2)?,
            ))
        })?
        .collect::<Result<Vec<_>, _>>()
    });
    match rows {
        Ok(rows) => rows
            .into_iter()
            .map(|(id, n, first)| {
                format!(
                    "{}: {n} messages on topic id {id}, which is not in the topics table, were skipped (first at message row id {first})",
                    f.path.display()
                )
            })
            .collect(),
        Err(_) => Vec::new(), // a damaged table: reported by the read itself
    }
}

/// Refuse a database that is not rosbag2's (no `topics`/`messages` tables) or comes from a
/// pre-release rosbag2 (2018, topics without `serialization_format`) with a clear message.
fn check_layout(conn: &Connection, path: &Path) -> Result<(), ReadError> {
    let columns = |table: &str| -> rusqlite::Result<Vec<String>> {
        conn.prepare(&format!("PRAGMA table_info({table})"))?
            .query_map([], |r| r.get::<_, String>(1))?
            .collect()
    };
    let sql_err = |e| {
        ReadError::Other(format!(
            "{}: database damaged: the layout of its tables (sqlite_master) is unreadable (sqlite: {e})",
            path.display()
        ))
    };
    let topics = columns("topics").map_err(sql_err)?;
    let messages = columns("messages").map_err(sql_err)?;
    let has = |cols: &[String], names: &[&str]| names.iter().all(|n| cols.iter().any(|c| c == n));
    if topics.is_empty() || messages.is_empty() {
        return Err(ReadError::Other(format!(
            "{}: not a rosbag2 database (no topics or messages table)",
            path.display()
        )));
    }
    if !has(&topics, &["id", "name", "type", "serialization_format"])
        || !has(&messages, &["id", "topic_id", "timestamp", "data"])
    {
        return Err(ReadError::Other(format!(
            "{}: a pre-release (2018) rosbag2 database (topics: {}; messages: {}), which is not \
             supported; re-record it or convert it with a current rosbag2",
            path.display(),
            topics.join(", "),
            messages.join(", ")
        )));
    }
    Ok(())
}

/// Register the topics of one storage file in `topics` (by name) and resolve their definitions.
/// A damaged `topics` table gives the topics read before the damage (messages on the others are
/// then skipped with a warning) plus a note, or a clear error when not one topic is readable; a
/// damaged `message_definitions` table is a note (definitions then come from `--msg-path` or the
/// built-in ones).
fn read_topics(
    conn: &Connection,
    path: &Path,
    topics: &mut Vec<BagTopic>,
    opts: &OpenOptions,
    notes: &mut Vec<String>,
) -> Result<HashMap<i64, usize>, ReadError> {
    check_layout(conn, path)?;
    let definitions = read_definitions(conn, path, notes);
    let mut ids = HashMap::new();
    let damaged = |what: String, e: rusqlite::Error| {
        format!(
            "{}: table topics damaged {what} (sqlite: {e})",
            path.display()
        )
    };
    let rows = conn
        .prepare("SELECT id, name, type, serialization_format FROM topics ORDER BY id")
        .and_then(|mut stmt| {
            let mut rows = stmt.query([])?;
            let mut out = Vec::new();
            loop {
                match rows.next() {
                    Ok(Some(row)) => out.push(topic_row(row)),
                    Ok(None) => return Ok((out, None)),
                    Err(e) if out.is_empty() => return Err(e),
                    Err(e) => return Ok((out, Some(e))),
                }
            }
        });
    let (rows, tail) = match rows {
        Ok(r) => r,
        Err(e) => {
            return Err(ReadError::Other(format!(
                "{}; no topic is readable, so no message can be assigned to one",
                damaged("at its first row".into(), e)
            )));
        }
    };
    if let Some(e) = tail {
        let last = rows.iter().rev().find_map(|r| r.as_ref().ok().map(|r| r.0));
        notes.push(format!(
            "{}; messages on topics after it are skipped",
            damaged(format!("after topic id {}", last.unwrap_or(0)), e)
        ));
    }
    for (k, row) in rows.into_iter().enumerate() {
        let (id, name, type_name, format) = match row {
            Ok(r) => r,
            Err(e) => {
                notes.push(format!(
                    "{}; that topic's messages are skipped",
                    damaged(format!("at its row {}", k + 1), e)
                ));
                continue;
            }
        };
        if let Some(i) = topics.iter().position(|t| t.name == name) {
            if topics[i].type_name != type_name {
                return Err(ReadError::Other(format!(
                    "{}: topic {name} has type {type_name} here but {} in an earlier file of the bag",
                    path.display(),
                    topics[i].type_name
                )));
            }
            ids.insert(id, i);
            continue;
        }
        let channel = topic_channel(path, (&name, &type_name, &format), &definitions, opts);
        ids.insert(id, topics.len());
        topics.push(BagTopic {
            name,
            type_name,
            channel,
        });
    }
    Ok(ids)
}

/// One row of the `topics` table: id, name, type, serialization format.
type TopicRow = (i64, String, String, String);

fn topic_row(row: &rusqlite::Row<'_>) -> rusqlite::Result<TopicRow> {
    Ok((row.get(0)?, row.get(1)?, row.get(2)?, row.get(3)?))
}

/// The `message_definitions` table (type → encoding, text), if the database has one; damage
/// ends it with a note.
fn read_definitions(
    conn: &Connection,
    path: &Path,
    notes: &mut Vec<String>,
) -> HashMap<String, (String, String)> {
    let mut definitions = HashMap::new();
    let read = |definitions: &mut HashMap<String, (String, String)>| -> rusqlite::Result<()> {
        if !has_table(conn, "message_definitions")? {
            return Ok(());
        }
        let mut stmt = conn.prepare(
            "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions",
        )?;
        let mut rows = stmt.query([])?;
        while let Some(row) = rows.next()? {
            definitions.insert(row.get(0)?, (row.get(1)?, row.get(2)?));
        }
        Ok(())
    };
    if let Err(e) = read(&mut definitions) {
        notes.push(format!(
            "{}: table message_definitions damaged after {} definitions (sqlite: {e}); the other \
             types' definitions come from --msg-path or the built-in ones",
            path.display(),
            definitions.len()
        ));
    }
    definitions
}

/// The channel of a new topic, or why it cannot be decoded (reported when it is read).
fn topic_channel(
    path: &Path,
    (name, type_name, format): (&str, &str, &str),
    definitions: &HashMap<String, (String, String)>,
    opts: &OpenOptions,
) -> Result<Arc<Channel>, String> {
    if format != "cdr" {
        return Err(format!(
            "{}: topic {name}: unsupported serialization format {format:?} (supported: cdr)",
            path.display()
        ));
    }
    // rosbag2 stores encoding "unknown" with an empty text when it had no definition.
    let embedded = definitions
        .get(type_name)
        .filter(|(_, text)| !text.trim().is_empty())
        .and_then(|(encoding, text)| match encoding.as_str() {
            "ros2msg" => Some(MsgSchema::parse_ros2msg(type_name, text)),
            "ros2idl" => Some(MsgSchema::parse_idl(type_name, text)),
            _ => None,
        });
    super::resolve_schema(path, name, type_name, embedded, opts)
        .map(|schema| Channel::new(name, type_name, Encoding::Cdr, schema))
}

/// Largest inflation accepted for a `compression_mode: FILE` storage file: its decompressed
/// scratch copy may be at most this many times its compressed size, plus [`FILE_SLACK_BYTES`].
const MAX_FILE_RATIO: u64 = 100;
/// See [`MAX_FILE_RATIO`].
const FILE_SLACK_BYTES: u64 = 64 << 20;
/// Largest message accepted from rosbag2 message compression (or its declared size if smaller).
const MAX_MESSAGE_BYTES: u64 = 64 << 20;

/// Decompress a `compression_mode: FILE` storage file (one zstd stream) to `out`, refusing to
/// write more than [`MAX_FILE_RATIO`] × its size (+ [`FILE_SLACK_BYTES`]) of scratch file.
fn decompress_file(path: &Path, out: &Path) -> Result<PathBuf, ReadError> {
    let input = std::fs::File::open(path).map_err(ReadError::io(path))?;
    let compressed = input.metadata().map_err(ReadError::io(path))?.len();
    let cap = compressed
        .saturating_mul(MAX_FILE_RATIO)
        .saturating_add(FILE_SLACK_BYTES);
    let output = std::fs::File::create(out).map_err(ReadError::io(out))?;
    let mut writer = std::io::BufWriter::new(output);
    let bad = |e: std::io::Error| {
        ReadError::Other(format!(
            "{}: zstd-compressed storage file does not decompress: {e}",
            path.display()
        ))
    };
    let decoder = zstd::stream::read::Decoder::new(input).map_err(bad)?;
    // Write at most `cap` bytes, then ask the stream for one more: the scratch file never
    // holds a byte past the bound.
    let mut limited = std::io::Read::take(decoder, cap);
    std::io::copy(&mut limited, &mut writer).map_err(bad)?;
    let more = std::io::Read::read(&mut limited.into_inner(), &mut [0u8; 1]).map_err(bad)? > 0;
    if more {
        return Err(ReadError::Other(format!(
            "{}: zstd-compressed storage file inflates to more than {cap} bytes ({MAX_FILE_RATIO} × its \
             {compressed} bytes + {} MiB): refused as a decompression bomb",
            path.display(),
            FILE_SLACK_BYTES >> 20
        )));
    }
    std::io::Write::flush(&mut writer).map_err(ReadError::io(out))?;
    Ok(out.to_path_buf())
}

/// Decompress one zstd-compressed message payload into `out`, capped at its declared content
/// size (when the frame states one) and at [`MAX_MESSAGE_BYTES`].
fn decompress_message(data: &[u8], out: &mut Vec<u8>) -> Result<(), String> {
    let declared = zstd::zstd_safe::get_frame_content_size(data).ok().flatten();
    let limit = declared.unwrap_or(MAX_MESSAGE_BYTES).min(MAX_MESSAGE_BYTES);
    out.clear();
    let decoder = zstd::stream::read::Decoder::with_buffer(data)
        .map_err(|e| format!("zstd payload does not decompress: {e}"))?;
    super::read_capped(decoder, limit as usize, out)
        .map_err(|e| format!("zstd payload does not decompress: {e}"))?;
    if out.len() as u64 > limit {
        return Err(format!(
            "zstd payload inflates to more than {limit} bytes ({}): refused as a decompression bomb",
            if declared.is_some_and(|d| d <= MAX_MESSAGE_BYTES) {
                "its declared size"
            } else {
                "the per-message limit"
            }
        ));
    }
    if declared.is_some_and(|d| d != out.len() as u64) {
        return Err(format!(
            "zstd payload decompresses to {} bytes, its frame header says {}",
            out.len(),
            declared.unwrap_or(0)
        ));
    }
    Ok(())
}

/// The MCAP storage of a rosbag2 bag: one reader per split file; with `compression_mode: FILE`
/// each file is first decompressed to a scratch folder (removed when the bag is dropped).
fn open_mcap_storage(
    dir: &Path,
    files: &[PathBuf],
    compression: Compression,
    opts: &OpenOptions,
) -> Result<Inner, ReadError> {
    let scratch = scratch_dir(compression)?;
    let mut sources = Vec::with_capacity(files.len());
    for (index, f) in files.iter().enumerate() {
        let source = match &scratch {
            Some(tmp) => {
                let copy = decompress_file(f, &tmp.path().join(format!("{index}.mcap")))?;
                let file = std::fs::File::open(&copy).map_err(ReadError::io(&copy))?;
                McapSource::from_reader(file, f, opts)?
            }
            None => McapSource::open(f, opts)?,
        };
        sources.push(source);
    }
    Ok(Inner::Mcap {
        bag: dir.to_path_buf(),
        files: sources,
        message_zstd: compression == Compression::MessageZstd,
        _scratch: scratch,
    })
}

/// A scratch folder for decompressed copies when the bag compresses whole files.
fn scratch_dir(compression: Compression) -> Result<Option<Scratch>, ReadError> {
    if compression != Compression::FileZstd {
        return Ok(None);
    }
    let dir = tempfile::tempdir().map_err(ReadError::io(&std::env::temp_dir()))?;
    let guard = crate::util::temp::TempPath::register(dir.path().to_path_buf());
    Ok(Some(Scratch { dir, _guard: guard }))
}

/// A scratch folder, also registered for removal on a termination signal.
struct Scratch {
    dir: tempfile::TempDir,
    _guard: crate::util::temp::TempPath,
}

impl Scratch {
    fn path(&self) -> &Path {
        self.dir.path()
    }
}

/// The fields of `metadata.yaml` the reader needs (rosbag2 metadata versions 1–9); a missing or
/// null field reads as empty.
#[derive(Debug, Clone, Default, PartialEq, serde::Deserialize)]
#[serde(default)]
struct BagMetadata {
    version: Option<u32>,
    #[serde(deserialize_with = "null_as_empty")]
    storage_identifier: String,
    #[serde(deserialize_with = "null_as_empty")]
    relative_file_paths: Vec<String>,
    #[serde(deserialize_with = "null_as_empty")]
    compression_format: String,
    #[serde(deserialize_with = "null_as_empty")]
    compression_mode: String,
}

fn null_as_empty<'de, D, T>(d: D) -> Result<T, D::Error>
where
    D: serde::Deserializer<'de>,
    T: Default + serde::Deserialize<'de>,
{
    Ok(<Option<T> as serde::Deserialize>::deserialize(d)?.unwrap_or_default())
}

impl BagMetadata {
    /// Parse the text of `metadata.yaml`; errors name the field and line.
    fn parse(text: &str) -> Result<BagMetadata, String> {
        #[derive(serde::Deserialize)]
        struct File {
            rosbag2_bagfile_information: Option<BagMetadata>,
        }
        // libyaml's scanner takes time quadratic in the nesting depth of flow collections (a
        // 250 kB file nested 50,000 deep: 36 s); no rosbag2 writer nests them.
        const MAX_FLOW_DEPTH: i64 = 64;
        let mut depth = 0i64;
        if text.bytes().any(|b| {
            depth += match b {
                b'[' | b'{' => 1,
                b']' | b'}' => -1,
                _ => 0,
            };
            depth > MAX_FLOW_DEPTH
        }) {
            return Err(format!(
                "flow collections ([ or {{) nested more than {MAX_FLOW_DEPTH} levels deep"
            ));
        }
        let file: File = serde_yaml_ng::from_str(text).map_err(|e| e.to_string())?;
        let meta = file
            .rosbag2_bagfile_information
            .ok_or("no rosbag2_bagfile_information section")?;
        match meta.version {
            None => Err("no version: a pre-release (2018) rosbag2 bag or not \
                         rosbag2 metadata; supported: rosbag2 metadata versions 1 to 9"
                .into()),
            Some(v) if !(1..=9).contains(&v) => Err(format!(
                "rosbag2 metadata version {v} is not supported (supported: up to 9)"
            )),
            Some(_) => Ok(meta),
        }
    }
}
