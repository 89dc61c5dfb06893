//! Robot stage: URDF loading, forward kinematics against Unitree's official URDF and hand-computed
//! values, and rigid-body dynamics checked against independent relations (energy, finite
//! differences) and against the shared recordings' generator (pinocchio on the official URDF).

mod common;

use std::path::PathBuf;

use g1viz::robot::{ArmDynamics, ArmJoints, Geometry, JointFriction, Payload, RobotModel};
use nalgebra::{Isometry3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const N: usize = 7;

fn shared_dir() -> Option<PathBuf> {
    common::shared_dir()
}

fn official_model() -> Option<RobotModel> {
    let path = shared_dir()?.join("g1_description/g1_29dof_with_hand_rev_1_0.urdf");
    Some(RobotModel::from_urdf_file(&path).expect("official URDF loads"))
}

fn random_q(rng: &mut ChaCha8Rng, model: &RobotModel, arm: &ArmJoints) -> [f64; N] {
    let limits = model.arm_limits(arm);
    std::array::from_fn(|i| rng.random_range(limits[i].0..=limits[i].1))
}

fn random_vec(rng: &mut ChaCha8Rng, scale: f64) -> [f64; N] {
    std::array::from_fn(|_| rng.random_range(-scale..=scale))
}

fn pose_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let d = a.inverse() * b;
    (d.translation.vector.norm(), d.rotation.angle())
}

fn builtin_arm() -> (RobotModel, ArmJoints, ArmDynamics) {
    let model = RobotModel::builtin();
    let arm = model.g1_left_arm().unwrap();
    let dynamics = ArmDynamics::new(&model, &arm).unwrap();
    (model, arm, dynamics)
}

#[test]
fn builtin_urdfs_load_with_primitive_visuals() {
    for model in [RobotModel::builtin(), RobotModel::builtin_no_hand()] {
        let root = model.root();
        assert_eq!(model.links()[root].name, "pelvis");
        assert!(model.links()[root].parent_joint.is_none());
        model.g1_left_arm().unwrap();
        for link in model.links() {
            assert!(!link.visuals.is_empty(), "{} has a visual", link.name);
            assert!(
                link.visuals
                    .iter()
                    .all(|v| !matches!(v.geometry, Geometry::Mesh { .. }))
            );
            assert!(
                link.visuals.iter().all(|v| v.rgba.is_some()),
                "{} colour from material",
                link.name
            );
        }
    }
    // pelvis, waist yaw/roll, torso, 7 arm links (+ palm and 7 finger links).
    assert_eq!(RobotModel::builtin_no_hand().links().len(), 11);
    assert_eq!(RobotModel::builtin().links().len(), 19);
}

#[test]
fn fk_at_home_matches_hand_computed_shoulder_and_elbow() {
    let model = RobotModel::builtin();
    let arm = model.g1_left_arm().unwrap();
    let poses = model.link_poses(&arm, &[0.0; N]);
    // Shoulder pitch origin = waist roll offset (-0.0039635, 0, 0.044) + shoulder offset
    // (0.0039563, 0.10022, 0.24778) from the URDF text, waist at 0.
    let shoulder = poses[model.link_index("left_shoulder_pitch_link").unwrap()]
        .translation
        .vector;
    assert!(
        (shoulder - Vector3::new(-0.0000072, 0.10022, 0.29178)).norm() < 1e-12,
        "{shoulder}"
    );
    // With every arm joint at 0 the shoulder-pitch link is rolled by rpy (0.27931, 5.4949e-5,
    // -1.9159e-4) and the shoulder-roll joint un-rolls by -0.27925: the roll link is almost level,
    // so the elbow joint sits ~(0.0158, 0.038+0.00624, -(0.013831+0.1032+0.080518)) below, up to
    // the 6e-5 rad residual roll. Checked to 0.2 mm.
    let elbow = poses[model.link_index("left_elbow_link").unwrap()]
        .translation
        .vector;
    let expected_offset_in_roll_link = Vector3::new(0.015783, 0.00624, -0.1032 - 0.080518);
    let roll_link_origin = shoulder
        + nalgebra::Rotation3::from_euler_angles(0.27931, 0.0, 0.0)
            * Vector3::new(0.0, 0.038, -0.013831);
    assert!(
        (elbow - (roll_link_origin + expected_offset_in_roll_link)).norm() < 2e-4,
        "{elbow}"
    );

    // Shoulder pitch by +pi/2 about y swings the upper arm forward/up: elbow z rises to about the
    // shoulder height and x becomes positive.
    let mut q = [0.0; N];
    q[0] = -std::f64::consts::FRAC_PI_2;
    let lifted = model.link_poses(&arm, &q)[model.link_index("left_elbow_link").unwrap()]
        .translation
        .vector;
    assert!(
        lifted.x > 0.15 && (lifted.z - shoulder.z).abs() < 0.05,
        "{lifted}"
    );
}

