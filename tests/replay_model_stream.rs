//! `replay --model` of a file (the validation streamed, the model's series computed trial by
//! trial from the file read again in pieces) against the replay of the whole recording loaded in
//! memory (`overlay::model_extras` + `log_replay`, the same series fed from the loaded samples):
//! both log the model's series through one computation (`ReplayLogger::log_model_trial`), so
//! these tests hold the file's trial-by-trial reading to the loaded recording — the decoded
//! `.rrd` files hold the same rows and the same values, on the shipped example and on a
//! simulated session read in pieces, whole and sliced (`--from/--to`, `--max-rate`). What the
//! series give (the bars, the colour scale) is checked against the decoded series themselves in
//! tests/viz.rs. `diagnose --save` of one session streams its replay too: checked the same way
//! against the replay of the loaded session.

use std::collections::BTreeMap;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use g1viz::identify::IdentifyOptions;
use g1viz::power::PowerModel;
use g1viz::robot::RobotModel;
use g1viz::session::StreamOptions;
use g1viz::signals::{SignalMap, load_recording};
use g1viz::viz::{ReplayOptions, log_replay};
use g1viz::viz::{SessionReplay, Window, replay_session};
use g1viz::viz::{Sink, open_stream, recording_id_for};
use rerun::external::re_log_encoding::DecoderApp;
use rerun::external::re_log_types::StoreKind;
use rerun::log::{Chunk, LogMsg};

fn example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap")
}

/// What a decoded `.rrd` holds: per (blueprint?, entity, static?) the rows; the data chunks.
struct Decoded {
    rows: BTreeMap<(bool, String, bool), usize>,
    chunks: Vec<Chunk>,
    /// The plot ranges of the last layout sent (each view's y axis), as printed, sorted.
    axes: Vec<String>,
}

fn decode(path: &Path) -> Decoded {
    let file = std::fs::File::open(path).unwrap();
    let mut d = Decoded {
        rows: BTreeMap::new(),
        chunks: Vec::new(),
        axes: Vec::new(),
    };
    let mut last_axes: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for msg in DecoderApp::decode_lazy(BufReader::new(file)) {
        if let LogMsg::ArrowMsg(store, arrow) = msg.unwrap() {
            let chunk = Chunk::from_arrow_msg(&arrow).unwrap();
            let blueprint = store.kind() == StoreKind::Blueprint;
            *d.rows
                .entry((
                    blueprint,
                    chunk.entity_path().to_string(),
                    chunk.is_static(),
                ))
                .or_default() += chunk.num_rows();
            if !blueprint {
                d.chunks.push(chunk);
            } else if chunk.entity_path().to_string().ends_with("/ScalarAxis") {
                // The layout is sent again once the data are logged: the viewer keeps the last.
                let text: Vec<String> = chunk
                    .components()
                    .iter()
                    .map(|(desc, list)| format!("{desc:?} {:?}", list.list_array))
                    .collect();
                last_axes.insert(chunk.entity_path().to_string(), text);
            }
        }
    }
    d.axes = last_axes.into_values().flatten().collect();
    d.axes.sort();
    d
}

/// The `(time [ns], value)` rows at `path`, sorted: scalars by their bits, anything else
/// (transforms, colours, text) as printed.
fn series(d: &Decoded, path: &str) -> Vec<(i64, String)> {
    use rerun::external::arrow::array::{Array, AsArray};
    use rerun::external::arrow::datatypes::Float64Type;
    let mut v = Vec::new();
    for chunk in d
        .chunks
        .iter()
        .filter(|c| !c.is_static() && c.entity_path().to_string() == path)
    {
        let times = chunk
            .timelines()
            .iter()
            .find(|(name, _)| name.as_str() == "time")
            .unwrap()
            .1
            .times_raw()
            .to_vec();
        for (desc, list) in chunk.components().iter() {
            let arr = &list.list_array;
            let values = arr.values().as_primitive_opt::<Float64Type>();
            for (i, &t) in times.iter().enumerate() {
                let text = match values {
                    Some(f) if arr.value_length(i) == 1 => {
                        format!("{:x}", f.value(arr.value_offsets()[i] as usize).to_bits())
                    }
                    _ => format!("{desc:?} {:?}", arr.value(i)),
                };
                v.push((t, text));
            }
            let _ = arr.len();
        }
    }
    v.sort_unstable();
    v
}

