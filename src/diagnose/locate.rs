//! Locate the mismatch: held-out power residuals broken down by joint, phase and regime
//! (driving vs braking, cold vs hot, slow vs fast, single vs multi-joint, calm vs swaying body,
//! early vs late), the sensor-lag scan, and the correlation of what no hypothesis explains with
//! recorded signals and derived features (per trial, with a Bonferroni guard).
//!
//! Groups are tested at trial level (each trial contributes the mean residual of its rows in
//! the group), because readings of one trial share the trial's baseline and are not independent.

use super::hypotheses::{N_LOCATE, joint_name, locate_name};
use super::reading_rows::{Rows, TrialMeta};
use super::stats::{pearson, t_upper_tail};
use crate::lsq::solve_normal;
use crate::trial::Phase;
use nalgebra::DMatrix;

use crate::{N_JOINTS, N_PARAMS};

/// Residual statistics of one group of readings.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Group {
    /// What the group holds.
    pub label: String,
    /// Number of readings.
    pub n_rows: usize,
    /// Number of trials contributing.
    pub n_trials: usize,
    /// Mean residual (measured − predicted) [W]; positive = power under-predicted.
    pub bias_w: f64,
    /// RMS residual [W].
    pub rmse_w: f64,
    /// Two-sided p-value of "mean residual = 0" over the contributing trials.
    pub p_value: f64,
}

/// Residuals split one way.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Breakdown {
    /// The dimension of the split (`joint`, `phase`, `regime`, …).
    pub by: String,
    /// Its groups.
    pub groups: Vec<Group>,
}

/// One trial's held-out residual.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct TrialResidual {
    /// Trial index (segmentation numbering).
    pub trial: usize,
    /// Mean residual of the trial's readings [W].
    pub mean_w: f64,
    /// Number of readings.
    pub n_rows: usize,
}

/// A signal the unexplained residual correlates with.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Correlate {
    /// Feature name (joint + quantity).
    pub feature: String,
    /// Pearson correlation of per-trial mean residual and per-trial mean feature.
    pub r: f64,
    /// Bonferroni-adjusted two-sided p-value (over all features tried).
    pub p_adjusted: f64,
    /// Significant at the diagnosis' level.
    pub significant: bool,
    /// Trials that carry it most (largest contribution to the correlation), segmentation numbering.
    pub trials: Vec<usize>,
    /// Whether it is a slow state — a motor temperature or session time: what a loss term that
    /// changes with a slow state leaves in the residual per trial (a joint's position or speed
    /// is also where the base model's own misfit shows: in a null fuzz session, 1894880942, the
    /// residual followed a wrist position at p = 1.6e-3).
    #[serde(skip)]
    pub slow: bool,
}

/// Per-trial sums of `(trial, value)` pairs (trials < `n`) and the values counted.
fn trial_sums(pairs: impl Iterator<Item = (usize, f64)>, n: usize) -> (Vec<f64>, Vec<usize>) {
    let (mut sum, mut cnt) = (vec![0.0; n], vec![0usize; n]);
    for (t, v) in pairs {
        sum[t] += v;
        cnt[t] += 1;
    }
    (sum, cnt)
}

/// Per-trial means of `(trial, value)` pairs (trials < `n`); `None` for a trial without any.
pub(crate) fn trial_means(pairs: impl Iterator<Item = (usize, f64)>, n: usize) -> Vec<Option<f64>> {
    let (sum, cnt) = trial_sums(pairs, n);
    let mean = |(s, c): (f64, usize)| (c > 0).then(|| s / c as f64);
    sum.into_iter().zip(cnt).map(mean).collect()
}

