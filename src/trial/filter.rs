//! The paper's two trial filters and the one cascade that applies them, each rejection recorded
//! with its statistic.
//!
//! * Balance contamination: the stabiliser's leg motion leaks into the arm rail's power and shows
//!   up as body sway in the pelvis IMU. σ_ω = std(‖ω_body‖) over the trajectory window; a trial is
//!   rejected when σ_ω > k · median(σ_ω) (k = 2.5 in the paper).
//! * Statistical outliers: fit, reject trials whose residual lies more than 3 σ̂ from the residual
//!   mean, refit; repeated for a configurable number of passes (2 in the paper).
//!
//! [`Cascade`] runs the IMU filter, then the residual passes; what a "residual" is belongs to the
//! caller (a refit per pass for identification and diagnosis, a fixed model for validation and
//! the replay overlay), handed in as a closure.

use std::fmt;

use crate::signals::Recording;

/// Which filter rejected a trial.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum RejectReason {
    /// σ_ω above k × median: body sway, power contaminated by balance compensation.
    #[serde(rename = "imu_sigma")]
    ImuSway,
    /// Residual beyond n σ̂ in a residual-rejection pass.
    #[serde(rename = "residual_3sigma")]
    Residual,
    /// Not enough data in the trial to use it (too few samples or readings).
    #[serde(rename = "unusable")]
    Unusable,
}

impl RejectReason {
    /// Short name as written in model files and logs (`imu_sigma`, `residual_3sigma`, `unusable`).
    pub fn name(self) -> &'static str {
        match self {
            RejectReason::ImuSway => "imu_sigma",
            RejectReason::Residual => "residual_3sigma",
            RejectReason::Unusable => "unusable",
        }
    }
}

/// One rejected trial: which filter, the statistic it tested and the threshold it exceeded.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Rejection {
    /// Index of the recording in the input list (0 for a single session).
    pub session: usize,
    /// Trial index within its session.
    pub trial: usize,
    /// Filter.
    #[serde(rename = "filter")]
    pub reason: RejectReason,
    /// The statistic that exceeded the threshold (σ_ω [rad/s], residual [W], or a count for
    /// [`RejectReason::Unusable`]).
    #[serde(with = "crate::util::nan_as_null")]
    pub statistic: f64,
    /// The threshold it exceeded (k·median σ_ω, the distance n·σ̂, or the minimum count).
    #[serde(with = "crate::util::nan_as_null")]
    pub threshold: f64,
    /// Residual pass number (1-based; 0 for the other filters).
    #[serde(default)]
    pub pass: usize,
    /// What was missing, for [`RejectReason::Unusable`] (empty otherwise).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub detail: String,
}

impl Rejection {
    /// A trial that could not be used, e.g. `only 2 joint samples in the pre-idle window`.
    pub fn unusable(session: usize, trial: usize, detail: impl Into<String>) -> Rejection {
        Rejection {
            session,
            trial,
            reason: RejectReason::Unusable,
            statistic: f64::NAN,
            threshold: f64::NAN,
            pass: 0,
            detail: detail.into(),
        }
    }

    /// Trial `s` rejected by the filter `reason`: its statistic beyond `threshold` (in residual
    /// pass `pass`, 0 for the other filters).
    fn beyond(s: &TrialStat, reason: RejectReason, threshold: f64, pass: usize) -> Rejection {
        Rejection {
            session: s.session,
            trial: s.trial,
            reason,
            statistic: s.value,
            threshold,
            pass,
            detail: String::new(),
        }
    }
}

/// One line for humans, e.g. `trial 11: IMU sway σ_ω = 0.0810 rad/s > 0.0040 (k × median)`;
/// trials of a second or later session are prefixed with the session index.
impl fmt::Display for Rejection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "session {} trial {}: {}",
            self.session,
            self.trial,
            self.why()
        )
    }
}

