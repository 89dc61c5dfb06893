//! The data stages of [`super::diagnose_trials`]: the usable trials (IMU and n·σ filters) and
//! the power rows at every scanned sensor lag, and the lag scan the report plots.

use std::collections::HashSet;

use anyhow::Result;

use crate::lsq::Gram;
use crate::signals::{PowerSeries, Recording};
use crate::trial::{Cascade, Rejection, TrialStat, TrialWindow};

use super::hypotheses::N_RAW;
use super::reading_rows::{Rows, TrialFeatures, TrialMeta, trial_rows};
use super::select::{FOLD_SEED, FoldGramsBuilder, Folds, PowerData, fit};
use super::{DiagnoseOptions, LagPoint};
use crate::session::TrialSource;

/// The rows of every trial at lag 0 (trial = position in the trial list), appended in trial
/// order, and how many trials the list holds.
pub(crate) struct TrialRows {
    rows: Rows,
    n_trials: usize,
}

impl TrialRows {
    /// `rows` of a list of `n_trials` trials (numbered by position).
    pub(crate) fn new(rows: Rows, n_trials: usize) -> TrialRows {
        TrialRows { rows, n_trials }
    }

    /// The rows of the trials at positions `kept` (ascending), renumbered 0.., copied without the
    /// descriptor features.
    pub(crate) fn subset(&self, kept: &[usize]) -> Rows {
        let rows = Rows {
            locate: Vec::new(),
            ..self.rows.clone()
        };
        TrialRows::new(rows, self.n_trials).keep(kept)
    }

    /// Keep only the trials at positions `kept` (ascending), renumbered 0.., in place (no
    /// second copy of the rows).
    pub(crate) fn keep(self, kept: &[usize]) -> Rows {
        let mut new_pos = vec![usize::MAX; self.n_trials];
        for (k, &i) in kept.iter().enumerate() {
            if let Some(p) = new_pos.get_mut(i) {
                *p = k;
            }
        }
        let mut r = self.rows;
        r.retain(|_, trial| {
            let p = new_pos[trial];
            (p != usize::MAX).then_some(p)
        });
        r
    }
}

/// One pass over the trials of `metas` at positions `which`: the Gram matrix of their rows at
/// each of `lags` and, with `keep`, their rows at `lags[0]` with the descriptor features
/// (numbered by position).
fn lag_grams(
    samples: &mut dyn TrialSource,
    (power, w): (&PowerSeries, f64),
    metas: &[TrialMeta],
    which: &[usize],
    lags: &[f64],
    keep: bool,
) -> Result<(Vec<Gram>, TrialRows)> {
    let windows: Vec<TrialWindow> = which.iter().map(|&i| metas[i].window.clone()).collect();
    let mut rows = Rows::default();
    let mut grams: Vec<Gram> = lags.iter().map(|_| Gram::zeros(N_RAW)).collect();
    let mut k = 0usize;
    samples.for_each(&windows, &mut |rec, _| {
        let (ti, meta) = (which[k], &metas[which[k]]);
        let feats = TrialFeatures::new(rec, meta);
        for (l, &lag) in lags.iter().enumerate() {
            let part = trial_rows(rec, power, meta, &feats, (lag, w), keep && l == 0);
            for (x, y) in part.x.iter().zip(&part.y) {
                grams[l].add_row(x, *y);
            }
            if keep && l == 0 {
                rows.append(part, ti);
            }
        }
        k += 1;
        Ok(())
    })?;
    Ok((grams, TrialRows::new(rows, metas.len())))
}

