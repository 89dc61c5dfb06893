//! Sim-to-real mismatch diagnosis: compare the twin (URDF dynamics + identified power model)
//! with a recording at the torque and power levels, locate where they disagree, name the
//! missing physics from a library of hypotheses scored by trial-wise cross-validation, model it
//! (refit with the accepted hypotheses), and report it in words, figures and JSON.
//!
//! Pipeline of [`diagnose_trials`]: trial windows → per-reading rows (φ, hypothesis features,
//! descriptors over each reading's own sensor window) → IMU and 3σ trial filters → rows at every
//! scanned sensor lag → greedy forward selection at the power level ([`select`]) and the payload
//! hypothesis at the torque level ([`torque`]) → final refit → breakdowns and correlates of
//! the held-out residuals ([`locate`]) → plain-language summary ([`summary`]).

pub(crate) mod counterpart;
mod diagnosis;
pub(crate) mod discover;
pub(crate) mod family;
pub(crate) mod field_rules;
pub(crate) mod fields;
mod flexible;
pub(crate) mod hypotheses;
mod lags;
pub(crate) mod locate;
pub(crate) mod meters;
mod options;
mod parsimony;
pub(crate) mod reading_rows;
mod refit;
pub(crate) mod report;
pub(crate) mod rest;
pub(crate) mod select;
mod select_discover;
pub(crate) mod stats;
mod stepwise;
pub(crate) mod summary;
#[cfg(test)]
mod testkit;
#[cfg(test)]
mod tests;
pub(crate) mod torque;
mod trials;
mod viewer_data;
mod window;

use anyhow::{Result, bail};

pub use crate::signals::Target;
pub use crate::trial::{Phase, TrialWindow};
pub use counterpart::{
    CounterpartComparison, CounterpartSeries, JointDifference, TrialDifference,
    compare as compare_counterpart, compare_files as compare_counterpart_files,
};
pub use diagnosis::{Diagnosis, FinalModel, LagPoint, Quality, SCHEMA_VERSION, SensorWindow};
pub use discover::{Discovery, DiscoveryReport, TiedTerm};
pub use fields::{ExcludedField, FieldSource};
pub use locate::{Breakdown, Correlate, Group, TrialResidual};
pub use meters::{MeterCheck, MeterDrift, MeterVerdict};
pub use options::DiagnoseOptions;
pub use report::{FIGURES as REPORT_FIGURES, write_report};
pub use rest::{RestPower, RestTerm};
pub use select::{Confounded, HypothesisScore, MechanismForms, Param};
pub use torque::TorqueComparison;
pub use viewer_data::{HighlightedTrial, LocatedField, ReplayData};

use crate::N_PARAMS;
use crate::power::PowerModel;
use crate::robot::{ArmDynamics, RobotModel};
use crate::session::{Memory, SessionFile, TrialSource};
use crate::signals::Recording;
use lags::{lag_scan, scan_lags, usable_trials};
use refit::{locate_residuals, rank_hypotheses, refit_final};
use select::Rule;
use select_discover::select_and_discover;
use trials::SessionInfo;
use viewer_data::{replay_data, show_found, show_rest};
use window::sensor_window;

/// [`crate::signals::join_recordings`], plus where each part's file lies on the joined time line (for
/// [`DiagnoseOptions::field_sources`]).
pub fn join_recordings_with_sources(
    parts: Vec<Recording>,
    gap_s: f64,
) -> (Recording, Vec<FieldSource>) {
    let mut sources = Vec::new();
    let mut end = None::<f64>;
    for r in &parts {
        let offset = end.map_or(0.0, |e| {
            e + gap_s - r.state.t.first().copied().unwrap_or(0.0)
        });
        sources.push(FieldSource {
            path: r.source.clone(),
            start_ns: r.start_ns,
            offset_s: offset,
        });
        end = Some(r.state.t.last().copied().unwrap_or(0.0) + offset);
    }
    (crate::signals::join_recordings(parts, gap_s), sources)
}

