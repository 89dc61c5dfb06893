//! Small helpers shared by every stage: atomic file output.

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result};

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
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(dir)
        .with_context(|| format!("creating directory {}", dir.display()))?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    let result = (|| {
        let file =
            std::fs::File::create(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
        let mut w = std::io::BufWriter::new(file);
        fill(&mut w)?;
        let file = w
            .into_inner()
            .map_err(|e| e.into_error())
            .context("flushing output")?;
        file.sync_all().ok();
        std::fs::rename(&tmp, path)
            .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Canonical form of a path that may not exist yet (canonical parent + file name).
pub fn canonical_target(path: &Path) -> Option<std::path::PathBuf> {
    if let Ok(p) = path.canonicalize() {
        return Some(p);
    }
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    Some(canonical_target(parent)?.join(path.file_name()?))
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
