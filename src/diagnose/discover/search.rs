//! The search over the candidates: each scored on top of the chosen terms with the gates of
//! the hypotheses at its family-first level, and a scored candidate turned into a
//! [`Discovery`].

use anyhow::Result;

use super::candidates::{
    Cand, Inputs, Kind, LOADS, RowValues, Signal, columns, generate, signal_values,
};
use super::fit::{Base, ExtFit};
use super::found::Discovery;
use super::words::describe;
use crate::N_JOINTS;
use crate::diagnose::Quality;
use crate::diagnose::family::Term;
use crate::diagnose::flexible::{arm_drives, drives, knots, shape_cols, unit_rms};
use crate::diagnose::select::{self, PowerData, Rule, State, jackknife_se};
use crate::diagnose::stepwise::{self, Gated, holm_level, not_significant};

/// A scored candidate.
pub(super) struct Scored {
    pub(super) idx: usize,
    pub(super) fit: ExtFit,
    pub(super) p: f64,
    pub(super) rel: f64,
    pub(super) d_bic: f64,
    pub(super) before: Quality,
    pub(super) after: Quality,
    pub(super) plausible: bool,
}

impl Gated for Scored {
    fn gated(&self) -> (f64, f64, f64) {
        (self.p, self.d_bic, self.rel)
    }
}

/// Forward selection over the candidates at the Holm level; returns the accepted (step,
/// score) pairs and the best rejected candidate of the first step.
pub(super) struct Search<'a, 'd> {
    pub(super) base: Base<'a, 'd>,
    pub(super) cands: Vec<Cand>,
    pub(super) rv: RowValues,
    pub(super) inp: &'a Inputs<'a>,
    pub(super) rule: Rule,
    /// Candidates generated (screened out or not).
    pub(super) m: usize,
    /// Total Holm weight of each mechanism family's generated candidates ([`super::candidates::family_of`]).
    pub(super) fam_total: Vec<f64>,
}

impl<'a, 'd> Search<'a, 'd> {
    /// The search on model `cur`: its design, and the candidates generated and screened on its
    /// residual ([`generate`]; notes on fields left out go to `notes`); also which fields are
    /// tried (not meters of the power, not duplicates).
    pub(super) fn new(
        data: &'a PowerData<'d>,
        cur: &'a State,
        inp: &'a Inputs<'a>,
        rule: &Rule,
        notes: &mut Vec<String>,
    ) -> Result<(Self, Vec<bool>)> {
        let base = Base::new(data, cur)?;
        let rows = base.rows;
        let resid: Vec<f64> = rows
            .y
            .iter()
            .zip(&cur.cv.pred)
            .map(|(y, p)| y - p)
            .collect();
        let twin = data.reference.is_some();
        let (cands, rv, usable, m, fam_total) =
            generate(inp, rows, data.n_trials, twin, &resid, notes);
        let search = Search {
            base,
            cands,
            rv,
            inp,
            rule: *rule,
            m,
            fam_total,
        };
        Ok((search, usable))
    }

    /// RMS of the readings: what no candidate may explain more than.
    pub(super) fn y_rms(&self) -> f64 {
        let y = &self.base.rows.y;
        (y.iter().map(|v| v * v).sum::<f64>() / y.len().max(1) as f64).sqrt()
    }

    pub(super) fn cols(&self, i: usize) -> Vec<Vec<f64>> {
        columns(&self.cands[i].kind, self.inp, &self.rv, self.base.rows)
    }

    /// Candidate `i`'s level in one weighted Bonferroni over every candidate generated (the
    /// library rivals' test, [`super::rival_of`]).
    pub(super) fn flat_level(&self, i: usize) -> f64 {
        self.rule.alpha * self.cands[i].weight / self.fam_total.iter().sum::<f64>()
    }

    /// Mechanism families with candidates: what the family-first Holm runs over.
    pub(super) fn n_families(&self) -> usize {
        self.fam_total.iter().filter(|&&w| w > 0.0).count()
    }

    /// Holm over the families: the level of the best remaining family at `step`.
    pub(super) fn family_level(&self, step: usize) -> f64 {
        holm_level(self.rule.alpha, self.n_families(), step)
    }

