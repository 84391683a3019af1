//! The photometric job kinds (science in `caliper_core::photometric`), one file each:
//!
//! - [`response`] `photometric_response`: camera response from a bracketed stack with
//!   exposure times;
//! - [`vignetting`] `vignetting`: `V(r)` from flat-field images;
//! - [`online`] `photometric_online`: response, vignetting and per-frame exposures of an
//!   auto-exposure image sequence or video clip ([`clip`] takes its frames);
//! - [`correct`] `photometric_correct`: apply a fitted model to images (linear,
//!   vignetting-free radiance).
//!
//! Every fit writes a `caliper.photometric/v1` document and DSO's files (`pcalib.txt`,
//! `vignette.png`, `times.txt`) as artifacts, so a DSO user downloads them as they are.
//! Frames are taken in natural name order (`frame2.png` before `frame10.png`): that is the
//! order of a sequence and of the `times.txt` ids. This module holds what they share.

mod clip;
mod correct;
mod online;
mod response;
mod vignetting;

pub use correct::{CorrectJobParams, PhotometricCorrect};
pub use online::{OnlineJobParams, PhotometricOnline};
pub use response::{PhotometricResponse, ResponseJobParams};
pub use vignetting::{Vignetting, VignettingJobParams};

use std::cmp::Ordering;

use caliper_core::Progress;
use caliper_core::io::ImageLimits;
use caliper_core::photometric::{InverseResponse, PhotoImage, PhotometricModel, dso, plot};
use serde::{Deserialize, Serialize};

use super::{Artifact, JobError, JobInput, ParamError, base_name, stem};
use crate::store::DatasetFile;

/// The photometric documents' exports.
pub(super) const EXPORTS: &[super::Export] = crate::exports::PHOTOMETRIC_EXPORTS;

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
    pub(super) fn validate(&self, field: &str) -> Result<(), ParamError> {
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
            return Err(ParamError::new(field, "needs at least one exposure time"));
        }
        if any_bad {
            return Err(ParamError::new(
                field,
                "exposure times must be finite and > 0",
            ));
        }
        Ok(())
    }

    /// The exposure of each (sorted) file.
    pub(super) fn resolve(
        &self,
        files: &[&DatasetFile],
        field: &str,
    ) -> Result<Vec<f64>, JobError> {
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

pub(super) fn one() -> f64 {
    1.0
}

pub(super) fn permanent(message: String) -> JobError {
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

pub(super) fn trim_zeros(d: &[u8]) -> &[u8] {
    let k = d.iter().take_while(|&&c| c == b'0').count();
    &d[k.min(d.len().saturating_sub(1))..]
}

/// The dataset's images in natural name order.
pub(super) fn sorted_files(input: &JobInput) -> Vec<&DatasetFile> {
    let mut files: Vec<&DatasetFile> = input.files.iter().collect();
    files.sort_by(|a, b| natural_cmp(&a.name, &b.name));
    files
}

/// Decode every image keeping its bit depth (8 or 16), checking cancellation between files.
pub(super) fn decode_all(
    input: &JobInput,
    files: &[&DatasetFile],
    progress: &dyn Progress,
) -> Result<Vec<PhotoImage>, JobError> {
    decode_each(input, files, progress, PhotoImage::decode)
}

/// Decode every image into its `[R, G, B]` planes (for `channels: rgb`), keeping the bit
/// depth; a grey image is refused with its name.
pub(super) fn decode_all_rgb(
    input: &JobInput,
    files: &[&DatasetFile],
    progress: &dyn Progress,
) -> Result<Vec<[PhotoImage; 3]>, JobError> {
    decode_each(input, files, progress, PhotoImage::decode_rgb)
}

/// Load and decode every file with `decode`, reporting progress and naming the file on error.
fn decode_each<T, E: std::fmt::Display>(
    input: &JobInput,
    files: &[&DatasetFile],
    progress: &dyn Progress,
    decode: impl Fn(&[u8], &ImageLimits) -> Result<T, E>,
) -> Result<Vec<T>, JobError> {
    let limits = ImageLimits::default();
    let mut out = Vec::with_capacity(files.len());
    for (i, f) in files.iter().enumerate() {
        progress.check()?;
        progress.report("decode", i as u64, files.len() as u64);
        let bytes = (input.load)(f)
            .map_err(|e| JobError::Transient(format!("storage: cannot read {}: {e}", f.name)))?;
        out.push(decode(&bytes, &limits).map_err(|e| permanent(format!("{}: {e}", f.name)))?);
    }
    Ok(out)
}

pub(super) fn text_artifact(name: &str, text: String) -> Artifact {
    Artifact {
        name: name.into(),
        media_type: "text/plain; charset=utf-8".into(),
        data: text.into_bytes().into(),
    }
}

pub(super) fn png_artifact(name: &str, data: Vec<u8>) -> Artifact {
    Artifact {
        name: name.into(),
        media_type: "image/png".into(),
        data: data.into(),
    }
}

/// `pcalib.txt` and the response plot, for every fit.
pub(super) fn response_artifacts(model: &PhotometricModel) -> Result<Vec<Artifact>, JobError> {
    let inv = InverseResponse::new(model.inverse_256.clone())?;
    Ok(vec![
        text_artifact("pcalib.txt", dso::write_pcalib(&inv)),
        Artifact::svg("response.svg", plot::response_svg(&model.response, None)),
    ])
}

/// `vignette.png` (16-bit, DSO) and the radial profile plot.
pub(super) fn vignette_artifacts(
    v: &caliper_core::photometric::VignetteModel,
) -> Result<Vec<Artifact>, JobError> {
    Ok(vec![
        png_artifact("vignette.png", dso::write_vignette_png(v)?),
        Artifact::svg("vignette_profile.svg", plot::vignette_profile_svg(v, None)),
    ])
}

/// `times.txt` lines for the sorted frames.
pub(super) fn times_entries(
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

/// 16-bit grey PNG of linear values, `[0, 1]` → `0..=65535`, clipped (not rescaled, so that
/// frames of one sequence stay comparable).
pub(super) fn png16_clipped(
    width: usize,
    height: usize,
    values: &[f32],
) -> Result<Vec<u8>, JobError> {
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
