//! URDF → kinematic tree: links with visuals and inertials, joints with origins and axes.
//!
//! Loading goes through urdf-rs for the XML; everything after that (tree building, mesh path
//! resolution, validation) is ours so that a bad file gives an error naming the file and the
//! problem instead of a panic (urdf-rs' own `package://` expansion panics without ROS installed).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow, bail};
use nalgebra::{Isometry3, Matrix3, Translation3, Unit, UnitQuaternion, Vector3};

/// The shipped URDF: pelvis → waist → torso → left arm → Dex3-1 left hand (primitive geometry).
pub const BUILTIN_URDF: &str = include_str!("../../urdf/g1_left_arm.urdf");
/// The shipped URDF without the hand (for with/without-hand dynamics).
pub const BUILTIN_URDF_NO_HAND: &str = include_str!("../../urdf/g1_left_arm_no_hand.urdf");

/// URDF names of the G1 left-arm joints in model order (SDK indices 15..21).
pub const G1_LEFT_ARM_JOINTS: [&str; crate::N_JOINTS] = [
    "left_shoulder_pitch_joint",
    "left_shoulder_roll_joint",
    "left_shoulder_yaw_joint",
    "left_elbow_joint",
    "left_wrist_roll_joint",
    "left_wrist_pitch_joint",
    "left_wrist_yaw_joint",
];

/// Shape of a visual element.
#[derive(Debug, Clone, PartialEq)]
pub enum Geometry {
    /// A mesh file (STL/DAE/OBJ…), path resolved against the URDF's folder; the file may be missing
    /// (the viewer reports it).
    Mesh {
        /// Resolved path of the mesh file.
        path: PathBuf,
        /// Per-axis scale.
        scale: [f64; 3],
    },
    /// Box centred on the visual origin.
    Box {
        /// Edge lengths along x, y, z [m].
        size: [f64; 3],
    },
    /// Cylinder along the visual frame's z axis, centred on its origin.
    Cylinder {
        /// Radius [m].
        radius: f64,
        /// Length [m].
        length: f64,
    },
    /// Sphere centred on the visual origin.
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
    /// Colour (linear 0..1 RGBA) from the visual's material or the robot-level material of that name.
    pub rgba: Option<[f32; 4]>,
}

/// Mass properties of a link.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Inertial {
    /// Mass [kg].
    pub mass: f64,
    /// Centre of mass in the link frame [m].
    pub com: Vector3<f64>,
    /// Rotational inertia about the centre of mass, expressed in the link frame [kg·m²].
    pub inertia: Matrix3<f64>,
}

/// A link of the kinematic tree.
#[derive(Debug, Clone, PartialEq)]
pub struct Link {
    /// URDF link name.
    pub name: String,
    /// Index (into [`RobotModel::joints`]) of the joint whose child this link is; `None` for the root.
    pub parent_joint: Option<usize>,
    /// Visual elements.
    pub visuals: Vec<Visual>,
    /// Mass properties.
    pub inertial: Inertial,
}

/// How a joint moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointKind {
    /// Rigid (also used for URDF floating/planar/spherical joints, which are held at their origin).
    Fixed,
    /// Rotation about the axis, with limits.
    Revolute,
    /// Rotation about the axis, unlimited.
    Continuous,
    /// Translation along the axis.
    Prismatic,
}

/// A joint of the kinematic tree.
#[derive(Debug, Clone, PartialEq)]
pub struct Joint {
    /// URDF joint name.
    pub name: String,
    /// Motion type.
    pub kind: JointKind,
    /// Index of the parent link in [`RobotModel::links`].
    pub parent_link: usize,
    /// Index of the child link in [`RobotModel::links`].
    pub child_link: usize,
    /// Pose of the joint frame (= child link frame at q = 0) in the parent link frame.
    pub origin: Isometry3<f64>,
    /// Unit motion axis in the joint frame.
    pub axis: Unit<Vector3<f64>>,
    /// Position limits (lower, upper) [rad or m] for revolute and prismatic joints.
    pub limits: Option<(f64, f64)>,
}

