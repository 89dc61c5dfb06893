//! The viewer layout the replay opens on, as a Rerun blueprint with fixed ids.
//!
//! The Rust SDK 0.36 has a blueprint builder (`rerun::blueprint::Blueprint`), but it gives every
//! container and view a random UUID and logs through the wall-clock row path, so two runs never
//! produce the same blueprint. We build the same blueprint entities it would (`viewport`,
//! `container/<id>`, `view/<id>`, `view/<id>/ViewContents`, on the `blueprint` timeline at 0)
//! with ids hashed from the view names, and send them with `RecordingStream::send_blueprint`
//! (activated and made the default), which works for files and live viewers alike.
//!
//! Every time-series view links its time axis to the others (zoom one, all follow) and the time
//! panel opens on the `session` timeline (seconds since the session start, as the reports and
//! the CLI count them).

use anyhow::Result;
use rerun::blueprint::components::{
    ContainerKind, IncludedContent, QueryExpression, RootContainer, ViewClass,
};
use rerun::components::Range1D;
use rerun::external::re_log_types::{
    BlueprintActivationCommand, RecordingId, SetStoreInfo, StoreId, StoreInfo, StoreKind,
    StoreSource, external::re_tuid::Tuid,
};
use rerun::external::re_sdk_types::blueprint::archetypes::{
    ContainerBlueprint, EyeControls3D, PlotLegend, ScalarAxis, TextLogColumns, TimeAxis,
    TimePanelBlueprint, ViewBlueprint, ViewContents, ViewportBlueprint,
};
use rerun::external::re_sdk_types::blueprint::components::{
    ActiveTab, Corner2D, Eye3DKind, LinkAxis, PanelState, PlayState, TextLogColumn, TimeRange,
    TimelineName,
};
use rerun::external::re_sdk_types::blueprint::datatypes::{
    TextLogColumn as TextLogColumnData, TextLogColumnKind, TimelineColumn,
};
use rerun::external::re_sdk_types::datatypes::{self as rr_data, Uuid};
use rerun::log::{ChunkId, LogMsg, RowId};
use rerun::{AsComponents, RecordingStream, TimeColumn};

use super::paths;

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
        /// The child shown first in a tab container (by name; `None`: the first).
        active: Option<String>,
        /// Columns of a grid container (`None`: the viewer decides).
        columns: Option<u32>,
        /// On the root: the window [s] the linked plots open on, centred on the time cursor
        /// (`None`: the whole session).
        window_s: Option<f64>,
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
        /// Where a plot's legend goes (time series and bar charts; `None`: the viewer's default).
        legend: Option<Legend>,
        /// The y range a plot opens on (time series only; `None`: fitted to the data). Set with
        /// headroom above the data, it keeps the legend (top corner) off the data.
        y_range: Option<[f64; 2]>,
        /// How [`Node::fit`] sets the legend and y range once the data's range is known.
        fit: Fit,
        /// The smallest height [px] of the plot area in a 1920×1080 browser window.
        plot_px: f64,
        /// A time series on its own time axis, always the whole session (the per-trial plots
        /// of a long session); `false`: linked to the other plots.
        whole: bool,
        /// On a whole-session axis: the time range [s] it opens on (`None`: the data's).
        x_range: Option<[f64; 2]>,
    },
}

/// How a plot's legend and y range follow from its data range ([`Node::fit`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fit {
    /// Left as built (3D, text, bar charts).
    Free,
    /// The data with 5 % to spare, widened until the viewer labels at least two ticks; no legend.
    Ticks,
    /// As `Ticks`, with room above the data for a legend of this many entries (no legend where
    /// it would take most of the plot).
    Legend(usize),
    /// Symmetric about zero ([`symmetric_range`]), widened for ticks if need be; no legend.
    Symmetric,
    /// Trial indices: half a step spare, widened for ticks; no legend.
    Indices,
}

/// A plot legend's place.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Legend {
    /// In the top-left corner.
    LeftTop,
    /// In the top-right corner.
    RightTop,
    /// Not shown (hovering still names the series).
    Hidden,
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

/// The range [min, max] of the values a view's entity queries (under its origin) take in, or
/// `None` without data: what [`Node::fit`] fits each plot to.
pub type RangeOf<'a> = dyn Fn(&[String], &str) -> Option<[f64; 2]> + 'a;

/// Builder methods that set fields of a view (no effect on a container).
macro_rules! view_setters {
    ($($(#[$doc:meta])* $name:ident($($arg:ident: $ty:ty),*) { $($field:ident = $value:expr),* })*) => {
        $($(#[$doc])* pub fn $name(mut self, $($arg: $ty),*) -> Node {
            if let Node::View { $($field,)* .. } = &mut self {
                $(*$field = $value;)*
            }
            self
        })*
    };
}

impl Node {
    view_setters! {
        /// Puts a time series on its own axis over the whole session, unlinked from the others.
        whole_session() { whole = true }
        /// Sets how [`Node::fit`] fits this plot, in a plot area at least `px` high.
        with_fit(new_fit: Fit, px: f64) { fit = new_fit, plot_px = px }
        /// Sets the y range a plot opens on (time series only; ignored when `None`).
        with_y_range(range: Option<[f64; 2]>) { y_range = range.or(*y_range) }
        /// Sets the time range a whole-session plot opens on ([`Node::whole_session`]).
        with_x_range(range: [f64; 2]) { x_range = Some(range) }
        /// Sets where a plot's legend goes (time series only).
        with_legend(new_legend: Legend) { legend = Some(new_legend) }
        /// Sets the initial camera (3D views only).
        with_eye(new_eye: Eye) { eye = Some(new_eye) }
    }

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
            legend: None,
            y_range: None,
            fit: Fit::Free,
            plot_px: DETAIL_PLOT_PX,
            whole: false,
            x_range: None,
        }
    }

    /// Sets the window [s] the linked plots open on, centred on the time cursor (the root's;
    /// `None`: the whole session). With a window the linked plots carry no y range: the viewer
    /// fits each to the data in the window as it moves (a whole-session range flattened it).
    pub fn with_window(mut self, window: Option<f64>) -> Node {
        if let Node::Container { window_s, .. } = &mut self {
            *window_s = window;
        }
        if window.is_some() {
            self.for_each_view(&mut Node::unfit_linked);
        }
        self
    }

    /// Calls `f` on every view of this tree.
    fn for_each_view(&mut self, f: &mut dyn FnMut(&mut Node)) {
        match self {
            Node::Container { children, .. } => {
                children.iter_mut().for_each(|c| c.for_each_view(f))
            }
            Node::View { .. } => f(self),
        }
    }

    /// Sets every fitted plot's legend and y range from its data range: `range_of(queries,
    /// origin)` is the range [min, max] of the values the view's entity queries take in (`None`:
    /// no data). Plots without data keep what they have.
    /// In a layout with a window ([`Node::with_window`]) the linked plots get their legends
    /// only: the viewer fits their y axes to the window.
    pub fn fit(&mut self, range_of: &RangeOf<'_>) {
        let windowed = self.window().is_some();
        self.for_each_view(&mut |v| v.fit_view(range_of, windowed));
    }

    /// The window [s] the linked plots open on (the root's; `None`: the whole session).
    fn window(&self) -> Option<f64> {
        match self {
            Node::Container { window_s, .. } => *window_s,
            Node::View { .. } => None,
        }
    }

    fn fit_view(&mut self, range_of: &RangeOf<'_>, windowed: bool) {
        let Node::View {
            class,
            origin,
            contents,
            legend,
            y_range,
            fit,
            plot_px,
            whole,
            ..
        } = self
        else {
            return;
        };
        if *class != "TimeSeries" || *fit == Fit::Free {
            return;
        }
        let Some(data) = range_of(contents, origin) else {
            return;
        };
        let (shown, range) = fitted_range(data, *fit, *plot_px);
        let fitted = *whole || !windowed;
        *legend = Some([Legend::Hidden, Legend::LeftTop][usize::from(shown && fitted)]);
        *y_range = fitted.then_some(range);
    }

    /// Drops a linked view's fitted y range (the viewer then fits it to the window; a range set
    /// by hand, [`Fit::Free`], stays) and its legend: nothing keeps a legend off data the viewer
    /// fits to the plot's edges, so the title or hovering names the series.
    fn unfit_linked(&mut self) {
        if let Node::View {
            class,
            whole: false,
            y_range,
            fit,
            legend,
            ..
        } = self
            && *class == "TimeSeries"
        {
            *y_range = y_range.filter(|_| *fit == Fit::Free);
            *legend = Some(Legend::Hidden);
        }
    }

    /// `children` in a container, or the only child itself when there is just one (a container
    /// of one view adds a tab strip and nothing else).
    pub fn group(
        kind: ContainerKind,
        name: impl Into<String>,
        mut children: Vec<Node>,
        shares: Vec<f32>,
    ) -> Node {
        if children.len() == 1 {
            return children.remove(0);
        }
        Node::container(kind, name, children, shares)
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
            active: None,
            columns: None,
            window_s: None,
        }
    }

    /// Makes the tab named `tab` the one its tab container opens on; false when no tab
    /// container in this tree has a child of that name.
    pub fn open_tab(&mut self, tab: &str) -> bool {
        match self {
            Node::View { .. } => false,
            Node::Container {
                kind,
                children,
                active,
                ..
            } => {
                if *kind == ContainerKind::Tabs && children.iter().any(|c| c.name() == tab) {
                    *active = Some(tab.to_owned());
                    return true;
                }
                children.iter_mut().any(|c| c.open_tab(tab))
            }
        }
    }

    /// The tab a user's `tab` means: its exact name, else the one name equal to it ignoring
    /// case, else the one name that starts with it ignoring case ("diagnosis" opens "Diagnosis
    /// summary" where that view is the diagnosis' only one); `None` when none or several match.
    pub fn resolve_tab(&self, tab: &str) -> Option<String> {
        let names = self.tab_names();
        if names.iter().any(|n| n == tab) {
            return Some(tab.to_owned());
        }
        let lower = tab.to_lowercase();
        for pick in [
            |n: &str, t: &str| n.to_lowercase() == t,
            |n: &str, t: &str| n.to_lowercase().starts_with(t),
        ] {
            let hits: Vec<&String> = names.iter().filter(|n| pick(n, &lower)).collect();
            if let [one] = hits.as_slice() {
                return Some((*one).clone());
            }
        }
        None
    }

    /// Names of the tabs of every tab container in this tree, in display order.
    pub fn tab_names(&self) -> Vec<String> {
        match self {
            Node::View { .. } => Vec::new(),
            Node::Container { kind, children, .. } => {
                let mut out = Vec::new();
                if *kind == ContainerKind::Tabs {
                    out.extend(children.iter().map(|c| c.name().to_owned()));
                }
                for c in children {
                    out.extend(c.tab_names());
                }
                out
            }
        }
    }

    /// A container's children (none for a view).
    pub fn children(&self) -> &[Node] {
        match self {
            Node::Container { children, .. } => children,
            Node::View { .. } => &[],
        }
    }

    /// Display name.
    pub fn name(&self) -> &str {
        match self {
            Node::Container { name, .. } | Node::View { name, .. } => name,
        }
    }

    fn blueprint_path(&self) -> String {
        let id = Uuid {
            bytes: stable_uuid(self.name()),
        };
        match self {
            Node::Container { .. } => format!("container/{id}"),
            Node::View { .. } => format!("view/{id}"),
        }
    }
}

