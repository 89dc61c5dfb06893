//! Diagnosis report: `report.md` with tables (torque level, residual breakdowns, hypothesis
//! ranking, final model, unexplained structure), PNG figures (residual by the located regime,
//! hypothesis ranking, per-trial fit before/after, residual over session time, sensor-lag scan)
//! and `diagnosis.json`. Every file is written atomically.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Context, Result};
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use super::Diagnosis;
use super::locate::trial_means;
use crate::plot::{
    Area, FONT, legend, md_cell, padded_range, plot_err, register_font, table, tick_label,
    write_png,
};

/// Figure file names, relative to the report directory.
pub const FIGURES: [&str; 5] = [
    "regime.png",
    "hypotheses.png",
    "before_after.png",
    "residual_time.png",
    "lag_scan.png",
];

/// Draw figure `FIGURES[i]` at `size` into `dir` and link it from `md` under `caption`.
fn figure(
    md: &mut String,
    dir: &Path,
    (i, size): (usize, (u32, u32)),
    caption: &str,
    draw: impl FnOnce(&Area) -> Result<()>,
) -> Result<()> {
    write_png(&dir.join(FIGURES[i]), size, draw)?;
    let _ = writeln!(md, "![{caption}]({})\n", FIGURES[i]);
    Ok(())
}

fn sig(v: f64) -> String {
    if v.abs() >= 0.01 && v.abs() < 1e4 {
        format!("{v:.3}")
    } else {
        format!("{v:.2e}")
    }
}

/// A markdown table with a row per item, built column by column: each column's heading beside
/// how it shows an item (`rows_of(items).col(…)….write(md)`), and a blank line after it.
struct Columns<'a, I: IntoIterator> {
    items: I,
    cols: Vec<(&'a str, Cell<'a, I::Item>)>,
}

/// How a column shows an item.
type Cell<'a, T> = Box<dyn Fn(&T) -> String + 'a>;

/// A table of `items`, no column yet.
fn rows_of<'a, I: IntoIterator>(items: I) -> Columns<'a, I> {
    let cols = Vec::new();
    Columns { items, cols }
}

impl<'a, I: IntoIterator> Columns<'a, I> {
    fn col(mut self, head: &'a str, cell: impl Fn(&I::Item) -> String + 'a) -> Self {
        self.cols.push((head, Box::new(cell)));
        self
    }

    fn write(self, md: &mut String) {
        let head: Vec<&str> = self.cols.iter().map(|c| c.0).collect();
        let cols = &self.cols;
        let rows = (self.items.into_iter()).map(|x| cols.iter().map(|c| c.1(&x)).collect());
        table(md, &head, rows);
        md.push('\n');
    }
}

/// The items' texts, comma-separated.
pub(super) fn joined<T: std::fmt::Display>(items: impl IntoIterator<Item = T>) -> String {
    let texts: Vec<String> = items.into_iter().map(|t| t.to_string()).collect();
    texts.join(", ")
}

/// Write `dir/report.md`, its figures and `dir/diagnosis.json`.
///
/// Sections in order: header, counterpart, torque level, where the model is wrong, hypotheses,
/// the final model, beyond the library, unexplained structure (with the lag scan), trials left
/// out; each section function appends its markdown and writes its figures.
pub fn write_report(dir: &Path, d: &Diagnosis) -> Result<()> {
    register_font()?;
    std::fs::create_dir_all(dir)
        .with_context(|| format!("creating report directory {}", dir.display()))?;
    let mut md = String::new();
    header_section(&mut md, d);
    if let Some(c) = &d.counterpart {
        counterpart_section(&mut md, c);
    }
    if let Some(t) = &d.torque {
        torque_section(&mut md, t);
    }
    where_section(&mut md, dir, d)?;
    hypotheses_section(&mut md, dir, d)?;
    final_section(&mut md, dir, d)?;
    beyond_section(&mut md, d);
    unexplained_section(&mut md, dir, d)?;
    crate::util::write_atomic(&dir.join("report.md"), md.as_bytes())?;
    d.save_json(&dir.join("diagnosis.json"))
}

