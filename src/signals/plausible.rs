//! Plausibility limits per signal and clock checks for the loader: one absurd value (a torque
//! of 3e38 N·m, a temperature of 10 000 °C) or one message stamped at log time 0 would otherwise
//! pass into the fit (an infeasible solve) or stretch the session over decades.
//!
//! Samples beyond their signal's physical limit are dropped, with one warning per signal naming
//! topic, field, count and the first one's time and value. Per topic, log times before 2000
//! (an unset clock), backward jumps of more than a second and forward gaps of more than an hour
//! give one warning each naming topic and time; when the recording's topics run on a wall clock
//! (some message after 2000), samples stamped before 2000 are dropped as well.

use std::collections::{BTreeMap, HashMap};

use super::map::{GROUPS, Group, SignalMap, group_signals};
use crate::read::{FieldPath, Session};

/// 2000-01-01T00:00:00Z [ns since the Unix epoch]: earlier log times mean an unset clock.
pub const WALL_CLOCK_FLOOR_NS: u64 = 946_684_800_000_000_000;
/// Largest forward gap between consecutive messages of a topic before a warning [ns].
pub const MAX_GAP_NS: u64 = 3_600_000_000_000;
/// Largest backward jump between consecutive messages of a topic before a warning [ns].
pub const MAX_BACKWARD_NS: u64 = 1_000_000_000;
/// Largest plausible |joint torque| [N·m].
pub const MAX_TORQUE_NM: f64 = 1e4;
/// Largest plausible |joint or body angular velocity| [rad/s].
pub const MAX_RATE_RAD_S: f64 = 1e3;
/// Largest plausible |joint position| [rad] (a few hundred turns).
pub const MAX_ANGLE_RAD: f64 = 1e3;
/// Plausible winding temperatures [°C].
pub const TEMPERATURE_RANGE_C: (f64, f64) = (-50.0, 250.0);
/// Largest plausible |electrical power| of a sensor [W].
pub const MAX_POWER_W: f64 = 1e5;
/// Largest plausible |quaternion component| (1 when normalised).
pub const MAX_QUATERNION: f64 = 10.0;

/// The accepted range of one signal, and how a warning names it.
#[derive(Debug, Clone, Copy)]
struct Limit {
    lo: f64,
    hi: f64,
    what: &'static str,
}

fn limit(name: &str) -> Option<Limit> {
    let sym = |m: f64, what| Limit {
        lo: -m,
        hi: m,
        what,
    };
    let kind = name.split('.').next().unwrap_or("");
    Some(match kind {
        "q" | "cmd_q" => sym(MAX_ANGLE_RAD, "beyond ±1e3 rad"),
        "dq" | "cmd_dq" | "gyro" => sym(MAX_RATE_RAD_S, "beyond ±1e3 rad/s"),
        "tau" => sym(MAX_TORQUE_NM, "beyond ±1e4 N·m"),
        "temp" => Limit {
            lo: TEMPERATURE_RANGE_C.0,
            hi: TEMPERATURE_RANGE_C.1,
            what: "outside −50…250 °C",
        },
        "quat" => sym(MAX_QUATERNION, "beyond ±10 (a unit quaternion)"),
        _ => return None,
    })
}

/// Samples dropped for one signal: count, and the first one's log time and value.
#[derive(Debug, Clone, Copy)]
struct Dropped {
    count: u64,
    first_ns: u64,
    first_value: f64,
}

/// Per topic: the previous log time and what its clock did.
#[derive(Debug, Default)]
struct TopicClock {
    last_ns: Option<u64>,
    /// (count, first log time, how many were dropped) of samples before 2000.
    early: (u64, u64, u64),
    /// (count, first jump size, its log time) of backward jumps.
    backward: (u64, u64, u64),
    /// (count, first gap size, its log time) of forward gaps.
    gaps: (u64, u64, u64),
}

