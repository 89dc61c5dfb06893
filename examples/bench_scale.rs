//! Benchmark of every model-related command against session length: wall time and peak RSS of
//! `info`, `identify`, `validate`, `diagnose` (alone, with `--save`, and with `--counterpart` of
//! the session's twin made by `simulate --like`, reused when present), `replay --save` and
//! `replay --model paper --save` and `simulate --like SESSION` (the twin on the session's timeline),
//! each run as a child process of the built `g1viz` binary, on sessions of 1 h, 4.4 h and 10 h,
//! plus the size of each `.rrd`.
//!
//! The sessions are made from paper-preset simulations (≈ 3.3 h each, seeds 1–3) written into
//! the scratch folder (reused when present): the 1 h session is the first hour of seed 1, the
//! 4.4 h one is seed 1 followed by the first 1.1 h of seed 2, the 10 h one is seeds 1, 2 and 3
//! followed by the first 0.1 h of seed 1 again — each part shifted to start 1 s after the
//! previous one ends, written as one zstd-chunked MCAP.
//!
//! ```text
//! cargo build && cargo run --example bench_scale -- [SCRATCH_DIR] [HOURS|FILE,…] [COMMAND,…]
//! # e.g. cargo run --example bench_scale -- /tmp/g1viz-scale 1,4.4 info,identify
//! #      cargo run --example bench_scale -- /tmp/x /tmp/x/session.mcap decompress,identify
//! ```
//!
//! An existing `.mcap` file may stand in for a session length (the twin and outputs are then
//! named after the file).
//!
//! Peak RSS is the child's own `ru_maxrss` and CPU its user + system time (from `wait4`), wall
//! time from spawn to exit. Each command has a 60 min limit. The machine's load average is printed
//! with the table. The command `decompress` runs `bench_decompress` (built beside this example:
//! `cargo build --examples`) on the same file, the one-core floor every other command's CPU is
//! given as a multiple of (the `× CPU` column), and its wall time the `× wall` column's.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use g1viz::sim::{Preset, SimConfig, simulate};

/// The built `g1viz` next to this example's folder (target/PROFILE/examples/..), or `$G1VIZ_BIN`.
fn g1viz_bin() -> Result<PathBuf> {
    if let Some(p) = std::env::var_os("G1VIZ_BIN") {
        return Ok(PathBuf::from(p));
    }
    let exe = std::env::current_exe()?;
    let bin = exe
        .parent()
        .and_then(Path::parent)
        .map(|d| d.join("g1viz"))
        .context("locating the g1viz binary")?;
    if !bin.exists() {
        bail!("{} not found: run `cargo build` first", bin.display());
    }
    Ok(bin)
}

/// The paper-preset simulation with `seed`, written once into `dir`.
fn paper_session(dir: &Path, seed: u64) -> Result<PathBuf> {
    let path = dir.join(format!("paper{seed}.mcap"));
    if !path.exists() {
        eprintln!("simulating {} …", path.display());
        let tmp = dir.join(format!("paper{seed}.partial.mcap"));
        let cfg = SimConfig {
            preset: Preset::Paper,
            seed,
            progress: false,
            ..SimConfig::default()
        };
        simulate(&cfg, &tmp)?;
        std::fs::rename(&tmp, &path)?;
    }
    Ok(path)
}

/// Write the parts (file, at most this many seconds from its start) end to end into `out`.
fn concatenate(parts: &[(PathBuf, f64)], out: &Path) -> Result<()> {
    let tmp = out.with_extension("partial.mcap");
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .create(BufWriter::new(File::create(&tmp)?))?;
    let mut channels: BTreeMap<String, u16> = BTreeMap::new();
    let mut end_ns: Option<u64> = None;
    for (path, seconds) in parts {
        let data = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        let mut offset: Option<i128> = None;
        let mut first: u64 = 0;
        let mut last = 0u64;
        for msg in mcap::MessageStream::new(&data)? {
            let msg = msg?;
            let off = *offset.get_or_insert_with(|| {
                first = msg.log_time;
                end_ns.map_or(0, |e| {
                    i128::from(e) + 1_000_000_000 - i128::from(msg.log_time)
                })
            });
            if (msg.log_time.saturating_sub(first)) as f64 * 1e-9 > *seconds {
                continue;
            }
            let ch = &msg.channel;
            let id = match channels.get(&ch.topic) {
                Some(&id) => id,
                None => {
                    let schema = match &ch.schema {
                        Some(s) => w.add_schema(&s.name, &s.encoding, &s.data)?,
                        None => 0,
                    };
                    let id =
                        w.add_channel(schema, &ch.topic, &ch.message_encoding, &ch.metadata)?;
                    channels.insert(ch.topic.clone(), id);
                    id
                }
            };
            let shift = |t: u64| (i128::from(t) + off) as u64;
            last = last.max(shift(msg.log_time));
            w.write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: id,
                    sequence: msg.sequence,
                    log_time: shift(msg.log_time),
                    publish_time: shift(msg.publish_time),
                },
                &msg.data,
            )?;
        }
        end_ns = Some(last);
    }
    w.finish()?;
    drop(w);
    std::fs::rename(&tmp, out)?;
    Ok(())
}

