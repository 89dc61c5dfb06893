//! Tests of the identification core: the constrained solver (clarabel vs the independent active-set method and
//! the KKT conditions), fit metrics against hand-computed values, the model file and the report.

use g1viz::lsq::{
    Bounds, Method, Metrics, bounded_quadratic, condition_number, condition_number_matrix,
    fit_constrained, fit_general, kkt_check, paper_lower_bounds, rows_to_matrix,
};
use g1viz::power::{PowerModel, regressor_into};
use g1viz::{N_JOINTS, N_PARAMS};
use nalgebra::{DMatrix, DVector};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs()).max(1e-300)
}

/// Trial-averaged regressor rows shaped like the paper's dataset: 1–4 joints move together along a cubic
/// smooth-step at one of the five speed levels, followed by a static post-idle; torque = a gravity-like
/// posture-dependent term plus an inertial term; each row averages its trial, y from `truth` plus noise.
fn paper_shaped(
    n_trials: usize,
    noise_w: f64,
    truth: &PowerModel,
    seed: u64,
) -> (Vec<[f64; N_PARAMS]>, Vec<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, noise_w).unwrap();
    let speeds = [0.5, 1.0, 1.5, 2.0, 2.5];
    let mut rows = Vec::new();
    let mut ys = Vec::new();
    for _ in 0..n_trials {
        let k = rng.random_range(1..=4usize);
        let mut moving = [false; N_JOINTS];
        let mut chosen = 0;
        while chosen < k {
            let j = rng.random_range(0..N_JOINTS);
            if !moving[j] {
                moving[j] = true;
                chosen += 1;
            }
        }
        let v = speeds[rng.random_range(0..speeds.len())];
        let mut amp = [0.0f64; N_JOINTS];
        let mut gain = [0.0f64; N_JOINTS];
        let mut phase = [0.0f64; N_JOINTS];
        for j in 0..N_JOINTS {
            if moving[j] {
                amp[j] = rng.random_range(0.3..1.2) * if rng.random::<bool>() { 1.0 } else { -1.0 };
            }
            gain[j] = rng.random_range(0.5..5.0);
            phase[j] = rng.random_range(-1.0..1.0);
        }
        // Peak smooth-step speed is 1.5·A/T: the largest amplitude sets T for the speed level.
        let amax = amp.iter().fold(0.0f64, |m, a| m.max(a.abs()));
        let duration = 1.5 * amax / v;
        let n_move = 150;
        let n_idle = 60;
        let mut tau0_sq = [0.0; N_JOINTS];
        for j in 0..N_JOINTS {
            tau0_sq[j] = (gain[j] * phase[j].sin()).powi(2);
        }
        let mut mean = [0.0; N_PARAMS];
        let mut phi = [0.0; N_PARAMS];
        for s in 0..(n_move + n_idle) {
            let u = (s as f64 / n_move as f64).min(1.0);
            let mut tau = [0.0; N_JOINTS];
            let mut dq = [0.0; N_JOINTS];
            for j in 0..N_JOINTS {
                let q = amp[j] * (3.0 * u * u - 2.0 * u * u * u);
                dq[j] = if s < n_move {
                    amp[j] * 6.0 * u * (1.0 - u) / duration
                } else {
                    0.0
                };
                let ddq = if s < n_move {
                    amp[j] * (6.0 - 12.0 * u) / (duration * duration)
                } else {
                    0.0
                };
                tau[j] = gain[j] * (q + phase[j]).sin() + 0.05 * ddq;
            }
            regressor_into(&tau, &dq, &tau0_sq, &mut phi);
            for p in 0..N_PARAMS {
                mean[p] += phi[p] / (n_move + n_idle) as f64;
            }
        }
        let y: f64 = truth
            .to_vector()
            .iter()
            .zip(&mean)
            .map(|(t, p)| t * p)
            .sum::<f64>()
            + noise.sample(&mut rng);
        rows.push(mean);
        ys.push(y);
    }
    (rows, ys)
}

/// Random dense problem whose unconstrained optimum violates many bounds.
fn random_problem(rows: usize, cols: usize, seed: u64) -> (DMatrix<f64>, DVector<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let phi = DMatrix::from_fn(rows, cols, |_, _| normal.sample(&mut rng));
    let truth = DVector::from_fn(cols, |_, _| rng.random_range(-1.0..1.0));
    let y = &phi * truth + DVector::from_fn(rows, |_, _| 0.1 * normal.sample(&mut rng));
    (phi, y)
}

