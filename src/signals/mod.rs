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

mod load;
mod map;

pub use load::{StreamSummary, load_recording, stream_recording};
pub use map::{
    G1_LEFT_ARM_BASE, G1_RIGHT_ARM_BASE, GROUPS, Group, JOINT_SHORT, SignalMap, SignalSpec,
    group_signals,
};
