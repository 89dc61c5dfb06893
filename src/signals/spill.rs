//! A session's decoded joint states kept on disk between streamed passes ([`StateSpill`]):
//! the first full read writes every state batch to an anonymous temporary file, and the passes
//! after it read their trials' samples back from there instead of decompressing and decoding
//! the recording again. Memory stays bounded (one block at a time); the disk holds about
//! 150 bytes per joint-state sample (≈ 0.5 GB for 10 h at 100 Hz), freed when the spill is
//! dropped.
//!
//! Exact: every value comes back bit for bit. A block's column is stored as `f32` when every
//! value in it survives the round trip (the recorded fields are `float32`/`int16`), as `f64`
//! otherwise; times always as `f64`.

use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::sync::{Arc, Mutex, OnceLock};

use anyhow::{Context, Result};

use super::{PowerSeries, StateSeries};
use crate::N_JOINTS;

/// Values per sample besides the time: q, q̇, τ, T (7 each), gyro (3), quaternion (4).
const COLUMNS: usize = 4 * N_JOINTS + 3 + 4 + 1;

/// Where column `c` (in the spill's column order) lies in a [`StateSeries`]: (the field's values
/// flattened sample by sample, values per sample, position in a sample); `$flat` and `$one` pick
/// shared or writable slices.
macro_rules! column {
    ($s:expr, $c:expr, $flat:ident, $one:ident) => {{
        const J: usize = N_JOINTS;
        match $c {
            c if c < J => ($s.q.$flat(), J, c),
            c if c < 2 * J => ($s.dq.$flat(), J, c - J),
            c if c < 3 * J => ($s.tau.$flat(), J, c - 2 * J),
            c if c < 4 * J => ($s.temp.$flat(), J, c - 3 * J),
            c if c < 4 * J + 3 => ($s.gyro.$flat(), 3, c - 4 * J),
            c if c < 4 * J + 7 => ($s.quat.$flat(), 4, c - 4 * J - 3),
            _ => ($s.volts.$one(), 1, 0),
        }
    }};
}

/// One written batch: its time span, where it starts in the file, its length, and which
/// columns are stored wide (`f64`).
#[derive(Debug, Clone, Copy)]
struct Block {
    t_min: f64,
    t_max: f64,
    offset: u64,
    n: usize,
    wide: u64,
}

/// Joint states written once and read back any number of times (see the module doc).
#[derive(Debug)]
pub struct StateSpill {
    file: Mutex<File>,
    blocks: Vec<Block>,
    /// The clock the times are on (the first pass's `start_ns`).
    pub origin_ns: u64,
    /// The session's main-board and battery power readings on the same clock, sorted, when the
    /// pass that wrote the spill kept them (`None`: it did not).
    pub power: Option<[PowerSeries; 2]>,
}

/// Builds a [`StateSpill`] batch by batch.
pub struct SpillWriter {
    out: BufWriter<File>,
    blocks: Vec<Block>,
    offset: u64,
}

impl SpillWriter {
    /// A writer onto a new anonymous temporary file (in the system's temporary folder).
    pub fn new() -> Result<Self> {
        let file = tempfile::tempfile()
            .context("creating a temporary file for the session's joint states")?;
        Ok(Self {
            out: BufWriter::with_capacity(1 << 20, file),
            blocks: Vec::new(),
            offset: 0,
        })
    }

