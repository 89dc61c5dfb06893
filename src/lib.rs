//! g1viz: replay, identify and diagnose the electrical power of the Unitree G1 arm.
//!
//! Data flows one way through one module per stage:
//!
//! ```text
//! read (MCAP, ROS 2 .db3, ROS 1 .bag; schema-driven decoding)
//!   → signals (named arm signals: q, dq, tau, temperature, IMU, MBS/BMS power)
//!   → trial (trial windows, segmentation, the IMU and n·σ filters)
//!   → session (a session's trials read one by one in bounded memory, from files or memory)
//!   → robot (URDF, forward kinematics, inverse dynamics)
//!   → power (the paper's 49-parameter model)
//!   → identify (regressors, constrained fit, validation, report)
//!   → diagnose (sim-to-real mismatch: locate, name, model)
//!   → viz (Rerun recording); rows (per-reading rows as Parquet, for many sessions and robots)
//! sim (digital twin) writes the same MCAP format that `read` reads.
//! timing (the power sensors' window and lag, and the scan that estimates them) sits under identify
//! and diagnose; lsq (least squares: normal equations, bounded solvers, metrics) and util sit under all of them.
//! ```
#![warn(missing_docs)]

pub mod diagnose;
pub mod fleet;
pub mod identify;
pub mod lsq;
mod plot;
pub mod power;
pub mod read;
pub mod robot;
pub mod rows;
pub mod session;
pub mod signals;
pub mod sim;
pub mod timing;
pub mod trial;
pub mod util;
#[cfg(feature = "viz")]
pub mod viz;

/// Number of arm joints the power model covers (one arm: shoulder pitch/roll/yaw, elbow, wrist roll/pitch/yaw).
pub const N_JOINTS: usize = 7;

/// Number of power-model parameters: 4 per joint plus 21 pairwise interactions.
pub const N_PARAMS: usize = 4 * N_JOINTS + N_JOINTS * (N_JOINTS - 1) / 2;
