//! `blur_score`: Laplacian variance and the singular-value feature per image, a blurred
//! verdict, and the sharpest-first ranking of the set (science in `caliper_core::blur`).

use caliper_core::Progress;
use caliper_core::blur::{BlurParams, render_svg, score_images};
use serde_json::{Value, json};

use clap::Args;

use super::{
    Artifact, CliContext, JobError, JobInput, JobOutput, Kind, ParamError, RunError, to_value,
};
use crate::store::DatasetKind;

/// The `blur_score` job kind.
pub struct BlurScore;

/// Flags of `caliper run blur-score`.
#[derive(Debug, Clone, Args)]
pub struct BlurScoreArgs {
    /// Singular values in the numerator of β [default: 10].
    #[arg(long)]
    pub k: Option<usize>,
    /// Blurred if the Laplacian variance is below this [default: 100].
    #[arg(long)]
    pub laplacian_threshold: Option<f64>,
    /// Blurred if β is above this [default: 0.6].
    #[arg(long)]
    pub beta_threshold: Option<f64>,
    /// How the two verdicts combine: either, both, laplacian, beta [default: either].
    #[arg(long)]
    pub rule: Option<String>,
}

impl Kind for BlurScore {
    const NAME: &'static str = "blur_score";
    const SCHEMA: &'static str = "caliper.blur_score/v1";
    const DATASET: DatasetKind = DatasetKind::Images;
    const DESCRIPTION: &'static str = "Score every image of a set for blur (Laplacian variance, singular-value feature), flag blurred ones and rank the set sharpest first.";
    type Params = BlurParams;
    type Cli = BlurScoreArgs;

    fn check(p: &mut BlurParams) -> Result<(), ParamError> {
        p.validate().map_err(|e| ParamError::from_core("", e))
    }

    fn cli_params(a: &BlurScoreArgs, _: &CliContext<'_>) -> Result<Value, RunError> {
        let mut params = serde_json::Map::new();
        let mut put = |k: &str, v: Option<Value>| {
            if let Some(v) = v {
                params.insert(k.into(), v);
            }
        };
        put("k", a.k.map(Value::from));
        put(
            "laplacian_threshold",
            a.laplacian_threshold.map(Value::from),
        );
        put("beta_threshold", a.beta_threshold.map(Value::from));
        put("rule", a.rule.clone().map(Value::from));
        Ok(Value::Object(params))
    }

    fn run(
        &self,
        params: BlurParams,
        input: &JobInput,
        progress: &dyn Progress,
    ) -> Result<JobOutput, JobError> {
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
        let parameters = to_value(&report)?;
        Ok(JobOutput {
            parameters,
            quality,
            artifacts: vec![Artifact::svg("scores.svg", svg)],
        })
    }
}
