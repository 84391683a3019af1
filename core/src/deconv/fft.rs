//! 2-D real FFTs on `f32` planes: `realfft` real transforms along rows, `rustfft` complex
//! transforms along the columns of the half spectrum, with cached plans.
//!
//! Rows use real-to-complex transforms (half the work of complex ones). The columns of the
//! half spectrum are complex and are transformed in place, many per call (rustfft batches a
//! buffer holding several columns back to back, with its SIMD kernels).
//!
//! Spectra are stored column-major (`spec[c * height + k]`, `c < width / 2 + 1`) so that the column
//! passes work on contiguous memory; pointwise filters do not care about the layout as long as
//! every spectrum comes from the same [`Fft2`].

use std::sync::{Arc, Mutex, OnceLock};

use rayon::prelude::*;
use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};

/// Complex sample type of the spectra.
pub type C32 = Complex<f32>;

/// The process-wide planners: both memoise plans (and their twiddle tables) per length, so
/// repeated deconvolutions at one size plan only once.
fn planner() -> &'static Mutex<(RealFftPlanner<f32>, FftPlanner<f32>)> {
    static PLANNER: OnceLock<Mutex<(RealFftPlanner<f32>, FftPlanner<f32>)>> = OnceLock::new();
    PLANNER.get_or_init(|| Mutex::new((RealFftPlanner::new(), FftPlanner::new())))
}

/// Whether `n` has no prime factor above 7: the lengths rustfft handles with its fastest
/// mixed-radix butterflies (a large prime length falls back to Bluestein, several times slower).
pub fn is_smooth(mut n: usize) -> bool {
    if n == 0 {
        return false;
    }
    for p in [2, 3, 5, 7] {
        while n.is_multiple_of(p) {
            n /= p;
        }
    }
    n == 1
}

/// Smallest even 7-smooth length ≥ `n` (even so the real transforms take their fast path).
pub fn fast_len(n: usize) -> usize {
    let mut m = n.max(2);
    while !m.is_multiple_of(2) || !is_smooth(m) {
        m += 1;
    }
    m
}

/// A 2-D real FFT of a fixed `height × width`.
#[derive(Clone)]
pub struct Fft2 {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    row_fwd: Arc<dyn RealToComplex<f32>>,
    row_inv: Arc<dyn ComplexToReal<f32>>,
    col_fwd: Arc<dyn Fft<f32>>,
    col_inv: Arc<dyn Fft<f32>>,
    /// Intermediate half-spectrum buffers returned by finished transforms, so that the
    /// iterative solvers (hundreds of transforms of one size) do not allocate and page in a
    /// fresh spectrum-sized buffer for every one of them.
    spare: Arc<Mutex<Vec<Vec<C32>>>>,
}

impl Fft2 {
    /// Plans (or fetches cached plans) for `height × width`.
    pub fn new(height: usize, width: usize) -> Self {
        let mut p = planner().lock().unwrap_or_else(|e| e.into_inner());
        let (real, complex) = &mut *p;
        Self {
            height,
            width,
            row_fwd: real.plan_fft_forward(width),
            row_inv: real.plan_fft_inverse(width),
            col_fwd: complex.plan_fft_forward(height),
            col_inv: complex.plan_fft_inverse(height),
            spare: Arc::default(),
        }
    }

    /// A spectrum-sized buffer (contents unspecified) from the spares, or a new one.
    fn take_spare(&self) -> Vec<C32> {
        let n = self.spec_len();
        let mut spare = self.spare.lock().unwrap_or_else(|e| e.into_inner());
        spare
            .pop()
            .filter(|v| v.len() == n)
            .unwrap_or_else(|| vec![C32::new(0.0, 0.0); n])
    }

    /// Returns a buffer from [`Fft2::take_spare`]; two are enough for any caller.
    fn put_spare(&self, buf: Vec<C32>) {
        let mut spare = self.spare.lock().unwrap_or_else(|e| e.into_inner());
        if spare.len() < 2 {
            spare.push(buf);
        }
    }

    /// Number of complex columns of the half spectrum.
    pub fn spec_width(&self) -> usize {
        self.width / 2 + 1
    }

    /// Length of a spectrum buffer.
    pub fn spec_len(&self) -> usize {
        self.spec_width() * self.height
    }

    /// Unnormalised forward transform of a row-major `height × width` plane.
    ///
    /// Rows are transformed in parallel; the column pass then works on blocks of [`BLOCK`]
    /// columns, gathering each block with reads of `BLOCK` adjacent values per row (a cache line
    /// or two) rather than one strided read per value, which at 1080p misses cache and TLB on
    /// almost every access.
    pub fn forward(&self, input: &[f32]) -> Vec<C32> {
        let mut spec = vec![C32::new(0.0, 0.0); self.spec_len()];
        self.forward_into(input, &mut spec);
        spec
    }

