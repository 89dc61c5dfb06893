//! Regression rows (φ, y) for the power model from segmented trials.
//!
//! Per state sample the regressor φ (49) is [`crate::power::regressor_into`] of the measured
//! torque (`tau_est`) and velocity, with Δτ² taken against the trial's pre-idle mean τ² per joint.
//! The target is net power: the power reading (MBS by default, BMS on request) minus the mean of
//! the readings in the trial's pre-idle window.
//!
//! Three ways to pair the ~1 Hz power readings with the 100 Hz regressors:
//! * [`Mode::Trial`] — the paper's trajectory-level aggregation: one row per trial, φ averaged over
//!   the trajectory window (trajectory start → post-idle end) and y the mean of the readings whose
//!   averaging window is centred in it.
//! * [`Mode::Sample`] — one row per state sample, y the latest reading at or before the sample
//!   (zero-order hold): each reading repeats ~100 times, the degenerate setup the paper warns about.
//! * [`Mode::Reading`] — beyond the paper: one row per reading inside the trajectory window, φ
//!   averaged over the reading's own averaging window [t − lag − W, t − lag]. The sensor window W
//!   and lag are estimated from the data by [`estimate_alignment`] (the scan lives in
//!   [`crate::timing`]).

use anyhow::{Result, bail};

use crate::power::regressor_into;
pub use crate::signals::Target;
use crate::signals::{PowerSeries, Recording};
pub use crate::timing::{Alignment, AlignmentEstimate, AlignmentScore};
use crate::timing::{ScanGrid, SearchFits, SearchRow, scan_alignment};
use crate::trial::{MIN_WINDOW_SAMPLES, TrialWindow, samples_in, sigma_omega};
use crate::{N_JOINTS, N_PARAMS};

/// How readings and regressors are paired into rows (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Mode {
    /// One row per trial (the paper's aggregation).
    Trial,
    /// One row per power reading, regressors averaged over the reading's window.
    Reading,
    /// One row per state sample, zero-order-held power (degenerate; for comparison).
    Sample,
}

impl Mode {
    /// Lower-case name ("trial" / "reading" / "sample").
    pub fn name(&self) -> &'static str {
        match self {
            Mode::Trial => "trial",
            Mode::Reading => "reading",
            Mode::Sample => "sample",
        }
    }
}

/// One regression row.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// Index of the trial (in its [`crate::trial::Segmentation`]).
    pub trial: usize,
    /// Time the row stands for [s]: reading stamp (reading mode), sample time (sample mode),
    /// trajectory start (trial mode).
    pub t: f64,
    /// Start of the interval φ was averaged over [s] (= `t` for a sample row).
    pub t0: f64,
    /// End of that interval [s].
    pub t1: f64,
    /// Regressor (mean over the interval).
    pub phi: [f64; N_PARAMS],
    /// Net power [W].
    pub y: f64,
    /// The trial's IMU statistic σ_ω = std(|ω_body|) over its trajectory window [rad/s].
    pub sigma_omega: f64,
    /// The trial's pre-idle mean squared torque per joint [Nm²].
    pub tau0_sq: [f64; N_JOINTS],
}

/// Per-trial quantities shared by its rows.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TrialBasis {
    /// Trial index.
    pub trial: usize,
    /// Pre-idle mean power [W] (subtracted from every reading of the trial).
    pub baseline_w: f64,
    /// Number of readings the baseline averages.
    pub baseline_readings: usize,
    /// Pre-idle mean τ² per joint [Nm²].
    pub tau0_sq: [f64; N_JOINTS],
    /// σ_ω over the trajectory window [rad/s].
    pub sigma_omega: f64,
    /// Trajectory window [s] (trajectory start → post-idle end).
    pub window: (f64, f64),
}

/// A trial that yields no rows, with the reason.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Skipped {
    /// Trial index.
    pub trial: usize,
    /// Why.
    pub reason: String,
}

