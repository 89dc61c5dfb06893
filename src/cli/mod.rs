//! The command line's shared pieces: the top-level parser, the subcommand list, the options
//! several subcommands share (reading a session, fitting a model) and value parsers. Each
//! subcommand lives in its own module with its arguments and one `run` function; the work itself
//! is library code.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand, ValueEnum};

use g1viz::identify::{Alignment, AlignmentChoice, IdentifyOptions, Mode, Target};
use g1viz::read::OpenOptions;
use g1viz::signals::SignalMap;
use g1viz::trial::Cascade;

pub mod diagnose;
pub mod export;
pub mod fleet;
pub mod identify;
pub mod info;
pub mod replay;
pub mod simulate;
pub mod validate;

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
  g1viz diagnose session.mcap --model model.json --counterpart twin.mcap
  g1viz export rows robot_a/ robot_b/ -o rows.parquet
  g1viz identify --rows rows.parquet -o model.json";

/// Replay, identify and diagnose the electrical power of the Unitree G1 arm.
#[derive(Parser)]
#[command(name = "g1viz", version, about, after_help = EXAMPLES)]
pub struct Cli {
    /// The subcommand.
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Print what a recording holds: topics, types, counts, rates, time range and the resolved arm signals.
    #[command(after_help = "\
Examples:
  g1viz info examples/g1_example.mcap
  g1viz info bag_folder/ --json > info.json
  g1viz info session.bag --signals right_arm.toml")]
    Info(info::InfoArgs),
    /// Replay a session in the Rerun viewer (or to an .rrd file): animated arm, joint signals, power,
    /// and with --model the identified model's prediction and loss terms.
    #[command(after_help = "\
Examples:
  g1viz replay examples/g1_example.mcap --model paper --save example.rrd   # then: rerun example.rrd
  g1viz replay session.mcap --spawn                                         # opens a viewer
  g1viz replay session.mcap --model model.json --connect                    # to a running viewer
  g1viz replay session.mcap --urdf g1_29dof_with_hand_rev_1_0.urdf --save meshes.rrd
  g1viz replay session.mcap --model paper --open-tab 'IMU and trials' --save imu.rrd
  g1viz replay session.mcap --trials 10-14 --max-rate 20 --save part.rrd     # a small file to share
  g1viz replay session.mcap --from 600 --to 900 --save ten_to_fifteen_min.rrd")]
    Replay(replay::ReplayArgs),
    /// Identify the 49-parameter arm power model from one or more sessions (writes model.json).
    #[command(after_help = "\
Examples:
  g1viz identify smoke.mcap -o model.json
  g1viz identify a.mcap b.mcap -o model.json --holdout holdout.mcap --report report/
  g1viz identify smoke.mcap --mode trial -o paper_rows.json       # the paper's aggregation
  g1viz identify short.mcap --window 0.2 --lag 0 -o model.json    # too short to estimate the timing")]
    Identify(identify::IdentifyArgs),
    /// Validate a model on a hold-out session.
    #[command(after_help = "\
Examples:
  g1viz validate --model model.json holdout.mcap
  g1viz validate --model paper holdout.mcap --json > metrics.json")]
    Validate(validate::ValidateArgs),
    /// Simulate a session with the digital twin (MCAP + truth JSON), optionally with concealed effects.
    #[command(after_help = "\
Examples:
  g1viz simulate --preset smoke --seed 1 -o sim.mcap
  g1viz simulate --preset holdout -o holdout.mcap --effect braking=0.3 --effect latency
  g1viz simulate --like session.mcap -o twin.mcap                 # the twin on a recording's commands")]
    Simulate(simulate::SimulateArgs),
    /// Diagnose sim-to-real mismatch: locate it, name the missing physics, model it.
    #[command(after_help = "\
Examples:
  g1viz diagnose session.mcap --report diag/
  g1viz diagnose session.mcap --model model.json --report diag/ --json diagnosis.json --save diag.rrd
  g1viz diagnose session.mcap --model model.json --counterpart twin.mcap   # twin from simulate --like")]
    Diagnose(diagnose::DiagnoseArgs),
    /// Export data for other tools: `export rows` writes the per-reading rows as Parquet.
    #[command(after_help = "\
Examples:
  g1viz export rows a.mcap b.mcap -o rows.parquet --robot g1_lab
  g1viz export rows recordings/ -o rows.parquet                    # every recording in a folder
  g1viz identify --rows rows.parquet -o model.json                 # fit from the table")]
    Export(export::ExportArgs),
    /// Per-robot, per-period power models of many sessions' rows (Parquet from `export rows`),
    /// and their drift: which robot's joint is wearing.
    #[command(after_help = "\
Examples:
  g1viz fleet fleet_rows/ --by robot,week --report fleet/ --save fleet.rrd
  g1viz fleet a.parquet b.parquet --by robot,day --z 5
  g1viz fleet fleet_rows/ --by session --save-sql sql/   # the queries and their results")]
    Fleet(fleet::FleetArgs),
}

