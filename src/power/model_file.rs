//! `model.json`: an identified power model with its units, joint names, fit metrics and provenance.
//!
//! # Schema (version 1)
//!
//! ```text
//! {
//!   "schema_version": 1,
//!   "description": "…",                      free text
//!   "units": { "a": "1", "b": "W/(N·m)^2", "c": "W·s/rad", "d": "W·s^2/rad^2", "e": "W·s^2/rad^2",
//!              "power": "W", "torque": "N·m", "joint_velocity": "rad/s" },
//!   "joint_names": [7 URDF joint names, model order: shoulder pitch, roll, yaw, elbow, wrist roll, pitch, yaw],
//!   "theta_names": ["a0", …, "a6", "b0", …, "d6", "e01", "e02", …, "e56"],
//!   "theta": [49 numbers in theta_names order]            ← authoritative
//!   "a": [7], "b": [7], "c": [7], "d": [7],               ← the same values by name (checked on load)
//!   "e": { "0,1": …, "0,2": …, …, "5,6": … },             ← 21 pairs i<j (checked on load)
//!   "theta_std_err": [49 numbers or null] | null,         standard errors (null: at a bound / not estimated)
//!   "metrics": {
//!     "identification": { "dataset", "n", "r2", "rmse", "mae", "bias", "skewness", "kurtosis",
//!                          "condition_number" } | null,
//!     "validation": { same fields } | null
//!   },
//!   "dominant_term": [ { "joint": name, "term": "copper" | "coulomb" | "viscous" | null, "value": x } × 7 ],
//!   "provenance": {
//!     "tool": "g1viz 0.1.0", "created": "caller-supplied timestamp",
//!     "sessions": [ { "path", "size_bytes", "role": "identification" | "validation" } ],
//!     "target": "mbs" | "bms", "rows": "trajectory" | "per_sample" | "per_reading",
//!     "filters": [ { "name", "parameters": { name: number }, "rejected": n } ],
//!     "trials": { "segmented", "used", "rejected" },
//!     "rejected_trials": [ { "session": index into "sessions", "trial", "filter": "imu_sigma" | "residual_3sigma" | "unusable",
//!                          "statistic", "threshold", "pass", "detail"? } ],
//!     "solver": { "method", "status", "iterations" } | null,
//!     "notes": [ "…" ]
//!   }
//! }
//! ```
//!
//! Model: P_net = Σ_i [a_i τ_i q̇_i + b_i (τ_i² − τ̄0_i²) + c_i |q̇_i| + d_i q̇_i²] + Σ_{i<j} e_ij |q̇_i||q̇_j|
//! (bias = mean(predicted − measured); kurtosis is Pearson's, 3 for a normal distribution; metrics that
//! are undefined, e.g. R² of a constant target, are `null`). Output is deterministic: the same inputs give the
//! same bytes (no wall-clock times are written; `created` comes from the caller).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail, ensure};
use serde::{Deserialize, Serialize};

use super::{LossTerm, N_PAIRS, PAIRS, PowerModel};
use crate::lsq::{Method, Metrics, Status};
use crate::signals::Target;
use crate::trial::Rejection;
use crate::util::nan_as_null;
use crate::{N_JOINTS, N_PARAMS};
use ModelProblem::Field;

/// The schema version this code writes and reads.
pub const SCHEMA_VERSION: u32 = 1;

/// The contents of a `model.json` file (see the module docs for the schema).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelFile {
    /// Schema version, [`SCHEMA_VERSION`].
    pub schema_version: u32,
    /// Free-text description.
    #[serde(default)]
    pub description: String,
    /// Units of the parameters and signals.
    pub units: BTreeMap<String, String>,
    /// URDF names of the 7 joints in model order.
    pub joint_names: Vec<String>,
    /// Names of the 49 parameters in θ order.
    pub theta_names: Vec<String>,
    /// θ, the 49 parameters (authoritative; the named fields repeat them).
    pub theta: Vec<f64>,
    /// a_i (inverse gear efficiency).
    pub a: [f64; N_JOINTS],
    /// b_i (copper loss) [W/(N·m)²].
    pub b: [f64; N_JOINTS],
    /// c_i (Coulomb friction) [W·s/rad].
    pub c: [f64; N_JOINTS],
    /// d_i (viscous friction) [W·s²/rad²].
    pub d: [f64; N_JOINTS],
    /// e_ij by pair key `"i,j"` [W·s²/rad²].
    pub e: BTreeMap<String, f64>,
    /// Standard error per parameter (None: held at a bound or not estimated).
    #[serde(default)]
    pub theta_std_err: Option<Vec<Option<f64>>>,
    /// Fit metrics.
    #[serde(default)]
    pub metrics: ModelMetrics,
    /// Dominant loss term per joint (argmax of b, c, d; the paper's table).
    pub dominant_term: Vec<DominantTerm>,
    /// Where the model came from.
    #[serde(default)]
    pub provenance: Provenance,
}

