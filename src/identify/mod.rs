//! Identification of the arm power model from recorded sessions: trial segmentation, regressor datasets,
//! outlier filters, the constrained least-squares fit, fit metrics and the markdown/PNG report.

pub mod dataset;
pub mod filters;
pub mod metrics;
pub mod pipeline;
pub mod report;
pub mod segment;
pub mod solve;
