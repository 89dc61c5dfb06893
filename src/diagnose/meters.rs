//! Meter or load: the arm rail is metered twice (the main board's meter, and the battery's, which
//! also carries the rest of the robot). A load on the rail shows on both meters; an artefact of one
//! meter (an offset or gain that follows some state, a lag, a window) on that meter alone.
//!
//! Every term found beyond the library and every rest-power term is checked against the other
//! meter trial by trial: the difference other − target of the two meters' per-trial power (net of
//! each one's own baseline for the moving part, the baseline itself for the rest power) is
//! regressed on what the term adds to the target's power. The rail's real power cancels in the
//! difference, so a load leaves a slope of 0 (the other meter shows all of it: share 1) and an
//! artefact of the target meter a slope of −1 (share 0). An artefact is renamed a correction of
//! that meter's reading, not a load on the rail; its fitted form is kept as the correction.
//!
//! The meters are also compared directly ([`compare`]): a gain or offset of one meter that drifts
//! over the session (or steps) changes the difference of the two meters' readings, in which every
//! real load cancels. It is invisible to the arm's model (each trial's power is taken net of its
//! own rest), so this comparison is the only place it can be found. A change significant on the
//! diagnosed meter that the other meter shows too, or cannot tell from an artefact (a battery
//! meter that also carries the rest of the robot wanders by watts), is located, not dropped: in a
//! 15-minute session the rest-power stage's block test cannot reach its Holm level, and this is
//! where a slow load or a meter's drift shows at all.
//!
//! Both are one regression ([`slopes`]): the trials are in time order and their rest readings
//! drift slowly, so every standard error here is widened for the residuals' serial correlation.

use serde::{Deserialize, Serialize};

use super::family::{dot, residual};
use super::reading_rows::{TrialMeta, baseline_readings};
use super::rest::{DRIFT_TRIALS, drift_basis};
use super::stats::t_upper_tail;
use crate::lsq::Gram;
use crate::signals::{PowerSeries, Target};

/// Standard errors a share must lie from ½ for a verdict.
const Z: f64 = 3.0;

/// What the rail's other meter shows of a finding.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeterCheck {
    /// The meter it was found on ("main-board" or "battery").
    pub meter: String,
    /// The meter it was checked against.
    pub other: String,
    /// Share of it that the other meter shows (1: a load on the rail; 0: an artefact of
    /// `meter`).
    pub share: f64,
    /// Standard error of the share.
    pub std_err: f64,
    /// Trials compared.
    pub n_trials: usize,
    /// Load, meter artefact or undecided.
    pub verdict: MeterVerdict,
}

/// What the other meter makes of a finding.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum MeterVerdict {
    /// Both meters show it: a load on the rail.
    #[serde(rename = "load")]
    Load,
    /// Only the meter it was found on shows it.
    #[serde(rename = "meter artefact")]
    Artefact,
    /// The other meter cannot tell which.
    #[serde(rename = "undecided")]
    Undecided,
}

impl MeterCheck {
    /// The check of a finding on `target`'s meter: the other meter shows `share` ± `std_err` of it
    /// over `n_trials` trials.
    fn new(
        target: Target,
        (share, std_err): (f64, f64),
        n_trials: usize,
        verdict: MeterVerdict,
    ) -> Self {
        MeterCheck {
            meter: meter_name(target).into(),
            other: meter_name(match target {
                Target::Mbs => Target::Bms,
                Target::Bms => Target::Mbs,
            })
            .into(),
            share,
            std_err,
            n_trials,
            verdict,
        }
    }

    /// Whether the finding is an artefact of the meter it was found on.
    pub fn artefact(&self) -> bool {
        self.verdict == MeterVerdict::Artefact
    }

    /// "it shows 95 ± 12 % of it" (rounded first: no "-0").
    fn shown(&self) -> String {
        format!(
            "{:.0} ± {:.0} % of it",
            (100.0 * self.share).round() + 0.0,
            100.0 * self.std_err
        )
    }

