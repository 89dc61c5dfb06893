//! Rerun output: a recorded (or simulated) session as a Rerun recording — animated arm, joint
//! signals, power, and whatever identification/diagnosis add — written to an `.rrd` file or
//! streamed to a viewer.
//!
//! Determinism: everything we log goes through [`ChunkWriter`], which builds the Rerun chunks
//! itself with row and chunk ids derived from a counter (the SDK's own `log`/`send_columns` stamp
//! wall-clock ids and `log_time`). The recording id is derived from the input
//! ([`recording_id_for`]), the blueprint uses fixed ids ([`blueprint`]), and `.rrd` files are
//! encoded by our own sink ([`rrd_sink`]), which also replaces the random row id the SDK puts on
//! the store-info message. Two runs give byte-identical data sections (stream header and every
//! message, checked in tests/viz.rs); only the RRD footer differs, because the SDK builds its
//! per-store chunk manifests from `HashMap`s (store order and manifest column order vary).
//! The footer is an index the viewer can rebuild; decoded, the two files are equal.

mod blueprint;
mod layers;
mod overlay;
mod paths;
mod replay;
mod robot3d;
mod rrd_sink;
mod session;
mod slice;
mod style;

use crate::plot::data_range;
pub use blueprint::{Legend, Node, send_blueprint};
pub use layers::TrialMean;
pub use overlay::{diagnosis_extras, model_extras};
pub use replay::{
    DiagnosisOverlay, ImuFilterMarks, ModelSeries, ReadingPrediction, ReplayExtras, ReplayLogger,
    ReplayOptions, ReplaySummary, TermSeries, TrajectoryPoint, TrialMark, idle_baseline, layout,
    log_replay, replay_files_with,
};
pub use session::{
    DEFAULT_DIAGNOSIS_BYTES, DEFAULT_REPLAY_BYTES, Notice, SessionReplay, SizeEstimate, Window,
    replay_diagnosis, replay_session,
};
pub use slice::{Decimator, Slice};

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use rerun::external::re_log_types::external::re_tuid::Tuid;
use rerun::log::{Chunk, ChunkComponents, ChunkId, RowId};
use rerun::{AsComponents, RecordingStream, SerializedComponentColumn, TimeColumn};

/// Where a Rerun recording goes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Sink {
    /// Write an `.rrd` file (atomically: a temporary file beside it, renamed by [`VizStream::finish`]).
    Save(PathBuf),
    /// Stream to a running viewer; `None` = the default `rerun+http://127.0.0.1:9876/proxy`.
    Connect(Option<String>),
    /// Start a viewer (`rerun` on PATH, e.g. `pip install rerun-sdk==0.36.3`) and stream to it.
    Spawn {
        /// Viewer memory limit, e.g. `"2GB"` or `"25%"`; the viewer drops the oldest data beyond it.
        memory_limit: String,
    },
}

/// An open Rerun output. Call [`VizStream::finish`] when done: it flushes and, for
/// [`Sink::Save`], moves the finished file into place. Dropping it without `finish` leaves no
/// output file (the temporary file is removed).
pub struct VizStream {
    stream: RecordingStream,
    file: Option<rrd_sink::PendingFile>,
}

impl VizStream {
    /// The stream to log into.
    pub fn stream(&self) -> &RecordingStream {
        &self.stream
    }

    /// Flushes everything; for a saved file, writes the footer and renames the temporary file to
    /// the target. Errors (disk full, viewer gone) are reported here.
    pub fn finish(self) -> Result<()> {
        let VizStream { stream, file } = self;
        stream
            .flush_blocking()
            .context("flushing the Rerun stream")?;
        match file {
            Some(file) => {
                drop(stream);
                file.commit()
            }
            None => Ok(()),
        }
    }
}

