//! A registry of in-flight temporary outputs (`.NAME.tmpPID` files beside a target, scratch
//! folders), so that nothing is left behind however the process ends: a [`TempPath`] removes
//! its path when dropped (an error, or a panic unwinding), and after
//! [`cleanup_on_termination_signals`] a SIGINT, SIGTERM or SIGHUP removes every registered path
//! before the process dies of that signal.
//!
//! The signal handler itself only writes the signal number to a pipe (async-signal-safe); a
//! watcher thread does the removal while holding the registry lock, then re-raises the signal
//! with its default action. Renames into place ([`TempPath::commit`]) take the same lock, so a
//! target is either complete or absent.

use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard, Once};

use anyhow::Context;

/// The registered paths.
static IN_FLIGHT: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn registry() -> MutexGuard<'static, Vec<PathBuf>> {
    // A panic while holding the lock leaves a valid list.
    IN_FLIGHT
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

fn remove(path: &Path) {
    if path.is_dir() {
        let _ = std::fs::remove_dir_all(path);
    } else {
        let _ = std::fs::remove_file(path);
    }
}

/// A temporary path registered for cleanup; removed (file or folder) when dropped unless
/// committed.
#[derive(Debug)]
pub struct TempPath {
    path: PathBuf,
}

impl TempPath {
    /// Register `path` (before creating it, so a signal can never miss it).
    pub fn register(path: PathBuf) -> TempPath {
        registry().push(path.clone());
        TempPath { path }
    }

    /// The temporary path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The temporary file beside `target` (`.NAME.tmpPID`, plus `suffix`), registered.
    pub fn beside(target: &Path, suffix: &str) -> TempPath {
        let dir = super::folder_of(target);
        let name = target
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let name = name.strip_suffix(suffix).unwrap_or(&name);
        TempPath::register(dir.join(format!(".{name}.tmp{}{suffix}", std::process::id())))
    }

    /// Rename the temporary file to `target` and unregister it (an error names both). Holds the
    /// registry lock, so a termination signal either comes before (the temporary file is
    /// removed, `target` is not touched) or after (`target` is complete).
    pub fn commit(self, target: &Path) -> anyhow::Result<()> {
        let mut list = registry();
        let (from, to) = (self.path.display(), target.display());
        std::fs::rename(&self.path, target).with_context(|| format!("renaming {from} to {to}"))?;
        list.retain(|p| p != &self.path);
        drop(list);
        std::mem::forget(self);
        Ok(())
    }
}

impl Drop for TempPath {
    fn drop(&mut self) {
        let mut list = registry();
        remove(&self.path);
        list.retain(|p| p != &self.path);
    }
}

/// How many paths are registered now (for tests).
pub fn in_flight() -> usize {
    registry().len()
}

/// Write end of the signal pipe (-1 until installed).
static PIPE_WRITE: std::sync::atomic::AtomicI32 = std::sync::atomic::AtomicI32::new(-1);

extern "C" fn on_signal(sig: libc::c_int) {
    let fd = PIPE_WRITE.load(std::sync::atomic::Ordering::Relaxed);
    let byte = sig as u8;
    // SAFETY: write(2) is async-signal-safe; the buffer is one valid byte.
    unsafe {
        libc::write(fd, (&byte as *const u8).cast(), 1);
    }
}

/// Remove every registered temporary path when the process gets SIGINT, SIGTERM or SIGHUP, then
/// die of that signal as it would have (exit status and shell behaviour unchanged). For
/// programs, not libraries: call it once at the start of `main`. Idempotent.
pub fn cleanup_on_termination_signals() {
    static INSTALL: Once = Once::new();
    INSTALL.call_once(|| {
        let mut fds = [0 as libc::c_int; 2];
        // SAFETY: pipe(2) fills the two-element array it is given.
        if unsafe { libc::pipe(fds.as_mut_ptr()) } != 0 {
            return;
        }
        let read_fd = fds[0];
        PIPE_WRITE.store(fds[1], std::sync::atomic::Ordering::Relaxed);
        let watcher = std::thread::Builder::new()
            .name("temp-cleanup".into())
            .spawn(move || watch(read_fd));
        if watcher.is_err() {
            return;
        }
        for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
            // SAFETY: installs a handler that only calls write(2); sigaction's struct is zeroed
            // and filled with valid values.
            unsafe {
                let mut action: libc::sigaction = std::mem::zeroed();
                action.sa_sigaction = on_signal as *const () as libc::sighandler_t;
                action.sa_flags = libc::SA_RESTART;
                libc::sigemptyset(&mut action.sa_mask);
                libc::sigaction(sig, &action, std::ptr::null_mut());
            }
        }
    });
}

/// The watcher thread: on a signal byte, remove everything registered (keeping the lock, so no
/// new temporary file or rename can start), then re-raise the signal with its default action.
fn watch(read_fd: libc::c_int) {
    let mut byte = 0u8;
    loop {
        // SAFETY: read(2) into one valid byte.
        let n = unsafe { libc::read(read_fd, (&mut byte as *mut u8).cast(), 1) };
        if n == 1 {
            break;
        }
        if n < 0 && std::io::Error::last_os_error().kind() == std::io::ErrorKind::Interrupted {
            continue;
        }
        return;
    }
    let sig = libc::c_int::from(byte);
    let list = registry();
    for path in list.iter() {
        remove(path);
    }
    // SAFETY: restoring the default action and raising the signal ends the process the way the
    // signal would have; the lock is held until then.
    unsafe {
        libc::signal(sig, libc::SIG_DFL);
        libc::kill(libc::getpid(), sig);
    }
    std::thread::sleep(std::time::Duration::from_secs(5));
    std::process::exit(128 + sig);
}
