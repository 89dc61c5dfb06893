//! Digital twin of the G1 left arm: simulates recording sessions of the paper's protocol (or
//! re-runs a real recording's trajectory) through URDF rigid-body dynamics, joint friction, a
//! thermal model and the paper's power model with switchable extra physics, and writes them in
//! the robot's own format (MCAP, `unitree_hg` CDR messages) plus a ground-truth JSON sidecar.
//!
//! ```no_run
//! use g1viz::sim::{SimConfig, Preset, simulate};
//! let mut cfg = SimConfig { preset: Preset::Smoke, seed: 7, ..SimConfig::default() };
//! cfg.effects.enable("braking=0.25")?;
//! let truth = simulate(&cfg, std::path::Path::new("smoke.mcap"))?; // + smoke.truth.json
//! println!("{} trials", truth.trials.len());
//! # anyhow::Ok(())
//! ```

mod battery;
mod effects;
pub(crate) mod like;
pub(crate) mod plant;
pub(crate) mod protocol;
pub(crate) mod thermal;
mod truth;
pub(crate) mod writer;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

pub use battery::{Battery, NMC_OCV, PACK_AH, PACK_RESISTANCE_OHM, nmc_cell_ocv};
pub use effects::{
    BalanceLeak, BrakingAsymmetry, BusLoss, BusPowerLoss, DEFAULT_PAYLOAD, DriveLoss, EFFECT_NAMES,
    Effects, ElectronicsLoss, FAN_MEAN_ON_OFF_S, GearFriction, HarnessDrag, HousingFriction,
    JOINT_FRICTION_PATTERN, JointFrictionExcess, MeterOffset, RailLoad, SWAY_CORRELATION_S,
    SensorLatency, StribeckFriction, SwitchingLoss, THERMAL_REFERENCE_C, ThermalDrift,
};
pub use like::{simulate_like, simulate_like_file};
pub use protocol::Preset;
pub use thermal::ThermalModel;
pub use truth::{
    ArtefactsTruth, Contamination, FrictionTruth, Generator, Joints, MessageCounts, Noise,
    Outliers, PlantTruth, ProtocolTruth, SensorTruth, SessionTimes, ThermalTruth, Theta,
    TopicEntry, TrialTruth, Truth,
};

use crate::N_JOINTS;
use crate::power::{PAIRS, PowerModel};
use crate::robot::{ArmDynamics, JointFriction, RobotModel};
use plant::{Engine, OutlierStep, Reference, Sway, Timeline, TrialArtefacts};
use protocol::Schedule;

/// URDF joint names of the left arm, model order.
pub use crate::robot::G1_LEFT_ARM_JOINTS as JOINT_NAMES;
/// Short joint names, model order.
pub use crate::signals::JOINT_SHORT;

/// Session epoch: the start time is this plus a seed-dependent offset of up to 3 h.
const EPOCH_NS: u64 = 1_773_482_400_000_000_000; // 2026-03-14T10:00:00Z
const EPOCH_ISO: &str = "2026-03-14T10:00:00+00:00";

/// Balance contamination and hardware-event outliers (artefacts of every session, not effects).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Artefacts {
    /// Target fraction of contaminated trials; the probability grows with speed^1.5 and joint
    /// count^0.8 (0 = off).
    pub contamination_fraction: f64,
    /// Sway amplitude range [rad/s].
    pub sway_amplitude_rad_s: [f64; 2],
    /// Sway frequency range [Hz].
    pub sway_freq_hz: [f64; 2],
    /// MBS leak gain: leak = k·|sway|² [W/(rad/s)²].
    pub k_leak: f64,
    /// Probability of a hardware-event outlier per trial (0 = off).
    pub outlier_fraction: f64,
    /// Outlier step range [W].
    pub outlier_step_w: [f64; 2],
    /// Outlier duration range [s].
    pub outlier_duration_s: [f64; 2],
}

impl Default for Artefacts {
    fn default() -> Self {
        Artefacts {
            contamination_fraction: 0.1,
            outlier_fraction: 0.015,
            ..Artefacts::NONE
        }
    }
}

impl Artefacts {
    /// No contamination and no outliers (clean sessions for tests).
    pub const NONE: Artefacts = Artefacts {
        contamination_fraction: 0.0,
        sway_amplitude_rad_s: [0.05, 0.3],
        sway_freq_hz: [1.0, 2.0],
        k_leak: 500.0 / 9.0,
        outlier_fraction: 0.0,
        outlier_step_w: [10.0, 20.0],
        outlier_duration_s: [2.0, 5.0],
    };
}

