//! Plausibility limits and clock checks of the signal loader, on copies of the example session
//! re-written with the `mcap` crate and one message changed: a joint torque of 3e38 N·m is
//! dropped with one warning naming topic, field, count, time and value (it used to reach the
//! fit and make the solver report an infeasible problem); one message at log time 0 is dropped
//! with a warning instead of stretching the session over 56 years; jumps and gaps in a topic's
//! log times are warned about; a recording wholly on a relative clock keeps its samples.

mod common;

use std::path::Path;

use common::{McapMsg, example_messages};

use g1viz::read::OpenOptions;
use g1viz::signals::{Recording, SignalMap, load_recording};

/// Payload offset of `motor_state[18].tau_est` (left elbow) in a LowState CDR message:
/// 4 (encapsulation) + 72 (header, IMU, first MotorState's mode + padding) + 18 × 56 (MotorState
/// stride) + 12 (q, dq, ddq).
const LEFT_ELBOW_TAU_OFFSET: usize = 4 + 72 + 18 * 56 + 12;

/// Write `msgs` as MCAP, with or without an index (no summary); either way the reader delivers
/// them in log-time order (without an index, from the chunk headers).
fn write(path: &Path, msgs: &[McapMsg], indexed: bool) {
    let mut opts = mcap::WriteOptions::new();
    if !indexed {
        opts = opts
            .emit_summary_records(false)
            .emit_statistics(false)
            .emit_chunk_indexes(false)
            .emit_summary_offsets(false)
            .emit_message_indexes(false);
    }
    let mut w = opts
        .create(std::io::BufWriter::new(
            std::fs::File::create(path).unwrap(),
        ))
        .unwrap();
    common::write_messages(&mut w, msgs);
    w.finish().unwrap();
}

fn load(path: &Path) -> Recording {
    load_recording(path, &SignalMap::g1_left_arm(), &OpenOptions::default()).unwrap()
}

/// The example re-written with `change` applied to its `k`-th /lowstate message; returns the
/// recording and the changed message's original log time.
fn changed(k: usize, indexed: bool, change: impl Fn(&mut McapMsg)) -> (Recording, u64) {
    let tmp = tempfile::tempdir().unwrap();
    let mut msgs = example_messages();
    let m = msgs
        .iter_mut()
        .filter(|m| m.topic == "/lowstate")
        .nth(k)
        .unwrap();
    let t = m.log_time;
    change(m);
    let path = tmp.path().join("changed.mcap");
    write(&path, &msgs, indexed);
    (load(&path), t)
}

fn clean() -> Recording {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("clean.mcap");
    write(&path, &example_messages(), true);
    let rec = load(&path);
    assert!(rec.warnings.is_empty(), "{:?}", rec.warnings);
    rec
}

/// `rec` is `clean` without its state sample `k`.
fn assert_state_without(rec: &Recording, clean: &Recording, k: usize) {
    let mut tau = clean.state.tau.clone();
    tau.remove(k);
    let mut t = clean.state.t.clone();
    t.remove(k);
    assert_eq!(rec.state.tau, tau);
    assert_eq!(rec.state.t, t);
    assert_eq!(rec.mbs.watts, clean.mbs.watts);
    assert_eq!(rec.start_ns, clean.start_ns);
}

#[test]
fn an_absurd_torque_is_dropped_with_one_warning() {
    let clean = clean();
    // The hand-computed offset is the elbow torque the loader reads.
    let msgs = example_messages();
    let first = msgs.iter().find(|m| m.topic == "/lowstate").unwrap();
    let raw = &first.data[LEFT_ELBOW_TAU_OFFSET..LEFT_ELBOW_TAU_OFFSET + 4];
    assert_eq!(
        f64::from(f32::from_le_bytes(raw.try_into().unwrap())),
        clean.state.tau[0][3]
    );

    let k = 100;
    let (rec, t) = changed(k, true, |m| {
        m.data[LEFT_ELBOW_TAU_OFFSET..LEFT_ELBOW_TAU_OFFSET + 4]
            .copy_from_slice(&3e38f32.to_le_bytes());
    });
    assert_state_without(&rec, &clean, k);
    assert_eq!(rec.warnings.len(), 1, "{:?}", rec.warnings);
    let w = &rec.warnings[0];
    for needle in [
        "changed.mcap",
        "topic /lowstate field motor_state[18].tau_est (tau.elbow)",
        "1 implausible sample beyond ±1e4 N·m dropped",
        &format!("first at log time {t} ns: 3.000e38"),
    ] {
        assert!(w.contains(needle), "{needle:?} missing in: {w}");
    }
}

