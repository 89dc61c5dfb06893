//! The paper's two outlier filters, applied per trial, each rejection recorded with its statistic.
//!
//! * Balance contamination: the stabiliser's leg motion leaks into the arm rail's power and shows
//!   up as body sway in the pelvis IMU. σ_ω = std(‖ω_body‖) over the trajectory window; a trial is
//!   rejected when σ_ω > k · median(σ_ω) (k = 2.5 in the paper).
//! * Statistical outliers: fit, reject trials whose residual lies more than 3 σ̂ from the residual
//!   mean, refit; repeated for a configurable number of passes (2 in the paper). The fitting is the
//!   caller's; [`three_sigma`] judges one pass.

use crate::signals::Recording;

/// Which filter rejected a trial.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum RejectReason {
    /// σ_ω above k × median: body sway, power contaminated by balance compensation.
    ImuSway,
    /// Residual beyond n σ̂ in a residual-rejection pass.
    Residual,
}

/// One rejected trial.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Rejection {
    /// Index of the recording in the identification's input list.
    pub session: usize,
    /// Trial index within its session.
    pub trial: usize,
    /// Filter.
    pub reason: RejectReason,
    /// The statistic that exceeded the threshold (σ_ω [rad/s] or residual [W]).
    pub statistic: f64,
    /// The threshold it exceeded (k·median σ_ω, or mean ± n·σ̂ as the distance n·σ̂).
    pub threshold: f64,
    /// Residual pass number (1-based; 0 for the IMU filter).
    pub pass: usize,
}

impl Rejection {
    /// One line for humans, e.g. `trial 11: IMU sway σ_ω = 0.081 rad/s > 0.004`.
    pub fn describe(&self) -> String {
        match self.reason {
            RejectReason::ImuSway => format!(
                "session {} trial {}: IMU sway σ_ω = {:.4} rad/s > {:.4} (k × median)",
                self.session, self.trial, self.statistic, self.threshold
            ),
            RejectReason::Residual => format!(
                "session {} trial {}: residual {:+.3} W beyond {:.3} W (pass {})",
                self.session, self.trial, self.statistic, self.threshold, self.pass
            ),
        }
    }
}

/// A trial's identity and statistic as the filters see it: (session, trial, value).
pub type TrialStat = (usize, usize, f64);

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

/// IMU balance-contamination filter: reject σ_ω > k · median(σ_ω) over the given trials.
pub fn imu_sway(sigmas: &[TrialStat], k: f64) -> Vec<Rejection> {
    let threshold = k * median(&sigmas.iter().map(|s| s.2).collect::<Vec<_>>());
    sigmas
        .iter()
        .filter(|s| s.2 > threshold)
        .map(|&(session, trial, statistic)| Rejection {
            session,
            trial,
            reason: RejectReason::ImuSway,
            statistic,
            threshold,
            pass: 0,
        })
        .collect()
}

/// One pass of residual rejection: trials whose residual is more than `n_sigma` · σ̂ from the
/// mean residual (σ̂ = sample standard deviation of the residuals). `pass` is recorded as given.
pub fn three_sigma(residuals: &[TrialStat], n_sigma: f64, pass: usize) -> Vec<Rejection> {
    let values: Vec<f64> = residuals.iter().map(|r| r.2).collect();
    if values.len() < 3 {
        return Vec::new();
    }
    let mean = values.iter().sum::<f64>() / values.len() as f64;
    let threshold = n_sigma * std_dev(&values);
    residuals
        .iter()
        .filter(|r| (r.2 - mean).abs() > threshold)
        .map(|&(session, trial, statistic)| Rejection {
            session,
            trial,
            reason: RejectReason::Residual,
            statistic,
            threshold,
            pass,
        })
        .collect()
}
