//! Re-running a recording through the twin streamed from its file ([`simulate_like_file`]): the
//! same twin as [`super::simulate_like`] of the loaded recording, in memory bounded by the
//! message stamps (16 bytes per joint-state sample) instead of the whole recording.
//!
//! Two passes: the first reads every message's stamp (the twin's timeline) and checks the joint
//! states for clock jumps; the second, on a reader thread, hands the reference trajectory (the
//! command, or the measured states without one) to the engine as it reaches it, keeping only a
//! sliding window of it.

use std::cell::RefCell;
use std::path::Path;
use std::sync::mpsc::{Receiver, sync_channel};

use anyhow::{Context, Result};

use super::plant::{Engine, Motion, Reference, Sampled, Timeline};
use super::{MAX_LIKE_GAP_S, SimConfig, Truth};
use crate::read::OpenOptions;
use crate::signals::{Recording, SignalMap, load_recording, stream_recording};

/// Samples per batch handed from the reader thread.
const BATCH_SAMPLES: usize = 20_000;

/// Reference samples kept behind the latest query [s]: the engine queries at most the tracking
/// lag (tens of ms) behind its clock.
const RETAIN_S: f64 = 60.0;

/// [`super::simulate_like`] of the recording at `path`, streamed: the same twin, byte for byte,
/// without loading the recording. A file whose messages are not in time order (an unindexed file
/// written out of order) is loaded instead. Returns the truth and the reader's warnings.
pub fn simulate_like_file(
    path: &Path,
    map: &SignalMap,
    opts: &OpenOptions,
    cfg: &SimConfig,
    out: &Path,
) -> Result<(Truth, Vec<String>)> {
    let stamps = read_stamps(path, map, opts)?;
    if !stamps.in_order {
        let rec = load_recording(path, map, opts)?;
        let warnings = rec.warnings.clone();
        return Ok((super::simulate_like(&rec, cfg, out)?, warnings));
    }
    anyhow::ensure!(
        !stamps.timeline.lowstate.is_empty(),
        "{}: the recording has no joint states to re-run",
        path.display()
    );
    if let Some((k, gap, t)) = stamps.worst_gap.filter(|g| g.1 > MAX_LIKE_GAP_S) {
        anyhow::bail!(
            "{}: joint states jump by {gap:.0} s after sample {k} (t = {t:.3} s): a bad timestamp or a clock reset; cut the recording there before re-running it",
            path.display()
        );
    }
    let commanded = !stamps.timeline.arm_sdk.is_empty();
    let lag = if commanded { cfg.tracking_lag_s } else { 0.0 };
    let cfg_like = SimConfig {
        tracking_lag_s: lag,
        ..cfg.clone()
    };
    let (dyn_true, dyn_urdf) = super::dynamics(&cfg_like)?;
    let (tx, rx) = sync_channel::<Sampled>(2);
    std::thread::scope(|scope| {
        let reader = scope.spawn(move || {
            stream_recording(path, map, opts, BATCH_SAMPLES, &mut |b: &Recording| {
                let s = if commanded {
                    Sampled {
                        t: b.command.t.clone(),
                        q: b.command.q.clone(),
                        dq: b.command.dq.clone(),
                    }
                } else {
                    Sampled {
                        t: b.state.t.clone(),
                        q: b.state.q.clone(),
                        dq: b.state.dq.clone(),
                    }
                };
                // The twin is done with the trajectory (or failed): stop reading.
                tx.send(s).map_err(|_| anyhow::Error::new(TwinStopped))
            })
        });
        let run = {
            let reference = StreamedSampled::new(rx);
            let engine = Engine {
                cfg: &cfg_like,
                dyn_true: &dyn_true,
                dyn_urdf: dyn_urdf.as_ref(),
                friction: &cfg.friction,
                timeline: &stamps.timeline,
                reference: Reference::Streamed(&reference),
                trials: &[],
                artefacts: &[],
            };
            super::run_like(&cfg_like, &engine, out)
            // The reference (the channel's receiver) is dropped here: a reader blocked on a
            // full channel returns.
        };
        let read = reader
            .join()
            .map_err(|_| anyhow::anyhow!("the reader thread panicked"))?;
        let truth = run?;
        match read {
            Err(e) if e.chain().any(|c| c.is::<TwinStopped>()) => {}
            r => {
                r.with_context(|| format!("reading {} a second time", path.display()))?;
            }
        }
        Ok((truth, stamps.warnings))
    })
}

/// The reader's stop when the twin no longer takes the trajectory (not an error of the read).
#[derive(Debug)]
struct TwinStopped;

impl std::fmt::Display for TwinStopped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("the twin stopped taking the trajectory")
    }
}

impl std::error::Error for TwinStopped {}

/// What the first pass keeps: every message's stamp, the joint states' largest gap.
struct Stamps {
    timeline: Timeline,
    /// (sample index, gap [s], time [s]) of the largest gap between joint states.
    worst_gap: Option<(usize, f64, f64)>,
    /// Whether every group's times came non-decreasing and non-negative (as one loaded batch
    /// would order them).
    in_order: bool,
    warnings: Vec<String>,
}

