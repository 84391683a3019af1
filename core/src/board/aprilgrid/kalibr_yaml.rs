//! Target descriptions as other tools write them: Kalibr's target yaml and OpenCV's ChArUco
//! parameters.
//!
//! Both are flat `key: value` documents, so they are read by a strict reader of exactly that:
//! an optional `%YAML…` line and `---`, `#` comments, one `key: value` per line at the left
//! margin, plain or quoted scalars. Anything nested is refused with its line number rather
//! than guessed at (Caliper's full YAML reader lives with the camera-file importers).

use crate::board::target::TargetSpec;
use crate::error::{CoreError, CoreResult};

/// `key → value` of a flat YAML document, in file order; duplicate keys are refused.
fn flat(fmt: &str, text: &str) -> CoreResult<Vec<(String, String)>> {
    let mut out: Vec<(String, String)> = Vec::new();
    for (n, raw) in text.lines().enumerate() {
        let line = strip_comment(raw);
        let t = line.trim_end();
        if t.trim().is_empty() || t.starts_with("%YAML") || t.trim() == "---" {
            continue;
        }
        if t.starts_with([' ', '\t', '-']) {
            return Err(CoreError::input(format!(
                "{fmt} line {}: nested values are not part of a target description",
                n + 1
            )));
        }
        let Some((k, v)) = t.split_once(':') else {
            return Err(CoreError::input(format!(
                "{fmt} line {}: expected `key: value`",
                n + 1
            )));
        };
        let key = k.trim().to_owned();
        let v = v.trim();
        let value = if v.len() >= 2
            && ((v.starts_with('\'') && v.ends_with('\''))
                || (v.starts_with('"') && v.ends_with('"')))
        {
            v[1..v.len() - 1].to_owned()
        } else {
            v.to_owned()
        };
        if out.iter().any(|(k2, _)| *k2 == key) {
            return Err(CoreError::input(format!(
                "{fmt} line {}: key `{key}` appears twice",
                n + 1
            )));
        }
        out.push((key, value));
    }
    Ok(out)
}

/// The line without a `#` comment (a `#` at the start or after a space, outside quotes).
fn strip_comment(line: &str) -> &str {
    let mut quote = None;
    let mut prev = ' ';
    for (i, ch) in line.char_indices() {
        match quote {
            Some(q) if ch == q => quote = None,
            Some(_) => {}
            None if ch == '\'' || ch == '"' => quote = Some(ch),
            None if ch == '#' && prev.is_whitespace() => return &line[..i],
            None => {}
        }
        prev = ch;
    }
    line
}

struct Doc<'a> {
    fmt: &'a str,
    kv: Vec<(String, String)>,
}

impl Doc<'_> {
    fn get(&self, key: &str) -> Option<&str> {
        self.kv
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    fn require(&self, key: &str) -> CoreResult<&str> {
        self.get(key)
            .ok_or_else(|| CoreError::param(key, format!("missing from the {} file", self.fmt)))
    }

    fn f64(&self, key: &str) -> CoreResult<f64> {
        let v = self.require(key)?;
        v.parse::<f64>()
            .map_err(|_| CoreError::param(key, format!("expected a number, got {v:?}")))
    }

    fn usize(&self, key: &str) -> CoreResult<usize> {
        let v = self.require(key)?;
        v.parse::<usize>()
            .map_err(|_| CoreError::param(key, format!("expected a whole number, got {v:?}")))
    }

    /// Keys that are not in `known` (a misspelt key silently ignored would give a wrong
    /// board).
    fn refuse_unknown(&self, known: &[&str]) -> CoreResult<()> {
        match self.kv.iter().find(|(k, _)| !known.contains(&k.as_str())) {
            Some((k, _)) => Err(CoreError::param(
                k.clone(),
                format!(
                    "unknown key in the {} file (known: {})",
                    self.fmt,
                    known.join(", ")
                ),
            )),
            None => Ok(()),
        }
    }
}