/// Rows of one recording.
#[derive(Debug, Clone, Default)]
pub struct Dataset {
    /// The rows, grouped by trial in time order.
    pub rows: Vec<Row>,
    /// Per-trial baselines and statistics of every trial that has rows.
    pub trials: Vec<TrialBasis>,
    /// Trials without rows.
    pub skipped: Vec<Skipped>,
}

/// Options of [`build`].
#[derive(Debug, Clone, Copy)]
pub struct DatasetOptions {
    /// Pairing.
    pub mode: Mode,
    /// Power sensor.
    pub target: Target,
    /// Reading timing.
    pub alignment: Alignment,
}

/// Sum of φ (with Δτ² against zero) and count over the state samples `r`.
fn phi_sum(rec: &Recording, r: std::ops::Range<usize>) -> ([f64; N_PARAMS], usize) {
    let s = &rec.state;
    let mut sum = [0.0; N_PARAMS];
    let mut phi = [0.0; N_PARAMS];
    for k in r.clone() {
        regressor_into(&s.tau[k], &s.dq[k], &[0.0; N_JOINTS], &mut phi);
        for (acc, v) in sum.iter_mut().zip(&phi) {
            *acc += v;
        }
    }
    (sum, r.len())
}

/// The joint-state times of `rec` that have τ and q̇ too.
fn state_times(rec: &Recording) -> &[f64] {
    let s = &rec.state;
    &s.t[..s.t.len().min(s.tau.len()).min(s.dq.len())]
}

/// Mean φ over the samples in (t0, t1] ([`samples_in`]) with Δτ² against `tau0_sq`; None with
/// fewer than [`MIN_WINDOW_SAMPLES`] inside.
fn phi_mean(
    rec: &Recording,
    t0: f64,
    t1: f64,
    tau0_sq: &[f64; N_JOINTS],
) -> Option<[f64; N_PARAMS]> {
    let (mut sum, count) = phi_sum(rec, samples_in(state_times(rec), t0, t1));
    if count < MIN_WINDOW_SAMPLES {
        return None;
    }
    for v in &mut sum {
        *v /= count as f64;
    }
    for j in 0..N_JOINTS {
        sum[N_JOINTS + j] -= tau0_sq[j];
    }
    Some(sum)
}

/// Per-joint mean τ² over the trial's pre-idle samples ([`TrialWindow::pre_idle`]).
fn mean_tau_sq(rec: &Recording, trial: &TrialWindow) -> Option<[f64; N_JOINTS]> {
    let (sum, count) = phi_sum(rec, trial.pre_idle(state_times(rec))?);
    Some(std::array::from_fn(|j| sum[N_JOINTS + j] / count as f64))
}

/// Readings whose averaging window lies inside [a, b] ([`crate::trial::readings_within`]):
/// (stamp, watts).
fn readings_within<'a>(
    p: &'a PowerSeries,
    align: &Alignment,
    a: f64,
    b: f64,
) -> impl Iterator<Item = (f64, f64)> + 'a {
    let r = crate::trial::readings_within(&p.t, a, b, align.lag_s, align.window_s);
    reading_values(p, r)
}

/// (stamp, watts) of the readings `r` of `p`.
fn reading_values(p: &PowerSeries, r: std::ops::Range<usize>) -> impl Iterator<Item = (f64, f64)> {
    let end = r.end.min(p.watts.len());
    let r = r.start.min(end)..end;
    p.t[r.clone()]
        .iter()
        .copied()
        .zip(p.watts[r].iter().copied())
}

/// What [`trial_basis`] computes from the joint states alone (the pre-idle τ̄0² and σ_ω): the
/// same for every alignment, so the timing search keeps it per trial (keyed by trial index).
type StateBasis = std::collections::HashMap<usize, Result<([f64; N_JOINTS], f64), String>>;

