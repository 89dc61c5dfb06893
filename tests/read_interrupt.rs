//! Interrupted outputs leave nothing behind: a `g1viz simulate … -o X` stopped by SIGTERM or
//! SIGINT in the middle of writing leaves no `.X.tmpPID` file and no X (or a complete one), and
//! dies of the signal as it would have; the library's temporary files are removed on an error
//! or a panic too.

mod common;

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use g1viz::util::temp;

/// Temporary files beside `target` (`.NAME.tmp*`).
fn temp_files(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.') && n.contains(".tmp"))
        .collect()
}

fn interrupted_simulation(signal: libc::c_int) {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("long.mcap");
    let mut child = common::Group::spawn(
        Command::new(env!("CARGO_BIN_EXE_g1viz"))
            .args(["simulate", "--preset", "paper", "-o"])
            .arg(&out)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null()),
    )
    .unwrap();
    // Wait (bounded) until the temporary output holds data, i.e. the write is under way.
    let started = Instant::now();
    let writing = loop {
        let growing = temp_files(tmp.path())
            .iter()
            .any(|n| std::fs::metadata(tmp.path().join(n)).is_ok_and(|m| m.len() > 100_000));
        if growing {
            break true;
        }
        if started.elapsed() > Duration::from_secs(300) {
            break false;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(writing, "the simulation never started writing");
    // SAFETY: kill(2) of our own child (not reaped yet, so its pid is not reused).
    unsafe {
        libc::kill(child.id() as libc::pid_t, signal);
    }
    let status = child
        .wait_within(Duration::from_secs(60))
        .expect("the simulation did not stop within 60 s of the signal");
    use std::os::unix::process::ExitStatusExt;
    assert_eq!(status.signal(), Some(signal), "{status:?}");
    assert_eq!(temp_files(tmp.path()), Vec::<String>::new());
    assert!(
        !out.exists(),
        "an interrupted simulation left {}",
        out.display()
    );
}

#[test]
fn sigterm_mid_write_leaves_no_temporary_or_partial_file() {
    interrupted_simulation(libc::SIGTERM);
}

#[test]
fn sigint_mid_write_leaves_no_temporary_or_partial_file() {
    interrupted_simulation(libc::SIGINT);
}

#[test]
fn temporary_files_are_removed_on_error_and_panic() {
    let tmp = tempfile::tempdir().unwrap();
    let target = tmp.path().join("out.json");
    let before = temp::in_flight();
    let err = g1viz::util::write_atomic_with(&target, |w| {
        use std::io::Write;
        w.write_all(b"partial")?;
        w.flush()?;
        assert_eq!(temp_files(tmp.path()).len(), 1);
        anyhow::bail!("failed half-way")
    });
    assert!(err.is_err());
    assert_eq!(temp_files(tmp.path()), Vec::<String>::new());
    assert!(!target.exists());

    let panicked = std::panic::catch_unwind(|| {
        let _ = g1viz::util::write_atomic_with(&target, |w| {
            use std::io::Write;
            w.write_all(b"partial")?;
            panic!("panic half-way")
        });
    });
    assert!(panicked.is_err());
    assert_eq!(temp_files(tmp.path()), Vec::<String>::new());
    assert!(!target.exists());

    g1viz::util::write_atomic(&target, b"{}").unwrap();
    assert_eq!(std::fs::read(&target).unwrap(), b"{}");
    assert_eq!(temp_files(tmp.path()), Vec::<String>::new());
    assert_eq!(temp::in_flight(), before);
}
