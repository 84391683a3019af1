//! Header detection: which column holds what, in which unit.
//!
//! The first non-blank line decides everything: its delimiter (`,` `;` tab, else whitespace),
//! whether it is a header (its first field is not a number) and, unless the parameters give
//! explicit columns, the column of the timestamp, each gyro and accel axis and the temperature,
//! recognised by name (EuRoC and common variants) or else by position. Units come from the
//! parameters or from hints in the header names (`deg`, `[g]`).

use super::line::trim;
use super::number::parse_f64;
use super::{AccelUnit, GyroUnit, ImuCsvParams, ParseStats};
use crate::error::{CoreError, CoreResult};

/// Resolved column layout: `wanted[k] = (column, slot)` sorted by column.
#[derive(Debug, Clone)]
pub(super) struct Layout {
    pub(super) wanted: Vec<(usize, usize)>,
    pub(super) delim: u8,
    pub(super) has_temp: bool,
    pub(super) gyro_scale: f64,
    pub(super) accel_scale: f64,
    pub(super) ts_pow10: i32,
}

fn detect_delim(line: &[u8]) -> u8 {
    for d in [b',', b';', b'\t'] {
        if line.contains(&d) {
            return d;
        }
    }
    b' '
}

fn split_fields(line: &[u8], delim: u8) -> Vec<&[u8]> {
    if delim == b' ' {
        line.split(|b| b.is_ascii_whitespace())
            .filter(|f| !f.is_empty())
            .collect()
    } else {
        line.split(|&b| b == delim).map(trim).collect()
    }
}

/// Decide the column layout from the first non-blank line. Returns whether that line is a
/// header (consumed) or already data.
pub(super) fn resolve_layout(
    line: &[u8],
    params: &ImuCsvParams,
    stats: &mut ParseStats,
) -> CoreResult<(Layout, bool)> {
    let delim = detect_delim(line);
    let fields = split_fields(line, delim);
    let first_is_number = fields
        .first()
        .is_some_and(|f| parse_f64(f).is_some() && !f.starts_with(b"#"));
    let is_header = !first_is_number;
    let names: Vec<String> = if is_header {
        fields
            .iter()
            .map(|f| {
                String::from_utf8_lossy(f)
                    .trim_start_matches('#')
                    .trim()
                    .to_ascii_lowercase()
            })
            .collect()
    } else {
        Vec::new()
    };

    let (cols, temp, source) = if let Some(c) = &params.columns {
        let all = [
            c.timestamp,
            c.gyro[0],
            c.gyro[1],
            c.gyro[2],
            c.accel[0],
            c.accel[1],
            c.accel[2],
        ];
        let mut seen = all.to_vec();
        seen.extend(c.temperature);
        let mut s = seen.clone();
        s.sort_unstable();
        s.dedup();
        if s.len() != seen.len() {
            return Err(CoreError::param(
                "columns",
                "column indices must be distinct",
            ));
        }
        if s.last().is_some_and(|&m| m > 4096) {
            return Err(CoreError::param("columns", "column index above 4096"));
        }
        (all.to_vec(), c.temperature, "params")
    } else if is_header {
        match map_header(&names) {
            Some((cols, temp)) => (cols, temp, "header"),
            None => {
                if fields.len() < 7 {
                    return Err(CoreError::input(format!(
                        "line {}: header has {} columns, need at least 7 (timestamp, gyro xyz, \
                         accel xyz) or explicit `columns` in the parameters",
                        stats.blank_lines + 1,
                        fields.len()
                    )));
                }
                let temp = names.iter().position(|n| n.contains("temp"));
                ((0..7).collect(), temp.filter(|&t| t >= 7), "positional")
            }
        }
    } else {
        ((0..7).collect(), None, "positional")
    };

    // Units: params win, else hints in the header's gyro/accel names.
    let gyro_unit = params.gyro_unit.unwrap_or_else(|| {
        if is_header
            && cols[1..4]
                .iter()
                .any(|&c| names.get(c).is_some_and(|n| n.contains("deg")))
        {
            GyroUnit::DegS
        } else {
            GyroUnit::RadS
        }
    });
    let accel_unit = params.accel_unit.unwrap_or_else(|| {
        let says_g = |n: &String| {
            n.contains("[g]") || n.contains("(g)") || n.ends_with(" g") || n.ends_with("_g")
        };
        if is_header && cols[4..7].iter().any(|&c| names.get(c).is_some_and(says_g)) {
            AccelUnit::G
        } else {
            AccelUnit::MS2
        }
    });

    let mut wanted: Vec<(usize, usize)> = cols.iter().enumerate().map(|(s, &c)| (c, s)).collect();
    if let Some(t) = temp {
        wanted.push((t, 7));
    }
    wanted.sort_unstable();
    stats.columns = cols.clone();
    stats.temperature_column = temp;
    stats.column_source = source.to_string();
    stats.gyro_unit = Some(gyro_unit);
    stats.accel_unit = Some(accel_unit);
    Ok((
        Layout {
            wanted,
            delim,
            has_temp: temp.is_some(),
            gyro_scale: match gyro_unit {
                GyroUnit::RadS => 1.0,
                GyroUnit::DegS => std::f64::consts::PI / 180.0,
            },
            accel_scale: match accel_unit {
                AccelUnit::MS2 => 1.0,
                AccelUnit::G => 9.806_65,
            },
            ts_pow10: params.timestamp_unit.pow10_to_ns(),
        },
        is_header,
    ))
}

