//! Test-only miniature session generator (protocol-shaped trials, a toy gravity model, the
//! paper's power model plus optional effects) to exercise the whole pipeline in unit tests.
//! The real acceptance tests use the project's simulator (tests/diagnose.rs).

use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};

use crate::N_JOINTS;
use crate::power::PowerModel;
use crate::signals::Recording;
use crate::trial::TrialWindow;

/// Effects of the miniature generator (same physics as `sim::Effects`).
#[derive(Default, Clone, Copy)]
pub(crate) struct Effects {
    pub braking_r: Option<f64>,
    pub latency_s: Option<f64>,
    pub harness_k: Option<f64>,
    pub thermal_alpha: Option<f64>,
}

const RATE: f64 = 100.0;

fn smooth(s: f64) -> (f64, f64) {
    let s = s.clamp(0.0, 1.0);
    (3.0 * s * s - 2.0 * s * s * s, 6.0 * s - 6.0 * s * s)
}

/// The toy arm's gravity torque amplitude and inertia per joint.
const GRAVITY: [f64; 7] = [6.0, 4.0, 1.0, 3.0, 0.5, 0.8, 0.3];
const INERTIA: [f64; 7] = [0.3, 0.3, 0.1, 0.1, 0.02, 0.02, 0.01];

fn tau_of(q: &[f64; 7], ddq: &[f64; 7], dq: &[f64; 7]) -> [f64; 7] {
    std::array::from_fn(|j| GRAVITY[j] * (q[j] + 0.3).sin() + INERTIA[j] * ddq[j] + 0.2 * dq[j])
}

/// One trial's motion: the joints moved, the waypoint segments (from, to, duration) and the
/// phase boundaries (pre-idle 2 s, trajectory, post-idle 2 s, return, 0.3 s gap).
struct Motion {
    moved: Vec<usize>,
    qdot_max: f64,
    segs: Vec<([f64; 7], [f64; 7], f64)>,
    last: [f64; 7],
    t_pre: f64,
    t_traj: f64,
    t_traj_end: f64,
    t_post_end: f64,
    t_ret: f64,
    t_return_end: f64,
    t_end: f64,
}

/// Draw trial `index`'s motion starting at `t`.
fn plan_motion(rng: &mut rand_chacha::ChaCha8Rng, index: usize, t: f64) -> Motion {
    let speeds = [0.5, 1.0, 1.5, 2.0, 2.5];
    let n_moved = rng.random_range(1..=3usize);
    let mut moved: Vec<usize> = Vec::new();
    while moved.len() < n_moved {
        let j = rng.random_range(0..N_JOINTS);
        if !moved.contains(&j) {
            moved.push(j);
        }
    }
    moved.sort();
    let qdot_max = speeds[index % speeds.len()];
    let mut waypoints: Vec<[f64; 7]> = vec![[0.0; 7]];
    for _ in 0..3 {
        let mut w = [0.0; 7];
        for &j in &moved {
            w[j] = rng.random_range(-1.2..1.2);
        }
        waypoints.push(w);
    }
    let mut segs: Vec<([f64; 7], [f64; 7], f64)> = Vec::new();
    for p in waypoints.windows(2) {
        let dmax = (0..7)
            .map(|j| (p[1][j] - p[0][j]).abs())
            .fold(0.0, f64::max);
        segs.push((p[0], p[1], (1.5 * dmax / qdot_max).max(0.3)));
    }
    let last = *waypoints.last().unwrap();
    let dmax = last.iter().map(|v| v.abs()).fold(0.0, f64::max);
    let t_pre = t;
    let t_traj = t + 2.0;
    let t_traj_end = t_traj + segs.iter().map(|s| s.2).sum::<f64>();
    let t_post_end = t_traj_end + 2.0;
    let t_ret = (1.5 * dmax / 0.5).max(0.3);
    let t_return_end = t_post_end + t_ret;
    let t_end = t_return_end + 0.3;
    Motion {
        moved,
        qdot_max,
        segs,
        last,
        t_pre,
        t_traj,
        t_traj_end,
        t_post_end,
        t_ret,
        t_return_end,
        t_end,
    }
}

impl Motion {
    /// Position, velocity and acceleration at time `t`.
    fn at(&self, t: f64) -> ([f64; 7], [f64; 7], [f64; 7]) {
        let (mut q, mut dq, mut ddq) = ([0.0; 7], [0.0; 7], [0.0; 7]);
        let mut put = |a: &[f64; 7], b: &[f64; 7], dur: f64, u: f64| {
            let (s, ds) = smooth(u / dur);
            let dds = (6.0 - 12.0 * (u / dur).clamp(0.0, 1.0)) / (dur * dur);
            for j in 0..7 {
                q[j] = a[j] + (b[j] - a[j]) * s;
                dq[j] = (b[j] - a[j]) * ds / dur;
                ddq[j] = (b[j] - a[j]) * dds;
            }
        };
        if t >= self.t_traj && t < self.t_traj_end {
            let mut u = t - self.t_traj;
            for (a, b, dur) in &self.segs {
                if u < *dur {
                    put(a, b, *dur, u);
                    break;
                }
                u -= dur;
            }
        } else if t >= self.t_traj_end && t < self.t_post_end {
            q = self.last;
        } else if t >= self.t_post_end && t < self.t_return_end {
            put(&self.last, &[0.0; 7], self.t_ret, t - self.t_post_end);
        }
        (q, dq, ddq)
    }