/// The residual statistics of the readings `members` of `rows`.
fn group_stats(
    label: String,
    rows: &Rows,
    resid: &[f64],
    members: &[usize],
    n_trials: usize,
) -> Group {
    let pairs = members.iter().map(|&r| (rows.trial[r], resid[r]));
    let means: Vec<f64> = trial_means(pairs, n_trials).into_iter().flatten().collect();
    let sq: f64 = members.iter().map(|&r| resid[r] * resid[r]).sum();
    let n = members.len();
    let bias = if n > 0 {
        members.iter().map(|&r| resid[r]).sum::<f64>() / n as f64
    } else {
        0.0
    };
    let p_value = if means.len() >= 3 {
        let m = means.iter().sum::<f64>() / means.len() as f64;
        let var = means.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (means.len() - 1) as f64;
        let t = m / (var / means.len() as f64).sqrt().max(1e-300);
        (2.0 * t_upper_tail(t.abs(), (means.len() - 1) as f64)).min(1.0)
    } else {
        1.0
    };
    Group {
        label,
        n_rows: n,
        n_trials: means.len(),
        bias_w: bias,
        rmse_w: if n > 0 { (sq / n as f64).sqrt() } else { 0.0 },
        p_value,
    }
}

/// Tercile cut points of `values`.
fn terciles(values: &[f64]) -> (f64, f64) {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return (0.0, 0.0);
    }
    (v[v.len() / 3], v[2 * v.len() / 3])
}

/// All breakdowns of the residuals `resid` (measured − predicted, held out) of `rows`: by what
/// moved (joint moved, phase, driving/braking/holding regime, braking joint), then by the
/// conditions it moved in (temperature, speed, number of joints moving, body sway (IMU),
/// session time).
pub(crate) fn breakdowns(
    rows: &Rows,
    trials: &[TrialMeta],
    resid: &[f64],
    joint_names: &[String],
) -> Vec<Breakdown> {
    let n_trials = trials.len();
    let name = |j: usize| joint_name(joint_names, j);
    let group = |label: String, f: &dyn Fn(usize) -> bool| {
        let m: Vec<usize> = (0..rows.len()).filter(|&r| f(r)).collect();
        group_stats(label, rows, resid, &m, n_trials)
    };
    let by = |by: &str, groups: Vec<Group>| Breakdown {
        by: by.into(),
        groups,
    };
    let split3 = |name: &str, labels: [&str; 3], unit: &str, value: &[f64]| {
        let (a, b) = terciles(value);
        // The tercile of `v` (NaN in the last, as a value not below either cut).
        let which = |v: f64| [a, b].iter().filter(|&&c| v >= c || v.is_nan()).count();
        let labels = [
            format!("{} (< {a:.1} {unit})", labels[0]),
            format!("{} ({a:.1}–{b:.1} {unit})", labels[1]),
            format!("{} (≥ {b:.1} {unit})", labels[2]),
        ];
        let groups = labels.into_iter().enumerate();
        by(
            name,
            groups
                .map(|(k, l)| group(l, &|r| which(value[r]) == k))
                .collect(),
        )
    };
    let moved = |r: usize| &trials[rows.trial[r]].window.joints_moved;
    let mut out = vec![by(
        "joint",
        (0..N_JOINTS)
            .map(|j| group(format!("{} moved", name(j)), &|r| moved(r).contains(&j)))
            .collect(),
    )];
    let phases = [
        (Phase::Trajectory, "trajectory"),
        (Phase::PostIdle, "post-idle"),
        (Phase::Return, "return"),
    ];
    let phases = phases
        .iter()
        .map(|(p, l)| group((*l).into(), &|r| rows.phase[r] == *p));
    out.push(by("phase", phases.collect()));
    // Driving vs braking by the sign of the window's total mechanical power Σ τ_i q̇_i.
    let mech: Vec<f64> = rows.x.iter().map(|x| x[..N_JOINTS].iter().sum()).collect();
    let moving: Vec<bool> = (rows.x.iter())
        .map(|x| x[2 * N_JOINTS..3 * N_JOINTS].iter().sum::<f64>() > 0.05)
        .collect();
    out.push(by(
        "regime",
        vec![
            group("driving (Σ τq̇ > 0)".into(), &|r| {
                moving[r] && mech[r] > 0.0
            }),
            group("braking (Σ τq̇ < 0)".into(), &|r| {
                moving[r] && mech[r] <= 0.0
            }),
            group("holding (no motion)".into(), &|r| !moving[r]),
        ],
    ));
    let braking =
        (0..N_JOINTS).map(|j| group(format!("{} braking", name(j)), &|r| rows.x[r][j] < -0.2));
    out.push(by("braking joint", braking.collect()));
    if !rows.locate.is_empty() {
        let temp: Vec<f64> = (rows.locate.iter())
            .map(|l| (0..N_JOINTS).map(|j| l[5 * j + 3]).sum::<f64>() / N_JOINTS as f64)
            .collect();
        out.push(split3("temperature", ["cold", "warm", "hot"], "°C", &temp));
    }
    let speed: Vec<f64> = (rows.trial.iter())
        .map(|&t| trials[t].window.speed_level())
        .collect();
    out.push(split3("speed", ["slow", "medium", "fast"], "rad/s", &speed));
    let counts = [
        (1usize, 1usize, "single joint"),
        (2, 2, "two joints"),
        (3, N_JOINTS, "three or more joints"),
    ];
    let counts = counts
        .iter()
        .map(|&(lo, hi, l)| group(l.into(), &|r| (lo..=hi).contains(&moved(r).len())));
    out.push(by("joints moving", counts.collect()));
    let mut sig: Vec<f64> = trials.iter().map(|t| t.sigma_omega).collect();
    sig.sort_by(f64::total_cmp);
    let calm = 1.5 * sig.get(sig.len() / 2).copied().unwrap_or(0.0);
    let sigma = |r: usize| trials[rows.trial[r]].sigma_omega;
    out.push(by(
        "body (IMU)",
        vec![
            group(
                format!("calm (σ_ω ≤ 1.5 × median = {calm:.3} rad/s)"),
                &|r| sigma(r) <= calm,
            ),
            group("swaying (σ_ω above)".into(), &|r| sigma(r) > calm),
        ],
    ));
    out.push(split3(
        "session time",
        ["early", "middle", "late"],
        "s",
        &rows.t,
    ));
    out
}

