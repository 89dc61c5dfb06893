//! Small statistics the significance rules need: Student-t tail probabilities (via the
//! regularised incomplete beta function), a one-sided paired t-test and Pearson correlation.

/// ln Γ(x) for x > 0 (Lanczos approximation, |error| < 2e-10).
fn ln_gamma(x: f64) -> f64 {
    const C: [f64; 6] = [
        76.180_091_729_471_46,
        -86.505_320_329_416_77,
        24.014_098_240_830_91,
        -1.231_739_572_450_155,
        0.001_208_650_973_866_179,
        -0.000_005_395_239_384_953,
    ];
    let tmp = x + 5.5 - (x + 0.5) * (x + 5.5).ln();
    let mut ser = 1.000_000_000_190_015;
    for (j, c) in C.iter().enumerate() {
        ser += c / (x + 1.0 + j as f64);
    }
    -tmp + (2.506_628_274_631_000_5 * ser / x).ln()
}

/// Continued fraction of the incomplete beta function (modified Lentz).
fn beta_cf(a: f64, b: f64, x: f64) -> f64 {
    let tiny = |v: f64| if v.abs() < 1e-300 { 1e-300 } else { v };
    let (qab, qap, qam) = (a + b, a + 1.0, a - 1.0);
    let (mut c, mut d) = (1.0, 1.0 / tiny(1.0 - qab * x / qap));
    let mut h = d;
    for m in 1..300 {
        let m = m as f64;
        let m2 = 2.0 * m;
        let mut del = 1.0;
        // The even and the odd step of the fraction.
        for aa in [
            m * (b - m) * x / ((qam + m2) * (a + m2)),
            -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2)),
        ] {
            d = 1.0 / tiny(1.0 + aa * d);
            c = tiny(1.0 + aa / c);
            del = d * c;
            h *= del;
        }
        if (del - 1.0).abs() < 1e-14 {
            break;
        }
    }
    h
}

/// Regularised incomplete beta function I_x(a, b).
pub fn inc_beta(a: f64, b: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let ln_front = ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b) + a * x.ln() + b * (1.0 - x).ln();
    if x < (a + 1.0) / (a + b + 2.0) {
        ln_front.exp() * beta_cf(a, b, x) / a
    } else {
        1.0 - ln_front.exp() * beta_cf(b, a, 1.0 - x) / b
    }
}

/// P(T > t) for Student's t with `df` degrees of freedom.
pub fn t_upper_tail(t: f64, df: f64) -> f64 {
    if !t.is_finite() {
        return if t > 0.0 { 0.0 } else { 1.0 };
    }
    let half = 0.5 * inc_beta(0.5 * df, 0.5, df / (df + t * t));
    if t >= 0.0 { half } else { 1.0 - half }
}

/// Standard normal upper tail P(Z > z) (complementary error function, |error| < 1.2e-7).
pub fn normal_upper_tail(z: f64) -> f64 {
    let x = z.abs() / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.5 * x);
    let erfc = t
        * (-x * x - 1.265_512_23
            + t * (1.000_023_68
                + t * (0.374_091_96
                    + t * (0.096_784_18
                        + t * (-0.186_288_06
                            + t * (0.278_868_07
                                + t * (-1.135_203_98
                                    + t * (1.488_515_87
                                        + t * (-0.822_152_23 + t * 0.170_872_77)))))))))
            .exp();
    if z >= 0.0 {
        0.5 * erfc
    } else {
        1.0 - 0.5 * erfc
    }
}

/// One-sided Wilcoxon signed-rank test that the paired differences `d` are shifted above zero
/// (normal approximation with tie and continuity corrections): (z, p-value). Zeros are dropped;
/// fewer than 6 non-zero differences give p = 1. Rank-based, so a few trials with huge
/// improvements neither dominate nor hide a consistent shift.
pub fn signed_rank_positive(d: &[f64]) -> (f64, f64) {
    let mut v: Vec<f64> = d
        .iter()
        .copied()
        .filter(|x| *x != 0.0 && x.is_finite())
        .collect();
    let n = v.len();
    if n < 6 {
        return (0.0, 1.0);
    }
    v.sort_by(|a, b| a.abs().total_cmp(&b.abs()));
    let mut w_plus = 0.0;
    let mut tie_term = 0.0;
    let mut i = 0;
    while i < n {
        let mut j = i;
        while j + 1 < n && v[j + 1].abs() == v[i].abs() {
            j += 1;
        }
        let rank = 0.5 * ((i + 1) + (j + 1)) as f64;
        let m = (j - i + 1) as f64;
        tie_term += m * m * m - m;
        for x in &v[i..=j] {
            if *x > 0.0 {
                w_plus += rank;
            }
        }
        i = j + 1;
    }
    let nf = n as f64;
    let mean = nf * (nf + 1.0) / 4.0;
    let var = nf * (nf + 1.0) * (2.0 * nf + 1.0) / 24.0 - tie_term / 48.0;
    let z = (w_plus - mean - 0.5) / var.sqrt();
    (z, normal_upper_tail(z))
}

