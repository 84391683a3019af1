//! The sample table of one track, expanded from `stsz`, `stsc` + `stco`/`co64`, `stts`, `ctts`,
//! `stss` and the edit list into one entry per sample, in decode order.
//!
//! Every count and offset comes from an untrusted file, so all arithmetic is checked and the
//! expansion is bounded by the sample count, itself checked against the limits and the file
//! size before anything is allocated.

use mp4_atom::{StszSamples, Trak};

use super::error::VideoError;
use super::limits::VideoLimits;

/// One compressed picture.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Sample {
    /// Byte offset in the file.
    pub offset: u64,
    /// Size in bytes (never zero once the table is built).
    pub size: u32,
    /// Decode time, media timescale.
    pub dts: i64,
    /// Presentation time after `ctts` and the edit list, media timescale.
    pub pts: i64,
    /// A sync sample (`stss`; every sample when there is no `stss`).
    pub keyframe: bool,
}

impl Sample {
    /// Whether the sample's bytes lie inside a file of `file_len` bytes.
    pub fn in_file(&self, file_len: u64) -> bool {
        self.offset
            .checked_add(u64::from(self.size))
            .is_some_and(|end| end <= file_len)
    }
}

fn bad(msg: impl Into<String>) -> VideoError {
    VideoError::Malformed(msg.into())
}

/// Builds the table of `trak`'s samples. `movie_timescale` converts the edit list's durations.
pub(crate) fn build(
    trak: &Trak,
    movie_timescale: u32,
    file_len: u64,
    limits: &VideoLimits,
) -> Result<(Vec<Sample>, i64), VideoError> {
    let stbl = &trak.mdia.minf.stbl;
    let count = match &stbl.stsz.samples {
        StszSamples::Identical { count, .. } => u64::from(*count),
        StszSamples::Different { sizes } => sizes.len() as u64,
    };
    if count > limits.max_frames {
        return Err(VideoError::TooManyFrames {
            frames: count,
            max_frames: limits.max_frames,
        });
    }
    // Every sample takes at least one byte of the file: a larger count is a lie.
    if count > file_len {
        return Err(bad(format!(
            "the sample table lists {count} samples in a file of {file_len} bytes"
        )));
    }
    let n = usize::try_from(count).map_err(|_| bad("sample count does not fit in memory"))?;
    let size_of = |i: usize| -> u32 {
        match &stbl.stsz.samples {
            StszSamples::Identical { size, .. } => *size,
            StszSamples::Different { sizes } => sizes.get(i).copied().unwrap_or(0),
        }
    };

    for i in 0..n {
        let size = u64::from(size_of(i));
        if size == 0 {
            return Err(VideoError::EmptySample { index: i as u64 });
        }
        if size > limits.max_sample_bytes {
            return Err(VideoError::SampleTooLarge {
                index: i as u64,
                size,
                max_bytes: limits.max_sample_bytes,
            });
        }
    }

    let offsets = chunk_samples(trak, n, &size_of)?;
    let (dts, duration) = decode_times(trak, n)?;
    let shift = edit_shift(trak, movie_timescale)?;

    let mut ctts = stbl
        .ctts
        .iter()
        .flat_map(|c| c.entries.iter())
        .flat_map(|e| std::iter::repeat_n(e.sample_offset, e.sample_count as usize))
        .take(n);

    let keyframes = match &stbl.stss {
        Some(stss) => {
            let mut k = vec![false; n];
            for &s in &stss.entries {
                if let Some(slot) = (s as usize).checked_sub(1).and_then(|i| k.get_mut(i)) {
                    *slot = true;
                }
            }
            k
        }
        None => vec![true; n],
    };

    let mut samples = Vec::with_capacity(n);
    for (i, ((&offset, &dts), &keyframe)) in offsets.iter().zip(&dts).zip(&keyframes).enumerate() {
        let offset_ct = ctts.next().unwrap_or(0);
        let pts = dts
            .checked_add(offset_ct)
            .and_then(|p| p.checked_add(shift))
            .ok_or_else(|| bad("presentation time overflows"))?;
        samples.push(Sample {
            offset,
            size: size_of(i),
            dts,
            pts,
            keyframe,
        });
    }
    Ok((samples, duration))
}