    /// Candidate `i`'s level at `step`, family first. A loss-term family has two tests at half
    /// its Holm level each: its block test ([`Self::block`]; `open` when it passed) and its best
    /// member against a Bonferroni over the family's weight; the rail loads have the second only,
    /// at the whole level. In an open family a member on a recorded state is judged at the
    /// family's level (which state and form is a selection within a family shown to act, guarded
    /// by the other gates); a member on session time, or in a family not open, at its Bonferroni
    /// share.
    pub(super) fn member_level(&self, i: usize, step: usize, open: bool) -> f64 {
        let c = &self.cands[i];
        let level = self.family_level(step);
        if open && !matches!(c.kind, Kind::Product(_, Signal::Time, _)) {
            return level;
        }
        let share = if c.family == LOADS { 1.0 } else { 0.5 };
        level * share * c.weight / self.fam_total[c.family].max(c.weight)
    }

    /// The family test of loss term `t` on the model so far (its columns `prev`): the term
    /// pooled times a piecewise-linear function of session time (knots at its quartiles) beside
    /// the term alone, paired held-out by trial.
    pub(super) fn block(&self, t: Term, prev: &[Vec<f64>]) -> Option<Scored> {
        let hours = &self.rv.hours;
        let (mid, knots) = knots(hours)?;
        let g = self.rv.pooled(t);
        let hinge = |k: f64, lo: f64| g.iter().zip(hours).map(move |(v, h)| v * (h - k).max(lo));
        let mut own = vec![g.clone(), hinge(mid, f64::NEG_INFINITY).collect()];
        own.extend(knots.iter().map(|&k| hinge(k, 0.0).collect()));
        let fit = |n: usize| {
            let cols: Vec<&Vec<f64>> = prev.iter().chain(&own[..n]).collect();
            self.base.fit(&cols).ok()
        };
        let (alone, fit) = (fit(1)?, fit(own.len())?);
        let (p, rel, before, after) = self.base.compare(&alone.pred, &fit.pred);
        Some(Scored {
            idx: 0,
            d_bic: fit.bic - alone.bic,
            fit,
            p,
            rel,
            before,
            after,
            plausible: true,
        })
    }

    /// Score candidate `i` on top of the chosen columns `prev` (current predictions and BIC).
    pub(super) fn score(
        &self,
        i: usize,
        prev: &[Vec<f64>],
        cur: (&[f64], f64),
        y_rms: f64,
    ) -> Option<Scored> {
        let own = self.cols(i);
        let mut cols: Vec<&Vec<f64>> = prev.iter().collect();
        cols.extend(own.iter());
        // A candidate whose fit fails (a degenerate column) is not a discovery.
        let fit = self.base.fit(&cols).ok()?;
        let (p, rel, before, after) = self.base.compare(cur.0, &fit.pred);
        let n = self.base.rows.len().max(1) as f64;
        // A loss the model lacks (a one-sided form of a library mechanism, on its own or
        // changing with a signal) draws power: a negative coefficient — for a term × signal, a
        // negative coefficient of the plain term that best reproduces what it adds — is another
        // term's remainder, not that loss. A term × a nearly constant signal is a free level:
        // the braking side's current times an IMU angle, its level negative, stood in for the
        // driving side's loss (fuzz seed 1088541151).
        let level = match self.cands[i].kind {
            Kind::Pooled(t) | Kind::Product(t, ..) if t.level_is_new() => Some(self.rv.pooled(t)),
            _ => None,
        };
        // What it adds per reading: the sum of squares, and the projection on that level.
        let (mut contrib, mut on_level) = (0.0, 0.0);
        for r in 0..self.base.rows.len() {
            let a: f64 = (own.iter().enumerate())
                .map(|(j, c)| c[r] * fit.gamma[prev.len() + j])
                .sum();
            contrib += a * a;
            on_level += level.map_or(0.0, |g| a * g[r]);
        }
        let loss_sign = level.is_none() || on_level > 0.0;
        let plausible =
            fit.gamma.iter().all(|g| g.is_finite()) && (contrib / n).sqrt() <= y_rms && loss_sign;
        Some(Scored {
            idx: i,
            d_bic: fit.bic - cur.1,
            fit,
            p,
            rel,
            before,
            after,
            plausible,
        })
    }

