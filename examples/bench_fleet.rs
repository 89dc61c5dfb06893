//! Benchmark of `g1viz fleet` on a synthetic fleet written by the simulator.
//!
//! ```text
//! cargo run --example bench_fleet -- DIR [ROBOTS DAYS EVERY PRESET SEED]   # default: 20 30 1 smoke, a fresh seed
//! ```
//!
//! Writes the fleet into DIR (once: an existing DIR is reused) with wear on three parameters of
//! two robots, a 40 % offset on one and a payload on another, then fits it by robot and week on
//! the files of its first day, its first 10 days and all of them, each fit in a process of its
//! own (this program again, `--fit DIR DAYS`), printing rows, files, time and peak memory (the
//! process's resident high-water mark), the data read, and the flags of the last.
//!
//! At a million rows (fleet 30699159 copied ten times by `examples/fleet_replicate.py`, `--fit DIR 30`,
//! 2026-11-29, idle): 1,073,670 rows, 6,000 files, 1,000 groups, 47.0 s (43.8 s per million rows), peak RSS
//! 172–176 MB (docs/fleet.md, A million rows).
//!
//! Fleet 30699159 (`/tmp/fleet11/fresh1`), 2026-11-29, load ≈ 2, two runs each (docs/fleet.md,
//! Memory): 1 / 10 / 30 days, peak RSS and wall time — before (main 2499cb7) 92–94 / 121–122 /
//! 155–158 MB, 0.66–0.74 / 1.97–2.31 / 4.69–5.14 s; now (residual passes in SQL, no file
//! statistics, 50 files a chunk) 93 / 113–114 / 121–122 MB, 0.72–0.73 / 2.15–2.18 / 5.20–5.39 s.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use g1viz::fleet::synth::{FleetSpec, Wear, write_fleet};
use g1viz::fleet::{Engine, FleetOptions, Key, drift, fit_fleet};

/// Peak resident memory of this process [MB] (Linux).
fn peak_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// One fit, by robot and week, of the files of the fleet's first `days` days (`DIR/ROBOT/dayNNN.parquet`).
fn fit(dir: &str, days: usize) -> Result<()> {
    let t = Instant::now();
    let mut files = Vec::new();
    for robot in std::fs::read_dir(dir)? {
        for f in std::fs::read_dir(robot?.path())? {
            let p = f?.path();
            let day = p
                .file_stem()
                .and_then(|s| s.to_str()?.strip_prefix("day")?.parse().ok());
            if day.is_some_and(|d: usize| d < days) {
                files.push(p);
            }
        }
    }
    let engine = Engine::open(&files)?;
    let opts = FleetOptions {
        by: vec![Key::Robot, Key::Week],
        target: "mbs".into(),
        filter: None,
        cascade: g1viz::trial::Cascade::default(),
        keep_results: false,
    };
    let fit = fit_fleet(&engine, &opts, &mut |_| {})?;
    let secs = t.elapsed().as_secs_f64();
    let rows: usize = fit.groups.iter().map(|g| g.rows).sum();
    println!(
        "{days} days: {rows} rows, {} files, {} groups, {secs:.2} s ({:.1} s per million rows), peak RSS {:.0} MB, {:.1} MB of Parquet data read",
        engine.files,
        fit.groups.len(),
        secs / (rows as f64 / 1e6),
        peak_mb().unwrap_or(f64::NAN),
        fit.bytes_scanned as f64 / 1e6
    );
    if let Some(d) = drift::analyse(&fit, 4.0, 4) {
        for t in d.drifting() {
            let (r, p, s, z) = (&t.robot, t.param, t.slope, t.z);
            println!("  drift {r} θ{p} {s:+.4}/week (z {z:+.1})");
        }
        for o in &d.outliers {
            println!("  differs {} θ{} (z {:+.1})", o.robot, o.param, o.z);
        }
    }
    Ok(())
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if let [flag, dir, days] = &args[..]
        && flag == "--fit"
    {
        return fit(dir, days.parse()?);
    }
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
    // Each size in a process of its own: a process's peak memory does not go down again.
    for days in [1, 10, spec.days] {
        let out = std::process::Command::new(std::env::current_exe()?)
            .args(["--fit", &dir.display().to_string(), &days.to_string()])
            .output()?;
        let text = String::from_utf8_lossy(&out.stdout);
        // The flags of the full fit only.
        let lines = text
            .lines()
            .filter(|l| days == spec.days || !l.starts_with("  "));
        lines.for_each(|l| println!("{l}"));
        anyhow::ensure!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    Ok(())
}