    /// Append one batch of joint states (all columns of equal length).
    pub fn push(&mut self, s: &StateSeries) -> Result<()> {
        let n = s.t.len();
        if n == 0 {
            return Ok(());
        }
        anyhow::ensure!(
            [
                s.q.len(),
                s.dq.len(),
                s.tau.len(),
                s.temp.len(),
                s.gyro.len(),
                s.quat.len()
            ]
            .iter()
            .all(|&l| l == n),
            "joint state columns of unequal length"
        );
        let mut wide = 0u64;
        let mut col = Vec::with_capacity(n);
        let mut bytes: Vec<u8> = Vec::with_capacity(n * (8 + COLUMNS * 8));
        bytes.extend(s.t.iter().flat_map(|t| t.to_le_bytes()));
        for c in 0..COLUMNS {
            let (flat, stride, at) = column!(s, c, as_flattened, as_slice);
            col.clear();
            col.extend(flat.chunks_exact(stride).take(n).map(|r| r[at]));
            col.resize(n, f64::NAN);
            if col
                .iter()
                .all(|&v| f64::from(v as f32).to_bits() == v.to_bits())
            {
                bytes.extend(col.iter().flat_map(|&v| (v as f32).to_le_bytes()));
            } else {
                wide |= 1 << c;
                bytes.extend(col.iter().flat_map(|v| v.to_le_bytes()));
            }
        }
        self.out
            .write_all(&bytes)
            .context("writing the session's joint states to a temporary file")?;
        let (t_min, t_max) =
            s.t.iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &t| {
                    (a.min(t), b.max(t))
                });
        self.blocks.push(Block {
            t_min,
            t_max,
            offset: self.offset,
            n,
            wide,
        });
        self.offset += bytes.len() as u64;
        Ok(())
    }

    /// The finished spill, its times on the clock `origin_ns`.
    pub fn finish(self, origin_ns: u64) -> Result<StateSpill> {
        let file = self
            .out
            .into_inner()
            .map_err(|e| e.into_error())
            .context("writing the session's joint states to a temporary file")?;
        Ok(StateSpill {
            file: Mutex::new(file),
            blocks: self.blocks,
            origin_ns,
            power: None,
        })
    }
}

/// Column `c` of sample `i` in the spill's column order.
#[cfg(test)]
fn value(s: &StateSeries, i: usize, c: usize) -> f64 {
    let (flat, stride, at) = column!(s, c, as_flattened, as_slice);
    flat.get(i * stride + at).copied().unwrap_or(f64::NAN)
}

impl StateSpill {
    /// Every written sample whose time lies in one of `ranges` (seconds, inclusive, compared as
    /// whole nanoseconds on the spill's clock as the recording's ranged read compares log
    /// times; `None`: every sample), block by block in the order written. Blocks outside every
    /// range are not read.
    pub fn stream(
        &self,
        ranges: Option<&[(f64, f64)]>,
        on_batch: &mut dyn FnMut(&StateSeries) -> Result<()>,
    ) -> Result<()> {
        let ns = |t: f64| (t * 1e9).round() as i64;
        let ranges_ns: Option<Vec<(i64, i64)>> =
            ranges.map(|r| r.iter().map(|&(a, b)| (ns(a), ns(b))).collect());
        let inside = |t: f64| {
            ranges_ns
                .as_ref()
                .is_none_or(|r| r.iter().any(|&(a, b)| (a..=b).contains(&ns(t))))
        };
        let mut file = self
            .file
            .lock()
            .map_err(|_| anyhow::anyhow!("the joint-state spill was poisoned"))?;
        let mut raw = Vec::new();
        for b in &self.blocks {
            if let Some(r) = &ranges_ns
                && !r.iter().any(|&(a, z)| ns(b.t_max) >= a && ns(b.t_min) <= z)
            {
                continue;
            }
            let width = |c: usize| if b.wide & (1 << c) != 0 { 8 } else { 4 };
            let len = b.n * (8 + (0..COLUMNS).map(width).sum::<usize>());
            raw.resize(len, 0);
            file.seek(SeekFrom::Start(b.offset))
                .and_then(|_| file.read_exact(&mut raw))
                .context("reading the session's joint states back from a temporary file")?;
            let mut s = StateSeries {
                t: Vec::with_capacity(b.n),
                q: vec![[0.0; N_JOINTS]; b.n],
                dq: vec![[0.0; N_JOINTS]; b.n],
                tau: vec![[0.0; N_JOINTS]; b.n],
                temp: vec![[0.0; N_JOINTS]; b.n],
                gyro: vec![[0.0; 3]; b.n],
                quat: vec![[0.0; 4]; b.n],
                volts: vec![0.0; b.n],
            };
            let (times, mut rest) = raw.split_at(b.n * 8);
            s.t.extend(times.chunks_exact(8).map(|x| f64::from_le_bytes(array(x))));
            for c in 0..COLUMNS {
                let (values, after) = rest.split_at(b.n * width(c));
                rest = after;
                let (flat, stride, at) = column!(s, c, as_flattened_mut, as_mut_slice);
                let slots = flat.chunks_exact_mut(stride).map(|r| &mut r[at]);
                if width(c) == 8 {
                    let read = values.chunks_exact(8).map(|x| f64::from_le_bytes(array(x)));
                    slots.zip(read).for_each(|(v, x)| *v = x);
                } else {
                    let read = values.chunks_exact(4).map(|x| f32::from_le_bytes(array(x)));
                    slots.zip(read).for_each(|(v, x)| *v = f64::from(x));
                }
            }
            if ranges_ns.is_some() {
                let keep: Vec<bool> = s.t.iter().map(|&t| inside(t)).collect();
                if !keep.iter().all(|&k| k) {
                    s = s.select(&keep);
                }
            }
            if !s.t.is_empty() {
                on_batch(&s)?;
            }
        }
        Ok(())
    }
}

