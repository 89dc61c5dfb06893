//! The twin's plant and session engine: joint tracking (the measured arm lags the command by
//! the PD loop's ~10 ms), true torques from rigid-body inverse dynamics + joint friction (+ payload),
//! winding temperatures, the arm rail's true power (paper model + effects + rest drift + artefacts),
//! the two 1 Hz power sensors on their own clocks, the standing rest of the robot and the IMU —
//! written message by message, in time order, to the MCAP output.

use std::collections::VecDeque;
use std::io::{Seek, Write};

use anyhow::Result;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::SimConfig;
use super::battery::Battery;
use super::effects::{
    ArmPower, Effects, FAN_MEAN_ON_OFF_S, PlantSample, SWAY_CORRELATION_S, arm_power,
};
use super::protocol::Schedule;
use super::thermal::ThermalState;
use super::truth::Noise;
use super::writer::{BmsFields, Cdr, ImuState, McapOut, MotorState, N_MOTORS, Topic};
use crate::N_JOINTS;
use crate::power::{PAIRS, PowerModel};
use crate::robot::{ArmDynamics, JointFriction};
use crate::trial::TrialWindow;

/// SDK index of the first left-arm motor.
pub const ARM_BASE: usize = 15;
/// MBS rest power [W].
pub const P_REST_W: f64 = 120.0;
/// BMS minus MBS at rest [W].
pub const BMS_OFFSET_W: f64 = 15.0;
/// Rest drift of the MBS rail: OU standard deviation [W] and time constant [s].
pub const REST_DRIFT: (f64, f64) = (0.3, 300.0);
/// Extra BMS noise (legs, computers): OU standard deviation [W] and time constant [s].
pub const BMS_OU: (f64, f64) = (2.0, 30.0);
/// Power-sensor averaging window [s].
pub const SENSOR_WINDOW_S: f64 = 0.2;
/// Power-sensor period [s] and uniform jitter [s].
pub const SENSOR_PERIOD: (f64, f64) = (1.0, 0.03);
/// Leg, waist and right-arm standing posture (SDK 0..=14 and 22..=28): q [rad], τ [Nm].
const STANDING: [(f64, f64); 22] = [
    (-0.1, -2.4),
    (0.0, 0.5),
    (0.0, 0.1),
    (0.3, 6.0),
    (-0.2, -3.0),
    (0.0, 0.2),
    (-0.1, -2.52),
    (0.0, -0.5),
    (0.0, -0.1),
    (0.3, 6.05),
    (-0.2, -3.0),
    (0.0, -0.2),
    (0.0, 0.0),
    (0.0, 0.0),
    (0.0, 0.0),
    // right arm at rest (mirror of the left arm's home torques)
    (0.0, -3.6),
    (0.0, -0.2),
    (0.0, 0.0),
    (0.0, -3.4),
    (0.0, 0.04),
    (0.0, -1.22),
    (0.0, 0.0),
];
/// Quantisation of the standing motors: q one 15-bit encoder step, dq, τ.
const STANDING_QUANT: (f64, f64, f64) = (std::f64::consts::TAU / 32768.0, 0.002, 0.01);

/// Message timestamps of a session [ns since the Unix epoch], each stream sorted.
#[derive(Debug, Clone, Default)]
pub struct Timeline {
    /// Time zero of the session [ns].
    pub start_ns: u64,
    /// `/lowstate` stamps.
    pub lowstate: Vec<u64>,
    /// `/arm_sdk` stamps (may be empty).
    pub arm_sdk: Vec<u64>,
    /// `/lf/mainboardstate` stamps.
    pub mbs: Vec<u64>,
    /// `/lf/bmsstate` stamps.
    pub bms: Vec<u64>,
}

/// Joint positions, velocities and accelerations at one instant (q, q̇, q̈).
pub type Motion = ([f64; N_JOINTS], [f64; N_JOINTS], [f64; N_JOINTS]);

/// Sampled joint reference (a recording's command or measured trajectory), linearly interpolated.
#[derive(Debug, Clone, Default)]
pub struct Sampled {
    /// Time [s].
    pub t: Vec<f64>,
    /// Position [rad].
    pub q: Vec<[f64; N_JOINTS]>,
    /// Velocity [rad/s].
    pub dq: Vec<[f64; N_JOINTS]>,
}

