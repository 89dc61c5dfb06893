//! `g1viz` command line: replay, identify, validate, simulate and diagnose G1 arm sessions.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand, ValueEnum};

use g1viz::identify::dataset::{Mode, Target};
use g1viz::identify::pipeline::{self, IdentifyOptions};
use g1viz::power::{ModelFile, PowerModel};
use g1viz::read::{OpenOptions, Session};
use g1viz::signals::{Recording, SignalMap, load_recording};

const EXAMPLES: &str = "\
Examples:
  g1viz info examples/g1_example.mcap
  g1viz replay examples/g1_example.mcap --save example.rrd
  g1viz replay session.mcap --urdf ../shared/g1_description/g1_29dof_with_hand_rev_1_0.urdf --spawn
  g1viz identify smoke.mcap -o model.json --report report/
  g1viz validate --model model.json holdout.mcap
  g1viz replay holdout.mcap --model model.json --save holdout.rrd
  g1viz simulate --preset smoke --seed 1 -o sim.mcap --effect braking=0.3
  g1viz simulate --like session.mcap -o twin.mcap
  g1viz diagnose session.mcap --model model.json --report diag/ --save diag.rrd
  g1viz diagnose session.mcap --model model.json --counterpart twin.mcap";

/// Replay, identify and diagnose the electrical power of the Unitree G1 arm.
#[derive(Parser)]
#[command(name = "g1viz", version, about, after_help = EXAMPLES)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print what a recording holds: topics, types, counts, rates, time range and the resolved arm signals.
    Info(InfoArgs),
    /// Replay a session in the Rerun viewer (or to an .rrd file): animated arm, joint signals, power,
    /// and with --model the identified model's prediction and loss terms.
    Replay(ReplayArgs),
    /// Identify the 49-parameter arm power model from one or more sessions (writes model.json).
    Identify(IdentifyArgs),
    /// Validate a model on a hold-out session.
    Validate(ValidateArgs),
    /// Simulate a session with the digital twin (MCAP + truth JSON), optionally with concealed effects.
    Simulate(SimulateArgs),
    /// Diagnose sim-to-real mismatch: locate it, name the missing physics, model it.
    Diagnose(DiagnoseArgs),
}

/// Options for reading a session, shared by every subcommand that reads one.
#[derive(Args, Clone)]
struct ReadArgs {
    /// Signal mapping override (TOML: topics, field paths, scales; e.g. `arm = "right"`).
    #[arg(long, value_name = "FILE")]
    signals: Option<PathBuf>,
    /// Folder with .msg definitions for bags that do not carry them (repeatable).
    #[arg(long = "msg-path", value_name = "DIR")]
    msg_paths: Vec<PathBuf>,
}

impl ReadArgs {
    fn open_options(&self) -> OpenOptions {
        OpenOptions {
            msg_paths: self.msg_paths.clone(),
        }
    }

    fn signal_map(&self) -> Result<SignalMap> {
        match &self.signals {
            Some(path) => SignalMap::from_toml_file(path),
            None => Ok(SignalMap::g1_left_arm()),
        }
    }

    fn load(&self, path: &Path) -> Result<Recording> {
        let rec = load_recording(path, &self.signal_map()?, &self.open_options())
            .with_context(|| format!("reading {}", path.display()))?;
        for w in &rec.warnings {
            eprintln!("warning: {w}");
        }
        Ok(rec)
    }
}

/// Power sensor used as the regression target.
#[derive(Clone, Copy, ValueEnum)]
enum TargetArg {
    /// Main-board sensor (arm/upper-body rail; the paper's choice).
    Mbs,
    /// Battery management system (whole robot).
    Bms,
}

/// How power readings are paired with the kinematics.
#[derive(Clone, Copy, ValueEnum)]
enum ModeArg {
    /// One row per power reading, regressors averaged over the reading's own window (default).
    Reading,
    /// One row per trajectory (the paper's aggregation).
    Trial,
    /// One row per 100 Hz sample with the reading held (degenerate; for comparison).
    Sample,
}

