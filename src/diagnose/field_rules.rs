//! Which recorded fields discovery may use: per-message statistics of each field over a whole
//! file ([`MsgStats`]) and the rules that leave out counters, clocks, hash- or CRC-like values
//! and constants ([`junk_reason`]).

/// First word of the clock rule's reason (discovery names these fields beside session time).
pub(crate) const CLOCK_REASON: &str = "clock";

/// Smallest range of an integer field that can be hash-like (a 16-bit counter's span).
const HASH_MIN_RANGE: f64 = 65_536.0;
/// |lag-1 autocorrelation| below which consecutive values are unrelated.
const HASH_MAX_LAG1: f64 = 0.1;
/// Share of consecutive messages that must step the same way for a counter.
const COUNTER_MIN_SHARE: f64 = 0.95;
/// |correlation with the clock| of the window values, within one file, above which a field
/// duplicates session time.
const CLOCK_MIN_R: f64 = 0.9999;
/// Per-message statistics of one field over everything a file carries (not only the windows):
/// what the junk rules of [`junk_reason`] look at.
#[derive(Debug, Clone, Copy)]
pub(crate) struct MsgStats {
    n: u64,
    all_int: bool,
    min: f64,
    max: f64,
    /// Σx and Σx² over the runs (a value repeated by consecutive messages counts once: a
    /// message re-sent unchanged repeats its checksum).
    sum: f64,
    sum_sq: f64,
    runs: u64,
    /// Consecutive runs (x_{t−1}, x_t): count, Σx_{t−1}, Σx_t, Σx_{t−1}², Σx_t², Σx_{t−1}x_t.
    pairs: [f64; 6],
    /// Consecutive messages, and those with x_t > x_{t−1} and with x_t < x_{t−1}.
    steps: u64,
    rises: u64,
    falls: u64,
    prev: f64,
}

impl Default for MsgStats {
    fn default() -> Self {
        MsgStats {
            n: 0,
            all_int: true,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            sum: 0.0,
            sum_sq: 0.0,
            runs: 0,
            pairs: [0.0; 6],
            steps: 0,
            rises: 0,
            falls: 0,
            prev: f64::NAN,
        }
    }
}

impl MsgStats {
    pub(crate) fn add(&mut self, x: f64) {
        if !x.is_finite() {
            return;
        }
        self.n += 1;
        self.all_int &= x.fract() == 0.0;
        self.min = self.min.min(x);
        self.max = self.max.max(x);
        let p = self.prev;
        if p.is_finite() {
            self.steps += 1;
            self.rises += u64::from(x > p);
            self.falls += u64::from(x < p);
            if x == p {
                return;
            }
            let q = &mut self.pairs;
            q[0] += 1.0;
            q[1] += p;
            q[2] += x;
            q[3] += p * p;
            q[4] += x * x;
            q[5] += p * x;
        }
        self.runs += 1;
        self.sum += x;
        self.sum_sq += x * x;
        self.prev = x;
    }

    /// Pool another file's statistics of the same field (pairs never span files).
    pub(crate) fn merge(&mut self, o: &MsgStats) {
        self.n += o.n;
        self.all_int &= o.all_int;
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
        self.sum += o.sum;
        self.sum_sq += o.sum_sq;
        self.runs += o.runs;
        for (a, b) in self.pairs.iter_mut().zip(o.pairs) {
            *a += b;
        }
        self.steps += o.steps;
        self.rises += o.rises;
        self.falls += o.falls;
    }

    /// Lag-1 autocorrelation over consecutive runs.
    fn lag1(&self) -> f64 {
        let [n, sa, sb, saa, sbb, sab] = self.pairs;
        let cov = sab - sa * sb / n;
        let va = saa - sa * sa / n;
        let vb = sbb - sb * sb / n;
        cov / (va * vb).sqrt().max(1e-300)
    }
}

/// Why a field is junk for discovery, from its own data only (no field names): `None` when it
/// is a candidate. `clock_r` is its window values' correlation with time within a file.
pub(crate) fn junk_reason(st: &MsgStats, clock_r: Option<f64>) -> Option<String> {
    if st.n == 0 {
        return None;
    }
    if st.max <= st.min {
        // Constant over the messages looked at: judged on the reading windows instead.
        return None;
    }
    // An integer that steps the same way at (nearly) every message counts messages or time; a
    // float drifting one way (a heading, a charge) is a physical signal and is judged by the
    // clock rule below instead.
    let steps = st.steps as f64;
    if st.all_int && steps >= 10.0 {
        let share = st.rises.max(st.falls) as f64 / steps;
        if share >= COUNTER_MIN_SHARE {
            return Some(format!(
                "counter: steps the same way in {:.1} % of consecutive messages (a duplicate of session time)",
                100.0 * share
            ));
        }
    }
    if let Some(r) = clock_r.filter(|r| r.abs() >= CLOCK_MIN_R) {
        return Some(format!(
            "{CLOCK_REASON}: its window values follow session time within each file (r = {r:+.5}), a duplicate of the session time discovery tries itself"
        ));
    }
    let n = st.runs as f64;
    let range = st.max - st.min;
    if st.all_int && range >= HASH_MIN_RANGE && st.runs >= 100 {
        let mean = st.sum / n;
        let var = (st.sum_sq / n - mean * mean).max(0.0);
        let uniform_var = range * range / 12.0;
        let lag1 = st.lag1();
        let centred = ((mean - 0.5 * (st.min + st.max)) / range).abs() < 0.1;
        let flat = (var / uniform_var - 1.0).abs() < 0.2;
        if lag1.abs() < HASH_MAX_LAG1 && centred && flat {
            return Some(format!(
                "hash-/CRC-like: integers spread evenly over [{}, {}] (variance {:.2} × a uniform's) with no memory from one value to the next (lag-1 r = {lag1:+.3} over {} changes)",
                st.min,
                st.max,
                var / uniform_var,
                st.runs
            ));
        }
    }
    None
}

