//! `g1viz validate`: a model on a hold-out session.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use super::{FitArgs, ReadArgs};
use g1viz::power::load_model_for;

#[derive(Args)]
pub struct ValidateArgs {
    /// The model to validate (model.json, or `paper` for the paper's parameters).
    #[arg(long, value_name = "M")]
    model: PathBuf,
    /// Hold-out session.
    session: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    fit: FitArgs,
    #[command(flatten)]
    read: ReadArgs,
}

/// Validate and print the metrics (text or JSON).
pub fn run(a: ValidateArgs) -> Result<()> {
    let map = a.read.signal_map()?;
    let model = load_model_for(&a.model, &map.joint_names, a.fit.options().target)?;
    // Streamed twice (segmentation, then rows): memory stays bounded whatever the length.
    let busy = super::spinner("validating the model (reading the session twice)");
    let v = g1viz::identify::validate_file(
        &model,
        &a.read.session_file(&a.session, &map),
        &a.fit.options(),
        &g1viz::session::StreamOptions::default(),
    );
    busy.finish_and_clear();
    let v = v?;
    super::warn(&v.session.warnings);
    for n in &v.notes {
        eprintln!("note: {n}");
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!("{}", v.summary());
    }
    // An undefined fit is a failed validation, not a result.
    for (what, r2) in [
        ("per-trial", v.trial_level.r2),
        ("per-reading", v.reading_level.r2),
    ] {
        anyhow::ensure!(
            r2.is_finite(),
            "validation of {} on {}: the {what} R² is not a number (predictions or measured power not finite, or the measured power constant)",
            a.model.display(),
            a.session.display()
        );
    }
    Ok(())
}
