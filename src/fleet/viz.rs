//! The fleet as a Rerun recording: every robot's parameters per period on the `time` timeline
//! (entity `fleet/<parameter>/<robot>`, one plot per parameter holds the fleet), flagged
//! drifts and robots differing from the fleet as text log entries at their last period and in
//! red, and the markdown report as a document.

use std::path::Path;

use anyhow::Result;
use rerun::{Color, Scalars, SeriesPoints, TextDocument, TextLog};

use super::drift::Drift;
use crate::power::PowerModel;
use crate::viz::{ChunkWriter, Sink, open_stream};

/// Row-id namespace of the fleet writer (see [`ChunkWriter`]).
const FLEET_NAMESPACE: u64 = 0x0F1E_0000_0000_0000;

/// Write `path` (`.rrd`) from a drift analysis and the report's markdown.
pub fn write_rrd(path: &Path, drift: &Drift, joints: &[String], markdown: &str) -> Result<()> {
    let id = format!(
        "fleet-{:016x}",
        crate::read::fingerprint::stable_hash(&[markdown.as_bytes()])
    );
    let out = open_stream("g1viz-fleet", &id, &Sink::Save(path.to_path_buf()), &[])?;
    let start = drift.t0_ns.max(0) as u64;
    let mut w = ChunkWriter::new(out.stream(), FLEET_NAMESPACE, start);
    const WEEK_S: f64 = 7.0 * 86_400.0;
    for t in &drift.trends {
        let flagged = t.drifting
            || drift
                .outliers
                .iter()
                .any(|o| o.param == t.param && o.robot == t.robot);
        let entity = format!("fleet/{}/{}", PowerModel::param_name(t.param), t.robot);
        let colour = if flagged {
            Color::from_rgb(220, 40, 40)
        } else {
            Color::from_rgb(110, 110, 110)
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