/// Stage: the trials usable for the diagnosis — trials without a pre-idle are unusable
/// (`skipped`), then the identification's IMU filter (`imu`: with it), then n·σ passes on the per-trial mean
/// residuals of the base model (hardware-event outliers) fitted on the rows at lag 0 (lag
/// index 0 of `rows`). Returns the kept trials, the rejections and the kept trials' positions
/// in `metas`.
pub(crate) fn filter_trials(
    metas: &[TrialMeta],
    skipped: Vec<(usize, String)>,
    rows: &TrialRows,
    opts: &DiagnoseOptions,
    imu: bool,
) -> Result<(Vec<TrialMeta>, Vec<Rejection>, Vec<usize>)> {
    let cascade = Cascade {
        imu_k: imu.then_some(opts.imu_threshold),
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
        let lag0 = rows.subset(&kept);
        let res = base_trial_residuals(&lag0, kept.len(), opts)?;
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

/// The usable trials and what the later stages need of them ([`usable_trials`]).
pub(crate) struct Usable {
    /// The usable trials.
    pub(crate) metas: Vec<TrialMeta>,
    /// Every rejection (unusable trials, filters).
    pub(crate) rejected: Vec<Rejection>,
    /// The rejected trials' windows, for the replay.
    pub(crate) rejected_windows: Vec<super::HighlightedTrial>,
    /// The IMU filter's statistic of every trial and its threshold, for the replay.
    pub(crate) imu: Option<crate::trial::ImuFilterMarks>,
    /// The usable trials' rows at lag 0.
    pub(crate) rows0: Rows,
    /// Their Gram matrices at the [`coarse_lags`].
    pub(crate) totals: Vec<Gram>,
}

/// Stage: rows of every trial at lag 0 and Gram matrices at every coarse lag (one pass), then
/// the usable trials ([`filter_trials`]), and the others' rows taken out of the Gram matrices
/// (one short pass over them only). `opts` has its sensor window resolved.
pub(crate) fn usable_trials(
    info: &super::trials::SessionInfo,
    samples: &mut dyn TrialSource,
    all_metas: Vec<TrialMeta>,
    skipped: Vec<(usize, String)>,
    opts: &DiagnoseOptions,
) -> Result<Usable> {
    let power = &info.power;
    let w = (opts.sensor_window_s).unwrap_or(crate::timing::Alignment::NOMINAL.window_s);
    let lags = coarse_lags(opts);
    let all: Vec<usize> = (0..all_metas.len()).collect();
    let (mut totals, rows0) = lag_grams(samples, (power, w), &all_metas, &all, &lags, true)?;
    let (metas, rejected, kept) = filter_trials(&all_metas, skipped, &rows0, opts, true)?;
    if metas.len() < 2 * opts.folds.max(2) {
        anyhow::bail!(
            "{}: only {} usable trials (need at least {} for {}-fold cross-validation by trial)",
            info.source.display(),
            metas.len(),
            2 * opts.folds.max(2),
            opts.folds
        );
    }
    let gone: Vec<usize> = (0..all_metas.len())
        .filter(|i| kept.binary_search(i).is_err())
        .collect();
    // The others' rows taken out of the Gram matrices: one pass over those trials only.
    if !gone.is_empty() {
        let (removed, _) = lag_grams(samples, (power, w), &all_metas, &gone, &lags, false)?;
        for (t, r) in totals.iter_mut().zip(&removed) {
            *t = t.minus(r);
        }
    }
    let spans = all_metas.iter().map(|m| {
        let w = &m.window;
        (w.t_traj_start, w.t_post_end, m.sigma_omega)
    });
    Ok(Usable {
        imu: crate::trial::ImuFilterMarks::new(Some(opts.imu_threshold), spans.collect()),
        rejected_windows: super::viewer_data::rejected_windows(&all_metas, &rejected),
        metas,
        rejected,
        rows0: rows0.keep(&kept),
        totals,
    })
}

/// Per-trial mean in-sample residual of the base model fitted to `rows`.
pub(crate) fn base_trial_residuals(
    rows: &Rows,
    n_trials: usize,
    opts: &DiagnoseOptions,
) -> Result<Vec<Option<f64>>> {
    let (folds, reference) = (opts.folds, opts.reference_theta());
    let data = PowerData::new(vec![0.0], vec![rows.clone()], n_trials, folds, reference);
    let fit = data.fit_all(&[], 0)?;
    let resid = (0..rows.len()).map(|r| (rows.trial[r], rows.y[r] - fit.predict(&rows.x[r])));
    Ok(super::locate::trial_means(resid, n_trials))
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

/// Keep only the readings of `rows` whose stamps (their bits) are in `common`.
fn retain_common(rows: &mut Rows, common: &HashSet<u64>) {
    let keep: Vec<bool> = rows
        .t
        .iter()
        .map(|t| common.contains(&t.to_bits()))
        .collect();
    rows.retain(|r, trial| keep[r].then_some(trial));
}

/// Append `part` (one trial's rows) to `to`, keeping only the readings in `common` and
/// numbering them as trial `ti`.
fn append_common(to: &mut Rows, mut part: Rows, common: &HashSet<u64>, ti: usize) {
    retain_common(&mut part, common);
    to.append(part, ti);
}

/// Stage: the power data of the usable trials `metas` at every scanned sensor lag.
///
/// `totals` (the Gram matrices of their rows at the [`coarse_lags`]) give the base model's best
/// coarse lag, and a fine scan (0.01 s) is added around it. One pass over the trials' samples
/// then builds each trial's rows at every lag, keeps the readings present at all lags (a gap
/// can drop a window at one lag), adds them to each lag's fold Gram matrices and shows the
/// trial to `extra` (the torque rows). Only the rows at lag 0 (`rows0`, with the descriptor
/// features) are kept; another lag's rows are built again, in one more pass, when a stage
/// needs them (on a 10 h session the rows of all ~29 lags took ~500 MB).
pub(crate) fn scan_lags<'a>(
    samples: &'a mut dyn TrialSource,
    power: &'a PowerSeries,
    metas: &'a [TrialMeta],
    mut rows0: Rows,
    totals: &[Gram],
    opts: &DiagnoseOptions,
    extra: &mut dyn FnMut(&Recording, usize, &TrialMeta),
) -> Result<PowerData<'a>> {
    let reference = opts.reference_theta();
    // Resolved by `diagnose_trials` before the stages run.
    let w = opts
        .sensor_window_s
        .unwrap_or(crate::timing::Alignment::NOMINAL.window_s);
    let mut lags = coarse_lags(opts);
    if lags.len() >= 3 {
        let sse: Vec<f64> = totals
            .iter()
            .map(|g| fit(&[], g, reference.as_deref()).map(|f| g.sse(&f.beta)))
            .collect::<Result<_>>()?;
        let best = (0..sse.len())
            .min_by(|&a, &b| sse[a].total_cmp(&sse[b]))
            .unwrap_or(0);
        let centre = lags[best];
        let mut fine = Vec::new();
        for k in -4i32..=4 {
            let l = centre + 0.01 * k as f64;
            if l > 0.0 && l <= opts.max_lag_s && lags.iter().all(|x| (x - l).abs() > 1e-6) {
                fine.push(l);
            }
        }
        lags.extend(fine);
        lags.sort_by(f64::total_cmp);
    }
    let folds = Folds::new(metas.len(), opts.folds, FOLD_SEED);
    let mut grams: Vec<FoldGramsBuilder> = lags
        .iter()
        .map(|_| FoldGramsBuilder::new(N_RAW, folds.k))
        .collect();
    let mut common: HashSet<u64> = HashSet::new();
    let windows: Vec<TrialWindow> = metas.iter().map(|m| m.window.clone()).collect();
    let mut ti = 0usize;
    samples.for_each(&windows, &mut |rec, _| {
        let feats = TrialFeatures::new(rec, &metas[ti]);
        let parts: Vec<Rows> = lags
            .iter()
            .map(|&l| trial_rows(rec, power, &metas[ti], &feats, (l, w), false))
            .collect();
        // The readings present at every lag (a handful per trial).
        let here: HashSet<u64> = parts[0]
            .t
            .iter()
            .map(|t| t.to_bits())
            .filter(|b| {
                parts[1..]
                    .iter()
                    .all(|p| p.t.iter().any(|u| u.to_bits() == *b))
            })
            .collect();
        for (g, part) in grams.iter_mut().zip(parts) {
            let mut rows = Rows::default();
            append_common(&mut rows, part, &here, ti);
            g.add_rows(&rows, &folds);
        }
        common.extend(here);
        extra(rec, ti, &metas[ti]);
        ti += 1;
        Ok(())
    })?;
    retain_common(&mut rows0, &common);
    let grams = grams.into_iter().map(FoldGramsBuilder::finish).collect();
    let at = lags.clone();
    let source = Box::new(move |want: &[usize]| -> Result<Vec<Rows>> {
        let mut out = vec![Rows::default(); want.len()];
        let mut ti = 0usize;
        samples.for_each(&windows, &mut |rec, _| {
            let feats = TrialFeatures::new(rec, &metas[ti]);
            for (to, &l) in out.iter_mut().zip(want) {
                let part = trial_rows(rec, power, &metas[ti], &feats, (at[l], w), false);
                append_common(to, part, &common, ti);
            }
            ti += 1;
            Ok(())
        })?;
        out.iter_mut().for_each(Rows::shrink_to_fit);
        Ok(out)
    });
    Ok(PowerData::with_source(
        lags, rows0, grams, folds, reference, source,
    ))
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