/// Diagnose a recording: segment its trials from the data (the identification's segmentation),
/// load the robot model for the torque level, and run [`diagnose_trials`].
pub fn diagnose(rec: &Recording, opts: &DiagnoseOptions) -> Result<Diagnosis> {
    let seg = crate::trial::segment(rec, &crate::trial::SegmentOptions::default());
    if seg.trials.is_empty() {
        let why: Vec<String> = seg
            .unmatched
            .iter()
            .take(5)
            .map(|s| format!("{:.1}–{:.1} s: {}", s.t0, s.t1, s.reason))
            .collect();
        bail!(
            "{}: no protocol trials found ({})",
            rec.source.display(),
            why.join("; ")
        );
    }
    let has_torque = rec.state.tau.iter().any(|t| t.iter().any(|v| *v != 0.0));
    let arm = arm_model(opts, has_torque, &rec.joint_names)?;
    diagnose_trials(rec, &seg.trials, arm.as_ref(), opts)
}

/// The URDF arm for the torque level, when it is asked for and the session recorded torques.
fn arm_model(
    opts: &DiagnoseOptions,
    has_torque: bool,
    joint_names: &[String],
) -> Result<Option<ArmDynamics>> {
    if !(opts.torque_level && has_torque) {
        return Ok(None);
    }
    let model = RobotModel::load(opts.urdf.as_deref())?;
    let joints = model.arm(joint_names)?;
    Ok(Some(ArmDynamics::new(&model, &joints)?))
}

/// Diagnose session files without holding them in memory: each file is streamed trial by trial
/// (several passes; only per-trial reductions are kept — the rows at every scanned lag, the
/// torque rows, the sensor-window scan's trials and discovery's window means), with the same
/// stages and the same result as [`diagnose`] on the files loaded and joined by
/// [`join_recordings_with_sources`] with `gap_s` (each file keeps its own clock, shifted onto
/// the joined one). `opts.field_sources` is ignored: discovery reads the files themselves.
pub fn diagnose_files(
    files: &[SessionFile],
    opts: &DiagnoseOptions,
    gap_s: f64,
) -> Result<Diagnosis> {
    stage(
        1,
        "reading the file: segmentation and per-trial reductions (1st pass)",
    );
    let (mut samples, s) = trials::open_streamed(files, opts.target, bus_model(opts), gap_s)?;
    let arm = arm_model(opts, s.has_torque, &s.info.joint_names)?;
    let opts = DiagnoseOptions {
        field_sources: s.field_sources,
        ..opts.clone()
    };
    run(
        &s.info,
        &mut samples,
        (s.metas, s.skipped),
        arm.as_ref(),
        &opts,
    )
}

/// What a diagnosis tells of where it is ([`on_stage`]).
#[derive(Debug, Clone, Copy)]
pub enum Progress<'a> {
    /// Stage `k` of `of`, named `name`, begins.
    Stage {
        /// Its number, from 1.
        k: usize,
        /// Stages in all.
        of: usize,
        /// What it does.
        name: &'a str,
    },
    /// Discovery's search at its `step`-th term: `done` of its `total` candidate terms scored.
    Candidates {
        /// The term being searched for, from 1.
        step: usize,
        /// Candidates scored so far at this step.
        done: usize,
        /// Candidates at this step.
        total: usize,
    },
    /// In the field pass over the file, the messages up to `done_s` of the `total_s` seconds
    /// the diagnosis reads fields over are read.
    Seconds {
        /// Seconds of the session read.
        done_s: f64,
        /// Seconds to read.
        total_s: f64,
    },
    /// In the stage's pass over the file, `done` of its `total` trials are read.
    Trials {
        /// Trials read so far.
        done: usize,
        /// Trials the pass reads.
        total: usize,
    },
}

