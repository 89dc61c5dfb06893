//! Rerun output: `.rrd` files written by the replay are read back with rerun's own decoder (and
//! `rerun rrd verify` when the stock CLI is on PATH) and checked against the input recording.
#![cfg(feature = "viz")]

mod common;

use std::collections::BTreeMap;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use g1viz::N_JOINTS;
use g1viz::robot::RobotModel;
use g1viz::signals::{CommandSeries, PowerSeries, Recording, StateSeries};
use g1viz::trial::{RejectReason, Rejection};
use g1viz::viz::replay::{ReplayExtras, ReplayOptions, TrialMark, log_replay};
use g1viz::viz::{Sink, open_stream, recording_id_for};
use rerun::external::re_build_info::CrateVersion;
use rerun::external::re_log_encoding::{DecoderApp, Encoder, EncodingOptions};
use rerun::external::re_log_types::StoreKind;
use rerun::log::{Chunk, LogMsg};

const ARM: [&str; N_JOINTS] = [
    "left_shoulder_pitch_joint",
    "left_shoulder_roll_joint",
    "left_shoulder_yaw_joint",
    "left_elbow_joint",
    "left_wrist_roll_joint",
    "left_wrist_pitch_joint",
    "left_wrist_yaw_joint",
];
const START_NS: u64 = 1_700_000_000_000_000_000;
const N: usize = 500; // 5 s at 100 Hz

/// Synthetic session: still for 1 s, then joint j follows 0.3·sin(2π·0.5·(t−1))·(j+1)/7.
/// MBS reads 120 W at 0.5 s (idle) and 150, 160, 170, 180 W at 1.5..4.5 s; BMS 135 W + 10 W·k.
fn synthetic(source: &Path) -> Recording {
    let mut state = StateSeries::default();
    for i in 0..N {
        let t = i as f64 * 0.01;
        let q: [f64; N_JOINTS] = std::array::from_fn(|j| joint_q(j, t));
        state.t.push(t);
        state.q.push(q);
        state.dq.push([0.1; N_JOINTS]);
        state.tau.push(std::array::from_fn(|j| j as f64));
        state.temp.push([30.0; N_JOINTS]);
        state.gyro.push([0.3, 0.4, 0.0]);
        state.quat.push([1.0, 0.0, 0.0, 0.0]);
    }
    let mut command = CommandSeries::default();
    for i in 0..(N / 2) {
        let t = i as f64 * 0.02;
        command.t.push(t);
        command.q.push(std::array::from_fn(|j| joint_q(j, t)));
        command.dq.push([0.0; N_JOINTS]);
    }
    let times = vec![0.5, 1.5, 2.5, 3.5, 4.5];
    Recording {
        source: source.to_path_buf(),
        start_ns: START_NS,
        joint_names: ARM.map(String::from).to_vec(),
        state,
        command,
        mbs: PowerSeries {
            t: times.clone(),
            watts: vec![120.0, 150.0, 160.0, 170.0, 180.0],
        },
        bms: PowerSeries {
            t: times,
            watts: vec![135.0, 145.0, 155.0, 165.0, 175.0],
        },
        warnings: vec![],
    }
}

fn joint_q(j: usize, t: f64) -> f64 {
    if t < 1.0 {
        0.0
    } else {
        0.3 * (std::f64::consts::PI * (t - 1.0)).sin() * (j + 1) as f64 / 7.0
    }
}

fn extras() -> ReplayExtras {
    ReplayExtras {
        trials: vec![
            TrialMark {
                index: 0,
                t_start: 1.0,
                t_end: 2.5,
                label: "joints 0-6".into(),
                rejected: None,
                highlight: None,
            },
            TrialMark {
                index: 1,
                t_start: 2.5,
                t_end: 4.0,
                label: "joints 0-6".into(),
                rejected: Some(Rejection {
                    session: 0,
                    trial: 1,
                    reason: RejectReason::ImuSway,
                    statistic: 0.4,
                    threshold: 0.16,
                    pass: 0,
                    detail: String::new(),
                }),
                highlight: None,
            },
        ],
        ..Default::default()
    }
}

fn write_rrd(rec: &Recording, out: &Path) -> anyhow::Result<()> {
    let robot = RobotModel::builtin();
    let arm = robot.arm(&rec.joint_names)?;
    let viz = open_stream(
        "g1viz_test",
        &recording_id_for(rec),
        &Sink::Save(out.to_path_buf()),
        &[&rec.source],
    )?;
    let opts = ReplayOptions {
        chunk_rows: 128,
        progress: false,
        ..Default::default()
    };
    log_replay(rec, &robot, &arm, &extras(), &opts, viz.stream())?;
    viz.finish()
}

fn decode(path: &Path) -> Vec<LogMsg> {
    let file = std::fs::File::open(path).expect("open rrd");
    DecoderApp::decode_lazy(BufReader::new(file))
        .map(|m| m.expect("decodable rrd message"))
        .collect()
}

/// Rows per (store kind, entity path, static?) and the chunks of the recording store.
#[derive(Default)]
struct Contents {
    rows: BTreeMap<(bool, String, bool), usize>,
    chunks: Vec<Chunk>,
}

fn contents(msgs: &[LogMsg]) -> Contents {
    let mut c = Contents::default();
    for msg in msgs {
        if let LogMsg::ArrowMsg(store, arrow) = msg {
            let chunk = Chunk::from_arrow_msg(arrow).expect("valid chunk");
            let blueprint = store.kind() == StoreKind::Blueprint;
            *c.rows
                .entry((
                    blueprint,
                    chunk.entity_path().to_string(),
                    chunk.is_static(),
                ))
                .or_default() += chunk.num_rows();
            if !blueprint {
                c.chunks.push(chunk);
            }
        }
    }
    c
}

fn rows(c: &Contents, path: &str) -> usize {
    c.rows
        .get(&(false, path.to_owned(), false))
        .copied()
        .unwrap_or(0)
}

/// The `(time [ns], value)` pairs of the scalar series at `path`, sorted by time.
fn series(c: &Contents, path: &str) -> Vec<(i64, f64)> {
    use rerun::external::arrow::array::AsArray;
    use rerun::external::arrow::datatypes::Float64Type;
    let mut v = Vec::new();
    for chunk in c
        .chunks
        .iter()
        .filter(|ch| !ch.is_static() && ch.entity_path().to_string() == path)
    {
        let times = chunk
            .timelines()
            .iter()
            .find(|(name, _)| name.as_str() == "time")
            .expect("time timeline")
            .1
            .times_raw()
            .to_vec();
        let (_, list) = chunk.components().iter().next().expect("one component");
        let values = list.list_array.values().as_primitive::<Float64Type>();
        assert_eq!(values.len(), chunk.num_rows());
        v.extend(times.into_iter().zip(values.values().iter().copied()));
    }
    v.sort_by_key(|p| p.0);
    v
}

/// Replay `rec` (with `extras`) on the builtin robot into `out`, as `g1viz replay --save` does.
fn save_replay(rec: &Recording, extras: &ReplayExtras, out: &Path, input: &Path) {
    let robot = RobotModel::builtin();
    let arm = robot.arm(&rec.joint_names).unwrap();
    let viz = open_stream(
        "g1viz_test",
        &recording_id_for(rec),
        &Sink::Save(out.to_path_buf()),
        &[input],
    )
    .unwrap();
    let opts = ReplayOptions {
        progress: false,
        ..Default::default()
    };
    log_replay(rec, &robot, &arm, extras, &opts, viz.stream()).unwrap();
    viz.finish().unwrap();
}

fn input_file(dir: &Path) -> PathBuf {
    let p = dir.join("session.mcap");
    std::fs::write(
        &p,
        b"not really an mcap; only its name and size matter here",
    )
    .unwrap();
    p
}

