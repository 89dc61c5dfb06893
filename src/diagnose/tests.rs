//! End-to-end tests of [`super::diagnose_trials`] on miniature simulated sessions.

#[cfg(test)]
mod refit_tests {
    use crate::diagnose::testkit::{Effects, session};
    use crate::diagnose::*;

    fn run(fx: Effects, seed: u64) -> Diagnosis {
        run_with(fx, seed, &DiagnoseOptions::default())
    }

    fn run_with(fx: Effects, seed: u64, opts: &DiagnoseOptions) -> Diagnosis {
        let (rec, windows) = session(60, seed, fx);
        let d = diagnose_trials(&rec, &windows, None, opts).unwrap();
        eprintln!("{}", d.summary);
        for h in &d.hypotheses {
            eprintln!(
                "  {:>14} {:>10.4} p={:.1e} dBIC={:7.1} rel={:+.3} {}",
                h.id, h.params[0].value, h.p_value, h.delta_bic, h.rel_improvement, h.verdict
            );
        }
        d
    }

    #[test]
    fn null_session_accepts_nothing() {
        let d = run(Effects::default(), 1);
        assert!(d.accepted.is_empty());
        assert!(d.unexplained.iter().all(|c| !c.significant));
    }

    #[test]
    fn braking_session_names_braking() {
        let d = run(
            Effects {
                braking_r: Some(0.4),
                ..Default::default()
            },
            2,
        );
        assert_eq!(d.hypotheses[0].id, "braking");
        let r = d
            .final_model
            .params
            .iter()
            .find(|p| p.symbol == "r")
            .unwrap()
            .value;
        assert!((r - 0.4).abs() < 0.04, "r = {r}");
        assert!(d.final_model.after.r2 > d.final_model.before.r2);
        let dir = std::env::var("DIAG_REPORT_DIR")
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|_| {
                std::env::temp_dir().join(format!("g1viz-diag-{}", std::process::id()))
            });
        write_report(&dir, &d).unwrap();
        let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
        assert!(md.contains("| 1 | braking |"));
        for f in REPORT_FIGURES.iter().take(4) {
            assert!(dir.join(f).metadata().unwrap().len() > 1000, "{f}");
        }
        let back: Diagnosis =
            serde_json::from_str(&std::fs::read_to_string(dir.join("diagnosis.json")).unwrap())
                .unwrap();
        assert_eq!(back.accepted.len(), d.accepted.len());
    }

    #[test]
    fn latency_session_finds_the_lag() {
        let d = run(
            Effects {
                latency_s: Some(0.3),
                ..Default::default()
            },
            3,
        );
        assert_eq!(d.hypotheses[0].id, "latency");
        let l = d
            .final_model
            .params
            .iter()
            .find(|p| p.symbol == "L")
            .unwrap()
            .value;
        assert!((l - 0.3).abs() < 0.03, "L = {l}");
    }

    #[test]
    fn harness_drag_is_located_at_the_elbow() {
        let d = run(
            Effects {
                harness_k: Some(4.0),
                ..Default::default()
            },
            4,
        );
        let top = &d.unexplained[0];
        assert!(top.significant && top.feature.starts_with("j3"), "{top:?}");
    }
}

#[cfg(test)]
mod twin_tests {
    use crate::diagnose::testkit::{Effects, session};
    use crate::diagnose::*;
    use crate::power::PowerModel;

    fn twin() -> DiagnoseOptions {
        DiagnoseOptions {
            reference: Some(PowerModel::PAPER),
            ..Default::default()
        }
    }

    #[test]
    fn twin_mode_recovers_thermal_drift_and_accepts_nothing_on_null() {
        let (rec, w) = session(
            60,
            5,
            Effects {
                thermal_alpha: Some(0.00393),
                ..Default::default()
            },
        );
        let d = diagnose_trials(&rec, &w, None, &twin()).unwrap();
        eprintln!("{}", d.summary);
        for h in &d.hypotheses {
            eprintln!(
                "  {:>14} {:>10.5} ± {:.5} p={:.1e} dBIC={:7.1} rel={:+.3}",
                h.id,
                h.params[0].value,
                h.params[0].std_err,
                h.p_value,
                h.delta_bic,
                h.rel_improvement
            );
        }
        assert_eq!(d.hypotheses[0].id, "thermal");
        let a = d
            .final_model
            .params
            .iter()
            .find(|p| p.symbol == "α")
            .unwrap()
            .value;
        assert!((a - 0.00393).abs() < 0.1 * 0.00393, "α = {a}");
        let (rec, w) = session(60, 6, Effects::default());
        let d = diagnose_trials(&rec, &w, None, &twin()).unwrap();
        eprintln!("{}", d.summary);
        assert!(d.accepted.is_empty());
    }
}

#[cfg(test)]
mod torque_tests {
    use crate::diagnose::testkit::{Effects, session};
    use crate::diagnose::*;
    use crate::robot::{ArmDynamics, Payload, RobotModel};
    use crate::signals::Recording;

