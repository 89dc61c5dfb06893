//! What a model or a diagnosis adds to a replay, logged: the power readings next to the
//! like-for-like prediction and their errors, the loss terms (per joint, per term, per trial),
//! the IMU filter's statistic and threshold, the trial track and log, the diagnosis overlay.

use anyhow::Result;
use rerun::components::{AggregationPolicy, InterpolationMode, MarkerShape, TextLogLevel};
use rerun::{SeriesLines, TextDocument, TextLog};

use super::replay::LINK_COLOUR_RATE_HZ;
use super::replay::{
    DiagnosisOverlay, ImuFilterMarks, ReadingPrediction, ReplayExtras, TermSeries, TrajectoryPoint,
    TrialMark, scalars, scalars_chunked,
};
use super::{ChunkWriter, paths, style};
use crate::N_JOINTS;

/// Logs what `extras` hold before any sample is read (the readings and their errors, each
/// trial's error, rest power and IMU statistic, the trial track, a diagnosis): at the replay's
/// start, so a viewer opening a long file shows the power plots and the per-trial plots first.
pub(super) fn log_known(
    w: &mut ChunkWriter<'_>,
    joints: &[String],
    extras: &ReplayExtras,
    chunk: usize,
) -> Result<()> {
    if extras.model.is_some() {
        let (path, name) = (paths::MODEL_PREDICTED, "predicted, instantaneous");
        style::line(w, path, name, style::PREDICTED_CONTEXT, 0.75)?;
    }
    if let Some(r) = &extras.readings {
        log_readings(w, r, chunk)?;
    }
    log_trajectories(w, &extras.trajectories)?;
    if let Some(imu) = &extras.imu_filter {
        log_imu_filter(w, imu)?;
    }
    log_trial_marks(w, paths::TRIALS, &sorted(&extras.trials), "rejected", true)?;
    if let Some(d) = &extras.diagnosis {
        log_diagnosis(w, joints, d, chunk)?;
        log_diagnosis_per_trial(w, joints, d)?;
    }
    Ok(())
}

/// Logs what the model's series give once logged (`stats`, gathered trial by trial,
/// [`super::ReplayLogger::log_model_trial`]): the terms' styles, the per-trial shares, the note,
/// and the trial log with each trial's shares.
pub(super) fn log_model_stats(
    w: &mut ChunkWriter<'_>,
    joints: &[String],
    extras: &ReplayExtras,
    stats: &ModelStats,
) -> Result<()> {
    let mut marks = std::borrow::Cow::Borrowed(&extras.trials[..]);
    if extras.model.is_some() {
        log_term_styles(w, joints)?;
        let means = &stats.means;
        log_bars(w, joints, means, true)?;
        let note = breakdown_note(joints, stats.colour_scale(), means);
        w.send_static(paths::BREAKDOWN_NOTE, &TextDocument::from_markdown(note))?;
        marks = std::borrow::Cow::Owned(with_shares(&extras.trials, means, joints));
    }
    log_trial_log(w, paths::TRIALS, &sorted(&marks))
}

/// The first time and the mean of `v` of each run of readings of one trial (`t`, `trial` and
/// `v` per reading, in session order).
pub(super) fn per_trial_mean(t: &[f64], trial: &[usize], v: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let n = t.len().min(trial.len()).min(v.len());
    let mean = |r: std::ops::Range<usize>| v[r.clone()].iter().sum::<f64>() / r.len() as f64;
    runs(trial, n).map(|r| (t[r.start], mean(r))).unzip()
}

/// The runs of the first `n` readings that belong to one trial (`trial` per reading).
fn runs(trial: &[usize], n: usize) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
    let mut k = 0;
    std::iter::from_fn(move || {
        let start = k;
        k += trial[start..n]
            .iter()
            .take_while(|&&x| x == trial[start])
            .count();
        (k > start).then_some(start..k)
    })
}

/// A diagnosis' [`TrialMean`]s: each trial's base terms ([`crate::diagnose::ReplayData::terms_w`])
/// averaged over its readings, so its shares come out of the model replay's computation.
fn reading_means(d: &crate::diagnose::ReplayData) -> Vec<TrialMean> {
    let col = |k: usize| d.terms_w.iter().map(|x| x.0[k]).collect();
    let terms = TermSeries {
        t: d.t.clone(),
        predicted: Vec::new(),
        per_joint: std::array::from_fn(col),
        interaction: d.terms_w.iter().map(|x| x.1).collect(),
    };
    let n = terms.len().min(d.trial.len());
    let over =
        |r: std::ops::Range<usize>| TrialMean::over(d.trial[r.start], &terms, &Vec::from_iter(r));
    runs(&d.trial, n).filter_map(over).collect()
}

