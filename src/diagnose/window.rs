//! The power sensor's averaging window W: given, or estimated from the data.

use anyhow::{Context, Result};

use crate::power::PowerModel;
use crate::signals::Recording;
use crate::timing::{AlignmentScore, ScanGrid, ridge_r2, scan_alignment};
use crate::trial::TrialWindow;

use super::data::{BusModel, build_rows, trial_meta};
use super::hypotheses::NOMINAL_BUS_VOLTS;
use super::{DiagnoseOptions, SensorWindow};

/// Largest number of trials the sensor-window scan uses (evenly spread over the session): the
/// window is a property of the sensor, and 150 trials fix it well while the scan's cost stays
/// bounded at paper scale.
const WINDOW_SCAN_TRIALS: usize = 150;

/// The sensor window: given, or estimated by the (W, lag) alignment scan
/// ([`crate::timing::scan_alignment`], the identification's grid) on the diagnosis' own rows of
/// at most [`WINDOW_SCAN_TRIALS`] trials.
pub(crate) fn sensor_window(
    rec: &Recording,
    windows: &[TrialWindow],
    opts: &DiagnoseOptions,
) -> Result<SensorWindow> {
    if let Some(w) = opts.sensor_window_s {
        return Ok(SensorWindow {
            window_s: w,
            estimated: false,
            scan_lag_s: 0.0,
            scan_r2: 0.0,
            scan_trials: 0,
        });
    }
    let step = windows.len().div_ceil(WINDOW_SCAN_TRIALS).max(1);
    let used: Vec<TrialWindow> = windows.iter().step_by(step).cloned().collect();
    let power = opts.target.series(rec);
    let bus = BusModel {
        model: opts.reference.unwrap_or(PowerModel::PAPER),
        volts: NOMINAL_BUS_VOLTS,
    };
    let (metas, _) = trial_meta(rec, &used, bus);
    let est = scan_alignment(&ScanGrid::IDENTIFY, |a| {
        let rows = build_rows(rec, power, &metas, a.lag_s, a.window_s, false);
        let r2 = ridge_r2(rows.x.iter().map(|x| x.as_slice()), &rows.y)?;
        Some((rows.len(), r2))
    })
    .with_context(|| {
        format!(
            "{}: estimating the power sensor's window: fewer than {} {} readings inside the {} \
             scanned trials; give the window (--sensor-window SECONDS)",
            rec.source.display(),
            crate::N_PARAMS + 1,
            opts.target.name().to_uppercase(),
            used.len()
        )
    })?;
    // A reading cannot average power after its own stamp: W trades against a negative lag on a
    // flat R² surface (W = 0.275 s at lag −0.05 s was seen on a 0.2 s sensor), so the best point
    // with lag ≥ 0 is taken; a positive lag is the latency hypothesis' to judge.
    let best = est
        .grid
        .iter()
        .filter(|g| g.alignment.lag_s >= -1e-9)
        .max_by(|a, b| a.r2.total_cmp(&b.r2))
        .copied()
        .unwrap_or(AlignmentScore {
            alignment: est.best,
            rows: 0,
            r2: est.r2,
        });
    Ok(SensorWindow {
        window_s: best.alignment.window_s,
        estimated: true,
        scan_lag_s: best.alignment.lag_s,
        scan_r2: best.r2,
        scan_trials: used.len(),
    })
}
