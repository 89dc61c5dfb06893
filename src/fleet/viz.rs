//! The fleet as a Rerun recording: every robot's parameters per period on the `time` timeline
//! (entity `fleet/<parameter>/<robot>`, one plot per parameter holds the fleet), flagged
//! drifts and robots differing from the fleet as text log entries at their last period and in
//! red, and the markdown report as a document. It opens on one plot per flagged parameter
//! (titled with the robots flagged on it), the flags and the report.

use std::path::Path;

use anyhow::Result;
use rerun::blueprint::components::ContainerKind;
use rerun::{Color, Scalars, SeriesPoints, TextDocument, TextLog};

use super::drift::Drift;
use super::report::{param_label, shown_params};
use crate::power::PowerModel;
use crate::viz::{ChunkWriter, Sink, open_stream};
use crate::viz::{Legend, Node, send_blueprint};

/// Row-id namespace of the fleet writer (see [`ChunkWriter`]).
const FLEET_NAMESPACE: u64 = 0x0F1E_0000_0000_0000;

/// The layout: the shown parameters' plots in a grid over the flags and the report.
fn layout(drift: &Drift, joints: &[String]) -> Node {
    let plots = shown_params(drift).into_iter().map(|(p, robots)| {
        let flagged = match robots.is_empty() {
            true => "nothing flagged".to_string(),
            false => format!("flagged: {}", robots.join(", ")),
        };
        let name = format!("{} — {flagged}", param_label(p, joints));
        let origin = format!("fleet/{}", PowerModel::param_name(p));
        Node::view("TimeSeries", name, origin, vec![]).with_legend(Legend::Hidden)
    });
    let plots = Node::group(
        ContainerKind::Grid,
        "Flagged parameters",
        plots.collect(),
        vec![],
    );
    let text = vec![
        Node::view("TextLog", "Flags", "fleet/flags", vec![]),
        Node::view("TextDocument", "Report", "fleet/report", vec![]),
    ];
    let text = Node::container(ContainerKind::Horizontal, "Flags and report", text, vec![]);
    Node::container(
        ContainerKind::Vertical,
        "Fleet",
        vec![plots, text],
        vec![2.0, 1.0],
    )
}

/// Write `path` (`.rrd`) from a drift analysis and the report's markdown.
pub fn write_rrd(path: &Path, drift: &Drift, joints: &[String], markdown: &str) -> Result<()> {
    let id = format!(
        "fleet-{:016x}",
        crate::read::fingerprint::stable_hash(&[markdown.as_bytes()])
    );
    let out = open_stream("g1viz-fleet", &id, &Sink::Save(path.to_path_buf()), &[])?;
    send_blueprint(out.stream(), &layout(drift, joints))?;
    let start = drift.t0_ns.max(0) as u64;
    let mut w = ChunkWriter::new(out.stream(), FLEET_NAMESPACE, start);
    const WEEK_S: f64 = 7.0 * 86_400.0;
    for t in &drift.trends {
        let flagged = drift.is_flagged(t.param, &t.robot);
        let entity = format!("fleet/{}/{}", PowerModel::param_name(t.param), t.robot);
        let colour = match flagged {
            true => Color::from_rgb(220, 40, 40),
            false => Color::from_rgb(110, 110, 110),
        };
        w.send_static(
            &entity,
            &SeriesPoints::new()
                .with_names([t.robot.as_str()])
                .with_colors([colour])
                .with_marker_sizes([if flagged { 4.0f32 } else { 2.5 }]),
        )?;
        let times: Vec<f64> = t.points.iter().map(|p| p.t_weeks * WEEK_S).collect();
        let values: Vec<f64> = t.points.iter().map(|p| p.value).collect();
        w.note_values(&entity, &values);
        w.send_columns(
            &entity,
            &times,
            Scalars::new(values).columns_of_unit_batches()?,
        )?;
    }
    for (t_weeks, text) in drift.flags(joints) {
        let log = TextLog::new(text).with_level("WARN");
        w.send_row("fleet/flags", t_weeks * WEEK_S, &log)?;
    }
    w.send_static("fleet/report", &TextDocument::from_markdown(markdown))?;
    out.finish()
}
