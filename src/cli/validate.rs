//! `g1viz validate`: a model on a hold-out session.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use super::{FitArgs, ReadArgs};
use g1viz::power::load_model;

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
    let model = load_model(&a.model)?;
    let busy = super::spinner("reading the session");
    let rec = match a.read.load(&a.session) {
        Ok(rec) => rec,
        Err(e) => {
            busy.finish_and_clear();
            return Err(e);
        }
    };
    busy.set_message("validating the model");
    let v = g1viz::identify::validate(&model, &rec, &a.fit.options());
    busy.finish_and_clear();
    let v = v?;
    for n in &v.notes {
        eprintln!("note: {n}");
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!("{}", v.summary());
    Ok(())
}
