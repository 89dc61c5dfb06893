//! Markdown report with PNG figures like the paper's: coefficient bars per joint (b, c, d), predicted
//! against measured net power, one point per row (identification and validation), residual histogram with a
//! fitted normal, and the mean term contributions (mechanical, copper, Coulomb, viscous, interaction).
//!
//! Text is drawn with the DejaVu Sans font shipped in `assets/fonts/` (Bitstream Vera licence, see
//! `assets/fonts/DejaVuSans-LICENSE.txt`), registered with plotters at first use, so figures render the same on
//! every machine. Each file is written to a temporary name in the output directory and renamed into place.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Context, Result, ensure};
use plotters::coord::Shift;
use plotters::coord::ranged1d::SegmentedCoord;
use plotters::coord::types::{RangedCoordf64, RangedCoordusize};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::N_JOINTS;
use crate::lsq::Metrics;
use crate::plot::{FONT, legend, padded_range, plot_err, register_font, table, write_png};
use crate::power::{DatasetMetrics, ModelFile, N_PAIRS, PAIRS, PowerModel, TERM_NAMES, TermMeans};

/// Everything the report shows. Fill what you have; absent parts are left out of the report.
#[derive(Debug, Clone)]
pub struct ReportInput {
    /// Report title.
    pub title: String,
    /// The identified model with its metrics and provenance (rejected trials come from its provenance).
    pub model: ModelFile,
    /// Per-row measured and predicted net power of the identification rows.
    pub identification: Option<PredictionSet>,
    /// Per-row measured and predicted net power of a hold-out session.
    pub validation: Option<PredictionSet>,
    /// Mean term contributions over a dataset.
    pub terms: Option<TermContributions>,
    /// The paper's aggregation comparison: κ(ΦᵀΦ) and R² for per-sample vs trajectory-averaged rows.
    pub aggregation: Vec<AggregationRow>,
    /// Truth parameters when the session is simulated: adds a per-parameter error table.
    pub truth: Option<PowerModel>,
    /// Free-form remarks (one paragraph each).
    pub notes: Vec<String>,
}

/// Measured vs predicted values of one dataset, one entry per row (trajectory or sample).
#[derive(Debug, Clone, PartialEq)]
pub struct PredictionSet {
    /// Dataset name for captions.
    pub label: String,
    /// Measured net power [W].
    pub measured: Vec<f64>,
    /// Predicted net power [W].
    pub predicted: Vec<f64>,
    /// Trial index of each row (empty when the rows are not trials): the parity plot labels
    /// its points with them.
    pub trials: Vec<usize>,
}

/// Mean term contributions over a dataset ([`TERM_NAMES`] order).
#[derive(Debug, Clone, PartialEq)]
pub struct TermContributions {
    /// Dataset name.
    pub dataset: String,
    /// Rows averaged.
    pub rows: usize,
    /// Each category's signed share of the energy turnover [%] ([`crate::power::shares_percent`]).
    pub shares_percent: [f64; 5],
    /// Mean of each category [W], when known.
    pub means_w: Option<[f64; 5]>,
}

impl TermContributions {
    /// From accumulated breakdowns.
    pub fn from_means(dataset: &str, means: &TermMeans) -> Self {
        TermContributions {
            dataset: dataset.to_string(),
            rows: means.count(),
            shares_percent: means.shares_percent(),
            means_w: Some(means.means()),
        }
    }
}

/// One row construction in the aggregation comparison.
#[derive(Debug, Clone, PartialEq)]
pub struct AggregationRow {
    /// e.g. `per-sample` or `trajectory-averaged`.
    pub rows: String,
    /// Number of rows.
    pub n: usize,
    /// κ(ΦᵀΦ).
    pub condition_number: f64,
    /// R² of the constrained fit on these rows.
    pub r2: f64,
}

/// File names of the figures, relative to the report directory.
pub const FIGURES: [&str; 6] = [
    "coefficients.png",
    "fit_identification.png",
    "residuals_identification.png",
    "fit_validation.png",
    "residuals_validation.png",
    "terms.png",
];

