//! The fuzz campaigns' own results, stored in `tests/data/fuzz-campaigns/*.json` as
//! `cargo run --example fuzz_readers` wrote them (`results.json`: verdict counts, distinct
//! findings, time, seed, commit, limits). For each: the file is consistent with itself, and a
//! sample of its inputs (regenerated from the seed: input `i` is a pure function of seed and
//! index) is re-run through `g1viz info` in a child under the campaign's own limits — address
//! space, file size (disk), CPU time per input — with a wall-clock backstop, and checked for a
//! clean end (exit 0 or 1, no signal) and a peak RSS under the campaign's budget. Campaigns that
//! recorded the largest peak RSS and longest time any clean input took have those inputs
//! re-run too, and the docs quote both figures.

mod common;
#[path = "support/fuzz_engine.rs"]
mod fuzz_engine;

use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use fuzz_engine::{input_for, seed_messages, seeds};

/// Inputs re-run per stored campaign.
const SAMPLE: u64 = 40;

fn campaigns() -> Vec<(PathBuf, serde_json::Value)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fuzz-campaigns");
    let mut out: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "json"))
        .map(|p| {
            let v = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
            (p, v)
        })
        .collect();
    out.sort_by(|a, b| a.0.cmp(&b.0));
    assert!(!out.is_empty(), "no stored campaign in {}", dir.display());
    out
}

fn sum(v: &serde_json::Value) -> u64 {
    v.as_object()
        .unwrap()
        .values()
        .map(|n| n.as_u64().unwrap())
        .sum()
}

#[test]
fn stored_campaign_results_are_consistent() {
    for (path, c) in campaigns() {
        let inputs = c["inputs"].as_u64().unwrap();
        assert!(inputs > 0, "{}", path.display());
        assert_eq!(sum(&c["verdicts"]), inputs, "{}", path.display());
        assert_eq!(sum(&c["inputs_per_kind"]), inputs, "{}", path.display());
        let clean = c["verdicts"]["clean"].as_u64().unwrap_or(0);
        let with_findings = c["inputs_with_findings"].as_u64().unwrap();
        assert_eq!(clean + with_findings, inputs, "{}", path.display());
        let per_finding: u64 = c["distinct_findings"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f["inputs"].as_u64().unwrap())
            .sum();
        assert_eq!(per_finding, with_findings, "{}", path.display());
        assert_eq!(
            c["commit"].as_str().unwrap().len(),
            40,
            "{}",
            path.display()
        );
        if let Some(o) = c.get("observed") {
            let rss = o["max_peak_rss_kib"].as_u64().unwrap();
            assert!(rss > 0, "{}", path.display());
            assert!(rss <= c["limits"]["peak_rss_kib"].as_u64().unwrap());
            let first = c["first_input"].as_u64().unwrap();
            for k in ["max_peak_rss_input", "slowest_input"] {
                let i = o[k].as_u64().unwrap();
                assert!(
                    (first..first + inputs).contains(&i),
                    "{}: {k}",
                    path.display()
                );
            }
        }
    }
    // Campaigns since the harness recorded what it observed carry it; the newest must.
    let newest = campaigns()
        .into_iter()
        .max_by_key(|(_, c)| c["finished_unix_s"].as_u64())
        .unwrap();
    assert!(
        newest.1.get("observed").is_some(),
        "{}: no observed peak RSS / time",
        newest.0.display()
    );
}

/// Set the campaign's limits in the child (between fork and exec).
/// docs/reading.md quotes each stored campaign from its file: seed, short commit, seconds, the
/// total and every container's count, and the number of findings.
#[test]
fn docs_quote_the_stored_campaigns() {
    let page = common::doc_page("docs/reading.md");
    let thousands = |n: u64| {
        let d = n.to_string();
        let mut out = String::new();
        for (i, c) in d.chars().enumerate() {
            if i > 0 && (d.len() - i).is_multiple_of(3) {
                out.push(',');
            }
            out.push(c);
        }
        out
    };
    for (path, c) in campaigns() {
        let k = &c["inputs_per_kind"];
        let findings = c["distinct_findings"].as_array().unwrap().len();
        let expected = [
            format!("seed {}", c["seed"]),
            format!("commit {}", &c["commit"].as_str().unwrap()[..7]),
            format!(
                "{} s",
                thousands(c["seconds"].as_f64().unwrap().round() as u64)
            ),
            format!("{} inputs", thousands(c["inputs"].as_u64().unwrap())),
            format!("ROS 1 {}", thousands(k["bag1"].as_u64().unwrap())),
            format!("`.db3` {}", thousands(k["db3"].as_u64().unwrap())),
            format!("MCAP {}", thousands(k["mcap"].as_u64().unwrap())),
            format!("{findings} findings"),
        ];
        let observed = c.get("observed").map(|o| {
            [
                format!(
                    "peak RSS at most {} MiB",
                    o["max_peak_rss_kib"].as_u64().unwrap().div_ceil(1024)
                ),
                format!(
                    "slowest input {} ms",
                    thousands(o["slowest_input_ms"].as_u64().unwrap())
                ),
            ]
        });
        let expected = expected.into_iter().chain(observed.into_iter().flatten());
        for e in expected {
            assert!(
                page.contains(&e),
                "docs/reading.md does not quote {} as \"{e}\"",
                path.display()
            );
        }
    }
}

