//! The power sensor's averaging window W: given, or estimated from the data (the default).
//!
//! Why the estimate is built this way. A reading averages power over [t − lag − W, t − lag];
//! a window mean is the signal at the window's centre plus a W²/24 · curvature term, so the
//! alignment scan's R² surface has a sharp ridge along a constant centre c = lag + W/2 and is
//! nearly flat along it. The centre is well determined, W along the ridge is not: on 72 nominal
//! trials the 2-D optimum wandered to W = 0.15 s, lag 0.025 s (the same centre as 0.2 s, lag 0),
//! and the latency hypothesis, handed the too-short window, then "found" the 0.024 s that
//! re-centres it.
//!
//! So the window is judged as an engineer judges a datasheet value: the scan finds the best
//! (W, lag ≥ 0) and its centre c; the sensor's nominal 0.2 s window, at the lag that puts its
//! centre at c (± 2 fine steps, lag ≥ 0), is kept unless freeing W (one more parameter) beats it
//! by the diagnosis' own BIC threshold (ΔBIC = n·ln(SSE_free/SSE_nominal) + ln n <
//! [`DiagnoseOptions::bic_threshold`]); a sensor that averages 0.5 s smooths visibly more and
//! rejects it.
//!
//! A lag is a latency claim only where the data demand one: a lagged point — the nominal window's
//! lag (beyond one fine step: it is derived from the centre), or the scan's own lagged point
//! (with one more ln n) — must beat **every** window the scan scored at lag 0 (and the lag-0
//! windows of the same centre, 2c ± 2 steps) by that rule ([`SensorWindow::lag_demanded`]), and
//! predict held-out trials better than the best of them ([`held_out_contest`]: a ridge is flat,
//! and an in-sample preference along it on a few dozen trials is noise as often as a latency).
//! Otherwise the best lag-0 window is the estimate (or the nominal window, where it needs no
//! lag) and the latency hypothesis is scored but cannot be claimed: a lag that only re-centres a
//! window of the wrong length is not a latency (the physics-fuzz campaign's 0.3 s sensors were
//! read as 0.2 s + 0.05 s, or 0.225 s + 0.04 s, and "found" the lag). Where a lag is demanded it
//! is the latency hypothesis' to judge (a real 0.3 s latency behind a 0.2 s window keeps the
//! nominal window at lag ≈ 0.3 s).
//!
//! Every candidate is fitted with the base regressors AND a fixed set of library mechanisms, one
//! pooled column each, net of its trial's pre-idle level: a mechanism the base model lacks
//! leaves a remainder that a shifted or resized window fits in part, so the scan would judge the
//! sensor's timing by the model's misfit (a 0.3 s window beside a DC-bus loss read as 0.2 s + a
//! 0.05 s latency, fuzz seed 1213589933). The set is fixed so that features the library or
//! discovery gain do not move the window ([`SCAN_MECHANISMS`]).
//!
//! A window can drift over the session (a meter whose averaging lengthens as it warms): with the
//! window judged, windows changing linearly from the first scanned trial to the last (±0.05 …
//! ±0.6 s, at the judged window ± 2 fine steps half-way) are scored on the same readings; a
//! drift is kept where it beats the best constant window by the BIC rule (one more parameter).
//! Every later stage then reads each trial at its own window (`TrialMeta::width_s`). The other
//! meter of the rail decides whose it is: scored with the same drift against a constant window,
//! if it rejects the drift (ΔBIC > −threshold) the drift is the diagnosed meter's artefact
//! (claimed, "Meter artefact: …"); otherwise it is located (a drifting clock of the arm would
//! show on both meters).
//!
//! Candidates are compared on one set of readings (stamps at least the largest scanned window
//! after the trajectory start) with one target (net of the pre-idle baseline at the nominal
//! window), over the IMU-kept trials without those the diagnosis' residual passes reject: one
//! contaminated trial with a mean residual of several watts outweighs the rest of the scan's
//! squared error and puts the window wherever that trial fits best.

use anyhow::{Context, Result};

use crate::signals::{PowerSeries, Recording};
use crate::timing::{
    Alignment, AlignmentEstimate, ScanGrid, Scores, SearchFits, SearchRow, scan_alignment,
};
use crate::trial::{Cascade, TrialStat, TrialWindow, is_rejected, samples_in};

use super::hypotheses::{Hypothesis, N_RAW, POWER_HYPOTHESES};
use super::lags::{TrialRows, filter_trials};
use super::reading_rows::{Rows, TrialFeatures, TrialMeta, build_rows, span};
use super::select::{FOLD_SEED, Folds, RIVAL_ALPHA};
use super::stats::improvement_p_value;
use super::trials::{SessionInfo, copy_span};
use super::{DiagnoseOptions, SensorWindow};
use crate::N_PARAMS;
use crate::lsq::Gram;
use crate::session::TrialSource;

