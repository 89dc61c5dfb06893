//! The diagnosis acceptance matrix as a markdown table for docs/diagnosis-results.md: for each concealed effect
//! (and null sessions, two effects at once, the harness drag outside the library), simulate
//! sessions, diagnose them, and print the true parameter, the recovered one ± its standard error,
//! the rank of the right hypothesis, what was accepted, and the held-out R² before → after.
//!
//! ```text
//! cargo run --release --no-default-features --example diagnose_matrix -- [--parts N] [--report DIR] [CASE…]
//! ```
//! Cases: null, thermal, thermal_refit, braking, bus_loss, latency, payload, gear_friction,
//! drive_loss, stribeck, balance_leak, braking+latency, bus_loss+payload, harness, harness15,
//! and the forms of single effects (library forms or forms of the generated family): bus_power, electronics_nm, joint_friction,
//! housing_friction, housing_related (housings starting with their windings), fan_load (default: all). `--parts N` joins N smoke sessions (≈ 24 trials each) for every case
//! instead of the case's own count (3, or 6 for the faint effects).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use g1viz::diagnose::{self, DiagnoseOptions, Diagnosis};
use g1viz::power::PowerModel;
use g1viz::signals::{SignalMap, load_recording};
use g1viz::sim::{self, Effects, Preset, SimConfig};

struct Case {
    name: &'static str,
    effects: &'static [&'static str],
    /// (hypothesis id, parameter symbol, true value) for each concealed effect in the library.
    truth: &'static [(&'static str, &'static str, f64)],
    /// Winding temperature at the start of each part (cycled over the parts).
    t_start_c: &'static [f64],
    /// Housing temperature at the start of each part (cycled; empty: settled with the winding).
    housing_c: &'static [f64],
    seeds: &'static [u64],
    /// Smoke sessions joined per seed (`--parts` overrides): faint effects need more trials.
    parts: u64,
    /// Effects outside the library: (recorded field the discovered term must follow, "" for a
    /// base-term correction; true parameter of the matching form).
    found: &'static [(&'static str, f64)],
}

