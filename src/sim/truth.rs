//! Ground-truth sidecar (`<out>.truth.json`) of a simulated session, with the same structure as
//! the shared recordings' truth files where it applies (`shared/recordings/README.md`), plus the
//! enabled effects with their parameters.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::effects::Effects;
use super::thermal::ThermalModel;
use crate::N_JOINTS;

/// Who wrote the session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Generator {
    /// "g1viz".
    pub name: String,
    /// Crate version.
    pub version: String,
    /// Versions of the libraries that shaped the file.
    pub libraries: BTreeMap<String, String>,
}

/// Session time range.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionTimes {
    /// First message time [ns since the Unix epoch].
    pub start_ns: u64,
    /// Last message time [ns].
    pub end_ns: u64,
    /// end − start [s].
    pub duration_s: f64,
    /// Epoch the start offset is drawn from (ISO 8601).
    pub epoch: String,
    /// Number of trials.
    pub n_trials: usize,
}

/// A topic name and its type.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TopicEntry {
    /// Topic name.
    pub topic: String,
    /// Message type.
    #[serde(rename = "type")]
    pub type_name: String,
}

/// Joint names and SDK indices.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Joints {
    /// URDF joint names in model order.
    pub names: Vec<String>,
    /// Short names.
    pub short: Vec<String>,
    /// SDK motor indices.
    pub sdk_index: Vec<usize>,
}

/// Balance-contamination artefact settings and count.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Contamination {
    /// Whether it was on.
    pub enabled: bool,
    /// Target fraction of trials.
    pub target_fraction: f64,
    /// Sway amplitude range [rad/s].
    pub amplitude_range_rad_s: [f64; 2],
    /// Sway frequency range [Hz].
    pub freq_range_hz: [f64; 2],
    /// Leak gain [W/(rad/s)²].
    #[serde(rename = "k_leak_W_per_(rad/s)^2")]
    pub k_leak: f64,
    /// Number of contaminated trials.
    pub n_trials: usize,
    /// Formula.
    pub model: String,
}

/// Hardware-event outlier settings and count.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Outliers {
    /// Whether they were on.
    pub enabled: bool,
    /// Probability per trial.
    pub target_fraction: f64,
    /// Step size range [W].
    #[serde(rename = "step_W")]
    pub step_w: [f64; 2],
    /// Duration range [s].
    pub duration_s: [f64; 2],
    /// Number of outlier trials.
    pub n_trials: usize,
}

/// Session artefacts (present in every session, like the shared recordings).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ArtefactsTruth {
    /// Balance contamination.
    pub contamination: Contamination,
    /// Hardware-event outliers.
    pub outliers: Outliers,
}

/// The true power-model parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Theta {
    /// Parameter order.
    pub order: String,
    /// θ (49).
    pub vector: Vec<f64>,
    /// a_i.
    pub a: [f64; N_JOINTS],
    /// b_i.
    pub b: [f64; N_JOINTS],
    /// c_i.
    pub c: [f64; N_JOINTS],
    /// d_i.
    pub d: [f64; N_JOINTS],
    /// e_ij keyed "i,j".
    pub e: BTreeMap<String, f64>,
    /// Where θ came from.
    pub source: String,
}

/// Measurement noise levels (standard deviations).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Noise {
    /// Joint position [rad].
    pub q_rad: f64,
    /// Joint velocity [rad/s].
    pub dq_rad_s: f64,
    /// Joint torque [Nm].
    #[serde(rename = "tau_Nm")]
    pub tau_nm: f64,
    /// MBS reading [W].
    #[serde(rename = "mbs_W")]
    pub mbs_w: f64,
    /// BMS reading [W].
    #[serde(rename = "bms_W")]
    pub bms_w: f64,
    /// IMU gyro [rad/s].
    pub gyro_rad_s: f64,
}

