//! Benchmark: time to write the `.rrd` of a 1-hour, 100 Hz session and the process's peak RSS.
//!
//! `cargo run --release --example bench_replay [-- MINUTES [OUT.rrd]]` (default 60 minutes,
//! output in the temp dir, removed afterwards unless OUT is given). The session is synthetic
//! (smooth joint motion, 1 Hz power readings); the replay cost does not depend on the values.
//! Targets (issue 2): < 20 s on 2 cores, peak RSS < 500 MB.
//!
//! `cargo run --release --example bench_replay -- --file SESSION.mcap [OUT.rrd]` measures what
//! `g1viz replay SESSION --save OUT.rrd` does: the file streamed (read, decoded and logged in
//! batches), so peak RSS should not depend on the session's length. Long sessions to feed it:
//! `cargo run --release --no-default-features --example bench_read -- --generate one_hour.mcap`
//! and `g1viz simulate --preset paper -o paper.mcap` (3.4 h).

use std::time::Instant;

use anyhow::Context;

use g1viz::N_JOINTS;
use g1viz::robot::RobotModel;
use g1viz::signals::{CommandSeries, PowerSeries, Recording, StateSeries};
use g1viz::viz::{ReplayExtras, ReplayOptions, log_replay};
use g1viz::viz::{Sink, open_stream, recording_id_for};

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1).peekable();
    if args.peek().is_some_and(|a| a == "--file") {
        args.next();
        let session = std::path::PathBuf::from(args.next().context("--file SESSION")?);
        return streamed(&session, args.next().map(std::path::PathBuf::from));
    }
    let minutes: f64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(60.0);
    let keep = args.next().map(std::path::PathBuf::from);
    let out = keep.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("g1viz_bench_{}.rrd", std::process::id()))
    });

    let rec = synthetic(minutes);
    let rss_input = peak_rss_mb();
    let robot = RobotModel::builtin();
    let arm = robot.arm(&rec.joint_names)?;
    let t0 = Instant::now();
    let viz = open_stream(
        "g1viz_bench",
        &recording_id_for(&rec),
        &Sink::Save(out.clone()),
        &[],
    )?;
    let opts = ReplayOptions::default();
    log_replay(
        &rec,
        &robot,
        &arm,
        &ReplayExtras::default(),
        &opts,
        viz.stream(),
    )?;
    viz.finish()?;
    let secs = t0.elapsed().as_secs_f64();
    let size = std::fs::metadata(&out)?.len();
    println!(
        "{} samples ({minutes} min at 100 Hz, {} links) -> {} in {secs:.2} s ({:.0} samples/s), {:.1} MB; peak RSS {:.0} MB (after building the input: {:.0} MB)",
        rec.state.t.len(),
        robot.links().len(),
        out.display(),
        rec.state.t.len() as f64 / secs,
        size as f64 / 1e6,
        peak_rss_mb(),
        rss_input,
    );
    if keep.is_none() {
        std::fs::remove_file(&out)?;
    }
    Ok(())
}

/// Stream `session` into an `.rrd`, as `g1viz replay SESSION --save OUT` does.
fn streamed(session: &std::path::Path, keep: Option<std::path::PathBuf>) -> anyhow::Result<()> {
    use g1viz::read::OpenOptions;
    use g1viz::signals::SignalMap;
    use g1viz::viz::recording_id_for_source;
    use g1viz::viz::replay_files_with;
    let out = keep.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("g1viz_bench_{}.rrd", std::process::id()))
    });
    let map = SignalMap::g1_left_arm();
    let robot = RobotModel::builtin();
    let arm = robot.arm(&map.joint_names)?;
    let t0 = Instant::now();
    let id = recording_id_for_source(session).context("unreadable session")?;
    let viz = open_stream("g1viz_bench", &id, &Sink::Save(out.clone()), &[session])?;
    let opts = ReplayOptions::default();
    let summary = replay_files_with(
        &[session],
        0.0,
        &map,
        &OpenOptions::default(),
        &robot,
        &arm,
        Default::default(),
        &opts,
        viz.stream(),
    )?;
    viz.finish()?;
    let secs = t0.elapsed().as_secs_f64();
    let size = std::fs::metadata(&out)?.len();
    println!(
        "{}: {:.1} MB, {} LowState samples ({:.2} h) streamed -> {:.1} MB .rrd in {secs:.2} s ({:.0} samples/s); peak RSS {:.0} MB",
        session.display(),
        std::fs::metadata(session)?.len() as f64 / 1e6,
        summary.samples,
        summary.samples as f64 / 100.0 / 3600.0,
        size as f64 / 1e6,
        summary.samples as f64 / secs,
        peak_rss_mb(),
    );
    if keep.is_none() {
        std::fs::remove_file(&out)?;
    }
    Ok(())
}

fn synthetic(minutes: f64) -> Recording {
    let n = (minutes * 60.0 * 100.0) as usize;
    let mut s = StateSeries::default();
    for i in 0..n {
        let t = i as f64 * 0.01;
        let q: [f64; N_JOINTS] = std::array::from_fn(|j| 0.5 * (0.3 * t + j as f64).sin());
        let dq: [f64; N_JOINTS] = std::array::from_fn(|j| 0.15 * (0.3 * t + j as f64).cos());
        s.t.push(t);
        s.q.push(q);
        s.dq.push(dq);
        s.tau.push(std::array::from_fn(|j| 2.0 * q[j]));
        s.temp.push([35.0; N_JOINTS]);
        s.gyro.push([0.01 * t.sin(), 0.0, 0.0]);
        s.quat.push([1.0, 0.0, 0.0, 0.0]);
    }
    let mut command = CommandSeries::default();
    for i in (0..n).step_by(2) {
        command.t.push(s.t[i]);
        command.q.push(s.q[i]);
        command.dq.push(s.dq[i]);
    }
    let secs = (minutes * 60.0) as usize;
    let power = |base: f64| PowerSeries {
        t: (0..secs).map(|k| k as f64 + 0.5).collect(),
        watts: (0..secs)
            .map(|k| base + 10.0 * (k as f64 * 0.1).sin())
            .collect(),
    };
    Recording {
        source: "synthetic-1h.mcap".into(),
        start_ns: 1_700_000_000_000_000_000,
        joint_names: g1viz::robot::G1_LEFT_ARM_JOINTS.map(String::from).to_vec(),
        state: s,
        command,
        mbs: power(120.0),
        bms: power(135.0),
        warnings: vec![],
    }
}

/// Peak resident set size [MB] (VmHWM from /proc/self/status; 0 where unavailable).
fn peak_rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<f64>().ok())
        })
        .map_or(0.0, |kb| kb / 1024.0)
}