/// Opens a Rerun output for application `app_id` with a fixed `recording_id` (see
/// [`recording_id_for`]). `inputs` are the files the recording is made from: saving onto one of
/// them is refused (canonical paths compared).
pub fn open_stream(
    app_id: &str,
    recording_id: &str,
    sink: &Sink,
    inputs: &[&Path],
) -> Result<VizStream> {
    let app = rerun::ApplicationId::try_new(app_id)
        .with_context(|| format!("invalid Rerun application id {app_id:?}"))?;
    // The recording's name, start time and properties are logged by the replay with
    // deterministic row ids, not by the SDK (wall-clock ids, and "now" as the start time).
    let builder = rerun::RecordingStreamBuilder::new(app)
        .recording_id(recording_id.to_owned())
        .send_properties(false);
    match sink {
        Sink::Save(path) => {
            crate::util::refuse_to_overwrite_inputs("Rerun output", path, inputs)?;
            let (sink, file) = rrd_sink::RrdFileSink::create(path)?;
            let (_enabled, store_info, _props, batcher, hooks, _blueprint) = builder.into_args();
            let stream = RecordingStream::new(store_info, None, batcher, hooks, Box::new(sink))
                .context("creating the Rerun recording stream")?;
            Ok(VizStream {
                stream,
                file: Some(file),
            })
        }
        Sink::Connect(url) => {
            let url = url
                .clone()
                .unwrap_or_else(|| rerun::DEFAULT_CONNECT_URL.to_owned());
            let stream = builder
                .connect_grpc_opts(url.clone())
                .with_context(|| format!("connecting to the Rerun viewer at {url}"))?;
            Ok(VizStream { stream, file: None })
        }
        Sink::Spawn { memory_limit } => {
            let opts = rerun::SpawnOptions {
                memory_limit: memory_limit.clone(),
                ..Default::default()
            };
            let stream = builder.spawn_opts(&opts).context(
                "starting the Rerun viewer (needs `rerun` on PATH: pip install rerun-sdk==0.36.3)",
            )?;
            Ok(VizStream { stream, file: None })
        }
    }
}

/// What an output shows. Each kind has its own application id (so its own default layout in
/// the viewer: a replay and a diagnosis opened together keep theirs) and its own recording id
/// for the same input (so they open side by side instead of merging into one recording).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputKind {
    /// `g1viz replay` without a model.
    Replay,
    /// `g1viz replay --model`.
    ModelReplay,
    /// `g1viz diagnose --save`.
    Diagnosis,
}

impl OutputKind {
    /// Lower-case tag: `replay`, `model`, `diagnosis`.
    pub fn tag(self) -> &'static str {
        match self {
            OutputKind::Replay => "replay",
            OutputKind::ModelReplay => "model",
            OutputKind::Diagnosis => "diagnosis",
        }
    }

    /// The Rerun application id of this kind of output (`g1viz-replay`, …).
    pub fn app_id(self) -> String {
        format!("g1viz-{}", self.tag())
    }

    /// The recording id of this kind of output made from the input with recording id `input_id`
    /// (see [`recording_id_for`] / [`recording_id_for_source`]).
    pub fn recording_id(self, input_id: &str) -> String {
        format!("{input_id}-{}", self.tag())
    }
}

/// Recording id derived from the input file (or bag directory): see [`recording_id_for_source`].
/// A recording that does not come from a readable file (synthetic, in tests and benchmarks) is
/// identified by its name, start time and sample count instead.
pub fn recording_id_for(rec: &crate::signals::Recording) -> String {
    if let Ok(id) = recording_id_for_source(&rec.source) {
        return id;
    }
    let name = rec.source.to_string_lossy();
    let h = crate::read::fingerprint::stable_hash(&[
        name.as_bytes(),
        &rec.start_ns.to_le_bytes(),
        &(rec.state.t.len() as u64).to_le_bytes(),
    ]);
    format!("g1viz-{h:016x}")
}

/// Recording id of the session at `path`, known before reading it (so a streamed replay can
/// open its output first): `g1viz-` and the session's [`crate::read::fingerprint::fingerprint`].
/// The same input gives the same id, so repeated runs produce comparable files, and a copied
/// file replays the same; an error names the path and the operating system's reason it cannot
/// be read.
pub fn recording_id_for_source(path: &Path) -> Result<String> {
    let id = crate::read::fingerprint::fingerprint(path).map(|h| format!("g1viz-{h:016x}"));
    id.ok_or_else(|| {
        let open = std::fs::metadata(path).and_then(|m| match m.is_dir() {
            true => std::fs::read_dir(path).map(drop),
            false => std::fs::File::open(path).map(drop),
        });
        match open {
            Err(e) => anyhow::anyhow!("cannot read {}: {e}", path.display()),
            Ok(()) => anyhow::anyhow!("cannot read {}", path.display()),
        }
    })
}

