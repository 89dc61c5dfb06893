//! Stream a recording once and fill a [`Recording`] from a [`SignalMap`]: one compiled
//! [`FieldExtractor`] per channel, non-finite samples dropped with a warning.

use std::path::Path;

use anyhow::bail;

use super::Recording;
use super::map::{GROUPS, Group, SignalMap, group_signals};
use crate::N_JOINTS;
use crate::read::{FieldExtractor, FieldPath, MessageRef, OpenOptions, ReadError, Session};

/// Detailed warnings of one kind before they are only counted.
const MAX_DETAILED_WARNINGS: usize = 10;

struct GroupPlan {
    group: Group,
    topic: String,
    paths: Vec<FieldPath>,
    scales: Vec<f64>,
    /// Absolute log time of every kept sample (converted to relative seconds at the end).
    t_ns: Vec<u64>,
    /// Dropped (non-finite) and undecodable samples.
    non_finite: usize,
    undecodable: usize,
}

/// What a streamed read found besides the samples: the time origin, sample counts and problems.
#[derive(Debug, Clone, Default)]
pub struct StreamSummary {
    /// Absolute time [ns since the Unix epoch] all batch times are relative to.
    pub start_ns: u64,
    /// Samples delivered per group: state, command, MBS, BMS.
    pub samples: [usize; 4],
    /// Problems met while reading (damage, NaNs, missing topics), each naming file/topic/offset.
    pub warnings: Vec<String>,
}

/// Load the arm signals of `path` (MCAP, ROS 2 bag or ROS 1 bag) as `map` describes them.
///
/// Times are relative to the earliest message read. A damaged file yields the data up to the
/// damage with a warning; a missing state topic or a field the schema lacks is an error.
pub fn load_recording(
    path: &Path,
    map: &SignalMap,
    opts: &OpenOptions,
) -> anyhow::Result<Recording> {
    let mut out = None;
    let summary = read_batches(path, map, opts, &ReadPlan::all(usize::MAX), &mut |batch| {
        out = Some(std::mem::take(batch));
        Ok(())
    })?;
    let mut rec = out.unwrap_or_default();
    rec.source = path.to_path_buf();
    rec.joint_names = map.joint_names.clone();
    rec.start_ns = summary.start_ns;
    rec.warnings = summary.warnings;
    Ok(rec)
}

/// Stream the arm signals of `path` in batches of at most `batch_samples` state (or command)
/// samples, so memory stays bounded whatever the file length. Each batch is a [`Recording`]
/// holding only that stretch (times relative to [`StreamSummary::start_ns`], which is fixed by
/// the first batch: the earliest sample of an indexed file, read in log-time order). Files
/// without an index are delivered in file order, sorted within each batch only.
///
/// Errors are those of [`load_recording`], plus any error `on_batch` returns (reading stops).
/// The missing-state-topic error comes at the end, after the batches that were read.
pub fn stream_recording(
    path: &Path,
    map: &SignalMap,
    opts: &OpenOptions,
    batch_samples: usize,
    on_batch: &mut dyn FnMut(&Recording) -> anyhow::Result<()>,
) -> anyhow::Result<StreamSummary> {
    read_batches(
        path,
        map,
        opts,
        &ReadPlan::all(batch_samples),
        &mut |batch| on_batch(batch),
    )
}

/// Stream only the joint states of `path` (no command or power topic is decoded), in batches of
/// at most `batch_samples`, with times relative to `origin_ns` (e.g. the
/// [`StreamSummary::start_ns`] of an earlier full read, so both reads share one clock).
/// With `ranges` (seconds on that clock, sorted, not overlapping), only the samples inside them
/// are decoded and delivered, and an indexed MCAP reads only the chunks that overlap them.
/// Errors as [`stream_recording`].
pub fn stream_state(
    path: &Path,
    map: &SignalMap,
    opts: &OpenOptions,
    origin_ns: u64,
    batch_samples: usize,
    ranges: Option<&[(f64, f64)]>,
    on_batch: &mut dyn FnMut(&Recording) -> anyhow::Result<()>,
) -> anyhow::Result<StreamSummary> {
    let to_ns = |t: f64| {
        let ns = (t * 1e9).round();
        if ns <= 0.0 {
            origin_ns.saturating_sub((-ns).min(u64::MAX as f64) as u64)
        } else {
            origin_ns.saturating_add(ns.min(u64::MAX as f64) as u64)
        }
    };
    let plan = ReadPlan {
        batch_samples: batch_samples.max(1),
        state_only: true,
        origin_ns: Some(origin_ns),
        ranges: ranges.map(|r| r.iter().map(|&(a, b)| (to_ns(a), to_ns(b))).collect()),
    };
    read_batches(path, map, opts, &plan, &mut |batch| on_batch(batch))
}