/// Map header names (lower case, `#` stripped) to columns. Recognises EuRoC
/// (`w_RS_S_x [rad s^-1]`, `a_RS_S_x [m s^-2]`) and common variants (`gyro_x`, `omega_x`, `wx`,
/// `acc_x`, `ax`, `temperature`).
fn map_header(names: &[String]) -> Option<(Vec<usize>, Option<usize>)> {
    // Drop a unit suffix in brackets or parentheses.
    let base: Vec<String> = names
        .iter()
        .map(|n| {
            let cut = n.find(['[', '(']).unwrap_or(n.len());
            n[..cut].trim().to_string()
        })
        .collect();
    let ts = base.iter().position(|n| {
        n.contains("timestamp") || n == "time" || n == "t" || n.starts_with("time")
    })?;
    let axis_of = |n: &str| -> Option<usize> {
        let last = n.chars().last()?;
        let ax = match last {
            'x' => 0,
            'y' => 1,
            'z' => 2,
            _ => return None,
        };
        let stem = n[..n.len() - 1].trim_end_matches(['_', ' ', '.', '-']);
        if stem.is_empty() {
            return None;
        }
        Some(ax)
    };
    let is_gyro = |n: &str| {
        n.starts_with("w_")
            || n.starts_with("gyr")
            || n.starts_with("omega")
            || n.starts_with("ang")
            || (n.len() == 2 && n.starts_with('w'))
            || n.starts_with("wx")
            || n.starts_with("wy")
            || n.starts_with("wz")
            || n.starts_with("g_")
            || (n.len() == 2 && n.starts_with('g'))
    };
    let is_acc = |n: &str| {
        n.starts_with("a_")
            || n.starts_with("acc")
            || n.starts_with("lin")
            || (n.len() == 2 && n.starts_with('a'))
    };
    let mut gyro = [None; 3];
    let mut accel = [None; 3];
    for (i, n) in base.iter().enumerate() {
        if i == ts {
            continue;
        }
        if let Some(ax) = axis_of(n) {
            if is_gyro(n) && gyro[ax].is_none() {
                gyro[ax] = Some(i);
            } else if is_acc(n) && accel[ax].is_none() {
                accel[ax] = Some(i);
            }
        }
    }
    let mut cols = vec![ts];
    for c in gyro.iter().chain(accel.iter()) {
        cols.push((*c)?);
    }
    let temp = base.iter().position(|n| n.contains("temp"));
    Some((cols, temp))
}
