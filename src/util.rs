//! Small helpers shared by every stage: atomic file output (its temporary files registered in
//! [`temp`] so no signal, error or panic leaves them behind), input checks.

pub mod temp;

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

/// The one set of progress lines on stderr that every bar and spinner joins: lines shown at
/// once (a command's stage spinner and a pass's reading bar) stack instead of overwriting each
/// other's line.
pub fn progress_lines() -> &'static indicatif::MultiProgress {
    static LINES: std::sync::LazyLock<indicatif::MultiProgress> =
        std::sync::LazyLock::new(indicatif::MultiProgress::new);
    &LINES
}

/// A bar `len()` steps long with `template` on the [`progress_lines`]; hidden when `shown` is
/// false or stderr is not a terminal (`len` is then not called).
pub fn progress_bar(
    shown: bool,
    template: &str,
    len: impl FnOnce() -> u64,
) -> indicatif::ProgressBar {
    if !shown || !std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        return indicatif::ProgressBar::hidden();
    }
    let bar = progress_lines().add(indicatif::ProgressBar::new(len()));
    if let Ok(style) = indicatif::ProgressStyle::with_template(template) {
        bar.set_style(style);
    }
    bar
}

/// Write `bytes` to `path` atomically: write a temporary file beside it, then rename.
/// A reader never sees a half-written file and a failed write leaves the old file intact.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes).map_err(Into::into))
}

/// Like [`write_atomic`], but the content is produced by `fill`, which writes into a buffered file.
pub fn write_atomic_with(
    path: &Path,
    fill: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> Result<()>,
) -> Result<()> {
    let dir = folder_of(path);
    std::fs::create_dir_all(dir)
        .with_context(|| format!("creating directory {}", dir.display()))?;
    // Removed when dropped (an error, a panic) or on a termination signal; renamed on success.
    let tmp = temp::TempPath::beside(path, "");
    let file = std::fs::File::create(tmp.path())
        .with_context(|| format!("creating {}", tmp.path().display()))?;
    let mut w = std::io::BufWriter::new(file);
    fill(&mut w)?;
    let file = w
        .into_inner()
        .map_err(|e| e.into_error())
        .context("flushing output")?;
    file.sync_all().ok();
    tmp.commit(path)
}

/// Canonical form of a path that may not exist yet (canonical parent + file name).
pub fn canonical_target(path: &Path) -> Option<std::path::PathBuf> {
    if let Ok(p) = path.canonicalize() {
        return Some(p);
    }
    Some(canonical_target(folder_of(path))?.join(path.file_name()?))
}

/// The folder `path` is in (`.` for a bare file name).
pub fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Refuses an output `target` (a file, or a folder a report is written into) that would
/// overwrite an input: the same file after resolving symlinks and `..`, a path inside an input
/// folder (a ROS 2 bag), or an input folder itself. `what` names the output in the error.
pub fn refuse_to_overwrite_inputs(what: &str, target: &Path, inputs: &[&Path]) -> Result<()> {
    let Some(t) = canonical_target(target) else {
        return Ok(());
    };
    for input in inputs {
        let Ok(i) = input.canonicalize() else {
            continue;
        };
        // A file of a ROS 2 bag folder: the folder's metadata and bag files are inputs too.
        let bag_dir = i
            .parent()
            .filter(|d| i.is_file() && d.join("metadata.yaml").is_file());
        let bag_file = |d: &Path| {
            let named = t.file_name().is_some_and(|n| n == "metadata.yaml");
            let bag = t
                .extension()
                .is_some_and(|e| ["db3", "mcap", "zstd"].iter().any(|x| e == *x));
            t.parent() == Some(d) && (named || bag)
        };
        let clash = t == i || (i.is_dir() && t.starts_with(&i)) || bag_dir.is_some_and(bag_file);
        if clash {
            anyhow::bail!(
                "refusing to write the {what} {} over the input {}",
                target.display(),
                input.display()
            );
        }
    }
    Ok(())
}

/// Largest text input (model JSON, signal map, URDF, bag metadata, truth file) read whole [bytes].
pub const MAX_TEXT_INPUT_BYTES: u64 = 256 << 20;

/// Read a small text input whole, refusing what is not a regular file (a FIFO, a device such as
/// `/dev/zero`) or larger than [`MAX_TEXT_INPUT_BYTES`], instead of blocking or exhausting memory.
pub fn read_text_input(path: &Path) -> std::io::Result<String> {
    use std::io::{Error, ErrorKind};
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(Error::new(ErrorKind::InvalidInput, "not a regular file"));
    }
    if meta.len() > MAX_TEXT_INPUT_BYTES {
        return Err(Error::new(
            ErrorKind::InvalidInput,
            format!(
                "{} bytes; a text input of more than {} MB is not what this expects",
                meta.len(),
                MAX_TEXT_INPUT_BYTES >> 20
            ),
        ));
    }
    std::fs::read_to_string(path)
}

/// Serde for an f64 that may be NaN or infinite: JSON has no such numbers, so they are written as
/// `null` and `null` reads back as NaN (`#[serde(with = "crate::util::nan_as_null")]`).
pub mod nan_as_null {
    use serde::{Deserialize, Deserializer, Serializer};

    /// Write a finite value as a number, anything else as `null`.
    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() {
            s.serialize_f64(*v)
        } else {
            s.serialize_none()
        }
    }

    /// Read a number, or `null` as NaN.
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
    }
}

/// The truth sidecar path of a simulated session's file: `x.mcap` → `x.truth.json`.
pub fn truth_path(out: &Path) -> PathBuf {
    out.with_extension("truth.json")
}

/// Refuses outputs that would overwrite an input (a file read, a bag folder, or a simulated
/// session's truth sidecar) or each other — checked before any work is done.
pub fn check_outputs(outputs: &[(&str, Option<&Path>)], inputs: &[Option<&Path>]) -> Result<()> {
    let sidecars: Vec<PathBuf> = inputs.iter().flatten().map(|p| truth_path(p)).collect();
    let mut all: Vec<&Path> = inputs.iter().flatten().copied().collect();
    all.extend(sidecars.iter().map(PathBuf::as_path));
    let outputs: Vec<(&str, &Path)> = outputs
        .iter()
        .filter_map(|(what, p)| p.map(|p| (*what, p)))
        .collect();
    for (k, (what, out)) in outputs.iter().enumerate() {
        crate::util::refuse_to_overwrite_inputs(what, out, &all)?;
        for (other, o) in &outputs[..k] {
            let (x, y) = (
                crate::util::canonical_target(out),
                crate::util::canonical_target(o),
            );
            if x.is_some() && x == y {
                bail!(
                    "the {what} and the {other} are the same file {}",
                    out.display()
                );
            }
        }
    }
    Ok(())
}

/// Refuses a session given twice; `why` says what that would spoil.
pub fn check_distinct_sessions(sessions: &[&Path], why: &str) -> Result<()> {
    for (k, a) in sessions.iter().enumerate() {
        for b in &sessions[..k] {
            if same_file(a, b) {
                bail!(
                    "{} and {} are the same recording: {why}",
                    b.display(),
                    a.display()
                );
            }
        }
    }
    Ok(())
}

/// Whether two paths name the same existing file.
pub fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}