/// A reporter of the diagnosis' progress ([`on_stage`]).
type StageReporter = Box<dyn Fn(Progress<'_>) + Send>;
static STAGE: std::sync::Mutex<Option<StageReporter>> = std::sync::Mutex::new(None);
/// Stages [`stage`] counts.
const STAGES: usize = 6;

/// Sets (or clears) what is told of the diagnosis' progress: each stage it enters, and the
/// trials read in each pass over the file (the CLI shows them on its spinner; a paper-scale
/// diagnosis runs tens of seconds).
pub fn on_stage(reporter: Option<StageReporter>) {
    if let Ok(mut s) = STAGE.lock() {
        *s = reporter;
    }
}

/// Tells the reporter, if any, of `p`.
fn report(p: Progress<'_>) {
    if let Ok(s) = STAGE.lock()
        && let Some(f) = s.as_ref()
    {
        f(p);
    }
}

/// Tells the reporter, if any, that stage `k` of [`STAGES`] begins.
fn stage(k: usize, name: &str) {
    report(Progress::Stage {
        k,
        of: STAGES,
        name,
    });
}

/// A trial source that tells `report` each pass's progress ([`Progress::Trials`]).
struct Counted<'a> {
    inner: &'a mut dyn TrialSource,
    report: &'a dyn Fn(Progress<'_>),
}

impl TrialSource for Counted<'_> {
    fn for_each(
        &mut self,
        trials: &[crate::trial::TrialWindow],
        f: &mut dyn FnMut(&Recording, &crate::trial::TrialWindow) -> Result<()>,
    ) -> Result<()> {
        let (total, mut done) = (trials.len(), 0);
        let report = self.report;
        self.inner.for_each(trials, &mut |rec, t| {
            let r = f(rec, t);
            done += 1;
            report(Progress::Trials { done, total });
            r
        })
    }
}

/// The bus-current feature's model: the twin's power model at the nominal supply voltage.
fn bus_model(opts: &DiagnoseOptions) -> reading_rows::BusModel {
    reading_rows::BusModel {
        model: opts.reference.unwrap_or(PowerModel::PAPER),
        volts: hypotheses::NOMINAL_BUS_VOLTS,
    }
}

/// Diagnose a recording whose trials are already segmented. `arm` enables the torque level.
///
/// The recording is reduced trial by trial (as [`diagnose_files`] reduces streamed files) and
/// the stages run on the reductions: per-trial quantities → sensor window ([`sensor_window`])
/// → rows at the coarse lags → usable trials ([`filter_trials`]) → fine lags and torque rows
/// ([`scan_lags`]) → library selection and discovery ([`select_and_discover`]) → torque level →
/// ranking ([`rank_hypotheses`]) → final refit ([`refit_final`]) → locate
/// ([`locate_residuals`]) → lag scan, replay data and assembly.
pub fn diagnose_trials(
    rec: &Recording,
    windows: &[TrialWindow],
    arm: Option<&ArmDynamics>,
    opts: &DiagnoseOptions,
) -> Result<Diagnosis> {
    let info = SessionInfo::of(rec, opts.target);
    let mut samples = Memory(rec);
    let metas = trials::trial_metas(&mut samples, windows, bus_model(opts))?;
    run(&info, &mut samples, metas, arm, opts)
}

