//! What the three container readers (MCAP, ROS 1 bag, rosbag2 sqlite) share, so that each format
//! file keeps only its container parsing: a topic's statistics and how they become a
//! [`TopicInfo`], which topics a read delivers, messages on ids without a topic record, the cap
//! on detailed warnings, and the one way a [`Channel`] is made.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use super::{Channel, Encoding, MsgSchema, ReadError, ReadSummary, TopicInfo};

/// Disagreements of one kind reported in detail before they are only counted.
pub(crate) const MAX_DETAILED: usize = 10;

/// Chunks (compressed or not, and after decompression) larger than this are treated as damage
/// rather than allocated.
pub(crate) const MAX_CHUNK_BYTES: u64 = 64 << 20;

/// Chunk decompression for the MCAP and ROS 1 readers, keeping one zstd context for every chunk
/// (creating one per chunk cost a few per cent of a whole read).
#[derive(Default)]
pub(crate) struct Inflater {
    zstd: Option<zstd::bulk::Decompressor<'static>>,
}

impl Inflater {
    /// Decompress one chunk's `data` (`compression` as the container names it) into `out`,
    /// capped at its declared `size` (itself at most [`MAX_CHUNK_BYTES`]): a chunk that
    /// inflates beyond it is damage whatever its compressed size, and so is one that inflates to
    /// less, unless it is `partial` (cut off by the end of the file: what came out is kept).
    pub fn chunk(
        &mut self,
        compression: &str,
        data: &[u8],
        size: u64,
        partial: bool,
        out: &mut Vec<u8>,
    ) -> Result<(), String> {
        if size > MAX_CHUNK_BYTES {
            let limit = MAX_CHUNK_BYTES >> 20;
            return Err(format!(
                "chunk claims {size} uncompressed bytes (more than the {limit} MiB limit)"
            ));
        }
        let size = size as usize;
        out.clear();
        let capped = |reader: &mut dyn std::io::Read, out: &mut Vec<u8>, name: &str| {
            match super::read_capped(reader, size, out) {
                Err(e) if !partial => Err(format!("{name} chunk does not decompress: {e}")),
                _ => Ok(()),
            }
        };
        match compression {
            "" | "none" => out.extend_from_slice(data),
            "lz4" => capped(&mut lz4_flex::frame::FrameDecoder::new(data), out, "lz4")?,
            "bz2" => capped(&mut bzip2::read::BzDecoder::new(data), out, "bz2")?,
            "zstd" => {
                let failed = |e: std::io::Error| {
                    format!(
                        "zstd decompression failed (or more than the declared {size} bytes): {e}"
                    )
                };
                let d = match &mut self.zstd {
                    Some(d) => d,
                    empty => empty.insert(zstd::bulk::Decompressor::new().map_err(failed)?),
                };
                // The bulk decoder writes at most the Vec's capacity: the declared size.
                out.reserve_exact(size);
                if let Err(e) = d.decompress_to_buffer(data, out) {
                    // A failed frame may leave the context mid-stream: start the next afresh.
                    self.zstd = None;
                    return Err(failed(e));
                }
            }
            other => {
                return Err(format!(
                    "unsupported chunk compression {other:?} (supported: zstd, lz4, bz2, none)"
                ));
            }
        }
        if out.len() > size || (!partial && out.len() != size) {
            let more = if out.len() > size { "more than " } else { "" };
            return Err(format!(
                "chunk decompressed to {more}{} bytes, its header says {size}",
                out.len()
            ));
        }
        Ok(())
    }
}

/// Count and first/last log time of one topic's (or connection's, channel's) messages.
#[derive(Debug, Clone, Copy)]
pub(crate) struct TopicStat {
    pub count: u64,
    pub first_ns: u64,
    pub last_ns: u64,
}

impl Default for TopicStat {
    fn default() -> Self {
        TopicStat {
            count: 0,
            first_ns: u64::MAX,
            last_ns: 0,
        }
    }
}

impl TopicStat {
    /// `n` more messages, the latest (or earliest) at `t`.
    pub fn add(&mut self, t: u64, n: u64) {
        self.count = self.count.saturating_add(n);
        self.first_ns = self.first_ns.min(t);
        self.last_ns = self.last_ns.max(t);
    }

    /// The messages of `other` too.
    pub fn merge(&mut self, other: &TopicStat) {
        self.add(other.first_ns, other.count);
        self.last_ns = self.last_ns.max(other.last_ns);
    }

