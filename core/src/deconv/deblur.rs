//! One entry point for the service: any method, any 8/16-bit grey/RGB(A) image.

use image::DynamicImage;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::blind::{BlindParams, estimate_kernel_restored};
use super::blind_rl::blind_richardson_lucy;
use super::color::{merge_image, split_image};
use super::gyro::{GyroPsfParams, gyro_psf, gyro_psf_grid};
use super::psf::MAX_PSF_SIZE;
use super::rl::MAX_RL_ITERATIONS;
use super::tv::{MAX_TV_ITERATIONS, TvParams, tv_deconv};
use super::varying::deconv_varying;
use super::{Plane, Psf, richardson_lucy, wiener};
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

/// Deconvolution method of [`deblur_image`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum DeblurMethod {
    /// Wiener filter with a gradient prior (needs `psf`; instant, the weakest).
    Wiener,
    /// Richardson-Lucy with unknown boundaries (needs `psf`).
    RichardsonLucy,
    /// Total-variation ADMM with unknown boundaries (needs `psf`; the best non-blind result).
    #[default]
    Tv,
    /// Kernel estimated from the image (L0 gradient prior, coarse to fine), then TV.
    Blind,
    /// Alternating Richardson-Lucy (MATLAB `deconvblind`): for comparison only, it fails on
    /// camera shake.
    BlindRl,
    /// Kernel drawn from a gyro trace over the exposure (needs `gyro`), then TV.
    Gyro,
}

/// Parameters of [`deblur_image`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct DeblurParams {
    /// Method (default `tv`).
    pub method: DeblurMethod,
    /// Known kernel: required by `wiener`, `richardson_lucy` and `tv`, refused by the others.
    pub psf: Option<Psf>,
    /// Iterations: RL (default 30), TV ADMM (default 80), alternating RL (default 50).
    pub iterations: Option<usize>,
    /// Wiener noise-to-signal ratio (default: estimated).
    pub nsr: Option<f64>,
    /// TV weight for `tv`, `blind` and `gyro` (default: from the estimated noise).
    pub tv_lambda: Option<f64>,
    /// For `tv`, `blind` and `gyro`: pixels at or above this value (0.5–1 of full scale;
    /// default 0.99) are taken as clipped by the sensor and only bound the restoration from
    /// below, and `blind` leaves them out of the kernel estimate; `null` treats them as linear.
    pub saturation: Option<f64>,
    /// Kernel side for `blind` / `blind_rl` (odd; default for `blind`: 1.4× the blur extent
    /// estimated from the image, 27 px to a third of the shorter side; for `blind_rl`, and for
    /// `blind` when no extent is found: 31 or a third of the shorter side).
    pub kernel_size: Option<usize>,
    /// For `blind` only: kernel entries below this fraction of the kernel's maximum are dropped
    /// after every kernel step (0.01–0.5). Default (`null`): kernels at 0.1 and 0.05 are both
    /// estimated and the one whose restoration explains the image better and is sharper is
    /// kept (twice the computation; the two run side by side). 0.05 keeps the faint strokes
    /// of long camera-shake paths that end in a bright dwell point; 0.1 keeps less of the
    /// least squares' noise, which chessboards and repetitive textures need.
    pub kernel_threshold: Option<f64>,
    /// For `blind` only: side (px, 128–16384) of the square region of a larger photo that
    /// the kernel is estimated on (at least 16 kernel windows), the part with the most
    /// strong edges in every direction, off clipped pixels; the whole photo is then restored
    /// with that kernel. Default (`null`): 2048, so that the kernel estimate's time and
    /// memory stop growing beyond 4 Mpx. Smaller is faster and less accurate (README,
    /// Benchmarks). A value at least the photo's longer side estimates on the whole photo.
    pub kernel_region: Option<usize>,
    /// Gyro trace, exposure and intrinsics for `gyro`.
    pub gyro: Option<GyroPsfParams>,
    /// For `gyro`: `[nx, ny]` cells, each restored with the kernel drawn at its centre and
    /// blended smoothly (blur that varies across the frame: rotation about the optical axis,
    /// wide lenses). Default: one kernel, drawn at the principal point. The cells must be small
    /// enough for the kernel to be nearly constant over each; 1–32 per axis.
    pub gyro_grid: Option<[usize; 2]>,
    /// For a video dataset: which frames to restore (required there, refused for images).
    pub frames: Option<super::FramePick>,
    /// Method `gyro` on a video dataset: the IMU log and where the frames lie on its clock;
    /// each frame gets the kernel of its own exposure (in place of `gyro`).
    pub gyro_clip: Option<super::GyroClipParams>,
}