/// Offsets of the first `n` samples from the chunk offsets and the sample-to-chunk runs.
fn chunk_samples(
    trak: &Trak,
    n: usize,
    size_of: &dyn Fn(usize) -> u32,
) -> Result<Vec<u64>, VideoError> {
    let stbl = &trak.mdia.minf.stbl;
    let chunks: Vec<u64> = match (&stbl.stco, &stbl.co64) {
        (Some(stco), _) => stco.entries.iter().map(|&o| u64::from(o)).collect(),
        (None, Some(co64)) => co64.entries.clone(),
        (None, None) => return Err(bad("the video track has no chunk offsets (stco/co64)")),
    };
    let runs = &stbl.stsc.entries;
    if n > 0 && runs.is_empty() {
        return Err(bad("the video track has no sample-to-chunk table (stsc)"));
    }
    let mut offsets = Vec::with_capacity(n);
    let mut run = 0usize;
    for (ci, &chunk_offset) in chunks.iter().enumerate() {
        if offsets.len() == n {
            break;
        }
        let chunk_no = ci as u64 + 1;
        while run + 1 < runs.len() && u64::from(runs[run + 1].first_chunk) <= chunk_no {
            run += 1;
        }
        let entry = &runs[run];
        if u64::from(entry.first_chunk) > chunk_no || entry.first_chunk == 0 {
            return Err(bad(
                "the sample-to-chunk table (stsc) does not start at chunk 1",
            ));
        }
        let mut offset = chunk_offset;
        for _ in 0..entry.samples_per_chunk {
            if offsets.len() == n {
                break;
            }
            let size = u64::from(size_of(offsets.len()));
            offsets.push(offset);
            offset = offset
                .checked_add(size)
                .ok_or_else(|| bad("a chunk runs past the largest file offset"))?;
        }
    }
    if offsets.len() < n {
        return Err(bad(format!(
            "the chunk tables place {} of {n} samples",
            offsets.len()
        )));
    }
    Ok(offsets)
}

/// Decode times of the first `n` samples from the time-to-sample runs, and the end time
/// of the last one (the track's duration).
fn decode_times(trak: &Trak, n: usize) -> Result<(Vec<i64>, i64), VideoError> {
    let mut dts = Vec::with_capacity(n);
    let mut t: i64 = 0;
    'runs: for e in &trak.mdia.minf.stbl.stts.entries {
        for _ in 0..e.sample_count {
            if dts.len() == n {
                break 'runs;
            }
            dts.push(t);
            t = t
                .checked_add(i64::from(e.sample_delta))
                .ok_or_else(|| bad("decode time overflows"))?;
        }
    }
    if dts.len() < n {
        return Err(bad(format!(
            "the time-to-sample table (stts) times {} of {n} samples",
            dts.len()
        )));
    }
    Ok((dts, t))
}

/// Shift from composition time to presentation time given by the edit list: empty edits
/// delay the start, the first real edit says which media time is shown first. Later edits
/// (cuts inside the clip) are not applied: phones and encoders write one edit.
fn edit_shift(trak: &Trak, movie_timescale: u32) -> Result<i64, VideoError> {
    let Some(elst) = trak.edts.as_ref().and_then(|e| e.elst.as_ref()) else {
        return Ok(0);
    };
    let media_timescale = u128::from(trak.mdia.mdhd.timescale);
    let mut empty: u128 = 0;
    for e in &elst.entries {
        match e.media_time {
            None => {
                if movie_timescale == 0 {
                    return Err(bad("the movie timescale is zero"));
                }
                let d =
                    u128::from(e.segment_duration) * media_timescale / u128::from(movie_timescale);
                empty = empty.saturating_add(d);
            }
            Some(t) => {
                let empty = i64::try_from(empty).map_err(|_| bad("edit list delay overflows"))?;
                let t = i64::try_from(t).map_err(|_| bad("edit list media time overflows"))?;
                return empty
                    .checked_sub(t)
                    .ok_or_else(|| bad("edit list shift overflows"));
            }
        }
    }
    Ok(0)
}