/// What the arm is commanded to do.
pub enum Reference<'a> {
    /// The protocol's analytic smooth steps.
    Protocol(&'a Schedule),
    /// A sampled trajectory read from a file as the engine reaches it.
    Streamed(&'a super::like::StreamedSampled),
}

impl Reference<'_> {
    /// q, q̇, q̈ at `t`; `hint` is a cursor for monotone queries.
    pub fn eval(&self, t: f64, hint: &mut usize) -> Motion {
        match self {
            Reference::Protocol(s) => s.eval(t, hint),
            Reference::Streamed(s) => s.eval(t, hint),
        }
    }
}

impl Sampled {
    /// q, q̇, q̈ at `t`, linearly interpolated (q̈ the slope of q̇ between the two samples); held
    /// at the first and the last sample outside them. `hint` is a cursor for monotone queries.
    pub fn eval(&self, t: f64, hint: &mut usize) -> Motion {
        let s = self;
        let zero = [0.0; N_JOINTS];
        let n = s.t.len();
        if n == 0 {
            return (zero, zero, zero);
        }
        while *hint + 1 < n && s.t[*hint + 1] <= t {
            *hint += 1;
        }
        while *hint > 0 && s.t[*hint] > t {
            *hint -= 1;
        }
        let k = *hint;
        if k + 1 >= n || t <= s.t[0] {
            let k = if t <= s.t[0] { 0 } else { n - 1 };
            return (s.q[k], s.dq[k], zero);
        }
        let h = s.t[k + 1] - s.t[k];
        let u = if h > 0.0 {
            ((t - s.t[k]) / h).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let lerp =
            |v: &[[f64; N_JOINTS]]| std::array::from_fn(|j| v[k][j] + u * (v[k + 1][j] - v[k][j]));
        let slope = |j: usize| {
            if h > 0.0 {
                (s.dq[k + 1][j] - s.dq[k][j]) / h
            } else {
                0.0
            }
        };
        (lerp(&s.q), lerp(&s.dq), std::array::from_fn(slope))
    }
}

/// Body sway of a balance-contaminated trial.
#[derive(Debug, Clone, Copy)]
pub struct Sway {
    /// Amplitude [rad/s].
    pub amplitude: f64,
    /// Frequency [Hz].
    pub freq_hz: f64,
    /// Direction of the sway axis in the body x-y plane [rad].
    pub axis: f64,
}

/// A hardware-event step on the MBS rail.
#[derive(Debug, Clone, Copy)]
pub struct OutlierStep {
    /// Start [s].
    pub start: f64,
    /// Duration [s].
    pub duration: f64,
    /// Step [W].
    pub step_w: f64,
}

/// The artefacts drawn for one trial (balance sway, hardware-event step). The trial's times are
/// its [`TrialWindow`]; this record holds only what the simulator alone knows about it (what the
/// session contains but no reader of a recording can see), so the shared trial type stays free
/// of simulator-only data. One per trial, in the order of [`Engine::trials`].
#[derive(Debug, Clone, Copy, Default)]
pub struct TrialArtefacts {
    /// Balance contamination (over the trajectory window).
    pub sway: Option<Sway>,
    /// Hardware-event outlier.
    pub outlier: Option<OutlierStep>,
}

/// Sway envelope: 0.5 s smooth ramps in and out of the trajectory window, 1 between.
fn sway_envelope(t: f64, t0: f64, t1: f64) -> f64 {
    if t <= t0 || t >= t1 {
        return 0.0;
    }
    let ramp = 0.5f64.min(0.5 * (t1 - t0));
    let u = ((t - t0) / ramp).min((t1 - t) / ramp).min(1.0);
    3.0 * u * u - 2.0 * u * u * u
}

/// Per-trial sums over the pre-idle and trajectory windows.
#[derive(Debug, Clone, Copy, Default)]
pub struct TrialSums {
    /// Samples in the pre-idle window.
    pub n_pre: u64,
    /// Σ arm power (base + effects) in pre-idle.
    pub arm_pre: f64,
    /// Σ effect power in pre-idle.
    pub eff_pre: f64,
    /// Samples in the trajectory window.
    pub n_traj: u64,
    /// Σ arm power in the trajectory window.
    pub arm_traj: f64,
    /// Σ effect power in the trajectory window.
    pub eff_traj: f64,
    /// Σ leak power in the trajectory window.
    pub leak_traj: f64,
    /// Σ winding temperature in the trajectory window.
    pub temp_traj: [f64; N_JOINTS],
}

/// What the engine reports besides the file.
#[derive(Debug, Clone, Default)]
pub struct RunStats {
    /// Messages per topic (by [`Topic`] index).
    pub counts: [u64; 4],
    /// Per-trial sums (same order as the trials).
    pub trials: Vec<TrialSums>,
    /// Home torque of the true plant [Nm].
    pub tau_home: [f64; N_JOINTS],
    /// Winding temperature range [°C].
    pub temp_range: [f64; 2],
    /// State-of-charge range.
    pub soc_range: [f64; 2],
    /// Session means of the base model's terms [W]: mech, copper, coulomb, viscous, interaction.
    pub mean_terms: [f64; 5],
}

/// Exact discretisation of an Ornstein–Uhlenbeck process step.
fn ou_step(x: f64, dt: f64, (sigma, tau): (f64, f64), rng: &mut ChaCha8Rng) -> f64 {
    let k = (-dt / tau).exp();
    x * k + sigma * (1.0 - k * k).max(0.0).sqrt() * gauss(rng)
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    StandardNormal.sample(rng)
}

fn quant(v: f64, step: f64) -> f64 {
    (v / step).round() * step
}

/// Everything the engine needs besides the output.
pub struct Engine<'a> {
    /// Configuration.
    pub cfg: &'a SimConfig,
    /// True plant dynamics (with payload when the effect is on).
    pub dyn_true: &'a ArmDynamics,
    /// URDF-only dynamics (for the payload's effect accounting); `None` without payload.
    pub dyn_urdf: Option<&'a ArmDynamics>,
    /// Joint friction inside τ.
    pub friction: &'a JointFriction,
    /// Message stamps.
    pub timeline: &'a Timeline,
    /// The command.
    pub reference: Reference<'a>,
    /// Trials, as scheduled (empty for `simulate_like`).
    pub trials: &'a [TrialWindow],
    /// Each trial's artefacts (same order as `trials`; a missing entry means none).
    pub artefacts: &'a [TrialArtefacts],
}

