//! One rule for every claim (issue 28 item 4), applied once after all stages to the final claim
//! set (library hypotheses, latency, terms found beyond the library): a claim is kept only if
//! the final model fits the held-out trials significantly better (the paired test by trial at
//! [`RIVAL_ALPHA`]) than the model without it in which EVERY other term takes its flexible
//! variant, by the held-out gain every candidate must show, and only if that test passes in at
//! least [`STABLE`] of bootstrap resamples of the trials. A claim that passes must also beat, in
//! its place, each of its rivals: the flexible variant of every other library mechanism,
//! modulated by the state the claim follows (session time for a library claim or a latency; a
//! found loss term's own signal) — a neighbouring mechanism otherwise absorbs a form the
//! library does not fit exactly (a per-joint gear friction told as braking, a one-sided copper
//! drift as drive electronics). Otherwise it is located ("X or Y"), kept in the model as the
//! best approximation, and not claimed. One test so answers "a second mechanism beside a
//! first?", "which mechanism?" and "stable?"; each claim's share of resamples is reported as its
//! stability.
//!
//! The flexible variant of a term with regressor g is the same for every term: g's per-joint
//! features each with its own coefficient (and on each joint's driving side), its driving share
//! (g on joints that drive), a free exponent (g·ln(|g|/ḡ), to first order), a threshold (the
//! excess of |g| over ḡ) and a piecewise-linear function of the state it follows (g·s and
//! g·(s − k)₊ at the quartiles k of s; session time for a term that follows none).

use anyhow::Result;

use super::flexible::{arm_drives, drives, shape_cols, state_cols, unit_rms};
use super::hypotheses::{
    Hypothesis, LATENCY_ID, POWER_HYPOTHESES, RAW_DRIVING_COPPER, driving_side_only,
    driving_side_raw,
};
use super::select::{
    PowerData, RIVAL_ALPHA, Rule, Selection, r2_rmse, regressor, state, trial_sse,
};
use super::stats::{
    EXTENDS, STABILITY_DRAWS, encompassing, improvement_p_value, resampled_stability,
};
use super::stepwise::STABLE;
use super::{DiscoveryReport, HypothesisScore, MechanismForms};
use crate::{N_JOINTS, N_PARAMS};

/// Columns of regressors, one value per reading each.
type Cols = Vec<Vec<f64>>;

/// The flexible variant of library hypothesis `h` on the rows of `lag` (pooled by `theta`): its
/// per-joint features (for the gear friction |τ_i q̇_i|) and, for a per-joint mechanism, each
/// on the joint's driving side, then [`shape_cols`] of its regressor over the state `s` (per
/// reading); and apart, its forms on the driving side alone (its driving share; each joint's
/// driving side, for a per-joint mechanism). A mechanism's flexible variant is that of every
/// form of it ([`rival_variants`]).
fn library_flexible(
    data: &PowerData,
    h: &Hypothesis,
    theta: &[f64],
    lag: usize,
    s: &[f64],
) -> Result<(Cols, Vec<Cols>)> {
    let rows = data.rows(lag)?;
    let (off, len) = h.raw;
    let feature = |x: &[f64; super::hypotheses::N_RAW], i: usize| x[N_PARAMS + off + i];
    let mut cols: Vec<Vec<f64>> = (0..len)
        .map(|i| rows.x.iter().map(|x| feature(x, i)).collect())
        .collect();
    let mut driving_side: Vec<Cols> = Vec::new();
    if len == N_JOINTS {
        let on_drive = |i| {
            rows.x
                .iter()
                .map(move |x| feature(x, i) * f64::from(u8::from(drives(x, i))))
        };
        driving_side.push((0..N_JOINTS).map(|i| on_drive(i).collect()).collect());
        cols.extend(driving_side[0].iter().cloned());
    }
    if h.id == "gear_friction" {
        cols.extend((0..N_JOINTS).map(|i| rows.x.iter().map(|x| x[i].abs()).collect()));
    }
    let g: Vec<f64> = rows.x.iter().map(|x| regressor(h, x, theta)).collect();
    let driving: Vec<f64> = rows
        .x
        .iter()
        .zip(&g)
        .map(|(x, v)| match len {
            N_JOINTS => (0..N_JOINTS)
                .filter(|&i| drives(x, i))
                .map(|i| feature(x, i) * h.weight(theta, i))
                .sum(),
            // a pooled feature's own driving side, sample by sample, where the library has it
            _ => driving_side_raw(h).map_or(v * f64::from(u8::from(arm_drives(x))), |r| x[r]),
        })
        .collect();
    driving_side.push(vec![driving.clone()]);
    cols.extend(shape_cols(&g, driving, s));
    Ok((cols, driving_side))
}

