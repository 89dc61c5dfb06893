//! Message definitions: ROS 2 `.msg` text (with the concatenated `MSG:` dependency sections
//! MCAP and rosbag2 embed), ROS 1 `.msg` text, and OMG IDL (`ros2idl`), parsed into one
//! [`MsgSchema`] type registry that the decoders walk.
//!
//! CONTRACT (owned by the reader work): the types and constructor signatures below are
//! used by the other readers; their bodies are to be implemented.

use std::collections::HashMap;

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
