//! Identification of the paper's arm power model from recorded sessions: trial segmentation,
//! regressors and targets, outlier filters, constrained least squares, metrics and reports.

pub mod dataset;
pub mod filters;
pub mod metrics;
pub mod pipeline;
pub mod report;
pub mod segment;
pub mod solve;
