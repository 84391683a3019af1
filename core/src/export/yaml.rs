//! The YAML Caliper writes and reads, by hand.
//!
//! Why not a YAML library: OpenCV's FileStorage starts its files with `%YAML:1.0`, which is not a
//! valid YAML 1.x directive (the spec wants `%YAML 1.1`), and tags matrices `!!opencv-matrix`, a
//! secondary-handle tag no generic parser resolves; both make conforming parsers refuse the file
//! (see `/work/shared/docs/formats.md`). The three formats Caliper exchanges only use a small,
//! regular subset, so a strict reader for exactly that subset is both smaller and safer than
//! pre-processing files for a general parser:
//!
//! * an optional `%YAML…` first line and an optional `---` document start;
//! * block mappings (`key: value`, nested by indentation, spaces only);
//! * block sequences (`- item`, items being scalars or flow sequences; Kalibr's `T_cn_cnm1`);
//! * flow sequences `[a, b, [c, d]]`, possibly spread over several lines (OpenCV wraps `data`);
//! * the tag `!!opencv-matrix` on a block mapping;
//! * plain, `'single'` and `"double"` quoted scalars, and `#` comments.
//!
//! Anything else (anchors, aliases, flow mappings, block scalars, other tags, several documents)
//! is refused with the line number, rather than guessed at.
//!
//! Numbers are written so that they read back bit-for-bit: the shortest decimal that round-trips
//! (Rust's `{:e}`), in C notation with a `.` in the mantissa and a signed exponent
//! (`5.3591573396163199e+02`), because YAML 1.1 resolvers (PyYAML, which Kalibr uses) only
//! recognise a float when it has a dot and a signed exponent: `1e-5` would be read as a string.

use crate::error::{CoreError, CoreResult};

// ---------------------------------------------------------------------------------------------
// Writing

/// How non-finite numbers are spelled: OpenCV writes `.Nan`/`.Inf`, YAML 1.1 wants `.nan`/`.inf`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum NanStyle {
    /// `.Nan`, `.Inf`, `-.Inf` (OpenCV `persistence.cpp`).
    OpenCv,
    /// `.nan`, `.inf`, `-.inf` (YAML 1.1 type repository).
    Yaml,
}

/// A non-finite value in the given style, or `None` for a finite one.
fn non_finite(is_nan: bool, is_inf: bool, negative: bool, style: NanStyle) -> Option<String> {
    let s = match (is_nan, is_inf, negative, style) {
        (true, _, _, NanStyle::OpenCv) => ".Nan",
        (true, _, _, NanStyle::Yaml) => ".nan",
        (_, true, false, NanStyle::OpenCv) => ".Inf",
        (_, true, true, NanStyle::OpenCv) => "-.Inf",
        (_, true, false, NanStyle::Yaml) => ".inf",
        (_, true, true, NanStyle::Yaml) => "-.inf",
        _ => return None,
    };
    Some(s.to_string())
}

/// `d.ddd[e±XX]` from Rust's shortest `{:e}` output (`5.35e2` → `5.35e+02`, `1e-5` → `1.0e-05`).
fn c_exponent(shortest: &str) -> String {
    let Some((mantissa, exponent)) = shortest.split_once('e') else {
        return shortest.to_string();
    };
    let Ok(exponent) = exponent.parse::<i32>() else {
        return shortest.to_string();
    };
    let dot = if mantissa.contains('.') { "" } else { ".0" };
    format!("{mantissa}{dot}e{exponent:+03}")
}

/// A double that reads back to the same bits, in a form every YAML reader types as a float.
///
/// Integral values below 10¹⁵ print as `640.0` (and `-0.0` keeps its sign); everything else as
/// the shortest round-trip decimal in C exponent notation.
pub(crate) fn fmt_f64(v: f64, style: NanStyle) -> String {
    if let Some(s) = non_finite(v.is_nan(), v.is_infinite(), v < 0.0, style) {
        return s;
    }
    if v == v.trunc() && v.abs() < 1e15 {
        return format!("{v:.1}");
    }
    c_exponent(&format!("{v:e}"))
}

/// [`fmt_f64`] for a single-precision value (OpenCV `dt: f` data).
pub(crate) fn fmt_f32(v: f32, style: NanStyle) -> String {
    if let Some(s) = non_finite(v.is_nan(), v.is_infinite(), v < 0.0, style) {
        return s;
    }
    if v == v.trunc() && v.abs() < 1e7 {
        return format!("{v:.1}");
    }
    c_exponent(&format!("{v:e}"))
}