/// The diagnosis' error per trial (the mean over its readings) of the base model, with the
/// accepted hypotheses and with the found terms: the whole-session overview of a long session;
/// past [`super::blueprint::WINDOWED_ABOVE_TRIALS`] trials, each trial's joint shares as a model
/// replay logs them (a long session's Joints tab takes its colour key from them).
fn log_diagnosis_per_trial(
    w: &mut ChunkWriter<'_>,
    joints: &[String],
    d: &DiagnosisOverlay,
) -> Result<()> {
    let d = &d.data;
    let means = reading_means(d);
    if means.len() > super::blueprint::WINDOWED_ABOVE_TRIALS {
        log_bars(w, joints, &means, false)?;
    }
    // Each reading's error, where the prediction has one per reading.
    let err = |p: &[f64]| -> Vec<f64> {
        let whole = p.len() == d.t.len();
        (d.measured_w.iter().zip(p).filter(|_| whole))
            .map(|(m, p)| m - p)
            .collect()
    };
    let (error, rest) = (paths::diag_trial_error, paths::diag_trial_rest);
    let (diamond, circle) = ((MarkerShape::Diamond, 3.0), (MarkerShape::Circle, 2.5));
    #[rustfmt::skip]
    let series = [
        (error("before"), "error per trial, base model", style::NEUTRAL, diamond, err(&d.before_w)),
        (error("after"), "error per trial, with hypotheses", style::ERROR, diamond, err(&d.after_w)),
        (error("found"), "error per trial, with found terms", style::WARNING, diamond, err(&d.found_w)),
        (rest("measured"), "rest power of the trial", style::MEASURED, circle, d.rest_w.clone()),
        (rest("found"), "with the loads found on it (held out)", style::WARNING, circle, d.rest_found_w.clone()),
    ];
    for (path, name, colour, (shape, size), v) in series {
        if v.len() != d.t.len() || v.is_empty() {
            continue;
        }
        let (t, m) = per_trial_mean(&d.t, &d.trial, &v);
        style::points(w, &path, name, colour, shape, size)?;
        scalars(w, &path, &t, m.into_iter())?;
    }
    Ok(())
}

/// Values of `v` where `keep` says so, with their times.
fn split(t: &[f64], v: &[f64], keep: impl Fn(usize) -> bool) -> (Vec<f64>, Vec<f64>) {
    (0..t.len().min(v.len()))
        .filter(|&i| keep(i))
        .map(|i| (t[i], v[i]))
        .unzip()
}

/// Readings: measured and like-for-like predicted at the reading stamps, and their error
/// (readings of rejected trials in the warning colour).
fn log_readings(w: &mut ChunkWriter<'_>, r: &ReadingPrediction, chunk: usize) -> Result<()> {
    use MarkerShape::{Circle, Diamond};
    let (measured, predicted) = (
        paths::MODEL_READING_MEASURED,
        paths::MODEL_READING_PREDICTED,
    );
    let name = "measured reading";
    style::points(w, measured, name, style::MEASURED, Circle, 4.0)?;
    let (window, lag) = (r.window_s, r.lag_s);
    let name = format!("predicted, reading window ({window:.2} s, lag {lag:.2} s)");
    style::points(w, predicted, &name, style::PREDICTED, Diamond, 4.0)?;
    scalars_chunked(w, measured, &r.t, &r.measured, chunk)?;
    scalars_chunked(w, predicted, &r.t, &r.predicted, chunk)?;
    let err: Vec<f64> = r
        .measured
        .iter()
        .zip(&r.predicted)
        .map(|(m, p)| m - p)
        .collect();
    let rejected = |i: usize| r.rejected.get(i).copied().unwrap_or(false);
    let (kt, kv) = split(&r.t, &err, |i| !rejected(i));
    let (rt, rv) = split(&r.t, &err, rejected);
    let path = paths::MODEL_ERROR_READING;
    style::points(w, path, "per reading", style::ERROR, Circle, 2.5)?;
    scalars_chunked(w, path, &kt, &kv, chunk)?;
    if !rt.is_empty() {
        let path = paths::MODEL_ERROR_READING_REJECTED;
        let name = "per reading, rejected trial";
        style::points(w, path, name, style::WARNING, Circle, 2.5)?;
        scalars_chunked(w, path, &rt, &rv, chunk)?;
    }
    Ok(())
}

/// Per-trajectory errors (mean reading − mean like-for-like prediction), at the trajectory end.
fn log_trajectories(w: &mut ChunkWriter<'_>, points: &[TrajectoryPoint]) -> Result<()> {
    use MarkerShape::{Cross, Diamond};
    let (kept, dropped) = (
        paths::MODEL_ERROR_TRAJECTORY,
        paths::MODEL_ERROR_TRAJECTORY_REJECTED,
    );
    let (ok, bad) = (style::ERROR_TRAJECTORY, style::WARNING);
    let kinds = [
        (false, kept, "", ok, Diamond),
        (true, dropped, ", rejected trial", bad, Cross),
    ];
    for (rejected, path, tail, colour, shape) in kinds {
        let name = format!("per trajectory{tail}");
        let (t, e): (Vec<f64>, Vec<f64>) = points
            .iter()
            .filter(|p| p.rejected == rejected)
            .map(|p| (p.t, p.measured - p.predicted))
            .unzip();
        if t.is_empty() {
            continue;
        }
        style::points(w, path, &name, colour, shape, 6.0)?;
        scalars(w, path, &t, e.into_iter())?;
    }
    let (t, rest): (Vec<f64>, Vec<f64>) = points
        .iter()
        .filter(|p| p.rest_w.is_finite())
        .map(|p| (p.t, p.rest_w))
        .unzip();
    if !t.is_empty() {
        let (path, name) = (paths::TRIAL_REST, "rest power (pre-idle mean)");
        style::points(w, path, name, style::MBS, MarkerShape::Circle, 2.5)?;
        scalars(w, path, &t, rest.into_iter())?;
    }
    Ok(())
}