/// The session of `hours` (1, 4.4 or 10), built once in `dir`.
fn session(dir: &Path, hours: f64) -> Result<PathBuf> {
    let out = dir.join(format!("session_{hours}h.mcap"));
    if out.exists() {
        return Ok(out);
    }
    let p = |seed| paper_session(dir, seed);
    let all = f64::INFINITY;
    let parts = match (hours * 10.0).round() as u32 {
        10 => vec![(p(1)?, 3600.0)],
        44 => vec![(p(1)?, all), (p(2)?, 1.1 * 3600.0)],
        100 => vec![(p(1)?, all), (p(2)?, all), (p(3)?, all), (p(1)?, 360.0)],
        _ => bail!("no recipe for a {hours} h session (1, 4.4 or 10)"),
    };
    eprintln!("writing {} …", out.display());
    concatenate(&parts, &out)?;
    Ok(out)
}

/// What one child process took.
struct Usage {
    /// Spawn to exit [s].
    wall: f64,
    /// User + system CPU [s].
    cpu: f64,
    /// Peak RSS [MB].
    rss: f64,
    ok: bool,
}

/// The time, CPU and peak RSS of one child process (killed after `limit`).
fn measure(cmd: &mut Command, limit: Duration) -> Result<Usage> {
    let t0 = Instant::now();
    let child = cmd
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()?;
    let pid = child.id() as libc::pid_t;
    let mut stderr = child.stderr;
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        if let Some(e) = stderr.as_mut() {
            let _ = std::io::Read::read_to_string(e, &mut s);
        }
        s
    });
    let mut status = 0;
    // SAFETY: rusage is plain data, filled by wait4 for our own child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    loop {
        // SAFETY: waiting on our own child with valid out-pointers.
        let r = unsafe { libc::wait4(pid, &mut status, libc::WNOHANG, &mut usage) };
        if r == pid {
            break;
        }
        if r < 0 {
            bail!("wait4 failed: {}", std::io::Error::last_os_error());
        }
        if t0.elapsed() > limit {
            // SAFETY: our own child, still running.
            unsafe { libc::kill(pid, libc::SIGKILL) };
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let wall = t0.elapsed().as_secs_f64();
    let err = reader.join().unwrap_or_default();
    let ok = libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0;
    if !ok {
        eprintln!(
            "  failed: {}",
            err.lines().last().unwrap_or("(killed or no message)")
        );
    }
    let secs = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    Ok(Usage {
        wall,
        cpu: secs(usage.ru_utime) + secs(usage.ru_stime),
        rss: usage.ru_maxrss as f64 / 1024.0,
        ok,
    })
}

/// Each command's name and arguments on the session `sp`, writing the model `mp` and the
/// recording `rp`, with the twin `tp` and the `simulate --like` output `lp`.
fn commands([sp, mp, rp, tp, lp]: [&str; 5]) -> Vec<(&'static str, Vec<&str>)> {
    vec![
        ("decompress", vec![sp]),
        ("info", vec!["info", sp]),
        ("identify", vec!["identify", sp, "-o", mp]),
        ("validate", vec!["validate", "--model", "paper", sp]),
        ("diagnose", vec!["diagnose", "--model", "paper", sp]),
        (
            "diagnose-save",
            vec!["diagnose", "--model", "paper", sp, "--save", rp],
        ),
        (
            "diagnose-counterpart",
            vec!["diagnose", "--model", "paper", sp, "--counterpart", tp],
        ),
        // Every sample (`--max-rate 0`): the default caps long replays at 150 MB.
        (
            "replay",
            vec!["replay", sp, "--max-rate", "0", "--save", rp],
        ),
        (
            "replay-model",
            vec![
                "replay",
                sp,
                "--model",
                "paper",
                "--max-rate",
                "0",
                "--save",
                rp,
            ],
        ),
        ("simulate-like", vec!["simulate", "--like", sp, "-o", lp]),
    ]
}