/// The same problem solved by the exact active-set method on its normal equations
/// (ΦᵀΦ + λ·diag‖φ_j‖², Φᵀy), independent of clarabel and of the row scaling.
fn active_set(phi: &DMatrix<f64>, y: &DVector<f64>, bounds: &Bounds) -> Vec<f64> {
    let mut g = phi.transpose() * phi;
    for j in 0..phi.ncols() {
        g[(j, j)] += bounds.ridge * phi.column(j).norm_squared();
    }
    bounded_quadratic(&g, &(phi.transpose() * y), &bounds.lower, &bounds.upper).unwrap()
}

fn assert_agree(phi: &DMatrix<f64>, y: &DVector<f64>, bounds: &Bounds, what: &str) -> usize {
    let c = fit_general(phi, y, bounds).unwrap();
    let b = active_set(phi, y, bounds);
    let scale = b.iter().fold(1.0f64, |m, v| m.max(v.abs()));
    let max_diff = c
        .theta
        .iter()
        .zip(&b)
        .fold(0.0f64, |m, (x, z)| m.max((x - z).abs()));
    assert!(
        max_diff <= 1e-6 * scale,
        "{what}: clarabel and the active-set method differ by {max_diff:e} (scale {scale})"
    );
    let b_rss = (phi * DVector::from_column_slice(&b) - y).norm_squared();
    assert!(
        close(c.rss, b_rss, 1e-8),
        "{what}: objectives {} vs {b_rss}",
        c.rss
    );
    let kb = kkt_check(phi, y, &b, bounds).unwrap();
    assert!(kb.max_violation() < 1e-9, "{what}: active-set KKT {kb:?}");
    let kc = kkt_check(phi, y, &c.theta, bounds).unwrap();
    assert!(kc.max_violation() < 1e-6, "{what}: clarabel KKT {kc:?}");
    let b_at_bound: Vec<bool> = (0..b.len())
        .map(|j| b[j] == bounds.lower[j] || b[j] == bounds.upper[j])
        .collect();
    assert_eq!(c.at_bound, b_at_bound, "{what}: active sets differ");
    b_at_bound.iter().filter(|&&a| a).count()
}

#[test]
fn clarabel_and_the_active_set_method_agree_on_random_lower_bounded_problems() {
    for seed in 0..8 {
        let (phi, y) = random_problem(120, N_PARAMS, seed);
        let bounds = Bounds::lower(&paper_lower_bounds());
        let active = assert_agree(&phi, &y, &bounds, &format!("seed {seed}"));
        assert!(
            active >= 10,
            "seed {seed}: only {active} active constraints, the test needs many"
        );
    }
}

#[test]
fn clarabel_and_the_active_set_method_agree_with_upper_bounds_free_columns_and_ridge() {
    for seed in 10..16 {
        let (phi, y) = random_problem(60, 12, seed);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut bounds = Bounds {
            lower: vec![f64::NEG_INFINITY; 12],
            upper: vec![f64::INFINITY; 12],
            ridge: 0.0,
        };
        for j in 0..12 {
            match j % 4 {
                0 => {}
                1 => bounds.lower[j] = rng.random_range(-0.2..0.2),
                2 => bounds.upper[j] = rng.random_range(-0.2..0.2),
                _ => {
                    bounds.lower[j] = -0.1;
                    bounds.upper[j] = 0.1;
                }
            }
        }
        assert_agree(&phi, &y, &bounds, &format!("box seed {seed}"));
        bounds.ridge = 0.05;
        assert_agree(&phi, &y, &bounds, &format!("ridge seed {seed}"));
    }
}

#[test]
fn unconstrained_fit_equals_normal_equations() {
    let (phi, y) = random_problem(50, 6, 99);
    let free = vec![f64::NEG_INFINITY; 6];
    let bounds = Bounds {
        lower: free,
        upper: vec![f64::INFINITY; 6],
        ridge: 0.0,
    };
    let theta = fit_general(&phi, &y, &bounds).unwrap().theta;
    // Independent: solve ΦᵀΦθ = Φᵀy by Cholesky.
    let normal = (phi.transpose() * &phi)
        .cholesky()
        .unwrap()
        .solve(&(phi.transpose() * &y));
    for j in 0..6 {
        assert!(
            (theta[j] - normal[j]).abs() < 1e-7 * normal.amax(),
            "θ{j}: {} vs {}",
            theta[j],
            normal[j]
        );
    }
}

