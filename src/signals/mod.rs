//! Named arm signals extracted from a recording: the bridge between topics/fields and
//! the physics. A [`Recording`] holds everything downstream stages need, column-wise.

use std::path::PathBuf;

use crate::N_JOINTS;

/// Joint-state samples (from `/lowstate`), one entry per message.
#[derive(Debug, Clone, Default)]
pub struct StateSeries {
    /// Time [s] since [`Recording::start_ns`].
    pub t: Vec<f64>,
    /// Joint positions [rad].
    pub q: Vec<[f64; N_JOINTS]>,
    /// Joint velocities [rad/s].
    pub dq: Vec<[f64; N_JOINTS]>,
    /// Estimated joint torques [Nm].
    pub tau: Vec<[f64; N_JOINTS]>,
    /// Motor winding temperatures [°C].
    pub temp: Vec<[f64; N_JOINTS]>,
    /// Body (pelvis IMU) angular velocity [rad/s].
    pub gyro: Vec<[f64; 3]>,
    /// Body orientation quaternion (w, x, y, z).
    pub quat: Vec<[f64; 4]>,
    /// Supply voltage of the arm's drives [V] (`motor_state[k].vol` of the arm's first motor):
    /// the bus current is P_elec / this voltage, which falls with the battery's charge.
    pub volts: Vec<f64>,
}

/// An operation applied alike to every column of a [`StateSeries`] (whatever its element type).
pub(crate) trait ColumnOp {
    /// Apply to one column (`from`: the same column of the other series, for the two-series
    /// walk [`StateSeries::zip_columns`]; empty for [`StateSeries::for_each_column`]).
    fn apply<T: Copy>(&mut self, to: &mut Vec<T>, from: &[T]);
}

impl StateSeries {
    /// `op` on every column, the time axis included: the one list of columns every
    /// whole-series operation goes through, so a new column is added in one place.
    pub(crate) fn zip_columns(&mut self, other: &StateSeries, op: &mut impl ColumnOp) {
        op.apply(&mut self.t, &other.t);
        op.apply(&mut self.q, &other.q);
        op.apply(&mut self.dq, &other.dq);
        op.apply(&mut self.tau, &other.tau);
        op.apply(&mut self.temp, &other.temp);
        op.apply(&mut self.gyro, &other.gyro);
        op.apply(&mut self.quat, &other.quat);
        op.apply(&mut self.volts, &other.volts);
    }

    /// `op` on every column alone.
    pub(crate) fn for_each_column(&mut self, op: &mut impl ColumnOp) {
        self.zip_columns(&StateSeries::default(), op);
    }

    /// Append samples `r` of every column of `from` (as far as each column reaches).
    pub(crate) fn extend_range(&mut self, from: &StateSeries, r: std::ops::Range<usize>) {
        struct Extend(std::ops::Range<usize>);
        impl ColumnOp for Extend {
            fn apply<T: Copy>(&mut self, to: &mut Vec<T>, from: &[T]) {
                let end = self.0.end.min(from.len());
                to.extend_from_slice(&from[self.0.start.min(end)..end]);
            }
        }
        self.zip_columns(from, &mut Extend(r));
    }

    /// Drop the samples before index `i` (of every column that has them).
    pub(crate) fn drain_front(&mut self, i: usize) {
        struct Drain(usize);
        impl ColumnOp for Drain {
            fn apply<T: Copy>(&mut self, v: &mut Vec<T>, _: &[T]) {
                v.drain(..self.0.min(v.len()));
            }
        }
        self.for_each_column(&mut Drain(i));
    }

    /// Reorder every full column by `order` (sample indices; the time axis too).
    pub(crate) fn permute(&mut self, order: &[usize]) {
        struct Permute<'a>(&'a [usize]);
        impl ColumnOp for Permute<'_> {
            fn apply<T: Copy>(&mut self, v: &mut Vec<T>, _: &[T]) {
                permute(v, self.0);
            }
        }
        self.for_each_column(&mut Permute(order));
    }

    /// Sort the samples by time (a file without an index may deliver them out of order).
    pub(crate) fn sort_by_time(&mut self) {
        if let Some(order) = time_order(&self.t) {
            self.permute(&order);
        }
    }

    /// The samples whose `keep` is true.
    pub(crate) fn select(&self, keep: &[bool]) -> StateSeries {
        let order: Vec<usize> = (0..self.t.len()).filter(|&i| keep[i]).collect();
        let mut out = StateSeries::default();
        struct Pick<'a>(&'a [usize]);
        impl ColumnOp for Pick<'_> {
            fn apply<T: Copy>(&mut self, to: &mut Vec<T>, from: &[T]) {
                to.extend(self.0.iter().filter_map(|&i| from.get(i).copied()));
            }
        }
        out.zip_columns(self, &mut Pick(&order));
        out
    }
}

/// Commanded joint references (from `/arm_sdk`).
#[derive(Debug, Clone, Default)]
pub struct CommandSeries {
    /// Time [s] since [`Recording::start_ns`].
    pub t: Vec<f64>,
    /// Commanded positions [rad].
    pub q: Vec<[f64; N_JOINTS]>,
    /// Commanded velocities [rad/s].
    pub dq: Vec<[f64; N_JOINTS]>,
}