/// A UUID (version 4 layout) hashed from a name, so the same layout always gets the same ids.
fn stable_uuid(name: &str) -> [u8; 16] {
    let hi = crate::read::fingerprint::stable_hash(&[b"g1viz-blueprint-hi", name.as_bytes()]);
    let lo = crate::read::fingerprint::stable_hash(&[b"g1viz-blueprint-lo", name.as_bytes()]);
    let mut b = [0u8; 16];
    b[..8].copy_from_slice(&hi.to_be_bytes());
    b[8..].copy_from_slice(&lo.to_be_bytes());
    b[6] = (b[6] & 0x0f) | 0x40;
    b[8] = (b[8] & 0x3f) | 0x80;
    b
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
        let timelines = std::iter::once((*timeline.timeline().name(), timeline)).collect();
        let chunk = super::one_row((chunk_id, row_id), path, timelines, data)?;
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
                active,
                columns,
                ..
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
                if let Some(tab) = children
                    .iter()
                    .find(|c| Some(c.name()) == active.as_deref())
                {
                    arch = arch.with_active_tab(ActiveTab(
                        format!("/{}", tab.blueprint_path()).as_str().into(),
                    ));
                }
                if let Some(n) = columns {
                    arch = arch.with_grid_columns(*n);
                }
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
                legend,
                y_range,
                whole,
                x_range,
                ..
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
                if *class == "TimeSeries" {
                    let axis = if *whole {
                        TimeAxis::new()
                            .with_link(LinkAxis::Independent)
                            .with_view_range(time_range(*x_range))
                    } else {
                        TimeAxis::new().with_link(LinkAxis::LinkToGlobal)
                    };
                    self.log(&format!("{path}/TimeAxis"), &axis)?;
                    if let Some([lo, hi]) = y_range {
                        let axis = ScalarAxis::new().with_range(Range1D::new(*lo, *hi));
                        self.log(&format!("{path}/ScalarAxis"), &axis)?;
                    }
                }
                if *class == "TextLog" {
                    self.log(&format!("{path}/TextLogColumns"), &text_log_columns())?;
                }
                if let Some(legend) = legend {
                    // `visible` set either way: a later send of the layout replaces an earlier
                    // hidden legend.
                    let arch = PlotLegend::new().with_visible(*legend != Legend::Hidden);
                    let arch = match legend {
                        Legend::LeftTop => arch.with_corner(Corner2D::LeftTop),
                        Legend::RightTop => arch.with_corner(Corner2D::RightTop),
                        Legend::Hidden => arch,
                    };
                    self.log(&format!("{path}/PlotLegend"), &arch)?;
                }
                let arch = ViewBlueprint::new(ViewClass((*class).into()))
                    .with_display_name(name.as_str())
                    .with_space_origin(origin.as_str());
                self.log(&path, &arch)
            }
        }
    }
}

/// The trial log's columns: the level and the text, which opens with the entry's session time
/// (the viewer's `session` column is cut past 1000 s; it, the wall-clock `time` column and the
/// entity path are hidden, so the text gets the width).
fn text_log_columns() -> TextLogColumns {
    let timeline = |name: &str, visible: bool| TimelineColumn {
        visible: visible.into(),
        timeline: name.into(),
    };
    let column = |kind, visible: bool| {
        TextLogColumn(TextLogColumnData {
            visible: visible.into(),
            kind,
        })
    };
    TextLogColumns::new()
        .with_timeline_columns([timeline("session", false), timeline("time", false)])
        .with_text_log_columns([
            column(TextLogColumnKind::EntityPath, false),
            column(TextLogColumnKind::LogLevel, true),
            column(TextLogColumnKind::Body, true),
        ])
}

/// Blueprint path of the viewer's shared view (`GLOBAL_VIEW_ID` in the viewer): the properties
/// every plot with a globally linked time axis reads.
const GLOBAL_VIEW: &str = "view/5c0dca6a-e63f-9cf7-f657-2602590474cc";

/// The time range a plot opens on: the whole session (the viewer's default for recordings
/// over a minute is a 60 s window around the time cursor), or a `window` seconds long at the
/// time cursor, a tenth of it before the cursor (it follows the cursor: move the cursor, or
/// right-click a whole-session plot, and the window goes there). The layout opens paused with
/// the cursor at the session's start, so the window shows the first trials.
fn session_range(window: Option<f64>) -> TimeRange {
    use rr_data::TimeRangeBoundary::{CursorRelative, Infinite};
    TimeRange(match window {
        None => rr_data::TimeRange {
            start: Infinite,
            end: Infinite,
        },
        Some(w) => {
            let ns = |f: f64| ((w * f * 1e9).round() as i64).into();
            rr_data::TimeRange {
                start: CursorRelative(ns(-0.1)),
                end: CursorRelative(ns(0.9)),
            }
        }
    })
}

/// The time range [s] `range` as the view range of a whole-session axis (`None`: the data's).
fn time_range(range: Option<[f64; 2]>) -> TimeRange {
    use rr_data::TimeRangeBoundary::Absolute;
    let Some([a, b]) = range else {
        return session_range(None);
    };
    let ns = |s: f64| Absolute(((s * 1e9).round() as i64).into());
    TimeRange(rr_data::TimeRange {
        start: ns(a),
        end: ns(b),
    })
}

/// Sends `root` as the active and default blueprint of `stream`'s application.
pub fn send_blueprint(stream: &RecordingStream, root: &Node) -> Result<()> {
    send_blueprint_generation(stream, root, 0)
}