/// The first `N` bytes of `x` (a chunk of exactly `N`).
fn array<const N: usize>(x: &[u8]) -> [u8; N] {
    x.try_into().unwrap_or([0; N])
}

/// A session's spill, shared by the copies of its file handle: empty until a first full pass
/// writes it ([`SpillSlot::fill`]); the passes after it read from it when it is there.
#[derive(Debug, Clone, Default)]
pub struct SpillSlot(Arc<OnceLock<StateSpill>>);

impl SpillSlot {
    /// The spill, once written.
    pub fn get(&self) -> Option<&StateSpill> {
        self.0.get()
    }

    /// Keep `spill` (a slot is filled once; a second fill is ignored).
    pub fn fill(&self, spill: StateSpill) {
        let _ = self.0.set(spill);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn series(n: usize, t0: f64) -> StateSeries {
        let mut s = StateSeries::default();
        for i in 0..n {
            let x = i as f64;
            s.t.push(t0 + 0.01 * x);
            // f32-exact values, and one column that is not (stored wide).
            s.q.push(std::array::from_fn(|j| {
                f64::from((x * 0.1 + j as f64) as f32)
            }));
            s.dq.push(std::array::from_fn(|j| (x * 0.1 + j as f64).sin()));
            s.tau.push([f64::from(1.5f32); N_JOINTS]);
            s.temp.push([31.0; N_JOINTS]);
            s.gyro.push([0.25, -0.5, 1e-3f32 as f64]);
            s.quat.push([1.0, 0.0, 0.0, f64::from(0.1f32)]);
            s.volts.push(f64::from(52.5f32 - x as f32 * 1e-3));
        }
        s
    }

    fn all(spill: &StateSpill, ranges: Option<&[(f64, f64)]>) -> StateSeries {
        let mut out = StateSeries::default();
        spill
            .stream(ranges, &mut |b| {
                out.extend_range(b, 0..usize::MAX);
                Ok(())
            })
            .unwrap();
        out
    }

    fn bits(s: &StateSeries) -> Vec<u64> {
        let mut v: Vec<u64> = s.t.iter().map(|x| x.to_bits()).collect();
        for i in 0..s.t.len() {
            v.extend((0..COLUMNS).map(|c| value(s, i, c).to_bits()));
        }
        v
    }

    /// Every value comes back bit for bit (narrow and wide columns), and a ranged read returns
    /// exactly the samples inside the ranges, ends included.
    #[test]
    fn the_spill_returns_every_value_and_exactly_the_ranges() {
        let (a, b) = (series(500, 0.0), series(300, 5.0));
        let mut w = SpillWriter::new().unwrap();
        w.push(&a).unwrap();
        w.push(&StateSeries::default()).unwrap();
        w.push(&b).unwrap();
        let spill = w.finish(7).unwrap();
        assert_eq!(spill.origin_ns, 7);
        let back = all(&spill, None);
        let mut whole = a.clone();
        whole.extend_range(&b, 0..usize::MAX);
        assert_eq!(bits(&back), bits(&whole));
        // Two ranges, one ending exactly on a sample, one past the end.
        let ranges = [(1.0, 2.0), (5.5, 99.0)];
        let got = all(&spill, Some(&ranges));
        let keep: Vec<bool> = whole
            .t
            .iter()
            .map(|&t| {
                ranges
                    .iter()
                    .any(|&(x, y)| t >= x - 1e-12 && t <= y + 1e-12)
            })
            .collect();
        assert_eq!(bits(&got), bits(&whole.select(&keep)));
        assert!(
            got.t.contains(&whole.t[200]),
            "the range's end sample (t = 2.0)"
        );
        // A range between the blocks reads nothing.
        assert!(all(&spill, Some(&[(100.0, 200.0)])).t.is_empty());
    }
}
