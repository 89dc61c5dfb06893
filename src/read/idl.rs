//! OMG IDL (`ros2idl`) message definitions: a lexer and a recursive-descent parser for the
//! subset ROS 2 generates (modules, structs, typedefs, sequences, fixed arrays, enums), producing
//! the same [`MsgSchema`] as the `.msg` parser in [`super::msgdef`]. Nesting depth is limited so a
//! hostile definition cannot overflow the stack.

use std::collections::{HashMap, HashSet};

use super::msgdef::{
    ArrayKind, Dialect, Field, FieldType, MAX_ARRAY_LEN, MAX_NESTING, MsgSchema, MsgType,
    Primitive, SchemaError, normalize_type_name,
};

#[derive(Debug, Clone, PartialEq)]
enum Tok {
    Ident(String),
    Number(String),
    Str,
    Punct(char),
    Scope,
}

fn tokenize_idl(type_name: &str, text: &str) -> Result<Vec<(Tok, usize)>, SchemaError> {
    let mut toks = Vec::new();
    let chars: Vec<char> = text.chars().collect();
    let mut i = 0;
    let mut line = 1;
    let mut at_line_start = true;
    while i < chars.len() {
        let c = chars[i];
        if c == '\n' {
            line += 1;
            at_line_start = true;
            i += 1;
            continue;
        }
        if c.is_whitespace() {
            i += 1;
            continue;
        }
        let starts_line = at_line_start;
        at_line_start = false;
        if (c == '#' && starts_line) || (c == '/' && chars.get(i + 1) == Some(&'/')) {
            // A preprocessor line (#include, #pragma …) or a line comment: ignored.
            while i < chars.len() && chars[i] != '\n' {
                i += 1;
            }
        } else if c == '/' && chars.get(i + 1) == Some(&'*') {
            i += 2;
            while i < chars.len() && !(chars[i] == '*' && chars.get(i + 1) == Some(&'/')) {
                if chars[i] == '\n' {
                    line += 1;
                }
                i += 1;
            }
            i += 2;
        } else if c == '"' {
            i += 1;
            while i < chars.len() && chars[i] != '"' {
                if chars[i] == '\\' {
                    i += 1;
                }
                if chars.get(i) == Some(&'\n') {
                    line += 1;
                }
                i += 1;
            }
            i += 1;
            toks.push((Tok::Str, line));
        } else if c == ':' && chars.get(i + 1) == Some(&':') {
            toks.push((Tok::Scope, line));
            i += 2;
        } else if c.is_ascii_alphabetic() || c == '_' {
            let start = i;
            while i < chars.len() && (chars[i].is_ascii_alphanumeric() || chars[i] == '_') {
                i += 1;
            }
            toks.push((Tok::Ident(chars[start..i].iter().collect()), line));
        } else if c.is_ascii_digit()
            || (c == '-' && chars.get(i + 1).is_some_and(|d| d.is_ascii_digit()))
        {
            let start = i;
            i += 1;
            while i < chars.len() && (chars[i].is_ascii_alphanumeric() || chars[i] == '.') {
                i += 1;
            }
            toks.push((Tok::Number(chars[start..i].iter().collect()), line));
        } else if "{}[]<>;,()=@:+-*/|&~.'".contains(c) {
            toks.push((Tok::Punct(c), line));
            i += 1;
        } else {
            return Err(SchemaError::Syntax {
                type_name: type_name.to_string(),
                line,
                what: format!("unexpected character {c:?} in IDL"),
            });
        }
    }
    Ok(toks)
}

struct IdlParser<'a> {
    type_name: &'a str,
    toks: Vec<(Tok, usize)>,
    pos: usize,
    /// Enclosing module names.
    scope: Vec<String>,
    /// typedef name (qualified) → (element type, array kind).
    typedefs: HashMap<String, (FieldType, ArrayKind)>,
    /// Enum names (qualified): serialised as uint32.
    enums: HashSet<String>,
    /// Current nesting of modules and `sequence<…>` (recursion depth of the parser).
    depth: usize,
    types: HashMap<String, MsgType>,
}

