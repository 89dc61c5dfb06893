//! Diagnosis rows: one row per power reading that falls inside a trial, holding the base
//! regressors φ, the hypotheses' extra features and descriptor features, each averaged over
//! the reading's own sensor window [t − lag − W, t − lag], and the net power target (reading
//! minus the trial's pre-idle mean reading).
//!
//! The set of readings is fixed by their time stamps (not by the lag), so rows built at two
//! lags describe the same readings and their errors can be compared trial by trial.

use crate::N_JOINTS;
use crate::power::PowerModel;
use crate::signals::{PowerSeries, Recording};
use crate::trial::{
    MIN_WINDOW_SAMPLES, Phase, TrialWindow, readings_within, samples_in, sigma_omega,
};

use super::hypotheses::{N_EXTRA, N_LOCATE, N_RAW, Sample, extras_into, locate_into, raw_row};

/// Margin before a trial's pre-idle start whose samples belong to the trial [s]: a window
/// reaching further back is cut there. The streamed reader keeps at least 0.5 s before the
/// pre-idle of the trial it is reading; this stays inside it.
pub(crate) const SPAN_MARGIN_S: f64 = 0.4;

/// Time span of `w` whose joint states the per-trial reductions look at: from
/// [`SPAN_MARGIN_S`] before the pre-idle to the end of the return home.
pub(crate) fn span(w: &TrialWindow) -> (f64, f64) {
    (w.t_pre_start - SPAN_MARGIN_S, w.t_return_end)
}

/// Per-trial quantities computed once from the kinematic side.
#[derive(Debug, Clone)]
pub(crate) struct TrialMeta {
    pub window: TrialWindow,
    /// Mean squared torque over pre-idle [Nm²].
    pub tau0_sq: [f64; N_JOINTS],
    /// Mean extra features over pre-idle (subtracted: the target is net of the pre-idle baseline).
    pub extra0: [f64; N_EXTRA],
    /// σ of the body angular-velocity magnitude over the trajectory window [rad/s].
    pub sigma_omega: f64,
    /// Bus-current model.
    pub bus: BusModel,
    /// Joint-state samples from the pre-idle start to the return end (the torque level's
    /// thinning counts them).
    pub n_samples: usize,
    /// The sensor window of this trial's readings where it drifts over the session (the
    /// window stage's correction, [`super::SensorWindow::window_at`]); `None`: the session's.
    pub width_s: Option<f64>,
}

/// Trials that cannot be used, each with its position and the reason (e.g. no pre-idle).
pub(crate) type Skipped = Vec<(usize, String)>;

/// Rows of one lag.
#[derive(Debug, Clone, Default)]
pub(crate) struct Rows {
    /// Position of each row's trial in the trial list.
    pub trial: Vec<usize>,
    /// Reading time stamp [s].
    pub t: Vec<f64>,
    /// Phase of the reading's window.
    pub phase: Vec<Phase>,
    /// Net power [W].
    pub y: Vec<f64>,
    /// Base regressors + extra features (window means).
    pub x: Vec<[f64; N_RAW]>,
    /// Descriptor features (window means), empty unless requested.
    pub locate: Vec<[f64; N_LOCATE]>,
}

impl Rows {
    pub fn len(&self) -> usize {
        self.y.len()
    }

    /// Keep, in place and in order, the rows for which `f(row, trial)` gives a trial index
    /// (the row's new `trial`); the others are dropped.
    pub fn retain(&mut self, mut f: impl FnMut(usize, usize) -> Option<usize>) {
        let new: Vec<Option<usize>> = (0..self.len()).map(|i| f(i, self.trial[i])).collect();
        fn keep<T>(v: &mut Vec<T>, new: &[Option<usize>]) {
            let mut i = 0..;
            v.retain(|_| i.next().is_some_and(|i| new[i].is_some()));
        }
        keep(&mut self.t, &new);
        keep(&mut self.phase, &new);
        keep(&mut self.y, &new);
        keep(&mut self.x, &new);
        keep(&mut self.locate, &new);
        self.trial = new.into_iter().flatten().collect();
        self.shrink_to_fit();
    }

