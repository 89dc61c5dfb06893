//! `g1viz export rows`: the per-reading rows of one or more sessions as a Parquet table, for
//! DataFusion / DuckDB / Polars across sessions and robots (`identify --rows` fits from it).

use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, Subcommand};

use super::{FitArgs, ReadArgs};

/// What to export.
#[derive(Args)]
pub struct ExportArgs {
    #[command(subcommand)]
    what: ExportWhat,
}

#[derive(Subcommand)]
enum ExportWhat {
    /// Per-reading rows (regressors, net power, trial/session/robot, temperatures, filter flags)
    /// as Parquet.
    #[command(after_help = "\
Examples:
  g1viz export rows a.mcap b.mcap -o rows.parquet --robot g1_lab
  g1viz export rows recordings/ -o rows.parquet                    # every recording in a folder")]
    Rows(RowsArgs),
}

#[derive(Args)]
struct RowsArgs {
    /// Session(s): files, bag folders, or folders of recordings.
    #[arg(required = true, value_name = "SESSION")]
    sessions: Vec<PathBuf>,
    /// The Parquet file to write.
    #[arg(short, long, value_name = "FILE")]
    output: PathBuf,
    /// Robot name written in every row (default: the first session's folder name).
    #[arg(long, value_name = "NAME")]
    robot: Option<String>,
    #[command(flatten)]
    fit: FitArgs,
    #[command(flatten)]
    read: ReadArgs,
}

/// Run the export.
pub fn run(a: ExportArgs) -> Result<()> {
    match a.what {
        ExportWhat::Rows(r) => rows(r),
    }
}

fn rows(a: RowsArgs) -> Result<()> {
    let outputs = [("row table", Some(&*a.output))];
    let why = "its rows would count twice";
    let (files, map) = a.read.sessions(&a.sessions, None, why, &outputs, &[])?;
    // The identification decides the sensor timing and which trials its filters reject. Every
    // session is streamed (memory bounded whatever its length): twice for the identification,
    // once more for the rows.
    let id = g1viz::identify::identify_files(
        &files,
        &a.fit.options(),
        &g1viz::session::StreamOptions::default(),
    )?;
    super::warn(id.sessions.iter().flat_map(|s| &s.warnings));
    let robot = a.robot.clone().unwrap_or_else(|| {
        files[0]
            .path
            .canonicalize()
            .ok()
            .and_then(|p| {
                p.parent()?
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
            })
            .unwrap_or_else(|| "robot".into())
    });
    let table = g1viz::rows::table_rows_files(&files, &id, &robot)?;
    g1viz::rows::write_parquet(&a.output, &table, &map.joint_names)?;
    let rejected = table.iter().filter(|r| r.rejected_by.is_some()).count();
    println!(
        "wrote {} ({} rows of {} sessions, robot {robot}; {rejected} rows in rejected trials, flagged)",
        a.output.display(),
        table.len(),
        files.len()
    );
    Ok(())
}