/// Baseline and statistics of one trial; Err(reason) when the trial cannot give rows. The
/// alignment-independent part comes from `cache` when given (and is kept there): the same
/// values, computed once per trial instead of once per alignment.
fn trial_basis(
    rec: &Recording,
    trial: &TrialWindow,
    target: Target,
    align: &Alignment,
    cache: Option<&mut StateBasis>,
) -> Result<TrialBasis, String> {
    let power = target.series(rec);
    let (pre0, pre1) = (trial.t_pre_start, trial.t_traj_start);
    let base = trial.baseline_readings(&power.t, align.lag_s, align.window_s);
    let pre: Vec<f64> = reading_values(power, base)
        .map(|(_, w)| w)
        .filter(|w| w.is_finite())
        .collect();
    if pre.is_empty() {
        return Err(format!(
            "no {} reading inside the pre-idle window {pre0:.2}–{pre1:.2} s (no baseline)",
            target.name().to_uppercase()
        ));
    }
    let window = (trial.t_traj_start, trial.t_post_end);
    let state = || {
        let tau0_sq = mean_tau_sq(rec, trial).ok_or_else(|| {
            format!(
                "fewer than {} joint-state samples in the pre-idle {pre0:.2}–{pre1:.2} s",
                crate::trial::MIN_PRE_IDLE_SAMPLES
            )
        })?;
        Ok((tau0_sq, sigma_omega(rec, window.0, window.1)))
    };
    let (tau0_sq, sigma) = match cache {
        Some(c) => c.entry(trial.index).or_insert_with(state).clone()?,
        None => state()?,
    };
    Ok(TrialBasis {
        trial: trial.index,
        baseline_w: pre.iter().sum::<f64>() / pre.len() as f64,
        baseline_readings: pre.len(),
        tau0_sq,
        sigma_omega: sigma,
        window,
    })
}

/// Keep a row only when all its numbers are finite (a NaN in a damaged file must not poison the fit).
fn push_finite(rows: &mut Vec<Row>, row: Row) {
    if row.y.is_finite() && row.phi.iter().all(|v| v.is_finite()) {
        rows.push(row);
    }
}

/// Build the rows of one recording's trials.
pub fn build(rec: &Recording, trials: &[TrialWindow], opts: &DatasetOptions) -> Dataset {
    let mut out = Dataset::default();
    let power = opts.target.series(rec);
    for trial in trials {
        let basis = match trial_basis(rec, trial, opts.target, &opts.alignment, None) {
            Ok(b) => b,
            Err(reason) => {
                out.skipped.push(Skipped {
                    trial: trial.index,
                    reason,
                });
                continue;
            }
        };
        let (a, b) = basis.window;
        let before = out.rows.len();
        let row = |t: f64, t0: f64, t1: f64, phi: [f64; N_PARAMS], watts: f64| Row {
            trial: trial.index,
            t,
            t0,
            t1,
            phi,
            y: watts - basis.baseline_w,
            sigma_omega: basis.sigma_omega,
            tau0_sq: basis.tau0_sq,
        };
        match opts.mode {
            Mode::Trial => {
                let inside: Vec<f64> = power
                    .t
                    .iter()
                    .zip(&power.watts)
                    .filter(|(t, _)| (a..=b).contains(&opts.alignment.centre_of(**t)))
                    .map(|(_, w)| *w)
                    .collect();
                if let (false, Some(phi)) = (inside.is_empty(), phi_mean(rec, a, b, &basis.tau0_sq))
                {
                    let mean = inside.iter().sum::<f64>() / inside.len() as f64;
                    push_finite(&mut out.rows, row(a, a, b, phi, mean));
                }
            }
            Mode::Reading => {
                for (t, w) in readings_within(power, &opts.alignment, a, b) {
                    let (t0, t1) = opts.alignment.window_of(t);
                    if let Some(phi) = phi_mean(rec, t0, t1, &basis.tau0_sq) {
                        push_finite(&mut out.rows, row(t, t0, t1, phi, w));
                    }
                }
            }
            Mode::Sample => sample_rows(rec, power, &basis, trial.index, 1, &mut out.rows),
        }
        if out.rows.len() == before {
            out.skipped.push(Skipped {
                trial: trial.index,
                reason: format!(
                    "no {} reading with finite joint-state samples in the trajectory window {a:.2}–{b:.2} s",
                    opts.target.name().to_uppercase()
                ),
            });
        } else {
            out.trials.push(basis);
        }
    }
    out
}

