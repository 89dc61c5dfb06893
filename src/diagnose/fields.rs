//! Every numeric field a recording carries, averaged over each power reading's own sensor
//! window: the raw material of discovery beyond the hypothesis library ([`super::discover`]).
//!
//! The fields are enumerated from the recording's own message definitions (the first message
//! of each topic decoded generically, every numeric leaf kept, strings skipped), so nothing
//! here knows the robot's topics. One streamed pass over each file; only messages inside some
//! reading window are extracted, and per window only sums are kept, so memory is
//! windows × fields whatever the file length. Low-rate topics (a 1 Hz board or battery
//! message seldom falls inside a 0.2 s window) hold their last value.

use std::collections::HashMap;
use std::path::PathBuf;

use anyhow::{Context, Result};

use crate::read::{FieldExtractor, FieldPath, OpenOptions, ReadError, Session, Value};

use super::field_rules::{MsgStats, clock_correlation, constant_value, junk_reason};

/// One recording file joined into the diagnosed recording.
#[derive(Debug, Clone)]
pub struct FieldSource {
    /// The file (or bag folder).
    pub path: PathBuf,
    /// Time origin of the file's part of the recording [ns since the Unix epoch]
    /// (its `Recording::start_ns`).
    pub start_ns: u64,
    /// Shift added to the part's relative times when parts were joined [s].
    pub offset_s: f64,
}

/// A reading window (start, end] in recording time [s] (a status message stamped with the
/// reading's own time belongs to it).
#[derive(Debug, Clone, Copy)]
pub struct Window {
    /// Start [s].
    pub start: f64,
    /// End [s].
    pub end: f64,
}

/// Window means of every non-constant numeric field: `values[f][w]` for field `names[f]`.
#[derive(Debug, Clone, Default)]
pub struct FieldTable {
    /// `topic.field.path` of each kept field.
    pub names: Vec<String>,
    /// Window value per field and window.
    pub values: Vec<Vec<f64>>,
    /// Whether a field repeats an earlier field's values exactly (kept for per-motor families,
    /// not tried again on its own).
    pub duplicate: Vec<bool>,
    /// Fields read in all (before dropping constant, incomplete and duplicate ones).
    pub n_read: usize,
    /// Problems met (a file that could not be read is skipped with a note, never fatal).
    pub notes: Vec<String>,
    /// Mean motor supply voltage over the windows (fields named `…].vol`), when recorded [V].
    pub bus_volts: Option<f64>,
    /// Fields left out of discovery by a rule on their own data, each with the reason
    /// (constant over the reading windows, or by `junk_reason`: a counter or clock, or hash-/CRC-like).
    pub excluded: Vec<ExcludedField>,
}

/// A field left out of discovery, and why.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ExcludedField {
    /// `topic.field.path`.
    pub name: String,
    /// The rule it met, with the figures.
    pub reason: String,
}

/// Numeric leaf paths of a decoded message, in declaration order.
fn numeric_leaves(v: &Value, prefix: &str, out: &mut Vec<String>) {
    match v {
        Value::Struct(fields) => {
            for (name, child) in fields {
                let p = if prefix.is_empty() {
                    name.clone()
                } else {
                    format!("{prefix}.{name}")
                };
                numeric_leaves(child, &p, out);
            }
        }
        Value::Array(items) => {
            for (i, child) in items.iter().enumerate() {
                match child {
                    Value::Struct(_) | Value::Array(_) => {
                        numeric_leaves(child, &format!("{prefix}[{i}]"), out)
                    }
                    c if c.as_f64().is_some() => out.push(format!("{prefix}[{i}]")),
                    _ => {}
                }
            }
        }
        other if other.as_f64().is_some() && !prefix.is_empty() => out.push(prefix.to_string()),
        _ => {}
    }
}

/// A topic's numeric fields (`topic.field.path`) and their extractor, from its first message.
fn numeric_fields(ch: &crate::read::Channel, data: &[u8]) -> Option<(Vec<String>, FieldExtractor)> {
    let v = crate::read::decode::decode(&ch.schema, ch.encoding, data).ok()?;
    let mut leaves = Vec::new();
    numeric_leaves(&v, "", &mut leaves);
    let paths: Result<Vec<FieldPath>, _> = leaves.iter().map(|l| FieldPath::parse(l)).collect();
    let ex = FieldExtractor::compile(&ch.schema, ch.encoding, &paths.ok()?).ok()?;
    Some((
        leaves.iter().map(|l| format!("{}.{l}", ch.topic)).collect(),
        ex,
    ))
}