/// The styles of the model's series: one per joint and term and the interaction
/// ([`log_term_data`]), each term summed over the joints and each joint's terms summed
/// ([`log_breakdown_data`]).
fn log_term_styles(w: &mut ChunkWriter<'_>, joints: &[String]) -> Result<()> {
    for name in joints {
        for (k, term) in paths::TERMS.iter().enumerate() {
            style::line(w, &paths::term(name, term), term, style::TERMS[k], 1.5)?;
        }
    }
    let name = "interaction Σ e_ij |q̇_i||q̇_j|";
    style::line(w, paths::TERM_INTERACTION, name, style::TERMS[4], 1.5)?;
    for (k, term) in paths::TERMS.iter().chain(&["interaction"]).enumerate() {
        style::line(w, &paths::by_term(term), term, style::TERMS[k], 1.5)?;
    }
    for (j, name) in joints.iter().enumerate() {
        style::line(w, &paths::by_joint(name), name, style::joint(j), 1.5)?;
    }
    Ok(())
}

/// One series per joint and term, and the interaction (styles: [`log_term_styles`]).
pub(super) fn log_term_data(
    w: &mut ChunkWriter<'_>,
    joints: &[String],
    terms: &TermSeries,
    chunk: usize,
) -> Result<()> {
    for (j, name) in joints.iter().enumerate() {
        for (k, data) in terms.per_joint.iter().enumerate() {
            let v: Vec<f64> = data.iter().map(|v| v[j]).collect();
            scalars_chunked(w, &paths::term(name, paths::TERMS[k]), &terms.t, &v, chunk)?;
        }
    }
    let (t, interaction) = (&terms.t, &terms.interaction);
    scalars_chunked(w, paths::TERM_INTERACTION, t, interaction, chunk)
}

/// Per sample: each term summed over the joints, and each joint's terms summed (styles:
/// [`log_term_styles`]).
pub(super) fn log_breakdown_data(
    w: &mut ChunkWriter<'_>,
    joints: &[String],
    terms: &TermSeries,
    chunk: usize,
) -> Result<()> {
    let (fields, n) = (&terms.per_joint, terms.len());
    let t = &terms.t[..n];
    for (k, field) in fields.iter().enumerate() {
        let sums: Vec<f64> = field[..n].iter().map(|v| v.iter().sum()).collect();
        scalars_chunked(w, &paths::by_term(paths::TERMS[k]), t, &sums, chunk)?;
    }
    let interaction = &terms.interaction[..n];
    scalars_chunked(w, &paths::by_term("interaction"), t, interaction, chunk)?;
    for (j, name) in joints.iter().enumerate() {
        let sums: Vec<f64> = (0..n)
            .map(|i| fields.iter().map(|f| f[i][j]).sum())
            .collect();
        scalars_chunked(w, &paths::by_joint(name), t, &sums, chunk)?;
    }
    Ok(())
}

/// Time between the bottom and top of a bar's vertical edge [s] (the viewer keeps one value per
/// time stamp, so an edge needs two stamps).
const EDGE_S: f64 = 0.01;