#[test]
fn hand_solved_bound_problem() {
    // min (θ0 + 1)² + (θ1 − 2)² + (θ0 + θ1 − 1)²  s.t. θ ≥ 0.
    // Unconstrained optimum θ = (−4/3, 5/3) violates θ0 ≥ 0; with θ0 = 0: min (θ1−2)² + (θ1−1)² → θ1 = 1.5,
    // gradient wrt θ0 at (0, 1.5): 2(1) + 2(0.5) = 3 > 0, so the bound is active: θ = (0, 1.5), RSS = 1 + 0.5.
    let phi = DMatrix::from_row_slice(3, 2, &[1.0, 0.0, 0.0, 1.0, 1.0, 1.0]);
    let y = DVector::from_vec(vec![-1.0, 2.0, 1.0]);
    let fit = fit_general(&phi, &y, &Bounds::lower(&[0.0, 0.0])).unwrap();
    assert!(
        fit.theta[0].abs() < 1e-9 && (fit.theta[1] - 1.5).abs() < 1e-9,
        "{:?}",
        fit.theta
    );
    assert!((fit.rss - 1.5).abs() < 1e-9);
    assert_eq!(fit.at_bound, vec![true, false]);
    assert!(fit.std_err[0].is_none() && fit.std_err[1].is_some());
    let exact = active_set(&phi, &y, &Bounds::lower(&[0.0, 0.0]));
    assert!(
        exact[0] == 0.0 && (exact[1] - 1.5).abs() < 1e-12,
        "{exact:?}"
    );
}

#[test]
fn standard_errors_match_textbook_simple_regression() {
    // y = α + βx on x = 1..5, y = (1.2, 1.9, 3.2, 3.8, 5.1): Sxx = 10, β̂ = Sxy/Sxx, s² = RSS/(n−2),
    // SE(β̂) = s/√Sxx, SE(α̂) = s·√(1/n + x̄²/Sxx).
    let x = [1.0, 2.0, 3.0, 4.0, 5.0];
    let y = [1.2, 1.9, 3.2, 3.8, 5.1];
    let xm = 3.0;
    let ym = y.iter().sum::<f64>() / 5.0;
    let sxy: f64 = x.iter().zip(&y).map(|(a, b)| (a - xm) * (b - ym)).sum();
    let beta = sxy / 10.0;
    let alpha = ym - beta * xm;
    let rss: f64 = x
        .iter()
        .zip(&y)
        .map(|(a, b)| (b - alpha - beta * a).powi(2))
        .sum();
    let s = (rss / 3.0).sqrt();
    let phi = DMatrix::from_fn(5, 2, |i, j| if j == 0 { 1.0 } else { x[i] });
    let bounds = Bounds::lower(&[f64::NEG_INFINITY, 0.0]);
    let fit = fit_general(&phi, &DVector::from_column_slice(&y), &bounds).unwrap();
    // An interior-point solution: exact to the solver's tolerance, not to rounding.
    assert!(
        (fit.theta[1] - beta).abs() < 1e-8 && (fit.theta[0] - alpha).abs() < 1e-8,
        "θ {:?} vs ({alpha}, {beta})",
        fit.theta
    );
    assert!(close(fit.std_err[1].unwrap(), s / 10f64.sqrt(), 1e-9));
    assert!(close(
        fit.std_err[0].unwrap(),
        s * (0.2 + xm * xm / 10.0).sqrt(),
        1e-9
    ));
}