    /// [`Fft2::forward`] into `spec` (length [`Fft2::spec_len`], every value overwritten).
    pub fn forward_into(&self, input: &[f32], spec: &mut [C32]) {
        let (h, w, wc) = (self.height, self.width, self.spec_width());
        debug_assert_eq!(input.len(), h * w);
        debug_assert_eq!(spec.len(), h * wc);
        let mut rows = self.take_spare();
        rows.par_chunks_mut(wc).enumerate().for_each_init(
            || (vec![0.0f32; w], self.row_fwd.make_scratch_vec()),
            |(buf, scratch), (r, out)| {
                let src = &input[r * w..(r + 1) * w];
                // Zero rows (most of a padded kernel plane) transform to zero.
                if src.iter().all(|&v| v == 0.0) {
                    out.fill(C32::new(0.0, 0.0));
                    return;
                }
                buf.copy_from_slice(src);
                // Lengths are right by construction; realfft only errs on wrong lengths.
                let _ = self.row_fwd.process_with_scratch(buf, out, scratch);
            },
        );
        spec.par_chunks_mut(h * BLOCK).enumerate().for_each_init(
            || vec![C32::new(0.0, 0.0); self.col_fwd.get_inplace_scratch_len()],
            |scratch, (b, out)| {
                let (c0, nc) = (b * BLOCK, out.len() / h);
                for k in 0..h {
                    let src = &rows[k * wc + c0..k * wc + c0 + nc];
                    for (ci, v) in src.iter().enumerate() {
                        out[ci * h + k] = *v;
                    }
                }
                self.col_fwd.process_with_scratch(out, scratch);
            },
        );
        self.put_spare(rows);
    }

    /// Unnormalised inverse transform (the result is `height · width` times the signal).
    ///
    /// Columns first (contiguous in the spectrum layout), then rows in blocks of [`BLOCK`], each
    /// block gathered with short contiguous reads per column (see [`Fft2::forward`]).
    pub fn inverse(&self, spec: &[C32]) -> Vec<f32> {
        let mut out = vec![0.0f32; self.height * self.width];
        self.inverse_into(spec, &mut out);
        out
    }

    /// [`Fft2::inverse`] into `out` (length `height · width`, every value overwritten).
    pub fn inverse_into(&self, spec: &[C32], out: &mut [f32]) {
        let (h, w, wc) = (self.height, self.width, self.spec_width());
        debug_assert_eq!(spec.len(), h * wc);
        debug_assert_eq!(out.len(), h * w);
        let mut cols = self.take_spare();
        cols.copy_from_slice(spec);
        cols.par_chunks_mut(h * BLOCK).for_each_init(
            || vec![C32::new(0.0, 0.0); self.col_inv.get_inplace_scratch_len()],
            |scratch, block| self.col_inv.process_with_scratch(block, scratch),
        );
        out.par_chunks_mut(w * BLOCK).enumerate().for_each_init(
            || {
                (
                    vec![C32::new(0.0, 0.0); wc * BLOCK],
                    self.row_inv.make_scratch_vec(),
                )
            },
            |(tile, scratch), (b, rows)| {
                let (r0, nr) = (b * BLOCK, rows.len() / w);
                for c in 0..wc {
                    let src = &cols[c * h + r0..c * h + r0 + nr];
                    for (ri, v) in src.iter().enumerate() {
                        tile[ri * wc + c] = *v;
                    }
                }
                for (ri, row) in rows.chunks_mut(w).enumerate() {
                    let buf = &mut tile[ri * wc..(ri + 1) * wc];
                    // The DC (and, for even widths, Nyquist) bins of a real signal are real;
                    // round-off leaves a tiny imaginary part that realfft would flag, so drop it.
                    buf[0].im = 0.0;
                    if w.is_multiple_of(2) {
                        buf[wc - 1].im = 0.0;
                    }
                    let _ = self.row_inv.process_with_scratch(buf, row, scratch);
                }
            },
        );
        self.put_spare(cols);
    }

    /// Spectrum of a kernel centred on the FFT origin (so that multiplying by it convolves
    /// without shifting): the kernel centre goes to (0, 0) and the rest wraps around.
    pub fn kernel_spectrum(
        &self,
        kw: usize,
        kh: usize,
        k: impl Fn(usize, usize) -> f64,
    ) -> Vec<C32> {
        let mut plane = vec![0.0f32; self.height * self.width];
        let mut spec = vec![C32::new(0.0, 0.0); self.spec_len()];
        self.kernel_spectrum_into(kw, kh, k, &mut plane, &mut spec);
        spec
    }

