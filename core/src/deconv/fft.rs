//! 2-D real FFTs on `f32` planes, built from `realfft` 1-D transforms, with cached plans.
//!
//! Rows use real-to-complex transforms (half the work of complex ones). The columns of the
//! half spectrum are complex; caliper-core only links `realfft`, so a complex column transform of
//! `z = a + ib` is assembled from two real transforms, `Z = A + iB` with `A`, `B` extended to the
//! full length by Hermitian symmetry — the same flop count as one complex FFT. The inverse uses
//! `IFFT(z) = conj(FFT(conj(z)))`.
//!
//! Spectra are stored column-major (`spec[c * height + k]`, `c < width / 2 + 1`) so that the column
//! passes work on contiguous memory; pointwise filters do not care about the layout as long as
//! every spectrum comes from the same [`Fft2`].

use std::sync::{Arc, Mutex, OnceLock};

use rayon::prelude::*;
use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};

/// Complex sample type of the spectra.
pub type C32 = Complex<f32>;

/// The process-wide planner: `RealFftPlanner` memoises plans (and their twiddle tables) per
/// length, so repeated deconvolutions at one size plan only once.
fn planner() -> &'static Mutex<RealFftPlanner<f32>> {
    static PLANNER: OnceLock<Mutex<RealFftPlanner<f32>>> = OnceLock::new();
    PLANNER.get_or_init(|| Mutex::new(RealFftPlanner::new()))
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
    col_fwd: Arc<dyn RealToComplex<f32>>,
}

