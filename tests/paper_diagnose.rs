//! Paper-scale diagnosis: a 1000-trial simulated session with a concealed winding-resistance
//! temperature drift (α = 0.00393 /K, the copper value), diagnosed with the base model refitted
//! inside every fold. The README states the drift is found at paper scale even where a short
//! session confounds it with b_i (α = 0.00382 ± 0.00012); this test holds that figure. The
//! truth is the simulator's α; the estimate is this code's result, held at its printed precision.
//! The README's bus-loss detection limit at paper scale is held here too.

mod common;

use g1viz::diagnose::{self, DiagnoseOptions};
use g1viz::signals::{SignalMap, load_recording};
use g1viz::sim::{self, Effects, Preset, SimConfig};

#[test]
fn paper_scale_thermal_drift_is_found_under_a_refit() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("paper_thermal.mcap");
    let mut effects = Effects::default();
    effects.enable("thermal").expect("thermal effect");
    let cfg = SimConfig {
        preset: Preset::Paper,
        seed: 21,
        effects,
        progress: false,
        ..SimConfig::default()
    };
    sim::simulate(&cfg, &path).expect("simulate");
    let rec = load_recording(&path, &SignalMap::g1_left_arm(), &Default::default()).expect("read");
    drop(dir);
    let d = diagnose::diagnose(&rec, &DiagnoseOptions::default()).expect("diagnose");
    print!("{}", d.summary);
    let ids: Vec<&str> = d.accepted.iter().map(|h| h.id.as_str()).collect();
    assert_eq!(ids, ["thermal"], "accepted: {ids:?}");
    let alpha = &d.accepted[0].params[0];
    println!("α = {} ± {}", alpha.value, alpha.std_err);
    common::assert_figure("paper-scale α [1/K]", alpha.value, "0.00382");
    common::assert_figure("paper-scale α s.e. [1/K]", alpha.std_err, "0.00012");
}

/// Diagnose a paper-scale session (seed 21, refit) with a shared DC-bus loss of `r_ohm`.
fn paper_bus_loss(r_ohm: f64) -> diagnose::Diagnosis {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("paper_bus.mcap");
    let mut effects = Effects::default();
    effects
        .enable(&format!("bus_loss={r_ohm}"))
        .expect("bus_loss effect");
    let cfg = SimConfig {
        preset: Preset::Paper,
        seed: 21,
        effects,
        progress: false,
        ..SimConfig::default()
    };
    sim::simulate(&cfg, &path).expect("simulate");
    let rec = load_recording(&path, &SignalMap::g1_left_arm(), &Default::default()).expect("read");
    drop(dir);
    diagnose::diagnose(&rec, &DiagnoseOptions::default()).expect("diagnose")
}

/// The bus-loss detection limit at paper scale (README): R_bus = 0.01 Ω is found (nothing else
/// claimed, within 10 %), so is 0.0075 Ω (the limit), and 0.005 Ω is not claimed: its fit is
/// significant, but it improves the held-out RMSE by less than the 2 % minimum improvement.
#[test]
fn paper_scale_bus_loss_detection_limit() {
    let mut outcome = Vec::new();
    for r in [0.01, 0.0075, 0.005] {
        let d = paper_bus_loss(r);
        let ids: Vec<String> = d.accepted.iter().map(|h| h.id.clone()).collect();
        let h = d
            .hypotheses
            .iter()
            .find(|h| h.id == "bus_loss")
            .expect("scored");
        println!(
            "R_bus {r} Ω: accepted {ids:?}; bus_loss {:.5} ± {:.5} Ω, p {:.1e}, ΔBIC {:.1}, held-out RMSE {:+.2} %: {}",
            h.params[0].value,
            h.params[0].std_err,
            h.p_value,
            h.delta_bic,
            -100.0 * h.rel_improvement,
            h.verdict
        );
        if r >= 0.0075 {
            // 0.0075 Ω sits at the limit: held-out RMSE −2.03 % against the 2 % minimum.
            assert_eq!(ids, ["bus_loss"], "R_bus {r}");
            assert!(
                (h.params[0].value - r).abs() <= 0.1 * r,
                "{:?}",
                h.params[0]
            );
        }
        if r == 0.005 {
            assert!(ids.is_empty(), "R_bus {r}: claimed {ids:?}");
            assert!(h.p_value < 1e-3 && h.rel_improvement < 0.02, "{h:?}");
        }
        // The README's figures, at their printed precision.
        let stated = match r {
            0.01 => ("0.0099", "0.0005", "-3.5"),
            0.0075 => ("0.0074", "0.0004", "-2.0"),
            _ => ("0.0048", "0.0005", "-0.9"),
        };
        common::assert_figure(&format!("R_bus {r}"), h.params[0].value, stated.0);
        common::assert_figure(&format!("R_bus {r} s.e."), h.params[0].std_err, stated.1);
        common::assert_figure(
            &format!("R_bus {r} held-out RMSE change [%]"),
            -100.0 * h.rel_improvement,
            stated.2,
        );
        if r == 0.005 {
            common::assert_figure("R_bus 0.005 p", h.p_value, "2.6e-8");
        }
        outcome.push((r, ids));
    }
    println!("{outcome:?}");
}
