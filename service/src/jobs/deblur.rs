//! `deblur`: deconvolve every image of a set (Wiener, Richardson-Lucy, TV, blind, alternating-RL
//! blind, or a gyro-drawn kernel; science in `caliper_core::deconv`).
//!
//! Artifacts per input `NAME.EXT`: `NAME.EXT` (the deblurred image, same format and bit depth
//! as the input), `NAME.kernel.png` (the kernel, scaled to its peak) and `NAME.kernel.json`
//! (the exact weights), and `NAME.preview.png` (blurred | deblurred side by side, 8-bit,
//! at most 1024 px wide) for dashboards.

use std::io::Cursor;

use caliper_core::Progress;
use caliper_core::deconv::{DeblurParams, deblur_image, psf_png};
use caliper_core::io::ImageLimits;
use image::{DynamicImage, ImageFormat};
use serde_json::{Value, json};

use super::{
    Artifact, JobError, JobInput, JobKind, JobOutput, base_name, param_error, parse_params,
    schema_of, stem, stored_params,
};
use crate::error::ApiError;
use crate::store::{DatasetFile, DatasetKind};

/// Widest before/after preview, px.
const PREVIEW_WIDTH: u32 = 1024;

/// The `deblur` job kind.
pub struct Deblur;

fn permanent(message: String) -> JobError {
    JobError::Permanent {
        code: "invalid_input",
        message,
    }
}

fn internal(e: impl std::fmt::Display) -> JobError {
    JobError::Permanent {
        code: "internal_error",
        message: e.to_string(),
    }
}

/// Decode an image keeping its pixel format, within the service's image limits.
pub fn decode_keep_format(
    bytes: &[u8],
    name: &str,
) -> Result<(DynamicImage, ImageFormat), JobError> {
    caliper_core::io::decode_image(bytes, &ImageLimits::default())
        .map_err(|e| permanent(format!("{name}: {e}")))
}

/// Encode in `format` (PNG, TIFF or JPEG; JPEG can only hold 8-bit grey/RGB, which is what a
/// JPEG decodes to anyway).
pub fn encode(
    img: &DynamicImage,
    format: ImageFormat,
) -> Result<(Vec<u8>, &'static str), JobError> {
    let (format, media) = match format {
        ImageFormat::Tiff => (ImageFormat::Tiff, "image/tiff"),
        ImageFormat::Jpeg => (ImageFormat::Jpeg, "image/jpeg"),
        _ => (ImageFormat::Png, "image/png"),
    };
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, format).map_err(internal)?;
    Ok((out.into_inner(), media))
}

/// Blurred | deblurred side by side, 8-bit RGB, scaled down to [`PREVIEW_WIDTH`].
fn preview(before: &DynamicImage, after: &DynamicImage) -> Result<Vec<u8>, JobError> {
    let (w, h) = (before.width(), before.height());
    let mut canvas = image::RgbImage::new(2 * w + 8, h);
    for p in canvas.pixels_mut() {
        *p = image::Rgb([255, 255, 255]);
    }
    image::imageops::replace(&mut canvas, &before.to_rgb8(), 0, 0);
    image::imageops::replace(&mut canvas, &after.to_rgb8(), i64::from(w) + 8, 0);
    let canvas = DynamicImage::ImageRgb8(canvas);
    let canvas = if canvas.width() > PREVIEW_WIDTH {
        let nh = (u64::from(canvas.height()) * u64::from(PREVIEW_WIDTH) / u64::from(canvas.width()))
            .max(1) as u32;
        canvas.resize_exact(PREVIEW_WIDTH, nh, image::imageops::FilterType::Triangle)
    } else {
        canvas
    };
    let mut out = Cursor::new(Vec::new());
    canvas
        .write_to(&mut out, ImageFormat::Png)
        .map_err(internal)?;
    Ok(out.into_inner())
}

