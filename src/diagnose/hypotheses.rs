//! The library of candidate physical explanations for a power-model mismatch.
//!
//! Each power-level hypothesis is a set of extra regressors, computed per sample from the
//! recording and averaged over exactly the same window as the base regressors φ, with one
//! physical parameter and unit. The per-sample features of all hypotheses live in one fixed
//! layout ([`N_EXTRA`] values after the 49 base regressors) so a fit of any subset of
//! hypotheses is a linear map of one pre-computed Gram matrix.
//!
//! Two hypotheses are not extra power regressors: power-sensor latency (a window shift,
//! scanned in `select`) and payload at the hand (torque level, in `torque`).

use crate::power::JOINT_TORQUE_CONSTANT;
pub use crate::power::STRIBECK_VELOCITY;
use crate::{N_JOINTS, N_PARAMS};

/// Reference temperature [°C] of the winding-resistance drift (R(T) = R0[1 + α(T − 25 °C)]).
pub const T_REF_C: f64 = 25.0;

/// One sample of arm signals plus the trial's pre-idle squared torque, the input of every feature.
#[derive(Debug, Clone, Copy)]
pub struct Sample<'a> {
    /// Joint positions [rad].
    pub q: &'a [f64; N_JOINTS],
    /// Joint velocities [rad/s].
    pub dq: &'a [f64; N_JOINTS],
    /// Joint torques [Nm].
    pub tau: &'a [f64; N_JOINTS],
    /// Winding temperatures [°C].
    pub temp: &'a [f64; N_JOINTS],
    /// Body angular velocity [rad/s].
    pub gyro: &'a [f64; 3],
    /// Mean squared torque of the trial's pre-idle window [Nm²].
    pub tau0_sq: &'a [f64; N_JOINTS],
    /// Bus current P_elec / V_bus [A]: the drives' net electrical input power by the twin's model
    /// (the reference model, or the paper's without one) over the supply voltage.
    pub bus_amps: f64,
}

// Offsets of each hypothesis' raw features in the extra-feature layout.
const THERMAL: usize = 0;
const BRAKING: usize = THERMAL + N_JOINTS;
const BUS: usize = BRAKING + N_JOINTS;
const GEAR: usize = BUS + 1;
const DRIVE: usize = GEAR + 1;
const STRIBECK: usize = DRIVE + 1;
const LEAK: usize = STRIBECK + 1;
const BUS_POWER: usize = LEAK + 1;
const DRIVE_NM: usize = BUS_POWER + 1;
const DRIVING_CURRENT: usize = DRIVE_NM + 1;
const DRIVING_TORQUE: usize = DRIVING_CURRENT + 1;
const THERMAL_DRIVING: usize = DRIVING_TORQUE + 1;
const DRIVING_COPPER: usize = THERMAL_DRIVING + N_JOINTS;

/// Number of per-sample extra features of the power-level hypotheses.
pub const N_EXTRA: usize = DRIVING_COPPER + N_JOINTS;

/// Position in a raw row of the drive current Σ_i |τ_i| / K_i [A] (the drive-electronics
/// loss's feature), for discovery's loss-term products.
pub(crate) const DRIVE_CURRENT: usize = N_PARAMS + DRIVE;

/// Positions in a raw row of the other pooled features discovery pairs with slow states: the
/// drive current and the torque Σ|τ_i| of the joints that drive (τ_i q̇_i > 0, moving; the braking
/// and holding joints' share is the rest of the whole), Stribeck friction and the bus current²
/// (P_elec/V_bus)², and the per-joint braking power min(τ_i q̇_i, 0) (joint 0's).
pub(crate) const RAW_DRIVING_CURRENT: usize = N_PARAMS + DRIVING_CURRENT;
/// See [`RAW_DRIVING_CURRENT`].
pub(crate) const RAW_DRIVING_TORQUE: usize = N_PARAMS + DRIVING_TORQUE;
/// See [`RAW_DRIVING_CURRENT`].
pub(crate) const RAW_TORQUE: usize = N_PARAMS + DRIVE_NM;
/// See [`RAW_DRIVING_CURRENT`].
pub(crate) const RAW_STRIBECK: usize = N_PARAMS + STRIBECK;
/// See [`RAW_DRIVING_CURRENT`].
pub(crate) const RAW_BUS_POWER: usize = N_PARAMS + BUS_POWER;
/// See [`RAW_DRIVING_CURRENT`].
pub(crate) const RAW_BRAKING: usize = N_PARAMS + BRAKING;
/// Position in a raw row of joint 0's τ_i² while it drives (τ_i q̇_i > 0, moving): the copper
/// loss on the driving side, a temperature drift's form without its temperature.
pub(crate) const RAW_DRIVING_COPPER: usize = N_PARAMS + DRIVING_COPPER;