impl Joint {
    /// Transform from the parent link frame to the child link frame at joint position `q`.
    pub fn transform(&self, q: f64) -> Isometry3<f64> {
        match self.kind {
            JointKind::Fixed => self.origin,
            JointKind::Revolute | JointKind::Continuous => {
                self.origin * UnitQuaternion::from_axis_angle(&self.axis, q)
            }
            JointKind::Prismatic => self.origin * Translation3::from(self.axis.into_inner() * q),
        }
    }
}

/// A robot description: links and joints of one URDF tree.
#[derive(Debug, Clone)]
pub struct RobotModel {
    pub(crate) name: String,
    pub(crate) links: Vec<Link>,
    pub(crate) joints: Vec<Joint>,
    pub(crate) root: usize,
    /// Links ordered so that every parent comes before its children.
    pub(crate) topo_order: Vec<usize>,
}

impl RobotModel {
    /// Loads a URDF file; mesh paths (`package://pkg/…`, relative, `file://`) are resolved against
    /// the file's folder.
    pub fn from_urdf_file(path: &Path) -> anyhow::Result<RobotModel> {
        let text = crate::util::read_text_input(path)
            .with_context(|| format!("cannot read URDF file {}", path.display()))?;
        let base = path.parent().unwrap_or(Path::new("."));
        Self::from_urdf_str(&text, base).with_context(|| format!("in URDF file {}", path.display()))
    }

    /// Parses URDF text; `base_dir` is the folder relative mesh paths are resolved against.
    pub fn from_urdf_str(text: &str, base_dir: &Path) -> anyhow::Result<RobotModel> {
        let robot = urdf_rs::read_from_string(text).map_err(|e| anyhow!("invalid URDF: {e}"))?;
        build(&robot, base_dir)
    }

    /// The URDF at `path`, or the shipped one when none is given (`--urdf` of every command).
    pub fn load(path: Option<&Path>) -> anyhow::Result<RobotModel> {
        match path {
            Some(p) => Self::from_urdf_file(p),
            None => Ok(Self::builtin()),
        }
    }

    /// The shipped `urdf/g1_left_arm.urdf` (left arm with Dex3-1 hand, primitive geometry).
    pub fn builtin() -> RobotModel {
        Self::from_urdf_str(BUILTIN_URDF, Path::new("."))
            .unwrap_or_else(|e| unreachable!("the shipped URDF is tested to load: {e:#}"))
    }

    /// The shipped `urdf/g1_left_arm_no_hand.urdf`.
    pub fn builtin_no_hand() -> RobotModel {
        Self::from_urdf_str(BUILTIN_URDF_NO_HAND, Path::new("."))
            .unwrap_or_else(|e| unreachable!("the shipped URDF is tested to load: {e:#}"))
    }

    /// The `<robot name=…>`.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// All links in URDF order.
    pub fn links(&self) -> &[Link] {
        &self.links
    }

    /// All joints in URDF order.
    pub fn joints(&self) -> &[Joint] {
        &self.joints
    }

    /// Index of the root link (the one that is no joint's child).
    pub fn root(&self) -> usize {
        self.root
    }

    /// Index of the link named `name`.
    pub fn link_index(&self, name: &str) -> Option<usize> {
        self.links.iter().position(|l| l.name == name)
    }

    /// Index of the joint named `name`.
    pub fn joint_index(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == name)
    }
}

