//! The rows one session contributes to an identification or validation, built trial by trial
//! as a [`crate::session::TrialSource`] hands each trial over: every trial's per-reading and
//! per-trial rows, and the per-sample rows as planned (thinned, or reduced to per-trial sums).

use super::dataset::{self, Dataset, DatasetOptions, Mode, Row};
use super::sample::SampleSums;
use crate::signals::{Recording, Target};
use crate::trial::TrialWindow;

/// What the row pass builds.
pub(crate) struct RowPlan<'a> {
    pub target: Target,
    pub alignment: dataset::Alignment,
    /// Every trial of the session (reading and trial rows are built for each).
    pub trials: &'a [TrialWindow],
    /// Trials whose sample rows are built (thinned by `sample_stride`).
    pub sample_trials: &'a [usize],
    pub sample_stride: usize,
    /// Trials whose sample rows are reduced to per-trial statistics (only when the fit itself
    /// is per sample).
    pub full_sample_trials: &'a [usize],
}

/// The rows of one session (every trial's reading and trial rows; sample rows as planned).
#[derive(Default)]
pub(crate) struct SessionSets {
    pub reading: Dataset,
    pub trial: Dataset,
    /// Thinned sample rows of the planned trials.
    pub sample_thin: Vec<Row>,
    /// The sample rows of the planned trials reduced to per-trial statistics (empty unless
    /// planned: only the per-sample fit needs them).
    pub sample_sums: SampleSums,
}

fn extend(to: &mut Dataset, from: Dataset) {
    to.rows.extend(from.rows);
    to.trials.extend(from.trials);
    to.skipped.extend(from.skipped);
}

impl SessionSets {
    /// Add the rows of `trial` built on `rec` (which holds at least the trial's window).
    pub(crate) fn add_trial(&mut self, rec: &Recording, trial: &TrialWindow, plan: &RowPlan) {
        let opts = |mode| DatasetOptions {
            mode,
            target: plan.target,
            alignment: plan.alignment,
        };
        let one = std::slice::from_ref(trial);
        extend(
            &mut self.reading,
            dataset::build(rec, one, &opts(Mode::Reading)),
        );
        extend(
            &mut self.trial,
            dataset::build(rec, one, &opts(Mode::Trial)),
        );
        if plan.sample_trials.contains(&trial.index) {
            self.sample_thin.extend(dataset::sample_rows_thinned(
                rec,
                trial,
                &opts(Mode::Sample),
                plan.sample_stride,
            ));
        }
        if plan.full_sample_trials.contains(&trial.index) {
            self.sample_sums
                .add(dataset::build(rec, one, &opts(Mode::Sample)));
        }
    }
}