/// Position in a raw row of a pooled hypothesis' feature on the driving joints only, each sample's
/// driving joints (the drive-electronics loss's forms: its current or torque while τ_i q̇_i > 0);
/// `None` where the library has no such feature.
pub(crate) fn driving_side_raw(h: &Hypothesis) -> Option<usize> {
    match h.raw {
        (DRIVE, 1) => Some(RAW_DRIVING_CURRENT),
        (DRIVE_NM, 1) => Some(RAW_DRIVING_TORQUE),
        _ => None,
    }
}

/// Whether `h` is a form on the driving joints alone (the winding-resistance drift's driving side).
pub(crate) fn driving_side_only(h: &Hypothesis) -> bool {
    h.raw.0 == THERMAL_DRIVING
}

/// Speed [rad/s] above which a joint moves (below it, velocity noise decides the sign of τq̇):
/// a holding joint counts with the braking ones in the driving/braking split.
const MOVING: f64 = 0.05;

/// Supply voltage [V] assumed for the bus current P_elec / V_bus when the recording's motor
/// supply voltages are not available (13 Li-ion cells, mid charge).
pub const NOMINAL_BUS_VOLTS: f64 = 50.0;

/// Width of a raw row: the 49 base regressors followed by the extra features.
pub const N_RAW: usize = N_PARAMS + N_EXTRA;

/// Fill the extra features of one sample (layout documented on each [`Hypothesis`]).
pub fn extras_into(s: &Sample, out: &mut [f64; N_EXTRA]) {
    let mut current = 0.0;
    let mut gear = 0.0;
    let mut stribeck = 0.0;
    let mut torque = 0.0;
    let mut driving = 0.0;
    let mut driving_nm = 0.0;
    for i in 0..N_JOINTS {
        let p = s.tau[i] * s.dq[i];
        out[THERMAL + i] = (s.temp[i] - T_REF_C) * (s.tau[i] * s.tau[i] - s.tau0_sq[i]);
        out[BRAKING + i] = p.min(0.0);
        (out[THERMAL_DRIVING + i], out[DRIVING_COPPER + i]) = (0.0, 0.0);
        let amps = s.tau[i].abs() / JOINT_TORQUE_CONSTANT[i];
        current += amps;
        if p > 0.0 && s.dq[i].abs() > MOVING {
            driving += amps;
            driving_nm += s.tau[i].abs();
            out[DRIVING_COPPER + i] = s.tau[i] * s.tau[i];
            out[THERMAL_DRIVING + i] = (s.temp[i] - T_REF_C) * out[DRIVING_COPPER + i];
        }
        torque += s.tau[i].abs();
        gear += p.abs();
        let v = s.dq[i] / STRIBECK_VELOCITY;
        stribeck += s.dq[i].abs() * (-v * v).exp();
    }
    out[BUS] = current * current;
    out[GEAR] = gear;
    out[DRIVE] = current;
    out[STRIBECK] = stribeck;
    out[LEAK] = s.gyro.iter().map(|w| w * w).sum();
    out[BUS_POWER] = s.bus_amps * s.bus_amps;
    out[DRIVE_NM] = torque;
    out[DRIVING_CURRENT] = driving;
    out[DRIVING_TORQUE] = driving_nm;
}

/// A sample's raw row: the base regressors φ followed by the extra features.
pub(crate) fn raw_row(s: &Sample) -> [f64; N_RAW] {
    let (mut phi, mut ex) = ([0.0; N_PARAMS], [0.0; N_EXTRA]);
    crate::power::regressor_into(s.tau, s.dq, s.tau0_sq, &mut phi);
    extras_into(s, &mut ex);
    let mut x = [0.0; N_RAW];
    x[..N_PARAMS].copy_from_slice(&phi);
    x[N_PARAMS..].copy_from_slice(&ex);
    x
}

