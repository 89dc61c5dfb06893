//! Benchmark of `g1viz fleet` on a synthetic fleet written by the simulator.
//!
//! ```text
//! cargo run --example bench_fleet -- DIR [ROBOTS DAYS EVERY PRESET SEED]   # default: 20 30 1 smoke, a fresh seed
//! ```
//!
//! Writes the fleet into DIR (once: an existing DIR is reused) with wear on three parameters of
//! two robots, a 40 % offset on one and a payload on another, then fits it by robot and week on
//! the first third of the days (`--where` on the reading time, pushed down to the Parquet scan)
//! and on all of them, printing rows, time and peak memory (the process's resident high-water
//! mark, reset before each fit) per million rows, the data read, and the flags.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use g1viz::fleet::synth::{FleetSpec, Wear, write_fleet};
use g1viz::fleet::{Engine, FleetOptions, Key, drift, fit_fleet};

/// Peak resident memory since the last reset [MB] (Linux), and a reset.
fn peak_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn reset_peak() {
    // "5" resets the peak resident set size (Linux ≥ 4.0); harmless elsewhere.
    std::fs::write("/proc/self/clear_refs", "5").ok();
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = PathBuf::from(
        args.first()
            .context("usage: bench_fleet DIR [ROBOTS DAYS EVERY PRESET SEED]")?,
    );
    let num = |i: usize, d: usize| args.get(i).and_then(|s| s.parse().ok()).unwrap_or(d);
    let spec = FleetSpec {
        robots: num(1, 20),
        days: num(2, 30),
        every_days: num(3, 1),
        preset: args
            .get(4)
            .map(|s| s.parse())
            .transpose()?
            .unwrap_or(g1viz::sim::Preset::Smoke),
        wear: vec![
            Wear {
                robot: 0,
                param: 7, // b0
                offset: 0.0,
                per_week: 0.1,
            },
            Wear {
                robot: 0,
                param: 10, // b3
                offset: 0.0,
                per_week: 0.1,
            },
            // c1 above the smoke trial set's detection limit (4 calibrated slope errors of
            // 0.07–0.11 W·s/rad a week over 30 days ≈ 28–31 % of nominal a week; docs/fleet.md).
            Wear {
                robot: 3,
                param: 15, // c1
                offset: 0.0,
                per_week: 0.5,
            },
            Wear {
                robot: 2,
                param: 9, // b2
                offset: 0.4,
                per_week: 0.0,
            },
        ],
        payload_robot: Some(1),
        // A fresh seed unless given (the fleet's noise is not one chosen to pass).
        seed: num(5, std::time::UNIX_EPOCH.elapsed()?.subsec_nanos() as usize) as u64,
    };
    if !dir.exists() {
        let t = Instant::now();
        let rows = write_fleet(&dir, &spec, &mut |done, total| {
            eprint!("\rsimulating, identifying, exporting: {done}/{total} sessions");
        })?;
        eprintln!();
        println!(
            "wrote {rows} rows of {} robots × {} days (seed {}) in {:.0} s",
            spec.robots,
            spec.days,
            spec.seed,
            t.elapsed().as_secs_f64()
        );
    }
    // The first third of the days, then all of them.
    for third in [true, false] {
        reset_peak();
        let t = Instant::now();
        let engine = Engine::open(std::slice::from_ref(&dir))?;
        let filter = if third {
            let (first, _) = engine.query("SELECT MIN(t_ns) AS t FROM rows")?;
            let t0 = first[0].column(0).as_any();
            let t0 = t0
                .downcast_ref::<arrow_array::Int64Array>()
                .context("MIN(t_ns) is not an integer")?
                .value(0);
            Some(format!(
                "t_ns < {}",
                t0 + (spec.days / 3) as i64 * 86_400_000_000_000
            ))
        } else {
            None
        };
        let opts = FleetOptions {
            by: vec![Key::Robot, Key::Week],
            target: "mbs".into(),
            filter,
            cascade: g1viz::trial::Cascade::default(),
            keep_results: false,
        };
        let fit = fit_fleet(&engine, &opts, &mut |_| {})?;
        let secs = t.elapsed().as_secs_f64();
        let rows: usize = fit.groups.iter().map(|g| g.rows).sum();
        let mrows = rows as f64 / 1e6;
        let peak = peak_mb().unwrap_or(f64::NAN);
        println!(
            "{}: {rows} rows, {} groups, {:.2} s ({:.1} s per million rows), peak RSS {peak:.0} MB ({:.0} MB per million rows), {:.1} MB of Parquet data read",
            if third {
                "first third of the days"
            } else {
                "all days"
            },
            fit.groups.len(),
            secs,
            secs / mrows,
            peak / mrows,
            fit.bytes_scanned as f64 / 1e6
        );
        if let Some(d) = drift::analyse(&fit, 4.0, 4) {
            for t in d.drifting() {
                println!(
                    "  drift {} θ{} {:+.4}/week (z {:+.1})",
                    t.robot, t.param, t.slope, t.z
                );
            }
            for o in &d.outliers {
                println!("  differs {} θ{} (z {:+.1})", o.robot, o.param, o.z);
            }
        }
    }
    Ok(())
}