const CASES: &[Case] = &[
    Case {
        name: "null",
        effects: &[],
        truth: &[],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 3,
        seeds: &[11, 12, 13, 14, 15],
        found: &[],
    },
    Case {
        name: "thermal",
        effects: &["thermal=0.00393"],
        truth: &[("thermal", "α", 0.00393)],
        t_start_c: &[70.0],
        housing_c: &[],
        parts: 3,
        seeds: &[3, 6, 7],
        found: &[],
    },
    Case {
        name: "braking",
        effects: &["braking=0.25"],
        truth: &[("braking", "r", 0.25)],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 6,
        seeds: &[3, 6, 7],
        found: &[],
    },
    Case {
        name: "bus_loss",
        effects: &["bus_loss=0.05"],
        truth: &[("bus_loss", "R_bus", 0.05)],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 3,
        seeds: &[3, 6, 7],
        found: &[],
    },
    Case {
        name: "latency",
        effects: &["latency=0.3"],
        truth: &[("latency", "L", 0.3)],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 3,
        seeds: &[3, 6, 7],
        found: &[],
    },
    Case {
        name: "payload",
        effects: &["payload=0.5"],
        truth: &[("payload", "m", 0.5)],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 3,
        seeds: &[3, 6, 7],
        found: &[],
    },
    Case {
        name: "thermal_refit",
        effects: &["thermal=0.00393"],
        truth: &[("thermal", "α", 0.00393)],
        // A refitted b_i absorbs a constant temperature offset; parts started at different
        // temperatures make the drift identifiable without the twin.
        t_start_c: &[30.0, 50.0, 70.0],
        housing_c: &[],
        parts: 6,
        seeds: &[3, 6, 7],
        found: &[],
    },
    Case {
        name: "gear_friction",
        effects: &["gear_friction=0.15"],
        truth: &[("gear_friction", "μ", 0.15)],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 6,
        seeds: &[3, 6, 7],
        found: &[],
    },
    Case {
        name: "drive_loss",
        effects: &["drive_loss=0.5"],
        truth: &[("drive_loss", "V_drop", 0.5)],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 3,
        seeds: &[3, 6, 7],
        found: &[],
    },
    Case {
        name: "stribeck",
        effects: &["stribeck=10"],
        truth: &[("stribeck", "F_s", 10.0)],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 6,
        seeds: &[3, 6, 7],
        found: &[],
    },
    Case {
        name: "balance_leak",
        effects: &["balance_leak"],
        truth: &[("balance_leak", "k_leak", 500.0 / 9.0)],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 6,
        seeds: &[3, 6, 7],
        found: &[],
    },
    Case {
        name: "braking+latency",
        effects: &["braking=0.25", "latency=0.3"],
        truth: &[("braking", "r", 0.25), ("latency", "L", 0.3)],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 3,
        seeds: &[4, 9],
        found: &[],
    },
    Case {
        name: "bus_loss+payload",
        effects: &["bus_loss=0.05", "payload=0.5"],
        truth: &[("bus_loss", "R_bus", 0.05), ("payload", "m", 0.5)],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 3,
        seeds: &[4, 9],
        found: &[],
    },
    Case {
        name: "harness",
        effects: &["harness_drag=4"],
        truth: &[],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 3,
        seeds: &[5, 8],
        found: &[],
    },
    Case {
        name: "harness15",
        effects: &["harness_drag=15"],
        truth: &[],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 3,
        seeds: &[5, 8],
        found: &[],
    },
    Case {
        name: "bus_power",
        effects: &["bus_power=10"],
        truth: &[("bus_power", "R_bus", 10.0)],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 3,
        seeds: &[3, 6],
        found: &[],
    },
    Case {
        name: "electronics_nm",
        effects: &["electronics_nm=0.5"],
        truth: &[("electronics_nm", "k_el", 0.5)],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 3,
        seeds: &[3, 6],
        found: &[],
    },
    Case {
        name: "joint_friction",
        effects: &["joint_friction=1"],
        truth: &[],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 3,
        seeds: &[3, 6],
        found: &[("", 1.0)],
    },
    Case {
        name: "housing_friction",
        effects: &["housing_friction=0.05"],
        truth: &[],
        // Windings and housings started at unrelated temperatures (a motor worked hard just
        // before has a hot winding in a cool housing), so the two can be told apart.
        t_start_c: &[30.0, 50.0, 70.0],
        housing_c: &[50.0, 30.0, 40.0, 35.0],
        parts: 6,
        seeds: &[3, 6],
        found: &[("temperature[1]", 0.05)],
    },
    Case {
        name: "housing_related",
        effects: &["housing_friction=0.05"],
        truth: &[],
        // The housings start settled with their windings (as on a real robot): housing and
        // winding temperatures move together, and the data may not tell them apart.
        t_start_c: &[30.0, 50.0, 70.0],
        housing_c: &[],
        parts: 6,
        seeds: &[3, 6],
        found: &[("temperature[1]", 0.05)],
    },
    Case {
        name: "fan_load",
        effects: &["fan_load=3"],
        truth: &[],
        t_start_c: &[30.0],
        housing_c: &[],
        parts: 3,
        seeds: &[3, 6],
        found: &[("fan_state[1]", 3.0)],
    },
];

