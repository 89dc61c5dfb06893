//! Fuzz the recording readers on stable Rust: structure-aware mutation of valid sessions in
//! every container and compression (seeds built from `examples/g1_example.mcap`), run in batched
//! child processes under an address-space limit, with a per-input CPU-time watchdog and a
//! per-input peak-RSS check; distinct findings (class + location) are saved with the input and
//! the command that reproduces them.
//!
//! ```text
//! cargo run --example fuzz_readers -- --minutes 60
//! cargo run --example fuzz_readers -- --inputs 1000000 --out /tmp/fuzz --seed 7 --batch 1000
//! cargo run --example fuzz_readers -- --worker DIR/input.mcap      # re-run one saved input
//! cargo run --example fuzz_readers -- --replay 7 123456            # re-run input 123456 of seed 7
//! ```
//!
//! A file `STOP` in the output folder ends a campaign early: the batches under way finish and
//! the summary is printed.
//!
//! Input `i` of campaign seed `S` is a pure function of `(S, i)`, so a child generates its own
//! inputs from a range of indices and the parent only hands out ranges. A child (under
//! `RLIMIT_AS` 2 GiB, `RLIMIT_FSIZE` 512 MiB, no core files) runs each input in-process: it
//! announces the input on stdout, resets its peak RSS (`/proc/self/clear_refs`), moves its soft
//! `RLIMIT_CPU` to the CPU time used so far plus the input's budget, runs the readers under
//! `catch_unwind`, then reports the outcome and the input's peak RSS (`VmHWM`). When a child dies
//! (signal, abort, CPU limit) the parent re-runs the input in flight alone in a fresh child, so
//! the finding is pinned to one input, and resumes the batch after it.
//!
//! Classes: `panic` (keyed by its source location), `crash` / `stack-overflow` / `alloc-abort`
//! (killed by a signal), `hang` (out of CPU time, or no progress within 30× the CPU budget in
//! wall-clock time), `oom-rss` (an input's peak RSS above 512 MB), `disk` (a scratch file beyond
//! the file-size limit). Clean errors and warnings are not findings.

#[path = "../tests/support/fuzz_engine.rs"]
mod fuzz_engine;

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::Mutex;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::time::{Duration, Instant};

use fuzz_engine::{Input, Kind, exercise, input_for, seed_messages, seeds};

/// Address-space limit of each child.
const LIMIT_AS_BYTES: u64 = 2 << 30;
/// Largest file a child may write (scratch copies of compressed bags).
const LIMIT_FSIZE_BYTES: u64 = 512 << 20;
/// Peak RSS above which an input counts as a memory bomb.
const MAX_RSS_KIB: u64 = 512 * 1024;
/// Exit code of a child whose input's peak RSS exceeded the budget.
const EXIT_RSS: i32 = 3;
/// Lines of a child's stderr kept for a finding's report.
const STDERR_TAIL: usize = 16;

#[derive(Clone)]
struct Args {
    minutes: Option<f64>,
    inputs: Option<u64>,
    out: PathBuf,
    seed: u64,
    first: u64,
    timeout: Duration,
    messages: usize,
    batch: u64,
    jobs: usize,
    progress: Duration,
}

