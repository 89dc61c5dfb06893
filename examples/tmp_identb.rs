// TEMPORARY (not committed): loads /tmp/identb/*.json extracted by Python, runs the pipeline.
use g1viz::identify::{dataset::*, pipeline::*, segment::*};
use g1viz::signals::*;
fn arr7(v: &serde_json::Value) -> Vec<[f64; 7]> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|r| {
            let a = r.as_array().unwrap();
            std::array::from_fn(|j| a[j].as_f64().unwrap())
        })
        .collect()
}
fn arrn<const N: usize>(v: &serde_json::Value) -> Vec<[f64; N]> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|r| {
            let a = r.as_array().unwrap();
            std::array::from_fn(|j| a[j].as_f64().unwrap())
        })
        .collect()
}
fn fv(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}
pub fn load(name: &str) -> Recording {
    let d: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(format!("/tmp/identb/{name}.json")).unwrap())
            .unwrap();
    let s = &d["state"];
    let c = &d["command"];
    Recording {
        source: format!("/work/shared/recordings/g1_{name}.mcap").into(),
        start_ns: d["start_ns"].as_u64().unwrap(),
        joint_names: vec![],
        state: StateSeries {
            t: fv(&s["t"]),
            q: arr7(&s["q"]),
            dq: arr7(&s["dq"]),
            tau: arr7(&s["tau"]),
            temp: arr7(&s["temp"]),
            gyro: arrn::<3>(&s["gyro"]),
            quat: arrn::<4>(&s["quat"]),
        },
        command: CommandSeries {
            t: fv(&c["t"]),
            q: arr7(&c["q"]),
            dq: arr7(&c["dq"]),
        },
        mbs: PowerSeries {
            t: fv(&d["mbs"]["t"]),
            watts: fv(&d["mbs"]["watts"]),
        },
        bms: PowerSeries {
            t: fv(&d["bms"]["t"]),
            watts: fv(&d["bms"]["watts"]),
        },
        warnings: vec![],
    }
}
fn truth(name: &str) -> Vec<[f64; 5]> {
    let d: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(format!("/work/shared/recordings/g1_{name}.truth.json")).unwrap(),
    )
    .unwrap();
    let s0 = d["session"]["start_ns"].as_u64().unwrap() as f64;
    d["trials"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| {
            std::array::from_fn(|k| {
                (t[[
                    "t_trial_start_ns",
                    "t_traj_start_ns",
                    "t_traj_end_ns",
                    "t_post_idle_end_ns",
                    "t_return_end_ns",
                ][k]]
                    .as_u64()
                    .unwrap() as f64
                    - s0)
                    / 1e9
            })
        })
        .collect()
}
fn main() {
    let mut recs = vec![];
    for name in ["smoke", "holdout"] {
        let rec = load(name);
        for src in [SegmentSource::Command, SegmentSource::State] {
            let seg = segment(
                &rec,
                &SegmentOptions {
                    source: src,
                    ..Default::default()
                },
            );
            let tr = truth(name);
            println!(
                "{name} {src:?}: {} trials (truth {}), unmatched {:?}",
                seg.trials.len(),
                tr.len(),
                seg.unmatched
            );
            let mut maxe = [0.0f64; 5];
            for (t, x) in seg.trials.iter().zip(&tr) {
                let b = [
                    t.t_pre_start,
                    t.t_traj_start,
                    t.t_traj_end,
                    t.t_post_end,
                    t.t_return_end,
                ];
                for k in 0..5 {
                    maxe[k] = maxe[k].max((b[k] - x[k]).abs());
                }
            }
            println!("  max err {:?}", maxe);
            if src == SegmentSource::Command {
                for t in &seg.trials {
                    print!(
                        "[{:?} {:.2} {:.2}] ",
                        t.joints_moved, t.qdot_max_cmd, t.qdot_max_meas
                    );
                }
                println!();
            }
        }
        recs.push(rec);
    }
    let t0 = std::time::Instant::now();
    for mode in [Mode::Reading, Mode::Trial] {
        let opts = IdentifyOptions {
            mode,
            ..Default::default()
        };
        let id = identify(&recs[..1], &opts).unwrap();
        println!(
            "mode {:?} align {:?} fit {:?} trial-level {:?} aligned {:?}",
            mode, id.alignment, id.fit, id.trial_level, id.trial_level_aligned
        );
        for m in &id.modes {
            println!("  {:?}", m);
        }
        for r in &id.rejections {
            println!("  {}", r.describe());
        }
        let th = id.model.to_vector();
        let tr = g1viz::power::PowerModel::PAPER.to_vector();
        println!(
            "  theta {:?}",
            th.iter()
                .zip(tr)
                .map(|(a, b)| format!("{:.2}/{:.2}", a, b))
                .collect::<Vec<_>>()
        );
        let v = validate(&id.model, &recs[1], &opts).unwrap();
        println!(
            "  validate trial {:?} kept {:?} reading {:?} align {:?}",
            v.trial_level, v.trial_level_aligned, v.reading_level, v.alignment
        );
        if let Some(e) = &id.alignment_estimate {
            let mut g = e.grid.clone();
            g.sort_by(|a, b| b.r2.total_cmp(&a.r2));
            for s in g.iter().take(6) {
                println!("    {:?}", s);
            }
        }
        println!("  took {:?}", t0.elapsed());
    }
    let v = validate(
        &g1viz::power::PowerModel::PAPER,
        &recs[1],
        &IdentifyOptions::default(),
    )
    .unwrap();
    println!(
        "truth model on holdout: {:?} kept {:?} reading {:?}",
        v.trial_level, v.trial_level_aligned, v.reading_level
    );
    let v = validate(
        &g1viz::power::PowerModel::PAPER,
        &recs[0],
        &IdentifyOptions::default(),
    )
    .unwrap();
    println!(
        "truth model on smoke: {:?} kept {:?} reading {:?}",
        v.trial_level, v.trial_level_aligned, v.reading_level
    );
    for p in &v.per_trial {
        println!(
            "   {} {:.3} {:.3} σω {:.4} {}",
            p.trial, p.measured_w, p.predicted_w, p.sigma_omega, p.rejected
        );
    }
}
