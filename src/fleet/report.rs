//! The fleet report: `fleet.md` (groups, drifts, robots differing from the fleet),
//! `fleet.json` (the same, for programs) and `fleet.png` (the flagged parameters per robot over
//! time, with their standard errors and the fitted lines).

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Result;
use plotters::prelude::*;

use super::FleetFit;
use super::drift::{Drift, Point, Trend};
use crate::plot::{FONT, padded_range, plot_err, write_png};
use crate::power::PowerModel;

/// A parameter's name with its joint, e.g. `d3 (left_elbow_joint)`.
pub fn param_label(p: usize, joints: &[String]) -> String {
    let name = PowerModel::param_name(p);
    match (p < 4 * crate::N_JOINTS).then(|| joints.get(p % crate::N_JOINTS)) {
        Some(Some(j)) => format!("{name} ({j})"),
        _ => name,
    }
}

/// A markdown section `title` with a table of `rows` under `header` (comma-separated; a row
/// "none" when empty). Each row is one cell of the row's cells joined by ` | `.
fn table(s: &mut String, title: &str, header: &str, rows: impl Iterator<Item = Vec<String>>) {
    let header: Vec<&str> = header.split(',').collect();
    let _ = write!(s, "\n## {title}\n\n");
    let mut rows = rows.peekable();
    let none = rows.peek().is_none().then(|| vec!["none".to_string()]);
    crate::plot::table(s, &header, rows.chain(none));
}

/// The markdown report.
pub fn markdown(fit: &FleetFit, drift: Option<&Drift>, joints: &[String]) -> String {
    let mut s = String::from("# Fleet power models\n\n");
    let by: Vec<&str> = fit.by.iter().map(|k| k.name()).collect();
    let _ = writeln!(
        s,
        "{} groups by {}. Filters per group as identification applies them (IMU σ_ω, then 3σ residual passes).\n",
        fit.groups.len(),
        by.join(", ")
    );
    let header = by.join(",") + ",rows,used,trials,rejected IMU / 3σ,R²,RMSE [W],note";
    let groups = fit.groups.iter().map(|g| {
        let (imu, rejected) = g.rejected_by();
        let (key, note) = (g.key.join(" | "), g.error.as_deref().unwrap_or(""));
        let (rows, used, trials) = (g.rows, g.rows_used, g.trials);
        let (r2, rmse) = (g.r2, g.rmse);
        vec![format!(
            "{key} | {rows} | {used} | {trials} | {imu} / {rejected} | {r2:.4} | {rmse:.3} | {note}"
        )]
    });
    table(&mut s, "Groups", &header, groups);
    let Some(d) = drift else {
        s.push_str("\nNo drift analysis: it needs `--by` with robot and a period (day, week or session).\n");
        return s;
    };
    let drifts = d.drifting().map(|t| {
        let (first, last) = (t.points.first(), t.points.last());
        let span = last.map_or(0.0, |p| p.t_weeks) - first.map_or(0.0, |p| p.t_weeks);
        let (robot, param) = (&t.robot, param_label(t.param, joints));
        let (level, level_se, slope, slope_se, z) = (t.level, t.level_se, t.slope, t.slope_se, t.z);
        let change = 100.0 * slope * span / level;
        vec![format!("{robot} | {param} | {level:.4} ± {level_se:.4} | {slope:+.4} ± {slope_se:.4} | {z:+.1} | {change:+.1} %")]
    });
    let title = format!("Drifts (slope beyond {} calibrated standard errors)", d.z);
    let header = "robot,parameter,level at start,slope per week,z,change over the periods";
    table(&mut s, &title, header, drifts);
    let levels = d.outliers.iter().map(|o| {
        let (robot, param) = (&o.robot, param_label(o.param, joints));
        let (level, fleet, z) = (o.level, o.fleet_level, o.z);
        vec![format!(
            "{robot} | {param} | {level:.4} | {fleet:.4} | {z:+.1}"
        )]
    });
    let title = format!(
        "Robots differing from the fleet (level at start beyond {} calibrated standard errors)",
        d.z
    );
    table(
        &mut s,
        &title,
        "robot,parameter,level,other robots,z",
        levels,
    );
    s.push_str("\n![flagged parameters per robot over time](fleet.png)\n");
    s
}

