//! `photometric_correct`: apply a fitted photometric model to images (undo the response and
//! vignetting, normalise exposure); 16-bit linear PNGs as artifacts.

use caliper_core::Progress;
use caliper_core::photometric::{CorrectParams, InverseResponse, PhotometricModel, correct};
use clap::Args;
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use super::{ExposureTimes, decode_all, one, png_artifact, png16_clipped, sorted_files};
use crate::jobs::{CliContext, JobError, JobInput, JobOutput, Kind, ParamError, RunError, stem};
use crate::store::DatasetKind;

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

/// `photometric_correct`: apply a model to images.
pub struct PhotometricCorrect;

/// Flags of `caliper run photometric-correct`.
#[derive(Debug, Clone, Args)]
pub struct CorrectArgs {
    /// A photometric document (or its `parameters.model` object) as JSON.
    #[arg(long)]
    pub model: std::path::PathBuf,
    /// Output gain [default: 1].
    #[arg(long)]
    pub gain: Option<f64>,
}

impl Kind for PhotometricCorrect {
    const NAME: &'static str = "photometric_correct";
    const SCHEMA: &'static str = "caliper.photometric_correct/v1";
    const DATASET: DatasetKind = DatasetKind::Images;
    const DESCRIPTION: &'static str = "Apply a photometric model to images: undo the response and vignetting and normalise exposure; 16-bit linear PNGs as artifacts.";
    type Params = CorrectJobParams;
    type Cli = CorrectArgs;

    fn check(p: &mut CorrectJobParams) -> Result<(), ParamError> {
        p.model
            .response
            .validate()
            .map_err(|e| ParamError::from_core("model.response", e))?;
        InverseResponse::new(p.model.inverse_256.clone())
            .map_err(|e| ParamError::from_core("model.inverse_256", e))?;
        if let Some(v) = &p.model.vignette {
            v.validate()
                .map_err(|e| ParamError::from_core("model.vignette", e))?;
        }
        if let Some(e) = &p.exposures {
            e.validate("exposures")?;
        }
        if !(p.gain.is_finite() && p.gain > 0.0) {
            return Err(ParamError::new("gain", "must be finite and > 0"));
        }
        Ok(())
    }

    fn cli_params(a: &CorrectArgs, _: &CliContext<'_>) -> Result<Value, RunError> {
        let text = std::fs::read_to_string(&a.model)?;
        let v: Value = serde_json::from_str(&text)
            .map_err(|e| RunError::Input(format!("{} is not JSON: {e}", a.model.display())))?;
        // A whole document, or just its model.
        let model = v.pointer("/parameters/model").cloned().unwrap_or(v);
        let mut params = json!({"model": model});
        if let Some(g) = a.gain {
            params["gain"] = json!(g);
        }
        Ok(params)
    }

    fn run(
        &self,
        p: CorrectJobParams,
        input: &JobInput,
        progress: &dyn Progress,
    ) -> Result<JobOutput, JobError> {
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