impl JobKind for Deblur {
    fn name(&self) -> &'static str {
        "deblur"
    }
    fn schema(&self) -> &'static str {
        "caliper.deblur/v1"
    }
    fn dataset_kind(&self) -> DatasetKind {
        DatasetKind::Images
    }
    fn description(&self) -> &'static str {
        "Deblur images: Wiener, Richardson-Lucy or TV with a known kernel, blind kernel estimation (L0 prior, coarse to fine), or a kernel drawn from a gyro trace; same format and bit depth out, with the kernel."
    }
    fn params_schema(&self) -> Value {
        schema_of::<DeblurParams>()
    }
    fn normalize_params(&self, params: &Value) -> Result<Value, ApiError> {
        let mut p: DeblurParams = parse_params(params)?;
        p.validate().map_err(param_error)?;
        // Store the kernel normalised (sum 1), so the job and its document use the same one.
        if let Some(k) = p.psf.take() {
            p.psf = Some(
                caliper_core::deconv::Psf::from_weights(k.width, k.height, k.data).map_err(
                    |e| param_error(caliper_core::CoreError::param("psf", e.to_string())),
                )?,
            );
        }
        serde_json::to_value(&p).map_err(ApiError::internal)
    }
    fn run(&self, input: &JobInput, progress: &dyn Progress) -> Result<JobOutput, JobError> {
        let p: DeblurParams = stored_params(&input.params)?;
        let mut artifacts = Vec::new();
        let mut images = Vec::new();
        let total = input.files.len() as u64;
        let mut seen = std::collections::HashSet::new();
        for (i, f) in input.files.iter().enumerate() {
            progress.check()?;
            progress.report("deblur", i as u64, total);
            let out_name = unique_name(base_name(&f.name), &mut seen);
            images.push(self.one(input, f, &p, &out_name, &mut artifacts, progress)?);
        }
        progress.report("deblur", total, total);
        let quality = json!({"images": images.len(), "method": p.method});
        Ok(JobOutput {
            parameters: json!({"method": p.method, "images": images}),
            quality,
            artifacts,
        })
    }
}

impl Deblur {
    /// Deblur one file, pushing its artifacts; returns its entry in the document.
    fn one(
        &self,
        input: &JobInput,
        f: &DatasetFile,
        p: &DeblurParams,
        out_name: &str,
        artifacts: &mut Vec<Artifact>,
        progress: &dyn Progress,
    ) -> Result<Value, JobError> {
        let bytes = (input.load)(f)
            .map_err(|e| JobError::Transient(format!("storage: cannot read {}: {e}", f.name)))?;
        let (img, format) = decode_keep_format(&bytes, &f.name)?;
        let out = deblur_image(&img, p, progress).map_err(|e| match e {
            caliper_core::CoreError::InvalidInput(m) => permanent(format!("{}: {m}", f.name)),
            other => other.into(),
        })?;
        let (data, media) = encode(&out.image, format)?;
        artifacts.push(Artifact {
            name: out_name.to_string(),
            media_type: media.into(),
            data: data.into(),
        });
        let s = stem(out_name);
        artifacts.push(Artifact {
            name: format!("{s}.kernel.png"),
            media_type: "image/png".into(),
            data: psf_png(&out.psf)?.into(),
        });
        artifacts.push(Artifact {
            name: format!("{s}.kernel.json"),
            media_type: "application/json".into(),
            data: out.psf.to_json().to_string().into_bytes().into(),
        });
        artifacts.push(Artifact {
            name: format!("{s}.preview.png"),
            media_type: "image/png".into(),
            data: preview(&img, &out.image)?.into(),
        });
        Ok(json!({
            "file": f.name,
            "artifact": out_name,
            "width": img.width(),
            "height": img.height(),
            "color": format!("{:?}", img.color()),
            "kernel": {
                "width": out.psf.width,
                "height": out.psf.height,
                "artifact_png": format!("{s}.kernel.png"),
                "artifact_json": format!("{s}.kernel.json"),
            },
        }))
    }
}

/// Archive entries may share a base name (`a/x.png`, `b/x.png`): number the later ones.
fn unique_name(name: &str, seen: &mut std::collections::HashSet<String>) -> String {
    if seen.insert(name.to_string()) {
        return name.to_string();
    }
    let (s, ext) = name.rsplit_once('.').unwrap_or((name, ""));
    for k in 2.. {
        let candidate = if ext.is_empty() {
            format!("{s}-{k}")
        } else {
            format!("{s}-{k}.{ext}")
        };
        if seen.insert(candidate.clone()) {
            return candidate;
        }
    }
    name.to_string()
}
