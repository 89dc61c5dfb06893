//! What an identified power model adds to a replay: each power reading next to the model's
//! prediction averaged over that reading's own window (like for like, as `validate` scores it),
//! the instantaneous prediction as context, per-joint loss-term series, per-trajectory errors,
//! the IMU filter's statistic and threshold, and the trials the IMU and 3σ filters reject (with
//! their statistics, as `validate` records them), so contaminated trajectories can be found in
//! the viewer.

use anyhow::Result;

use std::collections::BTreeMap;

use super::replay::{
    ImuFilterMarks, ModelSeries, ReadingPrediction, ReplayExtras, TermSeries, TrajectoryPoint,
    TrialMark,
};
use crate::identify::{IdentifyOptions, Validation, validate};
use crate::power::PowerModel;
use crate::signals::{Recording, StateSeries};
use crate::trial::TrialWindow;

/// Replay extras of `model` applied to `rec` (segmented and filtered as `opts` says), plus the
/// hold-out validation it is built on. The whole session is in memory; the streamed replay
/// builds the same extras from [`crate::identify::validate_file`].
pub fn model_extras(
    rec: &Recording,
    model: &PowerModel,
    opts: &IdentifyOptions,
) -> Result<(ReplayExtras, Validation)> {
    let v = validate(model, rec, opts)?;
    Ok((validation_extras(&v, opts, &rec.joint_names, model), v))
}

/// The model's instantaneous prediction and loss terms at every sample of `state` in `trial`'s
/// window (pre-idle start to return end), with the trial's copper baseline `tau0_sq`.
pub(super) fn trial_series(
    state: &StateSeries,
    trial: &TrialWindow,
    tau0_sq: &[f64; crate::N_JOINTS],
    model: &PowerModel,
) -> TermSeries {
    let n = state.t.len().min(state.tau.len()).min(state.dq.len());
    let first = state.t[..n].partition_point(|&t| t < trial.t_pre_start);
    let last = state.t[..n].partition_point(|&t| t <= trial.t_return_end);
    let mut terms = TermSeries::default();
    for k in first..last.max(first) {
        let (tau, dq) = (&state.tau[k], &state.dq[k]);
        let b = model.breakdown(tau, dq, tau0_sq);
        terms.t.push(state.t[k]);
        terms.predicted.push(model.predict(tau, dq, tau0_sq));
        let per_joint = [b.mechanical, b.copper, b.coulomb, b.viscous];
        for (series, v) in terms.per_joint.iter_mut().zip(per_joint) {
            series.push(v);
        }
        terms.interaction.push(b.interaction_total());
    }
    terms
}

/// The extras a validation of `model` gives without the samples: each reading with its
/// like-for-like prediction, per-trajectory errors, the IMU filter marks and the trial marks
/// (with the rejections `validate` records; `joint_names` label the trials), and the model with
/// the usable trials (those with a copper baseline), in session order, whose per-sample series
/// the replay computes ([`trial_series`]).
pub(super) fn validation_extras(
    v: &Validation,
    opts: &IdentifyOptions,
    joint_names: &[String],
    model: &PowerModel,
) -> ReplayExtras {
    // Indexed once: a linear search per baseline is quadratic in trials (~1e6 steps at paper scale).
    let mut by_index: BTreeMap<_, &TrialWindow> = BTreeMap::new();
    for t in &v.session.segmentation.trials {
        by_index.entry(t.index).or_insert(t); // the first, as a search would find
    }
    let plan = (v.baselines.iter())
        .filter_map(|b| Some(((*by_index.get(&b.trial)?).clone(), b.tau0_sq)))
        .collect();
    let is_rejected = |trial: usize| crate::trial::is_rejected(&v.rejections, 0, trial);
    let mut readings = ReadingPrediction {
        window_s: v.alignment.window_s,
        lag_s: v.alignment.lag_s,
        ..ReadingPrediction::default()
    };
    for r in &v.readings {
        readings.t.push(r.t);
        readings.trial.push(r.trial);
        readings.measured.push(r.measured_w);
        readings.predicted.push(r.predicted_w);
        readings.rejected.push(is_rejected(r.trial));
    }
    let trajectories = v
        .per_trial
        .iter()
        .map(|p| TrajectoryPoint {
            trial: p.trial,
            t: p.window.1,
            measured: p.measured_w,
            predicted: p.predicted_w,
            rejected: p.rejected,
            rest_w: p.rest_w,
        })
        .collect();
    let trials = v
        .session
        .segmentation
        .trials
        .iter()
        .map(|t| {
            let joints: Vec<String> = t
                .joints_moved
                .iter()
                .map(|&j| {
                    joint_names
                        .get(j)
                        .map(|n| super::short_joint_name(n))
                        .unwrap_or_default()
                })
                .collect();
            TrialMark {
                index: t.index,
                t_start: t.t_traj_start,
                t_end: t.t_post_end,
                label: format!(
                    "trial {} · {} · {:.2} rad/s",
                    t.index,
                    joints.join("+"),
                    t.qdot_max_cmd
                ),
                rejected: v.rejections.iter().find(|r| r.trial == t.index).cloned(),
                highlight: None,
            }
        })
        .collect();
    ReplayExtras {
        model: Some(ModelSeries {
            model: *model,
            plan,
        }),
        readings: Some(readings),
        trajectories,
        trials,
        imu_filter: imu_marks(v, opts),
        diagnosis: None,
    }
}

/// The IMU filter's statistic per trial (over its trajectory window) and its threshold, as the
/// filter cascade computes it from the same statistics.
fn imu_marks(v: &Validation, opts: &IdentifyOptions) -> Option<ImuFilterMarks> {
    let spans = v.per_trial.iter();
    let spans = spans.map(|p| (p.window.0, p.window.1, p.sigma_omega));
    ImuFilterMarks::new(opts.filters.imu_k, spans.collect())
}

/// Replay extras of a diagnosis: measured vs before/after predictions per reading, and the trials
/// where the mismatch was located, highlighted with the reason.
pub fn diagnosis_extras(d: &crate::diagnose::Diagnosis) -> ReplayExtras {
    let r = &d.replay;
    // Located trials with their reason, rejected ones with their rejection.
    let marks =
        (r.highlighted.iter().map(|h| (h, true))).chain(r.rejected.iter().map(|h| (h, false)));
    let highlighted = marks
        .map(|(h, located)| TrialMark {
            index: h.trial,
            t_start: h.t_start,
            t_end: h.t_end,
            label: format!("trial {}", h.trial),
            rejected: (!located)
                .then(|| d.rejected.iter().find(|x| x.trial == h.trial).cloned())
                .flatten(),
            highlight: located.then(|| h.reason.clone()),
        })
        .collect();
    ReplayExtras {
        diagnosis: Some(super::replay::DiagnosisOverlay {
            data: r.clone(),
            highlighted,
            summary: crate::diagnose::summary::summary_markdown(d),
            counterpart: d.counterpart.as_ref().map(|c| c.series.clone()),
            window: Some(d.sensor_window).filter(|w| w.drift_s != 0.0),
        }),
        imu_filter: r.imu.clone(),
        ..ReplayExtras::default()
    }
}