impl Default for Noise {
    fn default() -> Self {
        Noise {
            q_rad: 1e-4,
            dq_rad_s: 0.003,
            tau_nm: 0.05,
            mbs_w: 0.3,
            bms_w: 1.5,
            gyro_rad_s: 0.002,
        }
    }
}

/// Power-sensor model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SensorTruth {
    /// Averaging window before each stamp [s].
    pub avg_window_s: f64,
    /// Nominal period [s].
    pub period_s: f64,
    /// Period jitter (uniform ±) [s].
    pub jitter_s: f64,
    /// Quantisation of the recorded fields.
    pub quantisation: String,
}

/// Joint friction inside the true torque.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrictionTruth {
    /// Coulomb torque [Nm].
    #[serde(rename = "coulomb_Nm")]
    pub coulomb_nm: [f64; N_JOINTS],
    /// Viscous coefficient [Nm·s/rad].
    #[serde(rename = "viscous_Nms")]
    pub viscous_nms: [f64; N_JOINTS],
    /// Formula.
    pub form: String,
}

/// Thermal model and the winding temperature range reached.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ThermalTruth {
    /// Constants.
    #[serde(flatten)]
    pub model: ThermalModel,
    /// Winding temperature at session start [°C].
    #[serde(rename = "T_start_C")]
    pub t_start_c: f64,
    /// Lowest and highest winding temperature in the session [°C].
    #[serde(rename = "winding_temp_range_C")]
    pub winding_temp_range_c: [f64; 2],
    /// Whether temperature changes power (the `thermal` effect).
    pub affects_power: bool,
}

/// Plant description.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlantTruth {
    /// Formula of the rail power.
    pub rail_power: String,
    /// MBS rest power [W].
    #[serde(rename = "P_rest_W")]
    pub p_rest_w: f64,
    /// Rest drift model.
    pub rest_drift: String,
    /// BMS model.
    pub bms: String,
    /// True home torque (gravity at q = 0, incl. payload) [Nm].
    #[serde(rename = "tau_home_Nm")]
    pub tau_home_nm: [f64; N_JOINTS],
    /// Friction inside τ.
    pub joint_friction_in_tau: FrictionTruth,
    /// Measured q lags the command by this [s].
    pub tracking_lag_s: f64,
    /// Noise levels.
    pub noise: Noise,
    /// Sensor model.
    pub sensor: SensorTruth,
    /// Thermal model.
    pub thermal: ThermalTruth,
    /// Payload at the hand (when the payload effect is on).
    pub payload: Option<crate::robot::Payload>,
    /// Session-mean power of each base-model term over all samples [W].
    #[serde(rename = "mean_power_components_W")]
    pub mean_power_components_w: BTreeMap<String, f64>,
    /// State-of-charge range.
    pub battery_soc_range: [f64; 2],
    /// Battery model (absent: the linear default, so older truth files read as it).
    #[serde(default, skip_serializing_if = "is_linear")]
    pub battery: super::Battery,
}

fn is_linear(b: &super::Battery) -> bool {
    *b == super::Battery::Linear
}

/// Protocol constants.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProtocolTruth {
    /// Pre-idle [s].
    pub pre_idle_s: f64,
    /// Post-idle [s].
    pub post_idle_s: f64,
    /// Return speed [rad/s].
    pub return_speed_rad_s: f64,
    /// Segment formula.
    pub segment: String,
    /// Identification speeds [rad/s].
    pub id_speeds: Vec<f64>,
    /// Hold-out speeds [rad/s].
    pub holdout_speeds: Vec<f64>,
    /// PD gains.
    pub kp: f64,
    /// PD gains.
    pub kd: f64,
    /// Gap between trials [s].
    pub inter_trial_gap_s: [f64; 2],
}