/// What [`read_batches`] reads: batch size, which groups, the time origin.
struct ReadPlan {
    batch_samples: usize,
    /// Decode the state group only.
    state_only: bool,
    /// Fixed time origin (default: the first batch's earliest sample).
    origin_ns: Option<u64>,
    /// Only messages with log times in these ranges (inclusive ns, sorted, not overlapping).
    ranges: Option<Vec<(u64, u64)>>,
}

impl ReadPlan {
    fn all(batch_samples: usize) -> ReadPlan {
        ReadPlan {
            batch_samples: batch_samples.max(1),
            state_only: false,
            origin_ns: None,
            ranges: None,
        }
    }
}

/// Count and rate of one signal series, from a streamed read.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct SeriesStats {
    /// Samples (or readings).
    pub count: usize,
    /// Mean rate [Hz]: (count − 1) / (last − first stamp); 0 below two samples. Computed from
    /// the integer log times, so it does not depend on the time origin (nor on the order the
    /// recording stores its topics in).
    pub rate_hz: f64,
    #[serde(skip)]
    first_ns: Option<i128>,
    #[serde(skip)]
    last_ns: Option<i128>,
}

impl SeriesStats {
    /// Add the samples at times `t` [s] relative to `start_ns`.
    fn add(&mut self, t: &[f64], start_ns: u64) {
        for &v in t {
            // Exact: `t` was made from integer nanoseconds relative to `start_ns`.
            let ns = i128::from(start_ns) + (v * 1e9).round() as i128;
            self.first_ns = Some(self.first_ns.map_or(ns, |f| f.min(ns)));
            self.last_ns = Some(self.last_ns.map_or(ns, |l| l.max(ns)));
        }
        self.count += t.len();
        let span = self.first_ns.zip(self.last_ns).map(|(a, b)| b - a);
        let span = span.and_then(|s| u64::try_from(s).ok()).unwrap_or(0);
        self.rate_hz = crate::read::rate_hz(self.count as u64, 0, span);
    }
}

/// What the arm signals of a recording amount to, read in one streamed pass (memory does not
/// grow with the file): the joints and each series' count and rate.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct SignalStats {
    /// URDF joint names of the arm, in model order.
    pub joints: Vec<String>,
    /// Joint states.
    pub state: SeriesStats,
    /// Commands.
    pub command: SeriesStats,
    /// Main-board power readings.
    pub mbs_power: SeriesStats,
    /// Battery power readings.
    pub bms_power: SeriesStats,
    /// Problems met while reading.
    #[serde(skip)]
    pub warnings: Vec<String>,
}

/// Stream `path` once and count its arm signals (what `g1viz info` prints), holding one batch at
/// a time. Errors as [`load_recording`].
pub fn signal_stats(
    path: &Path,
    map: &SignalMap,
    opts: &OpenOptions,
) -> anyhow::Result<SignalStats> {
    let mut stats = SignalStats {
        joints: map.joint_names.clone(),
        ..SignalStats::default()
    };
    let summary = read_batches(path, map, opts, &ReadPlan::all(4096), &mut |batch| {
        stats.state.add(&batch.state.t, batch.start_ns);
        stats.command.add(&batch.command.t, batch.start_ns);
        stats.mbs_power.add(&batch.mbs.t, batch.start_ns);
        stats.bms_power.add(&batch.bms.t, batch.start_ns);
        Ok(())
    })?;
    stats.warnings = summary.warnings;
    Ok(stats)
}

/// Per-group read plans plus the batch being filled.
struct Batcher {
    plans: Vec<GroupPlan>,
    batch: Recording,
    start_ns: Option<u64>,
    samples: [usize; 4],
}