/// The static values at `path` (styles, notes, geometry), as text.
fn statics(d: &Decoded, path: &str) -> Vec<String> {
    let mut v: Vec<String> = d
        .chunks
        .iter()
        .filter(|c| c.is_static() && c.entity_path().to_string() == path)
        .flat_map(|c| {
            c.components()
                .iter()
                .map(|(desc, list)| format!("{desc:?} {:?}", list.list_array))
                .collect::<Vec<_>>()
        })
        .collect();
    v.sort();
    v.dedup();
    v
}

/// The in-memory model replay (the whole recording, `model_extras`, `log_replay`).
fn in_memory(session: &Path, out: &Path, opts: &IdentifyOptions, ro: &ReplayOptions) {
    let rec = load_recording(session, &SignalMap::g1_left_arm(), &Default::default()).unwrap();
    let (extras, _) = g1viz::viz::model_extras(&rec, &PowerModel::PAPER, opts).unwrap();
    let robot = RobotModel::builtin();
    let arm = robot.arm(&rec.joint_names).unwrap();
    let kind = g1viz::viz::OutputKind::ModelReplay;
    let viz = open_stream(
        &kind.app_id(),
        &kind.recording_id(&recording_id_for(&rec)),
        &Sink::Save(out.to_path_buf()),
        &[session],
    )
    .unwrap();
    log_replay(&rec, &robot, &arm, &extras, ro, viz.stream()).unwrap();
    viz.finish().unwrap();
}

/// The streamed model replay, as `g1viz replay --model paper --save` does it.
fn streamed(session: &Path, out: &Path, opts: &IdentifyOptions, ro: &ReplayOptions, w: Window) {
    let map = SignalMap::g1_left_arm();
    let read = Default::default();
    let robot = RobotModel::builtin();
    let sink = Sink::Save(out.to_path_buf());
    let inputs = [session];
    let r = SessionReplay {
        session,
        map: &map,
        read: &read,
        robot: &robot,
        model: Some(("paper", &PowerModel::PAPER)),
        fit: opts.clone(),
        sink: &sink,
        inputs: &inputs,
        window: w,
        opts: ro.clone(),
    };
    replay_session(&r, &mut |_| {}).unwrap();
}

/// Every row and every value of the two replays agree (model series, readings, bars, link
/// colours, the layout's plot ranges, the colour-scale note).
fn assert_same_replay(a: &Path, b: &Path, what: &str) {
    assert_same_replay_of(a, b, what, &["/model", "/breakdown", "/terms", "/bars"], 20);
}

