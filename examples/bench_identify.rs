//! Benchmark of identification end to end: read → segment → regressors → filters → fit, on a
//! session file (e.g. a paper-scale session from `bench_sim paper OUT.mcap`). With a truth sidecar
//! next to the file (`x.truth.json`), prints the per-parameter error against the true θ; with a
//! second session, validates on it.
//!
//! ```text
//! cargo run --release --no-default-features --example bench_identify -- SESSION.mcap [HOLDOUT.mcap]
//! ```

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use g1viz::N_PARAMS;
use g1viz::identify::{self as pipeline, IdentifyOptions};
use g1viz::power::PowerModel;
use g1viz::signals::{SignalMap, load_recording};

fn truth_theta(session: &Path) -> Option<[f64; N_PARAMS]> {
    let text = std::fs::read_to_string(session.with_extension("truth.json")).ok()?;
    let json: serde_json::Value = serde_json::from_str(&text).ok()?;
    let v: Vec<f64> = json["theta"]["vector"]
        .as_array()?
        .iter()
        .filter_map(|x| x.as_f64())
        .collect();
    v.try_into().ok()
}

fn main() -> Result<()> {
    let args: Vec<PathBuf> = std::env::args().skip(1).map(PathBuf::from).collect();
    let session = args
        .first()
        .context("usage: bench_identify SESSION.mcap [HOLDOUT.mcap]")?;
    let map = SignalMap::g1_left_arm();

    let t0 = Instant::now();
    let rec = load_recording(session, &map, &Default::default())?;
    let t_read = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let seg = g1viz::trial::segment(&rec, &Default::default());
    let t_segment = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    let id = pipeline::identify(std::slice::from_ref(&rec), &IdentifyOptions::default())?;
    let t_identify = t2.elapsed().as_secs_f64();
    println!(
        "{}: {} state samples, {} trials ({} unmatched stretches)",
        session.display(),
        rec.state.t.len(),
        seg.trials.len(),
        seg.unmatched.len()
    );
    println!(
        "read {t_read:.2} s, segment {t_segment:.3} s, identify {t_identify:.2} s (incl. window/lag search and the three \
         pairings), total {:.2} s",
        t0.elapsed().as_secs_f64()
    );
    println!(
        "window {:.3} s, lag {:.3} s; {} trials used, {} rejected; fit R² {:.4}, RMSE {:.3} W on {} rows",
        id.alignment.window_s,
        id.alignment.lag_s,
        id.trials_used,
        id.rejections.len(),
        id.fit.r2,
        id.fit.rmse,
        id.fit.n
    );
    for m in &id.modes {
        println!(
            "  {:>7} rows: n {:>7}, κ(ΦᵀΦ) {:.3e}, R² {:.4}",
            m.mode.name(),
            m.quality.n,
            m.kappa,
            m.quality.r2
        );
    }

    if let Some(truth) = truth_theta(session) {
        let theta = id.model.to_vector();
        let names: Vec<String> = (0..N_PARAMS).map(PowerModel::param_name).collect();
        println!("parameter  identified  truth   error");
        for p in 0..N_PARAMS {
            println!(
                "{:>9} {:>10.4} {:>7.4} {:>+8.4}",
                names[p],
                theta[p],
                truth[p],
                theta[p] - truth[p]
            );
        }
        let rms = (theta
            .iter()
            .zip(&truth)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            / N_PARAMS as f64)
            .sqrt();
        println!("rms parameter error {rms:.4}");
    }

    if let Some(holdout) = args.get(1) {
        let rec = load_recording(holdout, &map, &Default::default())?;
        for (label, model) in [("identified", id.model), ("paper θ", PowerModel::PAPER)] {
            let v = pipeline::validate(&model, &rec, &IdentifyOptions::default())?;
            println!(
                "{label} on {}: reading R² {:.4} RMSE {:.3} W; trial R² {:.4} (like for like), {:.4} (paper)",
                holdout.display(),
                v.reading_level.r2,
                v.reading_level.rmse,
                v.trial_level_aligned.r2,
                v.trial_level.r2
            );
        }
    }
    Ok(())
}