/// Largest number of trials the sensor-window scan uses (evenly spread over the session): the
/// window is a property of the sensor, and 150 trials fix it well while the scan's cost stays
/// bounded at paper scale.
const WINDOW_SCAN_TRIALS: usize = 150;

/// Coarse windows of the scan [s].
const WINDOWS: [f64; 7] = [0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0];

/// Coarse lags of the scan [s] (a reading cannot average power after its stamp: lag ≥ 0).
const LAGS: [f64; 7] = [0.0, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0];

/// Fine step of the scan [s].
const STEP: f64 = 0.025;

/// Readings compared by every candidate start this long after the trajectory start [s] (the
/// largest window the fine grid can reach).
const FIXED_SET_S: f64 = 1.0 + 4.0 * STEP;

/// The sensor window: given, or estimated (see the module docs) on the diagnosis' own rows of at
/// most [`WINDOW_SCAN_TRIALS`] IMU-kept trials (of `all`: every trial's quantities), whose
/// joint states are held for the scan (read once more from `samples`).
pub(crate) fn sensor_window(
    info: &SessionInfo,
    samples: &mut dyn TrialSource,
    all: &[TrialMeta],
    opts: &DiagnoseOptions,
) -> Result<SensorWindow> {
    if let Some(w) = opts.sensor_window_s {
        return Ok(SensorWindow {
            window_s: w,
            lag_demanded: true,
            ..SensorWindow::default()
        });
    }
    let metas = scan_trials(all, opts);
    let windows: Vec<TrialWindow> = metas.iter().map(|m| m.window.clone()).collect();
    let held = crate::session::hold_pass(samples, Recording::default(), &windows, copy_span)?;
    let rec = &held;
    let power = &info.power;
    let nominal = Alignment::NOMINAL;
    let all_rows = build_rows(rec, power, &metas, 0.0, nominal.window_s);
    let metas = without_outliers(metas, all_rows, opts)?;
    let reference = build_rows(rec, power, &metas, 0.0, nominal.window_s);
    let mut drifting = |cands: &[(Alignment, f64)]| {
        fixed_set_fits(rec, power, &metas, &reference, cands, |_| {}).scores()
    };
    let mut score = |cands: &[Alignment]| drifting(&still(cands));
    let grid = ScanGrid {
        windows: &WINDOWS,
        lags: &LAGS,
        step: STEP,
        min_lag: 0.0,
    };
    let est = scan_alignment(&grid, &mut score).with_context(|| {
        format!(
            "{}: estimating the power sensor's window: fewer than {} {} readings inside the {} \
             scanned trials; give the window (--sensor-window SECONDS)",
            info.source.display(),
            crate::N_PARAMS + 1,
            opts.target.name().to_uppercase(),
            metas.len()
        )
    })?;
    let folds = Folds::new(metas.len(), opts.folds, FOLD_SEED);
    let mut contest = |first: (Alignment, f64), rival: (Alignment, f64)| {
        let mut per_trial = Vec::with_capacity(metas.len());
        fixed_set_fits(rec, power, &metas, &reference, &[first, rival], |f| {
            per_trial.push(f.take())
        });
        held_out_contest(&per_trial, &folds)
    };
    let (judged, lag_s) = judge(
        &est,
        &mut score,
        &mut |lagged, rival| contest((lagged, 0.0), (rival, 0.0)),
        opts.bic_threshold,
    );
    let other = build_rows(rec, &info.other, &metas, 0.0, nominal.window_s);
    let mut on_other = |cands: &[(Alignment, f64)]| {
        fixed_set_fits(rec, &info.other, &metas, &other, cands, |_| {}).scores()
    };
    let (t0, t1) = drift_span(&metas);
    Ok(SensorWindow {
        scan_trials: metas.len(),
        drift_from_s: t0,
        drift_to_s: t1,
        ..drift(
            (judged, lag_s),
            (&mut drifting, &mut contest),
            &mut on_other,
            opts.bic_threshold,
        )
    })
}

impl SensorWindow {
    /// The window [s] of a trial starting at session time `t`: the drift's line (held beyond its
    /// ends) inside [[`STEP`], [`FIXED_SET_S`]], the windows the scan can score. The one place a
    /// trial's window is computed: the scan scores a drift at the windows every later stage
    /// reads.
    pub fn window_at(&self, t: f64) -> f64 {
        let span = self.drift_to_s - self.drift_from_s;
        if self.drift_s == 0.0 || span <= 0.0 {
            return self.window_s;
        }
        let u = ((t - self.drift_from_s) / span).clamp(0.0, 1.0) - 0.5;
        (self.window_s + self.drift_s * u).clamp(STEP, FIXED_SET_S)
    }
}

