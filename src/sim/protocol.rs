//! The paper's recording protocol: route library (single-joint sweeps, all pairs, 3- to 7-joint
//! combinations inside the URDF limits and away from the body), presets, and the commanded
//! trajectory of a session — pre-idle 2 s at home, smooth-step segments through the route's
//! waypoints (s = 3τ² − 2τ³, T = max(0.3 s, 1.5·max|Δq|/q̇_max)), post-idle 2 s, return home at
//! 0.5 rad/s, 0.1–0.6 s at home before the next trial.

use rand::{RngExt, SeedableRng, seq::SliceRandom};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::plant::Motion;
use crate::N_JOINTS;
use crate::trial::TrialWindow;

/// Pre-idle duration at home [s].
pub const PRE_IDLE_S: f64 = 2.0;
/// Post-idle duration at the final posture [s].
pub const POST_IDLE_S: f64 = 2.0;
/// Speed of the return to home [rad/s].
pub const RETURN_SPEED: f64 = 0.5;
/// Shortest smooth-step segment [s].
pub const MIN_SEGMENT_S: f64 = 0.3;
/// Home time between trials [s] (uniform).
pub const GAP_S: [f64; 2] = [0.1, 0.6];
/// Idle lead-in at home before the first trial [s].
pub const LEAD_IN_S: f64 = 3.0;
/// Idle tail at home after the last trial [s].
pub const TAIL_S: f64 = 1.0;
/// Identification speed levels [rad/s].
pub const ID_SPEEDS: [f64; 5] = [0.5, 1.0, 1.5, 2.0, 2.5];
/// Hold-out speed levels [rad/s].
pub const HOLDOUT_SPEEDS: [f64; 4] = [0.75, 1.25, 1.75, 2.25];

/// Waypoint ranges [rad] per joint: inside the URDF limits of `g1_29dof_with_hand_rev_1_0.urdf`
/// and away from the body (shoulder roll positive = abduction for the left arm).
pub const SAFE_RANGE: [[f64; 2]; N_JOINTS] = [
    [-1.25, 0.5],
    [0.2, 1.3],
    [-0.4, 0.85],
    [-1.0, 1.0],
    [-1.25, 1.25],
    [-1.1, 0.9],
    [-1.0, 0.9],
];

/// Smallest waypoint-to-waypoint step of a moved joint [rad], so every segment is a real motion.
const MIN_STEP: f64 = 0.3;

/// A named set of trials.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// 4 short trials of mixed kinds (tests).
    Tiny,
    /// ≈ 24 trials mixing route kinds and identification speeds (≈ 6 min).
    #[default]
    Smoke,
    /// ≈ 1000 trials: 200 routes × the 5 identification speeds (≈ 3.3 h).
    Paper,
    /// The paper's 46 hold-out trials at {0.75, 1.25, 1.75, 2.25} rad/s on identification routes.
    Holdout,
    /// 7 trials of mixed kinds (the shipped example session).
    Example,
}

impl Preset {
    /// Lower-case name as used on the command line and in the truth JSON.
    pub fn name(self) -> &'static str {
        match self {
            Preset::Tiny => "tiny",
            Preset::Smoke => "smoke",
            Preset::Paper => "paper",
            Preset::Holdout => "holdout",
            Preset::Example => "example",
        }
    }
}

impl std::str::FromStr for Preset {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> anyhow::Result<Self> {
        use Preset::{Example, Holdout, Paper, Smoke, Tiny};
        let known = [Tiny, Smoke, Paper, Holdout, Example];
        known.into_iter().find(|p| p.name() == s).ok_or_else(|| {
            anyhow::anyhow!(
                "unknown preset {s:?} (expected tiny, smoke, paper, holdout or example)"
            )
        })
    }
}

/// A route: the joints it moves and its waypoints (home is the implicit start).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Route {
    /// Stable identifier, e.g. `s3_0` (single, elbow, variant 0), `p45_1`, `c0135_0`.
    pub id: String,
    /// `single`, `pair`, `combo3` … `combo7`.
    pub kind: String,
    /// Model indices of the moved joints.
    pub joints: Vec<usize>,
    /// 3–5 postures [rad].
    pub waypoints: Vec<[f64; N_JOINTS]>,
}

