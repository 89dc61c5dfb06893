//! `g1viz fleet`: per-group power models of row tables (their sums run as SQL by an embedded
//! engine over the Parquet files), the drift of each robot's parameters, a report and a Rerun
//! recording.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use super::FitArgs;
use g1viz::fleet::{self, Engine, FleetOptions, Key};

#[derive(Args)]
pub struct FleetArgs {
    /// Row tables: Parquet files from `g1viz export rows`, or folders of them (searched
    /// recursively, e.g. a dataset partitioned as ROBOT/DAY.parquet).
    #[arg(required = true, value_name = "ROWS")]
    rows: Vec<PathBuf>,
    /// Grouping keys, comma-separated: robot, session, day, week (UTC; weeks start on Monday).
    /// Drift needs robot and a period (day, week or session).
    #[arg(long, default_value = "robot,week", value_name = "KEYS")]
    by: String,
    /// Only the rows where this SQL predicate over the row table's columns holds, e.g.
    /// `robot = 'g1_03' AND t_ns >= 1767225600e9`; pushed down to the Parquet scan, so row
    /// groups (and files) its column statistics exclude are not read.
    #[arg(long = "where", value_name = "SQL")]
    filter: Option<String>,
    /// A drift or a difference from the fleet is flagged beyond this many standard errors.
    #[arg(long, default_value_t = 4.0, value_name = "Z")]
    z: f64,
    /// Write fleet.md, fleet.json and fleet.png into DIR.
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    /// Write a Rerun recording of the fleet on a time axis (`rerun FILE` opens it).
    #[arg(long, value_name = "FILE")]
    save: Option<PathBuf>,
    /// Write each query the engine ran (NN_name.sql) with its result (NN_name.csv) into DIR, to
    /// run the same SQL on another engine (examples/fleet_sql_crosscheck.py: DuckDB, Spark).
    #[arg(long, value_name = "DIR")]
    save_sql: Option<PathBuf>,
    /// The filters and target of identification (--mode, --window and --lag are the export's
    /// and do not apply here).
    #[command(flatten)]
    fit: FitArgs,
}

/// Fit the groups, analyse the drift, print the summary and write the outputs.
pub fn run(a: FleetArgs) -> Result<()> {
    let opts = a.fit.options();
    let options = FleetOptions {
        by: Key::parse_list(&a.by)?,
        target: opts.target.name().to_string(),
        filter: a.filter.clone(),
        cascade: opts.filters,
        keep_results: a.save_sql.is_some(),
    };
    let started = std::time::Instant::now();
    let bar = super::spinner("opening the row tables");
    let engine = Engine::open(&a.rows)?;
    let fit = fleet::fit_fleet(&engine, &options, &mut |stage| {
        bar.set_message(stage.to_string())
    })?;
    bar.finish_and_clear();
    let joints = engine
        .joint_names
        .clone()
        .unwrap_or_else(|| g1viz::signals::SignalMap::g1_left_arm().joint_names);
    let drift = fleet::drift::analyse(&fit, a.z, 4);
    let rows: usize = fit.groups.iter().map(|g| g.rows).sum();
    let failed = fit.groups.iter().filter(|g| g.error.is_some()).count();
    println!(
        "{} groups ({failed} without a model) from {rows} rows of {} files in {:.1} s \
         ({:.1} MB of Parquet data read)",
        fit.groups.len(),
        engine.files,
        started.elapsed().as_secs_f64(),
        fit.bytes_scanned as f64 / 1e6
    );
    for g in fit.groups.iter().filter(|g| g.error.is_some()) {
        println!(
            "  {}: {}",
            g.label(&fit.by),
            g.error.as_deref().unwrap_or("")
        );
    }
    match &drift {
        Some(d) => {
            let flags = d.flags(&joints);
            for (_, text) in &flags {
                println!("flagged: {text}");
            }
            // The multiplicity: each followed robot parameter is tested for drift, and for level where
            // most robots follow it.
            println!(
                "{} flags at |z| > {} from {} robot parameters free in ≥ 4 periods, tested for drift and, where most robots follow them, for level",
                flags.len(),
                a.z,
                d.trends.len()
            );
        }
        None => println!("no drift analysis (--by needs robot and day, week or session)"),
    }
    if let Some(dir) = &a.save_sql {
        fleet::save_queries(&fit, dir)?;
        println!("wrote {} queries to {}", fit.queries.len(), dir.display());
    }
    if let Some(dir) = &a.report {
        fleet::report::write(dir, &fit, drift.as_ref(), &joints)?;
        println!("wrote {}", dir.join("fleet.md").display());
    }
    if let Some(path) = &a.save {
        let Some(d) = &drift else {
            anyhow::bail!("--save needs a drift analysis: --by with robot and a period");
        };
        save_rrd(
            path,
            d,
            &joints,
            &fleet::report::markdown(&fit, drift.as_ref(), &joints),
        )?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

#[cfg(feature = "viz")]
use fleet::viz::write_rrd as save_rrd;

#[cfg(not(feature = "viz"))]
fn save_rrd(_: &std::path::Path, _: &fleet::drift::Drift, _: &[String], _: &str) -> Result<()> {
    anyhow::bail!("--save needs the viz feature (built without it)")
}
