//! Robot model: URDF loading, forward kinematics and rigid-body dynamics of the G1 arm.
//!
//! - [`RobotModel`] loads any URDF (the shipped `urdf/g1_left_arm.urdf` via
//!   [`RobotModel::builtin`], or Unitree's official description with STL meshes) into a kinematic
//!   tree; [`RobotModel::link_poses`] gives every link's world pose for 7 arm joint angles.
//! - [`ArmDynamics`] is the arm with the pelvis fixed upright and all non-arm joints at 0:
//!   inverse dynamics (RNEA, allocation-free), gravity torque, mass matrix, forward dynamics,
//!   energies, a point payload at the hand and its linear regressor; [`JointFriction`] is the
//!   joint friction that the measured `tau_est` contains.
//!
//! ```
//! use g1viz::robot::{ArmDynamics, RobotModel};
//!
//! let model = RobotModel::builtin();
//! let arm = model.g1_left_arm()?;
//! let q = [0.3, 0.2, 0.0, 0.8, 0.0, 0.0, 0.0];
//!
//! // Where is the palm?
//! let poses = model.link_poses(&arm, &q);
//! let palm = model.link_index("left_hand_palm_link").unwrap();
//! println!("palm at {}", poses[palm].translation.vector);
//!
//! // Torque to hold the arm still there, and to accelerate the elbow at 1 rad/s².
//! let dynamics = ArmDynamics::new(&model, &arm)?;
//! let hold = dynamics.gravity_torque(&q);
//! let tau = dynamics.inverse_dynamics(&q, &[0.0; 7], &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]);
//! assert!(tau[3] > hold[3]);
//! # Ok::<(), anyhow::Error>(())
//! ```

mod dynamics;
mod kinematics;
mod model;

pub use dynamics::{ArmDynamics, GRAVITY, JointFriction, Payload};
pub use kinematics::ArmJoints;
pub use model::{
    BUILTIN_URDF, BUILTIN_URDF_NO_HAND, G1_LEFT_ARM_JOINTS, Geometry, Inertial, Joint, JointKind,
    Link, RobotModel, Visual, resolve_mesh_path,
};
