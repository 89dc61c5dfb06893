//! A session's fingerprint: a stable 64-bit hash that identifies a recorded session before it is
//! read (file name, size and edges; for a ROS 2 bag folder its metadata and bag files), so outputs
//! made from the same input get the same id run after run (used for Rerun recording ids).

use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

/// FNV-1a, 64 bit: a stable hash (std's hashers are randomly seeded or not guaranteed stable).
/// Each part is followed by a separator, so `("ab", "c")` and `("a", "bc")` differ.
pub fn stable_hash(parts: &[&[u8]]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for part in parts {
        for &b in *part {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
        h ^= 0xff;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// Bytes read from each end of a file.
const EDGE: u64 = 64 * 1024;

/// Fingerprint of the session at `path`: a stable hash of the file name, its size and its first
/// and last 64 KiB; for a ROS 2 bag directory, of its name, its `metadata.yaml` and the name and
/// size of each of its `.db3`/`.mcap` files (other files, such as an `.rrd` saved beside them, do
/// not count). A copied file has the fingerprint of its original; `None` when the path cannot be
/// read.
pub fn fingerprint(path: &Path) -> Option<u64> {
    // `.` or `dir/..` have no file name of their own: use the resolved one.
    let name = match path.file_name() {
        Some(n) => n.to_string_lossy().into_owned(),
        None => path
            .canonicalize()
            .ok()?
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
    };
    let meta = std::fs::metadata(path).ok()?;
    let mut parts: Vec<Vec<u8>> = vec![name.into_bytes()];
    if meta.is_dir() {
        bag_dir_parts(path, &mut parts)?;
    } else {
        file_parts(path, meta.len(), &mut parts)?;
    }
    let refs: Vec<&[u8]> = parts.iter().map(Vec::as_slice).collect();
    Some(stable_hash(&refs))
}

/// A rosbag2 folder: `metadata.yaml` (content) and every `.db3`/`.mcap` (name and size).
fn bag_dir_parts(path: &Path, parts: &mut Vec<Vec<u8>>) -> Option<()> {
    let mut entries: Vec<(String, u64)> = std::fs::read_dir(path)
        .ok()?
        .filter_map(|e| {
            let e = e.ok()?;
            let n = e.file_name().to_string_lossy().into_owned();
            let bag_file = n == "metadata.yaml" || n.ends_with(".db3") || n.ends_with(".mcap");
            bag_file.then_some((n, e.metadata().ok()?.len()))
        })
        .collect();
    entries.sort();
    for (n, size) in entries {
        if n == "metadata.yaml" {
            parts.push(std::fs::read(path.join(&n)).ok()?);
        }
        parts.push(n.into_bytes());
        parts.push(size.to_le_bytes().to_vec());
    }
    Some(())
}

/// A single file: its size, first and last [`EDGE`] bytes.
fn file_parts(path: &Path, size: u64, parts: &mut Vec<Vec<u8>>) -> Option<()> {
    parts.push(size.to_le_bytes().to_vec());
    let mut f = std::fs::File::open(path).ok()?;
    let mut head = Vec::new();
    (&mut f).take(EDGE).read_to_end(&mut head).ok()?;
    parts.push(head);
    if size > EDGE {
        // The last 64 KiB, without re-reading bytes the head already covered.
        f.seek(SeekFrom::Start((size - EDGE).max(EDGE))).ok()?;
        let mut tail = Vec::new();
        f.take(EDGE).read_to_end(&mut tail).ok()?;
        parts.push(tail);
    }
    Some(())
}
