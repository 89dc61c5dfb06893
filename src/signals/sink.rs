//! A consumer's view of a streamed recording, with a lifecycle like ripgrep's `Sink`:
//! [`RecordingSink::begin`] once with the session's header (source, clock origin, joints) before
//! any samples, [`RecordingSink::batch`] per stretch of samples, [`RecordingSink::finish`] once
//! with the read's summary. [`stream_into`] drives it over [`super::stream_recording`].

use std::path::Path;

use super::{Recording, SignalMap, StreamSummary, stream_recording};
use crate::read::OpenOptions;

/// What is known about a streamed session before its first samples are handed over.
#[derive(Debug, Clone, Copy)]
pub struct StreamHeader<'a> {
    /// File or bag directory being read.
    pub source: &'a Path,
    /// Absolute time [ns since the Unix epoch] every batch's times are relative to.
    pub start_ns: u64,
    /// URDF names of the 7 arm joints, in model order.
    pub joint_names: &'a [String],
}

/// A consumer of a streamed recording (see the module doc for the order of the calls).
pub trait RecordingSink {
    /// Called once, before the first batch.
    fn begin(&mut self, header: &StreamHeader<'_>) -> anyhow::Result<()>;
    /// Called for each stretch of samples, in time order (indexed files) or file order.
    fn batch(&mut self, batch: &Recording) -> anyhow::Result<()>;
    /// Called once after the last batch (also when no batch came: `begun` says whether
    /// [`RecordingSink::begin`] was called).
    fn finish(&mut self, summary: &StreamSummary, begun: bool) -> anyhow::Result<()>;
}

/// Streams `path` into `sink` in batches of at most `batch_samples` samples (memory bounded as
/// for [`stream_recording`]); errors of the read or of the sink stop it.
pub fn stream_into(
    path: &Path,
    map: &SignalMap,
    opts: &OpenOptions,
    batch_samples: usize,
    sink: &mut dyn RecordingSink,
) -> anyhow::Result<StreamSummary> {
    let mut begun = false;
    let summary = stream_recording(path, map, opts, batch_samples, &mut |batch| {
        if !begun {
            sink.begin(&StreamHeader {
                source: path,
                start_ns: batch.start_ns,
                joint_names: &batch.joint_names,
            })?;
            begun = true;
        }
        sink.batch(batch)
    })?;
    sink.finish(&summary, begun)?;
    Ok(summary)
}