impl Rejection {
    /// Why the trial was rejected, without the session/trial prefix of `Display`.
    pub fn why(&self) -> String {
        match self.reason {
            RejectReason::ImuSway => format!(
                "IMU sway σ_ω = {:.4} rad/s > {:.4} (k × median)",
                self.statistic, self.threshold
            ),
            RejectReason::Residual => format!(
                "residual {:+.3} W beyond {:.3} W (pass {})",
                self.statistic, self.threshold, self.pass
            ),
            RejectReason::Unusable => format!("unusable: {}", self.detail),
        }
    }
}

/// Settings of the filter cascade (the paper: k = 2.5, two passes at 3 σ̂).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Cascade {
    /// IMU filter factor k (reject σ_ω > k·median); None disables the filter.
    pub imu_k: Option<f64>,
    /// Residual-rejection passes (0 disables).
    pub passes: usize,
    /// Residual-rejection width n (reject |r − mean| > n·σ̂).
    pub n_sigma: f64,
    /// Fewer trials with a residual than this end the residual passes (σ̂ would be meaningless).
    pub min_trials: usize,
}

impl Default for Cascade {
    fn default() -> Self {
        Cascade {
            imu_k: Some(2.5),
            passes: 2,
            n_sigma: 3.0,
            min_trials: 3,
        }
    }
}

/// Whether `rejections` hold (session, trial).
pub fn is_rejected(rejections: &[Rejection], session: usize, trial: usize) -> bool {
    rejections
        .iter()
        .any(|r| r.session == session && r.trial == trial)
}

impl Cascade {
    /// The IMU filter alone over every trial's σ_ω (none when disabled).
    pub fn imu(&self, sigmas: &[TrialStat]) -> Vec<Rejection> {
        self.imu_k.map(|k| imu_sway(sigmas, k)).unwrap_or_default()
    }

    /// The residual passes after earlier rejections. `residuals(rejected)` returns the mean
    /// residual of every trial not yet rejected — a non-finite value for a trial without any
    /// reading, which is then rejected as unusable; the caller refits or keeps its model fixed.
    /// Stops at the first pass that rejects nothing, or when fewer than `min_trials` residuals
    /// remain.
    pub fn residual_passes<E>(
        &self,
        rejections: &mut Vec<Rejection>,
        mut residuals: impl FnMut(&[Rejection]) -> Result<Vec<TrialStat>, E>,
    ) -> Result<(), E> {
        for pass in 1..=self.passes {
            let all = residuals(rejections)?;
            if !self.residual_pass(pass, rejections, all) {
                break;
            }
        }
        Ok(())
    }

    /// Residual pass `pass` (1-based) of [`Cascade::residual_passes`] on the residuals `all` of
    /// the trials not yet rejected, for callers that run many trial sets in step (the fleet's
    /// groups share one scan per pass). Returns whether another pass is due (this one rejected
    /// something and `pass` < [`Cascade::passes`]).
    pub fn residual_pass(
        &self,
        pass: usize,
        rejections: &mut Vec<Rejection>,
        all: Vec<TrialStat>,
    ) -> bool {
        let (stats, empty): (Vec<TrialStat>, Vec<TrialStat>) =
            all.into_iter().partition(|r| r.value.is_finite());
        if stats.len() < self.min_trials.max(3) {
            return false;
        }
        let new = three_sigma(&stats, self.n_sigma, pass);
        let unusable: Vec<Rejection> = empty
            .iter()
            .map(|r| Rejection::unusable(r.session, r.trial, "no power readings in the trial"))
            .collect();
        let changed = !new.is_empty() || !unusable.is_empty();
        rejections.extend(unusable);
        rejections.extend(new);
        changed && pass < self.passes
    }

    /// IMU filter, then the residual passes.
    pub fn run<E>(
        &self,
        sigmas: &[TrialStat],
        residuals: impl FnMut(&[Rejection]) -> Result<Vec<TrialStat>, E>,
    ) -> Result<Vec<Rejection>, E> {
        let mut rejections = self.imu(sigmas);
        self.residual_passes(&mut rejections, residuals)?;
        Ok(rejections)
    }
}

/// A trial's identity and one statistic of it, as the filters see it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrialStat {
    /// Index of the recording in the input list.
    pub session: usize,
    /// Trial index within its session.
    pub trial: usize,
    /// The statistic (σ_ω [rad/s] or mean residual [W]); not finite when the trial has no data.
    pub value: f64,
}

