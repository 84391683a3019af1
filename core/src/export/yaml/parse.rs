//! The strict reader: text → [`Node`] tree for exactly the YAML subset described in the
//! parent module, refusing anything else with its line number.

use crate::error::{CoreError, CoreResult};

/// A parsed YAML node of the supported subset.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Node {
    /// `key:` with nothing after it and nothing nested.
    Null,
    /// A scalar's text; `quoted` scalars are always strings.
    Scalar { text: String, quoted: bool },
    /// A block or flow sequence.
    Seq(Vec<Node>),
    /// A block mapping, in document order, with its tag (`!!opencv-matrix`) if any.
    Map {
        tag: Option<String>,
        entries: Vec<(String, Node)>,
    },
}

/// The only tag the reader accepts.
pub(crate) const OPENCV_MATRIX_TAG: &str = "!!opencv-matrix";

/// One significant line: 1-based number, indentation, content without comment and trailing
/// whitespace.
struct Line<'a> {
    no: usize,
    indent: usize,
    text: &'a str,
}

fn syntax(line: usize, msg: impl std::fmt::Display) -> CoreError {
    CoreError::input(format!("line {line}: {msg}"))
}

/// Whether a quote at byte `i` of `s` opens a quoted scalar: at the start of a token only, so
/// that an apostrophe inside a plain scalar (`don't`) is not taken for one.
fn opens_quote(s: &str, i: usize) -> bool {
    s[..i]
        .chars()
        .next_back()
        .is_none_or(|p| p.is_whitespace() || matches!(p, '[' | ',' | ':' | '-' | '{'))
}

/// `s` without a trailing `# comment` (a `#` outside quotes, at the start or after whitespace).
fn strip_comment(s: &str) -> &str {
    let mut quote: Option<char> = None;
    let mut escaped = false;
    for (i, c) in s.char_indices() {
        match quote {
            Some('"') => {
                if escaped {
                    escaped = false;
                } else if c == '\\' {
                    escaped = true;
                } else if c == '"' {
                    quote = None;
                }
            }
            Some(q) => {
                if c == q {
                    quote = None;
                }
            }
            None => {
                if (c == '"' || c == '\'') && opens_quote(s, i) {
                    quote = Some(c);
                } else if c == '#' && s[..i].chars().next_back().is_none_or(char::is_whitespace) {
                    return &s[..i];
                }
            }
        }
    }
    s
}

/// Splits the text into significant lines, handling the directive, `---` and `...`.
fn significant_lines(text: &str) -> CoreResult<Vec<Line<'_>>> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = Vec::new();
    let mut started = false;
    let mut seen_start_marker = false;
    for (i, raw) in text.lines().enumerate() {
        let no = i + 1;
        let content = strip_comment(raw).trim_end();
        if content.is_empty() {
            continue;
        }
        let body = content.trim_start_matches(' ');
        let indent = content.len() - body.len();
        if body.starts_with('\t') {
            return Err(syntax(no, "tab in indentation (YAML allows spaces only)"));
        }
        if indent == 0 && body.starts_with('%') {
            if started || seen_start_marker || !body.starts_with("%YAML") {
                return Err(syntax(no, format!("unsupported directive `{body}`")));
            }
            continue;
        }
        if indent == 0 && (body == "---" || body.starts_with("--- ")) {
            if started || seen_start_marker {
                return Err(syntax(no, "several YAML documents are not supported"));
            }
            if body != "---" {
                return Err(syntax(no, "content after `---` is not supported"));
            }
            seen_start_marker = true;
            continue;
        }
        if indent == 0 && body == "..." {
            break;
        }
        started = true;
        lines.push(Line {
            no,
            indent,
            text: body,
        });
    }
    Ok(lines)
}