#[test]
fn paper_shaped_fit_recovers_paper_parameters_and_solvers_agree() {
    let (rows, y) = paper_shaped(897, 0.02, &PowerModel::PAPER, 7);
    let lower = paper_lower_bounds();
    let c = fit_constrained(&rows, &y, &lower).unwrap();
    let truth = PowerModel::PAPER.to_vector();
    let mut worst = (0, 0.0f64);
    for p in 0..N_PARAMS {
        let err = (c.theta[p] - truth[p]).abs();
        if err > worst.1 {
            worst = (p, err);
        }
        assert!(
            c.theta[p] >= lower[p] - 1e-9,
            "θ{p} = {} violates its bound",
            c.theta[p]
        );
    }
    println!(
        "worst parameter error {:.4} at θ{} ; clarabel {} iterations {:.2} ms",
        worst.1,
        worst.0,
        c.solver.iterations,
        c.solver.time_s * 1e3
    );
    assert!(worst.1 < 0.05, "parameter θ{} off by {}", worst.0, worst.1);
    let phi = rows_to_matrix(&rows);
    let yv = DVector::from_column_slice(&y);
    assert_agree(&phi, &yv, &Bounds::lower(&lower), "paper-shaped");
    // The fit is at least as good as the truth on its own data.
    let truth_rss: f64 = rows
        .iter()
        .zip(&y)
        .map(|(r, y)| (r.iter().zip(&truth).map(|(a, t)| a * t).sum::<f64>() - y).powi(2))
        .sum();
    assert!(c.rss <= truth_rss * (1.0 + 1e-9));
}

#[test]
fn zero_columns_are_pinned_and_reported() {
    let (mut phi, y) = random_problem(40, 5, 3);
    phi.column_mut(2).fill(0.0);
    let bounds = Bounds {
        lower: vec![0.0, 0.0, 1.0, 0.0, 0.0],
        upper: vec![f64::INFINITY; 5],
        ridge: 0.0,
    };
    let fit = fit_general(&phi, &y, &bounds).unwrap();
    assert_eq!(fit.unidentifiable, vec![2]);
    assert_eq!(fit.theta[2], 1.0);
    assert!(fit.std_err[2].is_none());
}

#[test]
fn bad_solver_input_is_a_clear_error() {
    let (mut phi, y) = random_problem(10, 3, 1);
    phi[(4, 1)] = f64::NAN;
    let err = fit_general(&phi, &y, &Bounds::lower(&[0.0; 3]))
        .unwrap_err()
        .to_string();
    assert!(err.contains("Φ[4][1]"), "{err}");
    let (phi, y) = random_problem(10, 3, 1);
    let err = fit_general(&phi, &y, &Bounds::lower(&[0.0; 2]))
        .unwrap_err()
        .to_string();
    assert!(err.contains("3 columns"), "{err}");
    let bad = Bounds {
        lower: vec![1.0, 0.0, 0.0],
        upper: vec![0.0, 1.0, 1.0],
        ridge: 0.0,
    };
    assert!(
        fit_general(&phi, &y, &bad)
            .unwrap_err()
            .to_string()
            .contains("column 0")
    );
    let short = DVector::from_vec(vec![1.0; 9]);
    assert!(fit_general(&phi, &short, &Bounds::lower(&[0.0; 3])).is_err());
}

#[test]
fn metrics_match_hand_computed_values() {
    // y = (1, 2, 3, 4), ŷ = (1.1, 1.9, 3.2, 3.8): SS_res = 0.1, SS_tot = 5 → R² = 0.98, RMSE = √0.025,
    // MAE = 0.15, bias = mean(ŷ − y) = 0.
    let m = Metrics::compute(&[1.0, 2.0, 3.0, 4.0], &[1.1, 1.9, 3.2, 3.8]);
    assert_eq!(m.n, 4);
    assert!(close(m.r2, 0.98, 1e-12));
    assert!(close(m.rmse, 0.025f64.sqrt(), 1e-12));
    assert!(close(m.mae, 0.15, 1e-12));
    assert!(m.bias.abs() < 1e-15);
    // Residuals e = (1, 2, 3, 4, 10): mean 4, deviations (−3, −2, −1, 0, 6): m2 = 10, m3 = 36, m4 = 278.8
    // → skewness = 36/10^1.5 = 1.1384199576606167, kurtosis = 2.788 (scipy: skew(e), kurtosis(e, fisher=False)).
    let m = Metrics::compute(&[1.0, 2.0, 3.0, 4.0, 10.0], &[0.0; 5]);
    assert!(
        close(m.skewness, 1.1384199576606167, 1e-12),
        "{}",
        m.skewness
    );
    assert!(close(m.kurtosis, 2.788, 1e-12), "{}", m.kurtosis);
    assert!(
        close(m.bias, -4.0, 1e-12),
        "predicting 0 for positive data is under-prediction"
    );
    // A normal sample has kurtosis ≈ 3 and skewness ≈ 0.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let normal = Normal::new(0.0, 2.0).unwrap();
    let e: Vec<f64> = (0..200_000).map(|_| normal.sample(&mut rng)).collect();
    let m = Metrics::compute(&e, &vec![0.0; e.len()]);
    assert!(
        (m.kurtosis - 3.0).abs() < 0.05 && m.skewness.abs() < 0.02,
        "{m:?}"
    );
    assert!(Metrics::compute(&[], &[]).r2.is_nan());
}

