//! Switchable physics the paper's power model lacks. Each effect is an `Option` with physical
//! parameters and units; the definitions are shared with the diagnosis hypotheses
//! (CONTRACTS.md). New effects are new fields: every consumer matches on them by name.
//!
//! How visible the defaults are (hold-out preset, the true base model validated per effect,
//! `bench_sim effects`): bus loss and payload change the trial-level fit most; braking and a
//! warm-start thermal drift double the like-for-like RMSE; latency shows as a shifted best
//! reading window (a pipeline that estimates the lag absorbs most of it); the payload changes
//! power only through the measured torques, so it is seen at the torque level (URDF inverse
//! dynamics vs `tau_est`); harness drag needs elbow motions (a few % of RMSE on the hold-out set).

use serde::{Deserialize, Serialize};

use crate::N_JOINTS;
use crate::power::{JOINT_TORQUE_CONSTANT, STRIBECK_VELOCITY};
use crate::robot::Payload;

/// Reference temperature of the winding resistance R0 [°C].
pub const THERMAL_REFERENCE_C: f64 = 25.0;

/// Winding-resistance temperature drift: R(T) = R0·[1 + α(T − 25 °C)], so the copper term of
/// joint i becomes b_i·(1 + α(T_i − 25))·(τ_i² − τ̄0_i²), T_i = the recorded winding temperature.
///
/// Visibility: the copper term is a few W at most, so over a short session that heats the
/// windings by a few K the change is ~1 % of it and invisible. Start the session warm
/// (`SimConfig::t_start_c`, e.g. 70 °C → +18 %) or run long sessions to see it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ThermalDrift {
    /// Temperature coefficient of resistance [1/K] (copper: 0.00393).
    pub alpha_per_k: f64,
}

/// Braking asymmetry: when τ_i q̇_i < 0 only the fraction r of the regenerated mechanical power is
/// returned: mech_i = a_i τ_i q̇_i if τ_i q̇_i ≥ 0, else r·a_i τ_i q̇_i.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BrakingAsymmetry {
    /// Returned fraction r of regenerated power [-] (0 = all dissipated, 1 = the base model).
    pub return_fraction: f64,
}

/// Shared DC-bus loss: P += R_bus·(Σ_i |τ_i| / K_i)², K = [`JOINT_TORQUE_CONSTANT`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BusLoss {
    /// Resistance of the shared supply path [Ω].
    pub resistance_ohm: f64,
}

/// Power-sensor latency: the MBS/BMS reading stamped t averages power over [t − L − W, t − L].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SensorLatency {
    /// Latency L [s].
    pub seconds: f64,
}

/// Cable-harness drag at the elbow (NOT in the diagnosis library, to test localisation):
/// P += k·(1 − cos q_elbow)·|q̇_elbow|.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HarnessDrag {
    /// Drag coefficient k [W·s/rad].
    pub w_per_rad_s: f64,
}

/// Load-dependent gear friction: a loss proportional to the transmitted mechanical power in
/// either direction, P += μ·Σ_i |τ_i q̇_i| (a gear efficiency η ≈ 1 − μ).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GearFriction {
    /// Loss fraction μ of the transmitted power [-].
    pub mu: f64,
}

/// Current-proportional drive-electronics loss (switch/diode voltage drop):
/// P += V_drop·Σ_i |τ_i| / K_i, K = [`JOINT_TORQUE_CONSTANT`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DriveLoss {
    /// Voltage drop V_drop across the drive [V].
    pub volts: f64,
}

/// Stribeck friction: extra breakaway friction F_s that decays with speed,
/// P += F_s·Σ_i |q̇_i|·exp(−(q̇_i / v_s)²), v_s = [`STRIBECK_VELOCITY`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StribeckFriction {
    /// Stribeck friction excess F_s [Nm].
    pub newton_m: f64,
}

/// Balance-compensation leakage: the standing robot sways continuously (body roll/pitch rate an
/// Ornstein–Uhlenbeck process of standard deviation `sway_rad_s` per axis) and the legs' balancing
/// power leaks into the arm's power reading, P += k·|ω_body|² (ω_body as the IMU gyroscope sees it,
/// contamination sway included; without this effect the contamination artefact's own k applies).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BalanceLeak {
    /// Leak coefficient k [W/(rad/s)²].
    pub w_per_rad2_s2: f64,
    /// Standard deviation of the ambient body sway rate per horizontal axis [rad/s].
    pub sway_rad_s: f64,
}

