//! The data stages of [`super::diagnose_trials`]: the usable trials (IMU and n·σ filters) and
//! the power rows at every scanned sensor lag, and the lag scan the report plots.

use anyhow::Result;

use crate::signals::{PowerSeries, Recording};
use crate::trial::{Cascade, Rejection, TrialStat, TrialWindow};

use super::data::{Rows, TrialMeta, build_rows};
use super::reduce::TrialSamples;
use super::select::PowerData;
use super::{DiagnoseOptions, LagPoint};

/// Rows of every trial at each of a set of lags, stored lag by lag in one [`Rows`] per lag
/// (trial = position in the trial list): no per-trial allocations, so memory is the rows
/// themselves (at 10 h the coarse lags' rows are most of the diagnosis' memory).
pub(crate) struct TrialRows {
    /// One [`Rows`] per lag, the trials' rows appended in trial order.
    pub(crate) by_lag: Vec<Rows>,
    /// `spans[lag][trial]`: where each trial's rows lie in `by_lag[lag]`.
    spans: Vec<Vec<std::ops::Range<usize>>>,
}

impl TrialRows {
    /// The rows of the trials at positions `kept` (ascending) at `lag`, renumbered 0.., copied.
    pub(crate) fn subset(&self, lag: usize, kept: &[usize]) -> Rows {
        let from = &self.by_lag[lag];
        let mut out = Rows::default();
        for (k, &i) in kept.iter().enumerate() {
            // A trial the samples never delivered (a read cut short) has no rows.
            let Some(s) = self.spans[lag].get(i).cloned() else {
                continue;
            };
            out.trial.extend(std::iter::repeat_n(k, s.len()));
            out.t.extend_from_slice(&from.t[s.clone()]);
            out.phase.extend_from_slice(&from.phase[s.clone()]);
            out.y.extend_from_slice(&from.y[s.clone()]);
            out.x.extend_from_slice(&from.x[s.clone()]);
            if !from.locate.is_empty() {
                out.locate.extend_from_slice(&from.locate[s]);
            }
        }
        out
    }

    /// Keep only the trials at positions `kept` (ascending), renumbered 0.., in place (no
    /// second copy of the rows), and return the rows lag by lag.
    pub(crate) fn keep(self, kept: &[usize]) -> Vec<Rows> {
        let mut new_pos = vec![usize::MAX; self.spans.first().map_or(0, Vec::len)];
        for (k, &i) in kept.iter().enumerate() {
            if let Some(p) = new_pos.get_mut(i) {
                *p = k;
            }
        }
        self.by_lag
            .into_iter()
            .map(|mut r| {
                let mut w = 0;
                for i in 0..r.len() {
                    let p = new_pos[r.trial[i]];
                    if p == usize::MAX {
                        continue;
                    }
                    r.trial[w] = p;
                    r.t[w] = r.t[i];
                    r.phase[w] = r.phase[i];
                    r.y[w] = r.y[i];
                    r.x[w] = r.x[i];
                    if !r.locate.is_empty() {
                        r.locate[w] = r.locate[i];
                    }
                    w += 1;
                }
                r.trial.truncate(w);
                r.t.truncate(w);
                r.phase.truncate(w);
                r.y.truncate(w);
                r.x.truncate(w);
                if !r.locate.is_empty() {
                    r.locate.truncate(w);
                }
                r.shrink_to_fit();
                r
            })
            .collect()
    }
}

/// Rows of each of `metas`' trials at each of `lags`, with the descriptor features at lag 0:
/// one pass over the trials' samples.
pub(crate) fn trial_rows(
    samples: &mut dyn TrialSamples,
    power: &PowerSeries,
    metas: &[TrialMeta],
    lags: &[f64],
    w: f64,
) -> Result<TrialRows> {
    let windows: Vec<TrialWindow> = metas.iter().map(|m| m.window.clone()).collect();
    let mut out = TrialRows {
        by_lag: vec![Rows::default(); lags.len()],
        spans: vec![Vec::with_capacity(metas.len()); lags.len()],
    };
    let mut ti = 0usize;
    samples.for_each(&windows, &mut |rec, _| {
        let one = std::slice::from_ref(&metas[ti]);
        for (l, &lag) in lags.iter().enumerate() {
            let part = build_rows(rec, power, one, lag, w, lag == 0.0);
            let to = &mut out.by_lag[l];
            let start = to.len();
            to.trial.extend(std::iter::repeat_n(ti, part.len()));
            to.t.extend(part.t);
            to.phase.extend(part.phase);
            to.y.extend(part.y);
            to.x.extend(part.x);
            to.locate.extend(part.locate);
            out.spans[l].push(start..to.len());
        }
        ti += 1;
        Ok(())
    })?;
    Ok(out)
}

/// Stage: the trials usable for the diagnosis — trials without a pre-idle are unusable
/// (`skipped`), then the identification's IMU filter, then n·σ passes on the per-trial mean
/// residuals of the base model (hardware-event outliers) fitted on the rows at lag 0 (lag
/// index 0 of `rows`). Returns the kept trials, the rejections and the kept trials' positions
/// in `metas`.
pub(crate) fn filter_trials(
    metas: &[TrialMeta],
    skipped: Vec<(usize, String)>,
    rows: &TrialRows,
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
        let mut lag0 = rows.subset(0, &kept);
        lag0.locate = Vec::new();
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
    // Appended lag by lag as each trial is built (no per-trial allocations).
    let mut fine_rows = vec![Rows::default(); fine.len()];
    let windows: Vec<TrialWindow> = metas.iter().map(|m| m.window.clone()).collect();
    let mut ti = 0usize;
    samples.for_each(&windows, &mut |rec, _| {
        let one = std::slice::from_ref(&metas[ti]);
        for (to, &l) in fine_rows.iter_mut().zip(&fine) {
            let part = build_rows(rec, power, one, l, w, false);
            to.trial.extend(std::iter::repeat_n(ti, part.len()));
            to.t.extend(part.t);
            to.phase.extend(part.phase);
            to.y.extend(part.y);
            to.x.extend(part.x);
        }
        extra(rec, ti, &metas[ti]);
        ti += 1;
        Ok(())
    })?;
    if !fine.is_empty() {
        for (&l, mut rows) in fine.iter().zip(fine_rows) {
            rows.shrink_to_fit();
            lags.push(l);
            all_rows.push(rows);
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