/// The checks of one load: built from the signal map (and the session's time range), fed every
/// decoded, scaled sample, and asked for its warnings at the end.
pub struct Plausible {
    file: String,
    /// Per group ([`GROUPS`] order): signal name and limit of each row value.
    signals: Vec<Vec<(String, Option<Limit>)>>,
    /// Samples before 2000 are dropped (the recording runs on a wall clock, says its index).
    drop_early: bool,
    /// A sample after 2000 has been read (then later samples before 2000 are dropped too).
    wall_clock_seen: bool,
    dropped: BTreeMap<(usize, usize), Dropped>,
    /// (group, field) → the field path, for warnings.
    paths: HashMap<(usize, usize), String>,
    /// Per topic (a handful: searched in a line, cheaper per sample than a map lookup).
    clocks: Vec<(String, TopicClock)>,
}

/// Pseudo field index of a power sensor's voltage × current product.
const POWER: usize = usize::MAX;

impl Plausible {
    /// Checks for loading `map`'s signals from `session` (`file` names it in warnings). The
    /// session's topic list (its summary or index) says whether any mapped topic runs on a
    /// wall clock.
    pub fn new(file: &str, map: &SignalMap, session: &mut Session) -> Plausible {
        let signals = GROUPS
            .iter()
            .map(|&g| {
                group_signals(g)
                    .into_iter()
                    .filter(|n| map.signals.contains_key(n))
                    .map(|n| {
                        let l = limit(&n);
                        (n, l)
                    })
                    .collect()
            })
            .collect();
        let topics: Vec<&str> = map.signals.values().map(|s| s.topic.as_str()).collect();
        // Only from a summary, an index or the chunk headers: a file is not read twice for this;
        // without any, early samples are dropped once a wall-clock one has been seen.
        let drop_early = (session.info_is_cheap()
            && session.info().is_ok_and(|info| {
                info.topics
                    .iter()
                    .any(|t| topics.contains(&t.topic.as_str()) && t.last_ns >= WALL_CLOCK_FLOOR_NS)
            }))
            || session
                .latest_time_hint()
                .is_some_and(|t| t >= WALL_CLOCK_FLOOR_NS);
        Plausible {
            file: file.to_string(),
            signals,
            drop_early,
            wall_clock_seen: false,
            dropped: BTreeMap::new(),
            paths: HashMap::new(),
            clocks: Vec::new(),
        }
    }

    /// Whether to keep one scaled sample of group `gi` (values in the group's signal order,
    /// field paths `paths`) from `topic` at `t_ns`.
    pub fn keep(
        &mut self,
        gi: usize,
        topic: &str,
        paths: &[FieldPath],
        row: &[f64],
        t_ns: u64,
    ) -> bool {
        if !self.clock(topic, t_ns) {
            return false;
        }
        let bad = self.signals.get(gi).and_then(|signals| {
            row.iter()
                .zip(signals)
                .position(|(&v, (_, l))| l.is_some_and(|l| !(l.lo..=l.hi).contains(&v)))
        });
        let power_group = matches!(GROUPS.get(gi), Some(Group::Mbs | Group::Bms));
        let bad = bad.or_else(|| {
            (power_group && row.len() >= 2 && (row[0] * row[1]).abs() > MAX_POWER_W)
                .then_some(POWER)
        });
        let Some(k) = bad else {
            return true;
        };
        let value = if k == POWER { row[0] * row[1] } else { row[k] };
        self.paths.entry((gi, k)).or_insert_with(|| {
            let field = |i: usize| paths.get(i).map(ToString::to_string).unwrap_or_default();
            if k == POWER {
                format!("{topic} fields {} × {}", field(0), field(1))
            } else {
                format!("{topic} field {}", field(k))
            }
        });
        self.dropped
            .entry((gi, k))
            .and_modify(|d| d.count += 1)
            .or_insert(Dropped {
                count: 1,
                first_ns: t_ns,
                first_value: value,
            });
        false
    }