/// Per-topic accumulation state.
struct TopicAcc {
    names: Vec<String>,
    /// `None` only in tests that add decoded rows themselves.
    extractor: Option<FieldExtractor>,
    /// Per field, per window: the sum of the values inside the window while it is open, its
    /// value once closed (the mean, or the held value when it got none; NaN before any message).
    /// `None` while every message so far carried the field's first value: most fields of a
    /// robot's state never change (unused motors, reserved words), and a window vector for
    /// each of them was most of a long diagnosis' memory. The vector is built, exactly as it
    /// would have been accumulated, when the value first changes ([`TopicAcc::dense`]).
    vals: Vec<Option<Vec<f64>>>,
    count: Vec<u32>,
    /// Each field's value in the topic's first message.
    first: Vec<f64>,
    /// The window cursor after the first message closed the windows before it (those hold NaN).
    cursor0: usize,
    /// Last value of each field and the time it was seen.
    last: Vec<f64>,
    last_t: f64,
    cursor: usize,
    row: Vec<f64>,
    /// Per-message statistics of each field, over the topic's first [`STATS_MESSAGES`]
    /// messages in the file.
    stats: Vec<MsgStats>,
    n_stats: usize,
    /// The latest message not decoded yet (outside every window, past the statistics) and its
    /// time: decoded only if a window closes after it without a message of its own, whose
    /// value it then holds ([`TopicAcc::offer`]).
    pending: Vec<u8>,
    pending_t: Option<f64>,
}

/// Messages per topic and file the junk rules look at: enough for their statistics, and the
/// cost stays bounded on hours-long files (a 500 Hz state topic carries ~10⁷ messages).
const STATS_MESSAGES: usize = 50_000;

/// The sum of `c` messages all carrying `v`, added one by one as the accumulation does.
fn repeated_sum(v: f64, c: u32) -> f64 {
    (0..c).fold(0.0, |s, _| s + v)
}

impl TopicAcc {
    fn new(names: Vec<String>, extractor: Option<FieldExtractor>) -> Self {
        let n = names.len();
        TopicAcc {
            extractor,
            vals: vec![None; n],
            count: Vec::new(),
            first: vec![f64::NAN; n],
            cursor0: 0,
            last: vec![f64::NAN; n],
            last_t: f64::NEG_INFINITY,
            cursor: 0,
            row: vec![0.0; n],
            stats: vec![MsgStats::default(); n],
            n_stats: 0,
            pending: Vec::new(),
            pending_t: None,
            names,
        }
    }

    /// One message's raw bytes at time `t`, with the same result as decoding it and calling
    /// [`TopicAcc::add`]: past the first [`STATS_MESSAGES`], a message outside every window
    /// only matters as the hold value of a window that closes without a message, so it is kept
    /// undecoded until the next one replaces it or such a window closes. On a 500 Hz state
    /// topic most messages fall between the power readings' windows.
    fn offer(&mut self, windows: &[Window], t: f64, data: &[u8]) {
        if self.n_stats >= STATS_MESSAGES {
            if windows.get(self.cursor).is_some_and(|w| w.end < t) {
                self.flush(windows);
                self.advance(windows, t);
            }
            if !windows.get(self.cursor).is_some_and(|w| t > w.start) {
                self.pending.clear();
                self.pending.extend_from_slice(data);
                self.pending_t = Some(t);
                return;
            }
            // Inside a window: this message supersedes the pending one before any window closes.
            self.pending_t = None;
        }
        self.decode_add(windows, t, data);
    }

    /// Decode and add the pending message, if any.
    fn flush(&mut self, windows: &[Window]) {
        if let Some(t) = self.pending_t.take() {
            let data = std::mem::take(&mut self.pending);
            self.decode_add(windows, t, &data);
            self.pending = data;
        }
    }