impl IdlParser<'_> {
    fn err(&self, what: impl Into<String>) -> SchemaError {
        let line = self
            .toks
            .get(self.pos)
            .or(self.toks.last())
            .map_or(0, |t| t.1);
        SchemaError::Syntax {
            type_name: self.type_name.to_string(),
            line,
            what: what.into(),
        }
    }
    /// One level deeper into modules / sequences; refused past [`MAX_NESTING`].
    fn enter(&mut self) -> Result<(), SchemaError> {
        self.depth += 1;
        if self.depth > MAX_NESTING {
            return Err(self.err(format!(
                "modules or sequences nested more than {MAX_NESTING} levels deep"
            )));
        }
        Ok(())
    }
    fn peek(&self) -> Option<&Tok> {
        self.toks.get(self.pos).map(|t| &t.0)
    }
    fn next(&mut self) -> Result<Tok, SchemaError> {
        let t = self
            .toks
            .get(self.pos)
            .map(|t| t.0.clone())
            .ok_or_else(|| self.err("unexpected end of IDL"))?;
        self.pos += 1;
        Ok(t)
    }
    fn expect(&mut self, c: char) -> Result<(), SchemaError> {
        match self.next()? {
            Tok::Punct(p) if p == c => Ok(()),
            other => Err(self.err(format!("expected `{c}`, found {other:?}"))),
        }
    }
    fn eat(&mut self, c: char) -> bool {
        if self.peek() == Some(&Tok::Punct(c)) {
            self.pos += 1;
            true
        } else {
            false
        }
    }
    fn ident(&mut self) -> Result<String, SchemaError> {
        match self.next()? {
            Tok::Ident(s) => Ok(s),
            other => Err(self.err(format!("expected a name, found {other:?}"))),
        }
    }
    fn number(&mut self) -> Result<usize, SchemaError> {
        match self.next()? {
            Tok::Number(n) => n.parse().map_err(|_| self.err(format!("bad number {n}"))),
            other => Err(self.err(format!("expected a number, found {other:?}"))),
        }
    }
    /// Skip tokens up to and including the `;` that ends the current declaration, stepping over
    /// nested braces.
    fn skip_declaration(&mut self) -> Result<(), SchemaError> {
        let mut depth = 0usize;
        loop {
            match self.next()? {
                Tok::Punct('{') => depth += 1,
                Tok::Punct('}') => depth = depth.saturating_sub(1),
                Tok::Punct(';') if depth == 0 => return Ok(()),
                _ => {}
            }
        }
    }
    /// Skip annotations such as `@key`, `@default (value=0)`, `@verbatim (…)`.
    fn skip_annotations(&mut self) -> Result<(), SchemaError> {
        while self.eat('@') {
            self.ident()?;
            while self.peek() == Some(&Tok::Scope) {
                self.pos += 1;
                self.ident()?;
            }
            if self.eat('(') {
                let mut depth = 1;
                while depth > 0 {
                    match self.next()? {
                        Tok::Punct('(') => depth += 1,
                        Tok::Punct(')') => depth -= 1,
                        _ => {}
                    }
                }
            }
        }
        Ok(())
    }
    fn qualified(&self, name: &str) -> String {
        let mut parts = self.scope.clone();
        parts.push(name.to_string());
        parts.join("/")
    }

    fn definitions(&mut self, until_brace: bool) -> Result<(), SchemaError> {
        loop {
            self.skip_annotations()?;
            match self.peek() {
                None if !until_brace => return Ok(()),
                None => return Err(self.err("missing `}`")),
                Some(Tok::Punct('}')) if until_brace => {
                    self.pos += 1;
                    self.eat(';');
                    return Ok(());
                }
                Some(Tok::Punct(';')) => self.pos += 1,
                _ => {
                    let kw = self.ident()?;
                    match kw.as_str() {
                        "module" => {
                            let name = self.ident()?;
                            self.expect('{')?;
                            self.scope.push(name);
                            self.enter()?;
                            self.definitions(true)?;
                            self.depth -= 1;
                            self.scope.pop();
                        }
                        "struct" => self.structure()?,
                        "typedef" => {
                            let (ty, array) = self.type_spec()?;
                            let (name, decl_array) = self.declarator()?;
                            let array =
                                combine_arrays(array, decl_array).map_err(|w| self.err(w))?;
                            self.expect(';')?;
                            self.typedefs.insert(self.qualified(&name), (ty, array));
                        }
                        "enum" => {
                            let name = self.ident()?;
                            self.enums.insert(self.qualified(&name));
                            self.skip_declaration()?;
                        }
                        _ => self.skip_declaration()?, // const, union …
                    }
                }
            }
        }
    }

    fn structure(&mut self) -> Result<(), SchemaError> {
        let short = self.ident()?;
        let name = self.qualified(&short);
        if self.eat(';') {
            return Ok(()); // forward declaration
        }
        self.expect('{')?;
        let mut fields = Vec::new();
        loop {
            self.skip_annotations()?;
            if self.eat('}') {
                break;
            }
            let (ty, array) = self.type_spec()?;
            loop {
                let (fname, decl_array) = self.declarator()?;
                let array = combine_arrays(array, decl_array).map_err(|w| self.err(w))?;
                fields.push(Field {
                    name: fname,
                    ty: ty.clone(),
                    array,
                });
                if !self.eat(',') {
                    break;
                }
            }
            self.expect(';')?;
        }
        self.eat(';');
        let key = normalize_type_name(&name, "");
        self.types
            .insert(key.clone(), MsgType { name: key, fields });
        Ok(())
    }

    /// `name` or `name[N]` (multi-dimensional arrays flattened).
    fn declarator(&mut self) -> Result<(String, ArrayKind), SchemaError> {
        let name = self.ident()?;
        let mut total: Option<usize> = None;
        while self.eat('[') {
            let n = self.number()?;
            self.expect(']')?;
            total = total
                .unwrap_or(1)
                .checked_mul(n)
                .filter(|t| *t <= MAX_ARRAY_LEN)
                .map(Some)
                .ok_or_else(|| {
                    self.err(format!(
                        "array {name}: dimensions multiply to more than {MAX_ARRAY_LEN} elements"
                    ))
                })?;
        }
        Ok((name, total.map_or(ArrayKind::Single, ArrayKind::Fixed)))
    }

    fn scoped_name(&mut self, first: String) -> Result<String, SchemaError> {
        let mut parts = vec![first];
        while self.peek() == Some(&Tok::Scope) {
            self.pos += 1;
            parts.push(self.ident()?);
        }
        Ok(parts.join("/"))
    }

    fn type_spec(&mut self) -> Result<(FieldType, ArrayKind), SchemaError> {
        if self.peek() == Some(&Tok::Scope) {
            self.pos += 1; // leading `::`
        }
        let first = self.ident()?;
        let prim = |p| Ok((FieldType::Primitive(p), ArrayKind::Single));
        match first.as_str() {
            "sequence" => {
                self.expect('<')?;
                self.enter()?;
                let (ty, inner) = self.type_spec()?;
                self.depth -= 1;
                if inner != ArrayKind::Single {
                    return Err(self.err("sequences of arrays are not supported"));
                }
                let kind = if self.eat(',') {
                    ArrayKind::Bounded(self.number()?)
                } else {
                    ArrayKind::Unbounded
                };
                self.expect('>')?;
                Ok((ty, kind))
            }
            "string" => {
                if self.eat('<') {
                    self.number()?;
                    self.expect('>')?;
                }
                prim(Primitive::String)
            }
            "wstring" | "wchar" => Err(self.err("wide strings/chars are not supported")),
            "boolean" => prim(Primitive::Bool),
            "octet" | "uint8" | "char" => prim(Primitive::U8),
            "int8" => prim(Primitive::I8),
            "int16" | "short" => prim(Primitive::I16),
            "uint16" => prim(Primitive::U16),
            "int32" => prim(Primitive::I32),
            "uint32" => prim(Primitive::U32),
            "int64" => prim(Primitive::I64),
            "uint64" => prim(Primitive::U64),
            "float" => prim(Primitive::F32),
            "double" => prim(Primitive::F64),
            "long" => {
                if self.peek() == Some(&Tok::Ident("long".into())) {
                    self.pos += 1;
                    return prim(Primitive::I64);
                }
                if self.peek() == Some(&Tok::Ident("double".into())) {
                    return Err(self.err("long double is not supported"));
                }
                prim(Primitive::I32)
            }
            "unsigned" => match self.ident()?.as_str() {
                "short" => prim(Primitive::U16),
                "long" => {
                    if self.peek() == Some(&Tok::Ident("long".into())) {
                        self.pos += 1;
                        return prim(Primitive::U64);
                    }
                    prim(Primitive::U32)
                }
                other => Err(self.err(format!("unknown type unsigned {other}"))),
            },
            _ => {
                let name = self.scoped_name(first)?;
                Ok(self.resolve_named(&name))
            }
        }
    }

    /// A named type: a typedef or enum (looked up from the innermost scope outwards) or a struct.
    fn resolve_named(&self, name: &str) -> (FieldType, ArrayKind) {
        for depth in (0..=self.scope.len()).rev() {
            let mut parts = self.scope[..depth].to_vec();
            parts.push(name.to_string());
            let q = parts.join("/");
            if let Some(t) = self.typedefs.get(&q) {
                return t.clone();
            }
            if self.enums.contains(&q) {
                return (FieldType::Primitive(Primitive::U32), ArrayKind::Single);
            }
        }
        let qualified = if name.contains('/') {
            name.to_string()
        } else {
            self.qualified(name)
        };
        (
            FieldType::Message(normalize_type_name(&qualified, "")),
            ArrayKind::Single,
        )
    }
}