    /// Append `part`'s rows, numbered as trial `ti`.
    pub fn append(&mut self, part: Rows, ti: usize) {
        self.trial.extend(std::iter::repeat_n(ti, part.len()));
        self.t.extend(part.t);
        self.phase.extend(part.phase);
        self.y.extend(part.y);
        self.x.extend(part.x);
        self.locate.extend(part.locate);
    }

    /// Give back the spare capacity of every column.
    pub fn shrink_to_fit(&mut self) {
        self.trial.shrink_to_fit();
        self.t.shrink_to_fit();
        self.phase.shrink_to_fit();
        self.y.shrink_to_fit();
        self.x.shrink_to_fit();
        self.locate.shrink_to_fit();
    }
}

fn sample_at<'a>(
    rec: &'a Recording,
    k: usize,
    tau0_sq: &'a [f64; N_JOINTS],
    bus: &BusModel,
) -> Option<Sample<'a>> {
    let s = &rec.state;
    let (tau, dq) = (s.tau.get(k)?, s.dq.get(k)?);
    Some(Sample {
        q: s.q.get(k)?,
        dq,
        tau,
        temp: s.temp.get(k)?,
        gyro: s.gyro.get(k)?,
        tau0_sq,
        bus_amps: bus.model.predict(tau, dq, tau0_sq) / bus.volts_at(s.volts.get(k)),
    })
}

/// What the bus-current feature needs: the drives' electrical power model and the supply voltage.
#[derive(Debug, Clone, Copy)]
pub(crate) struct BusModel {
    /// Power model of the drives' electrical input (the twin's).
    pub model: PowerModel,
    /// Supply voltage [V] where a sample has no recorded one.
    pub volts: f64,
}

impl BusModel {
    /// The supply voltage of a sample: the recorded one (it falls with the battery's charge, and
    /// the bus current P/V with it), or the nominal one where none was recorded.
    fn volts_at(&self, recorded: Option<&f64>) -> f64 {
        recorded
            .copied()
            .filter(|v| v.is_finite() && *v > 1.0)
            .unwrap_or(self.volts)
    }
}

/// Compute the per-trial quantities; trials without pre-idle samples are returned in `skipped`.
pub(crate) fn trial_meta(
    rec: &Recording,
    windows: &[TrialWindow],
    bus: BusModel,
) -> (Vec<TrialMeta>, Skipped) {
    let t = &rec.state.t;
    let mut out = Vec::new();
    let mut skipped = Vec::new();
    for w in windows {
        let Some(pre) = w.pre_idle(t) else {
            skipped.push((
                w.index,
                format!(
                    "only {} joint samples in the pre-idle window",
                    samples_in(t, w.t_pre_start, w.t_traj_start).len()
                ),
            ));
            continue;
        };
        let mut tau0_sq = [0.0; N_JOINTS];
        for tau in pre.clone().filter_map(|k| rec.state.tau.get(k)) {
            tau0_sq.iter_mut().zip(tau).for_each(|(a, t)| *a += t * t);
        }
        tau0_sq.iter_mut().for_each(|v| *v /= pre.len() as f64);
        let mut extra0 = [0.0; N_EXTRA];
        let mut buf = [0.0; N_EXTRA];
        let mut n = 0usize;
        for k in pre {
            if let Some(s) = sample_at(rec, k, &tau0_sq, &bus) {
                extras_into(&s, &mut buf);
                extra0.iter_mut().zip(&buf).for_each(|(a, b)| *a += b);
                n += 1;
            }
        }
        extra0.iter_mut().for_each(|v| *v /= n.max(1) as f64);
        // The identification's IMU statistic over the same trajectory window.
        let sigma_omega = sigma_omega(rec, w.t_traj_start, w.t_post_end);
        let n_samples = samples_in(t, w.t_pre_start, w.t_return_end).len();
        out.push(TrialMeta {
            window: w.clone(),
            tau0_sq,
            extra0,
            sigma_omega,
            bus,
            n_samples,
            width_s: None,
        });
    }
    (out, skipped)
}

