//! The durable record of an identification: the model file (`model.json`) and the inputs of the
//! markdown/PNG report.

use std::path::Path;

use anyhow::Result;

use super::dataset::Mode;
use super::pipeline::Identification;
use super::report::{AggregationRow, PredictionSet, ReportInput, TermContributions};
use super::table::TrialPrediction;
use super::validate::Validation;
use crate::power::{
    DatasetMetrics, FilterRecord, ModelFile, ModelMetrics, PowerModel, Provenance, SessionRef,
    SolverRecord, TrialCounts,
};
use crate::trial::RejectReason;

impl Identification {
    /// The model file (`model.json`) of this identification: θ, metrics on the fitted rows (with
    /// their κ), optional hold-out metrics, and provenance (sessions, target, rows, filters with
    /// their settings, trial counts, every rejected trial, solver). `joint_names` are the URDF
    /// names in model order (the recording's); `created` is written as given (reproducible output).
    pub fn model_file(
        &self,
        joint_names: &[String],
        validation: Option<&Validation>,
        created: &str,
    ) -> Result<ModelFile> {
        let rows = match self.options.mode {
            Mode::Trial => "trajectory",
            Mode::Reading => "per_reading",
            Mode::Sample => "per_sample",
        };
        let kappa = self
            .modes
            .iter()
            .find(|m| m.mode == self.options.mode)
            .map_or(f64::NAN, |m| m.kappa);
        let identification = DatasetMetrics {
            dataset: format!(
                "{} rows of {} retained trials (filtered)",
                rows.replace('_', "-"),
                self.trials_used
            ),
            fit: self.fit,
            condition_number: kappa,
        };
        let validation_metrics = validation.map(|v| DatasetMetrics {
            dataset: format!(
                "{}: per-reading rows, all usable trials",
                v.session.source.display()
            ),
            fit: v.reading_level,
            condition_number: f64::NAN,
        });
        let mut sessions: Vec<SessionRef> = self
            .sessions
            .iter()
            .map(|s| session_ref(&s.source, "identification"))
            .collect();
        if let Some(v) = validation {
            sessions.push(session_ref(&v.session.source, "validation"));
        }
        let filters = self.filter_records();
        let rejected_trials = self.rejections.clone();
        let mut notes = vec![format!(
            "power readings treated as averages over {}",
            self.reading_window(" (window and lag estimated from the data)")
        )];
        notes.extend(self.modes.iter().map(|m| {
            format!(
                "{} rows: n = {}, κ(ΦᵀΦ) = {:.3e}, R² = {:.4}",
                m.mode.name(),
                m.quality.n,
                m.kappa,
                m.quality.r2
            )
        }));
        let provenance = Provenance {
            created: created.to_string(),
            sessions,
            target: self.options.target.name().into(),
            rows: rows.into(),
            filters,
            trials: TrialCounts {
                segmented: self
                    .sessions
                    .iter()
                    .map(|s| s.segmentation.trials.len())
                    .sum(),
                used: self.trials_used,
                rejected: self.rejections.len(),
            },
            rejected_trials,
            solver: Some(SolverRecord {
                method: self.solver.method,
                status: self.solver.status,
                iterations: self.solver.iterations,
            }),
            notes,
            ..Provenance::default()
        };
        let mut file = ModelFile::new(
            &self.model,
            joint_names,
            ModelMetrics {
                identification: Some(identification),
                validation: validation_metrics,
            },
            provenance,
        )?;
        file.theta_std_err = Some(self.std_err.clone());
        Ok(file)
    }

    /// The filters with their settings and how many trials each rejected.
    fn filter_records(&self) -> Vec<FilterRecord> {
        let count = |reason: RejectReason| {
            self.rejections
                .iter()
                .filter(|r| r.reason == reason)
                .count()
        };
        let mut filters = Vec::new();
        if let Some(k) = self.options.filters.imu_k {
            filters.push(FilterRecord {
                name: "imu_sigma".into(),
                parameters: [("k_median".to_string(), k)].into(),
                rejected: count(RejectReason::ImuSway),
            });
        }
        if self.options.filters.passes > 0 {
            filters.push(FilterRecord {
                name: "residual_3sigma".into(),
                parameters: [
                    ("k_sigma".to_string(), self.options.filters.n_sigma),
                    ("passes".to_string(), self.options.filters.passes as f64),
                ]
                .into(),
                rejected: count(RejectReason::Residual),
            });
        }
        filters
    }

    /// Everything the markdown report shows: the model file, per-trial measured vs predicted on
    /// the retained trials (and on the hold-out session), term contributions (hold-out set when
    /// given, as in the paper), the row-pairing comparison, and the truth θ for simulated sessions.
    pub fn report_input(
        &self,
        model_file: ModelFile,
        validation: Option<&Validation>,
        truth: Option<PowerModel>,
    ) -> ReportInput {
        let set = |label: String, table: &[TrialPrediction]| PredictionSet {
            label,
            measured: table.iter().map(|p| p.measured_w).collect(),
            predicted: table.iter().map(|p| p.predicted_w).collect(),
            trials: table.iter().map(|p| p.trial).collect(),
        };
        let retained: Vec<TrialPrediction> = self
            .per_trial
            .iter()
            .filter(|p| !p.rejected)
            .cloned()
            .collect();
        let terms = match validation {
            Some(v) => TermContributions::from_means(
                &format!("hold-out trajectories ({})", v.session.source.display()),
                &v.terms,
            ),
            None => {
                TermContributions::from_means("identification trajectories (retained)", &self.terms)
            }
        };
        ReportInput {
            title: "Arm power model identification".into(),
            model: model_file,
            identification: Some(set(
                format!("identification: {} retained trials", retained.len()),
                &retained,
            )),
            validation: validation.map(|v| {
                set(
                    format!("hold-out: {} trials", v.per_trial.len()),
                    &v.per_trial,
                )
            }),
            terms: Some(terms),
            aggregation: self
                .modes
                .iter()
                .map(|m| AggregationRow {
                    rows: m.mode.name().into(),
                    n: m.quality.n,
                    condition_number: m.kappa,
                    r2: m.quality.r2,
                })
                .collect(),
            truth,
            notes: super::summary::per_session_markdown(self)
                .into_iter()
                .collect(),
        }
    }
}

/// A session reference for provenance; a path that cannot be read (e.g. an in-memory recording)
/// is recorded with size 0 rather than failing the model file.
fn session_ref(path: &Path, role: &str) -> SessionRef {
    SessionRef::from_path(path, role).unwrap_or_else(|_| SessionRef {
        path: path.display().to_string(),
        size_bytes: 0,
        role: role.into(),
    })
}
