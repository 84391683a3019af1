//! Streaming parser for EuRoC-style IMU CSV logs.
//!
//! A 6 h log at 200 Hz is ~460 MB of text, so the parser never holds the text: it reads fixed
//! batches (a few MiB), parses the complete lines of each batch in parallel (rayon) and appends
//! the kept samples to compact per-axis columns. Each axis is stored as `f32` *offsets from a
//! reference* (the median of its first ~1000 samples, in SI units): the offsets span the noise
//! and drift of the signal, not its absolute value (e.g. 9.81 m/s² of gravity), so the f32
//! rounding error is
//! ~6·10⁻⁸ of the offset range — five orders of magnitude below any MEMS noise floor — while the
//! memory is halved (32 bytes per sample with the timestamp step and temperature: 140 MB for 6 h).
//!
//! Defined behaviour for every kind of bad row (all counted in [`ParseStats`], with the first few
//! line numbers):
//! - blank lines: skipped;
//! - junk rows (too few fields, a required field that is not a number, comment or repeated header
//!   lines, over-long lines): skipped;
//! - rows with a NaN or infinite required value: skipped;
//! - a timestamp equal to the previous kept one: the row is dropped (duplicate);
//! - a timestamp before the previous kept one: the row is skipped (backwards jump). If more than
//!   1 % of the rows go backwards the log is rejected: that pattern means a forward glitch or
//!   concatenated logs, and keeping either part silently would be a wrong answer;
//! - steps longer than 1.5 × the median step: reported as gaps (the samples are kept).
//!
//! Nothing here panics on any byte sequence (see the garbage-input tests).

use std::io::BufRead;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

/// How many line numbers of each kind of skipped row are kept in [`ParseStats`].
const FIRST_LINES: usize = 10;
/// Bytes read per batch; each batch is split into pieces parsed in parallel.
const BATCH_BYTES: usize = 8 << 20;
/// A gap is a timestamp step longer than this multiple of the median step.
const GAP_FACTOR: f64 = 1.5;
/// Upper bound on remembered skip positions (used to map sample indices back to line numbers).
const MAX_SKIP_MARKS: usize = 1 << 20;

/// Unit of the gyroscope columns in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum GyroUnit {
    /// rad/s (EuRoC).
    RadS,
    /// deg/s.
    DegS,
}

/// Unit of the accelerometer columns in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum AccelUnit {
    /// m/s² (EuRoC).
    MS2,
    /// Standard gravity, 9.80665 m/s².
    G,
}

/// Unit of the timestamp column.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum TimeUnit {
    /// Nanoseconds (EuRoC).
    #[default]
    Ns,
    /// Microseconds.
    Us,
    /// Milliseconds.
    Ms,
    /// Seconds.
    S,
}

impl TimeUnit {
    fn pow10_to_ns(self) -> i32 {
        match self {
            TimeUnit::Ns => 0,
            TimeUnit::Us => 3,
            TimeUnit::Ms => 6,
            TimeUnit::S => 9,
        }
    }
}

/// Explicit 0-based column indices, overriding the header.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ImuColumns {
    /// Timestamp column.
    pub timestamp: usize,
    /// Gyroscope x, y, z columns.
    pub gyro: [usize; 3],
    /// Accelerometer x, y, z columns.
    pub accel: [usize; 3],
    /// Temperature column (°C), if any.
    #[serde(default)]
    pub temperature: Option<usize>,
}

/// How to read an IMU CSV log. The defaults read EuRoC files (`#timestamp [ns]`, gyro rad/s,
/// accel m/s²) and any file whose header names the columns recognisably.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ImuCsvParams {
    /// Gyroscope unit; default: `deg_s` if the header says "deg", else `rad_s`.
    pub gyro_unit: Option<GyroUnit>,
    /// Accelerometer unit; default: `g` if the header unit is `[g]`, else `m_s2`.
    pub accel_unit: Option<AccelUnit>,
    /// Timestamp unit (default `ns`).
    pub timestamp_unit: TimeUnit,
    /// Explicit column indices; default: from the header names, else positional
    /// (timestamp, gyro xyz, accel xyz[, temperature when the header names it]).
    pub columns: Option<ImuColumns>,
}

