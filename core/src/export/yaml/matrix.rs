//! Matrices in calibration files: OpenCV's `!!opencv-matrix` (`rows`, `cols`, `dt`, `data`)
//! and ROS's untagged `rows`/`cols`/`data` mappings, checked for shape and element type.

use super::access::{
    Fields, as_int, as_map, as_seq, as_str, bad, describe, f64_seq, parse_f32, parse_f64,
    parse_int, plain,
};
use super::parse::{Node, OPENCV_MATRIX_TAG};
use crate::error::CoreResult;

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
