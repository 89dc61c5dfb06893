//! The fleet as a Rerun recording: every robot's parameters per period on the `time` timeline
//! (entity `fleet/<parameter>/<robot>`, one plot per parameter holds the fleet), flagged
//! drifts and robots differing from the fleet as text log entries at their last period and in
//! red, and the markdown report as a document. It opens on one plot per flagged parameter
//! (titled with the robots flagged on it), the flags and the report.

use std::collections::BTreeSet;
use std::path::Path;

use anyhow::Result;
use rerun::blueprint::components::ContainerKind;
use rerun::{Color, RecordingInfo, Scalars, SeriesLines, SeriesPoints, TextDocument, TextLog};

use super::drift::Drift;
use super::report::{param_label, shown_params};
use crate::power::PowerModel;
use crate::viz::{ChunkWriter, Sink, open_stream};
use crate::viz::{Legend, Node, send_blueprint};

const DAY_S: f64 = 86_400.0;
const WEEK_S: f64 = 7.0 * DAY_S;

/// Row-id namespace of the fleet writer (see [`ChunkWriter`]).
const FLEET_NAMESPACE: u64 = 0x0F1E_0000_0000_0000;

/// The layout: the shown parameters' plots in a grid over the flags and the report, each plot
/// over every period (half a day to spare on either side: points on the edge were cut).
fn layout(drift: &Drift, joints: &[String]) -> Node {
    let last = drift
        .trends
        .iter()
        .flat_map(|t| &t.points)
        .map(|p| p.t_weeks);
    let last = last.fold(0.0, f64::max) * WEEK_S;
    let plots = shown_params(drift).into_iter().map(|(p, robots)| {
        let flagged = match robots.is_empty() {
            true => "nothing flagged".to_string(),
            false => format!("flagged: {}", robots.join(", ")),
        };
        let name = format!("{} — {flagged}", param_label(p, joints));
        let origin = format!("fleet/{}", PowerModel::param_name(p));
        let plot = Node::view("TimeSeries", name, origin, vec![]).whole_session();
        plot.with_x_range([-0.5 * DAY_S, last + 0.5 * DAY_S])
            .with_legend(Legend::Hidden)
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
    let robots = drift.trends.iter().map(|t| t.robot.as_str());
    let name = format!("fleet of {} robots", robots.collect::<BTreeSet<_>>().len());
    let start_time = rerun::components::Timestamp(drift.t0_ns.into());
    let info = RecordingInfo::new()
        .with_name(name)
        .with_start_time(start_time);
    w.send_static("__properties", &info)?;
    for t in &drift.trends {
        let flagged = drift.is_flagged(t.param, &t.robot);
        let entity = format!("fleet/{}/{}", PowerModel::param_name(t.param), t.robot);
        let colour =
            [Color::from_rgb(110, 110, 110), Color::from_rgb(220, 40, 40)][flagged as usize];
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
        if flagged {
            // The fitted straight line through the flagged robot's periods.
            let line = format!("{entity}/line");
            let name = format!("{} fitted, {:+.4} per week", t.robot, t.slope);
            let style = SeriesLines::new().with_names([name]).with_colors([colour]);
            w.send_static(&line, &style)?;
            let ends = [times[0], times[times.len() - 1]];
            let values = ends.map(|x| t.level + t.slope * x / WEEK_S);
            w.send_columns(
                &line,
                &ends,
                Scalars::new(values).columns_of_unit_batches()?,
            )?;
        }
    }
    for (t_weeks, text) in drift.flags(joints) {
        let log = TextLog::new(text).with_level("WARN");
        w.send_row("fleet/flags", t_weeks * WEEK_S, &log)?;
    }
    w.send_static("fleet/report", &TextDocument::from_markdown(markdown))?;
    out.finish()
}
