//! What an identified power model adds to a replay: each power reading next to the model's
//! prediction averaged over that reading's own window (like for like, as `validate` scores it),
//! the instantaneous prediction as context, per-joint loss-term series, per-trajectory errors,
//! the IMU filter's statistic and threshold, and the trials the IMU and 3σ filters reject (with
//! their statistics, as `validate` records them), so contaminated trajectories can be found in
//! the viewer.

use anyhow::Result;

use super::replay::{
    ImuFilterMarks, PowerPrediction, ReadingPrediction, ReplayExtras, TermSeries, TrajectoryPoint,
    TrialMark,
};
use crate::identify::dataset::{self, DatasetOptions, Mode};
use crate::identify::{IdentifyOptions, Validation, validate};
use crate::power::PowerModel;
use crate::signals::Recording;
use crate::trial::TrialStat;

/// Replay extras of `model` applied to `rec` (segmented and filtered as `opts` says), plus the
/// hold-out validation it is built on.
pub fn model_extras(
    rec: &Recording,
    model: &PowerModel,
    opts: &IdentifyOptions,
) -> Result<(ReplayExtras, Validation)> {
    let v = validate(model, rec, opts)?;
    let seg = &v.session.segmentation;
    let bases = dataset::build(
        rec,
        &seg.trials,
        &DatasetOptions {
            mode: Mode::Trial,
            target: opts.target,
            alignment: v.alignment,
        },
    )
    .trials;

    let mut prediction = PowerPrediction::default();
    let mut terms = TermSeries::default();
    for basis in &bases {
        let Some(trial) = seg.trials.iter().find(|t| t.index == basis.trial) else {
            continue;
        };
        let s = &rec.state;
        let first = s.t.partition_point(|&t| t < trial.t_pre_start);
        let last = s.t.partition_point(|&t| t <= trial.t_return_end);
        for k in first..last {
            let t = s.t[k];
            let b = model.breakdown(&s.tau[k], &s.dq[k], &basis.tau0_sq);
            prediction.t.push(t);
            prediction
                .predicted
                .push(model.predict(&s.tau[k], &s.dq[k], &basis.tau0_sq));
            terms.t.push(t);
            terms.mechanical.push(b.mechanical);
            terms.copper.push(b.copper);
            terms.coulomb.push(b.coulomb);
            terms.viscous.push(b.viscous);
            terms.interaction.push(b.interaction_total());
        }
    }

    let is_rejected = |trial: usize| crate::trial::is_rejected(&v.rejections, 0, trial);
    let readings = reading_predictions(rec, model, &v, opts, &is_rejected);
    let trajectories = v
        .per_trial
        .iter()
        .map(|p| TrajectoryPoint {
            trial: p.trial,
            t: p.window.1,
            measured: p.measured_w,
            predicted: p.predicted_w,
            rejected: p.rejected,
        })
        .collect();
    let imu_filter = imu_marks(&v, opts);

    let trials = seg
        .trials
        .iter()
        .map(|t| {
            let joints: Vec<String> = t
                .joints_moved
                .iter()
                .map(|&j| {
                    rec.joint_names
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
    let extras = ReplayExtras {
        prediction: Some(prediction),
        readings: Some(readings),
        trajectories,
        terms: Some(terms),
        trials,
        imu_filter,
        diagnosis: None,
    };
    Ok((extras, v))
}

/// Every power reading inside a trial's trajectory window, paired with the model's prediction
/// averaged over the reading's own window (the sensor timing `validate` used): the rows
/// `validate` scores per reading, so their error is its per-reading error.
fn reading_predictions(
    rec: &Recording,
    model: &PowerModel,
    v: &Validation,
    opts: &IdentifyOptions,
    is_rejected: &dyn Fn(usize) -> bool,
) -> ReadingPrediction {
    let rows = dataset::build(
        rec,
        &v.session.segmentation.trials,
        &DatasetOptions {
            mode: Mode::Reading,
            target: opts.target,
            alignment: v.alignment,
        },
    )
    .rows;
    let theta = model.to_vector();
    let mut out = ReadingPrediction {
        window_s: v.alignment.window_s,
        lag_s: v.alignment.lag_s,
        ..ReadingPrediction::default()
    };
    for row in rows {
        out.t.push(row.t);
        out.trial.push(row.trial);
        out.measured.push(row.y);
        out.predicted
            .push(theta.iter().zip(&row.phi).map(|(a, b)| a * b).sum());
        out.rejected.push(is_rejected(row.trial));
    }
    out
}

/// The IMU filter's statistic per trial (over its trajectory window) and its threshold, as the
/// filter cascade computes it from the same statistics ([`crate::trial::Cascade::imu_threshold`]).
fn imu_marks(v: &Validation, opts: &IdentifyOptions) -> Option<ImuFilterMarks> {
    let k = opts.filters.imu_k?;
    let sigmas: Vec<TrialStat> = v
        .per_trial
        .iter()
        .map(|p| TrialStat::new(0, p.trial, p.sigma_omega))
        .collect();
    let threshold = opts.filters.imu_threshold(&sigmas)?;
    if !threshold.is_finite() {
        return None;
    }
    Some(ImuFilterMarks {
        k,
        threshold,
        spans: v
            .per_trial
            .iter()
            .map(|p| (p.window.0, p.window.1, p.sigma_omega))
            .collect(),
    })
}

/// Replay extras of a diagnosis: measured vs before/after predictions per reading, and the trials
/// where the mismatch was located, highlighted with the reason.
pub fn diagnosis_extras(d: &crate::diagnose::Diagnosis) -> ReplayExtras {
    let r = &d.replay;
    let highlighted = r
        .highlighted
        .iter()
        .map(|h| TrialMark {
            index: h.trial,
            t_start: h.t_start,
            t_end: h.t_end,
            label: format!("trial {}", h.trial),
            rejected: None,
            highlight: Some(h.reason.clone()),
        })
        .collect();
    ReplayExtras {
        diagnosis: Some(super::replay::DiagnosisOverlay {
            t: r.t.clone(),
            measured: r.measured_w.clone(),
            before: r.before_w.clone(),
            after: r.after_w.clone(),
            highlighted,
            summary: d.summary.clone(),
            counterpart: d.counterpart.as_ref().map(|c| c.series.clone()),
            found: r.found_w.clone(),
            located: r
                .located
                .iter()
                .map(|l| (l.name.clone(), l.values.clone()))
                .collect(),
        }),
        ..ReplayExtras::default()
    }
}