    fn window(self, index: usize) -> TrialWindow {
        TrialWindow {
            index,
            t_pre_start: self.t_pre,
            t_traj_start: self.t_traj,
            t_traj_end: self.t_traj_end,
            t_post_end: self.t_post_end,
            t_return_end: self.t_return_end,
            joints_moved: self.moved,
            qdot_max_cmd: self.qdot_max,
            qdot_max_meas: f64::NAN,
        }
    }
}

/// Instantaneous power: 120 W idle, the paper's model, plus the effects switched on.
fn power_at(
    fx: &Effects,
    q: &[f64; 7],
    dq: &[f64; 7],
    tau: &[f64; 7],
    temp: &[f64; 7],
    tau0_sq: &[f64; 7],
) -> f64 {
    let mut p = 120.0 + PowerModel::PAPER.predict(tau, dq, tau0_sq);
    if let Some(r) = fx.braking_r {
        p += (r - 1.0) * (0..7).map(|j| (tau[j] * dq[j]).min(0.0)).sum::<f64>();
    }
    if let Some(a) = fx.thermal_alpha {
        let b = PowerModel::PAPER.b;
        p += (0..7)
            .map(|j| b[j] * a * (temp[j] - 25.0) * (tau[j] * tau[j] - tau0_sq[j]))
            .sum::<f64>();
    }
    if let Some(k) = fx.harness_k {
        p += k * (1.0 - q[3].cos()) * dq[3].abs();
    }
    p
}

pub(crate) fn session(n_trials: usize, seed: u64, fx: Effects) -> (Recording, Vec<TrialWindow>) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let noise_tau = Normal::new(0.0, 0.05).unwrap();
    let mut rec = Recording {
        joint_names: (0..7).map(|j| format!("j{j}")).collect(),
        ..Default::default()
    };
    let mut windows = Vec::new();
    let mut t = 0.0;
    let mut power_t = Vec::new(); // (t, instantaneous power)
    let home_tau = tau_of(&[0.0; 7], &[0.0; 7], &[0.0; 7]);
    let tau0_sq: [f64; 7] = std::array::from_fn(|j| home_tau[j] * home_tau[j]);
    for index in 0..n_trials {
        let motion = plan_motion(&mut rng, index, t);
        while t < motion.t_end {
            let (q, dq, ddq) = motion.at(t);
            let tau = tau_of(&q, &ddq, &dq);
            let temp: [f64; 7] =
                std::array::from_fn(|_| (70.0 - 20.0 * t / (n_trials as f64 * 14.0)).round());
            let p = power_at(&fx, &q, &dq, &tau, &temp, &tau0_sq);
            power_t.push((t, p));
            rec.state.t.push(t);
            rec.state.q.push(q);
            rec.state.dq.push(dq);
            rec.state
                .tau
                .push(std::array::from_fn(|j| tau[j] + noise_tau.sample(&mut rng)));
            rec.state.temp.push(temp);
            rec.state
                .gyro
                .push([0.002 * rng.random_range(-1.0..1.0), 0.0, 0.0]);
            rec.state.quat.push([1.0, 0.0, 0.0, 0.0]);
            t += 1.0 / RATE;
        }
        windows.push(motion.window(index));
    }
    sense(&mut rec, &power_t, &fx, &mut rng, t);
    (rec, windows)
}

/// The 1 Hz sensor on its own clock until `t_end`: mean power over [ts − L − 0.2, ts − L] plus
/// noise.
fn sense(
    rec: &mut Recording,
    power_t: &[(f64, f64)],
    fx: &Effects,
    rng: &mut rand_chacha::ChaCha8Rng,
    t_end: f64,
) {
    let t = t_end;
    let lag = fx.latency_s.unwrap_or(0.0);
    let noise = Normal::new(0.0, 0.15).unwrap();
    let mut ts = 0.537;
    let times: Vec<f64> = power_t.iter().map(|p| p.0).collect();
    while ts < t {
        let a = times.partition_point(|&x| x < ts - lag - 0.2);
        let b = times.partition_point(|&x| x < ts - lag);
        if b > a {
            let mean = power_t[a..b].iter().map(|p| p.1).sum::<f64>() / (b - a) as f64;
            rec.mbs.t.push(ts);
            rec.mbs.watts.push(mean + noise.sample(rng));
        }
        ts += 1.0 + rng.random_range(-0.03..0.03);
    }
}
