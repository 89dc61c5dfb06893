//! The streamed identification and validation (two passes over the file, memory bounded by the
//! piece length) against the same pipeline over the loaded recording in memory (`identify()`,
//! `validate()`: default pieces, samples from memory): same trials, same sensor timing, same θ,
//! including when the file is segmented in many short pieces.

mod common;

use std::path::{Path, PathBuf};

use g1viz::identify::{self, AlignmentChoice, Identification, IdentifyOptions};
use g1viz::power::PowerModel;
use g1viz::session::{SessionFile, StreamOptions};
use g1viz::signals::{SignalMap, load_recording};

fn example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap")
}

fn file(path: &Path) -> SessionFile {
    SessionFile {
        path: path.to_path_buf(),
        map: SignalMap::g1_left_arm(),
        read: Default::default(),
        spill: Default::default(),
    }
}

/// Options the example supports: it is too short for the timing search (42 readings).
fn nominal() -> IdentifyOptions {
    IdentifyOptions {
        alignment: AlignmentChoice::Given(identify::Alignment::NOMINAL),
        ..IdentifyOptions::default()
    }
}

fn assert_same(a: &Identification, b: &Identification) {
    assert_eq!(a.sessions.len(), b.sessions.len());
    for (x, y) in a.sessions.iter().zip(&b.sessions) {
        assert_eq!(x.segmentation.trials, y.segmentation.trials);
        assert_eq!(x.skipped, y.skipped);
    }
    assert_eq!(a.alignment, b.alignment);
    assert_eq!(a.rejections, b.rejections);
    assert_eq!(a.model.to_vector(), b.model.to_vector());
    assert_eq!(a.per_trial, b.per_trial);
    assert_eq!(a.fit, b.fit);
    assert_eq!(a.trials_used, b.trials_used);
    for (x, y) in a.modes.iter().zip(&b.modes) {
        assert_eq!(x.mode, y.mode);
        assert_eq!(x.quality, y.quality);
    }
}

#[test]
fn streamed_identify_equals_in_memory_on_the_example() {
    let rec = load_recording(&example(), &SignalMap::g1_left_arm(), &Default::default()).unwrap();
    let opts = nominal();
    let mem = identify::identify(std::slice::from_ref(&rec), &opts).unwrap();
    // One piece (the default) and pieces of 15 s (every trial boundary near a piece boundary).
    for chunk_s in [600.0, 15.0, 31.0] {
        let so = StreamOptions {
            chunk_s,
            batch_samples: 500,
            ..StreamOptions::default()
        };
        let streamed = identify::identify_files(&[file(&example())], &opts, &so).unwrap();
        assert_eq!(mem.sessions[0].segmentation.trials.len(), 7);
        assert_same(&mem, &streamed);
        assert_eq!(
            mem.sessions[0].segmentation.unmatched, streamed.sessions[0].segmentation.unmatched,
            "piece length {chunk_s} s"
        );
    }
}

#[test]
fn streamed_validate_equals_in_memory_on_the_example() {
    let rec = load_recording(&example(), &SignalMap::g1_left_arm(), &Default::default()).unwrap();
    let model = PowerModel::PAPER;
    let opts = IdentifyOptions::default();
    let mem = identify::validate(&model, &rec, &opts).unwrap();
    let so = StreamOptions {
        chunk_s: 20.0,
        batch_samples: 700,
        ..StreamOptions::default()
    };
    let streamed = identify::validate_file(&model, &file(&example()), &opts, &so).unwrap();
    assert_eq!(mem.alignment, streamed.alignment);
    assert_eq!(mem.per_trial, streamed.per_trial);
    assert_eq!(mem.trial_level, streamed.trial_level);
    assert_eq!(mem.reading_level, streamed.reading_level);
    assert_eq!(mem.rejections, streamed.rejections);
    assert_eq!(mem.notes, streamed.notes);
}