/// Joint friction inside the measured torque, as in the shared recordings' truth
/// (`plant.joint_friction_in_tau`).
pub const DEFAULT_FRICTION: JointFriction = JointFriction {
    coulomb_nm: [0.45, 0.4, 0.3, 0.35, 0.22, 0.2, 0.2],
    viscous_nms: [0.18, 0.15, 0.12, 0.12, 0.07, 0.06, 0.05],
};

/// Everything a simulated session depends on.
#[derive(Debug, Clone)]
pub struct SimConfig {
    /// Which trials.
    pub preset: Preset,
    /// RNG seed: same seed, same bytes.
    pub seed: u64,
    /// Extra physics switched on (default: none — the paper's plant).
    pub effects: Effects,
    /// True power-model parameters (default: the paper's tables).
    pub truth: PowerModel,
    /// URDF for the dynamics (default: the shipped one).
    pub urdf: Option<PathBuf>,
    /// Dex3-1 hand mounted (its inertia in the wrist).
    pub with_hand: bool,
    /// Seed of the route library (waypoints); the hold-out preset reuses the identification
    /// routes when both use the same route seed.
    pub route_seed: u64,
    /// Winding temperature at session start [°C] (a warm robot: 50–70 °C).
    pub t_start_c: f64,
    /// Housing temperature at session start [°C]; `None`: settled with the winding (ambient +
    /// 70 % of the winding's rise). A motor worked hard just before has a hot winding in a
    /// housing that is still cool.
    pub housing_start_c: Option<f64>,
    /// Motor thermal constants.
    pub thermal: ThermalModel,
    /// Battery model (default: linear, every documented figure's).
    pub battery: Battery,
    /// State of charge at session start (0..=1); `None`: a freshly charged pack, drawn in
    /// 0.96–0.98.
    pub soc_start: Option<f64>,
    /// Joint friction inside τ.
    pub friction: JointFriction,
    /// Measurement noise.
    pub noise: Noise,
    /// Contamination and outliers.
    pub artefacts: Artefacts,
    /// Lag of the measured joints behind the command (the PD loop, kp = 400, kd = 12) [s].
    pub tracking_lag_s: f64,
    /// Averaging window W of the power sensors [s] (a reading stamped t averages the W before
    /// t − latency; the G1's is about 0.2 s).
    pub sensor_window_s: f64,
    /// Show a progress bar on stderr (only drawn when stderr is a terminal).
    pub progress: bool,
    /// Days after the epoch (2026-03-14) the session starts on (a fleet's daily sessions).
    pub start_day: u64,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            preset: Preset::Smoke,
            seed: 1,
            effects: Effects::default(),
            truth: PowerModel::PAPER,
            urdf: None,
            with_hand: true,
            route_seed: 0,
            t_start_c: 30.0,
            housing_start_c: None,
            thermal: ThermalModel::default(),
            battery: Battery::Linear,
            soc_start: None,
            friction: DEFAULT_FRICTION,
            noise: Noise::default(),
            artefacts: Artefacts::default(),
            tracking_lag_s: 0.01,
            sensor_window_s: plant::SENSOR_WINDOW_S,
            progress: true,
            start_day: 0,
        }
    }
}

pub use crate::util::truth_path;

/// The true parameters of a simulated session, from its truth sidecar (ours or the shared
/// generator's: both carry `theta.vector`), when there is one.
pub fn truth_model(session: &Path) -> Option<PowerModel> {
    let text = crate::util::read_text_input(&truth_path(session)).ok()?;
    let json: serde_json::Value = serde_json::from_str(&text).ok()?;
    let v: Vec<f64> = serde_json::from_value(json["theta"]["vector"].clone()).ok()?;
    let v: [f64; crate::N_PARAMS] = v.try_into().ok()?;
    Some(PowerModel::from_vector(&v))
}

/// The true plant's dynamics (with the payload when that effect is on) and, with a payload, the
/// URDF-only dynamics the payload's share of the power is measured against.
fn dynamics(cfg: &SimConfig) -> Result<(ArmDynamics, Option<ArmDynamics>)> {
    let model = match &cfg.urdf {
        Some(path) => RobotModel::from_urdf_file(path)?,
        None if cfg.with_hand => RobotModel::builtin(),
        None => RobotModel::builtin_no_hand(),
    };
    let arm = model.arm(&JOINT_NAMES.map(String::from))?;
    let urdf =
        ArmDynamics::new(&model, &arm).context("building the arm dynamics for the simulator")?;
    Ok(match &cfg.effects.payload {
        Some(p) => (urdf.with_payload(p), Some(urdf)),
        None => (urdf, None),
    })
}

