//! `g1viz identify`: the paper's identification as a short sequence of named stages —
//! segment → IMU filter → sensor timing → rows → constrained fit with n·σ rejection → the three
//! row pairings compared → per-trial table — on one or more recordings.
//!
//! The rows are per trial (the paper), per power reading (default; many more rows, each aligned
//! with the sensor's own averaging window) or per sample (degenerate, for comparison). The trial
//! and sample pairings are also fitted on the same retained trials, with κ(ΦᵀΦ) and R² of each,
//! reproducing the paper's case for aggregation.

use std::cell::RefCell;
use std::collections::HashSet;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

use super::dataset::{
    self, Alignment, AlignmentEstimate, Dataset, DatasetOptions, Mode, Row, Skipped,
};
use super::fit::{fit_normal, fit_rows, kappa, quality, term_means, trial_residuals};
use super::sample::{self, SampleSums};
use super::sets::{RowPlan, SessionSets};
use super::table::{TrialPrediction, trial_metrics, trial_predictions};
use crate::lsq::{Gram, Metrics, MetricsAccumulator, SolverInfo};
use crate::power::{LossTerm, PowerModel, TermMeans};
use crate::session::{
    self, FileTrials, Memory, SEARCH_TRIALS, SessionFile, StreamOptions, TrialSource, search_stride,
};
use crate::signals::{Recording, Target};
use crate::trial::{
    self, Cascade, RejectReason, Rejection, SegmentOptions, Segmentation, TrialStat, TrialWindow,
};
use crate::{N_JOINTS, N_PARAMS};

/// Sensor timing for the per-reading rows.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum AlignmentChoice {
    /// Estimate W and lag from the data ([`dataset::estimate_alignment`]).
    Auto,
    /// Use the given timing.
    Given(Alignment),
}

/// Options of [`identify`] and [`super::validate`].
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct IdentifyOptions {
    /// Power sensor (`--target mbs|bms`).
    pub target: Target,
    /// Row pairing (`--mode trial|reading|sample`).
    pub mode: Mode,
    /// Segmenter tuning.
    pub segment: SegmentOptions,
    /// The IMU filter and the residual-rejection passes.
    pub filters: Cascade,
    /// Power-sensor window and lag.
    pub alignment: AlignmentChoice,
    /// Most trials the sensor-timing search uses ([`search_stride`]; default
    /// [`SEARCH_TRIALS`]).
    pub search_trials: usize,
}

impl Default for IdentifyOptions {
    fn default() -> Self {
        IdentifyOptions {
            target: Target::Mbs,
            mode: Mode::Reading,
            segment: SegmentOptions::default(),
            filters: Cascade::default(),
            alignment: AlignmentChoice::Auto,
            search_trials: SEARCH_TRIALS,
        }
    }
}

/// One row pairing fitted on the retained trials: the paper's aggregation argument in numbers.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ModeFit {
    /// Pairing.
    pub mode: Mode,
    /// Condition number κ(ΦᵀΦ) of the raw (unscaled) regressors; ∞ when rank-deficient.
    pub kappa: f64,
    /// Fit quality of that pairing's own constrained fit, on its own rows.
    pub quality: Metrics,
}

/// What happened to one input session.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct SessionSummary {
    /// File.
    pub source: PathBuf,
    /// Trials and unmatched stretches.
    pub segmentation: Segmentation,
    /// Trials without rows and why.
    pub skipped: Vec<Skipped>,
    /// Winding temperatures of the session's first joint-state sample [°C].
    #[serde(default)]
    pub first_temp_c: Option<[f64; N_JOINTS]>,
    /// Problems met while reading a streamed session.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// One session's share of a (multi-session) identification.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SessionBreakdown {
    /// File.
    pub source: PathBuf,
    /// Trials the segmenter found.
    pub trials: usize,
    /// Trials retained for the final fit.
    pub used: usize,
    /// Trials a filter rejected (IMU, residual).
    pub rejected: usize,
    /// Trials without rows (no baseline, no reading).
    pub without_rows: usize,
    /// The final model on the session's retained trials, one row per power reading.
    pub reading: Metrics,
    /// Winding temperatures of the session's first joint-state sample [°C].
    pub first_temp_c: Option<[f64; N_JOINTS]>,
}

