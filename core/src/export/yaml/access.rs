//! Typed access to parsed YAML: numbers, integers, strings, sequences and mappings out of
//! [`Node`]s, every error naming the format and the key.

use super::parse::Node;
use crate::error::{CoreError, CoreResult};

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
pub(super) fn plain<'n>(fmt: &str, key: &str, node: &'n Node, what: &str) -> CoreResult<&'n str> {
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
