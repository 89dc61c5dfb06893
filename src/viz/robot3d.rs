//! The robot in 3D: static link geometry (URDF meshes via `Asset3D`; primitives otherwise, a box
//! drawn as a capsule along its longest side, sized to the link) and
//! link poses animated from the recorded joint positions.
//!
//! Layout (flat): `robot` is the model root (the pelvis), oriented in the world by the recorded
//! IMU quaternion (yaw of the first sample removed), so the body's sway shows; `robot/<link>`
//! carries the link's pose relative to the root as a `Transform3D` (and, for the arm links,
//! small axes: the joint frames); `robot/<link>/visual<k>` carries the visual's origin in the
//! link frame (static `Transform3D`, with the mesh scale) and its shape. Links whose pose does
//! not depend on the arm joints get one static pose; the others one pose per logged sample.

use anyhow::Result;
use nalgebra::Isometry3;
use rerun::components::FillMode;
use rerun::{
    Asset3D, Capsules3D, Color, Cylinders3D, Ellipsoids3D, Quaternion, Transform3D,
    TransformAxes3D, ViewCoordinates,
};

use super::{ChunkWriter, paths};
use crate::N_JOINTS;
use crate::robot::{ArmJoints, Geometry, RobotModel};

/// Which links move with the arm, and their entity paths.
pub(super) struct ArmScene {
    /// Entity path of every link (same order as `RobotModel::links`).
    pub paths: Vec<String>,
    /// Indices of links whose pose depends on the arm joints.
    pub moving: Vec<usize>,
}

fn to_transform(pose: &Isometry3<f64>) -> Transform3D {
    let t = pose.translation.vector;
    Transform3D::from_translation_rotation(
        [t.x as f32, t.y as f32, t.z as f32],
        quaternion(&pose.rotation),
    )
}

/// A rotation as Rerun's quaternion.
fn quaternion(r: &nalgebra::UnitQuaternion<f64>) -> Quaternion {
    let q = r.quaternion();
    Quaternion::from_xyzw([q.i as f32, q.j as f32, q.k as f32, q.w as f32])
}

/// The links whose pose depends on the arm joints, by index in `RobotModel::links`: those
/// whose pose at two different joint vectors differs (exact for the tree-structured kinematics:
/// no joint maps both vectors to the same pose) by more than 1e-9 m or 1e-9 rad — far above the
/// rounding of a metre-long chain (~1e-15) and far below any motion of a 0.3–0.7 rad probe
/// (millimetres at least). The one answer to "does this link move": the poses logged, the
/// size estimate and the camera's target all take it.
pub(super) fn moving_links(robot: &RobotModel, arm: &ArmJoints) -> Vec<usize> {
    let home = robot.link_poses(arm, &[0.0; N_JOINTS]);
    let probe = robot.link_poses(arm, &[0.5, -0.4, 0.3, -0.6, 0.7, -0.5, 0.4]);
    let differ = |(a, b): &(&Isometry3<f64>, &Isometry3<f64>)| {
        (a.translation.vector - b.translation.vector).norm() > 1e-9
            || a.rotation.angle_to(&b.rotation) > 1e-9
    };
    (home.iter().zip(&probe).enumerate())
        .filter(|(_, pair)| differ(pair))
        .map(|(i, _)| i)
        .collect()
}

/// Entity-path-safe link name.
fn link_path(name: &str) -> String {
    format!("{}/{}", paths::ROBOT, super::path_safe(name, "_-"))
}