#[test]
fn rrd_has_expected_entities_and_rows() {
    let dir = tempfile::tempdir().unwrap();
    let rec = synthetic(&input_file(dir.path()));
    let out = dir.path().join("out.rrd");
    write_rrd(&rec, &out).unwrap();
    let msgs = decode(&out);
    let c = contents(&msgs);

    for j in [
        "sh_pitch", "sh_roll", "sh_yaw", "elbow", "wr_roll", "wr_pitch", "wr_yaw",
    ] {
        for s in ["q", "dq", "tau", "temperature"] {
            assert_eq!(rows(&c, &format!("/joints/{j}/{s}")), N, "joints/{j}/{s}");
        }
        assert_eq!(
            rows(&c, &format!("/joints/{j}/q_cmd")),
            N / 2,
            "joints/{j}/q_cmd"
        );
    }
    assert_eq!(rows(&c, "/imu/gyro_norm"), N);
    for p in ["mbs", "bms"] {
        assert_eq!(rows(&c, &format!("/power/{p}/raw")), 5);
        assert_eq!(rows(&c, &format!("/power/{p}/net")), 5);
    }
    // Every arm link is animated once per sample; the torso is static.
    assert_eq!(rows(&c, "/robot/left_wrist_yaw_link"), N);
    assert_eq!(rows(&c, "/robot/left_shoulder_pitch_link"), N);
    assert_eq!(rows(&c, "/robot/torso_link"), 0);
    assert_eq!(
        c.rows.get(&(false, "/robot/torso_link".into(), true)),
        Some(&1)
    );
    assert_eq!(rows(&c, "/trials/log"), 2);
    // The blueprint went into its own store, with a viewport.
    assert!(
        c.rows.contains_key(&(true, "/viewport".into(), false)),
        "no blueprint viewport: {:?}",
        c.rows.keys()
    );
    assert!(
        msgs.iter()
            .any(|m| matches!(m, LogMsg::BlueprintActivationCommand(_)))
    );
}

/// The blueprint is a complete tree: every view and container but the root is some container's
/// child, each container row holds all its children (a stock viewer otherwise shows only the
/// first one), and the 3D view has a starting camera.
#[test]
fn blueprint_layout_is_complete() {
    use rerun::external::arrow::array::{Array, AsArray};
    use std::collections::BTreeSet;
    let dir = tempfile::tempdir().unwrap();
    let rec = synthetic(&input_file(dir.path()));
    let out = dir.path().join("out.rrd");
    write_rrd(&rec, &out).unwrap();

    let mut nodes = BTreeSet::new();
    let mut children = Vec::new();
    let mut eye = false;
    for msg in decode(&out) {
        let LogMsg::ArrowMsg(store, arrow) = &msg else {
            continue;
        };
        if store.kind() != StoreKind::Blueprint {
            continue;
        }
        let chunk = Chunk::from_arrow_msg(arrow).expect("valid chunk");
        let path = chunk.entity_path().to_string();
        let parts: Vec<&str> = path.trim_start_matches('/').split('/').collect();
        match parts.as_slice() {
            ["view" | "container", _] => {
                nodes.insert(path.clone());
            }
            ["view", _, "EyeControls3D"] => eye = true,
            _ => {}
        }
        for column in chunk.components().0.values() {
            if column.descriptor.component != "ContainerBlueprint:contents" {
                continue;
            }
            let list = &column.list_array;
            assert_eq!(list.len(), 1, "{path}: one row");
            let values = list.values().as_string::<i32>();
            assert_eq!(list.value_length(0) as usize, values.len(), "{path}");
            assert!(values.len() >= 2, "{path}: {} children", values.len());
            children.extend(values.iter().map(|v| v.unwrap().to_owned()));
        }
    }
    let referenced: BTreeSet<String> = children.iter().cloned().collect();
    assert_eq!(referenced.len(), children.len(), "a node is listed twice");
    assert!(referenced.is_subset(&nodes), "{referenced:?} vs {nodes:?}");
    let unreferenced: Vec<_> = nodes.difference(&referenced).collect();
    assert_eq!(
        unreferenced.len(),
        1,
        "more than one root: {unreferenced:?}"
    );
    assert!(nodes.len() >= 8, "{nodes:?}");
    assert!(eye, "no EyeControls3D for the 3D view");
}

/// The recording names itself after the input file, carries the session's real start time and
/// its provenance (input, g1viz version, and what the caller adds: command, model) as recording
/// properties; the robot's root follows the recorded IMU orientation.
#[test]
fn recording_identifies_itself() {
    use rerun::external::arrow::array::AsArray;
    use rerun::external::arrow::datatypes::Int64Type;
    let dir = tempfile::tempdir().unwrap();
    let rec = synthetic(&input_file(dir.path()));
    let out = dir.path().join("out.rrd");
    let robot = RobotModel::builtin();
    let arm = robot.arm(&rec.joint_names).unwrap();
    let viz = open_stream("g1viz_test", "id", &Sink::Save(out.clone()), &[]).unwrap();
    let opts = ReplayOptions {
        progress: false,
        properties: vec![
            ("command".into(), "replay".into()),
            ("model".into(), "paper".into()),
        ],
        ..Default::default()
    };
    log_replay(&rec, &robot, &arm, &extras(), &opts, viz.stream()).unwrap();
    viz.finish().unwrap();

    let mut texts: BTreeMap<String, String> = BTreeMap::new();
    let mut start = None;
    for msg in decode(&out) {
        let LogMsg::ArrowMsg(store, arrow) = &msg else {
            continue;
        };
        if store.kind() != StoreKind::Recording {
            continue;
        }
        let chunk = Chunk::from_arrow_msg(arrow).unwrap();
        if !chunk.entity_path().to_string().starts_with("/__properties") {
            continue;
        }
        assert!(chunk.is_static());
        for column in chunk.components().0.values() {
            let values = column.list_array.values();
            let field = column.descriptor.component.to_string();
            if let Some(strings) = values.as_string_opt::<i32>() {
                texts.insert(field, strings.value(0).to_owned());
            } else if field.ends_with("start_time") {
                start = Some(values.as_primitive::<Int64Type>().value(0));
            }
        }
    }
    assert_eq!(
        texts.get("RecordingInfo:name").map(String::as_str),
        Some("session.mcap"),
        "{texts:?}"
    );
    assert_eq!(start, Some(START_NS as i64), "start time");
    let input = rec.source.display().to_string();
    assert_eq!(texts.get("input"), Some(&input), "{texts:?}");
    assert_eq!(texts.get("command").map(String::as_str), Some("replay"));
    assert_eq!(texts.get("model").map(String::as_str), Some("paper"));
    assert!(
        texts
            .get("version")
            .is_some_and(|v| v.starts_with("g1viz "))
    );
    // One body orientation per arm pose.
    let c = contents(&decode(&out));
    assert_eq!(rows(&c, "/robot"), N);
}

