//! `g1viz identify`: the paper's identification on one or more sessions, optionally validated on
//! a hold-out session; writes model.json and a report.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;

use super::{FitArgs, ReadArgs};
use g1viz::identify;
use g1viz::util::{check_distinct_sessions, check_outputs};

#[derive(Args)]
pub struct IdentifyArgs {
    /// Identification session(s).
    #[arg(required = true)]
    sessions: Vec<PathBuf>,
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
    let opts = a.fit.options();
    let mut sessions: Vec<&Path> = a.sessions.iter().map(PathBuf::as_path).collect();
    if let Some(h) = &a.holdout {
        sessions.push(h);
    }
    check_distinct_sessions(
        &sessions,
        "its trials would count twice (or be validated on themselves)",
    )?;
    let mut inputs: Vec<Option<&Path>> = sessions.iter().map(|p| Some(*p)).collect();
    inputs.push(a.read.signals.as_deref());
    check_outputs(
        &[
            ("model file", Some(&a.output)),
            ("report folder", a.report.as_deref()),
        ],
        &inputs,
    )?;
    let recs = a
        .sessions
        .iter()
        .map(|p| a.read.load(p))
        .collect::<Result<Vec<_>>>()?;
    let id = identify::identify(&recs, &opts)?;
    let validation = match &a.holdout {
        Some(p) => Some(identify::validate(&id.model, &a.read.load(p)?, &opts)?),
        None => None,
    };
    let names = recs
        .first()
        .map(|r| r.joint_names.clone())
        .unwrap_or_default();
    let file = id.model_file(&names, validation.as_ref(), "")?;
    file.save(&a.output)?;

    println!("identification:\n{}", id.summary());
    if let Some(v) = &validation {
        println!("hold-out {}:\n{}", v.session.source.display(), v.summary());
    }
    println!("wrote {}", a.output.display());
    if let Some(dir) = &a.report {
        let truth = a.sessions.first().and_then(|p| g1viz::sim::truth_model(p));
        let input = id.report_input(file, validation.as_ref(), truth);
        g1viz::identify::report::write_report(dir, &input)?;
        println!("wrote {}", dir.join("report.md").display());
    }
    Ok(())
}