/// The command line a table row names.
fn label(name: &str) -> &str {
    match name {
        "decompress" => "bare decompression (one core)",
        "replay-model" => "replay --model paper --save",
        "diagnose-save" => "diagnose --model paper --save",
        "diagnose-counterpart" => "diagnose --model paper --counterpart TWIN",
        "simulate-like" => "simulate --like SESSION",
        "replay" => "replay --save",
        other => other,
    }
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_default()
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    // The sessions are built in a child process: a child's peak RSS counts its parent's pages
    // at spawn time, so the measuring process must stay small.
    if args.first().map(String::as_str) == Some("--make") {
        let (dir, h) = (
            args.get(1).context("--make DIR HOURS")?,
            args.get(2).context("--make DIR HOURS")?,
        );
        session(Path::new(dir), h.parse()?)?;
        return Ok(());
    }
    let dir = PathBuf::from(args.first().cloned().unwrap_or_else(|| {
        std::env::temp_dir()
            .join("g1viz-scale")
            .display()
            .to_string()
    }));
    let hours: Vec<String> = args
        .get(1)
        .map_or("1,4.4,10", String::as_str)
        .split(',')
        .map(String::from)
        .collect();
    let wanted: Vec<String> = args
        .get(2)
        .map_or(
            "decompress,info,identify,validate,diagnose,diagnose-save,diagnose-counterpart,replay,replay-model,simulate-like",
            String::as_str,
        )
        .split(',')
        .map(String::from)
        .collect();
    std::fs::create_dir_all(&dir)?;
    let bin = g1viz_bin()?;
    println!("binary {}, scratch {}", bin.display(), dir.display());
    println!(
        "| session | MCAP | command | wall [s] | CPU [s] | × CPU | × wall | peak RSS [MB] | .rrd | load avg (1/5/15 min) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let decompress = std::env::current_exe()?.with_file_name("bench_decompress");
    for arg in &hours {
        let (s, h) = match arg.parse::<f64>() {
            Ok(_) => (dir.join(format!("session_{arg}h.mcap")), format!("{arg} h")),
            Err(_) => (PathBuf::from(arg), arg.clone()),
        };
        let tag = s
            .file_stem()
            .map_or(h.clone(), |n| n.to_string_lossy().into_owned());
        if !s.exists() {
            let ok = Command::new(std::env::current_exe()?)
                .args(["--make", &dir.display().to_string(), arg])
                .status()?;
            if !ok.success() {
                bail!("building the {h} session failed");
            }
        }
        let mcap_mb = std::fs::metadata(&s)?.len() as f64 / 1e6;
        let model = dir.join(format!("model_{tag}.json"));
        let rrd = dir.join(format!("replay_{tag}.rrd"));
        let sp = s.display().to_string();
        let like = dir.join(format!("like_{tag}.mcap"));
        let lp = like.display().to_string();
        let (mp, rp) = (model.display().to_string(), rrd.display().to_string());
        // The twin on the session's own commands and timeline (`diagnose --counterpart`).
        let twin = dir.join(format!("{tag}_twin.mcap"));
        let tp = twin.display().to_string();
        if wanted.iter().any(|w| w == "diagnose-counterpart") && !twin.exists() {
            let ok = Command::new(&bin)
                .args(["simulate", "--like", &sp, "-o", &tp])
                .current_dir(&dir)
                .status()?;
            if !ok.success() {
                bail!("simulate --like {sp} failed");
            }
        }
        let mut floor = None::<(f64, f64)>;
        let commands = commands([&sp, &mp, &rp, &tp, &lp]);
        for (name, argv) in commands {
            if !wanted.iter().any(|w| w == name) {
                continue;
            }
            let _ = std::fs::remove_file(&rrd);
            let exe = if name == "decompress" {
                &decompress
            } else {
                &bin
            };
            let u = measure(
                Command::new(exe).args(&argv).current_dir(&dir),
                Duration::from_secs(3600),
            )?;
            if name == "decompress" {
                floor = Some((u.cpu, u.wall));
            }
            let ratio =
                |x: f64, f: Option<f64>| f.map_or("–".into(), |f| format!("{:.2}", x / f));
            let (cpu_x, wall_x) = (
                ratio(u.cpu, floor.map(|f| f.0)),
                ratio(u.wall, floor.map(|f| f.1)),
            );
            let size = std::fs::metadata(&rrd)
                .map(|m| format!("{:.0} MB", m.len() as f64 / 1e6))
                .unwrap_or_else(|_| "–".into());
            let label = label(name);
            println!(
                "| {h} | {mcap_mb:.0} MB | `{label}` | {:.2}{} | {:.2} | {cpu_x} | {wall_x} | {:.0} | {size} | {} |",
                u.wall,
                if u.ok { "" } else { " (failed)" },
                u.cpu,
                u.rss,
                load_average()
            );
        }
        let _ = std::fs::remove_file(&rrd);
        let _ = std::fs::remove_file(&like);
        let _ = std::fs::remove_file(g1viz::sim::truth_path(&like));
    }
    Ok(())
}
