//! The viewer layout the replay opens on, as a Rerun blueprint with fixed ids.
//!
//! The Rust SDK 0.36 has a blueprint builder (`rerun::blueprint::Blueprint`), but it gives every
//! container and view a random UUID and logs through the wall-clock row path, so two runs never
//! produce the same blueprint. We build the same blueprint entities it would (`viewport`,
//! `container/<id>`, `view/<id>`, `view/<id>/ViewContents`, on the `blueprint` timeline at 0)
//! with ids hashed from the view names, and send them with `RecordingStream::send_blueprint`
//! (activated and made the default), which works for files and live viewers alike.

use anyhow::{Context, Result};
use rerun::blueprint::components::{
    ContainerKind, IncludedContent, QueryExpression, RootContainer, ViewClass,
};
use rerun::external::re_log_types::{
    BlueprintActivationCommand, RecordingId, SetStoreInfo, StoreId, StoreInfo, StoreKind,
    StoreSource, external::re_tuid::Tuid,
};
use rerun::external::re_sdk_types::blueprint::archetypes::{
    ContainerBlueprint, EyeControls3D, ViewBlueprint, ViewContents, ViewportBlueprint,
};
use rerun::external::re_sdk_types::blueprint::components::Eye3DKind;
use rerun::external::re_sdk_types::datatypes::Uuid;
use rerun::log::{Chunk, ChunkId, LogMsg, RowId};
use rerun::{AsComponents, RecordingStream, TimeColumn};

/// A node of the layout tree.
#[derive(Debug, Clone)]
pub enum Node {
    /// A container of other nodes.
    Container {
        /// Horizontal, vertical, tabs or grid.
        kind: ContainerKind,
        /// Display name.
        name: String,
        /// Children, in display order.
        children: Vec<Node>,
        /// Relative sizes of the children along the container's axis (empty = equal).
        shares: Vec<f32>,
    },
    /// A view.
    View {
        /// Rerun view class: `"3D"`, `"TimeSeries"`, `"TextLog"`, `"TextDocument"`.
        class: &'static str,
        /// Display name (also what its id is hashed from: keep names unique).
        name: String,
        /// Space origin (entity path).
        origin: String,
        /// Entity-path query expressions (`+ /power/**`, `- /x`); empty = `$origin/**`.
        contents: Vec<String>,
        /// Initial camera of a 3D view (ignored for other classes).
        eye: Option<Eye>,
    },
}

/// The initial camera of a 3D view (an orbit eye), in the view's origin frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Eye {
    /// Eye position.
    pub position: [f32; 3],
    /// The point the eye looks at (and orbits around).
    pub look_target: [f32; 3],
    /// The up direction.
    pub up: [f32; 3],
}

impl Eye {
    /// An eye `distance` away from `target` along `direction` (normalised), Z up.
    pub fn looking_at(target: [f32; 3], direction: [f32; 3], distance: f32) -> Eye {
        let norm = direction
            .iter()
            .map(|x| x * x)
            .sum::<f32>()
            .sqrt()
            .max(1e-6);
        Eye {
            position: std::array::from_fn(|i| target[i] + direction[i] / norm * distance),
            look_target: target,
            up: [0.0, 0.0, 1.0],
        }
    }
}

impl Node {
    /// A view node.
    pub fn view(
        class: &'static str,
        name: impl Into<String>,
        origin: impl Into<String>,
        contents: Vec<String>,
    ) -> Node {
        Node::View {
            class,
            name: name.into(),
            origin: origin.into(),
            contents,
            eye: None,
        }
    }

    /// Sets the initial camera (3D views only; no effect on containers).
    pub fn with_eye(mut self, new_eye: Eye) -> Node {
        if let Node::View { eye, .. } = &mut self {
            *eye = Some(new_eye);
        }
        self
    }

    /// A container node.
    pub fn container(
        kind: ContainerKind,
        name: impl Into<String>,
        children: Vec<Node>,
        shares: Vec<f32>,
    ) -> Node {
        Node::Container {
            kind,
            name: name.into(),
            children,
            shares,
        }
    }

    fn name(&self) -> &str {
        match self {
            Node::Container { name, .. } | Node::View { name, .. } => name,
        }
    }

    fn blueprint_path(&self) -> String {
        let id = uuid_string(&stable_uuid(self.name()));
        match self {
            Node::Container { .. } => format!("container/{id}"),
            Node::View { .. } => format!("view/{id}"),
        }
    }
}

/// A UUID (version 4 layout) hashed from a name, so the same layout always gets the same ids.
fn stable_uuid(name: &str) -> [u8; 16] {
    let hi = super::stable_hash(&[b"g1viz-blueprint-hi", name.as_bytes()]);
    let lo = super::stable_hash(&[b"g1viz-blueprint-lo", name.as_bytes()]);
    let mut b = [0u8; 16];
    b[..8].copy_from_slice(&hi.to_be_bytes());
    b[8..].copy_from_slice(&lo.to_be_bytes());
    b[6] = (b[6] & 0x0f) | 0x40;
    b[8] = (b[8] & 0x3f) | 0x80;
    b
}