fn parse_args(argv: Vec<String>) -> Result<Args, String> {
    let mut args = Args {
        minutes: None,
        inputs: None,
        out: PathBuf::from("fuzz-findings"),
        seed: 1,
        first: 0,
        timeout: Duration::from_secs(10),
        messages: 60,
        batch: 1000,
        jobs: 1,
        progress: Duration::from_secs(60),
    };
    let mut it = argv.into_iter();
    while let Some(a) = it.next() {
        let mut value = || it.next().ok_or(format!("{a} needs a value"));
        let num = |s: String| s.parse::<f64>().map_err(|e| format!("{a}: {e}"));
        match a.as_str() {
            "--minutes" => args.minutes = Some(num(value()?)?),
            "--inputs" => args.inputs = Some(num(value()?)? as u64),
            "--out" => args.out = PathBuf::from(value()?),
            "--seed" => args.seed = num(value()?)? as u64,
            "--first" => args.first = num(value()?)? as u64,
            "--timeout" => args.timeout = Duration::from_secs_f64(num(value()?)?),
            "--messages" => args.messages = num(value()?)? as usize,
            "--batch" => args.batch = (num(value()?)? as u64).max(1),
            "--jobs" => args.jobs = (num(value()?)? as usize).max(1),
            "--progress" => args.progress = Duration::from_secs_f64(num(value()?)?),
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if args.minutes.is_none() && args.inputs.is_none() {
        args.inputs = Some(1000);
    }
    Ok(args)
}

fn main() {
    let argv: Vec<String> = std::env::args().skip(1).collect();
    let result = match argv.first().map(String::as_str) {
        Some("--worker") if argv.len() == 2 => {
            let args = parse_args(Vec::new()).expect("defaults");
            std::process::exit(run_file(Path::new(&argv[1]), args.timeout))
        }
        Some("--batch-worker") => {
            parse_args(argv.get(3..).unwrap_or_default().to_vec()).and_then(|args| {
                let range = (|| Some(argv.get(1)?.parse().ok()?..argv.get(2)?.parse().ok()?))();
                let range = range.ok_or("--batch-worker FROM TO [options]")?;
                batch_worker(&args, range)
            })
        }
        Some("--replay") => {
            parse_args(argv.get(3..).unwrap_or_default().to_vec()).and_then(|mut args| {
                args.seed = argv
                    .get(1)
                    .and_then(|s| s.parse().ok())
                    .ok_or("--replay SEED INDEX")?;
                let i: u64 = argv
                    .get(2)
                    .and_then(|s| s.parse().ok())
                    .ok_or("--replay SEED INDEX")?;
                let seeds = build_seeds(args.messages)?;
                let input = input_for(&seeds, args.seed, i);
                eprintln!("input {i} of seed {}: {}", args.seed, input.label);
                let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
                let path = input.write_to(dir.path()).map_err(|e| e.to_string())?;
                std::process::exit(run_file(&path, args.timeout))
            })
        }
        _ => parse_args(argv).and_then(|args| campaign(&args)),
    };
    if let Err(e) = result {
        eprintln!("fuzz_readers: {e}");
        std::process::exit(1);
    }
}

// ---------------------------------------------------------------------------------------------
// Inputs

fn build_seeds(messages: usize) -> Result<Vec<Input>, String> {
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap");
    let bytes = std::fs::read(&example).map_err(|e| format!("{}: {e}", example.display()))?;
    Ok(seeds(&seed_messages(&bytes, messages)))
}

/// The reader an input targets, as reports name it.
fn kind_name(kind: Kind) -> &'static str {
    match kind {
        Kind::Mcap => "mcap",
        Kind::Bag1 => "bag1",
        Kind::Db3 => "db3",
    }
}

/// CPU budget of one input: the base watchdog plus one second per MB (linear work is allowed).
fn budget(input: &Input, base: Duration) -> Duration {
    let size: usize = input.files.values().map(Vec::len).sum();
    base + Duration::from_secs((size >> 20) as u64)
}

// ---------------------------------------------------------------------------------------------
// Child side

/// Where the last panic happened and what it said (set by the panic hook).
static LAST_PANIC: Mutex<Option<String>> = Mutex::new(None);

fn install_panic_hook() {
    std::panic::set_hook(Box::new(|info| {
        let location = info
            .location()
            .map(|l| format!("{}:{}:{}", l.file(), l.line(), l.column()))
            .unwrap_or_default();
        let message = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_default();
        eprintln!("panicked at {location}: {message}");
        if let Ok(mut p) = LAST_PANIC.lock() {
            *p = Some(format!(
                "{location}\t{}",
                message.replace(['\n', '\t'], " ")
            ));
        }
    }));
}

/// Reset this process's peak RSS to its current RSS (Linux `clear_refs` 5).
fn reset_peak_rss() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// This process's peak RSS since the last reset [KiB].
fn peak_rss_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        })
        .unwrap_or(0)
}