/// Write `dir/report.md` and its PNG figures (creating `dir`).
pub fn write_report(dir: &Path, r: &ReportInput) -> Result<()> {
    register_font()?;
    std::fs::create_dir_all(dir)
        .with_context(|| format!("creating report directory {}", dir.display()))?;
    let names = short_joint_names(&r.model.joint_names);
    let mut md = String::new();
    let _ = writeln!(md, "# {}\n", r.title);
    write_result(&mut md, r, &names);
    let _ = writeln!(md, "# Supporting tables\n");
    write_provenance(&mut md, &r.model);
    write_metrics(&mut md, r);
    write_parameters(&mut md, r, &names);
    write_png(&dir.join(FIGURES[0]), (900, 900), |root| {
        draw_coefficients(root, &r.model, &names)
    })?;
    let _ = writeln!(md, "![Coefficients b, c, d per joint]({})\n", FIGURES[0]);
    for (set, fit_png, res_png) in [
        (&r.identification, FIGURES[1], FIGURES[2]),
        (&r.validation, FIGURES[3], FIGURES[4]),
    ] {
        let Some(set) = set else { continue };
        ensure!(
            set.measured.len() == set.predicted.len() && !set.measured.is_empty(),
            "prediction set `{}` needs equally many measured and predicted values (got {} and {})",
            set.label,
            set.measured.len(),
            set.predicted.len()
        );
        let m = Metrics::compute(&set.measured, &set.predicted);
        write_png(&dir.join(fit_png), (760, 700), |root| {
            draw_parity(root, set, &m)
        })?;
        write_png(&dir.join(res_png), (700, 480), |root| {
            draw_residuals(root, set, &m)
        })?;
        let _ = writeln!(md, "## Measured vs predicted: {}\n", set.label);
        let _ = writeln!(
            md,
            "![Predicted against measured net power, one point per row]({fit_png})\n"
        );
        let _ = writeln!(md, "![Residual histogram with fitted normal]({res_png})\n");
    }
    if let Some(t) = &r.terms {
        write_terms(&mut md, t);
        write_png(&dir.join(FIGURES[5]), (800, 480), |root| {
            draw_terms(root, t)
        })?;
        let _ = writeln!(md, "![Mean term contributions]({})\n", FIGURES[5]);
    }
    write_rejected(&mut md, &r.model);
    for note in &r.notes {
        let _ = writeln!(md, "{note}\n");
    }
    crate::util::write_atomic(&dir.join("report.md"), md.as_bytes())
}

/// `left_shoulder_pitch_joint` → `shoulder pitch`.
fn short_joint_names(names: &[String]) -> Vec<String> {
    names
        .iter()
        .map(|n| {
            let s = n.strip_suffix("_joint").unwrap_or(n);
            let s = s
                .strip_prefix("left_")
                .or_else(|| s.strip_prefix("right_"))
                .unwrap_or(s);
            s.replace('_', " ")
        })
        .collect()
}

fn fmt_num(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "–".to_string()
    }
}

fn fmt_sci(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.2e}")
    } else {
        "∞ / n.a.".to_string()
    }
}

fn write_provenance<'a>(md: &mut String, m: &'a ModelFile) {
    let p = &m.provenance;
    let or_dash = |s: &'a str| if s.is_empty() { "–" } else { s };
    let _ = writeln!(md, "Tool: {}. Created: {}.\n", p.tool, or_dash(&p.created));
    if !p.sessions.is_empty() {
        let _ = writeln!(md, "| session | role | size [bytes] |\n|---|---|---:|");
        for s in &p.sessions {
            let _ = writeln!(md, "| `{}` | {} | {} |", s.path, s.role, s.size_bytes);
        }
        md.push('\n');
    }
    let _ = writeln!(
        md,
        "Target: {}. Rows: {}. Trials segmented {}, used {}, rejected {}.\n",
        or_dash(&p.target),
        or_dash(&p.rows),
        p.trials.segmented,
        p.trials.used,
        p.trials.rejected
    );
    for f in &p.filters {
        let params: Vec<String> = f
            .parameters
            .iter()
            .map(|(k, v)| format!("{k} = {v}"))
            .collect();
        let _ = writeln!(
            md,
            "- filter `{}` ({}): {} trials rejected",
            f.name,
            params.join(", "),
            f.rejected
        );
    }
    if let Some(s) = &p.solver {
        let _ = writeln!(
            md,
            "- solver {}: {} after {} iterations",
            s.method, s.status, s.iterations
        );
    }
    md.push('\n');
}