/// The most significant group over all breakdowns (at least 3 trials; the one-group "joint"
/// splits overlap, so they compete like the others).
pub(crate) fn worst(breakdowns: &[Breakdown]) -> Option<(String, Group)> {
    breakdowns
        .iter()
        .flat_map(|b| b.groups.iter().map(move |g| (b.by.clone(), g.clone())))
        .filter(|(_, g)| g.n_trials >= 3)
        .min_by(|a, b| {
            a.1.p_value
                .total_cmp(&b.1.p_value)
                .then(b.1.bias_w.abs().total_cmp(&a.1.bias_w.abs()))
        })
}

/// Per-trial mean residuals, largest magnitude first.
pub(crate) fn trial_residuals(
    rows: &Rows,
    trials: &[TrialMeta],
    resid: &[f64],
) -> Vec<TrialResidual> {
    let pairs = rows.trial.iter().copied().zip(resid.iter().copied());
    let (sum, cnt) = trial_sums(pairs, trials.len());
    let mut out: Vec<TrialResidual> = (0..trials.len())
        .filter(|&t| cnt[t] > 0)
        .map(|t| TrialResidual {
            trial: trials[t].window.index,
            mean_w: sum[t] / cnt[t] as f64,
            n_rows: cnt[t],
        })
        .collect();
    out.sort_by(|a, b| b.mean_w.abs().total_cmp(&a.mean_w.abs()));
    out
}