    /// The flexible variant of candidate `i` ([`crate::diagnose::parsimony`]): its own columns, then for
    /// a loss term its value per joint and [`shape_cols`] of it over the signal it follows
    /// (session time for none; a family's mean over the joints), for a rail load a
    /// piecewise-linear function of its field (net of the trial's pre-idle value). Also the
    /// state a loss term follows (empty for a rail load).
    pub(super) fn flexible(&self, i: usize) -> (Vec<Vec<f64>>, Vec<f64>) {
        let (rows, rv) = (self.base.rows, &self.rv);
        let mut cols = self.cols(i);
        let (t, s) = match &self.cands[i].kind {
            Kind::Additive(f, _) | Kind::Step(f, _) => {
                let (raw, base) = (&rv.raw[*f], &rv.baseline[*f]);
                let Some((_, knots)) = knots(raw) else {
                    return (cols, Vec::new());
                };
                let hinge = |k: f64| {
                    raw.iter()
                        .zip(base)
                        .map(move |(a, b)| (a - k).max(0.0) - (b - k).max(0.0))
                };
                cols.push(raw.iter().zip(base).map(|(a, b)| a - b).collect());
                cols.extend(knots.into_iter().map(|k| hinge(k).collect()));
                unit_rms(&mut cols);
                return (cols, Vec::new());
            }
            Kind::Product(t, Signal::Family(_, fs), _) => {
                let mean = (0..rows.len())
                    .map(|r| fs.iter().map(|&f| rv.raw[f][r]).sum::<f64>() / N_JOINTS as f64);
                (*t, mean.collect())
            }
            Kind::Product(t, sig, _) => (*t, signal_values(sig, rv)),
            Kind::PerJoint(t) | Kind::Pooled(t) => (*t, rv.hours.clone()),
        };
        let g = self.rv.pooled(t);
        let driving = rows.x.iter().zip(g).map(|(x, v)| match t.per_joint() {
            true => (0..N_JOINTS)
                .filter(|&i| drives(x, i))
                .map(|i| t.value(x, i))
                .sum(),
            false => v * f64::from(u8::from(arm_drives(x))),
        });
        if t.per_joint() {
            cols.extend((0..N_JOINTS).map(|i| rows.x.iter().map(|x| t.value(x, i)).collect()));
        }
        cols.extend(shape_cols(g, driving.collect(), &s));
        unit_rms(&mut cols);
        (cols, s)
    }

    pub(super) fn passes(&self, s: &Scored, level: f64) -> bool {
        stepwise::passes(&self.rule, s, level) && s.plausible
    }
}

/// Paired one-sided p-value (held-out error by trial) that predictions `a` fit better than `b`.
pub(super) fn p_better(search: &Search, a: &[f64], b: &[f64]) -> f64 {
    let rows = search.base.rows;
    select::p_better(&rows.y, a, b, &rows.trial, search.base.data.n_trials)
}

/// A base loss term times a signal (with its level) contains the plain pooled term: when it
/// does not fit significantly better than that pooled term (paired held-out test by trial at the
/// rule's α), the simpler one is what the data support — its position in `among`.
pub(super) fn simpler_nested(search: &Search, b: &Scored, among: &[&Scored]) -> Option<usize> {
    let Kind::Product(t, ..) = search.cands[b.idx].kind else {
        return None;
    };
    among.iter().position(|o| {
        matches!(search.cands[o.idx].kind, Kind::Pooled(u) if u == t) && {
            let p = p_better(search, &b.fit.pred, &o.fit.pred);
            not_significant(p, search.rule.alpha)
        }
    })
}

pub(super) fn to_discovery(
    s: &Scored,
    search: &Search,
    joint_names: &[String],
    level: f64,
    step: usize,
    verdict: String,
) -> Discovery {
    let n = search.cols(s.idx).len();
    let g: Vec<f64> = s.fit.gamma.iter().rev().take(n).rev().copied().collect();
    let se: Vec<f64> = (0..n)
        .map(|j| {
            let per: Vec<f64> = s
                .fit
                .fold_gamma
                .iter()
                .map(|t| t[t.len() - n + j])
                .collect();
            jackknife_se(&per)
        })
        .collect();
    let (name, form, fields, params) = describe(
        &search.cands[s.idx].kind,
        &search.inp.fields.names,
        joint_names,
        &g,
        &se,
    );
    Discovery {
        name,
        form,
        fields,
        params,
        p_value: s.p,
        alpha: level,
        delta_bic: s.d_bic,
        rel_improvement: s.rel,
        before: s.before,
        after: s.after,
        step,
        verdict,
        mechanism: match &search.cands[s.idx].kind {
            Kind::Product(t, ..) | Kind::Pooled(t) => t.library_id().map(String::from),
            _ => None,
        },
        ..Default::default()
    }
}
