//! Our `.rrd` file sink: encodes on the stream's own thread with rerun's encoder into a temporary
//! file beside the target, keeps the first write error, and renames the file into place only
//! when everything succeeded (the SDK's `FileSink` logs write errors and carries on, and writes
//! straight to the target). It also gives the SDK's store-info message a fixed row id instead of
//! a wall-clock one, so the file is reproducible.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use anyhow::{Context, Result, anyhow, bail};
use rerun::external::re_build_info::CrateVersion;
use rerun::external::re_log_encoding::{Encoder, EncodingOptions};
use rerun::external::re_log_types::external::re_tuid::Tuid;
use rerun::log::LogMsg;
use rerun::sink::{LogSink, SinkFlushError};

struct State {
    encoder: Option<Encoder<BufWriter<File>>>,
    error: Option<String>,
}

type Shared = Arc<Mutex<State>>;

fn lock(state: &Shared) -> MutexGuard<'_, State> {
    // A panic while holding the lock cannot leave the encoder half-written in a way that matters:
    // the error path deletes the temporary file anyway.
    state
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// The `LogSink` half, owned by the `RecordingStream`.
pub(super) struct RrdFileSink {
    state: Shared,
}

/// The file half, owned by the caller until [`PendingFile::commit`].
pub(super) struct PendingFile {
    state: Shared,
    tmp: PathBuf,
    /// Registers `tmp` for removal on drop or on a termination signal (`util::temp`).
    guard: Option<crate::util::temp::TempPath>,
    target: PathBuf,
}

impl RrdFileSink {
    /// Creates the temporary file beside `target` and writes the RRD stream header.
    pub(super) fn create(target: &Path) -> Result<(RrdFileSink, PendingFile)> {
        let dir = crate::util::folder_of(target);
        std::fs::create_dir_all(dir)
            .with_context(|| format!("creating directory {}", dir.display()))?;
        if target.file_name().is_none() {
            bail!("output path {} has no file name", target.display());
        }
        let guard = crate::util::temp::TempPath::beside(target, "");
        let tmp = guard.path().to_path_buf();
        let file = File::create(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
        let encoder = Encoder::new_eager(
            CrateVersion::LOCAL,
            EncodingOptions::PROTOBUF_COMPRESSED,
            BufWriter::with_capacity(1 << 20, file),
        );
        // On an error the guard, dropped, removes the file.
        let encoder =
            encoder.map_err(|e| anyhow!("writing the RRD header to {}: {e}", tmp.display()))?;
        let state = Arc::new(Mutex::new(State {
            encoder: Some(encoder),
            error: None,
        }));
        let pending = PendingFile {
            state: state.clone(),
            tmp,
            guard: Some(guard),
            target: target.to_path_buf(),
        };
        Ok((RrdFileSink { state }, pending))
    }
}

impl LogSink for RrdFileSink {
    fn send(&self, mut msg: LogMsg) {
        if let LogMsg::SetStoreInfo(info) = &mut msg {
            // The SDK stamps this message with the wall clock; derive it from the store id instead.
            let id = info.info.store_id.recording_id().as_str();
            let h = crate::read::fingerprint::stable_hash(&[id.as_bytes()]);
            info.row_id = Tuid::from_nanos_and_inc(h >> 1, 0);
        }
        let mut state = lock(&self.state);
        if state.error.is_some() {
            return;
        }
        let result = match state.encoder.as_mut() {
            Some(encoder) => encoder.append(&msg).map(|_| ()).map_err(|e| e.to_string()),
            None => Err("message logged after the .rrd file was finished".to_owned()),
        };
        if let Err(err) = result {
            state.error = Some(err);
        }
    }

    fn flush_blocking(&self, _timeout: Duration) -> Result<(), SinkFlushError> {
        let mut state = lock(&self.state);
        if let Some(err) = &state.error {
            return Err(SinkFlushError::Failed {
                message: err.clone(),
            });
        }
        if let Some(encoder) = state.encoder.as_mut()
            && let Err(err) = encoder.flush_blocking()
        {
            let message = err.to_string();
            state.error = Some(message.clone());
            return Err(SinkFlushError::Failed { message });
        }
        Ok(())
    }
}

impl PendingFile {
    /// Writes the footer, syncs, and renames the temporary file to the target.
    pub(super) fn commit(mut self) -> Result<()> {
        let mut state = lock(&self.state);
        if let Some(err) = state.error.take() {
            return Err(anyhow!("writing {}: {err}", self.tmp.display()));
        }
        let mut encoder = state
            .encoder
            .take()
            .ok_or_else(|| anyhow!("{} already finished", self.tmp.display()))?;
        drop(state);
        encoder
            .finish()
            .map_err(|e| anyhow!("writing the RRD footer to {}: {e}", self.tmp.display()))?;
        let mut writer = encoder
            .into_inner()
            .map_err(|e| anyhow!("closing {}: {e}", self.tmp.display()))?;
        writer
            .flush()
            .with_context(|| format!("writing {}", self.tmp.display()))?;
        let file = writer
            .into_inner()
            .map_err(|e| e.into_error())
            .with_context(|| format!("writing {}", self.tmp.display()))?;
        file.sync_all()
            .with_context(|| format!("syncing {}", self.tmp.display()))?;
        let guard = self.guard.take().context("already committed")?;
        guard.commit(&self.target)
    }
}

impl Drop for PendingFile {
    fn drop(&mut self) {
        if self.guard.is_some() {
            // Unfinished or failed: close the file; the guard, dropped next, removes it.
            lock(&self.state).encoder = None;
        }
    }
}