/// The layout a person can hold in their head: at most 8 tabs, the time panel on the session
/// timeline, every plot's time axis linked to the others.
#[test]
fn blueprint_has_few_tabs_linked_axes_and_session_time() {
    use rerun::Loggable as _;
    use rerun::external::arrow::array::AsArray;
    let dir = tempfile::tempdir().unwrap();
    let rec = synthetic(&input_file(dir.path()));
    let out = dir.path().join("out.rrd");
    write_rrd(&rec, &out).unwrap();
    let msgs = decode(&out);
    let mut tab_containers = Vec::new();
    let mut time_axes = 0;
    let mut time_series = 0;
    let mut timeline = None;
    let mut whole_session = false;
    for msg in &msgs {
        let LogMsg::ArrowMsg(store, arrow) = msg else {
            continue;
        };
        if store.kind() != StoreKind::Blueprint {
            continue;
        }
        let chunk = Chunk::from_arrow_msg(arrow).unwrap();
        let path = chunk.entity_path().to_string();
        // The viewer's shared view (what globally linked plots read): its range is the whole
        // session, both ends unbounded (the viewer's default is a 60 s window at the cursor).
        if path == "/view/5c0dca6a-e63f-9cf7-f657-2602590474cc/TimeAxis" {
            let range = chunk
                .components()
                .0
                .values()
                .find(|c| c.descriptor.component.as_str() == "TimeAxis:view_range")
                .expect("the shared time axis has a view range");
            let range =
                rerun::external::re_sdk_types::blueprint::components::TimeRange::from_arrow(
                    range.list_array.values(),
                )
                .unwrap();
            let infinite = rerun::external::re_sdk_types::datatypes::TimeRangeBoundary::Infinite;
            whole_session = range[0].0.start == infinite && range[0].0.end == infinite;
        } else if path.ends_with("/TimeAxis") {
            time_axes += 1;
        }
        for column in chunk.components().0.values() {
            let d = column.descriptor.component.to_string();
            let values = column.list_array.values();
            match d.as_str() {
                "ContainerBlueprint:container_kind"
                    if values
                        .as_primitive::<rerun::external::arrow::datatypes::UInt8Type>()
                        .value(0)
                        == 1 =>
                {
                    tab_containers.push(path.clone());
                }
                "ViewBlueprint:class_identifier"
                    if values.as_string::<i32>().value(0) == "TimeSeries" =>
                {
                    time_series += 1;
                }
                "TimePanelBlueprint:timeline" => {
                    timeline = Some(values.as_string::<i32>().value(0).to_owned());
                }
                _ => {}
            }
        }
    }
    assert_eq!(timeline.as_deref(), Some("session"));
    assert!(whole_session, "the plots open on the whole session");
    assert!(time_series >= 5, "{time_series} plots");
    assert_eq!(time_axes, time_series, "every plot links its time axis");
    assert_eq!(tab_containers.len(), 1, "{tab_containers:?}");
    let names = blueprint_strings(&msgs);
    let tabs = blueprint_children(&msgs, &tab_containers[0]);
    assert!((3..=8).contains(&tabs), "{tabs} tabs; {names:?}");
}

/// Number of children of the blueprint container at `path`.
fn blueprint_children(msgs: &[LogMsg], path: &str) -> usize {
    use rerun::external::arrow::array::Array;
    for msg in msgs {
        let LogMsg::ArrowMsg(store, arrow) = msg else {
            continue;
        };
        if store.kind() != StoreKind::Blueprint {
            continue;
        }
        let chunk = Chunk::from_arrow_msg(arrow).unwrap();
        if chunk.entity_path().to_string() != path {
            continue;
        }
        for column in chunk.components().0.values() {
            if column.descriptor.component == "ContainerBlueprint:contents" {
                return column.list_array.values().len();
            }
        }
    }
    0
}

/// Values read back through rerun's decoder equal the input (formula above) and the hand-computed net power.
#[test]
fn rrd_values_match_input() {
    let dir = tempfile::tempdir().unwrap();
    let rec = synthetic(&input_file(dir.path()));
    let out = dir.path().join("out.rrd");
    write_rrd(&rec, &out).unwrap();
    let c = contents(&decode(&out));

    let series = |path: &str| series(&c, path);
    let elbow = series("/joints/elbow/q");
    assert_eq!(elbow.len(), N);
    for (i, (t_ns, q)) in elbow.iter().enumerate() {
        assert_eq!(*t_ns, START_NS as i64 + i as i64 * 10_000_000);
        assert!((q - joint_q(3, i as f64 * 0.01)).abs() < 1e-12);
    }
    // Baseline = the single reading before the arm moves (120 W at 0.5 s): net = raw − 120.
    let net: Vec<f64> = series("/power/mbs/net").into_iter().map(|p| p.1).collect();
    assert_eq!(net, vec![0.0, 30.0, 40.0, 50.0, 60.0]);
    let gyro: Vec<f64> = series("/imu/gyro_norm").into_iter().map(|p| p.1).collect();
    assert!(gyro.iter().all(|g| (g - 0.5).abs() < 1e-12));
}

/// Two runs on the same input decode to the same messages (ids, timelines, data, blueprint).
#[test]
fn rrd_is_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let rec = synthetic(&input_file(dir.path()));
    let (a, b) = (dir.path().join("a.rrd"), dir.path().join("b.rrd"));
    write_rrd(&rec, &a).unwrap();
    write_rrd(&rec, &b).unwrap();
    let (ma, mb) = (decode(&a), decode(&b));
    assert_eq!(ma.len(), mb.len());
    for (i, (x, y)) in ma.iter().zip(&mb).enumerate() {
        assert!(x == y, "message {i} differs between two runs");
    }
    // Byte level: the data section (stream header + every message) is identical. The footer
    // (per-store manifests, whose order and column order the SDK takes from HashMaps) is not.
    let (ba, bb) = (std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    let mut encoder = Encoder::new_eager(
        CrateVersion::LOCAL,
        EncodingOptions::PROTOBUF_COMPRESSED,
        Vec::new(),
    )
    .unwrap();
    encoder.do_not_emit_footer();
    for msg in &ma {
        encoder.append(msg).unwrap();
    }
    let data_section = encoder.into_inner().unwrap();
    assert!(
        data_section.len() > ba.len() / 2,
        "data section {} of {} bytes",
        data_section.len(),
        ba.len()
    );
    assert!(
        ba.starts_with(&data_section),
        "first file's data section differs from its re-encoding"
    );
    assert!(
        bb.starts_with(&data_section),
        "second file's data section differs from the first's"
    );
}

#[test]
fn refuses_to_overwrite_input() {
    let dir = tempfile::tempdir().unwrap();
    let input = input_file(dir.path());
    let before = std::fs::read(&input).unwrap();
    let rec = synthetic(&input);
    // Same file, spelled differently.
    let sneaky = dir.path().join(".").join("session.mcap");
    let err = open_stream("g1viz_test", "x", &Sink::Save(sneaky), &[&input])
        .err()
        .expect("must refuse");
    assert!(err.to_string().contains("refusing"), "{err}");
    assert_eq!(std::fs::read(&input).unwrap(), before);
    // And no temporary file was left behind.
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 1, "{names:?}");
    drop(rec);
}

#[test]
fn unfinished_output_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never.rrd");
    let viz = open_stream("g1viz_test", "x", &Sink::Save(out.clone()), &[]).unwrap();
    drop(viz);
    assert!(
        std::fs::read_dir(dir.path()).unwrap().next().is_none(),
        "leftover files"
    );
}

/// The stock CLI of the pinned version accepts the file (skipped when `rerun` is not on PATH).
#[test]
fn stock_cli_verifies_rrd() {
    let Ok(version) = common::output_within(
        std::process::Command::new("rerun").arg("--version"),
        common::TOOL_LIMIT,
    ) else {
        common::skip("`rerun` not on PATH (pip install rerun-sdk==0.36.3): `rerun rrd verify`");
        return;
    };
    let version = String::from_utf8_lossy(&version.stdout);
    assert!(
        version.contains("0.36.3"),
        "stock CLI is not the pinned version: {version}"
    );
    let dir = tempfile::tempdir().unwrap();
    let rec = synthetic(&input_file(dir.path()));
    let out = dir.path().join("out.rrd");
    write_rrd(&rec, &out).unwrap();
    let status = common::output_within(
        std::process::Command::new("rerun")
            .args(["rrd", "verify"])
            .arg(&out),
        common::TOOL_LIMIT,
    )
    .unwrap();
    assert!(
        status.status.success(),
        "rerun rrd verify failed:\n{}\n{}",
        String::from_utf8_lossy(&status.stdout),
        String::from_utf8_lossy(&status.stderr)
    );
}