/// Route `variant` over `joints`. Waypoints depend only on (`route_seed`, joints, variant), so the
/// hold-out preset reuses exactly the identification waypoints.
pub fn route(joints: &[usize], variant: usize, route_seed: u64) -> Route {
    let mut key = route_seed ^ 0x9e37_79b9_7f4a_7c15;
    for &j in joints {
        key = key.wrapping_mul(31).wrapping_add(j as u64 + 1);
    }
    key = key.wrapping_mul(1_000_003).wrapping_add(variant as u64);
    let mut rng = ChaCha8Rng::seed_from_u64(key);
    let n_wp = rng.random_range(3..=5);
    let mut waypoints = Vec::with_capacity(n_wp);
    let mut prev = [0.0; N_JOINTS];
    for _ in 0..n_wp {
        let mut wp = [0.0; N_JOINTS];
        for &j in joints {
            let [lo, hi] = SAFE_RANGE[j];
            // Rejection sampling for a real step from the previous posture (always possible: ranges ≥ 1 rad).
            let mut v = rng.random_range(lo..hi);
            for _ in 0..64 {
                if (v - prev[j]).abs() >= MIN_STEP {
                    break;
                }
                v = rng.random_range(lo..hi);
            }
            wp[j] = (v * 1e6).round() / 1e6;
        }
        prev = wp;
        waypoints.push(wp);
    }
    let names: String = joints.iter().map(|j| j.to_string()).collect();
    let (prefix, kind) = match joints.len() {
        1 => ("s", "single".to_string()),
        2 => ("p", "pair".to_string()),
        n => ("c", format!("combo{n}")),
    };
    Route {
        id: format!("{prefix}{names}_{variant}"),
        kind,
        joints: joints.to_vec(),
        waypoints,
    }
}

/// All k-joint combinations of the 7 joints, in lexicographic order.
fn combinations(k: usize) -> Vec<Vec<usize>> {
    fn rec(start: usize, k: usize, cur: &mut Vec<usize>, out: &mut Vec<Vec<usize>>) {
        if cur.len() == k {
            out.push(cur.clone());
            return;
        }
        for j in start..N_JOINTS {
            cur.push(j);
            rec(j + 1, k, cur, out);
            cur.pop();
        }
    }
    let mut out = Vec::new();
    rec(0, k, &mut Vec::new(), &mut out);
    out
}

/// One planned trial: a route at a speed level.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedTrial {
    /// The route.
    pub route: Route,
    /// Peak joint speed [rad/s] (the speed level).
    pub qdot_max: f64,
}

/// The trials of a preset, in recording order. `seed` shuffles the order and picks the smoke mix.
pub fn plan(preset: Preset, seed: u64, route_seed: u64) -> Vec<PlannedTrial> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5151_0000);
    let r = |joints: &[usize], v: usize| route(joints, v, route_seed);
    let t = |route: Route, qdot_max: f64| PlannedTrial { route, qdot_max };
    match preset {
        Preset::Tiny => vec![
            t(r(&[3], 1), 2.0),
            t(r(&[0, 3], 0), 2.5),
            t(r(&[4, 5, 6], 0), 2.0),
            t(r(&[5], 1), 2.5),
        ],
        Preset::Example => vec![
            t(r(&[0], 0), 1.0),
            t(r(&[3], 0), 2.0),
            t(r(&[5], 0), 1.5),
            t(r(&[0, 3], 0), 1.5),
            t(r(&[4, 5], 0), 2.0),
            t(r(&[1, 3, 5], 0), 2.5),
            t(r(&[0, 1, 2, 3, 4, 5, 6], 0), 1.0),
        ],
        Preset::Smoke => {
            // Every single-joint sweep, six pairs, four triples, two quads, the full arm, and four
            // more single/pair routes; speeds cycle through the identification levels.
            let mut routes: Vec<Route> = (0..N_JOINTS).map(|j| r(&[j], 0)).collect();
            let pairs = combinations(2);
            for (set, n) in [(&pairs, 6), (&combinations(3), 4), (&combinations(4), 2)] {
                for _ in 0..n {
                    routes.push(r(&set[rng.random_range(0..set.len())], 0));
                }
            }
            routes.push(r(&[0, 1, 2, 3, 4, 5, 6], 0));
            routes.push(r(&[3], 1));
            routes.push(r(&[5], 1));
            routes.push(r(&pairs[rng.random_range(0..pairs.len())], 1));
            routes.push(r(&[0], 1));
            let offset = rng.random_range(0..ID_SPEEDS.len());
            routes
                .into_iter()
                .enumerate()
                .map(|(k, route)| t(route, ID_SPEEDS[(k + offset) % ID_SPEEDS.len()]))
                .collect()
        }
        Preset::Paper => {
            // 7×4 single sweeps, 21×3 pairs, 35×2 triples, 35 quads, 2 five-, 1 six-, 1 seven-joint
            // routes = 200 routes, each at the 5 identification speeds: 1000 trials, shuffled.
            let mut routes = Vec::new();
            for (k, variants) in [(1, 4), (2, 3), (3, 2), (4, 1)] {
                for joints in combinations(k) {
                    for v in 0..variants {
                        routes.push(r(&joints, v));
                    }
                }
            }
            let fives = combinations(5);
            routes.push(r(&fives[0], 0));
            routes.push(r(&fives[fives.len() - 1], 0));
            routes.push(r(&[0, 1, 2, 3, 4, 5], 0));
            routes.push(r(&[0, 1, 2, 3, 4, 5, 6], 0));
            let mut trials: Vec<PlannedTrial> = routes
                .iter()
                .flat_map(|route| ID_SPEEDS.iter().map(move |&s| t(route.clone(), s)))
                .collect();
            trials.shuffle(&mut rng);
            trials
        }
        Preset::Holdout => {
            // The paper's hold-out routes: single sweeps of shoulder pitch/roll/yaw, elbow and wrist
            // pitch (two variants for pitch, elbow, wrist pitch), wrist-only pairs and the wrist
            // triple; 12 routes × 4 speeds minus the slowest triple and one fastest pair = 46.
            let singles = [
                (0, 0),
                (1, 0),
                (2, 0),
                (3, 0),
                (5, 0),
                (0, 1),
                (3, 1),
                (5, 1),
            ];
            let wrist: [&[usize]; 4] = [&[4, 5], &[4, 6], &[5, 6], &[4, 5, 6]];
            let routes: Vec<Route> = (singles.iter().map(|&(j, v)| r(&[j], v)))
                .chain(wrist.iter().map(|j| r(j, 0)))
                .collect();
            let mut trials = Vec::new();
            for (k, &s) in HOLDOUT_SPEEDS.iter().enumerate() {
                for (n, route) in routes.iter().enumerate() {
                    let skip = (k == 0 && n == 11) || (k == HOLDOUT_SPEEDS.len() - 1 && n == 8);
                    if !skip {
                        trials.push(t(route.clone(), s));
                    }
                }
            }
            trials
        }
    }
}