/// Correlate per-trial mean residuals with per-trial mean descriptor features (plus session
/// time, body sway and speed level). When the base model was refitted (`base_fitted`), each
/// feature is first made orthogonal (per reading) to the base regressors φ, so what the refit
/// already absorbed neither hides nor fakes a correlate (a partial correlation); against a fixed
/// twin model the residual still holds that part, so the raw features are used. Returns the
/// strongest `top` correlates, most significant first.
pub(crate) fn correlates(
    rows: &Rows,
    trials: &[TrialMeta],
    resid: &[f64],
    joint_names: &[String],
    base_fitted: bool,
    level: f64,
    top: usize,
) -> Vec<Correlate> {
    let nt = trials.len();
    let nf = N_LOCATE + 3;
    let n = rows.len();
    // Row-level features, then their part orthogonal to φ.
    let mut f = DMatrix::zeros(n, nf);
    for r in 0..n {
        if let Some(l) = rows.locate.get(r) {
            for k in 0..N_LOCATE {
                f[(r, k)] = l[k];
            }
        }
        f[(r, N_LOCATE)] = rows.t[r];
        f[(r, N_LOCATE + 1)] = trials[rows.trial[r]].sigma_omega;
        f[(r, N_LOCATE + 2)] = trials[rows.trial[r]].window.speed_level();
    }
    let width = if base_fitted { N_PARAMS + 1 } else { 1 };
    let x = DMatrix::from_fn(
        n,
        width,
        |r, c| {
            if c + 1 < width { rows.x[r][c] } else { 1.0 }
        },
    );
    if let Some(b) = solve_normal(&(x.transpose() * &x), &(x.transpose() * &f), 1e-9) {
        f -= &x * b;
    }
    let (res, cnt) = trial_sums(rows.trial.iter().copied().zip(resid.iter().copied()), nt);
    let mut feat = vec![vec![0.0; nf]; nt];
    for r in 0..n {
        for k in 0..nf {
            feat[rows.trial[r]][k] += f[(r, k)];
        }
    }
    let keep: Vec<usize> = (0..nt).filter(|&t| cnt[t] > 0).collect();
    for &t in &keep {
        feat[t].iter_mut().for_each(|v| *v /= cnt[t] as f64);
    }
    let y: Vec<f64> = keep.iter().map(|&t| res[t] / cnt[t] as f64).collect();
    let names = |k: usize| match k {
        k if k < N_LOCATE => locate_name(k, joint_names),
        k if k == N_LOCATE => "session time".to_string(),
        k if k == N_LOCATE + 1 => "body sway σ_ω (IMU)".to_string(),
        _ => "trial speed level".to_string(),
    };
    let mut out: Vec<Correlate> = (0..nf)
        .filter(|&k| !(rows.locate.is_empty() && k < N_LOCATE))
        .map(|k| {
            let x: Vec<f64> = keep.iter().map(|&t| feat[t][k]).collect();
            let (r, p) = pearson(&x, &y);
            let p_adjusted = (p * nf as f64).min(1.0);
            let mx = x.iter().sum::<f64>() / x.len().max(1) as f64;
            let my = y.iter().sum::<f64>() / y.len().max(1) as f64;
            let mut contrib: Vec<(f64, usize)> = keep
                .iter()
                .enumerate()
                .map(|(i, &t)| ((x[i] - mx) * (y[i] - my) * r.signum(), t))
                .collect();
            contrib.sort_by(|a, b| b.0.total_cmp(&a.0));
            let trials_carrying = contrib
                .iter()
                .take(5)
                .filter(|c| c.0 > 0.0)
                .map(|c| trials[c.1].window.index)
                .collect();
            Correlate {
                feature: names(k),
                r,
                p_adjusted,
                significant: p_adjusted < level,
                trials: trials_carrying,
                slow: k == N_LOCATE || (k < 5 * N_JOINTS && k % 5 == 3),
            }
        })
        .collect();
    out.sort_by(|a, b| {
        a.p_adjusted
            .total_cmp(&b.p_adjusted)
            .then(b.r.abs().total_cmp(&a.r.abs()))
    });
    out.truncate(top);
    out
}
