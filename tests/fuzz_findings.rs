//! Regression tests for the hostile inputs of the first two fuzzing campaigns
//! (`../shared/robustness/fuzz-findings-{1,2}.tar.gz`, one input per finding, unpacked at run
//! time: the shared inputs are not copied into the repository). Each class of finding
//! runs its real inputs through the `g1viz info` binary in a child limited to 2 GiB of address
//! space (`ulimit -v 2097152`) and a 120 s watchdog, and asserts a clean end (exit 0 or 1, no
//! signal), a message naming the file, and the specific error or warning of the fix. Skipped
//! (via `tests/common`) when the shared folder is absent.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use g1viz::read::decode;
use g1viz::read::{Encoding, MsgSchema};

/// Address-space limit of each child [KiB].
const ULIMIT_V_KIB: u64 = 2_097_152;
/// Watchdog: a child still running after this is a hang.
const TIMEOUT_S: u64 = 120;
/// Largest peak RSS allowed for any child [KiB] (the readers' memory budget for hostile input).
const MAX_RSS_KIB: i64 = 512 * 1024;

/// The unpacked findings of campaign `n` (kept for the test's lifetime), or `None` (skipped)
/// without the data.
fn findings_of(n: u32) -> Option<(tempfile::TempDir, PathBuf)> {
    let shared = common::shared_dir()?;
    let tarball = shared.join(format!("robustness/fuzz-findings-{n}.tar.gz"));
    if !tarball.is_file() {
        common::skip(&format!("{} not found", tarball.display()));
        return None;
    }
    let tmp = tempfile::tempdir().unwrap();
    let ok = Command::new("tar")
        .arg("xzf")
        .arg(&tarball)
        .arg("-C")
        .arg(tmp.path())
        .status()
        .unwrap()
        .success();
    assert!(ok, "cannot unpack {}", tarball.display());
    let dir = tmp
        .path()
        .join(["fuzz-findings", "fuzz-findings-2"][(n - 1).min(1) as usize]);
    Some((tmp, dir))
}

/// The first campaign's findings (see [`findings_of`]).
fn findings() -> Option<(tempfile::TempDir, PathBuf)> {
    findings_of(1)
}

/// What a child run of `g1viz info FILE` did.
struct Run {
    code: Option<i32>,
    output: String,
    elapsed: Duration,
}

fn run_info(file: &Path) -> Run {
    let start = Instant::now();
    let out = Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -v {ULIMIT_V_KIB} && exec timeout -s KILL {TIMEOUT_S} \"$0\" info \"$1\""
        ))
        .arg(env!("CARGO_BIN_EXE_g1viz"))
        .arg(file)
        .output()
        .unwrap();
    let mut output = String::from_utf8_lossy(&out.stdout).into_owned();
    output.push_str(&String::from_utf8_lossy(&out.stderr));
    Run {
        code: out.status.code(),
        output,
        elapsed: start.elapsed(),
    }
}

/// Peak RSS of the largest child this test process has waited for [KiB].
fn children_peak_rss_kib() -> i64 {
    // SAFETY: getrusage only writes the struct it is given.
    unsafe {
        let mut usage: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage);
        usage.ru_maxrss
    }
}

/// Run `name` and check it ended cleanly, named the file and printed every needle.
fn check(dir: &Path, name: &str, needles: &[&str]) -> Run {
    let file = dir.join(name);
    assert!(file.exists(), "{} missing from the tarball", file.display());
    let run = run_info(&file);
    assert!(
        matches!(run.code, Some(0 | 1)),
        "{name}: exit {:?} after {:?} (crash, abort under the memory limit, or the watchdog):\n{}",
        run.code,
        run.elapsed,
        run.output
    );
    assert!(
        run.output.contains(file.to_str().unwrap()),
        "{name}: output does not name the file:\n{}",
        run.output
    );
    for needle in needles {
        assert!(
            run.output.contains(needle),
            "{name}: {needle:?} missing in:\n{}",
            run.output
        );
    }
    let rss = children_peak_rss_kib();
    assert!(
        rss < MAX_RSS_KIB,
        "{name}: a child peaked at {} MiB",
        rss / 1024
    );
    run
}

