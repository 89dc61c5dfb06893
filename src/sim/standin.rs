//! TEMPORARY stand-in for the robot stage's `ArmDynamics`, `Payload` and `JointFriction`
//! (CONTRACTS.md) so the simulator can be built and tested before the robot stage lands.
//! Crude diagonal inertia and a gravity torque that reproduces the G1's home torques.

use serde::{Deserialize, Serialize};

/// Point mass at the hand.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Payload {
    /// Mass [kg].
    pub mass_kg: f64,
    /// Position in the wrist-yaw link frame [m].
    pub com_m: [f64; 3],
}

/// Joint friction inside the measured torque.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct JointFriction {
    /// Coulomb torque [Nm].
    pub coulomb_nm: [f64; 7],
    /// Viscous coefficient [Nm·s/rad].
    pub viscous_nms: [f64; 7],
}

impl JointFriction {
    /// Fc·tanh(q̇/0.01) + Fv·q̇.
    pub fn torque(&self, dq: &[f64; 7]) -> [f64; 7] {
        let mut t = [0.0; 7];
        for i in 0..7 {
            t[i] = self.coulomb_nm[i] * (dq[i] / 0.01).tanh() + self.viscous_nms[i] * dq[i];
        }
        t
    }
}

/// Stand-in arm dynamics.
#[derive(Debug, Clone)]
pub struct ArmDynamics {
    extra_mass: f64,
}

const HOME: [f64; 7] = [-3.643, 0.2017, 0.0002, -3.4123, -0.0388, -1.219, 0.0];
const INERTIA: [f64; 7] = [0.25, 0.2, 0.05, 0.08, 0.01, 0.01, 0.005];

impl ArmDynamics {
    /// The stand-in without payload.
    pub fn standin() -> Self {
        ArmDynamics { extra_mass: 0.0 }
    }
    /// With a point mass at the hand.
    pub fn with_payload(&self, p: &Payload) -> Self {
        ArmDynamics {
            extra_mass: self.extra_mass + p.mass_kg,
        }
    }
    /// Gravity torque.
    pub fn gravity_torque(&self, q: &[f64; 7]) -> [f64; 7] {
        let s = 1.0 + self.extra_mass;
        let mut g = [0.0; 7];
        for i in 0..7 {
            g[i] = HOME[i] * s * q[i].cos();
        }
        g[0] = HOME[0] * s * (q[0] + 0.5 * q[3]).cos();
        g
    }
    /// Inverse dynamics.
    pub fn inverse_dynamics(&self, q: &[f64; 7], _dq: &[f64; 7], ddq: &[f64; 7]) -> [f64; 7] {
        let mut t = self.gravity_torque(q);
        for i in 0..7 {
            t[i] += INERTIA[i] * (1.0 + self.extra_mass) * ddq[i];
        }
        t
    }
}
