//! `photometric_response`: the camera response from a bracketed stack of a static scene with
//! known exposure times.

use caliper_core::Progress;
use caliper_core::photometric::{ResponseParams, dso, photometric_response};
use clap::Args;
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use super::{
    ExposureTimes, decode_all, response_artifacts, sorted_files, text_artifact, times_entries,
};
use crate::jobs::{
    CliContext, Export, JobError, JobInput, JobOutput, Kind, ParamError, RunError, to_value,
};
use crate::store::DatasetKind;

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

/// `photometric_response`: the response from a bracketed stack of a static scene.
pub struct PhotometricResponse;

/// Flags of `caliper run photometric-response`.
#[derive(Debug, Clone, Args)]
pub struct ResponseArgs {
    /// A `times.txt` (`id timestamp exposure` per line, ids = image file stems, or in image
    /// order when the ids do not match).
    #[arg(long)]
    pub times: Option<std::path::PathBuf>,
    /// Exposure times in natural file-name order, comma-separated.
    #[arg(long, value_delimiter = ',')]
    pub exposures: Option<Vec<f64>>,
    /// Fit options as JSON (`ResponseParams`).
    #[arg(long)]
    pub options: Option<String>,
}

impl Kind for PhotometricResponse {
    const NAME: &'static str = "photometric_response";
    const SCHEMA: &'static str = "caliper.photometric/v1";
    const DATASET: DatasetKind = DatasetKind::Images;
    const DESCRIPTION: &'static str = "Camera response (EMoR, monotone) from a bracketed stack of a static scene with exposure times; DSO pcalib.txt.";
    const EXPORTS: &'static [Export] = super::EXPORTS;
    type Params = ResponseJobParams;
    type Cli = ResponseArgs;

    fn check(p: &mut ResponseJobParams) -> Result<(), ParamError> {
        p.exposure_times.validate("exposure_times")?;
        p.options
            .validate()
            .map_err(|e| ParamError::from_core("options", e))
    }

    fn cli_params(a: &ResponseArgs, ctx: &CliContext<'_>) -> Result<Value, RunError> {
        let times = match (&a.times, &a.exposures) {
            (Some(_), Some(_)) => {
                return Err(RunError::Input(
                    "give --times or --exposures, not both".into(),
                ));
            }
            (None, None) => {
                return Err(RunError::Input(
                    "photometric-response needs exposure times: --times FILE or --exposures a,b,c"
                        .into(),
                ));
            }
            (None, Some(e)) => json!(e),
            (Some(path), None) => times_file(path, ctx)?,
        };
        let mut params = json!({"exposure_times": times});
        if let Some(o) = &a.options {
            params["options"] = crate::jobs::kind::json_flag("options", o)?;
        }
        Ok(params)
    }

    fn run(
        &self,
        p: ResponseJobParams,
        input: &JobInput,
        progress: &dyn Progress,
    ) -> Result<JobOutput, JobError> {
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

/// Exposure times from a DSO `times.txt`: by image name when its ids name the images,
/// otherwise in image order.
fn times_file(path: &std::path::Path, ctx: &CliContext<'_>) -> Result<Value, RunError> {
    let text = std::fs::read_to_string(path)?;
    let entries =
        dso::read_times(&text).map_err(|e| RunError::Input(format!("{}: {e}", path.display())))?;
    let images: Vec<String> = crate::offline::expand(ctx.inputs)?
        .iter()
        .filter_map(|(p, _)| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .collect();
    let stems: std::collections::HashMap<String, String> = images
        .iter()
        .map(|n| (crate::jobs::stem(n).to_string(), n.clone()))
        .collect();
    Ok(if entries.iter().all(|e| stems.contains_key(&e.id)) {
        let map: serde_json::Map<String, Value> = entries
            .iter()
            .filter_map(|e| stems.get(&e.id).map(|n| (n.clone(), json!(e.exposure_ms))))
            .collect();
        Value::Object(map)
    } else {
        json!(entries.iter().map(|e| e.exposure_ms).collect::<Vec<_>>())
    })
}
