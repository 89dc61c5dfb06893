//! Per-reading data for the replay of a diagnosis: measured and predicted power, the trials to
//! point the user to, and the recorded fields the terms found beyond the library follow.

use super::reading_rows::{Rows, TrialMeta};
use super::refit::Located;
use super::select_discover::RowFields;
use super::{Diagnosis, TrialWindow, select};

/// Data for the replay: per power reading, measured and predicted net power.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct ReplayData {
    /// Reading time stamp [s, Recording time].
    pub t: Vec<f64>,
    /// Trial index of each reading (segmentation numbering).
    pub trial: Vec<usize>,
    /// Measured net power [W].
    pub measured_w: Vec<f64>,
    /// Held-out prediction of the base model [W].
    pub before_w: Vec<f64>,
    /// Held-out prediction with the accepted hypotheses [W].
    pub after_w: Vec<f64>,
    /// Trials to highlight (worst residuals, carriers of unexplained structure).
    pub highlighted: Vec<HighlightedTrial>,
    /// Held-out prediction with the terms found beyond the library [W] (empty when none).
    #[serde(default)]
    pub found_w: Vec<f64>,
    /// The recorded fields the found terms follow, per reading (window values), to plot beside
    /// the residual.
    #[serde(default)]
    pub located: Vec<LocatedField>,
    /// Rest power of each reading's trial (its pre-idle mean) [W], when terms were found on it
    /// (empty otherwise). For the viewer only: `diagnosis.json` has the terms
    /// (`discovery.rest`), and a trial the rest-power stage could not use has no value (NaN).
    #[serde(skip)]
    pub rest_w: Vec<f64>,
    /// Held-out rest power of each reading's trial with the terms found on it [W] (viewer only).
    #[serde(skip)]
    pub rest_found_w: Vec<f64>,
    /// The trials a filter rejected, with their windows (viewer only: `diagnosis.json` lists
    /// the rejections in `rejected`).
    #[serde(skip)]
    pub rejected: Vec<HighlightedTrial>,
    /// The IMU filter over every trial, as a model replay shows it (viewer only).
    #[serde(skip)]
    pub imu: Option<crate::trial::ImuFilterMarks>,
    /// The final refit's base terms at each reading [W]: per joint mechanical, copper, Coulomb
    /// and viscous, and the interaction (viewer only: each trial's shares, as a model replay's).
    #[serde(skip)]
    pub terms_w: Vec<([[f64; crate::N_JOINTS]; 4], f64)>,
}

/// Each row's base terms under `theta` ([`ReplayData::terms_w`]; θ and the regressors in
/// [`crate::power::regressor_into`]'s order).
fn base_terms(theta: &[f64], rows: &Rows) -> Vec<([[f64; crate::N_JOINTS]; 4], f64)> {
    let n = crate::N_JOINTS;
    let term = |x: &[f64], k: usize| std::array::from_fn(|j| theta[k * n + j] * x[k * n + j]);
    let pairs = 4 * n..crate::N_PARAMS;
    let e = |x: &[f64]| pairs.clone().map(|c| theta[c] * x[c]).sum();
    let rows = rows.x.iter().filter(|_| theta.len() >= crate::N_PARAMS);
    rows.map(|x| (std::array::from_fn(|k| term(x, k)), e(x)))
        .collect()
}

/// A recorded field a found term follows, sampled on the readings' windows.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct LocatedField {
    /// `topic.field.path`.
    pub name: String,
    /// Window value per reading (same order as [`ReplayData::t`]).
    pub values: Vec<f64>,
}

/// A trial the replay should point the user to.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct HighlightedTrial {
    /// Trial index (segmentation numbering).
    pub trial: usize,
    /// Trajectory start [s, Recording time].
    pub t_start: f64,
    /// Return end [s].
    pub t_end: f64,
    /// Why it is highlighted.
    pub reason: String,
}

/// The windows of the `rejected` trials among `metas`, each with its rejection in words.
pub(crate) fn rejected_windows(
    metas: &[TrialMeta],
    rejected: &[crate::trial::Rejection],
) -> Vec<HighlightedTrial> {
    rejected
        .iter()
        .filter_map(|r| {
            let w = &metas.iter().find(|m| m.window.index == r.trial)?.window;
            let (t_start, t_end) = (w.t_traj_start, w.t_return_end);
            let (trial, reason) = (r.trial, r.to_string());
            Some(HighlightedTrial {
                trial,
                t_start,
                t_end,
                reason,
            })
        })
        .collect()
}