/// Per-trial bars keyed by trial index: each joint's and term's signed share of the trial's
/// energy turnover ([`TrialMean::turnover`]), one static bar chart per joint or term in its
/// colour, the bars side by side around the trial's index (their width kept at any time zoom).
/// Past [`super::blueprint::WINDOWED_ABOVE_TRIALS`] trials (a bar narrower than a pixel): one
/// point per trial at its start on the session's time axis instead. `terms`: the terms' bars too
/// (a diagnosis logs the joints' only: no view of it shows the terms').
fn log_bars(
    w: &mut ChunkWriter<'_>,
    joints: &[String],
    means: &[TrialMean],
    terms: bool,
) -> Result<()> {
    let shares: Vec<Shares> = means.iter().map(TrialMean::turnover).collect();
    let pick = |term: bool, k: usize| {
        shares
            .iter()
            .map(move |s| [&s.1, &s.0][usize::from(term)][k])
    };
    let long = means.len() > super::blueprint::WINDOWED_ABOVE_TRIALS;
    if !long {
        let all = |term: bool| {
            shares
                .iter()
                .flat_map(move |s| [&s.1, &s.0][usize::from(term)].clone())
        };
        bar_axis_anchors(w, paths::BARS_BY_JOINT, means, all(false))?;
        bar_axis_anchors(w, paths::BARS_BY_TERM, means, all(true))?;
    }
    let joint_series = joints.iter().map(String::as_str).enumerate();
    let term_series = paths::TERMS
        .iter()
        .chain(["interaction"].iter())
        .copied()
        .enumerate();
    let term_series = term_series.filter(|_| terms).map(|(k, n)| (true, k, n));
    let series = (joint_series.map(|(k, n)| (false, k, n))).chain(term_series);
    for (term, k, name) in series {
        let (path, colour, slots) = if term {
            (
                paths::bar_by_term(name),
                style::TERMS[k],
                style::TERMS.len(),
            )
        } else {
            (paths::bar_by_joint(name), style::joint(k), joints.len())
        };
        if long {
            style::points(w, &path, name, colour, MarkerShape::Circle, 1.5)?;
            let t: Vec<f64> = means.iter().map(|m| m.t).collect();
            scalars(w, &path, &t, pick(term, k))?;
        } else {
            // Bar `k` of `slots` around each trial's index, the group 0.8 wide and centred on
            // it: x is the bar's left edge (the viewer draws it from x to x + width); heights
            // that are not finite get no bar.
            let width = 0.8 / slots.max(1) as f64;
            let (x, v): (Vec<f64>, Vec<f64>) = (means.iter().zip(pick(term, k)))
                .map(|(m, v)| (m.index as f64 - 0.4 + k as f64 * width, v))
                .filter(|(_, v)| v.is_finite())
                .unzip();
            if !x.is_empty() {
                let bars = rerun::BarChart::new(v).with_widths(vec![width as f32; x.len()]);
                let bars = bars.with_abscissa(x).with_color(style::rgb(colour));
                w.send_static(&path, &bars)?;
            }
        }
    }
    Ok(())
}

/// Invisible bars (height 0 or at the y extent, fully transparent) at the ends of the extent
/// the bar charts under `tree` are fitted to: the viewer fits a bar chart to its bars (5 % to
/// spare) and labels only the multiples of a power of ten whose spacing is wide enough, so a
/// few trials in a narrow cell showed a single "0". The extent is the trials' (and the values')
/// widened until the viewer labels at least two ticks on each axis in a
/// [`blueprint::BAR_PLOT_PX`] plot.
fn bar_axis_anchors(
    w: &mut ChunkWriter<'_>,
    tree: &str,
    means: &[TrialMean],
    values: impl Iterator<Item = f64>,
) -> Result<()> {
    use super::blueprint::{BAR_PLOT_PX, X_LABEL_PX, Y_LABEL_PX, tick_range};
    let Some([first, last]) = super::data_range(means.iter().map(|m| m.index as f64)) else {
        return Ok(());
    };
    let [lo, hi] = super::data_range(values.chain([0.0])).unwrap_or([0.0, 0.0]);
    let margins = |[a, b]: [f64; 2]| {
        let span = b - a;
        Some([a - 0.05 * span, b + 0.05 * span])
    };
    let trials = [first - 0.4, last + 0.4];
    let x = tick_range(trials, BAR_PLOT_PX[0], X_LABEL_PX, &margins).map_or(trials, |r| r.0);
    let y = tick_range([lo, hi], BAR_PLOT_PX[1], Y_LABEL_PX, &margins).map_or([lo, hi], |r| r.0);
    // Heights 0 unless the values' extent had to widen (then the anchors reach the widened
    // extent, still invisible).
    let height = |end: f64, data: f64| if end == data { 0.0 } else { end };
    let width = 1e-3;
    w.send_static(
        &format!("{tree}/{}", paths::BAR_AXIS),
        &rerun::BarChart::new(vec![height(y[0], lo), height(y[1], hi)])
            .with_abscissa(vec![x[0], x[1] - width])
            .with_widths(vec![width as f32; 2])
            .with_color(rerun::Color::from_unmultiplied_rgba(0, 0, 0, 0)),
    )
}

/// Each term's and each joint's share [%] of an energy turnover ([`energy_shares`] order).
type Shares = (Vec<f64>, Vec<f64>);

/// The mean predicted power of one trial over its window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrialMean {
    /// Trial index.
    pub index: usize,
    /// Time of the trial's first sample [s].
    pub t: f64,
    /// Per joint, its four terms summed [W].
    pub by_joint: [f64; N_JOINTS],
    /// Per term (mechanical, copper, Coulomb, viscous, interaction), joints summed [W].
    pub by_term: [f64; 5],
    /// Samples averaged (at a fixed sample rate, the trial's energy is its mean × this).
    pub samples: usize,
}

impl TrialMean {
    /// The mean of `terms` at its samples `idx`, as trial `index` (`None` without samples).
    pub(super) fn over(index: usize, terms: &TermSeries, idx: &[usize]) -> Option<TrialMean> {
        if idx.is_empty() {
            return None;
        }
        let count = idx.len() as f64;
        let fields = &terms.per_joint;
        let mut mean = TrialMean {
            index,
            t: terms.t.get(idx[0]).copied().unwrap_or(f64::NAN),
            by_joint: [0.0; N_JOINTS],
            by_term: [0.0; 5],
            samples: idx.len(),
        };
        for &i in idx {
            for (k, field) in fields.iter().enumerate() {
                for (j, v) in field[i].iter().enumerate() {
                    mean.by_joint[j] += v / count;
                    mean.by_term[k] += v / count;
                }
            }
            mean.by_term[4] += terms.interaction[i] / count;
        }
        Some(mean)
    }

