//! Generic, schema-driven message decoding for CDR (ROS 2), ROS 1 serialisation and JSON.
//!
//! Two ways in: [`decode`] builds a full [`Value`] tree (for `info`, tests and odd topics);
//! [`FieldExtractor`] compiles a list of field paths once per channel and pulls just those
//! numbers out of each payload, which is what the signal pipeline uses on the hot path.

use super::msgdef::{ArrayKind, Field, FieldType, Primitive};
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
///
/// Paths whose position does not depend on the payload (every field before them has a fixed
/// size, as in all unitree_hg types) become constant byte offsets; the others are found by
/// walking the payload. [`FieldExtractor::extract`] checks the payload length once.
#[derive(Debug, Clone)]
pub struct FieldExtractor {
    encoding: Encoding,
    leaves: Vec<Leaf>,
    /// Path texts, for error messages.
    names: Vec<String>,
    /// Smallest payload length that holds every constant-offset field.
    min_len: usize,
    /// Needed by walked paths only.
    schema: Option<MsgSchema>,
    /// For types without strings or sequences: the payload lengths that can be a message of
    /// the type (its size, plus CDR end padding). Any other length means the definition does
    /// not match the payload, which would otherwise decode as plausible garbage.
    fixed_len: Option<(usize, usize)>,
    /// Root type name, for messages.
    root: String,
    /// The `float32` leaves at constant offsets as (offset, output slot), and the other leaves'
    /// indices: a little-endian payload reads the first without a per-leaf dispatch (the bulk of
    /// every unitree_hg message).
    f32_leaves: Vec<(usize, usize)>,
    other_leaves: Vec<usize>,
}

#[derive(Debug, Clone)]
enum Leaf {
    /// Constant byte offset from the start of the payload (including any CDR header).
    Offset(usize, Primitive),
    /// Walk the payload: (field index, optional element index) per segment.
    Walk(Vec<Step>, Primitive),
    /// JSON: look the path up by name.
    Json(FieldPath),
}

#[derive(Debug, Clone)]
struct Step {
    type_name: String,
    field: usize,
    index: Option<usize>,
}

/// Serialisation rules for the binary encodings.
#[derive(Debug, Clone, Copy)]
enum Rules {
    /// CDR: primitives aligned to their size relative to the start of the body; `le` = little endian.
    Cdr { le: bool },
    /// ROS 1: packed little endian.
    Ros1,
}

impl Rules {
    fn align(self, pos: usize, prim: Primitive) -> usize {
        match self {
            Rules::Ros1 => pos,
            Rules::Cdr { .. } => {
                let a = alignment(prim);
                pos.div_ceil(a) * a
            }
        }
    }
    fn little_endian(self) -> bool {
        match self {
            Rules::Ros1 => true,
            Rules::Cdr { le } => le,
        }
    }
    /// Bytes before the body (the CDR encapsulation header).
    fn header_len(self) -> usize {
        match self {
            Rules::Ros1 => 0,
            Rules::Cdr { .. } => 4,
        }
    }
}

/// CDR alignment of a primitive (and of length prefixes: 4).
fn alignment(prim: Primitive) -> usize {
    match prim {
        Primitive::Bool | Primitive::I8 | Primitive::U8 => 1,
        Primitive::I16 | Primitive::U16 => 2,
        Primitive::I32 | Primitive::U32 | Primitive::F32 | Primitive::String => 4,
        Primitive::Time | Primitive::Duration => 4,
        Primitive::I64 | Primitive::U64 | Primitive::F64 => 8,
    }
}

/// Size of a fixed-size primitive (`None` for strings).
fn prim_size(prim: Primitive) -> Option<usize> {
    match prim {
        Primitive::String => None,
        Primitive::Time | Primitive::Duration => Some(8),
        p => Some(alignment(p)),
    }
}

/// Check the CDR encapsulation header and return the body's byte order.
fn cdr_rules(data: &[u8]) -> Result<Rules, DecodeError> {
    match data.get(..4) {
        None => Err(DecodeError::Truncated { field: "CDR header".into(), needed: 4, len: data.len() }),
        Some([0, 0, _, _]) => Ok(Rules::Cdr { le: false }),
        Some([0, 1, _, _]) => Ok(Rules::Cdr { le: true }),
        Some([0, 2 | 3, _, _]) => Err(DecodeError::Invalid(
            "parameter-list CDR (PL_CDR encapsulation 0x0002/0x0003) is not supported; record with plain CDR".into(),
        )),
        Some(h) => Err(DecodeError::Invalid(format!(
            "unsupported CDR encapsulation 0x{:02x}{:02x} (supported: 0x0000/0x0001 plain CDR)",
            h.first().copied().unwrap_or(0),
            h.get(1).copied().unwrap_or(0)
        ))),
    }
}

