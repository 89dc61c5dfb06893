//! Reading recorded sessions: MCAP, ROS 2 bag directories (.db3) and ROS 1 .bag files,
//! decoded generically from the message definitions the recording carries.
//!
//! Every container yields the same [`MessageRef`]s through [`Session`], so everything
//! downstream is format-blind. Readers stream: memory does not grow with file length.
//! A damaged file is read up to the damage; what was lost is reported in
//! [`ReadSummary::warnings`] with the file and byte offset. What the three container readers
//! share (topic statistics, topic selection, messages on unknown ids, the cap on detailed
//! warnings) is in `shared.rs`.

use std::path::{Path, PathBuf};
use std::sync::Arc;

// The modules are the crate's own; what users and tests need is re-exported below.
pub(crate) mod bag1;
pub(crate) mod db3;
pub(crate) mod decode;
pub(crate) mod fingerprint;
mod idl;
pub(crate) mod mcap;
mod mcap_records;
pub(crate) mod msgdef;
pub(crate) mod session;
mod shared;

pub use bag1::Ros1BagSource;
pub use db3::Ros2BagSource;
pub use decode::{DecodeError, FieldExtractor, FieldPath, Value, decode};
pub use fingerprint::{fingerprint, stable_hash};
pub use mcap::McapSource;
pub use msgdef::{
    ArrayKind, Field, FieldType, MAX_ARRAY_LEN, MAX_NESTING, MsgSchema, MsgType, Primitive,
    SchemaError, builtin_definition, normalize_type_name,
};
pub use session::{Format, Session, detect_format};

/// How message payloads are serialised.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// OMG CDR (XCDR1) with its 4-byte encapsulation header (ROS 2).
    Cdr,
    /// ROS 1 serialisation: little-endian, packed, u32 length prefixes.
    Ros1,
    /// JSON text, one object per message (MCAP `json` encoding).
    Json,
}

/// One topic of a recording with the definition its messages are decoded with.
#[derive(Debug, Clone)]
pub struct Channel {
    /// Topic name, e.g. `/lowstate`.
    pub topic: String,
    /// Fully qualified type name as the file spells it, e.g. `unitree_hg/msg/LowState`.
    pub type_name: String,
    /// Payload encoding.
    pub encoding: Encoding,
    /// Parsed message definition (root type plus dependencies).
    pub schema: Arc<MsgSchema>,
}

/// One message, borrowed from the reader's buffer for the duration of a visit.
#[derive(Debug, Clone, Copy)]
pub struct MessageRef<'a> {
    /// The channel (topic, type, schema) the message belongs to.
    pub channel: &'a Arc<Channel>,
    /// Recording (log) time in nanoseconds since the Unix epoch.
    pub log_time_ns: u64,
    /// Serialised payload.
    pub data: &'a [u8],
    /// Byte offset in the file of the record holding this message, for error messages
    /// (for compressed chunks: the chunk's offset); for rosbag2 sqlite storage, the message's
    /// row id (see `row_id`).
    pub file_offset: u64,
    /// True when `file_offset` is a database row id, not a byte offset.
    pub row_id: bool,
}

impl MessageRef<'_> {
    /// Where the message is, for messages to the user: `record at byte offset N` or
    /// `message row id N`.
    pub fn location(&self) -> String {
        if self.row_id {
            format!("message row id {}", self.file_offset)
        } else {
            format!("record at byte offset {}", self.file_offset)
        }
    }
}

/// What a full read produced besides the messages.
#[derive(Debug, Clone, Default)]
pub struct ReadSummary {
    /// Messages delivered to the visitor.
    pub messages: u64,
    /// Damage and oddities met on the way, each naming file, topic or byte offset.
    pub warnings: Vec<String>,
    /// False when the read stopped early because the file is damaged or truncated.
    pub complete: bool,
}

/// Per-topic statistics of a recording, as `mcap info` / `ros2 bag info` print them.
#[derive(Debug, Clone, serde::Serialize)]
pub struct TopicInfo {
    /// Topic name.
    pub topic: String,
    /// Message type name.
    pub type_name: String,
    /// Encoding name (`cdr`, `ros1`, `json`).
    pub encoding: String,
    /// Number of messages.
    pub count: u64,
    /// First message log time [ns].
    pub first_ns: u64,
    /// Last message log time [ns].
    pub last_ns: u64,
    /// Mean rate [Hz] over the topic's own span.
    pub rate_hz: f64,
}

/// Container-level description of a recording.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SessionInfo {
    /// Path that was opened.
    pub path: PathBuf,
    /// Container format (`mcap`, `ros2-sqlite3`, `ros1-bag`).
    pub format: String,
    /// Earliest message log time [ns].
    pub start_ns: u64,
    /// Latest message log time [ns].
    pub end_ns: u64,
    /// Total messages.
    pub messages: u64,
    /// One entry per topic, sorted by topic name.
    pub topics: Vec<TopicInfo>,
    /// Warnings met while gathering the information.
    pub warnings: Vec<String>,
}

/// Errors reading a recording. Every variant names the file and, where it applies, the
/// topic and byte offset, so a user can find the damage.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The file could not be opened or read.
    #[error("cannot read {path}")]
    Io {
        /// File.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// The container structure is broken or unsupported.
    #[error("{path}: {what} (at byte offset {offset})")]
    Format {
        /// File.
        path: PathBuf,
        /// Byte offset of the bad record.
        offset: u64,
        /// What is wrong.
        what: String,
    },
    /// Anything else, already worded with its context.
    #[error("{0}")]
    Other(String),
}

