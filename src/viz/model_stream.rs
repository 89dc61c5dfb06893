//! The model replay of a session file in bounded memory (`replay --model`): the model's overlay
//! comes from the streamed validation ([`crate::identify::validate_file`]: readings, trials,
//! rejections, each trial's copper baseline), and the per-sample series (instantaneous
//! prediction, loss terms) are never held whole. The file is read once more for their
//! statistics (per-trial bars, the link colours at 10 Hz and the
//! histogram behind the colour scale), once for the replay itself, and once to log the series
//! trial by trial ([`crate::session::for_each_trial_with_batches`]). Every figure equals the one of
//! the in-memory replay ([`super::overlay::model_extras`]) computed from the whole series.
//!
//! Memory: the replay waits for the `.rrd` sink every [`REPLAY_FLUSH_SAMPLES`](super::replay::REPLAY_FLUSH_SAMPLES) samples (chunks
//! are built far faster than they are encoded), and logs in chunks of at least
//! [`STREAMED_CHUNK_ROWS`](super::replay::STREAMED_CHUNK_ROWS) samples (the file's footer indexes every chunk until the end).

use std::collections::BTreeMap;

use anyhow::{Context, Result};
use rerun::RecordingStream;

use super::TrialMean;
use super::overlay::trial_series;
use super::replay::{
    LINK_COLOUR_RATE_HZ, PowerPrediction, ReplayExtras, ReplayOptions, ReplaySummary,
    STREAMED_CHUNK_ROWS, SampleStats, StreamedReplay, TermSeries,
};
use super::slice::{Decimator, Slice};
use crate::N_JOINTS;
use crate::identify::Validation;
use crate::power::PowerModel;
use crate::robot::{ArmJoints, RobotModel};
use crate::session::{SessionFile, for_each_trial_with_batches};
use crate::signals::{Recording, StateSeries};
use crate::trial::TrialWindow;

/// The usable trials of a validation (those with a copper baseline), in session order, with it.
pub(super) fn planned(v: &Validation) -> Vec<(TrialWindow, [f64; N_JOINTS])> {
    // Indexed once: a linear search per baseline is quadratic in trials (~1e6 steps at paper scale).
    let mut by_index: BTreeMap<_, &TrialWindow> = BTreeMap::new();
    for t in &v.session.segmentation.trials {
        by_index.entry(t.index).or_insert(t); // the first, as a search would find
    }
    v.baselines
        .iter()
        .filter_map(|b| Some(((*by_index.get(&b.trial)?).clone(), b.tau0_sq)))
        .collect()
}

/// The model's series over one trial, sliced (`dec` carries the rate cap across trials, as one
/// decimator over the concatenated series of the in-memory replay does).
fn sliced_series(
    state: &StateSeries,
    trial: &TrialWindow,
    tau0_sq: &[f64; N_JOINTS],
    model: &PowerModel,
    slice: &Slice,
    dec: &mut Decimator,
) -> (PowerPrediction, TermSeries) {
    let mut p = PowerPrediction::default();
    let mut terms = TermSeries::default();
    trial_series(state, trial, tau0_sq, model, &mut p, &mut terms);
    if slice.is_all() {
        return (p, terms);
    }
    let k = slice.keep(&p.t, dec);
    (p.pick(&k), terms.pick(&k))
}

/// Per-joint power of sample `i` (the joint's four terms summed, as the in-memory replay sums).
fn joint_power(terms: &TermSeries, i: usize) -> [f64; N_JOINTS] {
    let fields = terms.fields();
    std::array::from_fn(|j| fields.iter().map(|f| f[i][j]).sum())
}

/// Bucket of a positive power in the colour-scale histogram: the top bits of its IEEE pattern
/// (monotone in the value for positive numbers; ~0.4 % wide).
fn bucket(x: f64) -> u64 {
    x.to_bits() >> 44
}

/// Whether a joint power counts for the colour scale (as in the in-memory replay).
fn counts(x: f64) -> bool {
    x.is_finite() && x > 0.0
}

/// Statistics of the sliced series, accumulated trial by trial.
#[derive(Default)]
struct Accumulator {
    means: Vec<TrialMean>,
    histogram: BTreeMap<u64, u64>,
    link_t: Vec<f64>,
    link_power: Vec<[f64; N_JOINTS]>,
    next_link: Option<f64>,
}

impl Accumulator {
    fn add(&mut self, trial: &TrialWindow, terms: &TermSeries) {
        for i in 0..terms.t.len() {
            let power = joint_power(terms, i);
            for &x in power.iter().filter(|&&x| counts(x)) {
                *self.histogram.entry(bucket(x)).or_default() += 1;
            }
            let t = terms.t[i];
            if self.next_link.is_none_or(|next| t >= next) {
                self.link_t.push(t);
                self.link_power.push(power);
                self.next_link = Some(t + 1.0 / LINK_COLOUR_RATE_HZ);
            }
        }
        self.add_mean(trial, terms);
    }

