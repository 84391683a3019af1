//! The photometric job kinds (science in `caliper_core::photometric`):
//!
//! - `photometric_response`: camera response from a bracketed stack with exposure times;
//! - `vignetting`: `V(r)` from flat-field images;
//! - `photometric_online`: response, vignetting and per-frame exposures of an auto-exposure
//!   image sequence;
//! - `photometric_correct`: apply a fitted model to images (linear, vignetting-free radiance).
//!
//! Every fit writes a `caliper.photometric/v1` document and DSO's files (`pcalib.txt`,
//! `vignette.png`, `times.txt`) as artifacts, so a DSO user downloads them as they are.
//! Frames are taken in natural name order (`frame2.png` before `frame10.png`): that is the
//! order of a sequence and of the `times.txt` ids.

use std::cmp::Ordering;

use caliper_core::Progress;
use caliper_core::io::ImageLimits;
use caliper_core::photometric::{
    CorrectParams, InverseResponse, OnlineParams, PhotoImage, PhotometricModel, ResponseParams,
    VignettingParams, correct, dso, photometric_online, photometric_response, plot, vignetting,
};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use super::{
    Artifact, JobError, JobInput, JobKind, JobOutput, base_name, param_error, parse_params,
    schema_of, stem, stored_params, to_value,
};
use crate::error::ApiError;
use crate::store::{DatasetFile, DatasetKind};

/// Exposure times of the images: a list in natural name order, or a map from file name.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(untagged)]
pub enum ExposureTimes {
    /// One value per image, in natural name order.
    List(Vec<f64>),
    /// Exposure per file name (every image of the dataset must be named).
    ByName(std::collections::BTreeMap<String, f64>),
}

impl ExposureTimes {
    fn validate(&self, field: &str) -> Result<(), ApiError> {
        let bad = |v: f64| !(v.is_finite() && v > 0.0);
        let any_bad = match self {
            ExposureTimes::List(v) => v.iter().copied().any(bad),
            ExposureTimes::ByName(m) => m.values().copied().any(bad),
        };
        let empty = match self {
            ExposureTimes::List(v) => v.is_empty(),
            ExposureTimes::ByName(m) => m.is_empty(),
        };
        if empty {
            return Err(
                ApiError::new("invalid_param", "needs at least one exposure time")
                    .with_field(format!("params.{field}")),
            );
        }
        if any_bad {
            return Err(
                ApiError::new("invalid_param", "exposure times must be finite and > 0")
                    .with_field(format!("params.{field}")),
            );
        }
        Ok(())
    }

    /// The exposure of each (sorted) file.
    fn resolve(&self, files: &[&DatasetFile], field: &str) -> Result<Vec<f64>, JobError> {
        match self {
            ExposureTimes::List(v) if v.len() == files.len() => Ok(v.clone()),
            ExposureTimes::List(v) => Err(permanent(format!(
                "params.{field} has {} values but the dataset has {} images",
                v.len(),
                files.len()
            ))),
            ExposureTimes::ByName(m) => files
                .iter()
                .map(|f| {
                    m.get(&f.name)
                        .or_else(|| m.get(base_name(&f.name)))
                        .copied()
                        .ok_or_else(|| {
                            permanent(format!("params.{field} has no exposure for {:?}", f.name))
                        })
                })
                .collect(),
        }
    }
}

/// Parameters of `photometric_response`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ResponseJobParams {
    /// Exposure time of every image (any unit: only ratios matter).
    pub exposure_times: ExposureTimes,
    /// Fit options.
    #[serde(default)]
    pub options: ResponseParams,
}

/// Parameters of `vignetting`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields, default)]
pub struct VignettingJobParams {
    /// Camera response of the flat-field images (from a `photometric_response` or
    /// `photometric_online` document's `parameters.model`); default: linear.
    pub model: Option<PhotometricModel>,
    /// Fit options.
    pub options: VignettingParams,
}

/// Parameters of `photometric_online`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields, default)]
pub struct OnlineJobParams {
    /// Time between frames, s, for the `times.txt` timestamps (default: frame index).
    pub frame_interval_s: Option<f64>,
    /// Fit options.
    pub options: OnlineParams,
}

