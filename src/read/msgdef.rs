//! Message definitions: ROS 2 `.msg` text (with the concatenated `MSG:` dependency sections
//! MCAP and rosbag2 embed), ROS 1 `.msg` text, and OMG IDL (`ros2idl`), parsed into one
//! [`MsgSchema`] type registry that the decoders walk. The IDL parser lives in `idl.rs`.

use std::collections::HashMap;
use std::path::PathBuf;

/// A primitive field type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Primitive {
    /// bool
    Bool,
    /// int8 (and ROS 1 `byte`)
    I8,
    /// uint8 (and `char`)
    U8,
    /// int16
    I16,
    /// uint16
    U16,
    /// int32
    I32,
    /// uint32
    U32,
    /// int64
    I64,
    /// uint64
    U64,
    /// float32
    F32,
    /// float64
    F64,
    /// string (UTF-8, length-prefixed)
    String,
    /// ROS 1 `time` (u32 sec, u32 nsec)
    Time,
    /// ROS 1 `duration` (i32 sec, i32 nsec)
    Duration,
}

/// The element type of a field.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FieldType {
    /// A primitive.
    Primitive(Primitive),
    /// A nested message, by fully qualified name as registered in [`MsgSchema::types`].
    Message(String),
}

/// Array-ness of a field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArrayKind {
    /// A single value.
    Single,
    /// `T[N]`: exactly N elements, no length prefix.
    Fixed(usize),
    /// `T[]` or `sequence<T>`: length-prefixed.
    Unbounded,
    /// `T[<=N]`: length-prefixed, at most N.
    Bounded(usize),
}

/// One field of a message type.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Field {
    /// Field name.
    pub name: String,
    /// Element type.
    pub ty: FieldType,
    /// Array-ness.
    pub array: ArrayKind,
}

/// One message type: its ordered fields (constants are not serialised and not listed).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MsgType {
    /// Fully qualified name, e.g. `unitree_hg/msg/MotorState`.
    pub name: String,
    /// Serialised fields in order.
    pub fields: Vec<Field>,
}

/// A root type plus every type it depends on.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MsgSchema {
    /// Fully qualified name of the root type.
    pub root: String,
    /// All types by fully qualified name.
    pub types: HashMap<String, MsgType>,
}

/// A message definition could not be parsed or resolved.
#[derive(Debug, Clone, thiserror::Error)]
pub enum SchemaError {
    /// Syntax error in the definition text.
    #[error("definition of {type_name}, line {line}: {what}")]
    Syntax {
        /// Type whose text is bad.
        type_name: String,
        /// 1-based line in the (concatenated) text.
        line: usize,
        /// What is wrong.
        what: String,
    },
    /// A referenced type has no definition anywhere.
    #[error(
        "no definition for message type {0}; pass a folder holding its .msg file with --msg-path DIR"
    )]
    MissingType(String),
    /// Unsupported schema encoding.
    #[error("unsupported schema encoding {0:?} (supported: ros2msg, ros2idl, ros1msg)")]
    UnsupportedEncoding(String),
}