/// A double-quoted YAML scalar. Control characters are refused rather than escaped: none of
/// the strings we write (names, topics, times) has a reason to contain one, and OpenCV's reader
/// understands only a few escapes.
pub(crate) fn quote(field: &str, s: &str) -> CoreResult<String> {
    if let Some(c) = s.chars().find(|c| c.is_control()) {
        return Err(CoreError::param(
            field,
            format!(
                "must not contain control characters (found U+{:04X})",
                c as u32
            ),
        ));
    }
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        if c == '"' || c == '\\' {
            out.push('\\');
        }
        out.push(c);
    }
    out.push('"');
    Ok(out)
}

/// `[a, b, c]` on one line.
pub(crate) fn flow(items: &[String]) -> String {
    format!("[{}]", items.join(", "))
}

/// OpenCV-style wrapped flow data: `[ a, b,\n       c ]` with continuation lines indented by
/// `indent` spaces and kept under about 80 columns, as FileStorage does.
pub(crate) fn flow_wrapped(items: &[String], first_col: usize, indent: usize) -> String {
    let mut out = String::from("[ ");
    let mut col = first_col + 2;
    for (i, item) in items.iter().enumerate() {
        let last = i + 1 == items.len();
        let piece_len = item.len() + if last { 2 } else { 1 };
        if i > 0 && col + piece_len > 80 {
            out.push('\n');
            out.push_str(&" ".repeat(indent));
            col = indent;
        } else if i > 0 {
            out.push(' ');
            col += 1;
        }
        out.push_str(item);
        col += item.len();
        if !last {
            out.push(',');
            col += 1;
        }
    }
    out.push_str(" ]");
    out
}

// ---------------------------------------------------------------------------------------------
// Reading

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

// ---------------------------------------------------------------------------------------------
// Typed access with the key named in every error

/// `fmt: `key`: msg` as [`CoreError::InvalidInput`].
pub(crate) fn bad(fmt: &str, key: &str, msg: impl std::fmt::Display) -> CoreError {
    CoreError::input(format!("{fmt}: `{key}`: {msg}"))
}

/// The entries of a mapping, looked up by any of a key's accepted spellings.
pub(crate) struct Fields<'a> {
    /// Format name for messages (`opencv-yaml`, …).
    pub fmt: &'static str,
    pub entries: &'a [(String, Node)],
}

impl<'a> Fields<'a> {
    pub(crate) fn new(fmt: &'static str, entries: &'a [(String, Node)]) -> Self {
        Self { fmt, entries }
    }

    /// The value under whichever of `names` is present (the first name is the canonical one,
    /// used in messages); an error if several spellings are present.
    pub(crate) fn find(&self, names: &[&str]) -> CoreResult<Option<(&'a str, &'a Node)>> {
        let mut found: Option<(&'a str, &'a Node)> = None;
        for (k, v) in self.entries {
            if names.contains(&k.as_str()) {
                if let Some((first, _)) = found {
                    return Err(CoreError::input(format!(
                        "{}: both `{first}` and `{k}` are present",
                        self.fmt
                    )));
                }
                found = Some((k.as_str(), v));
            }
        }
        Ok(found)
    }

    /// Like [`Fields::find`] but missing is an error naming the canonical key.
    pub(crate) fn require(&self, names: &[&str]) -> CoreResult<(&'a str, &'a Node)> {
        self.find(names)?.ok_or_else(|| {
            let others = if names.len() > 1 {
                format!(" (also accepted: {})", names[1..].join(", "))
            } else {
                String::new()
            };
            CoreError::input(format!("{}: missing key `{}`{others}", self.fmt, names[0]))
        })
    }

    pub(crate) fn f64(&self, names: &[&str]) -> CoreResult<Option<f64>> {
        self.find(names)?
            .map(|(k, v)| as_f64(self.fmt, k, v))
            .transpose()
    }

    pub(crate) fn int(&self, names: &[&str]) -> CoreResult<Option<i64>> {
        self.find(names)?
            .map(|(k, v)| as_int(self.fmt, k, v))
            .transpose()
    }

    pub(crate) fn string(&self, names: &[&str]) -> CoreResult<Option<String>> {
        self.find(names)?
            .map(|(k, v)| as_str(self.fmt, k, v).map(str::to_string))
            .transpose()
    }