/// Sample `k`'s base regressors φ and extra features (`None` where its data are missing).
fn features(rec: &Recording, k: usize, meta: &TrialMeta) -> Option<[f64; N_RAW]> {
    Some(raw_row(&sample_at(rec, k, &meta.tau0_sq, &meta.bus)?))
}

/// `x`'s extra features net of the trial's pre-idle level (the target is net of it too).
fn net_of_baseline(x: &mut [f64; N_RAW], meta: &TrialMeta) {
    for (v, b0) in x[crate::N_PARAMS..].iter_mut().zip(&meta.extra0) {
        *v -= b0;
    }
}

/// Mean of φ and the extras (and optionally the descriptors) over state samples in (a, b], the
/// window cut at the trial's span ([`span`]: a window never reaches into samples
/// that belong to no trial's span, so a streamed read sees the same samples as one in memory).
/// `None` when the window holds fewer than [`MIN_WINDOW_SAMPLES`] (a gap in the joint stream)
/// or a sample with missing data.
fn window_mean(
    rec: &Recording,
    meta: &TrialMeta,
    feats: &TrialFeatures,
    (a, b): (f64, f64),
    x: &mut [f64; N_RAW],
    loc: Option<&mut [f64; N_LOCATE]>,
) -> Option<()> {
    let a = a.max(span(&meta.window).0);
    let range = samples_in(&rec.state.t, a, b);
    if range.len() < MIN_WINDOW_SAMPLES {
        return None;
    }
    let n = range.len() as f64;
    x.fill(0.0);
    let mut lbuf = [0.0; N_LOCATE];
    let mut lsum = [0.0; N_LOCATE];
    for k in range {
        let f = feats.sample(rec, meta, k)?;
        for (xi, v) in x.iter_mut().zip(&f) {
            *xi += v;
        }
        if loc.is_some() {
            locate_into(&sample_at(rec, k, &meta.tau0_sq, &meta.bus)?, &mut lbuf);
            lsum.iter_mut().zip(&lbuf).for_each(|(a, b)| *a += b);
        }
    }
    x.iter_mut().for_each(|v| *v /= n);
    net_of_baseline(x, meta);
    if let Some(l) = loc {
        for (o, s) in l.iter_mut().zip(&lsum) {
            *o = s / n;
        }
    }
    Some(())
}

/// The base regressors and extra features of every state sample a trial's windows can reach
/// (its span up to the end of its return), computed once and shared by the rows of every lag:
/// a window's mean is then the same sums, in the same order, as from the samples.
pub(crate) struct TrialFeatures {
    first: usize,
    /// `None` for a sample with missing data (its windows give no row).
    feats: Vec<Option<[f64; N_RAW]>>,
}

impl TrialFeatures {
    /// No cached features: every window is computed from the samples (for a single use of a
    /// trial's samples, where computing every sample of its span first would cost more).
    pub(crate) fn none() -> TrialFeatures {
        TrialFeatures {
            first: 0,
            feats: Vec::new(),
        }
    }

    pub(crate) fn new(rec: &Recording, meta: &TrialMeta) -> TrialFeatures {
        let a = span(&meta.window).0;
        let range = samples_in(&rec.state.t, a, meta.window.t_return_end + 1e-6);
        TrialFeatures {
            first: range.start,
            feats: range.map(|k| features(rec, k, meta)).collect(),
        }
    }

    /// Sample `k`'s features: cached, or computed from the samples outside the cache.
    fn sample(&self, rec: &Recording, meta: &TrialMeta, k: usize) -> Option<[f64; N_RAW]> {
        match k.checked_sub(self.first).and_then(|i| self.feats.get(i)) {
            Some(f) => *f,
            None => features(rec, k, meta),
        }
    }

