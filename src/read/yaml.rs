//! The block-style YAML subset rosbag2 (yaml-cpp) and the Python `rosbags` library write:
//! nested mappings and sequences by indentation, plain/quoted/multi-line scalars, block
//! scalars, empty flow collections and flow sequences of scalars.
//! Nesting is limited to `MAX_DEPTH` levels so a hostile file cannot overflow the stack.

/// A YAML node.
#[derive(Debug, Clone, PartialEq)]
pub enum Yaml {
    /// `~`, `null` or nothing.
    Null,
    /// A scalar.
    Str(String),
    /// A sequence.
    Seq(Vec<Yaml>),
    /// A mapping, keys in file order.
    Map(Vec<(String, Yaml)>),
}

impl Yaml {
    /// The value of `key` in a mapping.
    pub fn get(&self, key: &str) -> Option<&Yaml> {
        match self {
            Yaml::Map(entries) => entries.iter().find(|(k, _)| k == key).map(|(_, v)| v),
            _ => None,
        }
    }

    /// A scalar's text (`""` for null).
    pub fn as_str(&self) -> Option<&str> {
        match self {
            Yaml::Str(s) => Some(s),
            Yaml::Null => Some(""),
            _ => None,
        }
    }
}

/// Deepest nesting of mappings and sequences accepted (rosbag2 metadata uses 6).
const MAX_DEPTH: usize = 64;

/// One non-empty, non-comment line.
struct Line {
    indent: usize,
    text: String,
    number: usize,
}

/// Parse a whole document; errors name the line.
pub fn parse(text: &str) -> Result<Yaml, String> {
    let mut lines: Vec<Line> = Vec::new();
    for (n, raw) in text.lines().enumerate() {
        let trimmed = raw.trim_end();
        let content = trimmed.trim_start();
        if content.is_empty() || content.starts_with('#') || content == "---" {
            continue;
        }
        if content == "..." {
            break;
        }
        if raw.starts_with('\t') {
            return Err(format!("line {}: tab indentation", n + 1));
        }
        lines.push(Line {
            indent: trimmed.len() - content.len(),
            text: content.to_string(),
            number: n + 1,
        });
    }
    let indent = lines.first().map_or(0, |l| l.indent);
    let mut p = Parser { lines, i: 0 };
    let node = p.node(indent, 0)?;
    if let Some(l) = p.lines.get(p.i) {
        return Err(format!("line {}: unexpected indentation", l.number));
    }
    Ok(node)
}

fn is_seq_item(text: &str) -> bool {
    text == "-" || text.starts_with("- ")
}

/// The document's lines and the next one to read.
struct Parser {
    lines: Vec<Line>,
    i: usize,
}

impl Parser {
    /// Refuse nesting deeper than [`MAX_DEPTH`] (the parser recurses once per level).
    fn too_deep(&self, depth: usize) -> Result<(), String> {
        if depth > MAX_DEPTH {
            let line = self.lines.get(self.i).map_or(0, |l| l.number);
            return Err(format!(
                "line {line}: mappings/sequences nested more than {MAX_DEPTH} levels deep"
            ));
        }
        Ok(())
    }

    fn node(&mut self, indent: usize, depth: usize) -> Result<Yaml, String> {
        let Some(line) = self.lines.get(self.i) else {
            return Ok(Yaml::Null);
        };
        if line.indent < indent {
            return Ok(Yaml::Null);
        }
        if is_seq_item(&line.text) {
            self.seq(line.indent, depth + 1)
        } else if split_key(&line.text).is_some() {
            self.map(line.indent, depth + 1)
        } else {
            let (first, number) = (line.text.clone(), line.number);
            let parent = line.indent.saturating_sub(1);
            self.i += 1;
            self.scalar(&first, parent)
                .map_err(|e| format!("line {number}: {e}"))
        }
    }

