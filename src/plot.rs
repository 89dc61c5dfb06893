//! What the identification, diagnosis and fleet reports share: markdown tables, the bundled
//! font and atomic PNG writing with plotters.

use std::path::Path;
use std::sync::Once;

use anyhow::{Context, Result, ensure};
use plotters::coord::Shift;
use plotters::prelude::*;

/// Font family name the figures use (registered from the bundled DejaVu Sans).
pub(crate) const FONT: &str = "sans-serif";
static FONT_BYTES: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");

/// A bitmap drawing area.
pub(crate) type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// Register the bundled font once (plotters' ab_glyph backend has no system fonts).
pub(crate) fn register_font() -> Result<()> {
    static ONCE: Once = Once::new();
    let mut ok = true;
    ONCE.call_once(|| {
        ok = plotters::style::register_font(FONT, FontStyle::Normal, FONT_BYTES).is_ok()
    });
    ensure!(ok, "the bundled DejaVu Sans font could not be loaded");
    Ok(())
}

/// A plotters error as an anyhow error.
pub(crate) fn plot_err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow::anyhow!("plotting failed: {e:?}")
}

/// Draw a `size` PNG at `path` atomically: into a temporary file beside it, renamed when complete.
pub(crate) fn write_png(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&Area) -> Result<()>,
) -> Result<()> {
    register_font()?;
    // Removed when dropped (an error, a panic) or on a termination signal; renamed on success.
    let tmp = crate::util::temp::TempPath::beside(path, ".png");
    let result = (|| {
        {
            let root = BitMapBackend::new(tmp.path(), size).into_drawing_area();
            root.fill(&WHITE).map_err(plot_err)?;
            draw(&root)?;
            root.present().map_err(plot_err)?;
        }
        tmp.commit(path)
    })();
    result.with_context(|| format!("drawing {}", path.display()))
}

/// The series' legend of a report figure, framed on a light background: at `at` (`None`: the
/// plotters default corner), names in `font_px` text.
pub(crate) fn legend<'a, 'b: 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, BitMapBackend<'b>, CT>,
    at: Option<SeriesLabelPosition>,
    font_px: u32,
) -> Result<()> {
    let mut labels = chart.configure_series_labels();
    if let Some(at) = at {
        labels.position(at);
    }
    labels
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font((FONT, font_px))
        .draw()
        .map_err(plot_err)
}

/// `text` safe inside a markdown table cell: the `|` of `|q̇|`, `|τ|`, `|ω|` would end the cell.
pub(crate) fn md_cell(text: &str) -> String {
    text.replace('|', "\\|")
}

/// A markdown table: the header's cells, then one line per row of cells.
pub(crate) fn table(md: &mut String, head: &[&str], rows: impl IntoIterator<Item = Vec<String>>) {
    let line = |cells: &[String]| format!("| {} |\n", cells.join(" | "));
    let head: Vec<String> = head.iter().map(|h| h.to_string()).collect();
    md.push_str(&line(&head));
    md.push_str(&format!("|{}|\n", vec!["---"; head.len()].join("|")));
    for r in rows {
        md.push_str(&line(&r));
    }
}

/// The range [min, max] of the finite `values`; `None` when there are none.
pub(crate) fn data_range(values: impl IntoIterator<Item = f64>) -> Option<[f64; 2]> {
    let (lo, hi) = values
        .into_iter()
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    lo.is_finite().then_some([lo, hi])
}

/// Axis range of the finite `values`, padded by `pad` of the span; (−1, 1) when there are none.
pub(crate) fn padded_range(values: impl Iterator<Item = f64>, pad: f64) -> (f64, f64) {
    let Some([lo, hi]) = data_range(values) else {
        return (-1.0, 1.0);
    };
    let pad = ((hi - lo) * pad).max(1e-6);
    (lo - pad, hi + pad)
}

/// A tick label for `v` on an axis spanning `span`: the decimals the ticks need (plotters puts
/// at most about ten ticks on an axis, so a step of at least span / 10), and never "-0" or
/// "-0.0": a tick computed a rounding error below zero (−1e-17) reads as zero.
pub(crate) fn tick_label(v: f64, span: f64) -> String {
    let step = span.abs() / 10.0;
    let decimals = if step.is_finite() && step > 0.0 {
        (-step.log10().floor()).clamp(0.0, 12.0) as usize
    } else {
        0
    };
    let s = format!("{v:.decimals$}");
    match s.strip_prefix('-') {
        Some(rest) if rest.chars().all(|c| c == '0' || c == '.') => rest.to_owned(),
        _ => s,
    }
}

#[cfg(test)]
mod tests {
    use super::tick_label;

    #[test]
    fn tick_labels_have_no_negative_zero() {
        // A span of 2 W: ticks every 0.2 W or more, one decimal.
        assert_eq!(tick_label(-0.0, 2.0), "0.0");
        assert_eq!(tick_label(-1e-17, 2.0), "0.0");
        assert_eq!(tick_label(-0.04, 2.0), "0.0");
        assert_eq!(tick_label(-0.2, 2.0), "-0.2");
        assert_eq!(tick_label(0.4, 2.0), "0.4");
        // A span of 40 W: whole watts.
        assert_eq!(tick_label(-1e-17, 40.0), "0");
        assert_eq!(tick_label(-5.0, 40.0), "-5");
        assert_eq!(tick_label(12.0, 40.0), "12");
        // A span of 0.05: ticks every 0.005 or more, three decimals.
        assert_eq!(tick_label(-0.005, 0.05), "-0.005");
        assert_eq!(tick_label(-3e-19, 0.05), "0.000");
        // Degenerate spans still give a label.
        assert_eq!(tick_label(-0.0, 0.0), "0");
        assert_eq!(tick_label(3.0, f64::NAN), "3");
    }
}