/// `metas` with each trial's window where the window drifts (one truth across stages: every
/// later stage builds the trial's rows and baseline at it).
pub(crate) fn with_widths(mut metas: Vec<TrialMeta>, sw: &SensorWindow) -> Vec<TrialMeta> {
    if sw.drift_s != 0.0 {
        for m in &mut metas {
            m.width_s = Some(sw.window_at(m.window.t_traj_start));
        }
    }
    metas
}

/// Alignments without a drift.
fn still(cands: &[Alignment]) -> Vec<(Alignment, f64)> {
    cands.iter().map(|&a| (a, 0.0)).collect()
}

/// Session times of the first and last trajectory start of `metas`: the span a window drift is
/// fitted over (linear between, held beyond).
fn drift_span(metas: &[TrialMeta]) -> (f64, f64) {
    let t = |m: Option<&TrialMeta>| m.map_or(0.0, |m| m.window.t_traj_start);
    (t(metas.first()), t(metas.last()))
}

/// ΔBIC of a fit with R² `r2` against one with `r2_0` on the same `n` readings and targets (the
/// SSE ratio is the R² complements'), with `extra` more parameters.
fn delta_bic(n: usize, r2: f64, r2_0: f64, extra: f64) -> f64 {
    let n = n as f64;
    n * ((1.0 - r2).max(1e-300) / (1.0 - r2_0).max(1e-300)).ln() + extra * n.ln()
}

/// The best-scored of `cands` (with its readings and R²) among those `keep` keeps.
fn best_of<T: Copy>(
    cands: &[T],
    scores: &[Option<(usize, f64)>],
    keep: impl Fn(&T) -> bool,
) -> Option<(T, usize, f64)> {
    (cands.iter().zip(scores))
        .filter(|(c, _)| keep(c))
        .filter_map(|(c, s)| s.map(|(n, r2)| (*c, n, r2)))
        .max_by(|a, b| a.2.total_cmp(&b.2))
}

/// Scores of alignments, each with a window change over the session (a drift, [s]).
type Drifting<'a> = dyn FnMut(&[(Alignment, f64)]) -> Scores + 'a;

/// p-value that the first of two alignments (each with its drift) predicts held-out trials
/// better than the second ([`held_out_contest`]).
type Contest<'a> = dyn FnMut((Alignment, f64), (Alignment, f64)) -> f64 + 'a;

/// Window changes over the session the drift scan tries [s] (both signs).
const DRIFTS: [f64; 7] = [0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.6];

/// A window that drifts over the session (module docs): `sw` with its drift where one beats the
/// best constant window near `sw`'s (at `lag_s`, the lag judged with it) by the BIC rule on the
/// diagnosed meter (`score`) and predicts held-out trials better (`contest`, p < RIVAL_ALPHA, as
/// a lag must), and whether the other meter (`other`) rejects that drift (an artefact of the
/// diagnosed meter).
fn drift(
    (sw, lag_s): (SensorWindow, f64),
    (score, contest): (&mut Drifting<'_>, &mut Contest<'_>),
    other: &mut Drifting<'_>,
    bic_threshold: f64,
) -> SensorWindow {
    let at = |window_s: f64, d: f64| {
        (
            Alignment {
                window_s: window_s.max(STEP),
                lag_s,
            },
            d,
        )
    };
    let grid = |w: f64, ds: &[f64], k: i32| -> Vec<(Alignment, f64)> {
        let ws = (-k..=k).map(|i| w + i as f64 * STEP);
        ws.flat_map(|w| ds.iter().map(move |&d| at(w, d))).collect()
    };
    let best = |cands: &[(Alignment, f64)], scores: &Scores, moving: bool| {
        best_of(cands, scores, |c| (c.1 != 0.0) == moving)
    };
    let mut ds: Vec<f64> = DRIFTS.iter().flat_map(|&d| [d, -d]).collect();
    ds.push(0.0);
    let cands = grid(sw.window_s, &ds, 2);
    let scores = score(&cands);
    let (Some(still), Some(coarse)) = (best(&cands, &scores, false), best(&cands, &scores, true))
    else {
        return sw;
    };
    // Finer around the best drift.
    let d = coarse.0.1;
    let fine = grid(coarse.0.0.window_s, &[d - 0.025, d, d + 0.025], 1);
    let fine: Vec<_> = fine.into_iter().filter(|c| c.1 != 0.0).collect();
    let moving = best(&fine, &score(&fine), true)
        .map_or(coarse, |f| if f.2 > coarse.2 { f } else { coarse });
    let delta_bic = delta_bic(moving.1, moving.2, still.2, 1.0);
    // In sample, the BIC rule; held out, the drift must predict better than the steady window
    // (a null session's 0.3 s window read as drifting to 0.2 s by ΔBIC −24.1, claimed as the
    // main-board meter's artefact: fuzz seed 1884212899).
    if delta_bic >= bic_threshold || contest(moving.0, still.0) >= RIVAL_ALPHA {
        return SensorWindow {
            drift_delta_bic: delta_bic,
            ..sw
        };
    }
    // The other meter: the same drift against a constant window, each at its best window near
    // the diagnosed meter's.
    let (w, d) = (moving.0.0.window_s, moving.0.1);
    let cands = grid(w, &[0.0, d], 4);
    let scores = other(&cands);
    let other_delta_bic = match (best(&cands, &scores, true), best(&cands, &scores, false)) {
        (Some(m), Some(s)) => self::delta_bic(m.1, m.2, s.2, 0.0),
        _ => 0.0,
    };
    SensorWindow {
        window_s: w,
        drift_s: d,
        drift_delta_bic: delta_bic,
        drift_other_delta_bic: other_delta_bic,
        drift_artefact: other_delta_bic > -bic_threshold,
        ..sw
    }
}