    /// The topic's line of [`super::SessionInfo`] (first time 0 for a topic without messages).
    pub fn info(&self, topic: &str, type_name: &str, encoding: &str) -> TopicInfo {
        let first = if self.count == 0 { 0 } else { self.first_ns };
        TopicInfo {
            topic: topic.to_string(),
            type_name: type_name.to_string(),
            encoding: encoding.to_string(),
            count: self.count,
            first_ns: first,
            last_ns: self.last_ns,
            rate_hz: super::rate_hz(self.count, first, self.last_ns),
        }
    }
}

/// One [`TopicInfo`] per topic name from the statistics of its connections (channels, files):
/// (topic, type, encoding, statistics); the first type and encoding met are kept.
pub(crate) fn by_topic<'a>(
    stats: impl Iterator<Item = (&'a str, &'a str, &'a str, TopicStat)>,
) -> Vec<TopicInfo> {
    let mut by: BTreeMap<&str, (&str, &str, TopicStat)> = BTreeMap::new();
    for (topic, type_name, encoding, s) in stats {
        let e = by.entry(topic);
        e.or_insert((type_name, encoding, TopicStat::default()))
            .2
            .merge(&s);
    }
    (by.into_iter())
        .map(|(topic, (type_name, encoding, s))| s.info(topic, type_name, encoding))
        .collect()
}

/// Which of a recording's topics (name, channel or why it has none) a read delivers: those in
/// `wanted` (all when `None`). A requested topic without a definition is an error; one that
/// only comes along with "all topics" is skipped with a warning (once).
pub(crate) fn select_topics<'a>(
    topics: impl Iterator<Item = (&'a str, &'a Result<Arc<Channel>, String>)>,
    wanted: Option<&[&str]>,
    warnings: &mut Vec<String>,
) -> Result<Vec<bool>, ReadError> {
    let mut selected = Vec::new();
    for (name, channel) in topics {
        let asked = wanted.is_none_or(|w| w.contains(&name));
        selected.push(asked && channel.is_ok());
        match channel {
            Err(e) if asked && wanted.is_some() => return Err(ReadError::Other(e.clone())),
            Err(e) if asked => {
                let w = format!("{e}; topic skipped");
                if !warnings.contains(&w) {
                    warnings.push(w);
                }
            }
            _ => {}
        }
    }
    Ok(selected)
}

/// Messages on ids that no topic record names (never delivered): id → (count, where the first
/// one is).
#[derive(Debug, Default, Clone)]
pub(crate) struct Orphans(pub BTreeMap<u32, (u64, u64)>);

impl Orphans {
    /// One more message on `id`, at `at`.
    pub fn add(&mut self, id: u32, at: u64) {
        self.0.entry(id).or_insert((0, at)).0 += 1;
    }

    /// The messages of `other` too.
    pub fn merge(&mut self, other: &Orphans) {
        for (id, (n, first)) in &other.0 {
            self.0.entry(*id).or_insert((0, *first)).0 += n;
        }
    }

    /// One warning per id: `{path}: N messages on {kind} id ID, which has no {kind} record, were
    /// skipped (the first {at} FIRST)`.
    pub fn warnings(&self, path: &Path, kind: &str, at: &str) -> Vec<String> {
        (self.0.iter())
            .map(|(id, (n, first))| {
                format!(
                    "{}: {n} messages on {kind} id {id}, which has no {kind} record, were skipped \
                     (the first {at} {first})",
                    path.display()
                )
            })
            .collect()
    }
}

/// Push the first [`MAX_DETAILED`] of `detailed` onto `warnings`, then `more(n)` for the `n` left
/// out, if any.
pub(crate) fn capped(
    warnings: &mut Vec<String>,
    detailed: Vec<String>,
    more: impl FnOnce(usize) -> String,
) {
    let left = detailed.len().saturating_sub(MAX_DETAILED);
    warnings.extend(detailed.into_iter().take(MAX_DETAILED));
    if left > 0 {
        warnings.push(more(left));
    }
}

impl Channel {
    /// A decodable topic.
    pub(crate) fn new(
        topic: &str,
        type_name: &str,
        encoding: Encoding,
        schema: MsgSchema,
    ) -> Arc<Channel> {
        Arc::new(Channel {
            topic: topic.to_string(),
            type_name: type_name.to_string(),
            encoding,
            schema: Arc::new(schema),
        })
    }
}

impl ReadSummary {
    /// The summary a read starts from: the warnings found when opening, complete unless
    /// opening met damage.
    pub(crate) fn starting(warnings: &[String], complete: bool) -> ReadSummary {
        ReadSummary {
            messages: 0,
            warnings: warnings.to_vec(),
            complete,
        }
    }
}