    /// One sentence for the summary.
    pub fn words(&self) -> String {
        let shown = format!("the {} meter shows {}", self.other, self.shown());
        match self.verdict {
            MeterVerdict::Load => format!("Both meters see it ({shown}): a load on the rail."),
            MeterVerdict::Artefact => format!(
                "One meter only ({shown}): an artefact of the {} meter, modelled as a correction of its reading.",
                self.meter
            ),
            MeterVerdict::Undecided => {
                format!("The other meter cannot tell load from artefact ({shown}).")
            }
        }
    }
}

/// The meter's name in the report's sentences.
pub(crate) fn meter_name(t: Target) -> &'static str {
    match t {
        Target::Mbs => "main-board",
        Target::Bms => "battery",
    }
}

/// One meter's power per trial: the rest power (mean of its baseline readings) and the net power
/// of the moving part (readings stamped in [t_traj_start + W, t_return_end], minus the rest).
pub(crate) fn per_trial(
    p: &PowerSeries,
    metas: &[TrialMeta],
    lag: f64,
    w: f64,
) -> (Vec<f64>, Vec<f64>) {
    let mean = |r: std::ops::Range<usize>| finite_mean(p.watts[r].iter().copied());
    metas
        .iter()
        .map(|m| {
            let rest = mean(baseline_readings(&p.t, m, lag, w));
            let a = p.t.partition_point(|&x| x < m.window.t_traj_start + w);
            let b = p.t.partition_point(|&x| x < m.window.t_return_end + 1e-9);
            (rest, mean(a..b.max(a)) - rest)
        })
        .unzip()
}

/// The mean of the finite values of `v` (NaN if none).
pub(crate) fn finite_mean(v: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = v
        .filter(|v| v.is_finite())
        .fold((0.0, 0), |(s, n), v| (s + v, n + 1));
    if n == 0 { f64::NAN } else { sum / f64::from(n) }
}

/// Each column's (slope, widened s.e.), the SSE and the rows used ([`slopes`]).
type Slopes = (Vec<(f64, f64)>, f64, usize);

/// The one inference rule of the meter comparisons: the slopes of `y` on `cols` (with a constant;
/// rows with a non-finite value left out), their standard errors widened for the serial
/// correlation of the residuals in trial order ([`serial_widening`]: the rest power and the
/// meters' difference drift slowly, so neighbouring trials are not independent), the SSE and
/// the rows used.
fn slopes(y: &[f64], cols: &[&[f64]]) -> Option<Slopes> {
    let mut g = Gram::zeros(cols.len() + 1);
    let mut rows = Vec::new();
    for (t, &d) in y.iter().enumerate() {
        let row: Vec<f64> = std::iter::once(1.0)
            .chain(cols.iter().map(|c| c[t]))
            .collect();
        if d.is_finite() && row.iter().all(|v| v.is_finite()) {
            g.add_row(&row, d);
            rows.push((row, d));
        }
    }
    let (beta, se) = g.solve_with_se()?;
    let resid: Vec<f64> = rows
        .iter()
        .map(|(x, y)| y - x.iter().zip(beta.iter()).map(|(x, b)| x * b).sum::<f64>())
        .collect();
    let widen = serial_widening(&resid);
    let sse = resid.iter().map(|r| r * r).sum();
    let b = (1..=cols.len()).map(|c| (beta[c], se[c] * widen)).collect();
    Some((b, sse, g.n))
}