/// The two timelines every temporal row carries: `time` (absolute timestamp, the robot's clock:
/// `Recording::start_ns` + t) and `session` (duration since the start of the session, handy for
/// comparing sessions). Both are built from the same seconds-since-start values.
pub(crate) fn time_columns(start_ns: u64, t: &[f64]) -> [TimeColumn; 2] {
    let rel: Vec<i64> = t.iter().map(|&s| (s * 1e9).round() as i64).collect();
    let abs: Vec<i64> = rel
        .iter()
        .map(|&r| (start_ns as i64).saturating_add(r))
        .collect();
    [
        TimeColumn::new_timestamp_nanos_since_epoch("time", abs),
        TimeColumn::new_duration_nanos("session", rel),
    ]
}

/// Builds Rerun chunks with deterministic row and chunk ids and sends them to a stream.
///
/// Ids are `Tuid(session start, namespace + counter)`: their time part is the session's start
/// (what the viewer shows as the recording's "modified" time, instead of 1970), and every writer
/// on one stream gets its own `namespace` (a multiple of 2⁴⁸: replay, identify, diagnose…) so
/// their ids never collide.
pub struct ChunkWriter<'a> {
    stream: &'a RecordingStream,
    namespace: u64,
    counter: u64,
    start_ns: u64,
    /// The range [min, max] of the finite scalars logged on each entity path (what the
    /// plots are fitted to once everything is logged).
    ranges: std::collections::BTreeMap<String, [f64; 2]>,
}

impl<'a> ChunkWriter<'a> {
    /// A writer for the session starting at `start_ns` (the timeline origin).
    pub fn new(stream: &'a RecordingStream, namespace: u64, start_ns: u64) -> Self {
        ChunkWriter {
            stream,
            namespace,
            counter: 0,
            start_ns,
            ranges: Default::default(),
        }
    }

    /// The stream this writer logs into.
    pub fn stream(&self) -> &'a RecordingStream {
        self.stream
    }

    /// Widens the range of the scalars logged on `path` to hold `values`.
    pub fn note_values(&mut self, path: &str, values: &[f64]) {
        let Some([lo, hi]) = data_range(values.iter().copied()) else {
            return;
        };
        match self.ranges.get_mut(path) {
            Some(r) => *r = [r[0].min(lo), r[1].max(hi)],
            None => {
                self.ranges.insert(path.to_owned(), [lo, hi]);
            }
        }
    }

    /// The range [min, max] of the scalars logged so far on the entity paths blueprint queries
    /// `queries` take in (`origin`: the view's origin, used when `queries` is empty or names
    /// `$origin`); `None` when nothing was logged there.
    pub fn range_of(&self, queries: &[String], origin: &str) -> Option<[f64; 2]> {
        let default = ["$origin/**".to_owned()];
        let queries = if queries.is_empty() {
            &default[..]
        } else {
            queries
        };
        let included = |p: &str| {
            queries
                .iter()
                .any(|q| blueprint::query_includes(q, origin, p))
        };
        data_range(
            self.ranges
                .iter()
                .filter(|(p, _)| included(p))
                .flat_map(|(_, r)| *r),
        )
    }

    fn next_tuid(&mut self) -> Tuid {
        self.counter += 1;
        Tuid::from_nanos_and_inc(self.start_ns, self.namespace.wrapping_add(self.counter))
    }

    fn row_ids(&mut self, n: usize) -> Vec<RowId> {
        (0..n).map(|_| RowId::from_tuid(self.next_tuid())).collect()
    }

    /// Sends `n` rows at times `t` [s since start] on `path`; `columns` must have `t.len()` rows.
    pub fn send_columns(
        &mut self,
        path: &str,
        t: &[f64],
        columns: impl IntoIterator<Item = SerializedComponentColumn>,
    ) -> Result<()> {
        let chunk_id = ChunkId::from_tuid(self.next_tuid());
        let row_ids = self.row_ids(t.len());
        let timelines = time_columns(self.start_ns, t)
            .into_iter()
            .map(|c| (*c.timeline().name(), c))
            .collect();
        let components: ChunkComponents = columns
            .into_iter()
            .map(|c| (c.descriptor, c.list_array))
            .collect();
        let chunk = Chunk::from_native_row_ids(
            chunk_id,
            path.into(),
            None,
            &row_ids,
            timelines,
            components,
        )
        .with_context(|| format!("building the Rerun chunk for {path}"))?;
        self.stream.send_chunk(chunk);
        Ok(())
    }

    /// Sends one row of `data` on `path` at time `t` [s since start].
    pub fn send_row(&mut self, path: &str, t: f64, data: &dyn AsComponents) -> Result<()> {
        let columns = data
            .as_serialized_batches()
            .into_iter()
            .map(|b| b.partitioned([1]))
            .collect::<Result<Vec<_>, _>>()?;
        self.send_columns(path, &[t], columns)
    }

    /// Waits until everything sent so far has reached the sink (bounds the memory of a fast
    /// producer, e.g. the model series of a streamed replay).
    pub fn flush(&self) -> Result<()> {
        self.stream
            .flush_blocking()
            .context("writing the recording")
    }

    /// Sends `data` as static (timeless) on `path`.
    pub fn send_static(&mut self, path: &str, data: &dyn AsComponents) -> Result<()> {
        let chunk_id = ChunkId::from_tuid(self.next_tuid());
        let row_id = RowId::from_tuid(self.next_tuid());
        let chunk = one_row((chunk_id, row_id), path, Default::default(), data)?;
        self.stream.send_chunk(chunk);
        Ok(())
    }
}