/// Arm the CPU-time watchdog: SIGXCPU once this process has used `budget` more CPU time.
fn arm_cpu_watchdog(budget: Duration) {
    // SAFETY: getrusage/getrlimit/setrlimit only read or write the structs given to them.
    unsafe {
        let mut usage: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_SELF, &mut usage);
        let used = (usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) as u64 + 1;
        let mut lim: libc::rlimit = std::mem::zeroed();
        libc::getrlimit(libc::RLIMIT_CPU, &mut lim);
        lim.rlim_cur = (used + budget.as_secs().max(1)).min(lim.rlim_max);
        libc::setrlimit(libc::RLIMIT_CPU, &lim);
    }
}

/// One input in this process: the watchdog, the readers under `catch_unwind`, the peak RSS.
/// Returns the panic (location and message) if any, and the peak RSS [KiB].
fn run_one(path: &Path, cpu: Duration) -> (Option<String>, u64) {
    reset_peak_rss();
    arm_cpu_watchdog(cpu);
    if let Ok(mut p) = LAST_PANIC.lock() {
        *p = None;
    }
    let outcome = catch_unwind(AssertUnwindSafe(|| exercise(path)));
    if std::env::var_os("FUZZ_VERBOSE").is_some() {
        eprintln!("{outcome:?}");
    }
    let panic = outcome.is_err().then(|| {
        LAST_PANIC
            .lock()
            .ok()
            .and_then(|mut p| p.take())
            .unwrap_or_else(|| "unknown\t".into())
    });
    (panic, peak_rss_kib())
}

/// `--worker PATH`: one saved input; exit 0 clean, 101 on a panic, `EXIT_RSS` on a memory bomb.
fn run_file(path: &Path, cpu: Duration) -> i32 {
    install_panic_hook();
    match run_one(path, cpu) {
        (Some(p), _) => {
            eprintln!("panic: {p}");
            101
        }
        (None, kib) if kib > MAX_RSS_KIB => {
            eprintln!("peak RSS {kib} KiB");
            EXIT_RSS
        }
        _ => 0,
    }
}

/// `--batch-worker FROM TO`: run inputs FROM..TO, reporting on stdout one line per event:
/// `S i` (started), `D i KIND KIB MS` (clean, with its peak RSS and wall-clock time), `P i KIND LOCATION\tMESSAGE` (panic), `M i KIND KIB`
/// (peak RSS over budget; the child then exits so the next input starts with a fresh heap).
fn batch_worker(args: &Args, range: std::ops::Range<u64>) -> Result<(), String> {
    install_panic_hook();
    let seeds = build_seeds(args.messages)?;
    let work = tempfile::tempdir().map_err(|e| e.to_string())?;
    let mut out = std::io::stdout().lock();
    for i in range {
        let input = input_for(&seeds, args.seed, i);
        let kind = kind_name(input.kind);
        let dir = work.path().join("in");
        let _ = std::fs::remove_dir_all(&dir);
        let path = input.write_to(&dir).map_err(|e| e.to_string())?;
        writeln!(out, "S {i}")
            .and_then(|_| out.flush())
            .map_err(|e| e.to_string())?;
        let start = Instant::now();
        let (panic, kib) = match self_test(i) {
            Some(action) => run_self_test(&action, budget(&input, args.timeout)),
            None => run_one(&path, budget(&input, args.timeout)),
        };
        let ms = start.elapsed().as_millis();
        let line = match (&panic, kib > MAX_RSS_KIB) {
            (Some(p), _) => format!("P {i} {kind} {p}"),
            (None, true) => format!("M {i} {kind} {kib}"),
            (None, false) => format!("D {i} {kind} {kib} {ms}"),
        };
        writeln!(out, "{line}")
            .and_then(|_| out.flush())
            .map_err(|e| e.to_string())?;
        if panic.is_none() && kib > MAX_RSS_KIB {
            std::process::exit(EXIT_RSS);
        }
    }
    Ok(())
}

/// `FUZZ_SELF_TEST=ACTION:INDEX` makes input INDEX misbehave on purpose (`abort`, `spin`,
/// `rss`, `panic`), to check that the harness catches and pins each class.
fn self_test(i: u64) -> Option<String> {
    let v = std::env::var("FUZZ_SELF_TEST").ok()?;
    let (action, index) = v.split_once(':')?;
    (index.parse::<u64>().ok()? == i).then(|| action.to_string())
}

