//! Sample-by-sample comparison of a recording with its simulated counterpart: the twin driven by
//! the recording's own commands on the same timeline (`g1viz simulate --like SESSION`). Where the
//! model-level diagnosis explains the recording with fitted terms, this shows directly how far
//! the twin's torques and power are from the robot's, per joint and per trial.

use std::path::Path;

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};

use super::Diagnosis;
use crate::N_JOINTS;
use crate::session::SessionFile;
use crate::signals::{PowerSeries, Recording, load_recording, stream_recording};

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

fn abs_ns(start_ns: u64, t: f64) -> i128 {
    i128::from(start_ns) + (t * 1e9).round() as i128
}

/// Index pairs (a, b) of samples whose absolute times agree within the tolerance (`ta` on the
/// clock starting at `a`, `tb` at `b`; both in time order).
fn match_times(a: u64, ta: &[f64], b: u64, tb: &[f64]) -> Vec<(usize, usize)> {
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

fn idle_mean(p: &PowerSeries, before: f64) -> Option<f64> {
    let idle = p.t.iter().zip(&p.watts).filter(|(t, _)| **t < before);
    Some(super::meters::finite_mean(idle.map(|(_, &w)| w))).filter(|m| m.is_finite())
}

/// Per-joint sums over the matched joint samples (recording − counterpart), in time order.
struct JointSums {
    matched: usize,
    tau_sq: [f64; N_JOINTS],
    tau: [f64; N_JOINTS],
    q_sq: [f64; N_JOINTS],
    /// The per-sample torque differences, when the viewer needs them.
    series: Option<(Vec<f64>, Vec<[f64; N_JOINTS]>)>,
}

impl JointSums {
    fn new(keep_series: bool) -> JointSums {
        JointSums {
            matched: 0,
            tau_sq: [0.0; N_JOINTS],
            tau: [0.0; N_JOINTS],
            q_sq: [0.0; N_JOINTS],
            series: keep_series.then(Default::default),
        }
    }

    /// One matched pair: the recording's sample at `t` and the counterpart's.
    fn add(
        &mut self,
        t: f64,
        real: (&[f64; N_JOINTS], &[f64; N_JOINTS]),
        sim: (&[f64; N_JOINTS], &[f64; N_JOINTS]),
    ) {
        let ((qr, tr), (qs, ts)) = (real, sim);
        let d: [f64; N_JOINTS] = std::array::from_fn(|j| tr[j] - ts[j]);
        for j in 0..N_JOINTS {
            let dq = qr[j] - qs[j];
            self.tau_sq[j] += d[j] * d[j];
            self.tau[j] += d[j];
            self.q_sq[j] += dq * dq;
        }
        self.matched += 1;
        if let Some((tt, dd)) = &mut self.series {
            tt.push(t);
            dd.push(d);
        }
    }
}

/// What [`finish`] needs of one side: its file, clock origin and target power series.
struct Side<'a> {
    source: &'a Path,
    start_ns: u64,
    power: &'a PowerSeries,
}

/// The comparison from the merge `m` (its joint sums, the recording's joint samples and first
/// motion, the counterpart's power) and the recording's side, with the counterpart's file and
/// clock origin.
fn finish(
    m: Merge<'_>,
    joint_names: &[String],
    real: Side,
    (sim_source, sim_start_ns): (&Path, u64),
    d: &Diagnosis,
) -> Result<CounterpartComparison> {
    let (sums, real_samples, moved) = (m.sums, m.real_samples, m.moved);
    let sim = Side {
        source: sim_source,
        start_ns: sim_start_ns,
        power: &m.sim_power,
    };
    let share = sums.matched as f64 / real_samples.max(1) as f64;
    if share < MIN_MATCHED_SHARE {
        bail!(
            "{}: only {} of {} joint samples of {} share its timeline; make the counterpart with `g1viz simulate --like {}`",
            sim.source.display(),
            sums.matched,
            real_samples,
            real.source.display(),
            real.source.display()
        );
    }
    let n = sums.matched as f64;
    let joints = (0..N_JOINTS)
        .map(|j| JointDifference {
            joint: super::hypotheses::joint_name(joint_names, j),
            tau_rms_nm: (sums.tau_sq[j] / n).sqrt(),
            tau_bias_nm: sums.tau[j] / n,
            q_rms_rad: (sums.q_sq[j] / n).sqrt(),
        })
        .collect();

    // Net power: each side minus its own readings before the (recording's) first motion.
    let (pr, ps) = (real.power, sim.power);
    let (Some(br), Some(bs)) = (idle_mean(pr, moved), idle_mean(ps, moved)) else {
        bail!(
            "{} / {}: no {:?} power reading before the arm first moves (t = {moved:.2} s): no idle baseline to compare net power",
            real.source.display(),
            sim.source.display(),
            d.target
        );
    };
    let readings = match_times(real.start_ns, &pr.t, sim.start_ns, &ps.t);
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

    let (tau_t, tau_diff) = sums.series.unwrap_or_default();
    Ok(CounterpartComparison {
        source: sim.source.display().to_string(),
        matched_samples: sums.matched,
        joints,
        matched_readings: diffs.len(),
        power_rms_w: (sse / n).sqrt(),
        power_bias_w: bias,
        power_r2: if sst > 0.0 { 1.0 - sse / sst } else { f64::NAN },
        worst_trials: worst,
        series: CounterpartSeries {
            power_t: diffs.iter().map(|x| x.0).collect(),
            power_w: diffs.iter().map(|x| x.2).collect(),
            tau_t,
            tau_diff,
        },
    })
}