/// A gap in the timestamps (a step longer than 1.5 × the median step).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct TimeGap {
    /// Index of the first sample after the gap.
    pub sample_index: usize,
    /// 1-based line number of that sample (None when too many rows were skipped to track it).
    pub line: Option<u64>,
    /// Time of the sample before the gap, seconds from the first sample.
    pub start_s: f64,
    /// Length of the step, seconds.
    pub duration_s: f64,
}

/// Everything the parser saw and did, for the job result.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ParseStats {
    /// Lines read (including header, blank and skipped lines).
    pub lines: u64,
    /// Bytes read.
    pub bytes: u64,
    /// The header line, if one was found.
    pub header: Option<String>,
    /// Columns used: `[timestamp, gx, gy, gz, ax, ay, az]` (0-based).
    pub columns: Vec<usize>,
    /// Temperature column used, if any.
    pub temperature_column: Option<usize>,
    /// How the columns were chosen: `params`, `header` or `positional`.
    pub column_source: String,
    /// Gyroscope unit of the file (values are converted to rad/s).
    pub gyro_unit: Option<GyroUnit>,
    /// Accelerometer unit of the file (values are converted to m/s²).
    pub accel_unit: Option<AccelUnit>,
    /// Samples kept.
    pub samples: usize,
    /// Blank lines skipped.
    pub blank_lines: u64,
    /// Junk rows skipped (not enough fields, non-numeric fields, comments, over-long lines).
    pub junk_rows: u64,
    /// First few line numbers (1-based) of junk rows.
    pub junk_lines_first: Vec<u64>,
    /// Rows skipped because a required value is NaN or infinite.
    pub nan_rows: u64,
    /// First few line numbers of NaN rows.
    pub nan_lines_first: Vec<u64>,
    /// Rows dropped because their timestamp equals the previous kept one.
    pub duplicate_timestamps: u64,
    /// First few line numbers of duplicates.
    pub duplicate_lines_first: Vec<u64>,
    /// Rows skipped because their timestamp is before the previous kept one.
    pub backwards_timestamps: u64,
    /// First few line numbers of backwards rows.
    pub backwards_lines_first: Vec<u64>,
    /// Time from the first to the last kept sample, seconds.
    pub duration_s: f64,
    /// Median timestamp step, seconds.
    pub dt_median_s: f64,
    /// Sample rate, 1 / median step, Hz.
    pub rate_hz: f64,
    /// Smallest and largest step, seconds.
    pub dt_min_s: f64,
    /// Largest step, seconds.
    pub dt_max_s: f64,
    /// Jitter: standard deviation of the steps that are not gaps, seconds.
    pub jitter_std_s: f64,
    /// Jitter: largest |step − median| among steps that are not gaps, seconds.
    pub jitter_max_abs_s: f64,
    /// Number of gaps (steps > 1.5 × median).
    pub gaps: u64,
    /// Total time lost in gaps (sum of step − median over gaps), seconds.
    pub gap_time_s: f64,
    /// The first few gaps.
    pub gaps_first: Vec<TimeGap>,
}

/// A parsed IMU log in compact columns (see the module doc for the f32 offset storage).
#[derive(Debug, Clone)]
pub struct ImuLog {
    /// What the parser saw.
    pub stats: ParseStats,
    t0_ns: i64,
    /// `dt_ns[i] = t[i+1] − t[i]`, saturated at `u32::MAX` (exact values in `long_steps`).
    dt_ns: Vec<u32>,
    long_steps: Vec<(usize, i64)>,
    reference: [f64; 6],
    data: [Vec<f32>; 6],
    temperature: Option<Vec<f32>>,
}

impl ImuLog {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.data[0].len()
    }

    /// Whether the log holds no sample (never true for a log returned by [`read_imu_log`]).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Timestamp of the first sample, ns.
    pub fn t0_ns(&self) -> i64 {
        self.t0_ns
    }

    /// Sample `i` of channel `c` (0..3 gyro xyz in rad/s, 3..6 accel xyz in m/s²).
    #[inline]
    pub fn value(&self, c: usize, i: usize) -> f64 {
        self.reference[c] + f64::from(self.data[c][i])
    }

    /// Channel `c` (see [`ImuLog::value`]) as f64, absolute values.
    pub fn channel(&self, c: usize) -> Vec<f64> {
        let r = self.reference[c];
        self.data[c].iter().map(|&d| r + f64::from(d)).collect()
    }

    /// Channel `c` as f32 offsets from its reference value (what is stored; the reference is the
    /// median of the first ~1000 samples, so a constant offset is irrelevant to callers that
    /// only need differences, like the Allan deviation).
    pub fn channel_offsets(&self, c: usize) -> &[f32] {
        &self.data[c]
    }

    /// Temperatures (°C) if the log has a temperature column.
    pub fn temperature(&self) -> Option<&[f32]> {
        self.temperature.as_deref()
    }

    /// Sample times in seconds from the first sample.
    pub fn times_s(&self) -> Vec<f64> {
        let mut out = Vec::with_capacity(self.len());
        let mut t: i64 = 0;
        out.push(0.0);
        let mut long = self.long_steps.iter().peekable();
        for (i, &d) in self.dt_ns.iter().enumerate() {
            let step = match long.peek() {
                Some(&&(j, s)) if j == i => {
                    long.next();
                    s
                }
                _ => i64::from(d),
            };
            t = t.saturating_add(step);
            out.push(t as f64 * 1e-9);
        }
        out
    }
}