/// Identification/validation options shared by identify, validate and replay --model.
#[derive(Args, Clone)]
struct FitArgs {
    /// Power sensor to model.
    #[arg(long, value_enum, default_value = "mbs")]
    target: TargetArg,
    /// Row pairing.
    #[arg(long, value_enum, default_value = "reading")]
    mode: ModeArg,
    /// IMU balance-contamination filter: reject trials with σ(|ω|) > K × median.
    #[arg(long, value_name = "K", default_value_t = 2.5, value_parser = positive)]
    imu_threshold: f64,
    /// Switch the IMU filter off.
    #[arg(long)]
    no_imu_filter: bool,
    /// Passes of n·σ residual rejection (0 = off).
    #[arg(long, default_value_t = 2)]
    sigma_passes: usize,
    /// Width of the residual rejection in σ.
    #[arg(long, default_value_t = 3.0, value_parser = positive)]
    n_sigma: f64,
}

impl FitArgs {
    fn options(&self) -> IdentifyOptions {
        IdentifyOptions {
            target: match self.target {
                TargetArg::Mbs => Target::Mbs,
                TargetArg::Bms => Target::Bms,
            },
            mode: match self.mode {
                ModeArg::Reading => Mode::Reading,
                ModeArg::Trial => Mode::Trial,
                ModeArg::Sample => Mode::Sample,
            },
            imu_k: (!self.no_imu_filter).then_some(self.imu_threshold),
            sigma_passes: self.sigma_passes,
            n_sigma: self.n_sigma,
            ..IdentifyOptions::default()
        }
    }
}

#[derive(Args)]
struct InfoArgs {
    /// Recording: .mcap, ROS 2 bag directory (or its metadata.yaml / .db3), or ROS 1 .bag.
    session: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    read: ReadArgs,
}

#[derive(Args)]
struct ReplayArgs {
    /// Recording to replay.
    session: PathBuf,
    /// Identified model (model.json, or `paper` for the paper's parameters): adds predicted vs
    /// measured power, error and loss terms.
    #[arg(long, value_name = "M")]
    model: Option<PathBuf>,
    /// Robot description (default: the shipped G1 left-arm URDF; Unitree's official URDF shows its meshes).
    #[arg(long, value_name = "URDF")]
    urdf: Option<PathBuf>,
    /// Write an .rrd file (atomically; refuses to overwrite the input).
    #[arg(long, value_name = "OUT", group = "sink")]
    save: Option<PathBuf>,
    /// Stream to a running viewer (default address rerun+http://127.0.0.1:9876/proxy).
    #[arg(long, value_name = "ADDR", group = "sink", num_args = 0..=1, default_missing_value = "")]
    connect: Option<String>,
    /// Start a viewer (`rerun` on PATH: pip install rerun-sdk==0.36.3) and stream to it.
    #[arg(long, group = "sink")]
    spawn: bool,
    /// Memory limit of the spawned viewer (e.g. 2GB or 25%).
    #[arg(long, default_value = "25%")]
    memory_limit: String,
    /// Arm poses per second in the 3D view (0 = every recorded sample). Joint and power series
    /// are always logged at full rate; 30 Hz keeps hour-long .rrd files a fraction of the size.
    #[arg(long, value_name = "HZ", default_value_t = 30.0, value_parser = non_negative)]
    pose_rate: f64,
    /// Do not send the viewer layout (keep the viewer's own).
    #[arg(long)]
    no_blueprint: bool,
    #[command(flatten)]
    fit: FitArgs,
    #[command(flatten)]
    read: ReadArgs,
}