#[test]
fn fk_shipped_urdf_matches_official_for_random_joint_vectors() {
    let Some(official) = official_model() else {
        return;
    };
    let ours = RobotModel::builtin();
    let (arm_o, arm_s) = (official.g1_left_arm().unwrap(), ours.g1_left_arm().unwrap());
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut worst = (0.0f64, 0.0f64);
    for _ in 0..100 {
        let q = random_q(&mut rng, &ours, &arm_s);
        let (po, ps) = (official.link_poses(&arm_o, &q), ours.link_poses(&arm_s, &q));
        for name in ["left_wrist_yaw_link", "left_hand_palm_link"] {
            let e = pose_error(
                &po[official.link_index(name).unwrap()],
                &ps[ours.link_index(name).unwrap()],
            );
            worst = (worst.0.max(e.0), worst.1.max(e.1));
        }
    }
    eprintln!(
        "FK shipped vs official: max {:.3e} m, {:.3e} rad",
        worst.0, worst.1
    );
    assert!(worst.0 < 1e-6 && worst.1 < 1e-6, "{worst:?}");
}

#[test]
fn official_urdf_meshes_resolve_to_existing_files() {
    let Some(model) = official_model() else {
        return;
    };
    let mut meshes = 0;
    for link in model.links() {
        for v in &link.visuals {
            if let Geometry::Mesh { path, .. } = &v.geometry {
                assert!(
                    path.is_file(),
                    "{} resolved to {}",
                    link.name,
                    path.display()
                );
                meshes += 1;
            }
        }
    }
    assert!(meshes > 40, "{meshes} meshes");
}

#[test]
fn package_and_missing_mesh_paths_resolve_against_the_urdf_folder() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("urdf")).unwrap();
    std::fs::create_dir_all(dir.path().join("meshes")).unwrap();
    std::fs::write(dir.path().join("meshes/a.STL"), b"").unwrap();
    let urdf = r#"<robot name="r">
        <link name="base"><visual><geometry><mesh filename="package://g1_description/meshes/a.STL"/></geometry></visual></link>
        <link name="tip"><visual><geometry><mesh filename="../meshes/missing.STL" scale="2 2 2"/></geometry></visual></link>
        <joint name="j" type="continuous"><parent link="base"/><child link="tip"/><axis xyz="0 0 1"/></joint>
    </robot>"#;
    let path = dir.path().join("urdf/r.urdf");
    std::fs::write(&path, urdf).unwrap();
    let model = RobotModel::from_urdf_file(&path).unwrap();
    let Geometry::Mesh { path: found, .. } = &model.links()[0].visuals[0].geometry else {
        panic!()
    };
    assert_eq!(
        found.canonicalize().unwrap(),
        dir.path().join("meshes/a.STL").canonicalize().unwrap()
    );
    let Geometry::Mesh {
        path: missing,
        scale,
    } = &model.links()[1].visuals[0].geometry
    else {
        panic!()
    };
    assert_eq!(
        missing,
        &dir.path().join("urdf").join("../meshes/missing.STL")
    );
    assert_eq!(scale, &[2.0; 3]);
}