/// Fit metrics on the identification data and, optionally, a hold-out validation session.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ModelMetrics {
    /// Metrics on the rows the model was fitted on.
    pub identification: Option<DatasetMetrics>,
    /// Metrics on a hold-out session.
    pub validation: Option<DatasetMetrics>,
}

/// [`Metrics`] of one dataset plus its regressor condition number.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DatasetMetrics {
    /// Which rows (e.g. `"trajectory-averaged, filtered"` or a session name).
    pub dataset: String,
    /// R², RMSE, …
    #[serde(flatten)]
    pub fit: Metrics,
    /// κ(ΦᵀΦ) of the rows (NaN/`null` when not computed or infinite).
    #[serde(with = "nan_as_null")]
    pub condition_number: f64,
}

/// One joint's dominant loss term.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DominantTerm {
    /// URDF joint name.
    pub joint: String,
    /// argmax(b, c, d), None when all are zero.
    pub term: Option<LossTerm>,
    /// The winning coefficient (0 when none).
    pub value: f64,
}

/// Where a model came from: sessions, target, filters, trial counts, rejected trials.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Provenance {
    /// Tool name and version.
    pub tool: String,
    /// Creation time as given by the caller (kept out of the library so output is reproducible).
    pub created: String,
    /// Input sessions.
    pub sessions: Vec<SessionRef>,
    /// Power sensor used as target (`mbs` or `bms`).
    pub target: String,
    /// Row construction: `trajectory` (the paper's aggregation), `per_sample` or `per_reading`.
    pub rows: String,
    /// Filters in the order they were applied.
    pub filters: Vec<FilterRecord>,
    /// Trial counts.
    pub trials: TrialCounts,
    /// Every rejected trial with its reason.
    pub rejected_trials: Vec<Rejection>,
    /// Solver that produced θ.
    pub solver: Option<SolverRecord>,
    /// Anything else worth knowing.
    pub notes: Vec<String>,
}

impl Default for Provenance {
    fn default() -> Self {
        Provenance {
            tool: format!("g1viz {}", env!("CARGO_PKG_VERSION")),
            created: String::new(),
            sessions: Vec::new(),
            target: String::new(),
            rows: String::new(),
            filters: Vec::new(),
            trials: TrialCounts::default(),
            rejected_trials: Vec::new(),
            solver: None,
            notes: Vec::new(),
        }
    }
}

/// An input session file (or bag directory).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionRef {
    /// Path as given by the user.
    pub path: String,
    /// Size in bytes (sum of the files for a bag directory).
    pub size_bytes: u64,
    /// `identification` or `validation`.
    pub role: String,
}

impl SessionRef {
    /// Describe `path` (a file, or a directory whose files' sizes are summed).
    pub fn from_path(path: &Path, role: &str) -> Result<SessionRef> {
        let meta = std::fs::metadata(path)
            .with_context(|| format!("reading metadata of {}", path.display()))?;
        let size_bytes = if meta.is_dir() {
            let mut total = 0;
            for entry in
                std::fs::read_dir(path).with_context(|| format!("listing {}", path.display()))?
            {
                let meta = entry?.metadata()?;
                if meta.is_file() {
                    total += meta.len();
                }
            }
            total
        } else {
            meta.len()
        };
        Ok(SessionRef {
            path: path.display().to_string(),
            size_bytes,
            role: role.to_string(),
        })
    }
}

/// Why a model file cannot be used, naming the file.
#[derive(Debug, thiserror::Error)]
pub enum ModelFileError {
    /// The file could not be read.
    #[error("reading model file {}: {reason}", .path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
    /// A valid model file that does not fit the session it is used on (joints, sensor).
    #[error("model file {} does not fit this session: {problem}", .path.display())]
    Mismatch {
        /// The file.
        path: PathBuf,
        /// What does not match.
        problem: ModelProblem,
    },
    /// The file was read but is not a usable model file.
    #[error("invalid model file {}: {problem}", .path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong with its content.
        problem: ModelProblem,
    },
}