impl TrialStat {
    /// (session, trial, value).
    pub fn new(session: usize, trial: usize, value: f64) -> TrialStat {
        TrialStat {
            session,
            trial,
            value,
        }
    }
}

/// σ_ω = std(‖ω_body‖) of the pelvis gyroscope over the samples with t in [t0, t1]; 0 when fewer
/// than two samples fall inside.
pub fn sigma_omega(rec: &Recording, t0: f64, t1: f64) -> f64 {
    let s = &rec.state;
    let n = s.t.len().min(s.gyro.len());
    let (i0, i1) = (
        s.t[..n].partition_point(|&x| x < t0),
        s.t[..n].partition_point(|&x| x <= t1),
    );
    let norms: Vec<f64> = s.gyro[i0..i1]
        .iter()
        .map(|g| (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt())
        .collect();
    std_dev(&norms)
}

fn std_dev(v: &[f64]) -> f64 {
    if v.len() < 2 {
        return 0.0;
    }
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

fn median(v: &[f64]) -> f64 {
    let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if s.is_empty() {
        return f64::NAN;
    }
    s.sort_by(f64::total_cmp);
    let m = s.len() / 2;
    if s.len() % 2 == 1 {
        s[m]
    } else {
        0.5 * (s[m - 1] + s[m])
    }
}

/// The IMU balance filter as the viewer shows it: its statistic per trial and its threshold.
#[derive(Debug, Clone, Default)]
pub struct ImuFilterMarks {
    /// The threshold factor k (threshold = k × median σ|ω|).
    pub k: f64,
    /// The threshold [rad/s].
    pub threshold: f64,
    /// Per trial: window start, end [s] and σ|ω| over it [rad/s].
    pub spans: Vec<(f64, f64, f64)>,
}

impl ImuFilterMarks {
    /// The marks of a filter of factor `k` over the trials' `spans` (window start, end, σ|ω|),
    /// its threshold the one [`imu_sway`] applies; `None` when the filter is off (`k` `None`)
    /// or the threshold is not finite.
    pub fn new(k: Option<f64>, spans: Vec<(f64, f64, f64)>) -> Option<ImuFilterMarks> {
        let k = k?;
        let sigmas: Vec<TrialStat> = spans.iter().map(|s| TrialStat::new(0, 0, s.2)).collect();
        let threshold = imu_threshold(&sigmas, k);
        threshold.is_finite().then_some(ImuFilterMarks {
            k,
            threshold,
            spans,
        })
    }
}

/// The IMU filter's threshold: k × the median of the finite σ_ω.
fn imu_threshold(sigmas: &[TrialStat], k: f64) -> f64 {
    k * median(&sigmas.iter().map(|s| s.value).collect::<Vec<_>>())
}

/// IMU balance-contamination filter: reject σ_ω > k · median(σ_ω) over the given trials.
pub fn imu_sway(sigmas: &[TrialStat], k: f64) -> Vec<Rejection> {
    let threshold = imu_threshold(sigmas, k);
    sigmas
        .iter()
        .filter(|s| s.value > threshold)
        .map(|s| Rejection::beyond(s, RejectReason::ImuSway, threshold, 0))
        .collect()
}

/// One pass of residual rejection: trials whose residual is more than `n_sigma` · σ̂ from the
/// mean residual (σ̂ = sample standard deviation of the residuals). `pass` is recorded as given.
pub fn three_sigma(residuals: &[TrialStat], n_sigma: f64, pass: usize) -> Vec<Rejection> {
    let values: Vec<f64> = residuals.iter().map(|r| r.value).collect();
    if values.len() < 3 {
        return Vec::new();
    }
    let mean = values.iter().sum::<f64>() / values.len() as f64;
    let threshold = n_sigma * std_dev(&values);
    residuals
        .iter()
        .filter(|r| (r.value - mean).abs() > threshold)
        .map(|r| Rejection::beyond(r, RejectReason::Residual, threshold, pass))
        .collect()
}
