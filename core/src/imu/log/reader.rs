//! The batch loop of [`read_imu_log`]: bounded memory whatever the log's size.
//!
//! The text is read in fixed batches of 8 MiB. While one batch is parsed (split at line
//! boundaries into pieces parsed in parallel, see `line`), the next one is read on the calling
//! thread, so reading overlaps parsing without requiring the reader to be `Send`. The first
//! non-blank line fixes the layout (`layout`); an incomplete last line is carried over to the
//! next batch, and a line longer than a whole batch is skipped as junk.

use std::io::BufRead;

use rayon::prelude::*;

use super::accum::{Accum, note};
use super::layout::{Layout, resolve_layout};
use super::line::{Piece, parse_piece, trim};
use super::{ImuCsvParams, ImuLog, ParseStats};
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

/// Bytes read per batch; each batch is split into pieces parsed in parallel.
const BATCH_BYTES: usize = 8 << 20;

/// Parses an IMU CSV log (see the `imu::log` module doc) into compact columns.
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
