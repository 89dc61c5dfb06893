//! The twin's battery: what every recorded voltage (`/lowstate.motor_state[k].vol`, the
//! main board's rail voltage, the BMS pack and cell voltages) follows.
//!
//! Two models. [`Battery::Linear`] (the default, behind every figure of the docs) is an
//! open-circuit voltage linear in state of charge with no internal resistance: every recorded
//! voltage is then a function of the charge alone, which falls steadily over a session, so the
//! voltages follow session time. [`Battery::Realistic`] is what a Li-ion pack does: a per-cell
//! open-circuit voltage that is not linear in charge ([`NMC_OCV`]) and a pack internal resistance
//! the load current flows through, so the terminal voltage sags under load,
//! V = OCV(SoC) − I·R_int with I = P_load / V, and the charge is counted in ampere-hours.

use serde::{Deserialize, Serialize};

/// Cells in series in the pack.
pub const CELLS: f64 = 13.0;
/// Usable energy of the linear model [Wh] (9 Ah pack, 13 cells).
pub const LINEAR_WH: f64 = 450.0;
/// Capacity of the realistic pack [Ah] (the G1's 9 Ah, 13-series pack).
pub const PACK_AH: f64 = 9.0;
/// Internal resistance of the realistic pack [Ω]: 13 series groups of three 18650-class NMC
/// cells of ≈ 30 mΩ DC resistance each (10 mΩ per group, 0.13 Ω) plus ≈ 20 mΩ of interconnects,
/// fuse and the BMS switches.
pub const PACK_RESISTANCE_OHM: f64 = 0.15;

/// Open-circuit voltage of one NMC/graphite cell [V] against state of charge, 25 °C: the shape
/// of the slow (C/20) OCV curves published for common 18650 NMC cells (a steep knee below 10 %,
/// a shallow middle plateau around 3.6–3.8 V, rising to 4.18 V at full charge; see e.g.
/// G. L. Plett, *Battery Management Systems, Vol. I: Battery Modeling*, Artech House 2015,
/// ch. 2, for such curves and how they are measured). Values rounded to 10 mV; not measured on
/// the G1's pack. Linearly interpolated between the points.
pub const NMC_OCV: [(f64, f64); 13] = [
    (0.00, 3.00),
    (0.05, 3.30),
    (0.10, 3.45),
    (0.15, 3.52),
    (0.20, 3.56),
    (0.30, 3.62),
    (0.40, 3.67),
    (0.50, 3.72),
    (0.60, 3.79),
    (0.70, 3.87),
    (0.80, 3.95),
    (0.90, 4.05),
    (1.00, 4.18),
];

/// Which battery the twin simulates ([`crate::sim::SimConfig::battery`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Battery {
    /// Open-circuit voltage 13·(3.3 + 0.85·SoC) V, no internal resistance, charge drawn as
    /// energy from 450 Wh: every recorded voltage is a function of the charge only.
    #[default]
    Linear,
    /// Per-cell NMC open-circuit voltage curve ([`NMC_OCV`]), pack internal resistance
    /// [`PACK_RESISTANCE_OHM`] carrying the load current, charge counted from a 9 Ah capacity.
    Realistic,
}

impl std::str::FromStr for Battery {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> anyhow::Result<Battery> {
        match s.trim() {
            "linear" => Ok(Battery::Linear),
            "realistic" => Ok(Battery::Realistic),
            other => anyhow::bail!("unknown battery {other:?} (known: linear, realistic)"),
        }
    }
}

/// One cell's open-circuit voltage at state of charge `soc` ([`NMC_OCV`], clamped to 0..=1).
pub fn nmc_cell_ocv(soc: f64) -> f64 {
    let s = if soc.is_nan() {
        0.0
    } else {
        soc.clamp(0.0, 1.0)
    };
    let k = NMC_OCV
        .windows(2)
        .position(|w| s <= w[1].0)
        .unwrap_or(NMC_OCV.len() - 2);
    let ((s0, v0), (s1, v1)) = (NMC_OCV[k], NMC_OCV[k + 1]);
    v0 + (v1 - v0) * (s - s0) / (s1 - s0)
}

impl Battery {
    /// Pack open-circuit voltage [V] at state of charge `soc`.
    pub fn open_circuit_volts(self, soc: f64) -> f64 {
        match self {
            Battery::Linear => CELLS * (3.3 + 0.85 * soc),
            Battery::Realistic => CELLS * nmc_cell_ocv(soc),
        }
    }

    /// Internal resistance of the pack [Ω].
    pub fn resistance_ohm(self) -> f64 {
        match self {
            Battery::Linear => 0.0,
            Battery::Realistic => PACK_RESISTANCE_OHM,
        }
    }