fn run_self_test(action: &str, cpu: Duration) -> (Option<String>, u64) {
    reset_peak_rss();
    arm_cpu_watchdog(cpu);
    match action {
        "abort" => std::process::abort(),
        "spin" => {
            let mut x = 0u64;
            loop {
                x = std::hint::black_box(x.wrapping_add(1));
            }
        }
        "rss" => {
            let v = std::hint::black_box(vec![1u8; 600 << 20]);
            drop(v);
            (None, peak_rss_kib())
        }
        _ => run_one(Path::new("/nonexistent"), cpu).0.map_or_else(
            || {
                let r = catch_unwind(|| panic!("self-test panic"));
                let p = r
                    .err()
                    .and(LAST_PANIC.lock().ok().and_then(|mut p| p.take()));
                (p, peak_rss_kib())
            },
            |p| (Some(p), 0),
        ),
    }
}

// ---------------------------------------------------------------------------------------------
// Parent side

/// What one child reported before it ended.
struct ChildRun {
    /// Indices finished (any outcome), in order.
    finished: Vec<(u64, String)>,
    /// Findings reported by the child itself: (index, class, location, detail).
    reported: Vec<(u64, String, String, String)>,
    /// Clean inputs' (index, peak RSS [KiB], wall-clock time [ms]).
    observed: Vec<(u64, u64, u64)>,
    /// The input in flight when the child died or stalled.
    in_flight: Option<u64>,
    /// Exit status (`None`: killed by the wall-clock backstop).
    status: Option<ExitStatus>,
    /// Last lines of the child's stderr.
    stderr: String,
}

/// Spawn a child on `from..to` with the resource limits, and collect what it reports.
fn run_child(exe: &Path, args: &Args, from: u64, to: u64) -> Result<ChildRun, String> {
    let mut cmd = Command::new(exe);
    cmd.arg("--batch-worker")
        .arg(from.to_string())
        .arg(to.to_string())
        .args(["--seed", &args.seed.to_string()])
        .args(["--messages", &args.messages.to_string()])
        .args(["--timeout", &args.timeout.as_secs_f64().to_string()])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    // SAFETY: only async-signal-safe setrlimit calls between fork and exec.
    unsafe {
        cmd.pre_exec(|| {
            for (res, v) in [
                (libc::RLIMIT_AS, LIMIT_AS_BYTES),
                (libc::RLIMIT_FSIZE, LIMIT_FSIZE_BYTES),
                (libc::RLIMIT_CORE, 0),
            ] {
                let lim = libc::rlimit {
                    rlim_cur: v,
                    rlim_max: v,
                };
                if libc::setrlimit(res, &lim) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
            }
            Ok(())
        });
    }
    let mut child = cmd
        .spawn()
        .map_err(|e| format!("spawn {}: {e}", exe.display()))?;
    let (tx, rx) = mpsc::channel();
    let stdout = child.stdout.take().expect("piped stdout");
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let stderr = child.stderr.take().expect("piped stderr");
    let tail = std::thread::spawn(move || {
        let mut lines = std::collections::VecDeque::new();
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if lines.len() == STDERR_TAIL {
                lines.pop_front();
            }
            lines.push_back(line);
        }
        Vec::from(lines).join("\n")
    });
    let mut run = ChildRun {
        finished: Vec::new(),
        reported: Vec::new(),
        observed: Vec::new(),
        in_flight: None,
        status: None,
        stderr: String::new(),
    };
    // The backstop for a child that blocks without using CPU (and for seed building).
    let backstop = args.timeout * 30 + Duration::from_secs(60);
    loop {
        match rx.recv_timeout(backstop) {
            Ok(line) => on_line(&line, &mut run),
            Err(RecvTimeoutError::Disconnected) => {
                run.status = Some(child.wait().map_err(|e| e.to_string())?);
                break;
            }
            Err(RecvTimeoutError::Timeout) => {
                let _ = child.kill();
                let _ = child.wait();
                break;
            }
        }
    }
    run.stderr = tail.join().unwrap_or_default();
    Ok(run)
}