    fn decode_add(&mut self, windows: &[Window], t: f64, data: &[u8]) {
        let Some(ex) = &self.extractor else { return };
        if ex.extract(data, &mut self.row).is_ok() {
            self.add(windows, t);
        }
    }

    /// Field `f`'s window vector as the accumulation would hold it now, while every message so
    /// far carried its first value: closed windows hold their mean (or the held value, or NaN
    /// before the first message), the open one its running sum, later ones 0.
    fn dense(&self, f: usize) -> Vec<f64> {
        let v0 = self.first[f];
        let seen = self.last_t > f64::NEG_INFINITY;
        (0..self.count.len())
            .map(|w| {
                let c = self.count[w];
                if w < self.cursor {
                    if c > 0 {
                        repeated_sum(v0, c) / c as f64
                    } else if seen && w >= self.cursor0 {
                        v0
                    } else {
                        f64::NAN
                    }
                } else if w == self.cursor {
                    repeated_sum(v0, c)
                } else {
                    0.0
                }
            })
            .collect()
    }

    /// Close every window ending before `t`: its mean, or the last value for an empty one.
    fn advance(&mut self, windows: &[Window], t: f64) {
        while self.cursor < windows.len() && windows[self.cursor].end < t {
            let w = self.cursor;
            let c = self.count[w];
            for (v, last) in self.vals.iter_mut().zip(&self.last) {
                let Some(v) = v else { continue };
                v[w] = if c > 0 {
                    v[w] / c as f64
                } else if self.last_t > f64::NEG_INFINITY {
                    *last
                } else {
                    f64::NAN
                };
            }
            self.cursor += 1;
        }
    }

    fn add(&mut self, windows: &[Window], t: f64) {
        if self.count.is_empty() {
            self.count = vec![0; windows.len()];
        }
        if self.n_stats < STATS_MESSAGES {
            self.n_stats += 1;
            for (st, &v) in self.stats.iter_mut().zip(&self.row) {
                st.add(v);
            }
        }
        self.advance(windows, t);
        if self.last_t == f64::NEG_INFINITY {
            self.cursor0 = self.cursor;
            self.first.copy_from_slice(&self.row);
        }
        for f in 0..self.vals.len() {
            if self.vals[f].is_none() && self.row[f].to_bits() != self.first[f].to_bits() {
                self.vals[f] = Some(self.dense(f));
            }
        }
        if let Some(w) = windows.get(self.cursor)
            && t > w.start
        {
            let k = self.cursor;
            self.count[k] += 1;
            for (s, v) in self.vals.iter_mut().zip(&self.row) {
                if let Some(s) = s {
                    s[k] += v;
                }
            }
        }
        self.last.copy_from_slice(&self.row);
        self.last_t = t;
    }
}

