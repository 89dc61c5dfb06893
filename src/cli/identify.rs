//! `g1viz identify`: the paper's identification on one or more sessions, optionally validated on
//! a hold-out session; writes model.json and a report.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;

use super::{FitArgs, ReadArgs};
use g1viz::identify;
use g1viz::util::check_outputs;

#[derive(Args)]
pub struct IdentifyArgs {
    /// Identification session(s): files, bag folders, or folders of recordings (one robot;
    /// each session keeps its own trials).
    #[arg(required_unless_present = "rows")]
    sessions: Vec<PathBuf>,
    /// Fit from a row table written by `g1viz export rows` instead of sessions (the rows of
    /// trials the export flagged as rejected are left out).
    #[arg(long, value_name = "PARQUET", conflicts_with_all = ["sessions", "holdout", "report"])]
    rows: Option<PathBuf>,
    /// Where to write the model.
    #[arg(short, long, value_name = "FILE", default_value = "model.json")]
    output: PathBuf,
    /// Hold-out session validated with the identified model (metrics go into model.json).
    #[arg(long, value_name = "SESSION")]
    holdout: Option<PathBuf>,
    /// Write a markdown report with figures into DIR.
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    #[command(flatten)]
    fit: FitArgs,
    #[command(flatten)]
    read: ReadArgs,
}

/// Identify, validate, write the model file and the report.
pub fn run(a: IdentifyArgs) -> Result<()> {
    if let Some(table) = &a.rows {
        return from_rows(&a, table);
    }
    let opts = a.fit.options();
    let outputs = [
        ("model file", Some(&*a.output)),
        ("report folder", a.report.as_deref()),
    ];
    let why = "its trials would count twice (or be validated on themselves)";
    let holdout = a.holdout.as_deref();
    // Each session is streamed twice (segmentation, then rows): memory stays bounded whatever
    // the sessions' length.
    let (files, map) = a.read.sessions(&a.sessions, holdout, why, &outputs, &[])?;
    let stream = g1viz::session::StreamOptions::default();
    let id = identify::identify_files(&files, &opts, &stream)?;
    super::warn(id.sessions.iter().flat_map(|s| &s.warnings));
    let validation = match holdout {
        Some(p) => {
            let v =
                identify::validate_file(&id.model, &a.read.session_file(p, &map), &opts, &stream)?;
            super::warn(&v.session.warnings);
            Some(v)
        }
        None => None,
    };
    let names = map.joint_names.clone();
    let file = id.model_file(&names, validation.as_ref(), "")?;
    file.save(&a.output)?;

    println!("identification:\n{}", id.summary());
    if let Some(v) = &validation {
        println!("hold-out {}:\n{}", v.session.source.display(), v.summary());
    }
    println!("wrote {}", a.output.display());
    if let Some(dir) = &a.report {
        let truth = files.first().and_then(|f| g1viz::sim::truth_model(&f.path));
        let input = id.report_input(file, validation.as_ref(), truth);
        g1viz::identify::write_report(dir, &input)?;
        println!("wrote {}", dir.join("report.md").display());
    }
    Ok(())
}

/// `identify --rows`: the constrained fit of a row table's kept rows; a model file whose
/// provenance names the table's sessions and robots.
fn from_rows(a: &IdentifyArgs, table: &Path) -> Result<()> {
    use g1viz::power::{
        DatasetMetrics, ModelFile, ModelMetrics, Provenance, SessionRef, SolverRecord,
    };
    use g1viz::rows::RowTable;
    check_outputs(&[("model file", Some(&a.output))], &[Some(table)])?;
    let RowTable { joint_names, rows } = g1viz::rows::read_table(table)?;
    // The regressors are per joint: a table of another arm (or robot) would fit the wrong joints.
    let names = a.read.signal_map()?.joint_names;
    match joint_names {
        Some(t) if t != names => anyhow::bail!(
            "{}: the rows are for joints {} but the signal map (--signals) is for {}; \
             fit them with the matching --signals",
            table.display(),
            t.join(", "),
            names.join(", ")
        ),
        Some(_) => {}
        None => eprintln!(
            "warning: {} names no joints (metadata {}); assuming {}",
            table.display(),
            g1viz::rows::JOINT_NAMES_KEY,
            names.join(", ")
        ),
    }
    let target = a.fit.options().target.name();
    if let Some(r) = rows.iter().find(|r| r.target != target) {
        anyhow::bail!(
            "{}: rows of target {} but --target {target}",
            table.display(),
            r.target
        );
    }
    let kept: Vec<_> = rows
        .iter()
        .filter(|r| r.rejected_by.is_none())
        .map(|r| r.row.clone())
        .collect();
    let fit = identify::fit_given_rows(&kept)
        .map_err(|e| e.context(format!("fitting the rows of {}", table.display())))?;
    let mut sessions: Vec<(String, String)> = rows
        .iter()
        .map(|r| (r.robot.clone(), r.session.clone()))
        .collect();
    sessions.sort();
    sessions.dedup();
    let provenance = Provenance {
        sessions: sessions
            .iter()
            .map(|(robot, s)| SessionRef {
                path: s.clone(),
                size_bytes: 0,
                role: format!(
                    "identification (robot {robot}, rows from {})",
                    table.display()
                ),
            })
            .collect(),
        target: target.into(),
        rows: "per_reading".into(),
        solver: Some(SolverRecord {
            method: fit.solver.method,
            status: fit.solver.status,
            iterations: fit.solver.iterations,
        }),
        notes: vec![format!(
            "fitted from {}: {} of {} rows (rows of rejected trials left out)",
            table.display(),
            kept.len(),
            rows.len()
        )],
        ..Provenance::default()
    };
    let metrics = ModelMetrics {
        identification: Some(DatasetMetrics {
            dataset: format!("per-reading rows of {} sessions", sessions.len()),
            fit: fit.fit,
            condition_number: fit.kappa,
        }),
        validation: None,
    };
    let mut file = ModelFile::new(&fit.model, &names, metrics, provenance)?;
    file.theta_std_err = Some(fit.std_err.clone());
    file.save(&a.output)?;
    println!(
        "fitted {} rows of {} sessions: R² {:.4}, RMSE {:.3} W",
        kept.len(),
        sessions.len(),
        fit.fit.r2,
        fit.fit.rmse
    );
    println!("wrote {}", a.output.display());
    Ok(())
}
