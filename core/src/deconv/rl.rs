//! Richardson-Lucy deconvolution with the unknown-boundary model of Bertero & Boccacci.

use rayon::prelude::*;

use super::fft::{C32, Fft2};
use super::ops::{SparseKernel, convolve_into};
use super::{PadLayout, Plane, Psf, check_inputs};
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

/// Largest accepted iteration count; RL gains little after a few hundred iterations and each one
/// costs four image-sized FFTs.
pub const MAX_RL_ITERATIONS: usize = 10_000;

/// Weight of the total-variation term (Dey et al. 2006 recommend 0.002 for data in [0, 1]-like
/// units). Unregularised RL converges to the maximum-likelihood image, which fits the noise: on
/// camera-shake blur with σ = 0.01 PSNR peaks around 30 iterations and then slowly falls. This
/// small TV term removes that slow decline without visibly flattening texture.
const TV_WEIGHT: f32 = 0.002;

/// The multiplicative correction raised to the power q = 1.75, `x ← x · (Kᵀ(y/Kx) / w)^q`: the
/// over-relaxed RL of Meinel (E. S. Meinel, "Origins of linear and nonlinear recursive
/// restoration algorithms", JOSA A 3(6), 1986), which moves about `q` times as far per iteration
/// along the same path and keeps the fixed point. On the benchmark set 1.7–1.75 gained 0.65 dB
/// at 30 iterations (26.58 → 27.26 dB) and results still improve up to 200 iterations on every
/// case; 2 became unstable with the TV term (60 iterations worse than 30), 3 diverges. The
/// Biggs-Andrews vector extrapolation (MATLAB `deconvlucy`) does nothing here: the TV term makes
/// successive updates anti-correlated, so its step factor is always clamped to zero.
///
/// Computed as `r·√r·⁴√r`, three square roots instead of a `powf`, which at 1080p cost a third
/// of an iteration.
#[inline]
fn relax(r: f32) -> f32 {
    let s = r.sqrt();
    r * s * s.sqrt()
}

/// Below this normalisation weight an object pixel is considered unseen by the data.
const MIN_WEIGHT: f32 = 1e-3;

/// Richardson-Lucy deconvolution (Richardson 1972, JOSA 62(1); Lucy 1974, AJ 79(6)) of `img`
/// (values in `[0, 1]`) by `psf`, for `iterations` steps; result clipped to `[0, 1]`.
///
/// Boundaries follow M. Bertero and P. Boccacci, "A simple method for the reduction of boundary
/// effects in the Richardson-Lucy approach to image deconvolution", A&A 437 (2005): the unknown
/// object lives on a domain larger than the image by the kernel's half size, the forward model
/// blurs it and keeps only the observed pixels (`y = M·(K ⊛ x)`), and the update is
///
/// `x ← x / w · Kᵀ(M·y / (K ⊛ x))`, with `w = Kᵀ M`.
///
/// Plain RL instead assumes something (zeros, periodicity) about the pixels beyond the border;
/// the mismatch there is fitted ever harder with each iteration and spreads inwards as ringing,
/// which is why scikit-image's RL gets worse with more iterations. Here there is no model error at
/// the border, so iterations only trade resolution against noise. The multiplicative update keeps
/// the estimate non-negative, and it conserves flux over the observed region.
///
/// Noise: the update is regularised by total variation as in N. Dey et al., "Richardson–Lucy
/// algorithm with total variation regularization for 3D confocal microscope deconvolution",
/// Microsc. Res. Tech. 69 (2006): the normaliser becomes `w − λ div(∇x/|∇x|)`, λ = 0.002, so
/// more iterations do not amplify noise without bound. The correction is over-relaxed
/// ([`relax`]), so 30 iterations reach what plain RL needs about 50 for.
///
/// The circular convolutions run on a 7-smooth FFT domain at least the image plus the kernel size,
/// which is exactly enough for the wrap-around never to mix the two sides of the object domain.
/// The start is the image mirrored into that domain. `progress.check()` runs every iteration.
pub fn richardson_lucy(
    img: &Plane,
    psf: &Psf,
    iterations: usize,
    progress: &dyn Progress,
) -> CoreResult<Plane> {
    check_inputs(img, psf)?;
    if iterations > MAX_RL_ITERATIONS {
        return Err(CoreError::param(
            "iterations",
            format!("{iterations} iterations; at most {MAX_RL_ITERATIONS}"),
        ));
    }
    let layout = PadLayout::new(img.height, img.width, psf.height / 2, psf.width / 2);
    let fft = Fft2::new(layout.padded_height, layout.padded_width);
    let n = fft.height * fft.width;
    let sparse = SparseKernel::new(psf.width, psf.height, |x, y| psf.at(x, y));
    // Thin (motion) kernels are convolved directly; others through the FFT, whose kernel
    // spectrum is then computed once.
    let kspec = if sparse.worth_it(n) {
        None
    } else {
        Some(fft.kernel_spectrum_direct(psf.width, psf.height, |x, y| psf.at(x, y)))
    };
    let width = fft.width;
    let mut spec = match kspec {
        Some(_) => vec![C32::new(0.0, 0.0); fft.spec_len()],
        None => Vec::new(),
    };
    let mut conv = |plane: &[f32], adjoint: bool, out: &mut [f32]| match &kspec {
        None => sparse.convolve_into(plane, width, adjoint, out),
        Some(k) => convolve_into(&fft, plane, k, adjoint, &mut spec, out),
    };

    let mask = layout.mask();
    let data: Vec<f32> = layout
        .pad_mirror(img)
        .iter()
        .zip(&mask)
        .map(|(v, m)| v.max(0.0) * m)
        .collect();
    let mut weight = vec![0.0f32; n];
    conv(&mask, true, &mut weight);
    let support: Vec<bool> = weight.iter().map(|&w| w > MIN_WEIGHT).collect();
    // Start from the mirrored image on the object domain, strictly positive so that no pixel is
    // frozen at zero by the multiplicative update.
    let mut x: Vec<f32> = layout
        .pad_mirror(img)
        .iter()
        .zip(&support)
        .map(|(&v, &s)| if s { v.max(1e-3) } else { 0.0 })
        .collect();

    let mut blurred = vec![0.0f32; n];
    let mut ratio = vec![0.0f32; n];
    let mut back = vec![0.0f32; n];
    let mut curv = vec![0.0f32; n];
    for it in 0..iterations {
        progress.check()?;
        conv(&x, false, &mut blurred);
        ratio
            .par_iter_mut()
            .zip(data.par_iter())
            .zip(blurred.par_iter().zip(mask.par_iter()))
            .for_each(|((r, &y), (&b, &m))| *r = if m > 0.0 { y / b.max(1e-6) } else { 0.0 });
        conv(&ratio, true, &mut back);
        tv_curvature(&x, &support, layout.padded_width, &mut curv);
        x.par_iter_mut()
            .zip(
                back.par_iter()
                    .zip(weight.par_iter().zip(support.par_iter())),
            )
            .zip(curv.par_iter())
            .for_each(|((x, (&c, (&w, &s))), &k)| {
                let den = (w - TV_WEIGHT * k).max(0.2 * w);
                *x = if s {
                    (*x * relax(c.max(0.0) / den)).max(0.0)
                } else {
                    0.0
                };
            });
        progress.report("richardson_lucy", it as u64 + 1, iterations as u64);
    }
    let out = layout.crop_map(&x, |v| v.clamp(0.0, 1.0));
    Plane::new(img.width, img.height, out)
}