#[test]
fn bad_urdfs_give_errors_naming_file_and_problem() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "garbage.urdf",
            "<robot name=\"r\"><link name=\"a\"></robot",
            "invalid URDF",
        ),
        (
            "dangling.urdf",
            r#"<robot name="r"><link name="a"/><joint name="j" type="fixed"><parent link="a"/><child link="b"/></joint></robot>"#,
            "child link 'b' does not exist",
        ),
        (
            "two_roots.urdf",
            r#"<robot name="r"><link name="a"/><link name="b"/></robot>"#,
            "one tree",
        ),
        (
            "cycle.urdf",
            r#"<robot name="r"><link name="a"/><link name="b"/>
               <joint name="j1" type="fixed"><parent link="a"/><child link="b"/></joint>
               <joint name="j2" type="fixed"><parent link="b"/><child link="a"/></joint></robot>"#,
            "cycle",
        ),
        (
            "zero_axis.urdf",
            r#"<robot name="r"><link name="a"/><link name="b"/>
               <joint name="j" type="continuous"><parent link="a"/><child link="b"/><axis xyz="0 0 0"/></joint></robot>"#,
            "zero length",
        ),
    ];
    for (file, text, problem) in cases {
        let path = dir.path().join(file);
        std::fs::write(&path, text).unwrap();
        let err = format!("{:#}", RobotModel::from_urdf_file(&path).unwrap_err());
        assert!(err.contains(file) && err.contains(problem), "{file}: {err}");
    }
    let err = format!(
        "{:#}",
        RobotModel::from_urdf_file(&dir.path().join("nope.urdf")).unwrap_err()
    );
    assert!(err.contains("nope.urdf"), "{err}");

    let model = RobotModel::builtin();
    let mut names = g1viz::robot::G1_LEFT_ARM_JOINTS.map(String::from).to_vec();
    names[3] = "left_elbow".into();
    assert!(format!("{:#}", model.arm(&names).unwrap_err()).contains("left_elbow"));
    // Out of chain order: the dynamics needs a serial chain.
    names = g1viz::robot::G1_LEFT_ARM_JOINTS.map(String::from).to_vec();
    names.swap(1, 2);
    let arm = model.arm(&names).unwrap();
    assert!(format!("{:#}", ArmDynamics::new(&model, &arm).unwrap_err()).contains("serial chain"));
}

#[test]
fn gravity_torque_is_the_gradient_of_potential_energy() {
    let (model, arm, dynamics) = builtin_arm();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let h = 1e-6;
    for _ in 0..20 {
        let q = random_q(&mut rng, &model, &arm);
        let g = dynamics.gravity_torque(&q);
        for i in 0..N {
            let (mut qp, mut qm) = (q, q);
            qp[i] += h;
            qm[i] -= h;
            let grad =
                (dynamics.potential_energy(&qp) - dynamics.potential_energy(&qm)) / (2.0 * h);
            assert!(
                (grad - g[i]).abs() < 1e-6,
                "joint {i}: dV/dq {grad} vs g {}",
                g[i]
            );
        }
    }
}

#[test]
fn mass_matrix_is_symmetric_positive_definite_and_gives_kinetic_energy() {
    let (model, arm, dynamics) = builtin_arm();
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    for _ in 0..20 {
        let q = random_q(&mut rng, &model, &arm);
        let m = dynamics.mass_matrix(&q);
        assert!((m - m.transpose()).abs().max() < 1e-12 * m.abs().max());
        let eig = m.symmetric_eigen().eigenvalues;
        assert!(eig.min() > 0.0, "{eig}");
        // KE from body velocities (independent code path) = ½ q̇ᵀ M q̇.
        let dq = random_vec(&mut rng, 2.0);
        let v = nalgebra::SVector::<f64, N>::from(dq);
        let ke = 0.5 * (v.transpose() * m * v)[0];
        assert!((ke - dynamics.kinetic_energy(&q, &dq)).abs() < 1e-10 * (1.0 + ke));
    }
}

#[test]
fn forward_dynamics_inverts_inverse_dynamics() {
    let (model, arm, dynamics) = builtin_arm();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for _ in 0..50 {
        let q = random_q(&mut rng, &model, &arm);
        let (dq, ddq) = (random_vec(&mut rng, 2.5), random_vec(&mut rng, 10.0));
        let tau = dynamics.inverse_dynamics(&q, &dq, &ddq);
        let back = dynamics.forward_dynamics(&q, &dq, &tau);
        for i in 0..N {
            assert!(
                (back[i] - ddq[i]).abs() < 1e-6,
                "joint {i}: {} vs {}",
                back[i],
                ddq[i]
            );
        }
    }
}