    /// Each term's and each joint's signed share [%] of the trial's energy turnover
    /// ([`energy_shares`] of the trial alone): within ±100 %, defined for every trial.
    pub(super) fn turnover(&self) -> Shares {
        energy_shares(std::slice::from_ref(self))
    }
}

/// What the bars, the note, the trial log and the link colours take of the model's series,
/// gathered trial by trial as they are logged, in memory bounded whatever the session's length.
#[derive(Debug, Default)]
pub(super) struct ModelStats {
    /// Each trial's mean over its mark's window (trajectory start to post-idle end), in order.
    pub means: Vec<TrialMean>,
    /// The joints' positive powers counted by 0.5 W step (⌈2 P⌉): the colour scale is their
    /// 98th percentile rounded up to 0.5 W, so the counts give it exactly.
    steps: std::collections::BTreeMap<u64, u64>,
    /// The joints' power at most [`LINK_COLOUR_RATE_HZ`] times a second: times and values.
    pub link_t: Vec<f64>,
    pub link_power: Vec<[f64; N_JOINTS]>,
}

impl ModelStats {
    /// Adds one trial's series (sliced as logged).
    pub fn add(&mut self, trial: &crate::trial::TrialWindow, terms: &TermSeries) {
        let fields = &terms.per_joint;
        for (i, &t) in terms.t.iter().enumerate().take(terms.len()) {
            let power: [f64; N_JOINTS] =
                std::array::from_fn(|j| fields.iter().map(|f| f[i][j]).sum());
            for &x in power.iter().filter(|x| x.is_finite() && **x > 0.0) {
                *self.steps.entry((x * 2.0).ceil() as u64).or_default() += 1;
            }
            if self
                .link_t
                .last()
                .is_none_or(|&last| t >= last + 1.0 / LINK_COLOUR_RATE_HZ)
            {
                self.link_t.push(t);
                self.link_power.push(power);
            }
        }
        let (t0, t1) = (trial.t_traj_start, trial.t_post_end);
        let inside: Vec<usize> = (0..terms.len())
            .filter(|&i| terms.t[i] >= t0 && terms.t[i] <= t1)
            .collect();
        self.means
            .extend(TrialMean::over(trial.index, terms, &inside));
    }

    /// The power [W] at which an arm link is drawn fully red: the 98th percentile of the joints'
    /// positive predicted power, rounded up to 0.5 W, at least 1 W.
    pub fn colour_scale(&self) -> f64 {
        let total: u64 = self.steps.values().sum();
        let rank = (total.saturating_sub(1) as f64 * 0.98) as u64;
        let mut below = 0;
        for (&step, &n) in &self.steps {
            if rank < below + n {
                return (step as f64 / 2.0).max(1.0);
            }
            below += n;
        }
        1.0
    }
}

/// `trials` with each one's label followed, on a line of its own, by its two largest terms and
/// its largest joint with their shares of the trial's energy turnover ([`TrialMean::turnover`],
/// the same shares as the per-trial plots and the note's), saying what a negative one means
/// where there is one.
fn with_shares(trials: &[TrialMark], means: &[TrialMean], joints: &[String]) -> Vec<TrialMark> {
    let largest = |v: &[f64], n: usize| {
        let mut k: Vec<usize> = (0..v.len()).collect();
        k.sort_by(|&a, &b| v[b].abs().total_cmp(&v[a].abs()));
        k.truncate(n);
        k
    };
    let names = crate::power::TERM_NAMES;
    trials
        .iter()
        .map(|m| {
            let mut m = m.clone();
            let Some(mean) = means.iter().find(|x| x.index == m.index) else {
                return m;
            };
            let (terms, by_joint) = mean.turnover();
            let mut cells: Vec<(&str, f64)> = (largest(&terms, 2).into_iter())
                .map(|k| (names[k], terms[k]))
                .collect();
            let j = largest(&by_joint, 1);
            cells.extend(
                j.iter()
                    .map(|&j| (joints.get(j).map_or("", String::as_str), by_joint[j])),
            );
            let text: Vec<String> = cells.iter().map(|(n, s)| format!("{n} {s:.0} %")).collect();
            // What a negative share means, on a line of its own: one line held both and ran
            // past the tab's right edge.
            let negative = cells.iter().any(|c| c.1 < 0.0);
            let returned = [
                "",
                "\n  negative: below the rest baseline, or energy returned",
            ];
            m.label = format!(
                "{}\n  share of the energy turnover: {}; {}{}",
                m.label,
                text[..text.len().min(2)].join(", "),
                text[2..].join(""),
                returned[usize::from(negative)],
            );
            m
        })
        .collect()
}