/// Stage: per-reading data for the replay, with the trials to point the user to (largest
/// held-out base residuals, carriers of unexplained structure).
pub(crate) fn replay_data(
    metas: &[TrialMeta],
    rows0: &Rows,
    sel: &select::Selection,
    located: &Located,
) -> ReplayData {
    let mut replay = ReplayData {
        t: rows0.t.clone(),
        trial: rows0.trial.iter().map(|&t| metas[t].window.index).collect(),
        measured_w: rows0.y.clone(),
        before_w: sel.base.cv.pred.clone(),
        after_w: sel.last.cv.pred.clone(),
        terms_w: base_terms(&sel.last.full.theta, rows0),
        ..ReplayData::default()
    };
    let mut mark = |trial: usize, reason: String| {
        if let Some(m) = metas.iter().find(|m| m.window.index == trial) {
            let w = &m.window;
            highlight(&mut replay, w, (w.t_traj_start, w.t_return_end), reason);
        }
    };
    for t in located.worst_trials.iter().take(5) {
        let why = "largest held-out residual of the base model";
        mark(t.trial, format!("{why}: {:+.2} W", t.mean_w));
    }
    for c in located.unexplained.iter().filter(|c| c.significant) {
        for &t in &c.trials {
            mark(t, format!("carries unexplained structure ({})", c.feature));
        }
    }
    replay
}

/// Trials marked where the rest power steps most with its found terms.
const REST_MARKED: usize = 5;

/// Stage: what the replay shows of the loads found on the rest power: each trial's rest power
/// and its prediction per reading, the fields they follow beside them, and the trials where the
/// predicted rest power steps most.
pub(crate) fn show_rest(d: &mut Diagnosis, f: &RowFields, rows: &Rows, metas: &[TrialMeta]) {
    let Some(rest) = d.discovery.as_ref().and_then(|r| r.rest.as_ref()) else {
        return;
    };
    if rest.found.is_empty() || rest.trial_pred.len() != metas.len() {
        return;
    }
    let at = |v: &[f64]| -> Vec<f64> {
        rows.trial
            .iter()
            .map(|&t| v.get(t).copied().unwrap_or(f64::NAN))
            .collect()
    };
    d.replay.rest_w = at(&f.base_power);
    d.replay.rest_found_w = at(&rest.trial_pred);
    for t in &rest.found {
        if !d.replay.located.iter().any(|l| l.name == t.field) {
            locate_field(&mut d.replay, f, &t.field);
        }
    }
    // Steps of the predicted rest power between consecutive trials that have one.
    let preds = rest.trial_pred.iter().copied().enumerate();
    let preds: Vec<(usize, f64)> = preds.filter(|(_, p)| p.is_finite()).collect();
    let mut steps: Vec<_> = (preds.windows(2))
        .map(|w| (w[1].0, w[1].1 - w[0].1))
        .collect();
    steps.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
    let names: Vec<&str> = rest.found.iter().map(|t| t.field.as_str()).collect();
    for &(t, step) in steps.iter().take(REST_MARKED) {
        let w = &metas[t].window;
        let reason = format!(
            "rest power steps {step:+.2} W from the trial before, with {}",
            names.join(", ")
        );
        highlight(&mut d.replay, w, (w.t_pre_start, w.t_traj_start), reason);
    }
}

/// The recorded field `name`'s value over each row's window, beside the residual.
fn locate_field(replay: &mut ReplayData, f: &RowFields, name: &str) {
    if let Some(k) = f.table.names.iter().position(|n| n == name) {
        let vals = &f.table.values[k];
        replay.located.push(LocatedField {
            name: name.to_string(),
            values: f.row_window.iter().map(|&w| vals[w]).collect(),
        });
    }
}

/// Point the user to trial `w` over `span` for `reason`, unless it is pointed to already.
fn highlight(replay: &mut ReplayData, w: &TrialWindow, span: (f64, f64), reason: String) {
    if !replay.highlighted.iter().any(|h| h.trial == w.index) {
        replay.highlighted.push(HighlightedTrial {
            trial: w.index,
            t_start: span.0,
            t_end: span.1,
            reason,
        });
    }
}

/// Stage: what the replay shows of the found terms: their fields beside the residual, the
/// prediction with them, and the trials they improve most.
pub(crate) fn show_found(d: &mut Diagnosis, f: &RowFields, rows: &Rows, metas: &[TrialMeta]) {
    let Some(r) = &d.discovery else {
        return;
    };
    if r.accepted.is_empty() || r.pred.len() != rows.len() {
        return;
    }
    for name in r.accepted.iter().flat_map(|t| t.fields.clone()) {
        locate_field(&mut d.replay, f, &name);
    }
    d.replay.found_w = r.pred.clone();
    let n = metas.len();
    let before = select::trial_sse(&rows.y, &d.replay.after_w, &rows.trial, n);
    let after = select::trial_sse(&rows.y, &r.pred, &rows.trial, n);
    let mut gain: Vec<(usize, f64)> = (0..n).map(|t| (t, before[t] - after[t])).collect();
    gain.sort_by(|a, b| b.1.total_cmp(&a.1));
    let names: Vec<&str> = r.accepted.iter().map(|t| t.name.as_str()).collect();
    for &(t, g) in gain.iter().take(5).filter(|(_, g)| *g > 0.0) {
        let w = &metas[t].window;
        let reason = format!(
            "carries what was found beyond the library ({}): held-out squared error −{g:.2} W²",
            names.join("; ")
        );
        highlight(&mut d.replay, w, (w.t_traj_start, w.t_return_end), reason);
    }
}
