//! Rigid-body dynamics of the 7-joint arm with the root (pelvis) fixed upright.
//!
//! Each arm joint moves one rigid body: its child link plus every link hanging from it through
//! non-arm joints held at 0 (e.g. the Dex3-1 palm and fingers on the wrist yaw link), merged with
//! the parallel-axis theorem. Everything upstream of the first arm joint (pelvis, waist at 0, torso)
//! is fixed and does not enter the arm's torques. Gravity is 9.81 m/s² along −Z of the root.
//!
//! All per-call work is on fixed-size stack arrays (no heap allocation), so inverse dynamics can
//! be called millions of times per simulated session.

use anyhow::{anyhow, bail};
use nalgebra::{Isometry3, Matrix3, SMatrix, SVector, Vector3};

use super::kinematics::ArmJoints;
use super::model::{Inertial, JointKind, RobotModel};
use crate::N_JOINTS;

/// Standard gravity used throughout [m/s²].
pub const GRAVITY: f64 = 9.81;

/// A point mass carried at the hand.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Payload {
    /// Mass [kg].
    pub mass_kg: f64,
    /// Position in the frame of the last arm joint's child link (G1: `left_wrist_yaw_link`) [m].
    pub com_m: [f64; 3],
}

/// Joint friction inside the measured joint torque: τ_f = Fc·tanh(q̇/0.01) + Fv·q̇.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct JointFriction {
    /// Coulomb friction per joint [Nm].
    pub coulomb_nm: [f64; N_JOINTS],
    /// Viscous friction per joint [Nm·s/rad].
    pub viscous_nms: [f64; N_JOINTS],
}

impl JointFriction {
    /// Velocity scale of the tanh smoothing of the Coulomb term [rad/s].
    pub const TANH_SCALE_RAD_S: f64 = 0.01;

    /// Friction torque per joint at velocities `dq`.
    pub fn torque(&self, dq: &[f64; N_JOINTS]) -> [f64; N_JOINTS] {
        std::array::from_fn(|i| {
            self.coulomb_nm[i] * (dq[i] / Self::TANH_SCALE_RAD_S).tanh()
                + self.viscous_nms[i] * dq[i]
        })
    }
}

/// One moving body of the arm chain, in the frame of its joint's child link.
#[derive(Debug, Clone, Copy)]
struct Body {
    /// Orientation of the joint frame (at q = 0) in the previous body's frame.
    rot0: Matrix3<f64>,
    /// Orientation at q as rot_const + sin q · rot_sin + cos q · rot_cos (Rodrigues' formula
    /// premultiplied by rot0), so a call costs no matrix product.
    rot_const: Matrix3<f64>,
    rot_sin: Matrix3<f64>,
    rot_cos: Matrix3<f64>,
    /// Position of the joint frame origin (at q = 0) in the previous body's frame.
    pos0: Vector3<f64>,
    /// Unit joint axis in this body's frame.
    axis: Vector3<f64>,
    prismatic: bool,
    mass: f64,
    /// Centre of mass in this body's frame.
    com: Vector3<f64>,
    /// Rotational inertia about the centre of mass, in this body's frame.
    inertia: Matrix3<f64>,
}

impl Body {
    /// Orientation and origin of this body's frame in the previous body's frame at joint position q.
    #[inline]
    fn placement(&self, q: f64) -> (Matrix3<f64>, Vector3<f64>) {
        if self.prismatic {
            (self.rot0, self.pos0 + self.rot0 * (self.axis * q))
        } else {
            let (s, c) = q.sin_cos();
            (
                self.rot_const + self.rot_sin * s + self.rot_cos * c,
                self.pos0,
            )
        }
    }
}

/// Per-body kinematics of one forward pass, each in its own body frame.
#[derive(Clone, Copy)]
struct Pass {
    /// Orientation of body k in body k−1 (root for k = 0).
    rot: [Matrix3<f64>; N_JOINTS],
    /// Origin of body k in body k−1.
    pos: [Vector3<f64>; N_JOINTS],
    omega: [Vector3<f64>; N_JOINTS],
    omega_dot: [Vector3<f64>; N_JOINTS],
    /// Linear acceleration of the frame origin, gravity included as an upward base acceleration.
    accel: [Vector3<f64>; N_JOINTS],
}

/// Dynamics of the arm chain of a [`RobotModel`].
#[derive(Debug, Clone)]
pub struct ArmDynamics {
    bodies: [Body; N_JOINTS],
}