fn limit(cmd: &mut Command, as_bytes: u64, fsize_bytes: u64, cpu_s: u64) {
    // SAFETY: only async-signal-safe setrlimit calls between fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            for (res, v) in [
                (libc::RLIMIT_AS, as_bytes),
                (libc::RLIMIT_FSIZE, fsize_bytes),
                (libc::RLIMIT_CPU, cpu_s),
                (libc::RLIMIT_CORE, 0),
            ] {
                let lim = libc::rlimit {
                    rlim_cur: v as libc::rlim_t,
                    rlim_max: v as libc::rlim_t,
                };
                if libc::setrlimit(res, &lim) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
            }
            Ok(())
        });
    }
}

#[test]
fn stored_campaign_samples_rerun_under_the_campaigns_limits() {
    let bytes =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap"))
            .unwrap();
    for (path, c) in campaigns() {
        let name = path.display();
        let all = seeds(&seed_messages(
            &bytes,
            c["seed_messages"].as_u64().unwrap() as usize,
        ));
        let (seed, first, inputs) = (
            c["seed"].as_u64().unwrap(),
            c["first_input"].as_u64().unwrap(),
            c["inputs"].as_u64().unwrap(),
        );
        let lim = &c["limits"];
        let as_bytes = lim["address_space_bytes"].as_u64().unwrap();
        let fsize = lim["file_size_bytes"].as_u64().unwrap();
        let rss_kib = lim["peak_rss_kib"].as_u64().unwrap() as i64;
        let cpu = lim["cpu_s_per_input"].as_f64().unwrap();
        let per_mb = lim["cpu_s_per_input_per_mb"].as_f64().unwrap();
        let tmp = tempfile::tempdir().unwrap();
        let step = (inputs / SAMPLE).max(1);
        // The sample, plus the inputs the campaign saw take the most memory and time.
        let heaviest = ["max_peak_rss_input", "slowest_input"]
            .map(|k| c["observed"][k].as_u64())
            .into_iter()
            .flatten();
        for i in (first..first + inputs)
            .step_by(step as usize)
            .take(SAMPLE as usize)
            .chain(heaviest)
        {
            let input = input_for(&all, seed, i);
            let dir = tmp.path().join(format!("i{i}"));
            let file = input.write_to(&dir).unwrap();
            let size: usize = input.files.values().map(Vec::len).sum();
            let budget = (cpu + per_mb * (size >> 20) as f64).ceil() as u64;
            let mut cmd = Command::new(env!("CARGO_BIN_EXE_g1viz"));
            cmd.arg("info").arg(&file).env("TMPDIR", tmp.path());
            limit(&mut cmd, as_bytes, fsize, budget);
            // The campaign's backstop: no progress within 30 × the CPU budget.
            let out = common::output_within(&mut cmd, Duration::from_secs(30 * budget)).unwrap();
            assert!(
                matches!(out.status.code(), Some(0 | 1)),
                "{name}: input {seed}:{i} ({}) ended {:?} (signal {:?}) under the campaign's limits:\n{}",
                input.label,
                out.status.code(),
                out.status.signal(),
                String::from_utf8_lossy(&out.stderr)
            );
            // SAFETY: getrusage only writes the struct it is given.
            let peak = unsafe {
                let mut usage: libc::rusage = std::mem::zeroed();
                libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage);
                usage.ru_maxrss
            };
            assert!(
                peak < rss_kib,
                "{name}: input {seed}:{i} ({}) peaked at {peak} KiB",
                input.label
            );
            std::fs::remove_dir_all(&dir).unwrap();
        }
    }
}