fn uuid_string(b: &[u8; 16]) -> String {
    let hex: String = b.iter().map(|x| format!("{x:02x}")).collect();
    format!(
        "{}-{}-{}-{}-{}",
        &hex[0..8],
        &hex[8..12],
        &hex[12..16],
        &hex[16..20],
        &hex[20..32]
    )
}

/// Collects blueprint chunks with deterministic ids.
struct BlueprintChunks {
    store_id: StoreId,
    counter: u64,
    msgs: Vec<LogMsg>,
}

/// Tuid time part for blueprint rows: distinct from the data writers' namespaces.
const BLUEPRINT_NAMESPACE: u64 = 0x0B1E_0000_0000_0000;

impl BlueprintChunks {
    fn log(&mut self, path: &str, data: &dyn AsComponents) -> Result<()> {
        self.counter += 1;
        let chunk_id =
            ChunkId::from_tuid(Tuid::from_nanos_and_inc(BLUEPRINT_NAMESPACE, self.counter));
        self.counter += 1;
        let row_id = RowId::from_tuid(Tuid::from_nanos_and_inc(BLUEPRINT_NAMESPACE, self.counter));
        let timeline = TimeColumn::new_sequence("blueprint", [0]);
        // One row holding each component's whole batch: the row's length must be the batch's
        // length (`partitioned` does not check it; `[1]` silently cut every list to its first
        // element, e.g. a container's contents to its first child).
        let components = data
            .as_serialized_batches()
            .into_iter()
            .map(|b| {
                let n = b.array.len();
                b.partitioned([n]).map(|c| (c.descriptor, c.list_array))
            })
            .collect::<Result<_, _>>()?;
        let chunk = Chunk::from_native_row_ids(
            chunk_id,
            path.into(),
            Some(true),
            &[row_id],
            std::iter::once((*timeline.timeline().name(), timeline)).collect(),
            components,
        )
        .with_context(|| format!("building blueprint chunk {path}"))?;
        self.msgs.push(LogMsg::ArrowMsg(
            self.store_id.clone(),
            chunk.to_arrow_msg()?,
        ));
        Ok(())
    }

    fn node(&mut self, node: &Node) -> Result<()> {
        let path = node.blueprint_path();
        match node {
            Node::Container {
                kind,
                name,
                children,
                shares,
            } => {
                for child in children {
                    self.node(child)?;
                }
                let mut arch = ContainerBlueprint::new(*kind)
                    .with_display_name(name.as_str())
                    .with_contents(
                        children
                            .iter()
                            .map(|c| IncludedContent(format!("/{}", c.blueprint_path()).into())),
                    );
                if !shares.is_empty() {
                    arch = match kind {
                        ContainerKind::Vertical => arch.with_row_shares(shares.iter().copied()),
                        _ => arch.with_col_shares(shares.iter().copied()),
                    };
                }
                self.log(&path, &arch)
            }
            Node::View {
                class,
                name,
                origin,
                contents,
                eye,
            } => {
                let queries: Vec<QueryExpression> = if contents.is_empty() {
                    vec![QueryExpression("$origin/**".into())]
                } else {
                    contents
                        .iter()
                        .map(|q| QueryExpression(q.as_str().into()))
                        .collect()
                };
                self.log(&format!("{path}/ViewContents"), &ViewContents::new(queries))?;
                if let Some(eye) = eye {
                    // A view property, like the SDKs' `Spatial3DView(eye_controls=...)`.
                    let controls = EyeControls3D::new()
                        .with_kind(Eye3DKind::Orbital)
                        .with_position(eye.position)
                        .with_look_target(eye.look_target)
                        .with_eye_up(eye.up);
                    self.log(&format!("{path}/EyeControls3D"), &controls)?;
                }
                let arch = ViewBlueprint::new(ViewClass((*class).into()))
                    .with_display_name(name.as_str())
                    .with_space_origin(origin.as_str());
                self.log(&path, &arch)
            }
        }
    }
}

/// Sends `root` as the active and default blueprint of `stream`'s application.
pub fn send_blueprint(stream: &RecordingStream, root: &Node) -> Result<()> {
    let Some(info) = stream.store_info() else {
        return Ok(()); // disabled stream: nothing to configure
    };
    let app_id = info.application_id().clone();
    let store_id = StoreId::new(
        StoreKind::Blueprint,
        app_id,
        RecordingId::from("g1viz-blueprint"),
    );
    let set_info = SetStoreInfo {
        row_id: Tuid::from_nanos_and_inc(BLUEPRINT_NAMESPACE, 0),
        info: StoreInfo::new(store_id.clone(), StoreSource::Other("g1viz".into())),
    };
    let mut chunks = BlueprintChunks {
        store_id: store_id.clone(),
        counter: 0,
        msgs: vec![LogMsg::SetStoreInfo(set_info)],
    };
    chunks.node(root)?;
    let root_id = Uuid {
        bytes: stable_uuid(root.name()),
    };
    chunks.log(
        "viewport",
        &ViewportBlueprint::new().with_root_container(RootContainer(root_id)),
    )?;
    stream.send_blueprint(
        chunks.msgs,
        BlueprintActivationCommand {
            blueprint_id: store_id,
            make_active: true,
            make_default: true,
        },
    );
    Ok(())
}