fn rules_for(encoding: Encoding, data: &[u8]) -> Result<Rules, DecodeError> {
    match encoding {
        Encoding::Cdr => cdr_rules(data),
        Encoding::Ros1 => Ok(Rules::Ros1),
        Encoding::Json => Err(DecodeError::Invalid(
            "JSON payloads have no binary layout".into(),
        )),
    }
}

/// Largest message layout computed (1 TiB): far beyond any real message, far below overflow.
const MAX_LAYOUT_BYTES: usize = 1 << 40;

fn too_large(what: &dyn Fn() -> String) -> DecodeError {
    DecodeError::Invalid(format!(
        "{}: the message layout exceeds {MAX_LAYOUT_BYTES} bytes",
        what()
    ))
}

/// Where bytes come from while walking: nowhere (layout only, fails on variable sizes) or a payload.
#[derive(Clone, Copy)]
enum Src<'a> {
    Layout,
    Payload(&'a [u8]),
}

/// Reads with bounds checks; positions are absolute in the payload, alignment relative to `base`.
struct Walker<'s, 'a> {
    schema: &'s MsgSchema,
    rules: Rules,
    base: usize,
    src: Src<'a>,
}

impl<'s, 'a> Walker<'s, 'a> {
    /// A walker over `src` under `rules` (payload offsets start after the rules' header).
    fn new(schema: &'s MsgSchema, rules: Rules, src: Src<'a>) -> Self {
        let base = rules.header_len();
        Walker {
            schema,
            rules,
            base,
            src,
        }
    }

    fn align(&self, pos: usize, prim: Primitive) -> usize {
        self.base + self.rules.align(pos - self.base, prim)
    }

    fn bytes<const N: usize>(
        &self,
        pos: usize,
        what: &dyn Fn() -> String,
    ) -> Result<[u8; N], DecodeError> {
        let Src::Payload(data) = self.src else {
            return Err(DecodeError::Invalid("layout walk reads no bytes".into()));
        };
        data.get(pos..pos + N)
            .and_then(|b| b.try_into().ok())
            .ok_or_else(|| DecodeError::Truncated {
                field: what(),
                needed: pos + N,
                len: data.len(),
            })
    }

    fn u32_at(&self, pos: usize, what: &dyn Fn() -> String) -> Result<u32, DecodeError> {
        let b = self.bytes::<4>(pos, what)?;
        Ok(if self.rules.little_endian() {
            u32::from_le_bytes(b)
        } else {
            u32::from_be_bytes(b)
        })
    }

    /// Read a length prefix at `pos` (aligned); returns (length, position after it), or `None` in layout mode.
    fn length(
        &self,
        pos: usize,
        what: &dyn Fn() -> String,
    ) -> Result<Option<(usize, usize)>, DecodeError> {
        if let Src::Layout = self.src {
            return Ok(None);
        }
        let pos = self.align(pos, Primitive::U32);
        let n = self.u32_at(pos, what)? as usize;
        Ok(Some((n, pos + 4)))
    }

    /// Position after `count` elements of `ty` starting at `pos`; `None` when the size is not
    /// known without the payload (layout mode only).
    fn skip_elements(
        &self,
        ty: &FieldType,
        count: usize,
        pos: usize,
        what: &dyn Fn() -> String,
    ) -> Result<Option<usize>, DecodeError> {
        if count == 0 {
            return Ok(Some(pos));
        }
        match ty {
            FieldType::Primitive(Primitive::String) => {
                let mut p = pos;
                for _ in 0..count {
                    let Some((n, after)) = self.length(p, what)? else {
                        return Ok(None);
                    };
                    p = after.checked_add(n).ok_or_else(|| {
                        DecodeError::Invalid(format!("{}: bad string length {n}", what()))
                    })?;
                }
                self.check_within(p, what)?;
                Ok(Some(p))
            }
            FieldType::Primitive(prim) => {
                let size = prim_size(*prim).unwrap_or(1);
                let end = count
                    .checked_mul(size)
                    .and_then(|b| self.align(pos, *prim).checked_add(b))
                    .ok_or_else(|| {
                        DecodeError::Invalid(format!("{}: bad array length {count}", what()))
                    })?;
                self.check_within(end, what)?;
                Ok(Some(end))
            }
            FieldType::Message(name) => self.skip_messages(name, count, pos, what),
        }
    }