/// Result of [`identify`].
#[derive(Debug, Clone, serde::Serialize)]
pub struct Identification {
    /// The identified parameters.
    pub model: PowerModel,
    /// Options used.
    pub options: IdentifyOptions,
    /// Per input session: segmentation and skipped trials.
    pub sessions: Vec<SessionSummary>,
    /// Sensor timing used for rows and baselines.
    pub alignment: Alignment,
    /// The timing search (when `AlignmentChoice::Auto`).
    pub alignment_estimate: Option<AlignmentEstimate>,
    /// Every rejected trial, filter by filter.
    pub rejections: Vec<Rejection>,
    /// Trials retained for the final fit.
    pub trials_used: usize,
    /// Fit quality of the final fit on its rows (mode of the options).
    pub fit: Metrics,
    /// The final model at trial level on the retained trials, the paper's way: φ averaged over
    /// the whole trajectory window vs the mean of the readings in it.
    pub trial_level: Metrics,
    /// The final model at trial level on the retained trials, like for like: prediction averaged
    /// over the readings' own windows vs the mean of the readings.
    pub trial_level_aligned: Metrics,
    /// Trial, reading and sample pairings fitted on the retained trials (κ, R²).
    pub modes: Vec<ModeFit>,
    /// Dominant loss term per joint (argmax of b, c, d; None when all are zero).
    pub dominant: Vec<Option<LossTerm>>,
    /// Mean term contributions on the retained trials' trajectory windows.
    #[serde(skip)]
    pub terms: TermMeans,
    /// Their signed shares [%] of the energy turnover ([`crate::power::shares_percent`]; mechanical,
    /// copper, Coulomb, viscous, interaction).
    pub shares_percent: [f64; 5],
    /// Standard error of each parameter of the final fit (None: at a bound or not excited).
    pub std_err: Vec<Option<f64>>,
    /// Solver of the final fit.
    pub solver: SolverInfo,
    /// Per-trial measured vs predicted (all trials with rows, rejected ones flagged).
    pub per_trial: Vec<TrialPrediction>,
    /// Per input session: trials used and rejected, per-reading fit, start temperatures.
    pub per_session: Vec<SessionBreakdown>,
}

/// One session segmented by the segmentation pass ([`crate::session`]): its trials, σ_ω of each,
/// the joint states the sensor-timing search reads, and the source of each trial's samples.
pub(crate) struct Prepared<'a> {
    /// What the segmentation pass found (its held trials: the timing search's).
    pub pass: session::Pass1,
    /// Each trial's samples: the file (its spill, else a ranged read) or the recording in memory.
    trials: RefCell<Box<dyn TrialSource + 'a>>,
}

impl<'a> Prepared<'a> {
    fn new(pass: session::Pass1, trials: Box<dyn TrialSource + 'a>) -> Prepared<'a> {
        let trials = RefCell::new(trials);
        Prepared { pass, trials }
    }

    /// Segment a recording in memory (the segmentation pass fed its batches).
    pub(crate) fn from_recording(
        rec: &'a Recording,
        opts: &SegmentOptions,
        so: StreamOptions,
    ) -> Result<Prepared<'a>> {
        let p1 = session::segment_recording(rec, opts, &so)?;
        Ok(Prepared::new(p1, Box::new(Memory(rec))))
    }