/// The sample rows (zero-order-held power) of one trial with its `basis`, keeping every
/// `every`-th row produced (all for 1); the rows left out are never materialised.
fn sample_rows(
    rec: &Recording,
    power: &PowerSeries,
    basis: &TrialBasis,
    trial: usize,
    every: usize,
    out: &mut Vec<Row>,
) {
    let (s, t, (a, b)) = (&rec.state, state_times(rec), basis.window);
    let (i0, i1) = (
        t.partition_point(|&x| x <= a),
        t.partition_point(|&x| x <= b),
    );
    let every = every.max(1);
    let mut produced = 0usize;
    let mut phi = [0.0; N_PARAMS];
    for k in i0..i1 {
        // Zero-order hold: the latest reading stamped at or before the sample.
        let r = power.t.partition_point(|&x| x <= s.t[k]);
        let Some(&w) = r.checked_sub(1).and_then(|r| power.watts.get(r)) else {
            continue;
        };
        regressor_into(&s.tau[k], &s.dq[k], &basis.tau0_sq, &mut phi);
        let y = w - basis.baseline_w;
        if !(y.is_finite() && phi.iter().all(|v| v.is_finite())) {
            continue;
        }
        let kept = produced.is_multiple_of(every);
        produced += 1;
        if !kept {
            continue;
        }
        out.push(Row {
            trial,
            t: s.t[k],
            t0: s.t[k],
            t1: s.t[k],
            phi,
            y,
            sigma_omega: basis.sigma_omega,
            tau0_sq: basis.tau0_sq,
        });
    }
}

/// The sample rows of one trial thinned to every `every`-th (the same rows as
/// `build(…, Mode::Sample).rows.iter().step_by(every)`, without building the others).
pub(crate) fn sample_rows_thinned(
    rec: &Recording,
    trial: &TrialWindow,
    opts: &DatasetOptions,
    every: usize,
) -> Vec<Row> {
    let mut rows = Vec::new();
    if let Ok(basis) = trial_basis(rec, trial, opts.target, &opts.alignment, None) {
        sample_rows(
            rec,
            opts.target.series(rec),
            &basis,
            trial.index,
            every,
            &mut rows,
        );
    }
    rows
}

/// The (rows, R²) of each candidate timing's per-reading rows (those [`build`] makes), every
/// candidate in one pass over the trials ([`SearchFits`]: a trial's per-sample regressors are
/// computed once, shared by all candidates). The same figures up to rounding.
fn search_scores(
    sessions: &[(&Recording, &[TrialWindow])],
    target: Target,
    cands: &[Alignment],
    caches: &mut [StateBasis],
) -> Vec<Option<(usize, f64)>> {
    let mut fits = SearchFits::new(cands.len());
    let mut rows = Vec::new();
    for ((rec, trials), cache) in sessions.iter().zip(caches) {
        let (power, times, s) = (target.series(rec), state_times(rec), &rec.state);
        for trial in trials.iter() {
            let (a, b) = trial.analysis_window();
            let mut tau0_sq = None;
            rows.clear();
            for (cand, align) in cands.iter().enumerate() {
                let Ok(basis) = trial_basis(rec, trial, target, align, Some(cache)) else {
                    continue;
                };
                tau0_sq = Some(basis.tau0_sq);
                rows.extend(readings_within(power, align, a, b).map(|(t, w)| {
                    let (t0, t1) = align.window_of(t);
                    let (samples, y) = (samples_in(times, t0, t1), w - basis.baseline_w);
                    SearchRow { cand, samples, y }
                }));
            }
            let Some(tau0_sq) = tau0_sq else { continue };
            fits.add_trial(&rows, |k| {
                let mut phi = [0.0; N_PARAMS];
                regressor_into(&s.tau[k], &s.dq[k], &tau0_sq, &mut phi);
                Some(phi)
            });
        }
    }
    fits.scores()
}

