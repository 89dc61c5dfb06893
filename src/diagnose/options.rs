//! The settings of a diagnosis ([`DiagnoseOptions`]) and their defaults.

use std::path::PathBuf;

use crate::power::PowerModel;
use crate::signals::Target;

use super::FieldSource;

/// Settings of a diagnosis.
#[derive(Debug, Clone)]
pub struct DiagnoseOptions {
    /// The twin's power model (e.g. a model.json identified earlier, or the paper's model). When
    /// given, the base model is held at it and the hypotheses explain the recording's departure
    /// from the twin (an effect that shifts every reading, like a warm motor, is visible). When
    /// absent, the base model is refitted on the training trials of every fold and the hypotheses
    /// must explain structure the 49 base parameters cannot absorb.
    pub reference: Option<PowerModel>,
    /// Power target.
    pub target: Target,
    /// Number of cross-validation folds (by trial).
    pub folds: usize,
    /// Significance level of the paired held-out test.
    pub alpha: f64,
    /// ΔBIC a hypothesis must beat (negative).
    pub bic_threshold: f64,
    /// Minimum relative held-out RMSE improvement.
    pub min_improvement: f64,
    /// Power sensor averaging window W [s] (a reading stamped t averages [t − W, t]).
    /// `None` (the default): estimated from the data by the (W, lag) alignment scan with the lag
    /// left to the latency hypothesis (see `diagnose/window.rs`); `Some(w)`: given.
    pub sensor_window_s: Option<f64>,
    /// Largest sensor latency scanned [s] (0 disables the latency hypothesis).
    pub max_lag_s: f64,
    /// IMU filter: reject trials whose σ_ω exceeds this multiple of the median.
    pub imu_threshold: f64,
    /// Passes of 3σ per-trial residual rejection.
    pub outlier_passes: usize,
    /// Cap on torque samples used at the torque level (evenly thinned beyond it).
    pub max_torque_samples: usize,
    /// URDF for the torque level (default: the shipped G1 left arm with hand).
    pub urdf: Option<PathBuf>,
    /// Compare torques and score the payload hypothesis.
    pub torque_level: bool,
    /// Search beyond the library ([`discover`]) when the library is done.
    pub discover: bool,
    /// Files whose every numeric field discovery reads (empty: the recording's own source when
    /// it is a file; joined recordings give one entry per part, see [`join_recordings_with_sources`]).
    pub field_sources: Vec<FieldSource>,
    /// SDK motor index of each arm joint (whose `motor_state[k]` fields belong to joint i).
    pub arm_motors: [usize; crate::N_JOINTS],
    /// The fields that meter the rail's current (`topic.field`: the main board's and the
    /// battery's, from the G1 signal map): consequences of every load on the rail, never a
    /// cause, so discovery and the rest-power stage never try them.
    pub meter_flows: Vec<String>,
}

impl DiagnoseOptions {
    /// The reference model's parameter vector, when there is one.
    pub(crate) fn reference_theta(&self) -> Option<Vec<f64>> {
        self.reference.map(|m| m.to_vector().to_vec())
    }
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        DiagnoseOptions {
            reference: None,
            target: Target::Mbs,
            folds: 10,
            alpha: 1e-3,
            bic_threshold: -10.0,
            min_improvement: 0.02,
            sensor_window_s: None,
            max_lag_s: 1.0,
            imu_threshold: 2.5,
            outlier_passes: 2,
            max_torque_samples: 60_000,
            urdf: None,
            torque_level: true,
            discover: true,
            field_sources: Vec::new(),
            arm_motors: std::array::from_fn(|i| crate::signals::G1_LEFT_ARM_BASE + i),
            meter_flows: {
                let map = crate::signals::SignalMap::g1_left_arm();
                ["mbs.current", "bms.current"]
                    .iter()
                    .filter_map(|k| map.signals.get(*k))
                    .map(|s| format!("{}.{}", s.topic, s.field))
                    .collect()
            },
        }
    }
}