/// The window and whether a lag is demanded, judged from the scan `est` (`score`: alignments'
/// (readings, R²) on the fixed reading set; `contest`: [`held_out_contest`] of a lagged point
/// against a lag-0 window), as the module docs say; and the lag that goes with
/// that window (the nominal window's own lag where it is kept: the scan's belongs to the scan's
/// window, and a 0.2 s window read at a 0.4 s window's lag is 0.1 s off-centre — a drift then
/// "fixed" it, fuzz seed 1189668034).
fn judge(
    est: &AlignmentEstimate,
    score: &mut dyn FnMut(&[Alignment]) -> Scores,
    contest: &mut dyn FnMut(Alignment, Alignment) -> f64,
    bic_threshold: f64,
) -> (SensorWindow, f64) {
    let best = est.best;
    let centre = best.lag_s + 0.5 * best.window_s;
    let nominal_w = Alignment::NOMINAL.window_s;
    let near = |w: f64, lag: f64| {
        (-2..=2)
            .map(|k| Alignment {
                window_s: w,
                lag_s: lag + k as f64 * STEP,
            })
            .filter(|a| a.lag_s >= 0.0)
            .collect::<Vec<_>>()
    };
    // 1. The sensor's nominal window at the lag that puts its centre where the data put it;
    // 2. the best window at lag 0: every lag-0 window the scan scored, and those of the data's
    //    centre (2c ± 2 steps) the scan can score (≤ [`FIXED_SET_S`]: a 0.58 s latency's centre
    //    made a 1.4 s lag-0 window "as good", and no reading was left inside it; fuzz seed
    //    874010922). Both sets scored together.
    let mut cands = near(nominal_w, (centre - 0.5 * nominal_w).max(0.0));
    let n_near = cands.len();
    cands.extend(
        (-2..=2)
            .map(|k| Alignment {
                window_s: 2.0 * centre + k as f64 * STEP,
                lag_s: 0.0,
            })
            .filter(|a| a.window_s > 0.0 && a.window_s <= FIXED_SET_S + 1e-9),
    );
    let scores = score(&cands);
    let (near_scores, lag0_scores) = scores.split_at(n_near);
    let nominal = best_of(&cands[..n_near], near_scores, |_| true);
    let window_delta_bic = nominal.map_or(0.0, |(_, n, r2)| delta_bic(n, est.r2, r2, 1.0));
    let lag0 = best_of(&cands[n_near..], lag0_scores, |_| true)
        .into_iter()
        .chain(
            est.grid
                .iter()
                .filter(|g| g.alignment.lag_s.abs() < 1e-9)
                .map(|g| (g.alignment, g.rows, g.r2)),
        );
    let lag0 = lag0.max_by(|a, b| a.2.total_cmp(&b.2));
    // 3. A lag is demanded only where a lagged point beats every window at lag 0 by the BIC
    //    rule: the nominal window's lag (one free parameter, as the lag-0 window's W), or the
    //    scan's own lagged point (one more). The nominal window's lag is derived from the centre,
    //    so one within one fine step is within the scan's resolution and demands nothing (the
    //    scan's own lagged point carries the extra ln n instead). Otherwise no latency can be claimed: a lag that only
    //    re-centres a window of the wrong length is not a latency (the campaign's spurious
    //    latencies were a 0.3 s window read as 0.2 s or 0.225 s + lag).
    let beats =
        |lagged: Option<(Alignment, usize, f64)>, extra: f64, min_lag: f64| match (lagged, lag0) {
            (Some((a, n, r2)), Some((_, _, r2_0))) if a.lag_s > min_lag + 1e-9 => {
                delta_bic(n, r2, r2_0, extra) < bic_threshold
            }
            (Some((a, _, _)), None) => a.lag_s > min_lag + 1e-9,
            _ => false,
        };
    let lag_delta_bic = match lag0 {
        Some((_, n, r2)) if best.lag_s > 0.0 => delta_bic(n, est.r2, r2, 1.0),
        _ => 0.0,
    };
    let scanned = est
        .grid
        .iter()
        .find(|g| g.alignment == best)
        .map(|g| (g.alignment, g.rows, g.r2));
    let nominal_kept = nominal.is_some() && window_delta_bic >= bic_threshold;
    // 4. ... and predicts held-out trials better than the best lag-0 window (p < RIVAL_ALPHA):
    //    along the ridge of one centre the in-sample ΔBIC of 42 trials read a 0.3 s window as
    //    0.2 s + 0.05 s by 13.5 (fuzz seed 958623570, held out p = 0.25; 113 trials of the same
    //    physics put 0.3 s ahead by 360).
    let lagged = match nominal {
        Some((a, _, _)) if nominal_kept => a,
        _ => best,
    };
    let in_sample = beats(nominal, 0.0, STEP) || beats(scanned, 1.0, 0.0);
    // Where the scan's best point is lagged but the in-sample rule does not demand the lag, the
    // contest is run on that point all the same: the timing is then located, with both tests'
    // figures (a true 0.033 s latency at 15 min fell 0.8 short of the BIC rule and was neither
    // named nor located, fuzz seed 1058246107).
    let contested = match in_sample {
        true => Some(lagged),
        false => (best.lag_s > 0.0).then_some(best),
    };
    let lag_held_out = contested
        .zip(lag0)
        .map(|(lagged, (rival, _, _))| contest(lagged, rival));
    let lag_demanded = in_sample && lag_held_out.is_none_or(|p| p < RIVAL_ALPHA);
    let (window_s, lag_s) = match (lag_demanded, nominal) {
        (true, Some((a, _, _))) if nominal_kept => (nominal_w, a.lag_s),
        (true, _) => (best.window_s, best.lag_s),
        // No lag: the nominal window stands where it needs none (its lag within one step).
        (false, Some((a, _, _))) if nominal_kept && a.lag_s <= STEP + 1e-9 => (nominal_w, 0.0),
        (false, _) => (lag0.map_or(best.window_s, |(a, _, _)| a.window_s), 0.0),
    };
    let sw = SensorWindow {
        window_s,
        estimated: true,
        scan_window_s: best.window_s,
        scan_lag_s: best.lag_s,
        scan_r2: est.r2,
        window_delta_bic,
        lag_delta_bic,
        lag_demanded,
        lag_held_out,
        ..SensorWindow::default()
    };
    (sw, lag_s)
}