/// Read every numeric field of `sources` over `windows` (sorted by start, non-overlapping).
/// Fields that are constant or not defined over every window are dropped; exact duplicates of
/// an earlier field are marked.
pub fn read_fields(sources: &[FieldSource], windows: &[Window]) -> FieldTable {
    let mut table = FieldTable::default();
    // Each field over every file: statistics pooled, the clock rule's smallest |r| (the field
    // must follow time in every file that has it), windows a later part fills where the
    // earlier ones did not cover them.
    let mut merged: HashMap<String, FieldRead> = HashMap::new();
    let mut order: Vec<String> = Vec::new();
    for src in sources {
        let topics = match read_one(src, windows, sources.len() == 1) {
            Ok(topics) => topics,
            Err(e) => {
                let note = format!("{}: fields not read: {e:#}", src.path.display());
                table.notes.push(note);
                continue;
            }
        };
        for f in topics {
            let Some(m) = merged.get_mut(&f.name) else {
                order.push(f.name.clone());
                merged.insert(f.name.clone(), f);
                continue;
            };
            m.stats.merge(&f.stats);
            if let Some(r) = f.clock_r {
                m.clock_r = Some(
                    m.clock_r
                        .map_or(r, |c| if c.abs() < r.abs() { c } else { r }),
                );
            }
            for (o, v) in m.vals.iter_mut().zip(f.vals) {
                if o.is_nan() {
                    *o = v;
                }
            }
        }
    }
    table.n_read = order.len();
    let vols: Vec<f64> = order
        .iter()
        .filter(|n| n.ends_with("].vol"))
        .filter_map(|n| merged.get(n))
        .flat_map(|f| f.vals.iter().copied().filter(|x| x.is_finite() && *x > 0.0))
        .collect();
    if !vols.is_empty() {
        table.bus_volts = Some(vols.iter().sum::<f64>() / vols.len() as f64);
    }
    // Exact duplicates, found by a hash of the values' bits (candidates compared bit by bit).
    let mut seen: HashMap<u64, Vec<usize>> = HashMap::new();
    for name in order {
        let Some(FieldRead {
            vals,
            constant,
            stats,
            clock_r,
            ..
        }) = merged.remove(&name)
        else {
            continue;
        };
        if let Some(reason) = junk_reason(&stats, clock_r) {
            table.excluded.push(ExcludedField { name, reason });
            continue;
        }
        let lo = match constant {
            Some(lo) => Some(lo),
            None if vals.iter().any(|v| !v.is_finite()) => continue,
            None => constant_value(&vals),
        };
        if let Some(lo) = lo {
            table.excluded.push(ExcludedField {
                name,
                reason: format!("constant over every reading window ({lo})"),
            });
            continue;
        }
        let key = {
            use std::hash::{Hash, Hasher};
            let mut h = std::hash::DefaultHasher::new();
            vals.iter().for_each(|v| v.to_bits().hash(&mut h));
            h.finish()
        };
        let same = seen.entry(key).or_default();
        let dup = same.iter().any(|&i| {
            table.values[i]
                .iter()
                .zip(&vals)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        });
        if !dup {
            same.push(table.names.len());
        }
        table.names.push(name);
        table.values.push(vals);
        table.duplicate.push(dup);
    }
    table
}

/// One field of one file: window values (NaN where a window lies outside the file), its
/// per-message statistics, and the correlation of its window values with time in this file.
struct FieldRead {
    name: String,
    /// Empty when `constant` is set.
    vals: Vec<f64>,
    /// The value of a field constant over every window (finite everywhere): its windows are
    /// not kept.
    constant: Option<f64>,
    stats: MsgStats,
    clock_r: Option<f64>,
}