/// What is wrong with a model file's content.
#[derive(Debug, thiserror::Error)]
pub enum ModelProblem {
    /// Not JSON at all.
    #[error("not valid JSON: {0}")]
    Json(String),
    /// JSON that does not have the model file's shape (missing fields, wrong types, null θ).
    #[error("does not match the model.json schema: {0}")]
    Schema(String),
    /// A field whose value is not acceptable: the message names the field (e.g. `theta`,
    /// `a[3]`, `e["0,1"]`), its value and what was expected.
    #[error("{0}")]
    Field(String),
}

/// The problem of a list field `name` of `n` entries (`unit`) whose length is not `wanted`
/// (how the message says what was expected), or none.
fn length(
    name: &str,
    n: usize,
    wanted: usize,
    unit: &str,
    expected: &str,
) -> Result<(), ModelProblem> {
    if n == wanted {
        return Ok(());
    }
    Err(Field(format!("field `{name}` has {n} {unit}, {expected}")))
}

/// One filter and its settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FilterRecord {
    /// e.g. `imu_sigma` or `residual_3sigma`.
    pub name: String,
    /// Thresholds and settings (e.g. `{"k_median": 2.5}`, `{"k_sigma": 3, "passes": 2}`).
    pub parameters: BTreeMap<String, f64>,
    /// Trials it rejected.
    pub rejected: usize,
}

/// Trial counts through the pipeline.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct TrialCounts {
    /// Trials found by segmentation.
    pub segmented: usize,
    /// Trials in the final fit.
    pub used: usize,
    /// Trials rejected by the filters.
    pub rejected: usize,
}

/// The solver run that produced θ (no timings: they would make the file non-reproducible).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SolverRecord {
    /// Solver (`clarabel`).
    pub method: Method,
    /// Final status (`Solved`, `AlmostSolved`, …).
    pub status: Status,
    /// Iterations.
    pub iterations: u32,
}

fn pair_key(i: usize, j: usize) -> String {
    format!("{i},{j}")
}

fn default_units() -> BTreeMap<String, String> {
    [
        ("a", "1"),
        ("b", "W/(N·m)^2"),
        ("c", "W·s/rad"),
        ("d", "W·s^2/rad^2"),
        ("e", "W·s^2/rad^2"),
        ("power", "W"),
        ("torque", "N·m"),
        ("joint_velocity", "rad/s"),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v.to_string()))
    .collect()
}

impl ModelFile {
    /// Build a model file; the named parameters, names and dominant terms are derived from `model`.
    pub fn new(
        model: &PowerModel,
        joint_names: &[String],
        metrics: ModelMetrics,
        provenance: Provenance,
    ) -> Result<ModelFile> {
        ensure!(
            joint_names.len() == N_JOINTS,
            "{} joint names given, the arm model has {N_JOINTS}",
            joint_names.len()
        );
        let theta = model.to_vector();
        if let Some(p) = theta.iter().position(|v| !v.is_finite()) {
            bail!(
                "parameter {} = {} is not finite",
                PowerModel::param_name(p),
                theta[p]
            );
        }
        let dominant_term = (0..N_JOINTS)
            .map(|i| {
                let term = model.dominant_term(i);
                let value = match term {
                    Some(LossTerm::Copper) => model.b[i],
                    Some(LossTerm::Coulomb) => model.c[i],
                    Some(LossTerm::Viscous) => model.d[i],
                    None => 0.0,
                };
                DominantTerm {
                    joint: joint_names[i].clone(),
                    term,
                    value,
                }
            })
            .collect();
        Ok(ModelFile {
            schema_version: SCHEMA_VERSION,
            description: "Electrical power model of the Unitree G1 arm (Deniz et al., physics-based, linear in parameters)"
                .to_string(),
            units: default_units(),
            joint_names: joint_names.to_vec(),
            theta_names: (0..N_PARAMS).map(PowerModel::param_name).collect(),
            theta: theta.to_vec(),
            a: model.a,
            b: model.b,
            c: model.c,
            d: model.d,
            e: PAIRS.iter().zip(&model.e).map(|(&(i, j), &v)| (pair_key(i, j), v)).collect(),
            theta_std_err: None,
            metrics,
            dominant_term,
            provenance,
        })
    }