/// A chunk of one sorted row of `data` (whole, [`whole_row`]) on `path` with the given ids, at
/// `timelines` (none: static).
fn one_row(
    (chunk_id, row_id): (ChunkId, RowId),
    path: &str,
    timelines: rerun::external::nohash_hasher::IntMap<rerun::TimelineName, TimeColumn>,
    data: &dyn AsComponents,
) -> Result<Chunk> {
    let components = whole_row(data)?;
    Chunk::from_native_row_ids(
        chunk_id,
        path.into(),
        Some(true),
        &[row_id],
        timelines,
        components,
    )
    .with_context(|| format!("building the Rerun chunk for {path}"))
}

/// `data` as one row holding each component's whole batch: the row's length must be the batch's
/// length (`partitioned` does not check it; `[1]` silently keeps only the first element, e.g.
/// one bar of a bar chart's widths or a container's first child).
fn whole_row(data: &dyn AsComponents) -> Result<ChunkComponents> {
    let components = data.as_serialized_batches().into_iter().map(|b| {
        let n = b.array.len();
        b.partitioned([n]).map(|c| (c.descriptor, c.list_array))
    });
    Ok(components.collect::<Result<_, _>>()?)
}

/// Short, path-friendly joint name: side prefix and `_joint` dropped, `shoulder` → `sh`,
/// `wrist` → `wr` (`left_shoulder_pitch_joint` → `sh_pitch`); anything else kept, with characters
/// that are not `[A-Za-z0-9_]` replaced by `_`.
pub fn short_joint_name(urdf_name: &str) -> String {
    let mut s = urdf_name;
    for prefix in ["left_", "right_"] {
        if let Some(rest) = s.strip_prefix(prefix) {
            s = rest;
        }
    }
    let s = s.strip_suffix("_joint").unwrap_or(s);
    path_safe(&s.replace("shoulder", "sh").replace("wrist", "wr"), "_")
}

/// `s` with every character that is neither ASCII alphanumeric nor one of `keep` replaced by `_`.
fn path_safe(s: &str, keep: &str) -> String {
    let safe = |c: char| c.is_ascii_alphanumeric() || keep.contains(c);
    s.chars().map(|c| if safe(c) { c } else { '_' }).collect()
}