    /// A required positive size that fits `u32`.
    pub(crate) fn size(&self, names: &[&str]) -> CoreResult<u32> {
        let (k, v) = self.require(names)?;
        positive_u32(self.fmt, k, as_int(self.fmt, k, v)?)
    }
}

pub(crate) fn positive_u32(fmt: &str, key: &str, v: i64) -> CoreResult<u32> {
    u32::try_from(v)
        .ok()
        .filter(|v| *v > 0)
        .ok_or_else(|| bad(fmt, key, format!("must be a positive integer, got {v}")))
}

/// The text of an unquoted scalar (numbers must not be quoted: YAML would type them strings).
fn plain<'n>(fmt: &str, key: &str, node: &'n Node, what: &str) -> CoreResult<&'n str> {
    match node {
        Node::Scalar {
            text,
            quoted: false,
        } => Ok(text),
        Node::Scalar { text, quoted: true } => Err(bad(
            fmt,
            key,
            format!("expected {what}, got the quoted string {text:?}"),
        )),
        other => Err(bad(
            fmt,
            key,
            format!("expected {what}, got {}", describe(other)),
        )),
    }
}

pub(crate) fn describe(node: &Node) -> &'static str {
    match node {
        Node::Null => "nothing",
        Node::Scalar { .. } => "a scalar",
        Node::Seq(_) => "a sequence",
        Node::Map { tag: Some(_), .. } => "a tagged mapping",
        Node::Map { tag: None, .. } => "a mapping",
    }
}

/// Whether `t` is a decimal number: `[+-]digits[.digits][e[+-]digits]` with at least one
/// mantissa digit (so `inf`, `nan`, `0x1p3`, `1_000` are refused).
fn is_decimal(t: &str) -> bool {
    let t = t.strip_prefix(['+', '-']).unwrap_or(t);
    let (mantissa, exponent) = match t.find(['e', 'E']) {
        Some(i) => (&t[..i], Some(&t[i + 1..])),
        None => (t, None),
    };
    let (int, frac) = mantissa.split_once('.').unwrap_or((mantissa, ""));
    let digits = |s: &str| s.bytes().all(|b| b.is_ascii_digit());
    let mantissa_ok = digits(int) && digits(frac) && !(int.is_empty() && frac.is_empty());
    let exponent_ok = exponent.is_none_or(|e| {
        let e = e.strip_prefix(['+', '-']).unwrap_or(e);
        !e.is_empty() && digits(e)
    });
    mantissa_ok && exponent_ok
}

/// `.nan`, `.inf`, `-.inf`, any case (OpenCV writes `.Nan`, YAML `.nan`/`.NaN`).
fn special_float(t: &str) -> Option<f64> {
    let lower = t.to_ascii_lowercase();
    match lower.as_str() {
        ".nan" => Some(f64::NAN),
        ".inf" | "+.inf" => Some(f64::INFINITY),
        "-.inf" => Some(f64::NEG_INFINITY),
        _ => None,
    }
}

pub(crate) fn parse_f64(fmt: &str, key: &str, t: &str) -> CoreResult<f64> {
    if let Some(v) = special_float(t) {
        return Ok(v);
    }
    if !is_decimal(t) {
        return Err(bad(fmt, key, format!("expected a number, got `{t}`")));
    }
    t.parse::<f64>()
        .map_err(|e| bad(fmt, key, format!("`{t}`: {e}")))
}

pub(crate) fn parse_f32(fmt: &str, key: &str, t: &str) -> CoreResult<f32> {
    if let Some(v) = special_float(t) {
        return Ok(v as f32);
    }
    if !is_decimal(t) {
        return Err(bad(fmt, key, format!("expected a number, got `{t}`")));
    }
    t.parse::<f32>()
        .map_err(|e| bad(fmt, key, format!("`{t}`: {e}")))
}

pub(crate) fn parse_int(fmt: &str, key: &str, t: &str) -> CoreResult<i64> {
    let digits = t.strip_prefix(['+', '-']).unwrap_or(t);
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return Err(bad(fmt, key, format!("expected an integer, got `{t}`")));
    }
    t.parse::<i64>()
        .map_err(|e| bad(fmt, key, format!("`{t}`: {e}")))
}

