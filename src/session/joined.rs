//! Session files joined end to end on one clock (each part starts a gap after the previous
//! part's last joint sample), read trial by trial: the trials of every part carry indices
//! counted over all files and times on the joined clock.

use anyhow::Result;

use super::{FileTrials, SessionFile, TrialSource};
use crate::signals::Recording;
use crate::trial::TrialWindow;

/// One file of a [`Joined`] session and where its trials lie on the joined clock.
pub(crate) struct JoinedPart {
    pub file: SessionFile,
    /// Its trials on its own clock.
    pub local: Vec<TrialWindow>,
    /// Index (on the joined list) of its first trial.
    pub first: usize,
    /// Shift of its times on the joined clock [s].
    pub offset_s: f64,
    /// Its own clock's origin (that of its segmentation pass), no power series.
    pub clock: Recording,
}

impl JoinedPart {
    /// Its trial `w` (on its own clock, local index `j`) on the joined clock.
    pub(crate) fn global(&self, w: &TrialWindow, j: usize) -> TrialWindow {
        global(w, self.offset_s, self.first + j)
    }
}

/// Session files joined end to end on one clock.
pub(crate) struct Joined {
    pub parts: Vec<JoinedPart>,
}

impl TrialSource for Joined {
    fn for_each(
        &mut self,
        trials: &[TrialWindow],
        f: &mut dyn FnMut(&Recording, &TrialWindow) -> Result<()>,
    ) -> Result<()> {
        for part in &self.parts {
            let range = part.first..part.first + part.local.len();
            let mine: Vec<&TrialWindow> =
                trials.iter().filter(|t| range.contains(&t.index)).collect();
            if mine.is_empty() {
                continue;
            }
            let local: Vec<TrialWindow> = mine
                .iter()
                .map(|t| part.local[t.index - part.first].clone())
                .collect();
            let mut k = 0usize;
            let mut source = FileTrials {
                file: part.file.clone(),
                clock: part.clock.clone(),
            };
            source.for_each(&local, &mut |buf, _| {
                let g = mine[k];
                k += 1;
                if part.offset_s != 0.0 {
                    f(&shift(buf, part.offset_s), g)
                } else {
                    f(buf, g)
                }
            })?;
        }
        Ok(())
    }
}

/// A trial window of a part moved onto the joined clock, with its joined index.
pub(crate) fn global(w: &TrialWindow, off: f64, index: usize) -> TrialWindow {
    TrialWindow {
        index,
        t_pre_start: w.t_pre_start + off,
        t_traj_start: w.t_traj_start + off,
        t_traj_end: w.t_traj_end + off,
        t_post_end: w.t_post_end + off,
        t_return_end: w.t_return_end + off,
        ..w.clone()
    }
}

/// The joint states of `rec` with their times shifted by `off` (a part of joined files).
pub(crate) fn shift(rec: &Recording, off: f64) -> Recording {
    let mut out = Recording {
        state: rec.state.clone(),
        ..Recording::default()
    };
    out.state.t.iter_mut().for_each(|t| *t += off);
    out
}
