//! The tests' own guard against hanging external processes (`tests/common`): a process group that
//! ignores SIGINT — what a background job inherits, and what made the `--connect` test wait for
//! ever — is still stopped within the bounded waits, grandchildren included, and a command that
//! overruns its time limit fails the test instead of blocking it.

mod common;

use std::process::Command;
use std::time::{Duration, Instant};

/// A shell that ignores SIGINT and starts a grandchild that ignores it too, like the pip `rerun`
/// wrapper and the CLI it starts when launched from a background job.
fn stubborn() -> Command {
    let mut cmd = Command::new("sh");
    cmd.args(["-c", "trap '' INT; sh -c \"trap '' INT; sleep 300\" & wait"]);
    cmd
}

/// Processes of group `pgid` that are still running (zombies waiting for a reaper do not count).
fn live_members(pgid: u32) -> Vec<String> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir("/proc").expect("/proc") {
        let path = entry.expect("entry").path().join("stat");
        let Ok(stat) = std::fs::read_to_string(&path) else {
            continue;
        };
        // pid (comm) state ppid pgrp …; comm may contain spaces, so split after the last ')'.
        let Some((head, rest)) = stat.rsplit_once(')') else {
            continue;
        };
        let fields: Vec<&str> = rest.split_whitespace().collect();
        if fields.len() > 2 && fields[2] == pgid.to_string() && fields[0] != "Z" {
            out.push(format!("{head}) {}", fields[0]));
        }
    }
    out
}

#[test]
fn a_group_ignoring_sigint_is_stopped_within_the_bounded_waits() {
    let group = common::Group::spawn(&mut stubborn()).expect("sh runs");
    let pgid = group.id();
    std::thread::sleep(Duration::from_millis(300));
    let t = Instant::now();
    let status = group.stop(Duration::from_secs(1));
    let took = t.elapsed();
    assert!(!status.success(), "{status:?}");
    assert!(took < Duration::from_secs(10), "stop took {took:?}");
    // Nothing of the group is left running (the grandchild `sleep` included).
    let deadline = Instant::now() + Duration::from_secs(5);
    while !live_members(pgid).is_empty() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(live_members(pgid).is_empty(), "{:?}", live_members(pgid));
}

#[test]
fn an_overrunning_command_fails_the_test_in_bounded_time() {
    let started = Instant::now();
    let result =
        std::panic::catch_unwind(|| common::output_within(&mut stubborn(), Duration::from_secs(1)));
    let message = match result {
        Err(e) => e.downcast_ref::<String>().cloned().unwrap_or_default(),
        Ok(o) => panic!("expected a time-limit failure, got {o:?}"),
    };
    assert!(
        message.contains("did not finish within 1s") && message.contains("sh"),
        "{message}"
    );
    assert!(started.elapsed() < Duration::from_secs(10));
}

#[test]
fn a_command_within_its_limit_returns_its_output_and_status() {
    let o = common::output_within(
        Command::new("sh").args(["-c", "echo out; echo err >&2; exit 3"]),
        Duration::from_secs(60),
    )
    .expect("sh runs");
    assert_eq!(o.status.code(), Some(3));
    assert_eq!(o.stdout, b"out\n");
    assert_eq!(o.stderr, b"err\n");
    // A program that does not exist is an Err (callers skip on it), not a panic.
    assert!(
        common::output_within(
            &mut Command::new("g1viz-no-such-program"),
            Duration::from_secs(5)
        )
        .is_err()
    );
}