/// The verdict before the tables: what was identified from how many trials, how well it
/// predicts (held out where there is a hold-out), where the power goes, each joint's dominant
/// loss, and how stable the parameters are (their median relative standard error).
fn write_result(md: &mut String, r: &ReportInput, names: &[String]) {
    let p = &r.model.provenance;
    let _ = writeln!(md, "## Result\n");
    let _ = writeln!(
        md,
        "Identified the arm's power model from {} of {} trials ({} rejected by the filters, \
         listed at the end).\n",
        p.trials.used, p.trials.segmented, p.trials.rejected
    );
    let quality = |name: &str, d: &DatasetMetrics| {
        format!(
            "{name} ({}): R² {}, RMSE {} W, MAE {} W over {} rows",
            d.dataset,
            fmt_num(d.fit.r2, 3),
            fmt_num(d.fit.rmse, 2),
            fmt_num(d.fit.mae, 2),
            d.fit.n
        )
    };
    let m = &r.model.metrics;
    let fits: Vec<String> = [
        ("held out", &m.validation),
        ("identification", &m.identification),
    ]
    .into_iter()
    .filter_map(|(name, d)| d.as_ref().map(|d| quality(name, d)))
    .collect();
    if !fits.is_empty() {
        let _ = writeln!(md, "Fit: {}.\n", fits.join("; "));
    }
    if let Some(t) = &r.terms {
        let shares: Vec<String> = TERM_NAMES
            .iter()
            .zip(t.shares_percent)
            .map(|(n, s)| format!("{n} {} %", fmt_num(s, 1)))
            .collect();
        let _ = writeln!(
            md,
            "Where the power goes ({}), each term's share of the energy turnover (the terms' \
             absolute sum): {}. A negative share is energy the term returns (the arm braking; \
             copper below the holding torque at rest).\n",
            t.dataset,
            shares.join(", ")
        );
    }
    let model = r.model.model();
    let dominant: Vec<String> = (0..N_JOINTS)
        .filter_map(|i| {
            let t = model.dominant_term(i)?;
            Some(format!("{} {}", names.get(i)?, t.name()))
        })
        .collect();
    if !dominant.is_empty() {
        let _ = writeln!(md, "Dominant loss per joint: {}.\n", dominant.join(", "));
    }
    if let Some(se) = &r.model.theta_std_err {
        let mut rel: Vec<f64> = se
            .iter()
            .zip(&r.model.theta)
            .filter_map(|(s, v)| s.map(|s| s / v.abs()).filter(|x| x.is_finite()))
            .collect();
        rel.sort_by(f64::total_cmp);
        if let Some(mid) = rel.get(rel.len() / 2) {
            let _ = writeln!(
                md,
                "Stability: median relative standard error of the {} non-zero parameters {} %.\n",
                rel.len(),
                fmt_num(100.0 * mid, 1)
            );
        }
    }
}

/// One dataset's line of the fit-quality table.
fn metrics_row(name: &str, d: &DatasetMetrics) -> Vec<String> {
    let f = &d.fit;
    vec![
        format!("{name} ({})", d.dataset),
        f.n.to_string(),
        fmt_num(f.r2, 3),
        fmt_num(f.rmse, 2),
        fmt_num(f.mae, 2),
        fmt_num(f.bias, 2),
        fmt_num(f.skewness, 2),
        fmt_num(f.kurtosis, 2),
        fmt_sci(d.condition_number),
    ]
}