/// Lines of a verdict section shown before the rest are folded behind their count.
const FOLD_AFTER_LINES: usize = 8;

/// Title, the counts of trials and readings, then the verdict (found, located but not
/// identified, tried and rejected, supporting figures: the summary's sections, long ones
/// folded) before any table.
fn header_section(md: &mut String, d: &Diagnosis) {
    let _ = writeln!(md, "# Sim-to-real diagnosis: {}\n", d.source);
    let _ = writeln!(
        md,
        "{} trials, {} {:?} readings; base model: {}; {} trials left out.\n",
        d.n_trials,
        d.n_readings,
        d.target,
        if d.base_model == "reference" {
            "held at the twin's model"
        } else {
            "refitted on the training trials of each fold"
        },
        d.rejected.len()
    );
    md.push_str(&super::summary::verdict_markdown(
        d,
        "##",
        Some(FOLD_AFTER_LINES),
    ));
    let _ = writeln!(md, "\n# Supporting tables\n");
}

/// Recorded vs URDF torque per joint.
fn torque_section(md: &mut String, t: &super::TorqueComparison) {
    let _ = writeln!(md, "## Torque level (tau_est vs URDF inverse dynamics)\n");
    let _ = writeln!(md, "{} samples.\n", t.n_samples);
    let f = |v: &[f64], j: usize| format!("{:.3}", v[j]);
    rows_of(0..t.rmse_urdf.len())
        .col("joint", |&j| t.joints.get(j).cloned().unwrap_or_default())
        .col("bias [Nm]", |&j| format!("{:+.3}", t.bias_urdf[j]))
        .col("RMS [Nm]", |&j| f(&t.rmse_urdf, j))
        .col("RMS after friction [Nm]", |&j| f(&t.rmse_with_friction, j))
        .col("Fc [Nm]", |&j| f(&t.coulomb_nm, j))
        .col("Fv [Nm·s/rad]", |&j| f(&t.viscous_nms, j))
        .write(md);
}

/// Residual breakdowns of the base model and the regime figure.
fn where_section(md: &mut String, dir: &Path, d: &Diagnosis) -> Result<()> {
    let _ = writeln!(
        md,
        "## Where the model is wrong (held-out residuals of the base model)\n"
    );
    if let Some((by, g)) = &d.worst {
        let _ = writeln!(
            md,
            "Group with the smallest p: **{by} / {}**: mean residual {:+.3} W over {} trials (p = {}{}).\n",
            g.label,
            g.bias_w,
            g.n_trials,
            sig(g.p_value),
            if g.p_value < 1e-3 {
                ""
            } else {
                "; not significant at p < 0.001"
            }
        );
    }
    for b in &d.breakdowns {
        let _ = writeln!(md, "**{}**\n", b.by);
        rows_of(&b.groups)
            .col("group", |g| md_cell(&g.label))
            .col("readings", |g| g.n_rows.to_string())
            .col("trials", |g| g.n_trials.to_string())
            .col("mean residual [W]", |g| format!("{:+.3}", g.bias_w))
            .col("RMS [W]", |g| format!("{:.3}", g.rmse_w))
            .col("p", |g| sig(g.p_value))
            .write(md);
    }
    let caption = "Residual by the located regime";
    figure(md, dir, (0, (900, 500)), caption, |a| draw_regime(a, d))?;
    let worst = (d.worst_trials.iter()).map(|t| format!("{} ({:+.2} W)", t.trial, t.mean_w));
    let _ = writeln!(md, "Worst trials: {}\n", joined(worst));
    Ok(())
}

