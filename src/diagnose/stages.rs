//! The data stages of [`super::diagnose_trials`]: the usable trials (IMU and n·σ filters) and
//! the power rows at every scanned sensor lag, and the lag scan the report plots.

use anyhow::Result;

use crate::power::PowerModel;
use crate::signals::Recording;
use crate::trial::{Cascade, Rejection, TrialStat, TrialWindow};

use super::data::{self, Rows, TrialMeta, build_rows, trial_meta};
use super::select::PowerData;
use super::{DiagnoseOptions, LagPoint, hypotheses};

/// Stage: the trials usable for the diagnosis — per-trial quantities (trials without a pre-idle
/// are unusable), the identification's IMU filter, then n·σ passes on the per-trial mean
/// residuals of the base model (hardware-event outliers).
pub(crate) fn filter_trials(
    rec: &Recording,
    windows: &[TrialWindow],
    opts: &DiagnoseOptions,
    w: f64,
    reference: Option<Vec<f64>>,
) -> Result<(Vec<TrialMeta>, Vec<Rejection>)> {
    let power = opts.target.series(rec);
    let bus = data::BusModel {
        model: opts.reference.unwrap_or(PowerModel::PAPER),
        volts: hypotheses::NOMINAL_BUS_VOLTS,
    };
    let (metas, skipped) = trial_meta(rec, windows, bus);
    let cascade = Cascade {
        imu_k: Some(opts.imu_threshold),
        passes: opts.outlier_passes,
        n_sigma: 3.0,
        min_trials: 10,
    };
    let sigmas: Vec<TrialStat> = metas
        .iter()
        .map(|m| TrialStat::new(0, m.window.index, m.sigma_omega))
        .collect();
    let mut rejected: Vec<Rejection> = skipped
        .into_iter()
        .map(|(trial, reason)| Rejection::unusable(0, trial, reason))
        .collect();
    rejected.extend(cascade.run(&sigmas, |rej| {
        let kept: Vec<TrialMeta> = metas
            .iter()
            .filter(|m| !crate::trial::is_rejected(rej, 0, m.window.index))
            .cloned()
            .collect();
        let rows = build_rows(rec, power, &kept, 0.0, w, false);
        let res = base_trial_residuals(&rows, kept.len(), opts.folds, reference.clone())?;
        Ok::<_, anyhow::Error>(
            kept.iter()
                .zip(&res)
                .map(|(m, r)| TrialStat::new(0, m.window.index, r.unwrap_or(f64::NAN)))
                .collect(),
        )
    })?);
    let metas = metas
        .into_iter()
        .filter(|m| !crate::trial::is_rejected(&rejected, 0, m.window.index))
        .collect();
    Ok((metas, rejected))
}

/// Per-trial mean in-sample residual of the base model fitted to `rows`.
pub(crate) fn base_trial_residuals(
    rows: &Rows,
    n_trials: usize,
    folds: usize,
    reference: Option<Vec<f64>>,
) -> Result<Vec<Option<f64>>> {
    let data = PowerData::new(vec![0.0], vec![rows.clone()], n_trials, folds, reference);
    let fit = data.fit_all(&[], 0)?;
    let mut sum = vec![0.0; n_trials];
    let mut cnt = vec![0usize; n_trials];
    for r in 0..rows.len() {
        let p: f64 = rows.x[r]
            .iter()
            .zip(fit.beta.iter())
            .map(|(a, b)| a * b)
            .sum();
        sum[rows.trial[r]] += rows.y[r] - p;
        cnt[rows.trial[r]] += 1;
    }
    Ok((0..n_trials)
        .map(|t| (cnt[t] > 0).then(|| sum[t] / cnt[t] as f64))
        .collect())
}

/// Power rows of the usable trials at every scanned sensor lag (ascending; index 0 = no lag),
/// restricted to the readings present at all lags (same readings everywhere).
pub(crate) struct LagRows {
    pub(crate) lags: Vec<f64>,
    pub(crate) rows: Vec<Rows>,
}

