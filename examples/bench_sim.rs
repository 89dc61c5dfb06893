//! Benchmark of the digital twin: time to simulate and write a preset session, file size and
//! throughput. Also how the README example session is produced.
//!
//! ```text
//! cargo run --release --no-default-features --example bench_sim                 # paper preset → temp dir
//! cargo run --release --no-default-features --example bench_sim -- smoke OUT.mcap [EFFECT…]
//! cargo run --no-default-features --example bench_sim -- example examples/g1_example.mcap
//! ```

use std::time::Instant;

use anyhow::Context;
use g1viz::sim::{Preset, SimConfig, simulate};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let preset: Preset = args.first().map_or(Ok(Preset::Paper), |s| s.parse())?;
    let tmp = tempfile::tempdir()?;
    let out = args
        .get(1)
        .map_or_else(|| tmp.path().join("bench.mcap"), std::path::PathBuf::from);
    let mut cfg = SimConfig {
        preset,
        seed: 1,
        ..SimConfig::default()
    };
    for e in args.iter().skip(2) {
        cfg.effects.enable(e)?;
    }
    let t0 = Instant::now();
    let truth = simulate(&cfg, &out)?;
    let secs = t0.elapsed().as_secs_f64();
    let bytes = std::fs::metadata(&out)
        .with_context(|| format!("reading size of {}", out.display()))?
        .len();
    let c = truth.message_counts;
    let msgs = c.lowstate + c.arm_sdk + c.bms + c.mbs;
    println!(
        "preset {}: {} trials, {:.0} s of robot time",
        preset.name(),
        truth.trials.len(),
        truth.session.duration_s
    );
    println!(
        "  messages: {} (/lowstate {}, /arm_sdk {}, MBS {}, BMS {})",
        msgs, c.lowstate, c.arm_sdk, c.mbs, c.bms
    );
    println!(
        "  generation {secs:.2} s ({:.0} robot-s per s, {:.0} k msgs/s), file {:.1} MB",
        truth.session.duration_s / secs,
        msgs as f64 / secs / 1e3,
        bytes as f64 / 1e6
    );
    println!(
        "  contaminated trials {}, outlier trials {}, winding temperature {:.1}–{:.1} °C",
        truth.artefacts.contamination.n_trials,
        truth.artefacts.outliers.n_trials,
        truth.plant.thermal.winding_temp_range_c[0],
        truth.plant.thermal.winding_temp_range_c[1]
    );
    Ok(())
}