/// [`assert_same_replay`], with more than `min_marked` series under the `marked` paths.
fn assert_same_replay_of(a: &Path, b: &Path, what: &str, marked: &[&str], min_marked: usize) {
    let (a, b) = (decode(a), decode(b));
    let differ: Vec<_> = a
        .rows
        .keys()
        .chain(b.rows.keys())
        .filter(|k| !k.0 && a.rows.get(*k) != b.rows.get(*k))
        .map(|k| (k, a.rows.get(k), b.rows.get(k)))
        .collect();
    assert!(
        differ.is_empty(),
        "{what}: rows per entity differ: {differ:?}"
    );
    let blueprint = |d: &Decoded| d.rows.keys().filter(|k| k.0).count();
    assert_eq!(blueprint(&a), blueprint(&b), "{what}: layout");
    // A long session's layout leaves its linked plots unranged (the viewer fits them to the
    // window); its whole-session plots carry theirs, so at least two ranges are compared.
    assert!(a.axes.len() >= 2, "{what}: {} plot ranges", a.axes.len());
    assert_eq!(a.axes, b.axes, "{what}: plot ranges");
    let temporal: Vec<&String> = a
        .rows
        .keys()
        .filter(|(bp, _, st)| !bp && !st)
        .map(|(_, p, _)| p)
        .collect();
    let mut model_paths = 0;
    for p in temporal {
        if marked.iter().any(|x| p.contains(x)) {
            model_paths += 1;
        }
        let (x, y) = (series(&a, p), series(&b, p));
        if !x.is_empty() || !y.is_empty() {
            assert_eq!(x, y, "{what}: {p}");
        }
    }
    assert!(
        model_paths > min_marked,
        "{what}: {model_paths} series under {marked:?}"
    );
    let statics_paths: Vec<&String> = a
        .rows
        .keys()
        .filter(|(bp, _, st)| !bp && *st)
        .map(|(_, p, _)| p)
        .filter(|p| !p.contains("__properties") && !p.contains("recording"))
        .collect();
    for p in statics_paths {
        assert_eq!(statics(&a, p), statics(&b, p), "{what}: static {p}");
    }
}

fn replay_options(stream: StreamOptions, slice: g1viz::viz::Slice) -> ReplayOptions {
    ReplayOptions {
        pose_rate_hz: Some(30.0),
        slice,
        stream,
        ..Default::default()
    }
}

#[test]
fn streamed_model_replay_equals_in_memory_on_the_example() {
    let dir = tempfile::tempdir().unwrap();
    let opts = IdentifyOptions::default();
    for (k, chunk_s) in [600.0, 15.0].into_iter().enumerate() {
        let so = StreamOptions {
            chunk_s,
            batch_samples: 500,
            ..StreamOptions::default()
        };
        let (a, b) = (
            dir.path().join(format!("mem{k}.rrd")),
            dir.path().join(format!("str{k}.rrd")),
        );
        in_memory(
            &example(),
            &a,
            &opts,
            &replay_options(so, Default::default()),
        );
        streamed(
            &example(),
            &b,
            &opts,
            &replay_options(so, Default::default()),
            Window::default(),
        );
        assert_same_replay(&a, &b, &format!("example, pieces of {chunk_s} s"));
    }
}

#[test]
fn streamed_model_replay_equals_in_memory_on_a_simulated_session_in_pieces() {
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
    let opts = IdentifyOptions::default();
    let so = StreamOptions {
        chunk_s: 60.0,
        batch_samples: 2000,
        ..StreamOptions::default()
    };
    let whole = replay_options(so, Default::default());
    let (a, b) = (dir.path().join("mem.rrd"), dir.path().join("str.rrd"));
    in_memory(&path, &a, &opts, &whole);
    streamed(&path, &b, &opts, &whole, Window::default());
    assert_same_replay(&a, &b, "simulated session, 60 s pieces");

    // Sliced: a window in session seconds and a rate cap, as --from/--to/--max-rate give.
    let window = Window {
        from_s: Some(100.0),
        to_s: Some(400.0),
        max_rate_hz: Some(20.0),
        trials: None,
    };
    let slice = window.resolve(None, &path).unwrap();
    let cut = replay_options(so, slice);
    let (c, d) = (
        dir.path().join("mem_cut.rrd"),
        dir.path().join("str_cut.rrd"),
    );
    in_memory(&path, &c, &opts, &cut);
    streamed(
        &path,
        &d,
        &opts,
        &replay_options(so, Default::default()),
        window,
    );
    assert_same_replay(&c, &d, "simulated session, 100-400 s at 20 Hz");
}