/// How a hypothesis' raw features enter the model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Combine {
    /// One coefficient on a single raw feature.
    Single,
    /// One coefficient on Σ_i w_i·raw_i, with w_i = the current fit's base parameters starting at
    /// this index of θ (the pooled form of a per-joint effect, refitted until consistent).
    WeightedByBase(usize),
}

/// A candidate physical effect the base model lacks.
#[derive(Debug)]
pub struct Hypothesis {
    /// Short identifier (also the simulator's effect name where it has one).
    pub id: &'static str,
    /// The physical mechanism this is one form of: forms of one mechanism compete (at most one
    /// is accepted; the report names the winner, the runner-up and the margin).
    pub mechanism: &'static str,
    /// What it is, in words.
    pub title: &'static str,
    /// Its form in a few words (how it differs from the other forms of its mechanism).
    pub form: &'static str,
    /// Symbol of the physical parameter.
    pub symbol: &'static str,
    /// Unit of the physical parameter.
    pub unit: &'static str,
    /// What the base model gets wrong when this effect is real (for the plain-language summary).
    pub model_assumes: &'static str,
    /// Offset and length of its raw features in the extra layout.
    pub raw: (usize, usize),
    /// How the raw features become one regressor.
    pub combine: Combine,
    /// The physical parameter is `offset` + the regressor's coefficient (1 for the braking return
    /// fraction, 0 for the others).
    pub offset: f64,
    /// Physical range of the parameter (inclusive): the limits below, each from a public figure
    /// (docs/diagnosis.md, "How large a mechanism can be").
    pub plausible: (f64, f64),
}

impl Hypothesis {
    /// Weight of raw feature `i` in the regressor: 1, or the base parameter it scales in `theta`.
    pub fn weight(&self, theta: &[f64], i: usize) -> f64 {
        match self.combine {
            Combine::Single => 1.0,
            Combine::WeightedByBase(b) => theta.get(b + i).copied().unwrap_or(1.0),
        }
    }
}

// Physical limits of the library's parameters (issue 28, branch diag24). A loss is never negative
// (every lower bound is 0); the upper bounds:
/// α [1/K]: the largest temperature coefficient of a winding metal (aluminium 0.0043/K; copper
/// 0.00393/K at 20 °C, IEC 60028), read against the recorded winding temperature.
const ALPHA_MAX: f64 = 0.0043;
/// V_drop [V]: two bridge devices in the current path at ≤ 2.5 V each (an IGBT's saturation
/// voltage at rated current; a MOSFET's drop is resistive, i.e. copper-like).
const V_DROP_MAX: f64 = 5.0;
/// F_s [Nm], one coefficient for every joint: a mix of per-joint breakaways, each below its
/// joint's peak torque (else it could not start moving) — at most the largest URDF effort, 25 Nm.
const F_S_MAX: f64 = 25.0;

/// The winding-resistance drift, pooled over the joints (its driving-side form shares its physics).
const THERMAL_DRIFT: Hypothesis = Hypothesis {
    id: "thermal",
    mechanism: "winding-resistance temperature drift",
    title: "winding-resistance temperature drift",
    form: "per-joint copper loss × (T − 25 °C)",
    symbol: "α",
    unit: "1/K",
    model_assumes: "the copper loss b_i·Δτ_i² does not depend on motor temperature",
    raw: (THERMAL, N_JOINTS),
    combine: Combine::WeightedByBase(N_JOINTS),
    offset: 0.0,
    plausible: (0.0, ALPHA_MAX),
};

/// The shared DC-bus loss in the phase current (its electrical-power form shares its physics);
/// the single-feature forms below take its `combine` and `offset`.
const BUS_LOSS: Hypothesis = Hypothesis {
    id: "bus_loss",
    mechanism: "shared DC-bus loss",
    title: "shared DC-bus loss ∝ (total drive current)²",
    form: "phase-current",
    symbol: "R_bus",
    unit: "Ω",
    model_assumes: "joints share no resistive path: there is no loss in the total current",
    raw: (BUS, 1),
    combine: Combine::Single,
    offset: 0.0,
    // Not a physical limit: a path dropping the whole bus at the arm's peak current (every joint
    // at its URDF effort, Σ effort_i/K_i = 127 A) has 0.39 Ω; the simulator's and the independent
    // generator's bus sessions are drawn at 5–10 Ω, which a physical bound would reject.
    plausible: (0.001, 2.0),
};