/// A simulated 24-trial session (~6 min) in 60 s pieces, with the timing search's held trials
/// capped at 12 (every 2nd trial held): trials equal; the timing search runs on the held subset.
#[test]
fn streamed_identify_on_a_smoke_session_in_pieces() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("smoke.mcap");
    g1viz::sim::simulate(
        &g1viz::sim::SimConfig {
            progress: false,
            seed: 5,
            ..Default::default()
        },
        &path,
    )
    .unwrap();
    let rec = load_recording(&path, &SignalMap::g1_left_arm(), &Default::default()).unwrap();
    let opts = IdentifyOptions::default();
    let mem = identify::identify(std::slice::from_ref(&rec), &opts).unwrap();
    let pieces = StreamOptions {
        chunk_s: 60.0,
        ..StreamOptions::default()
    };
    let f = file(&path);
    let streamed = identify::identify_files(std::slice::from_ref(&f), &opts, &pieces).unwrap();
    assert!(mem.sessions[0].segmentation.trials.len() >= 20);
    assert_same(&mem, &streamed);
    // The passes after the first read the joint states the first spilled (the default); without
    // the spill they read the recording's trial windows again: the same result either way.
    assert!(
        f.spill.get().is_some(),
        "the first pass spilled no joint states"
    );
    let unspilled = StreamOptions {
        spill_states: false,
        ..pieces
    };
    let f = file(&path);
    let from_file = identify::identify_files(std::slice::from_ref(&f), &opts, &unspilled).unwrap();
    assert!(f.spill.get().is_none());
    assert_same(&mem, &from_file);

    let held = StreamOptions {
        chunk_s: 60.0,
        hold_trials: 12,
        ..StreamOptions::default()
    };
    // Pass 1 cannot hold every trial's samples (12 of 24): the timing search's trials are read
    // in one more streamed pass, the same kept trials as in memory, so the result is the same.
    let subset = identify::identify_files(&[file(&path)], &opts, &held).unwrap();
    let est = subset.alignment_estimate.as_ref().unwrap();
    let full = mem.alignment_estimate.as_ref().unwrap();
    assert_eq!(est.grid.len(), full.grid.len());
    for (a, b) in est.grid.iter().zip(&full.grid) {
        assert_eq!(a.rows, b.rows);
        assert_eq!(a.alignment, b.alignment);
        assert_eq!(a.r2.to_bits(), b.r2.to_bits());
    }
    assert_same(&mem, &subset);

    // The search on every 2nd trial (cap 12 of 24): pass 1's held set (every 2nd, cap 12) is
    // that set, no extra pass; the estimate is the in-memory one on the same thinned trials.
    let thin = IdentifyOptions {
        search_trials: 12,
        ..opts.clone()
    };
    assert_eq!(g1viz::session::search_stride(&[24], 12), 2);
    let mem_thin = identify::identify(std::slice::from_ref(&rec), &thin).unwrap();
    let streamed_thin = identify::identify_files(&[file(&path)], &thin, &held).unwrap();
    let (a, b) = (
        mem_thin.alignment_estimate.as_ref().unwrap(),
        streamed_thin.alignment_estimate.as_ref().unwrap(),
    );
    for (x, y) in a.grid.iter().zip(&b.grid) {
        assert_eq!(
            (x.rows, x.alignment, x.r2.to_bits()),
            (y.rows, y.alignment, y.r2.to_bits())
        );
    }
    assert_same(&mem_thin, &streamed_thin);
    // Fewer rows than the search over every trial: the thinned set is what was searched.
    assert!(
        a.grid[0].rows < full.grid[0].rows * 2 / 3,
        "{} vs {}",
        a.grid[0].rows,
        full.grid[0].rows
    );
    // … and it finds the simulated sensor's timing (0.2 s window, no lag) within one fine step.
    assert!(
        (subset.alignment.window_s - 0.2).abs() <= 0.0251,
        "{:?}",
        subset.alignment
    );
    assert!(
        subset.alignment.lag_s.abs() <= 0.0251,
        "{:?}",
        subset.alignment
    );
}

