//! The per-trial table: each trial's mean measured net power against the model's prediction,
//! like for like (averaged over the readings' own windows) and the paper's way (over the whole
//! trajectory window), and metrics over such a table.

use super::dataset::{Dataset, Row};
use super::fit::predict;
use crate::N_PARAMS;
use crate::lsq::Metrics;
use crate::trial::Segmentation;

/// Per-trial measured vs predicted mean net power over the trajectory window.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TrialPrediction {
    /// Session index in the input list.
    pub session: usize,
    /// Trial index.
    pub trial: usize,
    /// Trajectory window [s].
    pub window: (f64, f64),
    /// Joints moved.
    pub joints_moved: Vec<usize>,
    /// Peak commanded speed [rad/s].
    pub qdot_max_cmd: f64,
    /// Mean measured net power of the readings inside the trajectory window [W].
    pub measured_w: f64,
    /// Predicted net power averaged over those readings' own windows [W] (like for like with `measured_w`).
    pub predicted_w: f64,
    /// Predicted mean net power over the whole trajectory window [W] (the paper's aggregate).
    pub predicted_window_w: f64,
    /// σ_ω [rad/s].
    pub sigma_omega: f64,
    /// Rejected by a filter (identification) or flagged by the IMU criterion (validation).
    pub rejected: bool,
    /// The trial's rest power: the mean of its pre-idle readings, taken off every reading [W].
    #[serde(default)]
    pub rest_w: f64,
}

/// One power reading of a usable trial next to the model's prediction averaged over the
/// reading's own window (like for like): a row of the per-reading metrics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReadingFit {
    /// Trial index.
    pub trial: usize,
    /// Reading stamp [s since the session start].
    pub t: f64,
    /// Measured net power (reading minus its trial's pre-idle mean) [W].
    pub measured_w: f64,
    /// Prediction averaged over the reading's window [W].
    pub predicted_w: f64,
}

/// Per-trial measured vs predicted from a trial's reading rows (like for like) and its trial row
/// (the paper's whole-window aggregate).
pub(crate) fn trial_predictions(
    session: usize,
    seg: &Segmentation,
    readings: &Dataset,
    windows: &Dataset,
    theta: &[f64; N_PARAMS],
    rejected: impl Fn(usize) -> bool,
) -> Vec<TrialPrediction> {
    let mut out: Vec<TrialPrediction> = Vec::new();
    for basis in &readings.trials {
        let rows: Vec<&Row> = readings
            .rows
            .iter()
            .filter(|r| r.trial == basis.trial)
            .collect();
        let (Some(trial), Some(window_row)) = (
            seg.trials.iter().find(|t| t.index == basis.trial),
            windows.rows.iter().find(|r| r.trial == basis.trial),
        ) else {
            continue;
        };
        let n = rows.len().max(1) as f64;
        out.push(TrialPrediction {
            session,
            trial: basis.trial,
            window: basis.window,
            joints_moved: trial.joints_moved.clone(),
            qdot_max_cmd: trial.qdot_max_cmd,
            measured_w: rows.iter().map(|r| r.y).sum::<f64>() / n,
            predicted_w: rows.iter().map(|r| predict(theta, &r.phi)).sum::<f64>() / n,
            predicted_window_w: predict(theta, &window_row.phi),
            sigma_omega: basis.sigma_omega,
            rejected: rejected(basis.trial),
            rest_w: basis.baseline_w,
        });
    }
    out
}

pub(crate) fn trial_metrics(
    table: &[&TrialPrediction],
    predicted: impl Fn(&TrialPrediction) -> f64,
) -> Metrics {
    let y: Vec<f64> = table.iter().map(|p| p.measured_w).collect();
    let yhat: Vec<f64> = table.iter().map(|p| predicted(p)).collect();
    Metrics::compute(&y, &yhat)
}
