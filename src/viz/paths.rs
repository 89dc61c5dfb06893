//! Every entity path g1viz logs to, in one table: the replay writes them, the blueprint queries
//! them and the tests read them back, all through these names.
//!
//! `<j>` is a joint's short name ([`super::short_joint_name`]), `<term>` one of [`TERMS`].

/// The robot (model root, oriented by the recorded IMU quaternion); links below it.
pub const ROBOT: &str = "robot";
/// Per-joint signal `q`, `q_cmd`, `dq`, `tau` or `temperature`.
pub fn joint(j: &str, signal: &str) -> String {
    format!("joints/{j}/{signal}")
}
/// Raw readings of a power sensor (`"mbs"` / `"bms"`) [W].
pub fn power_raw(sensor: &str) -> String {
    format!("power/{sensor}/raw")
}
/// Net readings of a power sensor (minus the idle baseline before the arm first moves) [W].
pub fn power_net(sensor: &str) -> String {
    format!("power/{sensor}/net")
}
/// |ω| of the body [rad/s] per sample.
pub const IMU_GYRO_NORM: &str = "imu/gyro_norm";
/// The IMU filter's statistic σ|ω| per trial, held over the trial's window [rad/s].
pub const IMU_SIGMA: &str = "imu/sigma_per_trial";
/// The IMU filter's threshold (k × median σ|ω|) [rad/s].
pub const IMU_THRESHOLD: &str = "imu/threshold";

/// Measured net power per reading (net of the trial's pre-idle) [W].
pub const MODEL_READING_MEASURED: &str = "model/power/reading_measured";
/// The model's prediction averaged over each reading's own window, at the reading [W].
pub const MODEL_READING_PREDICTED: &str = "model/power/reading_predicted";
/// The instantaneous per-sample prediction (context only) [W].
pub const MODEL_PREDICTED: &str = "model/power/predicted";
/// Error measured − predicted per reading, like for like [W].
pub const MODEL_ERROR_READING: &str = "model/error/reading";
/// The same, for the readings of trials a filter rejected.
pub const MODEL_ERROR_READING_REJECTED: &str = "model/error/reading_rejected";
/// Error per trajectory (mean reading − mean like-for-like prediction) [W].
pub const MODEL_ERROR_TRAJECTORY: &str = "model/error/trajectory";
/// The same, for rejected trials.
pub const MODEL_ERROR_TRAJECTORY_REJECTED: &str = "model/error/trajectory_rejected";
/// The loss terms of the model, in display order.
pub const TERMS: [&str; 4] = ["mechanical", "copper", "coulomb", "viscous"];
/// One loss term of one joint [W].
pub fn term(j: &str, term: &str) -> String {
    format!("model/terms/{j}/{term}")
}
/// Σ e_ij |q̇_i||q̇_j| [W].
pub const TERM_INTERACTION: &str = "model/terms/interaction/total";
/// Below this: one series per term, summed over the joints (and the interaction).
pub const BY_TERM: &str = "model/by_term";
/// A term summed over the joints [W] (`"interaction"` too).
pub fn by_term(term: &str) -> String {
    format!("model/by_term/{term}")
}
/// A joint's four terms summed [W].
pub fn by_joint(j: &str) -> String {
    format!("model/by_joint/{j}")
}
/// Below this: per-trial bars, one series per joint (its mean power over each trial's
/// trajectory [W], drawn as a bar in the joint's slot of the trial's window).
pub const BARS_BY_JOINT: &str = "model/bars/by_joint";
/// Per-trial bars of joint `j` [W].
pub fn bar_by_joint(j: &str) -> String {
    format!("{BARS_BY_JOINT}/{j}")
}
/// Below this: per-trial bars, one series per term (joints summed; `interaction` too) [W].
pub const BARS_BY_TERM: &str = "model/bars/by_term";
/// The invisible bars under each bar tree that fix the chart's extent (see `layers`).
pub const BAR_AXIS: &str = "x_axis_extent";
/// Per-trial bars of term `term` [W].
pub fn bar_by_term(term: &str) -> String {
    format!("{BARS_BY_TERM}/{term}")
}
/// What the breakdown views show (text, markdown).
pub const BREAKDOWN_NOTE: &str = "model/note";