/// Built-in ROS 2 definitions of the standard types the tool needs and of the Unitree G1
/// (`unitree_hg`) messages, so files and bags that do not carry definitions still decode.
const BUILTIN_DEFINITIONS: &[(&str, &str)] = &[
    ("builtin_interfaces/msg/Time", "int32 sec\nuint32 nanosec\n"),
    (
        "builtin_interfaces/msg/Duration",
        "int32 sec\nuint32 nanosec\n",
    ),
    (
        "std_msgs/msg/Header",
        "builtin_interfaces/Time stamp\nstring frame_id\n",
    ),
    (
        "unitree_hg/msg/BmsCmd",
        include_str!("msg/unitree_hg/BmsCmd.msg"),
    ),
    (
        "unitree_hg/msg/BmsState",
        include_str!("msg/unitree_hg/BmsState.msg"),
    ),
    (
        "unitree_hg/msg/HandCmd",
        include_str!("msg/unitree_hg/HandCmd.msg"),
    ),
    (
        "unitree_hg/msg/HandState",
        include_str!("msg/unitree_hg/HandState.msg"),
    ),
    (
        "unitree_hg/msg/IMUState",
        include_str!("msg/unitree_hg/IMUState.msg"),
    ),
    (
        "unitree_hg/msg/LowCmd",
        include_str!("msg/unitree_hg/LowCmd.msg"),
    ),
    (
        "unitree_hg/msg/LowState",
        include_str!("msg/unitree_hg/LowState.msg"),
    ),
    (
        "unitree_hg/msg/MainBoardState",
        include_str!("msg/unitree_hg/MainBoardState.msg"),
    ),
    (
        "unitree_hg/msg/MotorCmd",
        include_str!("msg/unitree_hg/MotorCmd.msg"),
    ),
    (
        "unitree_hg/msg/MotorState",
        include_str!("msg/unitree_hg/MotorState.msg"),
    ),
    (
        "unitree_hg/msg/PressSensorState",
        include_str!("msg/unitree_hg/PressSensorState.msg"),
    ),
];

/// Deepest nesting of message types accepted (real definitions stay below 10 levels).
pub const MAX_NESTING: usize = 64;

/// Largest fixed array size or sequence bound accepted (CDR and ROS 1 lengths are 32-bit).
pub const MAX_ARRAY_LEN: usize = u32::MAX as usize;

/// ROS 1's `std_msgs/Header` (differs from ROS 2's: a sequence number and a `time` stamp).
const ROS1_HEADER: &str = "uint32 seq\ntime stamp\nstring frame_id\n";

/// The built-in ROS 2 `.msg` text of a type (`pkg/Type` or `pkg/msg/Type`): the unitree_hg
/// messages and `builtin_interfaces/Time`, `builtin_interfaces/Duration`, `std_msgs/Header`.
pub fn builtin_definition(type_name: &str) -> Option<&'static str> {
    let name = normalize_type_name(type_name, "");
    BUILTIN_DEFINITIONS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, text)| *text)
}

/// Normalise a type name to `pkg/msg/Type`: accepts `pkg/Type`, `pkg/msg/Type`, `pkg::msg::Type`
/// and, with a non-empty `default_pkg`, an unqualified `Type`.
pub fn normalize_type_name(name: &str, default_pkg: &str) -> String {
    let name = name.trim().replace("::", "/");
    let parts: Vec<&str> = name.split('/').filter(|p| !p.is_empty()).collect();
    match parts.as_slice() {
        [ty] if !default_pkg.is_empty() => format!("{default_pkg}/msg/{ty}"),
        [pkg, ty] => format!("{pkg}/msg/{ty}"),
        [pkg, _, ty] => format!("{pkg}/msg/{ty}"),
        _ => name,
    }
}

/// Package part of a normalised or `pkg/Type` name (empty when unqualified).
fn package_of(name: &str) -> &str {
    match name.split_once('/') {
        Some((pkg, _)) => pkg,
        None => "",
    }
}

/// Which `.msg` dialect a text is written in.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum Dialect {
    Ros1,
    Ros2,
}

impl MsgSchema {
    /// Parse a schema given its encoding name as MCAP spells it (`ros2msg`, `ros2idl`, `ros1msg`).
    pub fn parse(encoding: &str, type_name: &str, text: &str) -> Result<MsgSchema, SchemaError> {
        match encoding {
            "ros2msg" => Self::parse_ros2msg(type_name, text),
            "ros2idl" => Self::parse_idl(type_name, text),
            "ros1msg" => Self::parse_ros1msg(type_name, text),
            other => Err(SchemaError::UnsupportedEncoding(other.to_string())),
        }
    }

    /// Parse ROS 2 `.msg` text, including the concatenated dependency sections
    /// (`=====` line, then `MSG: pkg/Type`) that MCAP and rosbag2 embed. Types still missing
    /// afterwards are taken from [`builtin_definition`].
    pub fn parse_ros2msg(type_name: &str, text: &str) -> Result<MsgSchema, SchemaError> {
        Self::parse_msg(type_name, text, Dialect::Ros2)
    }

