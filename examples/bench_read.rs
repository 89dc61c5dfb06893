//! Reader benchmark: decode throughput (LowState messages/s through the constant-offset
//! extractor and through the full `Value` decoder), time to `load_recording` a 1-hour 100 Hz
//! session, and peak RSS while loading.
//!
//! `cargo run --no-default-features --example bench_read [SESSION.mcap]` — without a path, a
//! 1-hour session is generated into a temporary file by repeating the shared smoke recording's
//! messages (`G1VIZ_SHARED` or `../shared`) with shifted timestamps and a rising tick counter;
//! `--generate OUT.mcap` only writes that file (then measure it in a fresh process).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use g1viz::read::decode;
use g1viz::read::{FieldExtractor, OpenOptions, Session};
use g1viz::signals::{Group, SignalMap, group_signals, load_recording};

struct Msg {
    topic: String,
    type_name: String,
    schema_text: String,
    log_time: u64,
    data: Vec<u8>,
}

fn shared_smoke() -> anyhow::Result<PathBuf> {
    let dir = std::env::var_os("G1VIZ_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared"));
    let p = dir.join("recordings/g1_smoke.mcap");
    anyhow::ensure!(
        p.is_file(),
        "{} not found: pass a session path or set G1VIZ_SHARED",
        p.display()
    );
    Ok(p)
}

/// All messages of the smoke session, with a ROS 2 schema text rebuilt from the built-in definitions.
fn smoke_messages(path: &Path) -> anyhow::Result<Vec<Msg>> {
    let mut session = Session::open(path, &OpenOptions::default())?;
    let mut out = Vec::new();
    session.read(None, &mut |m| {
        out.push(Msg {
            topic: m.channel.topic.clone(),
            type_name: m.channel.type_name.clone(),
            schema_text: String::new(),
            log_time: m.log_time_ns,
            data: m.data.to_vec(),
        });
        Ok(())
    })?;
    for m in &mut out {
        let mut text = g1viz::read::builtin_definition(&m.type_name)
            .context("builtin definition")?
            .to_string();
        for dep in ["IMUState", "MotorState", "MotorCmd"] {
            let dep_text =
                g1viz::read::builtin_definition(&format!("unitree_hg/{dep}")).context("dep")?;
            text.push_str(&format!(
                "\n{}\nMSG: unitree_hg/{dep}\n{dep_text}",
                "=".repeat(80)
            ));
        }
        m.schema_text = text;
    }
    Ok(out)
}

/// Write `seconds` of session by repeating `msgs` (zstd chunks, summary and indexes).
fn generate(msgs: &[Msg], out: &Path, seconds: f64) -> anyhow::Result<u64> {
    let first = msgs.first().context("empty smoke session")?.log_time;
    let span = msgs.last().context("empty")?.log_time - first + 10_000_000;
    let end = first + (seconds * 1e9) as u64;
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .create(std::io::BufWriter::new(std::fs::File::create(out)?))?;
    let mut channels = BTreeMap::<String, u16>::new();
    let mut written = 0u64;
    let mut tick = 0u32;
    'outer: for rep in 0u64.. {
        for m in msgs {
            let t = m.log_time + rep * span;
            if t >= end {
                break 'outer;
            }
            let id = match channels.get(&m.topic) {
                Some(id) => *id,
                None => {
                    let sid = w.add_schema(&m.type_name, "ros2msg", m.schema_text.as_bytes())?;
                    let id = w.add_channel(sid, &m.topic, "cdr", &BTreeMap::new())?;
                    channels.insert(m.topic.clone(), id);
                    id
                }
            };
            let mut data = m.data.clone();
            if m.topic == "/lowstate" {
                // tick (uint32 at body offset 12) keeps rising across repetitions.
                tick = tick.wrapping_add(10);
                if let Some(b) = data.get_mut(16..20) {
                    b.copy_from_slice(&tick.to_le_bytes());
                }
            }
            let header = mcap::records::MessageHeader {
                channel_id: id,
                sequence: written as u32,
                log_time: t,
                publish_time: t,
            };
            w.write_to_known_channel(&header, &data)?;
            written += 1;
        }
    }
    w.finish()?;
    Ok(written)
}

fn vm_hwm_kb() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}