/// Each trial's artefacts: contamination with a probability growing with speed^1.5 and joint
/// count^0.8 (scaled to the target fraction), outliers uniformly.
fn trial_artefacts(
    trials: &[protocol::PlannedTrial],
    schedule: &Schedule,
    a: &Artefacts,
    rng: &mut ChaCha8Rng,
) -> Vec<TrialArtefacts> {
    let weight = |t: &protocol::PlannedTrial| {
        (t.qdot_max / 2.5).powf(1.5) * (t.route.joints.len() as f64).powf(0.8)
    };
    let total: f64 = trials.iter().map(weight).sum::<f64>().max(1e-12);
    let lerp = |r: [f64; 2], u: f64| r[0] + u * (r[1] - r[0]);
    trials
        .iter()
        .zip(&schedule.trials)
        .map(|(t, tt)| {
            let p = (a.contamination_fraction * trials.len() as f64 * weight(t) / total).min(0.9);
            // Always draw the same numbers per trial so the artefact settings do not shift the
            // random streams of everything after them.
            let u: [f64; 8] = std::array::from_fn(|_| rng.random::<f64>());
            let sway = (u[0] < p).then(|| Sway {
                amplitude: lerp(a.sway_amplitude_rad_s, u[1]),
                freq_hz: lerp(a.sway_freq_hz, u[2]),
                axis: u[3] * std::f64::consts::TAU,
            });
            let outlier = (u[4] < a.outlier_fraction).then(|| OutlierStep {
                start: tt.t_traj_start + u[5] * (tt.t_post_end - tt.t_traj_start - 1.0).max(0.0),
                duration: lerp(a.outlier_duration_s, u[6]),
                step_w: lerp(a.outlier_step_w, u[7]),
            });
            TrialArtefacts { sway, outlier }
        })
        .collect()
}

/// Free-running 1 Hz sensor clock from `t0` to `end` [s]: period 1 s ± 30 ms (uniform).
fn sensor_clock(start_ns: u64, end_s: f64, rng: &mut ChaCha8Rng) -> Vec<u64> {
    let (period, jitter) = plant::SENSOR_PERIOD;
    let mut t = rng.random_range(0.3..1.0);
    let mut out = Vec::with_capacity(end_s as usize + 2);
    while t < end_s {
        out.push(start_ns + (t * 1e9).round() as u64);
        t += period + rng.random_range(-jitter..jitter);
    }
    out
}

/// Settings no session can have.
fn check_config(cfg: &SimConfig) -> Result<()> {
    if let Some(s) = cfg.soc_start {
        anyhow::ensure!(
            (0.0..=1.0).contains(&s),
            "state of charge at session start {s} is not within 0..=1"
        );
    }
    Ok(())
}

