//! `g1viz info`: what a recording holds — container, topics, counts, rates, time range — and the
//! arm signals resolved from it.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

use super::ReadArgs;
use g1viz::read::Session;
use g1viz::signals::{SeriesStats, signal_stats};

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

/// Print the summary (text or JSON). The signals are counted in one streamed pass, so memory
/// does not grow with the session.
pub fn run(a: InfoArgs) -> Result<()> {
    let mut session = Session::open(&a.session, &a.read.open_options())?;
    let info = session.info()?;
    let stats = a.read.signal_map().and_then(|map| {
        signal_stats(&a.session, &map, &a.read.open_options())
            .with_context(|| format!("reading {}", a.session.display()))
    });
    if let Ok(s) = &stats {
        super::warn(&s.warnings);
    }
    if a.json {
        let (signals, why) = match &stats {
            Ok(s) => (Some(s), None),
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
    match stats {
        Ok(s) => {
            println!("signals:");
            println!("  arm joints: {}", s.joints.join(", "));
            let line = |name: &str, x: &SeriesStats, unit: &str| {
                println!("  {name:<22} {:>8} {unit} at {:.2} Hz", x.count, x.rate_hz);
            };
            line("joint states", &s.state, "samples");
            line("commands", &s.command, "samples");
            line("MBS power (arm rail)", &s.mbs_power, "readings");
            line("BMS power (robot)", &s.bms_power, "readings");
        }
        Err(e) => println!("signals: not resolved: {e:#}"),
    }
    Ok(())
}
