//! Small pixel-domain operators shared by the iterative solvers: circular forward differences,
//! their adjoint, and spectral convolution on an [`Fft2`] domain.

use rayon::prelude::*;

use super::fft::{C32, Fft2};

/// Circular forward differences `(x[i+1] − x[i])` along rows (`gx`) and columns (`gy`).
pub(super) fn grad(x: &[f32], width: usize) -> (Vec<f32>, Vec<f32>) {
    let n = x.len();
    let height = n / width;
    let mut gx = vec![0.0f32; n];
    let mut gy = vec![0.0f32; n];
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
    (gx, gy)
}

/// Adjoint of [`grad`] (minus the divergence): `Dxᵀ gx + Dyᵀ gy`, circular.
pub(super) fn grad_adjoint(gx: &[f32], gy: &[f32], width: usize) -> Vec<f32> {
    let n = gx.len();
    let height = n / width;
    let mut out = vec![0.0f32; n];
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
    out
}

/// `ifft(fft(x) · k) / N`: circular convolution by a kernel spectrum (conjugated for the adjoint).
pub(super) fn convolve(fft: &Fft2, x: &[f32], kspec: &[C32], adjoint: bool) -> Vec<f32> {
    let scale = 1.0 / (fft.height * fft.width) as f32;
    let mut spec = fft.forward(x);
    spec.par_iter_mut()
        .zip(kspec.par_iter())
        .for_each(|(s, k)| {
            let k = if adjoint { k.conj() } else { *k };
            *s = *s * k * scale;
        });
    fft.inverse(&spec)
}
