//! Sample-by-sample comparison of a recording with its simulated counterpart: the twin driven by
//! the recording's own commands on the same timeline (`g1viz simulate --like SESSION`). Where the
//! model-level diagnosis explains the recording with fitted terms, this shows directly how far
//! the twin's torques and power are from the robot's, per joint and per trial.

use anyhow::{Result, bail};
use serde::{Deserialize, Serialize};

use super::Diagnosis;
use crate::N_JOINTS;
use crate::signals::{PowerSeries, Recording};

/// Samples closer than this in absolute time are the same message slot [ns].
const MATCH_TOLERANCE_NS: i128 = 1_000_000;

/// Share of the recording's joint samples the counterpart must match.
const MIN_MATCHED_SHARE: f64 = 0.5;

/// A joint moves once it is this far [rad] from its first sample (start of the idle baseline's end).
const MOTION_THRESHOLD_RAD: f64 = 0.02;

/// How one joint of the recording departs from the counterpart (recording − counterpart).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct JointDifference {
    /// URDF joint name.
    pub joint: String,
    /// RMS torque difference [Nm].
    pub tau_rms_nm: f64,
    /// Mean torque difference [Nm].
    pub tau_bias_nm: f64,
    /// RMS position difference [rad] (tracking: the twin follows the commands its own way).
    pub q_rms_rad: f64,
}

/// How one trial's net power departs from the counterpart's.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrialDifference {
    /// Trial index (segmentation numbering).
    pub trial: usize,
    /// First and last reading of the trial used [s, Recording time].
    pub t_start: f64,
    /// Last reading [s].
    pub t_end: f64,
    /// Mean net power difference over the trial's readings [W].
    pub power_mean_w: f64,
    /// Readings averaged.
    pub readings: usize,
}

/// The compared series themselves, for the viewer (`diagnose --save`); not stored in
/// diagnosis.json.
#[derive(Debug, Clone, Default)]
pub struct CounterpartSeries {
    /// Times of the readings found in both [s, recording time].
    pub power_t: Vec<f64>,
    /// The counterpart's net power at those readings [W].
    pub power_w: Vec<f64>,
    /// Times of the joint samples found in both [s, recording time].
    pub tau_t: Vec<f64>,
    /// Torque difference recording − counterpart per joint at those samples [Nm].
    pub tau_diff: Vec<[f64; N_JOINTS]>,
}

/// The comparison (recording − counterpart), stored in diagnosis.json.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CounterpartComparison {
    /// Counterpart file.
    pub source: String,
    /// Joint samples found in both.
    pub matched_samples: usize,
    /// Per joint, in model order.
    pub joints: Vec<JointDifference>,
    /// Power readings found in both (the diagnosis' target sensor).
    pub matched_readings: usize,
    /// RMS net power difference [W] (each side net of its own readings before the arm moves).
    pub power_rms_w: f64,
    /// Mean net power difference [W].
    pub power_bias_w: f64,
    /// R² of the counterpart's net power as a prediction of the recording's.
    pub power_r2: f64,
    /// Trials with the largest mean power difference (at most five), largest first.
    pub worst_trials: Vec<TrialDifference>,
    /// The per-sample series behind these figures (not serialized).
    #[serde(skip)]
    pub series: CounterpartSeries,
}

fn abs_ns(rec: &Recording, t: f64) -> i128 {
    i128::from(rec.start_ns) + (t * 1e9).round() as i128
}

/// Index pairs (a, b) of samples whose absolute times agree within the tolerance.
fn match_times(a: &Recording, ta: &[f64], b: &Recording, tb: &[f64]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut j = 0usize;
    for (i, &t) in ta.iter().enumerate() {
        let x = abs_ns(a, t);
        while j < tb.len() && abs_ns(b, tb[j]) < x - MATCH_TOLERANCE_NS {
            j += 1;
        }
        if let Some(&u) = tb.get(j)
            && (abs_ns(b, u) - x).abs() <= MATCH_TOLERANCE_NS
        {
            out.push((i, j));
            j += 1;
        }
    }
    out
}

/// Time [s] the arm first moves (`+∞` if never).
fn motion_start(rec: &Recording) -> f64 {
    let Some(q0) = rec.state.q.first() else {
        return f64::INFINITY;
    };
    rec.state
        .q
        .iter()
        .zip(&rec.state.t)
        .find(|(q, _)| {
            q.iter()
                .zip(q0)
                .any(|(a, b)| (a - b).abs() > MOTION_THRESHOLD_RAD)
        })
        .map_or(f64::INFINITY, |(_, &t)| t)
}