pub(crate) fn as_f64(fmt: &str, key: &str, node: &Node) -> CoreResult<f64> {
    parse_f64(fmt, key, plain(fmt, key, node, "a number")?)
}

pub(crate) fn as_int(fmt: &str, key: &str, node: &Node) -> CoreResult<i64> {
    parse_int(fmt, key, plain(fmt, key, node, "an integer")?)
}

pub(crate) fn as_str<'n>(fmt: &str, key: &str, node: &'n Node) -> CoreResult<&'n str> {
    match node {
        Node::Scalar { text, .. } => Ok(text),
        other => Err(bad(
            fmt,
            key,
            format!("expected a string, got {}", describe(other)),
        )),
    }
}

pub(crate) fn as_seq<'n>(fmt: &str, key: &str, node: &'n Node) -> CoreResult<&'n [Node]> {
    match node {
        Node::Seq(items) => Ok(items),
        other => Err(bad(
            fmt,
            key,
            format!("expected a sequence, got {}", describe(other)),
        )),
    }
}

pub(crate) fn as_map<'n>(fmt: &str, key: &str, node: &'n Node) -> CoreResult<&'n [(String, Node)]> {
    match node {
        Node::Map { entries, .. } => Ok(entries),
        other => Err(bad(
            fmt,
            key,
            format!("expected a mapping, got {}", describe(other)),
        )),
    }
}

/// A flow or block sequence of numbers.
pub(crate) fn f64_seq(fmt: &str, key: &str, node: &Node) -> CoreResult<Vec<f64>> {
    as_seq(fmt, key, node)?
        .iter()
        .map(|n| as_f64(fmt, key, n))
        .collect()
}

/// A sequence of exactly `n` numbers.
pub(crate) fn f64_array<const N: usize>(fmt: &str, key: &str, node: &Node) -> CoreResult<[f64; N]> {
    let v = f64_seq(fmt, key, node)?;
    let len = v.len();
    v.try_into()
        .map_err(|_| bad(fmt, key, format!("expected {N} numbers, got {len}")))
}

/// A matrix read from a mapping: `rows`, `cols`, row-major `data` (element type already
/// applied: single-precision data are rounded to `f32`).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Matrix {
    pub rows: usize,
    pub cols: usize,
    pub data: Vec<f64>,
}

impl Matrix {
    /// Errors unless the matrix is `rows × cols`.
    pub(crate) fn expect(&self, fmt: &str, key: &str, rows: usize, cols: usize) -> CoreResult<()> {
        if self.rows != rows || self.cols != cols {
            return Err(bad(
                fmt,
                key,
                format!(
                    "expected a {rows}×{cols} matrix, got {}×{}",
                    self.rows, self.cols
                ),
            ));
        }
        Ok(())
    }

    /// The entries of an N×1 or 1×N matrix (OpenCV writes either, depending on how the
    /// vector was allocated), or an error.
    pub(crate) fn vector(&self, fmt: &str, key: &str) -> CoreResult<&[f64]> {
        if self.cols == 1 || self.rows == 1 || self.data.is_empty() {
            Ok(&self.data)
        } else {
            Err(bad(
                fmt,
                key,
                format!(
                    "expected an N×1 or 1×N matrix, got {}×{}",
                    self.rows, self.cols
                ),
            ))
        }
    }
}

/// Largest matrix the reader builds (calibration files have at most a few thousand entries;
/// this only stops a hostile `rows` from allocating gigabytes before `data` is checked).
const MAX_MATRIX_ENTRIES: usize = 10_000_000;

fn dims(fmt: &str, key: &str, f: &Fields<'_>) -> CoreResult<(usize, usize)> {
    let mut out = [0usize; 2];
    for (slot, name) in out.iter_mut().zip(["rows", "cols"]) {
        let (_, node) = f
            .require(&[name])
            .map_err(|_| bad(fmt, key, format!("missing `{name}`")))?;
        let v = as_int(fmt, &format!("{key}.{name}"), node)?;
        *slot = usize::try_from(v)
            .map_err(|_| bad(fmt, key, format!("`{name}` must be ≥ 0, got {v}")))?;
    }
    Ok((out[0], out[1]))
}

fn check_keys(
    fmt: &str,
    key: &str,
    entries: &[(String, Node)],
    allowed: &[&str],
) -> CoreResult<()> {
    match entries.iter().find(|(k, _)| !allowed.contains(&k.as_str())) {
        Some((k, _)) => Err(bad(
            fmt,
            key,
            format!("unexpected field `{k}` (expected {})", allowed.join(", ")),
        )),
        None => Ok(()),
    }
}

