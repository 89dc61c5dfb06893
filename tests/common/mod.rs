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
        eprintln!(
            "note: shared data not found at {} (set G1VIZ_SHARED); skipping",
            dir.display()
        );
        None
    }
}

/// A file under the shared `recordings/` folder, if the folder is there.
#[allow(dead_code)] // not every test binary uses every helper
pub fn shared_recording(name: &str) -> Option<PathBuf> {
    shared_dir()
        .map(|d| d.join("recordings").join(name))
        .filter(|p| p.exists())
}
