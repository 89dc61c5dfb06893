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

/// Per-topic accumulation state.
struct TopicAcc {
    names: Vec<String>,
    extractor: Option<FieldExtractor>,
    /// Sums and counts per window (windows × fields, row-major by window).
    sum: Vec<f64>,
    count: Vec<u32>,
    /// Last value of each field and the time it was seen.
    last: Vec<f64>,
    last_t: f64,
    /// Held value per window (the last value before the window end) when the window got none.
    held: Vec<f64>,
    cursor: usize,
    row: Vec<f64>,
}

impl TopicAcc {
    fn new(names: Vec<String>, extractor: Option<FieldExtractor>, n_windows: usize) -> Self {
        let n = names.len();
        TopicAcc {
            extractor,
            sum: vec![0.0; n * n_windows],
            count: vec![0; n_windows],
            last: vec![f64::NAN; n],
            last_t: f64::NEG_INFINITY,
            held: vec![f64::NAN; n * n_windows],
            cursor: 0,
            row: vec![0.0; n],
            names,
        }
    }

    /// Close every window ending before `t` (holding the last value for empty ones).
    fn advance(&mut self, windows: &[Window], t: f64) {
        let n = self.names.len();
        while self.cursor < windows.len() && windows[self.cursor].end < t {
            let w = self.cursor;
            if self.last_t > f64::NEG_INFINITY {
                self.held[w * n..(w + 1) * n].copy_from_slice(&self.last);
            }
            self.cursor += 1;
        }
    }

    fn add(&mut self, windows: &[Window], t: f64) {
        self.advance(windows, t);
        let n = self.names.len();
        if let Some(w) = windows.get(self.cursor)
            && t > w.start
        {
            let k = self.cursor;
            self.count[k] += 1;
            for (s, v) in self.sum[k * n..(k + 1) * n].iter_mut().zip(&self.row) {
                *s += v;
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
    let mut merged: HashMap<String, Vec<f64>> = HashMap::new();
    let mut order: Vec<String> = Vec::new();
    for src in sources {
        match read_one(src, windows) {
            Ok(topics) => {
                for (name, vals) in topics {
                    match merged.get_mut(&name) {
                        // A later part fills the windows the earlier ones did not cover.
                        Some(old) => {
                            for (o, v) in old.iter_mut().zip(vals) {
                                if o.is_nan() {
                                    *o = v;
                                }
                            }
                        }
                        None => {
                            order.push(name.clone());
                            merged.insert(name, vals);
                        }
                    }
                }
            }
            Err(e) => table
                .notes
                .push(format!("{}: fields not read: {e:#}", src.path.display())),
        }
    }
    table.n_read = order.len();
    let vols: Vec<f64> = order
        .iter()
        .filter(|n| n.ends_with("].vol"))
        .filter_map(|n| merged.get(n))
        .flat_map(|v| v.iter().copied().filter(|x| x.is_finite() && *x > 0.0))
        .collect();
    if !vols.is_empty() {
        table.bus_volts = Some(vols.iter().sum::<f64>() / vols.len() as f64);
    }
    let mut seen: HashMap<Vec<u64>, usize> = HashMap::new();
    for name in order {
        let Some(vals) = merged.remove(&name) else {
            continue;
        };
        if vals.iter().any(|v| !v.is_finite()) {
            continue;
        }
        let (lo, hi) = vals
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                (a.min(v), b.max(v))
            });
        if hi - lo <= 1e-9 * hi.abs().max(lo.abs()).max(1e-300) {
            continue;
        }
        let key: Vec<u64> = vals.iter().map(|v| v.to_bits()).collect();
        let dup = seen.contains_key(&key);
        if !dup {
            seen.insert(key, table.names.len());
        }
        table.names.push(name);
        table.values.push(vals);
        table.duplicate.push(dup);
    }
    table
}

/// Window values of every numeric field of one file (NaN where a window lies outside it).
fn read_one(src: &FieldSource, windows: &[Window]) -> Result<Vec<(String, Vec<f64>)>> {
    let mut session = Session::open(&src.path, &OpenOptions::default())
        .with_context(|| format!("opening {}", src.path.display()))?;
    let nw = windows.len();
    let mut topics: HashMap<String, TopicAcc> = HashMap::new();
    let mut topic_order: Vec<String> = Vec::new();
    let mut t_first = f64::INFINITY;
    let mut t_last = f64::NEG_INFINITY;
    session
        .read(None, &mut |msg| {
            let topic = msg.channel.topic.as_str();
            let t = (msg.log_time_ns as i128 - src.start_ns as i128) as f64 * 1e-9 + src.offset_s;
            t_first = t_first.min(t);
            t_last = t_last.max(t);
            if !topics.contains_key(topic) {
                let mut names = Vec::new();
                let mut extractor = None;
                if let Ok(v) =
                    crate::read::decode::decode(&msg.channel.schema, msg.channel.encoding, msg.data)
                {
                    let mut leaves = Vec::new();
                    numeric_leaves(&v, "", &mut leaves);
                    let paths: Vec<FieldPath> = leaves
                        .iter()
                        .filter_map(|l| FieldPath::parse(l).ok())
                        .collect();
                    if paths.len() == leaves.len()
                        && let Ok(ex) = FieldExtractor::compile(
                            &msg.channel.schema,
                            msg.channel.encoding,
                            &paths,
                        )
                    {
                        names = leaves.iter().map(|l| format!("{topic}.{l}")).collect();
                        extractor = Some(ex);
                    }
                }
                topic_order.push(topic.to_string());
                topics.insert(topic.to_string(), TopicAcc::new(names, extractor, nw));
            }
            let Some(acc) = topics.get_mut(topic) else {
                return Ok(());
            };
            let Some(ex) = &acc.extractor else {
                return Ok(());
            };
            // Only messages inside a window, or the last one before a window, matter; the
            // others are still decoded for the hold value (cheap: fixed offsets).
            if ex.extract(msg.data, &mut acc.row).is_ok() {
                acc.add(windows, t);
            }
            Ok::<(), ReadError>(())
        })
        .with_context(|| format!("reading {}", src.path.display()))?;
    let mut out = Vec::new();
    for topic in topic_order {
        let Some(mut acc) = topics.remove(&topic) else {
            continue;
        };
        acc.advance(windows, f64::INFINITY);
        let n = acc.names.len();
        for (f, name) in acc.names.iter().enumerate() {
            let vals: Vec<f64> = (0..nw)
                .map(|w| {
                    // Windows outside this file's time span are not its to fill.
                    if windows[w].end < t_first || windows[w].start > t_last {
                        return f64::NAN;
                    }
                    if acc.count[w] > 0 {
                        acc.sum[w * n + f] / acc.count[w] as f64
                    } else {
                        acc.held[w * n + f]
                    }
                })
                .collect();
            out.push((name.clone(), vals));
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
        let mut acc = TopicAcc::new(vec!["x".into()], None, 2);
        for (t, v) in [(0.2, 1.0), (1.0, 3.0), (1.5, 7.0)] {
            acc.row[0] = v;
            acc.add(&windows, t);
        }
        acc.advance(&windows, f64::INFINITY);
        assert_eq!(acc.count, [2, 0]);
        assert_eq!(acc.sum[0], 4.0);
        assert_eq!(acc.held[1], 7.0);
    }
}