/// Two sessions of one robot (the example, and a simulated one started with warm windings): the
/// per-session breakdown accounts for every trial and row, and shows each start temperature.
#[test]
fn multi_session_breakdown() {
    let dir = tempfile::tempdir().unwrap();
    let warm = dir.path().join("warm.mcap");
    g1viz::sim::simulate(
        &g1viz::sim::SimConfig {
            preset: g1viz::sim::Preset::Example,
            progress: false,
            seed: 9,
            t_start_c: 55.0,
            ..Default::default()
        },
        &warm,
    )
    .unwrap();
    let opts = nominal();
    let id = identify::identify_files(
        &[file(&example()), file(&warm)],
        &opts,
        &StreamOptions::default(),
    )
    .unwrap();
    assert_eq!(id.per_session.len(), 2);
    let total: usize = id
        .sessions
        .iter()
        .map(|s| s.segmentation.trials.len())
        .sum();
    assert_eq!(
        id.per_session.iter().map(|b| b.trials).sum::<usize>(),
        total
    );
    assert_eq!(
        id.per_session.iter().map(|b| b.used).sum::<usize>(),
        id.trials_used
    );
    for (s, b) in id.per_session.iter().enumerate() {
        let rejected = id.rejections.iter().filter(|r| r.session == s).count();
        assert_eq!(b.rejected, rejected);
        assert_eq!(b.used + b.rejected + b.without_rows, b.trials, "{b:?}");
    }
    // The final fit's rows are the sessions' per-reading rows: their RMSEs pool to the fit's.
    let n: usize = id.per_session.iter().map(|b| b.reading.n).sum();
    assert_eq!(n, id.fit.n);
    let pooled = (id
        .per_session
        .iter()
        .map(|b| b.reading.n as f64 * b.reading.rmse.powi(2))
        .sum::<f64>()
        / n as f64)
        .sqrt();
    assert!(
        (pooled - id.fit.rmse).abs() < 1e-9,
        "{pooled} vs {}",
        id.fit.rmse
    );
    // Start temperatures: the example's first sample as read independently, the twin's 55 °C.
    let rec = load_recording(&example(), &SignalMap::g1_left_arm(), &Default::default()).unwrap();
    assert_eq!(
        id.per_session[0].first_temp_c,
        rec.state.temp.first().copied()
    );
    let warm_t = id.per_session[1].first_temp_c.unwrap();
    assert!(warm_t.iter().all(|t| (t - 55.0).abs() <= 1.5), "{warm_t:?}");
    let text = id.summary();
    assert!(text.contains("per session:"), "{text}");
    assert!(text.contains("warm.mcap"), "{text}");
    let report = dir.path().join("report");
    let file = id
        .model_file(&SignalMap::g1_left_arm().joint_names, None, "")
        .unwrap();
    g1viz::identify::write_report(&report, &id.report_input(file, None, None)).unwrap();
    let md = std::fs::read_to_string(report.join("report.md")).unwrap();
    assert!(md.contains("## Per session"), "{md}");
    let joined: Vec<String> = warm_t.iter().map(|v| format!("{v:.1}")).collect();
    assert!(md.contains(&joined.join(", ")), "{md}");
}

/// The exported rows of a streamed session (one trial held at a time) equal those built on the
/// loaded recording: regressors, net power, temperatures, flags.
#[test]
fn streamed_row_export_equals_in_memory() {
    let rec = load_recording(&example(), &SignalMap::g1_left_arm(), &Default::default()).unwrap();
    let opts = nominal();
    let mem_id = identify::identify(std::slice::from_ref(&rec), &opts).unwrap();
    let mem = g1viz::rows::table_rows(std::slice::from_ref(&rec), &mem_id, "r");
    let files = [file(&example())];
    let id = identify::identify_files(&files, &opts, &StreamOptions::default()).unwrap();
    // The export reads the joint states the identification spilled.
    assert!(files[0].spill.get().is_some());
    let streamed = g1viz::rows::table_rows_files(&files, &id, "r").unwrap();
    assert!(mem.len() > 40, "{}", mem.len());
    assert_eq!(mem.len(), streamed.len());
    for (a, b) in mem.iter().zip(&streamed) {
        assert_eq!(a.row, b.row);
        assert_eq!(
            (a.t_ns, &a.session, &a.rejected_by),
            (b.t_ns, &b.session, &b.rejected_by)
        );
        for (x, y) in a.temp_c.iter().zip(&b.temp_c) {
            assert!(x == y || (x.is_nan() && y.is_nan()), "{x} vs {y}");
        }
    }
}

