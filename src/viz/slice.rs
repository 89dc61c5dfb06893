//! Replaying part of a session: a time window in session seconds (`replay --from/--to`, or the
//! window of `--trials A-B`) and a rate cap for the series (`--max-rate`). Times stay relative to
//! the session start, so a slice lines up with the full replay on the `session` timeline.

use crate::signals::Recording;

use super::replay::{ImuFilterMarks, ReadingPrediction, ReplayExtras, TermSeries};

/// Which part of a session a replay logs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Slice {
    /// Start of the window [s since the session start].
    pub from_s: f64,
    /// End of the window [s] (inclusive).
    pub to_s: f64,
    /// At most this many samples per second of every per-sample series (`None`: all).
    pub max_rate_hz: Option<f64>,
}

impl Default for Slice {
    fn default() -> Self {
        Slice {
            from_s: f64::NEG_INFINITY,
            to_s: f64::INFINITY,
            max_rate_hz: None,
        }
    }
}

/// Keeps the first sample of each `1 / rate`-second bin of a series (carried across batches):
/// at most `rate` samples per second, evenly spread, whatever the jitter of the stamps.
#[derive(Debug, Clone, Copy)]
pub struct Decimator {
    last_bin: f64,
}

impl Default for Decimator {
    fn default() -> Self {
        Decimator {
            last_bin: f64::NEG_INFINITY,
        }
    }
}

impl Slice {
    /// Whether this slice logs everything (no window, no rate cap).
    pub fn is_all(&self) -> bool {
        *self == Slice::default()
    }

    /// Whether `t` lies in the window.
    pub fn contains(&self, t: f64) -> bool {
        t >= self.from_s && t <= self.to_s
    }

    /// Indices of the samples at `t` that are in the window and, with a rate cap, the first of
    /// their `1 / max_rate_hz` bin (`dec` carries the last bin across batches).
    pub fn keep(&self, t: &[f64], dec: &mut Decimator) -> Vec<usize> {
        let rate = self.max_rate_hz.filter(|r| *r > 0.0);
        let mut out = Vec::new();
        for (i, &ti) in t.iter().enumerate() {
            if !self.contains(ti) {
                continue;
            }
            if let Some(rate) = rate {
                let bin = (ti * rate).floor();
                if bin <= dec.last_bin {
                    continue;
                }
                dec.last_bin = bin;
            }
            out.push(i);
        }
        out
    }

    /// The state and command samples of `part` this slice logs (no power readings: the replay
    /// keeps them all for the idle baseline and logs those in the window).
    pub fn recording(
        &self,
        part: &Recording,
        state: &mut Decimator,
        cmd: &mut Decimator,
    ) -> Recording {
        let (s, c) = (&part.state, &part.command);
        let mut keep = vec![false; s.t.len()];
        self.keep(&s.t, state)
            .into_iter()
            .for_each(|i| keep[i] = true);
        let kc = self.keep(&c.t, cmd);
        Recording {
            source: part.source.clone(),
            start_ns: part.start_ns,
            joint_names: part.joint_names.clone(),
            state: s.select(&keep),
            command: crate::signals::CommandSeries {
                t: pick(&c.t, &kc),
                q: pick(&c.q, &kc),
                dq: pick(&c.dq, &kc),
            },
            ..Recording::default()
        }
    }

    /// What `extras` hold inside the window (the model's per-sample series are sliced as they
    /// are logged). Trials are kept when they overlap the window.
    pub fn extras(&self, e: &ReplayExtras) -> ReplayExtras {
        let all = Slice {
            max_rate_hz: None,
            ..*self
        };
        let ReplayExtras {
            model,
            readings,
            trajectories,
            trials,
            imu_filter,
            diagnosis,
        } = e;
        ReplayExtras {
            model: model.clone(),
            readings: readings.as_ref().map(|r| {
                let k = all.keep(&r.t, &mut Decimator::default());
                ReadingPrediction {
                    t: pick(&r.t, &k),
                    trial: pick(&r.trial, &k),
                    measured: pick(&r.measured, &k),
                    predicted: pick(&r.predicted, &k),
                    rejected: pick(&r.rejected, &k),
                    ..r.clone()
                }
            }),
            trajectories: trajectories
                .iter()
                .filter(|p| self.contains(p.t))
                .cloned()
                .collect(),
            trials: trials
                .iter()
                .filter(|m| self.overlaps(m.t_start, m.t_end))
                .cloned()
                .collect(),
            imu_filter: imu_filter.as_ref().map(|f| ImuFilterMarks {
                spans: f
                    .spans
                    .iter()
                    .filter(|s| self.overlaps(s.0, s.1))
                    .copied()
                    .collect(),
                ..*f
            }),
            // Per reading, as `diagnose --save` streams it: left whole.
            diagnosis: diagnosis.clone(),
        }
    }

    /// Whether [a, b] overlaps the window.
    pub fn overlaps(&self, a: f64, b: f64) -> bool {
        b >= self.from_s && a <= self.to_s
    }
}

/// The elements of `v` at `k` (indices past its end skipped).
fn pick<T: Clone>(v: &[T], k: &[usize]) -> Vec<T> {
    k.iter().filter_map(|&i| v.get(i).cloned()).collect()
}

impl TermSeries {
    /// The samples at `k`.
    pub(super) fn pick(&self, k: &[usize]) -> TermSeries {
        TermSeries {
            t: pick(&self.t, k),
            predicted: pick(&self.predicted, k),
            per_joint: self.per_joint.each_ref().map(|f| pick(f, k)),
            interaction: pick(&self.interaction, k),
        }
    }
}