/// The hypothesis ranking and its figure.
fn hypotheses_section(md: &mut String, dir: &Path, d: &Diagnosis) -> Result<()> {
    let _ = writeln!(
        md,
        "## Hypotheses (scored against the base model; accepted first)\n"
    );
    rows_of(&d.hypotheses)
        .col("rank", |h| h.rank.to_string())
        .col("hypothesis", |h| h.id.clone())
        .col("level", |h| h.level.to_string())
        .col("parameter", |h| {
            params_cell(&h.params[..h.params.len().min(1)])
        })
        .col("p", |h| sig(h.p_value))
        .col("ΔBIC", |h| format!("{:.1}", h.delta_bic))
        .col("held-out RMSE before → after", |h| {
            let (b, a, r) = (h.rmse_before, h.rmse_after, -100.0 * h.rel_improvement);
            format!("{b:.4} → {a:.4} ({r:+.1} %)")
        })
        .col("verdict", |h| h.verdict.clone())
        .write(md);
    let caption = "Held-out improvement per hypothesis";
    figure(md, dir, (1, (900, 450)), caption, |a| draw_hypotheses(a, d))?;
    Ok(())
}

/// The model with the accepted hypotheses, held-out quality and the before/after figures.
fn final_section(md: &mut String, dir: &Path, d: &Diagnosis) -> Result<()> {
    let f = &d.final_model;
    let _ = writeln!(md, "## Model with the accepted hypotheses\n");
    if f.hypotheses.is_empty() {
        let _ = writeln!(md, "No hypothesis accepted: the model is unchanged.\n");
    } else {
        rows_of(&f.params)
            .col("parameter", |p| format!("{} ({})", p.name, p.symbol))
            .col("value", |p| sig(p.value))
            .col("std. error", |p| sig(p.std_err))
            .col("unit", |p| p.unit.clone())
            .write(md);
    }
    let _ = writeln!(
        md,
        "| held out | R² before | R² after | RMSE before [W] | RMSE after [W] |\n|---|---|---|---|---|\n| per reading | {:.4} | {:.4} | {:.4} | {:.4} |\n| per trial | {:.4} | {:.4} | {:.4} | {:.4} |\n",
        f.before.r2,
        f.after.r2,
        f.before.rmse_w,
        f.after.rmse_w,
        f.before_per_trial.r2,
        f.after_per_trial.r2,
        f.before_per_trial.rmse_w,
        f.after_per_trial.rmse_w
    );
    let caption = "Per-trial net power, measured vs predicted before and after";
    figure(md, dir, (2, (1000, 520)), caption, |a| {
        draw_before_after(a, d)
    })?;
    let caption = "Held-out residual over the session, before and after";
    figure(md, dir, (3, (1000, 420)), caption, |a| {
        draw_residual_time(a, d)
    })?;
    Ok(())
}

/// Residual structure no hypothesis explains, the lag-scan figure and the trials left out.
fn unexplained_section(md: &mut String, dir: &Path, d: &Diagnosis) -> Result<()> {
    let _ = writeln!(md, "## Residual structure no hypothesis explains\n");
    let _ = writeln!(
        md,
        "Per-trial mean residual of the final model vs per-trial mean feature (feature made orthogonal to the base regressors), Bonferroni-adjusted.\n"
    );
    rows_of(&d.unexplained)
        .col("feature", |c| md_cell(&c.feature))
        .col("r", |c| format!("{:+.3}", c.r))
        .col("adjusted p", |c| sig(c.p_adjusted))
        .col("significant", |c| {
            (if c.significant { "yes" } else { "no" }).into()
        })
        .col("trials carrying it", |c| joined(&c.trials))
        .write(md);
    if d.lag_scan.len() > 1 {
        let caption = "Sensor-lag scan of the base model";
        figure(md, dir, (4, (800, 420)), caption, |a| draw_lag_scan(a, d))?;
    }
    if !d.rejected.is_empty() {
        let n = d.rejected.len();
        let _ = writeln!(
            md,
            "## Trials left out\n\n<details><summary>{n} trials</summary>\n"
        );
        rows_of(&d.rejected)
            .col("trial", |r| r.trial.to_string())
            .col("reason", |r| md_cell(&r.to_string()))
            .write(md);
        md.push_str("</details>\n\n");
    }
    Ok(())
}

/// The report figures' axis range: the values' padded by 8 %.
fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    padded_range(values, 0.08)
}