/// Simulates under a known torque with RK4 and checks work of τ = ΔKE + ΔPE: the torques from
/// Newton–Euler and the energies from positions/velocities are independent code paths.
#[test]
fn energy_balance_of_a_torqued_motion() {
    let (_, _, dynamics) = builtin_arm();
    let tau_at = |t: f64, q: &[f64; N]| -> [f64; N] {
        let g = dynamics.gravity_torque(q);
        std::array::from_fn(|i| 0.8 * g[i] + 0.5 * (3.0 * t + i as f64).sin())
    };
    let deriv =
        |t: f64, q: &[f64; N], dq: &[f64; N]| dynamics.forward_dynamics(q, dq, &tau_at(t, q));
    let (mut q, mut dq) = ([0.2, 0.3, -0.2, 0.6, 0.1, -0.2, 0.1], [0.0; N]);
    let e0 = dynamics.kinetic_energy(&q, &dq) + dynamics.potential_energy(&q);
    let (dt, steps) = (2e-4, 2500);
    let mut work = 0.0;
    let power = |t: f64, q: &[f64; N], dq: &[f64; N]| {
        let tau = tau_at(t, q);
        (0..N).map(|i| tau[i] * dq[i]).sum::<f64>()
    };
    let add = |a: &[f64; N], b: &[f64; N], s: f64| -> [f64; N] {
        std::array::from_fn(|i| a[i] + s * b[i])
    };
    for k in 0..steps {
        let t = k as f64 * dt;
        // RK4 on (q, dq, work).
        let (k1q, k1v, k1w) = (dq, deriv(t, &q, &dq), power(t, &q, &dq));
        let (q2, v2) = (add(&q, &k1q, dt / 2.0), add(&dq, &k1v, dt / 2.0));
        let (k2q, k2v, k2w) = (
            v2,
            deriv(t + dt / 2.0, &q2, &v2),
            power(t + dt / 2.0, &q2, &v2),
        );
        let (q3, v3) = (add(&q, &k2q, dt / 2.0), add(&dq, &k2v, dt / 2.0));
        let (k3q, k3v, k3w) = (
            v3,
            deriv(t + dt / 2.0, &q3, &v3),
            power(t + dt / 2.0, &q3, &v3),
        );
        let (q4, v4) = (add(&q, &k3q, dt), add(&dq, &k3v, dt));
        let (k4q, k4v, k4w) = (v4, deriv(t + dt, &q4, &v4), power(t + dt, &q4, &v4));
        q = std::array::from_fn(|i| {
            q[i] + dt / 6.0 * (k1q[i] + 2.0 * k2q[i] + 2.0 * k3q[i] + k4q[i])
        });
        dq = std::array::from_fn(|i| {
            dq[i] + dt / 6.0 * (k1v[i] + 2.0 * k2v[i] + 2.0 * k3v[i] + k4v[i])
        });
        work += dt / 6.0 * (k1w + 2.0 * k2w + 2.0 * k3w + k4w);
    }
    let e1 = dynamics.kinetic_energy(&q, &dq) + dynamics.potential_energy(&q);
    let ke = dynamics.kinetic_energy(&q, &dq);
    eprintln!(
        "energy balance: work {work:.6} J, dE {:.6} J, KE at end {ke:.4} J",
        e1 - e0
    );
    assert!(ke > 0.05, "the arm moved ({ke} J)");
    assert!(
        (work - (e1 - e0)).abs() < 1e-6 * (1.0 + work.abs()),
        "work {work} vs dE {}",
        e1 - e0
    );
}