/// The check of each column, `None` where the other meter has too few trials.
pub(crate) fn checks(target: Target, diff: &[f64], cols: &[Vec<f64>]) -> Vec<Option<MeterCheck>> {
    let cols: Vec<&[f64]> = cols.iter().map(Vec::as_slice).collect();
    let Some((s, _, n)) = slopes(diff, &cols) else {
        return vec![None; cols.len()];
    };
    s.into_iter()
        .map(|(k, se)| {
            // The other meter shows 1 + slope of what the term adds (other − target).
            let share = 1.0 + k;
            // A verdict only where the comparison tells 0 from 1 (Z·se ≤ ½); an artefact's
            // share is consistent with 0 (a load's is diluted below 1 where the other meter's
            // readings fall at other instants than the fields' windows follow).
            let resolved = Z * se <= 0.5;
            let verdict = if resolved && share - Z * se > 0.5 {
                MeterVerdict::Load
            } else if resolved && share + Z * se < 0.5 && share + Z * se >= 0.0 {
                MeterVerdict::Artefact
            } else {
                MeterVerdict::Undecided
            };
            Some(MeterCheck::new(target, (share, se), n, verdict))
        })
        .collect()
}

/// A change over the session of the diagnosed meter's rest reading: an artefact of that meter (a
/// drifting or stepping offset, or gain) where the rail's other meter does not show it, else
/// located ([`MeterCheck::verdict`] load or undecided).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeterDrift {
    /// The meter diagnosed ("main-board" or "battery").
    pub meter: String,
    /// How its rest reading changes: "drifting over the session" or "in a step … s after the
    /// first trial".
    pub form: String,
    /// Change of its rest reading over the session [W].
    pub change_w: f64,
    /// Standard error of `change_w` (widened for the trials' serial correlation).
    pub std_err_w: f64,
    /// Its mean rest reading [W] (a gain change of `change_w / rest_w`).
    pub rest_w: f64,
    /// p-value of the change on the meter itself, and the level it had to beat (α / forms tried).
    pub p_value: f64,
    /// Level (α / forms tried).
    pub alpha: f64,
    /// What the other meter shows of it (share 1: a real change of the rail's power).
    pub check: MeterCheck,
    /// One sentence naming it.
    pub name: String,
    /// For a located change (not an artefact): the recorded fields the rest power follows best,
    /// which the data cannot tell apart ([`MeterDrift::follows`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub fields: Vec<String>,
    /// Its form in time: first trial's start [s], the span of the trials' starts [s], and the
    /// step's place as a share of that span (`None`: a linear trend).
    #[serde(skip)]
    pub(crate) form_at: (f64, f64, Option<f64>),
}

impl MeterDrift {
    /// A located change named with the fields the rest power follows best (`fields`: the best
    /// first, then those it cannot be told from; at most [`FIELDS_NAMED`] in the name).
    pub(crate) fn follows(&mut self, fields: Vec<String>) {
        if fields.is_empty() || self.check.artefact() {
            return;
        }
        self.fields = fields;
        self.name = self.describe();
    }

    /// One sentence naming it: a meter's artefact, or a location — a drift said first as the
    /// recorded fields the rest power follows, where there are any.
    fn describe(&self) -> String {
        let (c, b, se) = (&self.check, self.change_w, self.std_err_w);
        let (meter, other) = (&c.meter, &c.other);
        let change = match self.form_at.2 {
            Some(_) => format!("its reading changes by {b:+.2} ± {se:.2} W {}", self.form),
            None => format!("its reading drifts by {b:+.2} ± {se:.2} W over the session"),
        };
        let shown = format!("it shows {}", c.shown());
        let located = match c.verdict {
            MeterVerdict::Artefact => {
                return format!(
                    "an artefact of the {meter} meter: {change} (an offset, or a gain change of {:+.2} % at its rest reading of {:.1} W), which the {other} meter does not show ({shown}; a change of the rail's power shows on both) — a correction of that meter's reading, not physics of the arm",
                    100.0 * b / self.rest_w,
                    self.rest_w,
                );
            }
            MeterVerdict::Load => format!(
                "the {meter} meter's rest reading: {change}, and the {other} meter shows it too ({shown}): a change of the rail's power — located, its cause not identified; not claimed"
            ),
            MeterVerdict::Undecided => format!(
                "the {meter} meter's rest reading: {change}; the {other} meter cannot tell a change of the rail's power from an artefact of the {meter} meter ({shown}) — located, not claimed"
            ),
        };
        if self.fields.is_empty() {
            return located;
        }
        let more = self.fields.len().saturating_sub(FIELDS_NAMED);
        let mut named = self.fields[..self.fields.len() - more].join(" or ");
        if more > 0 {
            named += &format!(" or {more} more");
        }
        match self.form_at.2 {
            None => format!(
                "the rail's rest power drifts with {named} (the recorded fields it follows best, not told apart) — {located}"
            ),
            Some(_) => format!(
                "{located}; of the recorded fields the rest power follows {named} best (not told apart)"
            ),
        }
    }