impl Batcher {
    fn len(&self) -> usize {
        self.batch.state.q.len().max(self.batch.command.q.len())
    }

    /// Give the filled batch (times set, each group sorted) to `on_batch` and start a new one.
    fn flush(
        &mut self,
        on_batch: &mut dyn FnMut(&mut Recording) -> anyhow::Result<()>,
    ) -> anyhow::Result<()> {
        let first = self.plans.iter().filter_map(|p| p.t_ns.iter().min()).min();
        let Some(&first) = first else {
            return Ok(());
        };
        let start = *self.start_ns.get_or_insert(first);
        self.batch.start_ns = start;
        for plan in &mut self.plans {
            set_times(&mut self.batch, plan.group, &plan.t_ns);
            plan.t_ns.clear();
        }
        on_batch(&mut self.batch)?;
        let b = &mut self.batch;
        // Emptied, not replaced: the next batch reuses the columns' memory.
        b.state.drain_front(usize::MAX);
        b.command = Default::default();
        b.mbs = Default::default();
        b.bms = Default::default();
        Ok(())
    }
}

/// One read plan per signal group: its topic, field paths and scales.
fn group_plans(map: &SignalMap) -> Vec<GroupPlan> {
    GROUPS
        .iter()
        .map(|&group| {
            let names = group_signals(group);
            let specs: Vec<_> = names.iter().filter_map(|n| map.signals.get(n)).collect();
            GroupPlan {
                group,
                topic: specs.first().map(|s| s.topic.clone()).unwrap_or_default(),
                paths: specs.iter().map(|s| s.field.clone()).collect(),
                scales: specs.iter().map(|s| s.scale).collect(),
                t_ns: Vec::new(),
                non_finite: 0,
                undecodable: 0,
            }
        })
        .collect()
}

/// Per topic: the type the extractors were compiled for, and (group index, extractor) for each
/// group reading the topic.
type Compiled = (String, Vec<(usize, FieldExtractor)>);

/// Decodes messages into a [`Batcher`]: field extractors compiled per topic on first sight (and
/// again when a topic's type changes), samples scaled, bad ones counted and warned about.
struct Decoder {
    file: String,
    /// Per topic (a handful): searched in a line, cheaper per message than hashing the name.
    extractors: Vec<(String, Compiled)>,
    row: Vec<f64>,
    warnings: Vec<String>,
    plausible: super::plausible::Plausible,
}

impl Decoder {
    /// Compile the extractors of every group reading `msg`'s topic (replacing entry `at`, when
    /// the topic's type changed); returns their index in `extractors`.
    fn compile(
        &mut self,
        b: &Batcher,
        msg: &MessageRef<'_>,
        at: Option<usize>,
    ) -> Result<usize, ReadError> {
        let topic = msg.channel.topic.as_str();
        let mut list = Vec::new();
        for (gi, plan) in b.plans.iter().enumerate().filter(|(_, p)| p.topic == topic) {
            let ex = FieldExtractor::compile(&msg.channel.schema, msg.channel.encoding, &plan.paths).map_err(|e| {
                ReadError::Other(format!(
                    "{}: topic {topic} ({}): schema does not match the signal map ({:?} signals): {e}",
                    self.file, msg.channel.type_name, plan.group
                ))
            })?;
            list.push((gi, ex));
        }
        let entry = (topic.to_string(), (msg.channel.type_name.clone(), list));
        Ok(match at {
            Some(i) => {
                self.extractors[i] = entry;
                i
            }
            None => {
                self.extractors.push(entry);
                self.extractors.len() - 1
            }
        })
    }