/// Parses a document whose root is a block mapping.
pub(crate) fn parse(text: &str) -> CoreResult<Vec<(String, Node)>> {
    let lines = significant_lines(text)?;
    let Some(first) = lines.first() else {
        return Err(CoreError::input("empty document"));
    };
    let mut p = Parser {
        lines: &lines,
        pos: 0,
    };
    let root_indent = first.indent;
    if is_seq_item(first.text) {
        return Err(syntax(first.no, "the document root must be a mapping"));
    }
    let entries = p.map(root_indent)?;
    if let Some(l) = p.peek() {
        return Err(syntax(l.no, "unexpected indentation"));
    }
    Ok(entries)
}

fn is_seq_item(text: &str) -> bool {
    text == "-" || text.starts_with("- ")
}

struct Parser<'l, 'a> {
    lines: &'l [Line<'a>],
    pos: usize,
}

impl<'a> Parser<'_, 'a> {
    fn peek(&self) -> Option<&Line<'a>> {
        self.lines.get(self.pos)
    }

    /// A block mapping whose keys sit at `indent`.
    fn map(&mut self, indent: usize) -> CoreResult<Vec<(String, Node)>> {
        let mut entries: Vec<(String, Node)> = Vec::new();
        while let Some(line) = self.peek() {
            if line.indent < indent {
                break;
            }
            let no = line.no;
            if line.indent > indent {
                return Err(syntax(no, "unexpected indentation"));
            }
            if is_seq_item(line.text) {
                return Err(syntax(
                    no,
                    "a sequence item where a mapping key was expected",
                ));
            }
            let (key, rest) = split_key(line.text, no)?;
            if entries.iter().any(|(k, _)| *k == key) {
                return Err(syntax(no, format!("duplicate key `{key}`")));
            }
            self.pos += 1;
            let value = self.value(rest, indent, no)?;
            entries.push((key, value));
        }
        Ok(entries)
    }

    /// The value after `key:` on line `no`, the key being at `indent`.
    fn value(&mut self, rest: &str, indent: usize, no: usize) -> CoreResult<Node> {
        let rest = rest.trim();
        if rest.is_empty() {
            return self.nested(indent);
        }
        if rest.starts_with('!') {
            let (tag, after) = rest.split_once(' ').unwrap_or((rest, ""));
            if tag != OPENCV_MATRIX_TAG {
                return Err(syntax(no, format!("unsupported tag `{tag}`")));
            }
            if !after.trim().is_empty() {
                return Err(syntax(
                    no,
                    format!("`{tag}` must be followed by an indented block mapping"),
                ));
            }
            return match self.nested(indent)? {
                Node::Map { entries, .. } => Ok(Node::Map {
                    tag: Some(tag.to_string()),
                    entries,
                }),
                _ => Err(syntax(
                    no,
                    format!("`{tag}` must be followed by an indented block mapping"),
                )),
            };
        }
        self.inline_value(rest, no)
    }

    /// A value written on the same line as its key or dash: flow sequence or scalar.
    fn inline_value(&mut self, rest: &str, no: usize) -> CoreResult<Node> {
        match rest.chars().next() {
            Some('[') => self.flow(rest, no),
            Some('{') => Err(syntax(no, "flow mappings `{…}` are not supported")),
            Some('&') | Some('*') => Err(syntax(no, "anchors and aliases are not supported")),
            Some('|') | Some('>') => Err(syntax(no, "block scalars are not supported")),
            Some('!') => Err(syntax(no, "tags are only supported on block mappings")),
            Some('@') | Some('`') => Err(syntax(no, "reserved indicator at scalar start")),
            _ => {
                let (node, used) = scalar(rest, no, false)?;
                if used != rest.len() {
                    return Err(syntax(no, "unexpected text after a quoted scalar"));
                }
                Ok(node)
            }
        }
    }

    /// The block under a `key:` at `indent`: a more indented mapping or sequence, a sequence at
    /// the same indentation (as PyYAML writes), or nothing.
    fn nested(&mut self, indent: usize) -> CoreResult<Node> {
        let Some(line) = self.peek() else {
            return Ok(Node::Null);
        };
        let (child, seq) = (line.indent, is_seq_item(line.text));
        if child > indent {
            if seq {
                self.seq(child)
            } else {
                Ok(Node::Map {
                    tag: None,
                    entries: self.map(child)?,
                })
            }
        } else if child == indent && seq {
            self.seq(child)
        } else {
            Ok(Node::Null)
        }
    }

    /// A block sequence whose dashes sit at `indent`.
    fn seq(&mut self, indent: usize) -> CoreResult<Node> {
        let mut items = Vec::new();
        while let Some(line) = self.peek() {
            if line.indent != indent || !is_seq_item(line.text) {
                break;
            }
            let no = line.no;
            let item = line.text[1..].trim();
            self.pos += 1;
            if item.is_empty() {
                return Err(syntax(no, "nested block items are not supported"));
            }
            if !item.starts_with('[')
                && !item.starts_with('"')
                && !item.starts_with('\'')
                && (item.contains(": ") || item.ends_with(':'))
            {
                return Err(syntax(no, "mappings inside sequences are not supported"));
            }
            items.push(self.inline_value(item, no)?);
        }
        Ok(Node::Seq(items))
    }

    /// A flow sequence starting at `first` on line `no`, continued on following lines until
    /// its brackets balance.
    fn flow(&mut self, first: &str, no: usize) -> CoreResult<Node> {
        let mut buf = first.to_string();
        while !brackets_closed(&buf) {
            let Some(line) = self.peek() else {
                return Err(syntax(no, "unterminated `[`"));
            };
            buf.push(' ');
            buf.push_str(line.text);
            self.pos += 1;
        }
        let mut pos = 0;
        let node = flow_seq(&buf, &mut pos, no)?;
        if !buf[pos..].trim().is_empty() {
            return Err(syntax(no, "unexpected text after `]`"));
        }
        Ok(node)
    }
}