fn write_metrics(md: &mut String, r: &ReportInput) {
    let _ = writeln!(md, "## Fit quality\n");
    let m = &r.model.metrics;
    let head = [
        "dataset",
        "n",
        "R²",
        "RMSE [W]",
        "MAE [W]",
        "bias [W]",
        "skewness",
        "kurtosis",
        "κ(ΦᵀΦ)",
    ];
    let rows = [
        ("identification", &m.identification),
        ("validation", &m.validation),
    ]
    .into_iter()
    .filter_map(|(name, d)| d.as_ref().map(|d| metrics_row(name, d)));
    table(md, &head, rows);
    let _ = writeln!(
        md,
        "\nbias = mean(predicted − measured); kurtosis is Pearson's (3 for a normal distribution).\n"
    );
    if !r.aggregation.is_empty() {
        let _ = writeln!(md, "### Per-sample vs aggregated rows\n");
        let rows = r.aggregation.iter().map(|a| {
            let (n, k, r2) = (
                a.n.to_string(),
                fmt_sci(a.condition_number),
                fmt_num(a.r2, 3),
            );
            vec![a.rows.clone(), n, k, r2]
        });
        table(md, &["rows", "n", "κ(ΦᵀΦ)", "R²"], rows);
        md.push('\n');
    }
}

fn with_se(v: f64, se: Option<f64>) -> String {
    match se {
        Some(s) => format!("{v:.4} ± {s:.4}"),
        None => format!("{v:.4}"),
    }
}

fn write_parameters(md: &mut String, r: &ReportInput, names: &[String]) {
    let m = r.model.model();
    let se = |p: usize| r.model.std_err(p);
    let _ = writeln!(md, "## Identified parameters\n");
    let head = [
        "joint",
        "a",
        "b [W/(N·m)²]",
        "c [W·s/rad]",
        "d [W·s²/rad²]",
        "dominant",
    ];
    let rows = (0..N_JOINTS).map(|i| {
        let joint = format!("{i} {}", names.get(i).map_or("", |s| s.as_str()));
        let coefs = [m.a[i], m.b[i], m.c[i], m.d[i]];
        let cells = (coefs.iter().enumerate()).map(|(k, &v)| with_se(v, se(k * N_JOINTS + i)));
        let dom = m.dominant_term(i).map_or("–", |t| t.name()).to_string();
        std::iter::once(joint).chain(cells).chain([dom]).collect()
    });
    table(md, &head, rows);
    let _ = writeln!(
        md,
        "\nPairwise interaction e_ij [W·s²/rad²] (± standard error when estimated):\n"
    );
    let per_col = N_PAIRS.div_ceil(3);
    let rows = (0..per_col).map(|row| {
        (0..3)
            .filter_map(|col| {
                let k = col * per_col + row;
                let (i, j) = PAIRS.get(k)?;
                Some([format!("({i},{j})"), with_se(m.e[k], se(4 * N_JOINTS + k))])
            })
            .flatten()
            .collect()
    });
    table(md, &["pair", "e_ij", "pair", "e_ij", "pair", "e_ij"], rows);
    md.push('\n');
    if let Some(truth) = &r.truth {
        let (est, tv) = (m.to_vector(), truth.to_vector());
        let _ = writeln!(md, "### Recovery of the truth parameters\n");
        let rows = (0..est.len()).map(|p| {
            let name = PowerModel::param_name(p).to_string();
            let (t, e) = (tv[p], est[p]);
            vec![
                name,
                format!("{t:.4}"),
                format!("{e:.4}"),
                format!("{:+.4}", e - t),
            ]
        });
        table(md, &["parameter", "truth", "estimate", "error"], rows);
        let worst = est
            .iter()
            .zip(&tv)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let _ = writeln!(md, "\nLargest absolute error: {worst:.4}.\n");
    }
}

fn write_terms(md: &mut String, t: &TermContributions) {
    let _ = writeln!(
        md,
        "## Term contributions ({}, {} rows)\n",
        t.dataset, t.rows
    );
    let rows = TERM_NAMES.iter().enumerate().map(|(k, name)| {
        let mean = t
            .means_w
            .map_or("–".to_string(), |m| format!("{:.3}", m[k]));
        vec![name.to_string(), mean, fmt_num(t.shares_percent[k], 1)]
    });
    table(md, &["term", "mean [W]", "share [%]"], rows);
    md.push('\n');
}

