//! Use g1viz as a library: load an identified model (model.json, or `paper`), read a recorded
//! session and predict the arm's net electrical power sample by sample — what an RL reward or an
//! energy budget needs.
//!
//! `cargo run --example predict_power -- MODEL SESSION`
//! (e.g. `cargo run --example predict_power -- paper examples/g1_example.mcap`)

use std::path::PathBuf;

use anyhow::{Context, Result};
use g1viz::N_JOINTS;
use g1viz::power::load_model;
use g1viz::read::OpenOptions;
use g1viz::signals::{SignalMap, load_recording};

fn main() -> Result<()> {
    let mut args = std::env::args_os().skip(1).map(PathBuf::from);
    let (Some(model), Some(session)) = (args.next(), args.next()) else {
        anyhow::bail!("usage: predict_power MODEL SESSION");
    };
    let model = load_model(&model)?;
    let rec = load_recording(&session, &SignalMap::g1_left_arm(), &OpenOptions::default())
        .with_context(|| format!("reading {}", session.display()))?;
    let s = &rec.state;
    anyhow::ensure!(
        !s.t.is_empty(),
        "{}: no joint-state samples",
        session.display()
    );
    // The copper term is relative to the holding torque at rest; take the first second as rest.
    let rest = s.t.iter().take_while(|&&t| t < s.t[0] + 1.0).count().max(1);
    let mut tau0_sq = [0.0; N_JOINTS];
    for tau in &s.tau[..rest] {
        for (acc, v) in tau0_sq.iter_mut().zip(tau) {
            *acc += v * v / rest as f64;
        }
    }
    let mut energy_j = 0.0;
    for k in 1..s.t.len() {
        let watts = model.predict(&s.tau[k], &s.dq[k], &tau0_sq);
        energy_j += watts * (s.t[k] - s.t[k - 1]);
    }
    let span = s.t.last().unwrap_or(&0.0) - s.t.first().unwrap_or(&0.0);
    println!("{} samples over {span:.1} s", s.t.len());
    println!(
        "predicted net arm energy {energy_j:.1} J, mean {:.2} W",
        energy_j / span.max(1e-9)
    );
    Ok(())
}