/// The lowest window value of `vals` when they are all finite and constant (to 1e-9 relative).
pub(crate) fn constant_value(vals: &[f64]) -> Option<f64> {
    if vals.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let (lo, hi) = vals
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    (hi - lo <= 1e-9 * hi.abs().max(lo.abs()).max(1e-300)).then_some(lo)
}

/// Pearson correlation of the finite window values with the windows' end times `ends` (≥ 10 windows).
pub(crate) fn clock_correlation(ends: impl Iterator<Item = f64>, vals: &[f64]) -> Option<f64> {
    let pts: Vec<(f64, f64)> = ends
        .zip(vals)
        .filter(|(_, v)| v.is_finite())
        .map(|(t, v)| (t, *v))
        .collect();
    if pts.len() < 10 {
        return None;
    }
    let n = pts.len() as f64;
    let (mt, mv) = pts
        .iter()
        .fold((0.0, 0.0), |(a, b), (t, v)| (a + t / n, b + v / n));
    let (mut stv, mut stt, mut svv) = (0.0, 0.0, 0.0);
    for (t, v) in &pts {
        stv += (t - mt) * (v - mv);
        stt += (t - mt) * (t - mt);
        svv += (v - mv) * (v - mv);
    }
    (svv > 0.0).then(|| stv / (stt * svv).sqrt().max(1e-300))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stats(xs: impl Iterator<Item = f64>) -> MsgStats {
        let mut st = MsgStats::default();
        xs.for_each(|x| st.add(x));
        st
    }

    /// A 32-bit hash of i (splitmix64's finaliser): what a CRC over changing bytes looks like.
    fn hash(i: u64) -> f64 {
        let mut z = i.wrapping_add(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 32) as f64
    }

    #[test]
    fn junk_rules_catch_counters_hashes_and_constants_only() {
        let n = 5000u64;
        let reason = |st: MsgStats| junk_reason(&st, None);
        // A message counter and a millisecond tick.
        assert!(reason(stats((0..n).map(|i| i as f64))).is_some_and(|r| r.starts_with("counter")));
        assert!(
            reason(stats((0..n).map(|i| 1_000_000.0 + 2.0 * i as f64)))
                .is_some_and(|r| r.starts_with("counter"))
        );
        // A CRC-like field.
        let r = reason(stats((0..n).map(hash)));
        assert!(r.as_deref().is_some_and(|r| r.starts_with("hash")), "{r:?}");
        // The checksum of a message re-sent unchanged for long stretches (an idle command).
        let r = reason(stats(
            (0..n).map(|i| if (i / 500) % 2 == 0 { hash(7) } else { hash(i) }),
        ));
        assert!(r.as_deref().is_some_and(|r| r.starts_with("hash")), "{r:?}");
        // Constant: left to the reading-window rule of `read_fields`.
        assert_eq!(reason(stats((0..n).map(|_| 7.0))), None);
        // Kept: a slowly heating integer temperature (steps up now and then), a 0/3000 rpm fan
        // switching every 400 messages, a noisy float, a wide but smooth integer (an encoder).
        assert_eq!(reason(stats((0..n).map(|i| 30.0 + (i / 300) as f64))), None);
        assert_eq!(
            reason(stats((0..n).map(|i| if (i / 400) % 2 == 0 {
                0.0
            } else {
                3000.0
            }))),
            None
        );
        assert_eq!(
            reason(stats((0..n).map(|i| (hash(i) / 4.3e9 - 0.5) * 0.01 + 0.2))),
            None
        );
        assert_eq!(
            reason(stats(
                (0..n).map(|i| (1e6 * (i as f64 / 700.0).sin()).round())
            )),
            None
        );
        // A float drifting one way is no counter.
        assert_eq!(reason(stats((0..n).map(|i| 0.001 * i as f64 + 0.3))), None);
        // Window values that follow the clock exactly; a temperature's do not.
        let clock = junk_reason(&stats((0..n).map(|i| (i % 2) as f64)), Some(0.99999));
        assert!(clock.is_some_and(|r| r.starts_with(CLOCK_REASON)));
        assert_eq!(
            junk_reason(&stats((0..n).map(|i| (i % 2) as f64)), Some(0.98)),
            None
        );
    }

    #[test]
    fn clock_correlation_of_window_values() {
        let ends: Vec<f64> = (0..20).map(|i| i as f64 + 0.2).collect();
        let windows = || ends.iter().copied();
        let t: Vec<f64> = ends.iter().map(|e| 1e3 * e + 5.0).collect();
        assert!(clock_correlation(windows(), &t).unwrap() > 0.999_999);
        let mut temp: Vec<f64> = (0..20).map(|i| 30.0 + (i / 7) as f64).collect();
        temp[3] = f64::NAN;
        assert!(clock_correlation(windows(), &temp).unwrap() < CLOCK_MIN_R);
        assert_eq!(clock_correlation(windows().take(5), &t[..5]), None);
    }
}