fn main() -> anyhow::Result<()> {
    let smoke = shared_smoke();
    let tmp = tempfile::tempdir()?;
    let args: Vec<std::ffi::OsString> = std::env::args_os().skip(1).collect();
    if args.first().is_some_and(|a| a == "--generate") {
        // Write the 1-hour session and exit, so a second run measures the load in a fresh process.
        let out = PathBuf::from(args.get(1).context("--generate OUT.mcap")?);
        let n = generate(&smoke_messages(&smoke?)?, &out, 3600.0)?;
        println!("generated {} ({n} messages)", out.display());
        return Ok(());
    }
    let (session_path, lowstate): (PathBuf, Vec<Vec<u8>>) = match args.first() {
        Some(p) => (PathBuf::from(p), Vec::new()),
        None => {
            let msgs = smoke_messages(&smoke?)?;
            let out = tmp.path().join("one_hour.mcap");
            let t = Instant::now();
            let n = generate(&msgs, &out, 3600.0)?;
            println!(
                "generated {} ({n} messages, {:.1} MB) in {:.1} s",
                out.display(),
                std::fs::metadata(&out)?.len() as f64 / 1e6,
                t.elapsed().as_secs_f64()
            );
            let low = msgs
                .into_iter()
                .filter(|m| m.topic == "/lowstate")
                .map(|m| m.data)
                .collect();
            (out, low)
        }
    };

    // Decode throughput on in-memory LowState payloads (the smoke session's, or the file's first ones).
    let lowstate = if lowstate.is_empty() {
        let mut s = Session::open(&session_path, &OpenOptions::default())?;
        let mut v = Vec::new();
        s.read(Some(&["/lowstate"]), &mut |m| {
            if v.len() < 40_000 {
                v.push(m.data.to_vec());
            }
            Ok(())
        })?;
        v
    } else {
        lowstate
    };
    let mut session = Session::open(&session_path, &OpenOptions::default())?;
    let mut schema = None;
    session.read(Some(&["/lowstate"]), &mut |m| {
        if schema.is_none() {
            schema = Some(m.channel.schema.clone());
        }
        Ok(())
    })?;
    let schema = schema.context("no /lowstate messages")?;
    let map = SignalMap::g1_left_arm();
    let paths: Vec<_> = group_signals(Group::State)
        .iter()
        .map(|n| map.signals[n].field.clone())
        .collect();
    let ex = FieldExtractor::compile(&schema, g1viz::read::Encoding::Cdr, &paths)?;
    let mut out = vec![0.0; ex.len()];
    let reps = 20;
    let t = Instant::now();
    let mut checksum = 0.0;
    for _ in 0..reps {
        for d in &lowstate {
            ex.extract(d, &mut out)?;
            checksum += out[0];
        }
    }
    let fast = (reps * lowstate.len()) as f64 / t.elapsed().as_secs_f64();
    let n_full = lowstate.len().min(10_000);
    let t = Instant::now();
    for d in &lowstate[..n_full] {
        let v = decode(&schema, g1viz::read::Encoding::Cdr, d)?;
        checksum += v.get(&paths[0]).and_then(|v| v.as_f64()).unwrap_or(0.0);
    }
    let full = n_full as f64 / t.elapsed().as_secs_f64();
    println!(
        "decode: extractor {:.0} LowState msgs/s ({} fields, constant offsets: {}); full Value decode {:.0} msgs/s  [checksum {checksum:.3}]",
        fast,
        paths.len(),
        ex.is_constant_offset(),
        full
    );
    drop(lowstate);

    // Reset the peak-RSS counter so it measures the load alone (Linux: clear_refs 5).
    let _ = std::fs::write("/proc/self/clear_refs", "5");
    let hwm_before = vm_hwm_kb();
    let t = Instant::now();
    let rec = load_recording(&session_path, &map, &OpenOptions::default())?;
    let dt = t.elapsed().as_secs_f64();
    println!(
        "load_recording: {:.2} s for {} LowState + {} command + {} MBS + {} BMS samples ({:.0} LowState msgs/s end to end, {} warnings)",
        dt,
        rec.state.t.len(),
        rec.command.t.len(),
        rec.mbs.t.len(),
        rec.bms.t.len(),
        rec.state.t.len() as f64 / dt,
        rec.warnings.len()
    );
    println!(
        "peak RSS during load: {} MB (before load {} MB)",
        vm_hwm_kb().map_or("?".into(), |k| format!("{:.0}", k as f64 / 1024.0)),
        hwm_before.map_or("?".into(), |k| format!("{:.0}", k as f64 / 1024.0))
    );
    Ok(())
}