/// A chart of the report's x–y figures on `a`: caption, axes over `x` and `y`, labelled mesh.
type XyChart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;
fn xy_chart<'a, 'b>(
    a: &'a Area<'b>,
    caption: &str,
    (x, y): ((f64, f64), (f64, f64)),
    (x_desc, y_desc): (&str, &str),
) -> Result<XyChart<'a, 'b>> {
    let mut chart = ChartBuilder::on(a)
        .caption(caption, (FONT, 18))
        .margin(10)
        .x_label_area_size(36)
        .y_label_area_size(60)
        .build_cartesian_2d(x.0..x.1, y.0..y.1)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style((FONT, 13))
        .draw()
        .map_err(plot_err)?;
    Ok(chart)
}

/// Horizontal bars, one per labelled category (top to bottom in the given order): the labels sit
/// left of the axis at full length, where vertical bars' labels overlapped or were cut.
fn draw_bars(a: &Area, caption: &str, x_desc: &str, bars: &[(String, f64, bool)]) -> Result<()> {
    let n = bars.len().max(1);
    let (lo, hi) = range(bars.iter().map(|b| b.1).chain([0.0]));
    let longest = bars.iter().map(|b| b.0.chars().count()).max().unwrap_or(0);
    let mut chart = ChartBuilder::on(a)
        .caption(caption, (FONT, 18))
        .margin(12)
        .x_label_area_size(44)
        .y_label_area_size((longest as u32 * 7 + 16).clamp(60, 320))
        .build_cartesian_2d(lo..hi, (0..n - 1).into_segmented())
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .disable_y_mesh()
        .y_labels(n)
        .x_desc(x_desc)
        .x_label_formatter(&|v| tick_label(*v, hi - lo))
        .y_label_formatter(&|v| match v {
            // Row 0 at the top.
            SegmentValue::CenterOf(i) => bars
                .get(n - 1 - *i)
                .map(|b| b.0.clone())
                .unwrap_or_default(),
            _ => String::new(),
        })
        .label_style((FONT, 13))
        .draw()
        .map_err(plot_err)?;
    chart
        .draw_series(bars.iter().enumerate().map(|(k, b)| {
            let i = n - 1 - k;
            let color = if b.2 {
                RGBColor(214, 96, 77)
            } else {
                RGBColor(150, 150, 150)
            };
            let mut r = Rectangle::new(
                [
                    (0.0, SegmentValue::Exact(i)),
                    (b.1, SegmentValue::Exact(i + 1)),
                ],
                color.filled(),
            );
            r.set_margin(4, 4, 0, 0);
            r
        }))
        .map_err(plot_err)?;
    Ok(())
}

fn draw_regime(a: &Area, d: &Diagnosis) -> Result<()> {
    let Some((by, _)) = &d.worst else {
        return Ok(());
    };
    let Some(b) = d.breakdowns.iter().find(|b| &b.by == by) else {
        return Ok(());
    };
    let bars: Vec<(String, f64, bool)> = b
        .groups
        .iter()
        .map(|g| (g.label.clone(), g.bias_w, g.p_value < 1e-3))
        .collect();
    draw_bars(
        a,
        &format!("Mean held-out residual by {by} (red: p < 0.001)"),
        "measured − predicted [W]",
        &bars,
    )
}

fn draw_hypotheses(a: &Area, d: &Diagnosis) -> Result<()> {
    let bars: Vec<(String, f64, bool)> = d
        .hypotheses
        .iter()
        .map(|h| {
            (
                format!("{} ({})", h.id, h.level),
                100.0 * h.rel_improvement,
                h.accepted,
            )
        })
        .collect();
    draw_bars(
        a,
        "Held-out RMSE improvement per hypothesis (red: accepted)",
        "improvement [%]",
        &bars,
    )
}

/// Per-trial means of measured, before and after (replay data), sorted by measured.
fn per_trial(d: &Diagnosis) -> Vec<(f64, f64, f64)> {
    let r = &d.replay;
    let n = r.trial.iter().max().map_or(0, |t| t + 1);
    let mean = |v: &[f64]| trial_means(r.trial.iter().copied().zip(v.iter().copied()), n);
    let (m, b, a) = (mean(&r.measured_w), mean(&r.before_w), mean(&r.after_w));
    // The trials with readings.
    let mut v: Vec<(f64, f64, f64)> = (0..n).filter_map(|t| Some((m[t]?, b[t]?, a[t]?))).collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v
}