fn read_stamps(path: &Path, map: &SignalMap, opts: &OpenOptions) -> Result<Stamps> {
    let mut tl = Timeline {
        start_ns: 0,
        lowstate: Vec::new(),
        arm_sdk: Vec::new(),
        mbs: Vec::new(),
        bms: Vec::new(),
    };
    let mut last = [f64::NEG_INFINITY; 4];
    let mut in_order = true;
    let mut worst_gap: Option<(usize, f64, f64)> = None;
    let mut start_ns = None;
    let summary = stream_recording(path, map, opts, BATCH_SAMPLES, &mut |b: &Recording| {
        let start = *start_ns.get_or_insert(b.start_ns);
        let to_ns = |t: &f64| (start as i128 + (t * 1e9).round() as i128).max(0) as u64;
        let groups: [(&[f64], &mut Vec<u64>); 4] = [
            (&b.state.t, &mut tl.lowstate),
            (&b.command.t, &mut tl.arm_sdk),
            (&b.mbs.t, &mut tl.mbs),
            (&b.bms.t, &mut tl.bms),
        ];
        for (g, (t, ns)) in groups.into_iter().enumerate() {
            for &x in t {
                if g == 0 && last[0].is_finite() {
                    let gap = x - last[0];
                    if worst_gap.is_none_or(|w| gap >= w.1) {
                        worst_gap = Some((ns.len() - 1, gap, last[0]));
                    }
                }
                in_order &= x >= last[g] && x >= 0.0;
                last[g] = x;
                ns.push(to_ns(&x));
            }
        }
        Ok(())
    })?;
    tl.start_ns = start_ns.unwrap_or(summary.start_ns);
    Ok(Stamps {
        timeline: tl,
        worst_gap,
        in_order,
        warnings: summary.warnings,
    })
}

/// A sampled reference read from a channel as queries reach it: a window of
/// [`Sampled`] samples, indexed globally (`base` is the global index of the window's first).
pub struct StreamedSampled {
    inner: RefCell<Window>,
}

struct Window {
    /// Window length past which old samples are dropped.
    trim_at: usize,
    base: usize,
    s: Sampled,
    rx: Receiver<Sampled>,
    done: bool,
    latest: f64,
}

impl StreamedSampled {
    fn new(rx: Receiver<Sampled>) -> Self {
        Self {
            inner: RefCell::new(Window {
                trim_at: 4 * BATCH_SAMPLES,
                base: 0,
                s: Sampled::default(),
                rx,
                done: false,
                latest: f64::NEG_INFINITY,
            }),
        }
    }

    /// [`Sampled::eval`] of the whole trajectory at `t` (`hint` a global cursor), for queries
    /// that move forward in time (up to [`RETAIN_S`] back).
    pub fn eval(&self, t: f64, hint: &mut usize) -> Motion {
        let mut w = self.inner.borrow_mut();
        w.latest = w.latest.max(t);
        // Every sample at or before t is in the window once one after it is (or none is left).
        while !w.done && w.s.t.last().is_none_or(|&l| l <= t) {
            match w.rx.recv() {
                Ok(b) => {
                    w.s.t.extend(b.t);
                    w.s.q.extend(b.q);
                    w.s.dq.extend(b.dq);
                }
                Err(_) => w.done = true,
            }
        }
        w.trim();
        let base = w.base;
        let mut local = hint.saturating_sub(base);
        let r = w.s.eval(t, &mut local);
        *hint = base + local;
        r
    }
}

impl Window {
    /// Drop the samples more than [`RETAIN_S`] behind the latest query, once there are many.
    fn trim(&mut self) {
        if self.s.t.len() < self.trim_at {
            return;
        }
        let keep_from = self.latest - RETAIN_S;
        let cut = self.s.t.partition_point(|&x| x < keep_from);
        if cut > 0 {
            self.s.t.drain(..cut);
            self.s.q.drain(..cut);
            self.s.dq.drain(..cut);
            self.base += cut;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The streamed window answers every query exactly as the whole trajectory does, also
    /// after it has dropped samples behind the queries (small batches, a small trim threshold)
    /// and with two cursors a lag apart, as the engine queries it.
    #[test]
    fn the_window_evaluates_like_the_whole_trajectory() {
        let n = 5_000;
        let mut whole = Sampled::default();
        let mut t = 0.0;
        for k in 0..n {
            // Uneven steps, a repeated stamp now and then.
            t += if k % 97 == 0 {
                0.0
            } else {
                0.01 + 0.003 * ((k % 7) as f64)
            };
            let x = k as f64;
            whole.t.push(t);
            whole
                .q
                .push(std::array::from_fn(|j| (x * 0.01 + j as f64).sin()));
            whole
                .dq
                .push(std::array::from_fn(|j| (x * 0.013 - j as f64).cos()));
        }
        let (tx, rx) = sync_channel::<Sampled>(n);
        for c in (0..n).step_by(37) {
            let e = (c + 37).min(n);
            tx.send(Sampled {
                t: whole.t[c..e].to_vec(),
                q: whole.q[c..e].to_vec(),
                dq: whole.dq[c..e].to_vec(),
            })
            .unwrap();
        }
        drop(tx);
        let streamed = StreamedSampled::new(rx);
        streamed.inner.borrow_mut().trim_at = 200;
        let (mut h_whole, mut h_streamed) = ([0usize; 2], [0usize; 2]);
        let mut q = -0.5;
        let mut trimmed = false;
        while q < t + 1.0 {
            for (c, lag) in [0.0, 0.03].into_iter().enumerate() {
                let a = whole.eval(q - lag, &mut h_whole[c]);
                let b = streamed.eval(q - lag, &mut h_streamed[c]);
                assert_eq!(a, b, "at t = {q} (lag {lag})");
                assert_eq!(h_whole[c], h_streamed[c], "cursor at t = {q}");
            }
            trimmed |= streamed.inner.borrow().base > 0;
            q += 0.0123;
        }
        assert!(trimmed, "the window never dropped a sample");
    }
}
