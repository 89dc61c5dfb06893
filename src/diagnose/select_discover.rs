//! Library selection, then discovery beyond the library over every numeric field the
//! recording's files carry: reading those fields over the rows' windows, and dropping a library
//! term a term beyond the library does better than; then [`super::parsimony`]'s rule.

use anyhow::Result;

use super::hypotheses::{self, POWER_HYPOTHESES};
use super::reading_rows::{Rows, TrialMeta};
use super::select::{self, PowerData, Rule};
use super::trials::SessionInfo;
use super::{
    Confounded, DiagnoseOptions, DiscoveryReport, FieldSource, HypothesisScore, discover, fields,
};

/// Stage: library selection, then discovery beyond it; a library term that a term beyond the
/// library fits significantly better than ([`library_rivals`]) is dropped, reported, and the
/// library selection re-run without it; then every claim faces [`super::parsimony`]'s rule.
pub(crate) fn select_and_discover(
    info: &SessionInfo,
    metas: &[TrialMeta],
    data: &PowerData,
    rule: &Rule,
    opts: &DiagnoseOptions,
) -> Result<(select::Selection, Option<DiscoveryReport>, RowFields)> {
    let mut excluded: Vec<&str> = Vec::new();
    let mut confounded = Vec::new();
    // Candidate groups beyond the library that may not be claimed in place of a library term
    // they could not be told from (`library_rivals`).
    let mut blocked: Vec<String> = Vec::new();
    let mut fields: Option<(usize, RowFields)> = None;
    // The first run's step-1 scores: a term excluded from later runs keeps its place in the
    // ranking (marked confounded by `mark_confounded`).
    let mut first_scores: Option<Vec<HypothesisScore>> = None;
    loop {
        let candidates: Vec<&'static hypotheses::Hypothesis> = POWER_HYPOTHESES
            .iter()
            .filter(|h| !excluded.contains(&h.id))
            .collect();
        let mut sel = select::select(data, &candidates, rule)?;
        let first = first_scores.get_or_insert_with(|| sel.first_step.clone());
        let lag = sel.last.lag;
        // The fields are read again only when the selected lag changed.
        let f = match fields.take() {
            Some((l, f)) if l == lag => f,
            other => {
                // The fields of another lag are dropped before the new ones are read.
                drop(other);
                run_fields(info, metas, data.rows0(), data.lags[lag], opts)
            }
        };
        if !opts.discover {
            super::parsimony::apply(data, &mut sel, None, rule)?;
            return Ok((sel, None, f));
        }
        let f = &fields.insert((lag, f)).1;
        let inputs = field_inputs(f, opts);
        let mut report =
            discover::discover(data, &sel.last, &inputs, rule, &info.joint_names, &blocked)?;
        let rivals = library_rivals(data, &sel.last, &inputs, rule, info, &mut blocked)?;
        let (ties, mut dropped): (Vec<_>, Vec<_>) = rivals.into_iter().partition(|c| c.tied);
        if dropped.is_empty() {
            // The rule; library terms the found terms leave without support are dropped and
            // the selection is run again without them.
            let kept: Vec<String> = report.accepted.iter().map(|t| t.name.clone()).collect();
            let col = report.cols.first().cloned().unwrap_or_default();
            let rows = data.rows(sel.last.lag)?;
            let theta = sel.last.full.theta.clone();
            for (h, p_value, rel_change) in
                super::parsimony::apply(data, &mut sel, Some(&mut report), rule)?
            {
                let mine: Vec<f64> = (rows.x.iter())
                    .map(|x| select::regressor(h, x, &theta))
                    .collect();
                dropped.push(Confounded {
                    kept: kept.join("; "),
                    dropped: h.id.into(),
                    correlation: super::stats::pearson(&mine, &col).0,
                    p_value,
                    rel_change,
                    tied: false,
                });
            }
        }
        if dropped.is_empty() {
            // A library term tied with a rival stays claimed (its form comes from physics, the
            // rival's from a search), the rival named beside it; the selection is not re-run
            // without it (without it another term would absorb part of its effect).
            confounded.extend(ties);
            sel.first_step.extend(
                first
                    .iter()
                    .filter(|h| excluded.contains(&h.id.as_str()))
                    .cloned(),
            );
            sel.confounded.extend(confounded);
            sel.accepted.retain(|a| !excluded.contains(&a.id.as_str()));
            let f = fields.map(|f| f.1).unwrap_or_default();
            return Ok((sel, Some(report), f));
        }
        for c in dropped {
            if let Some(h) = hypotheses::power_hypothesis(&c.dropped) {
                excluded.push(h.id);
            }
            confounded.push(c);
        }
    }
}