fn write_rejected(md: &mut String, m: &ModelFile) {
    let rej = &m.provenance.rejected_trials;
    if rej.is_empty() {
        return;
    }
    let _ = writeln!(md, "## Rejected trials ({})\n", rej.len());
    let fold = rej.len() > FOLD_ROWS;
    if fold {
        let _ = writeln!(
            md,
            "<details><summary>{} rejected trials</summary>\n",
            rej.len()
        );
    }
    let rows = rej.iter().map(|t| {
        let session = (m.provenance.sessions.get(t.session))
            .map_or_else(|| t.session.to_string(), |s| s.path.clone());
        vec![
            format!("`{session}`"),
            t.trial.to_string(),
            t.reason.name().to_string(),
            fmt_num(t.statistic, 3),
            fmt_num(t.threshold, 3),
            t.to_string(),
        ]
    });
    let head = [
        "session",
        "trial",
        "filter",
        "statistic",
        "threshold",
        "reason",
    ];
    table(md, &head, rows);
    md.push('\n');
    if fold {
        md.push_str("</details>\n\n");
    }
}

/// Rows of a long table shown before it is folded behind its count.
const FOLD_ROWS: usize = 10;

fn draw_coefficients(
    root: &DrawingArea<BitMapBackend<'_>, Shift>,
    model: &ModelFile,
    names: &[String],
) -> Result<()> {
    let m = model.model();
    let se = |p: usize| model.std_err(p).unwrap_or(0.0);
    let titles = [
        "b_i copper loss [W/(N·m)²]",
        "c_i Coulomb friction [W·s/rad]",
        "d_i viscous friction [W·s²/rad²]",
    ];
    let areas = root.split_evenly((3, 1));
    for (k, (area, values)) in areas.iter().zip([m.b, m.c, m.d]).enumerate() {
        let (offset, color) = ((k + 1) * N_JOINTS, TERM_COLORS[k + 1]);
        let top = (0..N_JOINTS)
            .map(|i| values[i] + se(offset + i))
            .fold(0.0f64, f64::max)
            .max(1e-3)
            * 1.15;
        let bars: Vec<(&str, f64, RGBColor)> = (0..N_JOINTS)
            .map(|i| (names.get(i).map_or("", String::as_str), values[i], color))
            .collect();
        let look = BarLook(20, 8, 28, 13, 18);
        let mut chart = bar_chart(area, titles[k], look, 0.0..top, None, &bars)?;
        chart
            .draw_series((0..N_JOINTS).filter(|&i| se(offset + i) > 0.0).map(|i| {
                let s = se(offset + i);
                let x = SegmentValue::CenterOf(i);
                PathElement::new(
                    vec![(x.clone(), (values[i] - s).max(0.0)), (x, values[i] + s)],
                    BLACK.stroke_width(2),
                )
            }))
            .map_err(plot_err)?;
        chart
            .draw_series((0..N_JOINTS).map(|i| {
                let y = values[i] + se(offset + i) + top * 0.02;
                Text::new(
                    format!("{:.3}", values[i]),
                    (SegmentValue::CenterOf(i), y),
                    centered_above(13),
                )
            }))
            .map_err(plot_err)?;
    }
    Ok(())
}

/// The terms' colours ([`TERM_NAMES`] order): mechanical, copper, Coulomb, viscous, interaction.
const TERM_COLORS: [RGBColor; 5] = [
    RGBColor(150, 150, 150),
    RGBColor(214, 96, 77),
    RGBColor(67, 147, 195),
    RGBColor(90, 174, 97),
    RGBColor(153, 112, 171),
];

/// How a bar chart of the report is laid out: caption and tick label size [px], margin, height of
/// the x label area, and each bar's gap to the edges of its slot [px].
struct BarLook(u32, u32, u32, u32, u32);

/// A chart over `y` with one bar per (name, height, colour) from zero, each named below its slot.
type BarChart<'a, 'b> = ChartContext<
    'a,
    BitMapBackend<'b>,
    Cartesian2d<SegmentedCoord<RangedCoordusize>, RangedCoordf64>,