/// Below this: what is known about the trials of `prefix` ("trials" or "diagnosis/trials").
pub fn trials_log(prefix: &str) -> String {
    format!("{prefix}/log")
}
/// Below this: the marked trials' spans of `prefix` (`kind` as in [`trial_span`]).
pub fn trial_spans(prefix: &str, kind: &str) -> String {
    format!("{prefix}/{kind}")
}
/// The trials of the replay.
pub const TRIALS: &str = "trials";
/// Each trial's rest power (pre-idle mean) at its trajectory's end [W].
pub const TRIAL_REST: &str = "trials/rest_power";
/// Below this: one point per marked trial of `prefix` at its start (`rejected` at 1, `located`
/// at 2), the overview's strip of a long session.
pub fn trial_strip(prefix: &str) -> String {
    format!("{prefix}/strip")
}
/// Per-trial means of the diagnosis' error (`before`, `after`, `found`), at each trial's first
/// reading [W].
pub fn diag_trial_error(which: &str) -> String {
    format!("diagnosis/per_trial/{which}")
}
/// Per-trial means of the diagnosis' rest power (`measured`, `found`; `""`: the tree) [W].
pub fn diag_trial_rest(which: &str) -> String {
    format!("diagnosis/per_trial_rest/{which}")
        .trim_end_matches('/')
        .to_owned()
}
/// Index of the trial under way (step series held from each trial's start to the next).
pub const TRIAL_INDEX: &str = "trials/index";

/// Measured net power per reading the diagnosis used [W].
pub const DIAG_MEASURED: &str = "diagnosis/power/measured";
/// Base-model prediction [W].
pub const DIAG_BEFORE: &str = "diagnosis/power/before";
/// Prediction with the accepted hypotheses [W].
pub const DIAG_AFTER: &str = "diagnosis/power/after";
/// Prediction with the terms found beyond the library [W].
pub const DIAG_FOUND: &str = "diagnosis/power/found";
/// Error with the found terms [W].
pub const DIAG_ERROR_FOUND: &str = "diagnosis/error/found";
/// Below this: the recorded fields the found terms follow.
pub const DIAG_LOCATED: &str = "diagnosis/located";
/// The `k`-th recorded field a found term follows, per reading.
pub fn diag_located(k: usize) -> String {
    format!("diagnosis/located/{k}")
}
/// Below this: the meter's averaging window at each reading, where it drifts (`drifting`), and
/// the alignment scan's one window (`fixed`) [s].
pub const DIAG_WINDOW: &str = "diagnosis/window";
/// Below this: the rest power of each reading's trial and its prediction.
pub const DIAG_REST: &str = "diagnosis/rest";
/// Rest power of each reading's trial (its pre-idle mean) [W].
pub const DIAG_REST_MEASURED: &str = "diagnosis/rest/measured";
/// Held-out rest power with the loads found on it [W].
pub const DIAG_REST_FOUND: &str = "diagnosis/rest/found";
/// The twin's net power on the recording's commands [W].
pub const DIAG_TWIN: &str = "diagnosis/power/twin";
/// Error of the base model [W].
pub const DIAG_ERROR_BEFORE: &str = "diagnosis/error/before";
/// Error with the accepted hypotheses [W].
pub const DIAG_ERROR_AFTER: &str = "diagnosis/error/after";
/// Trials where the mismatch is located.
pub const DIAG_TRIALS: &str = "diagnosis/trials";
/// τ recording − twin of a joint [Nm].
pub fn diag_torque(j: &str) -> String {
    format!("diagnosis/torque/{j}")
}
/// Below this: the torque differences.
pub const DIAG_TORQUE: &str = "diagnosis/torque";
/// The diagnosis summary (markdown).
pub const DIAG_SUMMARY: &str = "diagnosis/summary";

/// A blueprint query that includes `path` (and nothing below it).
pub fn include(path: &str) -> String {
    format!("+ /{path}")
}
/// A blueprint query that includes `path` and everything below it.
pub fn include_tree(path: &str) -> String {
    format!("+ /{path}/**")
}

/// The recording's properties (name and start time; ours below it, in `__properties/g1viz`).
pub const PROPERTIES: &str = "__properties";
/// The IMU statistic of the trials it rejected [rad/s].
pub const IMU_SIGMA_REJECTED: &str = "imu/sigma_rejected";
/// The span of one marked trial `k` (a thick segment on the trial track at height `k`):
/// `kind` is `rejected` (filters) or `located` (diagnosis).
pub fn trial_span(prefix: &str, kind: &str, k: usize) -> String {
    format!("{prefix}/{kind}/{k}")
}
