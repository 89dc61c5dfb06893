//! What an identified power model adds to a replay: per-sample predicted vs measured net power,
//! per-joint loss-term series, per-trajectory predictions and the trials the IMU and 3σ
//! filters reject (with their statistics), so contaminated trajectories can be found in the viewer.

use anyhow::Result;

use super::replay::{PowerPrediction, ReplayExtras, TermSeries, TrajectoryPoint, TrialMark};
use crate::identify::dataset::{self, DatasetOptions, Mode};
use crate::identify::{IdentifyOptions, Validation, validate};
use crate::power::PowerModel;
use crate::signals::Recording;

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
    let power = opts.target.series(rec);

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
            // Zero-order hold of the latest reading: what the sensor said at that moment.
            let r = power.t.partition_point(|&tp| tp <= t);
            let measured = if r == 0 {
                f64::NAN
            } else {
                power.watts[r - 1] - basis.baseline_w
            };
            let b = model.breakdown(&s.tau[k], &s.dq[k], &basis.tau0_sq);
            prediction.t.push(t);
            prediction.measured_net.push(measured);
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

    let trajectories = v
        .per_trial
        .iter()
        .map(|p| TrajectoryPoint {
            trial: p.trial,
            t: p.window.1,
            measured: p.measured_w,
            predicted: p.predicted_w,
        })
        .collect();

    let trials = seg
        .trials
        .iter()
        .map(|t| {
            let joints: Vec<String> = t
                .joints_moved
                .iter()
                .map(|&j| rec.joint_names.get(j).cloned().unwrap_or_default())
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
        trajectories,
        terms: Some(terms),
        trials,
        diagnosis: None,
    };
    Ok((extras, v))
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