/// One-sided paired t-test that the differences `d` have a positive mean: (t, p-value).
/// Fewer than 3 differences give p = 1.
pub fn paired_t_positive(d: &[f64]) -> (f64, f64) {
    let n = d.len();
    if n < 3 {
        return (0.0, 1.0);
    }
    let mean = d.iter().sum::<f64>() / n as f64;
    let var = d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    if var <= 0.0 {
        return if mean > 0.0 {
            (f64::INFINITY, 0.0)
        } else {
            (0.0, 1.0)
        };
    }
    let t = mean / (var / n as f64).sqrt();
    (t, t_upper_tail(t, (n - 1) as f64))
}

/// p-value that per-trial held-out evidence `d` is positive: the smaller of the paired
/// t-test (efficient when the evidence is spread thinly over many trials) and the signed-rank
/// test (robust when a few trials carry huge improvements), Bonferroni-corrected for taking two.
/// The evidence is [`encompassing`] when a model is tested against one it extends, per-trial
/// squared-error differences when two alternatives are compared.
pub fn improvement_p_value(d: &[f64]) -> f64 {
    (2.0 * paired_t_positive(d).1.min(signed_rank_positive(d).1)).min(1.0)
}

/// Weight of the squared predicted change in [`encompassing`]'s evidence for a model against
/// one it extends (½ is the squared-error difference).
pub const EXTENDS: f64 = 0.25;

/// Per group (trial or block), the held-out evidence that predictions `a` of readings `y`
/// improve on `b`: Σ (y − b)(a − b) − λ (a − b)². With λ = ½ it is half the squared-error
/// difference (the test of two alternatives). λ = 0 is the forecast-encompassing statistic,
/// the covariance of `b`'s held-out error with the change `a` predicts: when `a` extends `b`
/// by a true term its mean is (1 − λ) Σ (a − b)², twice that at λ = ½, at about the same
/// spread; but under no effect fold fits that share trials skew it upward (its p-values fall
/// below their level several times too often, docs/diagnosis.md). [`EXTENDS`] lies between.
pub fn encompassing(
    y: &[f64],
    (a, b): (&[f64], &[f64]),
    group: &[usize],
    n: usize,
    lambda: f64,
) -> Vec<f64> {
    let mut s = vec![0.0; n];
    for r in 0..y.len().min(group.len()) {
        let d = a[r] - b[r];
        s[group[r]] += (y[r] - b[r]) * d - lambda * d * d;
    }
    s
}

/// Calibration log: with `G1VIZ_P_LOG` set to a file, appends the stage and the candidate's
/// p-values at λ = 0, ⅛, ¼, ⅜ and ½ of [`encompassing`] (the variable is read once).
pub(crate) fn log_p(stage: &str, y: &[f64], a: &[f64], b: &[f64], group: &[usize], n: usize) {
    static PATH: std::sync::OnceLock<Option<std::ffi::OsString>> = std::sync::OnceLock::new();
    let Some(path) = PATH.get_or_init(|| std::env::var_os("G1VIZ_P_LOG")) else {
        return;
    };
    let p = |l| improvement_p_value(&encompassing(y, (a, b), group, n, l));
    let ps = [0.0, 0.125, 0.25, 0.375, 0.5].map(|l| format!("{:e}", p(l)));
    let line = format!("{stage} {}\n", ps.join(" "));
    let f = std::fs::OpenOptions::new()
        .append(true)
        .create(true)
        .open(path);
    let _ = f.and_then(|mut f| std::io::Write::write_all(&mut f, line.as_bytes()));
}

/// Resamples of the trials [`resampled_stability`] draws.
pub const STABILITY_DRAWS: usize = 200;