impl ArmDynamics {
    /// Builds the arm chain: the 7 joints must form a serial chain from the root in the given
    /// order (joint k's parent link hangs from joint k−1's child through non-arm joints only).
    pub fn new(model: &RobotModel, arm: &ArmJoints) -> anyhow::Result<ArmDynamics> {
        let joints = model.joints();
        let links = model.links();
        let arm_slot = |ji: usize| arm.joints.iter().position(|&a| a == ji);
        // Nearest arm joint above a link (None: the link is fixed to the root).
        let owner = |mut link: usize| -> Option<usize> {
            while let Some(ji) = links[link].parent_joint {
                if let Some(k) = arm_slot(ji) {
                    return Some(k);
                }
                link = joints[ji].parent_link;
            }
            None
        };
        let zero_pose = model.link_poses(arm, &[0.0; N_JOINTS]);

        let mut bodies = [Body {
            rot0: Matrix3::identity(),
            rot_const: Matrix3::identity(),
            rot_sin: Matrix3::zeros(),
            rot_cos: Matrix3::zeros(),
            pos0: Vector3::zeros(),
            axis: Vector3::z(),
            prismatic: false,
            mass: 0.0,
            com: Vector3::zeros(),
            inertia: Matrix3::zeros(),
        }; N_JOINTS];
        for (k, &ji) in arm.joints.iter().enumerate() {
            let joint = &joints[ji];
            let expected = k.checked_sub(1);
            if owner(joint.parent_link) != expected {
                bail!(
                    "arm joints do not form a serial chain in the given order: '{}' does not hang from {}",
                    joint.name,
                    expected.map_or("the root".to_string(), |e| format!(
                        "'{}'",
                        joints[arm.joints[e]].name
                    ))
                );
            }
            let prev_frame = expected.map_or(Isometry3::identity(), |e| {
                zero_pose[joints[arm.joints[e]].child_link]
            });
            let joint_frame = prev_frame.inverse() * zero_pose[joint.parent_link] * joint.origin;
            let rot0 = *joint_frame.rotation.to_rotation_matrix().matrix();
            // Rodrigues: Rot(a, q) = 1 + sin q·[a]× + (1 − cos q)·[a]×².
            let skew = joint.axis.cross_matrix();
            bodies[k].rot0 = rot0;
            bodies[k].rot_const = rot0 * (Matrix3::identity() + skew * skew);
            bodies[k].rot_sin = rot0 * skew;
            bodies[k].rot_cos = -(rot0 * skew * skew);
            bodies[k].pos0 = joint_frame.translation.vector;
            bodies[k].axis = joint.axis.into_inner();
            bodies[k].prismatic = joint.kind == JointKind::Prismatic;
        }
        for (l, link) in links.iter().enumerate() {
            let Some(k) = owner(l) else { continue };
            if link.inertial.mass == 0.0 {
                continue;
            }
            let body_frame = zero_pose[joints[arm.joints[k]].child_link];
            let in_body = body_frame.inverse() * zero_pose[l];
            let rot = in_body.rotation.to_rotation_matrix();
            let part = Inertial {
                mass: link.inertial.mass,
                com: (in_body * nalgebra::Point3::from(link.inertial.com)).coords,
                inertia: rot.matrix() * link.inertial.inertia * rot.matrix().transpose(),
            };
            merge(&mut bodies[k], &part);
        }
        if bodies.iter().all(|b| b.mass == 0.0) {
            return Err(anyhow!(
                "the arm of robot '{}' has no mass (no <inertial> downstream of its joints)",
                model.name()
            ));
        }
        Ok(ArmDynamics { bodies })
    }

    /// Mass [kg] and centre of mass (in the body's own frame) of each arm joint's rigid body.
    pub fn body_masses(&self) -> [(f64, [f64; 3]); N_JOINTS] {
        self.bodies.map(|b| (b.mass, [b.com.x, b.com.y, b.com.z]))
    }

    /// A copy with a point mass added to the last body.
    pub fn with_payload(&self, p: &Payload) -> ArmDynamics {
        let mut out = self.clone();
        let part = Inertial {
            mass: p.mass_kg,
            com: Vector3::from(p.com_m),
            inertia: Matrix3::zeros(),
        };
        merge(&mut out.bodies[N_JOINTS - 1], &part);
        out
    }