/// Parameters of `photometric_correct`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CorrectJobParams {
    /// The model to apply: `parameters.model` of a photometric document.
    pub model: PhotometricModel,
    /// Exposure of each image relative to the model's reference (default 1 for all).
    #[serde(default)]
    pub exposures: Option<ExposureTimes>,
    /// Output gain: written value = gain · radiance, clipped to `[0, 1]` of 16 bits (default 1).
    #[serde(default = "one")]
    pub gain: f64,
}

fn one() -> f64 {
    1.0
}

fn permanent(message: String) -> JobError {
    JobError::Permanent {
        code: "invalid_input",
        message,
    }
}

/// Natural order: digit runs compare as numbers, so `f2` < `f10`.
pub fn natural_cmp(a: &str, b: &str) -> Ordering {
    let (mut x, mut y) = (a.as_bytes(), b.as_bytes());
    loop {
        match (x.first(), y.first()) {
            (None, None) => return a.cmp(b),
            (None, _) => return Ordering::Less,
            (_, None) => return Ordering::Greater,
            (Some(p), Some(q)) if p.is_ascii_digit() && q.is_ascii_digit() => {
                let dx = x.iter().take_while(|c| c.is_ascii_digit()).count();
                let dy = y.iter().take_while(|c| c.is_ascii_digit()).count();
                let (nx, ny) = (trim_zeros(&x[..dx]), trim_zeros(&y[..dy]));
                let o = nx.len().cmp(&ny.len()).then_with(|| nx.cmp(ny));
                if o != Ordering::Equal {
                    return o;
                }
                x = &x[dx..];
                y = &y[dy..];
            }
            (Some(p), Some(q)) => {
                if p != q {
                    return p.cmp(q);
                }
                x = &x[1..];
                y = &y[1..];
            }
        }
    }
}

fn trim_zeros(d: &[u8]) -> &[u8] {
    let k = d.iter().take_while(|&&c| c == b'0').count();
    &d[k.min(d.len().saturating_sub(1))..]
}

/// The dataset's images in natural name order.
fn sorted_files(input: &JobInput) -> Vec<&DatasetFile> {
    let mut files: Vec<&DatasetFile> = input.files.iter().collect();
    files.sort_by(|a, b| natural_cmp(&a.name, &b.name));
    files
}

/// Decode every image keeping its bit depth (8 or 16), checking cancellation between files.
fn decode_all(
    input: &JobInput,
    files: &[&DatasetFile],
    progress: &dyn Progress,
) -> Result<Vec<PhotoImage>, JobError> {
    let limits = ImageLimits::default();
    let mut out = Vec::with_capacity(files.len());
    for (i, f) in files.iter().enumerate() {
        progress.check()?;
        progress.report("decode", i as u64, files.len() as u64);
        let bytes = (input.load)(f)
            .map_err(|e| JobError::Transient(format!("storage: cannot read {}: {e}", f.name)))?;
        let img = PhotoImage::decode(&bytes, &limits)
            .map_err(|e| permanent(format!("{}: {e}", f.name)))?;
        out.push(img);
    }
    Ok(out)
}

fn text_artifact(name: &str, text: String) -> Artifact {
    Artifact {
        name: name.into(),
        media_type: "text/plain; charset=utf-8".into(),
        data: text.into_bytes().into(),
    }
}

fn png_artifact(name: &str, data: Vec<u8>) -> Artifact {
    Artifact {
        name: name.into(),
        media_type: "image/png".into(),
        data: data.into(),
    }
}

/// `pcalib.txt` and the response plot, for every fit.
fn response_artifacts(model: &PhotometricModel) -> Result<Vec<Artifact>, JobError> {
    let inv = InverseResponse::new(model.inverse_256.clone())?;
    Ok(vec![
        text_artifact("pcalib.txt", dso::write_pcalib(&inv)),
        Artifact::svg("response.svg", plot::response_svg(&model.response, None)),
    ])
}