    /// Parse ROS 1 `.msg` text (concatenated `MSG:` sections as in bag connection records;
    /// `time`, `duration`, `byte`, `char`, `Header` → `std_msgs/Header`).
    pub fn parse_ros1msg(type_name: &str, text: &str) -> Result<MsgSchema, SchemaError> {
        Self::parse_msg(type_name, text, Dialect::Ros1)
    }

    /// Load `type_name` and its dependencies from `.msg` files under `search_dirs`
    /// (`DIR/<pkg>/msg/<Type>.msg` or `DIR/<pkg>/<Type>.msg`), falling back to the built-in
    /// definitions.
    pub fn from_msg_files(
        type_name: &str,
        search_dirs: &[PathBuf],
    ) -> Result<MsgSchema, SchemaError> {
        let root = normalize_type_name(type_name, "");
        let ty = definition(&root, Dialect::Ros2, search_dirs)?;
        let mut schema = MsgSchema {
            root: root.clone(),
            types: HashMap::from([(root, ty)]),
        };
        schema.resolve_missing(Dialect::Ros2, search_dirs)?;
        Ok(schema)
    }

    /// The root type's definition.
    pub fn root_type(&self) -> Result<&MsgType, SchemaError> {
        self.get(&self.root)
    }

    /// A type's definition by fully qualified name.
    pub fn get(&self, name: &str) -> Result<&MsgType, SchemaError> {
        self.types
            .get(name)
            .ok_or_else(|| SchemaError::MissingType(name.to_string()))
    }

    fn parse_msg(type_name: &str, text: &str, dialect: Dialect) -> Result<MsgSchema, SchemaError> {
        let root = normalize_type_name(type_name, "");
        let mut types = HashMap::new();
        let mut current = root.clone();
        let mut section = String::new();
        let mut section_line = 0;
        for (i, line) in text.lines().enumerate() {
            let trimmed = line.trim();
            if trimmed.len() >= 3 && trimmed.chars().all(|c| c == '=') {
                let ty = parse_msg_section(&current, &section, section_line, dialect)?;
                types.insert(current.clone(), ty);
                section.clear();
                current = String::new();
                section_line = i + 1;
                continue;
            }
            if let Some(name) = trimmed.strip_prefix("MSG:") {
                current = normalize_type_name(name, package_of(&root));
                section_line = i + 1;
                continue;
            }
            section.push_str(line);
            section.push('\n');
        }
        if current.is_empty() {
            return Err(SchemaError::Syntax {
                type_name: root,
                line: section_line,
                what: "dependency section without a `MSG: pkg/Type` line".into(),
            });
        }
        let ty = parse_msg_section(&current, &section, section_line, dialect)?;
        types.insert(current, ty);
        let mut schema = MsgSchema { root, types };
        schema.resolve_missing(dialect, &[])?;
        Ok(schema)
    }

    /// Add the definitions of referenced types the schema does not carry (from `.msg` files
    /// under `dirs`, else built in); fail on the rest.
    pub(super) fn resolve_missing(
        &mut self,
        dialect: Dialect,
        dirs: &[PathBuf],
    ) -> Result<(), SchemaError> {
        if !self.types.contains_key(&self.root) {
            return Err(SchemaError::MissingType(self.root.clone()));
        }
        loop {
            let missing =
                (self.types.values().flat_map(|t| t.fields.iter())).find_map(|f| match &f.ty {
                    FieldType::Message(n) if !self.types.contains_key(n) => Some(n.clone()),
                    _ => None,
                });
            let Some(name) = missing else {
                return self.check_acyclic();
            };
            let ty = definition(&name, dialect, dirs)?;
            self.types.insert(name, ty);
        }
    }

    /// A message type that contains itself (directly or through others) has no finite layout;
    /// decoding it would recurse without end. Types nested deeper than [`MAX_NESTING`] are
    /// refused too: the decoders recurse once per level.
    fn check_acyclic(&self) -> Result<(), SchemaError> {
        let mut names: Vec<&String> = self.types.keys().collect();
        names.sort();
        let mut depth = HashMap::new();
        for name in names {
            self.nesting(name, &mut Vec::new(), &mut depth)?;
        }
        Ok(())
    }