    /// `power` (the diagnosed meter's readings) with this artefact taken out: what every stage
    /// after the comparison reads.
    pub(crate) fn corrected(&self, power: &PowerSeries) -> PowerSeries {
        let (t0, span, step) = self.form_at;
        let x = |t: f64| {
            let u = (t - t0) / span;
            step.map_or(u, |s| f64::from(u8::from(u > s)))
        };
        PowerSeries {
            t: power.t.clone(),
            watts: (power.t.iter().zip(&power.watts))
                .map(|(&t, &w)| w - self.change_w * x(t))
                .collect(),
        }
    }
}

/// Most fields named in a located change's sentence (the JSON lists all).
const FIELDS_NAMED: usize = 4;

/// Where a step of the rest reading is tried: every boundary between two trials in this middle
/// share of the session (a step nearer an end has too few trials on one side to tell from the
/// drift).
const STEP_SPAN: (f64, f64) = (0.2, 0.8);

/// √((1+ρ)/(1−ρ)), ρ the lag-1 correlation of a residual in time order (bias-corrected, clamped
/// to [0, [`RHO_MAX`]]):
/// how much a slow regressor's standard error grows under serial correlation.
fn serial_widening(resid: &[f64]) -> f64 {
    let (num, den) = resid
        .windows(2)
        .fold((0.0, 0.0), |(n, d), w| (n + w[0] * w[1], d + w[0] * w[0]));
    let rho = num / den.max(1e-300);
    // Kendall's small-sample bias of the lag-1 estimate, −(1 + 3ρ)/n: a 15-minute session's 55
    // trials of a rail drifting with τ ≈ 300 s (ρ ≈ 0.95 between trials) read ρ ≈ 0.85, and
    // the uncorrected, 0.9-clamped widening located sub-watt "changes" in 3 of 8 null sessions.
    let rho = (rho + (1.0 + 3.0 * rho) / resid.len().max(1) as f64).clamp(0.0, RHO_MAX);
    ((1.0 + rho) / (1.0 - rho)).sqrt()
}

/// Largest lag-1 correlation [`serial_widening`] allows (a widening of ≈ 10).
const RHO_MAX: f64 = 0.98;