/// Each term's and each joint's signed share [%] of the arm's predicted energy turnover over
/// `means` (the trials' means weighted by their samples; [`crate::power::TERM_NAMES`] order,
/// joint order), by the same computation as `identify`'s shares
/// ([`crate::power::shares_percent`]).
pub(super) fn energy_shares(means: &[TrialMean]) -> (Vec<f64>, Vec<f64>) {
    let mut terms = [0.0; 5];
    let mut joints = [0.0; N_JOINTS];
    for m in means {
        let n = m.samples as f64;
        terms
            .iter_mut()
            .zip(m.by_term)
            .for_each(|(e, v)| *e += v * n);
        joints
            .iter_mut()
            .zip(m.by_joint)
            .for_each(|(e, v)| *e += v * n);
    }
    (
        crate::power::shares_percent(&terms),
        crate::power::shares_percent(&joints),
    )
}

/// The note shown beside the breakdown: what the terms are, what the copper term is relative to.
pub(super) fn breakdown_note(joints: &[String], colour_scale: f64, means: &[TrialMean]) -> String {
    let list: Vec<&str> = joints.iter().map(String::as_str).collect();
    let list = list.join(" → ");
    let (by_term, by_joint) = energy_shares(means);
    let row = |names: &mut dyn Iterator<Item = &str>, shares: &[f64]| {
        let cells: Vec<String> = names
            .zip(shares)
            .map(|(n, s)| format!("{n} **{s:.1} %**"))
            .collect();
        cells.join(" · ")
    };
    format!(
        "**Colours** (the same in every tab): {}.\n\n\
         **Shares** (here, in the per-trial plots and in the trial log alike): a term's or a \
         joint's energy over the energy turnover, the absolute sum of all the terms' or joints' \
         energies — within ±100 %, negative where the part returns energy (mechanical while \
         the arm brakes, copper while it holds less torque than at rest).\n\n\
         **Over the {} trials** (each trial's mean × its length, summed):\n\n\
         by term: {}\n\n\
         by joint: {}\n\n",
        style::colour_key(joints),
        means.len(),
        row(&mut crate::power::TERM_NAMES.iter().copied(), &by_term),
        row(&mut joints.iter().map(String::as_str), &by_joint),
    ) + &format!(
        "**Where the power goes** — the model's predicted net power, split per joint *i* into \
         mechanical *a_i τ_i q̇_i*, copper *b_i (τ_i² − τ̄0_i²)*, Coulomb *c_i \\|q̇_i\\|* and \
         viscous *d_i q̇_i²*, plus the interaction *Σ e_ij \\|q̇_i\\|\\|q̇_j\\|*.\n\n\
         **The copper term is relative to the holding torque τ̄0**: τ̄0_i² is joint *i*'s mean τ² \
         in the trial's pre-idle (the arm at rest), so the term is negative whenever the arm \
         holds less torque than it did at rest — not regeneration.\n\n\
         **Per trial**: each joint's and each term's share of the trial's energy turnover, a \
         group of bars at each trial's index on the x axis (past 20 trials one point per trial \
         at its start), one bar per joint, left to right {list}, or per term, left to right \
         mechanical, copper, Coulomb, viscous, interaction (coloured as in the plots over time; \
         hover a bar for its series).\n\n\
         In 3D each arm link is coloured by its joint's predicted power: grey at 0 W, red at \
         {colour_scale:.1} W and above, blue when negative.",
    )
}

/// σ|ω| per trial as bars over the trial windows (above the threshold in the warning colour),
/// and the threshold as a line.
fn log_imu_filter(w: &mut ChunkWriter<'_>, imu: &ImuFilterMarks) -> Result<()> {
    let bars = |rejected: bool| -> (Vec<f64>, Vec<f64>) {
        let mut t = Vec::new();
        let mut v = Vec::new();
        for &(t0, t1, s) in &imu.spans {
            if (s > imu.threshold) == rejected && s.is_finite() {
                let e = EDGE_S.min(0.05 * (t1 - t0));
                t.extend([t0, t0 + e, t1 - e, t1]);
                v.extend([0.0, s, s, 0.0]);
            }
        }
        (t, v)
    };
    for (rejected, path, name, colour) in [
        (
            false,
            paths::IMU_SIGMA,
            "σ|ω| per trial (the filter's statistic)",
            style::IMU_SIGMA,
        ),
        (
            true,
            paths::IMU_SIGMA_REJECTED,
            "σ|ω| per trial above the threshold: rejected",
            style::WARNING,
        ),
    ] {
        let (t, v) = bars(rejected);
        if t.is_empty() {
            continue;
        }
        style::line_with(w, path, (name, colour, 2.0), AggregationPolicy::Off)?;
        scalars(w, path, &t, v.into_iter())?;
    }
    let first = imu.spans.iter().map(|s| s.0).fold(f64::INFINITY, f64::min);
    let last = imu
        .spans
        .iter()
        .map(|s| s.1)
        .fold(f64::NEG_INFINITY, f64::max);
    if first.is_finite() && last.is_finite() {
        let (path, k) = (paths::IMU_THRESHOLD, imu.k);
        let name = format!("threshold {k} × median σ|ω| = {:.4} rad/s", imu.threshold);
        style::line(w, path, &name, style::THRESHOLD, 2.0)?;
        scalars(w, path, &[first, last], [imu.threshold; 2].into_iter())?;
    }
    Ok(())
}