    /// Nesting depth of type `name` (1 = only primitives) inside the types on `path`, memoised in
    /// `depth`. The recursion stops at [`MAX_NESTING`] levels, so a hostile schema cannot
    /// overflow the stack.
    fn nesting<'a>(
        &'a self,
        name: &'a str,
        path: &mut Vec<&'a str>,
        depth: &mut HashMap<&'a str, usize>,
    ) -> Result<usize, SchemaError> {
        if let Some(&d) = depth.get(name) {
            return Ok(d);
        }
        let refuse = |what: String| SchemaError::Syntax {
            type_name: name.to_string(),
            line: 0,
            what,
        };
        if let Some(from) = path.iter().position(|n| *n == name) {
            let chain = path[from..].join(" → ");
            let what = format!("the message contains itself ({chain} → {name}): no finite layout");
            return Err(refuse(what));
        }
        if path.len() >= MAX_NESTING {
            let what = format!("message types nested more than {MAX_NESTING} levels deep");
            return Err(refuse(what));
        }
        path.push(name);
        let mut d = 1;
        for f in self.types.get(name).map_or(&[][..], |t| &t.fields[..]) {
            if let FieldType::Message(child) = &f.ty {
                d = d.max(1 + self.nesting(child, path, depth)?);
            }
        }
        path.pop();
        depth.insert(name, d);
        Ok(d)
    }
}

/// The definition of type `name` (normalised) from its `.msg` file under `dirs`, else built in
/// (ROS 1's own `Header` in that dialect).
fn definition(name: &str, dialect: Dialect, dirs: &[PathBuf]) -> Result<MsgType, SchemaError> {
    let text = if dialect == Dialect::Ros1 && name == "std_msgs/msg/Header" {
        Some(ROS1_HEADER.to_string())
    } else {
        find_msg_file(name, dirs).or_else(|| builtin_definition(name).map(str::to_string))
    };
    let text = text.ok_or_else(|| SchemaError::MissingType(name.to_string()))?;
    parse_msg_section(name, &text, 0, dialect)
}

fn find_msg_file(name: &str, dirs: &[PathBuf]) -> Option<String> {
    let mut parts = name.split('/');
    let (pkg, ty) = (parts.next()?, parts.next_back()?);
    dirs.iter()
        .flat_map(|d| {
            [
                d.join(pkg).join("msg").join(format!("{ty}.msg")),
                d.join(pkg).join(format!("{ty}.msg")),
            ]
        })
        .find_map(|p| std::fs::read_to_string(p).ok())
}

/// Parse one type's `.msg` lines (no section separators). `first_line` is the 0-based line
/// of the section in the whole text, for error messages.
fn parse_msg_section(
    type_name: &str,
    text: &str,
    first_line: usize,
    dialect: Dialect,
) -> Result<MsgType, SchemaError> {
    let pkg = package_of(type_name).to_string();
    let mut fields = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let err = |what: String| SchemaError::Syntax {
            type_name: type_name.to_string(),
            line: first_line + i + 1,
            what,
        };
        let (ty_tok, rest) = line
            .split_once(char::is_whitespace)
            .ok_or_else(|| err(format!("expected `TYPE NAME`, found {line:?}")))?;
        let rest = rest.trim_start();
        let name_end = rest
            .find(|c: char| c.is_whitespace() || c == '=')
            .unwrap_or(rest.len());
        let name = &rest[..name_end];
        if name.is_empty() {
            return Err(err(format!("field without a name: {line:?}")));
        }
        if rest[name_end..].trim_start().starts_with('=') {
            continue; // a constant: not serialised
        }
        let (base, array) = split_array(ty_tok).map_err(&err)?;
        let ty = field_type(base, &pkg, dialect).map_err(&err)?;
        fields.push(Field {
            name: name.to_string(),
            ty,
            array,
        });
    }
    Ok(MsgType {
        name: type_name.to_string(),
        fields,
    })
}

