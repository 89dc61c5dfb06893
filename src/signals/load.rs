//! Stream a recording once and fill a [`Recording`] from a [`SignalMap`]: one compiled
//! [`FieldExtractor`] per channel, non-finite samples dropped with a warning.

use std::collections::HashMap;
use std::io::IsTerminal;
use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, bail};

use super::map::{GROUPS, Group, SignalMap, group_signals};
use super::{CommandSeries, PowerSeries, Recording, StateSeries};
use crate::N_JOINTS;
use crate::read::{Channel, FieldExtractor, FieldPath, OpenOptions, ReadError, Session};

/// Detailed warnings of one kind before they are only counted.
const MAX_DETAILED_WARNINGS: usize = 10;

/// Samples of one group: absolute times and row-major values (one row per message).
#[derive(Default)]
struct Columns {
    t_ns: Vec<u64>,
    values: Vec<f64>,
}

struct GroupPlan {
    group: Group,
    topic: String,
    paths: Vec<FieldPath>,
    scales: Vec<f64>,
    columns: Columns,
    /// Dropped (non-finite) and undecodable samples.
    non_finite: usize,
    undecodable: usize,
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
    map.validate()?;
    let mut session = Session::open(path, opts)?;
    let mut plans: Vec<GroupPlan> = GROUPS
        .iter()
        .map(|&group| {
            let names = group_signals(group);
            let specs: Vec<_> = names.iter().filter_map(|n| map.signals.get(n)).collect();
            GroupPlan {
                group,
                topic: specs.first().map(|s| s.topic.clone()).unwrap_or_default(),
                paths: specs.iter().map(|s| s.field.clone()).collect(),
                scales: specs.iter().map(|s| s.scale).collect(),
                columns: Columns::default(),
                non_finite: 0,
                undecodable: 0,
            }
        })
        .collect();
    let mut topic_names: Vec<String> = plans.iter().map(|p| p.topic.clone()).collect();
    topic_names.sort_unstable();
    topic_names.dedup();
    let topics: Vec<&str> = topic_names.iter().map(String::as_str).collect();

    let progress = progress_bar(&mut session);
    let mut warnings = Vec::new();
    // Per channel (by identity): (group index, extractor) for each group reading its topic.
    let mut extractors: HashMap<*const Channel, Vec<(usize, FieldExtractor)>> = HashMap::new();
    let mut row = Vec::new();
    let mut count = 0u64;
    let file = path.display().to_string();
    let summary = session.read(Some(&topics), &mut |msg| {
        count += 1;
        if count % 4096 == 0 {
            if let Some(pb) = &progress {
                pb.set_position(count);
            }
        }
        let key = Arc::as_ptr(msg.channel);
        if !extractors.contains_key(&key) {
            let mut list = Vec::new();
            for (gi, plan) in plans.iter().enumerate().filter(|(_, p)| p.topic == msg.channel.topic) {
                let ex = FieldExtractor::compile(&msg.channel.schema, msg.channel.encoding, &plan.paths).map_err(|e| {
                    ReadError::Other(format!(
                        "{file}: topic {} ({}): schema does not match the signal map ({:?} signals): {e}",
                        msg.channel.topic, msg.channel.type_name, plan.group
                    ))
                })?;
                list.push((gi, ex));
            }
            extractors.insert(key, list);
        }
        for (gi, ex) in extractors.get(&key).map(Vec::as_slice).unwrap_or(&[]) {
            let plan = &mut plans[*gi];
            row.resize(ex.len(), 0.0);
            if let Err(e) = ex.extract(msg.data, &mut row) {
                plan.undecodable += 1;
                if plan.undecodable <= MAX_DETAILED_WARNINGS {
                    warnings.push(format!(
                        "{file}: topic {} at log time {} ns (record at byte offset {}): {e}; message skipped",
                        plan.topic, msg.log_time_ns, msg.file_offset
                    ));
                }
                continue;
            }
            if let Some(bad) = row.iter().position(|v| !v.is_finite()) {
                plan.non_finite += 1;
                if plan.non_finite <= MAX_DETAILED_WARNINGS {
                    warnings.push(format!(
                        "{file}: topic {} field {} is {} at log time {} ns; sample dropped",
                        plan.topic,
                        plan.paths.get(bad).map(ToString::to_string).unwrap_or_default(),
                        row.get(bad).copied().unwrap_or(f64::NAN),
                        msg.log_time_ns
                    ));
                }
                continue;
            }
            plan.columns.t_ns.push(msg.log_time_ns);
            plan.columns.values.extend(row.iter().zip(&plan.scales).map(|(v, s)| v * s));
        }
        Ok(())
    })?;
    if let Some(pb) = progress {
        pb.finish_and_clear();
    }
    warnings.extend(summary.warnings);
    for plan in &plans {
        if plan.non_finite > MAX_DETAILED_WARNINGS || plan.undecodable > MAX_DETAILED_WARNINGS {
            warnings.push(format!(
                "{file}: topic {}: {} samples with non-finite values and {} undecodable messages dropped in all",
                plan.topic, plan.non_finite, plan.undecodable
            ));
        }
    }