/// `key` and the rest after `key:`.
fn split_key(text: &str, no: usize) -> CoreResult<(String, &str)> {
    if text.starts_with('"') || text.starts_with('\'') {
        let (node, used) = scalar(text, no, false)?;
        let Node::Scalar { text: key, .. } = node else {
            return Err(syntax(no, "bad key"));
        };
        let after = &text[used..];
        let Some(rest) = after.trim_start().strip_prefix(':') else {
            return Err(syntax(no, "expected `:` after a quoted key"));
        };
        if !(rest.is_empty() || rest.starts_with(' ')) {
            return Err(syntax(no, "expected a space after `:`"));
        }
        return Ok((key, rest));
    }
    if text.starts_with(['?', '[', '{', '&', '*', '!', '|', '>', '@', '`']) {
        return Err(syntax(no, format!("unsupported mapping key `{text}`")));
    }
    let split = text
        .find(": ")
        .or_else(|| text.ends_with(':').then(|| text.len() - 1));
    let Some(i) = split else {
        return Err(syntax(no, format!("expected `key: value`, got `{text}`")));
    };
    let key = text[..i].trim_end();
    if key.is_empty() {
        return Err(syntax(no, "empty mapping key"));
    }
    Ok((key.to_string(), &text[i + 1..]))
}

/// Whether the `[`s in `s` (outside quotes) are all closed.
fn brackets_closed(s: &str) -> bool {
    let mut depth = 0i64;
    let mut quote: Option<char> = None;
    let mut escaped = false;
    for (i, c) in s.char_indices() {
        match quote {
            Some(q) => {
                if q == '"' && escaped {
                    escaped = false;
                } else if q == '"' && c == '\\' {
                    escaped = true;
                } else if c == q {
                    quote = None;
                }
            }
            None => match c {
                '"' | '\'' if opens_quote(s, i) => quote = Some(c),
                '[' => depth += 1,
                ']' => depth -= 1,
                _ => {}
            },
        }
    }
    depth <= 0
}