/// Simulate a session of `cfg.preset` and write it to `out` (MCAP) and `truth_path(out)` (JSON).
pub fn simulate(cfg: &SimConfig, out: &Path) -> Result<Truth> {
    check_config(cfg)?;
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let planned = protocol::plan(cfg.preset, cfg.seed, cfg.route_seed);
    let schedule = Schedule::build(&planned, &mut rng);
    let start_ns = EPOCH_NS
        + cfg.start_day * 86_400_000_000_000
        + rng.random_range(0..3 * 3600 * 1_000_000_000u64);

    // Message clocks: /lowstate at 100 Hz with ~0.1 ms jitter, /arm_sdk 3 ms later.
    let n = (schedule.duration / 0.01).ceil() as u64;
    let mut lowstate = Vec::with_capacity(n as usize);
    let mut arm_sdk = Vec::with_capacity(n as usize);
    for k in 0..n {
        let j: f64 = rng.random_range(-250_000.0..250_000.0);
        let ns = start_ns + k * 10_000_000;
        lowstate.push((ns as i64 + j as i64) as u64);
        let j2: f64 = rng.random_range(-150_000.0..150_000.0);
        arm_sdk.push((ns as i64 + 3_000_000 + j2 as i64) as u64);
    }
    let end_s = (n as f64 - 1.0) * 0.01;
    let mbs = sensor_clock(start_ns, end_s, &mut rng);
    let bms = sensor_clock(start_ns, end_s, &mut rng);
    let timeline = Timeline {
        start_ns,
        lowstate,
        arm_sdk,
        mbs,
        bms,
    };

    let artefacts = trial_artefacts(&planned, &schedule, &cfg.artefacts, &mut rng);

    let (dyn_true, dyn_urdf) = dynamics(cfg)?;
    let engine = Engine {
        cfg,
        dyn_true: &dyn_true,
        dyn_urdf: dyn_urdf.as_ref(),
        friction: &cfg.friction,
        timeline: &timeline,
        reference: Reference::Protocol(&schedule),
        trials: &schedule.trials,
        artefacts: &artefacts,
    };
    let stats = run_to_file(cfg, &engine, &mut rng, out)?;

    let ns = |t: f64| start_ns + (t * 1e9).round() as u64;
    let trials = planned
        .iter()
        .zip(&schedule.trials)
        .zip(artefacts.iter().zip(&stats.trials))
        .enumerate()
        .map(|(index, ((pt, tt), (art, sums)))| {
            let mean = |s: f64, n: u64| if n > 0 { s / n as f64 } else { 0.0 };
            let (pre, traj) = (|s| mean(s, sums.n_pre), |s| mean(s, sums.n_traj));
            truth::TrialTruth {
                index,
                route_id: pt.route.id.clone(),
                route_kind: pt.route.kind.clone(),
                joints_moved: pt.route.joints.clone(),
                joints_moved_names: pt
                    .route
                    .joints
                    .iter()
                    .map(|&j| JOINT_SHORT[j].to_string())
                    .collect(),
                qdot_max: pt.qdot_max,
                waypoints_rad: pt.route.waypoints.clone(),
                t_trial_start_ns: ns(tt.t_pre_start),
                t_traj_start_ns: ns(tt.t_traj_start),
                t_traj_end_ns: ns(tt.t_traj_end),
                t_post_idle_end_ns: ns(tt.t_post_end),
                t_return_end_ns: ns(tt.t_return_end),
                contaminated: art.sway.is_some(),
                sway_amplitude_rad_s: art.sway.map(|s| round4(s.amplitude)),
                sway_freq_hz: art.sway.map(|s| round4(s.freq_hz)),
                outlier: art.outlier.is_some(),
                outlier_step_w: art.outlier.map(|o| round4(o.step_w)),
                outlier_start_ns: art.outlier.map(|o| ns(o.start)),
                outlier_duration_s: art.outlier.map(|o| round4(o.duration)),
                true_net_arm_power_traj_mean_w: round4(traj(sums.arm_traj) - pre(sums.arm_pre)),
                effect_power_traj_mean_w: round4(traj(sums.eff_traj) - pre(sums.eff_pre)),
                leak_power_traj_mean_w: round4(traj(sums.leak_traj)),
                winding_temp_traj_mean_c: sums.temp_traj.map(|s| (traj(s) * 100.0).round() / 100.0),
            }
        })
        .collect();
    let truth = build_truth(cfg, cfg.preset.name(), &timeline, &stats, trials, out);
    write_truth(&truth, out)?;
    Ok(truth)
}

fn round4(v: f64) -> f64 {
    (v * 1e4).round() / 1e4
}

fn run_to_file(
    cfg: &SimConfig,
    engine: &Engine,
    rng: &mut ChaCha8Rng,
    out: &Path,
) -> Result<plant::RunStats> {
    let template = "simulating {bar:40} {percent}% ({eta} left)";
    let len = || engine.timeline.lowstate.len() as u64;
    let pb = crate::util::progress_bar(cfg.progress, template, len);
    let mut stats = None;
    crate::util::write_atomic_with(out, |w| {
        let mut mcap = writer::McapOut::new(&mut *w)?;
        let s = engine.run(&mut mcap, rng, &|k| pb.set_position(k))?;
        mcap.finish()?;
        stats = Some(s);
        Ok(())
    })
    .with_context(|| format!("writing simulated session {}", out.display()))?;
    pb.finish_and_clear();
    stats.context("simulation produced no statistics")
}

