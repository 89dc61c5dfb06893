//! Fuzz the recording readers on stable Rust: structure-aware mutation of valid sessions in
//! every container and compression (seeds built from `examples/g1_example.mcap`), each input
//! run in a child process with an address-space limit and a watchdog; distinct findings (class
//! + location) are saved with the input and the command that reproduces them.
//!
//! ```text
//! cargo run --release --example fuzz_readers -- --minutes 60
//! cargo run --release --example fuzz_readers -- --inputs 100000 --out fuzz-findings --seed 7
//! ```
//!
//! Classes: `panic` (keyed by its source location), `crash` (killed by a signal: stack
//! overflow, abort on a failed allocation under the limit), `hang` (out of CPU time, or no exit
//! within 20× that in wall-clock time), `oom-rss` (peak RSS above the budget), `disk` (scratch file beyond the file-size
//! limit). Clean errors and warnings are not findings.

#[path = "../tests/support/fuzz_engine.rs"]
mod fuzz_engine;

use std::collections::BTreeMap;
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use fuzz_engine::{Input, Rng, exercise, mutate, seed_messages, seeds};

/// Address-space limit of each child.
const LIMIT_AS_BYTES: u64 = 2 << 30;
/// Largest file a child may write (scratch copies of compressed bags).
const LIMIT_FSIZE_BYTES: u64 = 512 << 20;
/// Peak RSS above which an input counts as a memory bomb.
const MAX_RSS_KIB: u64 = 512 * 1024;
/// Exit code of a worker whose peak RSS exceeded the budget.
const EXIT_RSS: i32 = 3;

struct Args {
    minutes: Option<f64>,
    inputs: Option<u64>,
    out: PathBuf,
    seed: u64,
    timeout: Duration,
    messages: usize,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        minutes: None,
        inputs: None,
        out: PathBuf::from("fuzz-findings"),
        seed: 1,
        timeout: Duration::from_secs(10),
        messages: 300,
    };
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut value = || it.next().ok_or(format!("{a} needs a value"));
        match a.as_str() {
            "--minutes" => args.minutes = Some(value()?.parse().map_err(|e| format!("{e}"))?),
            "--inputs" => args.inputs = Some(value()?.parse().map_err(|e| format!("{e}"))?),
            "--out" => args.out = PathBuf::from(value()?),
            "--seed" => args.seed = value()?.parse().map_err(|e| format!("{e}"))?,
            "--timeout" => {
                args.timeout =
                    Duration::from_secs_f64(value()?.parse().map_err(|e| format!("{e}"))?)
            }
            "--messages" => args.messages = value()?.parse().map_err(|e| format!("{e}"))?,
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if args.minutes.is_none() && args.inputs.is_none() {
        args.inputs = Some(1000);
    }
    Ok(args)
}

fn main() {
    let mut argv = std::env::args().skip(1);
    if argv.next().as_deref() == Some("--worker") {
        worker(Path::new(&argv.next().expect("--worker PATH")));
    }
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("fuzz_readers: {e}");
            std::process::exit(2);
        }
    };
    if let Err(e) = campaign(&args) {
        eprintln!("fuzz_readers: {e}");
        std::process::exit(1);
    }
}

/// Child: run the readers on one input, then check the peak RSS.
fn worker(path: &Path) -> ! {
    let outcome = exercise(path);
    if std::env::var_os("FUZZ_VERBOSE").is_some() {
        eprintln!("{outcome}");
    }
    let hwm = std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        })
        .unwrap_or(0);
    if hwm > MAX_RSS_KIB {
        eprintln!("peak RSS {hwm} KiB");
        std::process::exit(EXIT_RSS);
    }
    std::process::exit(0);
}

/// What one child run found, if anything: (class, location key, detail).
fn classify(
    status: Option<std::process::ExitStatus>,
    stderr: &str,
) -> Option<(String, String, String)> {
    let tail: String = stderr
        .lines()
        .rev()
        .take(12)
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect::<Vec<_>>()
        .join("\n");
    let Some(status) = status else {
        return Some(("hang".into(), String::new(), format!("wall clock\n{tail}")));
    };
    if let Some(sig) = status.signal() {
        let class = match sig {
            24 | 9 => "hang", // SIGXCPU / SIGKILL at the hard limit: out of CPU time
            25 => "disk",
            6 if stderr.contains("overflowed its stack") => "stack-overflow",
            6 if stderr.contains("memory allocation") => "alloc-abort",
            _ => "crash",
        };
        return Some((class.into(), String::new(), format!("signal {sig}\n{tail}")));
    }
    match status.code() {
        Some(0) => None,
        Some(EXIT_RSS) => Some(("oom-rss".into(), String::new(), tail)),
        _ => {
            let location = stderr
                .lines()
                .find_map(|l| {
                    l.split_once("panicked at ")
                        .map(|(_, r)| r.trim_end_matches(':').to_string())
                })
                .unwrap_or_default();
            Some(("panic".into(), location, tail))
        }
    }
}

