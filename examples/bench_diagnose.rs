//! Benchmark of the diagnosis end to end on a paper-scale session (≈ 1000 trials, 3.3 h):
//! read → segment → rows at every scanned sensor lag → filters → hypothesis selection (power and
//! torque level) → locate → summary → report, on the loaded session; then the same diagnosis
//! streamed from the file as `g1viz diagnose` does it. Without a session argument it first
//! simulates one (not timed), optionally with concealed effects.
//!
//! ```text
//! cargo run --release --no-default-features --example bench_diagnose -- [SESSION.mcap] [--effect NAME=VALUE]… [--twin] [--report DIR]
//! ```

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use g1viz::diagnose::{self, DiagnoseOptions};
use g1viz::power::PowerModel;
use g1viz::signals::{SignalMap, load_recording};
use g1viz::sim::{self, Effects, Preset, SimConfig};

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let mut session: Option<PathBuf> = None;
    let mut effects = Effects::default();
    let mut twin = false;
    let mut report: Option<PathBuf> = None;
    while let Some(a) = args.next() {
        match a.as_str() {
            "--effect" => effects.enable(&args.next().context("--effect NAME=VALUE")?)?,
            "--twin" => twin = true,
            "--report" => report = Some(args.next().context("--report DIR")?.into()),
            _ => session = Some(a.into()),
        }
    }
    let dir = tempfile::tempdir()?;
    let path = match session {
        Some(p) => p,
        None => {
            let out = dir.path().join("paper.mcap");
            let t = Instant::now();
            let cfg = SimConfig {
                preset: Preset::Paper,
                seed: 21,
                effects,
                progress: false,
                ..SimConfig::default()
            };
            sim::simulate(&cfg, &out)?;
            eprintln!(
                "simulated a paper-scale session in {:.1} s (not part of the benchmark)",
                t.elapsed().as_secs_f64()
            );
            out
        }
    };
    let opts = DiagnoseOptions {
        reference: twin.then_some(PowerModel::PAPER),
        ..DiagnoseOptions::default()
    };
    let t0 = Instant::now();
    let rec = load_recording(&path, &SignalMap::g1_left_arm(), &Default::default())?;
    let t_read = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let d = diagnose::diagnose(&rec, &opts)?;
    let t_diag = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    if let Some(r) = &report {
        diagnose::write_report(r, &d)?;
    }
    let t_report = t2.elapsed().as_secs_f64();
    print!("{}", d.summary);
    println!(
        "{}: {} state samples, {} trials used ({} left out), {} readings, {} lags scanned",
        path.display(),
        rec.state.t.len(),
        d.n_trials,
        d.rejected.len(),
        d.n_readings,
        d.lag_scan.len()
    );
    println!(
        "read {t_read:.2} s, diagnose {t_diag:.2} s (segment, rows, filters, selection, torque level, locate){}, total {:.2} s",
        if report.is_some() {
            format!(", report {t_report:.2} s")
        } else {
            String::new()
        },
        t0.elapsed().as_secs_f64()
    );
    drop(rec);
    // What `g1viz diagnose SESSION` does: the session streamed trial by trial, never held whole.
    let t3 = Instant::now();
    let file = g1viz::session::SessionFile {
        path: path.clone(),
        map: SignalMap::g1_left_arm(),
        read: Default::default(),
        spill: Default::default(),
    };
    let streamed = diagnose::diagnose_files(std::slice::from_ref(&file), &opts, 5.0)?;
    println!(
        "streamed (as the CLI does): {:.2} s, the same accepted hypotheses: {}",
        t3.elapsed().as_secs_f64(),
        streamed
            .accepted
            .iter()
            .map(|h| h.id.as_str())
            .eq(d.accepted.iter().map(|h| h.id.as_str()))
    );
    Ok(())
}