/// The shared smoke recording as a ROS 1 bag and as a rosbag2 (sqlite) folder, written by other
/// tools than this crate: identify and validate streamed in 15 s pieces (the readers' streamed
/// path on both containers) equal the pipeline over the loaded recording in memory.
#[test]
fn streamed_identify_and_validate_on_bag_and_db3() {
    let (Some(bag), Some(db3)) = (
        common::shared_recording("g1_smoke.bag"),
        common::shared_recording("g1_smoke_db3"),
    ) else {
        return;
    };
    // Three trials: too few readings for the timing search, so at the sensor's nominal timing.
    let opts = nominal();
    let so = StreamOptions {
        chunk_s: 15.0,
        batch_samples: 300,
        ..StreamOptions::default()
    };
    let map = SignalMap::g1_left_arm();
    for path in [bag, db3] {
        let rec = load_recording(&path, &map, &Default::default()).unwrap();
        let mem = identify::identify(std::slice::from_ref(&rec), &opts).unwrap();
        let streamed = identify::identify_files(&[file(&path)], &opts, &so).unwrap();
        assert_same(&mem, &streamed);
        assert!(!mem.sessions[0].segmentation.trials.is_empty());
        let model = PowerModel::PAPER;
        let mem = identify::validate(&model, &rec, &opts).unwrap();
        let streamed = identify::validate_file(&model, &file(&path), &opts, &so).unwrap();
        assert_eq!(mem.alignment, streamed.alignment, "{}", path.display());
        assert_eq!(mem.per_trial, streamed.per_trial, "{}", path.display());
        assert_eq!(mem.reading_level, streamed.reading_level);
        assert_eq!(mem.rejections, streamed.rejections);
        assert_eq!(mem.readings, streamed.readings);
        assert_eq!(mem.baselines, streamed.baselines);
    }
}

