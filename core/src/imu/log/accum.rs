//! Sequential accumulation of parsed pieces into the compact columns of an [`ImuLog`].
//!
//! Pieces arrive in line order. Each kept row is checked against the previous kept timestamp
//! (duplicate, backwards) and appended as f32 offsets from a per-channel reference (the median
//! of the first rows); skipped lines are counted and remembered so that a sample index can be
//! mapped back to its line number. [`Accum::finish`] derives the rate, jitter and gaps.

use super::layout::Layout;
use super::line::{Piece, Skip};
use super::{ImuLog, ParseStats, TimeGap};
use crate::error::{CoreError, CoreResult};

/// How many line numbers of each kind of skipped row are kept in [`ParseStats`].
const FIRST_LINES: usize = 10;
/// A gap is a timestamp step longer than this multiple of the median step.
const GAP_FACTOR: f64 = 1.5;
/// Upper bound on remembered skip positions (used to map sample indices back to line numbers).
const MAX_SKIP_MARKS: usize = 1 << 20;

/// Counts one skipped row and keeps its line number if it is among the first few.
pub(super) fn note(count: &mut u64, first: &mut Vec<u64>, line: u64) {
    *count += 1;
    if first.len() < FIRST_LINES {
        first.push(line);
    }
}

/// Sequential accumulation of parsed pieces into the log columns.
#[derive(Default)]
pub(super) struct Accum {
    pub(super) first_data_line: u64,
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
    pub(super) fn mark_skip(&mut self) {
        self.mark_at(self.data[0].len());
    }

    fn mark_at(&mut self, kept: usize) {
        if self.skip_marks.len() < MAX_SKIP_MARKS {
            self.skip_marks.push(kept);
        } else {
            self.skip_marks_overflow = true;
        }
    }

    pub(super) fn merge(
        &mut self,
        p: &Piece,
        base_line: u64,
        lay: &Layout,
        stats: &mut ParseStats,
    ) {
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

    pub(super) fn finish(mut self, mut stats: ParseStats, has_temp: bool) -> CoreResult<ImuLog> {
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