    /// Sample `k`'s base regressors and every library mechanism's features, the latter net of
    /// the trial's pre-idle level (as a row's are); `None` where missing or not finite.
    pub(crate) fn raw(&self, k: usize, meta: &TrialMeta) -> Option<[f64; N_RAW]> {
        let mut x = (*self.feats.get(k.checked_sub(self.first)?)?)?;
        net_of_baseline(&mut x, meta);
        x.iter().all(|v| v.is_finite()).then_some(x)
    }
}

/// A trial's baseline readings at sensor lag `lag` and window `width`: the rule identification
/// uses too ([`TrialWindow::baseline_readings`]), for every stage that reads a trial's rest power.
pub(crate) fn baseline_readings(
    pt: &[f64],
    m: &TrialMeta,
    lag: f64,
    width: f64,
) -> std::ops::Range<usize> {
    (m.window).baseline_readings(pt, lag, m.width_s.unwrap_or(width))
}

/// Build the rows for one sensor lag. Readings are assigned to trials by their stamps:
/// baseline readings by [`baseline_readings`], row readings with stamps in
/// [t_traj_start + W, t_return_end].
pub(crate) fn build_rows(
    rec: &Recording,
    power: &PowerSeries,
    trials: &[TrialMeta],
    lag: f64,
    width: f64,
) -> Rows {
    let mut rows = Rows::default();
    for (ti, meta) in trials.iter().enumerate() {
        let feats = TrialFeatures::none();
        let part = trial_rows(rec, power, meta, &feats, (lag, width), false);
        rows.append(part, ti);
    }
    rows
}

