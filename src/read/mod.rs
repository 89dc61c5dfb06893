//! Reading recorded sessions: MCAP, ROS 2 bag directories (.db3) and ROS 1 .bag files,
//! decoded generically from the message definitions the recording carries.
//!
//! Every container yields the same [`MessageRef`]s through [`Session`], so everything
//! downstream is format-blind. Readers stream: memory does not grow with file length.
//! A damaged file is read up to the damage; what was lost is reported in
//! [`ReadSummary::warnings`] with the file and byte offset.

use std::path::PathBuf;
use std::sync::Arc;

pub mod bag1;
pub mod db3;
pub mod decode;
pub mod fingerprint;
pub mod mcap;
pub mod msgdef;
pub mod session;

pub use decode::{DecodeError, FieldExtractor, FieldPath, Value};
pub use msgdef::{MsgSchema, SchemaError};
pub use session::Session;

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
    /// Publish time in nanoseconds since the Unix epoch (equal to log time where the format has only one).
    pub publish_time_ns: u64,
    /// Serialised payload.
    pub data: &'a [u8],
    /// Byte offset in the file of the record holding this message, for error messages
    /// (for compressed chunks: the chunk's offset).
    pub file_offset: u64,
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
    /// A message could not be decoded with its definition.
    // The inner error is part of the message, not a `source`: `{:#}` would print it twice.
    #[error("{path}: topic {topic}: {error} (record at byte offset {offset})")]
    Decode {
        /// File.
        path: PathBuf,
        /// Topic.
        topic: String,
        /// Byte offset of the record.
        offset: u64,
        /// Decoder error.
        error: DecodeError,
    },
    /// A message definition could not be parsed or is missing.
    #[error("{path}: topic {topic}: {error}")]
    Schema {
        /// File.
        path: PathBuf,
        /// Topic.
        topic: String,
        /// Schema error.
        error: SchemaError,
    },
    /// Anything else, already worded with its context.
    #[error("{0}")]
    Other(String),
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
    /// Stream every message (optionally only those of `topics`) in log-time order to `visit`.
    /// Damage stops the read with a warning in the summary rather than an error, once at
    /// least the file header was valid. An error returned by `visit` aborts the read and is returned.
    fn read(
        &mut self,
        topics: Option<&[&str]>,
        visit: &mut dyn FnMut(MessageRef<'_>) -> Result<(), ReadError>,
    ) -> Result<ReadSummary, ReadError>;
}
