//! Plain-language summary of a [`Diagnosis`] for the terminal: where the model is wrong, what
//! physics is missing (with its parameter and the held-out improvement), and what remains.

use std::fmt::Write;

use super::hypotheses::{LATENCY_ID, PAYLOAD_ID, power_hypothesis};
use super::report::joined;
use super::{Diagnosis, HypothesisScore, MechanismForms, Param};

fn fmt_param(p: &Param) -> String {
    // Two significant digits of the uncertainty (or of the value when there is none).
    let scale = if p.std_err.is_finite() && p.std_err > 0.0 {
        p.std_err
    } else {
        p.value.abs()
    };
    let d = if scale > 0.0 && scale.is_finite() {
        (1 - scale.log10().floor() as i32).clamp(0, 6) as usize
    } else {
        2
    };
    let unit = if p.unit == "-" { "" } else { p.unit.as_str() };
    let text = if p.std_err.is_finite() {
        format!(
            "{} = {:.*} ± {:.*} {unit}",
            p.symbol, d, p.value, d, p.std_err
        )
    } else {
        format!("{} = {:.*} {unit}", p.symbol, d, p.value)
    };
    text.trim_end().to_string()
}

fn assumption(s: &HypothesisScore) -> &'static str {
    match s.id.as_str() {
        LATENCY_ID => {
            "the model assumes each power reading describes the window just before its time stamp"
        }
        PAYLOAD_ID => "the URDF has no load at the hand",
        id => power_hypothesis(id)
            .map(|h| h.model_assumes)
            .unwrap_or("the model lacks this effect"),
    }
}

/// Joints whose braking readings show significantly under-predicted power.
fn braking_joints(d: &Diagnosis) -> Vec<String> {
    d.breakdowns
        .iter()
        .filter(|b| b.by == "braking joint")
        .flat_map(|b| b.groups.iter())
        .filter(|g| g.p_value < 1e-3 && g.bias_w > 0.0 && g.n_trials >= 3)
        .map(|g| g.label.trim_end_matches(" braking").to_string())
        .collect()
}

/// The summary text, verdict first: the counts, then [`sections`] one after the other.
pub fn summarise(d: &Diagnosis) -> String {
    let mut s = header(d);
    for (_, text) in sections(d) {
        s.push_str(&text);
    }
    s
}

/// The summary as markdown (the viewer's diagnosis tab): the counts, then each non-empty
/// section under its heading, every line its own paragraph.
pub fn summary_markdown(d: &Diagnosis) -> String {
    let mut md = header(d);
    md.push_str(&verdict_markdown(d, "####", None));
    md
}

/// [`sections`] as markdown: each non-empty section under a heading of level `heading`
/// (`"##"`), every line its own paragraph; with `fold` = n, a section's lines after the n-th
/// are folded behind their count (an HTML `<details>` block, as GitHub shows it).
pub fn verdict_markdown(d: &Diagnosis, heading: &str, fold: Option<usize>) -> String {
    let mut md = String::new();
    for (title, text) in sections(d).iter().filter(|(_, t)| !t.is_empty()) {
        let _ = write!(md, "\n{heading} {title}\n");
        let n = text.lines().count();
        let shown = fold.unwrap_or(n).min(n);
        for (i, line) in text.lines().enumerate() {
            if i == shown {
                let _ = write!(
                    md,
                    "\n<details><summary>{} more lines</summary>\n",
                    n - shown
                );
            }
            let _ = write!(md, "\n{}\n", line.trim_start());
        }
        if shown < n {
            md.push_str("\n</details>\n");
        }
    }
    md
}

/// The summary's first line: what was diagnosed, with how many trials and readings.
fn header(d: &Diagnosis) -> String {
    format!(
        "Diagnosis of {}: {} trials, {} {:?} power readings ({} trials left out).\n",
        d.source,
        d.n_trials,
        d.n_readings,
        d.target,
        d.rejected.len()
    )
}