fn write_truth(truth: &Truth, out: &Path) -> Result<()> {
    let path = truth_path(out);
    let text = serde_json::to_string_pretty(truth).context("serialising truth")?;
    crate::util::write_atomic(&path, text.as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}

fn build_truth(
    cfg: &SimConfig,
    preset: &str,
    tl: &Timeline,
    stats: &plant::RunStats,
    trials: Vec<truth::TrialTruth>,
    out: &Path,
) -> Truth {
    let topics = [&tl.lowstate, &tl.arm_sdk, &tl.mbs, &tl.bms];
    let first = topics.iter().filter_map(|t| t.first()).min();
    let last = topics.iter().filter_map(|t| t.last()).max();
    let start_ns = first.copied().unwrap_or(tl.start_ns);
    let end_ns = last.copied().unwrap_or(tl.start_ns);
    let m = &cfg.truth;
    let topic = |t: &str, ty: &str| truth::TopicEntry {
        topic: t.into(),
        type_name: ty.into(),
    };
    let n_contaminated = trials.iter().filter(|t| t.contaminated).count();
    let n_outliers = trials.iter().filter(|t| t.outlier).count();
    Truth {
        generator: truth::Generator {
            name: "g1viz".into(),
            version: env!("CARGO_PKG_VERSION").into(),
            libraries: BTreeMap::from([("mcap".to_string(), "0.26".to_string())]),
        },
        preset: preset.into(),
        seed: cfg.seed,
        rate_hz: 100.0,
        urdf: match (&cfg.urdf, cfg.with_hand) {
            (Some(p), _) => p.display().to_string(),
            (None, true) => "builtin:urdf/g1_left_arm.urdf".into(),
            (None, false) => "builtin:urdf/g1_left_arm_no_hand.urdf".into(),
        },
        session: truth::SessionTimes {
            start_ns,
            end_ns,
            duration_s: (end_ns - start_ns) as f64 * 1e-9,
            epoch: EPOCH_ISO.into(),
            n_trials: trials.len(),
        },
        files: BTreeMap::from([(
            "mcap".to_string(),
            serde_json::json!({ "path": out.file_name().map(|n| n.to_string_lossy().into_owned()), "end_ns": null }),
        )]),
        topics: (["lowstate", "arm_sdk", "bms", "mbs"]
            .iter()
            .zip(writer::TOPICS))
        .map(|(key, (t, ty))| (key.to_string(), topic(t, ty)))
        .collect(),
        joints: truth::Joints {
            names: JOINT_NAMES.iter().map(|s| s.to_string()).collect(),
            short: JOINT_SHORT.iter().map(|s| s.to_string()).collect(),
            sdk_index: (0..N_JOINTS).map(|i| plant::ARM_BASE + i).collect(),
        },
        effects: cfg.effects,
        artefacts: artefacts_truth(cfg, n_contaminated, n_outliers),
        theta: theta_truth(m),
        plant: plant_truth(cfg, stats),
        protocol: protocol_truth(),
        trials,
        message_counts: truth::MessageCounts {
            lowstate: stats.counts[writer::Topic::LowState as usize],
            arm_sdk: stats.counts[writer::Topic::ArmSdk as usize],
            bms: stats.counts[writer::Topic::Bms as usize],
            mbs: stats.counts[writer::Topic::Mbs as usize],
        },
    }
}

/// The artefacts' configuration and how many trials carry each.
fn artefacts_truth(
    cfg: &SimConfig,
    n_contaminated: usize,
    n_outliers: usize,
) -> truth::ArtefactsTruth {
    truth::ArtefactsTruth {
    contamination: truth::Contamination {
        enabled: cfg.artefacts.contamination_fraction > 0.0,
        target_fraction: cfg.artefacts.contamination_fraction,
        amplitude_range_rad_s: cfg.artefacts.sway_amplitude_rad_s,
        freq_range_hz: cfg.artefacts.sway_freq_hz,
        k_leak: cfg.artefacts.k_leak,
        n_trials: n_contaminated,
        model: "sway gyro = A*env(t)*sin(2 pi f t); MBS leak = k_leak*|sway|^2; probability grows with speed^1.5 and joint count^0.8".into(),
    },
    outliers: truth::Outliers {
        enabled: cfg.artefacts.outlier_fraction > 0.0,
        target_fraction: cfg.artefacts.outlier_fraction,
        step_w: cfg.artefacts.outlier_step_w,
        duration_s: cfg.artefacts.outlier_duration_s,
        n_trials: n_outliers,
    },
}
}

/// The true power model θ in both layouts.
fn theta_truth(m: &PowerModel) -> truth::Theta {
    let mut e = BTreeMap::new();
    for (k, &(i, j)) in PAIRS.iter().enumerate() {
        e.insert(format!("{i},{j}"), m.e[k]);
    }
    truth::Theta {
        order: "a0..a6, b0..b6, c0..c6, d0..d6, e_ij for i<j lexicographic (e01, e02, ..., e56)"
            .into(),
        vector: m.to_vector().to_vec(),
        a: m.a,
        b: m.b,
        c: m.c,
        d: m.d,
        e,
        source: if *m == PowerModel::PAPER {
            "paper tables".into()
        } else {
            "user model".into()
        },
    }
}

/// The plant: rail power, rest drift, friction inside τ, noise, sensors, thermal, payload and the
/// run's statistics.
fn plant_truth(cfg: &SimConfig, stats: &plant::RunStats) -> truth::PlantTruth {
    let terms = ["mech", "copper", "coulomb", "viscous", "interaction"];
    truth::PlantTruth {
    rail_power: "P_mbs = P_rest + drift + sum_i[a_i tau_i qd_i + b_i (tau_i^2 - tau_home_i^2) + c_i|qd_i| + d_i qd_i^2] + sum_{i<j} e_ij |qd_i||qd_j| + effects + contamination leak + outlier steps; tau, qd = true joint torque/velocity".into(),
    p_rest_w: plant::P_REST_W,
    rest_drift: format!("OU sigma {} W, tau {} s", plant::REST_DRIFT.0, plant::REST_DRIFT.1),
    bms: format!("P_bms = P_mbs + {} W + OU(sigma {} W, tau {} s)", plant::BMS_OFFSET_W, plant::BMS_OU.0, plant::BMS_OU.1),
    tau_home_nm: stats.tau_home,
    joint_friction_in_tau: truth::FrictionTruth {
        coulomb_nm: cfg.friction.coulomb_nm,
        viscous_nms: cfg.friction.viscous_nms,
        form: "Fc*tanh(qd/0.01) + Fv*qd".into(),
    },
    tracking_lag_s: cfg.tracking_lag_s,
    noise: cfg.noise,
    sensor: truth::SensorTruth {
        avg_window_s: cfg.sensor_window_s,
        period_s: plant::SENSOR_PERIOD.0,
        jitter_s: plant::SENSOR_PERIOD.1,
        quantisation: "MBS V 0.01 V, A 0.001 A; BMS 10 mV, 1 mA".into(),
    },
    thermal: truth::ThermalTruth {
        model: cfg.thermal,
        t_start_c: cfg.t_start_c,
        winding_temp_range_c: stats.temp_range.map(|v| (v * 100.0).round() / 100.0),
        affects_power: cfg.effects.thermal.is_some(),
    },
    payload: cfg.effects.payload,
    mean_power_components_w: terms.iter().zip(stats.mean_terms).map(|(k, v)| (k.to_string(), v)).collect(),
    battery_soc_range: stats.soc_range,
    battery: cfg.battery,
}
}

/// The protocol's constants.
fn protocol_truth() -> truth::ProtocolTruth {
    truth::ProtocolTruth {
        pre_idle_s: protocol::PRE_IDLE_S,
        post_idle_s: protocol::POST_IDLE_S,
        return_speed_rad_s: protocol::RETURN_SPEED,
        segment: "s=3t^2-2t^3, T=max(0.3, 1.5*max|dq|/qdot_max)".into(),
        id_speeds: protocol::ID_SPEEDS.to_vec(),
        holdout_speeds: protocol::HOLDOUT_SPEEDS.to_vec(),
        kp: 400.0,
        kd: 12.0,
        inter_trial_gap_s: protocol::GAP_S,
    }
}

/// Longest pause between joint states a `simulate_like` recording may have [s].
const MAX_LIKE_GAP_S: f64 = 3600.0;

/// The run of a re-recorded twin (`engine` on the recording's timeline and reference, no
/// trials): the session file and its truth.
fn run_like(cfg_like: &SimConfig, engine: &Engine, out: &Path) -> Result<Truth> {
    let mut rng = ChaCha8Rng::seed_from_u64(cfg_like.seed);
    let stats = run_to_file(cfg_like, engine, &mut rng, out)?;
    let truth = build_truth(cfg_like, "like", engine.timeline, &stats, Vec::new(), out);
    write_truth(&truth, out)?;
    Ok(truth)
}