    /// The power model (θ is authoritative; [`ModelFile::load`] has checked the named copies agree).
    pub fn model(&self) -> PowerModel {
        PowerModel::from_vector(&std::array::from_fn(|p| {
            self.theta.get(p).copied().unwrap_or(0.0)
        }))
    }

    /// The standard error of parameter `p`, when the file has one.
    pub fn std_err(&self, p: usize) -> Option<f64> {
        self.theta_std_err.as_ref()?.get(p).copied().flatten()
    }

    /// Read and validate a model file; errors name the file and the offending field.
    pub fn load(path: &Path) -> Result<ModelFile, ModelFileError> {
        let text = crate::util::read_text_input(path).map_err(|e| ModelFileError::Read {
            path: path.to_path_buf(),
            reason: format!("{e:#}"),
        })?;
        Self::from_json(&text).map_err(|problem| ModelFileError::Invalid {
            path: path.to_path_buf(),
            problem,
        })
    }

    /// Parse and validate model JSON text.
    pub fn from_json(text: &str) -> Result<ModelFile, ModelProblem> {
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(|e| ModelProblem::Json(e.to_string()))?;
        match value.get("schema_version") {
            None => {
                return Err(Field(format!(
                    "field `schema_version` is missing (expected {SCHEMA_VERSION})"
                )));
            }
            Some(v) if v.as_u64() == Some(SCHEMA_VERSION as u64) => {}
            Some(v) => {
                return Err(Field(format!(
                    "field `schema_version` is {v}; this g1viz reads version {SCHEMA_VERSION}"
                )));
            }
        }
        let file: ModelFile =
            serde_json::from_value(value).map_err(|e| ModelProblem::Schema(e.to_string()))?;
        file.validate()?;
        Ok(file)
    }

    fn validate(&self) -> Result<(), ModelProblem> {
        let model_has = format!("the power model has {N_PARAMS}");
        length("theta", self.theta.len(), N_PARAMS, "values", &model_has)?;
        if let Some(p) = self.theta.iter().position(|v| !v.is_finite()) {
            return Err(Field(format!(
                "field `theta[{p}]` ({}) is not a finite number",
                PowerModel::param_name(p)
            )));
        }
        check_magnitudes(&self.theta)?;
        let arm_has = format!("the arm has {N_JOINTS} joints");
        length(
            "joint_names",
            self.joint_names.len(),
            N_JOINTS,
            "names",
            &arm_has,
        )?;
        let expected = self.model();
        for (name, named, from_theta) in [
            ("a", &self.a, &expected.a),
            ("b", &self.b, &expected.b),
            ("c", &self.c, &expected.c),
            ("d", &self.d, &expected.d),
        ] {
            for i in 0..N_JOINTS {
                if named[i] != from_theta[i] {
                    return Err(Field(format!(
                        "field `{name}[{i}]` = {} disagrees with `theta` ({}) — edit both or only `theta` and the named copies",
                        named[i], from_theta[i]
                    )));
                }
            }
        }
        let pairs = format!("expected {N_PAIRS} pairs \"i,j\" with i<j");
        length("e", self.e.len(), N_PAIRS, "entries", &pairs)?;
        for (k, &(i, j)) in PAIRS.iter().enumerate() {
            let key = pair_key(i, j);
            match self.e.get(&key) {
                None => {
                    return Err(Field(format!("field `e` has no entry \"{key}\"")));
                }
                Some(&v) if v != expected.e[k] => {
                    return Err(Field(format!(
                        "field `e[\"{key}\"]` = {v} disagrees with `theta` ({})",
                        expected.e[k]
                    )));
                }
                Some(_) => {}
            }
        }
        let n = self.theta_std_err.as_ref().map_or(N_PARAMS, Vec::len);
        length(
            "theta_std_err",
            n,
            N_PARAMS,
            "values",
            &format!("expected {N_PARAMS}"),
        )
    }

    /// Check the model fits a session before it is used on it: the same 7 joints in the same
    /// order (URDF names, so the arm's side too) and, when the file records it, the same power
    /// sensor as `target`. Errors name the field and its value.
    pub fn check_use(&self, joints: &[String], target: Target) -> Result<(), ModelProblem> {
        check_joints(&self.joint_names, joints)?;
        let wanted = target.name();
        let recorded = self.provenance.target.as_str();
        if !recorded.is_empty() && recorded != wanted {
            return Err(Field(format!(
                "field `provenance.target` is {recorded:?}: the model was identified on the \
                 {recorded} sensor but is used on the {wanted} sensor here (--target \
                 {wanted}); pass --target {recorded} or use a model of the {wanted} sensor"
            )));
        }
        Ok(())
    }