/// Correlation time of the ambient body sway of [`BalanceLeak`] [s].
pub const SWAY_CORRELATION_S: f64 = 0.5;

/// Shared DC-bus loss from the drives' total electrical input power: the bus carries
/// I_bus = P_elec / V_bus, so P += R_bus·(P_elec / V_bus)², with P_elec = the arm drives' net
/// electrical input (the paper's model on the true torques plus every other effect of this list
/// except the rail load) and V_bus = the motors' supply voltage (what `motor_state[k].vol` records).
/// Regenerated power goes back through the bus: P_elec keeps its sign and is squared, so a
/// braking arm also loses on the bus. Unlike [`BusLoss`], a stalled joint (phase current, no
/// mechanical power) adds almost nothing.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BusPowerLoss {
    /// Resistance of the shared supply path [Ω].
    pub resistance_ohm: f64,
}

/// Drive-electronics loss per newton-metre (one coefficient for all joints, not through the
/// torque constant): P += k·Σ_i |τ_i|.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ElectronicsLoss {
    /// Loss per Nm of joint torque [W/Nm].
    pub w_per_nm: f64,
}

/// Unequal Coulomb friction excess per joint on the motor side (a drag the torque estimate does
/// not see): P += F·Σ_i w_i·|q̇_i|, w = [`JOINT_FRICTION_PATTERN`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct JointFrictionExcess {
    /// Scale F of the per-joint excess [Nm]; joint i gets F·w_i.
    pub newton_m: f64,
}

/// Relative size of the per-joint friction excess of [`JointFrictionExcess`] (shoulder pitch,
/// roll, yaw, elbow, wrist roll, pitch, yaw).
pub const JOINT_FRICTION_PATTERN: [f64; N_JOINTS] = [1.0, 0.25, 0.5, 1.5, 0.2, 0.75, 0.3];

/// Friction that follows the motor housing temperature (seals and bearings tighten as the
/// housing warms): P += k·Σ_i (T_housing,i − 25 °C)·|q̇_i|, T_housing = what
/// `motor_state[k].temperature[1]` records. The diagnosis library does not use that field.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HousingFriction {
    /// Coefficient k [W/(K·rad/s)].
    pub w_per_k_rad_s: f64,
}

/// A load on the main-board rail that follows a status field of another topic: a cooling fan
/// that cycles on and off during the session (on for ≈ 8 s, off for ≈ 12 s on average,
/// exponential durations) and draws `watts` while on. `/lf/mainboardstate` `fan_state[1]`
/// reads ≈ 3000 rpm while it runs and 0 while it stands (without this effect that fan turns
/// steadily 30 rpm below fan 0).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RailLoad {
    /// Power drawn while on [W].
    pub watts: f64,
}

/// Inverter switching loss, which follows the supply voltage: each drive's bridge dissipates
/// while its switches commutate the phase current against the DC-link voltage, so
/// P += k_sw·V_bus·Σ_i |τ_i| / K_i, K = [`JOINT_TORQUE_CONSTANT`], V_bus = the motors' supply
/// voltage (what `motor_state[k].vol` records). k_sw ≈ ½·(t_rise + t_fall)·f_sw summed over the
/// commutating legs (100–200 ns edges at 20 kHz: a few thousandths). The library's
/// drive-electronics loss is the conduction form V_drop·Σ|τ_i|/K_i at a constant voltage.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SwitchingLoss {
    /// Switching coefficient k_sw [W/(V·A)].
    pub per_volt_amp: f64,
}

/// A measurement artefact of one meter: fan 1 cycles as for [`RailLoad`] but draws nothing from
/// the arm rail, and the main-board meter's reading shifts by `watts` while it runs (interference
/// in its current sense). The battery meter does not show it: a correction of the main-board
/// meter, not a load.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MeterOffset {
    /// Shift of the main-board reading while the fan runs [W].
    pub watts: f64,
}

/// Mean on and off durations of the [`RailLoad`] fan [s].
pub const FAN_MEAN_ON_OFF_S: (f64, f64) = (8.0, 12.0);

