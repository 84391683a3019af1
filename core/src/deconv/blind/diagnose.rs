//! Fixed-point diagnostics of the kernel estimation, for the evaluation harness
//! (`examples/blind_eval.rs`, `BLIND_FIXED`): see the module doc of `blind` for what they showed.

use super::{BlindParams, clipped_map, estimate_kernel_traced, estimate_level, recentre};
use crate::deconv::{Plane, Psf};
use crate::error::{CoreError, CoreResult};
use crate::progress::NoProgress;

/// Diagnostics for the evaluation harness: is a given kernel (the truth) a fixed point of the
/// estimation? [`KernelStart::Pyramid`] runs every level from `start` resampled to the coarsest
/// one (the window is `start`'s side); [`KernelStart::Finest`] runs the full-resolution level
/// alone from `start`. An estimator that walks away from the truth is biased, not lost: no
/// search or initialisation can fix that.
#[doc(hidden)]
pub fn estimate_kernel_from(
    img: &Plane,
    params: &BlindParams,
    start: &Psf,
    mode: KernelStart,
) -> CoreResult<Psf> {
    let ks = start.width;
    // A `Psf` always has odd sides.
    if start.height != ks {
        return Err(CoreError::param("start", "must be square"));
    }
    let params = BlindParams {
        kernel_size: Some(ks),
        ..params.clone()
    };
    match mode {
        KernelStart::Pyramid => {
            estimate_kernel_traced(img, &params, &NoProgress, None, Some(start))
        }
        KernelStart::Finest => {
            params.validate()?;
            let clipped = params
                .final_tv
                .saturation
                .and_then(|level| clipped_map(img, level as f32));
            let mut kernel = estimate_level(
                (img, clipped.as_deref()),
                start.data.clone(),
                ks,
                &params,
                &NoProgress,
                (0, params.iterations_per_level),
                true,
            )?;
            recentre(&mut kernel, ks);
            Psf::from_weights(ks, ks, kernel)
        }
    }
}

/// Where `estimate_kernel_from` starts.
#[doc(hidden)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KernelStart {
    /// The whole pyramid, from the start kernel resampled to the coarsest level.
    Pyramid,
    /// The full-resolution level alone.
    Finest,
}
