//! A short fuzzing campaign in `cargo test`: a few hundred structure-aware mutations of the
//! seeds in every container and compression (see `tests/support/fuzz_engine.rs`), run in this
//! process through the whole reading path (open, info, read, generic decode, arm signals). A
//! panic fails the test with the input's recipe; long campaigns with child processes, memory
//! limits and a watchdog are `cargo run --release --example fuzz_readers`.

#[path = "support/fuzz_engine.rs"]
mod fuzz_engine;

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

use fuzz_engine::{Kind, Rng, exercise, mutate, seed_messages, seeds};

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