/// `diagnose SESSION --save` streams the session into the `.rrd` (the diagnosis' overlays are
/// per reading and per trial): the same rows and values as the replay of the loaded session
/// with the same diagnosis, on a simulated session with a power-sensor latency the diagnosis
/// finds (so the before/after series differ).
#[test]
fn streamed_diagnosis_replay_equals_in_memory() {
    use g1viz::diagnose::{self, DiagnoseOptions};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("latency.mcap");
    let mut effects = g1viz::sim::Effects::default();
    effects.enable("latency").unwrap();
    g1viz::sim::simulate(
        &g1viz::sim::SimConfig {
            progress: false,
            seed: 3,
            effects,
            ..Default::default()
        },
        &path,
    )
    .unwrap();
    let opts = DiagnoseOptions {
        reference: Some(PowerModel::PAPER),
        ..DiagnoseOptions::default()
    };
    let map = SignalMap::g1_left_arm();
    let file = g1viz::session::SessionFile {
        path: path.clone(),
        map: map.clone(),
        read: Default::default(),
        spill: Default::default(),
    };
    let d = diagnose::diagnose_files(std::slice::from_ref(&file), &opts, 5.0).unwrap();
    assert!(
        !d.replay.t.is_empty(),
        "the diagnosis has no readings to show"
    );
    assert!(
        !d.accepted.is_empty(),
        "the latency was not found: {}",
        d.summary
    );
    let extras = g1viz::viz::diagnosis_extras(&d);
    let robot = RobotModel::builtin();
    let arm = robot.arm(&map.joint_names).unwrap();
    let ro = ReplayOptions::default();
    let kind = g1viz::viz::OutputKind::Diagnosis;
    let (a, b) = (dir.path().join("mem.rrd"), dir.path().join("str.rrd"));
    let rec = load_recording(&path, &map, &Default::default()).unwrap();
    let out = open_stream(
        &kind.app_id(),
        &kind.recording_id(&recording_id_for(&rec)),
        &Sink::Save(a.clone()),
        &[path.as_path()],
    )
    .unwrap();
    log_replay(&rec, &robot, &arm, &extras, &ro, out.stream()).unwrap();
    out.finish().unwrap();
    let id = g1viz::viz::recording_id_for_source(&path).unwrap();
    let out = open_stream(
        &kind.app_id(),
        &kind.recording_id(&id),
        &Sink::Save(b.clone()),
        &[path.as_path()],
    )
    .unwrap();
    g1viz::viz::replay_files_with(
        &[path.as_path()],
        0.0,
        &map,
        &Default::default(),
        &robot,
        &arm,
        extras,
        &ro,
        out.stream(),
    )
    .unwrap();
    out.finish().unwrap();
    assert_same_replay_of(&a, &b, "diagnosis replay", &["diagnosis/"], 5);
}