fn draw_before_after(a: &Area, d: &Diagnosis) -> Result<()> {
    let v = per_trial(d);
    let n = v.len();
    let (lo, hi) = range(v.iter().flat_map(|p| [p.0, p.1, p.2]));
    let f = &d.final_model;
    let caption = format!(
        "Per-trial net power, held out: R² {:.3} → {:.3}, RMSE {:.2} → {:.2} W",
        f.before_per_trial.r2,
        f.after_per_trial.r2,
        f.before_per_trial.rmse_w,
        f.after_per_trial.rmse_w
    );
    let x = (-0.5, (n as f64 - 0.5).max(0.5));
    let descs = ("trial (sorted by measured)", "net power [W]");
    let mut chart = xy_chart(a, &caption, (x, (lo, hi)), descs)?;
    let (blue, grey, red) = (
        BLUE.stroke_width(1),
        GREY.stroke_width(1),
        RED.stroke_width(2),
    );
    let k = |k: usize| k as f64;
    let measured = v
        .iter()
        .enumerate()
        .map(|(i, p)| Circle::new((k(i), p.0), 3, blue));
    (chart.draw_series(measured).map_err(plot_err)?)
        .label("measured")
        .legend(move |(x, y)| Circle::new((x + 10, y), 4, blue));
    let before = v
        .iter()
        .enumerate()
        .map(|(i, p)| Cross::new((k(i), p.1), 3, grey));
    (chart.draw_series(before).map_err(plot_err)?)
        .label("before")
        .legend(move |(x, y)| Cross::new((x + 10, y), 4, grey));
    let after = LineSeries::new(v.iter().enumerate().map(|(i, p)| (k(i), p.2)), red);
    (chart.draw_series(after).map_err(plot_err)?)
        .label("after")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], red));
    legend(&mut chart, Some(SeriesLabelPosition::UpperLeft), 14)
}

/// The "before" series' colour.
const GREY: RGBColor = RGBColor(140, 140, 140);

fn draw_residual_time(a: &Area, d: &Diagnosis) -> Result<()> {
    let r = &d.replay;
    let resid = |p: &[f64]| -> Vec<(f64, f64)> {
        (0..r.t.len())
            .map(|k| (r.t[k], r.measured_w[k] - p[k]))
            .collect()
    };
    let (before, after) = (resid(&r.before_w), resid(&r.after_w));
    let (t0, t1) = range(r.t.iter().copied());
    let (lo, hi) = range(before.iter().chain(&after).map(|p| p.1));
    let caption = "Held-out residual per reading over the session";
    let descs = ("session time [s]", "measured − predicted [W]");
    let mut chart = xy_chart(a, caption, ((t0, t1), (lo, hi)), descs)?;
    for (pts, label, color) in [(before, "before", GREY), (after, "after", RED)] {
        (chart.draw_series(pts.iter().map(|p| Circle::new(*p, 2, color.filled()))))
            .map_err(plot_err)?
            .label(label)
            .legend(move |(x, y)| Circle::new((x + 10, y), 3, color.filled()));
    }
    legend(&mut chart, None, 14)
}

fn draw_lag_scan(a: &Area, d: &Diagnosis) -> Result<()> {
    let pts: Vec<(f64, f64)> = d.lag_scan.iter().map(|p| (p.lag_s, p.rmse_w)).collect();
    let xy = (
        range(pts.iter().map(|p| p.0)),
        range(pts.iter().map(|p| p.1)),
    );
    let caption = "Base-model RMSE vs assumed power-sensor latency";
    let mut chart = xy_chart(a, caption, xy, ("latency [s]", "RMSE [W]"))?;
    chart
        .draw_series(LineSeries::new(pts.iter().copied(), BLUE.stroke_width(2)))
        .map_err(plot_err)?;
    chart
        .draw_series(pts.iter().map(|p| Circle::new(*p, 3, BLUE.filled())))
        .map_err(plot_err)?;
    Ok(())
}

