//! A short fuzzing campaign in `cargo test`: a few hundred structure-aware mutations of the
//! seeds in every container and compression (see `tests/support/fuzz_engine.rs`), run in this
//! process through the whole reading path (open, info, read, generic decode, arm signals). A
//! panic fails the test with the input's recipe; long campaigns with child processes, memory
//! limits and a watchdog are `cargo run --release --example fuzz_readers`.

mod common;
#[path = "support/fuzz_engine.rs"]
mod fuzz_engine;

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

use fuzz_engine::{Kind, Rng, campaign_kind, exercise, input_for, mutate, seed_messages, seeds};

/// Inputs per run (fixed seed: the same inputs every run).
const INPUTS: u64 = 300;

#[test]
fn seeds_read_cleanly_in_every_container() {
    let bytes =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap"))
            .unwrap();
    let msgs = seed_messages(&bytes, 200);
    assert_eq!(msgs.len(), 200);
    let all = seeds(&msgs);
    assert_eq!(all.len(), 12);
    for seed in &all {
        let tmp = tempfile::tempdir().unwrap();
        let path = seed.write_to(tmp.path()).unwrap();
        let mut session = g1viz::read::Session::open(&path, &Default::default()).unwrap();
        let info = session.info().unwrap();
        assert_eq!(info.messages, 200, "{}: {info:?}", seed.label);
        let mut n = 0;
        let summary = session
            .read(None, &mut |m| {
                g1viz::read::decode(&m.channel.schema, m.channel.encoding, m.data)
                    .unwrap_or_else(|e| panic!("{}: {e}", seed.label));
                n += 1;
                Ok(())
            })
            .unwrap();
        // The unindexed bag says so (and is scanned); nothing else may warn.
        let expected = usize::from(seed.label == "bag1-unindexed");
        assert!(
            summary.complete && summary.warnings.len() == expected,
            "{}: {summary:?}",
            seed.label
        );
        assert_eq!(n, 200, "{}", seed.label);
    }
}

#[test]
fn short_campaign_finds_no_panic() {
    let bytes =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap"))
            .unwrap();
    let all = seeds(&seed_messages(&bytes, 120));
    let mut rng = Rng::new(20261123);
    let tmp = tempfile::tempdir().unwrap();
    let mut kinds = [0u32; 3];
    for i in 0..INPUTS {
        let seed = &all[rng.below(all.len())];
        let input = mutate(seed, &mut rng);
        kinds[input.kind as usize] += 1;
        let dir = tmp.path().join(format!("i{i}"));
        let path = input.write_to(&dir).unwrap();
        let outcome = catch_unwind(AssertUnwindSafe(|| exercise(&path)));
        assert!(outcome.is_ok(), "input {i} panicked: {}", input.label);
        std::fs::remove_dir_all(&dir).unwrap();
    }
    assert!(
        kinds.iter().all(|k| *k > 30),
        "every container mutated: {kinds:?} ({:?})",
        [Kind::Mcap, Kind::Bag1, Kind::Db3]
    );
}

/// The 1 M-input campaign of docs/reading.md (seed 2031, 60 seed messages, inputs 0..1,000,000).
const CAMPAIGN_SEED: u64 = 2031;
const CAMPAIGN_INPUTS: u64 = 1_000_000;
const CAMPAIGN_MESSAGES: usize = 60;

/// The per-container counts docs/reading.md states for the campaign are what its generator makes:
/// recomputed here for every one of the million inputs (the container is fixed by the input's
/// seed pick, so no input has to be built).
#[test]
fn readme_campaign_counts_are_the_generators() {
    let bytes =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap"))
            .unwrap();
    let all = seeds(&seed_messages(&bytes, CAMPAIGN_MESSAGES));
    let mut counts = [0u64; 3];
    for i in 0..CAMPAIGN_INPUTS {
        let k = match campaign_kind(&all, CAMPAIGN_SEED, i) {
            Kind::Bag1 => 0,
            Kind::Db3 => 1,
            Kind::Mcap => 2,
        };
        counts[k] += 1;
    }
    let fmt = |n: u64| {
        let s = n.to_string();
        let (head, tail) = s.split_at(s.len() - 3);
        format!("{head},{tail}")
    };
    let text = common::doc_page("docs/reading.md")
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ");
    let stated = format!(
        "(seed {CAMPAIGN_SEED}, dev profile, two batched jobs at `nice 19` on a 2-core machine \
         shared with builds, 6,528 s, 153 inputs/s): 1,000,000 inputs — ROS 1 {}, `.db3` {}, MCAP {}",
        fmt(counts[0]),
        fmt(counts[1]),
        fmt(counts[2])
    );
    assert!(
        text.contains(&stated),
        "docs/reading.md does not state the campaign's counts {counts:?}: expected {stated:?}"
    );
}

/// A sample of the campaign's own inputs (every 3,333rd of seed 2031, 300 in all, spread over
/// the million) re-read in this process: none may panic (the campaign's child processes also
/// checked memory and time; this keeps the figure honest against later reader changes).
#[test]
fn readme_campaign_sample_reads_without_panic() {
    let bytes =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap"))
            .unwrap();
    let all = seeds(&seed_messages(&bytes, CAMPAIGN_MESSAGES));
    let tmp = tempfile::tempdir().unwrap();
    for i in (0..CAMPAIGN_INPUTS).step_by(3_333).take(300) {
        let input = input_for(&all, CAMPAIGN_SEED, i);
        let dir = tmp.path().join(format!("i{i}"));
        let path = input.write_to(&dir).unwrap();
        let outcome = catch_unwind(AssertUnwindSafe(|| exercise(&path)));
        assert!(
            outcome.is_ok(),
            "campaign input {CAMPAIGN_SEED}:{i} panicked: {}",
            input.label
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