/// The shared smoke session (independent generator): one row per `/lowstate` message on every
/// joint series, one per power message, counts taken from the truth JSON.
#[test]
fn smoke_session_rrd_rows_match_truth() {
    let (Some(mcap), Some(truth_path)) = (
        common::shared_recording("g1_smoke.mcap"),
        common::shared_recording("g1_smoke.truth.json"),
    ) else {
        return;
    };
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&truth_path).unwrap()).unwrap();
    let count = |topic: &str| {
        truth["message_counts"][topic]
            .as_u64()
            .expect("message count") as usize
    };
    let rec = g1viz::signals::load_recording(
        &mcap,
        &g1viz::signals::SignalMap::g1_left_arm(),
        &g1viz::read::OpenOptions::default(),
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("smoke.rrd");
    save_replay(&rec, &ReplayExtras::default(), &out, &mcap);
    let c = contents(&decode(&out));
    for j in truth["joints"]["short"].as_array().unwrap() {
        let j = j.as_str().unwrap();
        assert_eq!(
            rows(&c, &format!("/joints/{j}/q")),
            count("lowstate"),
            "{j}"
        );
        assert_eq!(
            rows(&c, &format!("/joints/{j}/q_cmd")),
            count("arm_sdk"),
            "{j}"
        );
    }
    assert_eq!(rows(&c, "/power/mbs/raw"), count("mbs"));
    assert_eq!(rows(&c, "/power/bms/raw"), count("bms"));
    assert_eq!(rows(&c, "/power/mbs/net"), count("mbs"));
    assert_eq!(rows(&c, "/robot/left_elbow_link"), count("lowstate"));
}

/// Unitree's official URDF: links with STL meshes come out as `Asset3D` entities.
#[test]
fn official_urdf_meshes_become_assets() {
    let Some(shared) = common::shared_dir() else {
        return;
    };
    let urdf = shared.join("g1_description/g1_29dof_with_hand_rev_1_0.urdf");
    let robot = RobotModel::from_urdf_file(&urdf).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut rec = synthetic(&input_file(dir.path()));
    rec.state.t.truncate(20);
    for v in [
        &mut rec.state.q,
        &mut rec.state.dq,
        &mut rec.state.tau,
        &mut rec.state.temp,
    ] {
        v.truncate(20);
    }
    rec.state.gyro.truncate(20);
    rec.state.quat.truncate(20);
    let arm = robot.arm(&rec.joint_names).unwrap();
    let out = dir.path().join("mesh.rrd");
    let viz = open_stream("g1viz_test", "mesh", &Sink::Save(out.clone()), &[]).unwrap();
    let opts = ReplayOptions {
        progress: false,
        blueprint: false,
        ..Default::default()
    };
    let summary = log_replay(
        &rec,
        &robot,
        &arm,
        &ReplayExtras::default(),
        &opts,
        viz.stream(),
    )
    .unwrap();
    viz.finish().unwrap();
    assert!(summary.warnings.is_empty(), "{:?}", summary.warnings);
    let msgs = decode(&out);
    let mut assets = 0;
    for msg in &msgs {
        if let LogMsg::ArrowMsg(_, arrow) = msg {
            let chunk = Chunk::from_arrow_msg(arrow).unwrap();
            if chunk.components().values().any(|c| {
                c.descriptor
                    .archetype
                    .is_some_and(|a| a.to_string().contains("Asset3D"))
            }) {
                assets += 1;
            }
        }
    }
    let mesh_visuals: usize = robot
        .links()
        .iter()
        .flat_map(|l| &l.visuals)
        .filter(|v| matches!(v.geometry, g1viz::robot::Geometry::Mesh { .. }))
        .count();
    assert!(
        mesh_visuals > 30,
        "official URDF should have meshes, found {mesh_visuals}"
    );
    assert_eq!(assets, mesh_visuals);
    // The moving arm links are animated: 20 poses each.
    let c = contents(&msgs);
    assert_eq!(rows(&c, "/robot/left_wrist_yaw_link"), 20);
    assert_eq!(rows(&c, "/robot/pelvis"), 0);
}

/// `replay --model`: the model overlay on the shared smoke session marks exactly the truth's
/// balance-contaminated trials as IMU-rejected, predicts the independent generator's power (its
/// plant is the paper's model), and lands in the .rrd as per-joint loss-term series.
#[test]
fn model_overlay_marks_contaminated_trials_and_logs_loss_terms() {
    let (Some(mcap), Some(truth_path)) = (
        common::shared_recording("g1_smoke.mcap"),
        common::shared_recording("g1_smoke.truth.json"),
    ) else {
        return;
    };
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&truth_path).unwrap()).unwrap();
    let contaminated: Vec<usize> = truth["trials"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|t| t["contaminated"].as_bool() == Some(true))
        .map(|t| t["index"].as_u64().unwrap() as usize)
        .collect();
    assert!(
        !contaminated.is_empty(),
        "the smoke session has contaminated trials"
    );
    let rec = g1viz::signals::load_recording(
        &mcap,
        &g1viz::signals::SignalMap::g1_left_arm(),
        &g1viz::read::OpenOptions::default(),
    )
    .unwrap();
    let opts = g1viz::identify::IdentifyOptions::default();
    let (extras, validation) =
        g1viz::viz::overlay::model_extras(&rec, &g1viz::power::PowerModel::PAPER, &opts).unwrap();

    let mut imu: Vec<usize> = extras
        .trials
        .iter()
        .filter(|m| {
            m.rejected
                .as_ref()
                .is_some_and(|r| r.reason == RejectReason::ImuSway)
        })
        .map(|m| m.index)
        .collect();
    imu.sort_unstable();
    assert_eq!(
        imu, contaminated,
        "IMU-rejected trials = the truth's contaminated trials"
    );

    // Per trajectory, the paper's parameters predict the generator's clean trials closely.
    let clean: Vec<_> = extras
        .trajectories
        .iter()
        .filter(|p| !contaminated.contains(&p.trial))
        .collect();
    let mean = clean.iter().map(|p| p.measured).sum::<f64>() / clean.len() as f64;
    let ss_res: f64 = clean
        .iter()
        .map(|p| (p.measured - p.predicted).powi(2))
        .sum();
    let ss_tot: f64 = clean.iter().map(|p| (p.measured - mean).powi(2)).sum();
    let r2 = 1.0 - ss_res / ss_tot;
    assert!(r2 > 0.95, "per-trajectory R² of the true model {r2}");

    let terms = extras.terms.as_ref().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("smoke_model.rrd");
    save_replay(&rec, &extras, &out, &mcap);
    let c = contents(&decode(&out));
    assert_eq!(rows(&c, "/model/terms/elbow/copper"), terms.t.len());
    assert_eq!(rows(&c, "/model/power/predicted"), terms.t.len());
    assert_eq!(
        rows(&c, "/model/error/trajectory") + rows(&c, "/model/error/trajectory_rejected"),
        extras.trajectories.len()
    );
    // The IMU statistic and threshold are on the IMU plot's entities; the trial track holds one
    // step per trial and a span per rejected trial, named after it.
    assert_eq!(rows(&c, "/imu/threshold"), 2);
    assert_eq!(rows(&c, "/trials/index"), extras.trials.len());
    for m in extras.trials.iter().filter(|m| m.rejected.is_some()) {
        assert_eq!(rows(&c, &format!("/trials/rejected/{}", m.index)), 2);
    }
    assert_error_at_readings_is_like_for_like(&c, &validation);
}

/// The error plotted at the readings is the per-reading error `validate` reports (0.3 W order on
/// the smoke session, not the ±20 W of a 1 Hz window average minus a 100 Hz prediction), and
/// each plotted prediction is the mean of the plotted instantaneous prediction over the
/// reading's own window — recomputed here from the decoded series.
fn assert_error_at_readings_is_like_for_like(c: &Contents, v: &g1viz::identify::Validation) {
    let mut err: Vec<f64> = series(c, "/model/error/reading")
        .into_iter()
        .chain(series(c, "/model/error/reading_rejected"))
        .map(|p| p.1)
        .collect();
    assert_eq!(err.len(), rows(c, "/model/power/reading_measured"));
    assert!(err.len() > 100, "{} readings", err.len());
    err.iter_mut().for_each(|e| *e = *e * *e);
    let rmse = (err.iter().sum::<f64>() / err.len() as f64).sqrt();
    let reported = v.reading_level.rmse;
    assert!(
        (rmse - reported).abs() < 1e-6 * reported.max(1.0),
        "plotted per-reading RMSE {rmse} vs validate's {reported}"
    );
    assert!(rmse < 1.0, "per-reading RMSE {rmse} W");

    let instantaneous = series(c, "/model/power/predicted");
    let (w_ns, lag_ns) = (
        (v.alignment.window_s * 1e9).round() as i64,
        (v.alignment.lag_s * 1e9).round() as i64,
    );
    let mut checked = 0;
    for (t, predicted) in series(c, "/model/power/reading_predicted") {
        let (lo, hi) = (t - lag_ns - w_ns, t - lag_ns);
        let inside: Vec<f64> = instantaneous
            .iter()
            .filter(|(ts, _)| *ts > lo && *ts <= hi)
            .map(|p| p.1)
            .collect();
        assert!(
            !inside.is_empty(),
            "no prediction sample in the window of {t}"
        );
        let mean = inside.iter().sum::<f64>() / inside.len() as f64;
        assert!(
            (mean - predicted).abs() < 1e-6,
            "reading at {t}: window mean {mean} vs plotted {predicted}"
        );
        checked += 1;
    }
    assert!(checked > 100);
}

