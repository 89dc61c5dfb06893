//! Benchmark of the identification core on a paper-sized problem:
//! - the constrained fit of 897 trajectory-averaged rows × 49 parameters (clarabel and the active-set cross-check on ΦᵀΦ;
//!   target < 50 ms),
//! - `PowerModel::predict` and `PowerModel::breakdown` calls per second, with a counting allocator proving
//!   they allocate nothing.
//!
//! `cargo run --no-default-features --example bench_solve [-- --report DIR]` (`--report` also writes the
//! markdown/PNG report of the synthetic fit, to look at the figures).

use std::alloc::{GlobalAlloc, Layout, System};
use std::hint::black_box;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use g1viz::lsq::{
    Gram, Metrics, bounded_quadratic, condition_number, fit_constrained, paper_lower_bounds,
};
use g1viz::power::{ModelFile, ModelMetrics, PowerModel, Provenance, TermMeans, regressor_into};
use g1viz::{N_JOINTS, N_PARAMS};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Counts heap allocations so the benchmark can show the per-call APIs do none.
struct CountingAlloc;
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

/// 897 trajectory-averaged rows: 1–4 joints sweep with a smooth-step velocity profile at one of the
/// paper's five speeds, torque = posture-dependent gravity-like load; y = PAPER·φ̄ + 0.3 W noise.
fn paper_sized_rows(seed: u64) -> (Vec<[f64; N_PARAMS]>, Vec<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.3).expect("valid sigma");
    let truth = PowerModel::PAPER.to_vector();
    let (mut rows, mut ys) = (Vec::new(), Vec::new());
    for _ in 0..897 {
        let speed = [0.5, 1.0, 1.5, 2.0, 2.5][rng.random_range(0..5)];
        let n_moving = rng.random_range(1..=4usize);
        let mut amp = [0.0f64; N_JOINTS];
        for _ in 0..n_moving {
            amp[rng.random_range(0..N_JOINTS)] = rng.random_range(-1.2..1.2);
        }
        let gain: [f64; N_JOINTS] = std::array::from_fn(|_| rng.random_range(0.5..5.0));
        let amax = amp.iter().fold(0.05f64, |m, a| m.max(a.abs()));
        let duration = 1.5 * amax / speed;
        let tau0_sq: [f64; N_JOINTS] = std::array::from_fn(|j| (gain[j] * 0.3f64.sin()).powi(2));
        let (mut mean, mut phi) = ([0.0; N_PARAMS], [0.0; N_PARAMS]);
        let samples = 200;
        for s in 0..samples {
            let u = s as f64 / (samples - 1) as f64;
            let tau: [f64; N_JOINTS] = std::array::from_fn(|j| {
                gain[j] * (0.3 + amp[j] * (3.0 * u * u - 2.0 * u * u * u)).sin()
            });
            let dq: [f64; N_JOINTS] =
                std::array::from_fn(|j| amp[j] * 6.0 * u * (1.0 - u) / duration);
            regressor_into(&tau, &dq, &tau0_sq, &mut phi);
            for p in 0..N_PARAMS {
                mean[p] += phi[p] / samples as f64;
            }
        }
        ys.push(truth.iter().zip(&mean).map(|(t, p)| t * p).sum::<f64>() + noise.sample(&mut rng));
        rows.push(mean);
    }
    (rows, ys)
}

fn median_ms(mut times: Vec<f64>) -> f64 {
    times.sort_by(f64::total_cmp);
    times[times.len() / 2] * 1e3
}