    /// Replace the miniature session's torques by the shipped URDF's inverse dynamics (with an
    /// optional payload) plus joint friction and noise.
    fn with_urdf_torques(rec: &mut Recording, payload: Option<Payload>) -> ArmDynamics {
        let model = RobotModel::builtin();
        let joints = model.g1_left_arm().unwrap();
        let urdf = ArmDynamics::new(&model, &joints).unwrap();
        let plant = payload.map_or_else(|| urdf.clone(), |p| urdf.with_payload(&p));
        let s = &mut rec.state;
        let n = s.t.len();
        for k in 0..n {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
            let ddq: [f64; 7] =
                std::array::from_fn(|j| (s.dq[b][j] - s.dq[a][j]) / (s.t[b] - s.t[a]).max(1e-9));
            let tau = plant.inverse_dynamics(&s.q[k], &s.dq[k], &ddq);
            let noise = ((k * 7919) % 1000) as f64 / 1000.0 - 0.5;
            s.tau[k] = std::array::from_fn(|j| {
                tau[j] + 0.3 * (s.dq[k][j] / 0.01).tanh() + 0.1 * s.dq[k][j] + 0.05 * noise
            });
        }
        urdf
    }

    #[test]
    fn payload_is_recovered_at_the_torque_level_and_absent_when_there_is_none() {
        let (mut rec, w) = session(40, 8, Effects::default());
        let urdf = with_urdf_torques(
            &mut rec,
            Some(Payload {
                mass_kg: 0.5,
                com_m: [0.1, 0.0, 0.0],
            }),
        );
        let d = diagnose_trials(&rec, &w, Some(&urdf), &DiagnoseOptions::default()).unwrap();
        eprintln!("{}", d.summary);
        let p = d.hypotheses.iter().find(|h| h.id == "payload").unwrap();
        assert!(p.accepted && p.rank == 1, "{p:?}");
        assert!(
            (p.params[0].value - 0.5).abs() < 0.05,
            "m = {}",
            p.params[0].value
        );
        assert!(
            (p.params[1].value - 0.1).abs() < 0.01,
            "cx = {}",
            p.params[1].value
        );

        let (mut rec, w) = session(40, 9, Effects::default());
        let urdf = with_urdf_torques(&mut rec, None);
        let d = diagnose_trials(&rec, &w, Some(&urdf), &DiagnoseOptions::default()).unwrap();
        let p = d.hypotheses.iter().find(|h| h.id == "payload").unwrap();
        assert!(!p.accepted, "{p:?}");
    }
}

#[cfg(test)]
mod stage_tests {
    use crate::diagnose::testkit::{Effects, session};
    use crate::diagnose::*;
    use crate::signals::PowerSeries;
    use rand::{RngExt, SeedableRng};

    /// One truth across stages: a step of the main-board meter's offset that the battery meter
    /// does not show is found by the meter comparison and taken out of the readings before the
    /// rest power reads them, so the rest power claims no change of the rail's power for it.
    /// The same step where the battery meter wanders by watts (it cannot tell load from
    /// artefact), and a real step of the rail's power that both meters show, are located on the
    /// rest reading, not claimed and not corrected.
    #[test]
    fn a_meter_step_is_corrected_before_the_rest_power_reads_it() {
        // (battery meter's slow wander [W], step on the battery meter too, verdict)
        for (wander, on_both, verdict) in [
            (0.0, false, MeterVerdict::Artefact),
            (30.0, false, MeterVerdict::Undecided),
            (0.0, true, MeterVerdict::Load),
        ] {
            let (mut rec, windows) = session(240, 9, Effects::default());
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
            let (first, last) = (windows[0].t_traj_start, windows[239].t_traj_start);
            let at = first + 0.5 * (last - first);
            // The main-board meter's offset steps by 3 W halfway between the trials' starts.
            for (t, w) in rec.mbs.t.iter().zip(rec.mbs.watts.iter_mut()) {
                if *t > at {
                    *w += 3.0;
                }
            }
            // The battery meter: the same rail plus the rest of the robot, its own noise and a
            // wander held over ≈ 20 s (a random level per 20 s).
            let levels: Vec<f64> = (0..=(last / 20.0) as usize + 2)
                .map(|_| wander * (rng.random::<f64>() - 0.5))
                .collect();
            rec.bms = PowerSeries {
                t: rec.mbs.t.clone(),
                watts: (rec.mbs.t.iter().zip(&rec.mbs.watts))
                    .map(|(&t, w)| {
                        let own = if on_both || t <= at { 0.0 } else { -3.0 };
                        w + own
                            + 35.0
                            + levels[(t / 20.0) as usize]
                            + 0.3 * (rng.random::<f64>() - 0.5)
                    })
                    .collect(),
            };
            let d = diagnose_trials(&rec, &windows, None, &DiagnoseOptions::default()).unwrap();
            let r = d.discovery.as_ref().expect("discovery ran");
            let m = (r.meter_drift.as_ref())
                .or(r.meter_located.as_ref())
                .expect("the meter's step is found");
            assert!(
                m.form.contains("step") && (m.change_w - 3.0).abs() < 0.3,
                "{m:?}"
            );
            assert_eq!(m.check.verdict, verdict, "{m:?}");
            assert_eq!(r.meter_drift.is_some(), verdict == MeterVerdict::Artefact);
            let rest = r.rest.as_ref().expect("the rest power ran");
            if verdict == MeterVerdict::Artefact {
                // corrected before the rest power reads it
                assert!(rest.found.is_empty(), "{:?}", rest.found);
                assert!(rest.rmse_before_w < 0.5, "{rest:?}");
            } else {
                assert!(
                    d.summary
                        .contains("Located: the main-board meter's rest reading")
                );
            }
        }
    }
}