    /// Segment a file in one streamed pass.
    pub(crate) fn from_file(
        file: SessionFile,
        opts: &SegmentOptions,
        so: StreamOptions,
    ) -> Result<Prepared<'static>> {
        let p1 = session::segmentation_pass(&file, opts, &so)
            .with_context(|| format!("reading {}", file.path.display()))?;
        let clock = session::clock_of(&p1.held);
        Ok(Prepared::new(p1, Box::new(FileTrials { file, clock })))
    }

    /// The planned rows of this session (a second streamed pass for a file).
    pub(crate) fn rows(&self, plan: &RowPlan) -> Result<SessionSets> {
        let mut sets = SessionSets::default();
        self.for_each_trial(plan.trials, "rows", &mut |rec, t| {
            sets.add_trial(rec, t, plan);
            Ok(())
        })?;
        Ok(sets)
    }

    /// Call `on_trial` for each of `trials` (in time order) with a recording holding at least
    /// that trial's window and the power series, from the session's [`TrialSource`] (`what`
    /// names the pass in an error).
    fn for_each_trial(
        &self,
        trials: &[TrialWindow],
        what: &str,
        on_trial: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
    ) -> Result<()> {
        self.trials
            .borrow_mut()
            .for_each(trials, on_trial)
            .with_context(|| format!("{} ({what})", self.pass.source.display()))
    }

    /// After the timing search: a streamed session keeps only the power series and the clock of
    /// its held joint states.
    pub(crate) fn release_subset(&mut self) {
        self.pass.held.state = Default::default();
    }

    pub(crate) fn no_usable_trials(&self, skipped: &[Skipped]) -> anyhow::Error {
        let p = &self.pass;
        no_usable_trials(&p.source, p.has_state, &p.seg, skipped)
    }

    /// The session's summary, with its trials without rows (`skipped`).
    pub(crate) fn summary(self, skipped: Vec<Skipped>) -> SessionSummary {
        let p = self.pass;
        SessionSummary {
            source: p.source,
            segmentation: p.seg,
            skipped,
            first_temp_c: p.first_temp_c,
            warnings: p.warnings,
        }
    }
}

/// The part of `d` that belongs to `trials` (same as building `d` on those trials only: every
/// trial's rows depend on that trial alone).
pub(crate) fn restrict(d: &Dataset, trials: &[TrialWindow]) -> Dataset {
    let keep: HashSet<usize> = trials.iter().map(|t| t.index).collect();
    Dataset {
        rows: sample::of_trials(&d.rows, &keep, |r| r.trial),
        trials: sample::of_trials(&d.trials, &keep, |b| b.trial),
        skipped: sample::of_trials(&d.skipped, &keep, |s| s.trial),
    }
}

/// Explain why a session gave no rows.
pub(crate) fn no_usable_trials(
    source: &Path,
    has_state: bool,
    seg: &Segmentation,
    skipped: &[Skipped],
) -> anyhow::Error {
    let mut why: Vec<String> = Vec::new();
    if seg.trials.is_empty() {
        why.push(format!(
            "no trial matched the protocol in the {} stream",
            if seg.source.is_empty() {
                "(empty)"
            } else {
                &seg.source
            }
        ));
    }
    why.extend(
        seg.unmatched
            .iter()
            .take(5)
            .map(|s| format!("{:.2}–{:.2} s: {}", s.t0, s.t1, s.reason)),
    );
    why.extend(
        skipped
            .iter()
            .take(5)
            .map(|s| format!("trial {}: {}", s.trial, s.reason)),
    );
    if !has_state {
        why.push("no joint-state samples".into());
    }
    anyhow::anyhow!(
        "no usable trials in {}: {}",
        source.display(),
        why.join("; ")
    )
}

/// σ_ω of every trial of every session, the IMU filter's statistic.
fn imu_statistics(sessions: &[Prepared]) -> Vec<TrialStat> {
    sessions
        .iter()
        .enumerate()
        .flat_map(|(s, p)| {
            p.pass
                .seg
                .trials
                .iter()
                .zip(&p.pass.sigmas)
                .map(move |(t, &sigma)| TrialStat::new(s, t.index, sigma))
        })
        .collect()
}

/// Each session's trials that no rejection names.
fn trials_kept(sessions: &[Prepared], rejections: &[Rejection]) -> Vec<Vec<TrialWindow>> {
    sessions
        .iter()
        .enumerate()
        .map(|(s, p)| {
            p.pass
                .seg
                .trials
                .iter()
                .filter(|t| !trial::is_rejected(rejections, s, t.index))
                .cloned()
                .collect()
        })
        .collect()
}

