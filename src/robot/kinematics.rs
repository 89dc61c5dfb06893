//! Forward kinematics along the URDF tree with the 7 arm joints driven and every other joint at 0.

use anyhow::{anyhow, bail};
use nalgebra::Isometry3;

use super::model::{JointKind, RobotModel};
use crate::N_JOINTS;

/// The 7 arm joints of a model, in model order (shoulder pitch … wrist yaw).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ArmJoints {
    /// Indices into [`RobotModel::joints`].
    pub joints: [usize; N_JOINTS],
}

impl RobotModel {
    /// Maps the 7 arm joint names (model order) to joint indices. Every name must be a movable
    /// (revolute, continuous or prismatic) joint of this model.
    pub fn arm(&self, joint_names: &[String]) -> anyhow::Result<ArmJoints> {
        if joint_names.len() != N_JOINTS {
            bail!(
                "expected {N_JOINTS} arm joint names, got {}",
                joint_names.len()
            );
        }
        let mut joints = [0; N_JOINTS];
        for (slot, name) in joints.iter_mut().zip(joint_names) {
            let j = self.joint_index(name).ok_or_else(|| {
                anyhow!(
                    "arm joint '{name}' is not a joint of robot '{}'",
                    self.name()
                )
            })?;
            if self.joints()[j].kind == JointKind::Fixed {
                bail!(
                    "arm joint '{name}' is a fixed joint in robot '{}'",
                    self.name()
                );
            }
            *slot = j;
        }
        for i in 0..N_JOINTS {
            if joints[..i].contains(&joints[i]) {
                bail!("arm joint '{}' is named twice", joint_names[i]);
            }
        }
        Ok(ArmJoints { joints })
    }

    /// The G1 left arm ([`super::G1_LEFT_ARM_JOINTS`]).
    pub fn g1_left_arm(&self) -> anyhow::Result<ArmJoints> {
        self.arm(&super::G1_LEFT_ARM_JOINTS.map(String::from))
    }

    /// Position limits (lower, upper) of the arm joints; ±π for continuous joints.
    pub fn arm_limits(&self, arm: &ArmJoints) -> [(f64, f64); N_JOINTS] {
        arm.joints.map(|j| {
            self.joints()[j]
                .limits
                .unwrap_or((-std::f64::consts::PI, std::f64::consts::PI))
        })
    }

    /// World pose of every link (same order as [`RobotModel::links`]): root at the identity,
    /// arm joints at `q`, all other joints at 0.
    pub fn link_poses(&self, arm: &ArmJoints, q: &[f64; N_JOINTS]) -> Vec<Isometry3<f64>> {
        let mut poses = vec![Isometry3::identity(); self.links.len()];
        self.link_poses_into(arm, q, &mut poses);
        poses
    }

    /// [`RobotModel::link_poses`] into a caller-owned buffer (resized to the number of links), so
    /// replaying many samples does not allocate per sample.
    pub fn link_poses_into(
        &self,
        arm: &ArmJoints,
        q: &[f64; N_JOINTS],
        poses: &mut Vec<Isometry3<f64>>,
    ) {
        poses.resize(self.links.len(), Isometry3::identity());
        poses[self.root] = Isometry3::identity();
        for &l in &self.topo_order[1..] {
            // Every non-root link has a parent joint (checked when the model was built).
            let Some(ji) = self.links[l].parent_joint else {
                continue;
            };
            let joint = &self.joints[ji];
            let qj = arm
                .joints
                .iter()
                .position(|&a| a == ji)
                .map_or(0.0, |k| q[k]);
            poses[l] = poses[joint.parent_link] * joint.transform(qj);
        }
    }
}