/// Stream `mcap` into `out` as `g1viz replay SESSION --save OUT` does, in batches of `chunk_rows`.
fn stream_replay(mcap: &Path, out: &Path, chunk_rows: usize) -> g1viz::viz::replay::ReplaySummary {
    use g1viz::read::OpenOptions;
    use g1viz::signals::SignalMap;
    use g1viz::viz::recording_id_for_source;
    let map = SignalMap::g1_left_arm();
    let robot = RobotModel::builtin();
    let arm = robot.arm(&map.joint_names).unwrap();
    let id = recording_id_for_source(mcap).unwrap();
    let viz = open_stream("g1viz_test", &id, &Sink::Save(out.to_path_buf()), &[mcap]).unwrap();
    let opts = ReplayOptions {
        chunk_rows,
        progress: false,
        ..Default::default()
    };
    let summary = g1viz::viz::replay::replay_file(
        mcap,
        &map,
        &OpenOptions::default(),
        &robot,
        &arm,
        &opts,
        viz.stream(),
    )
    .unwrap();
    viz.finish().unwrap();
    summary
}

fn example_session() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap")
}

/// `g1viz replay` without a model streams the file (`replay_file`, bounded memory): in many small
/// batches it logs the same rows and values as the in-memory replay of the whole recording.
#[test]
fn streamed_replay_matches_the_in_memory_replay() {
    let mut sessions = vec![example_session()];
    sessions.extend(common::shared_recording("g1_smoke.mcap"));
    for mcap in sessions {
        let dir = tempfile::tempdir().unwrap();
        let rec = g1viz::signals::load_recording(
            &mcap,
            &g1viz::signals::SignalMap::g1_left_arm(),
            &Default::default(),
        )
        .unwrap();
        let whole = dir.path().join("whole.rrd");
        save_replay(&rec, &ReplayExtras::default(), &whole, &mcap);
        let streamed = dir.path().join("streamed.rrd");
        let summary = stream_replay(&mcap, &streamed, 300); // many batches
        assert_eq!(summary.samples, rec.state.t.len());
        assert_eq!(
            g1viz::viz::recording_id_for_source(&mcap).unwrap(),
            recording_id_for(&rec),
            "one recording id for both paths"
        );

        let (a, b) = (contents(&decode(&whole)), contents(&decode(&streamed)));
        assert_eq!(a.rows, b.rows, "{}: rows per entity", mcap.display());
        let scalar_paths: Vec<&String> = a
            .rows
            .keys()
            .filter(|(bp, p, st)| {
                !bp && !st
                    && ["/joints/", "/power/", "/imu/"]
                        .iter()
                        .any(|x| p.starts_with(x))
            })
            .map(|(_, p, _)| p)
            .collect();
        assert!(scalar_paths.len() > 30, "{scalar_paths:?}");
        for p in scalar_paths {
            assert_eq!(series(&a, p), series(&b, p), "{}: {p}", mcap.display());
        }
    }
}

/// A truncated file streams up to the damage, with a warning naming the file.
#[test]
fn streamed_replay_of_a_truncated_file_keeps_what_was_read() {
    let bytes = std::fs::read(example_session()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 3 / 5]).unwrap();
    let full = g1viz::signals::load_recording(
        &example_session(),
        &g1viz::signals::SignalMap::g1_left_arm(),
        &Default::default(),
    )
    .unwrap()
    .state
    .t
    .len();
    let out = dir.path().join("cut.rrd");
    let summary = stream_replay(&cut, &out, 500);
    assert!(
        summary.samples > full / 4 && summary.samples < full,
        "{} of {full} samples",
        summary.samples
    );
    assert!(
        summary.warnings.iter().any(|w| w.contains("cut.mcap")),
        "{:?}",
        summary.warnings
    );
    let c = contents(&decode(&out));
    assert_eq!(rows(&c, "/joints/elbow/q"), summary.samples);
}

/// The recording id is known before reading: stable for the same input, blind to files that are
/// not part of a bag directory (an `.rrd` saved into it), and defined for a path like `dir/..`.
#[test]
fn recording_id_comes_from_the_input_alone() {
    use g1viz::viz::recording_id_for_source;
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("bag");
    std::fs::create_dir(&bag).unwrap();
    std::fs::write(
        bag.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 5\n",
    )
    .unwrap();
    std::fs::write(bag.join("bag_0.db3"), vec![7u8; 4096]).unwrap();
    let id = recording_id_for_source(&bag).unwrap();
    std::fs::write(bag.join("replay.rrd"), b"output of an earlier run").unwrap();
    assert_eq!(
        recording_id_for_source(&bag).unwrap(),
        id,
        ".rrd beside the bag"
    );
    std::fs::create_dir(bag.join("sub")).unwrap();
    assert_eq!(
        recording_id_for_source(&bag.join("sub/..")).unwrap(),
        id,
        "bag/sub/.. is the bag"
    );
    // Same sizes, different metadata: a different session.
    std::fs::write(
        bag.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 6\n",
    )
    .unwrap();
    assert_ne!(
        recording_id_for_source(&bag).unwrap(),
        id,
        "metadata content counts"
    );
    // A file: a change in its last bytes changes the id.
    let f = dir.path().join("s.mcap");
    let mut bytes = vec![1u8; 200_000];
    std::fs::write(&f, &bytes).unwrap();
    let a = recording_id_for_source(&f).unwrap();
    bytes[199_999] = 2;
    std::fs::write(&f, &bytes).unwrap();
    assert_ne!(recording_id_for_source(&f).unwrap(), a);
}

/// Every string value in the blueprint store (view and container names, query expressions…).
fn blueprint_strings(msgs: &[LogMsg]) -> Vec<String> {
    use rerun::external::arrow::array::{Array, AsArray};
    use rerun::external::arrow::datatypes::DataType;
    let mut out = Vec::new();
    for msg in msgs {
        let LogMsg::ArrowMsg(store, arrow) = msg else {
            continue;
        };
        if store.kind() != StoreKind::Blueprint {
            continue;
        }
        let chunk = Chunk::from_arrow_msg(arrow).expect("valid chunk");
        for column in chunk.components().0.values() {
            let values = column.list_array.values();
            if values.data_type() == &DataType::Utf8 {
                out.extend(
                    values
                        .as_string::<i32>()
                        .iter()
                        .flatten()
                        .map(str::to_owned),
                );
            }
        }
    }
    out
}

