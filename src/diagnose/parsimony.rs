//! One parsimony rule for every claim beside another (issue 28 item 4), applied once after all
//! stages to the final claim set (library hypotheses and terms found beyond the library): a
//! claim is kept only if the final model fits the held-out trials significantly better (the
//! paired test by trial at [`RIVAL_ALPHA`]) than the model without it in which EVERY other term
//! takes its flexible variant. Otherwise it is located — the remainder of the others' form —,
//! kept in the model as the best approximation, and not claimed. A true effect whose form
//! differs a little from its fitted one then leaves no remainder for a second mechanism to take.
//!
//! The flexible variant of a term with regressor g is the same for every term: g's per-joint
//! features each with its own coefficient, its driving share (g on joints that drive), a free
//! exponent (g·ln(|g|/ḡ), to first order), a threshold (the excess of |g| over ḡ) and a
//! piecewise-linear function of the state it follows (g·s and g·(s − k)₊ at the quartiles k of
//! s; session time for a term that follows none).

use anyhow::Result;

use super::select::{PowerData, RIVAL_ALPHA, Selection, r2_rmse, regressor, state, trial_sse};
use super::stats::improvement_p_value;
use super::{DiscoveryReport, HypothesisScore, MechanismForms, hypotheses::Hypothesis};
use crate::{N_JOINTS, N_PARAMS};

/// Quantiles of a state at which its piecewise-linear function may bend.
const KNOTS: [f64; 3] = [0.25, 0.5, 0.75];

/// Whether joint `i` drives on raw row `x` (τ_i q̇_i > 0).
pub(crate) fn drives(x: &[f64], i: usize) -> bool {
    x[i] > 0.0
}

/// Whether the arm as a whole drives on raw row `x` (Σ τ_i q̇_i > 0).
pub(crate) fn arm_drives(x: &[f64]) -> bool {
    (0..N_JOINTS).map(|i| x[i]).sum::<f64>() > 0.0
}

/// The flexible columns of a term with regressor `g` (per reading), its driving share `driving`
/// and the state `s` it follows (per reading), each scaled to unit RMS; columns that are zero
/// everywhere are left out.
pub(crate) fn shape_cols(g: &[f64], driving: Vec<f64>, s: &[f64]) -> Vec<Vec<f64>> {
    let n = g.len().max(1) as f64;
    let g_bar = g.iter().map(|v| v.abs()).sum::<f64>() / n;
    let sign = g.iter().sum::<f64>().signum();
    let exponent = g.iter().map(|&v| match v.abs() / g_bar {
        r if r > 0.0 && r.is_finite() => v * r.ln(),
        _ => 0.0,
    });
    let threshold = g.iter().map(|v| sign * (v.abs() - g_bar).max(0.0));
    let mut cols = vec![driving, exponent.collect(), threshold.collect()];
    if let Some((mid, knots)) = knots(s) {
        cols.push(g.iter().zip(s).map(|(v, x)| v * (x - mid)).collect());
        for k in knots {
            cols.push(g.iter().zip(s).map(|(v, x)| v * (x - k).max(0.0)).collect());
        }
    }
    unit_rms(&mut cols);
    cols
}

/// The midpoint of state `s`'s range and its distinct [`KNOTS`] strictly inside it (a knot at
/// an end would repeat the linear column); `None` for a constant state.
pub(crate) fn knots(s: &[f64]) -> Option<(f64, Vec<f64>)> {
    let mut sorted: Vec<f64> = s.iter().copied().filter(|v| v.is_finite()).collect();
    sorted.sort_by(f64::total_cmp);
    let (&lo, &hi) = (sorted.first()?, sorted.last()?);
    let mut k: Vec<f64> = KNOTS
        .map(|q| sorted[((sorted.len() - 1) as f64 * q) as usize])
        .to_vec();
    k.retain(|&v| v > lo && v < hi);
    k.dedup();
    (hi > lo).then_some((0.5 * (lo + hi), k))
}

