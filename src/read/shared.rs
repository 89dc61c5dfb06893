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
