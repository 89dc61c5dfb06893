//! One entry point for every recording format: [`Session::open`] looks at the path (magic
//! bytes, extension, `metadata.yaml`) and boxes the matching [`MessageSource`].

use std::fs::File;
use std::path::{Path, PathBuf};

use super::bag1::MAGIC as ROS1_MAGIC;
use super::mcap::{MAGIC as MCAP_MAGIC, McapSource};
use super::{MessageSource, OpenOptions, ReadError, read_up_to};

/// Container formats [`Session::open`] recognises.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// MCAP file.
    Mcap,
    /// ROS 2 bag directory (`metadata.yaml` + `.db3` files), or its yaml / a `.db3` inside it.
    Ros2Bag,
    /// ROS 1 bag file (format 2.0).
    Ros1Bag,
}

/// A recording opened for reading, whatever its container format.
pub struct Session {
    path: PathBuf,
    source: Box<dyn MessageSource>,
}

impl std::fmt::Debug for Session {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Session")
            .field("path", &self.path)
            .field("format", &self.source.format())
            .finish()
    }
}

/// Decide the container format of `path` from magic bytes, extension or directory contents.
pub fn detect_format(path: &Path) -> Result<Format, ReadError> {
    let io = ReadError::io(path);
    if path.is_dir() {
        if path.join("metadata.yaml").is_file() {
            return Ok(Format::Ros2Bag);
        }
        return Err(ReadError::Other(format!(
            "{}: directory without metadata.yaml; expected a ROS 2 bag directory",
            path.display()
        )));
    }
    // A FIFO or device would block or never end: recordings are regular files.
    if !std::fs::metadata(path).map_err(&io)?.is_file() {
        return Err(ReadError::Other(format!(
            "{}: not a regular file (a recording is an MCAP, .db3 or .bag file, or a bag directory)",
            path.display()
        )));
    }
    let mut head = [0u8; 16];
    let mut file = File::open(path).map_err(&io)?;
    let n = read_up_to(&mut file, &mut head).map_err(&io)?;
    let head = &head[..n];
    if head.starts_with(MCAP_MAGIC) {
        return Ok(Format::Mcap);
    }
    if head.starts_with(ROS1_MAGIC) {
        return Ok(Format::Ros1Bag);
    }
    if head.starts_with(b"SQLite format 3\0") {
        return Ok(Format::Ros2Bag);
    }
    match path.extension().and_then(|e| e.to_str()) {
        Some("yaml" | "yml" | "db3") => Ok(Format::Ros2Bag),
        Some("mcap") => Err(ReadError::format(
            path,
            0,
            "not an MCAP file (bad magic bytes)",
        )),
        Some("bag") => Err(ReadError::format(
            path,
            0,
            "not a ROS 1 bag (expected `#ROSBAG V2.0`)",
        )),
        _ => Err(ReadError::format(
            path,
            0,
            "unknown recording format (expected MCAP, a ROS 1 .bag or a ROS 2 bag directory)",
        )),
    }
}

impl Session {
    /// Open a recording: an MCAP file, a ROS 2 bag (directory, its `metadata.yaml` or a `.db3`)
    /// or a ROS 1 `.bag`.
    pub fn open(path: &Path, opts: &OpenOptions) -> Result<Session, ReadError> {
        let source: Box<dyn MessageSource> = match detect_format(path)? {
            Format::Mcap => Box::new(McapSource::open(path, opts)?),
            Format::Ros2Bag => Box::new(super::db3::Ros2BagSource::open(path, opts)?),
            Format::Ros1Bag => Box::new(super::bag1::Ros1BagSource::open(path, opts)?),
        };
        Ok(Session {
            path: path.to_path_buf(),
            source,
        })
    }
}

/// Everything else a [`Session`] does is its reader's: [`MessageSource::read`],
/// [`MessageSource::info`], [`MessageSource::set_time_ranges`], …
impl std::ops::Deref for Session {
    type Target = dyn MessageSource;
    fn deref(&self) -> &Self::Target {
        self.source.as_ref()
    }
}

impl std::ops::DerefMut for Session {
    fn deref_mut(&mut self) -> &mut Self::Target {
        self.source.as_mut()
    }
}
