//! One trial's time window: the five protocol boundaries, what moved and how fast, and the one
//! rule by which identification and diagnosis pair a power reading with the samples it averages
//! and take a trial's baseline ([`samples_in`], [`readings_within`], [`TrialWindow::pre_idle`],
//! [`TrialWindow::baseline_readings`]).
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

/// Fewest joint-state samples a reading's window needs to give a row (fewer: a gap in the joint
/// stream, and no mean worth fitting).
pub const MIN_WINDOW_SAMPLES: usize = 2;

/// Fewest joint-state samples a trial's pre-idle needs for its baseline (the pre-idle mean τ²
/// every Δτ² is taken against).
pub const MIN_PRE_IDLE_SAMPLES: usize = 3;

/// The samples of the sorted times `t` inside the window (a, b]: a reading stamped at `b` (after
/// its lag) has seen the sample at `b` but not the one at `a`, the previous window's last.
pub fn samples_in(t: &[f64], a: f64, b: f64) -> std::ops::Range<usize> {
    let i0 = t.partition_point(|&x| x <= a);
    let i1 = t.partition_point(|&x| x <= b);
    i0..i1.max(i0)
}

/// The readings of the sorted stamps `pt` whose averaging window [t − lag − W, t − lag] lies
/// inside [a, b]: stamps in [a + W + lag, b + lag].
pub fn readings_within(pt: &[f64], a: f64, b: f64, lag: f64, width: f64) -> std::ops::Range<usize> {
    let i0 = pt.partition_point(|&x| x < a + width + lag);
    let i1 = pt.partition_point(|&x| x <= b + lag);
    i0..i1.max(i0)
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
    /// A test trial with the five boundaries `times` (pre-idle start, trajectory start and end,
    /// post-idle end, return end) that moved joint 0 at 1 rad/s.
    #[cfg(test)]
    pub(crate) fn for_test(index: usize, times: [f64; 5]) -> TrialWindow {
        let [
            t_pre_start,
            t_traj_start,
            t_traj_end,
            t_post_end,
            t_return_end,
        ] = times;
        TrialWindow {
            index,
            t_pre_start,
            t_traj_start,
            t_traj_end,
            t_post_end,
            t_return_end,
            joints_moved: vec![0],
            qdot_max_cmd: 1.0,
            qdot_max_meas: 1.0,
        }
    }

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

    /// Its pre-idle samples of the sorted times `t` ([`samples_in`] the pre-idle), `None` when
    /// fewer than [`MIN_PRE_IDLE_SAMPLES`]: the trial has no baseline.
    pub fn pre_idle(&self, t: &[f64]) -> Option<std::ops::Range<usize>> {
        let r = samples_in(t, self.t_pre_start, self.t_traj_start);
        (r.len() >= MIN_PRE_IDLE_SAMPLES).then_some(r)
    }

    /// Its baseline readings at sensor lag `lag` and window `width` ([`readings_within`] the
    /// pre-idle): without the lag, a lagging sensor's first baseline readings would average the
    /// previous trial's motion.
    pub fn baseline_readings(&self, pt: &[f64], lag: f64, width: f64) -> std::ops::Range<usize> {
        readings_within(pt, self.t_pre_start, self.t_traj_start, lag, width)
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