#[test]
fn deep_nesting_is_refused_instead_of_overflowing_the_stack() {
    let Some((_tmp, dir)) = findings() else {
        return;
    };
    for name in [
        "mcap-struct-stack-overflow-1.mcap",
        "mcap-struct-stack-overflow-2.mcap",
        "probe-mcap-idl-deep-module-stack-overflow-1.mcap",
        "probe-mcap-idl-deep-sequence-stack-overflow-1.mcap",
        "run1-mcap-struct-stack-overflow-idl-sequence.mcap",
    ] {
        check(&dir, name, &["nested more than 64 levels deep"]);
    }
    check(
        &dir,
        "db3-struct-stack-overflow-1.db3",
        &["metadata.yaml", "line "],
    );
    // Its deep block sequence sits in a field the metadata reader skips: the bag reads.
    check(
        &dir,
        "probe-db3-yaml-deep-sequence-stack-overflow-1.db3",
        &["ros2-sqlite3"],
    );
    // The definitions alone, through the library: `ENCODING\nTYPE\nTEXT`.
    for name in [
        "msgdef-stack-overflow-1.msgdef",
        "msgdef-stack-overflow-2.msgdef",
    ] {
        let text = std::fs::read_to_string(dir.join(name)).unwrap();
        let mut parts = text.splitn(3, '\n');
        let (encoding, ty, body) = (
            parts.next().unwrap(),
            parts.next().unwrap(),
            parts.next().unwrap(),
        );
        let err = MsgSchema::parse(encoding, ty, body)
            .unwrap_err()
            .to_string();
        assert!(err.contains("nested more than 64 levels"), "{name}: {err}");
    }
}

#[test]
fn an_array_size_product_that_overflows_is_refused() {
    let Some((_tmp, dir)) = findings() else {
        return;
    };
    check(
        &dir,
        "panic-92f2846c1580cdb7.mcap",
        &["dimensions multiply to more than"],
    );
}

#[test]
fn huge_fixed_arrays_and_duplicated_chunks_do_not_hang() {
    let Some((_tmp, dir)) = findings() else {
        return;
    };
    for name in [
        "probe-mcap-ros2msg-huge-nested-array-hang-1.mcap",
        "mcap-struct-hang-1.mcap",
        "mcap-struct-hang-2.mcap",
        "bag1-struct-hang-1.bag",
    ] {
        let run = check(&dir, name, &[]);
        assert!(
            run.elapsed < Duration::from_secs(TIMEOUT_S),
            "{name}: {:?}",
            run.elapsed
        );
    }
}

#[test]
fn decompression_bombs_are_capped_by_the_declared_size() {
    let Some((_tmp, dir)) = findings() else {
        return;
    };
    check(
        &dir,
        "probe-bag1-bz2-chunk-bomb-oom-rss-1.bag",
        &["decompressed to more than"],
    );
    let run = check(
        &dir,
        "probe-db3-file-zstd-disk-bomb-file-size-limit-1.db3",
        &["refused as a decompression bomb"],
    );
    assert_eq!(run.code, Some(1), "{}", run.output);
}

#[test]
fn duplicated_chunk_index_entries_are_loaded_once() {
    let Some((_tmp, dir)) = findings() else {
        return;
    };
    check(
        &dir,
        "probe-mcap-duplicate-chunk-index-oom-rss-1.mcap",
        &["chunk index entries more than once"],
    );
    check(
        &dir,
        "probe-bag1-duplicate-chunk-info-oom-rss-1.bag",
        &["chunk-info records more than once"],
    );
}

#[test]
fn flipped_length_prefixes_allocate_nothing_before_the_check() {
    let Some((_tmp, dir)) = findings() else {
        return;
    };
    for name in ["huge-alloc/mcap-raw-1.mcap", "huge-alloc/mcap-raw-2.mcap"] {
        check(&dir, name, &["byte offset"]);
    }
}

#[test]
fn messages_dropped_on_the_way_are_reported() {
    let Some((_tmp, dir)) = findings() else {
        return;
    };
    check(
        &dir,
        "silent-mcap-unknown-channel.mcap",
        &["which has no channel record, were skipped"],
    );
    check(
        &dir,
        "silent-bag1-conn.bag",
        &["which has no connection record, were skipped"],
    );
    check(&dir, "silent-bag1-datalen.bag", &["of the chunk", "lost"]);
}

#[test]
fn channels_missing_from_the_summary_are_learned_from_the_data_section() {
    let Some((_tmp, dir)) = findings() else {
        return;
    };
    let run = check(&dir, "info-no-summary-channels.mcap", &["/lowstate"]);
    assert!(!run.output.contains("<channel"), "{}", run.output);
}

