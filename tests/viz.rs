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
use g1viz::viz::{ReplayExtras, ReplayOptions, TrialMark, log_replay};
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

/// `msgs` with only the last chunk of each blueprint entity: the layout's last send (the replay
/// sends it before the data and again, fitted to the data, after it; both list every entity).
fn last_send(msgs: Vec<LogMsg>) -> Vec<LogMsg> {
    let path_of = |m: &LogMsg| match m {
        LogMsg::ArrowMsg(store, arrow) if store.kind() == StoreKind::Blueprint => Some(
            Chunk::from_arrow_msg(arrow)
                .unwrap()
                .entity_path()
                .to_string(),
        ),
        _ => None,
    };
    let mut last = BTreeMap::new();
    for (i, m) in msgs.iter().enumerate() {
        if let Some(p) = path_of(m) {
            last.insert(p, i);
        }
    }
    msgs.into_iter()
        .enumerate()
        .filter(|(i, m)| path_of(m).is_none_or(|p| last[&p] == *i))
        .map(|(_, m)| m)
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
    let opts = ReplayOptions::default();
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
    for msg in last_send(decode(&out)) {
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
    let dir = tempfile::tempdir().unwrap();
    let rec = synthetic(&input_file(dir.path()));
    let out = dir.path().join("out.rrd");
    let robot = RobotModel::builtin();
    let arm = robot.arm(&rec.joint_names).unwrap();
    let viz = open_stream("g1viz_test", "id", &Sink::Save(out.clone()), &[]).unwrap();
    let opts = ReplayOptions {
        properties: vec![
            ("command".into(), "replay".into()),
            ("model".into(), "paper".into()),
        ],
        ..Default::default()
    };
    log_replay(&rec, &robot, &arm, &extras(), &opts, viz.stream()).unwrap();
    viz.finish().unwrap();

    let (texts, start) = recording_properties(&out);
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
    let msgs = last_send(decode(&out));
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
        g1viz::viz::model_extras(&rec, &g1viz::power::PowerModel::PAPER, &opts).unwrap();

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

    // One model sample per state sample inside each trial with a copper baseline, counted here
    // from the recording's stamps and the validation's trial windows.
    let samples: usize = (validation.baselines.iter())
        .filter_map(|b| {
            validation
                .session
                .segmentation
                .trials
                .iter()
                .find(|t| t.index == b.trial)
        })
        .map(|t| {
            let inside = |x: &&f64| **x >= t.t_pre_start && **x <= t.t_return_end;
            rec.state.t.iter().filter(inside).count()
        })
        .sum();
    assert!(samples > 1000, "{samples} model samples");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("smoke_model.rrd");
    save_replay(&rec, &extras, &out, &mcap);
    let c = contents(&decode(&out));
    assert_eq!(rows(&c, "/model/terms/elbow/copper"), samples);
    assert_eq!(rows(&c, "/model/power/predicted"), samples);
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
fn stream_replay(mcap: &Path, out: &Path, chunk_rows: usize) -> g1viz::viz::ReplaySummary {
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
        ..Default::default()
    };
    let summary = g1viz::viz::replay_files_with(
        &[mcap],
        0.0,
        &map,
        &OpenOptions::default(),
        &robot,
        &arm,
        Default::default(),
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

/// `g1viz replay` without a model streams the file (`replay_files_with`, bounded memory): in many small
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
        // The data, entity for entity (the layouts differ: only the in-memory replay knows the
        // joints' range up front and gives their plot a legend).
        let data = |c: &Contents| -> Vec<((bool, String, bool), usize)> {
            c.rows
                .iter()
                .filter(|(k, _)| !k.0)
                .map(|(k, n)| (k.clone(), *n))
                .collect()
        };
        assert_eq!(data(&a), data(&b), "{}: rows per entity", mcap.display());
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
    save_replay(&real, &g1viz::viz::diagnosis_extras(&d), &out, &real_path);
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
    // The trial log: the located trials, and the rejected ones (each filter's rejection with
    // its window; a trial without a pre-idle has none to show).
    let filtered = d
        .rejected
        .iter()
        .filter(|x| x.reason != g1viz::trial::RejectReason::Unusable)
        .count();
    assert!(r.rejected.len() >= filtered, "{:?}", d.rejected);
    assert_eq!(
        rows(&c, "/diagnosis/trials/log"),
        r.highlighted.len() + r.rejected.len()
    );
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
    window: g1viz::viz::Window,
    model: Option<&g1viz::power::PowerModel>,
) -> Vec<g1viz::viz::Notice> {
    use g1viz::viz::{SessionReplay, replay_session};
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
    let window = g1viz::viz::Window {
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
    let window = g1viz::viz::Window {
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
    let window = g1viz::viz::Window {
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

/// Size per hour of session of a plain replay at the defaults, as docs/viewer.md states it
/// ("≈ N MB per hour … ± P %"): the example replayed, scaled to an hour. The size estimate
/// printed before writing lands within 25 % of the file written: at the defaults, with
/// `--max-rate 20`, for two trials at 20 Hz, and for 20 s with the model.
#[test]
fn rrd_size_per_hour_matches_readme_and_estimate() {
    use g1viz::viz::Notice;
    let page = common::doc_page("docs/viewer.md");
    let line = page
        .lines()
        .find(|l| l.contains("MB per hour of session"))
        .expect("docs/viewer.md states the .rrd size per hour");
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
        let window = g1viz::viz::Window {
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
                "{per_hour_mb:.0} MB per hour vs docs/viewer.md's {stated_mb} MB ± {}",
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
    use g1viz::diagnose::{LocatedField, ReplayData};
    use g1viz::viz::DiagnosisOverlay;
    let located = |name: &str, values: &[f64]| LocatedField {
        name: name.into(),
        values: values.to_vec(),
    };
    let dir = tempfile::tempdir().unwrap();
    let rec = synthetic(&input_file(dir.path()));
    let t: Vec<f64> = vec![0.5, 1.5, 2.5, 3.5, 4.5];
    let speed = vec![0.0, 0.4, 0.9, 0.3, 0.1];
    let temp = vec![31.0, 31.5, 32.0, 32.4, 32.9];
    let extras = ReplayExtras {
        diagnosis: Some(DiagnosisOverlay {
            data: ReplayData {
                t: t.clone(),
                measured_w: vec![1.0, 2.0, 3.0, 2.0, 1.0],
                before_w: vec![1.1, 1.8, 2.5, 1.9, 1.0],
                after_w: vec![1.0, 2.0, 2.9, 2.0, 1.0],
                found_w: vec![1.0, 2.0, 3.0, 2.0, 1.0],
                located: vec![
                    located("/lowstate.motor_state[3].dq", &speed),
                    located("/lowstate.motor_state[3].temperature", &temp),
                ],
                ..Default::default()
            },
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

/// A long diagnosis (more than 20 trials) gets the model replay's colour key on its Joints tab:
/// the per-trial joint shares logged from its per-reading base terms. Each point is checked
/// against the shares recomputed here from those terms (each joint's four terms summed,
/// averaged over the trial's readings, over the absolute sum of the joints' means, in %).
#[test]
fn long_diagnosis_joints_tab_has_the_replays_colour_key() {
    use g1viz::diagnose::ReplayData;
    use g1viz::viz::DiagnosisOverlay;
    let dir = tempfile::tempdir().unwrap();
    let rec = synthetic(&input_file(dir.path()));
    let (n_trials, per_trial) = (25, 3);
    let n = n_trials * per_trial;
    let t: Vec<f64> = (0..n).map(|i| 0.05 * i as f64).collect();
    let trial: Vec<usize> = (0..n).map(|i| i / per_trial).collect();
    let term = |i: usize, k: usize, j: usize| ((i * 7 + k * 3 + j * 11) as f64 * 0.37).sin();
    let terms_w: Vec<([[f64; N_JOINTS]; 4], f64)> = (0..n)
        .map(|i| {
            (
                std::array::from_fn(|k| std::array::from_fn(|j| term(i, k, j))),
                0.1,
            )
        })
        .collect();
    let extras = ReplayExtras {
        diagnosis: Some(DiagnosisOverlay {
            data: ReplayData {
                measured_w: vec![1.0; n],
                before_w: vec![0.9; n],
                after_w: vec![1.0; n],
                t: t.clone(),
                trial,
                terms_w: terms_w.clone(),
                ..Default::default()
            },
            summary: "nothing found".into(),
            ..Default::default()
        }),
        ..Default::default()
    };
    let out = dir.path().join("long_diagnosis.rrd");
    save_replay(&rec, &extras, &out, &rec.source);
    let msgs = decode(&out);
    let c = contents(&msgs);
    let views = blueprint_views(&msgs);
    let key = view_named(&views, "Key: joint shares [%]");
    assert!(
        view_includes(key, "/model/bars/by_joint/sh_pitch"),
        "{key:?}"
    );
    for (j, name) in rec.joint_names.iter().enumerate() {
        let path = format!(
            "/model/bars/by_joint/{}",
            g1viz::viz::short_joint_name(name)
        );
        let got: Vec<f64> = series(&c, &path).into_iter().map(|p| p.1).collect();
        assert_eq!(got.len(), n_trials, "{path}");
        for (k, g) in got.iter().enumerate() {
            let mean = |jj: usize| {
                let rows = k * per_trial..(k + 1) * per_trial;
                let sum: f64 = rows
                    .map(|i| (0..4).map(|kk| terms_w[i].0[kk][jj]).sum::<f64>())
                    .sum();
                sum / per_trial as f64
            };
            let turnover: f64 = (0..N_JOINTS).map(|jj| mean(jj).abs()).sum();
            let want = 100.0 * mean(j) / turnover;
            assert!((g - want).abs() < 1e-9, "{path} trial {k}: {g} vs {want}");
        }
    }
    // The titles name the hypotheses' series only where it shows: with none accepted (the
    // same prediction as the base model's) it lies under the base model's.
    let per_trial_title = |extras: &ReplayExtras| {
        save_replay(&rec, extras, &out, &rec.source);
        let views = blueprint_views(&decode(&out));
        view_named(&views, "Error per trial [W]").name.clone()
    };
    let title = "Error per trial [W]: base model grey";
    assert_eq!(
        per_trial_title(&extras),
        format!("{title}, with hypotheses teal")
    );
    let mut none = extras.clone();
    let d = &mut none.diagnosis.as_mut().unwrap().data;
    d.after_w = d.before_w.clone();
    assert_eq!(per_trial_title(&none), title);
}

/// The arm links of a model replay change colour with their joint's power: their colour is on
/// the timeline (no static colour, which would override it), grey at the session start, and
/// reddens during a trial; the per-trial bars' heights are each trial's share of the per-joint
/// power (recomputed here from the decoded loss-term series); the trial log names a
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
        g1viz::viz::model_extras(&rec, &g1viz::power::PowerModel::PAPER, &opts).unwrap();
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

    assert_bars_are_trial_shares(&c, &extras, rec.start_ns);

    // The colour scale the note states: the 98th percentile of the joints' positive predicted
    // power, rounded up to 0.5 W (at least 1 W), recomputed here from the decoded per-joint
    // series by a sort (the replay counts them by 0.5 W step as it logs them).
    let mut power: Vec<f64> = (ARM.iter())
        .map(|j| format!("/model/by_joint/{}", g1viz::viz::short_joint_name(j)))
        .flat_map(|p| series(&c, &p).into_iter().map(|x| x.1))
        .filter(|x| x.is_finite() && *x > 0.0)
        .collect();
    power.sort_by(f64::total_cmp);
    assert!(power.len() > 1000, "{} positive joint powers", power.len());
    let q = power[((power.len() - 1) as f64 * 0.98) as usize];
    let scale = ((q * 2.0).ceil() / 2.0).max(1.0);
    let note = static_strings(&c, "/model/note", "TextDocument:text").join("");
    assert!(
        note.contains(&format!("red at {scale:.1} W")),
        "{scale} W: {note}"
    );

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
    // Each log line is stamped at its trial's start rounded to 0.1 s, and its text opens with
    // that stamp (the viewer's session-time column, hidden, cut stamps past 1000 s).
    let stamps = session_stamps(&c, "/trials/log");
    assert_eq!(stamps.len(), extras.trials.len());
    for (line, s) in log.iter().zip(&stamps) {
        assert!(
            line.starts_with(&format!("{s:.1} s  trial ")),
            "{line} at {s}"
        );
    }
    let mut starts: Vec<f64> = extras.trials.iter().map(|m| m.t_start).collect();
    starts.sort_by(f64::total_cmp);
    for (s, t) in stamps.iter().zip(&starts) {
        assert!((s * 10.0 - (s * 10.0).round()).abs() < 1e-6, "stamp {s}");
        assert!((s - t).abs() <= 0.05 + 1e-9, "stamp {s} vs trial start {t}");
    }
    for m in rejected {
        let line = log
            .iter()
            .find(|l| l.contains(&format!(" s  trial {} ", m.index)))
            .expect("a log line per trial");
        assert!(line.contains("REJECTED"), "{line}");
        assert_eq!(
            line.matches(&format!("trial {}", m.index)).count(),
            1,
            "{line}"
        );
    }
}

/// A view of the decoded blueprint: its class, title, queries, legend and y range.
#[derive(Debug, Default, Clone)]
struct BlueprintView {
    class: String,
    name: String,
    queries: Vec<String>,
    /// `PlotLegend:visible` (None: not set).
    legend_visible: Option<bool>,
    /// Whether a `PlotLegend` was logged at all.
    legend_set: bool,
    y_range: Option<[f64; 2]>,
}

/// Every view of the blueprint in `msgs`, by its blueprint entity path.
fn blueprint_views(msgs: &[LogMsg]) -> BTreeMap<String, BlueprintView> {
    use rerun::external::arrow::array::AsArray;
    use rerun::external::arrow::datatypes::Float64Type;
    let mut views: BTreeMap<String, BlueprintView> = BTreeMap::new();
    for msg in msgs {
        let LogMsg::ArrowMsg(store, arrow) = msg else {
            continue;
        };
        if store.kind() != StoreKind::Blueprint {
            continue;
        }
        let chunk = Chunk::from_arrow_msg(arrow).unwrap();
        let path = chunk.entity_path().to_string();
        let Some(rest) = path.strip_prefix("/view/") else {
            continue;
        };
        let id = rest.split('/').next().unwrap().to_owned();
        let view = views.entry(id).or_default();
        for column in chunk.components().0.values() {
            let values = column.list_array.values();
            match column.descriptor.component.as_str() {
                "ViewBlueprint:class_identifier" => {
                    view.class = values.as_string::<i32>().value(0).to_owned();
                }
                "ViewBlueprint:display_name" => {
                    view.name = values.as_string::<i32>().value(0).to_owned();
                }
                "ViewContents:query" => view.queries.extend(
                    values
                        .as_string::<i32>()
                        .iter()
                        .flatten()
                        .map(str::to_owned),
                ),
                "PlotLegend:visible" => {
                    view.legend_set = true;
                    view.legend_visible = Some(values.as_boolean().value(0));
                }
                "PlotLegend:corner" => view.legend_set = true,
                "ScalarAxis:range" => {
                    let pair = values.as_fixed_size_list().value(0);
                    let v = pair.as_primitive::<Float64Type>();
                    assert_eq!(v.len(), 2);
                    view.y_range = Some([v.value(0), v.value(1)]);
                }
                _ => {}
            }
        }
    }
    // The viewer's shared view carries only a time axis.
    views.retain(|_, v| !v.class.is_empty());
    views
}

/// The view titled `name` (exactly, or its title starts with it).
fn view_named<'a>(views: &'a BTreeMap<String, BlueprintView>, name: &str) -> &'a BlueprintView {
    views
        .values()
        .find(|v| v.name == name || v.name.starts_with(name))
        .unwrap_or_else(|| {
            panic!(
                "no view {name:?}: {:?}",
                views.values().map(|v| &v.name).collect::<Vec<_>>()
            )
        })
}

/// Whether entity `path` is included by the view's queries (`+ /a`, `+ /a/**`).
fn view_includes(v: &BlueprintView, path: &str) -> bool {
    v.queries.iter().any(|q| {
        let q = q.trim_start_matches("+ ").trim();
        match q.strip_suffix("/**") {
            Some(tree) => path == tree || path.starts_with(&format!("{tree}/")),
            None => path == q,
        }
    })
}

/// The scalar series (entities with timed `Scalars`) a view shows: path and values.
fn view_series(c: &Contents, v: &BlueprintView) -> Vec<(String, Vec<f64>)> {
    let paths: std::collections::BTreeSet<String> = c
        .chunks
        .iter()
        .filter(|ch| {
            !ch.is_static()
                && ch
                    .components()
                    .0
                    .values()
                    .any(|col| col.descriptor.component.as_str() == "Scalars:scalars")
        })
        .map(|ch| ch.entity_path().to_string())
        .filter(|p| view_includes(v, p))
        .collect();
    paths
        .into_iter()
        .map(|p| {
            let values = series(c, &p).into_iter().map(|x| x.1).collect();
            (p, values)
        })
        .collect()
}

/// Legend geometry measured on the screenshots of the stock 0.36.3 web viewer (1920×1080
/// window): 18 px above the first entry, 23 px per entry; the smallest plot area of the
/// overview's power plot and of a half-height cell in the tabs.
const LEGEND_TOP_PX: f64 = 18.0;
const LEGEND_LINE_PX: f64 = 23.0;
const OVERVIEW_PLOT_PX: f64 = 190.0;
const DETAIL_PLOT_PX: f64 = 330.0;

/// Checks every plot of `msgs` (decoded as `c`): each sets its legend explicitly; a shown legend
/// has every entry (one per series with data) inside the plot and the data below it: the y range
/// the plot opens on holds all the data and leaves the legend's share of the height free above
/// it. Returns the titles of the plots that show a legend, with their number of entries.
fn assert_legends_clear_the_data(msgs: &[LogMsg], c: &Contents) -> BTreeMap<String, usize> {
    let views = blueprint_views(msgs);
    let mut shown = BTreeMap::new();
    for v in views.values() {
        if v.class != "TimeSeries" && v.class != "BarChart" {
            continue;
        }
        assert!(v.legend_set, "{}: legend not set explicitly", v.name);
        if v.legend_visible == Some(false) {
            continue;
        }
        assert_eq!(
            v.class, "TimeSeries",
            "{}: a bar chart has no y range",
            v.name
        );
        let series = view_series(c, v);
        // One entry per name (series of one name share an entry, e.g. a joint's q and command).
        let names: std::collections::BTreeSet<String> =
            series.iter().map(|s| legend_name(c, &s.0)).collect();
        let entries = names.len();
        assert!(entries > 0, "{}: a legend with no series", v.name);
        let values: Vec<f64> = series
            .iter()
            .flat_map(|s| s.1.iter().copied())
            .filter(|x| x.is_finite())
            .collect();
        let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let [y0, y1] = v
            .y_range
            .unwrap_or_else(|| panic!("{}: a legend without a y range can cover data", v.name));
        assert!(
            y0 <= lo && hi < y1,
            "{}: data {lo}..{hi} outside {y0}..{y1}",
            v.name
        );
        let plot_px = if v.name.starts_with("Net power") {
            OVERVIEW_PLOT_PX
        } else {
            DETAIL_PLOT_PX
        };
        let legend = (LEGEND_TOP_PX + LEGEND_LINE_PX * entries as f64) / plot_px;
        assert!(legend < 1.0, "{}: {entries} entries do not fit", v.name);
        let free = (y1 - hi) / (y1 - y0);
        assert!(
            free >= legend - 1e-9,
            "{}: {entries} legend entries need the top {legend:.2} of the plot, {free:.2} is free",
            v.name
        );
        shown.insert(v.name.clone(), entries);
    }
    shown
}

/// The name a series shows in a legend: its `SeriesLines`/`SeriesPoints` name, else its path.
fn legend_name(c: &Contents, path: &str) -> String {
    ["SeriesLines:names", "SeriesPoints:names"]
        .iter()
        .flat_map(|k| static_strings(c, path, k))
        .next()
        .unwrap_or_else(|| path.to_owned())
}

/// Legends never cover data (issue 13): on the model replay of the shipped example, every plot
/// that shows a legend opens on a y range that keeps the data below it, with every entry inside
/// the plot — the τ plot (all 7 joints), the loss-term grid's legend cell (all 4 terms, viscous
/// included), the IMU plot (all 4 series, the threshold included); small or dense plots (the
/// error, the trial track, the other grid cells, the bar charts) show none. A streamed replay
/// cannot know the joints' range when it sends the layout: its τ plot shows no legend.
#[test]
fn legends_never_cover_data() {
    let session = example_session();
    let rec = g1viz::signals::load_recording(
        &session,
        &g1viz::signals::SignalMap::g1_left_arm(),
        &Default::default(),
    )
    .unwrap();
    let (extras, _) =
        g1viz::viz::model_extras(&rec, &g1viz::power::PowerModel::PAPER, &Default::default())
            .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("model.rrd");
    save_replay(&rec, &extras, &out, &session);
    let msgs = decode(&out);
    let c = contents(&msgs);
    let shown = assert_legends_clear_the_data(&msgs, &c);
    let expect = [
        ("Net power at the readings [W]", 3),
        ("Predicted power by term, all joints [W]", 5),
        ("Predicted power by joint, all terms [W]", 7),
        ("sh_pitch [W]", 4),
        ("q [rad], command pale", 7),
        ("Joint velocity q̇ [rad/s]", 7),
        ("Joint torque τ [Nm]", 7),
        ("IMU |ω| [rad/s] and the balance filter", 4),
        ("Raw power MBS/BMS [W]", 2),
    ];
    for (name, entries) in expect {
        assert_eq!(shown.get(name), Some(&entries), "{name}: {shown:?}");
    }
    assert_eq!(shown.len(), expect.len(), "{shown:?}");
    let views = blueprint_views(&msgs);
    let imu = view_named(&views, "IMU |ω| [rad/s] and the balance filter");
    assert!(view_includes(imu, "/imu/threshold"), "{imu:?}");
    for hidden in [
        "Error measured − predicted",
        "Trials (index",
        "sh_roll [W]",
        "Pairwise [W]",
        "Trial energy turnover by joint",
        "Trial energy turnover by term",
        "Motor temperature",
    ] {
        assert_eq!(
            view_named(&views, hidden).legend_visible,
            Some(false),
            "{hidden}"
        );
    }

    // A plain replay streams the file: its layout is sent again once the data is logged, so
    // its plots carry legends too (issue 13).
    let mut sessions = vec![session];
    sessions.extend(common::shared_recording("g1_smoke.mcap"));
    for session in sessions {
        let streamed = dir.path().join("streamed.rrd");
        stream_replay(&session, &streamed, 4096);
        let msgs = decode(&streamed);
        let c = contents(&msgs);
        let shown = assert_legends_clear_the_data(&msgs, &c);
        let expect = [
            (
                "Net power [W]: MBS cyan, BMS olive (minus the idle baseline before the arm moves)",
                2,
            ),
            ("q [rad], command pale", 7),
            ("Joint velocity q̇ [rad/s]", 7),
            ("Joint torque τ [Nm]", 7),
            ("Raw power MBS/BMS [W]", 2),
        ];
        for (name, entries) in expect {
            assert_eq!(shown.get(name), Some(&entries), "{name}: {shown:?}");
        }
        assert_eq!(shown.len(), expect.len(), "{shown:?}");
        // The entries are the joints' names (each joint's q and command share one).
        let views = blueprint_views(&msgs);
        let q = view_named(&views, "q [rad], command pale");
        let names: std::collections::BTreeSet<String> = view_series(&c, q)
            .iter()
            .map(|s| legend_name(&c, &s.0))
            .collect();
        let joints: std::collections::BTreeSet<String> = ARM
            .iter()
            .map(|j| g1viz::viz::short_joint_name(j))
            .collect();
        assert_eq!(names, joints, "{}", session.display());
        assert_eq!(view_series(&c, q).len(), 14, "q and command per joint");
    }
}

/// The labels the stock 0.36.3 viewer draws on an axis showing [lo, hi] over `px` pixels —
/// egui_plot's rule, restated here from its source: grid lines every `s0`, `10 s0` and
/// `100 s0` (`s0`: the power of ten at or above the span of 8 px); a line carries the largest of
/// those steps its value is a multiple of, and gets a label when that step spans more than
/// `label_px` (20 px on a y axis, 60 px on an x axis); lines are the multiples in [lo, hi).
fn viewer_labels(range: [f64; 2], px: f64, label_px: f64) -> Vec<f64> {
    let [lo, hi] = range;
    let span = hi - lo;
    assert!(span > 0.0, "empty range {range:?}");
    let s0 = 10f64.powf((8.0 * span / px).log10().ceil());
    let mut labels = Vec::new();
    for step in [s0, 10.0 * s0, 100.0 * s0] {
        if step * px / span <= label_px {
            continue;
        }
        let mut k = (lo / step).ceil();
        while k * step < hi {
            labels.push(k * step);
            k += 1.0;
        }
    }
    labels.sort_by(f64::total_cmp);
    labels.dedup_by(|a, b| (*a - *b).abs() < 0.1 * s0);
    labels
}

/// The smallest plot area [px] of each plot in a 1920×1080 browser window, measured on the
/// screenshots of docs/viewer.md: the overview's power plot, trial track and error plot, and a
/// half-height cell of the tabs (every other plot is at least that high).
fn plot_height_px(title: &str) -> f64 {
    if title.starts_with("Net power") {
        190.0
    } else if title.starts_with("Trials (index") {
        40.0
    } else if title.starts_with("Error measured") {
        150.0
    } else {
        330.0
    }
}

/// A per-trial bar chart's plot area [px] (width, height) at 1920×1080.
const BAR_PLOT_PX: [f64; 2] = [300.0, 200.0];

/// Every plot of `msgs` (decoded as `c`) that has data opens with at least two labelled ticks
/// on each axis the layout sets (issue 13: "short panels with a single 0 tick"): a time series
/// on its y range (which holds all its data), a bar chart on the extent the viewer fits to its
/// bars (5 % to spare) on both axes. Returns the number of plots checked.
fn assert_every_plot_has_two_labelled_ticks(msgs: &[LogMsg], c: &Contents) -> usize {
    let views = blueprint_views(msgs);
    let mut checked = 0;
    for v in views.values() {
        match v.class.as_str() {
            "TimeSeries" => {
                let values: Vec<f64> = view_series(c, v)
                    .into_iter()
                    .flat_map(|s| s.1)
                    .filter(|x| x.is_finite())
                    .collect();
                if values.is_empty() {
                    continue;
                }
                let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
                let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                let range = v
                    .y_range
                    .unwrap_or_else(|| panic!("{}: no y range for its data", v.name));
                assert!(
                    range[0] <= lo && hi <= range[1],
                    "{}: data {lo}..{hi} outside {range:?}",
                    v.name
                );
                let labels = viewer_labels(range, plot_height_px(&v.name), 20.0);
                assert!(labels.len() >= 2, "{}: {range:?} labels {labels:?}", v.name);
                checked += 1;
            }
            "BarChart" => {
                let bars: Vec<String> =
                    c.chunks
                        .iter()
                        .filter(|ch| {
                            ch.is_static()
                                && ch.components().0.values().any(|col| {
                                    col.descriptor.component.as_str() == "BarChart:values"
                                })
                        })
                        .map(|ch| ch.entity_path().to_string())
                        .filter(|p| view_includes(v, p))
                        .collect();
                if bars.is_empty() {
                    continue;
                }
                let (mut x, mut y) = ([f64::INFINITY, f64::NEG_INFINITY], [0.0f64, 0.0f64]);
                for p in &bars {
                    let (abscissa, heights, widths) = bar_chart(c, p);
                    for ((a, h), w) in abscissa.iter().zip(&heights).zip(&widths) {
                        x = [x[0].min(*a), x[1].max(a + f64::from(*w))];
                        y = [y[0].min(*h), y[1].max(*h)];
                    }
                }
                let margins = |[a, b]: [f64; 2]| [a - 0.05 * (b - a), b + 0.05 * (b - a)];
                let xl = viewer_labels(margins(x), BAR_PLOT_PX[0], 60.0);
                let yl = viewer_labels(margins(y), BAR_PLOT_PX[1], 20.0);
                assert!(xl.len() >= 2, "{}: x {x:?} labels {xl:?}", v.name);
                assert!(yl.len() >= 2, "{}: y {y:?} labels {yl:?}", v.name);
                checked += 1;
            }
            _ => {}
        }
    }
    checked
}

/// Every plot opens with at least two labelled ticks (issue 13): the model replay of the shipped
/// example (few trials: its trial track and per-trial bar charts showed a single "0"), and the
/// plain streamed replay of the example and of the shared `g1_smoke` session.
#[test]
fn every_plot_opens_with_two_labelled_ticks() {
    let session = example_session();
    let rec = g1viz::signals::load_recording(
        &session,
        &g1viz::signals::SignalMap::g1_left_arm(),
        &Default::default(),
    )
    .unwrap();
    let (extras, _) =
        g1viz::viz::model_extras(&rec, &g1viz::power::PowerModel::PAPER, &Default::default())
            .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("model.rrd");
    save_replay(&rec, &extras, &out, &session);
    let msgs = decode(&out);
    let checked = assert_every_plot_has_two_labelled_ticks(&msgs, &contents(&msgs));
    // Power, track, error; by term, by joint, two bar charts; 8 loss cells; q, q̇, τ, °C; IMU;
    // raw power.
    assert!(checked >= 21, "{checked} plots checked");

    let mut sessions = vec![session];
    sessions.extend(common::shared_recording("g1_smoke.mcap"));
    for session in sessions {
        let streamed = dir.path().join("streamed.rrd");
        stream_replay(&session, &streamed, 4096);
        let msgs = decode(&streamed);
        let checked = assert_every_plot_has_two_labelled_ticks(&msgs, &contents(&msgs));
        assert!(checked >= 7, "{}: {checked} plots", session.display());
    }
}

/// The static bar chart at `path`: abscissa, heights and widths.
fn bar_chart(c: &Contents, path: &str) -> (Vec<f64>, Vec<f64>, Vec<f32>) {
    use rerun::Loggable as _;
    use rerun::external::arrow::array::AsArray;
    use rerun::external::arrow::datatypes::Float32Type;
    let chunk = c
        .chunks
        .iter()
        .find(|ch| ch.is_static() && ch.entity_path().to_string() == path)
        .unwrap_or_else(|| panic!("no bar chart at {path}"));
    let column = |name: &str| {
        chunk
            .components()
            .0
            .values()
            .find(|col| col.descriptor.component.as_str() == name)
            .unwrap_or_else(|| panic!("{path}: no {name}"))
            .list_array
            .values()
            .clone()
    };
    let tensor = |name: &str| -> Vec<f64> {
        let t = rerun::components::TensorData::from_arrow(&column(name)).unwrap();
        match &t[0].0.buffer {
            rerun::datatypes::TensorBuffer::F64(b) => b.iter().copied().collect(),
            other => panic!("{path} {name}: {other:?}"),
        }
    };
    let widths = column("BarChart:widths")
        .as_primitive::<Float32Type>()
        .values()
        .to_vec();
    (
        tensor("BarChart:abscissa"),
        tensor("BarChart:values"),
        widths,
    )
}

/// The `session` timeline stamps [s] of every row at `path`, sorted.
fn session_stamps(c: &Contents, path: &str) -> Vec<f64> {
    let mut v: Vec<f64> = c
        .chunks
        .iter()
        .filter(|ch| !ch.is_static() && ch.entity_path().to_string() == path)
        .flat_map(|ch| {
            ch.timelines()
                .iter()
                .find(|(name, _)| name.as_str() == "session")
                .expect("session timeline")
                .1
                .times_raw()
                .iter()
                .map(|ns| *ns as f64 * 1e-9)
                .collect::<Vec<_>>()
        })
        .collect();
    v.sort_by(f64::total_cmp);
    v
}

/// The default arm (issue 13): every `<box>` visual of the shipped URDF is drawn as a solid
/// capsule along the box's longest side, its radius the mean half-width of the other two sides
/// and its overall length (cylinder + both caps) the longest side — read from the URDF text here,
/// not from the model the replay built.
#[test]
fn default_arm_draws_each_urdf_box_as_a_capsule_sized_to_it() {
    use rerun::external::arrow::array::AsArray;
    use rerun::external::arrow::datatypes::Float32Type;
    let urdf = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("urdf/g1_left_arm.urdf"),
    )
    .unwrap();
    // (link, visual index, box size) for every box visual, in file order.
    let mut boxes = Vec::new();
    for link in urdf.split("<link ").skip(1) {
        let name = link.split('"').nth(1).unwrap().to_owned();
        let body = link.split("</link>").next().unwrap();
        for (k, visual) in body.split("<visual").skip(1).enumerate() {
            let visual = visual.split("</visual>").next().unwrap();
            if let Some(b) = visual.split("<box").nth(1) {
                let size: Vec<f64> = b
                    .split("size=\"")
                    .nth(1)
                    .unwrap()
                    .split('"')
                    .next()
                    .unwrap()
                    .split_whitespace()
                    .map(|x| x.parse().unwrap())
                    .collect();
                boxes.push((name.clone(), k, size));
            }
        }
    }
    assert!(
        boxes.len() >= 10,
        "{} boxes in the shipped URDF",
        boxes.len()
    );

    let dir = tempfile::tempdir().unwrap();
    let rec = synthetic(&input_file(dir.path()));
    let out = dir.path().join("out.rrd");
    write_rrd(&rec, &out).unwrap();
    let c = contents(&decode(&out));
    let f32s = |path: &str, component: &str| -> Vec<f32> {
        c.chunks
            .iter()
            .filter(|ch| ch.is_static() && ch.entity_path().to_string() == path)
            .flat_map(|ch| ch.components().0.values())
            .filter(|col| col.descriptor.component.as_str() == component)
            .flat_map(|col| {
                let v = col.list_array.values().as_primitive::<Float32Type>();
                (0..v.len()).map(|i| v.value(i)).collect::<Vec<_>>()
            })
            .collect()
    };
    for (link, k, size) in &boxes {
        let path = format!("/robot/{link}/visual{k}");
        let radii = f32s(&path, "Capsules3D:radii");
        let lengths = f32s(&path, "Capsules3D:lengths");
        assert_eq!((radii.len(), lengths.len()), (1, 1), "{path}: one capsule");
        let mut sides = size.clone();
        sides.sort_by(f64::total_cmp);
        let radius = 0.25 * (sides[0] + sides[1]);
        assert!(
            (f64::from(radii[0]) - radius).abs() < 1e-6,
            "{path}: radius {} vs box {size:?}",
            radii[0]
        );
        let overall = f64::from(lengths[0]) + 2.0 * f64::from(radii[0]);
        assert!(
            (overall - sides[2].max(2.0 * radius)).abs() < 1e-5,
            "{path}: capsule {overall} m long vs box {size:?}"
        );
    }
}

/// The measured readings stay visible next to the like-for-like prediction (issue 13): both are
/// markers (not lines) in the power plot, at least 3 px, in colours far apart from each other
/// and from the instantaneous context line drawn under them, one marker per reading.
#[test]
fn measured_readings_are_distinct_markers_in_the_power_plot() {
    use rerun::external::arrow::array::{Array, AsArray};
    use rerun::external::arrow::datatypes::{Float32Type, UInt32Type};
    let session = example_session();
    let rec = g1viz::signals::load_recording(
        &session,
        &g1viz::signals::SignalMap::g1_left_arm(),
        &Default::default(),
    )
    .unwrap();
    let (extras, _) =
        g1viz::viz::model_extras(&rec, &g1viz::power::PowerModel::PAPER, &Default::default())
            .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("model.rrd");
    save_replay(&rec, &extras, &out, &session);
    let msgs = decode(&out);
    let c = contents(&msgs);
    let views = blueprint_views(&msgs);
    let power = view_named(&views, "Net power at the readings [W]");
    let style = |path: &str, component: &str| -> Vec<u32> {
        c.chunks
            .iter()
            .filter(|ch| ch.is_static() && ch.entity_path().to_string() == path)
            .flat_map(|ch| ch.components().0.values())
            .filter(|col| col.descriptor.component.as_str() == component)
            .flat_map(|col| {
                let v = col.list_array.values();
                match v.data_type() {
                    rerun::external::arrow::datatypes::DataType::Float32 => {
                        let f = v.as_primitive::<Float32Type>();
                        (0..f.len())
                            .map(|i| f.value(i).to_bits())
                            .collect::<Vec<_>>()
                    }
                    _ => {
                        let u = v.as_primitive::<UInt32Type>();
                        (0..u.len()).map(|i| u.value(i)).collect()
                    }
                }
            })
            .collect()
    };
    let rgb = |c: u32| {
        [
            (c >> 24) as f64,
            ((c >> 16) & 255) as f64,
            ((c >> 8) & 255) as f64,
        ]
    };
    let dist = |a: u32, b: u32| {
        let (a, b) = (rgb(a), rgb(b));
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    };
    let readings = extras.readings.as_ref().unwrap();
    let mut colours = Vec::new();
    for path in [
        "/model/power/reading_measured",
        "/model/power/reading_predicted",
    ] {
        assert!(view_includes(power, path), "{path} not in {power:?}");
        let sizes = style(path, "SeriesPoints:marker_sizes");
        assert_eq!(sizes.len(), 1, "{path}: a marker series");
        assert!(
            f32::from_bits(sizes[0]) >= 3.0,
            "{path}: marker {}",
            f32::from_bits(sizes[0])
        );
        let colour = style(path, "SeriesPoints:colors");
        assert_eq!(colour.len(), 1, "{path}");
        colours.push(colour[0]);
        assert_eq!(
            series(&c, path).len(),
            readings.t.len(),
            "{path}: one per reading"
        );
    }
    let context = style("/model/power/predicted", "SeriesLines:colors");
    assert_eq!(context.len(), 1);
    assert!(
        dist(colours[0], colours[1]) > 150.0,
        "measured vs predicted colours"
    );
    assert!(
        dist(colours[0], context[0]) > 150.0,
        "measured vs context line colours"
    );
    // Terms and joints sit side by side (Where the power goes): no two terms alike and no term
    // like a joint, by CIE76 ΔE in L*a*b* (sRGB, D65). The earlier gold interaction beside the
    // olive copper was ΔE 20; Tableau's closest joints (purple, pink) are 28.
    let lab = |c: u32| {
        let lin = |u: f64| {
            let u = u / 255.0;
            if u > 0.04045 {
                ((u + 0.055) / 1.055).powf(2.4)
            } else {
                u / 12.92
            }
        };
        let [r, g, b] = rgb(c).map(lin);
        let f = |t: f64| {
            if t > 0.008856 {
                t.cbrt()
            } else {
                7.787 * t + 16.0 / 116.0
            }
        };
        let x = f((0.4124 * r + 0.3576 * g + 0.1805 * b) / 0.95047);
        let y = f(0.2126 * r + 0.7152 * g + 0.0722 * b);
        let z = f((0.0193 * r + 0.1192 * g + 0.9505 * b) / 1.08883);
        [116.0 * y - 16.0, 500.0 * (x - y), 200.0 * (y - z)]
    };
    let delta_e = |a: u32, b: u32| {
        let (a, b) = (lab(a), lab(b));
        (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
    };
    let under = |prefix: &str| -> BTreeMap<String, u32> {
        (c.chunks.iter())
            .map(|ch| ch.entity_path().to_string())
            .filter(|p| p.starts_with(prefix))
            .filter_map(|p| Some((p.clone(), *style(&p, "SeriesLines:colors").first()?)))
            .collect()
    };
    let (terms, joints) = (under("/model/by_term/"), under("/model/by_joint/"));
    assert_eq!((terms.len(), joints.len()), (5, 7), "{terms:?} {joints:?}");
    for (a, ca) in &terms {
        for (b, cb) in terms.iter().filter(|x| x.0 > a).chain(&joints) {
            let e = delta_e(*ca, *cb);
            assert!(e >= 30.0, "{a} and {b}: ΔE {e:.1}");
        }
    }
}

/// The recording's text properties (name, input, command, …) and start time [ns] in `rrd`.
fn recording_properties(rrd: &Path) -> (BTreeMap<String, String>, Option<i64>) {
    use rerun::external::arrow::array::AsArray;
    use rerun::external::arrow::datatypes::Int64Type;
    let mut texts: BTreeMap<String, String> = BTreeMap::new();
    let mut start = None;
    for msg in decode(rrd) {
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
    (texts, start)
}

/// The recording's properties hold the input and the command as typed (issue 13: the
/// screenshots showed the directory of the machine that made them): `g1viz replay` run from the
/// repository root on a relative path stores that path, and the program by its name.
#[test]
fn recording_properties_hold_paths_as_given() {
    use std::process::Command;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.rrd");
    let args = [
        "replay",
        "examples/g1_example.mcap",
        "--max-rate",
        "5",
        "--pose-rate",
        "5",
    ];
    let o = common::output_within(
        Command::new(env!("CARGO_BIN_EXE_g1viz"))
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .args(args)
            .arg("--save")
            .arg(&out),
        common::G1VIZ_LIMIT,
    )
    .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (texts, _) = recording_properties(&out);
    assert_eq!(
        texts.get("input").map(String::as_str),
        Some("examples/g1_example.mcap"),
        "{texts:?}"
    );
    assert_eq!(
        texts.get("command"),
        Some(&format!(
            "g1viz {} --save {}",
            args.join(" "),
            out.display()
        )),
        "{texts:?}"
    );
    assert_eq!(
        texts.get("RecordingInfo:name").map(String::as_str),
        Some("g1_example.mcap")
    );
    let here = env!("CARGO_MANIFEST_DIR");
    for (k, v) in &texts {
        assert!(!v.contains(here), "{k} = {v} names the build directory");
    }
}

/// Bars, keyed by trial index: for every trial, the elbow's bar sits in the elbow's slot (4th of
/// 7) of the group around the trial's index, and its height is the elbow's signed share [%] of
/// the trial's energy turnover: the mean of the decoded per-joint sum of its four terms over
/// the trial's window, over the absolute values of the same sum for all seven joints; the
/// copper bar likewise over the terms (with the interaction). Every trial has both. The seven
/// joints' bars never overlap.
fn assert_bars_are_trial_shares(c: &Contents, extras: &ReplayExtras, start_ns: u64) {
    let joints: Vec<String> = ARM
        .iter()
        .map(|j| g1viz::viz::short_joint_name(j).to_string())
        .collect();
    let names = ["mechanical", "copper", "coulomb", "viscous"];
    let series_of = |p: String| series(c, &p);
    // [joint][term] series, and the interaction.
    let terms: Vec<Vec<Vec<(i64, f64)>>> = joints
        .iter()
        .map(|j| {
            (names.iter())
                .map(|t| series_of(format!("/model/terms/{j}/{t}")))
                .collect()
        })
        .collect();
    let interaction = series_of("/model/terms/interaction/total".to_string());
    let (x, heights, widths) = bar_chart(c, "/model/bars/by_joint/elbow");
    assert_eq!(x.len(), heights.len());
    assert_eq!(widths.len(), heights.len());
    let width = 0.8 / 7.0;
    for w in &widths {
        assert!((f64::from(*w) - width).abs() < 1e-6, "bar width {w}");
    }
    let start = start_ns as i64;
    let mut checked = 0;
    for m in &extras.trials {
        let (a, b) = (
            start + (m.t_start * 1e9).round() as i64,
            start + (m.t_end * 1e9).round() as i64,
        );
        let inside: Vec<usize> = (0..interaction.len())
            .filter(|&i| interaction[i].0 >= a && interaction[i].0 <= b)
            .collect();
        if inside.is_empty() {
            continue;
        }
        let mean =
            |s: &[(i64, f64)]| inside.iter().map(|&i| s[i].1).sum::<f64>() / inside.len() as f64;
        let by_joint: Vec<f64> = terms
            .iter()
            .map(|j| j.iter().map(|s| mean(s)).sum())
            .collect();
        let mut by_term: Vec<f64> = (0..4)
            .map(|k| terms.iter().map(|j| mean(&j[k])).sum())
            .collect();
        by_term.push(mean(&interaction));
        let turnover = |v: &[f64], k: usize| 100.0 * v[k] / v.iter().map(|x| x.abs()).sum::<f64>();
        for (path, slot, slots, share) in [
            ("by_joint/elbow", 3.0, 7.0, turnover(&by_joint, 3)),
            ("by_term/copper", 1.0, 5.0, turnover(&by_term, 1)),
        ] {
            let (x, heights, _) = bar_chart(c, &format!("/model/bars/{path}"));
            let at = m.index as f64 - 0.4 + slot * 0.8 / slots;
            let k = (x.iter().position(|&xi| (xi - at).abs() < 1e-9))
                .unwrap_or_else(|| panic!("trial {}: no {path} bar at {at} in {x:?}", m.index));
            assert!(
                (heights[k] - share).abs() < 1e-4,
                "trial {} {path}: bar {} vs share {share}",
                m.index,
                heights[k]
            );
        }
        checked += 1;
    }
    assert!(checked >= 3, "{checked} trials checked");
    // The seven joints' bars of a trial sit side by side, none over another.
    let mut all_x: Vec<f64> = ARM
        .iter()
        .map(|j| g1viz::viz::short_joint_name(j))
        .flat_map(|j| bar_chart(c, &format!("/model/bars/by_joint/{j}")).0)
        .collect();
    all_x.sort_by(f64::total_cmp);
    for pair in all_x.windows(2) {
        assert!(pair[1] - pair[0] >= width - 1e-9, "bars overlap: {pair:?}");
    }
}

/// The short plots of the overview open on ranges with readable ticks (issue 13: "short panels
/// with a single 0 tick"): the error plot on a range symmetric about zero holding every decoded
/// error with 5 % to spare, with the ticks at ±10^k inside it, at most five steps across; the
/// trial track on the trial indices with half a step spare.
#[test]
fn overview_plots_open_on_readable_ranges() {
    let session = example_session();
    let rec = g1viz::signals::load_recording(
        &session,
        &g1viz::signals::SignalMap::g1_left_arm(),
        &Default::default(),
    )
    .unwrap();
    let (extras, _) =
        g1viz::viz::model_extras(&rec, &g1viz::power::PowerModel::PAPER, &Default::default())
            .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("model.rrd");
    save_replay(&rec, &extras, &out, &session);
    let msgs = decode(&out);
    let c = contents(&msgs);
    let views = blueprint_views(&msgs);

    let error = view_named(&views, "Error measured − predicted");
    let largest = view_series(&c, error)
        .iter()
        .flat_map(|s| s.1.iter().map(|v| v.abs()))
        .fold(0.0, f64::max);
    assert!(largest > 0.0);
    let [lo, hi] = error.y_range.expect("the error plot's range");
    assert_eq!(lo, -hi, "symmetric about zero");
    assert!(
        hi >= 1.05 * largest && hi <= 5.1 * largest,
        "±{hi} for errors up to {largest}"
    );
    // The viewer labels ticks at powers of ten: ±10^k inside the range, at most 5 steps across.
    let step = 10f64.powf(hi.log10().floor());
    assert!(step < hi && hi / step <= 2.5, "±{hi}: ticks every {step}");

    // The trial track holds the trial indices with half a step spare and, widened as far as
    // the next labelled tick, shows at least two labels in its 40 px.
    let track = view_named(&views, "Trials (index");
    let indices: Vec<f64> = extras.trials.iter().map(|m| m.index as f64).collect();
    let first = indices.iter().copied().fold(f64::INFINITY, f64::min);
    let last = indices.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let [lo, hi] = track.y_range.expect("the trial track's range");
    assert!(lo <= first - 0.5 && hi >= last + 0.5, "{lo}..{hi}");
    let labels = viewer_labels([lo, hi], 40.0, 20.0);
    assert!(labels.len() >= 2, "{lo}..{hi}: {labels:?}");
    assert!(
        hi - lo <= (last - first + 1.0).max(10.0) + 1.0,
        "{lo}..{hi}: wider than a decade of trials"
    );
}