/// A smooth-step segment from `q0` to `q1` over [t0, t0 + dur].
#[derive(Debug, Clone, Copy)]
struct Segment {
    t0: f64,
    dur: f64,
    q0: [f64; N_JOINTS],
    q1: [f64; N_JOINTS],
}

impl Segment {
    /// The move from `q0` to `q1` starting at `t0`, at peak speed `qdot_max`: the smooth step's
    /// peak speed is 1.5·Δq/T, so the joint that moves furthest peaks at `qdot_max`.
    fn new(t0: f64, q0: [f64; N_JOINTS], q1: [f64; N_JOINTS], qdot_max: f64) -> Segment {
        let max_dq = (0..N_JOINTS)
            .map(|j| (q1[j] - q0[j]).abs())
            .fold(0.0, f64::max);
        let dur = MIN_SEGMENT_S.max(1.5 * max_dq / qdot_max);
        Segment { t0, dur, q0, q1 }
    }
}

/// The commanded joint trajectory of a whole session: piecewise smooth steps, at home elsewhere.
#[derive(Debug, Clone)]
pub struct Schedule {
    segments: Vec<Segment>,
    /// The scheduled trials in order (times in s since session start; the commanded peak
    /// speed is the trial's speed level, nothing is measured).
    pub trials: Vec<TrialWindow>,
    /// Session duration [s].
    pub duration: f64,
}

impl Schedule {
    /// Lay out `trials` in time; `rng` draws the inter-trial gaps.
    pub fn build(trials: &[PlannedTrial], rng: &mut ChaCha8Rng) -> Schedule {
        let mut segments = Vec::new();
        let mut times = Vec::with_capacity(trials.len());
        let mut t = LEAD_IN_S;
        for (k, tr) in trials.iter().enumerate() {
            if k > 0 {
                t += rng.random_range(GAP_S[0]..GAP_S[1]);
            }
            let trial_start = t;
            t += PRE_IDLE_S;
            let traj_start = t;
            let mut q = [0.0; N_JOINTS];
            let mut go = |t: &mut f64, q0, q1, speed| {
                let s = Segment::new(*t, q0, q1, speed);
                *t += s.dur;
                segments.push(s);
            };
            for wp in &tr.route.waypoints {
                go(&mut t, q, *wp, tr.qdot_max);
                q = *wp;
            }
            let traj_end = t;
            t += POST_IDLE_S;
            let post_idle_end = t;
            go(&mut t, q, [0.0; N_JOINTS], RETURN_SPEED);
            times.push(TrialWindow {
                index: k,
                t_pre_start: trial_start,
                t_traj_start: traj_start,
                t_traj_end: traj_end,
                t_post_end: post_idle_end,
                t_return_end: t,
                joints_moved: tr.route.joints.clone(),
                qdot_max_cmd: tr.qdot_max,
                qdot_max_meas: f64::NAN,
            });
        }
        Schedule {
            segments,
            trials: times,
            duration: t + TAIL_S,
        }
    }