#[test]
fn a_message_at_log_time_zero_is_dropped_not_a_56_year_session() {
    let clean = clean();
    let k = 50;
    let (rec, _) = changed(k, true, |m| m.log_time = 0);
    assert_state_without(&rec, &clean, k);
    let span = rec.state.t.last().unwrap() - rec.state.t[0];
    assert!(span < 3600.0, "{span} s");
    let w = rec
        .warnings
        .iter()
        .find(|w| w.contains("before 2000"))
        .unwrap_or_else(|| panic!("{:?}", rec.warnings));
    for needle in [
        "topic /lowstate",
        "1 message(s)",
        "first at log time 0 ns",
        "dropped",
    ] {
        assert!(w.contains(needle), "{needle:?} missing in: {w}");
    }
}

#[test]
fn a_message_at_log_time_zero_in_a_file_without_index_is_dropped_too() {
    // No second pass over a file without index: its chunk headers say the recording runs on a
    // wall clock, so the stray message (delivered first, in log-time order) is dropped.
    let clean = clean();
    let k = 5000;
    let (rec, _) = changed(k, false, |m| m.log_time = 0);
    assert_state_without(&rec, &clean, k);
    assert!(
        rec.warnings.iter().any(|w| w.contains("topic /lowstate")
            && w.contains("before 2000")
            && w.contains("dropped")),
        "{:?}",
        rec.warnings
    );
}

#[test]
fn clock_jumps_and_gaps_in_a_topic_are_warned_about() {
    // One /lowstate message stamped 2 h late in a file without index: read in log-time order
    // it comes last, after a gap of 2 h less the rest of the session; in file order (the
    // chunks of a file that overlap in time beyond the memory budget) it would also be a 2 h
    // jump back, which time-ordered delivery never shows.
    let two_hours = 2 * 3_600_000_000_000u64;
    let last = example_messages()
        .iter()
        .filter(|m| m.topic == "/lowstate")
        .map(|m| m.log_time)
        .max()
        .unwrap();
    let (rec, t) = changed(200, false, |m| m.log_time += two_hours);
    let find = |needle: &str| {
        rec.warnings
            .iter()
            .find(|w| w.contains(needle) && w.contains("topic /lowstate"))
            .unwrap_or_else(|| panic!("{needle:?} not in {:?}", rec.warnings))
            .clone()
    };
    let hours = (t + two_hours - last) as f64 / 3.6e12;
    let gap = find(&format!("no message for {hours:.2} h"));
    assert!(
        gap.contains(&format!("before log time {} ns", t + two_hours)),
        "{gap}"
    );
    assert!(gap.contains("1 gap(s) of more than 1 h"), "{gap}");
    assert!(!rec.warnings.iter().any(|w| w.contains("jumps back")));
    assert_eq!(
        *rec.state.t.last().unwrap(),
        (t + two_hours - rec.start_ns) as f64 * 1e-9
    );
}

#[test]
fn a_recording_on_a_relative_clock_keeps_its_samples() {
    let clean = clean();
    let tmp = tempfile::tempdir().unwrap();
    let mut msgs = example_messages();
    let t0 = msgs.iter().map(|m| m.log_time).min().unwrap();
    for m in &mut msgs {
        m.log_time -= t0;
    }
    let path = tmp.path().join("relative.mcap");
    write(&path, &msgs, true);
    let rec = load(&path);
    assert_eq!(rec.state.t, clean.state.t);
    assert_eq!(rec.state.tau, clean.state.tau);
    assert_eq!(rec.start_ns, 0);
    assert!(
        rec.warnings
            .iter()
            .any(|w| w.contains("topic /lowstate") && w.contains("not on a wall clock")),
        "{:?}",
        rec.warnings
    );
}

#[test]
fn log_times_near_the_end_of_the_clock_do_not_overflow() {
    // Found by the fuzzing campaign: a message stamped near u64::MAX ns followed by normal ones
    // (file order) overflowed the backward-jump check. Read in log-time order it comes last:
    // the gap into it is the one warned about.
    let clean = clean();
    let (rec, _) = changed(10, false, |m| m.log_time = u64::MAX - 5);
    assert_eq!(rec.state.t.len(), clean.state.t.len());
    assert!(
        rec.warnings.iter().any(|w| w.contains("topic /lowstate")
            && w.contains("before log time 18446744073709551610 ns")),
        "{:?}",
        rec.warnings
    );
}