/// A low-rate power sensor reading stream.
#[derive(Debug, Clone, Default)]
pub struct PowerSeries {
    /// Time [s] since [`Recording::start_ns`] (the sensor's own timestamps).
    pub t: Vec<f64>,
    /// Power [W].
    pub watts: Vec<f64>,
}

impl CommandSeries {
    /// Sort the commands by time (a file without an index may deliver a batch out of order).
    pub(crate) fn sort_by_time(&mut self) {
        if let Some(o) = time_order(&self.t) {
            permute(&mut self.t, &o);
            permute(&mut self.q, &o);
            permute(&mut self.dq, &o);
        }
    }
}

impl PowerSeries {
    /// Sort the readings by time (a file without an index may deliver a batch out of order).
    pub fn sort_by_time(&mut self) {
        if let Some(o) = time_order(&self.t) {
            permute(&mut self.t, &o);
            permute(&mut self.watts, &o);
        }
    }
}

/// The order (stable) that sorts the times `t`; `None` when they are sorted already.
fn time_order(t: &[f64]) -> Option<Vec<usize>> {
    (!t.is_sorted()).then(|| {
        let mut order: Vec<usize> = (0..t.len()).collect();
        order.sort_by(|&a, &b| t[a].total_cmp(&t[b]));
        order
    })
}

/// Reorder `v` by `order` (sample indices) when it is a full column (as long as `order`).
pub(crate) fn permute<T: Copy>(v: &mut Vec<T>, order: &[usize]) {
    if v.len() == order.len() {
        *v = order.iter().map(|&i| v[i]).collect();
    }
}

/// A session's arm signals, ready for identification, diagnosis and replay.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    /// File or bag directory the signals came from.
    pub source: PathBuf,
    /// Absolute time [ns since the Unix epoch] of the earliest message; all `t` are relative to it.
    pub start_ns: u64,
    /// URDF joint names of the 7 arm joints, in model order.
    pub joint_names: Vec<String>,
    /// Measured joint states and IMU.
    pub state: StateSeries,
    /// Commanded references (empty when the session has no command topic).
    pub command: CommandSeries,
    /// Main-board (arm/upper-body rail) power.
    pub mbs: PowerSeries,
    /// Battery (whole-robot) power.
    pub bms: PowerSeries,
    /// Problems met while reading (damage, NaNs, missing topics), each naming file/topic/offset.
    pub warnings: Vec<String>,
}

/// Which power sensor is the regression target.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Target {
    /// Main-board sensor: the arm/upper-body rail (the paper's choice, lower noise).
    Mbs,
    /// Battery management system: whole-robot power.
    Bms,
}

impl Target {
    /// The recording's power series for this target.
    pub fn series<'a>(&self, rec: &'a Recording) -> &'a PowerSeries {
        match self {
            Target::Mbs => &rec.mbs,
            Target::Bms => &rec.bms,
        }
    }

    /// Lower-case name ("mbs" / "bms").
    pub fn name(&self) -> &'static str {
        match self {
            Target::Mbs => "mbs",
            Target::Bms => "bms",
        }
    }
}

impl Recording {
    /// Appends `r`'s samples, readings and warnings, its times shifted by `offset` [s] (the
    /// source and start time stay this one's).
    pub fn append(&mut self, r: Recording, offset: f64) {
        let shift = |v: &[f64]| v.iter().map(|t| t + offset).collect::<Vec<_>>();
        let n = self.state.t.len();
        self.state.extend_range(&r.state, 0..usize::MAX);
        self.state.t[n..].iter_mut().for_each(|t| *t += offset);
        self.command.t.extend(shift(&r.command.t));
        self.command.q.extend(r.command.q);
        self.command.dq.extend(r.command.dq);
        self.mbs.t.extend(shift(&r.mbs.t));
        self.mbs.watts.extend(r.mbs.watts);
        self.bms.t.extend(shift(&r.bms.t));
        self.bms.watts.extend(r.bms.watts);
        self.warnings.extend(r.warnings);
    }
}

/// Join recordings end to end into one (e.g. several short sessions of one robot, to diagnose
/// them together): each part's times are shifted to start `gap_s` after the previous part's last
/// joint sample. Warnings are kept, the first part's source and start time are used.
pub fn join_recordings(parts: Vec<Recording>, gap_s: f64) -> Recording {
    let mut parts = parts.into_iter();
    let Some(mut out) = parts.next() else {
        return Recording::default();
    };
    for r in parts {
        let offset = out.state.t.last().copied().unwrap_or(0.0) + gap_s
            - r.state.t.first().copied().unwrap_or(0.0);
        out.append(r, offset);
    }
    out
}

mod load;
mod map;
pub mod plausible;
mod sink;
mod spill;

pub use load::{
    SeriesStats, SignalStats, StreamSummary, load_recording, signal_stats, stream_recording,
    stream_state,
};
pub use map::{
    G1_LEFT_ARM_BASE, G1_RIGHT_ARM_BASE, GROUPS, Group, JOINT_SHORT, SignalMap, SignalSpec,
    group_signals,
};
pub use sink::{RecordingSink, StreamHeader, stream_joined_into};
pub use spill::{SpillSlot, SpillWriter, StateSpill};