/// One trial of the session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrialTruth {
    /// Index in the session.
    pub index: usize,
    /// Route id.
    pub route_id: String,
    /// Route kind.
    pub route_kind: String,
    /// Moved joints (model indices).
    pub joints_moved: Vec<usize>,
    /// Moved joints (short names).
    pub joints_moved_names: Vec<String>,
    /// Speed level [rad/s].
    pub qdot_max: f64,
    /// Waypoints [rad].
    pub waypoints_rad: Vec<[f64; N_JOINTS]>,
    /// Pre-idle start [ns].
    pub t_trial_start_ns: u64,
    /// Trajectory start [ns].
    pub t_traj_start_ns: u64,
    /// Trajectory end [ns].
    pub t_traj_end_ns: u64,
    /// Post-idle end [ns].
    pub t_post_idle_end_ns: u64,
    /// Return end [ns].
    pub t_return_end_ns: u64,
    /// Balance contamination in this trial.
    pub contaminated: bool,
    /// Sway amplitude [rad/s].
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub sway_amplitude_rad_s: Option<f64>,
    /// Sway frequency [Hz].
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub sway_freq_hz: Option<f64>,
    /// Hardware-event outlier in this trial.
    pub outlier: bool,
    /// Outlier step [W].
    #[serde(
        rename = "outlier_step_W",
        skip_serializing_if = "Option::is_none",
        default
    )]
    pub outlier_step_w: Option<f64>,
    /// Outlier start [ns].
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub outlier_start_ns: Option<u64>,
    /// Outlier duration [s].
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub outlier_duration_s: Option<f64>,
    /// Mean true net arm power over the trajectory window (trajectory start → post-idle end),
    /// base model + effects, minus the trial's pre-idle mean [W].
    #[serde(rename = "true_net_arm_power_traj_mean_W")]
    pub true_net_arm_power_traj_mean_w: f64,
    /// The effects' share of it (incl. the payload's torque change) [W].
    #[serde(rename = "effect_power_traj_mean_W")]
    pub effect_power_traj_mean_w: f64,
    /// Mean balance-leak power over the window [W].
    #[serde(rename = "leak_power_traj_mean_W")]
    pub leak_power_traj_mean_w: f64,
    /// Mean winding temperature per joint over the window [°C].
    #[serde(rename = "winding_temp_traj_mean_C")]
    pub winding_temp_traj_mean_c: [f64; N_JOINTS],
}

/// Messages per topic.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MessageCounts {
    /// `/lowstate`.
    pub lowstate: u64,
    /// `/arm_sdk`.
    pub arm_sdk: u64,
    /// `/lf/bmsstate`.
    pub bms: u64,
    /// `/lf/mainboardstate`.
    pub mbs: u64,
}

/// The whole truth sidecar.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Truth {
    /// Writer identity.
    pub generator: Generator,
    /// Preset name (or "like" for `simulate_like`).
    pub preset: String,
    /// RNG seed.
    pub seed: u64,
    /// `/lowstate` rate [Hz].
    pub rate_hz: f64,
    /// URDF the dynamics came from.
    pub urdf: String,
    /// Time range.
    pub session: SessionTimes,
    /// Output files.
    pub files: BTreeMap<String, serde_json::Value>,
    /// Topics by role.
    pub topics: BTreeMap<String, TopicEntry>,
    /// Joints.
    pub joints: Joints,
    /// Concealed effects switched on, with their parameters.
    pub effects: Effects,
    /// Session artefacts.
    pub artefacts: ArtefactsTruth,
    /// True power-model parameters.
    pub theta: Theta,
    /// Plant.
    pub plant: PlantTruth,
    /// Protocol.
    pub protocol: ProtocolTruth,
    /// Trials.
    pub trials: Vec<TrialTruth>,
    /// Messages per topic.
    pub message_counts: MessageCounts,
}

impl Truth {
    /// Read a truth sidecar (ours; the shared ones have extra fields and are read as JSON values).
    pub fn load(path: &std::path::Path) -> anyhow::Result<Truth> {
        use anyhow::Context;
        let text = crate::util::read_text_input(path)
            .with_context(|| format!("reading {}", path.display()))?;
        serde_json::from_str(&text)
            .with_context(|| format!("parsing truth file {}", path.display()))
    }
}