fn session(
    effects: &Effects,
    seed: u64,
    parts: u64,
    t_start_c: &[f64],
    housing_c: &[f64],
    dir: &std::path::Path,
) -> Result<(g1viz::signals::Recording, Vec<diagnose::FieldSource>)> {
    let mut recs = Vec::new();
    for part in 0..parts {
        let cfg = SimConfig {
            preset: Preset::Smoke,
            seed: seed * 100 + part,
            effects: *effects,
            t_start_c: t_start_c[part as usize % t_start_c.len()],
            housing_start_c: (!housing_c.is_empty())
                .then(|| housing_c[part as usize % housing_c.len()]),
            progress: false,
            ..SimConfig::default()
        };
        let out = dir.join(format!("s{seed}_{part}.mcap"));
        sim::simulate(&cfg, &out)?;
        recs.push(load_recording(
            &out,
            &SignalMap::g1_left_arm(),
            &Default::default(),
        )?);
    }
    Ok(diagnose::join_recordings_with_sources(recs, 5.0))
}

/// A discovered term in a table cell: its formula, the field(s) it follows, its first parameter.
fn found_cell(t: &diagnose::Discovery) -> String {
    let field = t.fields.first().map_or(String::new(), |f| {
        format!(" on {f}{}", if t.fields.len() > 1 { " …" } else { "" })
    });
    let p = t.params.first().map_or(String::new(), |p| {
        format!(", {} = {:.4} ± {:.4}", p.symbol, p.value, p.std_err)
    });
    // Rivals grouped by field pattern across the motors (`motor_state[*]`), best first.
    let mut groups: Vec<(String, &diagnose::TiedTerm, usize)> = Vec::new();
    for o in &t.tied {
        let key = o
            .fields
            .first()
            .map_or("session time".to_string(), |f| motor_pattern(f));
        match groups.iter_mut().find(|g| g.0 == key) {
            Some(g) => g.2 += 1,
            None => groups.push((key, o, 1)),
        }
    }
    let tied: Vec<String> = groups
        .iter()
        .map(|(key, o, n)| {
            let p = o.params.first().map_or(String::new(), |p| {
                format!(", best {} = {:.4} ± {:.4}", p.symbol, p.value, p.std_err)
            });
            format!(" or {key} ({n} candidate(s){p})")
        })
        .collect();
    let tied = if tied.is_empty() {
        String::new()
    } else {
        format!(" (field confounded:{})", tied.join(";"))
    };
    format!("found: {}{field}{p}{tied}", t.form)
}

/// A field name with the motor index as `[*]` (`…motor_state[17].temperature[0]` →
/// `…motor_state[*].temperature[0]`).
fn motor_pattern(f: &str) -> String {
    match f.find("motor_state[") {
        Some(a) => {
            let start = a + "motor_state[".len();
            match f[start..].find(']') {
                Some(b) => format!("{}*{}", &f[..start], &f[start + b..]),
                None => f.to_string(),
            }
        }
        None => f.to_string(),
    }
}

