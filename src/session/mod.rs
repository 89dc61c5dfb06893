//! A session's trials, read trial by trial in bounded memory: the one way every command reads
//! trials (identify, validate, diagnose, replay, the row export).
//!
//! * [`segment_file`] / the segmentation pass (`segment.rs`) reads a file once, piece by piece:
//!   the trials with their IMU statistic σ_ω, the whole power series (~1 Hz), the sensor-timing
//!   search's held trials, and a spill of the joint states to a temporary file.
//! * A [`TrialSource`] then hands each of a list of trials, in time order, a recording holding at
//!   least that trial's samples (pre-idle start − [`MARGIN_S`] to the later of its post-idle and
//!   return end): [`Memory`] (a whole recording in memory), [`FileTrials`] (one file, from its
//!   spill or, without one, a ranged read of the file) and [`Joined`] (files end to end on one
//!   clock). The stages after the source are one code path whatever it is.
//! * [`TrialWalk`] hands over trials as a session's batches go by (a streamed replay's model
//!   series); [`for_each_trial_with_batches`] walks the whole session once more with
//!   one (from the spill when there is one), showing every batch too.

mod joined;
mod segment;
mod walk;

use std::path::PathBuf;

use anyhow::{Context, Result};

use crate::read::OpenOptions;
use crate::signals::{Recording, SignalMap, SpillSlot};
use crate::trial::TrialWindow;

pub(crate) use joined::{Joined, JoinedPart, global, shift};
pub use segment::segment_file;
pub(crate) use segment::{Pass1, copy_window, segment_recording, segmentation_pass};
pub(crate) use walk::hold_pass;
pub use walk::{TrialWalk, for_each_trial_with_batches};

/// Default of the identification's `search_trials` and of [`StreamOptions::hold_trials`]: the
/// timing search's cost grows with its trials, and ~300 trials pin the window and lag to the fine
/// grid's 25 ms step.
pub const SEARCH_TRIALS: usize = 300;

/// The timing search's trial stride: the smallest power of two `s` for which every `s`-th trial
/// (by index, from trial 0) of every session, `counts[i]` trials in session i, is at most `cap`
/// trials. A power of two, so that a session's first pass can keep a bounded set while it does not
/// yet know its length — every `s'`-th trial, doubling `s'` whenever the set outgrows its cap —
/// and still hold the search's trials whenever its cap is at least `cap`
/// ([`StreamOptions::hold_trials`]).
pub fn search_stride(counts: &[usize], cap: usize) -> usize {
    let cap = cap.max(1);
    let mut s = 1usize;
    while counts.iter().map(|n| n.div_ceil(s)).sum::<usize>() > cap {
        s *= 2;
    }
    s
}

/// Tuning of the streamed read.
#[derive(Debug, Clone, Copy)]
pub struct StreamOptions {
    /// Length of the pieces the segmentation pass buffers [s] (a session shorter than this is
    /// segmented in one piece, exactly as in memory).
    pub chunk_s: f64,
    /// Most trials whose joint states pass 1 holds for the sensor-timing search (every n-th,
    /// n a power of two). At or above the identification's `search_trials` they
    /// include the search's trials; below it the search's trials are read in an extra pass.
    pub hold_trials: usize,
    /// Samples per decoded batch.
    pub batch_samples: usize,
    /// Whether the segmentation pass keeps the session's joint states in a temporary file
    /// (about 150 bytes per sample) for the passes after it ([`SessionFile::spill`]): they then
    /// read no more of the recording than those samples, bit for bit the same.
    pub spill_states: bool,
}

impl Default for StreamOptions {
    fn default() -> Self {
        StreamOptions {
            chunk_s: 300.0,
            hold_trials: SEARCH_TRIALS,
            batch_samples: 4096,
            spill_states: true,
        }
    }
}

/// A session file and how to read it.
#[derive(Debug, Clone)]
pub struct SessionFile {
    /// File or bag folder.
    pub path: PathBuf,
    /// Topics and fields of the arm signals.
    pub map: SignalMap,
    /// Reader options (message definitions).
    pub read: OpenOptions,
    /// The joint states the first full pass spilled to a temporary file
    /// ([`StreamOptions::spill_states`]); the passes after it read their trials' samples from
    /// there. Empty (`Default`): every pass reads the file. Shared by clones.
    pub spill: SpillSlot,
}

/// Margin around a trial's window whose samples are kept [s] (rows only read inside it).
pub(crate) const MARGIN_S: f64 = 0.5;

/// A source of each trial's samples.
pub(crate) trait TrialSource {
    /// Call `f` for each of `trials` (in time order) with a recording whose joint states (all
    /// columns) cover at least the trial's window, pre-idle start − [`MARGIN_S`] to the later of
    /// its post-idle and return end, on the session's clock, with the power series.
    fn for_each(
        &mut self,
        trials: &[TrialWindow],
        f: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
    ) -> Result<()>;
}

/// `rec` without its joint states and commands: its clock, joint names and power series.
pub(crate) fn clock_of(rec: &Recording) -> Recording {
    Recording {
        source: rec.source.clone(),
        start_ns: rec.start_ns,
        joint_names: rec.joint_names.clone(),
        mbs: rec.mbs.clone(),
        bms: rec.bms.clone(),
        ..Recording::default()
    }
}

/// A whole recording in memory: every trial sees all of it.
pub(crate) struct Memory<'a>(pub &'a Recording);

impl TrialSource for Memory<'_> {
    fn for_each(
        &mut self,
        trials: &[TrialWindow],
        f: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
    ) -> Result<()> {
        trials.iter().try_for_each(|t| f(self.0, t))
    }
}

/// One session file read trial by trial: from its spill when the segmentation pass made one on
/// this clock, else by a read of the file limited to the trials' windows (an indexed MCAP skips
/// the chunks between them). Holds about one trial's samples at a time.
pub(crate) struct FileTrials {
    pub file: SessionFile,
    /// The clock (`start_ns`, that of the segmentation pass) and the power series every trial's
    /// recording carries (empty when the caller needs joint states only).
    pub clock: Recording,
}

impl TrialSource for FileTrials {
    fn for_each(
        &mut self,
        trials: &[TrialWindow],
        f: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
    ) -> Result<()> {
        walk::trial_windows(&self.file, &self.clock, trials, f)
            .with_context(|| format!("reading {}", self.file.path.display()))
    }
}