/// The summary's sections, verdict first: what was found (each claim with its parameter and
/// evidence, forms and confounding), what was located but not identified, what was tried and
/// rejected; then the supporting figures (the base model's quality, torque, sensor window, what
/// remains unexplained and, folded behind a count, the fields left out of discovery).
pub fn sections(d: &Diagnosis) -> [(&'static str, String); 4] {
    let mut found = String::new();
    named(d, &mut found);
    forms_and_confounding(d, &mut found);
    let mut rejected = String::new();
    not_named(d, &mut rejected);
    let mut support = String::new();
    quality(d, &mut support);
    unexplained(d, &mut support);
    if let Some(r) = &d.discovery {
        found_lines(r, &mut found);
        rejected_lines(r, &mut rejected);
        left_out(r, &mut support);
    }
    let mut located_ = String::new();
    window_drift(d, &mut found, &mut located_);
    timing_located(d, &mut located_);
    located(d, &mut located_);
    unnamed_lines(d, &mut located_);
    implausible_lines(d, &mut located_);
    [
        ("Found", found),
        ("Located, not identified", located_),
        ("Tried and rejected", rejected),
        ("Supporting figures", support),
    ]
}

/// The base model's held-out quality, the torque level's worst joint, the sensor window and the
/// best sensor lag.
fn quality(d: &Diagnosis, s: &mut String) {
    let f = &d.final_model;
    let base = if d.base_model == "reference" {
        "the twin's power model"
    } else {
        "the base model (refitted per fold)"
    };
    let _ = writeln!(
        s,
        "Power: {base} predicts held-out readings with R² = {:.3}, RMSE = {:.2} W (per trial R² = {:.3}).",
        f.before.r2, f.before.rmse_w, f.before_per_trial.r2
    );
    if let Some(t) = &d.torque {
        let worst = (t.rmse_with_friction.iter().enumerate()).max_by(|a, b| a.1.total_cmp(b.1));
        let worst = worst.map_or(String::new(), |(j, v)| {
            format!("{} ({v:.2} Nm)", t.joints.get(j).map_or("", String::as_str))
        });
        let _ = writeln!(
            s,
            "Torque: URDF inverse dynamics + fitted joint friction vs tau_est; worst joint {worst}."
        );
    }
    sensor_lines(d, s);
}

/// A lag the held-out trials cannot tell from a longer window: the timing is located, neither
/// named (a latency at W or a window W′ at no lag, fuzz seed 1947408491).
fn timing_located(d: &Diagnosis, s: &mut String) {
    let sw = &d.sensor_window;
    if let (false, Some(p)) = (sw.lag_demanded, sw.lag_held_out) {
        let _ = writeln!(
            s,
            "Located: the readings' timing — a latency of {:.3} s behind a {:.3} s window, or a {:.3} s window at no lag; the data do not tell them apart (in-sample ΔBIC = {:.1}, held out p = {p:.1e}); neither is claimed.",
            sw.scan_lag_s, sw.scan_window_s, sw.window_s, sw.lag_delta_bic
        );
    }
}

/// Where the base model is most clearly wrong (located, not identified).
fn located(d: &Diagnosis, s: &mut String) {
    if let Some((by, g)) = &d.worst {
        if g.p_value < 1e-3 {
            let dir = if g.bias_w > 0.0 {
                "under-predicted"
            } else {
                "over-predicted"
            };
            let mut where_ = format!("in the {by} group \"{}\"", g.label);
            let bj = braking_joints(d);
            if (by.starts_with("braking") || by == "regime" && g.label.starts_with("braking"))
                && !bj.is_empty()
            {
                where_ = format!("while braking on {}", bj.join(", "));
            }
            let _ = writeln!(
                s,
                "Where: power is {dir} most clearly {where_} (mean residual {:+.2} W over {} trials, p = {:.1e}).",
                g.bias_w, g.n_trials, g.p_value
            );
        } else {
            let _ = writeln!(
                s,
                "Where: no group of readings has a significant residual bias (best p = {:.1e}).",
                g.p_value
            );
        }
    }
}

/// Structure whose mechanism the data do not tell: library forms ([`MechanismForms::unnamed`])
/// and found terms located as another term's remainder.
fn unnamed_lines(d: &Diagnosis, s: &mut String) {
    for f in d.forms.iter().filter(|f| f.unnamed) {
        // Within 0.1 % the two are one formula to these data (gear friction and a braking
        // asymmetry once each joint’s efficiency is refitted): more data would not tell them apart.
        let same = match f.margin.abs() < 1e-3 {
            true => {
                ", which fit the held-out trials identically (not separable from these readings)"
            }
            false => "",
        };
        let _ = writeln!(
            s,
            "Located: the power follows the {}{same} — mechanism not identified: {}; neither is claimed, {} is kept in the model as the best approximation.",
            f.mechanism,
            f.evidence(),
            f.winner
        );
    }
    if let Some(r) = &d.discovery {
        let rest = r
            .rest
            .iter()
            .flat_map(|r| r.located.iter().map(|t| (&t.name, &t.verdict)));
        for (name, verdict) in r.located.iter().map(|t| (&t.name, &t.verdict)).chain(rest) {
            let _ = writeln!(s, "Located: {name} — {verdict}.");
        }
    }
    for m in d.discovery.iter().flat_map(|r| &r.meter_located) {
        let _ = writeln!(
            s,
            "Located: {} (p = {:.1e} < {:.1e}).",
            m.name, m.p_value, m.alpha
        );
    }
}

/// Library forms the data support at a size no such mechanism has: located, not a mechanism (a
/// 54 Nm Stribeck friction that improves the held-out power by 40 % is structure of that shape,
/// not Stribeck friction — and not nothing).
fn implausible_lines(d: &Diagnosis, s: &mut String) {
    for h in d.hypotheses.iter().filter(|h| h.only_implausible()) {
        let size = joined(
            h.params
                .iter()
                .map(|p| format!("{} = {:.3} {}", p.symbol, p.value, p.unit)),
        );
        let _ = writeln!(
            s,
            "Located: the power follows the form of the {} (held-out RMSE {:+.1} %, p = {:.1e}, ΔBIC = {:.1}), but at {} — outside the physically plausible range: structure of this form, mechanism not identified; not claimed.",
            h.title,
            -100.0 * h.rel_improvement,
            h.p_value,
            h.delta_bic,
            size
        );
    }
}

/// A sensor window that drifts over the session ([`super::window`]): in *Found* when the other
/// meter rejects the drift (this meter's artefact, corrected), else in *Located*.
fn window_drift(d: &Diagnosis, found: &mut String, located: &mut String) {
    let sw = &d.sensor_window;
    let (s, head, why) = match sw.drift_artefact {
        true => (
            found,
            "Meter artefact",
            "it rejects the drift, so it is this meter's",
        ),
        false => (
            located,
            "Located",
            "it does not reject the drift: meter or the arm's clock, not decided",
        ),
    };
    if sw.drift_s != 0.0 {
        let _ = writeln!(
            s,
            "{head}: the {} meter's averaging window drifts over the session, {:.3} s → {:.3} s (ΔBIC = {:.1} against one window; on the other meter {:+.1}: {why}); corrected: every stage reads each trial at its own window.",
            super::meters::meter_name(d.target),
            sw.window_at(sw.drift_from_s),
            sw.window_at(sw.drift_to_s),
            sw.drift_delta_bic,
            sw.drift_other_delta_bic,
        );
    }
}

/// The estimated sensor window and the base model's best sensor lag.
fn sensor_lines(d: &Diagnosis, s: &mut String) {
    let sw = &d.sensor_window;
    if sw.estimated {
        let _ = writeln!(
            s,
            "Sensor window: each reading averages the {:.3} s before its stamp{} (estimated from {} trials by the (W, lag) alignment scan; best point W {:.3} s, lag {:.3} s, R² = {:.3}; {}).",
            sw.window_s,
            if sw.drift_s != 0.0 {
                ", mid-session"
            } else {
                ""
            },
            sw.scan_trials,
            sw.scan_window_s,
            sw.scan_lag_s,
            sw.scan_r2,
            match (sw.lag_demanded, sw.lag_held_out) {
                (false, None) => "no lag beats every window at lag 0: no latency is claimed".into(),
                (false, Some(p)) => format!(
                    "the lag is not demanded (in-sample ΔBIC = {:.1} against the best window at lag 0, held out p = {p:.1e}; a lag needs the BIC rule and p < {}): no latency is claimed (located above)",
                    sw.lag_delta_bic,
                    super::select::RIVAL_ALPHA
                ),
                (true, p) => format!(
                    "a lag beats every window at lag 0{}: the latency hypothesis judges it",
                    p.map_or(String::new(), |p| format!(
                        " in-sample, held out p = {p:.1e} against the best of them (needed < {})",
                        super::select::RIVAL_ALPHA
                    )),
                ),
            }
        );
    }
    if let Some(best) = d
        .lag_scan
        .iter()
        .min_by(|a, b| a.rmse_w.total_cmp(&b.rmse_w))
        .filter(|b| b.lag_s > 0.0 && sw.lag_demanded)
    {
        let _ = writeln!(
            s,
            "Time alignment: the base model fits best if readings lag the kinematics by {:.2} s.",
            best.lag_s
        );
    }
}

/// Why no hypothesis of the library is accepted, when none is.
fn not_named(d: &Diagnosis, s: &mut String) {
    if !d.accepted.is_empty() {
        return;
    }
    // Terms found beyond the library, on the arm's power or at rest, are claims of their own.
    let found = d.discovery.as_ref().is_some_and(|r| {
        !r.accepted.is_empty() || r.rest.as_ref().is_some_and(|p| !p.found.is_empty())
    });
    let tail = match found {
        true => "what is claimed was found beyond it (above)",
        false => "no missing physics is claimed",
    };
    let line = match d.hypotheses.first() {
        Some(_) if d.forms.iter().any(|f| f.unnamed) => {
            format!("no mechanism of the library is identified (located above); {tail}.")
        }
        Some(h) if h.only_implausible() => format!(
            "no mechanism of the library is identified (located above: the best candidate, {}, fits only at an implausible size); {tail}.",
            h.id
        ),
        Some(h) => format!(
            "no hypothesis in the library is supported (best candidate {}: held-out RMSE {:+.1} %, p = {:.1e}, ΔBIC = {:.1}); {tail}.",
            h.id,
            -100.0 * h.rel_improvement,
            h.p_value,
            h.delta_bic
        ),
        None => "no hypothesis was scored.".to_string(),
    };
    let _ = writeln!(s, "Named: {line}");
}

/// The accepted hypotheses with their parameters, and the model with them.
fn named(d: &Diagnosis, s: &mut String) {
    let f = &d.final_model;
    for h in &d.accepted {
        let first = h.params.first();
        let shown = (f.params.iter()).find(|p| first.is_some_and(|q| q.symbol == p.symbol));
        let p = shown.or(first);
        let (title, param) = match d.forms.iter().find(|f| f.confounded && f.winner == h.id) {
            Some(f) => (
                format!("{} (form: confounded — {})", f.mechanism, f.either()),
                either_params(f, p),
            ),
            None => (h.title.clone(), p.map(fmt_param).unwrap_or_default()),
        };
        let _ = writeln!(
            s,
            "Named: {}; adding {} with {} improves held-out {} R² from {:.3} to {:.3} (RMSE {:.3} → {:.3} {}{}).",
            assumption(h),
            title,
            param,
            h.level,
            h.r2_before,
            h.r2_after,
            h.rmse_before,
            h.rmse_after,
            if h.level == "torque" { "Nm" } else { "W" },
            held(h.stability)
        );
        if h.id == PAYLOAD_ID {
            let com = joined(h.params.iter().skip(1).map(fmt_param));
            let _ = writeln!(s, "       payload centre of mass: {com}.");
        }
    }
    let power_accepted: Vec<&str> = d
        .accepted
        .iter()
        .filter(|h| h.level == "power")
        .map(|h| h.id.as_str())
        .collect();
    if !power_accepted.is_empty() {
        let _ = writeln!(
            s,
            "Model: with {} the held-out power R² goes {:.3} → {:.3}, RMSE {:.2} → {:.2} W (per trial R² {:.3} → {:.3}).",
            power_accepted.join(" + "),
            f.before.r2,
            f.after.r2,
            f.before.rmse_w,
            f.after.rmse_w,
            f.before_per_trial.r2,
            f.after_per_trial.r2
        );
    }
}

/// The strongest correlates of the residual the final model leaves.
fn unexplained(d: &Diagnosis, s: &mut String) {
    let sig: Vec<_> = d.unexplained.iter().filter(|c| c.significant).collect();
    if sig.is_empty() {
        let _ = writeln!(
            s,
            "Unexplained: no significant correlation of the remaining residual with any recorded signal."
        );
    } else {
        for c in sig.iter().take(3) {
            let _ = writeln!(
                s,
                "Unexplained: the remaining residual correlates with {} (r = {:+.2}, p = {:.1e}); look at trials {}.",
                c.feature,
                c.r,
                c.p_adjusted,
                joined(&c.trials)
            );
        }
    }
}

/// The parameter of each of two confounded forms, the winner's as `shown` (its final refit).
fn either_params(f: &MechanismForms, shown: Option<&Param>) -> String {
    let one = |i: usize, p: Option<&Param>| {
        p.map(|p| format!("{} ({})", fmt_param(p), f.form_words[i]))
            .unwrap_or_default()
    };
    format!(
        "{} or {}",
        one(0, shown.or(f.params[0].first())),
        one(1, f.params[1].first())
    )
}

/// Mechanism forms (winner, runner-up, margin) and confounded pairs.
fn forms_and_confounding(d: &Diagnosis, s: &mut String) {
    // The confounded forms first.
    let forms = (d.forms.iter()).filter(|f| f.accepted && f.confounded);
    for f in forms.chain(d.forms.iter().filter(|f| f.accepted && !f.confounded)) {
        let evidence = format!(
            "held-out RMSE {:.3} vs {:.3} W, margin {:.1} %",
            f.rmse_w[0],
            f.rmse_w[1],
            100.0 * f.margin
        );
        let _ = if f.confounded {
            writeln!(
                s,
                "Form: {}: confounded — {}: the data do not tell them apart ({} vs {}: {evidence}, p = {:.2}); the mechanism is claimed, not the form.",
                f.mechanism,
                f.either(),
                f.winner,
                f.runner_up,
                f.p_value
            )
        } else {
            writeln!(
                s,
                "Form: {}: {} fits better than {} ({evidence}, p = {:.1e}).",
                f.mechanism, f.winner, f.runner_up, f.p_value
            )
        };
    }
    let tied = d.confounded.iter().filter(|c| c.tied);
    for c in tied.chain(d.confounded.iter().filter(|c| !c.tied)) {
        let _ = writeln!(s, "{}", confounded_line(c));
    }
}

/// The summary's line for a confounded pair, with its evidence.
fn confounded_line(c: &super::Confounded) -> String {
    if c.tied {
        format!(
            "Confounded: {} or {} (regressor correlation r = {:+.2}): they explain the same part of the power and the first fits the held-out trials {:+.1} % better, not significantly (p = {:.1e}); the first, the library's physical mechanism, is claimed, the second is not excluded.",
            c.dropped,
            c.kept,
            c.correlation,
            100.0 * c.rel_change,
            c.p_value,
        )
    } else {
        format!(
            "Confounded: {} or {} (regressor correlation r = {:+.2}); {} is not significant given {} (p = {:.1e}, held-out RMSE change {:+.1} %), so only {} is claimed.",
            c.kept,
            c.dropped,
            c.correlation,
            c.dropped,
            c.kept,
            c.p_value,
            -100.0 * c.rel_change,
            c.kept
        )
    }
}

/// "; stable in x % of N resamples": a claim's stability ([`super::parsimony`]), if measured.
fn held(stability: Option<f64>) -> String {
    stability.map_or(String::new(), |f| {
        format!(
            "; stable in {:.0} % of {} resamples",
            100.0 * f,
            super::stats::STABILITY_DRAWS
        )
    })
}

/// Terms found beyond the library and on the rest power.
fn found_lines(r: &super::DiscoveryReport, s: &mut String) {
    for t in &r.accepted {
        let _ = writeln!(
            s,
            "Found beyond the library: {}; {} with {} improves held-out power R² from {:.3} to {:.3} (RMSE {:.3} → {:.3} W, p = {:.1e} < {:.1e}{}).",
            t.name,
            t.form,
            joined(t.params.iter().map(fmt_param)),
            t.before.r2,
            t.after.r2,
            t.before.rmse_w,
            t.after.rmse_w,
            t.p_value,
            t.alpha,
            held(t.stability)
        );
        meter_line(t.meter.as_ref(), s);
        tied_lines(t, s);
    }
    if let Some(rest) = &r.rest {
        rest_found(rest, s);
    }
    if let Some(d) = &r.meter_drift {
        let _ = writeln!(
            s,
            "Meters: {} (p = {:.1e} < {:.1e}).",
            d.name, d.p_value, d.alpha
        );
    }
}

/// What discovery and the rest power tried without finding anything.
fn rejected_lines(r: &super::DiscoveryReport, s: &mut String) {
    if r.accepted.is_empty() {
        let best = best_rejected(r.best_rejected.as_ref().map(|b| (&b.name, &b.verdict)));
        let _ = writeln!(
            s,
            "Beyond the library: {} candidate terms from {} recorded fields tried, none supported at a family-wise level of {:.0e}{best}.",
            r.n_candidates, r.fields_used, r.alpha
        );
    }
    if let Some(rest) = r.rest.as_ref().filter(|r| r.found.is_empty()) {
        let best = best_rejected(rest.best_rejected.as_ref().map(|b| (&b.name, &b.verdict)));
        let _ = writeln!(
            s,
            "Rest power: {} candidates tried on {} trials' pre-idle power ({:.1} W on average, held-out RMSE {:.3} W), none supported{best}.",
            rest.n_candidates, rest.n_trials, rest.mean_w, rest.rmse_before_w
        );
    }
}

/// Fields named beside the count of those left out of discovery (the report lists all).
const LEFT_OUT_NAMED: usize = 3;

/// The fields left out of discovery as counters, clocks or hash-like, folded behind a count.
fn left_out(r: &super::DiscoveryReport, s: &mut String) {
    let junk: Vec<&str> = r
        .excluded
        .iter()
        .filter(|e| !e.reason.starts_with("constant"))
        .map(|e| e.name.as_str())
        .collect();
    if !junk.is_empty() {
        let more = if junk.len() > LEFT_OUT_NAMED {
            ", …"
        } else {
            ""
        };
        let _ = writeln!(
            s,
            "Left out of discovery as counters, clocks or hash-like: {} fields ({}{more}; all with reasons in the report).",
            junk.len(),
            junk[..junk.len().min(LEFT_OUT_NAMED)].join(", ")
        );
    }
}

/// What the rail's other meter shows of a finding, on a line of its own.
fn meter_line(m: Option<&super::MeterCheck>, s: &mut String) {
    if let Some(m) = m {
        let _ = writeln!(s, "  {}", m.words());
    }
}

/// " (best: <name>, <verdict>)" of the best rejected candidate, if any was tried.
fn best_rejected(b: Option<(&String, &String)>) -> String {
    b.map(|(name, verdict)| format!(" (best: {name}, {verdict})"))
        .unwrap_or_default()
}

/// Most fields named beside a rest-power term in the summary (the JSON lists all).
const REST_TIES_NAMED: usize = 4;

/// The loads found on the rest power (each trial's pre-idle mean, which the net-power model
/// subtracts).
fn rest_found(r: &super::RestPower, s: &mut String) {
    for t in &r.found {
        let more = t.tied.len().saturating_sub(REST_TIES_NAMED);
        let named = (t.tied.iter().take(REST_TIES_NAMED).cloned())
            .chain((more > 0).then(|| format!("{more} more")));
        let ties = match t.tied.is_empty() {
            true => String::new(),
            false => format!(
                " Not told apart from it (fit as well; not claimed): {}.",
                joined(named)
            ),
        };
        let _ = writeln!(
            s,
            "Rest power (each trial's pre-idle mean, {:.1} W on average, which the net-power model subtracts): {}; {} with {}; held-out RMSE over {} trials {:.3} → {:.3} W (held out by blocks of {} trials; p = {:.1e} < {:.1e} beside the rail's drift, piecewise linear over every {} trials{}).{ties}",
            r.mean_w,
            t.name,
            t.form,
            joined(t.params.iter().map(fmt_param)),
            r.n_trials,
            r.rmse_before_w,
            r.rmse_after_w,
            r.block_trials(),
            t.p_value,
            t.alpha,
            super::rest::DRIFT_TRIALS,
            held(t.stability)
        );
        meter_line(t.meter.as_ref(), s);
    }
}

/// Most rivals of a found term given a line of their own (the report lists all).
const TIED_LINES: usize = 3;

/// The candidates a found term was not told apart from, with their evidence.
fn tied_lines(t: &super::Discovery, s: &mut String) {
    for o in t.tied.iter().take(TIED_LINES) {
        let fields = if o.fields.is_empty() {
            String::new()
        } else {
            format!(" on {}", o.fields.join(", "))
        };
        let _ = writeln!(
            s,
            "  Not told apart from it: {}{fields} with {} fits as well (held-out RMSE {:.3} W vs {:.3} W, p = {:.1e} that the found term fits better; {}, r = {:+.2}); not claimed.",
            o.form,
            joined(o.params.iter().map(fmt_param)),
            o.rmse_w[1],
            o.rmse_w[0],
            o.p_value,
            if o.same_structure {
                "the same term on another field"
            } else {
                "contributions collinear"
            },
            o.correlation
        );
    }
    if t.tied.len() > TIED_LINES {
        let _ = writeln!(
            s,
            "  … and {} more not told apart from it (listed in the report).",
            t.tied.len() - TIED_LINES
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_confounded_pair_not_told_apart_is_named_beside_the_library_term() {
        let c = |tied: bool| super::super::Confounded {
            kept: "found term".into(),
            dropped: "gear_friction".into(),
            correlation: 0.87,
            p_value: 0.25,
            rel_change: 0.012,
            tied,
        };
        let line = confounded_line(&c(true));
        assert!(
            line.starts_with(
                "Confounded: gear_friction or found term (regressor correlation r = +0.87)"
            ),
            "{line}"
        );
        assert!(line.contains("+1.2 % better"), "{line}");
        assert!(line.contains("p = 2.5e-1"), "{line}");
        assert!(
            line.ends_with("the first, the library's physical mechanism, is claimed, the second is not excluded."),
            "{line}"
        );
        let line = confounded_line(&c(false));
        assert!(line.ends_with("so only found term is claimed."), "{line}");
        assert!(!line.contains("not excluded"), "{line}");
    }
}