/// The meters compared over the session: the target meter's rest reading (each trial's pre-idle
/// mean) changes in a step where one stands out of the rail's slow drift
/// ([`step_beside_drift`]), else it drifts (a trend over the session, [`trend`]); a step at every
/// place and the trend are the forms tried, each at α over their number. A change is checked
/// against the other meter (the slope of other − target on it, serially widened). It is claimed
/// an artefact of the target meter when the other meter shows significantly less than all of it
/// (share + 3 s.e. < 1) and can tell "none" from "all" at all (3 s.e. < 1): a change of the
/// rail's power, a load, shows on both, and a battery meter that wanders by watts cannot say
/// which it is. Otherwise the change is returned with the verdict "load" (the other meter
/// resolves it as one) or "undecided": a location, neither claimed nor corrected.
pub(crate) fn compare(
    target: Target,
    power: &PowerSeries,
    other_power: &PowerSeries,
    metas: &[TrialMeta],
    lag: f64,
    w: f64,
    alpha: f64,
) -> Option<MeterDrift> {
    if other_power.t.is_empty() || metas.len() < 12 {
        return None;
    }
    let (rest1, _) = per_trial(power, metas, lag, w);
    let (rest2, _) = per_trial(other_power, metas, lag, w);
    let t: Vec<f64> = metas.iter().map(|m| m.window.t_traj_start).collect();
    let span = (t[t.len() - 1] - t[0]).max(1e-9);
    let keep: Vec<usize> = (0..metas.len())
        .filter(|&i| rest1[i].is_finite() && rest2[i].is_finite())
        .collect();
    let u: Vec<f64> = keep.iter().map(|&i| (t[i] - t[0]) / span).collect();
    let y: Vec<f64> = keep.iter().map(|&i| rest1[i]).collect();
    let diff: Vec<f64> = keep.iter().map(|&i| rest2[i] - rest1[i]).collect();
    let places: Vec<f64> = (u.windows(2).map(|w| 0.5 * (w[0] + w[1])))
        .filter(|s| (STEP_SPAN.0..=STEP_SPAN.1).contains(s))
        .collect();
    let level = alpha / (places.len() + 1) as f64;
    let c = step_beside_drift(&u, &y, &places, level).or_else(|| trend(&u, &y, level))?;
    // The other meter: diff = other − target regressed on the change; share = 1 + slope.
    let col: Vec<f64> = c.x.iter().map(|x| c.b * x).collect();
    let (k, _, _) = slopes(&diff, &[&col])?;
    let (share, share_se) = (1.0 + k[0].0, k[0].1);
    if share.is_nan() {
        return None;
    }
    // An artefact where the other meter shows significantly less than all of it and can tell
    // none from all; otherwise the change is located on this meter, not claimed: a load
    // where the other meter resolves it as one, undecided where it cannot tell.
    let verdict = if share + Z * share_se < 1.0 && Z * share_se < 1.0 {
        MeterVerdict::Artefact
    } else if Z * share_se <= 0.5 && share - Z * share_se > 0.5 {
        MeterVerdict::Load
    } else {
        MeterVerdict::Undecided
    };
    let rest_w = finite_mean(y.iter().copied());
    // A trend is located only against a slow drift of the rail's rest power: its standard error
    // widened for the residuals WITHOUT it (under "no change" the drift keeps them correlated; a
    // fitted trend takes part of the drift and leaves them whiter).
    if verdict != MeterVerdict::Artefact && c.step.is_none() {
        let (my, mx) = (rest_w, finite_mean(c.x.iter().copied()));
        let fitted: Vec<f64> = (y.iter().zip(&c.x))
            .map(|(y, x)| y - my - c.b * (x - mx))
            .collect();
        let h0: Vec<f64> = y.iter().map(|y| y - my).collect();
        let wider = (serial_widening(&h0) / serial_widening(&fitted)).max(1.0);
        let df = y.len().saturating_sub(2).max(1) as f64;
        if 2.0 * t_upper_tail((c.b / (c.se * wider)).abs(), df) >= level {
            return None;
        }
    }
    let form = c.step.map_or("drifting over the session".to_string(), |s| {
        format!("in a step {:.0} s after the first trial", s * span)
    });
    let mut d = MeterDrift {
        meter: meter_name(target).into(),
        form,
        change_w: c.b,
        std_err_w: c.se,
        rest_w,
        p_value: c.p,
        alpha: level,
        check: MeterCheck::new(target, (share, share_se), y.len(), verdict),
        name: String::new(),
        fields: Vec::new(),
        form_at: (t[0], span, c.step),
    };
    d.name = d.describe();
    Some(d)
}

/// A change of the rest reading: its step's place as a share of the session (`None`: a trend),
/// its regressor per trial, its size [W] with the widened s.e., and its p-value.
struct Change {
    step: Option<f64>,
    x: Vec<f64>,
    b: f64,
    se: f64,
    p: f64,
}

