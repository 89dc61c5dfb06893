//! `g1viz info`: what a recording holds — container, topics, counts, rates, time range — and the
//! arm signals resolved from it.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use super::ReadArgs;
use g1viz::read::Session;
use g1viz::signals::{Recording, rate_hz};

#[derive(Args)]
pub struct InfoArgs {
    /// Recording: .mcap, ROS 2 bag directory (or its metadata.yaml / .db3), or ROS 1 .bag.
    session: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    read: ReadArgs,
}

/// Print the summary (text or JSON).
pub fn run(a: InfoArgs) -> Result<()> {
    let mut session = Session::open(&a.session, &a.read.open_options())?;
    let info = session.info()?;
    let rec = a.read.load(&a.session);
    if a.json {
        let (signals, why) = match &rec {
            Ok(rec) => (Some(signal_summary(rec)), None),
            Err(e) => (None, Some(format!("{e:#}"))),
        };
        let out = serde_json::json!({
            "container": info,
            "signals": signals,
            "signals_error": why,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    let span = (info.end_ns.saturating_sub(info.start_ns)) as f64 * 1e-9;
    println!("file:       {}", info.path.display());
    println!("format:     {}", info.format);
    println!("messages:   {}", info.messages);
    println!("duration:   {span:.3} s");
    println!("start:      {} ns", info.start_ns);
    println!("end:        {} ns", info.end_ns);
    println!("topics:");
    for t in &info.topics {
        println!(
            "  {:<24} {:>8} msgs  {:>8.2} Hz  {} [{}]",
            t.topic, t.count, t.rate_hz, t.type_name, t.encoding
        );
    }
    for w in &info.warnings {
        println!("warning: {w}");
    }
    match rec {
        Ok(rec) => {
            println!("signals:");
            println!("  arm joints: {}", rec.joint_names.join(", "));
            let line = |name: &str, n: usize, t: &[f64], unit: &str| {
                println!("  {name:<22} {n:>8} {unit} at {:.2} Hz", rate_hz(t));
            };
            line("joint states", rec.state.t.len(), &rec.state.t, "samples");
            line("commands", rec.command.t.len(), &rec.command.t, "samples");
            line(
                "MBS power (arm rail)",
                rec.mbs.t.len(),
                &rec.mbs.t,
                "readings",
            );
            line("BMS power (robot)", rec.bms.t.len(), &rec.bms.t, "readings");
        }
        Err(e) => println!("signals: not resolved: {e:#}"),
    }
    Ok(())
}

fn signal_summary(rec: &Recording) -> serde_json::Value {
    serde_json::json!({
        "joints": rec.joint_names,
        "state": { "samples": rec.state.t.len(), "rate_hz": rate_hz(&rec.state.t) },
        "command": { "samples": rec.command.t.len(), "rate_hz": rate_hz(&rec.command.t) },
        "mbs_power": { "readings": rec.mbs.t.len(), "rate_hz": rate_hz(&rec.mbs.t) },
        "bms_power": { "readings": rec.bms.t.len(), "rate_hz": rate_hz(&rec.bms.t) },
    })
}
