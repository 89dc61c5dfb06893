//! TEMPORARY stand-in for the ROBOT stage (viz branch only): the contract's types and
//! `link_poses` on a hand-built serial arm, so the replay compiles and is testable before the
//! real URDF-based module lands on main. Delete on merge (take main's version).

use std::path::PathBuf;

use anyhow::bail;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use crate::N_JOINTS;

/// Shape of a visual element.
#[derive(Debug, Clone, PartialEq)]
pub enum Geometry {
    /// A mesh file.
    Mesh {
        /// Resolved path of the mesh file.
        path: PathBuf,
        /// Per-axis scale.
        scale: [f64; 3],
    },
    /// Box centred on the visual origin.
    Box {
        /// Edge lengths [m].
        size: [f64; 3],
    },
    /// Cylinder along z.
    Cylinder {
        /// Radius [m].
        radius: f64,
        /// Length [m].
        length: f64,
    },
    /// Sphere.
    Sphere {
        /// Radius [m].
        radius: f64,
    },
}

/// One visual element of a link.
#[derive(Debug, Clone, PartialEq)]
pub struct Visual {
    /// Pose of the geometry in the link frame.
    pub origin: Isometry3<f64>,
    /// The shape.
    pub geometry: Geometry,
    /// Colour.
    pub rgba: Option<[f32; 4]>,
}

/// A link.
#[derive(Debug, Clone, PartialEq)]
pub struct Link {
    /// URDF link name.
    pub name: String,
    /// Index of the parent joint.
    pub parent_joint: Option<usize>,
    /// Visual elements.
    pub visuals: Vec<Visual>,
}

/// The 7 arm joints of a model.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ArmJoints {
    /// Joint indices.
    pub joints: [usize; N_JOINTS],
}

/// Stand-in robot: root + a serial chain of 7 revolute joints.
#[derive(Debug, Clone)]
pub struct RobotModel {
    links: Vec<Link>,
    joint_names: Vec<String>,
    origins: Vec<Isometry3<f64>>,
    axes: Vec<Vector3<f64>>,
}

impl RobotModel {
    /// A serial 7-joint arm with primitive visuals.
    pub fn builtin() -> RobotModel {
        let names = [
            "left_shoulder_pitch_joint",
            "left_shoulder_roll_joint",
            "left_shoulder_yaw_joint",
            "left_elbow_joint",
            "left_wrist_roll_joint",
            "left_wrist_pitch_joint",
            "left_wrist_yaw_joint",
        ];
        let axes = [Vector3::y(), Vector3::x(), Vector3::z(), Vector3::y(), Vector3::x(), Vector3::y(), Vector3::z()];
        let mut links = vec![Link {
            name: "torso_link".into(),
            parent_joint: None,
            visuals: vec![Visual {
                origin: Isometry3::translation(0.0, 0.0, 0.2),
                geometry: Geometry::Box { size: [0.2, 0.3, 0.4] },
                rgba: Some([0.7, 0.7, 0.7, 1.0]),
            }],
        }];
        let mut origins = Vec::new();
        for (i, name) in names.iter().enumerate() {
            links.push(Link {
                name: name.replace("_joint", "_link"),
                parent_joint: Some(i),
                visuals: vec![Visual {
                    origin: Isometry3::translation(0.0, 0.0, -0.05),
                    geometry: if i % 2 == 0 {
                        Geometry::Cylinder { radius: 0.03, length: 0.1 }
                    } else {
                        Geometry::Sphere { radius: 0.035 }
                    },
                    rgba: None,
                }],
            });
            let offset = if i == 0 { Vector3::new(0.0, 0.2, 0.35) } else { Vector3::new(0.0, 0.0, -0.08) };
            origins.push(Isometry3::from_parts(Translation3::from(offset), UnitQuaternion::identity()));
        }
        RobotModel { links, joint_names: names.map(String::from).to_vec(), origins, axes: axes.to_vec() }
    }

    /// Links.
    pub fn links(&self) -> &[Link] {
        &self.links
    }

    /// Arm joint indices by name.
    pub fn arm(&self, joint_names: &[String]) -> anyhow::Result<ArmJoints> {
        if joint_names.len() != N_JOINTS {
            bail!("expected {N_JOINTS} arm joint names");
        }
        let mut joints = [0; N_JOINTS];
        for (slot, name) in joints.iter_mut().zip(joint_names) {
            match self.joint_names.iter().position(|n| n == name) {
                Some(j) => *slot = j,
                None => bail!("unknown joint {name}"),
            }
        }
        Ok(ArmJoints { joints })
    }

    /// World pose of every link.
    pub fn link_poses(&self, arm: &ArmJoints, q: &[f64; N_JOINTS]) -> Vec<Isometry3<f64>> {
        let mut poses = vec![Isometry3::identity()];
        for j in 0..N_JOINTS {
            let qj = arm.joints.iter().position(|&a| a == j).map_or(0.0, |k| q[k]);
            let rot = UnitQuaternion::from_scaled_axis(self.axes[j] * qj);
            let parent = poses[j];
            poses.push(parent * self.origins[j] * rot);
        }
        poses
    }
}
