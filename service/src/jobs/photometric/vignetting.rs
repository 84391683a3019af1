//! `vignetting`: V(r) from flat-field images (the polynomial, or the radial spline with an
//! image-circle mask for fisheye lenses; see `caliper_core::photometric::vignetting`).

use caliper_core::Progress;
use caliper_core::photometric::{InverseResponse, PhotometricModel, VignettingParams, vignetting};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use super::{decode_all, sorted_files, vignette_artifacts};
use crate::jobs::{
    CliContext, Export, JobError, JobInput, JobOutput, JsonParams, Kind, ParamError, RunError,
    to_value,
};
use crate::store::DatasetKind;

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

/// `vignetting`: V(r) from flat-field images.
pub struct Vignetting;

impl Kind for Vignetting {
    const NAME: &'static str = "vignetting";
    const SCHEMA: &'static str = "caliper.photometric/v1";
    const DATASET: DatasetKind = DatasetKind::Images;
    const DESCRIPTION: &'static str = "Vignetting from flat-field images: V(r) = 1 + v1 r² + v2 r⁴ + v3 r⁶ (optionally its centre), or for fisheye and wide lenses a radial spline with the pixels outside the image circle masked (options.vignette_model: polynomial, spline or auto); DSO vignette.png (0 where masked).";
    const EXPORTS: &'static [Export] = super::EXPORTS;
    type Params = VignettingJobParams;
    type Cli = JsonParams;

    fn check(p: &mut VignettingJobParams) -> Result<(), ParamError> {
        p.options
            .validate()
            .map_err(|e| ParamError::from_core("options", e))?;
        if let Some(m) = &p.model {
            m.response
                .validate()
                .map_err(|e| ParamError::from_core("model.response", e))?;
        }
        Ok(())
    }

    fn cli_params(a: &JsonParams, _: &CliContext<'_>) -> Result<Value, RunError> {
        a.value()
    }

    fn run(
        &self,
        p: VignettingJobParams,
        input: &JobInput,
        progress: &dyn Progress,
    ) -> Result<JobOutput, JobError> {
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
            "model": r.model,
            "mask_radius_px": r.mask_radius_px,
        });
        Ok(JobOutput {
            parameters: to_value(&r)?,
            quality,
            artifacts: vignette_artifacts(&r.vignette)?,
        })
    }
}