    /// Decode one message into every group that reads its topic.
    fn decode(&mut self, b: &mut Batcher, msg: &MessageRef<'_>) -> Result<(), ReadError> {
        let topic = msg.channel.topic.as_str();
        let at = self.extractors.iter().position(|(t, _)| t == topic);
        let known = at.filter(|&i| self.extractors[i].1.0 == msg.channel.type_name);
        let i = match known {
            Some(i) => i,
            None => self.compile(b, msg, at)?,
        };
        let (_, list) = &self.extractors[i].1;
        for (gi, ex) in list {
            let plan = &mut b.plans[*gi];
            self.row.resize(ex.len(), 0.0);
            if let Err(e) = ex.extract(msg.data, &mut self.row) {
                plan.undecodable += 1;
                if plan.undecodable <= MAX_DETAILED_WARNINGS {
                    self.warnings.push(format!(
                        "{}: topic {} at log time {} ns ({}): {e}; message skipped",
                        self.file,
                        plan.topic,
                        msg.log_time_ns,
                        msg.location()
                    ));
                }
                continue;
            }
            if let Some(bad) = self.row.iter().position(|v| !v.is_finite()) {
                plan.non_finite += 1;
                if plan.non_finite <= MAX_DETAILED_WARNINGS {
                    self.warnings.push(format!(
                        "{}: topic {} field {} is {} at log time {} ns; sample dropped",
                        self.file,
                        plan.topic,
                        plan.paths
                            .get(bad)
                            .map(ToString::to_string)
                            .unwrap_or_default(),
                        self.row.get(bad).copied().unwrap_or(f64::NAN),
                        msg.log_time_ns
                    ));
                }
                continue;
            }
            for (v, s) in self.row.iter_mut().zip(&plan.scales) {
                *v *= s;
            }
            if !(self.plausible).keep(*gi, &plan.topic, &plan.paths, &self.row, msg.log_time_ns) {
                continue;
            }
            plan.t_ns.push(msg.log_time_ns);
            let group = plan.group;
            push_row(&mut b.batch, group, &self.row);
            b.samples[group as usize] += 1;
        }
        Ok(())
    }
}

fn read_batches(
    path: &Path,
    map: &SignalMap,
    opts: &OpenOptions,
    plan: &ReadPlan,
    on_batch: &mut dyn FnMut(&mut Recording) -> anyhow::Result<()>,
) -> anyhow::Result<StreamSummary> {
    map.validate()?;
    let batch_samples = plan.batch_samples;
    let mut session = Session::open(path, opts)?;
    let mut plans = group_plans(map);
    if plan.state_only {
        for p in plans.iter_mut().filter(|p| p.group != Group::State) {
            p.topic.clear();
        }
    }
    let mut topic_names: Vec<String> = plans
        .iter()
        .filter(|p| !p.topic.is_empty())
        .map(|p| p.topic.clone())
        .collect();
    topic_names.sort_unstable();
    topic_names.dedup();
    let topics: Vec<&str> = topic_names.iter().map(String::as_str).collect();

    let template = "reading {bar:40} {pos}/{len} messages ({eta})";
    let total = || session.info().map(|i| i.messages).unwrap_or(0);
    let progress = crate::util::progress_bar(true, template, total);
    let mut decoder = Decoder {
        file: path.display().to_string(),
        extractors: Vec::new(),
        row: Vec::new(),
        warnings: Vec::new(),
        plausible: super::plausible::Plausible::new(&path.display().to_string(), map, &mut session),
    };
    // Samples go straight into the typed series (no intermediate copy); times are set per batch.
    let mut b = Batcher {
        plans,
        batch: Recording {
            source: path.to_path_buf(),
            joint_names: map.joint_names.clone(),
            ..Recording::default()
        },
        start_ns: plan.origin_ns,
        samples: [0; 4],
    };
    // An error of `on_batch` stops the read; it is returned as is, not as a read error.
    let mut sink_error: Option<anyhow::Error> = None;
    let mut count = 0u64;
    session.set_time_ranges(plan.ranges.clone());
    let wanted = |t| (plan.ranges.as_ref()).is_none_or(|r| crate::read::overlaps(r, t, t));
    let read = session.read(Some(&topics), &mut |msg| {
        if !wanted(msg.log_time_ns) {
            return Ok(());
        }
        count += 1;
        if count.is_multiple_of(4096) {
            progress.set_position(count);
        }
        decoder.decode(&mut b, &msg)?;
        if b.len() >= batch_samples
            && let Err(e) = b.flush(on_batch)
        {
            sink_error = Some(e);
            return Err(ReadError::Other("stopped by the batch consumer".into()));
        }
        Ok(())
    });
    progress.finish_and_clear();
    if let Some(e) = sink_error {
        return Err(e);
    }
    let summary = read?;
    let mut warnings = decoder.warnings;
    warnings.extend(decoder.plausible.warnings());
    warnings.extend(summary.warnings);
    finish_warnings(&decoder.file, &b, map, &mut session, &mut warnings)?;
    b.flush(on_batch)?;
    Ok(StreamSummary {
        start_ns: b.start_ns.unwrap_or(0),
        samples: b.samples,
        warnings,
    })
}