fn combine_arrays(outer: ArrayKind, decl: ArrayKind) -> Result<ArrayKind, String> {
    match (outer, decl) {
        (a, ArrayKind::Single) => Ok(a),
        (ArrayKind::Single, d) => Ok(d),
        _ => Err("arrays of arrays/sequences are not supported".into()),
    }
}

impl MsgSchema {
    /// Parse OMG IDL (`ros2idl`): nested `module`s, `struct`s, `typedef`s, `sequence<T>`, fixed
    /// arrays, enums (as uint32); `#include`/`#pragma` lines, constants and annotations are
    /// ignored. Several IDL files concatenated with `=====` + `IDL: pkg/msg/Type` headers are
    /// accepted. Types still missing are taken from [`builtin_definition`].
    pub fn parse_idl(type_name: &str, text: &str) -> Result<MsgSchema, SchemaError> {
        let root = normalize_type_name(type_name, "");
        let cleaned: String = text
            .lines()
            .map(|l| {
                let t = l.trim();
                let separator = t.len() >= 3 && t.chars().all(|c| c == '=');
                if separator || t.starts_with("IDL:") {
                    ""
                } else {
                    l
                }
            })
            .collect::<Vec<_>>()
            .join("\n");
        let toks = tokenize_idl(&root, &cleaned)?;
        let mut parser = IdlParser {
            type_name,
            toks,
            pos: 0,
            scope: Vec::new(),
            typedefs: HashMap::new(),
            enums: HashSet::new(),
            depth: 0,
            types: HashMap::new(),
        };
        parser.definitions(false)?;
        let mut schema = MsgSchema {
            root,
            types: parser.types,
        };
        schema.resolve_missing(Dialect::Ros2, &[])?;
        Ok(schema)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn idl_modules_typedefs_sequences_enums() {
        let text = "#include <x.idl>\nmodule p { module msg {\n typedef double d3[3];\n enum Color { RED, GREEN };\n\
                    /* block */ struct S { sequence<int16> v; sequence<string, 4> names; d3 xyz; Color c; unsigned long long big; string<8> s; };\n}; };";
        let s = MsgSchema::parse_idl("p/msg/S", text).unwrap();
        let f = &s.types["p/msg/S"].fields;
        assert_eq!(f[0].array, ArrayKind::Unbounded);
        assert_eq!(f[1].array, ArrayKind::Bounded(4));
        assert_eq!(
            (f[2].ty.clone(), f[2].array),
            (FieldType::Primitive(Primitive::F64), ArrayKind::Fixed(3))
        );
        assert_eq!(f[3].ty, FieldType::Primitive(Primitive::U32));
        assert_eq!(f[4].ty, FieldType::Primitive(Primitive::U64));
        assert_eq!(f[5].ty, FieldType::Primitive(Primitive::String));
    }
}