/// `g1viz diagnose --save diag.rrd [--counterpart TWIN]`: the measured power, the base-model and
/// refitted predictions and their errors at every reading the diagnosis used, a log line per
/// located trial, the summary, and with a counterpart the twin's power and the per-joint torque
/// difference — read back through rerun's decoder, row for row and value for value.
#[test]
fn diagnosis_rrd_has_before_after_located_trials_and_counterpart() {
    use g1viz::diagnose::{self, DiagnoseOptions, compare_counterpart};
    use g1viz::power::PowerModel;
    use g1viz::read::OpenOptions;
    use g1viz::signals::{SignalMap, load_recording};
    use g1viz::sim::{self, Effects, Preset, SimConfig};

    let dir = tempfile::tempdir().unwrap();
    let real_path = dir.path().join("real.mcap");
    let mut effects = Effects::default();
    effects.enable("latency=0.3").unwrap();
    let cfg = SimConfig {
        preset: Preset::Smoke,
        seed: 31,
        effects,
        progress: false,
        ..SimConfig::default()
    };
    sim::simulate(&cfg, &real_path).unwrap();
    let load = |p: &Path| load_recording(p, &SignalMap::g1_left_arm(), &OpenOptions::default());
    let real = load(&real_path).unwrap();
    let twin_path = dir.path().join("twin.mcap");
    let twin_cfg = SimConfig {
        seed: 32,
        progress: false,
        ..SimConfig::default()
    };
    sim::simulate_like(&real, &twin_cfg, &twin_path).unwrap();
    let twin = load(&twin_path).unwrap();

    let opts = DiagnoseOptions {
        reference: Some(PowerModel::PAPER),
        folds: 5, // one smoke session has ≈ 20 trials
        ..DiagnoseOptions::default()
    };
    let mut d = diagnose::diagnose(&real, &opts).unwrap();
    assert!(
        d.accepted.iter().any(|h| h.id == "latency"),
        "a 0.3 s sensor latency is found: {}",
        d.summary
    );
    let comparison = compare_counterpart(&real, &twin, &d).unwrap();
    d.attach_counterpart(comparison);

    let out = dir.path().join("diag.rrd");
    save_replay(
        &real,
        &g1viz::viz::overlay::diagnosis_extras(&d),
        &out,
        &real_path,
    );
    let msgs = decode(&out);
    let c = contents(&msgs);

    let r = &d.replay;
    let n = r.t.len();
    assert!(n > 100, "{n} readings");
    let values = |path: &str| -> Vec<f64> { series(&c, path).into_iter().map(|p| p.1).collect() };
    // The replay's readings are in time order; the decoded series are sorted by time.
    let close = |a: &[f64], b: &[f64]| {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-9)
    };
    assert!(close(&values("/diagnosis/power/measured"), &r.measured_w));
    assert!(close(&values("/diagnosis/power/before"), &r.before_w));
    assert!(close(&values("/diagnosis/power/after"), &r.after_w));
    let err_after: Vec<f64> = r
        .measured_w
        .iter()
        .zip(&r.after_w)
        .map(|(m, p)| m - p)
        .collect();
    assert!(close(&values("/diagnosis/error/after"), &err_after));
    assert_eq!(rows(&c, "/diagnosis/error/before"), n);
    // The refit explains the latency: the error shrinks.
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    let before = rms(&values("/diagnosis/error/before"));
    let after = rms(&values("/diagnosis/error/after"));
    assert!(after < 0.5 * before, "rms error {before} → {after}");

    assert!(!r.highlighted.is_empty(), "located trials");
    assert_eq!(rows(&c, "/diagnosis/trials/log"), r.highlighted.len());
    assert!(
        c.rows
            .contains_key(&(false, "/diagnosis/summary".to_owned(), true)),
        "static summary document"
    );

    let cp = d.counterpart.as_ref().unwrap();
    assert_eq!(rows(&c, "/diagnosis/power/twin"), cp.matched_readings);
    let elbow: Vec<f64> = cp.series.tau_diff.iter().map(|x| x[3]).collect();
    assert_eq!(elbow.len(), cp.matched_samples);
    assert!(close(&values("/diagnosis/torque/elbow"), &elbow));
    // Nothing but sensor noise between the twin and its own plant's torques.
    assert!(
        rms(&elbow) < 0.15,
        "elbow τ difference {} Nm rms",
        rms(&elbow)
    );

    let names = blueprint_strings(&msgs);
    for view in ["Torque recording − twin [Nm]", "Diagnosis summary"] {
        assert!(names.iter().any(|s| s == view), "no view {view:?}");
    }
}