/// [`Effects`] (its fields in the truth JSON's order, each left out of it when off) and the
/// effects by name: [`EFFECT_NAMES`] (in documentation order) and switching one on by its name
/// (each name is the field of [`Effects`] it sets).
macro_rules! effects {
    ($($(#[$doc:meta])* $field:ident: $ty:ty,)* ; $($name:ident),*) => {
        /// The set of switched-on effects (all off by default: the paper's plant).
        #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
        pub struct Effects {
            $($(#[$doc])*
            #[serde(skip_serializing_if = "Option::is_none", default)]
            pub $field: Option<$ty>,)*
        }

        /// Names accepted by [`Effects::enable`], in documentation order.
        pub const EFFECT_NAMES: [&str; [$(stringify!($name)),*].len()] = [$(stringify!($name)),*];

        impl Effects {
            /// Switch on effect `name` at strength `value` (its default without one); false
            /// when no effect has that name.
            fn set_named(&mut self, name: &str, value: Option<f64>) -> bool {
                fn set<E: Strength>(slot: &mut Option<E>, value: Option<f64>) {
                    *slot = Some(value.map_or(E::DEFAULT, E::with));
                }
                match name {
                    $(stringify!($name) => set(&mut self.$name, value),)*
                    _ => return false,
                }
                true
            }
        }
    };
}

effects!(
    /// Winding-resistance temperature drift.
    thermal: ThermalDrift,
    /// Braking asymmetry.
    braking: BrakingAsymmetry,
    /// Shared DC-bus loss.
    bus_loss: BusLoss,
    /// Point mass at the hand that the URDF lacks.
    payload: Payload,
    /// Power-sensor latency.
    latency: SensorLatency,
    /// Elbow cable-harness drag.
    harness_drag: HarnessDrag,
    /// Load-dependent gear friction.
    gear_friction: GearFriction,
    /// Current-proportional drive-electronics loss.
    drive_loss: DriveLoss,
    /// Stribeck friction.
    stribeck: StribeckFriction,
    /// Balance-compensation leakage (with ambient body sway).
    balance_leak: BalanceLeak,
    /// Bus loss from total electrical power.
    bus_power: BusPowerLoss,
    /// Electronics loss per Nm.
    electronics_nm: ElectronicsLoss,
    /// Per-joint Coulomb friction excess.
    joint_friction: JointFrictionExcess,
    /// Friction following the housing temperature.
    housing_friction: HousingFriction,
    /// Switching fan load on the main-board rail.
    fan_load: RailLoad,
    /// A second switching fan on the same rail, cycling independently of the first and reported
    /// in `fan_state[0]`: a second load of the same kind on another field.
    fan0_load: RailLoad,
    /// Inverter switching loss following the supply voltage.
    switching: SwitchingLoss,
    /// A drive-electronics loss per ampere only while a joint drives (τq̇ > 0): the library's
    /// mechanism in a one-sided form.
    driving_loss: DriveLoss,
    /// The main-board meter's reading shifted while fan 1 runs (no load; a one-meter artefact).
    fan_meter: MeterOffset,
    ;
    thermal,
    braking,
    bus_loss,
    payload,
    latency,
    gear_friction,
    drive_loss,
    stribeck,
    balance_leak,
    harness_drag,
    bus_power,
    electronics_nm,
    joint_friction,
    housing_friction,
    fan_load,
    fan0_load,
    switching,
    fan_meter,
    driving_loss
);

/// Default payload: a 0.5 kg tool held 10 cm beyond the wrist-yaw link origin.
pub const DEFAULT_PAYLOAD: Payload = Payload {
    mass_kg: 0.5,
    com_m: [0.10, 0.0, 0.0],
};

/// An effect set by one number in its unit (`name=value` of [`Effects::enable`]), with a
/// default strength when no number is given.
trait Strength: Sized {
    const DEFAULT: Self;
    /// The effect at strength `v`, its other parameters at their defaults.
    fn with(v: f64) -> Self;
}

/// Each effect set by one number: its `DEFAULT` strength (documented) and its [`Strength`]
/// (the first field is the number).
macro_rules! strength {
    ($($(#[$doc:meta])* $ty:ident { $field:ident: $value:expr $(, $other:ident: $v:expr)* };)*) => {$(
        impl $ty {
            $(#[$doc])*
            pub const DEFAULT: $ty = $ty { $field: $value $(, $other: $v)* };
        }
        impl Strength for $ty {
            const DEFAULT: Self = <$ty>::DEFAULT;
            fn with(v: f64) -> Self {
                let mut effect = <$ty>::DEFAULT;
                effect.$field = v;
                effect
            }
        }
    )*};
}

strength! {
    /// Copper's temperature coefficient.
    ThermalDrift { alpha_per_k: 0.00393 };
    /// A quarter of the regenerated power comes back (drive and gear losses eat the rest).
    BrakingAsymmetry { return_fraction: 0.25 };
    /// 50 mΩ: battery internal resistance share plus harness and connectors of the arm rail.
    BusLoss { resistance_ohm: 0.05 };
    /// 0.3 s: a slow sensor pipeline (several 100 ms buffers are common on BMS/MBS links).
    SensorLatency { seconds: 0.3 };
    /// 4 W·s/rad: a drag torque of k·(1 − cos q) = 1.8 Nm at 1 rad elbow flexion
    /// (1.8 W at 1 rad/s) — a stiff cable bundle.
    HarnessDrag { w_per_rad_s: 4.0 };
    /// 15 % of the transmitted power: a harmonic stage of ≈ 85 % efficiency on top of the paper's
    /// loss terms (smaller fractions are within the noise of 1 Hz readings on a short session).
    GearFriction { mu: 0.15 };
    /// 0.5 V: a MOSFET bridge's conduction plus dead-time diode drop at a few amperes.
    DriveLoss { volts: 0.5 };
    /// 10 Nm of breakaway excess at the joint output: a deliberately strong effect. The paper's
    /// protocol never moves slower than 0.5 rad/s, so the low-speed band only shows during
    /// accelerations; 5 Nm is resolved to ≈ 15–25 % on ≈ 140 trials (docs/diagnosis-results.md).
    StribeckFriction { newton_m: 10.0 };
    /// The contamination artefact's leak (500/9 W per (rad/s)²: 5 W at 0.3 rad/s of sway) with a
    /// continuous 0.05 rad/s sway per axis.
    BalanceLeak { w_per_rad2_s2: 500.0 / 9.0, sway_rad_s: 0.05 };
    /// 50 mΩ, as [`BusLoss::DEFAULT`].
    BusPowerLoss { resistance_ohm: 0.05 };
    /// 0.5 W/Nm: about [`DriveLoss::DEFAULT`] at the arm's torque constants.
    ElectronicsLoss { w_per_nm: 0.5 };
    /// 1 Nm at the shoulder pitch (1.5 Nm at the elbow, 0.2 Nm at the wrist roll).
    JointFrictionExcess { newton_m: 1.0 };
    /// 0.05 W/(K·rad/s): 1 W more per rad/s at a housing 20 K above 25 °C.
    HousingFriction { w_per_k_rad_s: 0.05 };
    /// 0.01 W/(V·A): 0.5 W per ampere of phase current at a 50 V bus, about
    /// [`DriveLoss::DEFAULT`] (a slow bridge; fast ones switch for a few thousandths).
    SwitchingLoss { per_volt_amp: 0.01 };
    /// A 3 W fan.
    RailLoad { watts: 3.0 };
    /// The shift of a 3 W fan's load ([`RailLoad::DEFAULT`]).
    MeterOffset { watts: 3.0 };
}

impl Strength for Payload {
    const DEFAULT: Self = DEFAULT_PAYLOAD;
    fn with(mass_kg: f64) -> Self {
        Payload {
            mass_kg,
            ..DEFAULT_PAYLOAD
        }
    }
}

impl Effects {
    /// Switch on effect `spec` = `name` or `name=value` (value in the effect's unit: thermal α [1/K],
    /// braking r [-], bus_loss R [Ω], payload mass [kg] at the default position, latency [s],
    /// gear_friction μ [-], drive_loss V_drop [V], stribeck F_s [Nm], balance_leak k [W/(rad/s)²] at
    /// the default sway, harness_drag k [W·s/rad], bus_power R [Ω], electronics_nm k [W/Nm],
    /// joint_friction F [Nm], housing_friction k [W/(K·rad/s)], fan_load, fan0_load and fan_meter [W], switching
    /// k_sw [W/(V·A)], driving_loss V_drop [V]).
    pub fn enable(&mut self, spec: &str) -> anyhow::Result<()> {
        let (name, value) = match spec.split_once('=') {
            Some((n, v)) => {
                let v: f64 = v
                    .trim()
                    .parse()
                    .map_err(|_| anyhow::anyhow!("effect {spec:?}: value is not a number"))?;
                anyhow::ensure!(
                    v.is_finite() && v >= 0.0,
                    "effect {spec:?}: value must be finite and ≥ 0"
                );
                (n.trim(), Some(v))
            }
            None => (spec.trim(), None),
        };
        anyhow::ensure!(
            name != "braking" || value.is_none_or(|v| v <= 1.0),
            "effect {spec:?}: the braking fraction is at most 1"
        );
        anyhow::ensure!(
            self.set_named(name, value),
            "unknown effect {name:?} (known: {})",
            EFFECT_NAMES.join(", ")
        );
        Ok(())
    }

    /// True when no effect is switched on.
    pub fn is_empty(&self) -> bool {
        *self == Effects::default()
    }
}

/// Per-sample power of the plant [W], split into the base model and the effects' additions.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ArmPower {
    /// The paper's model evaluated on the true torques (without thermal/braking changes).
    pub base: f64,
    /// What the power-changing effects add (thermal, braking, bus loss, gear friction, drive loss,
    /// Stribeck friction, harness drag; the balance leak is added by the plant, which owns the sway).
    pub effects: f64,
}

/// One sample of the true plant state, the input of [`arm_power`].
#[derive(Debug, Clone, Copy)]
pub struct PlantSample<'a> {
    /// Joint positions [rad].
    pub q: &'a [f64; N_JOINTS],
    /// True joint torques (incl. friction and payload) [Nm].
    pub tau: &'a [f64; N_JOINTS],
    /// Joint velocities [rad/s].
    pub dq: &'a [f64; N_JOINTS],
    /// Home (gravity) torques [Nm].
    pub tau_home: &'a [f64; N_JOINTS],
    /// Winding temperatures [°C].
    pub winding_c: &'a [f64; N_JOINTS],
    /// Housing temperatures [°C].
    pub housing_c: &'a [f64; N_JOINTS],
    /// Supply voltage of the drives [V].
    pub bus_volts: f64,
}

/// Net arm power of the plant for one true state sample.
pub fn arm_power(model: &crate::power::PowerModel, effects: &Effects, s: &PlantSample) -> ArmPower {
    let (q, tau, dq) = (s.q, s.tau, s.dq);
    let tau0_sq = s.tau_home.map(|v| v * v);
    let base = model.predict(tau, dq, &tau0_sq);
    let mut extra = 0.0;
    for i in 0..N_JOINTS {
        if let Some(th) = effects.thermal {
            extra += model.b[i]
                * th.alpha_per_k
                * (s.winding_c[i] - THERMAL_REFERENCE_C)
                * (tau[i] * tau[i] - tau0_sq[i]);
        }
        if let Some(br) = effects.braking {
            let mech = model.a[i] * tau[i] * dq[i];
            if mech < 0.0 {
                extra += (br.return_fraction - 1.0) * mech;
            }
        }
    }
    let current: f64 = (0..N_JOINTS)
        .map(|i| tau[i].abs() / JOINT_TORQUE_CONSTANT[i])
        .sum();
    if let Some(bus) = effects.bus_loss {
        extra += bus.resistance_ohm * current * current;
    }
    if let Some(d) = effects.drive_loss {
        extra += d.volts * current;
    }
    if let Some(d) = effects.driving_loss {
        extra += d.volts
            * (0..N_JOINTS)
                .filter(|&i| tau[i] * dq[i] > 0.0)
                .map(|i| tau[i].abs() / JOINT_TORQUE_CONSTANT[i])
                .sum::<f64>();
    }
    if let Some(sw) = effects.switching {
        extra += sw.per_volt_amp * s.bus_volts.max(0.0) * current;
    }
    if let Some(g) = effects.gear_friction {
        extra += g.mu * (0..N_JOINTS).map(|i| (tau[i] * dq[i]).abs()).sum::<f64>();
    }
    if let Some(st) = effects.stribeck {
        extra += st.newton_m
            * dq.iter()
                .map(|w| {
                    let v = w / STRIBECK_VELOCITY;
                    w.abs() * (-v * v).exp()
                })
                .sum::<f64>();
    }
    if let Some(h) = effects.harness_drag {
        extra += h.w_per_rad_s * (1.0 - q[3].cos()) * dq[3].abs();
    }
    if let Some(e) = effects.electronics_nm {
        extra += e.w_per_nm * tau.iter().map(|t| t.abs()).sum::<f64>();
    }
    if let Some(f) = effects.joint_friction {
        extra += f.newton_m
            * (0..N_JOINTS)
                .map(|i| JOINT_FRICTION_PATTERN[i] * dq[i].abs())
                .sum::<f64>();
    }
    if let Some(h) = effects.housing_friction {
        extra += h.w_per_k_rad_s
            * (0..N_JOINTS)
                .map(|i| (s.housing_c[i] - THERMAL_REFERENCE_C) * dq[i].abs())
                .sum::<f64>();
    }
    if let Some(b) = effects.bus_power
        && s.bus_volts > 0.0
    {
        let amps = (base + extra) / s.bus_volts;
        extra += b.resistance_ohm * amps * amps;
    }
    ArmPower {
        base,
        effects: extra,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::power::PowerModel;

    /// `arm_power` at 25 °C and a 50 V bus.
    fn ap(
        e: &Effects,
        q: &[f64; N_JOINTS],
        tau: &[f64; N_JOINTS],
        dq: &[f64; N_JOINTS],
        tau_home: &[f64; N_JOINTS],
    ) -> ArmPower {
        let s = PlantSample {
            q,
            tau,
            dq,
            tau_home,
            winding_c: &[25.0; N_JOINTS],
            housing_c: &[25.0; N_JOINTS],
            bus_volts: 50.0,
        };
        arm_power(&PowerModel::PAPER, e, &s)
    }

    #[test]
    fn braking_loses_the_unreturned_fraction() {
        // Elbow braking: τ = 2 Nm, q̇ = −1 rad/s → regenerated 2 W; r = 0.25 returns 0.5 W, so the
        // plant draws 1.5 W more than the symmetric model (hand computed).
        let e = Effects {
            braking: Some(BrakingAsymmetry {
                return_fraction: 0.25,
            }),
            ..Default::default()
        };
        let mut tau = [0.0; N_JOINTS];
        let mut dq = [0.0; N_JOINTS];
        tau[3] = 2.0;
        dq[3] = -1.0;
        let p = ap(&e, &[0.0; 7], &tau, &dq, &[0.0; 7]);
        assert!((p.effects - 1.5).abs() < 1e-12);
        dq[3] = 1.0;
        let p = ap(&e, &[0.0; 7], &tau, &dq, &[0.0; 7]);
        assert_eq!(p.effects, 0.0);
    }

    #[test]
    fn bus_loss_and_harness_by_hand() {
        let e = Effects {
            bus_loss: Some(BusLoss {
                resistance_ohm: 0.1,
            }),
            harness_drag: Some(HarnessDrag { w_per_rad_s: 2.0 }),
            ..Default::default()
        };
        let mut tau = [0.0; N_JOINTS];
        tau[0] = 2.6; // 2 A at K = 1.3
        tau[4] = 0.7; // 1 A at K = 0.7
        let mut q = [0.0; N_JOINTS];
        q[3] = std::f64::consts::FRAC_PI_2;
        let mut dq = [0.0; N_JOINTS];
        dq[3] = 0.5;
        let p = ap(&e, &q, &tau, &dq, &tau);
        // 0.1 Ω · (3 A)² = 0.9 W; 2 · (1 − cos 90°) · 0.5 = 1 W.
        assert!((p.effects - 1.9).abs() < 1e-9, "{}", p.effects);
    }

    #[test]
    fn gear_drive_and_stribeck_by_hand() {
        let mut e = Effects::default();
        e.enable("gear_friction=0.1").unwrap();
        e.enable("drive_loss=0.5").unwrap();
        e.enable("stribeck=2").unwrap();
        let mut tau = [0.0; N_JOINTS];
        let mut dq = [0.0; N_JOINTS];
        tau[0] = 2.6; // 2 A, driving 2.6 W
        dq[0] = 1.0;
        tau[5] = -0.7; // 1 A, braking at q̇ = v_s: 0.07 W
        dq[5] = 0.1;
        let p = ap(&e, &[0.0; 7], &tau, &dq, &tau);
        // gear 0.1·(2.6 + 0.07) = 0.267; drive 0.5 V·3 A = 1.5;
        // Stribeck 2·(1·e^−100 + 0.1·e^−1) = 0.0735759.
        let want = 0.267 + 1.5 + 2.0 * (1.0 * (-100.0f64).exp() + 0.1 * (-1.0f64).exp());
        assert!((p.effects - want).abs() < 1e-9, "{} vs {want}", p.effects);
    }

    #[test]
    fn new_forms_by_hand() {
        let mut tau = [0.0; N_JOINTS];
        let mut dq = [0.0; N_JOINTS];
        tau[0] = 2.0;
        tau[3] = -1.0;
        dq[0] = 1.0;
        dq[3] = 2.0;
        let zero = [0.0; N_JOINTS];
        // Electronics per Nm: 0.5 W/Nm · (2 + 1) Nm = 1.5 W.
        let mut e = Effects::default();
        e.enable("electronics_nm=0.5").unwrap();
        assert!((ap(&e, &zero, &tau, &dq, &zero).effects - 1.5).abs() < 1e-12);
        // Per-joint friction: F = 2 → 2·(1.0·1 + 1.5·2) = 8 W.
        let mut e = Effects::default();
        e.enable("joint_friction=2").unwrap();
        assert!((ap(&e, &zero, &tau, &dq, &zero).effects - 8.0).abs() < 1e-12);
        // Housing friction: 0.1·(35 − 25)·1 + 0.1·(45 − 25)·2 = 1 + 4 = 5 W.
        let mut e = Effects::default();
        e.enable("housing_friction=0.1").unwrap();
        let mut housing = [25.0; N_JOINTS];
        housing[0] = 35.0;
        housing[3] = 45.0;
        let s = PlantSample {
            q: &zero,
            tau: &tau,
            dq: &dq,
            tau_home: &zero,
            winding_c: &[25.0; N_JOINTS],
            housing_c: &housing,
            bus_volts: 50.0,
        };
        assert!((arm_power(&PowerModel::PAPER, &e, &s).effects - 5.0).abs() < 1e-12);
        // Bus loss from electrical power: R·(P/V)² with P the base model's power.
        let mut e = Effects::default();
        e.enable("bus_power=0.1").unwrap();
        let p = ap(&e, &zero, &tau, &dq, &zero);
        let want = 0.1 * (p.base / 50.0).powi(2);
        assert!(p.base > 1.0 && (p.effects - want).abs() < 1e-12, "{p:?}");
        // A stalled joint (τ, no motion) loses on the bus only through its copper loss.
        let stalled = [5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let p = ap(&e, &zero, &stalled, &zero, &zero);
        assert!((p.effects - 0.1 * (p.base / 50.0).powi(2)).abs() < 1e-12);
    }

    #[test]
    fn switching_loss_follows_the_bus_voltage_by_hand() {
        let mut e = Effects::default();
        e.enable("switching=0.02").unwrap();
        let mut tau = [0.0; N_JOINTS];
        tau[0] = -2.6; // 2 A at K = 1.3
        tau[4] = 0.7; // 1 A at K = 0.7
        let zero = [0.0; N_JOINTS];
        let at = |volts: f64| {
            let s = PlantSample {
                q: &zero,
                tau: &tau,
                dq: &zero,
                tau_home: &zero,
                winding_c: &[25.0; N_JOINTS],
                housing_c: &[25.0; N_JOINTS],
                bus_volts: volts,
            };
            arm_power(&PowerModel::PAPER, &e, &s).effects
        };
        // 0.02 W/(V·A) · 50 V · 3 A = 3 W; at 40 V, 2.4 W.
        assert!((at(50.0) - 3.0).abs() < 1e-12, "{}", at(50.0));
        assert!((at(40.0) - 2.4).abs() < 1e-12, "{}", at(40.0));
        assert_eq!(SwitchingLoss::DEFAULT.per_volt_amp, 0.01);
    }

    #[test]
    fn every_name_enables_its_field() {
        for name in EFFECT_NAMES {
            let mut e = Effects::default();
            e.enable(name).unwrap();
            assert!(!e.is_empty(), "{name}");
            let json = serde_json::to_string(&e).unwrap();
            assert!(json.contains(name), "{name}: {json}");
        }
    }

    #[test]
    fn enable_parses_values() {
        let mut e = Effects::default();
        e.enable("braking=0.3").unwrap();
        e.enable("latency").unwrap();
        assert_eq!(e.braking.unwrap().return_fraction, 0.3);
        assert_eq!(e.latency.unwrap().seconds, SensorLatency::DEFAULT.seconds);
        assert!(e.enable("warp_drive").is_err());
        assert!(e.enable("thermal=abc").is_err());
    }
}