>;
fn bar_chart<'a, 'b>(
    area: &'a DrawingArea<BitMapBackend<'b>, Shift>,
    caption: &str,
    look: BarLook,
    y: std::ops::Range<f64>,
    y_desc: Option<&str>,
    bars: &[(&str, f64, RGBColor)],
) -> Result<BarChart<'a, 'b>> {
    let (n, BarLook(caption_px, margin, x_area, label_px, gap)) = (bars.len(), look);
    let mut chart = ChartBuilder::on(area)
        .caption(caption, (FONT, caption_px))
        .margin(margin)
        .x_label_area_size(x_area)
        .y_label_area_size(60)
        .build_cartesian_2d((0..n - 1).into_segmented(), y)
        .map_err(plot_err)?;
    let name = |v: &SegmentValue<usize>| match v {
        SegmentValue::CenterOf(i) => bars.get(*i).map_or("", |b| b.0).to_string(),
        _ => String::new(),
    };
    let mut mesh = chart.configure_mesh();
    (mesh.disable_x_mesh().x_labels(n))
        .x_label_formatter(&name)
        .label_style((FONT, label_px));
    if let Some(desc) = y_desc {
        mesh.y_desc(desc);
    }
    mesh.draw().map_err(plot_err)?;
    chart
        .draw_series(bars.iter().enumerate().map(|(i, &(_, v, color))| {
            let span = [
                (SegmentValue::Exact(i), 0.0),
                (SegmentValue::Exact(i + 1), v),
            ];
            let mut bar = Rectangle::new(span, color.filled());
            bar.set_margin(0, 0, gap, gap);
            bar
        }))
        .map_err(plot_err)?;
    Ok(chart)
}

/// Text anchored at its bottom centre, to label the top of a bar.
fn centered_above(size: u32) -> TextStyle<'static> {
    TextStyle::from((FONT, size).into_font()).pos(Pos::new(HPos::Center, VPos::Bottom))
}

/// Most points a parity plot labels with their trial ids.
const MAX_LABELLED_POINTS: usize = 80;

/// Predicted against measured, one point per row, with the y = x line: rows stay separate points
/// (no line joins rows that were sorted by value, which invents a curve and hides which row is
/// off).
fn draw_parity(
    root: &DrawingArea<BitMapBackend<'_>, Shift>,
    set: &PredictionSet,
    m: &Metrics,
) -> Result<()> {
    let (lo, hi) = padded_range(set.measured.iter().chain(&set.predicted).copied(), 0.05);
    let n = set.measured.len();
    let caption = format!(
        "{}: {} rows — R² = {}, RMSE = {} W",
        set.label,
        n,
        fmt_num(m.r2, 3),
        fmt_num(m.rmse, 2)
    );
    let mut chart = ChartBuilder::on(root)
        .caption(caption, (FONT, 20))
        .margin(12)
        .x_label_area_size(44)
        .y_label_area_size(64)
        .build_cartesian_2d(lo..hi, lo..hi)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("measured net power [W]")
        .y_desc("predicted net power [W]")
        .label_style((FONT, 14))
        .draw()
        .map_err(plot_err)?;
    chart
        .draw_series(LineSeries::new(
            [(lo, lo), (hi, hi)],
            RGBColor(120, 120, 120).stroke_width(1),
        ))
        .map_err(plot_err)?
        .label("predicted = measured")
        .legend(|(x, y)| {
            PathElement::new(
                vec![(x, y), (x + 20, y)],
                RGBColor(120, 120, 120).stroke_width(1),
            )
        });
    let radius = if n > 300 { 2 } else { 4 };
    chart
        .draw_series(
            set.measured
                .iter()
                .zip(&set.predicted)
                .map(|(&x, &y)| Circle::new((x, y), radius, BLUE.stroke_width(1))),
        )
        .map_err(plot_err)?
        .label(if set.trials.len() == n {
            "one trajectory (labelled with its trial)"
        } else {
            "one row (trajectory or reading)"
        })
        .legend(|(x, y)| Circle::new((x + 10, y), 4, BLUE.stroke_width(1)));
    // Trial ids beside their points, as long as the labels stay readable.
    if set.trials.len() == n && n <= MAX_LABELLED_POINTS {
        chart
            .draw_series(
                set.measured
                    .iter()
                    .zip(&set.predicted)
                    .zip(&set.trials)
                    .map(|((&x, &y), t)| {
                        EmptyElement::at((x, y))
                            + Text::new(
                                format!("{t}"),
                                (5, -14),
                                (FONT, 12).into_font().color(&BLACK),
                            )
                    }),
            )
            .map_err(plot_err)?;
    }
    legend(&mut chart, Some(SeriesLabelPosition::UpperLeft), 15)
}