/// Column slots of one parsed row: timestamp, 6 channels, temperature.
const SLOTS: usize = 8;

#[derive(Debug, Clone, Copy)]
struct Row {
    t: i64,
    v: [f64; 6],
    temp: f64,
    rel_line: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Skip {
    Blank,
    Junk,
    Nan,
}

#[derive(Default)]
struct Piece {
    lines: u64,
    rows: Vec<Row>,
    /// (relative line, kind)
    skips: Vec<(u32, Skip)>,
}

/// Resolved column layout: `wanted[k] = (column, slot)` sorted by column.
#[derive(Debug, Clone)]
struct Layout {
    wanted: Vec<(usize, usize)>,
    delim: u8,
    has_temp: bool,
    gyro_scale: f64,
    accel_scale: f64,
    ts_pow10: i32,
}

/// Parses an IMU CSV log (see the module doc) into compact columns.
///
/// `progress` gets step `"parse"` with the bytes read so far (total unknown: 0) and is checked
/// for cancellation after every batch. Errors: [`CoreError::InvalidInput`] with a line number when
/// no usable sample is found, the header maps no column, or timestamps go backwards too often;
/// [`CoreError::InvalidParam`] for inconsistent column indices.
pub fn read_imu_log(
    mut reader: impl BufRead,
    params: &ImuCsvParams,
    progress: &dyn Progress,
) -> CoreResult<ImuLog> {
    let mut stats = ParseStats::default();
    let mut line_no: u64 = 0; // lines fully consumed so far
    let mut layout: Option<Layout> = None;
    let mut acc = Accum::default();
    let mut skipping_long_line = false;
    // Double buffer: the next batch is read on this thread while a scoped thread parses the
    // current one (with rayon inside), so reading overlaps parsing without asking the reader
    // to be `Send`.
    let mut cur = vec![0u8; BATCH_BYTES];
    let mut next = vec![0u8; BATCH_BYTES];
    let mut cur_len = 0usize;
    let mut eof = fill(
        &mut reader,
        &mut cur,
        &mut cur_len,
        line_no,
        &mut stats.bytes,
    )?;
    if cur[..cur_len].starts_with(&[0xEF, 0xBB, 0xBF]) {
        cur.copy_within(3..cur_len, 0);
        cur_len -= 3;
    }
    loop {
        let mut start = 0usize;
        if skipping_long_line {
            match cur[..cur_len].iter().position(|&b| b == b'\n') {
                Some(p) => {
                    start = p + 1;
                    skipping_long_line = false;
                }
                None => start = cur_len,
            }
        }
        let end = if eof {
            cur_len
        } else {
            match cur[start..cur_len].iter().rposition(|&b| b == b'\n') {
                Some(p) => start + p + 1,
                None if start == 0 && cur_len == cur.len() => {
                    // A single line longer than a whole batch: junk, skip to its end.
                    line_no += 1;
                    note(&mut stats.junk_rows, &mut stats.junk_lines_first, line_no);
                    acc.mark_skip();
                    skipping_long_line = true;
                    cur_len
                }
                None => start,
            }
        };

        let mut body_start = start;
        if layout.is_none() {
            // Find the header (first non-blank line) and fix the layout.
            let mut pos = start;
            while pos < end {
                let nl = cur[pos..end]
                    .iter()
                    .position(|&b| b == b'\n')
                    .map_or(end, |p| pos + p);
                let line = trim(&cur[pos..nl]);
                if line.is_empty() {
                    line_no += 1;
                    stats.blank_lines += 1;
                    pos = (nl + 1).min(end);
                    continue;
                }
                let (l, header_consumed) = resolve_layout(line, params, &mut stats)?;
                if header_consumed {
                    line_no += 1;
                    stats.header = Some(String::from_utf8_lossy(line).chars().take(500).collect());
                    pos = (nl + 1).min(end);
                }
                layout = Some(l);
                break;
            }
            body_start = pos;
            acc.first_data_line = line_no + 1;
        }

        // Carry the incomplete last line over, then read the next batch while parsing this one.
        let tail = cur_len - end.max(body_start);
        next[..tail].copy_from_slice(&cur[end.max(body_start)..cur_len]);
        let mut next_len = tail;
        let mut next_eof = eof;
        let pieces: Vec<Piece> = match layout.as_ref() {
            Some(lay) if body_start < end => {
                let body = &cur[body_start..end];
                std::thread::scope(|sc| -> CoreResult<Vec<Piece>> {
                    let h = sc.spawn(|| parse_batch(body, lay));
                    if !eof {
                        next_eof = fill(
                            &mut reader,
                            &mut next,
                            &mut next_len,
                            line_no,
                            &mut stats.bytes,
                        )?;
                    }
                    h.join().map_err(|_| {
                        CoreError::input(format!("IMU log parser failed after line {line_no}"))
                    })
                })?
            }
            _ => {
                if !eof {
                    next_eof = fill(
                        &mut reader,
                        &mut next,
                        &mut next_len,
                        line_no,
                        &mut stats.bytes,
                    )?;
                }
                Vec::new()
            }
        };
        if let Some(lay) = layout.as_ref() {
            for p in &pieces {
                acc.merge(p, line_no, lay, &mut stats);
                line_no += p.lines;
            }
        }
        progress.report("parse", stats.bytes, 0);
        progress.check()?;
        if eof {
            break;
        }
        std::mem::swap(&mut cur, &mut next);
        cur_len = next_len;
        eof = next_eof;
    }
    stats.lines = line_no;

    let Some(lay) = layout else {
        return Err(CoreError::input(format!(
            "the IMU log is empty ({} lines, all blank)",
            line_no
        )));
    };
    acc.finish(stats, lay.has_temp)
}

/// Read until `buf` is full or the reader ends; returns whether it ended.
fn fill(
    reader: &mut impl BufRead,
    buf: &mut [u8],
    len: &mut usize,
    line_no: u64,
    bytes: &mut u64,
) -> CoreResult<bool> {
    while *len < buf.len() {
        match reader.read(&mut buf[*len..]) {
            Ok(0) => return Ok(true),
            Ok(n) => {
                *len += n;
                *bytes += n as u64;
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => {
                return Err(CoreError::input(format!(
                    "reading the IMU log failed after line {line_no}: {e}"
                )));
            }
        }
    }
    Ok(false)
}

/// Split complete lines into pieces at line boundaries and parse them in parallel.
fn parse_batch(body: &[u8], lay: &Layout) -> Vec<Piece> {
    let n_pieces = (rayon::current_num_threads() * 2).clamp(1, 16);
    let mut bounds = Vec::with_capacity(n_pieces + 1);
    bounds.push(0usize);
    for k in 1..n_pieces {
        let target = body.len() * k / n_pieces;
        let prev = bounds.last().copied().unwrap_or(0);
        if target <= prev {
            continue;
        }
        let cut = body[target..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(body.len(), |p| target + p + 1);
        if cut > prev && cut < body.len() {
            bounds.push(cut);
        }
    }
    bounds.push(body.len());
    bounds
        .par_windows(2)
        .map(|w| parse_piece(&body[w[0]..w[1]], lay))
        .collect()
}

/// Trim ASCII whitespace and a trailing `\r`.
fn trim(s: &[u8]) -> &[u8] {
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

fn note(count: &mut u64, first: &mut Vec<u64>, line: u64) {
    *count += 1;
    if first.len() < FIRST_LINES {
        first.push(line);
    }
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
fn resolve_layout(
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

/// Parse one piece of complete lines: the single-pass fast path for well-formed lines, the
/// general [`parse_line`] for anything else (which then classifies the line exactly).
fn parse_piece(text: &[u8], lay: &Layout) -> Piece {
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

/// Single pass over one well-formed line starting at `pos`: plain decimal fields separated by
/// the delimiter, integer timestamp in the file unit. Returns the row (values scaled, checked
/// finite) and the start of the next line, or None to let [`parse_line`] handle the line.
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

const NEG_POW10: [f64; 23] = [
    1e0, 1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-13, 1e-14,
    1e-15, 1e-16, 1e-17, 1e-18, 1e-19, 1e-20, 1e-21, 1e-22,
];

const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// A decimal number split as `(negative, mantissa, exponent, digits)`: value = ±mantissa·10^exponent.
/// None when the text is not a plain decimal (then the caller falls back to `str::parse`).
#[inline]
fn decimal(s: &[u8]) -> Option<(bool, u64, i32, u32)> {
    let mut i = 0;
    let n = s.len();
    let neg = match s.first() {
        Some(b'-') => {
            i = 1;
            true
        }
        Some(b'+') => {
            i = 1;
            false
        }
        _ => false,
    };
    let mut mant: u64 = 0;
    let mut digits: u32 = 0; // significant digits accumulated
    let mut any = false;
    let mut exp: i32 = 0;
    while i < n && s[i].is_ascii_digit() {
        any = true;
        if mant != 0 || s[i] != b'0' {
            digits += 1;
            if digits > 19 {
                return None;
            }
        }
        mant = mant * 10 + u64::from(s[i] - b'0');
        i += 1;
    }
    if i < n && s[i] == b'.' {
        i += 1;
        while i < n && s[i].is_ascii_digit() {
            any = true;
            if mant != 0 || s[i] != b'0' {
                digits += 1;
                if digits > 19 {
                    return None;
                }
            }
            mant = mant * 10 + u64::from(s[i] - b'0');
            exp -= 1;
            i += 1;
        }
    }
    if !any {
        return None;
    }
    if i < n && (s[i] == b'e' || s[i] == b'E') {
        i += 1;
        let eneg = take_sign(s, &mut i);
        let mut e: i32 = 0;
        let mut ed = false;
        while i < n && s[i].is_ascii_digit() {
            ed = true;
            e = (e * 10 + i32::from(s[i] - b'0')).min(100_000);
            i += 1;
        }
        if !ed {
            return None;
        }
        exp += if eneg { -e } else { e };
    }
    if i != n {
        return None;
    }
    Some((neg, mant, exp, digits))
}

/// Fast, exactly rounded parse of plain decimals (Clinger's fast path: mantissa < 2⁵³ and
/// |exponent| ≤ 22 make one correctly rounded multiplication or division); anything else goes
/// to the standard library parser. Returns None for non-numbers; NaN/inf parse as such.
#[inline]
pub(crate) fn parse_f64(s: &[u8]) -> Option<f64> {
    if let Some((neg, mant, exp, _)) = decimal(s)
        && mant < (1u64 << 53)
    {
        let m = mant as f64;
        let v = if mant == 0 {
            Some(0.0)
        } else if (0..=22).contains(&exp) {
            Some(m * POW10[exp as usize])
        } else if (-22..0).contains(&exp) {
            Some(m / POW10[(-exp) as usize])
        } else {
            None
        };
        if let Some(v) = v {
            return Some(if neg { -v } else { v });
        }
    }
    std::str::from_utf8(s).ok()?.parse::<f64>().ok()
}

/// Timestamp in integer ns from a decimal in `unit` (10^pow10 ns), exactly when the text has at
/// most 19 significant digits (`1.700000000005e+18` included), else via f64.
fn parse_timestamp(s: &[u8], pow10: i32) -> Option<i64> {
    if let Some((neg, mant, exp, _)) = decimal(s) {
        let e = exp + pow10;
        let m = i128::from(mant);
        let v: i128 = if e >= 0 {
            if e > 38 {
                return if mant == 0 { Some(0) } else { None };
            }
            m.checked_mul(10i128.checked_pow(e as u32)?)?
        } else if e < -38 {
            0
        } else {
            let d = 10i128.pow((-e) as u32);
            (m + d / 2) / d
        };
        let v = if neg { -v } else { v };
        return i64::try_from(v).ok();
    }
    let x: f64 = std::str::from_utf8(s).ok()?.parse().ok()?;
    let ns = x * 10f64.powi(pow10);
    if ns.is_finite() && ns.abs() < 9.2e18 {
        Some(ns.round() as i64)
    } else {
        None
    }
}

/// Sequential accumulation of parsed pieces into the log columns.
#[derive(Default)]
struct Accum {
    first_data_line: u64,
    last_t: Option<i64>,
    t0: i64,
    dt_ns: Vec<u32>,
    long_steps: Vec<(usize, i64)>,
    reference: [f64; 6],
    data: [Vec<f32>; 6],
    temp: Vec<f32>,
    /// For each skipped data line, the number of samples kept before it (sorted).
    skip_marks: Vec<usize>,
    skip_marks_overflow: bool,
}

impl Accum {
    fn mark_skip(&mut self) {
        self.mark_at(self.data[0].len());
    }

    fn mark_at(&mut self, kept: usize) {
        if self.skip_marks.len() < MAX_SKIP_MARKS {
            self.skip_marks.push(kept);
        } else {
            self.skip_marks_overflow = true;
        }
    }

    fn merge(&mut self, p: &Piece, base_line: u64, lay: &Layout, stats: &mut ParseStats) {
        // Skipped lines (blank/junk/NaN) are interleaved with rows; each is marked with the number
        // of samples kept before it, so rows and skips are merged in line order.
        let mut skips = p.skips.iter().peekable();
        let mut pending_marks: Vec<usize> = Vec::new();
        if self.last_t.is_none() && !p.rows.is_empty() {
            // Reference of the f32 offsets: the per-channel median of the first rows, so that a
            // spike in the very first sample cannot inflate every offset (and its rounding).
            let k = p.rows.len().min(1001);
            for c in 0..6 {
                let mut v: Vec<f64> = p.rows[..k].iter().map(|r| r.v[c]).collect();
                let mid = v.len() / 2;
                v.select_nth_unstable_by(mid, f64::total_cmp);
                self.reference[c] = v[mid];
            }
        }
        for row in &p.rows {
            while let Some(&&(rel, kind)) = skips.peek() {
                if rel >= row.rel_line {
                    break;
                }
                skips.next();
                self.skip(kind, base_line + u64::from(rel) + 1, stats);
                pending_marks.push(self.data[0].len());
            }
            let line = base_line + u64::from(row.rel_line) + 1;
            match self.last_t {
                Some(last) if row.t == last => {
                    note(
                        &mut stats.duplicate_timestamps,
                        &mut stats.duplicate_lines_first,
                        line,
                    );
                    pending_marks.push(self.data[0].len());
                    continue;
                }
                Some(last) if row.t < last => {
                    note(
                        &mut stats.backwards_timestamps,
                        &mut stats.backwards_lines_first,
                        line,
                    );
                    pending_marks.push(self.data[0].len());
                    continue;
                }
                Some(last) => {
                    let d = row.t - last;
                    if d >= i64::from(u32::MAX) {
                        self.long_steps.push((self.dt_ns.len(), d));
                        self.dt_ns.push(u32::MAX);
                    } else {
                        self.dt_ns.push(d as u32);
                    }
                }
                None => {
                    self.t0 = row.t;
                }
            }
            self.last_t = Some(row.t);
            for c in 0..6 {
                self.data[c].push((row.v[c] - self.reference[c]) as f32);
            }
            if lay.has_temp {
                self.temp.push(row.temp as f32);
            }
        }
        for &(rel, kind) in skips {
            self.skip(kind, base_line + u64::from(rel) + 1, stats);
            pending_marks.push(self.data[0].len());
        }
        for m in pending_marks {
            self.mark_at(m);
        }
    }

    fn skip(&mut self, kind: Skip, line: u64, stats: &mut ParseStats) {
        match kind {
            Skip::Blank => stats.blank_lines += 1,
            Skip::Junk => note(&mut stats.junk_rows, &mut stats.junk_lines_first, line),
            Skip::Nan => note(&mut stats.nan_rows, &mut stats.nan_lines_first, line),
        }
    }

    fn line_of_sample(&self, i: usize) -> Option<u64> {
        if self.skip_marks_overflow {
            return None;
        }
        // Skipped lines before sample i are those marked with fewer than or exactly i kept samples.
        let skipped = self.skip_marks.partition_point(|&m| m <= i);
        Some(self.first_data_line + (i + skipped) as u64)
    }

    fn finish(mut self, mut stats: ParseStats, has_temp: bool) -> CoreResult<ImuLog> {
        self.skip_marks.sort_unstable();
        let n = self.data[0].len();
        stats.samples = n;
        if n == 0 {
            let why = if stats.junk_rows > 0 {
                format!(
                    "no usable IMU sample in {} lines: {} junk rows (first at line {}), {} NaN rows; \
                     expected `timestamp,gx,gy,gz,ax,ay,az` numbers",
                    stats.lines,
                    stats.junk_rows,
                    stats.junk_lines_first.first().copied().unwrap_or(0),
                    stats.nan_rows
                )
            } else {
                format!(
                    "no usable IMU sample in {} lines ({} NaN rows, {} blank)",
                    stats.lines, stats.nan_rows, stats.blank_lines
                )
            };
            return Err(CoreError::input(why));
        }
        if n < 2 {
            return Err(CoreError::input(format!(
                "only one usable IMU sample (line {})",
                self.first_data_line
            )));
        }
        if stats.backwards_timestamps as f64 > 0.01 * (n as f64).max(100.0) {
            return Err(CoreError::input(format!(
                "{} timestamps go backwards (first at line {}): a forward time glitch or \
                 concatenated logs; fix the timestamps or split the log",
                stats.backwards_timestamps,
                stats.backwards_lines_first.first().copied().unwrap_or(0)
            )));
        }
        // Steps: median, jitter, gaps.
        let step = |i: usize| -> i64 {
            let d = self.dt_ns[i];
            if d == u32::MAX {
                self.long_steps
                    .binary_search_by_key(&i, |s| s.0)
                    .map_or(i64::from(d), |k| self.long_steps[k].1)
            } else {
                i64::from(d)
            }
        };
        let mut sorted = self.dt_ns.clone();
        let mid = sorted.len() / 2;
        let med_ns = if sorted.len() % 2 == 1 {
            f64::from(*sorted.select_nth_unstable(mid).1)
        } else {
            let hi = f64::from(*sorted.select_nth_unstable(mid).1);
            let lo = f64::from(sorted[..mid].iter().copied().max().unwrap_or(0));
            0.5 * (lo + hi)
        };
        drop(sorted);
        let total_ns = self.last_t.unwrap_or(self.t0) as i128 - self.t0 as i128;
        stats.duration_s = total_ns as f64 * 1e-9;
        stats.dt_median_s = med_ns * 1e-9;
        stats.rate_hz = if med_ns > 0.0 { 1e9 / med_ns } else { 0.0 };
        let (mut mn, mut mx) = (i64::MAX, 0i64);
        let (mut s1, mut s2, mut cnt) = (0.0f64, 0.0f64, 0u64);
        let mut jmax = 0.0f64;
        let gap_limit = GAP_FACTOR * med_ns;
        let mut t_rel: i64 = 0;
        for i in 0..self.dt_ns.len() {
            let d = step(i);
            let t_before = t_rel;
            t_rel = t_rel.saturating_add(d);
            mn = mn.min(d);
            mx = mx.max(d);
            let df = d as f64;
            if df > gap_limit {
                stats.gaps += 1;
                stats.gap_time_s += (df - med_ns) * 1e-9;
                if stats.gaps_first.len() < FIRST_LINES {
                    stats.gaps_first.push(TimeGap {
                        sample_index: i + 1,
                        line: self.line_of_sample(i + 1),
                        start_s: t_before as f64 * 1e-9,
                        duration_s: df * 1e-9,
                    });
                }
            } else {
                let r = df - med_ns;
                s1 += r;
                s2 += r * r;
                cnt += 1;
                jmax = jmax.max(r.abs());
            }
        }
        stats.dt_min_s = mn as f64 * 1e-9;
        stats.dt_max_s = mx as f64 * 1e-9;
        if cnt > 1 {
            let m = s1 / cnt as f64;
            stats.jitter_std_s = ((s2 / cnt as f64 - m * m).max(0.0)).sqrt() * 1e-9;
        }
        stats.jitter_max_abs_s = jmax * 1e-9;
        Ok(ImuLog {
            stats,
            t0_ns: self.t0,
            dt_ns: self.dt_ns,
            long_steps: self.long_steps,
            reference: self.reference,
            data: self.data,
            temperature: if has_temp { Some(self.temp) } else { None },
        })
    }
}

/// Consume an optional `+`/`-` at `*pos` (of an exponent); true for `-`.
#[inline]
fn take_sign(s: &[u8], pos: &mut usize) -> bool {
    match s.get(*pos) {
        Some(b'-') => {
            *pos += 1;
            true
        }
        Some(b'+') => {
            *pos += 1;
            false
        }
        _ => false,
    }
}
