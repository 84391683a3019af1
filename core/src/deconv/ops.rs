//! Small pixel-domain operators shared by the iterative solvers: circular forward differences,
//! their adjoint, and spectral convolution on an [`Fft2`] domain.

use rayon::prelude::*;

use super::fft::{C32, Fft2};

/// Circular forward differences `(x[i+1] − x[i])` along rows (`gx`) and columns (`gy`).
pub(super) fn grad(x: &[f32], width: usize) -> (Vec<f32>, Vec<f32>) {
    let n = x.len();
    let mut gx = vec![0.0f32; n];
    let mut gy = vec![0.0f32; n];
    grad_into(x, width, &mut gx, &mut gy);
    (gx, gy)
}

/// [`grad`] into `gx` and `gy` (each as long as `x`, every value overwritten), for loops that
/// reuse their buffers.
pub(super) fn grad_into(x: &[f32], width: usize, gx: &mut [f32], gy: &mut [f32]) {
    let height = x.len() / width;
    gx.par_chunks_mut(width)
        .zip(gy.par_chunks_mut(width))
        .enumerate()
        .for_each(|(r, (rx, ry))| {
            let row = &x[r * width..(r + 1) * width];
            let next = &x[((r + 1) % height) * width..((r + 1) % height + 1) * width];
            for c in 0..width {
                let c1 = if c + 1 == width { 0 } else { c + 1 };
                rx[c] = row[c1] - row[c];
                ry[c] = next[c] - row[c];
            }
        });
}

/// Adjoint of [`grad`] (minus the divergence), `Dxᵀ gx + Dyᵀ gy`, circular, into `out` (as
/// long as `gx`, every value overwritten).
pub(super) fn grad_adjoint_into(gx: &[f32], gy: &[f32], width: usize, out: &mut [f32]) {
    let height = gx.len() / width;
    out.par_chunks_mut(width).enumerate().for_each(|(r, o)| {
        let prev_r = (r + height - 1) % height;
        let (rx, ry) = (
            &gx[r * width..(r + 1) * width],
            &gy[r * width..(r + 1) * width],
        );
        let py = &gy[prev_r * width..(prev_r + 1) * width];
        for c in 0..width {
            let cp = if c == 0 { width - 1 } else { c - 1 };
            o[c] = (rx[cp] - rx[c]) + (py[c] - ry[c]);
        }
    });
}

/// `ifft(fft(x) · k) / N`: circular convolution by a kernel spectrum (conjugated for the adjoint).
pub(super) fn convolve(fft: &Fft2, x: &[f32], kspec: &[C32], adjoint: bool) -> Vec<f32> {
    let mut spec = vec![C32::new(0.0, 0.0); fft.spec_len()];
    let mut out = vec![0.0f32; x.len()];
    convolve_into(fft, x, kspec, adjoint, &mut spec, &mut out);
    out
}

/// [`convolve`] into `out` (as long as `x`), with `spec` ([`Fft2::spec_len`], contents
/// unspecified) as the spectrum buffer, for loops that reuse their buffers.
pub(super) fn convolve_into(
    fft: &Fft2,
    x: &[f32],
    kspec: &[C32],
    adjoint: bool,
    spec: &mut [C32],
    out: &mut [f32],
) {
    let scale = 1.0 / (fft.height * fft.width) as f32;
    fft.forward_into(x, spec);
    spec.par_iter_mut()
        .zip(kspec.par_iter())
        .for_each(|(s, k)| {
            let k = if adjoint { k.conj() } else { *k };
            *s = *s * k * scale;
        });
    fft.inverse_into(spec, out);
}

/// A kernel as its non-zero taps, for direct circular convolution on a padded `height × width`
/// domain with the same centring as [`Fft2::kernel_spectrum`].
///
/// Motion kernels are thin curves: a 15 px line has a few dozen non-zero taps in a 15×9 box.
/// Convolving with those directly costs a few dozen multiply-adds per pixel, contiguous and
/// vectorised, against two full 2-D FFTs (with their transposes) per convolution, so the
/// iterative solvers use it whenever it is the cheaper of the two ([`SparseKernel::worth_it`]).
pub(super) struct SparseKernel {
    /// Taps grouped by row offset: `(dy, [(dx, value)])`, where `dy`/`dx` are the tap's position
    /// relative to the kernel centre.
    rows: Vec<(isize, Vec<(isize, f32)>)>,
    taps: usize,
}