/// At most [`WINDOW_SCAN_TRIALS`] trials evenly spread over the session, without those the IMU
/// filter rejects (a swaying trial's balance power is noise to the window's fit).
fn scan_trials(metas: &[TrialMeta], opts: &DiagnoseOptions) -> Vec<TrialMeta> {
    let sigmas: Vec<TrialStat> = metas
        .iter()
        .map(|m| TrialStat::new(0, m.window.index, m.sigma_omega))
        .collect();
    let imu = Cascade {
        imu_k: Some(opts.imu_threshold),
        ..Cascade::default()
    };
    let rejected = imu.imu(&sigmas);
    let kept: Vec<TrialMeta> = metas
        .iter()
        .filter(|m| !is_rejected(&rejected, 0, m.window.index))
        .cloned()
        .collect();
    let step = kept.len().div_ceil(WINDOW_SCAN_TRIALS).max(1);
    kept.into_iter().step_by(step).collect()
}

/// `metas` without the trials the diagnosis' residual passes reject ([`filter_trials`] without
/// its IMU filter, on `rows`: theirs at the nominal window): one contaminated trial's residual of
/// several watts outweighs the rest of the scan's squared error and puts the window wherever that
/// trial fits best (a 0.3 s sensor was read as 0.225 s + a 0.05 s lag).
fn without_outliers(
    metas: Vec<TrialMeta>,
    rows: Rows,
    opts: &DiagnoseOptions,
) -> Result<Vec<TrialMeta>> {
    let rows = TrialRows::new(rows, metas.len());
    Ok(filter_trials(&metas, Vec::new(), &rows, opts, false)?.0)
}