#[derive(Args)]
struct IdentifyArgs {
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

#[derive(Args)]
struct ValidateArgs {
    /// The model to validate (model.json).
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

#[derive(Args)]
struct SimulateArgs {
    /// Output MCAP file (the truth sidecar goes beside it as NAME.truth.json).
    #[arg(short, long, value_name = "OUT")]
    output: PathBuf,
    /// Trial set: tiny, example, smoke, paper, holdout.
    #[arg(long, default_value = "smoke")]
    preset: String,
    /// Random seed (same seed, same file).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Switch on a concealed effect, e.g. braking=0.3, thermal=0.00393, bus_loss=0.05, latency=0.3,
    /// payload=0.5, gear_friction=0.15, drive_loss=0.5, stribeck=10, balance_leak=55,
    /// harness_drag=4 (repeatable; a bare NAME uses the default value).
    #[arg(long = "effect", value_name = "NAME=VALUE")]
    effects: Vec<String>,
    /// Re-run this recording's commanded trajectory through the twin (same timeline).
    #[arg(long, value_name = "SESSION")]
    like: Option<PathBuf>,
    /// True power model (default: the paper's tables).
    #[arg(long, value_name = "M")]
    model: Option<PathBuf>,
    /// URDF for the dynamics (default: the shipped one).
    #[arg(long, value_name = "URDF")]
    urdf: Option<PathBuf>,
    /// Simulate without the Dex3-1 hand.
    #[arg(long)]
    no_hand: bool,
    /// Winding temperature at session start [°C].
    #[arg(long, value_name = "C", value_parser = winding_temperature)]
    t_start: Option<f64>,
    /// No balance contamination and no hardware-event outliers.
    #[arg(long)]
    clean: bool,
    #[command(flatten)]
    read: ReadArgs,
}

#[derive(Args)]
struct DiagnoseArgs {
    /// Recording to diagnose.
    session: PathBuf,
    /// The twin's power model (model.json); without it the model is refitted inside each fold.
    #[arg(long, value_name = "M")]
    model: Option<PathBuf>,
    /// URDF for the torque-level comparison (default: the shipped one).
    #[arg(long, value_name = "URDF")]
    urdf: Option<PathBuf>,
    /// Power sensor.
    #[arg(long, value_enum, default_value = "mbs")]
    target: TargetArg,
    /// Write a markdown report with figures into DIR.
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    /// Write the machine-readable diagnosis here.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Write an .rrd with before/after predictions, residuals and the located trials.
    #[arg(long, value_name = "OUT")]
    save: Option<PathBuf>,
    /// Also compare sample by sample with the twin driven by the same commands on the same
    /// timeline (made with `g1viz simulate --like SESSION -o TWIN`).
    #[arg(long, value_name = "TWIN")]
    counterpart: Option<PathBuf>,
    #[command(flatten)]
    read: ReadArgs,
}

/// A finite number > 0 (clap value parser).
fn positive(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("{s:?} is not a finite number > 0")),
    }
}

/// A finite number ≥ 0 (clap value parser).
fn non_negative(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(format!("{s:?} is not a finite number ≥ 0")),
    }
}

/// A motor winding temperature a robot can start a session at [°C] (clap value parser).
fn winding_temperature(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if (-40.0..=150.0).contains(&v) => Ok(v),
        _ => Err(format!("{s:?} is not a temperature between -40 and 150 °C")),
    }
}

fn main() {
    // Rust ignores SIGPIPE, so printing into a closed pipe (`g1viz info … | head`) would panic;
    // a command-line tool should just stop, as `cat` does.
    #[cfg(unix)]
    // SAFETY: called first thing in main, before any thread exists; SIG_DFL is a valid handler.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    if let Err(err) = run(cli) {
        eprintln!("error: {err:#}");
        std::process::exit(1);
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Info(a) => info(a),
        Command::Replay(a) => replay(a),
        Command::Identify(a) => identify(a),
        Command::Validate(a) => validate(a),
        Command::Simulate(a) => simulate(a),
        Command::Diagnose(a) => diagnose(a),
    }
}

