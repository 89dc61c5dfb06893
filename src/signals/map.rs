//! Which topic and field each named arm signal comes from: the built-in G1 mapping and user
//! overrides from a small TOML file (`--signals FILE`).

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, bail};

use crate::N_JOINTS;
use crate::read::FieldPath;

/// Short joint names used in signal names (`q.sh_pitch`), in model order.
pub const JOINT_SHORT: [&str; N_JOINTS] = [
    "sh_pitch", "sh_roll", "sh_yaw", "elbow", "wr_roll", "wr_pitch", "wr_yaw",
];

/// URDF joint names of the G1 arms without the side prefix, in model order.
const JOINT_URDF: [&str; N_JOINTS] = [
    "shoulder_pitch_joint",
    "shoulder_roll_joint",
    "shoulder_yaw_joint",
    "elbow_joint",
    "wrist_roll_joint",
    "wrist_pitch_joint",
    "wrist_yaw_joint",
];

/// SDK motor index of the first left-arm joint (left shoulder pitch); the right arm starts at 22.
pub const G1_LEFT_ARM_BASE: usize = 15;
/// SDK motor index of the first right-arm joint.
pub const G1_RIGHT_ARM_BASE: usize = 22;

/// Where one named signal comes from.
#[derive(Debug, Clone, PartialEq)]
pub struct SignalSpec {
    /// Topic, e.g. `/lowstate`.
    pub topic: String,
    /// Field path inside the message, e.g. `motor_state[15].q`.
    pub field: FieldPath,
    /// Factor applied to the raw value (e.g. 1e-3 for mV → V).
    pub scale: f64,
}

/// The signal groups a [`crate::signals::Recording`] is filled from. All signals of one group
/// must come from one topic (they share a time axis).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Group {
    /// Joint states and IMU (required).
    State,
    /// Commanded references (optional).
    Command,
    /// Main-board power sensor: voltage × current (optional).
    Mbs,
    /// Battery power: voltage × current (optional).
    Bms,
}

/// Mapping from named signals to topics and fields, plus the URDF names of the 7 arm joints.
///
/// Signal names: `q.J`, `dq.J`, `tau.J`, `temp.J`, `cmd_q.J`, `cmd_dq.J` for J in [`JOINT_SHORT`];
/// `gyro.x|y|z`; `quat.w|x|y|z`; `bus.voltage` (the drives' supply); `mbs.voltage`, `mbs.current`, `bms.voltage`, `bms.current`
/// (power = voltage × current after scaling, in W).
#[derive(Debug, Clone, PartialEq)]
pub struct SignalMap {
    /// URDF joint names of the 7 arm joints, in model order.
    pub joint_names: Vec<String>,
    /// Every signal by name.
    pub signals: BTreeMap<String, SignalSpec>,
}

/// The signal names of each group in the order the loader reads them.
pub fn group_signals(group: Group) -> Vec<String> {
    let per_joint = |prefixes: &[&str]| -> Vec<String> {
        prefixes
            .iter()
            .flat_map(|p| JOINT_SHORT.iter().map(move |j| format!("{p}.{j}")))
            .collect()
    };
    match group {
        Group::State => {
            let mut v = per_joint(&["q", "dq", "tau", "temp"]);
            v.extend(
                [
                    "gyro.x",
                    "gyro.y",
                    "gyro.z",
                    "quat.w",
                    "quat.x",
                    "quat.y",
                    "quat.z",
                    "bus.voltage",
                ]
                .map(String::from),
            );
            v
        }
        Group::Command => per_joint(&["cmd_q", "cmd_dq"]),
        Group::Mbs => vec!["mbs.voltage".into(), "mbs.current".into()],
        Group::Bms => vec!["bms.voltage".into(), "bms.current".into()],
    }
}

/// All groups, required one first.
pub const GROUPS: [Group; 4] = [Group::State, Group::Command, Group::Mbs, Group::Bms];