impl Fft2 {
    /// Plans (or fetches cached plans) for `height × width`.
    pub fn new(height: usize, width: usize) -> Self {
        let mut p = planner().lock().unwrap_or_else(|e| e.into_inner());
        Self {
            height,
            width,
            row_fwd: p.plan_fft_forward(width),
            row_inv: p.plan_fft_inverse(width),
            col_fwd: p.plan_fft_forward(height),
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
        let (h, w, wc) = (self.height, self.width, self.spec_width());
        debug_assert_eq!(input.len(), h * w);
        let mut rows = vec![C32::new(0.0, 0.0); h * wc];
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
        let mut spec = vec![C32::new(0.0, 0.0); h * wc];
        spec.par_chunks_mut(h * BLOCK).enumerate().for_each_init(
            || ColScratch::new(&self.col_fwd, h),
            |s, (b, out)| {
                let (c0, nc) = (b * BLOCK, out.len() / h);
                for k in 0..h {
                    let src = &rows[k * wc + c0..k * wc + c0 + nc];
                    for (ci, v) in src.iter().enumerate() {
                        s.re[ci * h + k] = v.re;
                        s.im[ci * h + k] = v.im;
                    }
                }
                for (ci, col) in out.chunks_mut(h).enumerate() {
                    s.complex_fft(&self.col_fwd, ci, col, false);
                }
            },
        );
        spec
    }

    /// Unnormalised inverse transform (the result is `height · width` times the signal).
    ///
    /// Columns first (contiguous in the spectrum layout), then rows in blocks of [`BLOCK`], each
    /// block gathered with short contiguous reads per column (see [`Fft2::forward`]).
    pub fn inverse(&self, spec: &[C32]) -> Vec<f32> {
        let (h, w, wc) = (self.height, self.width, self.spec_width());
        debug_assert_eq!(spec.len(), h * wc);
        let mut cols = vec![C32::new(0.0, 0.0); h * wc];
        cols.par_chunks_mut(h * BLOCK).enumerate().for_each_init(
            || ColScratch::new(&self.col_fwd, h),
            |s, (b, out)| {
                let c0 = b * BLOCK;
                for (ci, col) in out.chunks_mut(h).enumerate() {
                    // IFFT(z) = conj(FFT(conj z)).
                    let src = &spec[(c0 + ci) * h..(c0 + ci + 1) * h];
                    for (k, v) in src.iter().enumerate() {
                        s.re[ci * h + k] = v.re;
                        s.im[ci * h + k] = -v.im;
                    }
                    s.complex_fft(&self.col_fwd, ci, col, true);
                }
            },
        );
        let mut out = vec![0.0f32; h * w];
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
        out
    }

    /// Spectrum of a kernel centred on the FFT origin (so that multiplying by it convolves
    /// without shifting): the kernel centre goes to (0, 0) and the rest wraps around.
    pub fn kernel_spectrum(
        &self,
        kw: usize,
        kh: usize,
        k: impl Fn(usize, usize) -> f64,
    ) -> Vec<C32> {
        let (plane, _) = self.kernel_plane(kw, kh, k);
        self.forward(&plane)
    }

    /// The kernel placed as in [`Fft2::kernel_spectrum`], and the plane rows it occupies.
    fn kernel_plane(
        &self,
        kw: usize,
        kh: usize,
        k: impl Fn(usize, usize) -> f64,
    ) -> (Vec<f32>, Vec<usize>) {
        let (h, w) = (self.height, self.width);
        let mut plane = vec![0.0f32; h * w];
        let (cx, cy) = (kw / 2, kh / 2);
        let mut used = Vec::with_capacity(kh);
        for y in 0..kh {
            let py = (y + h - cy) % h;
            used.push(py);
            for x in 0..kw {
                let px = (x + w - cx) % w;
                plane[py * w + px] += k(x, y) as f32;
            }
        }
        used.sort_unstable();
        used.dedup();
        (plane, used)
    }

    /// [`Fft2::kernel_spectrum`], faster for kernels of few rows (equal up to float rounding).
    ///
    /// Only the kernel's rows of the plane are non-zero, so after their row transforms each
    /// column's transform is a short sum, `K[k] = Σ_j R_j · e^{−2πi k y_j / h}`, evaluated
    /// directly (vectorised across columns) instead of by full column FFTs; that makes the
    /// kernel spectrum a small fraction of the cost of an image transform. Kernels with many
    /// rows relative to the height take the plain 2-D transform. The non-blind solvers use it;
    /// the blind estimator keeps [`Fft2::kernel_spectrum`], whose coarse-to-fine search is
    /// chaotic enough for rounding differences to change which kernel it settles on.
    pub(super) fn kernel_spectrum_direct(
        &self,
        kw: usize,
        kh: usize,
        k: impl Fn(usize, usize) -> f64,
    ) -> Vec<C32> {
        let (h, w, wc) = (self.height, self.width, self.spec_width());
        let (plane, used) = self.kernel_plane(kw, kh, k);
        // A direct column sum costs one vectorised complex multiply-add per row and bin; the
        // column FFTs about `5 log₂ h` flops per bin plus the gathers and the recombination.
        if used.len() > 2 * h.max(2).ilog2() as usize {
            return self.forward(&plane);
        }
        let rows: Vec<(usize, Vec<C32>)> = used
            .iter()
            .map(|&py| {
                let mut buf = plane[py * w..(py + 1) * w].to_vec();
                let mut out = self.row_fwd.make_output_vec();
                let _ = self.row_fwd.process(&mut buf, &mut out);
                (py, out)
            })
            .collect();
        let tau = std::f64::consts::TAU;
        let twiddle: Vec<C32> = (0..h)
            .map(|m| {
                let a = -tau * m as f64 / h as f64;
                C32::new(a.cos() as f32, a.sin() as f32)
            })
            .collect();
        let mut spec = vec![C32::new(0.0, 0.0); h * wc];
        spec.par_chunks_mut(h * BLOCK).enumerate().for_each_init(
            || vec![C32::new(0.0, 0.0); BLOCK],
            |acc, (b, out)| {
                let (c0, nc) = (b * BLOCK, out.len() / h);
                for kk in 0..h {
                    let acc = &mut acc[..nc];
                    acc.fill(C32::new(0.0, 0.0));
                    for (py, r) in &rows {
                        let t = twiddle[(kk * py) % h];
                        for (a, v) in acc.iter_mut().zip(&r[c0..c0 + nc]) {
                            *a += t * v;
                        }
                    }
                    for (ci, a) in acc.iter().enumerate() {
                        out[ci * h + kk] = *a;
                    }
                }
            },
        );
        spec
    }
}

/// Columns (rows) handled together by one task of the column (row) pass: enough for every row
/// (column) of the gather to read whole cache lines, few enough for the block to stay in L2.
const BLOCK: usize = 16;

/// Per-thread buffers for the complex transforms of a block of [`BLOCK`] columns.
struct ColScratch {
    /// Real parts, column `ci` at `ci * h..(ci + 1) * h`.
    re: Vec<f32>,
    /// Imaginary parts, same layout.
    im: Vec<f32>,
    a: Vec<C32>,
    b: Vec<C32>,
    scratch: Vec<C32>,
}

impl ColScratch {
    fn new(plan: &Arc<dyn RealToComplex<f32>>, h: usize) -> Self {
        Self {
            re: vec![0.0; h * BLOCK],
            im: vec![0.0; h * BLOCK],
            a: plan.make_output_vec(),
            b: plan.make_output_vec(),
            scratch: plan.make_scratch_vec(),
        }
    }

    /// `out = FFT(re + i·im)` of block column `ci`, or its conjugate when `conj_out` (for the
    /// inverse).
    fn complex_fft(
        &mut self,
        plan: &Arc<dyn RealToComplex<f32>>,
        ci: usize,
        out: &mut [C32],
        conj_out: bool,
    ) {
        let h = out.len();
        let (re, im) = (
            &mut self.re[ci * h..(ci + 1) * h],
            &mut self.im[ci * h..(ci + 1) * h],
        );
        let _ = plan.process_with_scratch(re, &mut self.a, &mut self.scratch);
        let _ = plan.process_with_scratch(im, &mut self.b, &mut self.scratch);
        let half = h / 2;
        let sign = if conj_out { -1.0 } else { 1.0 };
        // a + i b, with a, b extended past h/2 by Hermitian symmetry.
        for (k, o) in out.iter_mut().enumerate().take(half + 1) {
            let (a, b) = (self.a[k], self.b[k]);
            *o = C32::new(a.re - b.im, sign * (a.im + b.re));
        }
        for (k, o) in out.iter_mut().enumerate().skip(half + 1) {
            let (a, b) = (self.a[h - k].conj(), self.b[h - k].conj());
            *o = C32::new(a.re - b.im, sign * (a.im + b.re));
        }
    }
}