#[test]
fn payload_regressor_matches_finite_differences_of_with_payload() {
    let (model, arm, dynamics) = builtin_arm();
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let m = 0.7;
    for _ in 0..10 {
        let q = random_q(&mut rng, &model, &arm);
        let (dq, ddq) = (random_vec(&mut rng, 2.0), random_vec(&mut rng, 8.0));
        let y = dynamics.payload_regressor(&q, &dq, &ddq);
        let base = dynamics.inverse_dynamics(&q, &dq, &ddq);
        let at = |c: [f64; 3]| {
            dynamics
                .with_payload(&Payload {
                    mass_kg: m,
                    com_m: c,
                })
                .inverse_dynamics(&q, &dq, &ddq)
        };
        // Mass column: payload at the frame origin (exactly linear in m).
        let tm = at([0.0; 3]);
        for i in 0..N {
            assert!(((tm[i] - base[i]) / m - y[(i, 0)]).abs() < 1e-9);
        }
        // First-moment columns: central differences in c cancel the (neglected) second moment.
        let h = 1e-4;
        for axis in 0..3 {
            let (mut cp, mut cm) = ([0.0; 3], [0.0; 3]);
            cp[axis] = h;
            cm[axis] = -h;
            let (tp, tn) = (at(cp), at(cm));
            for i in 0..N {
                let fd = (tp[i] - tn[i]) / (2.0 * h * m);
                assert!(
                    (fd - y[(i, axis + 1)]).abs() < 1e-6 * (1.0 + fd.abs()),
                    "joint {i} axis {axis}: {fd} vs {}",
                    y[(i, axis + 1)]
                );
            }
        }
    }
}

#[test]
fn hand_adds_the_dex3_mass_to_the_last_body() {
    let with = ArmDynamics::new(
        &RobotModel::builtin(),
        &RobotModel::builtin().g1_left_arm().unwrap(),
    )
    .unwrap();
    let model = RobotModel::builtin_no_hand();
    let without = ArmDynamics::new(&model, &model.g1_left_arm().unwrap()).unwrap();
    // Palm + thumb 0/1/2 + middle 0/1 + index 0/1 masses, from the URDF text.
    let hand = 0.37283854 + 0.08623657 + 3.0 * 0.05885070 + 3.0 * 0.02030626;
    let (mw, mo) = (with.body_masses(), without.body_masses());
    assert!(
        (mw[6].0 - mo[6].0 - hand).abs() < 1e-9,
        "{} vs {}",
        mw[6].0 - mo[6].0,
        hand
    );
    for k in 0..6 {
        assert_eq!(mw[k], mo[k]);
    }
    // Held horizontally forward, the hand's weight adds shoulder-pitch torque.
    let q = [-1.2, 0.3, 0.0, 0.3, 0.0, 0.0, 0.0];
    assert!(with.gravity_torque(&q)[0].abs() > without.gravity_torque(&q)[0].abs() + 0.5);
}

#[test]
fn shipped_and_official_urdfs_give_the_same_inverse_dynamics() {
    let Some(official) = official_model() else {
        return;
    };
    let (model, arm, ours) = builtin_arm();
    let theirs = ArmDynamics::new(&official, &official.g1_left_arm().unwrap()).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut worst = 0.0f64;
    for _ in 0..100 {
        let q = random_q(&mut rng, &model, &arm);
        let (dq, ddq) = (random_vec(&mut rng, 2.5), random_vec(&mut rng, 10.0));
        let (a, b) = (
            ours.inverse_dynamics(&q, &dq, &ddq),
            theirs.inverse_dynamics(&q, &dq, &ddq),
        );
        worst = (0..N).map(|i| (a[i] - b[i]).abs()).fold(worst, f64::max);
    }
    eprintln!("inverse dynamics shipped vs official: max |dtau| {worst:.3e} Nm");
    assert!(worst < 1e-9);
}

fn truth_json() -> Option<serde_json::Value> {
    let path = shared_dir()?.join("recordings/g1_smoke.truth.json");
    let Ok(text) = std::fs::read_to_string(&path) else {
        common::skip(&format!("{} not found", path.display()));
        return None;
    };
    Some(serde_json::from_str(&text).unwrap())
}

/// The recordings' generator computed the home holding torques with pinocchio on the official
/// with-hand URDF; ours must agree.
#[test]
fn gravity_torque_at_home_matches_the_recordings_generator() {
    let Some(truth) = truth_json() else { return };
    let expected: Vec<f64> = serde_json::from_value(truth["plant"]["tau_home_Nm"].clone()).unwrap();
    let (_, _, dynamics) = builtin_arm();
    let ours = dynamics.gravity_torque(&[0.0; N]);
    let residual = (0..N)
        .map(|i| (ours[i] - expected[i]).abs())
        .fold(0.0, f64::max);
    eprintln!("tau_home: ours {ours:?}\n  truth {expected:?}\n  max residual {residual:.3e} Nm");
    assert!(residual < 1e-6, "max residual {residual} Nm");
}