/// Sends `root` as generation `generation` of the layout: 0 declares the store; a later one
/// (once the data is logged, e.g. with the plots fitted to it) sends the same blueprint store and
/// entities with rows of later ids (the viewer's latest-at query takes the later row at the same
/// blueprint time), then the activation again, so the viewer replaces its active copy of the
/// layout with this one.
pub(super) fn send_blueprint_generation(
    stream: &RecordingStream,
    root: &Node,
    generation: u32,
) -> Result<()> {
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
        counter: u64::from(generation) << 32,
        // The store is declared by the first send.
        msgs: if generation == 0 {
            vec![LogMsg::SetStoreInfo(set_info)]
        } else {
            Vec::new()
        },
    };
    chunks.node(root)?;
    chunks.log(
        &format!("{GLOBAL_VIEW}/TimeAxis"),
        &TimeAxis::new().with_view_range(session_range(root.window())),
    )?;
    chunks.log(
        "time_panel",
        // Collapsed to its one line of controls (play, timeline, time): the plots get the
        // height the streams tree would take.
        &TimePanelBlueprint::new()
            .with_timeline(TimelineName("session".into()))
            .with_state(PanelState::Collapsed)
            .with_play_state(PlayState::Paused),
    )?;
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

/// Which optional parts the replay layout shows, and the y ranges the plots open on.
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
    /// The IMU filter's statistic and threshold are logged.
    pub imu_filter: bool,
    /// The diagnosis found terms following recorded fields (plotted beside its summary,
    /// time-aligned with the prediction error).
    pub located: bool,
    /// The diagnosis found loads on the rest power (each trial's rest power and its prediction
    /// are plotted beside the fields).
    pub rest: bool,
    /// The diagnosis found the meter's averaging window drifting (plotted over the session).
    pub window_drift: bool,
    /// Series in the diagnosis' power plot (measured, before, after, and the found terms'
    /// prediction and the twin when present).
    pub diagnosis_power_series: usize,
    /// The diagnosis accepted hypotheses (else their series lies under the base model's, unnamed).
    pub hypotheses: bool,
    /// ± the 95th percentile of the kept trials' errors' size [W]: the windowed error plot's
    /// range.
    pub error_typical: Option<[f64; 2]>,
    /// σ|ω| per trial in the overview: 0 to 4× the threshold, so the kept trials' bars and the
    /// threshold stay visible beside rejected trials of 10–50× the threshold (those clip, red).
    pub imu_per_trial: Option<[f64; 2]>,
    /// A long session ([`opening_window`]): the linked plots open on this many seconds around
    /// the time cursor, and the overview shows per-trial plots over the whole session instead
    /// of the trial track (`None`: everything over the whole session).
    pub window_s: Option<f64>,
    /// Trials in the session, and how many a filter rejected (and a diagnosis located).
    pub trial_counts: TrialCounts,
    /// Each trial's rest power (pre-idle mean) is logged ([`paths::TRIAL_REST`]).
    pub trial_rest: bool,
    /// The joints' per-trial shares of the energy turnover are logged
    /// ([`paths::BARS_BY_JOINT`]; a long session's Joints tab gets its colour key from them).
    pub shares: bool,
    /// The first trial's start and the session's end [s] (the whole-session keys' time axis).
    pub span_s: Option<[f64; 2]>,
}

impl LayoutParts {
    /// The diagnosis plots its found terms' prediction (a power series beyond measured,
    /// before, after and the twin).
    fn found_terms(&self) -> bool {
        self.diagnosis_power_series > 3 + usize::from(self.counterpart)
    }
}

/// How many trials a session has and how many are marked (the per-trial strip's title).
#[derive(Debug, Clone, Copy, Default)]
pub struct TrialCounts {
    /// Trials in the session.
    pub total: usize,
    /// Trials a filter rejected.
    pub rejected: usize,
    /// Trials where a diagnosis located its mismatch.
    pub located: usize,
}

/// Above this many trials the overview shows per-trial plots over the session and the linked
/// plots open on a window of [`WINDOW_TRIALS`] trials (the shipped example has 7).
pub const WINDOWED_ABOVE_TRIALS: usize = 20;
/// Trials in the window the linked plots of a long session open on.
pub const WINDOW_TRIALS: f64 = 4.0;

/// The window [s] the linked plots of a session whose trials start at `starts` open on:
/// [`WINDOW_TRIALS`] × the median spacing of the trial starts, when there are more than
/// [`WINDOWED_ABOVE_TRIALS`] trials (`None`: the whole session).
pub fn opening_window(starts: &[f64]) -> Option<f64> {
    if starts.len() <= WINDOWED_ABOVE_TRIALS {
        return None;
    }
    let mut sorted = starts.to_vec();
    sorted.sort_by(f64::total_cmp);
    let mut gaps: Vec<f64> = sorted.windows(2).map(|w| w[1] - w[0]).collect();
    gaps.sort_by(f64::total_cmp);
    let median = gaps[gaps.len() / 2];
    (median.is_finite() && median > 0.0).then_some(WINDOW_TRIALS * median)
}

/// A y range symmetric about zero that holds `data` with 5 % to spare, its bound 1.2, 2.5 or
/// 12 × 10^k: the viewer labels ticks at powers of ten, so the ticks at zero and at ±10^k lie
/// inside it, at most five steps across (a fitted range of a short plot showed a single "0").
pub fn symmetric_range(data: [f64; 2]) -> [f64; 2] {
    let m = (data[0].abs().max(data[1].abs()) * 1.05).max(1e-6);
    let decade = 10f64.powf(m.log10().floor());
    let bound = [1.2, 2.5, 12.0]
        .iter()
        .map(|f| f * decade)
        .find(|b| *b >= m)
        .unwrap_or(12.0 * decade);
    [-bound, bound]
}

/// Legend geometry in the stock viewer (egui's default font, device pixel ratio 1): the space
/// above its first entry [px].
const LEGEND_TOP_PX: f64 = 18.0;
/// Height of each legend entry [px].
const LEGEND_LINE_PX: f64 = 23.0;
/// Width of a legend entry's marker and margins [px], and of each character of its name.
const LEGEND_MARKER_PX: f64 = 40.0;
const LEGEND_CHAR_PX: f64 = 7.5;
/// The smallest plot area [px] the overview's power plot gets in a 1920×1080 browser window.
pub const OVERVIEW_PLOT_PX: f64 = 190.0;
/// The smallest plot area [px] of a legend-carrying plot in the tabs (a half-height cell).
pub const DETAIL_PLOT_PX: f64 = 330.0;
/// The smallest plot width [px] of a plot in half the tabs' width (1920×1080, side panels open).
const HALF_PLOT_PX: f64 = 300.0;
/// Above this fraction of the plot's height a legend would squash the data: hide it instead.
const MAX_LEGEND_FRACTION: f64 = 0.6;

/// The y range that keeps `data` below a legend of `entries` lines in the plot's top corner:
/// the span above the data is the legend's share of the plot's height (and 5 % below the data).
/// `None` when the legend would take more than [`MAX_LEGEND_FRACTION`] of the plot.
fn legend_room(data: [f64; 2], entries: usize, plot_px: f64) -> Option<[f64; 2]> {
    let f = (LEGEND_TOP_PX + LEGEND_LINE_PX * entries as f64) / plot_px;
    if f > MAX_LEGEND_FRACTION {
        return None;
    }
    let [lo, hi] = data;
    let span = (hi - lo).max(1e-3);
    // The data fills [lo − 0.05 span, hi], the legend the top fraction f of the whole range.
    let headroom = 1.05 * f / (1.0 - f);
    Some([lo - 0.05 * span, hi + headroom * span])
}

/// The smallest plot area [px] of the overview's trial track in a 1920×1080 browser window.
pub const TRACK_PLOT_PX: f64 = 40.0;
/// The smallest plot area [px] of the overview's error plot in a 1920×1080 browser window.
pub const ERROR_PLOT_PX: f64 = 150.0;
/// The same in a long session's overview (measured on its screenshots: 83 px).
pub const WINDOWED_ERROR_PLOT_PX: f64 = 80.0;
/// The smallest plot area [px] of a per-trial bar chart: width, height (1920×1080 window).
pub const BAR_PLOT_PX: [f64; 2] = [300.0, 200.0];
/// The spacing [px] above which the stock viewer labels a tick of the y axis (egui_plot's
/// default `label_spacing` of a y axis is 20–30 px: labels fade in over it).
pub const Y_LABEL_PX: f64 = 20.0;
/// The spacing [px] above which the stock viewer labels a tick of the x axis (60–80 px).
pub const X_LABEL_PX: f64 = 60.0;
/// The margin the viewer adds on each side of the data when it fits a plot itself (egui_plot's
/// default margin fraction), as a fraction of the data's span.
pub const AUTO_MARGIN: f64 = 0.05;