/// The parameters the figure and the recording show: each flagged one (up to 6), else the
/// first trend's; with the robots flagged on each.
pub fn shown_params(drift: &Drift) -> Vec<(usize, Vec<&str>)> {
    let flagged = |p: usize| -> Vec<&str> {
        let of = drift.trends.iter().filter(|t| t.param == p);
        of.filter(|t| drift.is_flagged(p, &t.robot))
            .map(|t| t.robot.as_str())
            .collect()
    };
    let mut params: Vec<usize> = (drift.drifting().map(|t| t.param))
        .chain(drift.outliers.iter().map(|o| o.param))
        .collect();
    params.sort();
    params.dedup();
    if params.is_empty() {
        params.extend(drift.trends.first().map(|t| t.param));
    }
    params.truncate(6);
    params.into_iter().map(|p| (p, flagged(p))).collect()
}

/// The figure: one panel per [`shown_params`], every robot's periods with ±1 s.e. bars, its
/// fitted line; flagged robots in red.
pub fn figure(path: &Path, drift: &Drift, joints: &[String]) -> Result<()> {
    let params: Vec<usize> = shown_params(drift).iter().map(|(p, _)| *p).collect();
    let cols = params.len().clamp(1, 3);
    let rows = params.len().div_ceil(cols).max(1);
    write_png(path, (480 * cols as u32, 360 * rows as u32), |root| {
        let panels = root.split_evenly((rows, cols));
        for (panel, &p) in panels.iter().zip(&params) {
            let of: Vec<&Trend> = drift.trends.iter().filter(|t| t.param == p).collect();
            let pts = || of.iter().flat_map(|t| &t.points);
            let (x0, x1) = padded_range(pts().map(|q| q.t_weeks), 0.05);
            let (y0, y1) = padded_range(
                pts().flat_map(|q| [q.value - q.std_err, q.value + q.std_err]),
                0.08,
            );
            let mut chart = ChartBuilder::on(panel)
                .caption(param_label(p, joints), (FONT, 18))
                .margin(8)
                .x_label_area_size(32)
                .y_label_area_size(56)
                .build_cartesian_2d(x0..x1, y0..y1)
                .map_err(plot_err)?;
            chart
                .configure_mesh()
                .x_desc("weeks")
                .label_style((FONT, 12))
                .draw()
                .map_err(plot_err)?;
            for t in &of {
                let flagged = drift.is_flagged(p, &t.robot);
                let colour = [RGBColor(120, 120, 120), RED][flagged as usize];
                let bar = |q: &Point| [-1.0, 1.0].map(|k| (q.t_weeks, q.value + k * q.std_err));
                let bars = t
                    .points
                    .iter()
                    .map(|q| PathElement::new(bar(q), colour.mix(0.5)));
                chart.draw_series(bars).map_err(plot_err)?;
                chart
                    .draw_series(
                        t.points
                            .iter()
                            .map(|q| Circle::new((q.t_weeks, q.value), 3, colour.filled())),
                    )
                    .map_err(plot_err)?;
                let (a, b) = (
                    t.points.first().map(|q| q.t_weeks).unwrap_or(0.0),
                    t.points.last().map(|q| q.t_weeks).unwrap_or(0.0),
                );
                let series = chart
                    .draw_series(LineSeries::new(
                        [a, b].map(|x| (x, t.level + t.slope * x)),
                        colour.stroke_width(if flagged { 2 } else { 1 }),
                    ))
                    .map_err(plot_err)?;
                if flagged {
                    series.label(t.robot.clone()).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2))
                    });
                }
            }
            if of.iter().any(|t| drift.is_flagged(p, &t.robot)) {
                chart
                    .configure_series_labels()
                    .label_font((FONT, 12))
                    .background_style(WHITE.mix(0.8))
                    .draw()
                    .map_err(plot_err)?;
            }
        }
        Ok(())
    })
}

/// Write `fleet.md`, `fleet.json` and (with a drift analysis) `fleet.png` into `dir`.
pub fn write(dir: &Path, fit: &FleetFit, drift: Option<&Drift>, joints: &[String]) -> Result<()> {
    use anyhow::Context;
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let by: Vec<&str> = fit.by.iter().map(|k| k.name()).collect();
    let json = serde_json::json!({
        "by": by,
        "params": (0..crate::N_PARAMS).map(PowerModel::param_name).collect::<Vec<_>>(),
        "joint_names": joints,
        "groups": fit.groups,
        "drift": drift,
    });
    crate::util::write_atomic(
        &dir.join("fleet.json"),
        serde_json::to_string_pretty(&json)?.as_bytes(),
    )?;
    crate::util::write_atomic(
        &dir.join("fleet.md"),
        markdown(fit, drift, joints).as_bytes(),
    )?;
    if let Some(d) = drift {
        figure(&dir.join("fleet.png"), d, joints)?;
    }
    Ok(())
}
