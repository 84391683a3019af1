//! The overlapping Allan variance sums: Σ (x_{k+2m} − 2x_{k+m} + x_k)² for every cluster size
//! at once, over a compact cumulative sum ([`PhaseBuffer`]), blocked for the cache and split
//! across threads.

use rayon::prelude::*;

use crate::error::CoreResult;
use crate::progress::Progress;

/// Block length (samples) of the multi-τ pass and of the f32 delta storage of x.
const BLOCK: usize = 256;

/// Cluster sizes: powers of two (allantools "octave": m < N + 1) plus, for `per_octave` > 1,
/// rounded 2^(j/per_octave) in between; only m with at least 2 second differences.
pub fn cluster_sizes(n_samples: usize, per_octave: u32) -> Vec<usize> {
    let len = n_samples + 1; // phase points
    let mut ms = Vec::new();
    let p = per_octave.max(1);
    let mut j: u32 = 0;
    loop {
        let m = if p == 1 {
            1usize.checked_shl(j).unwrap_or(usize::MAX)
        } else {
            2f64.powf(f64::from(j) / f64::from(p)).round() as usize
        };
        // At least 2 second differences: n_terms = len − 2m ≥ 2.
        if m == 0 || m.checked_mul(2).is_none_or(|v| v + 2 > len) {
            break;
        }
        if ms.last() != Some(&m) {
            ms.push(m);
        }
        j += 1;
        if j > 64 * p {
            break;
        }
    }
    ms
}

/// Compact form of the cumulative sum x of one axis: x_i = heads[i / BLOCK] + deltas[i], the
/// heads exact in f64, the deltas (|x_i − x_head| ≲ √BLOCK·σ for a static log) in f32. Rounding
/// a delta costs ~6·10⁻⁸ of its size, i.e. ~10⁻⁶ σ — far below what the estimator resolves —
/// and halves both the buffer and the memory traffic of the long-τ passes, which read ~2 log₂ N
/// streams of x and are bandwidth-bound.
#[derive(Default)]
pub(crate) struct PhaseBuffer {
    heads: Vec<f64>,
    deltas: Vec<f32>,
}

