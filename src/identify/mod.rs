//! Identification of the arm power model from recorded sessions: regressor datasets (per trial,
//! per reading on the sensor's own window, per sample), the paper's filtered constrained fit
//! ([`identify()`]), hold-out validation ([`validate()`]), the model-file record and the
//! markdown/PNG report. Trials and their filters live in [`crate::trial`], the solvers in
//! [`crate::lsq`].

mod dataset;
mod fit;
mod pipeline;
mod record;
mod report;
mod sample;
mod sets;
mod summary;
mod table;
mod validate;

/// The session types [`identify_files`] and [`validate_file`] take.
pub use dataset::{
    Alignment, AlignmentEstimate, AlignmentScore, Dataset, DatasetOptions, Mode, Row, Skipped,
    Target, TrialBasis, build as build_dataset, estimate_alignment,
};
pub(crate) use fit::fit_normal;
pub use fit::{kappa, term_means};
pub use pipeline::{
    AlignmentChoice, Identification, IdentifyOptions, ModeFit, RowsFit, SessionBreakdown,
    SessionSummary, fit_given_rows, identify, identify_files,
};
pub use report::{
    AggregationRow, FIGURES as REPORT_FIGURES, PredictionSet, ReportInput, TermContributions,
    write_report,
};
pub use table::{ReadingFit, TrialPrediction};
pub use validate::{Validation, validate, validate_file};