/// The engine's state between events: the plant's slow states, the sensors' history, the
/// message counters and cursors, and the statistics so far.
struct RunState {
    /// Home torque of the true plant [Nm].
    tau_home: [f64; N_JOINTS],
    /// Home torque of the URDF-only plant [Nm] (with a payload).
    tau_home_urdf: Option<[f64; N_JOINTS]>,
    /// Squared home torques.
    tau0_sq: [f64; N_JOINTS],
    /// Sensor latency of the latency effect [s].
    latency: f64,
    /// How much rail-power history the sensors need [s].
    keep_s: f64,
    thermal: ThermalState,
    stats: RunStats,
    cdr: Cdr,
    /// (t, rail power) of the recent state samples.
    power_hist: VecDeque<(f64, f64)>,
    drift: f64,
    bms_ou: f64,
    t_bms_prev: f64,
    soc: f64,
    /// Pack terminal voltage at the last state sample [V] (the realistic battery; the linear
    /// one's is a function of `soc` alone).
    pack_v: f64,
    yaw0: f64,
    tick: u32,
    ref_hint: usize,
    cmd_hint: usize,
    trial_cursor: usize,
    t_prev: Option<f64>,
    sway_angle: [f64; 2],
    /// Ambient sway of the balance-leak effect.
    ambient: [f64; 2],
    /// The ambient sway's own random stream (switching the effect on leaves every other random
    /// draw of the session unchanged).
    sway_rng: ChaCha8Rng,
    /// The switching fan of the rail-load effect (its own random stream too).
    fan: Option<Fan>,
    /// The second switching fan (`fan0_load`, reported in `fan_state[0]`; a stream of its own).
    fan0: Option<Fan>,
    term_sums: [f64; 5],
    motors: [MotorState; N_MOTORS],
    i_ls: usize,
    i_cmd: usize,
    i_mbs: usize,
    i_bms: usize,
}

/// One state sample of the true plant: tracked motion, true torques and the arm's power.
struct PlantStep {
    q: [f64; N_JOINTS],
    dq: [f64; N_JOINTS],
    tau: [f64; N_JOINTS],
    /// The arm's power (base model + power-changing effects).
    power: ArmPower,
    /// Effect power so far (effects, fan load, payload share) [W].
    eff: f64,
    /// Fan load of the rail-load effects [W].
    fan_w: f64,
}

/// The trial artefacts active at one state sample.
struct ArtefactsNow {
    /// Contamination sway rate [rad/s] and its axis [rad].
    sway: f64,
    sway_axis: f64,
    /// Hardware-event step [W].
    step_w: f64,
    /// The trial whose pre-idle..post-idle window holds the sample.
    trial_here: Option<usize>,
}

