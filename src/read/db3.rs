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

use super::msgdef::{self, MsgSchema, SchemaError};
use super::{
    Channel, Encoding, MessageRef, MessageSource, OpenOptions, ReadError, ReadSummary, SessionInfo,
    TopicInfo,
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
        files: Vec<super::mcap::McapSource>,
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
    _scratch: Option<tempfile::TempDir>,
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
        let text = crate::util::read_text_input(&yaml_path).map_err(|source| ReadError::Io {
            path: yaml_path.clone(),
            source,
        })?;
        let meta = BagMetadata::parse(&text).map_err(|what| ReadError::Format {
            path: yaml_path.clone(),
            offset: 0,
            what,
        })?;
        if meta.relative_file_paths.is_empty() {
            return Err(ReadError::Format {
                path: yaml_path,
                offset: 0,
                what: "metadata.yaml lists no storage files (relative_file_paths is empty)".into(),
            });
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
            "mcap" => {
                if compression != Compression::None {
                    return Err(ReadError::Other(format!(
                        "{}: rosbag2 compression of MCAP storage is not supported (MCAP compresses its own chunks)",
                        yaml_path.display()
                    )));
                }
                let files = files
                    .iter()
                    .map(|f| super::mcap::McapSource::open(f, opts))
                    .collect::<Result<Vec<_>, _>>()?;
                Ok(Ros2BagSource {
                    inner: Inner::Mcap { bag: dir, files },
                })
            }
            other => Err(ReadError::Format {
                path: yaml_path,
                offset: 0,
                what: format!("unsupported rosbag2 storage {other:?} (supported: sqlite3, mcap)"),
            }),
        }
    }
}