impl Default for DeblurParams {
    fn default() -> Self {
        Self {
            method: DeblurMethod::Tv,
            psf: None,
            iterations: None,
            nsr: None,
            tv_lambda: None,
            saturation: Some(super::tv::DEFAULT_SATURATION),
            kernel_size: None,
            kernel_threshold: None,
            kernel_region: None,
            gyro: None,
            gyro_grid: None,
            frames: None,
            gyro_clip: None,
        }
    }
}

impl DeblurParams {
    /// Check the parameters alone (the service does so before queueing); errors name the field.
    pub fn validate(&self) -> CoreResult<()> {
        use DeblurMethod::*;
        let needs_psf = matches!(self.method, Wiener | RichardsonLucy | Tv);
        match (&self.psf, needs_psf) {
            (None, true) => {
                return Err(CoreError::param(
                    "psf",
                    format!("method {:?} needs a kernel", self.method),
                ));
            }
            (Some(_), false) => {
                return Err(CoreError::param(
                    "psf",
                    "a kernel is only used by wiener, richardson_lucy and tv",
                ));
            }
            (Some(p), true) => {
                if p.width.is_multiple_of(2)
                    || p.height.is_multiple_of(2)
                    || p.width > MAX_PSF_SIZE
                    || p.height > MAX_PSF_SIZE
                {
                    return Err(CoreError::param(
                        "psf",
                        format!("kernel sides must be odd and at most {MAX_PSF_SIZE}"),
                    ));
                }
                Psf::from_weights(p.width, p.height, p.data.clone())
                    .map_err(|e| CoreError::param("psf", e.to_string()))?;
            }
            (None, false) => {}
        }
        let on_clip = self.frames.is_some();
        if self.gyro_clip.is_some() && !(on_clip && self.method == Gyro) {
            return Err(CoreError::param(
                "gyro_clip",
                "only used by method gyro on a video dataset (with `frames`)",
            ));
        }
        if let Some(g) = &self.gyro_clip {
            g.validate().map_err(|e| prefixed("gyro_clip", e))?;
        }
        match (&self.gyro, self.method == Gyro) {
            (None, true) if on_clip && self.gyro_clip.is_none() => {
                return Err(CoreError::param(
                    "gyro_clip",
                    "method gyro on a clip needs gyro_clip: the IMU log and the clip's start \
                     on its clock",
                ));
            }
            (None, true) if on_clip => {}
            (None, true) => return Err(CoreError::param("gyro", "method gyro needs a trace")),
            (Some(_), true) if on_clip => {
                return Err(CoreError::param(
                    "gyro",
                    "a trace covers one exposure; for a clip give gyro_clip instead",
                ));
            }
            (Some(_), false) => {
                return Err(CoreError::param("gyro", "only used by method gyro"));
            }
            // Errors name the field by its path in the request (`gyro.fx`), as every other.
            (Some(g), true) => g.validate().map_err(|e| prefixed("gyro", e))?,
            (None, false) => {}
        }
        if let Some(f) = &self.frames {
            f.validate()?;
        }
        if let Some([nx, ny]) = self.gyro_grid {
            if self.method != Gyro {
                return Err(CoreError::param("gyro_grid", "only used by method gyro"));
            }
            if !(1..=MAX_GYRO_GRID).contains(&nx) || !(1..=MAX_GYRO_GRID).contains(&ny) {
                return Err(CoreError::param(
                    "gyro_grid",
                    format!("between 1 and {MAX_GYRO_GRID} cells per axis"),
                ));
            }
        }
        if let Some(n) = self.iterations {
            let max = if matches!(self.method, Tv | Blind | Gyro) {
                MAX_TV_ITERATIONS
            } else {
                MAX_RL_ITERATIONS
            };
            if self.method == Wiener {
                return Err(CoreError::param("iterations", "wiener is not iterative"));
            }
            if !(1..=max).contains(&n) {
                return Err(CoreError::param(
                    "iterations",
                    format!("must be between 1 and {max}"),
                ));
            }
        }
        if self.kernel_threshold.is_some() && self.method != Blind {
            return Err(CoreError::param(
                "kernel_threshold",
                "only used by method blind",
            ));
        }
        if self.kernel_region.is_some() && self.method != Blind {
            return Err(CoreError::param(
                "kernel_region",
                "only used by method blind",
            ));
        }
        if let Some(v) = self.nsr
            && !(v.is_finite() && v >= 0.0)
        {
            return Err(CoreError::param("nsr", "must be finite and ≥ 0"));
        }
        self.tv_params().validate().map_err(|e| match e {
            CoreError::InvalidParam { field, message } if field == "lambda" => {
                CoreError::param("tv_lambda", message)
            }
            other => other,
        })?;
        self.blind_params().validate()?;
        Ok(())
    }