impl Engine<'_> {
    /// Run the session, writing every message to `out` in time order.
    pub fn run<W: Write + Seek>(
        &self,
        out: &mut McapOut<W>,
        rng: &mut ChaCha8Rng,
        progress: &dyn Fn(u64),
    ) -> Result<RunStats> {
        let tl = self.timeline;
        let t_of = |ns: u64| (ns as i128 - tl.start_ns as i128) as f64 * 1e-9;
        let mut st = self.start(rng);
        loop {
            // Next event in time order; ties: lowstate, arm_sdk, bms, mbs.
            let candidates = [
                tl.lowstate.get(st.i_ls).copied(),
                tl.arm_sdk.get(st.i_cmd).copied(),
                tl.bms.get(st.i_bms).copied(),
                tl.mbs.get(st.i_mbs).copied(),
            ];
            let Some((which, ns)) = candidates
                .iter()
                .enumerate()
                .filter_map(|(k, v)| v.map(|v| (k, v)))
                .min_by_key(|&(k, v)| (v, k))
            else {
                break;
            };
            let t = t_of(ns);
            match which {
                0 => {
                    self.lowstate(&mut st, out, rng, ns, t)?;
                    if st.i_ls.is_multiple_of(4096) {
                        progress(st.i_ls as u64);
                    }
                }
                1 => self.arm_sdk(&mut st, out, ns, t)?,
                2 => out.write(Topic::Bms, ns, self.bms(&mut st, rng, t))?,
                _ => out.write(Topic::Mbs, ns, self.mbs(&mut st, rng, t))?,
            }
        }
        let n = st.i_ls.max(1) as f64;
        let mut stats = st.stats;
        stats.mean_terms = st.term_sums.map(|s| s / n);
        stats.counts = out.counts();
        if !stats.temp_range[0].is_finite() {
            stats.temp_range = [self.cfg.t_start_c; 2];
            stats.soc_range = [st.soc; 2];
        }
        Ok(stats)
    }

    /// Pack terminal voltage now [V]: the linear battery's open-circuit voltage at the current
    /// charge, the realistic one's voltage under the last state sample's load.
    fn pack_volts(&self, st: &RunState) -> f64 {
        match self.cfg.battery {
            Battery::Linear => Battery::Linear.open_circuit_volts(st.soc),
            Battery::Realistic => st.pack_v,
        }
    }

    /// Stage: the state at session start (draws the battery charge, the IMU yaw and the tick).
    fn start(&self, rng: &mut ChaCha8Rng) -> RunState {
        let cfg = self.cfg;
        let effects: &Effects = &cfg.effects;
        let zero = [0.0; N_JOINTS];
        let tau_home = self.dyn_true.gravity_torque(&zero);
        let tau_home_urdf = self.dyn_urdf.map(|d| d.gravity_torque(&zero));
        let tau0_sq = tau_home.map(|v| v * v);
        let latency = effects.latency.map_or(0.0, |l| l.seconds);
        let keep_s = latency + cfg.sensor_window_s + 2.0;

        let mut thermal = ThermalState::new(cfg.thermal, cfg.t_start_c);
        if let Some(h) = cfg.housing_start_c {
            thermal.set_housing(h);
        }
        let stats = RunStats {
            trials: vec![TrialSums::default(); self.trials.len()],
            tau_home,
            temp_range: [f64::INFINITY, f64::NEG_INFINITY],
            soc_range: [f64::INFINITY, f64::NEG_INFINITY],
            ..Default::default()
        };
        // Drawn even when the start is given, so the random streams stay the same.
        let drawn = 0.98 - 0.02 * rng.random::<f64>();
        let soc = cfg.soc_start.unwrap_or(drawn);
        let yaw0 = rng.random_range(-0.5..0.5);
        let tick: u32 = rng.random_range(1_000_000..9_000_000);
        RunState {
            tau_home,
            tau_home_urdf,
            tau0_sq,
            latency,
            keep_s,
            thermal,
            stats,
            cdr: Cdr::default(),
            power_hist: VecDeque::with_capacity(1024),
            drift: 0.0,
            bms_ou: 0.0,
            t_bms_prev: 0.0,
            soc,
            pack_v: cfg.battery.terminal_volts(soc, P_REST_W + BMS_OFFSET_W),
            yaw0,
            tick,
            ref_hint: 0,
            cmd_hint: 0,
            trial_cursor: 0,
            t_prev: None,
            sway_angle: [0.0; 2],
            ambient: [0.0; 2],
            sway_rng: ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x005a_1a4c_e000_u64),
            // The fan of `fan_meter` cycles as the rail load's would, drawing nothing.
            fan: (effects.fan_load.map(|l| l.watts))
                .or(effects.fan_meter.map(|_| 0.0))
                .map(|w| Fan::new(w, cfg.seed)),
            fan0: effects
                .fan0_load
                .map(|l| Fan::new(l.watts, cfg.seed ^ 0x0f00_0000_0000_u64)),
            term_sums: [0.0; 5],
            motors: [MotorState::default(); N_MOTORS],
            i_ls: 0,
            i_cmd: 0,
            i_mbs: 0,
            i_bms: 0,
        }
    }

    /// Stage (one `/lowstate` tick): the true plant, the trial's artefacts, the body sway and the
    /// balance leak, the rail power and its bookkeeping, then the message.
    fn lowstate<W: Write + Seek>(
        &self,
        st: &mut RunState,
        out: &mut McapOut<W>,
        rng: &mut ChaCha8Rng,
        ns: u64,
        t: f64,
    ) -> Result<()> {
        st.i_ls += 1;
        let dt = st.t_prev.map_or(0.01, |p| (t - p).max(0.0));
        st.t_prev = Some(t);
        let plant = self.plant_step(st, t, dt);
        let art = self.artefacts_at(st, t);
        let (rate, leak) = self.body_rate(st, &art, dt);
        let mut eff = plant.eff;
        if self.cfg.effects.balance_leak.is_some() {
            // With the effect on, all of the leak is the concealed effect's power.
            eff += leak;
        }
        st.drift = ou_step(st.drift, dt, REST_DRIFT, rng);
        self.account(st, t, dt, &plant, eff, leak, &art);
        let msg = self.lowstate_msg(st, rng, t, dt, &plant, rate);
        out.write(Topic::LowState, ns, msg)
    }

    /// Stage: the arm tracks the command; true torques, winding temperatures and the arm's
    /// power (with the fan load and the payload's share as effect power).
    fn plant_step(&self, st: &mut RunState, t: f64, dt: f64) -> PlantStep {
        let cfg = self.cfg;
        let model: &PowerModel = &cfg.truth;
        let (q, dq, ddq) = self
            .reference
            .eval(t - cfg.tracking_lag_s, &mut st.ref_hint);
        let fr = self.friction.torque(&dq);
        let rigid = self.dyn_true.inverse_dynamics(&q, &dq, &ddq);
        let tau: [f64; N_JOINTS] = std::array::from_fn(|i| rigid[i] + fr[i]);
        let bus_volts = self.pack_volts(st) - 0.15;
        let thermal = &mut st.thermal;
        thermal.step(t, dt, &tau);
        let housing_c: [f64; N_JOINTS] = std::array::from_fn(|i| thermal.housing_c(i));
        let sample = PlantSample {
            q: &q,
            tau: &tau,
            dq: &dq,
            tau_home: &st.tau_home,
            winding_c: &thermal.winding_c,
            housing_c: &housing_c,
            bus_volts,
        };
        let p = arm_power(model, &cfg.effects, &sample);
        let mut eff = p.effects;
        let fan_w = st.fan.as_mut().map_or(0.0, |f| f.load_at(t))
            + st.fan0.as_mut().map_or(0.0, |f| f.load_at(t));
        eff += fan_w;
        if let (Some(d), Some(th_u)) = (self.dyn_urdf, st.tau_home_urdf) {
            // The payload's share: the base model on true minus URDF-only torques.
            let rigid_u = d.inverse_dynamics(&q, &dq, &ddq);
            let tau_u: [f64; N_JOINTS] = std::array::from_fn(|i| rigid_u[i] + fr[i]);
            eff += p.base - model.predict(&tau_u, &dq, &th_u.map(|v| v * v));
        }
        accumulate_terms(model, &tau, &dq, &st.tau0_sq, &mut st.term_sums);
        PlantStep {
            q,
            dq,
            tau,
            power: p,
            eff,
            fan_w,
        }
    }

    /// Stage: the current trial's artefacts at `t` (contamination sway, outlier step).
    fn artefacts_at(&self, st: &mut RunState, t: f64) -> ArtefactsNow {
        while st.trial_cursor + 1 < self.trials.len()
            && self.trials[st.trial_cursor + 1].t_pre_start <= t
        {
            st.trial_cursor += 1;
        }
        let mut now = ArtefactsNow {
            sway: 0.0,
            sway_axis: 0.0,
            step_w: 0.0,
            trial_here: None,
        };
        if let Some(tp) = self.trials.get(st.trial_cursor) {
            let art = self
                .artefacts
                .get(st.trial_cursor)
                .copied()
                .unwrap_or_default();
            if let Some(s) = art.sway {
                now.sway = s.amplitude
                    * sway_envelope(t, tp.t_traj_start, tp.t_post_end)
                    * (std::f64::consts::TAU * s.freq_hz * (t - tp.t_traj_start)).sin();
                now.sway_axis = s.axis;
            }
            if let Some(o) = art.outlier
                && t >= o.start
                && t < o.start + o.duration
            {
                now.step_w = o.step_w;
            }
            if t >= tp.t_pre_start && t < tp.t_post_end {
                now.trial_here = Some(st.trial_cursor);
            }
        }
        now
    }

    /// Stage: body rate about the two horizontal axes — contamination sway plus, with the
    /// balance-leak effect, the ambient sway — and the legs' balancing power leaking in ∝ |ω|².
    fn body_rate(&self, st: &mut RunState, art: &ArtefactsNow, dt: f64) -> ([f64; 2], f64) {
        let sway = art.sway;
        let mut rate = [sway * art.sway_axis.cos(), sway * art.sway_axis.sin()];
        let leak = match self.cfg.effects.balance_leak {
            None => self.cfg.artefacts.k_leak * sway * sway,
            Some(b) => {
                for (r, a) in rate.iter_mut().zip(st.ambient.iter_mut()) {
                    *a = ou_step(*a, dt, (b.sway_rad_s, SWAY_CORRELATION_S), &mut st.sway_rng);
                    *r += *a;
                }
                b.w_per_rad2_s2 * (rate[0] * rate[0] + rate[1] * rate[1])
            }
        };
        (rate, leak)
    }

    /// Stage: the rail power into the sensors' history, the battery, and the run's statistics.
    #[allow(clippy::too_many_arguments)]
    fn account(
        &self,
        st: &mut RunState,
        t: f64,
        dt: f64,
        plant: &PlantStep,
        eff: f64,
        leak: f64,
        art: &ArtefactsNow,
    ) {
        let p = &plant.power;
        let p_arm = p.base + p.effects;
        let p_rail = P_REST_W + st.drift + p.base + p.effects + leak + art.step_w + plant.fan_w;
        let keep_s = st.keep_s;
        while st
            .power_hist
            .front()
            .is_some_and(|&(tf, _)| tf < t - keep_s)
        {
            st.power_hist.pop_front();
        }
        st.power_hist.push_back((t, p_rail));
        let battery = self.cfg.battery;
        if battery == Battery::Linear {
            st.soc -= battery.soc_used(p_rail + BMS_OFFSET_W, 0.0, dt);
        } else {
            // Everything the pack feeds (the rail, the rest of the robot's offset and noise).
            let load = p_rail + BMS_OFFSET_W + st.bms_ou;
            st.soc -= battery.soc_used(load, st.pack_v, dt);
            st.pack_v = battery.terminal_volts(st.soc, load);
        }
        let (stats, soc) = (&mut st.stats, st.soc);
        stats.soc_range = [stats.soc_range[0].min(soc), stats.soc_range[1].max(soc)];
        for &w in &st.thermal.winding_c {
            stats.temp_range = [stats.temp_range[0].min(w), stats.temp_range[1].max(w)];
        }
        if let Some(k) = art.trial_here {
            let tp = &self.trials[k];
            let s = &mut stats.trials[k];
            if t < tp.t_traj_start {
                s.n_pre += 1;
                s.arm_pre += p_arm;
                s.eff_pre += eff;
            } else {
                s.n_traj += 1;
                s.arm_traj += p_arm;
                s.eff_traj += eff;
                s.leak_traj += leak;
                for i in 0..N_JOINTS {
                    s.temp_traj[i] += st.thermal.winding_c[i];
                }
            }
        }
    }

    /// Stage: the `/lowstate` message's payload — every motor (the standing rest of the robot quantised,
    /// the arm with sensor noise) and the pelvis IMU.
    fn lowstate_msg<'a>(
        &self,
        st: &'a mut RunState,
        rng: &mut ChaCha8Rng,
        t: f64,
        dt: f64,
        plant: &PlantStep,
        rate: [f64; 2],
    ) -> &'a [u8] {
        let noise: Noise = self.cfg.noise;
        let (q, dq, tau) = (&plant.q, &plant.dq, &plant.tau);
        let vol = quant(self.pack_volts(st) - 0.15 + 0.03 * gauss(rng), 0.1) as f32;
        for (slot, &(q0, tau0)) in STANDING.iter().enumerate() {
            let k = if slot < 15 { slot } else { slot + N_JOINTS };
            st.motors[k] = MotorState {
                mode: 1,
                q: quant(q0 + noise.q_rad * gauss(rng), STANDING_QUANT.0) as f32,
                dq: quant(noise.dq_rad_s * gauss(rng), STANDING_QUANT.1) as f32,
                tau_est: quant(tau0 + noise.tau_nm * gauss(rng), STANDING_QUANT.2) as f32,
                temperature: [30, 28],
                vol,
            };
        }
        for i in 0..N_JOINTS {
            st.motors[ARM_BASE + i] = MotorState {
                mode: 1,
                q: (q[i] + noise.q_rad * gauss(rng)) as f32,
                dq: (dq[i] + noise.dq_rad_s * gauss(rng)) as f32,
                tau_est: (tau[i] + noise.tau_nm * gauss(rng)) as f32,
                temperature: [
                    st.thermal.winding_c[i].round() as i16,
                    st.thermal.housing_c(i).round() as i16,
                ],
                vol,
            };
        }
        for (angle, r) in st.sway_angle.iter_mut().zip(rate) {
            *angle += r * dt;
            if self.cfg.effects.balance_leak.is_some() {
                // The balance controller pulls the body back (2 s time constant).
                *angle -= *angle * dt / 2.0;
            }
        }
        let imu = imu_state(t, st.yaw0, rate, st.sway_angle, noise.gyro_rad_s, rng);
        let tick = st.tick;
        st.tick = tick.wrapping_add(10);
        st.cdr.low_state(tick, &imu, &st.motors)
    }

    /// Stage (one `/arm_sdk` message): the command.
    fn arm_sdk<W: Write + Seek>(
        &self,
        st: &mut RunState,
        out: &mut McapOut<W>,
        ns: u64,
        t: f64,
    ) -> Result<()> {
        st.i_cmd += 1;
        let (q, dq, _) = self.reference.eval(t, &mut st.cmd_hint);
        out.write(
            Topic::ArmSdk,
            ns,
            st.cdr.low_cmd(ARM_BASE, &q, &dq, 400.0, 12.0),
        )
    }

    /// Stage (one `/lf/bmsstate` reading, its payload): the battery's view of the rail power plus the rest
    /// of the robot.
    fn bms<'a>(&self, st: &'a mut RunState, rng: &mut ChaCha8Rng, t: f64) -> &'a [u8] {
        let noise: Noise = self.cfg.noise;
        st.i_bms += 1;
        let p = window_mean(&st.power_hist, t - st.latency, self.cfg.sensor_window_s);
        st.bms_ou = ou_step(st.bms_ou, (t - st.t_bms_prev).max(0.0), BMS_OU, rng);
        st.t_bms_prev = t;
        let p_bms = p + BMS_OFFSET_W + st.bms_ou + noise.bms_w * gauss(rng);
        let volts = quant(self.pack_volts(st), 0.01);
        let cell = (volts / 13.0 * 1000.0).round();
        let mut cell_mv = [0u16; 13];
        for (c, v) in cell_mv.iter_mut().enumerate() {
            *v = (cell + [-2.0, 0.0, 2.0, -1.0, 1.0][c % 5]).clamp(0.0, 65535.0) as u16;
        }
        let temp = 28.0 + 2.0 * t / 3600.0;
        let b = BmsFields {
            pack_mv: (volts * 1000.0).round() as u32,
            current_ma: (p_bms / volts * 1000.0).round() as i32,
            soc_pct: (st.soc * 100.0).round().clamp(0.0, 100.0) as u8,
            temps_c: [
                temp as i16,
                (temp as i16).saturating_add(1),
                (temp as i16).saturating_sub(1),
                temp as i16,
            ],
            cell_mv,
        };
        st.cdr.bms_state(&b)
    }

    /// Stage (one `/lf/mainboardstate` reading, its payload): the arm rail's sensor and the fans.
    fn mbs<'a>(&self, st: &'a mut RunState, rng: &mut ChaCha8Rng, t: f64) -> &'a [u8] {
        let noise: Noise = self.cfg.noise;
        st.i_mbs += 1;
        let artefact = match (self.cfg.effects.fan_meter, &st.fan) {
            (Some(m), Some(f)) if f.on => m.watts,
            _ => 0.0,
        };
        let p = window_mean(&st.power_hist, t - st.latency, self.cfg.sensor_window_s)
            + artefact
            + noise.mbs_w * gauss(rng);
        let volts = quant(self.pack_volts(st) - 0.4 + 0.005 * gauss(rng), 0.01);
        let amps = quant(p / volts, 0.001);
        let rpm = 2085.0 + 10.0 * gauss(rng);
        let rpm2 = match st.fan.as_mut() {
            None => rpm - 30.0,
            Some(f) => f.rpm(),
        };
        let rpm = st.fan0.as_mut().map_or(rpm, |f| f.rpm());
        let fans = [rpm as u16, rpm2 as u16];
        st.cdr
            .main_board_state(volts as f32, amps as f32, fans, [39, 36])
    }
}