fn row(case: &Case, seed: u64, mode: &str, d: &Diagnosis) -> String {
    let mut accepted: Vec<String> = d
        .accepted
        .iter()
        .map(
            |h| match d.forms.iter().find(|f| f.confounded && f.winner == h.id) {
                Some(f) => format!("{} (form: confounded — {})", f.mechanism, f.either()),
                None => h.id.clone(),
            },
        )
        .collect();
    if let Some(r) = &d.discovery {
        accepted.extend(r.accepted.iter().map(found_cell));
    }
    for c in &d.confounded {
        accepted.push(format!("(confounded: {} or {})", c.kept, c.dropped));
    }
    let mut truth = Vec::new();
    let mut found = Vec::new();
    let mut ranks = Vec::new();
    for (id, symbol, value) in case.truth {
        let shown = format!("{value:.4}");
        let shown = shown.trim_end_matches('0').trim_end_matches('.');
        truth.push(format!("{symbol} = {shown}"));
        let p = d
            .final_model
            .params
            .iter()
            .find(|p| p.symbol == *symbol)
            .or_else(|| {
                d.hypotheses
                    .iter()
                    .find(|h| h.id == *id)
                    .and_then(|h| h.params.iter().find(|p| p.symbol == *symbol))
            });
        found.push(match p {
            Some(p) => format!(
                "{:.4} ± {:.4} ({:+.1} %)",
                p.value,
                p.std_err,
                100.0 * (p.value - value) / value
            ),
            None => "—".into(),
        });
        ranks.push(
            d.hypotheses
                .iter()
                .find(|h| h.id == *id)
                .map_or("—".into(), |h| h.rank.to_string()),
        );
    }
    for (field, value) in case.found {
        truth.push(format!("{field} {value}"));
        let hit = d.discovery.as_ref().and_then(|r| {
            r.accepted.iter().find(|t| {
                if field.is_empty() {
                    t.fields.is_empty()
                } else {
                    t.fields.iter().any(|f| f.contains(field))
                }
            })
        });
        // The field named only as confounded with the found term: its parameter fitted in the
        // found term's place.
        let tie = d.discovery.as_ref().and_then(|r| {
            r.accepted
                .iter()
                .flat_map(|t| t.tied.iter())
                .find(|o| !field.is_empty() && o.fields.iter().any(|f| f.contains(field)))
        });
        if let (None, Some(p)) = (hit, tie.and_then(|o| o.params.first())) {
            found.push(format!(
                "confounded: {} = {:.4} ± {:.4} ({:+.1} %)",
                p.symbol,
                p.value,
                p.std_err,
                100.0 * (p.value - value) / value
            ));
            continue;
        }
        found.push(match hit {
            None => "not found".into(),
            Some(t)
                if t.fields.is_empty() && t.params.iter().any(|p| p.symbol.starts_with("k_")) =>
            {
                // Identified per-joint coefficients: worst relative error against F·w_i.
                let w = g1viz::sim::JOINT_FRICTION_PATTERN;
                let ided: Vec<(&diagnose::Param, f64)> = t
                    .params
                    .iter()
                    .filter_map(|p| {
                        let i: usize = p.symbol.strip_prefix("k_")?.parse().ok()?;
                        Some((p, w[i]))
                    })
                    .collect();
                let worst = ided
                    .iter()
                    .map(|(p, wi)| (p.value - value * wi) / (value * wi))
                    .max_by(|a, b| a.abs().total_cmp(&b.abs()))
                    .unwrap_or(f64::NAN);
                let worst_se = ided
                    .iter()
                    .map(|(p, wi)| (p.value - value * wi).abs() / p.std_err)
                    .fold(0.0, f64::max);
                let pooled =
                    t.params
                        .iter()
                        .find(|p| p.symbol == "k_pooled")
                        .map_or(String::new(), |p| {
                            format!(
                                "; {} pooled: k = {:.4} ± {:.4} (mean excess {:.4})",
                                g1viz::N_JOINTS - ided.len(),
                                p.value,
                                p.std_err,
                                value * w.iter().sum::<f64>() / w.len() as f64
                            )
                        });
                if ided.is_empty() {
                    format!("no joint identified (s.e. > 4 % of k_i){pooled}")
                } else {
                    format!(
                        "{} joints identified, worst error {:+.1} %, worst {:.1} s.e.{pooled}",
                        ided.len(),
                        100.0 * worst,
                        worst_se
                    )
                }
            }
            Some(t) => {
                let p = &t.params[0];
                format!(
                    "{} = {:.4} ± {:.4} ({:+.1} %)",
                    p.symbol,
                    p.value,
                    p.std_err,
                    100.0 * (p.value - value) / value
                )
            }
        });
    }
    if case.name.starts_with("harness") {
        let c = d.unexplained.first();
        found.push(c.map_or("—".into(), |c| {
            format!(
                "top correlate: {} (r = {:+.2}, p = {:.1e}{}), trials {:?}",
                // `|` would end the markdown table cell.
                c.feature.replace('|', "\\|"),
                c.r,
                c.p_adjusted,
                if c.significant { "" } else { ", n.s." },
                c.trials
            )
        }));
    }
    let f = &d.final_model;
    // Held-out R² after: with the terms found beyond the library when there are any.
    let after_r2 = d
        .discovery
        .as_ref()
        .filter(|r| !r.accepted.is_empty())
        .and_then(|r| r.after)
        .map_or(f.after.r2, |q| q.r2);
    let torque = d
        .accepted
        .iter()
        .find(|h| h.level == "torque")
        .map(|h| format!("; torque {:.3} → {:.3}", h.r2_before, h.r2_after))
        .unwrap_or_default();
    format!(
        "| {} (seed {seed}) | {mode} | {} | {} | {} | {} | {:.3} → {:.3}{torque} | {} / {} |",
        case.name,
        if truth.is_empty() {
            "—".into()
        } else {
            truth.join(", ")
        },
        if found.is_empty() {
            "—".into()
        } else {
            cell(&found.join("; "))
        },
        if ranks.is_empty() {
            "—".into()
        } else {
            ranks.join(", ")
        },
        if accepted.is_empty() {
            "none".into()
        } else {
            cell(&accepted.join(", "))
        },
        f.before.r2,
        after_r2,
        d.n_trials,
        d.n_trials + d.rejected.len(),
    )
}