/// `vignette.png` (16-bit, DSO) and the radial profile plot.
fn vignette_artifacts(
    v: &caliper_core::photometric::VignetteModel,
) -> Result<Vec<Artifact>, JobError> {
    Ok(vec![
        png_artifact("vignette.png", dso::write_vignette_png(v)?),
        Artifact::svg("vignette_profile.svg", plot::vignette_profile_svg(v, None)),
    ])
}

/// `times.txt` lines for the sorted frames.
fn times_entries(
    files: &[&DatasetFile],
    exposures: &[f64],
    interval: Option<f64>,
) -> Vec<dso::TimeEntry> {
    files
        .iter()
        .zip(exposures)
        .enumerate()
        .map(|(i, (f, &e))| dso::TimeEntry {
            id: stem(&f.name).to_string(),
            timestamp: interval.map_or(i as f64, |d| i as f64 * d),
            exposure_ms: e,
        })
        .collect()
}

/// `photometric_response`: the response from a bracketed stack of a static scene.
pub struct PhotometricResponse;

impl JobKind for PhotometricResponse {
    fn name(&self) -> &'static str {
        "photometric_response"
    }
    fn schema(&self) -> &'static str {
        "caliper.photometric/v1"
    }
    fn dataset_kind(&self) -> DatasetKind {
        DatasetKind::Images
    }
    fn description(&self) -> &'static str {
        "Camera response (EMoR, monotone) from a bracketed stack of a static scene with exposure times; DSO pcalib.txt."
    }
    fn params_schema(&self) -> Value {
        schema_of::<ResponseJobParams>()
    }
    fn normalize_params(&self, params: &Value) -> Result<Value, ApiError> {
        let p: ResponseJobParams = parse_params(params)?;
        p.exposure_times.validate("exposure_times")?;
        p.options
            .validate()
            .map_err(|e| param_error(prefix(e, "options")))?;
        serde_json::to_value(&p).map_err(ApiError::internal)
    }
    fn run(&self, input: &JobInput, progress: &dyn Progress) -> Result<JobOutput, JobError> {
        let p: ResponseJobParams = stored_params(&input.params)?;
        let files = sorted_files(input);
        let times = p.exposure_times.resolve(&files, "exposure_times")?;
        let images = decode_all(input, &files, progress)?;
        let r = photometric_response(&images, &times, &p.options, progress)?;
        let quality = json!({
            "images": images.len(),
            "residual_rms_levels": r.diagnostics.residual_rms_levels,
            "monotone": r.diagnostics.monotone,
            "converged": r.diagnostics.converged,
        });
        let mut artifacts = response_artifacts(&r.model)?;
        let entries = times_entries(&files, &r.exposure_ratios, None);
        artifacts.push(text_artifact("times.txt", dso::write_times(&entries)));
        Ok(JobOutput {
            parameters: to_value(&r)?,
            quality,
            artifacts,
        })
    }
}

/// `vignetting`: V(r) from flat-field images.
pub struct Vignetting;

impl JobKind for Vignetting {
    fn name(&self) -> &'static str {
        "vignetting"
    }
    fn schema(&self) -> &'static str {
        "caliper.photometric/v1"
    }
    fn dataset_kind(&self) -> DatasetKind {
        DatasetKind::Images
    }
    fn description(&self) -> &'static str {
        "Vignetting V(r) = 1 + v1 r² + v2 r⁴ + v3 r⁶ (optionally its centre) from flat-field images; DSO vignette.png."
    }
    fn params_schema(&self) -> Value {
        schema_of::<VignettingJobParams>()
    }
    fn normalize_params(&self, params: &Value) -> Result<Value, ApiError> {
        let p: VignettingJobParams = parse_params(params)?;
        p.options
            .validate()
            .map_err(|e| param_error(prefix(e, "options")))?;
        if let Some(m) = &p.model {
            m.response
                .validate()
                .map_err(|e| param_error(prefix(e, "model.response")))?;
        }
        serde_json::to_value(&p).map_err(ApiError::internal)
    }
    fn run(&self, input: &JobInput, progress: &dyn Progress) -> Result<JobOutput, JobError> {
        let p: VignettingJobParams = stored_params(&input.params)?;
        let files = sorted_files(input);
        let images = decode_all(input, &files, progress)?;
        let inverse = match &p.model {
            Some(m) => InverseResponse::new(m.inverse_256.clone())?,
            None => InverseResponse::linear(256),
        };
        let r = vignetting(&images, &inverse, &p.options, progress)?;
        let quality = json!({
            "images": images.len(),
            "relative_rms": r.relative_rms,
            "pixels_used": r.pixels_used,
        });
        Ok(JobOutput {
            parameters: to_value(&r)?,
            quality,
            artifacts: vignette_artifacts(&r.vignette)?,
        })
    }
}