/// The text of a trial's log entry: its label, and on a line of its own why it was rejected
/// (filter, statistic, threshold) or where a diagnosis located its mismatch (the log's rows
/// grow with their lines, so no line runs past the right edge of the tab).
fn trial_text(m: &TrialMark) -> String {
    match (&m.rejected, &m.highlight) {
        (Some(r), _) => format!("{}\n  REJECTED: {}", m.label, r.why()),
        (None, Some(why)) => format!("{}\n  {why}", m.label),
        (None, None) => m.label.clone(),
    }
}

/// A trial log line's stamp: `t` [s] rounded to 0.1 s.
pub(super) fn log_stamp(t: f64) -> f64 {
    (t * 10.0).round() / 10.0
}

/// The strip of a long session's overview: a point per rejected trial at 1 and per located
/// trial at 2, at the trial's start (`order`: by start).
fn log_strip(w: &mut ChunkWriter<'_>, prefix: &str, order: &[&TrialMark]) -> Result<()> {
    let strip = paths::trial_strip(prefix);
    for (kind, y, colour) in [
        ("rejected", 1.0, style::WARNING),
        ("located", 2.0, style::PREDICTED),
    ] {
        let keep = |m: &TrialMark| match kind {
            "rejected" => m.rejected.is_some(),
            _ => m.highlight.is_some(),
        };
        let t: Vec<f64> = order
            .iter()
            .filter(|m| keep(m))
            .map(|m| m.t_start)
            .collect();
        if t.is_empty() {
            continue;
        }
        let path = format!("{strip}/{kind}");
        let name = format!("{kind} trial");
        style::points(w, &path, &name, colour, MarkerShape::Asterisk, 4.0)?;
        scalars(w, &path, &t, std::iter::repeat_n(y, t.len()))?;
    }
    Ok(())
}

/// Whether the trial is marked (rejected by a filter, or located by a diagnosis).
fn marked(m: &TrialMark) -> bool {
    m.rejected.is_some() || m.highlight.is_some()
}

/// `trials` by start (then index).
fn sorted(trials: &[TrialMark]) -> Vec<&TrialMark> {
    let mut order: Vec<&TrialMark> = trials.iter().collect();
    order.sort_by(|a, b| a.t_start.total_cmp(&b.t_start).then(a.index.cmp(&b.index)));
    order
}

/// A log line per trial of `order` (by start) at its start, under `prefix`.
fn log_trial_log(w: &mut ChunkWriter<'_>, prefix: &str, order: &[&TrialMark]) -> Result<()> {
    if order.is_empty() {
        return Ok(());
    }
    // Stamped at the start rounded to 0.1 s (the trial track keeps the exact start); the viewer
    // sizes the log's time column for short stamps and cuts those past 1000 s, so the layout
    // hides it and each entry opens with its session time.
    let t_log: Vec<f64> = order.iter().map(|m| log_stamp(m.t_start)).collect();
    let texts = order.iter().zip(&t_log);
    let texts: Vec<String> = texts
        .map(|(m, s)| format!("{s:.1} s  {}", trial_text(m)))
        .collect();
    let level = |m: &&TrialMark| [TextLogLevel::INFO, TextLogLevel::WARN][usize::from(marked(m))];
    let levels: Vec<TextLogLevel> = order.iter().map(|m| level(m).into()).collect();
    let columns = TextLog::update_fields()
        .with_many_text(texts)
        .with_many_level(levels)
        .columns_of_unit_batches()?;
    w.send_columns(&paths::trials_log(prefix), &t_log, columns)
}

/// The marks of the trials of `order` (by start): with `index`, the trial track `trials/index`
/// (the trial under way, held until the next one starts); a long session's strip; a thick
/// segment at the trial's index for every marked trial (`<prefix>/<kind>/<k>`, named with its
/// reason and statistic).
fn log_trial_marks(
    w: &mut ChunkWriter<'_>,
    prefix: &str,
    order: &[&TrialMark],
    kind: &str,
    index: bool,
) -> Result<()> {
    if order.is_empty() {
        return Ok(());
    }
    if index {
        w.send_static(
            paths::TRIAL_INDEX,
            &SeriesLines::new()
                .with_names(["trial under way"])
                .with_colors([style::rgb(style::NEUTRAL)])
                .with_widths([1.0])
                .with_interpolation_mode(InterpolationMode::StepAfter),
        )?;
        let t: Vec<f64> = order.iter().map(|m| m.t_start).collect();
        scalars(
            w,
            paths::TRIAL_INDEX,
            &t,
            order.iter().map(|m| m.index as f64),
        )?;
    }
    log_strip(w, prefix, order)?;
    for m in order.iter().filter(|m| marked(m)) {
        let path = paths::trial_span(prefix, kind, m.index);
        style::line(w, &path, &trial_text(m), style::WARNING, 6.0)?;
        let index = [m.index as f64; 2].into_iter();
        scalars(w, &path, &[m.t_start, m.t_end], index)?;
    }
    Ok(())
}