/// Logs the static parts: view coordinates, geometry, the pose of every link that never moves.
/// Meshes that cannot be read are skipped with a warning (the rest of the robot still shows).
/// With `colour_links` the arm joints' child links get their colour on the timeline (see
/// [`log_link_colors`]) instead of a static one.
pub(super) fn log_static_robot(
    w: &mut ChunkWriter<'_>,
    robot: &RobotModel,
    arm: &ArmJoints,
    colour_links: bool,
    warnings: &mut Vec<String>,
) -> Result<ArmScene> {
    w.send_static("/", &ViewCoordinates::RIGHT_HAND_Z_UP())?;
    let home = robot.link_poses(arm, &[0.0; N_JOINTS]);
    let arm_links: Vec<usize> = arm
        .joints
        .iter()
        .filter_map(|&j| robot.joints().get(j).map(|jt| jt.child_link))
        .collect();
    let mut scene = ArmScene {
        paths: Vec::new(),
        moving: moving_links(robot, arm),
    };
    for (i, link) in robot.links().iter().enumerate() {
        let path = link_path(&link.name);
        if scene.moving.contains(&i) {
            if arm_links.contains(&i) {
                // The joint frame: short axes at the arm link's origin (its joint).
                w.send_static(&path, &TransformAxes3D::new(0.06))?;
            }
        } else if let Some(pose) = home.get(i) {
            w.send_static(&path, &to_transform(pose))?;
        }
        for (k, visual) in link.visuals.iter().enumerate() {
            let vpath = format!("{path}/visual{k}");
            let color = visual.rgba.map_or(Color::from_rgb(180, 180, 190), |c| {
                let u = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
                Color::from_unmultiplied_rgba(u(c[0]), u(c[1]), u(c[2]), u(c[3]))
            });
            let origin = to_transform(&visual.origin);
            // Arm links coloured by their power get their colour on the timeline (static data
            // would override it), starting grey at the session start.
            let timed = colour_links && arm_links.contains(&i);
            let static_colour = (!timed).then_some(color);
            match &visual.geometry {
                Geometry::Mesh { path: mesh, scale } => match Asset3D::from_file_path(mesh) {
                    Ok(asset) => {
                        let origin =
                            origin.with_scale([scale[0] as f32, scale[1] as f32, scale[2] as f32]);
                        w.send_static(&vpath, &origin)?;
                        let asset = match static_colour {
                            Some(c) => asset.with_albedo_factor(c.0),
                            None => asset,
                        };
                        w.send_static(&vpath, &asset)?;
                    }
                    Err(err) => {
                        warnings.push(format!(
                            "link {}: mesh {}: {err}; not shown",
                            link.name,
                            mesh.display()
                        ));
                        continue;
                    }
                },
                geometry => {
                    w.send_static(&vpath, &origin)?;
                    log_primitive(w, &vpath, geometry, static_colour)?;
                }
            }
            if timed {
                let columns = colour_columns(&visual.geometry, &[color])?;
                w.send_columns(&vpath, &[0.0], columns)?;
            }
        }
        scene.paths.push(path);
    }
    Ok(scene)
}

/// Logs the poses of the moving links for the samples `t`/`q`, one chunk per link.
pub(super) fn log_link_poses(
    w: &mut ChunkWriter<'_>,
    robot: &RobotModel,
    arm: &ArmJoints,
    scene: &ArmScene,
    t: &[f64],
    q: &[[f64; N_JOINTS]],
) -> Result<()> {
    if scene.moving.is_empty() || t.is_empty() {
        return Ok(());
    }
    let mut translations: Vec<Vec<[f32; 3]>> =
        vec![Vec::with_capacity(t.len()); scene.moving.len()];
    let mut rotations: Vec<Vec<Quaternion>> = vec![Vec::with_capacity(t.len()); scene.moving.len()];
    let mut poses = Vec::new();
    for qi in q {
        robot.link_poses_into(arm, qi, &mut poses);
        for (k, &link) in scene.moving.iter().enumerate() {
            let Some(p) = poses.get(link) else { continue };
            let v = p.translation.vector;
            translations[k].push([v.x as f32, v.y as f32, v.z as f32]);
            rotations[k].push(quaternion(&p.rotation));
        }
    }
    for (k, &link) in scene.moving.iter().enumerate() {
        let columns = Transform3D::update_fields()
            .with_many_translation(std::mem::take(&mut translations[k]))
            .with_many_quaternion(std::mem::take(&mut rotations[k]))
            .columns_of_unit_batches()?;
        w.send_columns(&scene.paths[link], t, columns)?;
    }
    Ok(())
}

/// Logs the body (model root) orientation from the IMU quaternions `quat` (w, x, y, z) at `t`:
/// the yaw of the first orientation (kept in `yaw0`) is removed so the robot starts facing the
/// same way whatever its heading was; roll, pitch and any later yaw change show as recorded.
/// Non-finite or zero quaternions are replaced by the identity.
pub(super) fn log_body_orientation(
    w: &mut ChunkWriter<'_>,
    yaw0: &mut Option<f64>,
    t: &[f64],
    quat: &[[f64; 4]],
) -> Result<()> {
    use nalgebra::{Quaternion as Q, UnitQuaternion};
    if t.is_empty() {
        return Ok(());
    }
    let unit = |q: &[f64; 4]| -> UnitQuaternion<f64> {
        let raw = Q::new(q[0], q[1], q[2], q[3]);
        if q.iter().all(|x| x.is_finite()) && raw.norm() > 1e-9 {
            UnitQuaternion::from_quaternion(raw)
        } else {
            UnitQuaternion::identity()
        }
    };
    let first = *yaw0.get_or_insert_with(|| unit(&quat[0]).euler_angles().2);
    let unyaw = UnitQuaternion::from_euler_angles(0.0, 0.0, -first);
    let rotations: Vec<Quaternion> = quat
        .iter()
        .map(|q| quaternion(&(unyaw * unit(q))))
        .collect();
    let columns = Transform3D::update_fields()
        .with_many_quaternion(rotations)
        .columns_of_unit_batches()?;
    w.send_columns(paths::ROBOT, t, columns)
}

