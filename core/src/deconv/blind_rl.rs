//! Alternating Richardson-Lucy blind deconvolution, as MATLAB's `deconvblind`.

use rayon::prelude::*;

use super::fft::Fft2;
use super::ops::convolve;
use super::{PadLayout, Plane, Psf};
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

/// Blind deconvolution by alternating Richardson-Lucy updates of the image and the kernel
/// (D. S. C. Biggs and M. Andrews, "Acceleration of iterative image restoration algorithms",
/// Applied Optics 36(8), 1997; T. J. Holmes, "Blind deconvolution of quantum-limited incoherent
/// imagery", JOSA A 9(7), 1992) — the method of MATLAB `deconvblind`, kept for parity.
///
/// Each iteration does one multiplicative EM step on the image with the current kernel and one
/// on the kernel with the current image (`k ← k · (x ⋆ (y / (k ⊛ x))) / Σx`, then restricted to
/// its `kernel_size` window and normalised). Starting from a flat disc, this converges to a
/// nearly symmetric, smooth kernel on camera shake: the error ratios on Levin's set are in the
/// hundreds (science notes). Use [`super::blind_deconv`] for real work.
///
/// Works on the image mirrored and tapered into a periodic domain; returns the image and kernel.
pub fn blind_richardson_lucy(
    img: &Plane,
    kernel_size: usize,
    iterations: usize,
    progress: &dyn Progress,
) -> CoreResult<(Plane, Psf)> {
    super::check_inputs(img, &Psf::identity())?;
    if kernel_size < 3
        || kernel_size.is_multiple_of(2)
        || 2 * kernel_size > img.width.min(img.height)
    {
        return Err(CoreError::param(
            "kernel_size",
            "must be odd, ≥ 3 and at most half the shorter image side",
        ));
    }
    if !(1..=super::rl::MAX_RL_ITERATIONS).contains(&iterations) {
        return Err(CoreError::param(
            "iterations",
            "must be between 1 and 10000",
        ));
    }
    let ks = kernel_size;
    let layout = PadLayout::new(img.height, img.width, ks, ks);
    let fft = Fft2::new(layout.padded_height, layout.padded_width);
    let y: Vec<f32> = layout
        .pad_tapered(img)
        .iter()
        .map(|v| v.max(1e-4))
        .collect();
    let mut x = y.clone();
    let r = ks as f64 / 4.0;
    let mut k: Vec<f64> = Psf::disc(r)
        .map(|d| d.centred_weights(ks))
        .unwrap_or_else(|_| vec![1.0 / (ks * ks) as f64; ks * ks]);
    let (h, w) = (fft.height, fft.width);
    let c = ks / 2;
    for it in 0..iterations {
        progress.check()?;
        let kspec = fft.kernel_spectrum(ks, ks, |a, b| k[b * ks + a]);
        // `y / (k ⊛ x)`, the RL ratio for the current image.
        let ratio_of = |x: &[f32]| -> Vec<f32> {
            let kx = convolve(&fft, x, &kspec, false);
            y.par_iter()
                .zip(kx.par_iter())
                .map(|(y, b)| y / b.max(1e-6))
                .collect()
        };
        // Image step.
        let ratio = ratio_of(&x);
        let back = convolve(&fft, &ratio, &kspec, true);
        x.par_iter_mut()
            .zip(back.par_iter())
            .for_each(|(x, b)| *x = (*x * b.max(0.0)).max(0.0));
        // Kernel step: correlate the ratio with the image, read the kernel window.
        let ratio = ratio_of(&x);
        let xs = fft.forward(&x);
        let rs = fft.forward(&ratio);
        let scale = 1.0 / (h * w) as f32;
        let corr: Vec<_> = xs
            .iter()
            .zip(&rs)
            .map(|(a, b)| a.conj() * b * scale)
            .collect();
        let corr = fft.inverse(&corr);
        let xsum: f64 = x.iter().map(|&v| f64::from(v)).sum();
        for yy in 0..ks {
            let py = (yy + h - c) % h;
            for xx in 0..ks {
                let px = (xx + w - c) % w;
                k[yy * ks + xx] *= (f64::from(corr[py * w + px]) / xsum.max(1e-12)).max(0.0);
            }
        }
        let s: f64 = k.iter().sum();
        if !(s > 0.0 && s.is_finite()) {
            return Err(CoreError::NoSolution("blind RL kernel vanished".into()));
        }
        k.iter_mut().for_each(|v| *v /= s);
        progress.report("blind_rl", it as u64 + 1, iterations as u64);
    }
    let data = layout
        .crop(&x)
        .into_iter()
        .map(|v| v.clamp(0.0, 1.0))
        .collect();
    Ok((
        Plane::new(img.width, img.height, data)?,
        Psf::from_weights(ks, ks, k)?,
    ))
}