/// The library mechanisms the window is judged beside, each one pooled column (its raw features
/// summed over the joints): a fixed set, so the window does not move when the library or
/// discovery gain features (14 new per-joint features moved one session's window 0.3 → 0.325 s
/// and lost a location, fuzz seed 8374588).
const SCAN_MECHANISMS: [&str; 8] = [
    "thermal",
    "braking",
    "bus_loss",
    "gear_friction",
    "drive_loss",
    "stribeck",
    "balance_leak",
    "bus_power",
];

/// Columns of the window scan: the base regressors, then one per [`SCAN_MECHANISMS`].
const N_SCAN: usize = N_PARAMS + SCAN_MECHANISMS.len();

/// Where each of [`SCAN_MECHANISMS`]' raw features lie in a raw row (empty if not in the library).
fn scan_ranges() -> Vec<std::ops::Range<usize>> {
    let at = |id| POWER_HYPOTHESES.iter().find(|h| h.id == id);
    let range = |h: &Hypothesis| N_PARAMS + h.raw.0..N_PARAMS + h.raw.0 + h.raw.1;
    SCAN_MECHANISMS
        .map(|id| at(id).map_or(0..0, range))
        .to_vec()
}

/// A raw row's columns of the window scan (`ranges`: [`scan_ranges`]).
fn scan_row(x: &[f64; N_RAW], ranges: &[std::ops::Range<usize>]) -> [f64; N_SCAN] {
    let mut out = [0.0; N_SCAN];
    out[..N_PARAMS].copy_from_slice(&x[..N_PARAMS]);
    for (o, r) in out[N_PARAMS..].iter_mut().zip(ranges) {
        *o = x[r.clone()].iter().sum();
    }
    out
}

/// The normal equations of each candidate's rows on the base regressors and
/// the pooled library mechanisms ([`SCAN_MECHANISMS`]; one truth across stages: a mechanism
/// missing from the base model cannot move the window or demand a lag — a 0.3 s sensor beside a
/// DC-bus loss was read as 0.2 s + a 0.05 s latency, fuzz seed 1213589933), restricted
/// to the fixed reading set (stamps ≥ trajectory start + [`FIXED_SET_S`] among the `reference`
/// rows) with the reference rows' targets, in one pass over the trials ([`SearchFits`]). A
/// candidate's rows are the readings [`build_rows`] gives it: a trial without its baseline
/// readings gives none, a window is cut at the trial's [`span`] and needs its samples' data.
/// `each_trial` sees the fits after every trial (to take that trial's own).
fn fixed_set_fits(
    rec: &Recording,
    power: &PowerSeries,
    metas: &[TrialMeta],
    reference: &Rows,
    cands: &[(Alignment, f64)],
    mut each_trial: impl FnMut(&mut SearchFits<N_SCAN>),
) -> SearchFits<N_SCAN> {
    let mut fits = SearchFits::<N_SCAN>::new(cands.len());
    let ranges = scan_ranges();
    let (mut rows, mut first) = (Vec::new(), 0);
    let (drift_from_s, drift_to_s) = drift_span(metas);
    let line = SensorWindow {
        drift_from_s,
        drift_to_s,
        ..SensorWindow::default()
    };
    for (ti, meta) in metas.iter().enumerate() {
        let w = &meta.window;
        let end = first + reference.trial[first..].partition_point(|&t| t == ti);
        rows.clear();
        for (cand, &(a, drift_s)) in cands.iter().enumerate() {
            let (window_s, line) = (a.window_s, line);
            let window_s = SensorWindow {
                window_s,
                drift_s,
                ..line
            }
            .window_at(w.t_traj_start);
            let a = Alignment { window_s, ..a };
            let mut base = w.baseline_readings(&power.t, a.lag_s, a.window_s);
            if !base.any(|k| power.watts.get(k).is_some_and(|v| v.is_finite())) {
                continue;
            }
            let from = w.t_traj_start + FIXED_SET_S.max(a.window_s);
            for k in (first..end).filter(|&k| reference.t[k] >= from) {
                let b = reference.t[k] - a.lag_s;
                let samples = samples_in(&rec.state.t, (b - a.window_s).max(span(w).0), b);
                let y = reference.y[k];
                rows.push(SearchRow { cand, samples, y });
            }
        }
        let feats = TrialFeatures::new(rec, meta);
        fits.add_trial(&rows, |k| feats.raw(k, meta).map(|x| scan_row(&x, &ranges)));
        each_trial(&mut fits);
        first = end;
    }
    fits
}