/// Which optional parts the replay layout shows.
#[derive(Debug, Clone, Copy, Default)]
pub struct LayoutParts {
    /// Identified-model predictions, errors and loss terms are logged.
    pub model: bool,
    /// Diagnosis before/after predictions are logged.
    pub diagnosis: bool,
    /// The diagnosis carries a counterpart (torque difference recording − twin per joint).
    pub counterpart: bool,
    /// Trial marks are logged.
    pub trials: bool,
    /// The diagnosis found terms following recorded fields (plotted in their own tab, time-
    /// aligned with the prediction error).
    pub located: bool,
}

/// The replay layout: the 3D arm on the left; on the right power (measured vs predicted), the
/// prediction error, and tabs of joint plots (q, dq, τ, temperature), per-joint loss terms, IMU
/// and the trial log. The 3D view's camera starts on the front left of the arm, ~1.5 m from
/// `arm_center` (a point on the arm in the `/robot` frame, X forward, Y left, Z up).
pub fn replay_layout(joints: &[String], parts: LayoutParts, arm_center: [f32; 3]) -> Node {
    use ContainerKind::{Horizontal, Tabs, Vertical};
    let each = |signal: &str| {
        joints
            .iter()
            .map(|j| format!("+ /joints/{j}/{signal}"))
            .collect::<Vec<_>>()
    };
    let mut q = each("q");
    q.extend(each("q_cmd"));

    // Net power (a few W) beside net predictions; the raw rail readings (~120 W) get their own
    // tab so they do not flatten the net traces.
    let mut power_contents = vec!["+ /power/mbs/net".to_owned(), "+ /power/bms/net".to_owned()];
    if parts.model {
        power_contents.push("+ /model/power/**".into());
    }
    if parts.diagnosis {
        power_contents.push("+ /diagnosis/power/**".into());
    }
    let mut right = vec![Node::view(
        "TimeSeries",
        "Net power [W]",
        "/",
        power_contents,
    )];
    if parts.model || parts.diagnosis {
        let mut error = vec!["+ /model/error/**".to_owned()];
        if parts.diagnosis {
            error.push("+ /diagnosis/error/**".into());
        }
        right.push(Node::view("TimeSeries", "Prediction error [W]", "/", error));
    }

    let mut tabs = vec![
        Node::view("TimeSeries", "Joint position q [rad]", "/", q),
        Node::view("TimeSeries", "Joint velocity dq [rad/s]", "/", each("dq")),
        Node::view("TimeSeries", "Joint torque tau [Nm]", "/", each("tau")),
        Node::view(
            "TimeSeries",
            "Motor temperature [°C]",
            "/",
            each("temperature"),
        ),
    ];
    if parts.model {
        for j in joints {
            tabs.push(Node::view(
                "TimeSeries",
                format!("Loss terms {j} [W]"),
                format!("/model/terms/{j}"),
                vec![],
            ));
        }
        tabs.push(Node::view(
            "TimeSeries",
            "Interaction losses [W]",
            "/model/terms/interaction",
            vec![],
        ));
    }
    tabs.push(Node::view(
        "TimeSeries",
        "Raw power MBS/BMS [W]",
        "/",
        vec!["+ /power/mbs/raw".to_owned(), "+ /power/bms/raw".to_owned()],
    ));
    tabs.push(Node::view("TimeSeries", "IMU |ω| [rad/s]", "/imu", vec![]));
    if parts.trials || parts.diagnosis {
        let mut logs = vec!["+ /trials/**".to_owned()];
        if parts.diagnosis {
            logs.push("+ /diagnosis/**".into());
        }
        tabs.push(Node::view("TextLog", "Trials", "/", logs));
    }
    if parts.counterpart {
        tabs.push(Node::view(
            "TimeSeries",
            "Torque recording − twin [Nm]",
            "/diagnosis/torque",
            vec![],
        ));
    }
    if parts.located {
        tabs.push(Node::view(
            "TimeSeries",
            "Fields the found terms follow",
            "/diagnosis/located",
            vec![],
        ));
    }
    if parts.diagnosis {
        tabs.push(Node::view(
            "TextDocument",
            "Diagnosis summary",
            "/diagnosis/summary",
            vec![],
        ));
    }
    right.push(Node::container(Tabs, "Signals", tabs, vec![]));
    let n = right.len();
    let shares = match n {
        2 => vec![1.0, 1.5],
        _ => vec![1.0, 0.7, 1.5],
    };
    Node::container(
        Horizontal,
        "g1viz replay",
        vec![
            Node::view("3D", "Arm", "/robot", vec![]).with_eye(Eye::looking_at(
                arm_center,
                [1.0, 0.8, 0.45],
                1.5,
            )),
            Node::container(Vertical, "Plots", right, shares),
        ],
        vec![1.0, 1.3],
    )
}