/// The best step of the rest reading `y` at `places` (shares of the session `u`) beside the
/// rail's slow drift — the rest-power stage's, piecewise linear over every [`DRIFT_TRIALS`]
/// trials: it follows a smooth change and not a step —, kept if it passes `level` (t test, the
/// s.e. widened for the serial correlation of the residuals with the step). A step fitted
/// alone takes a smooth drift's largest swing: a 15-minute null session was told "a step of
/// −0.77 W 352 s after the first trial".
fn step_beside_drift(u: &[f64], y: &[f64], places: &[f64], level: f64) -> Option<Change> {
    let q = drift_basis(u, DRIFT_TRIALS);
    let e0 = residual(&q, y);
    let at = |s: f64| -> Vec<f64> { u.iter().map(|&u| f64::from(u8::from(u > s))).collect() };
    let explained = |x: &[f64]| dot(x, &e0).powi(2) / dot(x, x);
    let (s, x) = (places.iter())
        .map(|&s| (s, residual(&q, &at(s))))
        .filter(|(_, x)| dot(x, x) > 1e-9)
        .max_by(|a, b| explained(&a.1).total_cmp(&explained(&b.1)))?;
    let xx = dot(&x, &x);
    let b = dot(&x, &e0) / xx;
    let e1: Vec<f64> = e0.iter().zip(&x).map(|(e, x)| e - b * x).collect();
    let df = y.len().checked_sub(q.len() + 1).filter(|&d| d > 0)? as f64;
    let se = (dot(&e1, &e1) / df / xx).sqrt() * serial_widening(&e1);
    let p = 2.0 * t_upper_tail((b / se).abs(), df);
    (p < level).then(|| Change {
        step: Some(s),
        x: at(s),
        b,
        se,
        p,
    })
}

/// A linear trend of the rest reading `y` over the session `u`, kept if its slope passes
/// `level` ([`slopes`]).
fn trend(u: &[f64], y: &[f64], level: f64) -> Option<Change> {
    let (b, se) = slopes(y, &[u])?.0[0];
    let p = 2.0 * t_upper_tail((b / se).abs(), y.len().saturating_sub(2).max(1) as f64);
    (p < level).then(|| Change {
        step: None,
        x: u.to_vec(),
        b,
        se,
        p,
    })
}