/// The end of a read: totals of dropped samples, an error when no state sample was read (naming
/// the topics the file has and any damage met), a warning per empty optional group.
fn finish_warnings(
    file: &str,
    b: &Batcher,
    map: &SignalMap,
    session: &mut Session,
    warnings: &mut Vec<String>,
) -> anyhow::Result<()> {
    for plan in &b.plans {
        if plan.non_finite > MAX_DETAILED_WARNINGS || plan.undecodable > MAX_DETAILED_WARNINGS {
            warnings.push(format!(
                "{file}: topic {}: {} samples with non-finite values and {} undecodable messages dropped in all",
                plan.topic, plan.non_finite, plan.undecodable
            ));
        }
    }
    if b.samples[0] == 0 {
        let state_topic = map.group_topic(Group::State).unwrap_or("");
        let present = session
            .info()
            .map(|i| {
                i.topics
                    .iter()
                    .map(|t| format!("{} ({}, {} msgs)", t.topic, t.type_name, t.count))
                    .collect::<Vec<_>>()
                    .join(", ")
            })
            .unwrap_or_else(|e| format!("(could not list topics: {e})"));
        let present = if present.is_empty() {
            "none readable".to_owned()
        } else {
            present
        };
        // A file damaged before its first state message: say where, not just that nothing came.
        let damage = if warnings.is_empty() {
            String::new()
        } else {
            format!("; {}", warnings.join("; "))
        };
        bail!(
            "{file}: required topic {state_topic} has no readable messages; topics in the file: {present}{damage}"
        );
    }
    // A group left out of the read (empty topic) is not missing.
    for plan in b.plans.iter().skip(1).filter(|p| !p.topic.is_empty()) {
        if b.samples[plan.group as usize] == 0 {
            warnings.push(format!(
                "{file}: optional topic {} has no messages: {:?} series left empty",
                plan.topic, plan.group
            ));
        }
    }
    Ok(())
}

fn joints(row: &[f64], block: usize) -> [f64; N_JOINTS] {
    std::array::from_fn(|j| row.get(block * N_JOINTS + j).copied().unwrap_or(f64::NAN))
}

/// Append one scaled sample of `group` (values in [`group_signals`] order) to its series.
fn push_row(rec: &mut Recording, group: Group, r: &[f64]) {
    let at = |i: usize| r.get(i).copied().unwrap_or(f64::NAN);
    match group {
        Group::State => {
            let s = &mut rec.state;
            s.q.push(joints(r, 0));
            s.dq.push(joints(r, 1));
            s.tau.push(joints(r, 2));
            s.temp.push(joints(r, 3));
            let o = 4 * N_JOINTS;
            s.gyro.push([at(o), at(o + 1), at(o + 2)]);
            s.quat.push([at(o + 3), at(o + 4), at(o + 5), at(o + 6)]);
            s.volts.push(at(o + 7));
        }
        Group::Command => {
            rec.command.q.push(joints(r, 0));
            rec.command.dq.push(joints(r, 1));
        }
        Group::Mbs => rec.mbs.watts.push(at(0) * at(1)),
        Group::Bms => rec.bms.watts.push(at(0) * at(1)),
    }
}

/// Set a group's time axis (seconds since `rec.start_ns`), sorting its samples by time when
/// the source delivered them out of order (files without an index).
fn set_times(rec: &mut Recording, group: Group, t_ns: &[u64]) {
    let start = rec.start_ns;
    // Signed: a later batch of an unindexed file may hold samples earlier than the origin.
    let t = (t_ns.iter())
        .map(|&t| (i128::from(t) - i128::from(start)) as f64 * 1e-9)
        .collect();
    match group {
        Group::State => (rec.state.t = t, rec.state.sort_by_time()),
        Group::Command => (rec.command.t = t, rec.command.sort_by_time()),
        Group::Mbs => (rec.mbs.t = t, rec.mbs.sort_by_time()),
        Group::Bms => (rec.bms.t = t, rec.bms.sort_by_time()),
    };
}