/// Colour of a joint's predicted power `p` on a scale of `full` W: grey at 0, red at `full`
/// and above, blue for negative power (copper below the holding torque, braking).
pub(super) fn loss_colour(p: f64, full: f64) -> Color {
    const GREY: [f64; 3] = [180.0, 180.0, 190.0];
    let (x, target) = if p >= 0.0 {
        ((p / full).min(1.0), [230.0, 50.0, 50.0])
    } else {
        ((-p / full).min(1.0), [60.0, 120.0, 230.0])
    };
    let x = if x.is_finite() { x } else { 0.0 };
    let c = |i: usize| (GREY[i] + (target[i] - GREY[i]) * x).round() as u8;
    Color::from_rgb(c(0), c(1), c(2))
}

/// Colours each arm joint's child link by the joint's predicted power `power[k][j]` at `t[k]`
/// (see [`loss_colour`]; the scale `full` [W] is stated in the view's note).
pub(super) fn log_link_colors(
    w: &mut ChunkWriter<'_>,
    robot: &RobotModel,
    arm: &ArmJoints,
    scene: &ArmScene,
    t: &[f64],
    power: &[[f64; N_JOINTS]],
    full: f64,
) -> Result<()> {
    if t.is_empty() {
        return Ok(());
    }
    for (j, &joint) in arm.joints.iter().enumerate() {
        let Some(child) = robot.joints().get(joint).map(|jt| jt.child_link) else {
            continue;
        };
        let (Some(link), Some(path)) = (robot.links().get(child), scene.paths.get(child)) else {
            continue;
        };
        let colours: Vec<Color> = power.iter().map(|p| loss_colour(p[j], full)).collect();
        for (k, visual) in link.visuals.iter().enumerate() {
            let vpath = format!("{path}/visual{k}");
            let columns = colour_columns(&visual.geometry, &colours)?;
            w.send_columns(&vpath, t, columns)?;
        }
    }
    Ok(())
}

/// A URDF box drawn as a capsule along its longest side: the box's cross-section sets the
/// radius (a rounded limb the size of the link instead of a crate).
fn box_as_capsule(size: &[f64; 3]) -> Capsules3D {
    let axis = (0..3)
        .max_by(|&a, &b| size[a].total_cmp(&size[b]))
        .unwrap_or(2);
    let others: Vec<f64> = (0..3).filter(|&k| k != axis).map(|k| size[k]).collect();
    let radius = 0.25 * (others[0] + others[1]);
    let half = (0.5 * size[axis] - radius).max(0.0) as f32;
    let mut a = [0.0f32; 3];
    let mut b = [0.0f32; 3];
    a[axis] = -half;
    b[axis] = half;
    Capsules3D::from_endpoints_and_radii([a], [b], [radius as f32])
}

/// Logs one primitive shape (`colour`: static colour, or `None` when it comes on the timeline).
fn log_primitive(
    w: &mut ChunkWriter<'_>,
    vpath: &str,
    geometry: &Geometry,
    colour: Option<Color>,
) -> Result<()> {
    // Each shape solid, with its static colour when it has one.
    macro_rules! send {
        ($shape:expr) => {{
            let shape = $shape.with_fill_mode(FillMode::Solid);
            match colour {
                Some(c) => w.send_static(vpath, &shape.with_colors([c])),
                None => w.send_static(vpath, &shape),
            }
        }};
    }
    match geometry {
        Geometry::Box { size } => send!(box_as_capsule(size)),
        Geometry::Cylinder { radius, length } => send!(Cylinders3D::from_lengths_and_radii(
            [*length as f32],
            [*radius as f32]
        )),
        Geometry::Sphere { radius } => send!(Ellipsoids3D::from_radii([*radius as f32])),
        Geometry::Mesh { .. } => Ok(()),
    }
}

/// The colour column of a visual of `geometry`, one row per colour.
fn colour_columns(
    geometry: &Geometry,
    colours: &[Color],
) -> Result<Vec<rerun::SerializedComponentColumn>> {
    let colours = colours.to_vec();
    macro_rules! columns {
        ($fields:expr) => {
            $fields.columns_of_unit_batches()?.collect()
        };
    }
    Ok(match geometry {
        Geometry::Box { .. } => columns!(Capsules3D::update_fields().with_colors(colours)),
        Geometry::Cylinder { .. } => columns!(Cylinders3D::update_fields().with_colors(colours)),
        Geometry::Sphere { .. } => columns!(Ellipsoids3D::update_fields().with_colors(colours)),
        Geometry::Mesh { .. } => {
            columns!(Asset3D::update_fields().with_many_albedo_factor(colours.iter().map(|c| c.0)))
        }
    })
}