impl SparseKernel {
    /// Non-zero taps of a `kw × kh` kernel given by `k(x, y)`.
    pub(super) fn new(kw: usize, kh: usize, k: impl Fn(usize, usize) -> f64) -> Self {
        let (cx, cy) = ((kw / 2) as isize, (kh / 2) as isize);
        let mut rows = Vec::new();
        let mut taps = 0;
        for y in 0..kh {
            let row: Vec<(isize, f32)> = (0..kw)
                .filter_map(|x| {
                    let v = k(x, y) as f32;
                    (v != 0.0).then_some((x as isize - cx, v))
                })
                .collect();
            if !row.is_empty() {
                taps += row.len();
                rows.push((y as isize - cy, row));
            }
        }
        Self { rows, taps }
    }

    /// Whether direct convolution beats the FFT route on a domain of `n` pixels. One FFT
    /// convolution is a forward and an inverse real 2-D transform, about `5 log₂ n` flops per
    /// pixel plus two transposes; a direct tap is one vectorised multiply-add. Measured at
    /// 1080p on two cores, direct stays ahead up to roughly `4 log₂ n` taps (≈ 85).
    pub(super) fn worth_it(&self, n: usize) -> bool {
        self.taps > 0 && (self.taps as f64) <= 4.0 * (n.max(2) as f64).log2()
    }

    /// Circular convolution of the row-major `plane` (`width` columns) into `out`, exactly the
    /// operation of [`convolve`] (`adjoint`: correlation, the conjugate spectrum).
    pub(super) fn convolve_into(
        &self,
        plane: &[f32],
        width: usize,
        adjoint: bool,
        out: &mut [f32],
    ) {
        let height = plane.len() / width;
        let (h, w) = (height as isize, width as isize);
        out.par_chunks_mut(width).enumerate().for_each(|(y, o)| {
            o.fill(0.0);
            for (dy, taps) in &self.rows {
                // Convolution reads x − offset, correlation x + offset.
                let dy = if adjoint { *dy } else { -*dy };
                let sy = (y as isize + dy).rem_euclid(h) as usize;
                let src = &plane[sy * width..(sy + 1) * width];
                for &(dx, v) in taps {
                    let dx = if adjoint { dx } else { -dx };
                    let s = dx.rem_euclid(w) as usize;
                    // out[x] += v · src[(x + s) mod width], in two contiguous runs.
                    let (head, tail) = o.split_at_mut(width - s);
                    for (a, &b) in head.iter_mut().zip(&src[s..]) {
                        *a += v * b;
                    }
                    for (a, &b) in tail.iter_mut().zip(&src[..s]) {
                        *a += v * b;
                    }
                }
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::super::Psf;
    use super::*;

    /// Direct convolution and correlation agree with the FFT route, including wrap-around and a
    /// kernel wider than the domain is high.
    #[test]
    fn sparse_kernel_matches_fft_convolution() {
        for (h, w, psf) in [
            (10, 12, Psf::motion(4.0, 20.0).expect("motion")),
            (7, 16, Psf::motion(9.0, 75.0).expect("motion")),
            (24, 18, Psf::disc(3.0).expect("disc")),
        ] {
            let x: Vec<f32> = (0..h * w).map(|i| ((i * 37 % 11) as f32) / 11.0).collect();
            let fft = Fft2::new(h, w);
            let kspec = fft.kernel_spectrum(psf.width, psf.height, |a, b| psf.at(a, b));
            let sparse = SparseKernel::new(psf.width, psf.height, |a, b| psf.at(a, b));
            let direct = fft.kernel_spectrum_direct(psf.width, psf.height, |a, b| psf.at(a, b));
            for (a, b) in direct.iter().zip(&kspec) {
                assert!((a - b).norm() < 1e-5, "{a} vs {b}");
            }
            for adjoint in [false, true] {
                let want = convolve(&fft, &x, &kspec, adjoint);
                let mut got = vec![1.0f32; h * w];
                sparse.convolve_into(&x, w, adjoint, &mut got);
                for (a, b) in got.iter().zip(&want) {
                    assert!((a - b).abs() < 1e-5, "{a} vs {b} (adjoint {adjoint})");
                }
            }
        }
    }
}
