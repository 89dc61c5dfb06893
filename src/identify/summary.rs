//! Plain-text summaries of an identification and a validation for the terminal.

use super::pipeline::{Identification, SessionSummary};
use super::validate::Validation;
use crate::lsq::Metrics;
use crate::power::{LossTerm, TERM_NAMES};

fn metrics_line(label: &str, m: &Metrics) -> String {
    format!(
        "{label}: n {}, R² {:.4}, RMSE {:.3} W, MAE {:.3} W, bias {:+.3} W, skewness {:.2}, kurtosis {:.2}",
        m.n, m.r2, m.rmse, m.mae, m.bias, m.skewness, m.kurtosis
    )
}

fn shares_line(shares: &[f64; 5]) -> String {
    let parts: Vec<String> = TERM_NAMES
        .iter()
        .zip(shares)
        .map(|(name, v)| format!("{name} {v:.1} %"))
        .collect();
    format!(
        "term shares of the energy turnover (−: below rest, or returned): {}",
        parts.join(", ")
    )
}

fn segmentation_lines(out: &mut Vec<String>, s: &SessionSummary) {
    out.push(format!(
        "{}: {} trials ({} stream), {} stretches not matching the protocol",
        s.source.display(),
        s.segmentation.trials.len(),
        s.segmentation.source,
        s.segmentation.unmatched.len()
    ));
    out.extend(
        s.segmentation
            .unmatched
            .iter()
            .map(|u| format!("  {:.2}–{:.2} s: {}", u.t0, u.t1, u.reason)),
    );
    out.extend(
        s.skipped
            .iter()
            .map(|k| format!("  trial {} skipped: {}", k.trial, k.reason)),
    );
}

/// "31.2–35.0 °C" (range over the joints) or "–".
fn temp_range(t: &Option<[f64; crate::N_JOINTS]>) -> String {
    match t {
        Some(t) => {
            let lo = t.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = t.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            format!("{lo:.1}–{hi:.1} °C")
        }
        None => "–".into(),
    }
}

/// One line per session of a multi-session identification.
fn per_session_lines(out: &mut Vec<String>, id: &Identification) {
    if id.per_session.len() < 2 {
        return;
    }
    out.push("per session:".into());
    for b in &id.per_session {
        out.push(format!(
            "  {}: {} trials, {} used, {} rejected, {} without rows; per reading n {}, RMSE {:.3} W, R² {:.4}; start winding {}",
            b.source.display(),
            b.trials,
            b.used,
            b.rejected,
            b.without_rows,
            b.reading.n,
            b.reading.rmse,
            b.reading.r2,
            temp_range(&b.first_temp_c)
        ));
    }
}

/// The per-session breakdown as a markdown table (for the report), empty for one session.
pub(crate) fn per_session_markdown(id: &Identification) -> Option<String> {
    if id.per_session.len() < 2 {
        return None;
    }
    let mut md = String::from("## Per session\n\n");
    let head = [
        "session",
        "trials",
        "used",
        "rejected",
        "without rows",
        "readings",
        "RMSE [W]",
        "R²",
        "start winding T per joint [°C]",
    ];
    let rows = id.per_session.iter().map(|b| {
        let temps = b.first_temp_c.map_or("–".into(), |t| {
            t.iter()
                .map(|v| format!("{v:.1}"))
                .collect::<Vec<_>>()
                .join(", ")
        });
        let counts = [b.trials, b.used, b.rejected, b.without_rows, b.reading.n];
        std::iter::once(b.source.display().to_string())
            .chain(counts.iter().map(usize::to_string))
            .chain([
                format!("{:.3}", b.reading.rmse),
                format!("{:.4}", b.reading.r2),
                temps,
            ])
            .collect()
    });
    crate::plot::table(&mut md, &head, rows);
    Some(md)
}

impl Identification {
    /// Plain-text summary for the terminal: sessions and segmentation, rejected trials, sensor
    /// timing, fit quality, the row-pairing comparison, dominant terms and term shares.
    pub fn summary(&self) -> String {
        let mut out = Vec::new();
        for s in &self.sessions {
            segmentation_lines(&mut out, s);
        }
        out.extend(self.rejections.iter().map(|r| format!("rejected {r}")));
        per_session_lines(&mut out, self);
        out.push(format!(
            "power readings = averages over {}",
            self.reading_window(" (estimated)")
        ));
        out.push(format!(
            "{} trials used, target {}, {} rows",
            self.trials_used,
            self.options.target.name(),
            self.options.mode.name()
        ));
        out.push(metrics_line("fit", &self.fit));
        if self.fit.n < crate::N_PARAMS {
            out.push(format!(
                "warning: {} rows for {} parameters — the model is not identifiable from these \
                 sessions (record more trials); the fit is one of many that match them",
                self.fit.n,
                crate::N_PARAMS
            ));
        }
        out.push(metrics_line(
            "trial level (like for like)",
            &self.trial_level_aligned,
        ));
        out.push(metrics_line(
            "trial level (paper: whole-window regressors)",
            &self.trial_level,
        ));
        out.extend(self.modes.iter().map(|m| {
            format!(
                "{:>7} rows: n {:>7}, κ(ΦᵀΦ) {:.3e}, R² {:.4}",
                m.mode.name(),
                m.quality.n,
                m.kappa,
                m.quality.r2
            )
        }));
        let dominant: Vec<String> = self
            .dominant
            .iter()
            .enumerate()
            .map(|(j, d)| format!("{j}: {}", d.map_or("none", LossTerm::name)))
            .collect();
        out.push(format!("dominant term per joint: {}", dominant.join(", ")));
        out.push(shares_line(&self.shares_percent));
        out.join("\n")
    }
}

impl Identification {
    /// The window each power reading averages, `[t − lag − window, t − lag]`, followed by
    /// `estimated` when the timing was estimated from the data.
    pub(super) fn reading_window(&self, estimated: &str) -> String {
        let (lag, window) = (self.alignment.lag_s, self.alignment.window_s);
        let note = if self.alignment_estimate.is_some() {
            estimated
        } else {
            ""
        };
        format!("[t − {lag:.3} s − {window:.3} s, t − {lag:.3} s]{note}")
    }
}

impl Validation {
    /// Plain-text summary for the terminal: segmentation, metrics at reading and trial level,
    /// term shares.
    pub fn summary(&self) -> String {
        let mut out = Vec::new();
        segmentation_lines(&mut out, &self.session);
        out.push(metrics_line("per reading", &self.reading_level));
        out.push(metrics_line(
            "per trial (like for like)",
            &self.trial_level_aligned,
        ));
        if let Some(m) = &self.trial_level_aligned_imu_kept {
            out.push(metrics_line("per trial, IMU-calm trials only", m));
        }
        out.push(metrics_line(
            "per trial (paper: whole-window regressors)",
            &self.trial_level,
        ));
        out.push(shares_line(&self.shares_percent));
        out.join("\n")
    }
}