#[test]
fn condition_numbers_match_known_values() {
    // cond₂(hilb(3)) = 524.0567775860644 (MATLAB/numpy); κ(HᵀH) is its square.
    let h = DMatrix::from_fn(3, 3, |i, j| 1.0 / (i + j + 1) as f64);
    assert!(close(
        condition_number_matrix(&h),
        524.0567775860644f64.powi(2),
        1e-8
    ));
    // Orthogonal columns with norms 1..49 (rows e_k·k): κ(ΦᵀΦ) = 49².
    let rows: Vec<[f64; N_PARAMS]> = (0..N_PARAMS)
        .map(|k| {
            let mut r = [0.0; N_PARAMS];
            r[k] = (k + 1) as f64;
            r
        })
        .collect();
    assert!(close(condition_number(&rows), 49.0 * 49.0, 1e-10));
    assert!(condition_number(&rows[..48]).is_infinite());
}

#[test]
fn breakdown_matches_hand_computed_terms_and_sums_to_predict() {
    let m = PowerModel::PAPER;
    let tau = [1.0, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0];
    let dq = [2.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
    let tau0_sq = [0.5, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
    let b = m.breakdown(&tau, &dq, &tau0_sq);
    // Joint 0: a τq̇ = 1·1·2, b Δτ² = 0.4184·(1 − 0.5), c|q̇| = 0, d q̇² = 0.6467·4.
    assert!(close(b.mechanical[0], 2.0, 1e-15));
    assert!(close(b.copper[0], 0.2092, 1e-12));
    assert_eq!(b.coulomb[0], 0.0);
    assert!(close(b.viscous[0], 2.5868, 1e-12));
    // Joint 3 (elbow): τq̇ = −2 (braking), Δτ² = 4 − 1 → 0.3942·3, c = 0.0324·1, d = 0.
    assert!(close(b.mechanical[3], -2.0, 1e-15));
    assert!(close(b.copper[3], 1.1826, 1e-12));
    assert!(close(b.coulomb[3], 0.0324, 1e-12));
    // Only pair (0,3) moves together: e03 = 0.9090 · 2 · 1.
    assert!(close(b.interaction_total(), 1.818, 1e-12));
    let hand = 2.0 + 0.2092 + 2.5868 - 2.0 + 1.1826 + 0.0324 + 1.818;
    assert!(close(b.total(), hand, 1e-12));
    assert!(close(m.predict(&tau, &dq, &tau0_sq), hand, 1e-12));
    let mut means = g1viz::power::TermMeans::default();
    means.add(&b);
    means.add(&g1viz::power::TermBreakdown::default());
    let shares = means.shares_percent();
    assert!(close(means.means()[1], (0.2092 + 1.1826) / 2.0, 1e-12));
    assert!(close(shares.iter().sum::<f64>(), 100.0, 1e-12));
    assert!(close(shares[4], 100.0 * 1.818 / hand, 1e-12));
}

#[test]
fn dominant_terms_reproduce_the_papers_table() {
    use g1viz::power::LossTerm::{Copper, Coulomb, Viscous};
    // Table "Identified Power Model Parameters": viscous, Coulomb, copper, copper, viscous, viscous, viscous.
    let expected = [Viscous, Coulomb, Copper, Copper, Viscous, Viscous, Viscous];
    for (i, e) in expected.iter().enumerate() {
        assert_eq!(PowerModel::PAPER.dominant_term(i), Some(*e), "joint {i}");
    }
    let zero = PowerModel::from_vector(&[0.0; N_PARAMS]);
    assert_eq!(zero.dominant_term(0), None);
}

fn joint_names() -> Vec<String> {
    [
        "shoulder_pitch",
        "shoulder_roll",
        "shoulder_yaw",
        "elbow",
        "wrist_roll",
        "wrist_pitch",
        "wrist_yaw",
    ]
    .iter()
    .map(|n| format!("left_{n}_joint"))
    .collect()
}

fn sample_model_file() -> g1viz::power::ModelFile {
    use g1viz::power::*;
    let metrics = ModelMetrics {
        identification: Some(DatasetMetrics {
            dataset: "trajectory-averaged, filtered".into(),
            fit: Metrics::compute(&[1.0, 2.0, 3.0, 4.0], &[1.1, 1.9, 3.2, 3.8]),
            condition_number: 1.5e6,
        }),
        validation: Some(DatasetMetrics {
            dataset: "hold-out".into(),
            fit: Metrics::compute(&[1.0, 1.0], &[1.0, 1.5]),
            condition_number: f64::INFINITY,
        }),
    };
    let provenance = Provenance {
        created: "2026-01-01T00:00:00Z".into(),
        sessions: vec![SessionRef {
            path: "paper.mcap".into(),
            size_bytes: 1234,
            role: "identification".into(),
        }],
        target: "mbs".into(),
        rows: "trajectory".into(),
        filters: vec![FilterRecord {
            name: "imu_sigma".into(),
            parameters: [("k_median".to_string(), 2.5)].into_iter().collect(),
            rejected: 1,
        }],
        trials: TrialCounts {
            segmented: 10,
            used: 9,
            rejected: 1,
        },
        rejected_trials: vec![g1viz::trial::Rejection {
            session: 0,
            trial: 4,
            reason: g1viz::trial::RejectReason::ImuSway,
            statistic: 0.31,
            threshold: 0.12,
            pass: 0,
            detail: String::new(),
        }],
        solver: Some(SolverRecord {
            method: Method::Clarabel,
            status: g1viz::lsq::Status::Solved,
            iterations: 12,
        }),
        ..Provenance::default()
    };
    let mut file = ModelFile::new(&PowerModel::PAPER, &joint_names(), metrics, provenance).unwrap();
    file.theta_std_err = Some(
        (0..N_PARAMS)
            .map(|p| {
                if p % 3 == 0 {
                    None
                } else {
                    Some(0.01 * p as f64)
                }
            })
            .collect(),
    );
    file
}

#[test]
fn model_file_round_trips_and_is_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model.json");
    let file = sample_model_file();
    file.save(&path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let back = g1viz::power::ModelFile::load(&path).unwrap();
    // NaN ≠ NaN, so compare through the JSON text (validation skewness of 2 rows is defined; κ = ∞ → null).
    assert_eq!(back.model(), PowerModel::PAPER);
    assert_eq!(back.theta_std_err, file.theta_std_err);
    assert_eq!(back.provenance, file.provenance);
    assert!(
        back.metrics
            .validation
            .as_ref()
            .unwrap()
            .condition_number
            .is_nan()
    );
    assert_eq!(back.metrics.identification, file.metrics.identification);
    back.save(&path).unwrap();
    assert_eq!(
        std::fs::read(&path).unwrap(),
        bytes,
        "save → load → save changes the bytes"
    );
    let text = String::from_utf8(bytes).unwrap();
    // The named copies are readable by people: spot-check against the paper's tables.
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(json["schema_version"], 1);
    assert_eq!(json["e"]["1,3"], 1.1053);
    assert_eq!(json["d"][6], 1.7848);
    assert_eq!(json["theta_names"][48], "e56");
    assert_eq!(json["dominant_term"][1]["term"], "coulomb");
    assert_eq!(json["metrics"]["identification"]["r2"], 0.98);
}

#[test]
fn model_file_errors_name_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let good = sample_model_file().to_json().unwrap();
    let cases: Vec<(&str, String, &str)> = vec![
        (
            "version.json",
            good.replace("\"schema_version\": 1", "\"schema_version\": 7"),
            "schema_version",
        ),
        (
            "short.json",
            good.replacen("\"theta\": [\n    1.0,", "\"theta\": [", 1),
            "`theta` has 48",
        ),
        (
            "edited.json",
            good.replace("\"0,1\": 0.0", "\"0,1\": 0.5"),
            "e[\"0,1\"]",
        ),
        (
            "null.json",
            good.replacen("\"theta\": [\n    1.0,", "\"theta\": [\n    null,", 1),
            "schema",
        ),
        ("broken.json", good[..good.len() / 2].to_string(), "JSON"),
    ];
    for (name, text, needle) in cases {
        assert_ne!(text, good, "{name}: the test edit did not apply");
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        let err = format!("{:#}", g1viz::power::ModelFile::load(&path).unwrap_err());
        assert!(err.contains(name) && err.contains(needle), "{name}: {err}");
    }
    let missing = dir.path().join("absent.json");
    assert!(
        format!("{:#}", g1viz::power::ModelFile::load(&missing).unwrap_err())
            .contains("absent.json")
    );
}

#[test]
fn report_writes_markdown_and_readable_pngs() {
    use g1viz::identify::{
        AggregationRow, PredictionSet, REPORT_FIGURES as FIGURES, ReportInput, TermContributions,
        write_report,
    };
    let (rows, y) = paper_shaped(120, 0.3, &PowerModel::PAPER, 11);
    let fit = fit_constrained(&rows, &y, &paper_lower_bounds()).unwrap();
    let model = PowerModel::from_vector(&fit.theta49().unwrap());
    let predicted: Vec<f64> = rows
        .iter()
        .map(|r| model.breakdown_from_regressor(r).total())
        .collect();
    let mut means = g1viz::power::TermMeans::default();
    for r in &rows {
        means.add(&model.breakdown_from_regressor(r));
    }
    let mut file = sample_model_file();
    file.theta_std_err = Some(fit.std_err.clone());
    let input = ReportInput {
        title: "Test identification".into(),
        model: file,
        identification: Some(PredictionSet {
            label: "identification".into(),
            measured: y.clone(),
            predicted: predicted.clone(),
            trials: Vec::new(),
        }),
        validation: Some(PredictionSet {
            label: "hold-out".into(),
            measured: y[..40].to_vec(),
            predicted: predicted[..40].to_vec(),
            trials: Vec::new(),
        }),
        terms: Some(TermContributions::from_means("identification", &means)),
        aggregation: vec![
            AggregationRow {
                rows: "per-sample".into(),
                n: 120_000,
                condition_number: 7.8e11,
                r2: 0.03,
            },
            AggregationRow {
                rows: "trajectory-averaged".into(),
                n: 120,
                condition_number: 2.0e5,
                r2: 0.93,
            },
        ],
        truth: Some(PowerModel::PAPER),
        notes: vec!["Synthetic data.".into()],
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report");
    write_report(&out, &input).unwrap();
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for needle in [
        "| identification (trajectory-averaged, filtered) | 4 | 0.980 |",
        "7.80e11",
        "| 1 shoulder roll |",
        "Coulomb",
        "| `paper.mcap` | 4 | imu_sigma |",
        "e56",
    ] {
        assert!(md.contains(needle), "report.md lacks {needle:?}:\n{md}");
    }
    for fig in FIGURES {
        let bytes = std::fs::read(out.join(fig)).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{fig} is not a PNG");
        assert!(
            bytes.len() > 10_000,
            "{fig} is suspiciously small ({} bytes)",
            bytes.len()
        );
        assert!(md.contains(fig), "report.md does not link {fig}");
    }
    let leftovers: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left behind");
}

#[test]
fn collinear_columns_reach_the_same_objective() {
    // The paper's collinearity: when two joints share a velocity profile, |q̇_i||q̇_j| ≡ q̇_i² (up to scale), so
    // θ is not unique. The solver must still terminate at the minimum and satisfy the KKT conditions: with
    // φ7 = 2φ3 and both ≥ 0, the problem without column 7 has the same minimum at θ3' = θ3 + 2θ7.
    let (mut phi, y) = random_problem(80, 10, 21);
    let dup = phi.column(3).clone_owned() * 2.0;
    phi.column_mut(7).copy_from(&dup);
    let bounds = Bounds::lower(&[0.0; 10]);
    let c = fit_general(&phi, &y, &bounds).unwrap();
    let reduced = phi.clone().remove_column(7);
    let b = active_set(&reduced, &y, &Bounds::lower(&[0.0; 9]));
    let b_rss = (&reduced * DVector::from_column_slice(&b) - &y).norm_squared();
    assert!(close(c.rss, b_rss, 1e-7), "objectives {} vs {b_rss}", c.rss);
    assert!(
        kkt_check(&phi, &y, &c.theta, &bounds)
            .unwrap()
            .max_violation()
            < 1e-6
    );
    // The identifiable combination θ3 + 2θ7 agrees.
    assert!((c.theta[3] + 2.0 * c.theta[7] - b[3]).abs() < 1e-5);
}