/// Account one line of a child's report.
fn on_line(line: &str, run: &mut ChildRun) {
    let mut parts = line.splitn(4, ' ');
    let (tag, i) = (
        parts.next(),
        parts.next().and_then(|s| s.parse::<u64>().ok()),
    );
    let (Some(tag), Some(i)) = (tag, i) else {
        return;
    };
    let kind = parts.next().unwrap_or("").to_string();
    let rest = parts.next().unwrap_or("").to_string();
    match tag {
        "S" => run.in_flight = Some(i),
        "D" | "P" | "M" => {
            run.in_flight = None;
            if tag == "P" {
                let (location, message) = rest.split_once('\t').unwrap_or((&rest, ""));
                let key = location.to_string();
                run.reported
                    .push((i, "panic".into(), key, message.to_string()));
            } else if tag == "D" {
                let mut n = rest.split(' ').map(|x| x.parse::<u64>().unwrap_or(0));
                let (kib, ms) = (n.next().unwrap_or(0), n.next().unwrap_or(0));
                run.observed.push((i, kib, ms));
            } else if tag == "M" {
                run.reported.push((
                    i,
                    "oom-rss".into(),
                    kind.clone(),
                    format!("peak RSS {rest} KiB"),
                ));
            }
            run.finished.push((i, kind));
        }
        _ => {}
    }
}

/// The class of a child that died (`None` status: stopped by the wall-clock backstop).
fn classify_death(status: Option<ExitStatus>, stderr: &str) -> Option<String> {
    let Some(status) = status else {
        return Some("hang".into());
    };
    if let Some(sig) = status.signal() {
        return Some(
            match sig {
                24 | 9 => "hang", // SIGXCPU / SIGKILL: out of CPU time
                25 => "disk",     // SIGXFSZ
                6 if stderr.contains("overflowed its stack") => "stack-overflow",
                6 if stderr.contains("memory allocation") => "alloc-abort",
                _ => "crash",
            }
            .into(),
        );
    }
    match status.code() {
        Some(0) | Some(EXIT_RSS) => None,
        Some(c) => Some(format!("exit-{c}")),
        None => Some("crash".into()),
    }
}

/// Campaign state: counts and distinct findings.
struct Tally {
    done: u64,
    per_kind: BTreeMap<String, u64>,
    /// Inputs per verdict: `clean` (an error or warnings count as clean), or the finding class.
    verdicts: BTreeMap<String, u64>,
    findings: BTreeMap<(String, String), u64>,
    finding_inputs: u64,
    /// Largest peak RSS of a clean input [KiB] and the input.
    max_rss: (u64, u64),
    /// Longest wall-clock time of a clean input [ms] and the input.
    slowest: (u64, u64),
}

impl Tally {
    /// Record a finding on input `i`; saves it when it is the first of its (class, location).
    fn finding(
        &mut self,
        args: &Args,
        seeds: &[Input],
        (i, class, location): (u64, &str, &str),
        detail: &str,
    ) -> Result<(), String> {
        let input = input_for(seeds, args.seed, i);
        let location = if location.is_empty() {
            kind_name(input.kind).to_string()
        } else {
            location.to_string()
        };
        self.finding_inputs += 1;
        let count = self
            .findings
            .entry((class.to_string(), location.clone()))
            .or_default();
        *count += 1;
        if *count > 1 {
            return Ok(());
        }
        let index = self.findings.len();
        eprintln!(
            "finding #{index}: {class} at {location} (input {i}: {})",
            input.label
        );
        let dir = args.out.join(format!("{index:03}-{class}"));
        let path = input.write_to(&dir).map_err(|e| e.to_string())?;
        let report = format!(
            "class: {class}\nlocation: {location}\ninput: {}\ngenerated: seed {} input {i}: {}\n\
             reproduce: cargo run --example fuzz_readers -- --worker {}\n\
             or: cargo run --example fuzz_readers -- --replay {} {i}\n\nchild stderr tail:\n{detail}\n",
            path.display(),
            args.seed,
            input.label,
            path.display(),
            args.seed,
        );
        std::fs::write(dir.join("finding.txt"), report).map_err(|e| e.to_string())
    }
}