    /// Position after `count` nested messages of type `name` from `pos`. In layout mode the
    /// size of an element depends only on its start position modulo the largest alignment (8),
    /// so the walk stops at the first repeated phase and jumps the remaining whole cycles
    /// arithmetically: a huge fixed array costs at most 9 element walks, not one per element.
    fn skip_messages(
        &self,
        name: &str,
        count: usize,
        pos: usize,
        what: &dyn Fn() -> String,
    ) -> Result<Option<usize>, DecodeError> {
        let msg = self
            .schema
            .get(name)
            .map_err(|e| DecodeError::Invalid(e.to_string()))?;
        let layout = matches!(self.src, Src::Layout);
        let mut seen: [Option<(usize, usize)>; 8] = [None; 8];
        let (mut k, mut p) = (0usize, pos);
        while k < count {
            if layout {
                let phase = (p - self.base) % 8;
                if let Some((k0, p0)) = seen[phase] {
                    let cycles = (count - k) / (k - k0);
                    p = (p - p0)
                        .checked_mul(cycles)
                        .and_then(|a| p.checked_add(a))
                        .ok_or_else(|| too_large(what))?;
                    self.check_within(p, what)?;
                    k += cycles * (k - k0);
                    seen = [None; 8];
                    if k >= count {
                        break;
                    }
                }
                seen[(p - self.base) % 8] = Some((k, p));
            }
            let before = p;
            for f in &msg.fields {
                match self.skip_field(f, p, what)? {
                    Some(next) => p = next,
                    None => return Ok(None),
                }
            }
            self.check_within(p, what)?;
            k += 1;
            if p == before {
                break; // a type without bytes: every further element is empty too
            }
        }
        Ok(Some(p))
    }

    /// In payload mode, fail when `end` lies beyond the payload (stops absurd lengths early); in
    /// layout mode, when a layout exceeds [`MAX_LAYOUT_BYTES`] (keeps offsets far from overflow).
    fn check_within(&self, end: usize, what: &dyn Fn() -> String) -> Result<(), DecodeError> {
        match self.src {
            Src::Payload(data) if end > data.len() => Err(DecodeError::Truncated {
                field: what(),
                needed: end,
                len: data.len(),
            }),
            Src::Layout if end > MAX_LAYOUT_BYTES => Err(too_large(what)),
            _ => Ok(()),
        }
    }

    fn skip_field(
        &self,
        f: &Field,
        pos: usize,
        what: &dyn Fn() -> String,
    ) -> Result<Option<usize>, DecodeError> {
        match f.array {
            ArrayKind::Single => self.skip_elements(&f.ty, 1, pos, what),
            ArrayKind::Fixed(n) => self.skip_elements(&f.ty, n, pos, what),
            ArrayKind::Unbounded | ArrayKind::Bounded(_) => {
                let Some((n, after)) = self.length(pos, what)? else {
                    return Ok(None);
                };
                self.skip_elements(&f.ty, n, after, what)
            }
        }
    }

    /// Follow `steps` from `pos`; returns the position of the leaf element (before alignment).
    fn follow(
        &self,
        steps: &[Step],
        mut pos: usize,
        what: &dyn Fn() -> String,
    ) -> Result<Option<usize>, DecodeError> {
        for step in steps {
            let msg = self
                .schema
                .get(&step.type_name)
                .map_err(|e| DecodeError::Invalid(e.to_string()))?;
            let Some(fields) = msg.fields.get(..step.field) else {
                return Err(DecodeError::Invalid(format!("{}: schema changed", what())));
            };
            for f in fields {
                match self.skip_field(f, pos, what)? {
                    Some(p) => pos = p,
                    None => return Ok(None),
                }
            }
            let Some(field) = msg.fields.get(step.field) else {
                return Err(DecodeError::Invalid(format!("{}: schema changed", what())));
            };
            if let Some(i) = step.index {
                let (len, start) = match field.array {
                    ArrayKind::Fixed(n) => (n, pos),
                    _ => match self.length(pos, what)? {
                        Some(v) => v,
                        None => return Ok(None),
                    },
                };
                if i >= len {
                    return Err(DecodeError::Invalid(format!(
                        "{}: index {i} out of range, array has {len} elements",
                        what()
                    )));
                }
                match self.skip_elements(&field.ty, i, start, what)? {
                    Some(p) => pos = p,
                    None => return Ok(None),
                }
            }
        }
        Ok(Some(pos))
    }

