//! Writing YAML scalars: numbers that read back bit-for-bit and are typed as floats by every
//! reader we target, double-quoted strings, and flow sequences (OpenCV's wrapped `data` lists).

use crate::error::{CoreError, CoreResult};

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

/// Formats `v` as a YAML float that reads back to the same bits (public form of [`fmt_f64`]
/// with YAML 1.1's spelling of non-finite values).
///
/// A finite value always comes out as digits, a `.`, digits and, when there is an exponent, a
/// signed one: `0.0`, `-0.0`, `640.0`, `123456789.0`, `2.0e-03`, `1.0e+20`, `5.0e-324`. That is
/// the form all three readers Caliper's files go to type as a float:
/// * PyYAML (YAML 1.1), and so Kalibr, which loads its files with it, resolves a plain scalar
///   as a float only when it has a `.` and, with an exponent, a sign
///   (`[-+]?[0-9][0-9_]*\.[0-9_]*([eE][-+][0-9]+)?`): `2e-3` and `1e-05` are read as *strings*
///   and `640` as an integer;
/// * OpenCV's `FileStorage` reads a plain number as a real when its leading digits are followed
///   by `.` or `e`, as an `int` otherwise.
///
/// Integral values below 10¹⁵ are printed in fixed notation, all others as the shortest decimal
/// that round-trips, in C exponent notation with at least two exponent digits. NaN and the
/// infinities are written `.nan`, `.inf` and `-.inf` (YAML 1.1, read as floats by PyYAML);
/// OpenCV writes `.Nan`/`.Inf` instead, which is what Caliper's OpenCV export uses.
pub fn yaml_number(v: f64) -> String {
    fmt_f64(v, NanStyle::Yaml)
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
