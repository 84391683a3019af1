//! `blur_score`: Laplacian variance and the singular-value feature per image, a blurred
//! verdict, and the sharpest-first ranking of the set (science in `caliper_core::blur`).

use caliper_core::Progress;
use caliper_core::blur::{BlurParams, render_svg, score_images};
use serde_json::{Value, json};

use super::{
    Artifact, JobError, JobInput, JobKind, JobOutput, param_error, parse_params, stored_params,
};
use crate::error::ApiError;
use crate::store::DatasetKind;

/// The `blur_score` job kind.
pub struct BlurScore;

impl JobKind for BlurScore {
    fn name(&self) -> &'static str {
        "blur_score"
    }

    fn schema(&self) -> &'static str {
        "caliper.blur_score/v1"
    }

    fn dataset_kind(&self) -> DatasetKind {
        DatasetKind::Images
    }

    fn description(&self) -> &'static str {
        "Score every image of a set for blur (Laplacian variance, singular-value feature), flag blurred ones and rank the set sharpest first."
    }

    fn params_schema(&self) -> Value {
        serde_json::to_value(<BlurParams as utoipa::PartialSchema>::schema()).unwrap_or(Value::Null)
    }

    fn normalize_params(&self, params: &Value) -> Result<Value, ApiError> {
        let p: BlurParams = parse_params(params)?;
        p.validate().map_err(param_error)?;
        serde_json::to_value(&p).map_err(ApiError::internal)
    }

    fn run(&self, input: &JobInput, progress: &dyn Progress) -> Result<JobOutput, JobError> {
        let params: BlurParams = stored_params(&input.params)?;
        let names: Vec<String> = input.files.iter().map(|f| f.name.clone()).collect();
        let limits = caliper_core::io::ImageLimits::default();
        let load = |i: usize| -> caliper_core::CoreResult<Vec<u8>> {
            let f = &input.files[i];
            (input.load)(f).map_err(|e| {
                // Storage trouble is not the input's fault: surface it as transient below.
                caliper_core::CoreError::NoSolution(format!("storage: cannot read {}: {e}", f.name))
            })
        };
        let report = match score_images(&names, load, &params, &limits, progress) {
            Ok(r) => r,
            Err(caliper_core::CoreError::NoSolution(m)) if m.starts_with("storage:") => {
                return Err(JobError::Transient(m));
            }
            Err(e) => return Err(e.into()),
        };
        let svg = render_svg(&report, &params);
        let quality = json!({
            "images": report.summary.count,
            "blurred": report.summary.blurred_count,
            "laplacian_variance": report.summary.laplacian,
            "svd_beta": report.summary.beta,
        });
        let parameters = serde_json::to_value(&report).map_err(|e| JobError::Permanent {
            code: "internal_error",
            message: e.to_string(),
        })?;
        Ok(JobOutput {
            parameters,
            quality,
            artifacts: vec![Artifact::svg("scores.svg", svg)],
        })
    }
}