/// The power-level hypotheses (extra regressors).
pub static POWER_HYPOTHESES: [Hypothesis; 10] = [
    THERMAL_DRIFT,
    Hypothesis {
        id: "thermal_driving",
        title: "winding-resistance temperature drift on the joints that drive",
        form: "driving side only",
        model_assumes: "the copper loss b_i·τ_i² of a driving joint does not depend on its temperature",
        // (T_i − 25 °C)·τ_i² while τ_i q̇_i > 0 (moving), whole τ²: a joint drives only in motion.
        raw: (THERMAL_DRIVING, N_JOINTS),
        ..THERMAL_DRIFT
    },
    Hypothesis {
        id: "braking",
        mechanism: "braking asymmetry",
        title: "braking asymmetry (regenerated power only partly returned)",
        form: "per-joint braking power",
        symbol: "r",
        unit: "-",
        model_assumes: "regenerated (braking) mechanical power is fully returned to the bus",
        raw: (BRAKING, N_JOINTS),
        combine: Combine::WeightedByBase(0),
        // A path returns at most what is regenerated (r ≤ 1) and, drawing nothing, at least 0.
        offset: 1.0,
        plausible: (0.0, 1.0),
    },
    BUS_LOSS,
    Hypothesis {
        id: "gear_friction",
        mechanism: "load-dependent gear friction",
        title: "load-dependent gear friction ∝ Σ|τ_i q̇_i|",
        form: "∝ Σ|τq̇|",
        symbol: "μ",
        unit: "-",
        model_assumes: "gear friction does not grow with the transmitted load",
        raw: (GEAR, 1),
        // The arm's gears are backdriven (torque control): efficiency > 50 %, loss < the power.
        plausible: (0.0, 1.0),
        ..BUS_LOSS
    },
    Hypothesis {
        id: "drive_loss",
        mechanism: "drive-electronics loss",
        title: "current-proportional drive-electronics loss ∝ Σ|τ_i|/K_i",
        form: "per-ampere",
        symbol: "V_drop",
        unit: "V",
        model_assumes: "the drives have no loss proportional to their current (switch/diode drop)",
        raw: (DRIVE, 1),
        plausible: (0.0, V_DROP_MAX),
        ..BUS_LOSS
    },
    Hypothesis {
        id: "stribeck",
        mechanism: "Stribeck friction",
        title: "Stribeck friction Σ|q̇_i|·exp(−(q̇_i/v_s)²), v_s = 0.1 rad/s",
        form: "v_s = 0.1 rad/s",
        symbol: "F_s",
        unit: "Nm",
        model_assumes: "friction is pure Coulomb + viscous (no extra breakaway friction at low speed)",
        raw: (STRIBECK, 1),
        plausible: (0.0, F_S_MAX),
        ..BUS_LOSS
    },
    Hypothesis {
        id: "balance_leak",
        mechanism: "balance-compensation leakage",
        title: "balance-compensation leakage ∝ |ω_body|²",
        form: "∝ |ω_body|²",
        symbol: "k_leak",
        unit: "W/(rad/s)²",
        model_assumes: "leg power for balance does not leak into the arm power reading",
        raw: (LEAK, 1),
        // Not a physical limit: no public figure bounds the legs' balance power per sway.
        plausible: (0.1, 1.0e5),
        ..BUS_LOSS
    },
    Hypothesis {
        id: "bus_power",
        title: "shared DC-bus loss ∝ (total electrical input power / V_bus)²",
        form: "electrical-power",
        model_assumes: "the drives' shared supply path has no resistance: there is no loss in the bus current P_elec/V_bus",
        raw: (BUS_POWER, 1),
        plausible: (0.001, 50.0),
        ..BUS_LOSS
    },
    Hypothesis {
        id: "electronics_nm",
        mechanism: "drive-electronics loss",
        title: "drive-electronics loss ∝ Σ|τ_i| (one coefficient per Nm)",
        form: "per-Nm",
        symbol: "k_el",
        unit: "W/Nm",
        model_assumes: "the drives have no loss proportional to their torque",
        raw: (DRIVE_NM, 1),
        // V_drop per Nm of the joint with the smallest torque constant (0.7 Nm/A): any mix.
        plausible: (0.0, V_DROP_MAX / 0.7),
        ..BUS_LOSS
    },
];