/// `g1viz replay --connect ADDR` against the stock server of the pinned version (`rerun --port P
/// --save FILE`, no window): the server receives the same rows per entity as `--save` writes.
#[test]
fn connect_streams_to_a_stock_rerun_server() {
    use std::net::{TcpListener, TcpStream};
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};

    if common::output_within(Command::new("rerun").arg("--version"), common::TOOL_LIMIT).is_err() {
        common::skip("`rerun` not on PATH (pip install rerun-sdk==0.36.3): --connect test");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/g1_example.mcap");
    let saved = dir.path().join("saved.rrd");
    let received = dir.path().join("received.rrd");
    let g1viz = |args: &[&str]| {
        let o = common::output_within(
            Command::new(env!("CARGO_BIN_EXE_g1viz"))
                .arg("replay")
                .arg(&example)
                .args(args),
            common::G1VIZ_LIMIT,
        )
        .unwrap();
        assert!(
            o.status.success(),
            "g1viz replay {args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    };
    g1viz(&["--save", saved.to_str().unwrap()]);

    let port = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    // Its own process group: stopping it reaches the pip wrapper and the CLI it starts, and a
    // panic below kills both (the group is killed when `server` is dropped).
    let server = common::Group::spawn(
        Command::new("rerun")
            .args(["--port", &port.to_string(), "--save"])
            .arg(&received)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null()),
    )
    .unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    while TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            Instant::now() < deadline,
            "rerun server did not listen on {port}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    g1viz(&["--connect", &format!("rerun+http://127.0.0.1:{port}/proxy")]);
    // The server writes what it receives as it arrives; wait until the file stops growing.
    let mut last = 0;
    loop {
        std::thread::sleep(Duration::from_millis(500));
        let len = std::fs::metadata(&received).map_or(0, |m| m.len());
        if len > 0 && len == last {
            break;
        }
        assert!(
            Instant::now() < deadline + Duration::from_secs(30),
            "server file still growing"
        );
        last = len;
    }
    // SIGINT to the whole group lets the server finish its file; SIGTERM, then SIGKILL, follow
    // after bounded waits, so an ignored SIGINT cannot hang the test.
    server.stop(Duration::from_secs(20));

    let (a, b) = (contents(&decode(&saved)), contents(&decode(&received)));
    let recording_rows = |c: &Contents| -> BTreeMap<(String, bool), usize> {
        c.rows
            .iter()
            .filter(|((blueprint, _, _), _)| !blueprint)
            .map(|((_, path, stat), n)| ((path.clone(), *stat), *n))
            .collect()
    };
    let (ra, rb) = (recording_rows(&a), recording_rows(&b));
    assert!(ra.len() > 20, "{ra:?}");
    assert_eq!(ra, rb, "rows per entity: --save vs received over --connect");
    assert_eq!(
        series(&a, "/power/mbs/net"),
        series(&b, "/power/mbs/net"),
        "values"
    );
}

/// Replays `session` as `g1viz replay --save out` does with `window` (and `model`), through the
/// same entry point as the CLI; returns the notices it printed.
fn replay_window(
    session: &Path,
    out: &Path,
    window: g1viz::viz::session::Window,
    model: Option<&g1viz::power::PowerModel>,
) -> Vec<g1viz::viz::session::Notice> {
    use g1viz::viz::session::{SessionReplay, replay_session};
    let map = g1viz::signals::SignalMap::g1_left_arm();
    let read = g1viz::read::OpenOptions::default();
    let robot = RobotModel::builtin();
    let sink = Sink::Save(out.to_path_buf());
    let inputs = [session];
    let replay = SessionReplay {
        session,
        map: &map,
        read: &read,
        robot: &robot,
        model: model.map(|m| ("paper", m)),
        fit: g1viz::identify::IdentifyOptions::default(),
        sink: &sink,
        inputs: &inputs,
        window,
        opts: ReplayOptions {
            progress: false,
            pose_rate_hz: Some(30.0),
            ..Default::default()
        },
    };
    let mut notices = Vec::new();
    replay_session(&replay, &mut |n| notices.push(n)).unwrap();
    notices
}

/// Session seconds of the series at `path` in a decoded replay of a session starting at
/// `start_ns`.
fn session_times(c: &Contents, path: &str, start_ns: u64) -> Vec<f64> {
    series(c, path)
        .iter()
        .map(|(t, _)| (*t - start_ns as i64) as f64 * 1e-9)
        .collect()
}

/// `replay --from 20 --to 45`: every joint sample of the window, and nothing outside it, on the
/// session timeline (times keep their place); the power readings of the window only.
#[test]
fn replay_from_to_logs_exactly_the_window() {
    let session = example_session();
    let rec = g1viz::signals::load_recording(
        &session,
        &g1viz::signals::SignalMap::g1_left_arm(),
        &Default::default(),
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("window.rrd");
    let window = g1viz::viz::session::Window {
        from_s: Some(20.0),
        to_s: Some(45.0),
        ..Default::default()
    };
    replay_window(&session, &out, window, None);
    let c = contents(&decode(&out));
    let expected: Vec<f64> = rec
        .state
        .t
        .iter()
        .copied()
        .filter(|t| (20.0..=45.0).contains(t))
        .collect();
    assert!(expected.len() > 1000);
    let got = session_times(&c, "/joints/elbow/q", rec.start_ns);
    assert_eq!(got.len(), expected.len());
    for (g, e) in got.iter().zip(&expected) {
        assert!((g - e).abs() < 1e-6, "{g} vs {e}");
    }
    let readings = session_times(&c, "/power/mbs/raw", rec.start_ns);
    let want = rec
        .mbs
        .t
        .iter()
        .filter(|t| (20.0..=45.0).contains(*t))
        .count();
    assert_eq!(readings.len(), want);
    assert!(
        readings
            .iter()
            .all(|t| (20.0 - 1e-6..=45.0 + 1e-6).contains(t))
    );
}

/// `replay --max-rate 10`: the joint series keep one sample per 0.1 s bin at most, and still
/// span the session (≈ 10 per second of it).
#[test]
fn replay_max_rate_caps_the_series() {
    let session = example_session();
    let rec = g1viz::signals::load_recording(
        &session,
        &g1viz::signals::SignalMap::g1_left_arm(),
        &Default::default(),
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("capped.rrd");
    let window = g1viz::viz::session::Window {
        max_rate_hz: Some(10.0),
        ..Default::default()
    };
    replay_window(&session, &out, window, None);
    let c = contents(&decode(&out));
    let t = session_times(&c, "/joints/sh_pitch/tau", rec.start_ns);
    let duration = rec.state.t.last().unwrap() - rec.state.t[0];
    // One sample per 0.1 s bin at most.
    let bins: Vec<i64> = t.iter().map(|x| (x * 10.0).floor() as i64).collect();
    assert!(
        bins.windows(2).all(|w| w[1] > w[0]),
        "two samples in one 0.1 s bin"
    );
    let expected = duration * 10.0;
    assert!(
        (t.len() as f64 - expected).abs() < 0.02 * expected + 2.0,
        "{} samples for {duration:.1} s",
        t.len()
    );
    // The gyro series too; power readings (≈ 1 Hz) are untouched.
    assert_eq!(rows(&c, "/imu/gyro_norm"), t.len());
    assert_eq!(rows(&c, "/power/mbs/raw"), rec.mbs.t.len());
}

/// `replay --model paper --trials 2-3`: the trial track holds trials 2 and 3 only, the joint
/// samples lie within their windows (pre-idle of 2 to return of 3), and the model's series too.
#[test]
fn replay_trials_logs_those_trials() {
    let session = example_session();
    let rec = g1viz::signals::load_recording(
        &session,
        &g1viz::signals::SignalMap::g1_left_arm(),
        &Default::default(),
    )
    .unwrap();
    let seg = g1viz::trial::segment(&rec, &Default::default());
    assert!(seg.trials.len() >= 4, "{} trials", seg.trials.len());
    let (a, b) = (&seg.trials[2], &seg.trials[3]);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("trials.rrd");
    let window = g1viz::viz::session::Window {
        trials: Some((a.index, b.index)),
        ..Default::default()
    };
    replay_window(
        &session,
        &out,
        window,
        Some(&g1viz::power::PowerModel::PAPER),
    );
    let c = contents(&decode(&out));
    let track: Vec<f64> = series(&c, "/trials/index").iter().map(|p| p.1).collect();
    assert_eq!(track, vec![a.index as f64, b.index as f64]);
    let (lo, hi) = (a.t_pre_start - 1e-6, b.t_return_end + 1e-6);
    for path in [
        "/joints/elbow/q",
        "/model/power/predicted",
        "/model/by_term/copper",
    ] {
        let t = session_times(&c, path, rec.start_ns);
        assert!(!t.is_empty(), "{path}");
        assert!(t.iter().all(|x| (lo..=hi).contains(x)), "{path}");
    }
    let all = rec
        .state
        .t
        .iter()
        .filter(|t| (lo..=hi).contains(*t))
        .count();
    assert_eq!(rows(&c, "/joints/elbow/q"), all);
}

/// Size per hour of session of a plain replay at the defaults, as the README states it
/// ("≈ N MB per hour … ± P %"): the example replayed, scaled to an hour. The size estimate
/// printed before writing lands within 25 % of the file written: at the defaults, with
/// `--max-rate 20`, for two trials at 20 Hz, and for 20 s with the model.
#[test]
fn rrd_size_per_hour_matches_readme_and_estimate() {
    use g1viz::viz::session::Notice;
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("README.md")).unwrap();
    let line = readme
        .lines()
        .find(|l| l.contains("MB per hour of session"))
        .expect("the README states the .rrd size per hour");
    let number = |tag: &str| -> f64 {
        let at = line
            .find(tag)
            .unwrap_or_else(|| panic!("{tag:?} in {line:?}"));
        let before = &line[..at];
        let start = before
            .rfind(|c: char| !(c.is_ascii_digit() || c == '.'))
            .map_or(0, |i| i + 1);
        before[start..].parse().unwrap()
    };
    let stated_mb = number(" MB per hour of session");
    let tolerance = number(" %") / 100.0;
    let session = example_session();
    let rec = g1viz::signals::load_recording(
        &session,
        &g1viz::signals::SignalMap::g1_left_arm(),
        &Default::default(),
    )
    .unwrap();
    let duration = rec.state.t.last().unwrap() - rec.state.t[0];
    let dir = tempfile::tempdir().unwrap();
    let paper = g1viz::power::PowerModel::PAPER;
    let cases = [
        ("defaults", None, None, None),
        ("capped", Some(20.0), None, None),
        ("two trials", Some(20.0), Some((2, 3)), None),
        ("model, 20 s", None, None, Some(&paper)),
    ];
    for (name, max_rate, trials, model) in cases {
        let out = dir.path().join(format!("{name}.rrd"));
        let window = g1viz::viz::session::Window {
            max_rate_hz: max_rate,
            trials,
            from_s: model.map(|_| 10.0),
            to_s: model.map(|_| 30.0),
        };
        let notices = replay_window(&session, &out, window, model);
        let size = std::fs::metadata(&out).unwrap().len() as f64;
        let estimate = notices
            .iter()
            .find_map(|n| match n {
                Notice::Estimate(e) => Some(e.bytes),
                _ => None,
            })
            .expect("an estimate before writing");
        assert!(
            (estimate / size - 1.0).abs() < 0.25,
            "{name}: estimate {estimate:.0} B vs {size:.0} B written"
        );
        if name == "defaults" {
            let per_hour_mb = size * 3600.0 / duration / 1e6;
            assert!(
                (per_hour_mb / stated_mb - 1.0).abs() <= tolerance,
                "{per_hour_mb:.0} MB per hour vs the README's {stated_mb} MB ± {}",
                tolerance * 100.0
            );
        }
    }
}

/// The strings of the static component `component` (e.g. `SeriesLines:names`) at `path`.
fn static_strings(c: &Contents, path: &str, component: &str) -> Vec<String> {
    use rerun::external::arrow::array::{Array, AsArray};
    use rerun::external::arrow::datatypes::DataType;
    let mut out = Vec::new();
    for chunk in c
        .chunks
        .iter()
        .filter(|ch| ch.is_static() && ch.entity_path().to_string() == path)
    {
        for column in chunk.components().0.values() {
            if column.descriptor.component.as_str() != component {
                continue;
            }
            let values = column.list_array.values();
            if values.data_type() == &DataType::Utf8 {
                out.extend(
                    values
                        .as_string::<i32>()
                        .iter()
                        .flatten()
                        .map(str::to_owned),
                );
            }
        }
    }
    out
}

/// A diagnosis whose found terms follow recorded fields gets the "Fields the found terms follow"
/// view in its Diagnosis tab, rooted at `/diagnosis/located`: one series per field, named after
/// the field, with the field's value at every reading (the values given here, read back).
#[test]
fn diagnosis_rrd_has_the_located_fields_tab() {
    use g1viz::viz::replay::DiagnosisOverlay;
    let dir = tempfile::tempdir().unwrap();
    let rec = synthetic(&input_file(dir.path()));
    let t: Vec<f64> = vec![0.5, 1.5, 2.5, 3.5, 4.5];
    let speed = vec![0.0, 0.4, 0.9, 0.3, 0.1];
    let temp = vec![31.0, 31.5, 32.0, 32.4, 32.9];
    let extras = ReplayExtras {
        diagnosis: Some(DiagnosisOverlay {
            t: t.clone(),
            measured: vec![1.0, 2.0, 3.0, 2.0, 1.0],
            before: vec![1.1, 1.8, 2.5, 1.9, 1.0],
            after: vec![1.0, 2.0, 2.9, 2.0, 1.0],
            found: vec![1.0, 2.0, 3.0, 2.0, 1.0],
            located: vec![
                ("/lowstate.motor_state[3].dq".into(), speed.clone()),
                ("/lowstate.motor_state[3].temperature".into(), temp.clone()),
            ],
            summary: "found: a term following the elbow speed".into(),
            ..Default::default()
        }),
        ..Default::default()
    };
    let out = dir.path().join("located.rrd");
    save_replay(&rec, &extras, &out, &rec.source);
    let msgs = decode(&out);
    let c = contents(&msgs);
    let names = blueprint_strings(&msgs);
    assert!(
        names.iter().any(|s| s == "Fields the found terms follow"),
        "{names:?}"
    );
    assert!(
        names
            .iter()
            .any(|s| s.trim_start_matches('/') == "diagnosis/located"),
        "view origin"
    );
    for (k, (field, values)) in [
        ("/lowstate.motor_state[3].dq", &speed),
        ("/lowstate.motor_state[3].temperature", &temp),
    ]
    .iter()
    .enumerate()
    {
        let path = format!("/diagnosis/located/{k}");
        let got: Vec<f64> = series(&c, &path).into_iter().map(|p| p.1).collect();
        assert_eq!(&got, *values, "{path}");
        assert_eq!(
            static_strings(&c, &path, "SeriesLines:names"),
            vec![field.to_string()]
        );
    }
    // Found terms: their prediction and error are logged beside the base model's.
    assert_eq!(rows(&c, "/diagnosis/power/found"), t.len());
    assert_eq!(rows(&c, "/diagnosis/error/found"), t.len());
}

/// The arm links of a model replay change colour with their joint's power: their colour is on
/// the timeline (no static colour, which would override it), grey at the session start, and
/// reddens during a trial; the per-trial bars' heights are each trial's mean of the per-joint
/// power series (recomputed here from the decoded loss-term series); the trial log names a
/// rejected trial's statistic once, without the "session 0 trial N" of the rejection's own text.
#[test]
fn model_replay_colours_links_draws_trial_bars_and_logs_rejections() {
    use rerun::external::arrow::array::{Array, AsArray};
    let session = example_session();
    let rec = g1viz::signals::load_recording(
        &session,
        &g1viz::signals::SignalMap::g1_left_arm(),
        &Default::default(),
    )
    .unwrap();
    let opts = g1viz::identify::IdentifyOptions::default();
    let (extras, _) =
        g1viz::viz::overlay::model_extras(&rec, &g1viz::power::PowerModel::PAPER, &opts).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("model.rrd");
    save_replay(&rec, &extras, &out, &session);
    let c = contents(&decode(&out));

    // Link colours: the elbow link's shape has colours only on the timeline, more than one.
    let elbow = "/robot/left_elbow_link/visual0";
    let colour_rows = |is_static: bool| -> usize {
        c.chunks
            .iter()
            .filter(|ch| ch.is_static() == is_static && ch.entity_path().to_string() == elbow)
            .flat_map(|ch| ch.components().0.values())
            .filter(|col| col.descriptor.component.as_str().ends_with(":colors"))
            .map(|col| col.list_array.len())
            .sum()
    };
    assert_eq!(colour_rows(true), 0, "no static colour on an arm link");
    assert!(
        colour_rows(false) > 100,
        "{} colour rows",
        colour_rows(false)
    );
    let mut distinct = std::collections::BTreeSet::new();
    for ch in c
        .chunks
        .iter()
        .filter(|ch| !ch.is_static() && ch.entity_path().to_string() == elbow)
    {
        for col in ch.components().0.values() {
            if col.descriptor.component.as_str().ends_with(":colors") {
                let v = col
                    .list_array
                    .values()
                    .as_primitive::<rerun::external::arrow::datatypes::UInt32Type>();
                distinct.extend(v.values().iter().copied());
            }
        }
    }
    assert!(
        distinct.len() > 10,
        "{} distinct link colours",
        distinct.len()
    );

    // Bars: for every trial, the flat top of the elbow's bar is the mean of the decoded
    // per-joint sum of its four terms over the trial's window.
    let terms: Vec<Vec<(i64, f64)>> = ["mechanical", "copper", "coulomb", "viscous"]
        .iter()
        .map(|t| series(&c, &format!("/model/terms/elbow/{t}")))
        .collect();
    let bars = series(&c, "/model/bars/by_joint/elbow");
    let start = rec.start_ns as i64;
    let mut checked = 0;
    for m in &extras.trials {
        let (a, b) = (
            start + (m.t_start * 1e9).round() as i64,
            start + (m.t_end * 1e9).round() as i64,
        );
        let inside: Vec<usize> = (0..terms[0].len())
            .filter(|&i| terms[0][i].0 >= a && terms[0][i].0 <= b)
            .collect();
        if inside.is_empty() {
            continue;
        }
        let mean = inside
            .iter()
            .map(|&i| terms.iter().map(|s| s[i].1).sum::<f64>())
            .sum::<f64>()
            / inside.len() as f64;
        let top: Vec<f64> = bars
            .iter()
            .filter(|(t, v)| *t > a && *t < b && *v != 0.0)
            .map(|p| p.1)
            .collect();
        assert_eq!(top.len(), 2, "trial {}: the bar's two top corners", m.index);
        for v in top {
            assert!(
                (v - mean).abs() < 1e-6,
                "trial {}: bar {v} vs mean {mean}",
                m.index
            );
        }
        checked += 1;
    }
    assert!(checked >= 3, "{checked} trials checked");

    // Trial log: a rejected trial's line names it once.
    let rejected: Vec<&TrialMark> = extras
        .trials
        .iter()
        .filter(|m| m.rejected.is_some())
        .collect();
    let log = c
        .chunks
        .iter()
        .filter(|ch| ch.entity_path().to_string() == "/trials/log")
        .flat_map(|ch| ch.components().0.values())
        .filter(|col| col.descriptor.component.as_str() == "TextLog:text")
        .flat_map(|col| {
            col.list_array
                .values()
                .as_string::<i32>()
                .iter()
                .flatten()
                .map(str::to_owned)
                .collect::<Vec<_>>()
        })
        .collect::<Vec<_>>();
    assert_eq!(log.len(), extras.trials.len());
    for line in &log {
        assert!(!line.contains("session 0"), "{line}");
    }
    for m in rejected {
        let line = log
            .iter()
            .find(|l| l.starts_with(&format!("trial {} ", m.index)))
            .expect("a log line per trial");
        assert!(line.contains("REJECTED"), "{line}");
        assert_eq!(
            line.matches(&format!("trial {}", m.index)).count(),
            1,
            "{line}"
        );
    }
}