    /// Terminal voltage [V] while the pack delivers `load_w` [W]: the larger root of
    /// V² − OCV·V + R·P = 0 (V = OCV − R·P/V); when the load exceeds what the pack can deliver
    /// (OCV² < 4RP) the voltage at maximum power, OCV/2.
    pub fn terminal_volts(self, soc: f64, load_w: f64) -> f64 {
        let ocv = self.open_circuit_volts(soc);
        let r = self.resistance_ohm();
        if r == 0.0 {
            return ocv;
        }
        let disc = ocv * ocv - 4.0 * r * load_w;
        0.5 * (ocv + disc.max(0.0).sqrt())
    }

    /// State of charge used while delivering `load_w` [W] for `dt` [s] at terminal voltage
    /// `volts`: energy from [`LINEAR_WH`] for the linear model, charge (I = P/V) from
    /// [`PACK_AH`] for the realistic one (the loss in R_int is drawn from the cells too).
    pub fn soc_used(self, load_w: f64, volts: f64, dt: f64) -> f64 {
        match self {
            Battery::Linear => load_w * dt / 3600.0 / LINEAR_WH,
            Battery::Realistic => load_w / volts.max(1.0) * dt / 3600.0 / PACK_AH,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nmc_curve_is_monotonic_and_interpolates_its_table() {
        let mut prev = f64::NEG_INFINITY;
        for k in 0..=1000 {
            let v = nmc_cell_ocv(k as f64 / 1000.0);
            assert!(v > prev, "not increasing at SoC {}", k as f64 / 1000.0);
            prev = v;
        }
        // Table points and a midpoint by hand: (3.72 + 3.79) / 2 at 55 %.
        assert_eq!(nmc_cell_ocv(0.0), 3.00);
        assert_eq!(nmc_cell_ocv(1.0), 4.18);
        assert!((nmc_cell_ocv(0.55) - 3.755).abs() < 1e-12);
        assert!((nmc_cell_ocv(0.95) - 4.115).abs() < 1e-12);
        // Clamped outside 0..=1 and for NaN.
        assert_eq!(nmc_cell_ocv(1.5), 4.18);
        assert_eq!(nmc_cell_ocv(-0.5), 3.00);
        assert_eq!(nmc_cell_ocv(f64::NAN), 3.00);
        // Not linear: the slope near full charge is more than twice the plateau's.
        let slope = |a: f64, b: f64| (nmc_cell_ocv(b) - nmc_cell_ocv(a)) / (b - a);
        assert!(slope(0.9, 1.0) > 2.0 * slope(0.3, 0.5));
    }

    #[test]
    fn terminal_voltage_sags_under_load_by_current_times_resistance() {
        let b = Battery::Realistic;
        let soc = 0.8;
        let ocv = b.open_circuit_volts(soc);
        assert!((ocv - 13.0 * 3.95).abs() < 1e-12);
        // At rest no sag.
        assert_eq!(b.terminal_volts(soc, 0.0), ocv);
        // 150 W at ≈ 51 V is ≈ 2.9 A: 0.15 Ω sags 0.442 V (by hand: OCV = 51.35 V,
        // V = (51.35 + √(51.35² − 4·0.15·150)) / 2 = 50.908 V); V = OCV − R·P/V holds.
        let v = b.terminal_volts(soc, 150.0);
        assert!(v < ocv, "sag has the wrong sign");
        assert!((ocv - v - 0.15 * 150.0 / v).abs() < 1e-9);
        assert!((v - 50.908).abs() < 1e-3, "V {v}");
        assert!((ocv - v - 0.442).abs() < 1e-3, "sag {}", ocv - v);
        // More load, more sag; 20 W more (an arm motion) ≈ 0.06 V more.
        let dv = v - b.terminal_volts(soc, 170.0);
        assert!((dv - 0.15 * 20.0 / v).abs() < 1e-3, "{dv}");
        // Beyond the maximum power point: OCV / 2, not NaN.
        assert_eq!(b.terminal_volts(soc, 1e6), 0.5 * ocv);
    }

    #[test]
    fn linear_battery_is_the_old_model() {
        let b = Battery::Linear;
        for soc in [0.0, 0.5, 0.97] {
            assert_eq!(b.open_circuit_volts(soc), 13.0 * (3.3 + 0.85 * soc));
            assert_eq!(b.terminal_volts(soc, 500.0), b.open_circuit_volts(soc));
        }
        assert_eq!(b.soc_used(135.0, 50.0, 3600.0), 135.0 / 450.0);
        // Realistic: 9 A for an hour is the whole 9 Ah.
        assert!((Battery::Realistic.soc_used(450.0, 50.0, 3600.0) - 1.0).abs() < 1e-12);
        assert_eq!("realistic".parse::<Battery>().unwrap(), Battery::Realistic);
        assert_eq!("linear".parse::<Battery>().unwrap(), Battery::Linear);
        assert!("lead-acid".parse::<Battery>().is_err());
    }
}