    fn tv_params(&self) -> TvParams {
        let d = TvParams::default();
        TvParams {
            lambda: self.tv_lambda,
            iterations: match self.method {
                DeblurMethod::Tv | DeblurMethod::Gyro => self.iterations.unwrap_or(d.iterations),
                _ => d.iterations,
            },
            saturation: self.saturation,
        }
    }

    fn blind_params(&self) -> BlindParams {
        BlindParams {
            kernel_size: self.kernel_size,
            kernel_threshold: self.kernel_threshold,
            kernel_region: self.kernel_region.unwrap_or(super::DEFAULT_KERNEL_REGION),
            final_tv: TvParams {
                lambda: self.tv_lambda,
                iterations: self.iterations.unwrap_or(TvParams::default().iterations),
                saturation: self.saturation,
            },
            ..BlindParams::default()
        }
    }
}

/// A nested struct's validation error, with the field named by its path (`gyro.fx`) as
/// every other field is.
fn prefixed(prefix: &str, e: CoreError) -> CoreError {
    match e {
        CoreError::InvalidParam { field, message } => CoreError::InvalidParam {
            field: format!("{prefix}.{field}"),
            message,
        },
        other => other,
    }
}

/// Most cells per axis of [`DeblurParams::gyro_grid`].
pub const MAX_GYRO_GRID: usize = 32;

/// Result of [`deblur_image`].
#[derive(Debug, Clone)]
pub struct DeblurOutput {
    /// The deblurred image, in the input's pixel format and bit depth.
    pub image: DynamicImage,
    /// The kernel used (given, estimated or drawn from the gyro trace).
    pub psf: Psf,
    /// The method that ran.
    pub method: DeblurMethod,
    /// For `blind`: the cleaning threshold the kernel was estimated with (given, or the one
    /// the blind choice kept).
    pub kernel_threshold: Option<f64>,
    /// For `blind` without a fixed threshold: how far the two candidate kernels agree
    /// ([`super::kernel_agreement`]); below `kernel_uncertain_below` the kernel is doubtful.
    pub kernel_agreement: Option<f64>,
    /// With `kernel_agreement`: the agreement below which the kernel counts as uncertain for
    /// this photo's noise ([`super::uncertain_agreement`]).
    pub kernel_uncertain_below: Option<f64>,
    /// For `blind`: the region of a larger photo the kernel was estimated on.
    pub kernel_region: Option<super::Region>,
}