fn draw_residuals(
    root: &DrawingArea<BitMapBackend<'_>, Shift>,
    set: &PredictionSet,
    m: &Metrics,
) -> Result<()> {
    let res: Vec<f64> = set
        .measured
        .iter()
        .zip(&set.predicted)
        .map(|(y, p)| y - p)
        .filter(|v| v.is_finite())
        .collect();
    let n = res.len().max(1) as f64;
    let mean = res.iter().sum::<f64>() / n;
    let sd = (res.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / n)
        .sqrt()
        .max(1e-9);
    let (lo, hi) = padded_range(
        res.iter()
            .copied()
            .chain([mean - 3.5 * sd, mean + 3.5 * sd]),
        0.05,
    );
    let bins = ((n.sqrt().ceil() as usize).clamp(8, 50)) as f64;
    let width = (hi - lo) / bins;
    let mut counts = vec![0usize; bins as usize];
    for r in &res {
        let k = (((r - lo) / width) as usize).min(counts.len() - 1);
        counts[k] += 1;
    }
    let pdf_peak = n * width / (sd * (2.0 * std::f64::consts::PI).sqrt());
    let top = (counts.iter().copied().max().unwrap_or(1) as f64).max(pdf_peak) * 1.15;
    let caption = format!(
        "{} residuals (measured − predicted): skewness {}, kurtosis {}",
        set.label,
        fmt_num(m.skewness, 2),
        fmt_num(m.kurtosis, 2)
    );
    let mut chart = ChartBuilder::on(root)
        .caption(caption, (FONT, 16))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(lo..hi, 0.0..top)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("residual [W]")
        .y_desc("rows")
        .y_label_formatter(&|y| format!("{y:.0}"))
        .label_style((FONT, 14))
        .draw()
        .map_err(plot_err)?;
    chart
        .draw_series(counts.iter().enumerate().map(|(k, &c)| {
            let x0 = lo + k as f64 * width;
            Rectangle::new(
                [(x0, 0.0), (x0 + width, c as f64)],
                RGBColor(120, 150, 200).filled(),
            )
        }))
        .map_err(plot_err)?
        .label("residuals")
        .legend(|(x, y)| {
            Rectangle::new(
                [(x, y - 5), (x + 15, y + 5)],
                RGBColor(120, 150, 200).filled(),
            )
        });
    let curve = (0..=200).map(|k| {
        let x = lo + (hi - lo) * k as f64 / 200.0;
        (x, pdf_peak * (-0.5 * ((x - mean) / sd).powi(2)).exp())
    });
    chart
        .draw_series(LineSeries::new(curve, RED.stroke_width(2)))
        .map_err(plot_err)?
        .label(format!("normal μ = {mean:.2} W, σ = {sd:.2} W"))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED.stroke_width(2)));
    legend(&mut chart, Some(SeriesLabelPosition::UpperRight), 14)
}

fn draw_terms(root: &DrawingArea<BitMapBackend<'_>, Shift>, t: &TermContributions) -> Result<()> {
    let shares = t.shares_percent;
    let (lo, hi) = padded_range(shares.iter().copied().chain([0.0]), 0.05);
    let (lo, hi) = (lo.min(0.0), hi * 1.1);
    let bars: Vec<(&str, f64, RGBColor)> = (TERM_NAMES.iter().zip(shares).zip(TERM_COLORS))
        .map(|((name, s), c)| (*name, if s.is_finite() { s } else { 0.0 }, c))
        .collect();
    let caption = format!("Mean term contributions ({}, {} rows)", t.dataset, t.rows);
    let y_desc = Some("share of the energy turnover [%]");
    let look = BarLook(18, 12, 34, 14, 25);
    let mut chart = bar_chart(root, &caption, look, lo..hi, y_desc, &bars)?;
    chart
        .draw_series(shares.iter().enumerate().map(|(k, &s)| {
            let y = if s.is_finite() { s.max(0.0) } else { 0.0 };
            let at = (SegmentValue::CenterOf(k), y + (hi - lo) * 0.01);
            Text::new(format!("{} %", fmt_num(s, 1)), at, centered_above(15))
        }))
        .map_err(plot_err)?;
    Ok(())
}