/// `diagnose A B --save` replays the sessions part by part on the diagnosis' joined clock
/// (`replay_files_with`): the same rows and values as the replay of the sessions loaded and
/// joined (`join_recordings_with_sources`, as the diagnosis joins them), the second part's
/// samples shifted onto the first's clock.
#[test]
fn streamed_joined_diagnosis_replay_equals_in_memory() {
    use g1viz::diagnose::{self, DiagnoseOptions};
    let dir = tempfile::tempdir().unwrap();
    let map = SignalMap::g1_left_arm();
    let mut paths = Vec::new();
    for seed in [3, 4] {
        let path = dir.path().join(format!("latency{seed}.mcap"));
        let mut effects = g1viz::sim::Effects::default();
        effects.enable("latency").unwrap();
        g1viz::sim::simulate(
            &g1viz::sim::SimConfig {
                progress: false,
                seed,
                effects,
                ..Default::default()
            },
            &path,
        )
        .unwrap();
        paths.push(path);
    }
    let files: Vec<_> = paths
        .iter()
        .map(|p| g1viz::session::SessionFile {
            path: p.clone(),
            map: map.clone(),
            read: Default::default(),
            spill: Default::default(),
        })
        .collect();
    let opts = DiagnoseOptions {
        reference: Some(PowerModel::PAPER),
        ..DiagnoseOptions::default()
    };
    let d = diagnose::diagnose_files(&files, &opts, 5.0).unwrap();
    let parts: Vec<_> = paths
        .iter()
        .map(|p| load_recording(p, &map, &Default::default()).unwrap())
        .collect();
    let first_end = parts[0].state.t.last().copied().unwrap();
    let (rec, _) = diagnose::join_recordings_with_sources(parts, 5.0);
    assert!(
        d.replay.t.iter().any(|&t| t > first_end + 5.0),
        "the diagnosis has no readings in the second session"
    );
    let extras = g1viz::viz::diagnosis_extras(&d);
    let robot = RobotModel::builtin();
    let arm = robot.arm(&map.joint_names).unwrap();
    let ro = ReplayOptions::default();
    let kind = g1viz::viz::OutputKind::Diagnosis;
    let (a, b) = (dir.path().join("mem.rrd"), dir.path().join("str.rrd"));
    let inputs: Vec<&Path> = paths.iter().map(PathBuf::as_path).collect();
    let out = open_stream(
        &kind.app_id(),
        &kind.recording_id(&recording_id_for(&rec)),
        &Sink::Save(a.clone()),
        &inputs,
    )
    .unwrap();
    log_replay(&rec, &robot, &arm, &extras, &ro, out.stream()).unwrap();
    out.finish().unwrap();
    let id = g1viz::viz::recording_id_for_source(&paths[0]).unwrap();
    let out = open_stream(
        &kind.app_id(),
        &kind.recording_id(&id),
        &Sink::Save(b.clone()),
        &inputs,
    )
    .unwrap();
    g1viz::viz::replay_files_with(
        &inputs,
        5.0,
        &map,
        &Default::default(),
        &robot,
        &arm,
        extras,
        &ro,
        out.stream(),
    )
    .unwrap();
    out.finish().unwrap();
    assert_same_replay_of(&a, &b, "joined diagnosis replay", &["diagnosis/"], 5);
    // The second session is on the joined clock: the streamed replay's joint samples reach past
    // the first session's end and the 5 s gap.
    let q = series(&decode(&b), "/joints/elbow/q");
    let span_s = match (q.first(), q.last()) {
        (Some(a), Some(z)) => (z.0 - a.0) as f64 * 1e-9,
        _ => 0.0,
    };
    assert!(
        span_s > first_end + 5.0,
        "the streamed replay spans {span_s:.1} s, the first session alone {first_end:.1} s"
    );
}

/// `g1viz diagnose SESSION --model paper --save OUT --json J` end to end through the binary (the
/// streamed path the CLI takes for one session): the `.rrd` holds the diagnosis' measured power
/// at every reading the diagnosis used, as its JSON lists them, and the recording's properties.
#[test]
fn cli_diagnose_save_streams_the_diagnosis_rrd() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("latency.mcap");
    let mut effects = g1viz::sim::Effects::default();
    effects.enable("latency").unwrap();
    g1viz::sim::simulate(
        &g1viz::sim::SimConfig {
            progress: false,
            seed: 5,
            effects,
            ..Default::default()
        },
        &path,
    )
    .unwrap();
    let (rrd, json) = (dir.path().join("d.rrd"), dir.path().join("d.json"));
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_g1viz"))
        .args(["diagnose", "--model", "paper", "--save"])
        .arg(&rrd)
        .arg("--json")
        .arg(&json)
        .arg(&path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let d: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let readings = d["replay"]["t"].as_array().unwrap().len();
    assert!(readings > 50, "{readings} readings");
    let decoded = decode(&rrd);
    let measured: usize = decoded
        .rows
        .iter()
        .filter(|((bp, p, st), _)| !bp && !st && p.ends_with("diagnosis/power/measured"))
        .map(|(_, n)| n)
        .sum();
    assert_eq!(
        measured, readings,
        "measured power rows vs the diagnosis' readings"
    );
    assert!(
        decoded
            .rows
            .keys()
            .any(|(_, p, _)| p.contains("__properties")),
        "no recording properties"
    );
}