/// `photometric_online`: response, vignetting and exposures of an auto-exposure sequence.
pub struct PhotometricOnline;

impl JobKind for PhotometricOnline {
    fn name(&self) -> &'static str {
        "photometric_online"
    }
    fn schema(&self) -> &'static str {
        "caliper.photometric/v1"
    }
    fn dataset_kind(&self) -> DatasetKind {
        DatasetKind::Images
    }
    fn description(&self) -> &'static str {
        "Online photometric calibration of an auto-exposure image sequence (Bergmann et al. 2017): response, vignetting and per-frame exposures; DSO pcalib.txt, vignette.png, times.txt."
    }
    fn params_schema(&self) -> Value {
        schema_of::<OnlineJobParams>()
    }
    fn normalize_params(&self, params: &Value) -> Result<Value, ApiError> {
        let p: OnlineJobParams = parse_params(params)?;
        p.options
            .validate()
            .map_err(|e| param_error(prefix(e, "options")))?;
        if let Some(d) = p.frame_interval_s
            && !(d.is_finite() && d > 0.0)
        {
            return Err(ApiError::new("invalid_param", "must be finite and > 0")
                .with_field("params.frame_interval_s"));
        }
        serde_json::to_value(&p).map_err(ApiError::internal)
    }
    fn run(&self, input: &JobInput, progress: &dyn Progress) -> Result<JobOutput, JobError> {
        let p: OnlineJobParams = stored_params(&input.params)?;
        let files = sorted_files(input);
        let images = decode_all(input, &files, progress)?;
        let r = photometric_online(&images, &p.options, progress)?;
        let quality = json!({
            "frames": images.len(),
            "tracks": r.tracks,
            "mean_track_length": r.mean_track_length,
            "residual_rms_levels": r.diagnostics.residual_rms_levels,
            "converged": r.diagnostics.converged,
        });
        let mut artifacts = response_artifacts(&r.model)?;
        if let Some(v) = &r.model.vignette {
            artifacts.extend(vignette_artifacts(v)?);
        }
        let entries = times_entries(&files, &r.exposure_ratios, p.frame_interval_s);
        artifacts.push(text_artifact("times.txt", dso::write_times(&entries)));
        let ts: Vec<f64> = entries.iter().map(|e| e.timestamp).collect();
        artifacts.push(Artifact::svg(
            "exposures.svg",
            plot::exposure_svg(&r.exposure_ratios, Some(&ts), None),
        ));
        Ok(JobOutput {
            parameters: to_value(&r)?,
            quality,
            artifacts,
        })
    }
}

/// `photometric_correct`: apply a model to images.
pub struct PhotometricCorrect;