/// Deblurs an 8/16-bit (or float) grey, grey+alpha, RGB or RGBA image; the result has the same
/// pixel format and bit depth. Colour channels are deconvolved in parallel with the same kernel
/// (the blur is optical, common to all channels); blind methods estimate it on the Rec. 601 luma,
/// which has the best signal-to-noise ratio. Alpha is copied unchanged.
pub fn deblur_image(
    img: &DynamicImage,
    params: &DeblurParams,
    progress: &dyn Progress,
) -> CoreResult<DeblurOutput> {
    params.validate()?;
    let split = split_image(img)?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    let iterations = params.iterations;
    // The blind choice between kernels restores the luma; a grey image's is the result.
    let mut luma_restored: Option<Plane> = None;
    let mut kernel_threshold: Option<f64> = None;
    let mut kernel_agreement: Option<f64> = None;
    let mut kernel_uncertain_below: Option<f64> = None;
    let mut kernel_region: Option<super::Region> = None;
    let psf = match params.method {
        DeblurMethod::Wiener | DeblurMethod::RichardsonLucy | DeblurMethod::Tv => params
            .psf
            .clone()
            .ok_or_else(|| CoreError::param("psf", "missing"))?,
        DeblurMethod::Blind => {
            let e = estimate_kernel_restored(&split.luma(), &params.blind_params(), progress)?;
            luma_restored = e.restored.filter(|_| split.color.len() == 1);
            kernel_threshold = Some(e.threshold);
            kernel_agreement = e.agreement;
            kernel_uncertain_below = e.uncertain_below;
            kernel_region = e.region;
            e.psf
        }
        DeblurMethod::BlindRl => {
            let ks = params.blind_params().kernel_size_for(w, h)?;
            blind_richardson_lucy(&split.luma(), ks, iterations.unwrap_or(50), progress)?.1
        }
        DeblurMethod::Gyro => gyro_psf(
            params
                .gyro
                .as_ref()
                .ok_or_else(|| CoreError::param("gyro", "missing"))?,
        )?,
    };
    if psf.width > w || psf.height > h {
        return Err(CoreError::param(
            "psf",
            format!(
                "{}×{} kernel is larger than the {w}×{h} image",
                psf.width, psf.height
            ),
        ));
    }
    let tv = match params.method {
        DeblurMethod::Blind => params.blind_params().final_tv,
        _ => params.tv_params(),
    };
    let run = |p: &Plane| -> CoreResult<Plane> {
        match params.method {
            DeblurMethod::Wiener => wiener(p, &psf, params.nsr),
            DeblurMethod::RichardsonLucy | DeblurMethod::BlindRl => richardson_lucy(
                p,
                &psf,
                iterations.unwrap_or(30).min(MAX_RL_ITERATIONS),
                progress,
            ),
            DeblurMethod::Tv | DeblurMethod::Blind | DeblurMethod::Gyro => {
                tv_deconv(p, &psf, &tv, progress)
            }
        }
    };
    // Spatially varying gyro blur: the kernels of the grid, restored tile by tile.
    let grid = match (params.method, params.gyro_grid, &params.gyro) {
        (DeblurMethod::Gyro, Some([nx, ny]), Some(g)) => {
            Some((gyro_psf_grid(g, w, h, nx, ny)?, nx, ny))
        }
        _ => None,
    };
    let planes = split
        .color
        .par_iter()
        .map(|p| match &grid {
            Some((kernels, nx, ny)) => deconv_varying(p, kernels, *nx, *ny, |tile, k| {
                tv_deconv(tile, k, &tv, progress)
            }),
            None => match &luma_restored {
                Some(done) => Ok(done.clone()),
                None => run(p),
            },
        })
        .collect::<CoreResult<Vec<Plane>>>()?;
    Ok(DeblurOutput {
        image: merge_image(&split, &planes)?,
        psf,
        method: params.method,
        kernel_threshold,
        kernel_agreement,
        kernel_uncertain_below,
        kernel_region,
    })
}

/// The kernel as an 8-bit grey PNG scaled so that its largest weight is 255 (for previews; the
/// JSON of [`Psf::to_json`] is the lossless form).
pub fn psf_png(psf: &Psf) -> CoreResult<Vec<u8>> {
    let g = psf.to_gray();
    let buf = image::GrayImage::from_raw(g.width, g.height, g.data)
        .ok_or_else(|| CoreError::input("kernel buffer size mismatch"))?;
    let mut out = std::io::Cursor::new(Vec::new());
    DynamicImage::ImageLuma8(buf)
        .write_to(&mut out, image::ImageFormat::Png)
        .map_err(|e| CoreError::input(format!("PNG encoding failed: {e}")))?;
    Ok(out.into_inner())
}