impl ReadError {
    /// The [`ReadError::Io`] of reading `path`, for `map_err`.
    pub(crate) fn io(path: &Path) -> impl Fn(std::io::Error) -> ReadError + use<> {
        let path = path.to_path_buf();
        move |source| ReadError::Io {
            path: path.clone(),
            source,
        }
    }

    /// A [`ReadError::Format`]: `what` is wrong in `path` at byte `offset`.
    pub(crate) fn format(path: &Path, offset: u64, what: impl Into<String>) -> ReadError {
        ReadError::Format {
            path: path.to_path_buf(),
            offset,
            what: what.into(),
        }
    }
}

/// Mean rate [Hz] of `count` messages over a topic's own span [first, last] ns; 0 when it has
/// fewer than two messages.
pub(crate) fn rate_hz(count: u64, first_ns: u64, last_ns: u64) -> f64 {
    if count < 2 || last_ns <= first_ns {
        return 0.0;
    }
    (count - 1) as f64 / ((last_ns - first_ns) as f64 * 1e-9)
}

/// Whether [a, b] overlaps one of `ranges` (sorted, inclusive bounds).
pub(crate) fn overlaps(ranges: &[(u64, u64)], a: u64, b: u64) -> bool {
    // The first range that does not end before a.
    let i = ranges.partition_point(|r| r.1 < a);
    ranges.get(i).is_some_and(|r| r.0 <= b)
}

/// Assemble a [`SessionInfo`] from per-topic statistics (sorted by topic name here; start and
/// end from the topics' own first and last messages).
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
        // Saturating: counts come from files; a reader warns where they are implausible.
        messages: topics.iter().fold(0u64, |a, t| a.saturating_add(t.count)),
        topics,
        warnings,
    }
}

/// Read at most `size + 1` bytes of `reader` into `out`: one byte more than allowed is enough
/// to tell a stream longer than its declared size (a decompression bomb) without inflating it
/// further.
pub(crate) fn read_capped(
    reader: impl std::io::Read,
    size: usize,
    out: &mut Vec<u8>,
) -> std::io::Result<()> {
    use std::io::Read;
    out.reserve(size);
    reader.take(size as u64 + 1).read_to_end(out).map(|_| ())
}

/// Like `read_exact` but returns how much was read when the file is shorter.
pub(crate) fn read_up_to(file: &mut impl std::io::Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match file.read(&mut buf[got..])? {
            0 => break,
            n => got += n,
        }
    }
    Ok(got)
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
    let normalised = msgdef::normalize_type_name(type_name, "");
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

/// Package and bare type name of `pkg/Type` or `pkg/msg/Type`.
fn split_type_name(type_name: &str) -> (&str, &str) {
    let pkg = type_name.split('/').next().unwrap_or(type_name);
    let name = type_name.rsplit('/').next().unwrap_or(type_name);
    (pkg, name)
}

/// Options shared by all readers.
#[derive(Debug, Clone, Default)]
pub struct OpenOptions {
    /// Extra folders searched for `.msg` definitions when a recording does not carry them
    /// (`--msg-path`, repeatable). Layout: `DIR/<package>/msg/<Type>.msg` or `DIR/<package>/<Type>.msg`.
    pub msg_paths: Vec<PathBuf>,
}

/// A container format reader. Implemented by the MCAP, ROS 2 bag and ROS 1 bag readers;
/// [`Session`] picks one from the path.
pub trait MessageSource {
    /// Container format name (`mcap`, `ros2-sqlite3`, `ros1-bag`).
    fn format(&self) -> &'static str;
    /// Topic statistics, from the summary/index when present, otherwise by a scan.
    fn info(&mut self) -> Result<SessionInfo, ReadError>;
    /// Whether [`MessageSource::info`] is cheap (a summary, an index, or a scan already done
    /// when opening) rather than a pass over the whole file.
    fn info_is_cheap(&self) -> bool {
        true
    }
    /// The latest log time the headers read when opening claim (MCAP chunk headers of a file
    /// without an index), when [`MessageSource::info`] is not cheap; `None` when unknown.
    fn latest_time_hint(&self) -> Option<u64> {
        None
    }
    /// Stream every message (optionally only those of `topics`) in log-time order to `visit`.
    /// Damage stops the read with a warning in the summary rather than an error, once at
    /// least the file header was valid. An error returned by `visit` aborts the read and is returned.
    fn read(
        &mut self,
        topics: Option<&[&str]>,
        visit: &mut dyn FnMut(MessageRef<'_>) -> Result<(), ReadError>,
    ) -> Result<ReadSummary, ReadError>;
    /// A hint for the next reads: only messages whose log time falls in one of `ranges`
    /// (inclusive nanosecond bounds, sorted, not overlapping) are needed. A reader that can
    /// skip whole stretches outside them (MCAP chunks, through the chunk index) does; every
    /// reader may still deliver messages outside them, so the caller filters. `None` (the
    /// default) reads everything.
    fn set_time_ranges(&mut self, ranges: Option<Vec<(u64, u64)>>) {
        let _ = ranges;
    }
}