    fn read_prim(
        &self,
        prim: Primitive,
        pos: usize,
        what: &dyn Fn() -> String,
    ) -> Result<(Value, usize), DecodeError> {
        let pos = self.align(pos, prim);
        let le = self.rules.little_endian();
        macro_rules! num {
            ($t:ty, $n:literal, $variant:ident, $conv:ty) => {{
                let b = self.bytes::<$n>(pos, what)?;
                let v = if le {
                    <$t>::from_le_bytes(b)
                } else {
                    <$t>::from_be_bytes(b)
                };
                (Value::$variant(v as $conv), pos + $n)
            }};
        }
        Ok(match prim {
            Primitive::Bool => (Value::Bool(self.bytes::<1>(pos, what)?[0] != 0), pos + 1),
            Primitive::I8 => num!(i8, 1, Int, i64),
            Primitive::U8 => num!(u8, 1, UInt, u64),
            Primitive::I16 => num!(i16, 2, Int, i64),
            Primitive::U16 => num!(u16, 2, UInt, u64),
            Primitive::I32 => num!(i32, 4, Int, i64),
            Primitive::U32 => num!(u32, 4, UInt, u64),
            Primitive::I64 => num!(i64, 8, Int, i64),
            Primitive::U64 => num!(u64, 8, UInt, u64),
            Primitive::F32 => num!(f32, 4, Float, f64),
            Primitive::F64 => num!(f64, 8, Float, f64),
            Primitive::Time | Primitive::Duration => {
                let sec = self.u32_at(pos, what)?;
                let nsec = self.u32_at(pos + 4, what)?;
                let value = if prim == Primitive::Time {
                    vec![
                        ("sec".to_string(), Value::UInt(sec.into())),
                        ("nsec".to_string(), Value::UInt(nsec.into())),
                    ]
                } else {
                    vec![
                        ("sec".to_string(), Value::Int((sec as i32).into())),
                        ("nsec".to_string(), Value::Int((nsec as i32).into())),
                    ]
                };
                (Value::Struct(value), pos + 8)
            }
            Primitive::String => {
                let n = self.u32_at(pos, what)? as usize;
                let start = pos + 4;
                let end = start.checked_add(n).ok_or_else(|| {
                    DecodeError::Invalid(format!("{}: bad string length", what()))
                })?;
                let Src::Payload(data) = self.src else {
                    return Err(DecodeError::Invalid("layout walk reads no bytes".into()));
                };
                let bytes = data.get(start..end).ok_or_else(|| DecodeError::Truncated {
                    field: what(),
                    needed: end,
                    len: data.len(),
                })?;
                // CDR counts the terminating NUL; ROS 1 does not have one.
                let text = match self.rules {
                    Rules::Cdr { .. } => bytes.strip_suffix(&[0]).unwrap_or(bytes),
                    Rules::Ros1 => bytes,
                };
                let s = std::str::from_utf8(text).map_err(|_| {
                    DecodeError::Invalid(format!("{}: string is not UTF-8", what()))
                })?;
                (Value::String(s.to_string()), end)
            }
        })
    }

    fn decode_elements(
        &self,
        ty: &FieldType,
        count: usize,
        mut pos: usize,
        name: &str,
    ) -> Result<(Vec<Value>, usize), DecodeError> {
        let what = || name.to_string();
        self.check_within(pos.saturating_add(count.min(1)), &what)?;
        // Every element but one of a field-less type takes at least one byte: more elements than
        // payload bytes can only be empty structs, which would allocate without bound.
        if let Src::Payload(data) = self.src
            && count > data.len()
        {
            return Err(DecodeError::Invalid(format!(
                "{name}: {count} elements cannot fit in a payload of {} bytes",
                data.len()
            )));
        }
        let mut out = Vec::with_capacity(count.min(4096));
        for _ in 0..count {
            let (v, p) = self.decode_one(ty, pos, name)?;
            out.push(v);
            pos = p;
        }
        Ok((out, pos))
    }

    /// Decode one element; `name` is the field being decoded (for error messages).
    fn decode_one(
        &self,
        ty: &FieldType,
        pos: usize,
        name: &str,
    ) -> Result<(Value, usize), DecodeError> {
        match ty {
            FieldType::Primitive(p) => self.read_prim(*p, pos, &|| name.to_string()),
            FieldType::Message(type_name) => {
                let msg = self
                    .schema
                    .get(type_name)
                    .map_err(|e| DecodeError::Invalid(e.to_string()))?;
                let mut fields = Vec::with_capacity(msg.fields.len());
                let mut p = pos;
                for f in &msg.fields {
                    let (v, next) = self.decode_field(f, p)?;
                    fields.push((f.name.clone(), v));
                    p = next;
                }
                Ok((Value::Struct(fields), p))
            }
        }
    }

