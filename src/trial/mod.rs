//! The trial — the protocol's repeated unit (pre-idle at home → trajectory → post-idle → return)
//! — and everything decided per trial: its window ([`TrialWindow`]), segmentation of a session
//! from the data alone ([`segment()`]), the balance-contamination statistic ([`sigma_omega`]), and
//! the filters that reject trials ([`Cascade`], [`Rejection`]).
//!
//! Identification, diagnosis, validation, the replay overlay and the simulator all speak in
//! these types.

mod filter;
mod segment;
mod window;

pub use filter::{
    Cascade, ImuFilterMarks, RejectReason, Rejection, TrialStat, imu_sway, is_rejected,
    sigma_omega, three_sigma,
};
pub use segment::{SegmentOptions, SegmentSource, Segmentation, Stretch, segment};
pub use window::{
    MIN_PRE_IDLE_SAMPLES, MIN_WINDOW_SAMPLES, Phase, TrialWindow, readings_within, samples_in,
};