/// Scale each column to unit RMS (non-finite values set to 0); columns zero everywhere are
/// left out.
pub(crate) fn unit_rms(cols: &mut Vec<Vec<f64>>) {
    for c in cols.iter_mut() {
        let n = c.len().max(1) as f64;
        c.iter_mut()
            .filter(|v| !v.is_finite())
            .for_each(|v| *v = 0.0);
        let rms = (c.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
        if rms > 0.0 {
            c.iter_mut().for_each(|v| *v /= rms);
        }
    }
    cols.retain(|c| c.iter().any(|v| *v != 0.0));
}

/// The flexible variant of library hypothesis `h` on the rows of `lag` (pooled by `theta`): its
/// per-joint features, then [`shape_cols`] of its regressor over session time.
fn library_flexible(
    data: &PowerData,
    h: &Hypothesis,
    theta: &[f64],
    lag: usize,
) -> Result<Vec<Vec<f64>>> {
    let rows = data.rows(lag)?;
    let (off, len) = h.raw;
    let feature = |x: &[f64; super::hypotheses::N_RAW], i: usize| x[N_PARAMS + off + i];
    let mut cols: Vec<Vec<f64>> = (0..len)
        .map(|i| rows.x.iter().map(|x| feature(x, i)).collect())
        .collect();
    let g: Vec<f64> = rows.x.iter().map(|x| regressor(h, x, theta)).collect();
    let driving = rows.x.iter().zip(&g).map(|(x, v)| match len {
        N_JOINTS => (0..N_JOINTS)
            .filter(|&i| drives(x, i))
            .map(|i| feature(x, i) * theta.get(i).copied().unwrap_or(1.0))
            .sum(),
        _ => v * f64::from(u8::from(arm_drives(x))),
    });
    cols.extend(shape_cols(&g, driving.collect(), &rows.t));
    Ok(cols)
}

/// Apply the rule to `sel`'s library claims and `report`'s found terms: a located library claim
/// leaves `sel.accepted` (a [`super::MechanismForms`] entry says why); a located found term moves
/// from `report.accepted` to `report.located` with the test in its verdict.
pub(crate) fn apply(
    data: &PowerData,
    sel: &mut Selection,
    report: Option<&mut DiscoveryReport>,
) -> Result<()> {
    let (spec, lag) = (sel.last.spec.clone(), sel.last.lag);
    let found: &[super::Discovery] = report.as_deref().map_or(&[], |r| &r.accepted);
    let n_lib = spec.len();
    let n_terms = n_lib + found.len();
    if n_terms < 2 {
        return Ok(());
    }
    let full_pred = match report.as_deref() {
        Some(r) if !r.pred.is_empty() => r.pred.clone(),
        _ => sel.last.cv.pred.clone(),
    };
    let mut flex = Vec::with_capacity(n_terms);
    for h in &spec {
        flex.push(library_flexible(data, h, &sel.last.full.theta, lag)?);
    }
    flex.extend(found.iter().map(|d| d.flexible.clone()));
    let names: Vec<String> = (spec.iter().map(|h| h.mechanism.to_string()))
        .chain(found.iter().map(|d| d.name.clone()))
        .collect();
    let bare = state(data, Vec::new(), lag)?;
    let base = super::discover::Base::new(data, &bare)?;
    let rows = data.rows(lag)?;
    let sse = |pred: &[f64]| trial_sse(&rows.y, pred, &rows.trial, data.n_trials);
    let rmse = |pred: &[f64]| r2_rmse(&rows.y, pred).1;
    let e_full = sse(&full_pred);
    let claimed = (0..n_lib).filter(|&j| sel.accepted.iter().any(|a| a.id == spec[j].id));
    let mut located = Vec::new();
    for k in claimed.chain(n_lib..n_terms) {
        let others: Vec<usize> = (0..n_terms).filter(|&o| o != k).collect();
        let cols: Vec<&Vec<f64>> = others.iter().flat_map(|&o| &flex[o]).collect();
        let pred = base.fit(&cols)?.pred;
        let d: Vec<f64> = sse(&pred).iter().zip(&e_full).map(|(a, b)| a - b).collect();
        let p_value = improvement_p_value(&d);
        if p_value < RIVAL_ALPHA {
            continue;
        }
        let words: Vec<&str> = others.iter().map(|&o| names[o].as_str()).collect();
        let test = Remainder {
            of: words.join(" and "),
            rmse: [rmse(&full_pred), rmse(&pred)],
            p_value,
        };
        located.push((k, test));
    }
    for (k, test) in located.iter().filter(|(k, _)| *k < n_lib) {
        sel.forms.push(test.form(&sel.accepted, spec[*k].id));
    }
    super::select::unname_all(sel);
    if let Some(r) = report {
        for (k, test) in located.iter().rev().filter(|(k, _)| *k >= n_lib) {
            let mut d = r.accepted.remove(k - n_lib);
            d.verdict = format!("{}; {}", test.words(), d.verdict);
            r.located.insert(0, d);
        }
    }
    Ok(())
}

/// The test that located a claim as the remainder of other terms' form.
struct Remainder {
    /// The other terms, in words.
    of: String,
    /// Held-out RMSE [W] of the final model and of the one without the claim, others flexible.
    rmse: [f64; 2],
    /// One-sided paired p-value that the final model fits better.
    p_value: f64,
}

impl Remainder {
    fn words(&self) -> String {
        format!(
            "located — the remainder of the form of {}, not claimed: without it, with {} in \
             flexible form, the held-out RMSE is {:.3} W against {:.3} W (p = {:.2} ≥ {RIVAL_ALPHA})",
            self.of, self.of, self.rmse[1], self.rmse[0], self.p_value
        )
    }

    /// The located library claim `id` as an unnamed form (its score from `accepted`).
    fn form(&self, accepted: &[HypothesisScore], id: &str) -> MechanismForms {
        let s = accepted.iter().find(|a| a.id == id);
        let mechanism = super::hypotheses::power_hypothesis(id).map_or(id, |h| h.mechanism);
        let words = format!("the remainder of the form of {}", self.of);
        MechanismForms {
            mechanism: format!("{mechanism} or {words}"),
            winner: id.to_string(),
            runner_up: format!("{}, flexible", self.of),
            rmse_w: self.rmse,
            margin: 1.0 - self.rmse[0] / self.rmse[1].max(1e-300),
            p_value: self.p_value,
            accepted: true,
            form_words: [mechanism.to_string(), words],
            params: [s.map(|s| s.params.clone()).unwrap_or_default(), Vec::new()],
            confounded: true,
            unnamed: true,
            partial_r: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::hypotheses::Sample;
    use super::super::select::select;
    use super::super::select::tests::{RULE, synth};
    use super::*;

    #[test]
    fn a_second_mechanism_taking_a_misfitted_forms_remainder_is_located() {
        // A DC-bus loss with exponent 1.6 (the library fits 2): forward selection claims the
        // drive-electronics loss per ampere beside the per-ampere² bus loss, which together
        // approximate I^1.6; each is the other's remainder under a free exponent.
        let k = crate::power::JOINT_TORQUE_CONSTANT;
        let all: Vec<_> = super::super::hypotheses::POWER_HYPOTHESES.iter().collect();
        let bus = move |s: &Sample| {
            let i: f64 = (0..7).map(|j| s.tau[j].abs() / k[j]).sum();
            0.15 * i.powf(1.6)
        };
        for seed in 1..3 {
            let data = synth(seed, 80, &bus);
            let mut sel = select(&data, &all, &RULE).unwrap();
            assert_eq!(
                sel.accepted.len(),
                2,
                "the case: two claims before the rule"
            );
            apply(&data, &mut sel, None).unwrap();
            assert!(sel.accepted.len() < 2, "{:?}", sel.accepted);
            let located = sel.forms.iter().filter(|f| f.unnamed);
            assert!(
                located
                    .clone()
                    .any(|f| f.mechanism.contains("the remainder of"))
            );
            assert!(located.clone().all(|f| f.p_value >= RIVAL_ALPHA));
        }
    }
}