fn info(a: InfoArgs) -> Result<()> {
    let mut session = Session::open(&a.session, &a.read.open_options())?;
    let info = session.info()?;
    let rec = a.read.load(&a.session);
    if a.json {
        let signals = rec.as_ref().ok().map(signal_summary);
        let out = serde_json::json!({ "container": info, "signals": signals });
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
                println!("  {name:<22} {n:>8} {unit} at {:.2} Hz", rate(t));
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

fn rate(t: &[f64]) -> f64 {
    match (t.first(), t.last()) {
        (Some(a), Some(b)) if t.len() > 1 && b > a => (t.len() - 1) as f64 / (b - a),
        _ => 0.0,
    }
}

fn signal_summary(rec: &Recording) -> serde_json::Value {
    serde_json::json!({
        "joints": rec.joint_names,
        "state": { "samples": rec.state.t.len(), "rate_hz": rate(&rec.state.t) },
        "command": { "samples": rec.command.t.len(), "rate_hz": rate(&rec.command.t) },
        "mbs_power": { "readings": rec.mbs.t.len(), "rate_hz": rate(&rec.mbs.t) },
        "bms_power": { "readings": rec.bms.t.len(), "rate_hz": rate(&rec.bms.t) },
    })
}

/// A model.json, or `paper` for the paper's tabulated parameters.
fn load_model(path: &Path) -> Result<PowerModel> {
    if path.as_os_str() == "paper" && !path.exists() {
        return Ok(PowerModel::PAPER);
    }
    Ok(ModelFile::load(path)?.model())
}

#[cfg(feature = "viz")]
fn replay(a: ReplayArgs) -> Result<()> {
    use g1viz::robot::RobotModel;
    use g1viz::viz::{self, Sink};

    let robot = match &a.urdf {
        Some(p) => RobotModel::from_urdf_file(p)?,
        None => RobotModel::builtin(),
    };
    let sink = if let Some(out) = &a.save {
        Sink::Save(out.clone())
    } else if let Some(addr) = &a.connect {
        Sink::Connect((!addr.is_empty()).then(|| addr.clone()))
    } else if a.spawn {
        Sink::Spawn {
            memory_limit: a.memory_limit.clone(),
        }
    } else {
        bail!("say where the replay goes: --save OUT.rrd, --connect [ADDR] or --spawn");
    };
    let mut inputs: Vec<&Path> = vec![&a.session];
    if let Some(m) = a.model.as_deref().filter(|m| m.exists()) {
        inputs.push(m);
    }
    let opts = viz::replay::ReplayOptions {
        pose_rate_hz: (a.pose_rate > 0.0).then_some(a.pose_rate),
        blueprint: !a.no_blueprint,
        ..Default::default()
    };
    let summary = match &a.model {
        // The model overlay needs the whole session (trial segmentation, fitted windows).
        Some(m) => {
            let rec = a.read.load(&a.session)?;
            let arm = robot.arm(&rec.joint_names)?;
            let model = load_model(m)?;
            let (extras, v) = viz::overlay::model_extras(&rec, &model, &a.fit.options())?;
            for n in &v.notes {
                eprintln!("note: {n}");
            }
            eprintln!(
                "model {}: per-trajectory R² {:.3}, RMSE {:.2} W on {} trials",
                m.display(),
                v.trial_level_aligned.r2,
                v.trial_level_aligned.rmse,
                v.per_trial.len()
            );
            let out = viz::open_stream("g1viz", &viz::recording_id_for(&rec), &sink, &inputs)?;
            let summary =
                viz::replay::log_replay(&rec, &robot, &arm, &extras, &opts, out.stream())?;
            out.finish()?;
            summary
        }
        // A plain replay streams the file: memory does not grow with its length.
        None => {
            let map = a.read.signal_map()?;
            let arm = robot.arm(&map.joint_names)?;
            let id = viz::recording_id_for_source(&a.session)
                .with_context(|| format!("cannot read {}", a.session.display()))?;
            let out = viz::open_stream("g1viz", &id, &sink, &inputs)?;
            let summary = viz::replay::replay_file(
                &a.session,
                &map,
                &a.read.open_options(),
                &robot,
                &arm,
                &opts,
                out.stream(),
            )
            .with_context(|| format!("replaying {}", a.session.display()))?;
            out.finish()?;
            summary
        }
    };
    for w in &summary.warnings {
        eprintln!("warning: {w}");
    }
    if let Some(path) = &a.save {
        eprintln!("wrote {} ({} samples)", path.display(), summary.samples);
    }
    Ok(())
}

#[cfg(not(feature = "viz"))]
fn replay(_: ReplayArgs) -> Result<()> {
    bail!(
        "this g1viz was built without the `viz` feature (Rerun output); rebuild with default features"
    )
}

fn identify(a: IdentifyArgs) -> Result<()> {
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
    let id = pipeline::identify(&recs, &opts)?;
    let validation = match &a.holdout {
        Some(p) => Some(pipeline::validate(&id.model, &a.read.load(p)?, &opts)?),
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
        let truth = a.sessions.first().and_then(|p| truth_model(p));
        let input = id.report_input(file, validation.as_ref(), truth);
        g1viz::identify::report::write_report(dir, &input)?;
        println!("wrote {}", dir.join("report.md").display());
    }
    Ok(())
}

/// The true parameters of a simulated session, from its truth sidecar (ours or the shared
/// generator's: both carry `theta.vector`), when there is one.
fn truth_model(session: &Path) -> Option<PowerModel> {
    let text = g1viz::util::read_text_input(&g1viz::sim::truth_path(session)).ok()?;
    let json: serde_json::Value = serde_json::from_str(&text).ok()?;
    let v: Vec<f64> = serde_json::from_value(json["theta"]["vector"].clone()).ok()?;
    let v: [f64; g1viz::N_PARAMS] = v.try_into().ok()?;
    Some(PowerModel::from_vector(&v))
}

fn validate(a: ValidateArgs) -> Result<()> {
    let model = load_model(&a.model)?;
    let rec = a.read.load(&a.session)?;
    let v = pipeline::validate(&model, &rec, &a.fit.options())?;
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

fn simulate(a: SimulateArgs) -> Result<()> {
    use g1viz::sim::{Artefacts, SimConfig};
    let truth_out = g1viz::sim::truth_path(&a.output);
    check_outputs(
        &[
            ("simulated session", Some(&a.output)),
            ("truth file", Some(&truth_out)),
        ],
        &[
            a.like.as_deref(),
            a.model.as_deref(),
            a.urdf.as_deref(),
            a.read.signals.as_deref(),
        ],
    )?;
    let mut cfg = SimConfig {
        preset: a.preset.parse()?,
        seed: a.seed,
        with_hand: !a.no_hand,
        ..SimConfig::default()
    };
    for e in &a.effects {
        cfg.effects.enable(e)?;
    }
    if let Some(m) = &a.model {
        cfg.truth = load_model(m)?;
    }
    cfg.urdf = a.urdf.clone();
    if let Some(t) = a.t_start {
        cfg.t_start_c = t;
    }
    if a.clean {
        cfg.artefacts = Artefacts::NONE;
    }
    let truth = match &a.like {
        Some(p) => g1viz::sim::simulate_like(&a.read.load(p)?, &cfg, &a.output)?,
        None => g1viz::sim::simulate(&cfg, &a.output)?,
    };
    let what = match &a.like {
        // The twin follows the recording's commands; it knows no trial windows.
        Some(p) => format!("the twin of {} on its timeline", p.display()),
        None => format!("{} trials", truth.trials.len()),
    };
    println!(
        "wrote {} and {} ({what})",
        a.output.display(),
        g1viz::sim::truth_path(&a.output).display(),
    );
    Ok(())
}

/// Refuses outputs that would overwrite an input (a file read, a bag folder, or a simulated
/// session's truth sidecar) or each other — checked before any work is done.
fn check_outputs(outputs: &[(&str, Option<&Path>)], inputs: &[Option<&Path>]) -> Result<()> {
    let sidecars: Vec<PathBuf> = inputs
        .iter()
        .flatten()
        .map(|p| g1viz::sim::truth_path(p))
        .collect();
    let mut all: Vec<&Path> = inputs.iter().flatten().copied().collect();
    all.extend(sidecars.iter().map(PathBuf::as_path));
    let outputs: Vec<(&str, &Path)> = outputs
        .iter()
        .filter_map(|(what, p)| p.map(|p| (*what, p)))
        .collect();
    for (k, (what, out)) in outputs.iter().enumerate() {
        g1viz::util::refuse_to_overwrite_inputs(what, out, &all)?;
        for (other, o) in &outputs[..k] {
            let (x, y) = (
                g1viz::util::canonical_target(out),
                g1viz::util::canonical_target(o),
            );
            if x.is_some() && x == y {
                bail!(
                    "the {what} and the {other} are the same file {}",
                    out.display()
                );
            }
        }
    }
    Ok(())
}

/// Refuses a session given twice; `why` says what that would spoil.
fn check_distinct_sessions(sessions: &[&Path], why: &str) -> Result<()> {
    for (k, a) in sessions.iter().enumerate() {
        for b in &sessions[..k] {
            if same_file(a, b) {
                bail!(
                    "{} and {} are the same recording: {why}",
                    b.display(),
                    a.display()
                );
            }
        }
    }
    Ok(())
}

fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

fn diagnose(a: DiagnoseArgs) -> Result<()> {
    use g1viz::diagnose::{self, DiagnoseOptions};
    if let Some(c) = &a.counterpart {
        check_distinct_sessions(
            &[&a.session, c],
            "the counterpart must be its twin (`g1viz simulate --like`)",
        )?;
    }
    check_outputs(
        &[
            ("diagnosis JSON", a.json.as_deref()),
            ("report folder", a.report.as_deref()),
            ("Rerun output", a.save.as_deref()),
        ],
        &[
            Some(&a.session),
            a.model.as_deref(),
            a.counterpart.as_deref(),
            a.urdf.as_deref(),
            a.read.signals.as_deref(),
        ],
    )?;
    let rec = a.read.load(&a.session)?;
    let opts = DiagnoseOptions {
        reference: a.model.as_deref().map(load_model).transpose()?,
        target: match a.target {
            TargetArg::Mbs => Target::Mbs,
            TargetArg::Bms => Target::Bms,
        },
        urdf: a.urdf.clone(),
        ..DiagnoseOptions::default()
    };
    let mut d = diagnose::diagnose(&rec, &opts)?;
    if let Some(p) = &a.counterpart {
        let twin = a.read.load(p)?;
        d.attach_counterpart(diagnose::counterpart::compare(&rec, &twin, &d)?);
    }
    println!("{}", d.summary);
    if let Some(p) = &a.json {
        d.save_json(p)?;
        println!("wrote {}", p.display());
    }
    if let Some(dir) = &a.report {
        diagnose::report::write_report(dir, &d)?;
        println!("wrote {}", dir.join("report.md").display());
    }
    if let Some(out) = &a.save {
        save_diagnosis_rrd(&rec, &a, &d, out)?;
        println!("wrote {}", out.display());
    }
    Ok(())
}

#[cfg(feature = "viz")]
fn save_diagnosis_rrd(
    rec: &Recording,
    a: &DiagnoseArgs,
    d: &g1viz::diagnose::Diagnosis,
    out: &Path,
) -> Result<()> {
    use g1viz::robot::RobotModel;
    use g1viz::viz::{self, Sink};
    let robot = match &a.urdf {
        Some(p) => RobotModel::from_urdf_file(p)?,
        None => RobotModel::builtin(),
    };
    let arm = robot.arm(&rec.joint_names)?;
    let extras = viz::overlay::diagnosis_extras(d);
    let stream = viz::open_stream(
        "g1viz",
        &viz::recording_id_for(rec),
        &Sink::Save(out.to_path_buf()),
        &[&a.session],
    )?;
    viz::replay::log_replay(
        rec,
        &robot,
        &arm,
        &extras,
        &Default::default(),
        stream.stream(),
    )?;
    stream.finish()
}

#[cfg(not(feature = "viz"))]
fn save_diagnosis_rrd(
    _: &Recording,
    _: &DiagnoseArgs,
    _: &g1viz::diagnose::Diagnosis,
    _: &Path,
) -> Result<()> {
    bail!("--save needs the `viz` feature (Rerun output); rebuild with default features")
}
