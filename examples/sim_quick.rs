fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let preset: g1viz::sim::Preset = args[1].parse()?;
    let out = std::path::PathBuf::from(&args[2]);
    let mut cfg = g1viz::sim::SimConfig { preset, seed: 1, ..Default::default() };
    for e in &args[3..] { cfg.effects.enable(e)?; }
    let t0 = std::time::Instant::now();
    let truth = g1viz::sim::simulate(&cfg, &out)?;
    eprintln!("{} trials, {:?} in {:.2}s", truth.trials.len(), truth.message_counts, t0.elapsed().as_secs_f64());
    Ok(())
}
