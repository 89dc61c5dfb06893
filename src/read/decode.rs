//! Generic, schema-driven message decoding for CDR (ROS 2), ROS 1 serialisation and JSON.
//!
//! Two ways in: [`decode`] builds a full [`Value`] tree (for `info`, tests and odd topics);
//! [`FieldExtractor`] compiles a list of field paths once per channel and pulls just those
//! numbers out of each payload, which is what the signal pipeline uses on the hot path.
//!
//! CONTRACT (owned by the reader work): the types and signatures below are used by the other
//! stages; their bodies are to be implemented.

use super::{Encoding, MsgSchema};

/// A decoded value.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// bool
    Bool(bool),
    /// Any signed integer.
    Int(i64),
    /// Any unsigned integer.
    UInt(u64),
    /// float32/float64.
    Float(f64),
    /// string.
    String(String),
    /// Fixed array or sequence.
    Array(Vec<Value>),
    /// Nested message: fields in order.
    Struct(Vec<(String, Value)>),
}

/// A path to a numeric field, e.g. `motor_state[17].tau_est` or `bmsvoltage[0]`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FieldPath {
    /// Path segments: field name with an optional index.
    pub segments: Vec<(String, Option<usize>)>,
}

/// Decoding failed; names the field and the byte position inside the payload.
#[derive(Debug, Clone, thiserror::Error)]
pub enum DecodeError {
    /// The payload ended before the field.
    #[error("payload too short: field {field} needs bytes up to {needed}, payload has {len}")]
    Truncated {
        /// Field path being decoded.
        field: String,
        /// Bytes needed.
        needed: usize,
        /// Payload length.
        len: usize,
    },
    /// A field path does not exist in the schema.
    #[error("no field {path} in {type_name}")]
    NoSuchField {
        /// Requested path.
        path: String,
        /// Root type.
        type_name: String,
    },
    /// Anything else wrong with the payload (bad header, bad length, bad UTF-8, bad JSON).
    #[error("{0}")]
    Invalid(String),
}

/// Compiled extraction of several numeric fields from payloads of one channel.
#[derive(Debug, Clone)]
pub struct FieldExtractor {
    _private: (),
}

/// Decode a whole payload into a [`Value`] tree.
pub fn decode(
    _schema: &MsgSchema,
    _encoding: Encoding,
    _data: &[u8],
) -> Result<Value, DecodeError> {
    Err(DecodeError::Invalid("decoder not implemented yet".into()))
}
