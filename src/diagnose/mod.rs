//! Sim-to-real mismatch diagnosis: compare the twin (URDF dynamics + identified power model)
//! with a recording at the torque and power levels, locate where they disagree, name the
//! missing physics from a library of hypotheses scored by trial-wise cross-validation, model it
//! (refit with the accepted hypotheses), and report it in words, figures and JSON.

pub mod data;
pub mod hypotheses;
mod qp;
pub mod select;
pub mod stats;

pub use data::{Phase, TrialWindow};
pub use select::{HypothesisScore, Param};