    fn decode_field(&self, f: &Field, pos: usize) -> Result<(Value, usize), DecodeError> {
        let what = || f.name.clone();
        match f.array {
            ArrayKind::Single => self.decode_one(&f.ty, pos, &f.name),
            ArrayKind::Fixed(n) => {
                let (v, p) = self.decode_elements(&f.ty, n, pos, &f.name)?;
                Ok((Value::Array(v), p))
            }
            ArrayKind::Unbounded | ArrayKind::Bounded(_) => {
                let (n, after) = self
                    .length(pos, &what)?
                    .ok_or_else(|| DecodeError::Invalid("layout walk".into()))?;
                let (v, p) = self.decode_elements(&f.ty, n, after, &f.name)?;
                Ok((Value::Array(v), p))
            }
        }
    }
}

/// Decode a whole payload into a [`Value`] tree.
pub fn decode(schema: &MsgSchema, encoding: Encoding, data: &[u8]) -> Result<Value, DecodeError> {
    if encoding == Encoding::Json {
        return Ok(Value::from_json(&parse_json(data)?));
    }
    let walker = Walker::new(schema, rules_for(encoding, data)?, Src::Payload(data));
    let root = FieldType::Message(schema.root.clone());
    schema
        .root_type()
        .map_err(|e| DecodeError::Invalid(e.to_string()))?;
    Ok(walker.decode_one(&root, walker.base, &schema.root)?.0)
}

fn parse_json(data: &[u8]) -> Result<serde_json::Value, DecodeError> {
    serde_json::from_slice(data).map_err(|e| DecodeError::Invalid(format!("bad JSON: {e}")))
}

impl Value {
    /// Convert parsed JSON (objects keep their key order; `null` becomes NaN so that missing
    /// numbers are reported like NaN values).
    fn from_json(json: &serde_json::Value) -> Value {
        match json {
            serde_json::Value::Null => Value::Float(f64::NAN),
            serde_json::Value::Bool(b) => Value::Bool(*b),
            serde_json::Value::Number(n) => {
                if let Some(u) = n.as_u64() {
                    Value::UInt(u)
                } else if let Some(i) = n.as_i64() {
                    Value::Int(i)
                } else {
                    Value::Float(n.as_f64().unwrap_or(f64::NAN))
                }
            }
            serde_json::Value::String(s) => Value::String(s.clone()),
            serde_json::Value::Array(a) => Value::Array(a.iter().map(Value::from_json).collect()),
            serde_json::Value::Object(o) => Value::Struct(
                o.iter()
                    .map(|(k, v)| (k.clone(), Value::from_json(v)))
                    .collect(),
            ),
        }
    }

    /// The value at `path` (field names and element indices), if present.
    pub fn get(&self, path: &FieldPath) -> Option<&Value> {
        let mut v = self;
        for (name, index) in &path.segments {
            let Value::Struct(fields) = v else {
                return None;
            };
            v = &fields.iter().find(|(n, _)| n == name)?.1;
            if let Some(i) = index {
                let Value::Array(items) = v else { return None };
                v = items.get(*i)?;
            }
        }
        Some(v)
    }

    /// The value as a number (bools as 0/1); `None` for strings, arrays and structs.
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            Value::Bool(b) => Some(f64::from(u8::from(*b))),
            Value::Int(i) => Some(*i as f64),
            Value::UInt(u) => Some(*u as f64),
            Value::Float(f) => Some(*f),
            _ => None,
        }
    }
}

impl FieldPath {
    /// Parse `name[index].name…`, e.g. `motor_state[17].tau_est` or `bmsvoltage[0]`.
    pub fn parse(s: &str) -> Result<FieldPath, DecodeError> {
        let bad = |what: &str| DecodeError::Invalid(format!("bad field path {s:?}: {what}"));
        let mut segments = Vec::new();
        for part in s.trim().split('.') {
            let (name, index) = match part.split_once('[') {
                None => (part, None),
                Some((name, rest)) => {
                    let digits = rest.strip_suffix(']').ok_or_else(|| bad("missing `]`"))?;
                    let i = digits
                        .trim()
                        .parse::<usize>()
                        .map_err(|_| bad("index is not a number"))?;
                    (name, Some(i))
                }
            };
            if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
                return Err(bad("empty or invalid field name"));
            }
            segments.push((name.to_string(), index));
        }
        Ok(FieldPath { segments })
    }
}

impl std::fmt::Display for FieldPath {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for (i, (name, index)) in self.segments.iter().enumerate() {
            if i > 0 {
                f.write_str(".")?;
            }
            f.write_str(name)?;
            if let Some(i) = index {
                write!(f, "[{i}]")?;
            }
        }
        Ok(())
    }
}