    fn forward(
        &self,
        q: &[f64; N_JOINTS],
        dq: &[f64; N_JOINTS],
        ddq: &[f64; N_JOINTS],
        g: f64,
    ) -> Pass {
        let mut pass = Pass {
            rot: [Matrix3::identity(); N_JOINTS],
            pos: [Vector3::zeros(); N_JOINTS],
            omega: [Vector3::zeros(); N_JOINTS],
            omega_dot: [Vector3::zeros(); N_JOINTS],
            accel: [Vector3::zeros(); N_JOINTS],
        };
        let (mut w, mut wd, mut a) = (
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::new(0.0, 0.0, g),
        );
        for (k, b) in self.bodies.iter().enumerate() {
            let (rot, pos) = b.placement(q[k]);
            let rt = rot.transpose();
            let w_in = rt * w;
            let a_in = rt * (a + wd.cross(&pos) + w.cross(&w.cross(&pos)));
            let wd_in = rt * wd;
            if b.prismatic {
                w = w_in;
                wd = wd_in;
                a = a_in + 2.0 * w.cross(&(b.axis * dq[k])) + b.axis * ddq[k];
            } else {
                w = w_in + b.axis * dq[k];
                wd = wd_in + w_in.cross(&(b.axis * dq[k])) + b.axis * ddq[k];
                a = a_in;
            }
            pass.rot[k] = rot;
            pass.pos[k] = pos;
            pass.omega[k] = w;
            pass.omega_dot[k] = wd;
            pass.accel[k] = a;
        }
        pass
    }

    /// Backward pass from a tip wrench (force, moment about the last body's origin, last body frame)
    /// plus the bodies' own inertial wrenches when `with_bodies`.
    fn backward(
        &self,
        pass: &Pass,
        tip: (Vector3<f64>, Vector3<f64>),
        with_bodies: bool,
    ) -> [f64; N_JOINTS] {
        let mut tau = [0.0; N_JOINTS];
        let (mut f, mut n) = tip;
        for k in (0..N_JOINTS).rev() {
            let b = &self.bodies[k];
            if with_bodies {
                let (w, wd) = (pass.omega[k], pass.omega_dot[k]);
                let acc_com = pass.accel[k] + wd.cross(&b.com) + w.cross(&w.cross(&b.com));
                let force = acc_com * b.mass;
                n += b.inertia * wd + w.cross(&(b.inertia * w)) + b.com.cross(&force);
                f += force;
            }
            tau[k] = if b.prismatic {
                b.axis.dot(&f)
            } else {
                b.axis.dot(&n)
            };
            // Express in the previous body's frame, moment about its origin.
            let f_prev = pass.rot[k] * f;
            n = pass.rot[k] * n + pass.pos[k].cross(&f_prev);
            f = f_prev;
        }
        tau
    }

    fn rnea(
        &self,
        q: &[f64; N_JOINTS],
        dq: &[f64; N_JOINTS],
        ddq: &[f64; N_JOINTS],
        g: f64,
    ) -> [f64; N_JOINTS] {
        let pass = self.forward(q, dq, ddq, g);
        self.backward(&pass, (Vector3::zeros(), Vector3::zeros()), true)
    }

    /// Joint torques [Nm] (force [N] for prismatic joints) that produce accelerations `ddq` at
    /// state (`q`, `dq`) under gravity (recursive Newton–Euler). Friction is not included.
    pub fn inverse_dynamics(
        &self,
        q: &[f64; N_JOINTS],
        dq: &[f64; N_JOINTS],
        ddq: &[f64; N_JOINTS],
    ) -> [f64; N_JOINTS] {
        self.rnea(q, dq, ddq, GRAVITY)
    }

    /// Torques that hold the arm still at `q` against gravity.
    pub fn gravity_torque(&self, q: &[f64; N_JOINTS]) -> [f64; N_JOINTS] {
        self.rnea(q, &[0.0; N_JOINTS], &[0.0; N_JOINTS], GRAVITY)
    }

    /// Joint-space mass matrix M(q) (columns by Newton–Euler with unit accelerations, no gravity).
    pub fn mass_matrix(&self, q: &[f64; N_JOINTS]) -> SMatrix<f64, N_JOINTS, N_JOINTS> {
        let mut m = SMatrix::<f64, N_JOINTS, N_JOINTS>::zeros();
        for j in 0..N_JOINTS {
            let mut e = [0.0; N_JOINTS];
            e[j] = 1.0;
            let col = self.rnea(q, &[0.0; N_JOINTS], &e, 0.0);
            m.set_column(j, &SVector::from(col));
        }
        m
    }

