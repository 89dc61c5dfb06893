//! One trial's time window: the five protocol boundaries, what moved and how fast.
//!
//! The same type is produced by the segmenter (from the data), by the simulator (from its
//! schedule) and read by identification, diagnosis and the viewer.

use serde::{Deserialize, Serialize};

/// One trial of the paper's protocol: pre-idle at home → trajectory → post-idle → return home.
/// Times in seconds of Recording time (same meaning as the truth JSON's `t_trial_start_ns`,
/// `t_traj_start_ns`, `t_traj_end_ns`, `t_post_idle_end_ns`, `t_return_end_ns`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrialWindow {
    /// Position of the trial in the session (0-based, counting matched trials only).
    pub index: usize,
    /// Start of the pre-idle window used for baselines.
    pub t_pre_start: f64,
    /// Start of the trajectory (end of the pre-idle).
    pub t_traj_start: f64,
    /// End of the trajectory (start of the post-idle).
    pub t_traj_end: f64,
    /// End of the post-idle (start of the return).
    pub t_post_end: f64,
    /// End of the return home.
    pub t_return_end: f64,
    /// Model indices of the joints that moved during the trajectory.
    pub joints_moved: Vec<usize>,
    /// Peak commanded joint speed over the trajectory [rad/s] (the speed level); NaN without a command stream.
    pub qdot_max_cmd: f64,
    /// Peak measured joint speed over the trajectory [rad/s] (3-sample mean of |q̇|); NaN when not measured.
    pub qdot_max_meas: f64,
}

/// Where in a trial a time lies (after the pre-idle).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Phase {
    /// Moving through the route.
    Trajectory,
    /// Holding the final posture.
    PostIdle,
    /// Returning home.
    Return,
}

impl TrialWindow {
    /// The trial's speed level [rad/s]: the commanded peak when known, else the measured one.
    pub fn speed_level(&self) -> f64 {
        if self.qdot_max_cmd.is_finite() {
            self.qdot_max_cmd
        } else {
            self.qdot_max_meas
        }
    }

    /// The window the paper's per-trial quantities are taken over: trajectory + post-idle.
    pub fn analysis_window(&self) -> (f64, f64) {
        (self.t_traj_start, self.t_post_end)
    }

    /// Phase at time `t` (None before the trajectory or after the return).
    pub fn phase_at(&self, t: f64) -> Option<Phase> {
        if t < self.t_traj_start || t > self.t_return_end {
            None
        } else if t < self.t_traj_end {
            Some(Phase::Trajectory)
        } else if t < self.t_post_end {
            Some(Phase::PostIdle)
        } else {
            Some(Phase::Return)
        }
    }
}