#[test]
fn a_sequence_of_empty_structs_longer_than_the_payload_is_refused() {
    let Some((_tmp, dir)) = findings() else {
        return;
    };
    // `cdr\nTYPE\nLEN\n<LEN bytes of .msg text><payload>`.
    let bytes = std::fs::read(dir.join("probe-cdr-decode-empty-sequence-oom-rss-1.cdr")).unwrap();
    let mut lines = bytes.splitn(4, |b| *b == b'\n');
    let (_, ty, len, rest) = (
        lines.next().unwrap(),
        std::str::from_utf8(lines.next().unwrap()).unwrap(),
        std::str::from_utf8(lines.next().unwrap())
            .unwrap()
            .parse::<usize>()
            .unwrap(),
        lines.next().unwrap(),
    );
    let (text, payload) = rest.split_at(len);
    let schema = MsgSchema::parse_ros2msg(ty, std::str::from_utf8(text).unwrap()).unwrap();
    let err = decode(&schema, Encoding::Cdr, payload)
        .unwrap_err()
        .to_string();
    assert!(err.contains("cannot fit in a payload"), "{err}");
}

/// The second campaign's findings (`fuzz-findings-2.tar.gz`, the campaign's own inputs with
/// the `.txt` it wrote beside each): every input ends cleanly (exit 0/1, under the time and
/// memory limits above), and where the result of the undamaged file cannot be had back, a
/// warning names the record that disagrees. The `*-struct-*` inputs and `mcap-raw-8` are files
/// rewritten as a whole (messages deleted or duplicated with the checksums recomputed, a topic
/// name changed in a file without CRCs): nothing in them can tell a reader they differ from the
/// original, so only a clean end is asserted for them. The ROS 1 `bag1-raw-*` inputs have their
/// index data records damaged: the counts shown are the ones read, with a warning.
#[test]
fn second_campaign_inputs_end_cleanly_and_disagreements_are_reported() {
    let Some((_tmp, dir)) = findings_of(2) else {
        return;
    };
    let stats_disagree = "the statistics record at byte offset";
    for name in [
        "repro-stats-count-2pow30.mcap",
        "repro-stats-count-u64max.mcap",
    ] {
        check(&dir, name, &[stats_disagree, "messages:   28\n"]);
    }
    check(&dir, "overflow-sum-chunk-index.mcap", &["byte offset"]);
    let run = check(
        &dir,
        "encrypted.bag",
        &["the bag is encrypted (encryptor enc)"],
    );
    assert_eq!(run.code, Some(1), "{}", run.output);
    check(
        &dir,
        "msg_op0.bag",
        &[
            "record op 0x00 is neither a message nor a connection record",
            "1 of its 1 messages lost",
        ],
    );
    for k in 1..=7 {
        let name = format!("silent/mcap-raw-{k}.mcap");
        let run = check(&dir, &name, &["messages:   28\n"]);
        assert!(
            run.output.contains(stats_disagree) || run.output.contains("chunk index record"),
            "{name}: no warning about the index:\n{}",
            run.output
        );
    }
    // ROS 1 index damage: the counts shown are the ones read, i.e. the undamaged file's
    // (its fingerprint in the `.txt`: 12, 2, 2, 12 messages).
    for k in 1..=8 {
        let name = format!("silent/bag1-raw-{k}.bag");
        let run = check(&dir, &name, &["messages:   28\n", "index data record"]);
        for (topic, n) in [
            ("/arm_sdk", 12),
            ("/lf/bmsstate", 2),
            ("/lf/mainboardstate", 2),
            ("/lowstate", 12),
        ] {
            let line = run
                .output
                .lines()
                .find(|l| l.trim_start().starts_with(&format!("{topic} ")))
                .unwrap_or_else(|| panic!("{name}: no line for {topic}:\n{}", run.output));
            assert!(line.contains(&format!(" {n} msgs")), "{name}: {line}");
        }
    }
    check(&dir, "silent/bag1-struct-2.bag", &["messages:   28\n"]);
    for name in std::fs::read_dir(dir.join("silent")).unwrap() {
        let name = name.unwrap().file_name().into_string().unwrap();
        if !name.ends_with(".txt") {
            check(&dir, &format!("silent/{name}"), &[]);
        }
    }
}