/// Stage 3: the power sensor's window and lag, given or estimated from at most
/// [`IdentifyOptions::search_trials`] trials: every s-th trial of each session
/// ([`search_stride`]) that the IMU filter keeps. The segmentation pass holds those trials'
/// samples; if it could not ([`StreamOptions::hold_trials`] below the search's cap), they are
/// read in one more pass over the trial source ([`session::hold_pass`]).
pub(crate) fn resolve_alignment(
    sessions: &[Prepared],
    kept: &[Vec<TrialWindow>],
    opts: &IdentifyOptions,
) -> Result<(Alignment, Option<AlignmentEstimate>)> {
    match opts.alignment {
        AlignmentChoice::Given(a) => Ok((a, None)),
        AlignmentChoice::Auto => {
            let counts: Vec<usize> = sessions.iter().map(|p| p.pass.seg.trials.len()).collect();
            let stride = search_stride(&counts, opts.search_trials);
            let thinned: Vec<Vec<TrialWindow>> = kept
                .iter()
                .map(|t| {
                    t.iter()
                        .filter(|t| t.index.is_multiple_of(stride))
                        .cloned()
                        .collect()
                })
                .collect();
            let mut loaded: Vec<Option<Recording>> = Vec::new();
            for (p, t) in sessions.iter().zip(&thinned) {
                let held: HashSet<usize> = p.pass.held_trials.iter().map(|t| t.index).collect();
                loaded.push(match t.iter().all(|t| held.contains(&t.index)) {
                    true => None,
                    false => Some(
                        session::hold_pass(
                            &mut **p.trials.borrow_mut(),
                            session::clock_of(&p.pass.held),
                            t,
                            session::copy_window,
                        )
                        .with_context(|| {
                            format!("reading {} (timing search)", p.pass.source.display())
                        })?,
                    ),
                });
            }
            let pairs: Vec<(&Recording, &[TrialWindow])> = sessions
                .iter()
                .zip(&thinned)
                .zip(&loaded)
                .map(|((p, t), l)| (l.as_ref().unwrap_or(&p.pass.held), t.as_slice()))
                .collect();
            let est = dataset::estimate_alignment(&pairs, opts.target)?;
            Ok((est.best, Some(est)))
        }
    }
}

/// The sample-row stride of the pairing comparison: at most `SAMPLE_ROWS_MAX` rows over the
/// given trials' trajectory windows (at 100 Hz).
fn sample_stride(trials: &[Vec<TrialWindow>]) -> usize {
    // Sample rows of a paper-scale session would take ~0.5 GB (1e6 × 49 f64): the comparison
    // thins them trial by trial, which keeps the zero-order-hold structure that makes them
    // degenerate.
    const SAMPLE_ROWS_MAX: f64 = 100_000.0;
    let traj_seconds: f64 = trials
        .iter()
        .flatten()
        .map(|t| t.t_post_end - t.t_traj_start)
        .sum();
    ((traj_seconds * 100.0 / SAMPLE_ROWS_MAX).ceil() as usize).max(1)
}

/// Stage 4a: every session's rows (reading and trial rows of every trial; sample rows of the
/// kept trials, thinned, and all of them when the fit is per sample).
fn session_rows(
    sessions: &[Prepared],
    kept: &[Vec<TrialWindow>],
    opts: &IdentifyOptions,
    alignment: Alignment,
) -> Result<Vec<SessionSets>> {
    let stride = sample_stride(kept);
    sessions
        .iter()
        .zip(kept)
        .map(|(p, k)| {
            let kept_idx: Vec<usize> = k.iter().map(|t| t.index).collect();
            let plan = RowPlan {
                target: opts.target,
                alignment,
                trials: &p.pass.seg.trials,
                // The sample pairing's comparison, thinned now; a per-sample fit scores its own
                // rows instead.
                sample_trials: if opts.mode != Mode::Sample {
                    &kept_idx
                } else {
                    &[]
                },
                sample_stride: stride,
                full_sample_trials: if opts.mode == Mode::Sample {
                    &kept_idx
                } else {
                    &[]
                },
            };
            p.rows(&plan)
        })
        .collect()
}

/// What the final fit is made of, one entry per session.
enum FitInput {
    /// Rows of the trial or reading pairing.
    Rows(Vec<Dataset>),
    /// The sample rows reduced to per-trial statistics (`--mode sample`).
    Sums(Vec<SampleSums>),
}