/// The switching main-board fan of the rail-load effect: on/off with exponential durations.
struct Fan {
    watts: f64,
    on: bool,
    next_toggle: f64,
    rng: ChaCha8Rng,
}

impl Fan {
    fn new(watts: f64, seed: u64) -> Fan {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x00fa_9100_ad00_u64);
        let first = FAN_MEAN_ON_OFF_S.1 * -(1.0 - rng.random::<f64>()).ln();
        Fan {
            watts,
            on: false,
            next_toggle: first,
            rng,
        }
    }

    /// Advance to session time `t` and return the load drawn then [W].
    fn load_at(&mut self, t: f64) -> f64 {
        while t >= self.next_toggle {
            self.on = !self.on;
            let mean = if self.on {
                FAN_MEAN_ON_OFF_S.0
            } else {
                FAN_MEAN_ON_OFF_S.1
            };
            self.next_toggle += mean * -(1.0 - self.rng.random::<f64>()).ln();
        }
        if self.on { self.watts } else { 0.0 }
    }

    /// Speed the board reports for the fan now [rpm].
    fn rpm(&mut self) -> f64 {
        if self.on {
            3000.0 + 10.0 * gauss(&mut self.rng)
        } else {
            0.0
        }
    }
}

/// Mean of the power samples with time in (end − window, end]; the nearest sample when none is
/// inside (a reading before the first state sample).
fn window_mean(hist: &VecDeque<(f64, f64)>, end: f64, window: f64) -> f64 {
    let mut sum = 0.0;
    let mut n = 0u32;
    for &(t, p) in hist.iter().rev() {
        if t > end {
            continue;
        }
        if t <= end - window {
            break;
        }
        sum += p;
        n += 1;
    }
    if n > 0 {
        return sum / n as f64;
    }
    let nearest = hist
        .iter()
        .min_by(|a, b| (a.0 - end).abs().total_cmp(&(b.0 - end).abs()));
    nearest.map_or(P_REST_W, |&(_, p)| p)
}