    fn seq(&mut self, indent: usize, depth: usize) -> Result<Yaml, String> {
        self.too_deep(depth)?;
        let mut items = Vec::new();
        while let Some(line) = self.lines.get_mut(self.i) {
            if line.indent != indent || !is_seq_item(&line.text) {
                break;
            }
            let rest = line.text[1..].trim_start().to_string();
            if rest.is_empty() {
                self.i += 1;
                let child = self.lines.get(self.i).map_or(indent + 1, |l| l.indent);
                items.push(if child > indent {
                    self.node(child, depth)?
                } else {
                    Yaml::Null
                });
            } else {
                // `- key: value` opens a mapping whose keys sit at the column after "- ".
                let column = indent + (line.text.len() - rest.len());
                line.indent = column;
                line.text = rest;
                items.push(self.node(column, depth)?);
            }
        }
        Ok(Yaml::Seq(items))
    }

    fn map(&mut self, indent: usize, depth: usize) -> Result<Yaml, String> {
        self.too_deep(depth)?;
        let mut entries = Vec::new();
        while let Some(line) = self.lines.get(self.i) {
            if line.indent != indent {
                if line.indent > indent {
                    return Err(format!("line {}: unexpected indentation", line.number));
                }
                break;
            }
            let Some((key, rest)) = split_key(&line.text) else {
                return Err(format!("line {}: expected `key: value`", line.number));
            };
            let number = line.number;
            self.i += 1;
            let value = match self.lines.get(self.i) {
                _ if !rest.is_empty() => {
                    (self.scalar(&rest, indent)).map_err(|e| format!("line {number}: {e}"))?
                }
                Some(next) if next.indent > indent => self.node(next.indent, depth)?,
                // A sequence may sit at the same indentation as its key.
                Some(next) if next.indent == indent && is_seq_item(&next.text) => {
                    self.seq(indent, depth + 1)?
                }
                _ => Yaml::Null,
            };
            entries.push((key, value));
        }
        Ok(Yaml::Map(entries))
    }

    /// A scalar starting with `first`, continued on following lines indented deeper than `parent`.
    fn scalar(&mut self, first: &str, parent: usize) -> Result<Yaml, String> {
        let mut continuation = Vec::new();
        while let Some(l) = self.lines.get(self.i).filter(|l| l.indent > parent) {
            continuation.push(l.text.as_str());
            self.i += 1;
        }
        scalar_text(first, &continuation)
    }
}

/// `key: rest` (key possibly quoted) or `key:` at the end of the line.
fn split_key(text: &str) -> Option<(String, String)> {
    let (key, after) = if let Some(q @ ('"' | '\'')) = text.chars().next() {
        let end = text[1..].find(q)? + 1;
        (text[1..end].to_string(), &text[end + 1..])
    } else {
        let pos = text
            .find(": ")
            .or_else(|| text.ends_with(':').then(|| text.len() - 1))?;
        if text.starts_with(['[', '{']) {
            return None;
        }
        (text[..pos].trim_end().to_string(), &text[pos..])
    };
    let rest = after.strip_prefix(':')?;
    if !(rest.is_empty() || rest.starts_with(' ')) {
        return None;
    }
    Some((key, strip_comment(rest.trim()).to_string()))
}

fn strip_comment(text: &str) -> &str {
    if text.starts_with(['"', '\'']) {
        return text;
    }
    match text.find(" #") {
        Some(p) => text[..p].trim_end(),
        None => text,
    }
}