    /// The trial's mean power per joint and per term over its mark's window (trajectory start
    /// to post-idle end), summed in the in-memory replay's order.
    fn add_mean(&mut self, trial: &TrialWindow, terms: &TermSeries) {
        let (t0, t1) = (trial.t_traj_start, trial.t_post_end);
        let inside: Vec<usize> = (0..terms.t.len())
            .filter(|&i| terms.t[i] >= t0 && terms.t[i] <= t1)
            .collect();
        self.means
            .extend(TrialMean::over(trial.index, terms, &inside));
    }

    /// The statistics, and where the colour scale's 98th percentile lies (its histogram bucket
    /// and rank inside it; `None` without positive power).
    fn finish(self) -> (SampleStats, Option<(u64, usize)>) {
        let total: u64 = self.histogram.values().sum();
        let mut target = None;
        if total > 0 {
            let rank = ((total - 1) as f64 * 0.98) as u64;
            let mut below = 0u64;
            for (&b, &n) in &self.histogram {
                if rank < below + n {
                    target = Some((b, (rank - below) as usize));
                    break;
                }
                below += n;
            }
        }
        let (mut link_t, mut link_power) = (self.link_t, self.link_power);
        link_t.shrink_to_fit();
        link_power.shrink_to_fit();
        let stats = SampleStats {
            means: self.means,
            colour_scale: 1.0,
            link_power: (link_t, link_power),
        };
        (stats, target)
    }
}

/// A model replay of a session file, streamed.
pub(super) struct StreamedModel<'a> {
    /// The session.
    pub file: &'a SessionFile,
    /// The model.
    pub model: &'a PowerModel,
    /// The usable trials with their copper baselines ([`planned`]).
    pub plan: &'a [(TrialWindow, [f64; N_JOINTS])],
    /// The replay's options (slice, chunking, stream tuning).
    pub opts: &'a ReplayOptions,
}

impl StreamedModel<'_> {
    /// Read the file once, calling `each` with every planned trial's sliced series.
    fn pass(
        &self,
        each: &mut dyn FnMut(&TrialWindow, &PowerPrediction, &TermSeries) -> Result<()>,
    ) -> Result<()> {
        let windows: Vec<TrialWindow> = self.plan.iter().map(|(t, _)| t.clone()).collect();
        let mut dec = Decimator::default();
        let mut next = 0usize;
        for_each_trial_with_batches(
            self.file,
            &windows,
            self.opts.stream.batch_samples,
            &mut |_| {},
            &mut |rec: &Recording, t: &TrialWindow| {
                // The trials come in plan order.
                let tau0 = self.plan[next].1;
                next += 1;
                let (p, terms) =
                    sliced_series(&rec.state, t, &tau0, self.model, &self.opts.slice, &mut dec);
                each(t, &p, &terms)
            },
        )
        .with_context(|| format!("reading {}", self.file.path.display()))
    }

    /// The statistics pass: what the bars and the link colours need.
    pub(super) fn stats(&self) -> Result<(SampleStats, Option<(u64, usize)>)> {
        let mut acc = Accumulator::default();
        self.pass(&mut |t, _, terms| {
            acc.add(t, terms);
            Ok(())
        })?;
        Ok(acc.finish())
    }

    /// The replay: the session's samples, then the model's series trial by trial, then the
    /// power series and the overlays of `extras` (whose `sample_stats` come from
    /// [`Self::stats`]; `colour` is the colour scale's bucket and rank from it).
    pub(super) fn replay(
        &self,
        robot: &RobotModel,
        arm: &ArmJoints,
        mut extras: ReplayExtras,
        colour: Option<(u64, usize)>,
        stream: &RecordingStream,
    ) -> Result<ReplaySummary> {
        let quiet = ReplayOptions {
            progress: false,
            chunk_rows: self.opts.chunk_rows.max(STREAMED_CHUNK_ROWS),
            ..self.opts.clone()
        };
        let mut sink = StreamedReplay::new(stream, robot, arm, &quiet, &extras);
        crate::signals::stream_into(
            &self.file.path,
            &self.file.map,
            &self.file.read,
            quiet.chunk_rows,
            &mut sink,
        )
        .with_context(|| format!("replaying {}", self.file.path.display()))?;
        let mut warnings = std::mem::take(&mut sink.warnings);
        let mut logger = sink.logger.context("the recording delivered no samples")?;
        let mut in_bucket = Vec::new();
        self.pass(&mut |_, p, terms| {
            if let Some((b, _)) = colour {
                for i in 0..terms.t.len() {
                    in_bucket.extend(
                        joint_power(terms, i)
                            .into_iter()
                            .filter(|&x| counts(x) && bucket(x) == b),
                    );
                }
            }
            logger.log_model_samples(p, terms)
        })?;
        if let (Some((_, rank)), Some(stats)) = (colour, extras.sample_stats.as_mut()) {
            in_bucket.sort_by(f64::total_cmp);
            if let Some(&q) = in_bucket.get(rank) {
                stats.colour_scale = ((q * 2.0).ceil() / 2.0).max(1.0);
            }
        }
        let mut summary = logger.finish(&extras)?;
        warnings.append(&mut summary.warnings);
        summary.warnings = warnings;
        Ok(summary)
    }
}