impl FitInput {
    /// Each session's trials without rows.
    fn into_skipped(self) -> Vec<Vec<Skipped>> {
        match self {
            FitInput::Rows(sets) => sets.into_iter().map(|d| d.skipped).collect(),
            FitInput::Sums(sets) => sets.into_iter().map(|d| d.skipped).collect(),
        }
    }

    /// The normal equations of the trials no rejection names (statistics only).
    fn gram_kept(&self, rej: &[Rejection]) -> Gram {
        let mut g = Gram::zeros(N_PARAMS);
        if let FitInput::Sums(sets) = self {
            not_rejected(sets, |d| &d.sums, |t| t.trial, rej).for_each(|(_, t)| t.add_to(&mut g));
        }
        g
    }

    /// The mean residual of θ over each trial no rejection names, session by session.
    fn residuals(&self, theta: &[f64; N_PARAMS], rej: &[Rejection]) -> Vec<TrialStat> {
        match self {
            FitInput::Rows(sets) => {
                trial_residuals(theta, not_rejected(sets, |d| &d.rows, |r| r.trial, rej))
            }
            FitInput::Sums(sets) => not_rejected(sets, |d| &d.sums, |t| t.trial, rej)
                .map(|(s, t)| TrialStat::new(s, t.trial, t.mean_residual(theta)))
                .collect(),
        }
    }
}