/// The step between the labelled ticks the stock viewer (0.36.3, egui_plot's default log-10 grid)
/// draws on an axis spanning `span` over `px` pixels. Its grid has lines every `s0`, `10 s0` and
/// `100 s0`, `s0` the power of ten at or above the span of 8 px; a line gets a label when the
/// spacing of its step exceeds `label_px`. The labelled ticks are therefore the multiples of the
/// smallest power of ten whose spacing exceeds `label_px`.
pub fn labelled_step(span: f64, px: f64, label_px: f64) -> f64 {
    let min = (label_px * span / px).max(f64::MIN_POSITIVE);
    let mut step = 10f64.powf(min.log10().floor());
    while step <= min {
        step *= 10.0;
    }
    step
}

/// The labelled ticks of an axis showing `range` over `px` pixels (the viewer's grid takes the
/// multiples of the step in [lo, hi)).
pub fn labelled_ticks(range: [f64; 2], px: f64, label_px: f64) -> Vec<f64> {
    let [lo, hi] = range;
    let step = labelled_step(hi - lo, px, label_px);
    let (first, last) = ((lo / step).ceil() as i64, (hi / step).ceil() as i64);
    (first..last.min(first + 1000))
        .map(|k| k as f64 * step)
        .collect()
}

/// The axis range for `data` under `pad` (the margins and legend room around the data),
/// `data` widened to the multiples of the labelled step around it until the viewer labels at
/// least two ticks. Returns the widened data and the axis range; `None` when `pad` refuses.
pub fn tick_range(
    data: [f64; 2],
    px: f64,
    label_px: f64,
    pad: &dyn Fn([f64; 2]) -> Option<[f64; 2]>,
) -> Option<([f64; 2], [f64; 2])> {
    let [lo, hi] = data;
    let spare = (1e-3 * lo.abs().max(hi.abs())).max(1e-6);
    let mut d = if hi - lo < spare {
        [lo - spare, hi + spare]
    } else {
        data
    };
    for _ in 0..8 {
        let r = pad(d)?;
        if labelled_ticks(r, px, label_px).len() >= 2 {
            return Some((d, r));
        }
        let step = labelled_step(r[1] - r[0], px, label_px);
        let first = (d[0] / step).ceil() * step;
        if first <= d[1] {
            // One multiple inside: reach the next one on the nearer side.
            let (up, down) = (first + step, first - step);
            if up - d[1] <= d[0] - down {
                d[1] = up;
            } else {
                d[0] = down;
            }
        } else {
            // None inside: the multiples around the data.
            d = [first - step, first];
        }
    }
    pad(d).map(|r| (d, r))
}

/// `data` with `AUTO_MARGIN` of its span on each side.
fn with_margins(data: [f64; 2]) -> [f64; 2] {
    let span = data[1] - data[0];
    [data[0] - AUTO_MARGIN * span, data[1] + AUTO_MARGIN * span]
}

/// Whether the plot shows its legend, and the y range it opens on, for `data` under `fit` in a
/// plot area `px` high: every range holds the data, and the viewer labels at least two ticks.
pub fn fitted_range(data: [f64; 2], fit: Fit, px: f64) -> (bool, [f64; 2]) {
    let plain = |d| Some(with_margins(d));
    let ticks = |pad: &dyn Fn([f64; 2]) -> Option<[f64; 2]>| {
        tick_range(data, px, Y_LABEL_PX, pad).map(|(_, r)| r)
    };
    let fallback = with_margins(data);
    match fit {
        Fit::Legend(entries) => match ticks(&|d| legend_room(d, entries, px)) {
            Some(r) => (true, r),
            None => (false, ticks(&plain).unwrap_or(fallback)),
        },
        Fit::Symmetric => {
            let sym = symmetric_range(data);
            if labelled_ticks(sym, px, Y_LABEL_PX).len() >= 2 {
                (false, sym)
            } else {
                (false, ticks(&|d| Some(symmetric_range(d))).unwrap_or(sym))
            }
        }
        Fit::Indices => (
            false,
            ticks(&|[a, b]| Some([a - 0.5, b + 0.5])).unwrap_or([data[0] - 0.5, data[1] + 0.5]),
        ),
        Fit::Ticks | Fit::Free => (false, ticks(&plain).unwrap_or(fallback)),
    }
}

/// Whether blueprint query `query` (`+ /a`, `+ /a/**`, `$origin/**`) takes in entity `path`.
pub fn query_includes(query: &str, origin: &str, path: &str) -> bool {
    let Some(q) = query
        .trim()
        .strip_prefix('+')
        .map(str::trim)
        .or_else(|| (!query.trim_start().starts_with('-')).then_some(query.trim()))
    else {
        return false;
    };
    // Entity paths with or without their leading slash.
    let rooted = |p: &str| format!("/{}", p.trim_matches('/'));
    let q = q.replace("$origin", &rooted(origin));
    let path = rooted(path);
    match q.strip_suffix("/**").map(rooted) {
        Some(tree) if tree == "/" => true,
        Some(tree) => path == tree || path.starts_with(&format!("{tree}/")),
        None => path == rooted(&q),
    }
}

/// The IMU filter's series: σ|ω| per trial, of the rejected trials, and the threshold.
const IMU_FILTER: [&str; 3] = [
    paths::IMU_SIGMA,
    paths::IMU_SIGMA_REJECTED,
    paths::IMU_THRESHOLD,
];

fn include(paths: &[&str]) -> Vec<String> {
    paths.iter().map(|p| paths::include(p)).collect()
}

/// What the rows of [`VIEWS`] read: the parts shown, the joints' short names and where the 3D
/// camera looks.
struct Ctx<'a> {
    p: &'a LayoutParts,
    joints: &'a [String],
    arm_center: [f32; 3],
}

impl Ctx<'_> {
    /// The query of `path(j)` for each joint `j`.
    fn each(&self, path: impl Fn(&str) -> String) -> Vec<String> {
        self.joints
            .iter()
            .map(|j| paths::include(&path(j)))
            .collect()
    }

    /// A long session's span ([`LayoutParts::span_s`]): its tabs get colour keys.
    fn keyed(p: &LayoutParts) -> bool {
        p.span_s.is_some() && p.window_s.is_some()
    }
}