/// p-value that the first of two candidates predicts held-out trials better than the second,
/// from each trial's normal equations of both (`per_trial[t]`): each trial's squared error under
/// the fit without its fold, the paired test of two alternatives ([`improvement_p_value`]). A
/// gate, not a claim: the latency a lag lets through faces the claims' own tests (stability
/// included) — asking stability here too lost a true 0.019 s latency (fuzz seed 478772213:
/// p = 0.038, held in 59 % of resamples).
fn held_out_contest(per_trial: &[Vec<Gram>], folds: &Folds) -> f64 {
    let sse = |c: usize| {
        let (mut fold, mut total) = (vec![Gram::zeros(N_SCAN); folds.k], Gram::zeros(N_SCAN));
        for (t, g) in per_trial.iter().enumerate() {
            fold[folds.of_trial[t]].add(&g[c]);
            total.add(&g[c]);
        }
        let theta: Vec<_> = fold.iter().map(|g| total.minus(g).solve(1e-9)).collect();
        (per_trial.iter().enumerate())
            .map(|(t, g)| {
                theta[folds.of_trial[t]]
                    .as_ref()
                    .map_or(0.0, |th| g[c].sse(th))
            })
            .collect::<Vec<f64>>()
    };
    let (lagged, rival) = (sse(0), sse(1));
    let d: Vec<f64> = rival.iter().zip(&lagged).map(|(r, l)| r - l).collect();
    improvement_p_value(&d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::reading_rows::trial_meta;
    use crate::diagnose::testkit::{Effects, session};
    use crate::signals::{PowerSeries, Recording};

    /// The one-pass scores (running sums shared by every candidate) equal a fit of the rows
    /// [`build_rows`] gives each candidate on its own, restricted to the fixed reading set —
    /// on a session whose trial 3 lost a reading's worth of joint states (no row there).
    #[test]
    fn fixed_set_fits_score_as_the_fit_of_each_candidates_built_rows() {
        let (mut rec, windows) = session(30, 7, Effects::default());
        let k = rec
            .state
            .t
            .partition_point(|&t| t < windows[3].t_traj_start + 5.0);
        rec.state.tau[k][2] = f64::NAN;
        let bus = super::super::bus_model(&DiagnoseOptions::default());
        let (metas, _) = trial_meta(&rec, &windows, bus);
        let reference = build_rows(&rec, &rec.mbs, &metas, 0.0, 0.2);
        let cands: Vec<Alignment> = [(0.2, 0.0), (0.5, 0.1), (0.05, 0.3), (1.0, 1.0), (1.5, 0.0)]
            .map(|(window_s, lag_s)| Alignment { window_s, lag_s })
            .to_vec();
        let got =
            fixed_set_fits(&rec, &rec.mbs, &metas, &reference, &still(&cands), |_| {}).scores();
        for (a, got) in cands.iter().zip(got) {
            let rows = build_rows(&rec, &rec.mbs, &metas, a.lag_s, a.window_s);
            let mut gram = crate::lsq::Gram::zeros(N_SCAN);
            let mut y = Vec::new();
            for r in 0..rows.len() {
                let start = metas[rows.trial[r]].window.t_traj_start;
                let at = reference.t.iter().position(|&t| t == rows.t[r]);
                if let (true, Some(k)) = (rows.t[r] >= start + FIXED_SET_S, at) {
                    gram.add_row(&scan_row(&rows.x[r], &scan_ranges()), reference.y[k]);
                    y.push(reference.y[k]);
                }
            }
            let want = crate::timing::ridge_r2_of(&gram, &y).map(|r2| (y.len(), r2));
            let ((n, r2), (m, w)) = (got.expect("scored"), want.expect("fitted"));
            assert_eq!(n, m, "{a:?}");
            assert!((r2 - w).abs() < 1e-9, "{a:?}: {r2} vs {w}");
        }
    }

    /// The held-out contest prefers the candidate whose regressors the readings were built from
    /// over one that sees them through noise (of the same size as the readings' own), and does
    /// not prefer either of two equally noisy views.
    #[test]
    fn the_held_out_contest_prefers_the_true_regressors_and_ties_equal_views() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut u = || 2.0 * rng.random::<f64>() - 1.0;
        let (trials, per_trial) = (40, 12);
        let beta: Vec<f64> = (0..N_SCAN).map(|_| u()).collect();
        let grams: Vec<Vec<crate::lsq::Gram>> = (0..trials)
            .map(|_| {
                let mut g = vec![crate::lsq::Gram::zeros(N_SCAN); 3];
                for _ in 0..per_trial {
                    let x: Vec<f64> = (0..N_SCAN).map(|_| u()).collect();
                    let y = x.iter().zip(&beta).map(|(a, b)| a * b).sum::<f64>() + 0.3 * u();
                    let blur = |u: &mut dyn FnMut() -> f64| {
                        x.iter().map(|v| v + 0.3 * u()).collect::<Vec<_>>()
                    };
                    let (b1, b2) = (blur(&mut u), blur(&mut u));
                    for (c, row) in [&x, &b1, &b2].into_iter().enumerate() {
                        g[c].add_row(row, y);
                    }
                }
                g
            })
            .collect();
        let folds = Folds::new(trials, 10, FOLD_SEED);
        let pick = |a: usize, b: usize| -> Vec<Vec<crate::lsq::Gram>> {
            grams
                .iter()
                .map(|g| vec![g[a].clone(), g[b].clone()])
                .collect()
        };
        let p = held_out_contest(&pick(0, 1), &folds);
        assert!(p < 1e-6, "true vs blurred: p {p}");
        let p = held_out_contest(&pick(1, 0), &folds);
        assert!(p > 0.5, "blurred vs true: p {p}");
        let p = held_out_contest(&pick(1, 2), &folds);
        assert!(p > RIVAL_ALPHA, "two blurred views: p {p}");
    }

    /// Readings of a rail meter, built here from the stated physics (not by the code under test):
    /// the paper's power model plus 120 W (+ `offset_w`) on the recording's joint states, averaged
    /// over the window `window(t)` ending at each stamp (1 s ± 30 ms apart from `first_s`), plus
    /// uniform noise of ± `noise_w`.
    fn meter(
        rec: &Recording,
        window: impl Fn(f64) -> f64,
        (first_s, offset_w, noise_w): (f64, f64, f64),
        seed: u64,
    ) -> PowerSeries {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let st = &rec.state;
        let p: Vec<f64> = (0..st.t.len())
            .map(|k| {
                120.0 + crate::power::PowerModel::PAPER.predict(&st.tau[k], &st.dq[k], &[0.0; 7])
            })
            .collect();
        let mut out = PowerSeries::default();
        let mut ts = first_s;
        while ts < st.t[st.t.len() - 1] {
            let k = samples_in(&st.t, ts - window(ts), ts);
            if !k.is_empty() {
                let mean = p[k.clone()].iter().sum::<f64>() / k.len() as f64;
                out.t.push(ts);
                out.watts
                    .push(mean + offset_w + noise_w * (2.0 * rng.random::<f64>() - 1.0));
            }
            ts += 1.0 + 0.03 * (2.0 * rng.random::<f64>() - 1.0);
        }
        out
    }

    /// The drift scan on readings whose window drifts (a main-board window 0.15 → 0.45 s over the
    /// session, linear between the first and last trial's start): the drift is recovered within
    /// one coarse drift step (± 0.05 s) with the mid-session window within two fine steps, and it
    /// is the main-board meter's artefact where the battery meter's window holds at 0.3 s; where
    /// both meters drift (the arm's clock) it is not; a session whose window holds gets no drift.
    #[test]
    fn the_drift_scan_recovers_a_drifting_window_and_gives_none_to_a_steady_one() {
        let (mut rec, windows) = session(40, 11, Effects::default());
        let (t0, t1) = (windows[0].t_traj_start, windows[39].t_traj_start);
        let drifting = move |t: f64| 0.3 + 0.3 * (((t - t0) / (t1 - t0)).clamp(0.0, 1.0) - 0.5);
        let opts = DiagnoseOptions::default();
        let bus = super::super::bus_model(&opts);
        let mut run = |mbs: &dyn Fn(f64) -> f64, bms: &dyn Fn(f64) -> f64| {
            rec.mbs = meter(&rec, mbs, (0.537, 0.0, 0.15), 1);
            rec.bms = meter(&rec, bms, (0.811, 60.0, 0.5), 2);
            let (metas, _) = trial_meta(&rec, &windows, bus);
            let info = SessionInfo::of(&rec, crate::signals::Target::Mbs);
            sensor_window(&info, &mut crate::session::Memory(&rec), &metas, &opts).expect("scan")
        };
        let steady = |_: f64| 0.3;
        let sw = run(&drifting, &steady);
        let mid = sw.window_at(0.5 * (t0 + t1));
        assert!((sw.drift_s - 0.3).abs() <= 0.05 + 1e-9, "{sw:?}");
        assert!((mid - 0.3).abs() <= 2.0 * STEP + 1e-9, "{mid} {sw:?}");
        assert!(
            sw.drift_delta_bic < opts.bic_threshold && sw.drift_artefact,
            "{sw:?}"
        );
        let sw = run(&drifting, &drifting);
        assert!(
            (sw.drift_s - 0.3).abs() <= 0.05 + 1e-9 && !sw.drift_artefact,
            "{sw:?}"
        );
        let sw = run(&steady, &steady);
        assert_eq!(sw.drift_s, 0.0, "{sw:?}");
        assert!((sw.window_s - 0.3).abs() <= STEP + 1e-9, "{sw:?}");
    }
}