fn main() -> anyhow::Result<()> {
    let report_dir = std::env::args().skip_while(|a| a != "--report").nth(1);
    let (rows, y) = paper_sized_rows(1);
    let lower = paper_lower_bounds();
    println!(
        "problem: {} rows × {N_PARAMS} parameters, κ(ΦᵀΦ) = {:.3e}",
        rows.len(),
        condition_number(&rows)
    );

    let mut fit = fit_constrained(&rows, &y, &lower)?;
    let mut times = Vec::new();
    for _ in 0..20 {
        let t = Instant::now();
        fit = fit_constrained(&rows, &y, &lower)?;
        times.push(t.elapsed().as_secs_f64());
    }
    println!(
        "clarabel: median {:.2} ms over 20 solves (status {}, {} iterations; target < 50 ms)",
        median_ms(times),
        fit.solver.status,
        fit.solver.iterations
    );
    let mut times = Vec::new();
    let active_set = || {
        let mut g = Gram::zeros(N_PARAMS);
        for (row, &v) in rows.iter().zip(&y) {
            g.add_row(row, v);
        }
        bounded_quadratic(&g.g, &g.h, &lower, &[f64::INFINITY; N_PARAMS])
    };
    let mut check = active_set()?;
    for _ in 0..20 {
        let t = Instant::now();
        check = active_set()?;
        times.push(t.elapsed().as_secs_f64());
    }
    let max_diff = fit
        .theta
        .iter()
        .zip(&check)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    println!(
        "active set on ΦᵀΦ: median {:.2} ms over 20 solves; max |θ_clarabel − θ_active_set| = {max_diff:.2e}",
        median_ms(times)
    );
    let truth = PowerModel::PAPER.to_vector();
    let worst = fit
        .theta
        .iter()
        .zip(&truth)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    println!("largest |θ − θ_paper| = {worst:.4} (noise 0.3 W per row)");

    let model = g1viz::power::PowerModel::from_vector(&fit.theta49()?);
    let calls = 10_000_000u64;
    let mut tau = [1.0, 0.5, 0.2, 2.0, 0.1, 0.3, 0.05];
    let mut dq = [0.3, -0.2, 0.1, 1.0, 0.0, 0.5, -0.4];
    let tau0_sq = [1.0, 0.25, 0.04, 4.0, 0.01, 0.09, 0.0];
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    let t = Instant::now();
    let mut acc = 0.0;
    for k in 0..calls {
        tau[0] = (k & 1023) as f64 * 1e-3;
        dq[3] = (k & 511) as f64 * 2e-3;
        acc += black_box(&model).predict(black_box(&tau), black_box(&dq), black_box(&tau0_sq));
    }
    let predict_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    for k in 0..calls {
        dq[3] = (k & 511) as f64 * 2e-3;
        acc += black_box(&model)
            .breakdown(black_box(&tau), black_box(&dq), black_box(&tau0_sq))
            .copper[3];
    }
    let breakdown_s = t.elapsed().as_secs_f64();
    let allocations = ALLOCATIONS.load(Ordering::Relaxed) - before;
    black_box(acc);
    println!(
        "predict:   {:.1} M calls/s ({:.1} ns/call); breakdown: {:.1} M calls/s; heap allocations during {} calls: {allocations}",
        calls as f64 / predict_s / 1e6,
        predict_s / calls as f64 * 1e9,
        calls as f64 / breakdown_s / 1e6,
        2 * calls
    );

    if let Some(dir) = report_dir {
        use g1viz::identify::{PredictionSet, ReportInput, TermContributions, write_report};
        let predicted: Vec<f64> = rows
            .iter()
            .map(|r| model.breakdown_from_regressor(r).total())
            .collect();
        let mut means = TermMeans::default();
        rows.iter()
            .for_each(|r| means.add(&model.breakdown_from_regressor(r)));
        let names: Vec<String> = [
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
        .collect();
        let metrics = ModelMetrics {
            identification: Some(g1viz::power::DatasetMetrics {
                dataset: "synthetic, trajectory-averaged".into(),
                fit: Metrics::compute(&y, &predicted),
                condition_number: condition_number(&rows),
            }),
            validation: None,
        };
        let mut file = ModelFile::new(&model, &names, metrics, Provenance::default())?;
        file.theta_std_err = Some(fit.std_err.clone());
        let input = ReportInput {
            title: "bench_solve: synthetic paper-sized fit".into(),
            model: file,
            identification: Some(PredictionSet {
                label: "identification".into(),
                measured: y.clone(),
                predicted,
                trials: Vec::new(),
            }),
            validation: None,
            terms: Some(TermContributions::from_means("identification rows", &means)),
            aggregation: Vec::new(),
            truth: Some(PowerModel::PAPER),
            notes: Vec::new(),
        };
        write_report(std::path::Path::new(&dir), &input)?;
        println!("report written to {dir}/report.md");
    }
    Ok(())
}
