//! The latent-image side of the kernel estimation: the L0-regularised restoration and the
//! salient-edge selection.

use rayon::prelude::*;

use super::super::fft::{C32, Fft2};
use super::super::ops::{grad_adjoint_into, grad_into};
use crate::error::CoreResult;
use crate::progress::Progress;

/// Gradient magnitude below which latent gradients are left out of the kernel step: the salient
/// edge selection of S. Cho and S. Lee, "Fast motion deblurring", SIGGRAPH Asia 2009 (also in
/// Pan et al.'s code). Gradients are binned by direction (4 bins of 45°) and the threshold is the
/// largest that still keeps `2·√(N·ks²)` pixels in every bin (`N` observed pixels), so that
/// every direction constrains the kernel; it is relaxed by 1.1 per alternation.
pub(super) fn salient_threshold(gx: &[f32], gy: &[f32], mask: &[f32], ks: usize) -> f32 {
    let mut bins: [Vec<f32>; 4] = Default::default();
    let mut n = 0usize;
    for ((&x, &y), &m) in gx.iter().zip(gy).zip(mask) {
        if m <= 0.0 {
            continue;
        }
        n += 1;
        let mag = x.hypot(y);
        if mag <= 0.0 {
            continue;
        }
        let a = y.atan2(x).rem_euclid(std::f32::consts::PI);
        let b = ((a / std::f32::consts::FRAC_PI_4).round() as usize) % 4;
        bins[b].push(mag);
    }
    let keep = (2.0 * (n as f64).sqrt() * ks as f64) as usize;
    let mut t = f32::INFINITY;
    for bin in &mut bins {
        if bin.is_empty() {
            continue;
        }
        bin.sort_unstable_by(|a, b| b.total_cmp(a));
        let v = bin[keep.min(bin.len() - 1)];
        t = t.min(v);
    }
    if t.is_finite() { t } else { 0.0 }
}

/// `argmin_x ‖k ⊛ x − y‖² + λ‖∇x‖₀` by half-quadratic splitting (Pan et al.'s `L0Restoration`,
/// after L. Xu, C. Lu, Y. Xu, J. Jia, "Image smoothing via L0 gradient minimization", 2011).
pub(super) fn l0_restore(
    fft: &Fft2,
    y_spec: &[C32],
    kspec: &[C32],
    dpow: &[f32],
    lambda: f32,
    progress: &dyn Progress,
) -> CoreResult<Vec<f32>> {
    const BETA_MAX: f32 = 1e5;
    let scale = 1.0 / (fft.height * fft.width) as f32;
    let kty: Vec<C32> = kspec
        .par_iter()
        .zip(y_spec.par_iter())
        .map(|(k, y)| k.conj() * y)
        .collect();
    let k2: Vec<f32> = kspec.iter().map(|k| k.norm_sqr()).collect();
    // Start from the blurred image itself (as the authors' code).
    let mut s = fft.inverse(&y_spec.iter().map(|v| v * scale).collect::<Vec<C32>>());
    let mut beta = 2.0 * lambda;
    // Buffers reused by every β step (the arithmetic is the same as with fresh ones).
    let n = s.len();
    let (mut h, mut v, mut div) = (vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]);
    let mut xs = vec![C32::new(0.0, 0.0); fft.spec_len()];
    while beta < BETA_MAX {
        progress.check()?;
        grad_into(&s, fft.width, &mut h, &mut v);
        let thr = lambda / beta;
        h.par_iter_mut().zip(v.par_iter_mut()).for_each(|(h, v)| {
            if *h * *h + *v * *v < thr {
                *h = 0.0;
                *v = 0.0;
            }
        });
        grad_adjoint_into(&h, &v, fft.width, &mut div);
        fft.forward_into(&div, &mut xs);
        xs.par_iter_mut()
            .zip(kty.par_iter())
            .zip(k2.par_iter().zip(dpow.par_iter()))
            .for_each(|((d, a), (k2, dp))| *d = (a + *d * beta) * (scale / (k2 + beta * dp)));
        fft.inverse_into(&xs, &mut s);
        beta *= 2.0;
    }
    Ok(s)
}