/// Estimate the sensor's averaging window W and lag from the data: the per-reading rows are
/// built for each candidate (W, lag) and fitted by (lightly ridge-regularised) least squares; the
/// candidate with the highest R² wins ([`scan_alignment`] on the identification's
/// grid: W 0.05–1.0 s, lag −0.3–0.5 s, then a 0.025 s grid around the best).
pub fn estimate_alignment(
    sessions: &[(&Recording, &[TrialWindow])],
    target: Target,
) -> Result<AlignmentEstimate> {
    // Each trial's pre-idle τ̄0² and σ_ω do not depend on the alignment: computed once.
    let mut caches: Vec<StateBasis> = sessions.iter().map(|_| StateBasis::new()).collect();
    let est = scan_alignment(&ScanGrid::IDENTIFY, |cands| {
        search_scores(sessions, target, cands, &mut caches)
    });
    let Some(est) = est else {
        let nominal = DatasetOptions {
            mode: Mode::Reading,
            target,
            alignment: Alignment::NOMINAL,
        };
        let readings: usize = sessions
            .iter()
            .map(|(rec, trials)| build(rec, trials, &nominal).rows.len())
            .sum();
        let trials: usize = sessions.iter().map(|(_, t)| t.len()).sum();
        bail!(
            "only {readings} {} power readings inside the {trials} trajectory windows; estimating \
             the sensor window and lag needs more than {N_PARAMS} (one per model parameter): record \
             more trials, or give the timing (--window SECONDS --lag SECONDS; the G1's sensor \
             averages about {} s with no lag)",
            target.name().to_uppercase(),
            Alignment::NOMINAL.window_s
        )
    };
    Ok(est)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::signals::StateSeries;

    /// `n` joint-state samples at 100 Hz: τ_j = `tau` + w(k, j), q̇_j = w(k, j + 2) where
    /// `moving(k)` (else 0), w(k, j) = sin(k (j + 1) `f`); τ not finite at (sample, joint) `nan`.
    fn waves(
        n: usize,
        f: f64,
        tau: f64,
        moving: fn(usize) -> bool,
        nan: (usize, usize),
    ) -> StateSeries {
        let w = |k: usize, j: usize| ((k * (j + 1)) as f64 * f).sin();
        let mut s = StateSeries {
            t: (0..n).map(|k| k as f64 * 0.01).collect(),
            tau: (0..n)
                .map(|k| std::array::from_fn(|j| tau + w(k, j)))
                .collect(),
            dq: (0..n)
                .map(|k| std::array::from_fn(|j| if moving(k) { w(k, j + 2) } else { 0.0 }))
                .collect(),
            ..StateSeries::default()
        };
        s.tau[nan.0][nan.1] = f64::NAN;
        s
    }

    /// Thinned sample rows are every n-th of the rows `build` makes, including when a
    /// non-finite sample is dropped in between (the count is over rows produced, not samples).
    #[test]
    fn thinned_sample_rows_are_every_nth_built_row() {
        let state = waves(1200, 0.013, 2.0, |k| k > 300, (700, 3));
        let t = state.t.clone();
        let mbs = PowerSeries {
            t: (0..12).map(|k| k as f64 + 0.5).collect(),
            watts: (0..12).map(|k| 20.0 + k as f64).collect(),
        };
        let rec = Recording {
            state,
            mbs,
            ..Recording::default()
        };
        let trial = TrialWindow::for_test(4, [0.0, 3.0, 9.0, 11.0, 11.9]);
        let opts = DatasetOptions {
            mode: Mode::Sample,
            target: Target::Mbs,
            alignment: Alignment::NOMINAL,
        };
        let all = build(&rec, std::slice::from_ref(&trial), &opts).rows;
        assert!(all.len() > 700 && all.len() < 800, "{}", all.len());
        assert!(
            all.iter().all(|r| r.t != t[700]),
            "the NaN sample gives no row"
        );
        for every in [1, 3, 7] {
            let thin = sample_rows_thinned(&rec, &trial, &opts, every);
            let expected: Vec<Row> = all.iter().step_by(every).cloned().collect();
            assert_eq!(thin, expected, "every {every}");
        }
    }

    /// The timing search's scores (running sums shared by every candidate, one pass) equal a
    /// ridge fit of the rows [`build`] makes at each candidate, one candidate at a time — also
    /// with a non-finite sample inside some windows and a trial without a pre-idle reading.
    #[test]
    fn search_scores_equal_the_fit_of_the_built_rows() {
        let state = waves(9000, 0.0071, 1.5, |k| k % 3000 > 500, (4321, 2));
        let (tau, dq) = (&state.tau, &state.dq);
        let (pt, watts): (Vec<f64>, Vec<f64>) = (0..360)
            .map(|k| {
                let s = k as f64 * 0.25 + 0.01;
                let i = ((s - 0.1) * 100.0) as usize;
                let p: f64 = (0..N_JOINTS)
                    .map(|j| tau[i][j] * dq[i][j] + dq[i][j].abs())
                    .sum();
                (s, 30.0 + p + 0.1 * (k as f64 * 1.7).sin())
            })
            .unzip();
        let rec = Recording {
            state,
            mbs: PowerSeries { t: pt, watts },
            ..Recording::default()
        };
        let trial = |index: usize, s: f64, pre: f64| {
            TrialWindow::for_test(index, [s, s + pre, s + 25.0, s + 29.0, s + 29.9])
        };
        // Trial 2's pre-idle ends before its first reading window can fit: no baseline.
        let trials = [
            trial(0, 0.0, 5.0),
            trial(1, 30.0, 5.0),
            trial(2, 60.0, 0.05),
        ];
        let cands: Vec<Alignment> = [(0.2, 0.0), (0.5, 0.1), (0.05, -0.2), (1.0, 0.3), (0.3, 0.5)]
            .iter()
            .map(|&(window_s, lag_s)| Alignment { window_s, lag_s })
            .collect();
        let mut caches = vec![StateBasis::new()];
        let got = search_scores(&[(&rec, &trials[..])], Target::Mbs, &cands, &mut caches);
        for (alignment, got) in cands.iter().zip(got) {
            let opts = DatasetOptions {
                mode: Mode::Reading,
                target: Target::Mbs,
                alignment: *alignment,
            };
            let d = build(&rec, &trials, &opts);
            assert_eq!(d.skipped.first().map(|s| s.trial), Some(2), "{alignment:?}");
            let y: Vec<f64> = d.rows.iter().map(|r| r.y).collect();
            let mut gram = crate::lsq::Gram::zeros(N_PARAMS);
            d.rows.iter().for_each(|r| gram.add_row(&r.phi, r.y));
            let r2 = crate::timing::ridge_r2_of(&gram, &y).expect("enough rows");
            let (rows, got_r2) = got.expect("scored");
            assert_eq!(rows, d.rows.len(), "{alignment:?}");
            assert!(
                (got_r2 - r2).abs() < 1e-9,
                "{alignment:?}: {got_r2} vs {r2}"
            );
        }
        assert_eq!(
            caches[0].len(),
            2,
            "the trial without a baseline is not cached"
        );
    }
}