/// The library terms of `cur` that a candidate beyond the library, on a recorded field the
/// library does not read, does the same work as ([`discover::rival_of`]): a term a rival beats
/// is returned alone (the first in `cur`'s order; it is dropped as confounded with the rival and
/// discovery then finds the rival); otherwise every term that ties with a rival is returned
/// (`tied`: the library term stays claimed, the rival named beside it), and every candidate
/// that explains the same is `blocked` from discovery.
pub(crate) fn library_rivals(
    data: &PowerData,
    cur: &select::State,
    inputs: &discover::Inputs,
    rule: &Rule,
    info: &SessionInfo,
    blocked: &mut Vec<String>,
) -> Result<Vec<Confounded>> {
    let mut ties = Vec::new();
    for (j, h) in cur.spec.iter().enumerate() {
        let mut spec = cur.spec.clone();
        spec.remove(j);
        let without = select::state(data, spec, cur.lag)?;
        let Some(r) = discover::rival_of(data, cur, &without, inputs, rule, &info.joint_names)?
        else {
            continue;
        };
        let c = Confounded {
            kept: r.name,
            dropped: h.id.into(),
            correlation: r.correlation,
            p_value: r.p_library,
            rel_change: 1.0 - r.rmse[0] / r.rmse[1].max(1e-300),
            tied: r.tied,
        };
        if !r.tied {
            return Ok(vec![c]);
        }
        blocked.extend(r.blocked);
        ties.push(c);
    }
    Ok(ties)
}

/// The recorded fields over the final rows' windows and every trial's baseline windows.
#[derive(Default)]
pub(crate) struct RowFields {
    pub(crate) table: fields::FieldTable,
    /// Index into the table's windows of each row.
    pub(crate) row_window: Vec<usize>,
    /// Per trial (position in the trial list): indices of its baseline windows.
    pub(crate) base_windows: Vec<Vec<usize>>,
    /// Per trial: its rest power, the mean of its baseline readings [W] (NaN without any).
    pub(crate) base_power: Vec<f64>,
    /// Per trial: its start (pre-idle) on the session clock [s].
    pub(crate) trial_start: Vec<f64>,
}

/// Stage: read every numeric field of the recording's files over the rows' windows.
pub(crate) fn run_fields(
    info: &SessionInfo,
    metas: &[TrialMeta],
    rows: &Rows,
    lag: f64,
    opts: &DiagnoseOptions,
) -> RowFields {
    let power = &info.power;
    // Resolved by `diagnose_trials` before the stages run.
    let w = opts
        .sensor_window_s
        .unwrap_or(crate::timing::Alignment::NOMINAL.window_s);
    let window = |t: f64| fields::Window {
        start: t - lag - w,
        end: t - lag,
    };
    // (window, tag): tag < rows.len() = row, otherwise baseline of trial tag − rows.len().
    let mut all: Vec<(fields::Window, usize)> = rows
        .t
        .iter()
        .enumerate()
        .map(|(r, &t)| (window(t), r))
        .collect();
    for (ti, m) in metas.iter().enumerate() {
        for k in super::reading_rows::baseline_readings(&power.t, m, lag, w) {
            if power.watts.get(k).is_some_and(|v| v.is_finite()) {
                all.push((window(power.t[k]), rows.len() + ti));
            }
        }
    }
    let base_power = super::meters::per_trial(power, metas, lag, w).0;
    let trial_start: Vec<f64> = metas.iter().map(|m| m.window.t_pre_start).collect();
    all.sort_by(|a, b| a.0.start.total_cmp(&b.0.start));
    let mut row_window = vec![0; rows.len()];
    let mut base_windows = vec![Vec::new(); metas.len()];
    for (i, (_, tag)) in all.iter().enumerate() {
        if *tag < rows.len() {
            row_window[*tag] = i;
        } else {
            base_windows[tag - rows.len()].push(i);
        }
    }
    let windows: Vec<fields::Window> = all.iter().map(|a| a.0).collect();
    let own = FieldSource {
        path: info.source.clone(),
        start_ns: info.start_ns,
        offset_s: 0.0,
    };
    let sources: Vec<FieldSource> = if opts.field_sources.is_empty() {
        info.source.exists().then_some(own).into_iter().collect()
    } else {
        opts.field_sources.clone()
    };
    let table = if opts.discover && !sources.is_empty() {
        fields::read_fields(&sources, &windows)
    } else {
        fields::FieldTable::default()
    };
    RowFields {
        table,
        row_window,
        base_windows,
        base_power,
        trial_start,
    }
}

/// Stage: discovery inputs (the field table and where the rows' and baselines' windows are).
pub(crate) fn field_inputs<'a>(
    f: &'a RowFields,
    opts: &'a DiagnoseOptions,
) -> discover::Inputs<'a> {
    discover::Inputs {
        fields: &f.table,
        row_window: &f.row_window,
        base_windows: &f.base_windows,
        base_power: &f.base_power,
        trial_start: &f.trial_start,
        arm_motors: opts.arm_motors,
        meter_flows: &opts.meter_flows,
    }
}