/// Kalibr's target yaml (`aprilgrid` or `checkerboard`).
pub(crate) fn from_kalibr(text: &str) -> CoreResult<TargetSpec> {
    let doc = Doc {
        fmt: "Kalibr target",
        kv: flat("Kalibr target", text)?,
    };
    let kind = doc.require("target_type")?;
    let spec = match kind {
        "aprilgrid" => {
            doc.refuse_unknown(&[
                "target_type",
                "tagCols",
                "tagRows",
                "tagSize",
                "tagSpacing",
                "tagFamily",
            ])?;
            TargetSpec::Aprilgrid {
                tag_rows: doc.usize("tagRows")?,
                tag_cols: doc.usize("tagCols")?,
                tag_size: doc.f64("tagSize")?,
                tag_spacing: doc.f64("tagSpacing")?,
                tag_family: doc.get("tagFamily").unwrap_or("tag36h11").to_owned(),
            }
        }
        "checkerboard" => {
            doc.refuse_unknown(&[
                "target_type",
                "targetCols",
                "targetRows",
                "rowSpacingMeters",
                "colSpacingMeters",
            ])?;
            let (rs, cs) = (doc.f64("rowSpacingMeters")?, doc.f64("colSpacingMeters")?);
            if (rs - cs).abs() > 1e-9 * rs.abs().max(cs.abs()) {
                return Err(CoreError::param(
                    "rowSpacingMeters",
                    format!("rectangular squares ({rs} × {cs}) are not supported"),
                ));
            }
            TargetSpec::Chessboard {
                cols: doc.usize("targetCols")?,
                rows: doc.usize("targetRows")?,
                square: cs,
            }
        }
        other => {
            return Err(CoreError::param(
                "target_type",
                format!("{other:?} is not supported (aprilgrid, checkerboard)"),
            ));
        }
    };
    spec.validate()?;
    Ok(spec)
}

/// OpenCV's `PredefinedDictionaryType` numbers of the dictionaries Caliper knows.
fn opencv_dictionary(v: &str) -> CoreResult<String> {
    let Ok(n) = v.parse::<u32>() else {
        return Ok(v.to_owned());
    };
    let name = match n {
        0 => "DICT_4X4_50",
        1 => "DICT_4X4_100",
        2 => "DICT_4X4_250",
        3 => "DICT_4X4_1000",
        4 => "DICT_5X5_50",
        5 => "DICT_5X5_100",
        6 => "DICT_5X5_250",
        7 => "DICT_5X5_1000",
        8 => "DICT_6X6_50",
        9 => "DICT_6X6_100",
        10 => "DICT_6X6_250",
        11 => "DICT_6X6_1000",
        20 => "DICT_APRILTAG_36h11",
        _ => {
            return Err(CoreError::param(
                "dictionary",
                format!("OpenCV dictionary number {n} is not supported"),
            ));
        }
    };
    Ok(name.to_owned())
}

/// OpenCV ChArUco parameters (`squaresX`, `squaresY`, `squareLength`, `markerLength`,
/// `dictionary`, optional `legacyPattern`).
pub(crate) fn from_opencv_charuco(text: &str) -> CoreResult<TargetSpec> {
    let doc = Doc {
        fmt: "OpenCV ChArUco",
        kv: flat("OpenCV ChArUco", text)?,
    };
    doc.refuse_unknown(&[
        "squaresX",
        "squaresY",
        "squareLength",
        "markerLength",
        "dictionary",
        "legacyPattern",
    ])?;
    let legacy = match doc.get("legacyPattern") {
        None | Some("0" | "false" | "False") => false,
        Some("1" | "true" | "True") => true,
        Some(v) => {
            return Err(CoreError::param(
                "legacyPattern",
                format!("expected true/false or 1/0, got {v:?}"),
            ));
        }
    };
    let spec = TargetSpec::Charuco {
        squares_x: doc.usize("squaresX")?,
        squares_y: doc.usize("squaresY")?,
        square: doc.f64("squareLength")?,
        marker: doc.f64("markerLength")?,
        dictionary: opencv_dictionary(doc.require("dictionary")?)?,
        legacy,
    };
    spec.validate()?;
    Ok(spec)
}