/// Resolve `path` against the schema: the walk steps and the leaf primitive.
fn resolve(schema: &MsgSchema, path: &FieldPath) -> Result<(Vec<Step>, Primitive), DecodeError> {
    let no_field = |why: String| DecodeError::NoSuchField {
        path: format!("{path} ({why})"),
        type_name: schema.root.clone(),
    };
    let mut type_name = schema.root.clone();
    let mut steps = Vec::new();
    let n = path.segments.len();
    for (k, (name, index)) in path.segments.iter().enumerate() {
        let msg = schema
            .get(&type_name)
            .map_err(|e| no_field(e.to_string()))?;
        let (fi, field) = msg
            .fields
            .iter()
            .enumerate()
            .find(|(_, f)| &f.name == name)
            .ok_or_else(|| no_field(format!("{type_name} has no field {name}")))?;
        match (field.array, index) {
            (ArrayKind::Single, Some(_)) => {
                return Err(no_field(format!("{name} is not an array")));
            }
            (ArrayKind::Fixed(len), Some(i)) if *i >= len => {
                return Err(no_field(format!("{name} has {len} elements")));
            }
            (ArrayKind::Bounded(len), Some(i)) if *i >= len => {
                return Err(no_field(format!("{name} holds at most {len} elements")));
            }
            (ArrayKind::Single, None) => {}
            (_, None) => return Err(no_field(format!("{name} is an array; give an index"))),
            _ => {}
        }
        steps.push(Step {
            type_name: type_name.clone(),
            field: fi,
            index: *index,
        });
        match (&field.ty, k + 1 == n) {
            (FieldType::Primitive(p), true) => {
                if matches!(p, Primitive::String | Primitive::Time | Primitive::Duration) {
                    return Err(no_field(format!("{name} is not a number")));
                }
                return Ok((steps, *p));
            }
            (FieldType::Primitive(_), false) => {
                return Err(no_field(format!("{name} has no sub-fields")));
            }
            (FieldType::Message(t), false) => type_name = t.clone(),
            (FieldType::Message(_), true) => {
                return Err(no_field(format!("{name} is a message, not a number")));
            }
        }
    }
    Err(no_field("empty path".into()))
}

impl FieldExtractor {
    /// Compile extraction of `paths` (each must end at a numeric or bool field) for payloads of
    /// `schema` in `encoding`. Fails with [`DecodeError::NoSuchField`] when a path is not in the schema.
    /// For JSON channels without a message definition (empty root type) paths are checked per message.
    pub fn compile(
        schema: &MsgSchema,
        encoding: Encoding,
        paths: &[FieldPath],
    ) -> Result<FieldExtractor, DecodeError> {
        let names = paths.iter().map(ToString::to_string).collect();
        let schemaless = schema
            .root_type()
            .map(|t| t.fields.is_empty())
            .unwrap_or(true);
        if encoding == Encoding::Json {
            if !schemaless {
                for p in paths {
                    resolve(schema, p)?;
                }
            }
            let leaves = paths.iter().cloned().map(Leaf::Json).collect();
            let other_leaves = (0..paths.len()).collect();
            return Ok(FieldExtractor {
                encoding,
                leaves,
                names,
                min_len: 0,
                schema: None,
                fixed_len: None,
                root: schema.root.clone(),
                f32_leaves: Vec::new(),
                other_leaves,
            });
        }
        let rules = match encoding {
            Encoding::Ros1 => Rules::Ros1,
            _ => Rules::Cdr { le: true }, // offsets do not depend on byte order
        };
        let layout = Walker::new(schema, rules, Src::Layout);
        let base = layout.base;
        let mut leaves = Vec::with_capacity(paths.len());
        let mut min_len = base;
        let mut needs_schema = false;
        for p in paths {
            let (steps, prim) = resolve(schema, p)?;
            let what = || p.to_string();
            match layout.follow(&steps, base, &what)? {
                Some(pos) => {
                    let off = layout.align(pos, prim);
                    min_len = min_len.max(off + prim_size(prim).unwrap_or(0));
                    leaves.push(Leaf::Offset(off, prim));
                }
                None => {
                    needs_schema = true;
                    leaves.push(Leaf::Walk(steps, prim));
                }
            }
        }
        let what = || schema.root.clone();
        let fixed_len = match layout.skip_messages(&schema.root, 1, base, &what) {
            Ok(Some(end)) if encoding == Encoding::Cdr => {
                Some((end, base + (end - base).div_ceil(8) * 8))
            }
            Ok(Some(end)) => Some((end, end)),
            _ => None,
        };
        let (mut f32_leaves, mut other_leaves) = (Vec::new(), Vec::new());
        for (slot, leaf) in leaves.iter().enumerate() {
            match leaf {
                Leaf::Offset(off, Primitive::F32) => f32_leaves.push((*off, slot)),
                _ => other_leaves.push(slot),
            }
        }
        Ok(FieldExtractor {
            encoding,
            leaves,
            names,
            min_len,
            schema: needs_schema.then(|| schema.clone()),
            fixed_len,
            root: schema.root.clone(),
            f32_leaves,
            other_leaves,
        })
    }