/// The counterpart comparison as markdown tables.
fn counterpart_section(md: &mut String, c: &super::counterpart::CounterpartComparison) {
    let _ = writeln!(
        md,
        "## Counterpart: the twin driven by the same commands ({})\n",
        c.source
    );
    let _ = writeln!(
        md,
        "{} joint samples and {} power readings on the same timeline. Net power, recording − twin: \
         {:.2} W rms, {:+.2} W on average; R² of the twin's power {:.3}.\n",
        c.matched_samples, c.matched_readings, c.power_rms_w, c.power_bias_w, c.power_r2
    );
    rows_of(&c.joints)
        .col("joint", |j| j.joint.clone())
        .col("τ RMS [Nm]", |j| format!("{:.3}", j.tau_rms_nm))
        .col("τ bias [Nm]", |j| format!("{:+.3}", j.tau_bias_nm))
        .col("q RMS [rad]", |j| format!("{:.4}", j.q_rms_rad))
        .write(md);
    if !c.worst_trials.is_empty() {
        rows_of(&c.worst_trials)
            .col("trial", |t| t.trial.to_string())
            .col("readings", |t| t.readings.to_string())
            .col("from [s]", |t| format!("{:.1}", t.t_start))
            .col("to [s]", |t| format!("{:.1}", t.t_end))
            .col("mean net power difference [W]", |t| {
                format!("{:+.2}", t.power_mean_w)
            })
            .write(md);
    }
}

/// Mechanism forms, confounded pairs and discovery beyond the library.
fn beyond_section(md: &mut String, d: &Diagnosis) {
    if !d.forms.is_empty() {
        let _ = writeln!(
            md,
            "## Mechanisms with several forms (same cross-validation)\n"
        );
        rows_of(&d.forms)
            .col("mechanism", |f| f.mechanism.clone())
            .col("winning form", |f| f.winner.clone())
            .col("runner-up", |f| f.runner_up.clone())
            .col("held-out RMSE [W]", |f| {
                format!("{:.3} vs {:.3}", f.rmse_w[0], f.rmse_w[1])
            })
            .col("margin", |f| format!("{:.1} %", 100.0 * f.margin))
            .col("p", |f| sig(f.p_value))
            .col("accepted", |f| match (f.accepted, f.confounded) {
                (true, true) => format!("mechanism only — form: confounded, {}", f.either()),
                (true, false) => "yes".into(),
                _ => "no".into(),
            })
            .write(md);
    }
    if !d.confounded.is_empty() {
        let _ = writeln!(md, "## Confounded\n");
        let tied = " (not told apart: the dropped column's library term stays claimed)";
        rows_of(&d.confounded)
            .col("kept", |c| {
                format!("{}{}", c.kept, if c.tied { tied } else { "" })
            })
            .col("dropped", |c| c.dropped.clone())
            .col("regressor r", |c| format!("{:+.2}", c.correlation))
            .col("p of dropped given kept", |c| sig(c.p_value))
            .col("RMSE change", |c| {
                format!("{:+.2} %", -100.0 * c.rel_change)
            })
            .write(md);
    }
    let Some(r) = &d.discovery else {
        return;
    };
    let _ = writeln!(
        md,
        "## Beyond the library\n\n{} numeric fields read, {} used; {} candidate terms tried; family-wise level {} (Holm).\n",
        r.fields_read,
        r.fields_used,
        r.n_candidates,
        sig(r.alpha)
    );
    rows_of(r.accepted.iter().chain(&r.best_rejected))
        .col("step", |t| t.step.to_string())
        .col("found", |t| t.name.clone())
        .col("form", |t| t.form.clone())
        .col("field(s)", |t| t.fields.join(", "))
        .col("parameter(s)", |t| params_cell(&t.params))
        .col("held-out R² before → after", |t| {
            format!("{:.3} → {:.3}", t.before.r2, t.after.r2)
        })
        .col("p", |t| sig(t.p_value))
        .col("verdict", |t| t.verdict.clone())
        .write(md);
    tied_terms(md, r);
    for n in &r.notes {
        let _ = writeln!(md, "- {n}\n");
    }
    if let Some(rest) = &r.rest {
        rest_section(md, rest);
    }
    excluded_fields(md, r);
}