impl Ros2BagSource {
    /// A bag folder without `metadata.yaml` (lost, or a recorder that died): its `.db3` files
    /// in name order, which is rosbag2's split order (`name_0.db3`, `name_1.db3`, …).
    fn open_without_metadata(dir: &Path, opts: &OpenOptions) -> Result<Ros2BagSource, ReadError> {
        let io = |source| ReadError::Io {
            path: dir.to_path_buf(),
            source,
        };
        let mut files = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(io)? {
            let path = entry.map_err(io)?.path();
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
    fn format(&self) -> &'static str {
        match &self.inner {
            Inner::Sqlite(_) => "ros2-sqlite3",
            Inner::Mcap { .. } => "ros2-mcap",
        }
    }

    fn info(&mut self) -> Result<SessionInfo, ReadError> {
        match &mut self.inner {
            Inner::Sqlite(db) => db.info(),
            Inner::Mcap { bag, files } => {
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
            Inner::Mcap { files, .. } => {
                let mut total = ReadSummary {
                    complete: true,
                    ..ReadSummary::default()
                };
                for f in files.iter_mut() {
                    let s = f.read(topics, visit)?;
                    total.messages += s.messages;
                    total.warnings.extend(s.warnings);
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

/// Combine the infos of consecutive split files into one.
fn merge_infos(path: &Path, format: &str, infos: Vec<SessionInfo>) -> SessionInfo {
    let mut by_topic: HashMap<String, TopicInfo> = HashMap::new();
    let mut warnings = Vec::new();
    for info in infos {
        warnings.extend(info.warnings);
        for t in info.topics {
            by_topic
                .entry(t.topic.clone())
                .and_modify(|m| {
                    m.count += t.count;
                    m.first_ns = m.first_ns.min(t.first_ns);
                    m.last_ns = m.last_ns.max(t.last_ns);
                })
                .or_insert(t);
        }
    }
    let mut topics: Vec<TopicInfo> = by_topic.into_values().collect();
    for t in &mut topics {
        t.rate_hz = rate_hz(t.count, t.first_ns, t.last_ns);
    }
    session_info(path, format, topics, warnings)
}

/// Mean rate over a topic's own span, 0 when it has fewer than two messages.
pub(crate) fn rate_hz(count: u64, first_ns: u64, last_ns: u64) -> f64 {
    if count < 2 || last_ns <= first_ns {
        return 0.0;
    }
    (count - 1) as f64 / ((last_ns - first_ns) as f64 * 1e-9)
}

/// Assemble a [`SessionInfo`] from per-topic statistics (sorted by topic name here).
pub(crate) fn session_info(
    path: &Path,
    format: &str,
    mut topics: Vec<TopicInfo>,
    warnings: Vec<String>,
) -> SessionInfo {
    topics.sort_by(|a, b| a.topic.cmp(&b.topic));
    let present = topics.iter().filter(|t| t.count > 0);
    let start_ns = present.clone().map(|t| t.first_ns).min().unwrap_or(0);
    let end_ns = present.map(|t| t.last_ns).max().unwrap_or(0);
    SessionInfo {
        path: path.to_path_buf(),
        format: format.to_string(),
        start_ns,
        end_ns,
        messages: topics.iter().map(|t| t.count).sum(),
        topics,
        warnings,
    }
}

/// The message definition of `type_name` from, in order: the definition the recording carries
/// (`embedded`, parsed with `parse`), `.msg` files on `--msg-path`, the built-in definitions.
/// The error text names the type, the topic and where to put a definition.
pub(crate) fn resolve_schema(
    file: &Path,
    topic: &str,
    type_name: &str,
    embedded: Option<Result<MsgSchema, SchemaError>>,
    opts: &OpenOptions,
) -> Result<MsgSchema, String> {
    match embedded {
        Some(Ok(schema)) => return Ok(schema),
        Some(Err(e)) => {
            return Err(format!(
                "{}: topic {topic}: the message definition of {type_name} stored in the recording is bad: {e}",
                file.display()
            ));
        }
        None => {}
    }
    if !opts.msg_paths.is_empty() {
        match MsgSchema::from_msg_files(type_name, &opts.msg_paths) {
            Ok(schema) => return Ok(schema),
            Err(SchemaError::MissingType(_)) => {}
            Err(e) => {
                return Err(format!(
                    "{}: topic {topic}: definition of {type_name} found on --msg-path is bad: {e}",
                    file.display()
                ));
            }
        }
    }
    let normalised = normalise_type_name(type_name);
    let builtin =
        msgdef::builtin_definition(type_name).or_else(|| msgdef::builtin_definition(&normalised));
    if let Some(text) = builtin {
        return MsgSchema::parse_ros2msg(&normalised, text).map_err(|e| {
            format!(
                "{}: topic {topic}: built-in definition of {type_name}: {e}",
                file.display()
            )
        });
    }
    let (pkg, name) = split_type_name(type_name);
    let searched = if opts.msg_paths.is_empty() {
        "no --msg-path given".to_string()
    } else {
        format!(
            "not found under --msg-path {}",
            opts.msg_paths
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        )
    };
    Err(format!(
        "{}: topic {topic}: no message definition for type {type_name} (the recording does not carry one, \
         {searched}, and it is not built in); put its definition at DIR/{pkg}/msg/{name}.msg \
         (with the .msg files of the types it uses) and pass --msg-path DIR",
        file.display()
    ))
}

/// `pkg/Type` → `pkg/msg/Type`; `pkg/msg/Type` unchanged.
fn normalise_type_name(type_name: &str) -> String {
    let (pkg, name) = split_type_name(type_name);
    format!("{pkg}/msg/{name}")
}

/// Package and bare type name of `pkg/Type` or `pkg/msg/Type`.
fn split_type_name(type_name: &str) -> (&str, &str) {
    let pkg = type_name.split('/').next().unwrap_or(type_name);
    let name = type_name.rsplit('/').next().unwrap_or(type_name);
    (pkg, name)
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
            return Err(ReadError::Format {
                path: yaml_path.to_path_buf(),
                offset: 0,
                what: format!(
                    "unsupported rosbag2 compression format {format:?} (supported: zstd)"
                ),
            });
        }
        match mode.as_str() {
            "file" => Ok(Compression::FileZstd),
            "message" => Ok(Compression::MessageZstd),
            other => Err(ReadError::Format {
                path: yaml_path.to_path_buf(),
                offset: 0,
                what: format!(
                    "unsupported rosbag2 compression mode {other:?} (supported: file, message)"
                ),
            }),
        }
    }
}

fn sql_error(path: &Path, e: rusqlite::Error) -> ReadError {
    ReadError::Other(format!("{}: sqlite: {e}", path.display()))
}

/// Open a database strictly read-only: the `immutable` URI flag also keeps sqlite from
/// creating journal files beside it or taking locks.
fn open_db(path: &Path) -> Result<Connection, ReadError> {
    let abs = std::path::absolute(path).map_err(|source| ReadError::Io {
        path: path.to_path_buf(),
        source,
    })?;
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
    Connection::open_with_flags(
        &uri,
        OpenFlags::SQLITE_OPEN_READ_ONLY
            | OpenFlags::SQLITE_OPEN_URI
            | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(|e| sql_error(path, e))
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
        let scratch = if compression == Compression::FileZstd {
            Some(tempfile::tempdir().map_err(|source| ReadError::Io {
                path: std::env::temp_dir(),
                source,
            })?)
        } else {
            None
        };
        let mut topics: Vec<BagTopic> = Vec::new();
        let mut db_files = Vec::with_capacity(files.len());
        for (index, path) in files.into_iter().enumerate() {
            let db_path = match &scratch {
                Some(dir) => decompress_file(&path, &dir.path().join(format!("{index}.db3")))?,
                None => path.clone(),
            };
            let conn = open_db(&db_path)?;
            let topic_ids = read_topics(&conn, &path, &mut topics, opts)?;
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
        })
    }

    fn info(&mut self) -> Result<SessionInfo, ReadError> {
        let mut stats: Vec<(u64, u64, u64)> = vec![(0, u64::MAX, 0); self.topics.len()];
        for f in &self.files {
            let conn = open_db(&f.db_path)?;
            let mut stmt = conn
                .prepare(
                    "SELECT topic_id, count(*), min(timestamp), max(timestamp) FROM messages GROUP BY topic_id",
                )
                .map_err(|e| sql_error(&f.path, e))?;
            let mut rows = stmt.query([]).map_err(|e| sql_error(&f.path, e))?;
            while let Some(row) = rows.next().map_err(|e| sql_error(&f.path, e))? {
                let id: i64 = row.get(0).map_err(|e| sql_error(&f.path, e))?;
                let n: i64 = row.get(1).map_err(|e| sql_error(&f.path, e))?;
                let first: i64 = row.get(2).map_err(|e| sql_error(&f.path, e))?;
                let last: i64 = row.get(3).map_err(|e| sql_error(&f.path, e))?;
                let Some(&t) = f.topic_ids.get(&id) else {
                    continue;
                };
                let s = &mut stats[t];
                s.0 += n.max(0) as u64;
                s.1 = s.1.min(first.max(0) as u64);
                s.2 = s.2.max(last.max(0) as u64);
            }
        }
        let mut warnings = Vec::new();
        let topics = self
            .topics
            .iter()
            .zip(stats)
            .map(|(t, (count, first, last))| {
                let first = if count == 0 { 0 } else { first };
                if let Err(e) = &t.channel {
                    warnings.push(e.clone());
                }
                TopicInfo {
                    topic: t.name.clone(),
                    type_name: t.type_name.clone(),
                    encoding: "cdr".into(),
                    count,
                    first_ns: first,
                    last_ns: last,
                    rate_hz: rate_hz(count, first, last),
                }
            })
            .collect();
        Ok(session_info(&self.bag, "ros2-sqlite3", topics, warnings))
    }

    fn read(
        &mut self,
        wanted: Option<&[&str]>,
        visit: &mut dyn FnMut(MessageRef<'_>) -> Result<(), ReadError>,
    ) -> Result<ReadSummary, ReadError> {
        let mut summary = ReadSummary {
            complete: true,
            ..ReadSummary::default()
        };
        // Which topics to deliver; an explicitly requested topic without a definition is an
        // error, one that only comes along with "all topics" is skipped with a warning.
        let mut selected = vec![false; self.topics.len()];
        for (i, t) in self.topics.iter().enumerate() {
            let asked = wanted.is_none_or(|w| w.contains(&t.name.as_str()));
            if !asked {
                continue;
            }
            match &t.channel {
                Ok(_) => selected[i] = true,
                Err(e) if wanted.is_some() => return Err(ReadError::Other(e.clone())),
                Err(e) => summary.warnings.push(format!("{e}; topic skipped")),
            }
        }
        let conns = self
            .files
            .iter()
            .map(|f| open_db(&f.db_path))
            .collect::<Result<Vec<_>, _>>()?;
        let mut stmts = Vec::with_capacity(conns.len());
        for (conn, f) in conns.iter().zip(&self.files) {
            let ids: Vec<String> = f
                .topic_ids
                .iter()
                .filter(|&(_, &t)| selected[t])
                .map(|(id, _)| id.to_string())
                .collect();
            if ids.is_empty() {
                continue;
            }
            // Ties in time keep insertion (rowid) order, which the timestamp index also gives.
            let sql = format!(
                "SELECT topic_id, timestamp, data, id FROM messages WHERE topic_id IN ({}) ORDER BY timestamp, id",
                ids.join(",")
            );
            let stmt = conn.prepare(&sql).map_err(|e| sql_error(&f.path, e))?;
            stmts.push((stmt, f));
        }
        let mut streams = Vec::with_capacity(stmts.len());
        for (stmt, f) in stmts.iter_mut() {
            let mut rows = stmt.query([]).map_err(|e| sql_error(&f.path, e))?;
            rows.advance().map_err(|e| sql_error(&f.path, e))?;
            streams.push((rows, *f));
        }
        let mut scratch = Vec::new();
        loop {
            // k-way merge: the stream whose current row is earliest (k is the number of split
            // files, small, so a linear pick beats a heap).
            let mut best: Option<(usize, i64)> = None;
            for (k, (rows, f)) in streams.iter().enumerate() {
                if let Some(row) = rows.get() {
                    let ts: i64 = row.get(1).map_err(|e| sql_error(&f.path, e))?;
                    if best.is_none_or(|(_, b)| ts < b) {
                        best = Some((k, ts));
                    }
                }
            }
            let Some((k, ts)) = best else { break };
            let (rows, f) = &mut streams[k];
            if let Some(row) = rows.get() {
                let id: i64 = row.get(0).map_err(|e| sql_error(&f.path, e))?;
                let rowid: i64 = row.get(3).map_err(|e| sql_error(&f.path, e))?;
                let data = row
                    .get_ref(2)
                    .and_then(|v| v.as_blob().map_err(Into::into))
                    .map_err(|e| sql_error(&f.path, e))?;
                let channel = f
                    .topic_ids
                    .get(&id)
                    .and_then(|&t| self.topics[t].channel.as_ref().ok());
                if let Some(channel) = channel {
                    let payload = if self.message_compression {
                        scratch.clear();
                        if let Err(e) = zstd::stream::copy_decode(data, &mut scratch) {
                            return Err(ReadError::Other(format!(
                                "{}: topic {}: message row {rowid}: zstd payload does not decompress: {e}",
                                f.path.display(),
                                channel.topic
                            )));
                        }
                        &scratch[..]
                    } else {
                        data
                    };
                    let time = ts.max(0) as u64;
                    visit(MessageRef {
                        channel,
                        log_time_ns: time,
                        publish_time_ns: time,
                        data: payload,
                        file_offset: rowid.max(0) as u64,
                    })?;
                    summary.messages += 1;
                }
            }
            rows.advance().map_err(|e| sql_error(&f.path, e))?;
        }
        Ok(summary)
    }
}

/// Register the topics of one storage file in `topics` (by name) and resolve their definitions.
fn read_topics(
    conn: &Connection,
    path: &Path,
    topics: &mut Vec<BagTopic>,
    opts: &OpenOptions,
) -> Result<HashMap<i64, usize>, ReadError> {
    let sql_err = |e| sql_error(path, e);
    let mut definitions: HashMap<String, (String, String)> = HashMap::new();
    if has_table(conn, "message_definitions").map_err(sql_err)? {
        let mut stmt = conn
            .prepare(
                "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions",
            )
            .map_err(sql_err)?;
        let mut rows = stmt.query([]).map_err(sql_err)?;
        while let Some(row) = rows.next().map_err(sql_err)? {
            let ty: String = row.get(0).map_err(sql_err)?;
            let encoding: String = row.get(1).map_err(sql_err)?;
            let text: String = row.get(2).map_err(sql_err)?;
            definitions.insert(ty, (encoding, text));
        }
    }
    let mut ids = HashMap::new();
    let mut stmt = conn
        .prepare("SELECT id, name, type, serialization_format FROM topics ORDER BY id")
        .map_err(sql_err)?;
    let mut rows = stmt.query([]).map_err(sql_err)?;
    while let Some(row) = rows.next().map_err(sql_err)? {
        let id: i64 = row.get(0).map_err(sql_err)?;
        let name: String = row.get(1).map_err(sql_err)?;
        let type_name: String = row.get(2).map_err(sql_err)?;
        let format: String = row.get(3).map_err(sql_err)?;
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
        let channel = if format != "cdr" {
            Err(format!(
                "{}: topic {name}: unsupported serialization format {format:?} (supported: cdr)",
                path.display()
            ))
        } else {
            // rosbag2 stores encoding "unknown" with an empty text when it had no definition.
            let embedded = definitions
                .get(&type_name)
                .filter(|(_, text)| !text.trim().is_empty())
                .and_then(|(encoding, text)| match encoding.as_str() {
                    "ros2msg" => Some(MsgSchema::parse_ros2msg(&type_name, text)),
                    "ros2idl" => Some(MsgSchema::parse_idl(&type_name, text)),
                    _ => None,
                });
            resolve_schema(path, &name, &type_name, embedded, opts).map(|schema| {
                Arc::new(Channel {
                    topic: name.clone(),
                    type_name: type_name.clone(),
                    encoding: Encoding::Cdr,
                    schema: Arc::new(schema),
                })
            })
        };
        ids.insert(id, topics.len());
        topics.push(BagTopic {
            name,
            type_name,
            channel,
        });
    }
    Ok(ids)
}

/// Decompress a `compression_mode: FILE` storage file (one zstd stream) to `out`.
fn decompress_file(path: &Path, out: &Path) -> Result<PathBuf, ReadError> {
    let input = std::fs::File::open(path).map_err(|source| ReadError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let output = std::fs::File::create(out).map_err(|source| ReadError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    let mut writer = std::io::BufWriter::new(output);
    zstd::stream::copy_decode(std::io::BufReader::new(input), &mut writer).map_err(|e| {
        ReadError::Other(format!(
            "{}: zstd-compressed storage file does not decompress: {e}",
            path.display()
        ))
    })?;
    std::io::Write::flush(&mut writer).map_err(|source| ReadError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    Ok(out.to_path_buf())
}

/// The fields of `metadata.yaml` the reader needs (rosbag2 metadata versions 4–9).
#[derive(Debug, Clone, Default, PartialEq)]
struct BagMetadata {
    version: u32,
    storage_identifier: String,
    relative_file_paths: Vec<String>,
    compression_format: String,
    compression_mode: String,
}

impl BagMetadata {
    fn parse(text: &str) -> Result<BagMetadata, String> {
        let doc = yaml::parse(text)?;
        let info = doc
            .get("rosbag2_bagfile_information")
            .ok_or("metadata.yaml has no rosbag2_bagfile_information section")?;
        let scalar = |key: &str| info.get(key).and_then(yaml::Yaml::as_str).unwrap_or("");
        let version = scalar("version");
        let version: u32 = version
            .parse()
            .map_err(|_| format!("metadata.yaml: version {version:?} is not a number"))?;
        if !(1..=9).contains(&version) {
            return Err(format!(
                "metadata.yaml: rosbag2 metadata version {version} is not supported (supported: up to 9)"
            ));
        }
        let relative_file_paths = match info.get("relative_file_paths") {
            Some(yaml::Yaml::Seq(items)) => items
                .iter()
                .map(|i| i.as_str().map(str::to_string))
                .collect::<Option<Vec<_>>>()
                .ok_or(
                    "metadata.yaml: relative_file_paths holds something other than file names",
                )?,
            _ => Vec::new(),
        };
        Ok(BagMetadata {
            version,
            storage_identifier: scalar("storage_identifier").to_string(),
            relative_file_paths,
            compression_format: scalar("compression_format").to_string(),
            compression_mode: scalar("compression_mode").to_string(),
        })
    }
}

/// The block-style YAML subset rosbag2 (yaml-cpp) and the Python `rosbags` library write:
/// nested mappings and sequences by indentation, plain/quoted/multi-line scalars, block
/// scalars, empty flow collections and flow sequences of scalars.
mod yaml {
    /// A YAML node.
    #[derive(Debug, Clone, PartialEq)]
    pub enum Yaml {
        Null,
        Str(String),
        Seq(Vec<Yaml>),
        Map(Vec<(String, Yaml)>),
    }

    impl Yaml {
        pub fn get(&self, key: &str) -> Option<&Yaml> {
            match self {
                Yaml::Map(entries) => entries.iter().find(|(k, _)| k == key).map(|(_, v)| v),
                _ => None,
            }
        }

        pub fn as_str(&self) -> Option<&str> {
            match self {
                Yaml::Str(s) => Some(s),
                Yaml::Null => Some(""),
                _ => None,
            }
        }
    }

    struct Line {
        indent: usize,
        text: String,
        number: usize,
    }

    pub fn parse(text: &str) -> Result<Yaml, String> {
        let mut lines: Vec<Line> = Vec::new();
        for (n, raw) in text.lines().enumerate() {
            let trimmed = raw.trim_end();
            let content = trimmed.trim_start();
            if content.is_empty() || content.starts_with('#') || content == "---" {
                continue;
            }
            if content == "..." {
                break;
            }
            if raw.starts_with('\t') {
                return Err(format!("metadata.yaml line {}: tab indentation", n + 1));
            }
            lines.push(Line {
                indent: trimmed.len() - content.len(),
                text: content.to_string(),
                number: n + 1,
            });
        }
        let mut i = 0;
        let indent = lines.first().map_or(0, |l| l.indent);
        let node = parse_node(&mut lines, &mut i, indent)?;
        if let Some(l) = lines.get(i) {
            return Err(format!(
                "metadata.yaml line {}: unexpected indentation",
                l.number
            ));
        }
        Ok(node)
    }

    fn parse_node(lines: &mut [Line], i: &mut usize, indent: usize) -> Result<Yaml, String> {
        let Some(line) = lines.get(*i) else {
            return Ok(Yaml::Null);
        };
        if line.indent < indent {
            return Ok(Yaml::Null);
        }
        if is_seq_item(&line.text) {
            parse_seq(lines, i, line.indent)
        } else if split_key(&line.text).is_some() {
            parse_map(lines, i, line.indent)
        } else {
            let first = line.text.clone();
            let parent = line.indent.saturating_sub(1);
            *i += 1;
            scalar(&first, lines, i, parent)
        }
    }

    fn is_seq_item(text: &str) -> bool {
        text == "-" || text.starts_with("- ")
    }

    fn parse_seq(lines: &mut [Line], i: &mut usize, indent: usize) -> Result<Yaml, String> {
        let mut items = Vec::new();
        while let Some(line) = lines.get_mut(*i) {
            if line.indent != indent || !is_seq_item(&line.text) {
                break;
            }
            let rest = line.text[1..].trim_start().to_string();
            if rest.is_empty() {
                *i += 1;
                let child = lines.get(*i).map_or(indent + 1, |l| l.indent);
                items.push(if child > indent {
                    parse_node(lines, i, child)?
                } else {
                    Yaml::Null
                });
            } else {
                // `- key: value` opens a mapping whose keys sit at the column after "- ".
                let column = indent + (line.text.len() - rest.len());
                line.indent = column;
                line.text = rest;
                items.push(parse_node(lines, i, column)?);
            }
        }
        Ok(Yaml::Seq(items))
    }

    fn parse_map(lines: &mut [Line], i: &mut usize, indent: usize) -> Result<Yaml, String> {
        let mut entries = Vec::new();
        while let Some(line) = lines.get(*i) {
            if line.indent != indent {
                if line.indent > indent {
                    return Err(format!(
                        "metadata.yaml line {}: unexpected indentation",
                        line.number
                    ));
                }
                break;
            }
            let Some((key, rest)) = split_key(&line.text) else {
                return Err(format!(
                    "metadata.yaml line {}: expected `key: value`",
                    line.number
                ));
            };
            *i += 1;
            let value = if rest.is_empty() {
                match lines.get(*i) {
                    Some(next) if next.indent > indent => {
                        let child = next.indent;
                        parse_node(lines, i, child)?
                    }
                    // A sequence may sit at the same indentation as its key.
                    Some(next) if next.indent == indent && is_seq_item(&next.text) => {
                        parse_seq(lines, i, indent)?
                    }
                    _ => Yaml::Null,
                }
            } else {
                scalar(&rest, lines, i, indent)?
            };
            entries.push((key, value));
        }
        Ok(Yaml::Map(entries))
    }

    /// `key: rest` (key possibly quoted) or `key:` at the end of the line.
    fn split_key(text: &str) -> Option<(String, String)> {
        let (key, after) = if let Some(q @ ('"' | '\'')) = text.chars().next() {
            let end = text[1..].find(q)? + 1;
            (text[1..end].to_string(), &text[end + 1..])
        } else {
            let pos = text
                .find(": ")
                .or_else(|| text.ends_with(':').then(|| text.len() - 1))?;
            if text.starts_with(['[', '{']) {
                return None;
            }
            (text[..pos].trim_end().to_string(), &text[pos..])
        };
        let rest = after.strip_prefix(':')?;
        if !(rest.is_empty() || rest.starts_with(' ')) {
            return None;
        }
        Some((key, strip_comment(rest.trim()).to_string()))
    }

    fn strip_comment(text: &str) -> &str {
        if text.starts_with(['"', '\'']) {
            return text;
        }
        match text.find(" #") {
            Some(p) => text[..p].trim_end(),
            None => text,
        }
    }

    /// A scalar starting with `first`, continued on following lines indented deeper than `parent`.
    fn scalar(first: &str, lines: &[Line], i: &mut usize, parent: usize) -> Result<Yaml, String> {
        let mut text = first.to_string();
        let block = text.starts_with('|') || text.starts_with('>');
        let mut continuation = Vec::new();
        while let Some(l) = lines.get(*i) {
            if l.indent <= parent {
                break;
            }
            continuation.push(l.text.as_str());
            *i += 1;
        }
        if block {
            let sep = if text.starts_with('|') { "\n" } else { " " };
            return Ok(Yaml::Str(continuation.join(sep)));
        }
        for c in continuation {
            text.push(' ');
            text.push_str(c);
        }
        let text = text.trim();
        Ok(match text {
            "~" | "null" | "Null" | "NULL" => Yaml::Null,
            "[]" => Yaml::Seq(Vec::new()),
            "{}" => Yaml::Map(Vec::new()),
            _ if text.starts_with('"') => Yaml::Str(double_quoted(text)?),
            _ if text.starts_with('\'') => Yaml::Str(
                text.strip_prefix('\'')
                    .and_then(|t| t.strip_suffix('\''))
                    .ok_or_else(|| format!("unterminated quoted string {text}"))?
                    .replace("''", "'"),
            ),
            _ if text.starts_with('[') && text.ends_with(']') => Yaml::Seq(
                text[1..text.len() - 1]
                    .split(',')
                    .map(|s| Yaml::Str(s.trim().trim_matches(['"', '\'']).to_string()))
                    .collect(),
            ),
            _ => Yaml::Str(text.to_string()),
        })
    }

    fn double_quoted(text: &str) -> Result<String, String> {
        let body = text
            .strip_prefix('"')
            .and_then(|t| t.strip_suffix('"'))
            .ok_or_else(|| format!("unterminated quoted string {text}"))?;
        let mut out = String::with_capacity(body.len());
        let mut chars = body.chars();
        while let Some(c) = chars.next() {
            if c != '\\' {
                out.push(c);
                continue;
            }
            match chars.next() {
                Some('n') => out.push('\n'),
                Some('t') => out.push('\t'),
                Some('r') => out.push('\r'),
                Some('0') => out.push('\0'),
                Some(' ') | None => {}
                Some(other) => out.push(other),
            }
        }
        Ok(out)
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        #[test]
        fn yaml_cpp_style_v5_metadata() {
            let text = "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: sqlite3\n  \
                relative_file_paths:\n    - a_0.db3\n    - a_1.db3\n  duration:\n    nanoseconds: 10\n  \
                topics_with_message_count:\n    - topic_metadata:\n        name: /chatter\n        \
                type: std_msgs/msg/String\n        offered_qos_profiles: \"- history: 3\\n  depth: 0\"\n      \
                message_count: 100\n  compression_format: \"\"\n  compression_mode: \"\"\n  custom_data: ~\n";
            let doc = parse(text).unwrap();
            let info = doc.get("rosbag2_bagfile_information").unwrap();
            assert_eq!(info.get("version"), Some(&Yaml::Str("5".into())));
            assert_eq!(
                info.get("relative_file_paths"),
                Some(&Yaml::Seq(vec![
                    Yaml::Str("a_0.db3".into()),
                    Yaml::Str("a_1.db3".into())
                ]))
            );
            let Some(Yaml::Seq(topics)) = info.get("topics_with_message_count") else {
                panic!("no topics")
            };
            let meta = topics[0].get("topic_metadata").unwrap();
            assert_eq!(meta.get("name").unwrap().as_str(), Some("/chatter"));
            assert_eq!(
                meta.get("offered_qos_profiles").unwrap().as_str(),
                Some("- history: 3\n  depth: 0")
            );
            assert_eq!(
                topics[0].get("message_count").unwrap().as_str(),
                Some("100")
            );
            assert_eq!(info.get("compression_mode").unwrap().as_str(), Some(""));
            assert_eq!(info.get("custom_data"), Some(&Yaml::Null));
        }

        #[test]
        fn multi_line_plain_scalar_and_same_indent_sequence() {
            let text = "a:\n  h: \n    RIHS01_abc\n  l:\n  - x\n  - y\n  q: []\n";
            let doc = parse(text).unwrap();
            let a = doc.get("a").unwrap();
            assert_eq!(a.get("h").unwrap().as_str(), Some("RIHS01_abc"));
            assert_eq!(
                a.get("l"),
                Some(&Yaml::Seq(vec![
                    Yaml::Str("x".into()),
                    Yaml::Str("y".into())
                ]))
            );
            assert_eq!(a.get("q"), Some(&Yaml::Seq(vec![])));
        }
    }
}
