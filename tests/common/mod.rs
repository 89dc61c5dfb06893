//! Helpers shared by the integration tests.

use std::path::{Path, PathBuf};

/// The shared read-only data folder (`$G1VIZ_SHARED`, else `<crate>/../shared`), or `None` with a
/// note on stderr so the caller can skip.
pub fn shared_dir() -> Option<PathBuf> {
    let dir = std::env::var_os("G1VIZ_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared"));
    if dir.join("recordings").is_dir() {
        Some(dir)
    } else {
        skip(&format!(
            "shared data not found at {} (set G1VIZ_SHARED)",
            dir.display()
        ));
        None
    }
}

/// Note on stderr that a test (or part of it) is skipped because something outside the crate is
/// missing — the shared data, python3 with its packages, the stock `rerun` CLI. With
/// `G1VIZ_REQUIRE_ALL=1` (set by `.ci/run`, which installs all of it) a skip is a failure, so a
/// missing install step cannot turn into a green run that checked nothing.
pub fn skip(reason: &str) {
    if std::env::var_os("G1VIZ_REQUIRE_ALL").is_some_and(|v| !v.is_empty() && v != "0") {
        panic!("G1VIZ_REQUIRE_ALL is set but a check would be skipped: {reason}");
    }
    eprintln!("note: skipping: {reason}");
}

/// A file under the shared `recordings/` folder, if the folder is there.
#[allow(dead_code)] // not every test binary uses every helper
pub fn shared_recording(name: &str) -> Option<PathBuf> {
    let path = shared_dir()?.join("recordings").join(name);
    if path.exists() {
        Some(path)
    } else {
        skip(&format!("{} not found", path.display()));
        None
    }
}