    /// Commanded position, velocity and acceleration at time `t` [s]. `hint` is a segment cursor
    /// for monotone queries (start at 0).
    pub fn eval(&self, t: f64, hint: &mut usize) -> Motion {
        while *hint < self.segments.len() && self.segments[*hint].t0 + self.segments[*hint].dur <= t
        {
            *hint += 1;
        }
        while *hint > 0 && self.segments[*hint - 1].t0 + self.segments[*hint - 1].dur > t {
            *hint -= 1;
        }
        let zero = [0.0; N_JOINTS];
        match self.segments.get(*hint) {
            // At rest at the previous segment's end posture (or home before the first).
            None => (self.segments.last().map_or(zero, |s| s.q1), zero, zero),
            Some(s) if t < s.t0 => (s.q0, zero, zero),
            Some(s) => {
                let u = ((t - s.t0) / s.dur).clamp(0.0, 1.0);
                let (p, v, a) = (
                    3.0 * u * u - 2.0 * u * u * u,
                    (6.0 * u - 6.0 * u * u) / s.dur,
                    (6.0 - 12.0 * u) / (s.dur * s.dur),
                );
                let mut q = zero;
                let mut dq = zero;
                let mut ddq = zero;
                for j in 0..N_JOINTS {
                    let d = s.q1[j] - s.q0[j];
                    q[j] = s.q0[j] + d * p;
                    dq[j] = d * v;
                    ddq[j] = d * a;
                }
                (q, dq, ddq)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The duration of a move of `dq` on one joint at peak speed `v`.
    fn segment_duration(dq: f64, v: f64) -> f64 {
        let mut q1 = [0.0; N_JOINTS];
        q1[0] = dq;
        Segment::new(0.0, [0.0; N_JOINTS], q1, v).dur
    }

    #[test]
    fn segment_duration_matches_the_shared_truth_trial() {
        // g1_smoke.truth.json trial 0: waypoints 0.43568, −0.878021, 0.341609, −1.125251 on
        // shoulder pitch at 1 rad/s; trajectory lasts 6.653807973 s, return 3.375752025 s.
        let wps = [0.43568, -0.878021, 0.341609, -1.125251];
        let mut prev = 0.0f64;
        let total: f64 = wps
            .iter()
            .map(|&w| {
                let d = segment_duration((w - prev).abs(), 1.0);
                prev = w;
                d
            })
            .sum();
        // The JSON rounds waypoints to 1e-6 rad: up to 1.5e-6 s per segment.
        assert!((total - 6.653807973).abs() < 1e-5, "{total}");
        assert!((segment_duration(1.125251, RETURN_SPEED) - 3.375752025).abs() < 1e-5);
    }

    #[test]
    fn peak_speed_equals_the_level() {
        let tr = PlannedTrial {
            route: route(&[3], 0, 0),
            qdot_max: 1.5,
        };
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let s = Schedule::build(&[tr], &mut rng);
        let tt = &s.trials[0];
        let mut hint = 0;
        let mut peak: f64 = 0.0;
        let mut t = tt.t_traj_start;
        while t < tt.t_traj_end {
            peak = peak.max(s.eval(t, &mut hint).1[3].abs());
            t += 1e-3;
        }
        assert!((peak - 1.5).abs() < 1e-3, "{peak}");
    }

    #[test]
    fn holdout_reuses_identification_waypoints() {
        let paper = plan(Preset::Paper, 1, 0);
        for t in plan(Preset::Holdout, 2, 0) {
            assert!(HOLDOUT_SPEEDS.contains(&t.qdot_max));
            let same = paper
                .iter()
                .find(|p| p.route.id == t.route.id)
                .expect("route in the paper set");
            assert_eq!(same.route.waypoints, t.route.waypoints);
        }
    }

    #[test]
    fn waypoints_stay_in_the_safe_ranges() {
        for t in plan(Preset::Paper, 1, 0) {
            assert!((3..=5).contains(&t.route.waypoints.len()));
            for wp in &t.route.waypoints {
                for j in 0..N_JOINTS {
                    let [lo, hi] = SAFE_RANGE[j];
                    let moved = t.route.joints.contains(&j);
                    assert!(if moved {
                        wp[j] >= lo && wp[j] <= hi
                    } else {
                        wp[j] == 0.0
                    });
                }
            }
        }
    }

    #[test]
    fn preset_sizes() {
        assert_eq!(plan(Preset::Holdout, 1, 0).len(), 46);
        assert_eq!(plan(Preset::Paper, 1, 0).len(), 1000);
        assert_eq!(plan(Preset::Smoke, 1, 0).len(), 24);
    }
}
