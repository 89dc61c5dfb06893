//! A consumer's view of a streamed recording, with a lifecycle like ripgrep's `Sink`:
//! [`RecordingSink::begin`] once with the session's header (source, clock origin, joints) before
//! any samples, [`RecordingSink::batch`] per stretch of samples, [`RecordingSink::finish`] once
//! with the read's summary. [`stream_joined_into`] drives it over [`super::stream_recording`].

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

/// Streams one file, or several joined end to end into one session exactly as
/// [`super::join_recordings`] joins them loaded, into `sink` in batches of at most
/// `batch_samples` samples (memory bounded as for [`stream_recording`]; errors of the read or of
/// the sink stop it): each part's times are shifted so that its first
/// joint sample comes `gap_s` after the previous part's last one; the header (source, clock origin,
/// joints) is the first part's, and every batch is on its clock. [`RecordingSink::begin`] and
/// [`RecordingSink::finish`] are called once (the summary adds the parts' counts and warnings).
pub fn stream_joined_into(
    paths: &[&Path],
    map: &SignalMap,
    opts: &OpenOptions,
    batch_samples: usize,
    gap_s: f64,
    sink: &mut dyn RecordingSink,
) -> anyhow::Result<StreamSummary> {
    let mut joined = Joined {
        sink,
        begun: false,
        start_ns: None,
        source: paths.first().map(|p| p.to_path_buf()).unwrap_or_default(),
    };
    let mut total = StreamSummary {
        start_ns: 0,
        samples: [0; 4],
        warnings: Vec::new(),
    };
    // End of the joined session so far (its last joint sample; 0 before any).
    let mut end = 0.0;
    for (k, path) in paths.iter().enumerate() {
        // The shift is known at the part's first joint sample; batches before it wait.
        let mut offset: Option<f64> = (k == 0).then_some(0.0);
        let mut waiting: Vec<Recording> = Vec::new();
        let mut last_state: Option<f64> = None;
        let summary = stream_recording(path, map, opts, batch_samples, &mut |batch| {
            if let Some(&t) = batch.state.t.iter().max_by(|a, b| a.total_cmp(b)) {
                last_state = Some(last_state.map_or(t, |l: f64| l.max(t)));
            }
            if offset.is_none() {
                let Some(&t0) = batch.state.t.first() else {
                    waiting.push(batch.clone());
                    return Ok(());
                };
                offset = Some(end + gap_s - t0);
            }
            let off = offset.unwrap_or(0.0);
            for b in waiting.drain(..) {
                joined.batch(&b, off)?;
            }
            joined.batch(batch, off)
        })?;
        // A part without joint samples is shifted as if its first were at 0.
        let off = *offset.get_or_insert(end + gap_s);
        for b in waiting.drain(..) {
            joined.batch(&b, off)?;
        }
        if let Some(l) = last_state {
            end = l + off;
        }
        if k == 0 {
            total.start_ns = summary.start_ns;
        }
        for (t, s) in total.samples.iter_mut().zip(summary.samples) {
            *t += s;
        }
        total.warnings.extend(summary.warnings);
    }
    joined.sink.finish(&total, joined.begun)?;
    Ok(total)
}

/// The sink side of [`stream_joined_into`]: one header, every part's batches on the first
/// part's clock.
struct Joined<'s> {
    sink: &'s mut dyn RecordingSink,
    begun: bool,
    start_ns: Option<u64>,
    source: std::path::PathBuf,
}

impl Joined<'_> {
    fn batch(&mut self, b: &Recording, offset: f64) -> anyhow::Result<()> {
        let start_ns = *self.start_ns.get_or_insert(b.start_ns);
        if !self.begun {
            self.sink.begin(&StreamHeader {
                source: &self.source,
                start_ns,
                joint_names: &b.joint_names,
            })?;
            self.begun = true;
        }
        if offset == 0.0 && b.start_ns == start_ns {
            return self.sink.batch(b);
        }
        let mut shifted = Recording {
            start_ns,
            source: b.source.clone(),
            joint_names: b.joint_names.clone(),
            ..Recording::default()
        };
        shifted.append(b.clone(), offset);
        self.sink.batch(&shifted)
    }
}
