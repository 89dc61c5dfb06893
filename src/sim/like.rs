//! Re-running a recording through the twin, loaded ([`simulate_like`]) or streamed from its file
//! ([`simulate_like_file`], in memory bounded by the message stamps, 16 bytes per joint-state
//! sample, instead of the whole recording): one path for both.
//!
//! The stamps of every message make the twin's timeline, checked for clock jumps; then a reader
//! thread hands the reference trajectory (the command, or the measured states without one) to
//! the engine as it reaches it, batch by batch (the loaded recording is one batch), keeping only
//! a sliding window of it.

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

/// [`simulate_like`] of the recording at `path`, streamed: the same twin, byte for byte,
/// without loading the recording. A file whose messages are not in time order (an unindexed file
/// written out of order) is loaded instead. Returns the truth and the reader's warnings.
pub fn simulate_like_file(
    path: &Path,
    map: &SignalMap,
    opts: &OpenOptions,
    cfg: &SimConfig,
    out: &Path,
) -> Result<(Truth, Vec<String>)> {
    let mut stamps = Stamps::default();
    let summary = stream_recording(path, map, opts, BATCH_SAMPLES, &mut |b: &Recording| {
        stamps.add(b);
        Ok(())
    })?;
    if stamps.out_of_order {
        let rec = load_recording(path, map, opts)?;
        return Ok((simulate_like(&rec, cfg, out)?, rec.warnings));
    }
    stamps.timeline.start_ns = stamps.start_ns.unwrap_or(summary.start_ns);
    let truth = run_twin(path, &stamps, cfg, out, &|emit| {
        stream_recording(path, map, opts, BATCH_SAMPLES, emit).map(|_| ())
    })?;
    Ok((truth, summary.warnings))
}

/// Re-run a recording's trajectory through the twin on the same timeline (same start and message
/// times): the commanded `/arm_sdk` trajectory when the recording has one (the twin's arm then lags
/// it like the robot's), otherwise the measured one (no extra lag). Artefacts tied to trials
/// (contamination, outliers) are not added: the recording's trials are not known here.
pub fn simulate_like(rec: &Recording, cfg: &SimConfig, out: &Path) -> Result<Truth> {
    let mut stamps = Stamps::default();
    stamps.add(rec);
    stamps.timeline.start_ns = rec.start_ns;
    run_twin(&rec.source, &stamps, cfg, out, &|emit| emit(rec))
}

/// Hands a recording's batches, in time order, to the callback.
type ReadBatches<'a> = dyn Fn(&mut dyn FnMut(&Recording) -> Result<()>) -> Result<()> + Sync + 'a;

/// The twin on the timeline `stamps` of the recording `source`, its reference trajectory handed
/// over batch by batch by `read` (on a reader thread) as the engine reaches it.
fn run_twin(
    source: &Path,
    stamps: &Stamps,
    cfg: &SimConfig,
    out: &Path,
    read: &ReadBatches<'_>,
) -> Result<Truth> {
    super::check_config(cfg)?;
    anyhow::ensure!(
        !stamps.timeline.lowstate.is_empty(),
        "{}: the recording has no joint states to re-run",
        source.display()
    );
    // A clock jump (one message stamped at 0, a reset) would make the twin simulate the gap.
    if let Some((k, gap, t)) = stamps.worst_gap.filter(|g| g.1 > MAX_LIKE_GAP_S) {
        anyhow::bail!(
            "{}: joint states jump by {gap:.0} s after sample {k} (t = {t:.3} s): a bad timestamp or a clock reset; cut the recording there before re-running it",
            source.display()
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
            read(&mut |b: &Recording| {
                let (c, m) = (&b.command, &b.state);
                let (t, q, dq) = match commanded {
                    true => (&c.t, &c.q, &c.dq),
                    false => (&m.t, &m.q, &m.dq),
                };
                let (t, q, dq) = (t.clone(), q.clone(), dq.clone());
                let s = Sampled { t, q, dq };
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
                r.with_context(|| format!("reading {} a second time", source.display()))?;
            }
        }
        Ok(truth)
    })
}

/// The reader's stop when the twin no longer takes the trajectory (not an error of the read).
#[derive(Debug, thiserror::Error)]
#[error("the twin stopped taking the trajectory")]
struct TwinStopped;

/// What the first pass keeps: every message's stamp, the joint states' largest gap.
#[derive(Default)]
struct Stamps {
    timeline: Timeline,
    /// (sample index, gap [s], time [s]) of the largest gap between joint states.
    worst_gap: Option<(usize, f64, f64)>,
    /// Whether some group's times went backwards or below zero (one loaded batch would have
    /// been ordered).
    out_of_order: bool,
    /// The first batch's start.
    start_ns: Option<u64>,
    /// Each group's latest time [s].
    last: [Option<f64>; 4],
}

impl Stamps {
    /// Take the stamps of the next batch of the recording.
    fn add(&mut self, b: &Recording) {
        let start = *self.start_ns.get_or_insert(b.start_ns);
        let to_ns = |t: &f64| (start as i128 + (t * 1e9).round() as i128).max(0) as u64;
        let tl = &mut self.timeline;
        let groups: [(&[f64], &mut Vec<u64>); 4] = [
            (&b.state.t, &mut tl.lowstate),
            (&b.command.t, &mut tl.arm_sdk),
            (&b.mbs.t, &mut tl.mbs),
            (&b.bms.t, &mut tl.bms),
        ];
        let last = &mut self.last;
        for (g, (t, ns)) in groups.into_iter().enumerate() {
            for &x in t {
                if let (0, Some(l)) = (g, last[0]) {
                    let gap = x - l;
                    if self.worst_gap.is_none_or(|w| gap >= w.1) {
                        self.worst_gap = Some((ns.len() - 1, gap, l));
                    }
                }
                self.out_of_order |= !(x >= 0.0 && last[g].is_none_or(|l| x >= l));
                last[g] = Some(x);
                ns.push(to_ns(&x));
            }
        }
    }
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