/// A flow sequence at byte `*pos` of `s` (which must be `[`); advances past the `]`.
fn flow_seq(s: &str, pos: &mut usize, no: usize) -> CoreResult<Node> {
    let bytes = s.as_bytes();
    let skip_ws = |pos: &mut usize| {
        while *pos < bytes.len() && bytes[*pos].is_ascii_whitespace() {
            *pos += 1;
        }
    };
    if bytes.get(*pos) != Some(&b'[') {
        return Err(syntax(no, "expected `[`"));
    }
    *pos += 1;
    let mut items = Vec::new();
    loop {
        skip_ws(pos);
        match bytes.get(*pos) {
            None => return Err(syntax(no, "unterminated `[`")),
            // `[]`, or a trailing comma `[a, b, ]` (valid YAML).
            Some(b']') => {
                *pos += 1;
                return Ok(Node::Seq(items));
            }
            Some(b'[') => items.push(flow_seq(s, pos, no)?),
            Some(b'{') => return Err(syntax(no, "flow mappings `{…}` are not supported")),
            Some(b',') => return Err(syntax(no, "empty entry in a flow sequence")),
            Some(_) => {
                let (node, used) = scalar(&s[*pos..], no, true)?;
                *pos += used;
                items.push(node);
            }
        }
        skip_ws(pos);
        match bytes.get(*pos) {
            Some(b',') => *pos += 1,
            Some(b']') => {
                *pos += 1;
                return Ok(Node::Seq(items));
            }
            None => return Err(syntax(no, "unterminated `[`")),
            Some(_) => return Err(syntax(no, "expected `,` or `]` in a flow sequence")),
        }
    }
}

/// A scalar at the start of `s`, and the bytes it used. In flow context a plain scalar ends
/// at `,` or `]`; in block context it is the whole (comment-stripped) rest of the line.
fn scalar(s: &str, no: usize, in_flow: bool) -> CoreResult<(Node, usize)> {
    let mut chars = s.char_indices();
    match chars.next() {
        Some((_, '\'')) => {
            let mut out = String::new();
            let mut it = s.char_indices().skip(1).peekable();
            while let Some((i, c)) = it.next() {
                if c == '\'' {
                    if it.peek().map(|(_, c)| *c) == Some('\'') {
                        out.push('\'');
                        it.next();
                    } else {
                        return Ok((
                            Node::Scalar {
                                text: out,
                                quoted: true,
                            },
                            i + 1,
                        ));
                    }
                } else {
                    out.push(c);
                }
            }
            Err(syntax(no, "unterminated single-quoted scalar"))
        }
        Some((_, '"')) => {
            let mut out = String::new();
            let mut it = s.char_indices().skip(1);
            while let Some((i, c)) = it.next() {
                match c {
                    '"' => {
                        return Ok((
                            Node::Scalar {
                                text: out,
                                quoted: true,
                            },
                            i + 1,
                        ));
                    }
                    '\\' => {
                        let e = match it.next().map(|(_, e)| e) {
                            Some('\\') => '\\',
                            Some('"') => '"',
                            Some('/') => '/',
                            Some('n') => '\n',
                            Some('t') => '\t',
                            Some('r') => '\r',
                            Some(other) => {
                                return Err(syntax(
                                    no,
                                    format!("unsupported escape `\\{other}` in a quoted scalar"),
                                ));
                            }
                            None => break,
                        };
                        out.push(e);
                    }
                    c => out.push(c),
                }
            }
            Err(syntax(no, "unterminated double-quoted scalar"))
        }
        Some(_) => {
            let end = if in_flow {
                s.find([',', ']']).unwrap_or(s.len())
            } else {
                s.len()
            };
            let text = s[..end].trim();
            if text.is_empty() {
                return Err(syntax(no, "empty scalar"));
            }
            Ok((
                Node::Scalar {
                    text: text.to_string(),
                    quoted: false,
                },
                end,
            ))
        }
        None => Err(syntax(no, "empty scalar")),
    }
}
