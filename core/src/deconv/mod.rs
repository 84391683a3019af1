//! Deconvolution: point-spread functions, Wiener and Richardson-Lucy, and restoration metrics.
//!
//! The model is `B = I ⊛ K + n` (science notes, "Deblur"): a sharp image `I` convolved with a
//! kernel `K` plus noise. Everything here works on [`Plane`]s, single-channel `f32` images with
//! values in `[0, 1]`; colour and 16-bit callers split channels and scale before calling.
//!
//! * [`Psf`]: normalised odd-sized kernels (motion, disc, Gaussian, parsed from text/JSON/PNG).
//! * [`wiener`]: one-shot frequency-domain filter on a mirror-padded, tapered, fast-FFT-sized
//!   domain; noise level estimated from the image when not given.
//! * [`richardson_lucy`]: multiplicative EM iterations with the unknown-boundary model of
//!   Bertero & Boccacci (2005), so that borders do not drive divergence.
//! * [`tv_deconv`]: total-variation ADMM with the unknown-boundary data term (the best non-blind
//!   result).
//! * [`blind_deconv`] / [`estimate_kernel`]: coarse-to-fine L0-gradient kernel estimation
//!   (Pan et al. 2014/2017), then TV; [`blind_richardson_lucy`] as MATLAB `deconvblind`.
//! * [`gyro_psf`]: the kernel drawn from a gyro trace and the pinhole intrinsics (Joshi et al. 2010);
//!   [`gyro_psf_grid`] + [`deconv_varying`] for blur that varies across the frame.
//! * [`deblur_image`]: one entry point for 8/16-bit grey/RGB(A) images, any of the above.
//! * [`psnr`], [`ssim`], [`error_ratio`]: quality against a reference.

mod blind;
mod blind_rl;
mod boundary;
mod color;
mod deblur;
mod fft;
mod frames;
mod gyro;
mod gyro_log;
mod metrics;
mod ops;
mod psf;
mod resample;
mod rl;
mod tv;
mod varying;
mod wiener;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_solvers;

pub use blind::{
    AGREEMENT_SHIFT, BlindOutput, BlindParams, DEFAULT_KERNEL_REGION, DEFAULT_KERNEL_THRESHOLD,
    KernelEstimate, KernelStart, LOW_KERNEL_THRESHOLD, Region, UNCERTAIN_AGREEMENT, blind_deconv,
    estimate_blur_extent, estimate_kernel, estimate_kernel_from, estimate_kernel_restored,
    estimate_kernel_trace, gradient_autocorrelation, kernel_agreement, uncertain_agreement,
};
pub use blind_rl::blind_richardson_lucy;
pub use boundary::{PadLayout, reflect};
pub use color::{ChannelLayout, SampleDepth, SplitImage, merge_image, split_image};
pub use deblur::{DeblurMethod, DeblurOutput, DeblurParams, MAX_GYRO_GRID, deblur_image, psf_png};
pub use fft::{Fft2, fast_len, is_smooth};
pub use frames::{FramePick, MAX_CLIP_FRAMES};
pub use gyro::{GyroPsfParams, GyroSample, gyro_psf, gyro_psf_at, gyro_psf_grid};
pub use gyro_log::{GyroClipParams, GyroLog, gyro_trace_from_log};
pub use metrics::{error_ratio, error_ratio_aligned, psnr, ssim};
pub use psf::{MAX_PSF_SIZE, Psf};
pub use resample::resize;
pub use rl::{MAX_RL_ITERATIONS, richardson_lucy};
pub use tv::{DEFAULT_SATURATION, MAX_TV_ITERATIONS, TvParams, auto_tv_lambda, tv_deconv};
pub use varying::deconv_varying;
pub use wiener::{estimate_noise_sigma, wiener};

use crate::error::{CoreError, CoreResult};
use crate::io::Gray;

/// A single-channel `f32` image, row-major, nominally in `[0, 1]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Plane {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Pixels, row after row.
    pub data: Vec<f32>,
}

impl Plane {
    /// Build from raw pixels; fails on a size mismatch, an empty image or non-finite values.
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> CoreResult<Self> {
        if width == 0 || height == 0 {
            return Err(CoreError::input("image is empty"));
        }
        if data.len() != width * height {
            return Err(CoreError::input(format!(
                "image {width}×{height} needs {} values, got {}",
                width * height,
                data.len()
            )));
        }
        if data.iter().any(|v| !v.is_finite()) {
            return Err(CoreError::input("image has non-finite values"));
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// 8-bit grey scaled to `[0, 1]`.
    pub fn from_gray(img: &Gray) -> CoreResult<Self> {
        Self::new(
            img.width as usize,
            img.height as usize,
            img.data.iter().map(|&v| f32::from(v) / 255.0).collect(),
        )
    }

    /// Back to 8-bit grey, clipped to `[0, 1]` and rounded.
    pub fn to_gray(&self) -> Gray {
        Gray {
            width: self.width as u32,
            height: self.height as u32,
            data: self
                .data
                .iter()
                .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
                .collect(),
        }
    }

    /// Pixel at column `x`, row `y`.
    pub fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Mean value (accumulated in f64).
    pub fn mean(&self) -> f64 {
        self.data.iter().map(|&v| f64::from(v)).sum::<f64>() / self.data.len() as f64
    }
}

/// Rejects images and kernels that cannot be deconvolved (the fields are public, so a caller
/// may have built them by hand).
fn check_inputs(img: &Plane, psf: &Psf) -> CoreResult<()> {
    if img.width == 0 || img.height == 0 || img.data.len() != img.width * img.height {
        return Err(CoreError::input(format!(
            "image {}×{} with {} values is malformed",
            img.width,
            img.height,
            img.data.len()
        )));
    }
    if img.data.iter().any(|v| !v.is_finite()) {
        return Err(CoreError::input("image has non-finite values"));
    }
    if psf.width.is_multiple_of(2)
        || psf.height.is_multiple_of(2)
        || psf.data.len() != psf.width * psf.height
    {
        return Err(CoreError::input(format!(
            "PSF {}×{} is malformed (sides must be odd)",
            psf.width, psf.height
        )));
    }
    Ok(())
}