/// Stage: rows at every coarse lag (0.05 s steps up to [`DiagnoseOptions::max_lag_s`]), then a
/// fine scan (0.01 s) around the base model's best coarse lag.
pub(crate) fn scan_lags(
    rec: &Recording,
    power: &crate::signals::PowerSeries,
    metas: &[TrialMeta],
    opts: &DiagnoseOptions,
    reference: Option<Vec<f64>>,
) -> Result<LagRows> {
    // Resolved by `diagnose_trials` before the stages run.
    let w = opts
        .sensor_window_s
        .unwrap_or(crate::timing::Alignment::NOMINAL.window_s);
    // Rows at every scanned lag; keep only readings present at all lags (same readings everywhere).
    let mut lags = vec![0.0];
    if opts.max_lag_s > 0.0 {
        let coarse = (opts.max_lag_s / 0.05).round() as usize;
        lags.extend((1..=coarse).map(|k| k as f64 * 0.05));
    }
    let mut all_rows: Vec<Rows> = lags
        .iter()
        .map(|&l| build_rows(rec, power, metas, l, w, l == 0.0))
        .collect();
    // Fine scan (0.01 s) around the base model's best coarse lag.
    if lags.len() >= 3 {
        // The rows move into the scan and back out of it: at paper scale one copy of all lags'
        // rows is ~100 MB.
        let data = PowerData::new(
            lags.clone(),
            std::mem::take(&mut all_rows),
            metas.len(),
            opts.folds,
            reference,
        );
        let sse: Vec<f64> = (0..lags.len())
            .map(|l| {
                data.fit_all(&[], l)
                    .map(|f| data.grams[l].total.sse(&f.beta))
            })
            .collect::<Result<_>>()?;
        let best = (0..lags.len())
            .min_by(|&a, &b| sse[a].total_cmp(&sse[b]))
            .unwrap_or(0);
        all_rows = data.rows;
        let centre = lags[best];
        for k in -4i32..=4 {
            let l = centre + 0.01 * k as f64;
            if l > 0.0 && l <= opts.max_lag_s && lags.iter().all(|x| (x - l).abs() > 1e-6) {
                lags.push(l);
                all_rows.push(build_rows(rec, power, metas, l, w, false));
            }
        }
        let mut by_lag: Vec<(f64, Rows)> = lags.into_iter().zip(all_rows).collect();
        by_lag.sort_by(|a, b| a.0.total_cmp(&b.0));
        (lags, all_rows) = by_lag.into_iter().unzip();
    }
    common_readings(&mut all_rows);
    Ok(LagRows {
        lags,
        rows: all_rows,
    })
}

/// Stage: the base model's in-sample RMSE refitted at every scanned lag.
pub(crate) fn lag_scan(data: &PowerData) -> Result<Vec<LagPoint>> {
    (0..data.lags.len())
        .map(|l| {
            let g = &data.grams[l].total;
            data.fit_all(&[], l).map(|f| LagPoint {
                lag_s: data.lags[l],
                rmse_w: (g.sse(&f.beta) / g.n.max(1) as f64).sqrt(),
            })
        })
        .collect()
}

/// Keep, at every lag, only the readings present at all lags (a gap can drop a window at one lag).
pub(crate) fn common_readings(all: &mut [Rows]) {
    use std::collections::HashMap;
    let mut count: HashMap<u64, usize> = HashMap::new();
    for rows in all.iter() {
        for t in &rows.t {
            *count.entry(t.to_bits()).or_default() += 1;
        }
    }
    let n = all.len();
    for rows in all.iter_mut() {
        let keep: Vec<bool> = rows
            .t
            .iter()
            .map(|t| count.get(&t.to_bits()) == Some(&n))
            .collect();
        if keep.iter().all(|k| *k) {
            continue;
        }
        let mut i = 0;
        let mut filt = Rows::default();
        for (r, k) in keep.iter().enumerate() {
            if *k {
                filt.trial.push(rows.trial[r]);
                filt.t.push(rows.t[r]);
                filt.phase.push(rows.phase[r]);
                filt.y.push(rows.y[r]);
                filt.x.push(rows.x[r]);
                if let Some(l) = rows.locate.get(r) {
                    filt.locate.push(*l);
                }
                i += 1;
            }
        }
        debug_assert_eq!(i, filt.len());
        *rows = filt;
    }
}