    /// Pretty-printed JSON (deterministic: maps are sorted, floats printed shortest-exact).
    pub fn to_json(&self) -> Result<String> {
        let mut s = serde_json::to_string_pretty(self).context("serialising model file")?;
        s.push('\n');
        Ok(s)
    }

    /// Write atomically (a reader never sees a half-written file).
    pub fn save(&self, path: &Path) -> Result<()> {
        self.validate()
            .context("refusing to write an invalid model file")?;
        crate::util::write_atomic(path, self.to_json()?.as_bytes())
            .with_context(|| format!("writing model file {}", path.display()))
    }
}

/// Largest inverse gear efficiency a model may have (a_i = 100: 1 % efficiency).
pub const MAX_A: f64 = 100.0;
/// Largest magnitude of a loss coefficient b, c, d, e (in their units; identified values are
/// of order 1).
pub const MAX_LOSS_COEFFICIENT: f64 = 1e4;

/// Refuse a negative or absurd inverse gear efficiency and absurd loss coefficients (θ is finite
/// here).
fn check_magnitudes(theta: &[f64]) -> Result<(), ModelProblem> {
    for (p, &v) in theta.iter().enumerate() {
        let name = PowerModel::param_name(p);
        let problem = if p < N_JOINTS {
            if v < 0.0 {
                Some(format!(
                    "is negative: {name} is an inverse gear efficiency (1 = lossless gear)"
                ))
            } else if v > MAX_A {
                Some(format!(
                    "is beyond {MAX_A}: {name} is an inverse gear efficiency (1 = lossless gear)"
                ))
            } else {
                None
            }
        } else if v.abs() > MAX_LOSS_COEFFICIENT {
            Some(format!(
                "is beyond ±{MAX_LOSS_COEFFICIENT:e}: an absurd loss coefficient (identified \
                 values are of order 1)"
            ))
        } else {
            None
        };
        if let Some(why) = problem {
            return Err(Field(format!("field `theta[{p}]` ({name}) = {v} {why}")));
        }
    }
    Ok(())
}

/// The arm side a URDF joint name belongs to (`left_…` / `right_…`).
fn side(name: &str) -> Option<&'static str> {
    ["left", "right"]
        .into_iter()
        .find(|s| name.strip_prefix(s).is_some_and(|r| r.starts_with('_')))
}

/// The model's joints must be the session's, in the same order.
fn check_joints(model: &[String], session: &[String]) -> Result<(), ModelProblem> {
    let Some(k) = (0..model.len().max(session.len())).find(|&k| model.get(k) != session.get(k))
    else {
        return Ok(());
    };
    let (m, s) = (model.get(k), session.get(k));
    let shown = |v: Option<&String>| v.map_or("nothing".to_string(), |v| format!("{v:?}"));
    let why = match (m.and_then(|m| side(m)), s.and_then(|s| side(s))) {
        (Some(a), Some(b)) if a != b => {
            format!("the model was identified on the {a} arm, the session is the {b} arm's")
        }
        _ if model.len() == session.len() && session.iter().all(|j| model.contains(j)) => {
            format!(
                "the same joints in another order (model: {}; session: {})",
                model.join(", "),
                session.join(", ")
            )
        }
        _ => "the model was identified on other joints".to_string(),
    };
    Err(Field(format!(
        "field `joint_names[{k}]` is {}, but the session's joint {k} is {}: {why}",
        shown(m),
        shown(s)
    )))
}

/// Load a model file for use on a session with these joints (URDF names, model order) and
/// this power sensor: [`ModelFile::load`] plus [`ModelFile::check_use`]. `paper` (when no such
/// file exists) is the paper's tabulated model, which has no joint names to check.
pub fn load_model_for(
    path: &Path,
    joints: &[String],
    target: Target,
) -> Result<PowerModel, ModelFileError> {
    if path.as_os_str() == "paper" && !path.exists() {
        return Ok(PowerModel::PAPER);
    }
    let file = ModelFile::load(path)?;
    file.check_use(joints, target)
        .map_err(|problem| ModelFileError::Mismatch {
            path: path.to_path_buf(),
            problem,
        })?;
    Ok(file.model())
}