/// The per-sample fit (`--mode sample`) holds no sample rows: each trial's are reduced to their
/// normal equations and sums as they are built. Streamed (in pieces) it equals the in-memory
/// pipeline on the example and on a simulated 24-trial session (timing estimated, residual
/// rejection on), and both equal a constrained fit of every retained trial's sample rows built
/// and held independently (the fit the per-sample mode made before it was bounded).
#[test]
fn streamed_sample_mode_equals_in_memory_and_the_fit_of_the_rows() {
    let dir = tempfile::tempdir().unwrap();
    let sim = dir.path().join("smoke.mcap");
    g1viz::sim::simulate(
        &g1viz::sim::SimConfig {
            progress: false,
            seed: 5,
            ..Default::default()
        },
        &sim,
    )
    .unwrap();
    let sample = |base: IdentifyOptions| IdentifyOptions {
        mode: identify::Mode::Sample,
        ..base
    };
    let narrow = IdentifyOptions {
        filters: g1viz::trial::Cascade {
            n_sigma: 1.5,
            ..Default::default()
        },
        ..IdentifyOptions::default()
    };
    for (path, opts, chunk_s) in [
        (example(), sample(nominal()), 15.0),
        // A narrow residual band, so trials are rejected by their mean residual too.
        (sim.clone(), sample(narrow), 60.0),
    ] {
        let rec = load_recording(&path, &SignalMap::g1_left_arm(), &Default::default()).unwrap();
        let mem = identify::identify(std::slice::from_ref(&rec), &opts).unwrap();
        let so = StreamOptions {
            chunk_s,
            batch_samples: 500,
            ..StreamOptions::default()
        };
        let streamed = identify::identify_files(&[file(&path)], &opts, &so).unwrap();
        assert_same(&mem, &streamed);
        assert_eq!(mem.std_err, streamed.std_err);
        let by_residual = mem
            .rejections
            .iter()
            .any(|r| r.reason == g1viz::trial::RejectReason::Residual);
        assert_eq!(by_residual, path == sim, "{:?}", mem.rejections);
        for (x, y) in mem.modes.iter().zip(&streamed.modes) {
            assert_eq!(x.kappa, y.kappa, "{:?}", x.mode);
        }

        // Independently: every retained trial's sample rows, held, fitted as rows.
        let retained: Vec<_> = mem.sessions[0]
            .segmentation
            .trials
            .iter()
            .filter(|t| !mem.rejections.iter().any(|r| r.trial == t.index))
            .cloned()
            .collect();
        let rows = identify::build_dataset(
            &rec,
            &retained,
            &identify::DatasetOptions {
                mode: identify::Mode::Sample,
                target: opts.target,
                alignment: mem.alignment,
            },
        )
        .rows;
        assert!(rows.len() > 1000, "{} rows", rows.len());
        // The rows fitted directly (QR of the rows, clarabel), scored with the whole-set metrics.
        let phi: Vec<[f64; 49]> = rows.iter().map(|r| r.phi).collect();
        let y: Vec<f64> = rows.iter().map(|r| r.y).collect();
        let lower = g1viz::lsq::paper_lower_bounds();
        let held = g1viz::lsq::fit_constrained(&phi, &y, &lower).unwrap();
        let yhat: Vec<f64> = phi
            .iter()
            .map(|p| p.iter().zip(&held.theta).map(|(a, b)| a * b).sum())
            .collect();
        let held_fit = g1viz::lsq::Metrics::compute(&y, &yhat);
        assert_eq!(mem.fit.n, rows.len());
        assert_eq!(mem.trials_used, retained.len());
        let close = |a: f64, b: f64, tol: f64| (a - b).abs() <= tol * b.abs().max(1e-9);
        for (name, a, b) in [
            ("r2", mem.fit.r2, held_fit.r2),
            ("rmse", mem.fit.rmse, held_fit.rmse),
            ("mae", mem.fit.mae, held_fit.mae),
            ("bias", mem.fit.bias, held_fit.bias),
            ("skewness", mem.fit.skewness, held_fit.skewness),
            ("kurtosis", mem.fit.kurtosis, held_fit.kurtosis),
        ] {
            assert!(close(a, b, 1e-6), "{}: {name} {a} vs {b}", path.display());
        }
        let sample_mode = mem.modes.iter().find(|m| m.mode == identify::Mode::Sample);
        let kappa = g1viz::lsq::condition_number(&phi);
        assert!(close(sample_mode.unwrap().kappa, kappa, 1e-6));
        // The held fit's standard errors (from the rows' residuals) are the bounded fit's.
        for (a, b) in mem.std_err.iter().zip(&held.std_err) {
            match (a, b) {
                (Some(a), Some(b)) => assert!(close(*a, *b, 1e-4), "std err {a} vs {b}"),
                _ => assert_eq!(a.is_some(), b.is_some()),
            }
        }
        // Predictions agree to solver accuracy (θ itself is ill-determined per sample).
        let (a, b) = (mem.model.to_vector(), held.theta.clone());
        let rms = |theta: &[f64]| {
            let sq: f64 = rows
                .iter()
                .map(|r| {
                    r.phi
                        .iter()
                        .zip(theta)
                        .map(|(p, t)| p * t)
                        .sum::<f64>()
                        .powi(2)
                })
                .sum();
            (sq / rows.len() as f64).sqrt()
        };
        let diff: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x - y).collect();
        assert!(
            rms(&diff) <= 1e-4 * rms(&b),
            "{}: predictions differ by {} W rms",
            path.display(),
            rms(&diff)
        );
    }
}
