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
mod stream;
mod summary;
mod table;
mod validate;

pub use dataset::{
    Alignment, AlignmentEstimate, AlignmentScore, Dataset, DatasetOptions, Mode, Row, Skipped,
    Target, TrialBasis, build as build_dataset, estimate_alignment,
};
pub(crate) use fit::fit_normal;
pub use fit::{kappa, term_means};
pub use pipeline::{
    AlignmentChoice, Identification, IdentifyOptions, ModeFit, RowsFit, SEARCH_TRIALS,
    SessionBreakdown, SessionSummary, fit_given_rows, identify, identify_files, search_stride,
};
pub use report::{
    AggregationRow, FIGURES as REPORT_FIGURES, PredictionSet, ReportInput, TermContributions,
    write_report,
};
pub use stream::{
    SessionFile, StreamOptions, for_each_trial, for_each_trial_and_batch,
    for_each_trial_and_batch_no_commands, for_each_trial_state, segment_file,
};
pub use table::{ReadingFit, TrialBaseline, TrialPrediction};
pub use validate::{Validation, validate, validate_file};