/// A spinner with `message` and the elapsed time on stderr, for a job that can take seconds
/// (hidden when stderr is not a terminal). Call `finish_and_clear` when the job is done.
pub fn spinner(message: &str) -> indicatif::ProgressBar {
    use std::io::IsTerminal;
    if !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let bar = g1viz::util::progress_lines().add(indicatif::ProgressBar::new_spinner());
    if let Ok(style) = indicatif::ProgressStyle::with_template("{spinner} {msg} ({elapsed})") {
        bar.set_style(style);
    }
    bar.set_message(message.to_owned());
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    bar
}

/// Prints each of `warnings` on stderr.
pub fn warn<'a>(warnings: impl IntoIterator<Item = &'a String>) {
    for w in warnings {
        eprintln!("warning: {w}");
    }
}

/// The command line as typed (program name first), for provenance in outputs.
pub fn command_line() -> String {
    // The program by its file name: its directory is the machine's, not part of the command.
    let program = std::env::args().next().map(|a| {
        std::path::Path::new(&a)
            .file_name()
            .map_or(a.clone(), |n| n.to_string_lossy().into_owned())
    });
    program
        .into_iter()
        .chain(std::env::args().skip(1))
        .map(|a| {
            if a.contains(char::is_whitespace) {
                format!("'{a}'")
            } else {
                a
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// Options for reading a session, shared by every subcommand that reads one.
#[derive(Args, Clone)]
pub struct ReadArgs {
    /// Signal mapping override (TOML: topics, field paths, scales; e.g. `arm = "right"`).
    #[arg(long, value_name = "FILE")]
    pub signals: Option<PathBuf>,
    /// Folder with .msg definitions for bags that do not carry them (repeatable).
    #[arg(long = "msg-path", value_name = "DIR")]
    pub msg_paths: Vec<PathBuf>,
}

impl ReadArgs {
    pub fn open_options(&self) -> OpenOptions {
        OpenOptions {
            msg_paths: self.msg_paths.clone(),
        }
    }

    pub fn signal_map(&self) -> Result<SignalMap> {
        match &self.signals {
            Some(path) => SignalMap::from_toml_file(path),
            None => Ok(SignalMap::g1_left_arm()),
        }
    }

    /// The recordings `named` ([`expand_sessions`]) as files to stream, with the signal map,
    /// after refusing one given twice among them and `more` (`why`: what that would spoil) and
    /// `outputs` that would overwrite them, the signal map's file or the other `inputs`.
    pub fn sessions(
        &self,
        named: &[PathBuf],
        more: Option<&Path>,
        why: &str,
        outputs: &[(&str, Option<&Path>)],
        inputs: &[Option<&Path>],
    ) -> Result<(Vec<g1viz::session::SessionFile>, SignalMap)> {
        let sessions = expand_sessions(named)?;
        let all: Vec<&Path> = sessions.iter().map(PathBuf::as_path).chain(more).collect();
        g1viz::util::check_distinct_sessions(&all, why)?;
        let read = all.into_iter().chain(self.signals.as_deref()).map(Some);
        g1viz::util::check_outputs(
            outputs,
            &read.chain(inputs.iter().copied()).collect::<Vec<_>>(),
        )?;
        let map = self.signal_map()?;
        let files = sessions
            .iter()
            .map(|p| self.session_file(p, &map))
            .collect();
        Ok((files, map))
    }

    /// `path` with this signal map and these reader options, for a streamed read.
    pub fn session_file(&self, path: &Path, map: &SignalMap) -> g1viz::session::SessionFile {
        g1viz::session::SessionFile {
            path: path.to_path_buf(),
            map: map.clone(),
            read: self.open_options(),
            spill: Default::default(),
        }
    }
}

/// Power sensor used as the regression target.
#[derive(Clone, Copy, ValueEnum)]
pub enum TargetArg {
    /// Main-board sensor (arm/upper-body rail; the paper's choice).
    Mbs,
    /// Battery management system (whole robot).
    Bms,
}

impl From<TargetArg> for Target {
    fn from(t: TargetArg) -> Target {
        match t {
            TargetArg::Mbs => Target::Mbs,
            TargetArg::Bms => Target::Bms,
        }
    }
}

/// How power readings are paired with the kinematics.
#[derive(Clone, Copy, ValueEnum)]
pub enum ModeArg {
    /// One row per power reading, regressors averaged over the reading's own window (default).
    Reading,
    /// One row per trajectory (the paper's aggregation).
    Trial,
    /// One row per 100 Hz sample with the reading held (degenerate; for comparison).
    Sample,
}

/// Identification/validation options shared by identify, validate and replay --model.
#[derive(Args, Clone)]
pub struct FitArgs {
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
    /// Power-sensor averaging window [s] (default: estimated from the data together with the lag).
    #[arg(long, value_name = "SECONDS", value_parser = positive, requires = "lag")]
    window: Option<f64>,
    /// Power-sensor lag [s] (with --window).
    #[arg(long, value_name = "SECONDS", requires = "window", allow_hyphen_values = true, value_parser = finite)]
    lag: Option<f64>,
}

impl FitArgs {
    pub fn options(&self) -> IdentifyOptions {
        IdentifyOptions {
            target: self.target.into(),
            mode: match self.mode {
                ModeArg::Reading => Mode::Reading,
                ModeArg::Trial => Mode::Trial,
                ModeArg::Sample => Mode::Sample,
            },
            filters: Cascade {
                imu_k: (!self.no_imu_filter).then_some(self.imu_threshold),
                passes: self.sigma_passes,
                n_sigma: self.n_sigma,
                ..Cascade::default()
            },
            alignment: match (self.window, self.lag) {
                (Some(window_s), Some(lag_s)) => {
                    AlignmentChoice::Given(Alignment { window_s, lag_s })
                }
                _ => AlignmentChoice::Auto,
            },
            ..IdentifyOptions::default()
        }
    }
}

/// `s` as a number `ok` accepts, else the error "`s` is not `what`" (the value parsers below).
fn number(s: &str, ok: impl Fn(f64) -> bool, what: &str) -> Result<f64, String> {
    (s.parse::<f64>().ok().filter(|v| ok(*v))).ok_or_else(|| format!("{s:?} is not {what}"))
}

/// A finite number > 0 (clap value parser).
pub fn positive(s: &str) -> Result<f64, String> {
    number(s, |v| v.is_finite() && v > 0.0, "a finite number > 0")
}

/// A finite number (clap value parser).
pub fn finite(s: &str) -> Result<f64, String> {
    number(s, f64::is_finite, "a finite number")
}

/// A finite number ≥ 0 (clap value parser).
pub fn non_negative(s: &str) -> Result<f64, String> {
    number(s, |v| v.is_finite() && v >= 0.0, "a finite number ≥ 0")
}

/// A motor winding temperature a robot can start a session at [°C] (clap value parser).
pub fn winding_temperature(s: &str) -> Result<f64, String> {
    let ok = |v| (-40.0..=150.0).contains(&v);
    number(s, ok, "a temperature between -40 and 150 °C")
}

/// The recordings named on the command line: a file or a bag folder as given; any other folder
/// stands for the recordings inside it (`.mcap` and `.bag` files and bag folders, in name order).
pub fn expand_sessions(paths: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let is_bag_dir = |p: &Path| p.join("metadata.yaml").is_file();
    let mut out = Vec::new();
    for p in paths {
        if !p.is_dir() || is_bag_dir(p) {
            out.push(p.clone());
            continue;
        }
        let mut found: Vec<PathBuf> = std::fs::read_dir(p)
            .with_context(|| format!("listing {}", p.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|e| {
                is_bag_dir(e)
                    || (e.is_file()
                        && matches!(e.extension().and_then(|x| x.to_str()), Some("mcap" | "bag")))
            })
            .collect();
        if found.is_empty() {
            anyhow::bail!(
                "{}: a folder with no recordings in it (.mcap, .bag or ROS 2 bag folders)",
                p.display()
            );
        }
        found.sort();
        out.extend(found);
    }
    Ok(out)
}

/// Run the parsed command.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Info(a) => info::run(a),
        Command::Replay(a) => replay::run(a),
        Command::Identify(a) => identify::run(a),
        Command::Validate(a) => validate::run(a),
        Command::Simulate(a) => simulate::run(a),
        Command::Diagnose(a) => diagnose::run(a),
        Command::Export(a) => export::run(a),
        Command::Fleet(a) => fleet::run(a),
    }
}