#[test]
fn joint_friction_matches_the_truth_json_form() {
    let Some(truth) = truth_json() else { return };
    let f = &truth["plant"]["joint_friction_in_tau"];
    assert_eq!(f["form"], "Fc*tanh(qd/0.01) + Fv*qd");
    let friction = JointFriction {
        coulomb_nm: serde_json::from_value(f["coulomb_Nm"].clone()).unwrap(),
        viscous_nms: serde_json::from_value(f["viscous_Nms"].clone()).unwrap(),
    };
    let tau = friction.torque(&[0.01, -1.0, 0.0, 2.0, 0.0, 0.0, 0.0]);
    // Hand-computed: 0.45·tanh(1) + 0.18·0.01; −(0.4·tanh(100) + 0.15); 0; 0.35 + 0.24.
    assert!((tau[0] - (0.45 * 0.761_594_155_955_764_9 + 0.0018)).abs() < 1e-12);
    assert!((tau[1] + 0.55).abs() < 1e-12);
    assert_eq!(tau[2], 0.0);
    assert!((tau[3] - 0.59).abs() < 1e-12);
}

/// The independent generator's recorded `tau_est` is inverse dynamics of the official with-hand URDF
/// plus joint friction plus 0.05 Nm noise: our dynamics on our shipped URDF must reproduce it.
#[test]
fn inverse_dynamics_reproduces_recorded_torques_of_the_smoke_session() {
    let Some(shared) = shared_dir() else { return };
    let mcap = shared.join("recordings/g1_smoke.mcap");
    let truth: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(shared.join("recordings/g1_smoke.truth.json")).unwrap(),
    )
    .unwrap();
    let fr = &truth["plant"]["joint_friction_in_tau"];
    let arr =
        |v: &serde_json::Value| -> [f64; N] { std::array::from_fn(|i| v[i].as_f64().unwrap()) };
    let friction = JointFriction {
        coulomb_nm: arr(&fr["coulomb_Nm"]),
        viscous_nms: arr(&fr["viscous_Nms"]),
    };
    let rec = g1viz::signals::load_recording(
        &mcap,
        &g1viz::signals::SignalMap::g1_left_arm(),
        &g1viz::read::OpenOptions::default(),
    )
    .unwrap();
    let (_, _, dyns) = builtin_arm();
    let s = &rec.state;
    let n = s.t.len();
    // Centred 7-sample moving average of q and q̇, q̈ as the central difference over ±3 samples.
    let smooth = |x: &[[f64; N]], k: usize| -> [f64; N] {
        let mut m = [0.0; N];
        for row in &x[k - 3..=k + 3] {
            for j in 0..N {
                m[j] += row[j] / 7.0;
            }
        }
        m
    };
    let (mut sq, mut bias) = ([0.0; N], [0.0; N]);
    let mut count = 0.0;
    for k in 6..n - 6 {
        let q = smooth(&s.q, k);
        let dq = smooth(&s.dq, k);
        let (dq_a, dq_b) = (smooth(&s.dq, k + 3), smooth(&s.dq, k - 3));
        let dt = s.t[k + 3] - s.t[k - 3];
        let ddq: [f64; N] = std::array::from_fn(|j| (dq_a[j] - dq_b[j]) / dt);
        let tau = dyns.inverse_dynamics(&q, &dq, &ddq);
        let f = friction.torque(&dq);
        for j in 0..N {
            let r = s.tau[k][j] - tau[j] - f[j];
            sq[j] += r * r;
            bias[j] += r;
        }
        count += 1.0;
    }
    for j in 0..N {
        let rms = (sq[j] / count).sqrt();
        let b = bias[j] / count;
        println!("joint {j}: torque residual RMS {rms:.3} Nm, bias {b:+.4} Nm");
        assert!(
            rms < 0.10,
            "joint {j}: RMS residual {rms} Nm (noise is 0.05 Nm)"
        );
        assert!(b.abs() < 0.01, "joint {j}: bias {b} Nm");
    }
}