    /// [`Fft2::kernel_spectrum`] into `spec`, with `plane` (`height · width`, contents
    /// unspecified) as the buffer for the wrapped kernel.
    pub fn kernel_spectrum_into(
        &self,
        kw: usize,
        kh: usize,
        k: impl Fn(usize, usize) -> f64,
        plane: &mut [f32],
        spec: &mut [C32],
    ) {
        let (h, w) = (self.height, self.width);
        plane.fill(0.0);
        let (cx, cy) = (kw / 2, kh / 2);
        for y in 0..kh {
            let py = (y + h - cy) % h;
            for x in 0..kw {
                let px = (x + w - cx) % w;
                plane[py * w + px] += k(x, y) as f32;
            }
        }
        self.forward_into(plane, spec);
    }

    /// [`Fft2::kernel_spectrum`], faster for kernels of few rows (equal up to float rounding).
    ///
    /// Only the kernel's rows of the plane are non-zero, so after their row transforms each
    /// column's transform is a short sum, `K[k] = Σ_j R_j · e^{−2πi k y_j / h}`. Per kernel row
    /// the factors `e^{−2πi k y_j / h}` form one table over `k`, so each spectrum column is a few
    /// complex scaled additions of those tables — contiguous, vectorisable, and no image-sized
    /// plane is ever allocated. Kernels with many rows relative to the height take the plain
    /// 2-D transform. The non-blind solvers use it; the blind estimator keeps
    /// [`Fft2::kernel_spectrum`], whose coarse-to-fine search is chaotic enough for rounding
    /// differences to change which kernel it settles on.
    pub(super) fn kernel_spectrum_direct(
        &self,
        kw: usize,
        kh: usize,
        k: impl Fn(usize, usize) -> f64,
    ) -> Vec<C32> {
        let (h, w, wc) = (self.height, self.width, self.spec_width());
        // A direct column sum costs one complex multiply-add per kernel row and bin; the column
        // FFTs about `5 log₂ h` flops per bin plus the gathers and the recombination.
        if kh > 2 * h.max(2).ilog2() as usize || kh > h || kw > w {
            return self.kernel_spectrum(kw, kh, k);
        }
        let (cx, cy) = (kw / 2, kh / 2);
        let tau = std::f64::consts::TAU;
        // Per non-zero kernel row: its row spectrum (split into re / im) and twiddle table.
        struct Row {
            re: Vec<f32>,
            im: Vec<f32>,
            tw_re: Vec<f32>,
            tw_im: Vec<f32>,
        }
        let rows: Vec<Row> = (0..kh)
            .filter_map(|y| {
                let mut buf = vec![0.0f32; w];
                for x in 0..kw {
                    buf[(x + w - cx) % w] += k(x, y) as f32;
                }
                if buf.iter().all(|&v| v == 0.0) {
                    return None;
                }
                let mut out = self.row_fwd.make_output_vec();
                let _ = self.row_fwd.process(&mut buf, &mut out);
                let py = (y + h - cy) % h;
                let (tw_re, tw_im) = (0..h)
                    .map(|m| {
                        let a = -tau * ((m * py) % h) as f64 / h as f64;
                        (a.cos() as f32, a.sin() as f32)
                    })
                    .unzip();
                Some(Row {
                    re: out.iter().map(|c| c.re).collect(),
                    im: out.iter().map(|c| c.im).collect(),
                    tw_re,
                    tw_im,
                })
            })
            .collect();
        let mut spec = vec![C32::new(0.0, 0.0); h * wc];
        spec.par_chunks_mut(h).enumerate().for_each_init(
            || (vec![0.0f32; h], vec![0.0f32; h]),
            |(acc_re, acc_im), (c, out)| {
                acc_re.fill(0.0);
                acc_im.fill(0.0);
                for r in &rows {
                    let (a, b) = (r.re[c], r.im[c]);
                    for (((ar, ai), &tr), &ti) in acc_re
                        .iter_mut()
                        .zip(acc_im.iter_mut())
                        .zip(&r.tw_re)
                        .zip(&r.tw_im)
                    {
                        *ar += a * tr - b * ti;
                        *ai += a * ti + b * tr;
                    }
                }
                for ((o, &re), &im) in out.iter_mut().zip(acc_re.iter()).zip(acc_im.iter()) {
                    *o = C32::new(re, im);
                }
            },
        );
        spec
    }
}

/// Columns (rows) handled together by one task of the column (row) pass: enough for every row
/// (column) of the gather to read whole cache lines, few enough for the block to stay in L2.
const BLOCK: usize = 16;