    let state_empty = plans.first().is_none_or(|p| p.columns.t_ns.is_empty());
    if state_empty {
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
        bail!(
            "{file}: required topic {state_topic} has no readable messages; topics in the file: {present}"
        );
    }
    for plan in plans.iter().skip(1) {
        if plan.columns.t_ns.is_empty() {
            warnings.push(format!(
                "{file}: optional topic {} has no messages: {:?} series left empty",
                plan.topic, plan.group
            ));
        }
    }
    let start_ns = plans
        .iter()
        .filter_map(|p| p.columns.t_ns.iter().min())
        .min()
        .copied()
        .unwrap_or(0);
    let mut rec = Recording {
        source: path.to_path_buf(),
        start_ns,
        joint_names: map.joint_names.clone(),
        warnings,
        ..Recording::default()
    };
    for plan in &mut plans {
        sort_by_time(&mut plan.columns, plan.paths.len());
        fill(&mut rec, plan).with_context(|| format!("{file}: topic {}", plan.topic))?;
    }
    Ok(rec)
}

fn progress_bar(session: &mut Session) -> Option<indicatif::ProgressBar> {
    if !std::io::stderr().is_terminal() {
        return None;
    }
    let total = session.info().map(|i| i.messages).unwrap_or(0);
    let pb = indicatif::ProgressBar::new(total);
    if let Ok(style) =
        indicatif::ProgressStyle::with_template("reading {bar:40} {pos}/{len} messages ({eta})")
    {
        pb.set_style(style);
    }
    Some(pb)
}

/// Sort rows by time when the source delivered them out of order (unindexed files).
fn sort_by_time(c: &mut Columns, width: usize) {
    if c.t_ns.is_sorted() || width == 0 {
        return;
    }
    let mut order: Vec<usize> = (0..c.t_ns.len()).collect();
    order.sort_by_key(|&i| c.t_ns[i]);
    let t = order.iter().map(|&i| c.t_ns[i]).collect();
    let values = order
        .iter()
        .flat_map(|&i| c.values[i * width..(i + 1) * width].iter().copied())
        .collect();
    *c = Columns { t_ns: t, values };
}

fn joints(row: &[f64], block: usize) -> [f64; N_JOINTS] {
    std::array::from_fn(|j| row[block * N_JOINTS + j])
}

fn fill(rec: &mut Recording, plan: &GroupPlan) -> anyhow::Result<()> {
    let width = plan.paths.len();
    let rel = |t: u64| t.saturating_sub(rec.start_ns) as f64 * 1e-9;
    let t: Vec<f64> = plan.columns.t_ns.iter().map(|&t| rel(t)).collect();
    let rows = plan.columns.values.chunks_exact(width.max(1));
    match plan.group {
        Group::State => {
            let mut s = StateSeries {
                t,
                ..StateSeries::default()
            };
            for r in rows {
                s.q.push(joints(r, 0));
                s.dq.push(joints(r, 1));
                s.tau.push(joints(r, 2));
                s.temp.push(joints(r, 3));
                let o = 4 * N_JOINTS;
                s.gyro.push([r[o], r[o + 1], r[o + 2]]);
                s.quat.push([r[o + 3], r[o + 4], r[o + 5], r[o + 6]]);
            }
            rec.state = s;
        }
        Group::Command => {
            let mut c = CommandSeries {
                t,
                ..CommandSeries::default()
            };
            for r in rows {
                c.q.push(joints(r, 0));
                c.dq.push(joints(r, 1));
            }
            rec.command = c;
        }
        Group::Mbs | Group::Bms => {
            let watts = rows.map(|r| r[0] * r[1]).collect();
            let p = PowerSeries { t, watts };
            if plan.group == Group::Mbs {
                rec.mbs = p;
            } else {
                rec.bms = p;
            }
        }
    }
    Ok(())
}