/// The stages on a session's reductions (`metas`: every trial's quantities, and the trials
/// without a pre-idle); `samples` gives the trials' joint states for the per-trial passes.
fn run(
    info: &SessionInfo,
    samples: &mut dyn TrialSource,
    (all_metas, skipped): (Vec<reading_rows::TrialMeta>, reading_rows::Skipped),
    arm: Option<&ArmDynamics>,
    opts: &DiagnoseOptions,
) -> Result<Diagnosis> {
    let samples = &mut Counted {
        inner: samples,
        report: &report,
    };
    let power = &info.power;
    if power.t.is_empty() {
        bail!(
            "{}: no {:?} power readings to diagnose",
            info.source.display(),
            opts.target
        );
    }
    // The trial count first: a session too short for the cross-validation fails on it at once,
    // not after a sensor-window estimate that needs more trials too.
    let need = 2 * opts.folds.max(2);
    if all_metas.len() < need {
        bail!(
            "{}: only {} trials with a pre-idle (need at least {need} usable for {}-fold \
             cross-validation by trial; diagnose needs a longer session)",
            info.source.display(),
            all_metas.len(),
            opts.folds
        );
    }
    stage(2, "estimating the sensor window");
    let sensor = sensor_window(info, samples, &all_metas, opts)?;
    let all_metas = window::with_widths(all_metas, &sensor);
    let w = sensor.window_s;
    let resolved = DiagnoseOptions {
        sensor_window_s: Some(w),
        ..opts.clone()
    };
    let opts = &resolved;
    stage(3, "rows at the coarse lags, filters");
    let u = usable_trials(info, samples, all_metas, skipped, opts)?;
    let metas = &u.metas;
    // Every lag's Gram matrices, the fine lags and the torque rows (one more pass).
    let stride = torque::stride(metas, opts.max_torque_samples);
    let mut torque_rows = Vec::new();
    stage(4, "fine lags and torque rows");
    let mut data = scan_lags(
        samples,
        power,
        metas,
        u.rows0,
        &u.totals,
        opts,
        &mut |rec, ti, meta| {
            if let Some(a) = arm {
                torque::trial_rows(rec, ti, meta, a, stride, &mut torque_rows);
            }
        },
    )?;
    data.lag_claimable = sensor.lag_demanded;
    if data.rows0().len() < 3 * (N_PARAMS + 10) / 2 {
        bail!(
            "{}: only {} power readings inside usable trials; too few to diagnose a {N_PARAMS}-parameter model",
            info.source.display(),
            data.rows0().len()
        );
    }
    let rule = Rule {
        alpha: opts.alpha,
        bic_threshold: opts.bic_threshold,
        min_improvement: opts.min_improvement,
    };
    stage(
        5,
        "hypotheses and discovery (reads the recorded fields: the file's 2nd pass)",
    );
    let (drift, corrected) = meter_corrected(info, metas, &sensor, rule.alpha);
    let info = corrected.as_ref().unwrap_or(info);
    let (sel, mut discovery, fields) = select_and_discover(info, metas, &data, &rule, opts)?;
    if let Some(r) = discovery.as_mut() {
        let (rows, lag) = (data.rows(sel.last.lag)?, data.lags[sel.last.lag]);
        r.settle_meters(info, metas, rows, (lag, w), drift);
    }

    // Torque level.
    let torque = match arm {
        Some(_) => torque::torque_level(&info.joint_names, &torque_rows, metas.len(), &data.folds)?,
        None => None,
    };
    drop(torque_rows);
    stage(6, "ranking, final refit, locating the residual");
    let judged = (discovery, torque, sensor);
    let mut diag = assemble(info, metas, &data, &fields, (&sel, &rule), judged)?;
    (diag.rejected, diag.replay.rejected) = (u.rejected, u.rejected_windows);
    diag.replay.imu = u.imu;
    diag.summary = summary::summarise(&diag);
    Ok(diag)
}

/// One truth across stages: an artefact of the diagnosed meter that the other meter does not
/// show (a drifting or stepping offset, [`meters::compare`]) and the session with it taken out
/// of the readings, which every stage after this one reads (rest power, discovery, the meter
/// checks, the replay). The rows built before are net of each trial's own rest, which such an
/// artefact does not reach.
fn meter_corrected(
    info: &SessionInfo,
    metas: &[reading_rows::TrialMeta],
    sensor: &SensorWindow,
    alpha: f64,
) -> (Option<MeterDrift>, Option<SessionInfo>) {
    let lag = if sensor.lag_demanded {
        sensor.scan_lag_s
    } else {
        0.0
    };
    let (power, other, w) = (&info.power, &info.other, sensor.window_s);
    let drift = meters::compare(info.target, power, other, metas, lag, w, alpha);
    let corrected = drift
        .as_ref()
        .filter(|d| d.check.artefact())
        .map(|d| SessionInfo {
            power: d.corrected(power),
            ..info.clone()
        });
    (drift, corrected)
}