fn build(robot: &urdf_rs::Robot, base_dir: &Path) -> anyhow::Result<RobotModel> {
    if robot.links.is_empty() {
        bail!("the robot has no <link>");
    }
    let mut index: HashMap<&str, usize> = HashMap::new();
    for (i, l) in robot.links.iter().enumerate() {
        if index.insert(l.name.as_str(), i).is_some() {
            bail!("link '{}' is defined twice", l.name);
        }
    }
    let materials: HashMap<&str, [f32; 4]> = robot
        .materials
        .iter()
        .filter_map(|m| Some((m.name.as_str(), rgba_of(m.color.as_ref()?))))
        .collect();

    let mut links = Vec::with_capacity(robot.links.len());
    for l in &robot.links {
        let visuals = l
            .visual
            .iter()
            .map(|v| visual(v, base_dir, &materials))
            .collect::<anyhow::Result<Vec<_>>>()
            .with_context(|| format!("link '{}'", l.name))?;
        let inertial = inertial(&l.inertial).with_context(|| format!("link '{}'", l.name))?;
        links.push(Link {
            name: l.name.clone(),
            parent_joint: None,
            visuals,
            inertial,
        });
    }

    let mut joints = Vec::with_capacity(robot.joints.len());
    let mut joint_names = std::collections::HashSet::new();
    for (ji, j) in robot.joints.iter().enumerate() {
        if !joint_names.insert(j.name.as_str()) {
            bail!("joint '{}' is defined twice", j.name);
        }
        let link = |role: &str, name: &str| {
            let found = index.get(name).copied();
            found.ok_or_else(|| anyhow!("joint '{}': {role} link '{name}' does not exist", j.name))
        };
        let (parent, child) = (
            link("parent", &j.parent.link)?,
            link("child", &j.child.link)?,
        );
        if let Some(prev) = links[child].parent_joint {
            bail!(
                "link '{}' is the child of two joints ('{}' and '{}')",
                j.child.link,
                robot.joints[prev].name,
                j.name
            );
        }
        links[child].parent_joint = Some(ji);
        joints.push(joint(j, parent, child).with_context(|| format!("joint '{}'", j.name))?);
    }

    let roots: Vec<usize> = (0..links.len())
        .filter(|&i| links[i].parent_joint.is_none())
        .collect();
    let root = match roots.as_slice() {
        [r] => *r,
        [] => bail!("the joints form a cycle: every link is some joint's child"),
        many => bail!(
            "the links do not form one tree: {} links have no parent joint ({})",
            many.len(),
            many.iter()
                .map(|&i| links[i].name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };

    // Breadth-first from the root; a link never reached sits on a cycle.
    let mut children: Vec<Vec<usize>> = vec![Vec::new(); links.len()];
    for j in &joints {
        children[j.parent_link].push(j.child_link);
    }
    let mut topo_order = vec![root];
    let mut k = 0;
    while k < topo_order.len() {
        topo_order.extend_from_slice(&children[topo_order[k]]);
        k += 1;
    }
    if topo_order.len() != links.len() {
        bail!(
            "the joints form a cycle (not every link is reachable from root '{}')",
            links[root].name
        );
    }

    Ok(RobotModel {
        name: robot.name.clone(),
        links,
        joints,
        root,
        topo_order,
    })
}

fn finite3(what: &str, v: &[f64; 3]) -> anyhow::Result<()> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        bail!("{what} has a non-finite value {v:?}")
    }
}

fn pose(p: &urdf_rs::Pose) -> anyhow::Result<Isometry3<f64>> {
    finite3("origin xyz", &p.xyz.0)?;
    finite3("origin rpy", &p.rpy.0)?;
    let [x, y, z] = p.xyz.0;
    let [r, pi, ya] = p.rpy.0;
    // URDF rpy = fixed-axis roll about x, then pitch about y, then yaw about z: R = Rz·Ry·Rx.
    Ok(Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(r, pi, ya),
    ))
}

fn joint(j: &urdf_rs::Joint, parent: usize, child: usize) -> anyhow::Result<Joint> {
    use urdf_rs::JointType as T;
    let kind = match j.joint_type {
        T::Revolute => JointKind::Revolute,
        T::Continuous => JointKind::Continuous,
        T::Prismatic => JointKind::Prismatic,
        T::Fixed | T::Floating | T::Planar | T::Spherical => JointKind::Fixed,
    };
    finite3("axis", &j.axis.xyz.0)?;
    let axis_v = Vector3::from(j.axis.xyz.0);
    let axis = if kind == JointKind::Fixed {
        Unit::try_new(axis_v, 1e-12).unwrap_or(Vector3::x_axis())
    } else {
        Unit::try_new(axis_v, 1e-12)
            .ok_or_else(|| anyhow!("axis {:?} has zero length", j.axis.xyz.0))?
    };
    let limits = match kind {
        JointKind::Revolute | JointKind::Prismatic => {
            let (lo, hi) = (j.limit.lower, j.limit.upper);
            if lo.is_nan() || hi.is_nan() || lo > hi {
                bail!("limit lower={lo} upper={hi} is not an interval");
            }
            Some((lo, hi))
        }
        _ => None,
    };
    Ok(Joint {
        name: j.name.clone(),
        kind,
        parent_link: parent,
        child_link: child,
        origin: pose(&j.origin)?,
        axis,
        limits,
    })
}