/// Run `from..to` in one or more children: a batched child, and when it dies, the input in
/// flight alone in a fresh child (pinning the finding) before the rest resumes batched.
/// Returns the index after the last input run.
fn run_range(
    exe: &Path,
    args: &Args,
    seeds: &[Input],
    (from, to): (u64, u64),
    tally: &Mutex<Tally>,
) -> Result<u64, String> {
    let run = run_child(exe, args, from, to)?;
    let mut t = tally.lock().map_err(|e| e.to_string())?;
    for (i, kind) in &run.finished {
        t.done += 1;
        *t.per_kind.entry(kind.clone()).or_default() += 1;
        let verdict = run
            .reported
            .iter()
            .find(|r| r.0 == *i)
            .map_or("clean", |r| r.1.as_str())
            .to_string();
        *t.verdicts.entry(verdict).or_default() += 1;
    }
    for &(i, kib, ms) in &run.observed {
        t.max_rss = t.max_rss.max((kib, i));
        t.slowest = t.slowest.max((ms, i));
    }
    for (i, class, location, detail) in &run.reported {
        t.finding(
            args,
            seeds,
            (*i, class, location),
            &format!("{detail}\n{}", run.stderr),
        )?;
    }
    let next = run.finished.last().map_or(from, |(i, _)| i + 1);
    let Some(i) = run.in_flight else {
        if let Some(class) = classify_death(run.status, &run.stderr) {
            return Err(format!(
                "child on {from}..{to} ended as {class} between inputs (after {next}):\n{}",
                run.stderr
            ));
        }
        return Ok(next);
    };
    drop(t);
    // The child died (or stalled) on input i: run it alone to pin the finding.
    let (class, detail) = if run.status.is_none() {
        (
            "hang".to_string(),
            format!("no progress in wall-clock time\n{}", run.stderr),
        )
    } else {
        let alone = run_child(exe, args, i, i + 1)?;
        match classify_death(alone.status, &alone.stderr).filter(|_| alone.in_flight.is_some()) {
            Some(class) => (class, format!("{:?}\n{}", alone.status, alone.stderr)),
            None => (
                format!(
                    "{}-in-batch",
                    classify_death(run.status, &run.stderr).unwrap_or_else(|| "crash".into())
                ),
                format!("only in its batch ({:?})\n{}", run.status, run.stderr),
            ),
        }
    };
    let mut t = tally.lock().map_err(|e| e.to_string())?;
    t.done += 1;
    *t.verdicts.entry(class.clone()).or_default() += 1;
    t.finding(args, seeds, (i, &class, ""), &detail)?;
    Ok(i + 1)
}

/// The output of `git ARGS` in the current folder, trimmed (empty when git fails).
fn git(a: &[&str]) -> String {
    Command::new("git")
        .args(a)
        .output()
        .ok()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default()
}