/// The items (`of` each session's set) of the trials no rejection names, with their session.
fn not_rejected<'a, S, T: 'a>(
    sets: &'a [S],
    of: impl Fn(&'a S) -> &'a [T] + 'a,
    trial_of: impl Fn(&T) -> usize + Copy + 'a,
    rej: &'a [Rejection],
) -> impl Iterator<Item = (usize, &'a T)> + 'a {
    sets.iter().enumerate().flat_map(move |(s, set)| {
        let kept = (of(set).iter()).filter(move |x| !trial::is_rejected(rej, s, trial_of(x)));
        kept.map(move |x| (s, x))
    })
}

/// Stage 4b: the rows of the options' pairing on the kept trials, one data set per session
/// (per-trial statistics of the sample rows in sample mode).
fn build_sets(
    sessions: &[Prepared],
    rows: &[SessionSets],
    kept: &[Vec<TrialWindow>],
    opts: &IdentifyOptions,
) -> Result<FitInput> {
    let per_session = sessions.iter().zip(rows).zip(kept);
    // A session whose kept trials give no row is an error naming why.
    let usable = |p: &Prepared, trials: &[TrialWindow], rowless: bool, skipped: &[Skipped]| {
        if rowless && !trials.is_empty() {
            return Err(p.no_usable_trials(skipped));
        }
        Ok(())
    };
    if opts.mode == Mode::Sample {
        let sets = per_session.map(|((p, r), trials)| {
            let keep: HashSet<usize> = trials.iter().map(|t| t.index).collect();
            let d = r.sample_sums.restrict(&keep);
            usable(p, trials, d.sums.is_empty(), &d.skipped).map(|()| d)
        });
        return Ok(FitInput::Sums(sets.collect::<Result<_>>()?));
    }
    let sets = per_session.map(|((p, r), trials)| {
        let all = if opts.mode == Mode::Trial {
            &r.trial
        } else {
            &r.reading
        };
        let d = restrict(all, trials);
        usable(p, trials, d.rows.is_empty(), &d.skipped).map(|()| d)
    });
    Ok(FitInput::Rows(sets.collect::<Result<_>>()?))
}

/// Result of stage 5.
struct FinalFit {
    fit: crate::lsq::Fit,
    theta: [f64; N_PARAMS],
    /// The rows fitted (none for a fit of per-trial statistics).
    rows: Vec<Row>,
}

/// Stage 5: the constrained fit with iterative n·σ rejection by trial (each pass refits without
/// the trials rejected so far), then the final fit on what remains.
fn fit_with_rejection(
    input: &FitInput,
    rejections: &mut Vec<Rejection>,
    opts: &IdentifyOptions,
) -> Result<FinalFit> {
    let min_rows = if opts.mode == Mode::Trial {
        1
    } else {
        N_PARAMS
    };
    let fit_kept = |rej: &[Rejection]| -> Result<(crate::lsq::Fit, Vec<Row>, usize)> {
        let after_residual_rejection = rej.iter().any(|r| r.reason == RejectReason::Residual);
        let check = |n: usize| {
            if after_residual_rejection && n < min_rows {
                bail!("residual rejection left {n} rows, too few to fit");
            }
            Ok(())
        };
        match input {
            FitInput::Rows(sets) => {
                let kept = not_rejected(sets, |d| &d.rows, |r| r.trial, rej);
                let rows: Vec<Row> = kept.map(|(_, r)| r.clone()).collect();
                check(rows.len())?;
                let (fit, _) = fit_rows(&rows).context("constrained least squares")?;
                let n = rows.len();
                Ok((fit, rows, n))
            }
            FitInput::Sums(_) => {
                let normal = input.gram_kept(rej);
                check(normal.n)?;
                let fit = fit_normal(&normal).context("constrained least squares")?;
                Ok((fit, Vec::new(), normal.n))
            }
        }
    };
    opts.filters.residual_passes(rejections, |rej| {
        let (fit, _, _) = fit_kept(rej)?;
        let theta = fit.theta49()?;
        Ok::<_, anyhow::Error>(input.residuals(&theta, rej))
    })?;
    let (fit, rows, n) = fit_kept(rejections)?;
    if n == 0 {
        bail!("no rows left after filtering");
    }
    let theta = fit.theta49()?;
    Ok(FinalFit { fit, theta, rows })
}

/// Stage 5b: κ(ΦᵀΦ) and the fit quality of the final fit on its own rows. A per-sample fit was
/// made from per-trial statistics: its κ comes from their sum, and the retained trials' sample
/// rows are built once more (a streamed pass for a file) and scored one at a time.
fn final_scores(
    sessions: &[Prepared],
    input: &FitInput,
    final_fit: &FinalFit,
    rejections: &[Rejection],
    retained: &[Vec<TrialWindow>],
    opts: &IdentifyOptions,
    alignment: Alignment,
) -> Result<(f64, Metrics)> {
    if let FitInput::Rows(_) = input {
        return Ok((
            kappa(&final_fit.rows),
            quality(&final_fit.theta, &final_fit.rows),
        ));
    }
    let dopts = DatasetOptions {
        mode: Mode::Sample,
        target: opts.target,
        alignment,
    };
    let mut acc = MetricsAccumulator::default();
    for (p, trials) in sessions.iter().zip(retained) {
        p.for_each_trial(trials, "scoring the per-sample fit", &mut |rec, t| {
            let set = dataset::build(rec, std::slice::from_ref(t), &dopts);
            sample::score_rows(&mut acc, &final_fit.theta, &set.rows);
            Ok(())
        })?;
    }
    let kappa = input.gram_kept(rejections).condition_number();
    Ok((kappa, acc.finish()))
}

/// Stage 6: the trial, reading and sample pairings on the same retained trials, each with its
/// own constrained fit (the options' pairing reuses the final fit and its `scores`, κ and
/// quality). Also returns the trial rows.
fn compare_pairings(
    rows: &[SessionSets],
    retained: &[Vec<TrialWindow>],
    opts: &IdentifyOptions,
    final_fit: &FinalFit,
    scores: (f64, Metrics),
) -> Result<(Vec<ModeFit>, Vec<Row>)> {
    let mode_rows = |mode: Mode| -> Vec<Row> {
        let mut out = Vec::new();
        for (r, ts) in rows.iter().zip(retained) {
            match mode {
                Mode::Trial => out.extend(restrict(&r.trial, ts).rows),
                Mode::Reading => out.extend(restrict(&r.reading, ts).rows),
                // Those the rows pass kept, thinned by the stride planned from the IMU-kept trials.
                Mode::Sample => {
                    let keep: HashSet<usize> = ts.iter().map(|t| t.index).collect();
                    out.extend(sample::of_trials(&r.sample_thin, &keep, |r| r.trial))
                }
            }
        }
        out
    };
    let mut modes = Vec::new();
    let mut trial_rows = Vec::new();
    for mode in [Mode::Trial, Mode::Reading, Mode::Sample] {
        if mode == opts.mode {
            modes.push(ModeFit {
                mode,
                kappa: scores.0,
                quality: scores.1,
            });
            if mode == Mode::Trial {
                trial_rows = final_fit.rows.clone();
            }
            continue;
        }
        let rows = mode_rows(mode);
        let (fit, kappa) = fit_rows(&rows)?;
        let theta = fit.theta49()?;
        modes.push(ModeFit {
            mode,
            kappa,
            quality: quality(&theta, &rows),
        });
        if mode == Mode::Trial {
            trial_rows = rows;
        }
    }
    Ok((modes, trial_rows))
}

/// Stage 7: per-trial measured vs predicted over every trial with rows, rejected ones flagged.
fn per_trial_table(
    sessions: &[Prepared],
    rows: &[SessionSets],
    theta: &[f64; N_PARAMS],
    rejections: &[Rejection],
) -> Vec<TrialPrediction> {
    let mut per_trial = Vec::new();
    for (s, (p, r)) in sessions.iter().zip(rows).enumerate() {
        per_trial.extend(trial_predictions(
            s,
            &p.pass.seg,
            &r.reading,
            &r.trial,
            theta,
            |t| trial::is_rejected(rejections, s, t),
        ));
    }
    per_trial
}

/// Identify the power model from one or more recordings in memory.
pub fn identify(recs: &[Recording], opts: &IdentifyOptions) -> Result<Identification> {
    let sessions = recs
        .iter()
        .map(|r| Prepared::from_recording(r, &opts.segment, StreamOptions::default()))
        .collect::<Result<Vec<_>>>()?;
    identify_prepared(sessions, opts)
}

/// Identify the power model from one or more session files, reading each in two streamed passes
/// (memory bounded whatever the sessions' length): [`identify`] over the files.
pub fn identify_files(
    files: &[SessionFile],
    opts: &IdentifyOptions,
    stream: &StreamOptions,
) -> Result<Identification> {
    let sessions = files
        .iter()
        .map(|f| Prepared::from_file(f.clone(), &opts.segment, *stream))
        .collect::<Result<Vec<_>>>()?;
    identify_prepared(sessions, opts)
}

fn identify_prepared(sessions: Vec<Prepared>, opts: &IdentifyOptions) -> Result<Identification> {
    if sessions.is_empty() {
        bail!("identify needs at least one recording");
    }
    // Stage 1 check: a session without a single trial is an error.
    if let Some(p) = sessions.iter().find(|p| p.pass.seg.trials.is_empty()) {
        return Err(p.no_usable_trials(&[]));
    }
    let mut rejections = opts.filters.imu(&imu_statistics(&sessions));
    let kept = trials_kept(&sessions, &rejections);
    let (alignment, alignment_estimate) = resolve_alignment(&sessions, &kept, opts)?;
    let mut sessions = sessions;
    sessions.iter_mut().for_each(Prepared::release_subset);
    let rows = session_rows(&sessions, &kept, opts, alignment)?;
    let input = build_sets(&sessions, &rows, &kept, opts)?;
    let final_fit = fit_with_rejection(&input, &mut rejections, opts)?;
    let retained = trials_kept(&sessions, &rejections);
    let scores = final_scores(
        &sessions,
        &input,
        &final_fit,
        &rejections,
        &retained,
        opts,
        alignment,
    )?;
    let (modes, trial_rows) = compare_pairings(&rows, &retained, opts, &final_fit, scores)?;
    let per_trial = per_trial_table(&sessions, &rows, &final_fit.theta, &rejections);

    let per_session = session_breakdown(&sessions, &rows, &retained, &rejections, &final_fit.theta);
    let model = PowerModel::from_vector(&final_fit.theta);
    let terms = term_means(&model, &trial_rows);
    let retained_table: Vec<&TrialPrediction> = per_trial.iter().filter(|p| !p.rejected).collect();
    let sessions = sessions
        .into_iter()
        .zip(input.into_skipped())
        .map(|(p, skipped)| p.summary(skipped))
        .collect();
    Ok(Identification {
        model,
        options: opts.clone(),
        sessions,
        alignment,
        alignment_estimate,
        trials_used: retained.iter().map(Vec::len).sum(),
        fit: scores.1,
        trial_level: trial_metrics(&retained_table, |p| p.predicted_window_w),
        trial_level_aligned: trial_metrics(&retained_table, |p| p.predicted_w),
        modes,
        dominant: (0..N_JOINTS).map(|j| model.dominant_term(j)).collect(),
        terms,
        shares_percent: terms.shares_percent(),
        std_err: final_fit.fit.std_err.clone(),
        solver: final_fit.fit.solver.clone(),
        rejections,
        per_trial,
        per_session,
    })
}

/// Stage 8: each session's trials used and rejected and the final model's per-reading fit there.
fn session_breakdown(
    sessions: &[Prepared],
    rows: &[SessionSets],
    retained: &[Vec<TrialWindow>],
    rejections: &[Rejection],
    theta: &[f64; N_PARAMS],
) -> Vec<SessionBreakdown> {
    sessions
        .iter()
        .zip(rows)
        .zip(retained)
        .enumerate()
        .map(|(s, ((p, r), kept))| {
            let rejected = (p.pass.seg.trials)
                .iter()
                .filter(|t| trial::is_rejected(rejections, s, t.index))
                .count();
            let used = restrict(&r.reading, kept);
            SessionBreakdown {
                source: p.pass.source.clone(),
                trials: p.pass.seg.trials.len(),
                used: used.trials.len(),
                rejected,
                without_rows: used.skipped.len(),
                reading: quality(theta, &used.rows),
                first_temp_c: p.pass.first_temp_c,
            }
        })
        .collect()
}

/// A fit of rows that were built elsewhere (e.g. read back from a row table): the paper's
/// constrained fit and its quality on those rows.
#[derive(Debug, Clone)]
pub struct RowsFit {
    /// The fitted model.
    pub model: PowerModel,
    /// Fit quality on the rows.
    pub fit: Metrics,
    /// κ(ΦᵀΦ) of the rows.
    pub kappa: f64,
    /// Standard error of each parameter (None: at a bound or not excited).
    pub std_err: Vec<Option<f64>>,
    /// Solver run.
    pub solver: SolverInfo,
}

/// Fit the power model to given rows (no segmentation or filtering: the rows are taken as they
/// are; leave out rejected trials before calling).
pub fn fit_given_rows(rows: &[Row]) -> Result<RowsFit> {
    if rows.len() < N_PARAMS {
        bail!(
            "{} rows, fewer than the {N_PARAMS} parameters of the model",
            rows.len()
        );
    }
    let (fit, kappa) = fit_rows(rows).context("constrained least squares")?;
    let theta = fit.theta49()?;
    Ok(RowsFit {
        model: PowerModel::from_vector(&theta),
        fit: quality(&theta, rows),
        kappa,
        std_err: fit.std_err.clone(),
        solver: fit.solver,
    })
}

#[cfg(test)]
mod search_tests {
    use crate::session::search_stride;

    #[test]
    fn search_stride_is_the_smallest_power_of_two_within_the_cap() {
        assert_eq!(search_stride(&[], 300), 1);
        assert_eq!(search_stride(&[300], 300), 1);
        assert_eq!(search_stride(&[301], 300), 2);
        assert_eq!(search_stride(&[1000], 300), 4);
        assert_eq!(search_stride(&[2400], 300), 8);
        // Across sessions: 150 + 151 trials need every 2nd (75 + 76).
        assert_eq!(search_stride(&[150, 151], 300), 2);
        for n in 0..2000usize {
            for cap in [1usize, 7, 300] {
                let s = search_stride(&[n], cap);
                assert!(s.is_power_of_two());
                assert!(n.div_ceil(s) <= cap);
                assert!(s == 1 || n.div_ceil(s / 2) > cap);
            }
        }
    }
}