    /// Number of paths (the length `out` must have).
    pub fn len(&self) -> usize {
        self.leaves.len()
    }

    /// True when no paths were compiled.
    pub fn is_empty(&self) -> bool {
        self.leaves.is_empty()
    }

    /// True when every path has a constant byte offset (the fast path).
    pub fn is_constant_offset(&self) -> bool {
        self.leaves.iter().all(|l| matches!(l, Leaf::Offset(..)))
    }

    /// Read every compiled field of one payload into `out` (same order as the paths). NaN and
    /// infinite values are returned as they are; the caller decides what to do with them.
    pub fn extract(&self, data: &[u8], out: &mut [f64]) -> Result<(), DecodeError> {
        if out.len() != self.leaves.len() {
            return Err(DecodeError::Invalid(format!(
                "output has {} slots for {} fields",
                out.len(),
                self.leaves.len()
            )));
        }
        if self.encoding == Encoding::Json {
            return self.extract_json(data, out);
        }
        let rules = rules_for(self.encoding, data)?;
        if let Some((lo, hi)) = self.fixed_len
            && !(lo..=hi).contains(&data.len())
        {
            return Err(DecodeError::Invalid(format!(
                "payload is {} bytes but every {} message is {lo} bytes{}: the message definition does not match the payload",
                data.len(),
                self.root,
                if hi > lo {
                    format!(" (up to {hi} with padding)")
                } else {
                    String::new()
                }
            )));
        }
        if data.len() < self.min_len {
            let first_missing = self
                .leaves
                .iter()
                .zip(&self.names)
                .find(|(l, _)| matches!(l, Leaf::Offset(o, p) if o + prim_size(*p).unwrap_or(0) > data.len()))
                .map_or_else(String::new, |(_, n)| n.clone());
            return Err(DecodeError::Truncated {
                field: first_missing,
                needed: self.min_len,
                len: data.len(),
            });
        }
        let le = rules.little_endian();
        // Within `min_len` (checked above): these reads cannot fail.
        if le && !self.f32_leaves.is_empty() {
            for &(off, slot) in &self.f32_leaves {
                let b = data.get(off..off + 4).and_then(|b| b.try_into().ok());
                if let (Some(b), Some(v)) = (b, out.get_mut(slot)) {
                    *v = f64::from(f32::from_le_bytes(b));
                }
            }
        }
        let all: Vec<usize>;
        let slow = if le {
            &self.other_leaves
        } else {
            all = (0..self.leaves.len()).collect();
            &all
        };
        for &i in slow {
            let (leaf, name, slot) = (&self.leaves[i], &self.names[i], &mut out[i]);
            *slot = match leaf {
                Leaf::Offset(off, prim) => {
                    read_number(data, *off, *prim, le).ok_or_else(|| DecodeError::Truncated {
                        field: name.clone(),
                        needed: off + 8,
                        len: data.len(),
                    })?
                }
                Leaf::Walk(steps, prim) => {
                    let schema = self
                        .schema
                        .as_ref()
                        .ok_or_else(|| DecodeError::Invalid("extractor has no schema".into()))?;
                    let walker = Walker::new(schema, rules, Src::Payload(data));
                    let what = || name.clone();
                    let pos = walker
                        .follow(steps, walker.base, &what)?
                        .ok_or_else(|| DecodeError::Invalid("walk failed".into()))?;
                    walker
                        .read_prim(*prim, pos, &what)?
                        .0
                        .as_f64()
                        .unwrap_or(f64::NAN)
                }
                Leaf::Json(_) => {
                    return Err(DecodeError::Invalid("JSON path on a binary channel".into()));
                }
            };
        }
        Ok(())
    }

    fn extract_json(&self, data: &[u8], out: &mut [f64]) -> Result<(), DecodeError> {
        let json = Value::from_json(&parse_json(data)?);
        for ((leaf, slot), name) in self.leaves.iter().zip(out.iter_mut()).zip(&self.names) {
            let Leaf::Json(path) = leaf else {
                return Err(DecodeError::Invalid("binary path on a JSON channel".into()));
            };
            let v = json.get(path).ok_or_else(|| DecodeError::NoSuchField {
                path: name.clone(),
                type_name: "JSON message".into(),
            })?;
            *slot = v.as_f64().ok_or_else(|| {
                DecodeError::Invalid(format!("{name} is not a number in the JSON message"))
            })?;
        }
        Ok(())
    }
}