fn inertial(i: &urdf_rs::Inertial) -> anyhow::Result<Inertial> {
    let m = i.mass.value;
    if !m.is_finite() || m < 0.0 {
        bail!("mass {m} is not a finite non-negative number");
    }
    let t = &i.inertia;
    let frame = pose(&i.origin).context("inertial")?;
    let local = Matrix3::new(
        t.ixx, t.ixy, t.ixz, t.ixy, t.iyy, t.iyz, t.ixz, t.iyz, t.izz,
    );
    if local.iter().any(|x| !x.is_finite()) {
        bail!("inertia has a non-finite value");
    }
    let r = frame.rotation.to_rotation_matrix();
    Ok(Inertial {
        mass: m,
        com: frame.translation.vector,
        inertia: r.matrix() * local * r.matrix().transpose(),
    })
}

fn rgba_of(c: &urdf_rs::Color) -> [f32; 4] {
    c.rgba.0.map(|x| x as f32)
}

fn visual(
    v: &urdf_rs::Visual,
    base_dir: &Path,
    materials: &HashMap<&str, [f32; 4]>,
) -> anyhow::Result<Visual> {
    let geometry = match &v.geometry {
        urdf_rs::Geometry::Box { size } => Geometry::Box { size: size.0 },
        urdf_rs::Geometry::Cylinder { radius, length } => Geometry::Cylinder {
            radius: *radius,
            length: *length,
        },
        // A capsule drawn as its cylinder is close enough for a viewer; the inertials are separate.
        urdf_rs::Geometry::Capsule { radius, length } => Geometry::Cylinder {
            radius: *radius,
            length: *length + 2.0 * radius,
        },
        urdf_rs::Geometry::Sphere { radius } => Geometry::Sphere { radius: *radius },
        urdf_rs::Geometry::Mesh { filename, scale } => Geometry::Mesh {
            path: resolve_mesh_path(filename, base_dir),
            scale: scale.map(|s| s.0).unwrap_or([1.0; 3]),
        },
    };
    let rgba = v.material.as_ref().and_then(|m| {
        m.color
            .as_ref()
            .map(rgba_of)
            .or_else(|| materials.get(m.name.as_str()).copied())
    });
    Ok(Visual {
        origin: pose(&v.origin)?,
        geometry,
        rgba,
    })
}

/// Resolves a URDF mesh filename against the URDF's folder.
///
/// `package://pkg/rest` has no ROS package index to consult here, so the first existing of
/// `base/rest`, `base/../rest` and `base/pkg/rest` is taken (a description package usually holds the
/// URDF in `urdf/` or at its root); when none exists, `base/rest` is returned and the viewer reports it.
pub fn resolve_mesh_path(filename: &str, base_dir: &Path) -> PathBuf {
    if let Some(rest) = filename.strip_prefix("package://") {
        let (pkg, rel) = rest.split_once('/').unwrap_or(("", rest));
        let candidates = [
            base_dir.join(rel),
            base_dir.join("..").join(rel),
            base_dir.join(pkg).join(rel),
        ];
        return candidates
            .iter()
            .find(|p| p.exists())
            .unwrap_or(&candidates[0])
            .clone();
    }
    if let Some(abs) = filename.strip_prefix("file://") {
        return PathBuf::from(abs);
    }
    base_dir.join(filename)
}
