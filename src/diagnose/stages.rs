//! The data stages of [`super::diagnose_trials`]: the usable trials (IMU and n·σ filters) and
//! the power rows at every scanned sensor lag, and the lag scan the report plots.

use anyhow::Result;

use crate::signals::{PowerSeries, Recording};
use crate::trial::{Cascade, Rejection, TrialStat, TrialWindow};

use super::data::{Rows, TrialMeta, build_rows};
use super::reduce::TrialSamples;
use super::select::PowerData;
use super::{DiagnoseOptions, LagPoint};

/// Rows of each of `metas`' trials (outer) at each of `lags` (inner), each trial's rows on its
/// own (trial position 0; see [`assemble`]), with the descriptor features at lag 0: one pass
/// over the trials' samples.
pub(crate) fn trial_rows(
    samples: &mut dyn TrialSamples,
    power: &PowerSeries,
    metas: &[TrialMeta],
    lags: &[f64],
    w: f64,
) -> Result<Vec<Vec<Rows>>> {
    let windows: Vec<TrialWindow> = metas.iter().map(|m| m.window.clone()).collect();
    let mut out = Vec::with_capacity(metas.len());
    samples.for_each(&windows, &mut |rec, _| {
        let ti = out.len();
        let meta = &metas[ti];
        let one = std::slice::from_ref(meta);
        out.push(
            lags.iter()
                .map(|&l| build_rows(rec, power, one, l, w, l == 0.0))
                .collect(),
        );
        Ok(())
    })?;
    Ok(out)
}

/// One trial list's rows from each trial's own rows, in order, each row's trial set to its
/// trial's position (as [`build_rows`] over the whole list numbers them).
pub(crate) fn assemble(parts: impl IntoIterator<Item = Rows>, with_locate: bool) -> Rows {
    let mut out = Rows::default();
    for (ti, p) in parts.into_iter().enumerate() {
        out.trial.extend(std::iter::repeat_n(ti, p.len()));
        out.t.extend(p.t);
        out.phase.extend(p.phase);
        out.y.extend(p.y);
        out.x.extend(p.x);
        if with_locate {
            out.locate.extend(p.locate);
        }
    }
    out
}

/// Stage: the trials usable for the diagnosis — trials without a pre-idle are unusable
/// (`skipped`), then the identification's IMU filter, then n·σ passes on the per-trial mean
/// residuals of the base model (hardware-event outliers) fitted on the rows at lag 0
/// (`rows[trial][0]`, each trial's own rows at lag 0). Returns the kept trials, the rejections
/// and the kept trials' positions in `metas`.
pub(crate) fn filter_trials(
    metas: &[TrialMeta],
    skipped: Vec<(usize, String)>,
    rows: &[Vec<Rows>],
    opts: &DiagnoseOptions,
    reference: Option<Vec<f64>>,
) -> Result<(Vec<TrialMeta>, Vec<Rejection>, Vec<usize>)> {
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
        let kept: Vec<usize> = (0..metas.len())
            .filter(|&i| !crate::trial::is_rejected(rej, 0, metas[i].window.index))
            .collect();
        let lag0 = assemble(kept.iter().map(|&i| rows[i][0].clone()), false);
        let res = base_trial_residuals(&lag0, kept.len(), opts.folds, reference.clone())?;
        Ok::<_, anyhow::Error>(
            kept.iter()
                .zip(&res)
                .map(|(&i, r)| TrialStat::new(0, metas[i].window.index, r.unwrap_or(f64::NAN)))
                .collect(),
        )
    })?);
    let kept: Vec<usize> = (0..metas.len())
        .filter(|&i| !crate::trial::is_rejected(&rejected, 0, metas[i].window.index))
        .collect();
    let metas = kept.iter().map(|&i| metas[i].clone()).collect();
    Ok((metas, rejected, kept))
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

/// Coarse lags of the scan: 0 and 0.05 s steps up to [`DiagnoseOptions::max_lag_s`].
pub(crate) fn coarse_lags(opts: &DiagnoseOptions) -> Vec<f64> {
    let mut lags = vec![0.0];
    if opts.max_lag_s > 0.0 {
        let coarse = (opts.max_lag_s / 0.05).round() as usize;
        lags.extend((1..=coarse).map(|k| k as f64 * 0.05));
    }
    lags
}

/// Stage: rows at every coarse lag ([`coarse_lags`], `coarse`: the kept trials' rows there), then
/// a fine scan (0.01 s) around the base model's best coarse lag, built in one more pass over the
/// trials' samples that also shows each trial to `extra` (the torque rows).
pub(crate) fn scan_lags(
    samples: &mut dyn TrialSamples,
    power: &PowerSeries,
    metas: &[TrialMeta],
    coarse: Vec<Rows>,
    opts: &DiagnoseOptions,
    reference: Option<Vec<f64>>,
    extra: &mut dyn FnMut(&Recording, usize, &TrialMeta),
) -> Result<LagRows> {
    // Resolved by `diagnose_trials` before the stages run.
    let w = opts
        .sensor_window_s
        .unwrap_or(crate::timing::Alignment::NOMINAL.window_s);
    let mut lags = coarse_lags(opts);
    let mut all_rows = coarse;
    // Fine scan (0.01 s) around the base model's best coarse lag.
    let mut fine = Vec::new();
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
                fine.push(l);
            }
        }
    }
    // The fine lags' rows (built without descriptors), and whatever else needs the samples.
    let mut per_trial = Vec::with_capacity(metas.len());
    let windows: Vec<TrialWindow> = metas.iter().map(|m| m.window.clone()).collect();
    samples.for_each(&windows, &mut |rec, _| {
        let ti = per_trial.len();
        let one = std::slice::from_ref(&metas[ti]);
        let rows: Vec<Rows> = fine
            .iter()
            .map(|&l| build_rows(rec, power, one, l, w, false))
            .collect();
        per_trial.push(rows);
        extra(rec, ti, &metas[ti]);
        Ok(())
    })?;
    if !fine.is_empty() {
        let mut by_trial: Vec<std::vec::IntoIter<Rows>> =
            per_trial.into_iter().map(Vec::into_iter).collect();
        for &l in &fine {
            lags.push(l);
            all_rows.push(assemble(
                by_trial.iter_mut().map(|t| t.next().unwrap_or_default()),
                false,
            ));
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