/// Compare `real` (the diagnosed recording) with `sim`, its counterpart, on the diagnosis'
/// power target; trials are those of `d` (their readings in `d.replay`). The same merge as
/// [`compare_files`], over each recording as one batch.
pub fn compare(real: &Recording, sim: &Recording, d: &Diagnosis) -> Result<CounterpartComparison> {
    let mut once = Some(SimBatch::of(sim, d.target));
    let mut m = Merge::new(true, Box::new(move || once.take()));
    m.add_real(real.start_ns, &real.state)?;
    m.drain()?;
    let side = Side {
        source: &real.source,
        start_ns: real.start_ns,
        power: d.target.series(real),
    };
    finish(m, &real.joint_names, side, (&sim.source, sim.start_ns), d)
}

/// One batch of the counterpart's joint samples (absolute times) and target power readings.
struct SimBatch {
    ns: Vec<i128>,
    q: Vec<[f64; N_JOINTS]>,
    tau: Vec<[f64; N_JOINTS]>,
    power: PowerSeries,
}

impl SimBatch {
    /// The batch of recording `b` (`target`: the diagnosis' power target).
    fn of(b: &Recording, target: crate::signals::Target) -> SimBatch {
        let st = &b.state;
        SimBatch {
            ns: st.t.iter().map(|&t| abs_ns(b.start_ns, t)).collect(),
            q: st.q.clone(),
            tau: st.tau.clone(),
            power: target.series(b).clone(),
        }
    }
}

/// The counterpart's samples not yet passed by the recording: (absolute time, q, τ).
type SimQueue = std::collections::VecDeque<(i128, [f64; N_JOINTS], [f64; N_JOINTS])>;

/// The recording's joint samples merged with the counterpart's in time order, batch by batch:
/// each recording sample is paired with the counterpart's sample within the tolerance, if any.
struct Merge<'a> {
    sums: JointSums,
    /// The recording's first sample, and the first time [s] the arm is this far from it
    /// (`+∞` while it has not moved).
    q0: Option<[f64; N_JOINTS]>,
    moved: f64,
    sim_power: PowerSeries,
    /// The counterpart's samples not yet passed by the recording.
    pending: SimQueue,
    /// The counterpart's next batch (`None`: its stream ended).
    next: Box<dyn FnMut() -> Option<SimBatch> + 'a>,
    sim_done: bool,
    last_sim: i128,
    last_real: f64,
    real_samples: usize,
}