/// `div(∇x / |∇x|)` (forward differences for the gradient, backward for the divergence), with
/// differences across the edge of the object domain treated as zero so that the domain's own
/// border does not act as an edge. Written into `out`.
///
/// Works on blocks of rows in parallel, carrying the unit gradients of the row above in small
/// buffers rather than storing them for the whole image, which keeps the pass in cache and
/// allocation-free.
fn tv_curvature(x: &[f32], support: &[bool], width: usize, out: &mut [f32]) {
    let height = x.len() / width;
    out.par_chunks_mut(width * CURV_ROWS)
        .enumerate()
        .for_each_init(
            || [(); 4].map(|_| vec![0.0f32; width]),
            |[ux, uy, ux_up, uy_up], (b, block)| {
                let r0 = b * CURV_ROWS;
                if r0 > 0 {
                    // Only the vertical component of the row above is used.
                    unit_gradients(x, support, width, height, r0 - 1, ux_up, uy_up);
                } else {
                    uy_up.fill(0.0);
                }
                for (dr, o) in block.chunks_mut(width).enumerate() {
                    let r = r0 + dr;
                    unit_gradients(x, support, width, height, r, ux, uy);
                    let s = &support[r * width..(r + 1) * width];
                    for c in 0..width {
                        o[c] = if s[c] {
                            let left = if c > 0 { ux[c - 1] } else { 0.0 };
                            (ux[c] - left) + (uy[c] - uy_up[c])
                        } else {
                            0.0
                        };
                    }
                    // This row is the next one's row above.
                    std::mem::swap(ux, ux_up);
                    std::mem::swap(uy, uy_up);
                }
            },
        );
}

/// Rows per task of [`tv_curvature`]: each task recomputes the unit gradients of the row above
/// its first row, so blocks amortise that over several rows.
const CURV_ROWS: usize = 16;

/// Unit gradient `∇x / |∇x|` (ε-smoothed) of row `r` into `ux`, `uy`; zero off the support and
/// for differences that leave it or the domain.
fn unit_gradients(
    x: &[f32],
    support: &[bool],
    width: usize,
    height: usize,
    r: usize,
    ux: &mut [f32],
    uy: &mut [f32],
) {
    // The ε-smoothing of |∇x|: at the noise level, so that noise-sized gradients are not
    // pushed at full strength (which makes the update oscillate); 0.001–0.03 change the result
    // by < 0.1 dB.
    const EPS: f32 = 0.01;
    let base = r * width;
    let row = &x[base..base + width];
    let srow = &support[base..base + width];
    let below = (r + 1 < height).then(|| {
        (
            &x[base + width..base + 2 * width],
            &support[base + width..base + 2 * width],
        )
    });
    for c in 0..width {
        if !srow[c] {
            ux[c] = 0.0;
            uy[c] = 0.0;
            continue;
        }
        let gx = if c + 1 < width && srow[c + 1] {
            row[c + 1] - row[c]
        } else {
            0.0
        };
        let gy = match below {
            Some((xb, sb)) if sb[c] => xb[c] - row[c],
            _ => 0.0,
        };
        let m = (gx * gx + gy * gy + EPS * EPS).sqrt();
        ux[c] = gx / m;
        uy[c] = gy / m;
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn relax_is_the_power_one_point_seven_five() {
        for r in [0.0f32, 1e-6, 0.3, 1.0, 1.7, 40.0] {
            let want = r.powf(1.75);
            assert!(
                (super::relax(r) - want).abs() <= 1e-6 * want.max(1.0),
                "{r}"
            );
        }
    }
}