/// Σ (x_{k+2m} − 2x_{k+m} + x_k)² for every m in `ms`, x the mean-removed cumulative sum of
/// `y` (offsets; a constant cancels) kept in `buf` (reused across axes). The pass over x is
/// blocked (all m per block, so the short-m windows stay in cache) and split in index ranges
/// across threads. For m a multiple of the block length the heads of the three terms combine
/// into one constant per block, so the inner loop reads only f32 deltas.
pub(crate) fn oavar_sums(
    y: &[f32],
    ms: &[usize],
    buf: &mut PhaseBuffer,
    progress: &dyn Progress,
) -> CoreResult<Vec<f64>> {
    let n = y.len();
    let len = n + 1;
    // Mean and prefix sums in parallel chunks (chunk = whole blocks): chunk totals, their
    // running offsets, then each chunk fills its heads and deltas.
    let chunk_blocks = (len.div_ceil(BLOCK) / (rayon::current_num_threads() * 4).max(1)).max(16);
    let chunk = chunk_blocks * BLOCK;
    let mean = y
        .par_chunks(chunk)
        .map(|c| c.iter().map(|&v| f64::from(v)).sum::<f64>())
        .sum::<f64>()
        / n.max(1) as f64;
    buf.heads.clear();
    buf.heads.resize(len.div_ceil(BLOCK), 0.0);
    buf.deltas.clear();
    buf.deltas.resize(len, 0.0);
    let totals: Vec<f64> = y
        .par_chunks(chunk)
        .map(|c| c.iter().map(|&v| f64::from(v) - mean).sum::<f64>())
        .collect();
    let mut starts = Vec::with_capacity(totals.len() + 1);
    let mut acc = 0.0f64;
    for t in &totals {
        starts.push(acc);
        acc += t;
    }
    starts.push(acc);
    buf.deltas
        .par_chunks_mut(chunk)
        .zip(buf.heads.par_chunks_mut(chunk_blocks))
        .enumerate()
        .for_each(|(ci, (dd, hh))| {
            let i0 = ci * chunk;
            let mut s = starts[ci];
            let mut head = s;
            for (k, out) in dd.iter_mut().enumerate() {
                if k % BLOCK == 0 {
                    head = s;
                    hh[k / BLOCK] = head;
                }
                *out = (s - head) as f32;
                if let Some(&v) = y.get(i0 + k) {
                    s += f64::from(v) - mean;
                }
            }
        });
    let (heads, d) = (&buf.heads[..], &buf.deltas[..]);
    let longest = ms
        .iter()
        .map(|&m| len.saturating_sub(2 * m))
        .max()
        .unwrap_or(0);
    let n_blocks = longest.div_ceil(BLOCK);
    let parts = (rayon::current_num_threads() * 4)
        .clamp(1, 64)
        .min(n_blocks.max(1));
    let per = n_blocks.div_ceil(parts.max(1)).max(1);
    let mut scratch_len = 0;
    for &m in ms {
        if m < BLOCK {
            scratch_len = scratch_len.max(BLOCK + 2 * m);
        }
    }
    let x_at = |j: usize| heads[j / BLOCK] + f64::from(d[j]);
    let partial: Vec<Vec<f64>> = (0..parts)
        .into_par_iter()
        .map(|p| {
            let mut sums = vec![0.0f64; ms.len()];
            let mut xs = vec![0.0f64; scratch_len];
            let (b0, b1) = (p * per, ((p + 1) * per).min(n_blocks));
            for blk in b0..b1 {
                let b = blk * BLOCK;
                // Exact f64 x over the window the unaligned m need.
                let w_end = (b + scratch_len).min(len);
                for (k, v) in xs[..w_end - b].iter_mut().enumerate() {
                    *v = x_at(b + k);
                }
                for (k, &m) in ms.iter().enumerate() {
                    let n_terms = len.saturating_sub(2 * m);
                    if b >= n_terms {
                        continue;
                    }
                    let e = (b + BLOCK).min(n_terms);
                    let cnt = e - b;
                    sums[k] += if m < BLOCK {
                        second_diff_sq(&xs[..cnt], &xs[m..m + cnt], &xs[2 * m..2 * m + cnt])
                    } else if m % BLOCK == 0 {
                        let q = m / BLOCK;
                        let h = heads[blk + 2 * q] - 2.0 * heads[blk + q] + heads[blk];
                        second_diff_sq_f32(h, &d[b..e], &d[b + m..e + m], &d[b + 2 * m..e + 2 * m])
                    } else {
                        // Dense (non-octave) long m: reconstruct each term.
                        (b..e)
                            .map(|i| {
                                let v = x_at(i + 2 * m) - 2.0 * x_at(i + m) + x_at(i);
                                v * v
                            })
                            .sum()
                    };
                }
                if blk % 1024 == 0 {
                    progress.check()?;
                }
            }
            Ok(sums)
        })
        .collect::<CoreResult<_>>()?;
    let mut sums = vec![0.0f64; ms.len()];
    for p in &partial {
        for (s, v) in sums.iter_mut().zip(p) {
            *s += v;
        }
    }
    Ok(sums)
}

/// Σ (h + c − 2b + a)² over f32 deltas, in f64, four accumulators.
#[inline]
fn second_diff_sq_f32(h: f64, a: &[f32], b: &[f32], c: &[f32]) -> f64 {
    let n = a.len().min(b.len()).min(c.len());
    let (a, b, c) = (&a[..n], &b[..n], &c[..n]);
    let mut acc = [0.0f64; 4];
    let n4 = n / 4 * 4;
    let mut i = 0;
    while i < n4 {
        for j in 0..4 {
            let e = h + (f64::from(c[i + j]) - 2.0 * f64::from(b[i + j]) + f64::from(a[i + j]));
            acc[j] += e * e;
        }
        i += 4;
    }
    let mut tail = 0.0;
    for k in n4..n {
        let e = h + (f64::from(c[k]) - 2.0 * f64::from(b[k]) + f64::from(a[k]));
        tail += e * e;
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// Σ (c − 2b + a)², four independent accumulators so the loop vectorises.
#[inline]
fn second_diff_sq(a: &[f64], b: &[f64], c: &[f64]) -> f64 {
    let n = a.len().min(b.len()).min(c.len());
    let (a, b, c) = (&a[..n], &b[..n], &c[..n]);
    let mut acc = [0.0f64; 4];
    let n4 = n / 4 * 4;
    let mut i = 0;
    while i < n4 {
        for j in 0..4 {
            let d = c[i + j] - 2.0 * b[i + j] + a[i + j];
            acc[j] += d * d;
        }
        i += 4;
    }
    let mut tail = 0.0;
    for k in n4..n {
        let d = c[k] - 2.0 * b[k] + a[k];
        tail += d * d;
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}