/// An OpenCV `!!opencv-matrix` (`rows`, `cols`, `dt`, `data`).
///
/// `dt` is OpenCV's element-type code (`u c w s i f d`, optionally preceded by a channel count);
/// multi-channel matrices are refused since no key we read has one. Integer data must be
/// integers; `f` data are parsed as `f32`, exactly as OpenCV would store them.
pub(crate) fn opencv_matrix(fmt: &str, key: &str, node: &Node) -> CoreResult<Matrix> {
    let Node::Map {
        tag: Some(tag),
        entries,
    } = node
    else {
        return Err(bad(
            fmt,
            key,
            format!("expected a {OPENCV_MATRIX_TAG}, got {}", describe(node)),
        ));
    };
    if tag != OPENCV_MATRIX_TAG {
        return Err(bad(fmt, key, format!("unsupported tag `{tag}`")));
    }
    check_keys(fmt, key, entries, &["rows", "cols", "dt", "data"])?;
    let f = Fields::new("", entries);
    let (rows, cols) = dims(fmt, key, &f)?;
    let (_, dt) = f
        .require(&["dt"])
        .map_err(|_| bad(fmt, key, "missing `dt`"))?;
    let dt = as_str(fmt, key, dt)?;
    let (channels, elem) = dt.split_at(dt.len().saturating_sub(1));
    if !(channels.is_empty() || channels == "1") {
        return Err(bad(
            fmt,
            key,
            format!("multi-channel matrices (`dt: {dt}`) are not supported"),
        ));
    }
    let (_, data) = f
        .require(&["data"])
        .map_err(|_| bad(fmt, key, "missing `data`"))?;
    let items = as_seq(fmt, key, data)?;
    check_len(fmt, key, rows, cols, items.len())?;
    let data_key = format!("{key}.data");
    let data = items
        .iter()
        .map(|n| {
            let t = plain(fmt, &data_key, n, "a number")?;
            match elem {
                "d" => parse_f64(fmt, &data_key, t),
                "f" => parse_f32(fmt, &data_key, t).map(f64::from),
                "u" | "c" | "w" | "s" | "i" => {
                    let v = parse_int(fmt, &data_key, t)?;
                    let (lo, hi) = match elem {
                        "u" => (0, 255),
                        "c" => (-128, 127),
                        "w" => (0, 65_535),
                        "s" => (-32_768, 32_767),
                        _ => (i64::from(i32::MIN), i64::from(i32::MAX)),
                    };
                    if !(lo..=hi).contains(&v) {
                        return Err(bad(
                            fmt,
                            &data_key,
                            format!("{v} out of range for `dt: {elem}`"),
                        ));
                    }
                    Ok(v as f64)
                }
                _ => Err(bad(fmt, key, format!("unknown element type `dt: {dt}`"))),
            }
        })
        .collect::<CoreResult<Vec<f64>>>()?;
    Ok(Matrix { rows, cols, data })
}

fn check_len(fmt: &str, key: &str, rows: usize, cols: usize, len: usize) -> CoreResult<()> {
    let n = rows
        .checked_mul(cols)
        .filter(|n| *n <= MAX_MATRIX_ENTRIES)
        .ok_or_else(|| bad(fmt, key, format!("{rows}×{cols} is too large")))?;
    if len != n {
        return Err(bad(
            fmt,
            key,
            format!("{rows}×{cols} matrix needs {n} data entries, got {len}"),
        ));
    }
    Ok(())
}

/// A ROS-style matrix mapping (`rows`, `cols`, `data`, no `dt`, no tag).
pub(crate) fn ros_matrix(fmt: &str, key: &str, node: &Node) -> CoreResult<Matrix> {
    let entries = as_map(fmt, key, node)?;
    check_keys(fmt, key, entries, &["rows", "cols", "data"])?;
    let f = Fields::new("", entries);
    let (rows, cols) = dims(fmt, key, &f)?;
    let (_, data) = f
        .require(&["data"])
        .map_err(|_| bad(fmt, key, "missing `data`"))?;
    let data = f64_seq(fmt, &format!("{key}.data"), data)?;
    check_len(fmt, key, rows, cols, data.len())?;
    Ok(Matrix { rows, cols, data })
}
