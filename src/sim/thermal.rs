//! First-order thermal model of each arm motor: the winding temperature T follows
//! C·dT/dt = P_heat − (T − T_amb)/R_th with P_heat = idle loss + copper heating b_heat·τ², C = τ_th/R_th.
//! The housing sits between winding and ambient: it settles at ambient + 70 % of the winding's
//! rise, lagging the winding with [`HOUSING_LAG`] times its time constant (a second, heavier
//! thermal mass), so a warm motor that cools down shows a housing that is still warm. Winding
//! constants as in the shared truth files (`plant.thermal`): with them a session's windings warm
//! by a few K over several minutes.

use serde::{Deserialize, Serialize};

use crate::N_JOINTS;

/// Thermal constants of the seven arm motors.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ThermalModel {
    /// Winding-to-ambient thermal resistance [K/W].
    #[serde(rename = "R_K_per_W")]
    pub r_k_per_w: [f64; N_JOINTS],
    /// Thermal time constant [s].
    pub tau_s: [f64; N_JOINTS],
    /// Heat at standstill without torque (iron/drive losses) [W].
    pub idle_w: [f64; N_JOINTS],
    /// Copper heating coefficient [W/(Nm)²] (heat = b_heat·τ²).
    pub b_heat: [f64; N_JOINTS],
    /// Ambient temperature at session start [°C].
    pub ambient_c: f64,
    /// Ambient warming rate [K/h].
    pub ambient_rate_k_per_h: f64,
}

impl Default for ThermalModel {
    fn default() -> Self {
        ThermalModel {
            r_k_per_w: [5.5, 5.3, 6.0, 5.5, 8.4, 7.2, 8.4],
            tau_s: [1500.0, 1500.0, 1300.0, 1300.0, 900.0, 900.0, 900.0],
            idle_w: [1.6, 1.5, 1.3, 1.4, 1.0, 1.1, 1.0],
            b_heat: [0.42, 0.36, 0.28, 0.39, 0.15, 0.38, 0.15],
            ambient_c: 23.0,
            ambient_rate_k_per_h: 1.5,
        }
    }
}

/// Housing time constant as a multiple of the winding's.
pub const HOUSING_LAG: f64 = 3.0;
/// Share of the winding's rise above ambient the housing settles at.
const HOUSING_SHARE: f64 = 0.7;

/// Winding and housing temperatures of the seven motors, integrated step by step.
#[derive(Debug, Clone)]
pub struct ThermalState {
    model: ThermalModel,
    /// Current winding temperature [°C].
    pub winding_c: [f64; N_JOINTS],
    /// Current housing temperature [°C].
    housing: [f64; N_JOINTS],
}

impl ThermalState {
    /// All windings at `t_start_c` [°C].
    pub fn new(model: ThermalModel, t_start_c: f64) -> Self {
        let amb = model.ambient_c;
        ThermalState {
            winding_c: [t_start_c; N_JOINTS],
            housing: [amb + HOUSING_SHARE * (t_start_c - amb); N_JOINTS],
            model,
        }
    }

    /// Set every housing temperature [°C].
    pub fn set_housing(&mut self, c: f64) {
        self.housing = [c; N_JOINTS];
    }

    /// Ambient temperature at session time `t` [s].
    pub fn ambient(&self, t: f64) -> f64 {
        self.model.ambient_c + self.model.ambient_rate_k_per_h * t / 3600.0
    }

    /// Advance by `dt` [s] at session time `t` with joint torques `tau` [Nm] (exact exponential
    /// step for a constant input over dt, stable for any dt).
    pub fn step(&mut self, t: f64, dt: f64, tau: &[f64; N_JOINTS]) {
        let amb = self.ambient(t);
        for (i, (w, tq)) in self.winding_c.iter_mut().zip(tau).enumerate() {
            let heat = self.model.idle_w[i] + self.model.b_heat[i] * tq * tq;
            let t_eq = amb + heat * self.model.r_k_per_w[i];
            let k = (-dt / self.model.tau_s[i]).exp();
            *w = t_eq + (*w - t_eq) * k;
            let h_eq = amb + HOUSING_SHARE * (*w - amb);
            let kh = (-dt / (HOUSING_LAG * self.model.tau_s[i])).exp();
            self.housing[i] = h_eq + (self.housing[i] - h_eq) * kh;
        }
    }

    /// Housing temperature [°C] of motor `i`.
    pub fn housing_c(&self, i: usize) -> f64 {
        self.housing[i]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settles_at_ambient_plus_heat_times_resistance() {
        let m = ThermalModel {
            ambient_rate_k_per_h: 0.0,
            ..Default::default()
        };
        let mut s = ThermalState::new(m, 30.0);
        let tau = [2.0; N_JOINTS];
        for k in 0..100_000 {
            s.step(k as f64, 1.0, &tau);
        }
        for i in 0..N_JOINTS {
            let expected = 23.0 + (m.idle_w[i] + m.b_heat[i] * 4.0) * m.r_k_per_w[i];
            assert!((s.winding_c[i] - expected).abs() < 1e-6);
        }
    }

    #[test]
    fn time_constant_by_hand() {
        // After one time constant a step response covers 1 − 1/e of the way.
        let m = ThermalModel {
            ambient_rate_k_per_h: 0.0,
            ..Default::default()
        };
        let mut s = ThermalState::new(m, 30.0);
        let t_eq = 23.0 + m.idle_w[0] * m.r_k_per_w[0];
        let steps = 1500 * 100;
        for k in 0..steps {
            s.step(k as f64 * 0.01, 0.01, &[0.0; N_JOINTS]);
        }
        let expected = t_eq + (30.0 - t_eq) * (-1.0f64).exp();
        assert!((s.winding_c[0] - expected).abs() < 1e-6);
    }

    #[test]
    fn housing_lags_the_winding_and_settles_at_seventy_percent() {
        let m = ThermalModel {
            ambient_rate_k_per_h: 0.0,
            ..Default::default()
        };
        // A hot motor left without load: the winding cools faster than its housing.
        let mut s = ThermalState::new(m, 70.0);
        let h0 = s.housing_c(0);
        assert!((h0 - (23.0 + 0.7 * 47.0)).abs() < 1e-12);
        for k in 0..60_000 {
            s.step(k as f64 * 0.01, 0.01, &[0.0; N_JOINTS]);
        }
        // After 600 s the winding has dropped a third of the way to equilibrium, the housing
        // much less.
        let w_drop = 70.0 - s.winding_c[0];
        let h_drop = h0 - s.housing_c(0);
        assert!(w_drop > 10.0 && h_drop < 0.5 * w_drop, "{w_drop} {h_drop}");
        for k in 60_000..4_000_000 {
            s.step(k as f64 * 0.01, 0.01, &[0.0; N_JOINTS]);
        }
        let t_eq = 23.0 + m.idle_w[0] * m.r_k_per_w[0];
        assert!((s.housing_c(0) - (23.0 + 0.7 * (t_eq - 23.0))).abs() < 0.05);
    }
}