/// The scalar of the text `first` and its continuation lines.
fn scalar_text(first: &str, continuation: &[&str]) -> Result<Yaml, String> {
    let mut text = first.to_string();
    let block = text.starts_with('|') || text.starts_with('>');
    if block {
        let sep = if text.starts_with('|') { "\n" } else { " " };
        return Ok(Yaml::Str(continuation.join(sep)));
    }
    for c in continuation {
        text.push(' ');
        text.push_str(c);
    }
    let text = text.trim();
    Ok(match text {
        "~" | "null" | "Null" | "NULL" => Yaml::Null,
        "[]" => Yaml::Seq(Vec::new()),
        "{}" => Yaml::Map(Vec::new()),
        _ if text.starts_with('"') => Yaml::Str(double_quoted(text)?),
        _ if text.starts_with('\'') => Yaml::Str(
            text.strip_prefix('\'')
                .and_then(|t| t.strip_suffix('\''))
                .ok_or_else(|| format!("unterminated quoted string {text}"))?
                .replace("''", "'"),
        ),
        _ if text.starts_with('[') && text.ends_with(']') => Yaml::Seq(
            text[1..text.len() - 1]
                .split(',')
                .map(|s| Yaml::Str(s.trim().trim_matches(['"', '\'']).to_string()))
                .collect(),
        ),
        _ => Yaml::Str(text.to_string()),
    })
}

fn double_quoted(text: &str) -> Result<String, String> {
    let body = text
        .strip_prefix('"')
        .and_then(|t| t.strip_suffix('"'))
        .ok_or_else(|| format!("unterminated quoted string {text}"))?;
    let mut out = String::with_capacity(body.len());
    let mut chars = body.chars();
    while let Some(c) = chars.next() {
        if c != '\\' {
            out.push(c);
            continue;
        }
        match chars.next() {
            Some('n') => out.push('\n'),
            Some('t') => out.push('\t'),
            Some('r') => out.push('\r'),
            Some('0') => out.push('\0'),
            Some(' ') | None => {}
            Some(other) => out.push(other),
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yaml_cpp_style_v5_metadata() {
        let text = "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: sqlite3\n  \
            relative_file_paths:\n    - a_0.db3\n    - a_1.db3\n  duration:\n    nanoseconds: 10\n  \
            topics_with_message_count:\n    - topic_metadata:\n        name: /chatter\n        \
            type: std_msgs/msg/String\n        offered_qos_profiles: \"- history: 3\\n  depth: 0\"\n      \
            message_count: 100\n  compression_format: \"\"\n  compression_mode: \"\"\n  custom_data: ~\n";
        let doc = parse(text).unwrap();
        let info = doc.get("rosbag2_bagfile_information").unwrap();
        assert_eq!(info.get("version"), Some(&Yaml::Str("5".into())));
        assert_eq!(
            info.get("relative_file_paths"),
            Some(&Yaml::Seq(vec![
                Yaml::Str("a_0.db3".into()),
                Yaml::Str("a_1.db3".into())
            ]))
        );
        let Some(Yaml::Seq(topics)) = info.get("topics_with_message_count") else {
            panic!("no topics")
        };
        let meta = topics[0].get("topic_metadata").unwrap();
        assert_eq!(meta.get("name").unwrap().as_str(), Some("/chatter"));
        assert_eq!(
            meta.get("offered_qos_profiles").unwrap().as_str(),
            Some("- history: 3\n  depth: 0")
        );
        assert_eq!(
            topics[0].get("message_count").unwrap().as_str(),
            Some("100")
        );
        assert_eq!(info.get("compression_mode").unwrap().as_str(), Some(""));
        assert_eq!(info.get("custom_data"), Some(&Yaml::Null));
    }

    #[test]
    fn multi_line_plain_scalar_and_same_indent_sequence() {
        let text = "a:\n  h: \n    RIHS01_abc\n  l:\n  - x\n  - y\n  q: []\n";
        let doc = parse(text).unwrap();
        let a = doc.get("a").unwrap();
        assert_eq!(a.get("h").unwrap().as_str(), Some("RIHS01_abc"));
        assert_eq!(
            a.get("l"),
            Some(&Yaml::Seq(vec![
                Yaml::Str("x".into()),
                Yaml::Str("y".into())
            ]))
        );
        assert_eq!(a.get("q"), Some(&Yaml::Seq(vec![])));
    }
}