impl JobKind for PhotometricCorrect {
    fn name(&self) -> &'static str {
        "photometric_correct"
    }
    fn schema(&self) -> &'static str {
        "caliper.photometric_correct/v1"
    }
    fn dataset_kind(&self) -> DatasetKind {
        DatasetKind::Images
    }
    fn description(&self) -> &'static str {
        "Apply a photometric model to images: undo the response and vignetting and normalise exposure; 16-bit linear PNGs as artifacts."
    }
    fn params_schema(&self) -> Value {
        schema_of::<CorrectJobParams>()
    }
    fn normalize_params(&self, params: &Value) -> Result<Value, ApiError> {
        let p: CorrectJobParams = parse_params(params)?;
        p.model
            .response
            .validate()
            .map_err(|e| param_error(prefix(e, "model.response")))?;
        InverseResponse::new(p.model.inverse_256.clone())
            .map_err(|e| param_error(prefix(e, "model.inverse_256")))?;
        if let Some(v) = &p.model.vignette {
            v.validate()
                .map_err(|e| param_error(prefix(e, "model.vignette")))?;
        }
        if let Some(e) = &p.exposures {
            e.validate("exposures")?;
        }
        if !(p.gain.is_finite() && p.gain > 0.0) {
            return Err(
                ApiError::new("invalid_param", "must be finite and > 0").with_field("params.gain")
            );
        }
        serde_json::to_value(&p).map_err(ApiError::internal)
    }
    fn run(&self, input: &JobInput, progress: &dyn Progress) -> Result<JobOutput, JobError> {
        let p: CorrectJobParams = stored_params(&input.params)?;
        let files = sorted_files(input);
        let exposures = match &p.exposures {
            Some(e) => e.resolve(&files, "exposures")?,
            None => vec![1.0; files.len()],
        };
        let images = decode_all(input, &files, progress)?;
        let mut artifacts = Vec::with_capacity(images.len());
        let mut outputs = Vec::with_capacity(images.len());
        let mut clipped_total = 0usize;
        for ((f, img), &exposure) in files.iter().zip(&images).zip(&exposures) {
            let plane = correct(
                img,
                &p.model,
                &CorrectParams {
                    exposure,
                    gain: p.gain,
                },
                progress,
            )?;
            let clipped = plane.data.iter().filter(|&&v| v > 1.0).count();
            clipped_total += clipped;
            let png = png16_clipped(plane.width, plane.height, &plane.data)?;
            let name = format!("{}.png", stem(&f.name));
            outputs.push(json!({
                "file": f.name,
                "artifact": name,
                "exposure": exposure,
                "mean_radiance": plane.mean(),
                "clipped_pixels": clipped,
            }));
            artifacts.push(png_artifact(&name, png));
        }
        let quality = json!({"images": images.len(), "clipped_pixels": clipped_total});
        Ok(JobOutput {
            parameters: json!({"images": outputs, "gain": p.gain}),
            quality,
            artifacts,
        })
    }
}

/// 16-bit grey PNG of linear values, `[0, 1]` → `0..=65535`, clipped (not rescaled, so that
/// frames of one sequence stay comparable).
fn png16_clipped(width: usize, height: usize, values: &[f32]) -> Result<Vec<u8>, JobError> {
    let data: Vec<u16> = values
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 65535.0).round() as u16)
        .collect();
    let buf: image::ImageBuffer<image::Luma<u16>, Vec<u16>> =
        image::ImageBuffer::from_raw(width as u32, height as u32, data)
            .ok_or_else(|| permanent("corrected image size mismatch".into()))?;
    let mut out = std::io::Cursor::new(Vec::new());
    buf.write_to(&mut out, image::ImageFormat::Png)
        .map_err(|e| permanent(format!("cannot encode PNG: {e}")))?;
    Ok(out.into_inner())
}

/// Prefix a core parameter error's field with the params sub-object it lives in.
fn prefix(e: caliper_core::CoreError, at: &str) -> caliper_core::CoreError {
    match e {
        caliper_core::CoreError::InvalidParam { field, message } => {
            caliper_core::CoreError::InvalidParam {
                field: format!("{at}.{field}"),
                message,
            }
        }
        other => other,
    }
}

#[cfg(test)]
mod tests {
    use super::natural_cmp;
    use std::cmp::Ordering;

    #[test]
    fn natural_order_compares_digit_runs_as_numbers() {
        assert_eq!(natural_cmp("f2.png", "f10.png"), Ordering::Less);
        assert_eq!(natural_cmp("f010.png", "f9.png"), Ordering::Greater);
        assert_eq!(natural_cmp("a.png", "b.png"), Ordering::Less);
        let mut v = vec!["img10", "img1", "img02", "img2"];
        v.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(v, ["img1", "img02", "img2", "img10"]);
    }
}