fn idle_mean(p: &PowerSeries, before: f64) -> Option<f64> {
    let v: Vec<f64> =
        p.t.iter()
            .zip(&p.watts)
            .filter(|(t, w)| **t < before && w.is_finite())
            .map(|(_, &w)| w)
            .collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// Compare `real` (the diagnosed recording) with `sim`, its counterpart, on the diagnosis'
/// power target; trials are those of `d` (their readings in `d.replay`).
pub fn compare(real: &Recording, sim: &Recording, d: &Diagnosis) -> Result<CounterpartComparison> {
    let pairs = match_times(real, &real.state.t, sim, &sim.state.t);
    let share = pairs.len() as f64 / real.state.t.len().max(1) as f64;
    if share < MIN_MATCHED_SHARE {
        bail!(
            "{}: only {} of {} joint samples of {} share its timeline; make the counterpart with `g1viz simulate --like {}`",
            sim.source.display(),
            pairs.len(),
            real.state.t.len(),
            real.source.display(),
            real.source.display()
        );
    }
    let tau_diff: Vec<[f64; N_JOINTS]> = pairs
        .iter()
        .map(|&(a, b)| std::array::from_fn(|j| real.state.tau[a][j] - sim.state.tau[b][j]))
        .collect();
    let mut joints = Vec::with_capacity(N_JOINTS);
    for j in 0..N_JOINTS {
        let (mut s2, mut s1, mut q2) = (0.0, 0.0, 0.0);
        for (&(a, b), d) in pairs.iter().zip(&tau_diff) {
            let dt = d[j];
            let dq = real.state.q[a][j] - sim.state.q[b][j];
            s2 += dt * dt;
            s1 += dt;
            q2 += dq * dq;
        }
        let n = pairs.len() as f64;
        joints.push(JointDifference {
            joint: real
                .joint_names
                .get(j)
                .cloned()
                .unwrap_or_else(|| format!("joint {j}")),
            tau_rms_nm: (s2 / n).sqrt(),
            tau_bias_nm: s1 / n,
            q_rms_rad: (q2 / n).sqrt(),
        });
    }

    // Net power: each side minus its own readings before the (recording's) first motion.
    let (pr, ps) = (d.target.series(real), d.target.series(sim));
    let moved = motion_start(real);
    let (Some(br), Some(bs)) = (idle_mean(pr, moved), idle_mean(ps, moved)) else {
        bail!(
            "{} / {}: no {:?} power reading before the arm first moves (t = {moved:.2} s): no idle baseline to compare net power",
            real.source.display(),
            sim.source.display(),
            d.target
        );
    };
    let readings = match_times(real, &pr.t, sim, &ps.t);
    let diffs: Vec<(f64, f64, f64)> = readings
        .iter()
        .map(|&(a, b)| (pr.t[a], pr.watts[a] - br, ps.watts[b] - bs))
        .filter(|(_, r, s)| r.is_finite() && s.is_finite())
        .collect();
    if diffs.is_empty() {
        bail!(
            "{}: no {:?} power reading at the recording's reading times",
            sim.source.display(),
            d.target
        );
    }
    let n = diffs.len() as f64;
    let bias = diffs.iter().map(|(_, r, s)| r - s).sum::<f64>() / n;
    let sse: f64 = diffs.iter().map(|(_, r, s)| (r - s) * (r - s)).sum();
    let mean_r = diffs.iter().map(|(_, r, _)| r).sum::<f64>() / n;
    let sst: f64 = diffs
        .iter()
        .map(|(_, r, _)| (r - mean_r) * (r - mean_r))
        .sum();

    // Per trial: the readings the diagnosis assigned to each trial.
    let mut per: std::collections::BTreeMap<usize, (f64, f64, f64, usize)> = Default::default();
    for (&t, &trial) in d.replay.t.iter().zip(&d.replay.trial) {
        let k = diffs.partition_point(|x| x.0 < t - 1e-6);
        if let Some(&(tk, r, s)) = diffs.get(k)
            && (tk - t).abs() < 1e-6
        {
            let e = per.entry(trial).or_insert((t, t, 0.0, 0));
            e.0 = e.0.min(t);
            e.1 = e.1.max(t);
            e.2 += r - s;
            e.3 += 1;
        }
    }
    let mut worst: Vec<TrialDifference> = per
        .into_iter()
        .map(|(trial, (t0, t1, sum, k))| TrialDifference {
            trial,
            t_start: t0,
            t_end: t1,
            power_mean_w: sum / k as f64,
            readings: k,
        })
        .collect();
    worst.sort_by(|a, b| b.power_mean_w.abs().total_cmp(&a.power_mean_w.abs()));
    worst.truncate(5);

    Ok(CounterpartComparison {
        source: sim.source.display().to_string(),
        matched_samples: pairs.len(),
        joints,
        matched_readings: diffs.len(),
        power_rms_w: (sse / n).sqrt(),
        power_bias_w: bias,
        power_r2: if sst > 0.0 { 1.0 - sse / sst } else { f64::NAN },
        worst_trials: worst,
        series: CounterpartSeries {
            power_t: diffs.iter().map(|x| x.0).collect(),
            power_w: diffs.iter().map(|x| x.2).collect(),
            tau_t: pairs.iter().map(|&(a, _)| real.state.t[a]).collect(),
            tau_diff,
        },
    })
}

/// Plain-language paragraph for the terminal summary and the report.
pub fn describe(c: &CounterpartComparison) -> String {
    let worst = c
        .joints
        .iter()
        .max_by(|a, b| a.tau_rms_nm.total_cmp(&b.tau_rms_nm));
    let mut s = format!(
        "Counterpart ({}, the twin driven by the same commands): net power differs by {:.2} W rms (recording − twin {:+.2} W on average, R² of the twin's power {:.3}) over {} readings",
        c.source, c.power_rms_w, c.power_bias_w, c.power_r2, c.matched_readings
    );
    if let Some(w) = worst {
        s.push_str(&format!(
            "; torque differs most on {} ({:.3} Nm rms, {:+.3} Nm on average)",
            w.joint, w.tau_rms_nm, w.tau_bias_nm
        ));
    }
    if let Some(t) = c.worst_trials.first() {
        s.push_str(&format!(
            "; largest trial difference: trial {} ({:+.2} W over {} readings, {:.0}–{:.0} s)",
            t.trial, t.power_mean_w, t.readings, t.t_start, t.t_end
        ));
    }
    s.push('.');
    s
}

impl Diagnosis {
    /// Add a counterpart comparison: stored in diagnosis.json and appended to the summary.
    pub fn attach_counterpart(&mut self, c: CounterpartComparison) {
        self.summary.push_str(&describe(&c));
        self.summary.push('\n');
        self.counterpart = Some(c);
    }
}