fn accumulate_terms(
    m: &PowerModel,
    tau: &[f64; N_JOINTS],
    dq: &[f64; N_JOINTS],
    tau0_sq: &[f64; N_JOINTS],
    sums: &mut [f64; 5],
) {
    for i in 0..N_JOINTS {
        sums[0] += m.a[i] * tau[i] * dq[i];
        sums[1] += m.b[i] * (tau[i] * tau[i] - tau0_sq[i]);
        sums[2] += m.c[i] * dq[i].abs();
        sums[3] += m.d[i] * dq[i] * dq[i];
    }
    for (k, &(i, j)) in PAIRS.iter().enumerate() {
        sums[4] += m.e[k] * dq[i].abs() * dq[j].abs();
    }
}

/// Pelvis IMU of the standing robot: fixed small roll/pitch, slowly drifting yaw, plus the
/// balance sway (body rate `rate` about the horizontal axes, its integral in roll/pitch).
fn imu_state(
    t: f64,
    yaw0: f64,
    rate: [f64; 2],
    sway_angle: [f64; 2],
    gyro_noise: f64,
    rng: &mut ChaCha8Rng,
) -> ImuState {
    let roll = 0.004 + sway_angle[0];
    let pitch = 0.015 + sway_angle[1];
    let yaw = yaw0 + 1.7e-5 * t;
    let (sr, cr) = (0.5 * roll).sin_cos();
    let (sp, cp) = (0.5 * pitch).sin_cos();
    let (sy, cy) = (0.5 * yaw).sin_cos();
    let quat = [
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ];
    let g = 9.81;
    let acc = [
        -g * pitch.sin(),
        g * roll.sin() * pitch.cos(),
        g * roll.cos() * pitch.cos(),
    ];
    ImuState {
        quaternion: quat.map(|v| v as f32),
        gyroscope: [
            (rate[0] + gyro_noise * gauss(rng)) as f32,
            (rate[1] + gyro_noise * gauss(rng)) as f32,
            (gyro_noise * gauss(rng)) as f32,
        ],
        accelerometer: std::array::from_fn(|k| (acc[k] + 0.02 * gauss(rng)) as f32),
        rpy: [roll as f32, pitch as f32, yaw as f32],
        temperature: 38,
    }
}