/// A rival no library mechanism has: the base model's terms split on their driving side — the
/// transmitted power's efficiency on its driving side changing with the claim's state, which a
/// constant braking asymmetry would otherwise stand in for (issue 28 item 4), and each joint's
/// copper loss while it drives, which a one-sided mechanism (a temperature drift of the driving
/// joints at a nearly constant temperature) would otherwise stand in for. The braking side
/// changing is not a rival: it is the braking asymmetry's own flexible form.
const SPLIT: &str = "base model's terms on their driving side (copper loss, efficiency changing with the same state)";

/// [`SPLIT`]'s columns: the driving share of Σ τ_i q̇_i times the piecewise-linear function of
/// the state `s` without its constant (a constant split is the braking asymmetry itself), and
/// each joint's τ_i² while it drives.
fn split_by(x: &[[f64; super::hypotheses::N_RAW]], s: &[f64]) -> Vec<Vec<f64>> {
    let g: Vec<f64> = (x.iter())
        .map(|x| (0..N_JOINTS).map(|i| x[i].max(0.0)).sum())
        .collect();
    let mut cols = state_cols(&g, s);
    cols.extend((0..N_JOINTS).map(|i| x.iter().map(|x| x[RAW_DRIVING_COPPER + i]).collect()));
    unit_rms(&mut cols);
    cols
}