/// The last stage: ranking, final refit, locating the residual, the lag scan and the replay data,
/// assembled into the [`Diagnosis`] (its caller adds the trials left out and the summary).
fn assemble(
    info: &SessionInfo,
    metas: &[reading_rows::TrialMeta],
    data: &select::PowerData,
    fields: &select_discover::RowFields,
    (sel, rule): (&select::Selection, &Rule),
    j: (
        Option<DiscoveryReport>,
        Option<torque::TorqueLevel>,
        SensorWindow,
    ),
) -> Result<Diagnosis> {
    let (mut discovery, torque, sensor) = j;
    let ranking = rank_hypotheses(sel, torque.as_ref(), rule);
    let final_model = refit_final(
        sel,
        &ranking.accepted,
        torque.as_ref(),
        data.rows0(),
        metas.len(),
    );
    let located = locate_residuals(&info.joint_names, metas, data, sel, discovery.as_ref());
    if let Some(r) = discovery.as_mut() {
        r.locate_unexplained(&located.unexplained);
    }
    let replay = replay_data(metas, data.rows0(), sel, &located);
    let mut diag = Diagnosis {
        schema_version: SCHEMA_VERSION,
        source: info.source.display().to_string(),
        target: info.target,
        joint_names: info.joint_names.clone(),
        n_trials: metas.len(),
        n_readings: data.rows0().len(),
        rejected: Vec::new(),
        torque: torque.map(|t| t.comparison),
        base_model: if data.reference.is_some() {
            "reference".into()
        } else {
            "refit".into()
        },
        lag_scan: lag_scan(data)?,
        breakdowns: located.breakdowns,
        worst: located.worst,
        worst_trials: located.worst_trials,
        hypotheses: ranking.ranked,
        accepted: ranking.accepted,
        final_model,
        unexplained: located.unexplained,
        forms: sel.forms.clone(),
        confounded: sel.confounded.clone(),
        discovery,
        bus_volts: fields
            .table
            .bus_volts
            .unwrap_or(hypotheses::NOMINAL_BUS_VOLTS),
        sensor_window: sensor,
        summary: String::new(),
        replay,
        counterpart: None,
    };
    show_found(&mut diag, fields, data.rows0(), metas);
    show_rest(&mut diag, fields, data.rows0(), metas);
    Ok(diag)
}

#[cfg(test)]
mod progress_tests {
    use super::*;

    /// Each pass over the trials tells its progress trial by trial, up to the pass's total,
    /// and the trials reach the pass's own function unchanged.
    #[test]
    fn a_pass_over_the_trials_reports_each_trial_read() {
        let (rec, windows) = testkit::session(5, 1, testkit::Effects::default());
        let seen = std::sync::Mutex::new(Vec::new());
        let note = |p: Progress<'_>| {
            if let Progress::Trials { done, total } = p {
                seen.lock().unwrap().push((done, total));
            }
        };
        let mut counted = Counted {
            inner: &mut Memory(&rec),
            report: &note,
        };
        let mut indices = Vec::new();
        counted
            .for_each(&windows[1..4], &mut |_, t| {
                indices.push(t.index);
                Ok(())
            })
            .unwrap();
        assert_eq!(
            indices,
            vec![windows[1].index, windows[2].index, windows[3].index]
        );
        assert_eq!(*seen.lock().unwrap(), vec![(1, 3), (2, 3), (3, 3)]);
    }
}