impl<'a> Merge<'a> {
    fn new(keep_series: bool, next: Box<dyn FnMut() -> Option<SimBatch> + 'a>) -> Merge<'a> {
        Merge {
            sums: JointSums::new(keep_series),
            q0: None,
            moved: f64::INFINITY,
            sim_power: PowerSeries::default(),
            pending: SimQueue::new(),
            next,
            sim_done: false,
            last_sim: i128::MIN,
            last_real: f64::NEG_INFINITY,
            real_samples: 0,
        }
    }

    /// Queue a counterpart batch's samples and keep its readings.
    fn take_sim(&mut self, b: SimBatch) -> Result<()> {
        self.sim_power.t.extend_from_slice(&b.power.t);
        self.sim_power.watts.extend_from_slice(&b.power.watts);
        for ((ns, q), tau) in b.ns.into_iter().zip(b.q).zip(b.tau) {
            if ns < self.last_sim {
                return Err(OutOfOrder.into());
            }
            self.last_sim = ns;
            self.pending.push_back((ns, q, tau));
        }
        Ok(())
    }

    /// The recording's samples `st` (clock from `start_ns`), in time order.
    fn add_real(&mut self, start_ns: u64, st: &crate::signals::StateSeries) -> Result<()> {
        for k in 0..st.t.len().min(st.q.len()).min(st.tau.len()) {
            let t = st.t[k];
            if t < self.last_real {
                return Err(OutOfOrder.into());
            }
            self.last_real = t;
            self.real_samples += 1;
            let q0 = self.q0.get_or_insert(st.q[k]);
            let far = |(a, b): (&f64, &f64)| (a - b).abs() > MOTION_THRESHOLD_RAD;
            if self.moved == f64::INFINITY && st.q[k].iter().zip(q0.iter()).any(far) {
                self.moved = t;
            }
            let x = abs_ns(start_ns, t);
            loop {
                while (self.pending.front()).is_some_and(|p| p.0 < x - MATCH_TOLERANCE_NS) {
                    self.pending.pop_front();
                }
                if !self.pending.is_empty() || self.sim_done {
                    break;
                }
                match (self.next)() {
                    Some(sb) => self.take_sim(sb)?,
                    None => self.sim_done = true,
                }
            }
            if let Some(p) = self.pending.front()
                && (p.0 - x).abs() <= MATCH_TOLERANCE_NS
            {
                let (q, tau) = (p.1, p.2);
                self.sums.add(t, (&st.q[k], &st.tau[k]), (&q, &tau));
                self.pending.pop_front();
            }
        }
        Ok(())
    }

    /// The counterpart's remaining readings (its samples are no longer needed).
    fn drain(&mut self) -> Result<()> {
        while !self.sim_done {
            self.pending.clear();
            match (self.next)() {
                Some(sb) => self.take_sim(sb)?,
                None => self.sim_done = true,
            }
        }
        self.sim_power.sort_by_time();
        Ok(())
    }
}

/// Samples in batch order went back in time: the file has no index (its batches are sorted
/// only within themselves), so it is compared loaded.
#[derive(Debug)]
struct OutOfOrder;

impl std::fmt::Display for OutOfOrder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("samples out of time order")
    }
}

impl std::error::Error for OutOfOrder {}

/// [`compare`] on the two files read side by side, never held whole: the counterpart is
/// streamed on a second thread and merged with the recording sample by sample, keeping the
/// per-joint sums (and the per-sample torque differences only with `keep_series`, for the
/// viewer). Same figures as [`compare`] on the loaded recordings; a file whose samples do not
/// come in time order (no index) is loaded and compared so.
pub fn compare_files(
    real: &SessionFile,
    sim: &SessionFile,
    d: &Diagnosis,
    keep_series: bool,
) -> Result<CounterpartComparison> {
    match compare_streamed(real, sim, d, keep_series) {
        Err(e) if e.downcast_ref::<OutOfOrder>().is_some() => {
            let load = |f: &SessionFile| load_recording(&f.path, &f.map, &f.read);
            let (r, s) = (load(real)?, load(sim)?);
            let mut c = compare(&r, &s, d)?;
            if !keep_series {
                c.series.tau_t = Vec::new();
                c.series.tau_diff = Vec::new();
            }
            Ok(c)
        }
        other => other,
    }
}

fn compare_streamed(
    real: &SessionFile,
    sim: &SessionFile,
    d: &Diagnosis,
    keep_series: bool,
) -> Result<CounterpartComparison> {
    const BATCH: usize = 4096;
    let target = d.target;
    let (tx, rx) = std::sync::mpsc::sync_channel::<SimBatch>(2);
    let sim_file = sim.clone();
    let reader = std::thread::spawn(move || -> Result<u64> {
        let (path, map, read) = (&sim_file.path, &sim_file.map, &sim_file.read);
        let summary = stream_recording(path, map, read, BATCH, &mut |b| {
            tx.send(SimBatch::of(b, target))
                .map_err(|_| anyhow::anyhow!("the comparison stopped"))
        })
        .with_context(|| format!("reading the counterpart {}", sim_file.path.display()))?;
        Ok(summary.start_ns)
    });
    let mut m = Merge::new(keep_series, Box::new(move || rx.recv().ok()));
    let mut real_power = PowerSeries::default();
    let streamed = stream_recording(&real.path, &real.map, &real.read, BATCH, &mut |b| {
        let tp = target.series(b);
        real_power.t.extend_from_slice(&tp.t);
        real_power.watts.extend_from_slice(&tp.watts);
        m.add_real(b.start_ns, &b.state)
    })
    .with_context(|| format!("reading {}", real.path.display()));
    let drained = if streamed.is_ok() { m.drain() } else { Ok(()) };
    // The channel's receiver dropped: the reader thread ends.
    m.next = Box::new(|| None);
    let joined = reader
        .join()
        .map_err(|_| anyhow::anyhow!("the counterpart's reader thread panicked"))?;
    let real_summary = streamed?;
    drained?;
    let sim_start_ns = joined?;
    real_power.sort_by_time();
    let side = Side {
        source: &real.path,
        start_ns: real_summary.start_ns,
        power: &real_power,
    };
    finish(m, &real.map.joint_names, side, (&sim.path, sim_start_ns), d)
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
