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
use crate::power::JOINT_TORQUE_CONSTANT;
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

/// The set of switched-on effects (all off by default: the paper's plant).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Effects {
    /// Winding-resistance temperature drift.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub thermal: Option<ThermalDrift>,
    /// Braking asymmetry.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub braking: Option<BrakingAsymmetry>,
    /// Shared DC-bus loss.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub bus_loss: Option<BusLoss>,
    /// Point mass at the hand that the URDF lacks.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub payload: Option<Payload>,
    /// Power-sensor latency.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub latency: Option<SensorLatency>,
    /// Elbow cable-harness drag.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub harness_drag: Option<HarnessDrag>,
}

/// Names accepted by [`Effects::enable`], in documentation order.
pub const EFFECT_NAMES: [&str; 6] = [
    "thermal",
    "braking",
    "bus_loss",
    "payload",
    "latency",
    "harness_drag",
];

impl ThermalDrift {
    /// Copper's temperature coefficient.
    pub const DEFAULT: ThermalDrift = ThermalDrift {
        alpha_per_k: 0.00393,
    };
}
impl BrakingAsymmetry {
    /// A quarter of the regenerated power comes back (drive and gear losses eat the rest).
    pub const DEFAULT: BrakingAsymmetry = BrakingAsymmetry {
        return_fraction: 0.25,
    };
}
impl BusLoss {
    /// 50 mΩ: battery internal resistance share plus harness and connectors of the arm rail.
    pub const DEFAULT: BusLoss = BusLoss {
        resistance_ohm: 0.05,
    };
}
impl SensorLatency {
    /// 0.3 s: a slow sensor pipeline (several 100 ms buffers are common on BMS/MBS links).
    pub const DEFAULT: SensorLatency = SensorLatency { seconds: 0.3 };
}
impl HarnessDrag {
    /// 4 W·s/rad: a drag torque of k·(1 − cos q) = 1.8 Nm at 1 rad elbow flexion
    /// (1.8 W at 1 rad/s) — a stiff cable bundle.
    pub const DEFAULT: HarnessDrag = HarnessDrag { w_per_rad_s: 4.0 };
}
/// Default payload: a 0.5 kg tool held 10 cm beyond the wrist-yaw link origin.
pub const DEFAULT_PAYLOAD: Payload = Payload {
    mass_kg: 0.5,
    com_m: [0.10, 0.0, 0.0],
};

impl Effects {
    /// Switch on effect `spec` = `name` or `name=value` (value in the effect's unit: thermal α [1/K],
    /// braking r [-], bus_loss R [Ω], payload mass [kg] at the default position, latency [s],
    /// harness_drag k [W·s/rad]).
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
        match name {
            "thermal" => {
                self.thermal =
                    Some(
                        value.map_or(ThermalDrift::DEFAULT, |alpha_per_k| ThermalDrift {
                            alpha_per_k,
                        }),
                    )
            }
            "braking" => {
                self.braking = Some(value.map_or(BrakingAsymmetry::DEFAULT, |return_fraction| {
                    BrakingAsymmetry { return_fraction }
                }))
            }
            "bus_loss" => {
                self.bus_loss = Some(value.map_or(BusLoss::DEFAULT, |resistance_ohm| BusLoss {
                    resistance_ohm,
                }))
            }
            "payload" => {
                self.payload = Some(value.map_or(DEFAULT_PAYLOAD, |mass_kg| Payload {
                    mass_kg,
                    ..DEFAULT_PAYLOAD
                }))
            }
            "latency" => {
                self.latency =
                    Some(value.map_or(SensorLatency::DEFAULT, |seconds| SensorLatency { seconds }))
            }
            "harness_drag" => {
                self.harness_drag =
                    Some(
                        value.map_or(HarnessDrag::DEFAULT, |w_per_rad_s| HarnessDrag {
                            w_per_rad_s,
                        }),
                    )
            }
            _ => anyhow::bail!(
                "unknown effect {name:?} (known: {})",
                EFFECT_NAMES.join(", ")
            ),
        }
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
    /// What the power-changing effects add (thermal, braking, bus loss, harness drag).
    pub effects: f64,
}

/// Net arm power of the plant for true torque `tau` (incl. friction and payload), velocity `dq`,
/// position `q`, home torque `tau_home` and winding temperature `temp_c`.
pub fn arm_power(
    model: &crate::power::PowerModel,
    effects: &Effects,
    q: &[f64; N_JOINTS],
    tau: &[f64; N_JOINTS],
    dq: &[f64; N_JOINTS],
    tau_home: &[f64; N_JOINTS],
    temp_c: &[f64; N_JOINTS],
) -> ArmPower {
    let mut tau0_sq = [0.0; N_JOINTS];
    for i in 0..N_JOINTS {
        tau0_sq[i] = tau_home[i] * tau_home[i];
    }
    let base = model.predict(tau, dq, &tau0_sq);
    let mut extra = 0.0;
    for i in 0..N_JOINTS {
        if let Some(th) = effects.thermal {
            extra += model.b[i]
                * th.alpha_per_k
                * (temp_c[i] - THERMAL_REFERENCE_C)
                * (tau[i] * tau[i] - tau0_sq[i]);
        }
        if let Some(br) = effects.braking {
            let mech = model.a[i] * tau[i] * dq[i];
            if mech < 0.0 {
                extra += (br.return_fraction - 1.0) * mech;
            }
        }
    }
    if let Some(bus) = effects.bus_loss {
        let current: f64 = (0..N_JOINTS)
            .map(|i| tau[i].abs() / JOINT_TORQUE_CONSTANT[i])
            .sum();
        extra += bus.resistance_ohm * current * current;
    }
    if let Some(h) = effects.harness_drag {
        extra += h.w_per_rad_s * (1.0 - q[3].cos()) * dq[3].abs();
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
        let p = arm_power(
            &PowerModel::PAPER,
            &e,
            &[0.0; 7],
            &tau,
            &dq,
            &[0.0; 7],
            &[25.0; 7],
        );
        assert!((p.effects - 1.5).abs() < 1e-12);
        dq[3] = 1.0;
        let p = arm_power(
            &PowerModel::PAPER,
            &e,
            &[0.0; 7],
            &tau,
            &dq,
            &[0.0; 7],
            &[25.0; 7],
        );
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
        let p = arm_power(&PowerModel::PAPER, &e, &q, &tau, &dq, &tau, &[25.0; 7]);
        // 0.1 Ω · (3 A)² = 0.9 W; 2 · (1 − cos 90°) · 0.5 = 1 W.
        assert!((p.effects - 1.9).abs() < 1e-9, "{}", p.effects);
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