/// How stable a finding is under resampling of the trials: the fraction of `draws` bootstrap
/// resamples (trials drawn with replacement, seeded by `seed`) in which `after` still passes
/// its gate over `before` — [`improvement_p_value`] of the resampled evidence `ev` below
/// `level` and a held-out RMSE gain of at least `min_gain`. `before` and `after` are per-trial
/// held-out squared errors, `ev` the per-trial [`encompassing`] evidence, in the same order.
pub fn resampled_stability(
    (before, after, ev): (&[f64], &[f64], &[f64]),
    (level, min_gain): (f64, f64),
    draws: usize,
    seed: u64,
) -> f64 {
    use rand::{RngExt, SeedableRng};
    let n = before.len().min(after.len());
    if n == 0 || draws == 0 {
        return 0.0;
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut d = vec![0.0; n];
    let mut held = 0usize;
    for _ in 0..draws {
        let (mut sb, mut sa) = (0.0f64, 0.0f64);
        for slot in d.iter_mut() {
            let k = rng.random_range(0..n);
            sb += before[k];
            sa += after[k];
            *slot = ev[k];
        }
        let gain = 1.0 - (sa / sb.max(1e-300)).sqrt();
        if gain >= min_gain && improvement_p_value(&d) < level {
            held += 1;
        }
    }
    held as f64 / draws as f64
}

/// Pearson correlation of `x` and `y` and its two-sided p-value (t test with n − 2 df).
pub fn pearson(x: &[f64], y: &[f64]) -> (f64, f64) {
    let n = x.len().min(y.len());
    if n < 4 {
        return (0.0, 1.0);
    }
    let mx = x[..n].iter().sum::<f64>() / n as f64;
    let my = y[..n].iter().sum::<f64>() / n as f64;
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for k in 0..n {
        let (a, b) = (x[k] - mx, y[k] - my);
        sxy += a * b;
        sxx += a * a;
        syy += b * b;
    }
    if sxx <= 0.0 || syy <= 0.0 {
        return (0.0, 1.0);
    }
    let r = (sxy / (sxx * syy).sqrt()).clamp(-1.0, 1.0);
    let df = (n - 2) as f64;
    let t = r * (df / (1.0 - r * r).max(1e-300)).sqrt();
    (r, 2.0 * t_upper_tail(t.abs(), df))
}

/// The 5 % and 95 % quantiles of `v` (`None` when it is empty).
fn q5_95(v: &[f64]) -> Option<(f64, f64)> {
    let mut s: Vec<f64> = v.to_vec();
    s.sort_by(f64::total_cmp);
    let q = |p: f64| s[((s.len() - 1) as f64 * p).round() as usize];
    (!s.is_empty()).then(|| (q(0.05), q(0.95)))
}

/// 5–95 % span of a field's values.
pub(crate) fn span(v: &[f64]) -> f64 {
    q5_95(v).map_or(0.0, |(lo, hi)| hi - lo)
}

/// Threshold of a field that switches between levels: the midpoint of its 5–95 % range when
/// fewer than 10 % of the values lie in the middle third of it.
pub(crate) fn step_threshold(v: &[f64]) -> Option<f64> {
    let (lo, hi) = q5_95(v).filter(|(lo, hi)| hi > lo)?;
    let mid = v
        .iter()
        .filter(|&&x| x > lo + (hi - lo) / 3.0 && x < hi - (hi - lo) / 3.0)
        .count();
    (mid * 10 < v.len()).then_some(0.5 * (lo + hi))
}

#[cfg(test)]
mod tests {
    /// A gain every trial shares is stable; one carried by a few trials is not, nor one whose
    /// p-value sits at its level; the same seed gives the same figure.
    #[test]
    fn stability_separates_a_steady_gain_from_a_lucky_one() {
        let stab = |b: &[f64], a: &[f64], gate, draws, seed| {
            let d: Vec<f64> = b.iter().zip(a).map(|(x, z)| x - z).collect();
            super::resampled_stability((b, a, &d), gate, draws, seed)
        };
        let n = 60;
        let before: Vec<f64> = (0..n).map(|k| 10.0 + (k % 7) as f64).collect();
        let steady: Vec<f64> = before.iter().map(|b| 0.8 * b).collect();
        assert_eq!(stab(&before, &steady, (1e-6, 0.02), 200, 1), 1.0);
        // Three trials carry the whole gain: resamples without them fail the gate.
        let lucky: Vec<f64> = (0..n)
            .map(|k| if k < 3 { 0.0 } else { before[k] * 1.001 })
            .collect();
        let s = stab(&before, &lucky, (1e-3, 0.02), 200, 1);
        assert!(s < 0.5, "{s}");
        // Noisy gains whose p-value lies at the level pass in about half of the resamples.
        let noisy: Vec<f64> = (0..n)
            .map(|k| before[k] * (0.9 + 0.25 * ((k * 37 % 11) as f64 / 10.0 - 0.5)))
            .collect();
        let d: Vec<f64> = before.iter().zip(&noisy).map(|(b, a)| b - a).collect();
        let level = super::improvement_p_value(&d);
        let s = stab(&before, &noisy, (level, 0.0), 200, 1);
        assert!((0.25..0.75).contains(&s), "{s} at p = {level:e}");
        assert_eq!(s, stab(&before, &noisy, (level, 0.0), 200, 1));
    }

    use super::*;

    #[test]
    fn t_tail_matches_tables() {
        // Textbook critical values: t_{0.975, 10} = 2.228, t_{0.999, 30} = 3.385, t_{0.95, 1} = 6.314.
        assert!((t_upper_tail(2.228, 10.0) - 0.025).abs() < 2e-4);
        assert!((t_upper_tail(3.385, 30.0) - 0.001).abs() < 2e-5);
        assert!((t_upper_tail(6.314, 1.0) - 0.05).abs() < 2e-4);
        assert!((t_upper_tail(0.0, 7.0) - 0.5).abs() < 1e-12);
        assert!((t_upper_tail(-2.228, 10.0) - 0.975).abs() < 2e-4);
    }

    #[test]
    fn pearson_of_a_line_is_one_and_of_orthogonal_data_zero() {
        let x = [1.0, 2.0, 3.0, 4.0, 5.0];
        let (r, p) = pearson(&x, &[2.0, 4.0, 6.0, 8.0, 10.0]);
        assert!((r - 1.0).abs() < 1e-12 && p < 1e-6);
        let (r, p) = pearson(&[1.0, -1.0, 1.0, -1.0], &[1.0, 1.0, -1.0, -1.0]);
        assert!(r.abs() < 1e-12 && (p - 1.0).abs() < 1e-9);
    }

    #[test]
    fn paired_t_matches_hand_computed_statistic() {
        // d = 1, 2, 3, 4, 5: mean 3, s = √2.5, t = 3/(√2.5/√5) = 3√2 = 4.243, df 4.
        let (t, p) = paired_t_positive(&[1.0, 2.0, 3.0, 4.0, 5.0]);
        assert!((t - 3.0 * 2f64.sqrt()).abs() < 1e-12);
        assert!((p - t_upper_tail(t, 4.0)).abs() < 1e-15 && p < 0.01 && p > 0.001);
        assert!((improvement_p_value(&[1.0, 2.0, 3.0, 4.0, 5.0]) - 2.0 * p).abs() < 1e-15);
    }

    #[test]
    fn encompassing_matches_hand_computed_evidence() {
        // y = 1, 2 (groups 0, 1), b = 0, a = 1: (y − b)(a − b) − λ(a − b)² = 1 − λ, 2 − λ; at
        // λ = ½ half the squared-error differences 1 − 0 and 4 − 1.
        let (y, a, b) = ([1.0, 2.0], [1.0, 1.0], [0.0, 0.0]);
        let e = |l| encompassing(&y, (&a, &b), &[0, 1], 2, l);
        assert_eq!(e(0.0), vec![1.0, 2.0]);
        assert_eq!(e(0.25), vec![0.75, 1.75]);
        assert_eq!(e(0.5), vec![0.5, 1.5]);
    }

    #[test]
    fn normal_tail_matches_tables() {
        assert!((normal_upper_tail(1.959_964) - 0.025).abs() < 1e-6);
        assert!((normal_upper_tail(3.090_232) - 0.001).abs() < 1e-7);
        assert!((normal_upper_tail(-1.0) - 0.841_345).abs() < 1e-6);
    }

    #[test]
    fn signed_rank_matches_hand_computed_statistic() {
        // d = 1..10 all positive: W+ = 55, mean 27.5, var = 10·11·21/24 = 96.25 → z = 27/9.811 = 2.752.
        let d: Vec<f64> = (1..=10).map(f64::from).collect();
        let (z, p) = signed_rank_positive(&d);
        assert!((z - 27.0 / 96.25f64.sqrt()).abs() < 1e-9);
        assert!((p - normal_upper_tail(z)).abs() < 1e-15 && p < 0.003);
        // Symmetric differences: no evidence.
        let d: Vec<f64> = (1..=20)
            .map(|k| if k % 2 == 0 { k as f64 } else { -(k as f64) })
            .collect();
        assert!(signed_rank_positive(&d).1 > 0.2);
    }
}