/// The name of a finding on `fields` that is an artefact of the meter it was found on.
pub(crate) fn artefact_name(c: &MeterCheck, fields: &str) -> String {
    format!(
        "the {} meter's reading follows {fields}, which the {} meter does not show: a correction of that meter, not a load on the rail",
        c.meter, c.other
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A load seen by both meters has share ≈ 1, an artefact of one ≈ 0 (noise on the other).
    #[test]
    fn a_load_shows_on_both_meters_and_an_artefact_on_one() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let n = 400;
        let z: Vec<f64> = (0..n)
            .map(|i| 3.0 * f64::from(u8::from(i % 3 == 0)))
            .collect();
        let noise: Vec<f64> = (0..n).map(|_| 2.0 * (rng.random::<f64>() - 0.5)).collect();
        // Load: both meters carry z, the difference only noise.
        let load: Vec<f64> = noise.clone();
        // Artefact of the target: it carries z, the other not.
        let art: Vec<f64> = noise.iter().zip(&z).map(|(e, z)| e - z).collect();
        let c = checks(Target::Mbs, &load, std::slice::from_ref(&z));
        let c = c[0].as_ref().unwrap();
        assert_eq!(c.verdict, MeterVerdict::Load, "{c:?}");
        assert!((c.share - 1.0).abs() < 0.1, "{c:?}");
        let c = checks(Target::Mbs, &art, std::slice::from_ref(&z));
        let c = c[0].as_ref().unwrap();
        assert_eq!(c.verdict, MeterVerdict::Artefact, "{c:?}");
        assert!(c.share.abs() < 0.1 && c.other == "battery", "{c:?}");
    }

    /// A session of trials every 16 s with one reading of each meter in each pre-idle: the
    /// diagnosed (main-board) meter's rest readings `target`, the other meter's `other`.
    fn session(target: &[f64], other: &[f64]) -> (PowerSeries, PowerSeries, Vec<TrialMeta>) {
        use crate::diagnose::hypotheses::N_EXTRA;
        use crate::diagnose::reading_rows::BusModel;
        let metas = (0..target.len())
            .map(|i| {
                let t0 = 16.0 * i as f64;
                TrialMeta {
                    window: crate::trial::TrialWindow {
                        index: i,
                        t_pre_start: t0,
                        t_traj_start: t0 + 2.0,
                        t_traj_end: t0 + 12.0,
                        t_post_end: t0 + 14.0,
                        t_return_end: t0 + 15.0,
                        joints_moved: Vec::new(),
                        qdot_max_cmd: f64::NAN,
                        qdot_max_meas: f64::NAN,
                    },
                    tau0_sq: [0.0; crate::N_JOINTS],
                    extra0: [0.0; N_EXTRA],
                    sigma_omega: 0.0,
                    bus: BusModel {
                        model: crate::power::PowerModel::PAPER,
                        volts: 48.0,
                    },
                    n_samples: 0,
                    width_s: None,
                }
            })
            .collect();
        let t: Vec<f64> = (0..target.len()).map(|i| 16.0 * i as f64 + 1.5).collect();
        let series = |w: &[f64]| PowerSeries {
            t: t.clone(),
            watts: w.to_vec(),
        };
        (series(target), series(other), metas)
    }

    /// Deterministic noise in [−½, ½) per trial (`k` picks the sequence).
    fn noise(i: usize, k: usize) -> f64 {
        ((i * 7919 + k * 104_729) % 97) as f64 / 97.0 - 0.5
    }

    /// A smooth drift of the rail's rest power (a slow swing of 0.3 W, both meters) is not told as
    /// a step: the best of the steps fitted alone takes its swing (+0.40 W 528 s after the first
    /// trial, located, before the step had to stand out of the rail's slow drift).
    #[test]
    fn a_smooth_drift_is_not_called_a_step() {
        let n = 56;
        let u = |i: usize| i as f64 / (n - 1) as f64;
        let target: Vec<f64> = (0..n)
            .map(|i| {
                120.0 + 0.3 * (std::f64::consts::TAU * 0.9 * u(i) + 3.0).sin() + 0.6 * noise(i, 0)
            })
            .collect();
        let other: Vec<f64> = (0..n)
            .map(|i| target[i] + 15.0 + 3.0 * noise(i, 1))
            .collect();
        let (p1, p2, metas) = session(&target, &other);
        let d = compare(Target::Mbs, &p1, &p2, &metas, 0.0, 0.3, 1e-3);
        assert!(d.as_ref().is_none_or(|d| d.form_at.2.is_none()), "{d:?}");
    }

    /// A 1.5 W step of the main-board meter alone, 0.37 of the way through the session, beside a
    /// smooth 1 W rise of the rail that both meters show, is that meter's artefact at its place
    /// and size (the step fitted alone, or a line, took the rail's rise with it: a 3.3 W linear
    /// "artefact").
    #[test]
    fn a_step_in_one_meter_is_named_its_artefact() {
        let n = 56;
        let u = |i: usize| i as f64 / (n - 1) as f64;
        let rail = |i: usize| 0.5 * (1.0 + ((u(i) - 0.7) / 0.08).tanh());
        let target: Vec<f64> = (0..n)
            .map(|i| 120.0 + rail(i) + 1.5 * f64::from(u8::from(u(i) > 0.37)) + 0.3 * noise(i, 0))
            .collect();
        let other: Vec<f64> = (0..n).map(|i| 135.0 + rail(i) + noise(i, 1)).collect();
        let (p1, p2, metas) = session(&target, &other);
        let d = compare(Target::Mbs, &p1, &p2, &metas, 0.0, 0.3, 1e-3).expect("the step is found");
        let (_, span, step) = d.form_at;
        assert!(
            d.check.artefact() && d.name.contains("artefact of the main-board meter"),
            "{d:?}"
        );
        assert!(
            step.is_some_and(|s| (s - 0.37).abs() < 1.0 / span * 16.0),
            "{d:?}"
        );
        assert!((d.change_w - 1.5).abs() < 0.2, "{d:?}");
    }
}