fn spec(topic: &str, field: &str, scale: f64) -> SignalSpec {
    SignalSpec {
        topic: topic.into(),
        field: FieldPath::parse(field).unwrap_or(FieldPath {
            segments: Vec::new(),
        }),
        scale,
    }
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct TomlMap {
    arm: Option<String>,
    sdk_index_base: Option<usize>,
    joint_names: Option<Vec<String>>,
    #[serde(default)]
    signal: Vec<TomlSignal>,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct TomlSignal {
    name: String,
    topic: Option<String>,
    field: Option<String>,
    scale: Option<f64>,
}

/// Largest `sdk_index_base` a signal map accepts.
const MAX_SDK_INDEX_BASE: usize = 4096;

impl SignalMap {
    /// The G1 default for the left arm (SDK indices 15–21): `/lowstate` motor states and IMU,
    /// `/arm_sdk` commands, `/lf/mainboardstate` value[0]·value[1] W, `/lf/bmsstate`
    /// bmsvoltage[0] mV · current mA · 1e-6 W.
    pub fn g1_left_arm() -> SignalMap {
        Self::g1_arm("left", G1_LEFT_ARM_BASE)
    }

    /// G1 mapping with the arm's joints at SDK indices `base..base+7` and URDF names `side_*`.
    pub fn g1_arm(side: &str, base: usize) -> SignalMap {
        let mut signals = BTreeMap::new();
        // Signal, topic, the array of motors, the field of a motor.
        let per_joint = [
            ("q", "/lowstate", "motor_state", "q"),
            ("dq", "/lowstate", "motor_state", "dq"),
            ("tau", "/lowstate", "motor_state", "tau_est"),
            ("temp", "/lowstate", "motor_state", "temperature[0]"),
            ("cmd_q", "/arm_sdk", "motor_cmd", "q"),
            ("cmd_dq", "/arm_sdk", "motor_cmd", "dq"),
        ];
        for (i, j) in JOINT_SHORT.iter().enumerate() {
            let k = base + i;
            for (signal, topic, motors, field) in per_joint {
                let path = format!("{motors}[{k}].{field}");
                signals.insert(format!("{signal}.{j}"), spec(topic, &path, 1.0));
            }
        }
        let imu = [
            ("gyro", "gyroscope", &["x", "y", "z"][..]),
            ("quat", "quaternion", &["w", "x", "y", "z"][..]),
        ];
        for (signal, field, axes) in imu {
            for (i, axis) in axes.iter().enumerate() {
                let path = format!("imu_state.{field}[{i}]");
                signals.insert(format!("{signal}.{axis}"), spec("/lowstate", &path, 1.0));
            }
        }
        let bus = format!("motor_state[{base}].vol");
        for (signal, topic, path, scale) in [
            ("bus.voltage", "/lowstate", bus.as_str(), 1.0),
            ("mbs.voltage", "/lf/mainboardstate", "value[0]", 1.0),
            ("mbs.current", "/lf/mainboardstate", "value[1]", 1.0),
            ("bms.voltage", "/lf/bmsstate", "bmsvoltage[0]", 1e-3),
            ("bms.current", "/lf/bmsstate", "current", 1e-3),
        ] {
            signals.insert(signal.into(), spec(topic, path, scale));
        }
        let joint_names = JOINT_URDF.iter().map(|j| format!("{side}_{j}")).collect();
        SignalMap {
            joint_names,
            signals,
        }
    }

    /// Load overrides from a TOML file on top of the left-arm default:
    ///
    /// ```toml
    /// arm = "right"                 # optional: "left" (default) or "right" (SDK 22–28, right_* joints)
    /// # sdk_index_base = 22         # optional: other index conventions
    /// # joint_names = ["…", …]      # optional: 7 URDF joint names
    /// [[signal]]
    /// name = "tau.elbow"
    /// topic = "/lowstate"           # each of topic/field/scale is optional
    /// field = "motor_state[18].tau_est"
    /// scale = 1.0
    /// ```
    pub fn from_toml_file(path: &Path) -> anyhow::Result<SignalMap> {
        let text = crate::util::read_text_input(path)
            .with_context(|| format!("reading signal map {}", path.display()))?;
        Self::from_toml_str(&text).with_context(|| format!("signal map {}", path.display()))
    }

    /// [`SignalMap::from_toml_file`] on a string.
    pub fn from_toml_str(text: &str) -> anyhow::Result<SignalMap> {
        let t: TomlMap = toml::from_str(text)?;
        let side = t.arm.as_deref().unwrap_or("left");
        let default_base = match side {
            "left" => G1_LEFT_ARM_BASE,
            "right" => G1_RIGHT_ARM_BASE,
            other => bail!("arm = {other:?}: expected \"left\" or \"right\""),
        };
        let base = t.sdk_index_base.unwrap_or(default_base);
        // Whether the indices exist is checked against the message definition when a file is
        // read; this only keeps the arithmetic finite.
        if base > MAX_SDK_INDEX_BASE {
            bail!(
                "sdk_index_base = {base} is out of range (at most {MAX_SDK_INDEX_BASE}; the G1 has 35 motor slots)"
            );
        }
        let mut map = Self::g1_arm(side, base);
        if let Some(names) = t.joint_names {
            if names.len() != N_JOINTS {
                bail!(
                    "joint_names has {} names; the arm has {N_JOINTS} joints",
                    names.len()
                );
            }
            map.joint_names = names;
        }
        for s in t.signal {
            let Some(entry) = map.signals.get_mut(&s.name) else {
                let known: Vec<&str> = map.signals.keys().map(String::as_str).collect();
                bail!(
                    "unknown signal {:?}; known signals: {}",
                    s.name,
                    known.join(", ")
                );
            };
            if let Some(topic) = s.topic {
                entry.topic = topic;
            }
            if let Some(field) = s.field {
                entry.field =
                    FieldPath::parse(&field).with_context(|| format!("signal {}", s.name))?;
            }
            if let Some(scale) = s.scale {
                if !scale.is_finite() {
                    bail!("signal {}: scale must be a finite number", s.name);
                }
                entry.scale = scale;
            }
        }
        map.validate()?;
        Ok(map)
    }

    /// Check that every signal exists and that each group reads one topic.
    pub fn validate(&self) -> anyhow::Result<()> {
        for group in GROUPS {
            let names = group_signals(group);
            let mut topic: Option<&str> = None;
            for name in &names {
                let s = self
                    .signals
                    .get(name)
                    .with_context(|| format!("signal map lacks signal {name}"))?;
                if s.field.segments.is_empty() {
                    bail!("signal {name} has an empty field path");
                }
                match topic {
                    None => topic = Some(&s.topic),
                    Some(t) if t != s.topic => bail!(
                        "signal {name} reads topic {} but {} reads {t}: signals of one group ({group:?}) must share a topic",
                        s.topic,
                        names[0]
                    ),
                    Some(_) => {}
                }
            }
        }
        Ok(())
    }

    /// The topic a group reads (`None` if the map lacks the group's signals).
    pub fn group_topic(&self, group: Group) -> Option<&str> {
        group_signals(group)
            .first()
            .and_then(|n| self.signals.get(n))
            .map(|s| s.topic.as_str())
    }
}

impl Default for SignalMap {
    fn default() -> Self {
        Self::g1_left_arm()
    }
}