/// A rival a claim must answer in its place.
enum Rival {
    /// The best other library mechanism the data supported beside a library claim at its step,
    /// in its library form: the claim must fit significantly better.
    Plain(&'static Hypothesis),
    /// Another library mechanism's forms in flexible variant, modulated by the state the claim
    /// follows: the claim must fit significantly better — unless the variant contains the
    /// claim's own form (with each joint's efficiency refitted, the per-joint gear friction and
    /// braking asymmetry span the same columns), which cannot be beaten: then it must not fit
    /// significantly better (many more parameters that fit no better are no evidence for their
    /// mechanism).
    /// With `true` (a claim on the driving side alone), each of its forms on the driving side
    /// alone is a rival too ([`rival_variants`]).
    Flexible(&'static str, Vec<&'static Hypothesis>, bool),
    /// [`SPLIT`]: the claim must fit significantly better.
    Split,
}

/// The rivals of a claim of mechanism `own`: `plain` (the library's supported rival), every
/// other library mechanism but those of `skip` in flexible form (`plain`'s first), then, when
/// `split`, [`SPLIT`].
fn rivals(
    own: &str,
    skip: &[&'static Hypothesis],
    plain: Option<&'static Hypothesis>,
    split: bool,
) -> Vec<Rival> {
    // One entry per mechanism, at its first form.
    let mut out: Vec<_> = (POWER_HYPOTHESES.iter())
        .filter(|h| std::ptr::eq(forms_of(h)[0], *h) && h.mechanism != own)
        .filter(|h| skip.iter().all(|k| k.mechanism != h.mechanism))
        .map(|h| (h.mechanism, forms_of(h)))
        .collect();
    out.sort_by_key(|(m, _)| plain.is_none_or(|p| p.mechanism != *m));
    let flexible = out.into_iter().map(|(m, f)| Rival::Flexible(m, f, false));
    (plain.map(Rival::Plain).into_iter())
        .chain(flexible)
        .chain(split.then_some(Rival::Split))
        .collect()
}

/// Every form of `h`'s mechanism in the library.
fn forms_of(h: &Hypothesis) -> Vec<&'static Hypothesis> {
    POWER_HYPOTHESES
        .iter()
        .filter(|g| g.mechanism == h.mechanism)
        .collect()
}

/// A rival's columns on the rows of `lag`: its forms' flexible variants modulated by the state
/// `s` the claim follows ([`SPLIT`]'s for none).
fn rival_cols(
    data: &PowerData,
    forms: &[&'static Hypothesis],
    theta: &[f64],
    lag: usize,
    s: &[f64],
) -> Result<Vec<Vec<f64>>> {
    Ok(rival_variants(data, forms, theta, (lag, s), false)?.swap_remove(0))
}

/// A rival's columns as [`rival_cols`] (first) and, for a claim on the driving side alone
/// (`one_sided`), each of its forms on the driving side alone ([`library_flexible`], unit RMS):
/// a one-sided claim must beat the rival's own one-sided forms, not only its whole flexible
/// variant — dozens of free columns, which the held-out test charges for, so that a claim of
/// one parameter beat it where the rival's driving side alone fits as well (a driving-side
/// drive-electronics loss claimed as the winding-resistance drift of the driving joints, fuzz
/// seed 1676948751).
fn rival_variants(
    data: &PowerData,
    forms: &[&'static Hypothesis],
    theta: &[f64],
    (lag, s): (usize, &[f64]),
    one_sided: bool,
) -> Result<Vec<Cols>> {
    if forms.is_empty() {
        return Ok(vec![split_by(&data.rows(lag)?.x, s)]);
    }
    let mut out = vec![Vec::new()];
    for h in forms {
        let (whole, driving_side) = library_flexible(data, h, theta, lag, s)?;
        out[0].extend(whole);
        if one_sided {
            out.extend(driving_side);
        }
    }
    for v in &mut out {
        unit_rms(v);
    }
    Ok(out)
}

/// Relative change of a rival's held-out RMSE below which adding the claim's own column to it
/// changes nothing: the rival's flexible variant contains the claim's form.
const NESTED: f64 = 1e-4;

/// Apply the rule to `sel`'s library claims (latency included) and `report`'s found terms, and
/// record each claim's stability: a located library claim leaves `sel.accepted` (a
/// [`super::MechanismForms`] entry says why); a located found term moves from `report.accepted`
/// to `report.located` with the test in its verdict. Returns the library claims that failed the
/// test beside found terms (not their rival pairing): the caller drops them and selects again.
pub(crate) fn apply(
    data: &PowerData,
    sel: &mut Selection,
    report: Option<&mut DiscoveryReport>,
    rule: &Rule,
) -> Result<Vec<(&'static Hypothesis, f64, f64)>> {
    let (spec, lag) = (sel.last.spec.clone(), sel.last.lag);
    let found: &[super::Discovery] = report.as_deref().map_or(&[], |r| &r.accepted);
    let (n_lib, n_terms) = (spec.len(), spec.len() + found.len());
    let full_pred = match report.as_deref() {
        Some(r) if !r.pred.is_empty() => r.pred.clone(),
        _ => sel.last.cv.pred.clone(),
    };
    let rows = data.rows(lag)?;
    let judge = Judge {
        data,
        rows,
        theta: sel.last.full.theta.clone(),
        e_full: trial_sse(&rows.y, &full_pred, &rows.trial, data.n_trials),
        full_pred,
        min_gain: rule.min_improvement,
    };
    let mut flex = (spec.iter())
        .map(|h| rival_cols(data, &forms_of(h), &judge.theta, lag, &rows.t))
        .collect::<Result<Vec<_>>>()?;
    flex.extend(found.iter().map(|d| d.flexible.clone()));
    let names: Vec<String> = (spec.iter().map(|h| h.mechanism.to_string()))
        .chain(found.iter().map(|d| d.name.clone()))
        .collect();
    let claimed = |id: &str| sel.accepted.iter().any(|a| a.id == id);
    let bare = state(data, Vec::new(), lag)?;
    let base = super::discover::Base::new(data, &bare)?;
    let mut tests: Vec<(usize, Remainder)> = Vec::new();
    for k in (0..n_lib)
        .filter(|&j| claimed(spec[j].id))
        .chain(n_lib..n_terms)
    {
        let others: Vec<usize> = (0..n_terms).filter(|&o| o != k).collect();
        let cols: Vec<&Vec<f64>> = others.iter().flat_map(|&o| &flex[o]).collect();
        let words: Vec<&str> = others.iter().map(|&o| names[o].as_str()).collect();
        let pred = base.fit(&cols)?.pred;
        let t = judge.test(&pred, remainder_of(&words), None, k, rule.alpha);
        let (list, s, own) = claim_rivals(sel, &spec, found, k, rows, &judge.theta);
        tests.push((k, judge.against(t, &base, &cols, list, (lag, s, k, own))?));
    }
    // A latency must beat the same terms at no lag in flexible form, and beside them each
    // other library mechanism's flexible variant (a misfitted loss's remainder lags its cause).
    if claimed(LATENCY_ID) && lag > 0 {
        let t0 = &data.rows(0)?.t;
        let mut flex0 = Vec::new();
        for h in &spec {
            flex0.extend(rival_cols(data, &forms_of(h), &judge.theta, 0, t0)?);
        }
        let cols: Vec<&Vec<f64>> = flex0.iter().chain(flex[n_lib..].iter().flatten()).collect();
        let bare0 = state(data, Vec::new(), 0)?;
        let base0 = super::discover::Base::new(data, &bare0)?;
        let of = "the same terms at no lag, in flexible form".to_string();
        let t = judge.test(&base0.fit(&cols)?.pred, of, None, n_terms, rule.alpha);
        let list = rivals(LATENCY_ID, &spec, None, false);
        let t = judge.against(t, &base0, &cols, list, (0, t0, n_terms, None))?;
        tests.push((usize::MAX, t));
    }
    let by_found = record(sel, report, &tests, &spec, n_lib, n_terms);
    Ok(by_found)
}

/// The final model's held-out fit, against which [`apply`] tests every claim.
struct Judge<'a, 'd> {
    data: &'a PowerData<'d>,
    rows: &'a super::reading_rows::Rows,
    theta: Vec<f64>,
    /// The final model's held-out prediction and its squared error per trial.
    full_pred: Vec<f64>,
    e_full: Vec<f64>,
    min_gain: f64,
}

impl Judge<'_, '_> {
    fn rmse(&self, pred: &[f64]) -> f64 {
        r2_rmse(&self.rows.y, pred).1
    }

    /// The test of claim `k`: the final model against `alt`, the model without it (`of` says
    /// what stands in its place, `rival` the mechanism among it).
    fn test(
        &self,
        alt: &[f64],
        of: String,
        rival: Option<&'static str>,
        k: usize,
        level: f64,
    ) -> Remainder {
        let rows = self.rows;
        let e = trial_sse(&rows.y, alt, &rows.trial, self.data.n_trials);
        // Against the model without it, which the final model extends, the evidence is the
        // selection gate's (`EXTENDS`); between alternatives, the squared-error difference.
        let d: Vec<f64> = match of.is_empty() {
            true => encompassing(
                &rows.y,
                (&self.full_pred, alt),
                &rows.trial,
                self.data.n_trials,
                EXTENDS,
            ),
            false => e.iter().zip(&self.e_full).map(|(a, b)| a - b).collect(),
        };
        let (seed, gate) = (0x5eed_0000 + k as u64, (RIVAL_ALPHA, 0.0));
        let worse: Vec<f64> = d.iter().map(|v| -v).collect();
        Remainder {
            of,
            rival,
            rmse: [self.rmse(&self.full_pred), self.rmse(alt)],
            p_value: improvement_p_value(&d),
            p_rival: improvement_p_value(&worse),
            beaten: false,
            held: resampled_stability((&e, &self.e_full, &d), gate, STABILITY_DRAWS, seed),
            min_gain: self.min_gain,
            level,
        }
    }

    /// A claim that passes must also beat each rival in its place (others flexible, on `base`
    /// with columns `cols`), at RIVAL_ALPHA: the first it does not beat makes it "X or Y".
    fn against(
        &self,
        mut t: Remainder,
        base: &super::discover::Base,
        cols: &[&Vec<f64>],
        list: Vec<Rival>,
        (l, s, k, own): (usize, &[f64], usize, Option<Vec<f64>>),
    ) -> Result<Remainder> {
        let x = &self.data.rows(l)?.x;
        for r in &list {
            let (name, extras) = match r {
                Rival::Plain(h) => {
                    let col = x.iter().map(|x| regressor(h, x, &self.theta)).collect();
                    (h.mechanism, vec![vec![col]])
                }
                Rival::Flexible(m, forms, one_sided) => (
                    *m,
                    rival_variants(self.data, forms, &self.theta, (l, s), *one_sided)?,
                ),
                Rival::Split => (SPLIT, vec![split_by(x, s)]),
            };
            for extra in &extras {
                if !t.claimed() || s.is_empty() {
                    return Ok(t);
                }
                let mut alt_cols: Vec<&Vec<f64>> = cols.iter().copied().chain(extra).collect();
                let alt = base.fit(&alt_cols)?;
                let mut v = self.test(&alt.pred, format!("the {name}"), Some(name), k, RIVAL_ALPHA);
                (v.held, v.min_gain) = (t.held, 0.0);
                // A flexible variant that contains the claim's form (adding the claim changes
                // its fit by nothing) cannot be beaten: there the claim is lost only if it fits
                // significantly better.
                if let (Rival::Flexible(..), Some(own)) = (r, &own) {
                    alt_cols.push(own);
                    let with_own = self.rmse(&base.fit(&alt_cols)?.pred);
                    v.beaten = (1.0 - with_own / self.rmse(&alt.pred)).abs() < NESTED;
                }
                if !v.claimed() {
                    t = v;
                }
            }
        }
        Ok(t)
    }
}

/// The rivals of claim `k` (library claims first, then found terms), the state their flexible
/// variants follow and the claim's own contribution per reading (`None` if unknown): every other
/// library mechanism in flexible form, modulated by the state the claim follows — session time
/// for a library claim (after the one the data supported beside it first, then the driving
/// efficiency changing), a found loss term's own signal (a rail load has none).
fn claim_rivals<'a>(
    sel: &Selection,
    spec: &[&'static Hypothesis],
    found: &'a [super::Discovery],
    k: usize,
    rows: &'a super::reading_rows::Rows,
    theta: &[f64],
) -> (Vec<Rival>, &'a [f64], Option<Vec<f64>>) {
    let n_lib = spec.len();
    let (list, s) = match k < n_lib {
        true => {
            let plain = (sel.rivals.iter())
                .find(|(id, r)| {
                    id == spec[k].id && !spec.iter().any(|h| h.mechanism == r.mechanism)
                })
                .map(|(_, r)| *r);
            let mut list = rivals(spec[k].mechanism, spec, plain, true);
            if driving_side_only(spec[k]) {
                for r in &mut list {
                    if let Rival::Flexible(_, _, one_sided) = r {
                        *one_sided = true;
                    }
                }
            }
            (list, rows.t.as_slice())
        }
        false => {
            let d = &found[k - n_lib];
            let own = (d.mechanism.as_deref())
                .and_then(super::hypotheses::power_hypothesis)
                .map_or("", |h| h.mechanism);
            let s = match d.follows.len() == rows.len() {
                true => d.follows.as_slice(),
                false => &[],
            };
            (rivals(own, &[], None, false), s)
        }
    };
    let own: Vec<f64> = match k < n_lib {
        true => (rows.x.iter())
            .map(|x| regressor(spec[k], x, theta))
            .collect(),
        false => found[k - n_lib].contribution.clone(),
    };
    (list, s, (own.len() == rows.len()).then_some(own))
}

/// Record each test's outcome: stability on every claim, a located library claim's form (it leaves
/// the accepted list), a located found term moved to `report.located`. Returns the library claims
/// a found term leaves without support (not their rival pairing).
fn record(
    sel: &mut Selection,
    report: Option<&mut DiscoveryReport>,
    tests: &[(usize, Remainder)],
    spec: &[&'static Hypothesis],
    n_lib: usize,
    n_terms: usize,
) -> Vec<(&'static Hypothesis, f64, f64)> {
    for (k, t) in tests {
        let lib = *k < n_lib || *k == usize::MAX;
        let id = spec.get(*k).map_or(LATENCY_ID, |h| h.id);
        if let Some(a) = sel.accepted.iter_mut().find(|a| lib && a.id == id) {
            a.stability = Some(t.held);
        }
        if lib && !t.claimed() {
            sel.forms.push(t.form(&sel.accepted, id));
        }
    }
    let by_found = (tests.iter())
        .filter(|(k, t)| *k < n_lib && n_terms > n_lib && !t.claimed() && t.rival.is_none())
        .map(|(k, t)| (spec[*k], t.p_value, t.gain()))
        .collect();
    super::select::unname(&mut sel.forms, &mut sel.accepted, &mut sel.first_step);
    if let Some(r) = report {
        for (k, t) in tests
            .iter()
            .rev()
            .filter(|(k, _)| (n_lib..n_terms).contains(k))
        {
            let d = &mut r.accepted[k - n_lib];
            d.stability = Some(t.held);
            if !t.claimed() {
                let mut d = r.accepted.remove(k - n_lib);
                d.verdict = format!("{}; {}", t.words(), d.verdict);
                // "X or Y": a rival mechanism that fits as well is named beside it.
                if let Some(rival) = t.rival {
                    d.name = format!("{} — or the {rival}: not told apart", d.name);
                }
                r.located.insert(0, d);
            }
        }
    }
    by_found
}

/// What stands in a claim's place when the other terms `words` take their flexible variants
/// (empty: nothing).
fn remainder_of(words: &[&str]) -> String {
    match words {
        [] => String::new(),
        w => format!("the remainder of the form of {}", w.join(" and ")),
    }
}

/// The test of a claim against the model without it, every other term flexible. Its resamples
/// ask whether the evidence holds, not whether the size stays above the gain gate: a claim whose
/// whole-data gain sits at the gate would pass about half of them by construction (the
/// paper-scale bus loss at its detection limit: 2.03 %, 52 %).
struct Remainder {
    /// What stands in its place, in words (empty: nothing).
    of: String,
    /// The rival mechanism among it, if any.
    rival: Option<&'static str>,
    /// Held-out RMSE [W] of the final model and of the one without the claim.
    rmse: [f64; 2],
    /// One-sided paired p-value that the final model fits better.
    p_value: f64,
    /// The same, that the model without the claim fits better.
    p_rival: f64,
    /// The claim is lost only if the model without it fits significantly better (a flexible
    /// rival that contains the claim's form, [`Rival::Flexible`]).
    beaten: bool,
    /// Share of trial resamples in which the test passes.
    held: f64,
    /// Held-out RMSE gain over the model without it that the claim must show.
    min_gain: f64,
    /// Level of the test.
    level: f64,
}

impl Remainder {
    /// Held-out RMSE gain of the final model over the one without the claim.
    fn gain(&self) -> f64 {
        1.0 - self.rmse[0] / self.rmse[1].max(1e-300)
    }

    /// Whether the claim passes: significant and stable under resampling of the trials.
    fn claimed(&self) -> bool {
        match self.beaten {
            true => self.p_rival >= self.level,
            false => {
                self.p_value < self.level && self.gain() >= self.min_gain && self.held >= STABLE
            }
        }
    }

    /// "X or Y": the claim's mechanism `m` or what stands in its place; a claim without any is
    /// only its form, with the gate it failed.
    fn either(&self, m: &str) -> String {
        let failed = match () {
            _ if self.p_value >= self.level || self.p_value.is_nan() => {
                "not significant against the model without it"
            }
            _ if self.gain() < self.min_gain => "below the held-out gain a claim must show",
            _ => "not stable under resampling of the trials",
        };
        match self.of.is_empty() {
            true => format!("form of {m}, {failed}"),
            false => format!("{m} or {}", self.of),
        }
    }

    fn words(&self) -> String {
        if self.beaten {
            return format!(
                "located — not claimed: without it, {} fits the held-out trials better, at RMSE \
                 {:.3} W against {:.3} W (p = {:.1e} < {:.0e})",
                self.of, self.rmse[1], self.rmse[0], self.p_rival, self.level
            );
        }
        format!(
            "located — not claimed: without it, {} fits the held-out trials at RMSE {:.3} W \
             against {:.3} W (p = {:.1e}, needed < {:.0e} and a {:.0} % gain; held in {:.0} % \
             of {STABILITY_DRAWS} resamples of the trials, needed ≥ {:.0} %)",
            if self.of.is_empty() {
                "the model"
            } else {
                &self.of
            },
            self.rmse[1],
            self.rmse[0],
            self.p_value,
            self.level,
            100.0 * self.min_gain,
            100.0 * self.held,
            100.0 * STABLE
        )
    }

    /// The located library claim `id` as an unnamed form (its score from `accepted`).
    fn form(&self, accepted: &[HypothesisScore], id: &str) -> MechanismForms {
        let s = accepted.iter().find(|a| a.id == id);
        let mechanism = super::hypotheses::power_hypothesis(id).map_or(id, |h| h.mechanism);
        // A claim beside no other term is tested against the model without it.
        let without = match self.of.is_empty() {
            true => "the model without it".to_string(),
            false => self.of.clone(),
        };
        MechanismForms {
            mechanism: self.either(mechanism),
            winner: id.to_string(),
            runner_up: without.clone(),
            rmse_w: self.rmse,
            margin: self.gain(),
            p_value: self.p_value,
            accepted: true,
            form_words: [
                mechanism.to_string(),
                self.rival.map_or(without, str::to_string),
            ],
            params: [s.map(|s| s.params.clone()).unwrap_or_default(), Vec::new()],
            confounded: true,
            unnamed: true,
            stability: Some(self.held),
            level: self.level,
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
            apply(&data, &mut sel, None, &RULE).unwrap();
            assert!(sel.accepted.len() < 2, "{:?}", sel.accepted);
            let located = sel.forms.iter().filter(|f| f.unnamed);
            assert!(
                located
                    .clone()
                    .any(|f| f.mechanism.contains("the remainder of"))
            );
            // Not significant at the rule's level beside the other's flexible variant (that of
            // every form of its mechanism).
            assert!(located.clone().all(|f| f.p_value >= RULE.alpha));
        }
    }
}
