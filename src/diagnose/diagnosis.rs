//! What a diagnosis returns ([`Diagnosis`], serialised as diagnosis.json) and its parts: the
//! sensor window used, the lag scan, held-out quality, the final model.

use anyhow::Result;

use crate::signals::Target;
use crate::trial::Rejection;

use super::{
    Breakdown, Confounded, Correlate, DiscoveryReport, Group, HypothesisScore, MechanismForms,
    Param, ReplayData, TorqueComparison, TrialResidual,
};

/// Version of the `diagnosis.json` layout.
pub const SCHEMA_VERSION: u32 = 1;

/// The power sensor's averaging window the diagnosis used (a field missing from an older file
/// reads as its default).
#[derive(Debug, Clone, Copy, Default, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SensorWindow {
    /// Window W [s].
    pub window_s: f64,
    /// Estimated from the data (true) or given (false).
    pub estimated: bool,
    /// W of the best (W, lag ≥ 0) point of the alignment scan [s] (0 when W was given).
    pub scan_window_s: f64,
    /// Lag of that point [s] (the latency hypothesis judges a lag; this is only the scan's
    /// by-product). 0 when W was given.
    pub scan_lag_s: f64,
    /// Per-reading R² of the base regressors' least-squares fit at that point (0 when given:
    /// JSON has no NaN).
    pub scan_r2: f64,
    /// ΔBIC of freeing W against the nominal 0.2 s window at the same window centre (negative
    /// favours the free W; the nominal window is kept unless it beats the diagnosis' BIC
    /// threshold). 0 when W was given.
    pub window_delta_bic: f64,
    /// ΔBIC of freeing the lag against the best window at lag 0 near the same window centre
    /// (negative favours the lag; used only when the nominal window is rejected). 0 when W was
    /// given or the scan's best lag is 0.
    pub lag_delta_bic: f64,
    /// Whether a lagged point of the scan beats every window it scored at lag 0 (see
    /// `diagnose/window.rs`); only then may the latency hypothesis be claimed. True when W was
    /// given (the latency hypothesis alone judges the lag).
    pub lag_demanded: bool,
    /// Where the scan's best point is lagged or its readings demand a lag in-sample: p-value
    /// that the lagged point predicts held-out trials better than the best window at lag 0
    /// (per-trial squared errors; a lag needs p < 0.05 beside the in-sample rule).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lag_held_out: Option<f64>,
    /// Trials the scan used.
    pub scan_trials: usize,
    /// Change of the window over the session [s]: from the first scanned trial's start
    /// (`drift_from_s`, session time) to the last's (`drift_to_s`), linear between, `window_s`
    /// half-way; 0 when the window holds (see `diagnose/window.rs`).
    pub drift_s: f64,
    /// Session time where the drift starts [s].
    pub drift_from_s: f64,
    /// Session time where the drift ends [s].
    pub drift_to_s: f64,
    /// ΔBIC of the drift against the best constant window on the diagnosed meter.
    pub drift_delta_bic: f64,
    /// ΔBIC of the same drift against a constant window on the other meter (positive: the
    /// other meter rejects it).
    pub drift_other_delta_bic: f64,
    /// The drift is the diagnosed meter's artefact: the other meter rejects it.
    pub drift_artefact: bool,
}

/// Held-out quality of a model.
#[derive(Debug, Clone, Copy, Default, serde::Serialize, serde::Deserialize)]
pub struct Quality {
    /// Coefficient of determination.
    pub r2: f64,
    /// Root-mean-square error [W].
    pub rmse_w: f64,
}

/// One point of the sensor-lag scan.
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
pub struct LagPoint {
    /// Assumed latency [s].
    pub lag_s: f64,
    /// In-sample RMSE of the base model refitted at this lag [W].
    pub rmse_w: f64,
}

/// The model refitted with the accepted hypotheses.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct FinalModel {
    /// Accepted hypotheses, in the order they were added.
    pub hypotheses: Vec<String>,
    /// Their physical parameters with standard errors (jackknife over the folds).
    pub params: Vec<Param>,
    /// Base power-model θ (49) of the final refit (a, b, c, d, e order).
    pub theta: Vec<f64>,
    /// Held-out quality of the base model (per reading).
    pub before: Quality,
    /// Held-out quality with the accepted hypotheses (per reading).
    pub after: Quality,
    /// The same per trial (mean of each trial's readings), before.
    pub before_per_trial: Quality,
    /// The same per trial, after.
    pub after_per_trial: Quality,
}

/// Everything a diagnosis found (serialised as diagnosis.json, verdict first: the summary, what
/// was accepted and found, where the base model is wrong and what was tried; then the counts,
/// the supporting tables and the replay data).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Diagnosis {
    /// Layout version ([`SCHEMA_VERSION`]).
    pub schema_version: u32,
    /// Recording diagnosed.
    pub source: String,
    /// Power target.
    pub target: Target,
    /// Plain-language summary.
    pub summary: String,
    /// Accepted hypotheses in selection order, scored at their step.
    pub accepted: Vec<HypothesisScore>,
    /// The refit with the accepted hypotheses.
    pub final_model: FinalModel,
    /// Forms of each mechanism with several, compared with the same cross-validation.
    #[serde(default)]
    pub forms: Vec<MechanismForms>,
    /// Hypotheses forward selection accepted together that the data cannot tell apart.
    #[serde(default)]
    pub confounded: Vec<Confounded>,
    /// Discovery beyond the library (absent when switched off).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub discovery: Option<DiscoveryReport>,
    /// Where the base model is worst: (breakdown, group).
    pub worst: Option<(String, Group)>,
    /// Every hypothesis scored against the base model, ranked (1 = best).
    pub hypotheses: Vec<HypothesisScore>,
    /// Residual structure left after the final model: strongest correlates.
    pub unexplained: Vec<Correlate>,
    /// Trials used.
    pub n_trials: usize,
    /// Power readings used.
    pub n_readings: usize,
    /// Trials left out, with reasons.
    pub rejected: Vec<Rejection>,
    /// How the base model was obtained: `reference` (held at the twin's model) or `refit` (per fold).
    pub base_model: String,
    /// The power sensor's averaging window used for every reading's regressors.
    #[serde(default)]
    pub sensor_window: SensorWindow,
    /// Mean recorded motor supply voltage [V] (nominal where none is recorded); the bus-current
    /// form divides each sample's power by that sample's recorded voltage.
    #[serde(default)]
    pub bus_volts: f64,
    /// Torque level (absent without a robot model or torque data).
    pub torque: Option<TorqueComparison>,
    /// Sensor-lag scan of the base model.
    pub lag_scan: Vec<LagPoint>,
    /// Residual breakdowns of the base model (held out).
    pub breakdowns: Vec<Breakdown>,
    /// Trials with the largest held-out base residual.
    pub worst_trials: Vec<TrialResidual>,
    /// URDF joint names.
    pub joint_names: Vec<String>,
    /// Per-reading data for the replay.
    pub replay: ReplayData,
    /// Sample-by-sample comparison with a simulated counterpart, when one was given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub counterpart: Option<super::CounterpartComparison>,
}

impl Diagnosis {
    /// Write diagnosis.json (atomic).
    pub fn save_json(&self, path: &std::path::Path) -> Result<()> {
        let text = serde_json::to_string_pretty(self)?;
        crate::util::write_atomic(path, text.as_bytes())
    }
}