/// One trial's rows (numbered trial 0) at sensor `lag` and window `width`, from its
/// [`TrialFeatures`] (`with_locate`: with the descriptor features).
pub(crate) fn trial_rows(
    rec: &Recording,
    power: &PowerSeries,
    meta: &TrialMeta,
    feats: &TrialFeatures,
    (lag, width): (f64, f64),
    with_locate: bool,
) -> Rows {
    let mut rows = Rows::default();
    let pt = &power.t;
    let mut x = [0.0; N_RAW];
    let mut loc = [0.0; N_LOCATE];
    let w = &meta.window;
    let width = meta.width_s.unwrap_or(width);
    let base = baseline_readings(pt, meta, lag, width);
    let baseline = super::meters::finite_mean(base.filter_map(|k| power.watts.get(k).copied()));
    if baseline.is_nan() {
        return rows;
    }
    // Readings whose window (at lag 0) lies inside the trajectory, post-idle and return: fixed
    // by their stamps, so the rows of every lag describe the same readings.
    for k in readings_within(pt, w.t_traj_start, w.t_return_end, 0.0, width) {
        let (Some(&tk), Some(&p)) = (pt.get(k), power.watts.get(k)) else {
            continue;
        };
        if !p.is_finite() {
            continue;
        }
        let l = with_locate.then_some(&mut loc);
        let got = window_mean(rec, meta, feats, (tk - lag - width, tk - lag), &mut x, l);
        // A gap in the joint stream, or non-finite samples (damaged file): no row.
        if got.is_none() || x.iter().any(|v| !v.is_finite()) {
            continue;
        }
        let mid = tk - 0.5 * width;
        let phase = w.phase_at(mid).unwrap_or(Phase::Return);
        rows.trial.push(0);
        rows.t.push(tk);
        rows.phase.push(phase);
        rows.y.push(p - baseline);
        rows.x.push(x);
        if with_locate {
            rows.locate.push(loc);
        }
    }
    rows
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::{Alignment, DatasetOptions, Mode, build_dataset};
    use crate::signals::{StateSeries, Target};

    /// A session written here, by neither row builder: 100 Hz joint states whose τ and q̇ vary
    /// sample by sample, readings every 0.25 s (on the sample grid, so window edges fall on
    /// samples) plus one every 0.37 s (off it), with a NaN reading and a gap in the joint stream.
    fn session() -> (Recording, TrialWindow) {
        let wave = |k: usize, j: usize| ((k * (j + 3)) as f64 * 0.011).sin();
        let ks: Vec<usize> = (0..2000).filter(|k| !(900..905).contains(k)).collect();
        let col = |f: &dyn Fn(usize, usize) -> f64| -> Vec<[f64; N_JOINTS]> {
            ks.iter()
                .map(|&k| std::array::from_fn(|j| f(k, j)))
                .collect()
        };
        let state = StateSeries {
            t: ks.iter().map(|&k| k as f64 * 0.01).collect(),
            q: col(&|k, j| 0.1 * wave(k, j)),
            dq: col(&|k, j| if k > 300 { wave(k, j + 1) } else { 0.0 }),
            tau: col(&|k, j| 1.0 + wave(k, j + 2)),
            temp: col(&|_, _| 40.0),
            gyro: ks.iter().map(|&k| [0.01 * wave(k, 0), 0.0, 0.0]).collect(),
            quat: ks.iter().map(|_| [1.0, 0.0, 0.0, 0.0]).collect(),
            volts: Vec::new(),
        };
        let mut t: Vec<f64> = (1..80).map(|k| k as f64 * 0.25).collect();
        t.extend((1..54).map(|k| k as f64 * 0.37));
        t.sort_by(f64::total_cmp);
        let watts = t
            .iter()
            .enumerate()
            .map(|(i, &s)| if i == 40 { f64::NAN } else { 20.0 + s.sin() })
            .collect();
        let rec = Recording {
            state,
            mbs: PowerSeries { t, watts },
            ..Recording::default()
        };
        let trial = TrialWindow::for_test(0, [0.5, 3.0, 12.0, 14.0, 18.0]);
        (rec, trial)
    }

    /// Identification's per-reading rows and the diagnosis' rows follow one rule (the samples a
    /// reading averages, the fewest a window needs, the pre-idle and the baseline readings): on
    /// the readings both take, the same φ and net power; and the diagnosis takes a row for every
    /// reading identification takes.
    #[test]
    fn identification_and_diagnosis_build_the_same_reading_rows() {
        let (rec, trial) = session();
        let bus = BusModel {
            model: PowerModel::PAPER,
            volts: 50.0,
        };
        let (metas, skipped) = trial_meta(&rec, std::slice::from_ref(&trial), bus);
        assert!(skipped.is_empty());
        for (w, lag) in [(0.2, 0.0), (0.25, 0.1), (0.3, 0.05), (0.5, 0.3)] {
            let opts = DatasetOptions {
                mode: Mode::Reading,
                target: Target::Mbs,
                alignment: Alignment {
                    window_s: w,
                    lag_s: lag,
                },
            };
            let id = build_dataset(&rec, std::slice::from_ref(&trial), &opts);
            let rows = build_rows(&rec, &rec.mbs, &metas, lag, w);
            assert!(
                id.rows.len() > 30,
                "W {w}, lag {lag}: {} rows",
                id.rows.len()
            );
            for r in &id.rows {
                let k = rows.t.iter().position(|&t| t == r.t);
                let k = k.unwrap_or_else(|| panic!("W {w}, lag {lag}: no row at {}", r.t));
                assert!((rows.y[k] - r.y).abs() < 1e-12, "y at {}", r.t);
                for (a, b) in r.phi.iter().zip(&rows.x[k][..crate::N_PARAMS]) {
                    assert!(
                        (a - b).abs() <= 1e-9 * (1.0 + a.abs()),
                        "φ at {}: {a} {b}",
                        r.t
                    );
                }
            }
            let (lo, hi) = (trial.t_traj_start + lag + w, trial.t_post_end + lag);
            let inside = rows.t.iter().filter(|&&t| t >= lo && t <= hi).count();
            assert_eq!(inside, id.rows.len(), "W {w}, lag {lag}");
        }
    }
}