/// Window values of every numeric field of one file (NaN where a window lies outside it).
/// `summarise`: fields constant over every window are returned without their windows.
fn read_one(src: &FieldSource, windows: &[Window], summarise: bool) -> Result<Vec<FieldRead>> {
    let mut session = Session::open(&src.path, &OpenOptions::default())
        .with_context(|| format!("opening {}", src.path.display()))?;
    // A topic whose first message does not decode is skipped (`None`).
    let mut topics: HashMap<String, Option<TopicAcc>> = HashMap::new();
    let mut topic_order: Vec<String> = Vec::new();
    let mut t_first = f64::INFINITY;
    let mut t_last = f64::NEG_INFINITY;
    // Progress: told each 1/200 of the span the windows cover.
    let total_s = windows.iter().map(|w| w.end).fold(0.0, f64::max);
    let mut next_report = 0.0;
    session
        .read(None, &mut |msg| {
            let topic = msg.channel.topic.as_str();
            let t = (msg.log_time_ns as i128 - src.start_ns as i128) as f64 * 1e-9 + src.offset_s;
            if t >= next_report {
                next_report = t + total_s / 200.0;
                super::report(super::Progress::Seconds {
                    done_s: t.min(total_s),
                    total_s,
                });
            }
            t_first = t_first.min(t);
            t_last = t_last.max(t);
            if !topics.contains_key(topic) {
                topic_order.push(topic.to_string());
                let acc =
                    numeric_fields(msg.channel, msg.data).map(|(n, e)| TopicAcc::new(n, Some(e)));
                topics.insert(topic.to_string(), acc);
            }
            if let Some(Some(acc)) = topics.get_mut(topic) {
                acc.offer(windows, t, msg.data);
            }
            Ok::<(), ReadError>(())
        })
        .with_context(|| format!("reading {}", src.path.display()))?;
    let mut out = Vec::new();
    for topic in topic_order {
        let Some(Some(mut acc)) = topics.remove(&topic) else {
            continue;
        };
        acc.flush(windows);
        acc.advance(windows, f64::INFINITY);
        let names = std::mem::take(&mut acc.names);
        let stats = std::mem::take(&mut acc.stats);
        for (f, (name, stats)) in names.into_iter().zip(stats).enumerate() {
            let unchanged = acc.vals[f].is_none();
            // One field's window vector at a time.
            let mut vals = acc.vals[f].take().unwrap_or_else(|| acc.dense(f));
            // Windows outside this file's time span are not its to fill.
            for (v, w) in vals.iter_mut().zip(windows) {
                if w.end < t_first || w.start > t_last {
                    *v = f64::NAN;
                }
            }
            let clock_r = clock_correlation(windows.iter().map(|w| w.end), &vals);
            // A field that never changed is left out as constant by `read_fields` (unless a
            // junk rule takes it first): its windows need not be kept. The supply voltages
            // are kept: their mean is the bus voltage.
            let constant = (summarise && unchanged && !name.ends_with("].vol"))
                .then(|| constant_value(&vals))
                .flatten();
            if constant.is_some() {
                vals = Vec::new();
            }
            out.push(FieldRead {
                name,
                clock_r,
                vals,
                constant,
                stats,
            });
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn leaves_of_nested_messages() {
        let v = Value::Struct(vec![
            ("a".into(), Value::Float(1.0)),
            ("s".into(), Value::String("x".into())),
            (
                "m".into(),
                Value::Array(vec![
                    Value::Struct(vec![("q".into(), Value::Float(0.0))]),
                    Value::Struct(vec![("q".into(), Value::Float(0.0))]),
                ]),
            ),
            ("t".into(), Value::Array(vec![Value::Int(1), Value::Int(2)])),
        ]);
        let mut out = Vec::new();
        numeric_leaves(&v, "", &mut out);
        assert_eq!(out, ["a", "m[0].q", "m[1].q", "t[0]", "t[1]"]);
    }

    #[test]
    fn window_means_and_holds() {
        let windows = [
            Window {
                start: 0.0,
                end: 1.0,
            },
            Window {
                start: 2.0,
                end: 3.0,
            },
        ];
        let mut acc = TopicAcc::new(vec!["x".into()], None);
        for (t, v) in [(0.2, 1.0), (1.0, 3.0), (1.5, 7.0)] {
            acc.row[0] = v;
            acc.add(&windows, t);
        }
        acc.advance(&windows, f64::INFINITY);
        assert_eq!(acc.count, [2, 0]);
        assert_eq!(acc.vals[0].as_deref(), Some(&[2.0, 7.0][..]));
    }

    /// The window values of a topic's fields, accumulated with the windows of a field that has
    /// not changed yet left out, equal the plain definition: the mean of the messages inside
    /// each window, the last value before an empty one, NaN before the first message.
    #[test]
    fn unchanged_fields_keep_no_windows_and_give_the_same_values() {
        let windows: Vec<Window> = (0..12)
            .map(|k| Window {
                start: 1.0 + k as f64,
                end: 1.2 + k as f64 + if k == 5 { 0.6 } else { 0.0 },
            })
            .collect();
        // Messages every 0.07 s from t = 2.5 (windows 0 and 1 come before the first message).
        let msgs: Vec<(f64, [f64; 4])> = (0..160)
            .map(|i| {
                let t = 2.5 + 0.07 * i as f64;
                // Constant; changes at message 40; changes at the first message of window 6;
                // a value that is not exact in binary, changing once late.
                let late = if i < 150 { 0.1 } else { 0.3 };
                let w6 = if t > 7.0 { 2.0 } else { -1.5 };
                (
                    t,
                    [3.25, if i < 40 { 7.0 } else { 7.0 + i as f64 }, w6, late],
                )
            })
            .collect();
        let mut acc = TopicAcc::new((0..4).map(|f| format!("f{f}")).collect(), None);
        for (t, row) in &msgs {
            acc.row.copy_from_slice(row);
            acc.add(&windows, *t);
        }
        acc.advance(&windows, f64::INFINITY);
        assert!(acc.vals[0].is_none(), "the constant field kept its windows");
        assert!(acc.vals[1].is_some() && acc.vals[2].is_some() && acc.vals[3].is_some());
        for f in 0..4 {
            let got = acc.vals[f].clone().unwrap_or_else(|| acc.dense(f));
            for (w, win) in windows.iter().enumerate() {
                let inside: Vec<f64> = msgs
                    .iter()
                    .filter(|(t, _)| *t > win.start && *t <= win.end)
                    .map(|(_, r)| r[f])
                    .collect();
                let want = if !inside.is_empty() {
                    inside.iter().sum::<f64>() / inside.len() as f64
                } else {
                    msgs.iter()
                        .rfind(|(t, _)| *t <= win.start)
                        .map_or(f64::NAN, |(_, r)| r[f])
                };
                assert!(
                    (got[w] - want).abs() <= 1e-12 * want.abs().max(1.0)
                        || (got[w].is_nan() && want.is_nan()),
                    "field {f} window {w}: {} vs {want}",
                    got[w]
                );
            }
        }
    }

    /// Messages offered as raw bytes (decoded lazily past the statistics) give the same window
    /// values, bit for bit, as decoding and adding every message: inside windows, before
    /// windows that get no message (their hold), with values that change only between windows.
    #[test]
    fn lazily_decoded_messages_give_the_same_windows() {
        use crate::read::{Encoding, MsgSchema};
        let schema =
            MsgSchema::parse_ros1msg("p/T", "float64 a\nfloat64 b\nfloat64 c\nfloat64 d\n")
                .unwrap();
        let paths: Vec<FieldPath> = ["a", "b", "c", "d"]
            .iter()
            .map(|p| FieldPath::parse(p).unwrap())
            .collect();
        let ex = || FieldExtractor::compile(&schema, Encoding::Ros1, &paths).unwrap();
        // 0.2 s windows once a second for 130 s; messages at 500 Hz for 130 s except a gap
        // 100.6–104.9 s (windows 101–104 get no message; the last one before them lies
        // between windows).
        let windows: Vec<Window> = (0..130)
            .map(|k| Window {
                start: k as f64 + 0.3,
                end: k as f64 + 0.5,
            })
            .collect();
        let in_window = |t: f64| windows.iter().any(|w| t > w.start && t <= w.end);
        let msgs: Vec<(f64, [f64; 4])> = (0..65_000)
            .map(|i| 0.002 * i as f64)
            .filter(|t| !(100.6..104.9).contains(t))
            .enumerate()
            .map(|(i, t)| {
                // Constant; changing every message; changing only in messages outside every
                // window (and back); changing once between window 100 and the gap.
                let c = if !in_window(t) && i % 7 == 0 {
                    5.0
                } else {
                    1.0
                };
                let d = if t > 100.55 { 0.3 } else { 0.1 };
                (t, [3.25, (i as f64 * 0.37).sin(), c, d])
            })
            .collect();
        assert!(msgs.len() > STATS_MESSAGES + 10_000);
        let names: Vec<String> = (0..4).map(|f| format!("f{f}")).collect();
        let mut plain = TopicAcc::new(names.clone(), Some(ex()));
        let mut lazy = TopicAcc::new(names, Some(ex()));
        let mut decoded = 0usize;
        for (t, row) in &msgs {
            let data: Vec<u8> = row.iter().flat_map(|v| v.to_le_bytes()).collect();
            plain.decode_add(&windows, *t, &data);
            let n = lazy.n_stats;
            lazy.offer(&windows, *t, &data);
            decoded += usize::from(lazy.last_t == *t || lazy.n_stats > n);
        }
        for acc in [&mut plain, &mut lazy] {
            acc.flush(&windows);
            acc.advance(&windows, f64::INFINITY);
        }
        for f in 0..4 {
            let a = plain.vals[f].clone().unwrap_or_else(|| plain.dense(f));
            let b = lazy.vals[f].clone().unwrap_or_else(|| lazy.dense(f));
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&a), bits(&b), "field {f}");
        }
        // The hold of the empty windows is the value just before the gap.
        let d = plain.vals[3].clone().unwrap();
        assert_eq!(d[101], 0.3);
        // Most messages past the statistics were never decoded.
        assert!(decoded < STATS_MESSAGES + 5_000, "{decoded} decoded");
    }
}