/// The trials' rest power explained by the fields at rest ([`super::rest`]).
fn rest_section(md: &mut String, r: &super::RestPower) {
    let _ = writeln!(
        md,
        "### Rest power

Each trial's pre-idle power (mean {:.2} W; the net-power model subtracts it, so a load that changes between trials never reaches it) against every field above at rest, each in discovery's shapes: {} candidates, {} trials in {} blocks of {} (held out by block), each tested beside the rail's drift (piecewise linear over every {} trials), Holm. Held-out RMSE {:.3} → {:.3} W.\n",
        r.mean_w,
        r.n_candidates,
        r.n_trials,
        r.n_blocks,
        r.block_trials(),
        super::rest::DRIFT_TRIALS,
        r.rmse_before_w,
        r.rmse_after_w
    );
    rows_of(r.found.iter().chain(&r.best_rejected))
        .col("found", |t| t.name.clone())
        .col("form", |t| t.form.clone())
        .col("parameter(s)", |t| params_cell(&t.params))
        .col("p", |t| sig(t.p_value))
        .col("verdict", |t| t.verdict.clone())
        .col("not told apart from it", |t| t.tied.join(", "))
        .write(md);
}

/// The candidates each found term was not told apart from (its field is confounded), with the
/// evidence: held-out RMSE of both, p that the found term fits better, correlation of what
/// each adds to the prediction.
fn tied_terms(md: &mut String, r: &super::DiscoveryReport) {
    if r.accepted.iter().all(|t| t.tied.is_empty()) {
        return;
    }
    let _ = writeln!(
        md,
        "### Not told apart from a found term (confounded: claimed as one mechanism, the field in doubt)\n"
    );
    let rows = (r.accepted.iter()).flat_map(|t| t.tied.iter().map(move |o| (t.step, o)));
    rows_of(rows)
        .col("step", |(step, _)| step.to_string())
        .col("candidate", |(_, o)| o.name.clone())
        .col("form", |(_, o)| o.form.clone())
        .col("field(s)", |(_, o)| o.fields.join(", "))
        .col("parameter(s)", |(_, o)| params_cell(&o.params))
        .col("held-out RMSE [W] found vs candidate", |(_, o)| {
            format!("{:.3} vs {:.3}", o.rmse_w[0], o.rmse_w[1])
        })
        .col("p (found fits better)", |(_, o)| sig(o.p_value))
        .col("r of contributions", |(_, o)| {
            format!("{:+.3}", o.correlation)
        })
        .col("why a rival", |(_, o)| match o.same_structure {
            true => "same term, another field".into(),
            false => "collinear contribution".into(),
        })
        .write(md);
}

/// The fields discovery left out by a rule on their own data, with the reason.
fn excluded_fields(md: &mut String, r: &super::DiscoveryReport) {
    if r.excluded.is_empty() {
        return;
    }
    let n = r.excluded.len();
    let _ = writeln!(
        md,
        "### Fields left out of discovery ({n})\n\n<details><summary>{n} fields, each with its reason</summary>\n"
    );
    rows_of(&r.excluded)
        .col("field", |e| format!("`{}`", e.name))
        .col("reason", |e| md_cell(&e.reason))
        .write(md);
    md.push_str("</details>\n\n");
}

/// A table cell's parameters: `symbol = value ± s.e. unit` each, `; `-separated.
fn params_cell(params: &[super::Param]) -> String {
    let cells = params.iter().map(|p| {
        let (v, e) = (sig(p.value), sig(p.std_err));
        format!("{} = {v} ± {e} {}", p.symbol, p.unit)
    });
    cells.collect::<Vec<_>>().join("; ")
}
