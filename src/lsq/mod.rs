//! Least squares, the kernel under identification and diagnosis: normal-equation statistics
//! ([`Gram`]), bound-constrained solvers on rows (clarabel's interior-point QP, with a KKT check)
//! and on a Gram matrix (an exact active-set QP), condition numbers and
//! fit metrics as the paper reports them.
//!
//! Nothing here knows about robots or power: columns are columns.

mod gram;
mod metrics;
mod qp;
mod solve;

pub use gram::{Gram, solve_normal};
pub use metrics::{Metrics, MetricsAccumulator, condition_number, condition_number_matrix};
pub use qp::bounded_quadratic;
pub use solve::{
    Bounds, Fit, KktReport, Method, SolverInfo, Status, fit_constrained, fit_general, fit_gram,
    kkt_check, paper_lower_bounds, rows_to_matrix,
};