/// Identifier of the power-sensor latency hypothesis (window shift, not an extra regressor).
pub const LATENCY_ID: &str = "latency";
/// Identifier of the payload-at-the-hand hypothesis (torque level).
pub const PAYLOAD_ID: &str = "payload";

/// Look a power hypothesis up by identifier.
pub fn power_hypothesis(id: &str) -> Option<&'static Hypothesis> {
    POWER_HYPOTHESES.iter().find(|h| h.id == id)
}

/// Number of per-sample descriptor features used to locate unexplained structure.
pub const N_LOCATE: usize = 5 * N_JOINTS + 1;

/// Fill the descriptor features of one sample: per joint q, |q̇|, |τ|, T, |q|·|q̇|, then |ω_body|.
pub fn locate_into(s: &Sample, out: &mut [f64; N_LOCATE]) {
    for i in 0..N_JOINTS {
        out[5 * i] = s.q[i];
        out[5 * i + 1] = s.dq[i].abs();
        out[5 * i + 2] = s.tau[i].abs();
        out[5 * i + 3] = s.temp[i];
        out[5 * i + 4] = s.q[i].abs() * s.dq[i].abs();
    }
    out[5 * N_JOINTS] = s.gyro.iter().map(|w| w * w).sum::<f64>().sqrt();
}

/// Joint `j`'s name in `joint_names` ("joint j" where there is none).
pub(crate) fn joint_name(joint_names: &[String], j: usize) -> String {
    joint_names
        .get(j)
        .cloned()
        .unwrap_or_else(|| format!("joint {j}"))
}

/// Human-readable name of descriptor feature `k` given the arm's joint names.
pub fn locate_name(k: usize, joint_names: &[String]) -> String {
    if k >= 5 * N_JOINTS {
        return "body angular velocity |ω| (IMU)".into();
    }
    let joint = joint_name(joint_names, k / 5);
    let what = match k % 5 {
        0 => "position q",
        1 => "speed |q̇|",
        2 => "torque |τ|",
        3 => "motor temperature T",
        _ => "position × speed |q|·|q̇|",
    };
    format!("{joint} {what}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extras_match_hand_computed_values() {
        let q = [0.0; 7];
        let dq = [1.0, -2.0, 0.0, 0.0, 0.0, 0.0, 0.5];
        let tau = [2.0, 3.0, 0.0, -1.3, 0.0, 0.0, 0.7];
        let temp = [35.0, 25.0, 25.0, 25.0, 25.0, 25.0, 45.0];
        let gyro = [0.1, 0.2, 0.0];
        let tau0_sq = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let s = Sample {
            q: &q,
            dq: &dq,
            tau: &tau,
            temp: &temp,
            gyro: &gyro,
            tau0_sq: &tau0_sq,
            bus_amps: 3.0,
        };
        let mut out = [0.0; N_EXTRA];
        extras_into(&s, &mut out);
        // (35 − 25)·(4 − 1) = 30; (45 − 25)·0.49 = 9.8
        assert!((out[THERMAL] - 30.0).abs() < 1e-12);
        assert!((out[THERMAL + 6] - 9.8).abs() < 1e-12);
        // τq̇: 2, −6, …, 0.35 → braking keeps only −6
        assert_eq!(out[BRAKING + 1], -6.0);
        assert_eq!(out[BRAKING], 0.0);
        // current: (2 + 3 + 1.3)/1.3 + 0.7/0.7
        let i = 6.3 / 1.3 + 1.0;
        assert!((out[DRIVE] - i).abs() < 1e-12);
        assert!((out[BUS] - i * i).abs() < 1e-12);
        assert!((out[GEAR] - (2.0 + 6.0 + 0.35)).abs() < 1e-12);
        assert!((out[LEAK] - 0.05).abs() < 1e-12);
        // Stribeck vanishes at high speed, equals |q̇| for q̇ ≪ v_s.
        assert!(out[STRIBECK] < 1e-6);
        assert_eq!(out[BUS_POWER], 9.0);
        assert!((out[DRIVE_NM] - 7.0).abs() < 1e-12);
        // only joints 0 and 6 drive (τq̇ > 0): 2/1.3 + 0.7/0.7
        assert!((out[DRIVING_CURRENT] - (2.0 / 1.3 + 1.0)).abs() < 1e-12);
        assert!((out[DRIVING_TORQUE] - 2.7).abs() < 1e-12);
    }
}