/// A markdown table cell: `|` (as in |q̇|) escaped, already escaped ones left alone.
fn cell(s: &str) -> String {
    s.replace("\\|", "|").replace('|', "\\|")
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let mut parts: Option<u64> = None;
    let mut report: Option<PathBuf> = None;
    let mut only = Vec::new();
    while let Some(a) = args.next() {
        match a.as_str() {
            "--parts" => parts = Some(args.next().context("--parts N")?.parse()?),
            "--report" => report = Some(args.next().context("--report DIR")?.into()),
            _ => only.push(a),
        }
    }
    let dir = tempfile::tempdir()?;
    println!(
        "| session | base model | truth | recovered ± s.e. (error) | rank | accepted | held-out R² before → after | trials used / found |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for case in CASES
        .iter()
        .filter(|c| only.is_empty() || only.iter().any(|o| o == c.name))
    {
        let mut effects = Effects::default();
        for e in case.effects {
            effects.enable(e)?;
        }
        for &seed in case.seeds {
            let t0 = Instant::now();
            let n = parts.unwrap_or(case.parts);
            let (rec, sources) = session(
                &effects,
                seed,
                n,
                case.t_start_c,
                case.housing_c,
                dir.path(),
            )?;
            let base = DiagnoseOptions {
                field_sources: sources,
                ..DiagnoseOptions::default()
            };
            for (mode, opts) in [
                ("refit", base.clone()),
                (
                    "twin (paper θ)",
                    DiagnoseOptions {
                        reference: Some(PowerModel::PAPER),
                        ..base.clone()
                    },
                ),
            ] {
                let d = diagnose::diagnose(&rec, &opts)?;
                println!("{}", row(case, seed, mode, &d));
                // Why a concealed effect was not accepted, for whoever reads the table.
                for (id, _, _) in case.truth {
                    let accepted = d.accepted.iter().any(|h| h.id == *id);
                    if let Some(h) = d.hypotheses.iter().find(|h| h.id == *id && !accepted) {
                        eprintln!("  {} {mode}: {id} {}", case.name, h.verdict);
                    }
                }
                // What discovery tried when it found nothing (or what it left out).
                for line in d.summary.lines().filter(|l| {
                    l.starts_with("Beyond") || l.starts_with("Confounded") || l.starts_with("Form")
                }) {
                    eprintln!("  {} {mode}: {line}", case.name);
                }
                if let Some(r) = &report {
                    let sub = r.join(format!(
                        "{}_{seed}_{}",
                        case.name,
                        if mode == "refit" { "refit" } else { "twin" }
                    ));
                    diagnose::write_report(&sub, &d)?;
                }
            }
            eprintln!(
                "{} seed {seed}: {:.1} s",
                case.name,
                t0.elapsed().as_secs_f64()
            );
        }
    }
    Ok(())
}