/// Split `T[]`, `T[N]`, `T[<=N]` into the element type and the array kind.
fn split_array(tok: &str) -> Result<(&str, ArrayKind), String> {
    let Some(open) = tok.find('[') else {
        return Ok((tok, ArrayKind::Single));
    };
    let inner = tok[open + 1..]
        .strip_suffix(']')
        .ok_or_else(|| format!("unterminated array bracket in {tok:?}"))?;
    let parse_n = |s: &str| {
        s.trim()
            .parse::<usize>()
            .ok()
            .filter(|n| *n <= MAX_ARRAY_LEN)
            .ok_or_else(|| format!("bad array size in {tok:?} (at most {MAX_ARRAY_LEN})"))
    };
    let kind = if inner.trim().is_empty() {
        ArrayKind::Unbounded
    } else if let Some(n) = inner.trim().strip_prefix("<=") {
        ArrayKind::Bounded(parse_n(n)?)
    } else {
        ArrayKind::Fixed(parse_n(inner)?)
    };
    Ok((&tok[..open], kind))
}

/// Resolve a `.msg` element type name.
fn field_type(base: &str, pkg: &str, dialect: Dialect) -> Result<FieldType, String> {
    let base = match base.split_once("<=") {
        Some((b, _)) => b, // bounded string `string<=N`
        None => base,
    };
    let prim = match base {
        "bool" => Primitive::Bool,
        "int8" => Primitive::I8,
        "uint8" => Primitive::U8,
        "byte" if dialect == Dialect::Ros1 => Primitive::I8,
        "byte" | "char" => Primitive::U8,
        "int16" => Primitive::I16,
        "uint16" => Primitive::U16,
        "int32" => Primitive::I32,
        "uint32" => Primitive::U32,
        "int64" => Primitive::I64,
        "uint64" => Primitive::U64,
        "float32" => Primitive::F32,
        "float64" => Primitive::F64,
        "string" => Primitive::String,
        "time" if dialect == Dialect::Ros1 => Primitive::Time,
        "duration" if dialect == Dialect::Ros1 => Primitive::Duration,
        "wstring" => return Err("wstring fields are not supported".into()),
        "Header" if dialect == Dialect::Ros1 => {
            return Ok(FieldType::Message("std_msgs/msg/Header".into()));
        }
        other => {
            if other.is_empty()
                || !other
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '/')
            {
                return Err(format!("bad type name {other:?}"));
            }
            return Ok(FieldType::Message(normalize_type_name(other, pkg)));
        }
    };
    Ok(FieldType::Primitive(prim))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field<'a>(s: &'a MsgSchema, ty: &str, name: &str) -> &'a Field {
        s.types[ty].fields.iter().find(|f| f.name == name).unwrap()
    }

    #[test]
    fn ros2msg_constants_defaults_bounds_and_sections() {
        let text = "# header comment\nint32 MODE_A=1\nstring NAME = \"x # y\"\nint32 a 5 # default\n\
                    string<=10 s\nfloat64[<=3] b\nuint8[] c\nPoint[2] p\nbuiltin_interfaces/Time t\n\
                    ================================================================================\n\
                    MSG: my_pkg/Point\nfloat32 x\nfloat32 y\n";
        let s = MsgSchema::parse_ros2msg("my_pkg/msg/Thing", text).unwrap();
        assert_eq!(s.root, "my_pkg/msg/Thing");
        let names: Vec<&str> = s.types["my_pkg/msg/Thing"]
            .fields
            .iter()
            .map(|f| f.name.as_str())
            .collect();
        assert_eq!(names, ["a", "s", "b", "c", "p", "t"]);
        assert_eq!(
            field(&s, "my_pkg/msg/Thing", "s").ty,
            FieldType::Primitive(Primitive::String)
        );
        assert_eq!(
            field(&s, "my_pkg/msg/Thing", "b").array,
            ArrayKind::Bounded(3)
        );
        assert_eq!(
            field(&s, "my_pkg/msg/Thing", "c").array,
            ArrayKind::Unbounded
        );
        let p = field(&s, "my_pkg/msg/Thing", "p");
        assert_eq!(
            (p.ty.clone(), p.array),
            (
                FieldType::Message("my_pkg/msg/Point".into()),
                ArrayKind::Fixed(2)
            )
        );
        // builtin_interfaces/Time came from the built-in definitions.
        assert_eq!(s.types["builtin_interfaces/msg/Time"].fields.len(), 2);
    }

    #[test]
    fn ros1msg_header_time_byte_char() {
        let text = "Header header\ntime stamp\nduration d\nbyte b\nchar c\n";
        let s = MsgSchema::parse_ros1msg("pkg/T", text).unwrap();
        let t = &s.types["pkg/msg/T"];
        assert_eq!(
            t.fields[0].ty,
            FieldType::Message("std_msgs/msg/Header".into())
        );
        assert_eq!(t.fields[1].ty, FieldType::Primitive(Primitive::Time));
        assert_eq!(t.fields[2].ty, FieldType::Primitive(Primitive::Duration));
        assert_eq!(t.fields[3].ty, FieldType::Primitive(Primitive::I8));
        assert_eq!(t.fields[4].ty, FieldType::Primitive(Primitive::U8));
        // ROS 1 header: seq, time stamp, frame_id.
        assert_eq!(
            s.types["std_msgs/msg/Header"].fields[1].ty,
            FieldType::Primitive(Primitive::Time)
        );
    }

    #[test]
    fn recursive_definitions_are_refused() {
        let direct = "uint32 x\nNode[2] children\n================\nMSG: pkg/Node\nuint32 y\nNode[2] children\n";
        let err = MsgSchema::parse_ros2msg("pkg/msg/Root", direct).unwrap_err();
        assert!(err.to_string().contains("contains itself"), "{err}");
        let mutual = "pkg/A a\n================\nMSG: pkg/A\npkg/B b\n================\nMSG: pkg/B\npkg/A[] a\n";
        let err = MsgSchema::parse_ros2msg("pkg/msg/Root", mutual).unwrap_err();
        assert!(
            err.to_string()
                .contains("pkg/msg/A → pkg/msg/B → pkg/msg/A"),
            "{err}"
        );
        // A type used twice side by side is not a cycle.
        let diamond = "pkg/A a1\npkg/A a2\n================\nMSG: pkg/A\nuint8 v\n";
        MsgSchema::parse_ros2msg("pkg/msg/Root", diamond).unwrap();
    }

    #[test]
    fn missing_dependency_is_reported() {
        let err = MsgSchema::parse_ros2msg("a/B", "Unknown x\n").unwrap_err();
        assert!(
            err.to_string().contains("a/msg/Unknown") && err.to_string().contains("--msg-path"),
            "{err}"
        );
        let err = MsgSchema::parse_ros2msg("a/B", "int32[x y\n").unwrap_err();
        assert!(matches!(err, SchemaError::Syntax { line: 1, .. }), "{err}");
    }

    #[test]
    fn builtin_unitree_definitions_and_msg_files() {
        assert!(
            builtin_definition("unitree_hg/LowState")
                .unwrap()
                .contains("MotorState[35] motor_state")
        );
        assert!(builtin_definition("unitree_hg/msg/BmsState").is_some());
        let s = MsgSchema::from_msg_files("unitree_hg/msg/LowState", &[]).unwrap();
        assert_eq!(s.types.len(), 3); // LowState, IMUState, MotorState
        let dir = std::env::temp_dir().join(format!("g1viz_msgdef_{}", std::process::id()));
        std::fs::create_dir_all(dir.join("q/msg")).unwrap();
        std::fs::write(dir.join("q/msg/A.msg"), "B b\nint8 z\n").unwrap();
        std::fs::write(dir.join("q/msg/B.msg"), "float32 w\n").unwrap();
        let s = MsgSchema::from_msg_files("q/A", std::slice::from_ref(&dir)).unwrap();
        assert_eq!(s.types["q/msg/B"].fields[0].name, "w");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