/// Run one input in a child. `cpu` is the watchdog in CPU time (RLIMIT_CPU: a busy machine does
/// not turn slow inputs into hangs); a wall-clock backstop of 20× catches a child that blocks.
fn run_child(
    exe: &Path,
    path: &Path,
    cpu: Duration,
) -> std::io::Result<(Option<std::process::ExitStatus>, String)> {
    let cpu_s = cpu.as_secs().max(1);
    let timeout = cpu * 20;
    let mut cmd = Command::new(exe);
    cmd.arg("--worker")
        .arg(path)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    // SAFETY: only async-signal-safe setrlimit calls between fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            for (res, v, hard) in [
                (libc::RLIMIT_AS, LIMIT_AS_BYTES, LIMIT_AS_BYTES),
                (libc::RLIMIT_FSIZE, LIMIT_FSIZE_BYTES, LIMIT_FSIZE_BYTES),
                (libc::RLIMIT_CORE, 0, 0),
                (libc::RLIMIT_CPU, cpu_s, cpu_s + 1),
            ] {
                let lim = libc::rlimit {
                    rlim_cur: v,
                    rlim_max: hard,
                };
                if libc::setrlimit(res, &lim) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
            }
            Ok(())
        });
    }
    let mut child = cmd.spawn()?;
    let stderr = child.stderr.take();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        if let Some(mut e) = stderr {
            let _ = std::io::Read::read_to_string(&mut e, &mut s);
        }
        s
    });
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait()? {
            break Some(s);
        }
        if start.elapsed() > timeout {
            child.kill()?;
            child.wait()?;
            break None;
        }
        std::thread::sleep(Duration::from_millis(2));
    };
    Ok((status, reader.join().unwrap_or_default()))
}

fn campaign(args: &Args) -> Result<(), String> {
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap");
    let bytes = std::fs::read(&example).map_err(|e| format!("{}: {e}", example.display()))?;
    let seeds = seeds(&seed_messages(&bytes, args.messages));
    std::fs::create_dir_all(&args.out).map_err(|e| e.to_string())?;
    let work = tempfile::tempdir().map_err(|e| e.to_string())?;
    let mut rng = Rng::new(args.seed);
    let deadline = args
        .minutes
        .map(|m| Instant::now() + Duration::from_secs_f64(m * 60.0));
    let mut findings: BTreeMap<(String, String), u64> = BTreeMap::new();
    let mut per_kind: BTreeMap<String, u64> = BTreeMap::new();
    let started = Instant::now();
    let mut n = 0u64;
    while args.inputs.is_none_or(|max| n < max) && deadline.is_none_or(|d| Instant::now() < d) {
        let seed = &seeds[rng.below(seeds.len())];
        let input = mutate(seed, &mut rng);
        let dir = work.path().join(format!("i{}", n % 4));
        let _ = std::fs::remove_dir_all(&dir);
        let path = input.write_to(&dir).map_err(|e| e.to_string())?;
        // The watchdog allows linear work on big inputs: +1 s per MB.
        let size: usize = input.files.values().map(Vec::len).sum();
        let timeout = args.timeout + Duration::from_secs((size >> 20) as u64);
        let (status, stderr) = run_child(&exe, &path, timeout).map_err(|e| e.to_string())?;
        n += 1;
        *per_kind.entry(format!("{:?}", input.kind)).or_default() += 1;
        if let Some((class, location, detail)) = classify(status, &stderr) {
            let key = (
                class.clone(),
                if location.is_empty() {
                    format!("{:?}", input.kind)
                } else {
                    location.clone()
                },
            );
            let count = findings.entry(key.clone()).or_default();
            *count += 1;
            if *count == 1 {
                save_finding(&args.out, findings.len(), &input, &key, &detail)?;
                eprintln!(
                    "finding #{}: {} at {} ({})",
                    findings.len(),
                    key.0,
                    key.1,
                    input.label
                );
            }
        }
        if n.is_multiple_of(1000) {
            eprintln!(
                "{n} inputs, {} distinct findings, {:.0} inputs/s",
                findings.len(),
                n as f64 / started.elapsed().as_secs_f64()
            );
        }
    }
    println!(
        "{n} inputs ({}) in {:.0} s: {} distinct findings",
        per_kind
            .iter()
            .map(|(k, v)| format!("{k} {v}"))
            .collect::<Vec<_>>()
            .join(", "),
        started.elapsed().as_secs_f64(),
        findings.len()
    );
    for ((class, location), count) in &findings {
        println!("  {class} at {location}: {count} inputs");
    }
    Ok(())
}

fn save_finding(
    out: &Path,
    index: usize,
    input: &Input,
    key: &(String, String),
    detail: &str,
) -> Result<(), String> {
    let dir = out.join(format!("{index:03}-{}", key.0));
    let path = input.write_to(&dir).map_err(|e| e.to_string())?;
    let report = format!(
        "class: {}\nlocation: {}\ninput: {}\ngenerated: {}\nreproduce: target/release/examples/fuzz_readers --worker {}\n\nchild stderr tail:\n{detail}\n",
        key.0,
        key.1,
        path.display(),
        input.label,
        path.display()
    );
    std::fs::write(dir.join("finding.txt"), report).map_err(|e| e.to_string())
}