    /// Joint accelerations under torques `tau`: M(q)⁻¹ (τ − C(q, q̇)q̇ − g(q)).
    pub fn forward_dynamics(
        &self,
        q: &[f64; N_JOINTS],
        dq: &[f64; N_JOINTS],
        tau: &[f64; N_JOINTS],
    ) -> [f64; N_JOINTS] {
        let bias = self.rnea(q, dq, &[0.0; N_JOINTS], GRAVITY);
        let rhs = SVector::<f64, N_JOINTS>::from_fn(|i, _| tau[i] - bias[i]);
        let m = self.mass_matrix(q);
        let ddq = match m.cholesky() {
            Some(ch) => ch.solve(&rhs),
            // Only a massless body makes M singular; LU then gives the least-bad answer.
            None => m.lu().solve(&rhs).unwrap_or_else(SVector::zeros),
        };
        ddq.into()
    }

    /// Gravitational potential energy [J] of the arm bodies, zero at the root's z = 0.
    pub fn potential_energy(&self, q: &[f64; N_JOINTS]) -> f64 {
        let (mut rot, mut pos) = (Matrix3::identity(), Vector3::zeros());
        let mut energy = 0.0;
        for (k, b) in self.bodies.iter().enumerate() {
            let (r, p) = b.placement(q[k]);
            pos += rot * p;
            rot *= r;
            energy += b.mass * GRAVITY * (pos + rot * b.com).z;
        }
        energy
    }

    /// Kinetic energy [J] of the arm bodies.
    pub fn kinetic_energy(&self, q: &[f64; N_JOINTS], dq: &[f64; N_JOINTS]) -> f64 {
        let (mut w, mut v) = (Vector3::zeros(), Vector3::zeros());
        let mut energy = 0.0;
        for (k, b) in self.bodies.iter().enumerate() {
            let (rot, pos) = b.placement(q[k]);
            let rt = rot.transpose();
            v = rt * (v + w.cross(&pos));
            w = rt * w;
            if b.prismatic {
                v += b.axis * dq[k];
            } else {
                w += b.axis * dq[k];
            }
            let v_com = v + w.cross(&b.com);
            energy += 0.5 * b.mass * v_com.norm_squared() + 0.5 * w.dot(&(b.inertia * w));
        }
        energy
    }

    /// Payload regressor Y (7×4): the torque a point payload adds is Y·[m, m·cx, m·cy, m·cz] with
    /// c in the last body's frame, up to the payload's second moment m(|c|²1 − ccᵀ) about that
    /// frame's origin, which is neglected (quadratic in c, small for a compact payload near the hand).
    pub fn payload_regressor(
        &self,
        q: &[f64; N_JOINTS],
        dq: &[f64; N_JOINTS],
        ddq: &[f64; N_JOINTS],
    ) -> SMatrix<f64, N_JOINTS, 4> {
        let pass = self.forward(q, dq, ddq, GRAVITY);
        let last = N_JOINTS - 1;
        let (w, wd, a) = (pass.omega[last], pass.omega_dot[last], pass.accel[last]);
        let mut y = SMatrix::<f64, N_JOINTS, 4>::zeros();
        // Mass column: force m·a at the origin, no moment.
        y.set_column(
            0,
            &SVector::from(self.backward(&pass, (a, Vector3::zeros()), false)),
        );
        for axis in 0..3 {
            let h = Vector3::ith(axis, 1.0);
            let force = wd.cross(&h) + w.cross(&w.cross(&h));
            let moment = h.cross(&a);
            y.set_column(
                axis + 1,
                &SVector::from(self.backward(&pass, (force, moment), false)),
            );
        }
        y
    }
}

/// Adds a part (mass, com and inertia about its com, in the body frame) to a body, re-centring the
/// inertia on the combined centre of mass (parallel-axis theorem).
fn merge(body: &mut Body, part: &Inertial) {
    let total = body.mass + part.mass;
    if total <= 0.0 {
        return;
    }
    let com = (body.com * body.mass + part.com * part.mass) / total;
    let shift =
        |m: f64, d: Vector3<f64>| (Matrix3::identity() * d.norm_squared() - d * d.transpose()) * m;
    body.inertia = body.inertia
        + shift(body.mass, body.com - com)
        + part.inertia
        + shift(part.mass, part.com - com);
    body.mass = total;
    body.com = com;
}