/// Read one fixed-size primitive at `off` as f64 (`None` when out of bounds).
#[inline]
fn read_number(data: &[u8], off: usize, prim: Primitive, le: bool) -> Option<f64> {
    macro_rules! rd {
        ($t:ty, $n:literal) => {{
            let b: [u8; $n] = data.get(off..off + $n)?.try_into().ok()?;
            (if le {
                <$t>::from_le_bytes(b)
            } else {
                <$t>::from_be_bytes(b)
            }) as f64
        }};
    }
    Some(match prim {
        Primitive::Bool => f64::from(u8::from(*data.get(off)? != 0)),
        Primitive::I8 => rd!(i8, 1),
        Primitive::U8 => rd!(u8, 1),
        Primitive::I16 => rd!(i16, 2),
        Primitive::U16 => rd!(u16, 2),
        Primitive::I32 => rd!(i32, 4),
        Primitive::U32 => rd!(u32, 4),
        Primitive::I64 => rd!(i64, 8),
        Primitive::U64 => rd!(u64, 8),
        Primitive::F32 => rd!(f32, 4),
        Primitive::F64 => rd!(f64, 8),
        Primitive::String | Primitive::Time | Primitive::Duration => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ros1_packed_layout_by_hand() {
        let schema =
            MsgSchema::parse_ros1msg("p/T", "uint8 a\nfloat64 x\nstring s\ntime t\nint16[] v\n")
                .unwrap();
        let mut d = vec![9u8];
        d.extend(1.25f64.to_le_bytes());
        d.extend(2u32.to_le_bytes());
        d.extend(b"ok");
        d.extend(5u32.to_le_bytes());
        d.extend(6u32.to_le_bytes());
        d.extend(2u32.to_le_bytes());
        d.extend((-3i16).to_le_bytes());
        d.extend(4i16.to_le_bytes());
        let v = decode(&schema, Encoding::Ros1, &d).unwrap();
        let get = |p: &str| v.get(&FieldPath::parse(p).unwrap()).cloned();
        assert_eq!(get("a"), Some(Value::UInt(9)));
        assert_eq!(get("x"), Some(Value::Float(1.25)));
        assert_eq!(get("s"), Some(Value::String("ok".into())));
        assert_eq!(get("t.nsec"), Some(Value::UInt(6)));
        assert_eq!(get("v[1]"), Some(Value::Int(4)));
        let paths: Vec<FieldPath> = ["a", "x", "v[0]"]
            .iter()
            .map(|p| FieldPath::parse(p).unwrap())
            .collect();
        let ex = FieldExtractor::compile(&schema, Encoding::Ros1, &paths).unwrap();
        let mut out = [0.0; 3];
        ex.extract(&d, &mut out).unwrap();
        assert_eq!(out, [9.0, 1.25, -3.0]);
    }

    #[test]
    fn field_paths_and_bad_paths() {
        let p = FieldPath::parse("motor_state[17].tau_est").unwrap();
        assert_eq!(
            p.segments,
            vec![
                ("motor_state".to_string(), Some(17)),
                ("tau_est".to_string(), None)
            ]
        );
        assert_eq!(p.to_string(), "motor_state[17].tau_est");
        for bad in ["", "a[", "a[x]", "a..b", "a b"] {
            assert!(FieldPath::parse(bad).is_err(), "{bad}");
        }
        let schema = MsgSchema::parse_ros2msg("p/T", "float32[2] a\n").unwrap();
        for bad in ["a", "a[2]", "b", "a[0].c"] {
            let e =
                FieldExtractor::compile(&schema, Encoding::Cdr, &[FieldPath::parse(bad).unwrap()])
                    .unwrap_err();
            assert!(matches!(e, DecodeError::NoSuchField { .. }), "{bad}: {e}");
        }
    }

    #[test]
    fn json_by_field_name_null_is_nan() {
        let schema = MsgSchema {
            root: "j".into(),
            types: [(
                "j".to_string(),
                crate::read::msgdef::MsgType {
                    name: "j".into(),
                    fields: vec![],
                },
            )]
            .into_iter()
            .collect(),
        };
        let paths: Vec<FieldPath> = ["value[1]", "n", "b"]
            .iter()
            .map(|p| FieldPath::parse(p).unwrap())
            .collect();
        let ex = FieldExtractor::compile(&schema, Encoding::Json, &paths).unwrap();
        let mut out = [0.0; 3];
        ex.extract(br#"{"value":[1,2.5],"n":null,"b":true}"#, &mut out)
            .unwrap();
        assert_eq!(out[0], 2.5);
        assert!(out[1].is_nan());
        assert_eq!(out[2], 1.0);
        assert!(ex.extract(br#"{"value":[1]}"#, &mut out).is_err());
        assert!(ex.extract(b"not json", &mut out).is_err());
    }
}