    /// Track `topic`'s clock; false when the sample is to be dropped (before 2000 on a
    /// recording that runs on a wall clock).
    fn clock(&mut self, topic: &str, t_ns: u64) -> bool {
        let i = match self.clocks.iter().position(|(t, _)| t == topic) {
            Some(i) => i,
            None => {
                self.clocks.push((topic.to_string(), TopicClock::default()));
                self.clocks.len() - 1
            }
        };
        let c = &mut self.clocks[i].1;
        if t_ns < WALL_CLOCK_FLOOR_NS {
            if c.early.0 == 0 {
                c.early.1 = t_ns;
            }
            c.early.0 += 1;
            if self.drop_early || self.wall_clock_seen {
                c.early.2 += 1;
                return false;
            }
        } else {
            self.wall_clock_seen = true;
        }
        if let Some(last) = c.last_ns {
            let note = |slot: &mut (u64, u64, u64), size: u64| {
                if slot.0 == 0 {
                    (slot.1, slot.2) = (size, t_ns);
                }
                slot.0 += 1;
            };
            if t_ns.saturating_add(MAX_BACKWARD_NS) < last {
                note(&mut c.backward, last - t_ns);
            } else if t_ns > last.saturating_add(MAX_GAP_NS) {
                note(&mut c.gaps, t_ns - last);
            }
        }
        c.last_ns = Some(t_ns);
        true
    }

    /// The warnings: one per signal with dropped samples, one per clock problem per topic.
    pub fn warnings(&self) -> Vec<String> {
        let file = &self.file;
        let mut out = Vec::new();
        for (&(gi, k), d) in &self.dropped {
            let (name, what) = if k == POWER {
                let sensor = if GROUPS.get(gi) == Some(&Group::Bms) {
                    "bms"
                } else {
                    "mbs"
                };
                (format!("{sensor} power"), "beyond ±1e5 W")
            } else {
                let (name, l) = &self.signals[gi][k];
                (name.clone(), l.map_or("", |l| l.what))
            };
            out.push(format!(
                "{file}: topic {} ({name}): {} implausible sample{} {what} dropped (first at log time {} ns: {:.3e})",
                self.paths.get(&(gi, k)).map_or("", String::as_str),
                d.count,
                if d.count == 1 { "" } else { "s" },
                d.first_ns,
                d.first_value
            ));
        }
        let mut clocks: Vec<&(String, TopicClock)> = self.clocks.iter().collect();
        clocks.sort_by(|a, b| a.0.cmp(&b.0));
        for (topic, c) in clocks {
            if c.early.2 > 0 {
                out.push(format!(
                    "{file}: topic {topic}: {} message(s) stamped before 2000 (first at log time {} ns) in a recording on a wall clock: dropped (a recorder whose clock was not set?)",
                    c.early.2, c.early.1
                ));
            }
            if c.early.0 > c.early.2 {
                out.push(if self.wall_clock_seen {
                    format!(
                        "{file}: topic {topic}: {} message(s) stamped before 2000 (first at log time {} ns) kept: read before the first wall-clock time, and the file has no index to tell",
                        c.early.0 - c.early.2,
                        c.early.1
                    )
                } else {
                    format!(
                        "{file}: topic {topic}: log times before 2000 (first {} ns): the recording is not on a wall clock",
                        c.early.1
                    )
                });
            }
            if c.backward.0 > 0 {
                out.push(format!(
                    "{file}: topic {topic}: log time jumps back by {:.3} s at log time {} ns ({} backward jump(s) of more than 1 s)",
                    c.backward.1 as f64 * 1e-9,
                    c.backward.2,
                    c.backward.0
                ));
            }
            if c.gaps.0 > 0 {
                out.push(format!(
                    "{file}: topic {topic}: no message for {:.2} h before log time {} ns ({} gap(s) of more than 1 h)",
                    c.gaps.1 as f64 / 3.6e12,
                    c.gaps.2,
                    c.gaps.0
                ));
            }
        }
        out
    }
}