/// A series to log: its path, name, colour, `Some(size)` for circles of that size (`None`: a
/// line), and its values.
type Styled = (String, String, [u8; 3], Option<f32>, Vec<f64>);

/// Logs each of `series` with its style at `t`, in chunks; one that is empty or not as long as
/// `t` is left out.
fn log_styled(w: &mut ChunkWriter<'_>, t: &[f64], series: Vec<Styled>, chunk: usize) -> Result<()> {
    for (path, name, colour, dots, v) in series {
        if v.len() != t.len() || v.is_empty() {
            continue;
        }
        match dots {
            Some(size) => style::points(w, &path, &name, colour, MarkerShape::Circle, size)?,
            None => style::line(w, &path, &name, colour, 1.5)?,
        }
        scalars_chunked(w, &path, t, &v, chunk)?;
    }
    Ok(())
}

/// The diagnosis: measured vs before/after (and the twin), their errors, the located trials,
/// the torque differences and the summary.
fn log_diagnosis(
    w: &mut ChunkWriter<'_>,
    joints: &[String],
    d: &DiagnosisOverlay,
    chunk: usize,
) -> Result<()> {
    let r = &d.data;
    // Each marked trial's energy shares in the log, as in a model replay's.
    let marks = &with_shares(&d.highlighted, &reading_means(r), joints);
    let order = sorted(marks);
    log_trial_log(w, paths::DIAG_TRIALS, &order)?;
    log_trial_marks(w, paths::DIAG_TRIALS, &order, "located", false)?;
    let err = |p: &[f64]| -> Vec<f64> { r.measured_w.iter().zip(p).map(|(m, p)| m - p).collect() };
    let s = |path: &str, name: &str, colour, dots, v: Vec<f64>| {
        (path.into(), name.into(), colour, dots, v)
    };
    #[rustfmt::skip]
    let mut series: Vec<Styled> = vec![
        s(paths::DIAG_MEASURED, "measured reading (net)", style::MEASURED, Some(3.0), r.measured_w.clone()),
        s(paths::DIAG_BEFORE, "base model", style::NEUTRAL, None, r.before_w.clone()),
        s(paths::DIAG_AFTER, "with accepted hypotheses", style::PREDICTED, None, r.after_w.clone()),
        s(paths::DIAG_ERROR_BEFORE, "error, base model", style::NEUTRAL, Some(2.5), err(&r.before_w)),
        s(paths::DIAG_ERROR_AFTER, "error, with hypotheses", style::ERROR, Some(2.5), err(&r.after_w)),
        s(paths::DIAG_FOUND, "with terms found beyond the library", style::WARNING, None, r.found_w.clone()),
        s(paths::DIAG_ERROR_FOUND, "error with found terms", style::WARNING, Some(2.5), err(&r.found_w)),
        s(paths::DIAG_REST_MEASURED, "rest power of the trial (pre-idle mean)", style::MEASURED, None, r.rest_w.clone()),
        s(paths::DIAG_REST_FOUND, "with the loads found on it (held out)", style::WARNING, None, r.rest_found_w.clone()),
    ];
    for (k, f) in r.located.iter().enumerate() {
        let path = paths::diag_located(k);
        series.push(s(&path, &f.name, style::joint(k), None, f.values.clone()));
    }
    // A drifting meter window: its width at each reading beside the scan's one window.
    if let Some(sw) = &d.window {
        let [drifting, fixed] =
            ["drifting", "fixed"].map(|k| format!("{}/{k}", paths::DIAG_WINDOW));
        let name = format!("the meter's window, {:+.3} s over the session", sw.drift_s);
        let widths = r.t.iter().map(|&t| sw.window_at(t)).collect();
        series.push(s(&drifting, &name, style::WARNING, None, widths));
        let one = "one window (the alignment scan's)";
        series.push(s(
            &fixed,
            one,
            style::NEUTRAL,
            None,
            vec![sw.scan_window_s; r.t.len()],
        ));
    }
    log_styled(w, &r.t, series, chunk)?;
    if let Some(cp) = &d.counterpart {
        let twin = s(
            paths::DIAG_TWIN,
            "twin on the same commands",
            style::MBS,
            None,
            cp.power_w.clone(),
        );
        log_styled(w, &cp.power_t, vec![twin], chunk)?;
        let torque = joints.iter().enumerate().map(|(j, name)| {
            let v = cp.tau_diff.iter().map(|x| x[j]).collect();
            s(
                &paths::diag_torque(name),
                &format!("{name} τ recording − twin"),
                style::joint(j),
                None,
                v,
            )
        });
        log_styled(w, &cp.tau_t, torque.collect(), chunk)?;
    }
    w.send_static(
        paths::DIAG_SUMMARY,
        &TextDocument::from_markdown(d.summary.clone()),
    )
}