/// A view's title: as written (`{j}`: one view per joint, named after it), or made from the layout.
enum Title {
    Is(&'static str),
    Of(fn(&Ctx) -> String),
}

/// How a view is fitted ([`Node::fit`]): the rule, the plot height [px] it is fitted for, the
/// legend it opens with, and whether it is a time series on its own whole-session axis.
#[derive(Clone, Copy)]
struct Look(Fit, f64, Option<Legend>, bool);

const HIDDEN: Option<Legend> = Some(Legend::Hidden);
/// Left as built (3D, text).
const FREE: Look = Look(Fit::Free, DETAIL_PLOT_PX, None, false);
/// A plot of the tabs, fitted for ticks, no legend.
const TICKS: Look = Look(Fit::Ticks, DETAIL_PLOT_PX, HIDDEN, false);
/// One value per trial over the whole session (a long session's overview).
const PER_TRIAL: Look = Look(Fit::Ticks, ERROR_PLOT_PX, HIDDEN, true);
/// A long session's colour key ([`key`]).
const KEY: Look = Look(Fit::Free, DETAIL_PLOT_PX, Some(Legend::RightTop), true);

/// Fitted with room for a legend of `entries` lines above the data once it is logged; until
/// then no legend (nothing keeps it off data of unknown range).
const fn room(entries: usize, px: f64) -> Look {
    Look(Fit::Legend(entries), px, HIDDEN, false)
}

/// One view of the replay layout: the container it goes in ([`BOXES`]), when it is shown, its
/// class, title, origin and entity queries (for joint `j` of a per-joint view), how it is
/// fitted, its share of the container (a short session's, a long one's) and what else it sets.
struct Row(
    &'static str,
    fn(&LayoutParts) -> bool,
    &'static str,
    Title,
    &'static str,
    fn(&Ctx, &str) -> Vec<String>,
    Look,
    [f32; 2],
    fn(Node, &Ctx) -> Node,
);

fn all(_: &LayoutParts) -> bool {
    true
}
fn none(_: &Ctx, _: &str) -> Vec<String> {
    Vec::new()
}
fn same(v: Node, _: &Ctx) -> Node {
    v
}

const TS: &str = "TimeSeries";
const ROOT: &str = "g1viz replay";
const OVERVIEW: &str = "Overview";
const RAW: &str = "Raw power MBS/BMS [W]";
const PLOTS: &str = "Diagnosis plots";

/// A container: name, parent, kind, share of the parent, kept with one child (else the child
/// takes its place), and a grid's columns (beyond this many children: the second count).
type Frame = (
    &'static str,
    &'static str,
    ContainerKind,
    f32,
    bool,
    Option<(usize, [u32; 2])>,
);

/// The layout's containers ([`Frame`]), the root first.
#[rustfmt::skip]
const BOXES: &[Frame] = {
    use ContainerKind::{Grid, Horizontal, Tabs, Vertical};
    &[
        (ROOT, "", Horizontal, 0.0, true, None),
        (OVERVIEW, ROOT, Vertical, 1.0, true, None),
        ("Details", ROOT, Tabs, 1.25, true, None),
        ("Where the power goes", "Details", Horizontal, 0.0, true, None),
        ("Power over time", "Where the power goes", Vertical, 1.0, true, None),
        ("Per trial", "Where the power goes", Vertical, 1.0, true, None),
        ("Loss terms per joint", "Details", Grid, 0.0, true, Some((8, [4, 3]))),
        ("Joints", "Details", Grid, 0.0, true, Some((4, [2, 3]))),
        ("IMU and trials", "Details", Vertical, 0.0, false, None),
        (RAW, "Details", Vertical, 0.0, true, None),
        ("Diagnosis", "Details", Horizontal, 0.0, true, None),
        (PLOTS, "Diagnosis", Vertical, 1.4, false, None),
    ]
};

/// The replay layout, view by view. Left, the overview, top to bottom: the 3D arm (body
/// oriented by the IMU), power at the readings (measured vs the prediction averaged over each
/// reading's window, the instantaneous prediction as a thin context line), the trial track
/// (rejected trials as red bars), the error at the readings; a long session's ([`opening_window`])
/// readings and error on a window of a few trials around the time cursor, and below them one
/// value per trial over the whole session on their own axes (right-clicking one moves the
/// cursor, and the window, there): the rejected (and located) trials as a strip, each trial's
/// error, rest power and IMU statistic. Right, full-height tabs: where the power goes (per term,
/// per joint, per-trial bars keyed by trial index, or a long session's per-trial points, and
/// what the terms are), the loss terms per joint (one grid, the terms' legend on the first
/// cell), the joints (q with its command, q̇, τ, temperature), IMU and trials (|ω|, the filter's
/// statistic and threshold, the trial log), raw power, the diagnosis (summary; the fields its
/// found terms follow, the rest power, the torque differences). A long session's plots show no
/// legend (the viewer fits them to the window): the titles name the series, and the Joints and
/// Loss terms tabs get a colour key ([`key`]).
#[rustfmt::skip]
const VIEWS: &[Row] = {
    use Title::{Is, Of};
    use paths::{include as one, include_tree as tree};
    const OV: f64 = OVERVIEW_PLOT_PX;
    const D: f64 = DETAIL_PLOT_PX;
    &[
    Row(OVERVIEW, all, "3D", Is("Arm"), "/", |_, _| vec!["+ /".into(), tree(paths::ROBOT)], FREE, [1.5, 1.0],
        |v, c| v.with_eye(Eye::looking_at(c.arm_center, [1.0, 0.8, 0.45], 0.75))),
    Row(OVERVIEW, |p| p.model, TS, Of(power_title), "/", |_, _| include(&[paths::MODEL_READING_MEASURED,
        paths::MODEL_READING_PREDICTED, paths::MODEL_PREDICTED]), room(3, OV), [1.1, 1.0], same),
    Row(OVERVIEW, |p| p.diagnosis && !p.model, TS, Of(power_title), "/", |_, _| vec![tree("diagnosis/power")],
        room(3, OV), [1.1, 1.0], |v, c| v.with_fit(Fit::Legend(c.p.diagnosis_power_series), OV)),
    Row(OVERVIEW, |p| !p.model && !p.diagnosis, TS, Of(power_title), "/",
        |_, _| include(&[&paths::power_net("mbs"), &paths::power_net("bms")]), room(2, OV), [1.1, 1.0], same),
    Row(OVERVIEW, |p| p.window_s.is_none() && (p.trials || p.diagnosis), TS,
        Is("Trials (index; red: rejected or located)"), "/", |_, _| vec![one(paths::TRIAL_INDEX),
        tree(&paths::trial_spans(paths::TRIALS, "rejected")), tree(&paths::trial_spans(paths::DIAG_TRIALS, "located"))],
        Look(Fit::Indices, TRACK_PLOT_PX, HIDDEN, false), [0.4; 2], same),
    Row(OVERVIEW, |p| p.model || p.diagnosis, TS, Of(error_title), "/", |c, _| {
        let trees = [(c.p.model, "model/error"), (c.p.diagnosis, "diagnosis/error")];
        trees.into_iter().filter(|t| t.0).map(|t| tree(t.1)).collect()
    }, Look(Fit::Symmetric, ERROR_PLOT_PX, HIDDEN, false), [1.0, 0.8], |v, c| match (c.p.window_s, c.p.error_typical) {
        // A window the viewer fitted labelled a single tick (0) where its errors were small:
        // a fixed range about zero over most of the session's errors keeps 0 and ±10^k.
        (Some(_), Some(e)) => v.with_fit(Fit::Free, WINDOWED_ERROR_PLOT_PX)
            .with_y_range(Some(fitted_range(e, Fit::Symmetric, WINDOWED_ERROR_PLOT_PX).1)),
        _ => v,
    }),
    // A fixed range half a step around its rows (1: rejected, 2: located): the data alone
    // ([1, 1]) was widened to ticks 0.999…1.001, whose labels overlapped on the low strip.
    Row(OVERVIEW, |p| p.window_s.is_some(), TS, Of(strip_title), "/", |c, _| {
        let strips = [(true, paths::TRIALS), (c.p.diagnosis, paths::DIAG_TRIALS)];
        strips.into_iter().filter(|s| s.0).map(|s| tree(&paths::trial_strip(s.1))).collect()
    }, Look(Fit::Free, TRACK_PLOT_PX, HIDDEN, true), [0.45; 2],
        |v, c| v.with_y_range(Some([0.5, 1.5 + f64::from(u8::from(c.p.diagnosis))]))),
    Row(OVERVIEW, |p| p.window_s.is_some() && (p.model || p.diagnosis), TS, Of(trial_error_title), "/", |c, _| match c.p.model {
        true => include(&[paths::MODEL_ERROR_TRAJECTORY, paths::MODEL_ERROR_TRAJECTORY_REJECTED]),
        false => vec![tree("diagnosis/per_trial")],
    }, PER_TRIAL, [0.8; 2], same),
    Row(OVERVIEW, |p| p.window_s.is_some() && p.trial_rest, TS, Is("Rest power per trial [W] (pre-idle mean)"), "/",
        |_, _| vec![one(paths::TRIAL_REST)], PER_TRIAL, [0.8; 2], same),
    Row(OVERVIEW, |p| p.window_s.is_some() && !p.trial_rest && p.rest, TS,
        Is("Rest power per trial [W]: measured blue, with the loads found on it red"), "/",
        |_, _| vec![tree(&paths::diag_trial_rest(""))], PER_TRIAL, [0.8; 2], same),
    // A set range is not refitted to the data (whose rejected trials reach 10–50× it).
    Row(OVERVIEW, |p| p.window_s.is_some() && p.imu_filter, TS,
        Is("IMU σ|ω| per trial [rad/s] (above the black threshold: rejected, red; axis to 4× it)"), "/",
        |_, _| include(&IMU_FILTER), PER_TRIAL, [0.8; 2], |v, c| match c.p.imu_per_trial {
            Some(r) => v.with_fit(Fit::Free, ERROR_PLOT_PX).with_y_range(Some(r)),
            None => v,
        }),
    Row("Power over time", |p| p.model, TS, Is("Predicted power by term, all joints [W]"), "/",
        |_, _| vec![tree(paths::BY_TERM)], room(paths::TERMS.len() + 1, D), [0.0; 2], same),
    Row("Power over time", |p| p.model, TS, Is("Predicted power by joint, all terms [W]"), "/",
        |c, _| c.each(paths::by_joint), room(crate::N_JOINTS, D), [0.0; 2], same),
    Row("Per trial", |p| p.model && !Ctx::keyed(p), "BarChart", Is("Trial energy turnover by joint [%], x: trial"), "/",
        |_, _| vec![tree(paths::BARS_BY_JOINT)], Look(Fit::Free, D, HIDDEN, false), [1.0; 2], same),
    Row("Per trial", |p| p.model && Ctx::keyed(p), TS, Is("Trial energy turnover by joint [%]"), "/",
        |_, _| vec![tree(paths::BARS_BY_JOINT)], KEY, [1.0; 2], |v, c| key(v, c, &joint_names(c.joints), [HALF_PLOT_PX, D])),
    Row("Per trial", |p| p.model && !Ctx::keyed(p), "BarChart", Is("Trial energy turnover by term [%], x: trial"), "/",
        |_, _| vec![tree(paths::BARS_BY_TERM)], Look(Fit::Free, D, HIDDEN, false), [1.0; 2], same),
    Row("Per trial", |p| p.model && Ctx::keyed(p), TS, Is("Trial energy turnover by term [%]"), "/",
        |_, _| vec![tree(paths::BARS_BY_TERM)], KEY, [1.0; 2], |v, c| key(v, c, &term_names(), [HALF_PLOT_PX, D])),
    Row("Per trial", |p| p.model, "TextDocument", Is("What the terms are"), paths::BREAKDOWN_NOTE, none, FREE, [0.8; 2], same),
    Row("Loss terms per joint", |p| p.model, TS, Is("{j} [W]"), "/",
        |_, j| paths::TERMS.iter().map(|t| one(&paths::term(j, t))).collect(), room(paths::TERMS.len(), D), [0.0; 2], same),
    // A title short enough to show whole in a cell of four columns ("Interaction [W]" was cut).
    Row("Loss terms per joint", |p| p.model, TS, Is("Pairwise [W]"), "/", |_, _| vec![one(paths::TERM_INTERACTION)],
        TICKS, [0.0; 2], same),
    Row("Loss terms per joint", |p| p.model && Ctx::keyed(p), TS, Is("Key: term shares [%]"), "/",
        |_, _| vec![tree(paths::BARS_BY_TERM)], KEY, [0.0; 2], |v, c| key(v, c, &term_names(), THIRD_PLOT_PX)),
    Row("Joints", all, TS, Is("q [rad], command pale"), "/", |c, _| {
        let mut q = c.each(|j| paths::joint(j, "q"));
        q.extend(c.each(|j| paths::joint(j, "q_cmd")));
        q
    }, room(crate::N_JOINTS, D), [0.0; 2], same),
    Row("Joints", all, TS, Is("Joint velocity q̇ [rad/s]"), "/", |c, _| c.each(|j| paths::joint(j, "dq")),
        room(crate::N_JOINTS, D), [0.0; 2], same),
    Row("Joints", all, TS, Is("Joint torque τ [Nm]"), "/", |c, _| c.each(|j| paths::joint(j, "tau")),
        room(crate::N_JOINTS, D), [0.0; 2], same),
    Row("Joints", all, TS, Is("Motor temperature [°C]"), "/", |c, _| c.each(|j| paths::joint(j, "temperature")),
        TICKS, [0.0; 2], same),
    Row("Joints", |p| p.shares && Ctx::keyed(p), TS, Is("Key: joint shares [%]"), "/",
        |_, _| vec![tree(paths::BARS_BY_JOINT)], KEY, [0.0; 2],
        |v, c| key(v, c, &joint_names(c.joints), [THIRD_PLOT_PX[0], D])),
    Row("IMU and trials", |p| p.imu_filter, TS, Of(|c| match c.p.window_s {
        Some(_) => "IMU [rad/s]: |ω| grey, σ|ω| per trial blue (rejected red), threshold black",
        None => "IMU |ω| [rad/s] and the balance filter",
    }.into()), "/", |_, _| include(&[paths::IMU_GYRO_NORM, IMU_FILTER[0], IMU_FILTER[1], IMU_FILTER[2]]),
        room(4, D), [1.5; 2], same),
    Row("IMU and trials", |p| !p.imu_filter, TS, Is("IMU |ω| of the body [rad/s]"), "/",
        |_, _| vec![one(paths::IMU_GYRO_NORM)], TICKS, [1.5; 2], same),
    Row("IMU and trials", |p| p.trials || p.diagnosis, "TextLog", Is("Trial log"), "/", |c, _| {
        let logs = [(true, paths::TRIALS), (c.p.diagnosis, paths::DIAG_TRIALS)];
        logs.into_iter().filter(|l| l.0).map(|l| one(&paths::trials_log(l.1))).collect()
    }, FREE, [1.0; 2], same),
    Row("Details", |p| p.window_s.is_none(), TS, Is(RAW), "/", raw_power, room(2, D), [0.0; 2], same),
    // Without a legend the title names the series; the tab keeps its short name.
    Row(RAW, |p| p.window_s.is_some(), TS, Is("Raw power [W]: MBS cyan, BMS olive"), "/", raw_power,
        Look(Fit::Ticks, D, None, false), [0.0; 2], same),
    Row("Diagnosis", |p| p.diagnosis, "TextDocument", Is("Diagnosis summary"), paths::DIAG_SUMMARY, none, FREE,
        [1.0; 2], same),
    Row(PLOTS, |p| p.located, TS, Is("Fields the found terms follow"), paths::DIAG_LOCATED, none, TICKS, [0.0; 2], same),
    Row(PLOTS, |p| p.rest, TS, Is("Rest power [W]: measured blue, with found loads red"), paths::DIAG_REST, none,
        TICKS, [0.0; 2], same),
    // Over the whole session (the drift spans it), on its own axis.
    Row(PLOTS, |p| p.window_drift, TS, Is("Meter window [s] over the session: drifting red, one window grey"),
        paths::DIAG_WINDOW, none, Look(Fit::Ticks, D, HIDDEN, true), [0.0; 2], same),
    Row(PLOTS, |p| p.counterpart, TS, Is("Torque recording − twin [Nm]"), paths::DIAG_TORQUE, none, TICKS, [0.0; 2], same),
    ]
};

fn raw_power(_: &Ctx, _: &str) -> Vec<String> {
    include(&[&paths::power_raw("mbs"), &paths::power_raw("bms")])
}

/// The overview's power plot: without a legend on a long session's window (the viewer fits it,
/// so the legend would cover the data) the title names the series.
fn power_title(c: &Ctx) -> String {
    let p = c.p;
    let Some(window_s) = p.window_s else {
        return match p.model || p.diagnosis {
            true => "Net power at the readings [W]",
            false => {
                "Net power [W]: MBS cyan, BMS olive (minus the idle baseline before the arm moves)"
            }
        }
        .into();
    };
    let mut key = String::from("measured blue, ");
    if p.model {
        key.push_str("predicted orange, instant brown");
    } else {
        key.push_str(["base grey", "base grey, hyp. orange"][usize::from(p.hypotheses)]);
        if p.found_terms() {
            key.push_str(", found red");
        }
        if p.counterpart {
            key.push_str(", twin cyan");
        }
    }
    format!("Net power [W], {window_s:.0} s at cursor: {key}")
}

/// The error at the readings: dots per reading, diamonds per trajectory, rejected trials in red
/// (the trial track above says so; with a diagnosis: the base model's error and the error with
/// the hypotheses, drawn over it, the found terms' in red). Small and dense: the title names
/// the markers.
fn error_title(c: &Ctx) -> String {
    let p = c.p;
    let mut name = String::from("Error measured − predicted [W]");
    if p.model {
        name.push_str(": dots per reading, diamonds per trial");
    }
    if p.diagnosis {
        name.push_str(if p.model { "; " } else { ": " });
        name.push_str(
            ["base model grey", "base model grey, hypotheses teal"][usize::from(p.hypotheses)],
        );
        if p.found_terms() {
            name.push_str(", found terms red");
        }
    }
    name
}

/// A long session's strip of rejected (and located) trials, titled with their counts.
fn strip_title(c: &Ctx) -> String {
    let n = c.p.trial_counts;
    let mut strip = format!("Rejected trials: {} of {} (red)", n.rejected, n.total);
    if c.p.diagnosis {
        strip.push_str(&format!("; located: {} (orange)", n.located));
    }
    strip + " · right-click one to see it above"
}

/// Each trial's error: the model's, or the diagnosis' series that show (no accepted
/// hypothesis: theirs lies under the base model's).
fn trial_error_title(c: &Ctx) -> String {
    if c.p.model {
        return "Error per trial [W] (rejected: red crosses)".into();
    }
    let named = [
        (true, "base model grey"),
        (c.p.hypotheses, "with hypotheses teal"),
        (c.p.found_terms(), "with found terms red"),
    ];
    let named: Vec<&str> = named.iter().filter(|n| n.0).map(|n| n.1).collect();
    format!("Error per trial [W]: {}", named.join(", "))
}

/// The replay layout ([`VIEWS`]) for `parts`: `joints` the short joint names, `arm_center` a
/// point on the arm in the `/robot` frame (X forward, Y left, Z up) the 3D camera starts 0.75 m
/// from, on the front left.
pub fn replay_layout(joints: &[String], parts: LayoutParts, arm_center: [f32; 3]) -> Node {
    let c = Ctx {
        p: &parts,
        joints,
        arm_center,
    };
    let mut root = Draft(&BOXES[0], Vec::new());
    for Row(at, when, class, title, origin, contents, look, share, tune) in VIEWS {
        if !when(&parts) {
            continue;
        }
        let name = match title {
            Title::Is(name) => name.to_string(),
            Title::Of(f) => f(&c),
        };
        let each = match name.contains("{j}") {
            true => joints.iter().map(String::as_str).collect(),
            false => vec![""],
        };
        for (k, j) in each.into_iter().enumerate() {
            // A per-joint view's legend is the first's (the same colours in every cell).
            let Look(fit, plot_px, legend, whole) = [*look, TICKS][usize::from(k > 0)];
            let view = Node::view(class, name.replace("{j}", j), *origin, contents(&c, j));
            let mut view = view.with_fit(fit, plot_px);
            if let Node::View {
                legend: l,
                whole: w,
                ..
            } = &mut view
            {
                (*l, *w) = (legend, whole);
            }
            let mut path: Vec<&Frame> = Vec::new();
            let mut at = *at;
            while let Some(b) = BOXES[1..].iter().find(|b| b.0 == at) {
                path.insert(0, b);
                at = b.1;
            }
            root.insert(
                &path,
                tune(view, &c),
                share[usize::from(parts.window_s.is_some())],
            );
        }
    }
    root.node().with_window(parts.window_s)
}

/// A container being filled: its frame and its views and containers, each with its share.
struct Draft(&'static Frame, Vec<(Result<Node, Draft>, f32)>);

impl Draft {
    /// Adds `view` to the container at `path` below this one, making the containers on the way.
    fn insert(&mut self, path: &[&'static Frame], view: Node, share: f32) {
        let Some((&first, rest)) = path.split_first() else {
            return self.1.push((Ok(view), share));
        };
        let found = (self.1.iter()).position(|i| matches!(&i.0, Err(d) if d.0.0 == first.0));
        let k = found.unwrap_or_else(|| {
            self.1.push((Err(Draft(first, Vec::new())), first.3));
            self.1.len() - 1
        });
        if let Err(d) = &mut self.1[k].0 {
            d.insert(rest, view, share);
        }
    }

    /// The container (or its only child, where its frame says so); shares where every child has one.
    fn node(self) -> Node {
        let Draft(&(name, _, kind, _, keep, grid), items) = self;
        let (mut children, shares): (Vec<Node>, Vec<f32>) = (items.into_iter())
            .map(|(i, s)| (i.unwrap_or_else(Draft::node), s))
            .unzip();
        if children.len() == 1 && !keep {
            return children.remove(0);
        }
        let shared = children.len() > 1 && shares.iter().all(|s| *s > 0.0);
        let columns = grid.map(|(full, n)| n[usize::from(children.len() > full)]);
        let shares = if shared { shares } else { Vec::new() };
        let mut node = Node::container(kind, name, children, shares);
        if let Node::Container { columns: c, .. } = &mut node {
            *c = columns;
        }
        node
    }
}

/// The joints' names, as the keys' legends list them.
fn joint_names(joints: &[String]) -> Vec<&str> {
    joints.iter().map(String::as_str).collect()
}

/// The terms' names (the interaction last), as the keys' legends list them.
fn term_names() -> Vec<&'static str> {
    paths::TERMS
        .iter()
        .copied()
        .chain(["interaction"])
        .collect()
}

/// The plot area [px] of a cell in a grid of three columns and rows (1920×1080 window, the
/// side panels open): width, height.
const THIRD_PLOT_PX: [f64; 2] = [200.0, 240.0];
/// The y range of the per-trial shares [%]: the viewer labels −100, 0 and 100 only (a step of
/// 10 would need a plot over 440 px high), so the axis reads as shares within ±100 %.
pub const SHARE_RANGE: [f64; 2] = [-110.0, 110.0];

/// Each joint's or term's share of each trial's energy turnover [%] (the per-trial points a long
/// session logs) over the whole session, on [`SHARE_RANGE`], with the legend of `names` top right
/// over time after the session's end: the session's span ([`LayoutParts::span_s`]) is stretched
/// until the legend, about as wide as its longest name, clears the data in a plot area `plot_px`
/// (width, height). A colour key that covers nothing, on an axis that does not run past 100 %.
fn key(view: Node, c: &Ctx, names: &[&str], plot_px: [f64; 2]) -> Node {
    let chars = names.iter().map(|n| n.chars().count()).max().unwrap_or(0);
    let legend = (LEGEND_MARKER_PX + LEGEND_CHAR_PX * chars as f64) / plot_px[0];
    let [a, b] = c.p.span_s.unwrap_or_default();
    let width = (b - a).max(1e-3) * (1.0 + 2.0 * AUTO_MARGIN) / (1.0 - legend.min(0.7));
    view.with_x_range([a - AUTO_MARGIN * (b - a), a + width])
        .with_fit(Fit::Free, plot_px[1])
        .with_y_range(Some(SHARE_RANGE))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every view of `node`: name and whether it is on its own whole-session axis.
    fn views(node: &Node) -> Vec<(String, bool)> {
        match node {
            Node::View { name, whole, .. } => vec![(name.clone(), *whole)],
            Node::Container { children, .. } => children.iter().flat_map(views).collect(),
        }
    }

    /// Past 20 trials the linked plots open on 4 trials' spacing around the cursor; the
    /// overview's per-trial plots keep the whole session, the strip names the counts, and the
    /// trial track (one diagonal over a long session) is gone. The example's 7 trials: as before.
    #[test]
    fn a_long_session_opens_on_a_window_with_per_trial_plots() {
        let starts: Vec<f64> = (0..30)
            .map(|k| 10.0 * k as f64 + 0.1 * (k % 3) as f64)
            .collect();
        assert_eq!(opening_window(&starts[..7]), None);
        assert_eq!(opening_window(&starts[..20]), None);
        let w = opening_window(&starts).unwrap();
        assert!((w - 40.0).abs() < 1.0, "{w}");
        let joints: Vec<String> = (0..7).map(|j| format!("j{j}")).collect();
        let parts = LayoutParts {
            model: true,
            trials: true,
            imu_filter: true,
            window_s: Some(w),
            trial_counts: TrialCounts {
                total: 1000,
                rejected: 125,
                ..Default::default()
            },
            trial_rest: true,
            span_s: Some([0.0, 300.0]),
            ..LayoutParts::default()
        };
        let mut root = replay_layout(&joints, parts, [0.0; 3]);
        assert!(matches!(root, Node::Container { window_s: Some(x), .. } if x == w));
        // Fitted to data of −20…130 W: the per-trial plots open on it, the linked plots carry
        // no y range and no legend (the viewer fits them to the window); the strip opens on its
        // rows, half a step spare.
        root.fit(&|_, _| Some([-20.0, 130.0]));
        root.for_each_view(&mut |v| {
            if let Node::View {
                class: "TimeSeries",
                name,
                y_range,
                whole,
                legend,
                ..
            } = v
            {
                assert_eq!(*whole, y_range.is_some(), "{name}");
                if name.starts_with("Rejected trials") {
                    assert_eq!(*y_range, Some([0.5, 1.5]), "{name}");
                }
                if !*whole {
                    assert_eq!(*legend, Some(Legend::Hidden), "{name}");
                }
            }
        });
        // With the errors' typical size known, the windowed error plot keeps a range about
        // zero that the viewer labels at 0 and ±10^k (its own fit labelled a single 0); ±2.5
        // would label only 0 in the low plot, so a typical 2 W widens further.
        for (typical, bound) in [(Some(0.7), Some(1.2)), (Some(2.0), None), (None, None)] {
            let error_typical = typical.map(|e| [-e, e]);
            let parts = LayoutParts {
                error_typical,
                ..parts
            };
            let mut root = replay_layout(&joints, parts, [0.0; 3]);
            let mut range = None;
            root.for_each_view(&mut |v| match v {
                Node::View { name, y_range, .. } if name.starts_with("Error measured") => {
                    range = *y_range
                }
                _ => {}
            });
            assert_eq!(range.is_some(), typical.is_some());
            let (Some(e), Some(r)) = (typical, range) else {
                continue;
            };
            assert!(r[0] == -r[1] && r[1] >= e, "{r:?}");
            assert!(bound.is_none_or(|b| (r[1] - b).abs() < 1e-9), "{r:?}");
            assert!(labelled_ticks(r, WINDOWED_ERROR_PLOT_PX, Y_LABEL_PX).len() >= 2);
        }
        let v = views(&root);
        let whole: Vec<&str> = v
            .iter()
            .filter(|x| x.1 && !x.0.starts_with("Trial energy turnover") && !x.0.starts_with("Key"))
            .map(|x| x.0.as_str())
            .collect();
        assert_eq!(whole.len(), 4, "{whole:?}");
        assert!(
            whole[0].starts_with("Rejected trials: 125 of 1000"),
            "{whole:?}"
        );
        assert!(whole.iter().any(|n| n.starts_with("Rest power per trial")));
        assert!(v.iter().any(|(n, wh)| !wh
            && n.starts_with("Net power [W], 40 s at cursor: measured blue")));
        assert!(!v.iter().any(|(n, _)| n.starts_with("Trials (index")));
        // Bars a thousand groups wide are sub-pixel: the per-trial means are points over the
        // whole session instead (the example keeps its bar charts, below).
        let per_trial = |root: &Node| -> Vec<(String, bool)> {
            views(root)
                .into_iter()
                .filter(|(n, _)| n.starts_with("Trial energy turnover"))
                .collect()
        };
        let long = per_trial(&root);
        assert_eq!(long.len(), 2, "{long:?}");
        assert!(
            long.iter()
                .all(|(n, whole)| *whole && !n.ends_with("x: trial"))
        );
        let (window_s, origin) = (None, [0.0; 3]);
        let short = replay_layout(&joints, LayoutParts { window_s, ..parts }, origin);
        assert!(matches!(short, Node::Container { window_s: None, .. }));
        assert!(views(&short).iter().all(|(_, wh)| !wh));
        let bars = per_trial(&short);
        assert!(bars.len() == 2 && bars.iter().all(|(n, _)| n.ends_with("x: trial")));
        let track = |v: &(String, bool)| v.0.starts_with("Trials (index");
        assert!(views(&short).iter().any(track));
    }

    /// A long session's Joints and Loss terms tabs (their plots show no legend) carry a colour
    /// key beside their grid: the per-trial shares over the whole session on −110…110 % (the
    /// viewer labels −100, 0 and 100: a step of 10 spans 15 px of a 330 px plot, under the 20 px
    /// a label needs), the legend top right over time after the session's end, as wide as its
    /// longest name (40 px + 7.5 px a character) in a 200 px wide plot. The example's tabs are
    /// the grids alone.
    #[test]
    fn a_long_sessions_joints_and_terms_tabs_carry_a_colour_key() {
        let joints: Vec<String> = (0..7).map(|j| format!("joint_{j}")).collect();
        let parts = |window_s| LayoutParts {
            model: true,
            shares: true,
            window_s,
            span_s: Some([100.0, 1100.0]),
            ..LayoutParts::default()
        };
        for px in [240.0, 330.0, 440.0] {
            assert_eq!(
                labelled_ticks(SHARE_RANGE, px, Y_LABEL_PX),
                [-100.0, 0.0, 100.0]
            );
        }
        for (tab, tree, longest) in [
            ("Joints", "by_joint", "joint_0"),
            ("Loss terms per joint", "by_term", "interaction"),
        ] {
            let mut root = replay_layout(&joints, parts(Some(40.0)), [0.0; 3]);
            root.fit(&|_, _| Some([-40.0, 90.0]));
            let tab_of = |root: &Node| {
                let mut tabs = root.children()[1].children().iter();
                tabs.find(|c| c.name() == tab).cloned().expect(tab)
            };
            let Node::Container {
                kind: ContainerKind::Grid,
                children,
                columns: Some(3),
                ..
            } = tab_of(&root)
            else {
                panic!("{tab}: not a grid of three columns");
            };
            let Some(Node::View {
                contents,
                whole: true,
                legend,
                y_range,
                x_range: Some([a, b]),
                ..
            }) = children.last()
            else {
                panic!("{tab}: no key in the grid");
            };
            assert_eq!(contents, &[format!("+ /model/bars/{tree}/**")], "{tab}");
            assert_eq!(*legend, Some(Legend::RightTop), "{tab}");
            assert_eq!(*y_range, Some([-110.0, 110.0]), "{tab}: not refitted");
            let after = (b - 1100.0) / (b - a);
            let legend = (40.0 + 7.5 * longest.len() as f64) / 200.0;
            assert!(*a < 100.0 && after >= legend, "{tab}: {a}..{b}");
            let grid = tab_of(&replay_layout(&joints, parts(None), [0.0; 3]));
            let keys = grid
                .children()
                .iter()
                .filter(|v| v.name().starts_with("Key"));
            assert_eq!(keys.count(), 0, "{tab}");
        }
    }

    /// A diagnosis that found the meter's window drifting plots it in its Diagnosis tab, over
    /// the whole session on its own axis (the linked plots open on a few trials).
    #[test]
    fn a_drifting_meter_window_is_plotted_over_the_session() {
        let joints: Vec<String> = (0..7).map(|j| format!("j{j}")).collect();
        let window = |window_drift| {
            let parts = LayoutParts {
                diagnosis: true,
                window_drift,
                window_s: Some(40.0),
                ..LayoutParts::default()
            };
            let v = views(&replay_layout(&joints, parts, [0.0; 3]));
            v.into_iter().find(|v| v.0.starts_with("Meter window"))
        };
        assert_eq!(window(false), None);
        assert!(
            window(true).is_some_and(|(_, whole)| whole),
            "{:?}",
            window(true)
        );
    }

    #[test]
    fn a_tab_is_found_by_its_name_ignoring_case_or_by_a_unique_start() {
        let view = |name: &str| Node::view("TimeSeries", name, "x", vec![]);
        let tabs = Node::container(
            ContainerKind::Tabs,
            "tabs",
            vec![
                view("Joints"),
                view("Joint limits"),
                view("IMU and trials"),
                view("Diagnosis summary"),
            ],
            vec![],
        );
        assert_eq!(tabs.resolve_tab("Joints").as_deref(), Some("Joints"));
        assert_eq!(tabs.resolve_tab("joints").as_deref(), Some("Joints"));
        assert_eq!(
            tabs.resolve_tab("Diagnosis").as_deref(),
            Some("Diagnosis summary")
        );
        assert_eq!(tabs.resolve_tab("Joint"), None, "two tabs start with it");
        assert_eq!(tabs.resolve_tab("Torque"), None);
    }

    /// Hand-worked cases of the viewer's tick rule: the example's 7 trials on a 45 px track
    /// (spacing of 1: 45/8 < 20 px; of 10: 56 px) and the error plot's ±1.2 W over 183 px.
    #[test]
    fn labelled_step_follows_the_viewer_grid() {
        assert_eq!(labelled_step(8.0, 45.0, Y_LABEL_PX), 10.0);
        assert_eq!(labelled_step(2.4, 183.0, Y_LABEL_PX), 1.0);
        // A step whose spacing is exactly the label spacing is not labelled.
        assert_eq!(labelled_step(1.0, 20.0, Y_LABEL_PX), 10.0);
        assert_eq!(labelled_ticks([-0.5, 6.5], 45.0, Y_LABEL_PX), vec![0.0]);
        assert_eq!(
            labelled_ticks([-0.5, 10.5], 45.0, Y_LABEL_PX),
            vec![0.0, 10.0]
        );
    }

    /// A few trials in a narrow bar chart: the extent reaches the next labelled tick on the
    /// nearer side only (10, not −10).
    #[test]
    fn tick_range_widens_towards_the_nearer_tick() {
        let margins = |[a, b]: [f64; 2]| Some([a - 0.05 * (b - a), b + 0.05 * (b - a)]);
        let (d, r) = tick_range([-0.4, 6.4], 300.0, X_LABEL_PX, &margins).unwrap();
        assert_eq!(d, [-0.4, 10.0]);
        assert_eq!(labelled_ticks(r, 300.0, X_LABEL_PX).len(), 2);
        // Already readable: unchanged.
        let (d, _) = tick_range([-0.4, 30.4], 300.0, X_LABEL_PX, &margins).unwrap();
        assert_eq!(d, [-0.4, 30.4]);
    }

    #[test]
    fn queries_match_paths_with_or_without_the_leading_slash() {
        assert!(query_includes("+ /joints/elbow/q", "/", "joints/elbow/q"));
        assert!(!query_includes(
            "+ /joints/elbow/q",
            "/",
            "joints/elbow/q_cmd"
        ));
        assert!(query_includes(
            "+ /model/bars/**",
            "/",
            "model/bars/by_joint/elbow"
        ));
        assert!(!query_includes("+ /model/bars/**", "/", "model/barsx"));
        assert!(query_includes(
            "$origin/**",
            "diagnosis/torque",
            "diagnosis/torque/elbow"
        ));
        assert!(!query_includes("- /joints/**", "/", "joints/elbow/q"));
    }
}
