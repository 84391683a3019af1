//! The line parsers: one piece of complete lines into rows and classified skips.
//!
//! Most lines of a real log are well formed, so [`parse_piece`] first tries `fast_line`, a
//! single pass over the bytes that reads plain decimals with SWAR digit groups and builds the
//! value with one multiplication (why it is kept: see its doc comment); any line it does not
//! fully understand (whitespace delimiters, exponents it does not take, non-ns timestamps, NaN,
//! junk) goes to `parse_line`, which splits the fields, parses them with the standard library
//! and says why a line is skipped.

use super::layout::Layout;
use super::number::{parse_f64, parse_timestamp, take_sign};

/// Column slots of one parsed row: timestamp, 6 channels, temperature.
const SLOTS: usize = 8;

#[derive(Debug, Clone, Copy)]
pub(super) struct Row {
    pub(super) t: i64,
    pub(super) v: [f64; 6],
    pub(super) temp: f64,
    pub(super) rel_line: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Skip {
    Blank,
    Junk,
    Nan,
}

#[derive(Default)]
pub(super) struct Piece {
    pub(super) lines: u64,
    pub(super) rows: Vec<Row>,
    /// (relative line, kind)
    pub(super) skips: Vec<(u32, Skip)>,
}

/// Trim ASCII whitespace and a trailing `\r`.
pub(super) fn trim(s: &[u8]) -> &[u8] {
    let a = s
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(s.len());
    let b = s
        .iter()
        .rposition(|b| !b.is_ascii_whitespace())
        .map_or(a, |p| p + 1);
    &s[a..b.max(a)]
}

/// Parse one piece of complete lines: the single-pass fast path for well-formed lines, the
/// general [`parse_line`] for anything else (which then classifies the line exactly).
pub(super) fn parse_piece(text: &[u8], lay: &Layout) -> Piece {
    let mut out = Piece {
        lines: 0,
        rows: Vec::with_capacity(text.len() / 64 + 1),
        skips: Vec::new(),
    };
    let max_col = lay.wanted.last().map_or(0, |w| w.0);
    // Dense slot table: slot_of[col] = slot + 1 (0 = unused column).
    let mut slot_of = vec![0u8; max_col + 1];
    for &(c, s) in &lay.wanted {
        slot_of[c] = s as u8 + 1;
    }
    let fast_ok = lay.delim != b' ';
    let mut pos = 0;
    while pos < text.len() {
        let rel = out.lines as u32;
        out.lines += 1;
        if fast_ok && let Some((row, next)) = fast_line(text, pos, lay, &slot_of) {
            out.rows.push(Row {
                rel_line: rel,
                ..row
            });
            pos = next;
            continue;
        }
        let nl = text[pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(text.len(), |p| pos + p);
        let line = &text[pos..nl];
        pos = nl + 1;
        match parse_line(line, lay, max_col) {
            Ok(mut row) => {
                row.rel_line = rel;
                out.rows.push(row);
            }
            Err(kind) => out.skips.push((rel, kind)),
        }
    }
    out
}

/// Eight ASCII digits at `pos` as a number (SWAR: one 64-bit load, three multiplies), or None
/// if the 8 bytes are not all digits.
#[inline]
fn eight_digits(text: &[u8], pos: usize) -> Option<u64> {
    let chunk: [u8; 8] = text.get(pos..pos + 8)?.try_into().ok()?;
    let v = u64::from_le_bytes(chunk);
    const HI: u64 = 0xF0F0_F0F0_F0F0_F0F0;
    if (v & HI) | ((v.wrapping_add(0x0606_0606_0606_0606) & HI) >> 4) != 0x3333_3333_3333_3333 {
        return None;
    }
    let v = v - 0x3030_3030_3030_3030;
    // Pairs, then quads, then the octet (byte 0 is the most significant digit).
    let v = v.wrapping_mul(10).wrapping_add(v >> 8);
    let v = ((v & 0x0000_00FF_0000_00FF).wrapping_mul(0x000F_4240_0000_0064))
        .wrapping_add(((v >> 16) & 0x0000_00FF_0000_00FF).wrapping_mul(0x0000_2710_0000_0001))
        >> 32;
    Some(v)
}

/// Accumulate decimal digits at `pos` into `mant` (wrapping; callers reject more than 19
/// digits), returning how many were read.
#[inline]
fn digits(text: &[u8], pos: &mut usize, mant: &mut u64, nd: &mut u32) -> u32 {
    let start = *nd;
    while *nd <= 11 {
        match eight_digits(text, *pos) {
            Some(d8) => {
                *mant = mant.wrapping_mul(100_000_000).wrapping_add(d8);
                *nd += 8;
                *pos += 8;
            }
            None => break,
        }
    }
    while let Some(&b) = text.get(*pos) {
        let d = b.wrapping_sub(b'0');
        if d >= 10 {
            break;
        }
        *mant = mant.wrapping_mul(10).wrapping_add(u64::from(d));
        *nd += 1;
        *pos += 1;
    }
    *nd - start
}

const NEG_POW10: [f64; 23] = [
    1e0, 1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-13, 1e-14,
    1e-15, 1e-16, 1e-17, 1e-18, 1e-19, 1e-20, 1e-21, 1e-22,
];

const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// Single pass over one well-formed line starting at `pos`: plain decimal fields separated by
/// the delimiter, integer timestamp in the file unit. Returns the row (values scaled, checked
/// finite) and the start of the next line, or None to let [`parse_line`] handle the line.
///
/// This fast path is kept, rather than handing every field to `str::parse`, because the
/// `imu_vs_peer` benchmark shows it matters: with `IMU_PARSE_ONLY=1` on a 77 MB, 1 h, 200 Hz
/// EuRoC log (values printed `%.10g` as the peer writes them) parsing took a median 347 ms
/// through this path against 625 ms with every line sent to [`parse_line`] (12 alternating runs
/// each, opt-level 2, on two shared cores). It is also not bit-identical to `str::parse`: a
/// negative exponent multiplies by the rounded 10⁻ᵏ (at most one ulp off), so replacing it
/// would change results.
#[inline]
fn fast_line(text: &[u8], mut pos: usize, lay: &Layout, slot_of: &[u8]) -> Option<(Row, usize)> {
    let n = text.len();
    let mut vals = [0.0f64; SLOTS];
    let mut t: i64 = 0;
    let last = slot_of.len() - 1;
    for (col, &slot) in slot_of.iter().enumerate() {
        if slot == 0 {
            // Unused column: skip to the delimiter.
            while pos < n && text[pos] != lay.delim {
                if text[pos] == b'\n' {
                    return None;
                }
                pos += 1;
            }
        } else {
            let slot = usize::from(slot - 1);
            let neg = match text.get(pos) {
                Some(b'-') => {
                    pos += 1;
                    true
                }
                _ => false,
            };
            let mut mant: u64 = 0;
            let mut nd = 0u32;
            let mut exp: i32 = 0;
            digits(text, &mut pos, &mut mant, &mut nd);
            if slot == 0 {
                // Timestamp: integer in ns only.
                if nd == 0 || nd > 19 || lay.ts_pow10 != 0 {
                    return None;
                }
                let m = i64::try_from(mant).ok()?;
                t = if neg { -m } else { m };
            } else {
                if pos < n && text[pos] == b'.' {
                    pos += 1;
                    exp -= digits(text, &mut pos, &mut mant, &mut nd) as i32;
                }
                if pos < n && (text[pos] | 0x20) == b'e' {
                    pos += 1;
                    let eneg = take_sign(text, &mut pos);
                    let mut e: i32 = 0;
                    let mut ed = 0;
                    while pos < n && ed < 4 {
                        let d = text[pos].wrapping_sub(b'0');
                        if d >= 10 {
                            break;
                        }
                        e = e * 10 + i32::from(d);
                        ed += 1;
                        pos += 1;
                    }
                    if ed == 0 {
                        return None;
                    }
                    exp += if eneg { -e } else { e };
                }
                if nd == 0 || nd > 19 || mant >= (1u64 << 53) {
                    return None;
                }
                let m = mant as f64;
                let v = if mant == 0 {
                    0.0
                } else if (0..=22).contains(&exp) {
                    m * POW10[exp as usize]
                } else if (-22..0).contains(&exp) {
                    // Multiplying by the rounded 10^-k instead of dividing by 10^k: at most one
                    // ulp (10⁻¹⁶) off the correctly rounded value, and 3–4× cheaper; the values
                    // are stored as f32 offsets anyway.
                    m * NEG_POW10[(-exp) as usize]
                } else {
                    return None;
                };
                vals[slot] = if neg { -v } else { v };
            }
        }
        // Field terminator.
        let b = *text.get(pos)?;
        if col == last {
            if b == lay.delim {
                // Extra columns: skip to the end of the line.
                while pos < n && text[pos] != b'\n' {
                    pos += 1;
                }
            } else if b == b'\r' {
                pos += 1;
            }
            return match text.get(pos) {
                Some(b'\n') | None => {
                    let mut v = [0.0; 6];
                    for i in 0..6 {
                        let scale = if i < 3 {
                            lay.gyro_scale
                        } else {
                            lay.accel_scale
                        };
                        v[i] = vals[i + 1] * scale;
                    }
                    Some((
                        Row {
                            t,
                            v,
                            temp: vals[7],
                            rel_line: 0,
                        },
                        pos + 1,
                    ))
                }
                _ => None,
            };
        }
        if b != lay.delim {
            return None;
        }
        pos += 1;
    }
    None
}

#[inline]
fn parse_line(line: &[u8], lay: &Layout, max_col: usize) -> Result<Row, Skip> {
    let line = match line.last() {
        Some(b'\r') => &line[..line.len() - 1],
        _ => line,
    };
    if line.iter().all(|b| b.is_ascii_whitespace()) {
        return Err(Skip::Blank);
    }
    let mut vals = [f64::NAN; SLOTS];
    let mut t: Option<i64> = None;
    let mut ts_nan = false;
    let mut k = 0; // index into lay.wanted
    let mut col = 0;
    let mut pos = 0;
    let n = line.len();
    while col <= max_col {
        if pos > n {
            return Err(Skip::Junk); // not enough fields
        }
        // Field boundaries.
        let (fs, fe, next) = if lay.delim == b' ' {
            let mut s = pos;
            while s < n && line[s].is_ascii_whitespace() {
                s += 1;
            }
            if s >= n {
                return Err(Skip::Junk);
            }
            let mut e = s;
            while e < n && !line[e].is_ascii_whitespace() {
                e += 1;
            }
            (s, e, e + 1)
        } else {
            let e = line[pos..]
                .iter()
                .position(|&b| b == lay.delim)
                .map_or(n, |p| pos + p);
            (pos, e, e + 1)
        };
        if k < lay.wanted.len() && lay.wanted[k].0 == col {
            let field = trim(&line[fs..fe]);
            let slot = lay.wanted[k].1;
            if slot == 0 {
                match parse_timestamp(field, lay.ts_pow10) {
                    Some(v) => t = Some(v),
                    None => {
                        if is_nan_word(field) {
                            ts_nan = true;
                        } else {
                            return Err(Skip::Junk);
                        }
                    }
                }
            } else {
                match parse_f64(field) {
                    Some(v) => vals[slot] = v,
                    None => return Err(Skip::Junk),
                }
            }
            k += 1;
        }
        col += 1;
        pos = next;
    }
    let Some(t) = t else {
        return if ts_nan {
            Err(Skip::Nan)
        } else {
            Err(Skip::Junk)
        };
    };
    let mut v = [0.0; 6];
    for (i, slot) in v.iter_mut().enumerate() {
        let scale = if i < 3 {
            lay.gyro_scale
        } else {
            lay.accel_scale
        };
        *slot = vals[i + 1] * scale;
        if !slot.is_finite() {
            return Err(Skip::Nan);
        }
    }
    let temp = vals[7];
    if lay.has_temp && !temp.is_finite() {
        return Err(Skip::Nan);
    }
    Ok(Row {
        t,
        v,
        temp,
        rel_line: 0,
    })
}

fn is_nan_word(f: &[u8]) -> bool {
    let f = f
        .strip_prefix(b"-")
        .or_else(|| f.strip_prefix(b"+"))
        .unwrap_or(f);
    f.eq_ignore_ascii_case(b"nan")
        || f.eq_ignore_ascii_case(b"inf")
        || f.eq_ignore_ascii_case(b"infinity")
}
