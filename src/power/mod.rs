//! The paper's linear-in-parameters power model of the 7-joint arm:
//!
//! P_net = Σ_i [a_i τ_i q̇_i + b_i (τ_i² − τ̄0_i²) + c_i |q̇_i| + d_i q̇_i²] + Σ_{i<j} e_ij |q̇_i||q̇_j|
//!
//! Parameter order everywhere (vectors, regressors, model.json): a0..a6, b0..b6, c0..c6,
//! d0..d6, then e_ij for i<j in lexicographic order (e01, e02, …, e56).

use crate::{N_JOINTS, N_PARAMS};

/// Number of pairwise interaction terms.
pub const N_PAIRS: usize = N_JOINTS * (N_JOINTS - 1) / 2;

/// The joint pairs (i, j), i < j, in parameter order.
pub const PAIRS: [(usize, usize); N_PAIRS] = {
    let mut out = [(0, 0); N_PAIRS];
    let mut k = 0;
    let mut i = 0;
    while i < N_JOINTS {
        let mut j = i + 1;
        while j < N_JOINTS {
            out[k] = (i, j);
            k += 1;
            j += 1;
        }
        i += 1;
    }
    out
};

/// Parameters of the arm power model. Units: a [-], b [W/(Nm)²], c [W·s/rad], d [W·s²/rad²], e [W·s²/rad²].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PowerModel {
    /// Inverse gear efficiency per joint (scales mechanical power τq̇).
    pub a: [f64; N_JOINTS],
    /// Copper-loss coefficient per joint (scales Δτ² = τ² − τ̄0²).
    pub b: [f64; N_JOINTS],
    /// Coulomb-friction coefficient per joint (scales |q̇|).
    pub c: [f64; N_JOINTS],
    /// Viscous-friction coefficient per joint (scales q̇²).
    pub d: [f64; N_JOINTS],
    /// Pairwise interaction coefficients in [`PAIRS`] order (scale |q̇_i||q̇_j|).
    pub e: [f64; N_PAIRS],
}

/// Fill the 49-element regressor φ for one sample: [τq̇ (7), Δτ² (7), |q̇| (7), q̇² (7), |q̇_i||q̇_j| (21)].
/// `tau0_sq` is the per-joint mean squared torque of the trial's static pre-idle window.
#[inline]
pub fn regressor_into(
    tau: &[f64; N_JOINTS],
    dq: &[f64; N_JOINTS],
    tau0_sq: &[f64; N_JOINTS],
    phi: &mut [f64; N_PARAMS],
) {
    for i in 0..N_JOINTS {
        phi[i] = tau[i] * dq[i];
        phi[N_JOINTS + i] = tau[i] * tau[i] - tau0_sq[i];
        phi[2 * N_JOINTS + i] = dq[i].abs();
        phi[3 * N_JOINTS + i] = dq[i] * dq[i];
    }
    for (k, &(i, j)) in PAIRS.iter().enumerate() {
        phi[4 * N_JOINTS + k] = dq[i].abs() * dq[j].abs();
    }
}

impl PowerModel {
    /// The parameters identified in the paper (its Tables "Identified Power Model Parameters"
    /// and "Identified Pairwise Interaction Coefficients").
    pub const PAPER: PowerModel = PowerModel {
        a: [1.0; N_JOINTS],
        b: [0.4184, 0.3563, 0.2799, 0.3942, 0.0000, 0.3768, 0.0000],
        c: [0.0000, 1.2767, 0.0000, 0.0324, 0.0000, 0.3464, 0.0000],
        d: [0.6467, 0.0000, 0.2749, 0.0000, 1.0282, 1.2004, 1.7848],
        // (0,1) (0,2) (0,3) (0,4) (0,5) (0,6) (1,2) (1,3) (1,4) (1,5) (1,6)
        // (2,3) (2,4) (2,5) (2,6) (3,4) (3,5) (3,6) (4,5) (4,6) (5,6)
        e: [
            0.0000, 0.0000, 0.9090, 0.0000, 0.0000, 0.4365, 0.0000, 1.1053, 0.1039, 0.1034, 0.5111,
            0.4054, 0.0554, 0.0050, 0.8613, 0.0000, 0.0000, 0.0591, 0.3417, 0.0000, 0.2936,
        ],
    };

    /// The parameter vector θ in the documented order.
    pub fn to_vector(&self) -> [f64; N_PARAMS] {
        let mut v = [0.0; N_PARAMS];
        v[..N_JOINTS].copy_from_slice(&self.a);
        v[N_JOINTS..2 * N_JOINTS].copy_from_slice(&self.b);
        v[2 * N_JOINTS..3 * N_JOINTS].copy_from_slice(&self.c);
        v[3 * N_JOINTS..4 * N_JOINTS].copy_from_slice(&self.d);
        v[4 * N_JOINTS..].copy_from_slice(&self.e);
        v
    }

    /// Build a model from θ in the documented order.
    pub fn from_vector(v: &[f64; N_PARAMS]) -> Self {
        let mut m = PowerModel {
            a: [0.0; N_JOINTS],
            b: [0.0; N_JOINTS],
            c: [0.0; N_JOINTS],
            d: [0.0; N_JOINTS],
            e: [0.0; N_PAIRS],
        };
        m.a.copy_from_slice(&v[..N_JOINTS]);
        m.b.copy_from_slice(&v[N_JOINTS..2 * N_JOINTS]);
        m.c.copy_from_slice(&v[2 * N_JOINTS..3 * N_JOINTS]);
        m.d.copy_from_slice(&v[3 * N_JOINTS..4 * N_JOINTS]);
        m.e.copy_from_slice(&v[4 * N_JOINTS..]);
        m
    }

    /// Predicted net arm power [W] for one sample. No allocation: cheap enough for an RL reward loop.
    #[inline]
    pub fn predict(
        &self,
        tau: &[f64; N_JOINTS],
        dq: &[f64; N_JOINTS],
        tau0_sq: &[f64; N_JOINTS],
    ) -> f64 {
        let mut p = 0.0;
        for i in 0..N_JOINTS {
            p += self.a[i] * tau[i] * dq[i]
                + self.b[i] * (tau[i] * tau[i] - tau0_sq[i])
                + self.c[i] * dq[i].abs()
                + self.d[i] * dq[i] * dq[i];
        }
        for (k, &(i, j)) in PAIRS.iter().enumerate() {
            p += self.e[k] * dq[i].abs() * dq[j].abs();
        }
        p
    }
}

/// Joint-level torque constant [Nm/A] of each arm joint's drive (motor torque constant × gear
/// ratio), used to turn joint torque into drive current for current-based loss terms
/// (shared DC-bus loss, drive-electronics loss). Nominal figures for the G1 arm actuators;
/// the simulator's plant and the diagnosis hypotheses both use these so their physical
/// parameters (e.g. bus resistance in Ω) mean the same thing.
pub const JOINT_TORQUE_CONSTANT: [f64; N_JOINTS] = [1.3, 1.3, 1.3, 1.3, 0.7, 0.7, 0.7];