fn campaign(args: &Args) -> Result<(), String> {
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let seeds = build_seeds(args.messages)?;
    std::fs::create_dir_all(&args.out).map_err(|e| e.to_string())?;
    let deadline = args
        .minutes
        .map(|m| Instant::now() + Duration::from_secs_f64(m * 60.0));
    let tally = Mutex::new(Tally {
        done: 0,
        per_kind: BTreeMap::new(),
        verdicts: BTreeMap::new(),
        findings: BTreeMap::new(),
        finding_inputs: 0,
        max_rss: (0, 0),
        slowest: (0, 0),
    });
    let started = Instant::now();
    // The commit as the campaign starts (the binary's, unless it was built from another).
    let commit = git(&["rev-parse", "HEAD"]);
    let dirty = !git(&["status", "--porcelain", "--untracked-files=no"]).is_empty();
    let last_progress = Mutex::new(Instant::now());
    let end = args.inputs.map_or(u64::MAX, |n| args.first + n);
    eprintln!(
        "fuzz_readers: seed {}, inputs {}..{}, {} job(s), batch {}, CPU watchdog {:?} (+1 s/MB), {} seed messages",
        args.seed,
        args.first,
        args.inputs.map_or("∞".to_string(), |_| end.to_string()),
        args.jobs,
        args.batch,
        args.timeout,
        args.messages
    );
    // Batches are handed out in index order; a started batch always runs to its end, so the
    // inputs run are exactly `first..next` when the campaign stops.
    let next = Mutex::new(args.first);
    let job = || -> Result<(), String> {
        loop {
            let from = {
                let mut n = next.lock().map_err(|e| e.to_string())?;
                let stop = args.out.join("STOP").exists();
                if *n >= end || stop || deadline.is_some_and(|d| Instant::now() >= d) {
                    return Ok(());
                }
                let from = *n;
                *n = (from + args.batch).min(end);
                from
            };
            let to = (from + args.batch).min(end);
            let mut at = from;
            while at < to {
                at = run_range(&exe, args, &seeds, (at, to), &tally)?;
            }
            let mut last = last_progress.lock().map_err(|e| e.to_string())?;
            if last.elapsed() >= args.progress {
                *last = Instant::now();
                let t = tally.lock().map_err(|e| e.to_string())?;
                progress(&t, started);
            }
        }
    };
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..args.jobs).map(|_| s.spawn(job)).collect();
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .unwrap_or_else(|_| Err("a job thread panicked".into()))
            })
            .collect::<Result<Vec<()>, String>>()
    })?;
    let tally = tally.into_inner().map_err(|e| e.to_string())?;
    progress(&tally, started);
    println!(
        "seed {}: {} inputs (indices {}..{}; {}) in {:.0} s: {} distinct findings on {} inputs",
        args.seed,
        tally.done,
        args.first,
        args.first + tally.done,
        tally
            .per_kind
            .iter()
            .map(|(k, v)| format!("{k} {v}"))
            .collect::<Vec<_>>()
            .join(", "),
        started.elapsed().as_secs_f64(),
        tally.findings.len(),
        tally.finding_inputs
    );
    for ((class, location), count) in &tally.findings {
        println!("  {class} at {location}: {count} inputs");
    }
    write_results(args, &tally, started.elapsed(), (&commit, dirty))
}

/// The campaign's observed results, as `results.json` in the output folder: what to store in
/// the repository and quote (verdict counts per input, distinct findings, time, seed, commit,
/// the limits every input ran under, and the largest peak RSS and longest wall-clock time any
/// clean input was seen to take, with its index).
fn write_results(
    args: &Args,
    tally: &Tally,
    elapsed: Duration,
    (commit, dirty): (&str, bool),
) -> Result<(), String> {
    let findings: Vec<_> = tally
        .findings
        .iter()
        .map(|((class, location), n)| {
            serde_json::json!({ "class": class, "location": location, "inputs": n })
        })
        .collect();
    let results = serde_json::json!({
        "seed": args.seed,
        "first_input": args.first,
        "inputs": tally.done,
        "seed_messages": args.messages,
        "seconds": elapsed.as_secs_f64().round(),
        "jobs": args.jobs,
        "commit": commit,
        "uncommitted_changes": dirty,
        "finished_unix_s": std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs()),
        "limits": {
            "address_space_bytes": LIMIT_AS_BYTES,
            "file_size_bytes": LIMIT_FSIZE_BYTES,
            "peak_rss_kib": MAX_RSS_KIB,
            "cpu_s_per_input": args.timeout.as_secs_f64(),
            "cpu_s_per_input_per_mb": 1.0,
        },
        "inputs_per_kind": tally.per_kind,
        "verdicts": tally.verdicts,
        "distinct_findings": findings,
        "inputs_with_findings": tally.finding_inputs,
        "observed": {
            "max_peak_rss_kib": tally.max_rss.0,
            "max_peak_rss_input": tally.max_rss.1,
            "slowest_input_ms": tally.slowest.0,
            "slowest_input": tally.slowest.1,
        },
    });
    let text = serde_json::to_string_pretty(&results).map_err(|e| e.to_string())?;
    std::fs::write(args.out.join("results.json"), text + "\n").map_err(|e| e.to_string())
}

fn progress(tally: &Tally, started: Instant) {
    let secs = started.elapsed().as_secs_f64();
    eprintln!(
        "[{:.0} s] {} inputs, {} distinct findings on {} inputs, {:.1} inputs/s",
        secs,
        tally.done,
        tally.findings.len(),
        tally.finding_inputs,
        tally.done as f64 / secs.max(1e-9)
    );
}
