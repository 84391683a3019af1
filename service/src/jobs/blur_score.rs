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
    /// With rule either/both/laplacian: blurred if the Laplacian variance is below this
    /// [default: 100].
    #[arg(long)]
    pub laplacian_threshold: Option<f64>,
    /// With rule either/both/beta: blurred if β is above this [default: 0.6].
    #[arg(long)]
    pub beta_threshold: Option<f64>,
    /// With rule combined: blurred if the combined score (0–1) is above this [default: 0.6].
    #[arg(long)]
    pub blur_threshold: Option<f64>,
    /// Which scores decide: combined, either, both, laplacian or beta [default: combined].
    #[arg(long)]
    pub rule: Option<String>,
}

impl Kind for BlurScore {
    const NAME: &'static str = "blur_score";
    const SCHEMA: &'static str = "caliper.blur_score/v1";
    const DATASET: DatasetKind = DatasetKind::Images;
    const ALSO_VIDEO: bool = true;
    const DESCRIPTION: &'static str = "Score every image of a set, or every frame of a video clip, for blur (Laplacian variance, singular-value feature), flag blurred ones, rank the set sharpest first and pick a clip's sharpest frames spread over time.";
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
        put("blur_threshold", a.blur_threshold.map(Value::from));
        put("rule", a.rule.clone().map(Value::from));
        Ok(Value::Object(params))
    }

    fn run(
        &self,
        params: BlurParams,
        input: &JobInput,
        progress: &dyn Progress,
    ) -> Result<JobOutput, JobError> {
        if super::spool::single_clip(input).is_some() {
            return score_video(&params, input, progress);
        }
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
        let mut artifacts = vec![Artifact::svg("scores.svg", svg)];
        // Blur maps as heat maps over the image (`NAME.blurmap.png`): where the frame is sharp.
        let mut seen = std::collections::HashSet::new();
        for (i, (f, score)) in input.files.iter().zip(&report.images).enumerate() {
            progress.check()?;
            let Some(map) = &score.map else { continue };
            let bytes = (input.load)(f).map_err(|e| {
                JobError::Transient(format!("storage: cannot read {}: {e}", f.name))
            })?;
            let gray = caliper_core::io::decode_gray8(&bytes, &limits)?;
            let mut name = format!("{}.blurmap.png", super::stem(super::base_name(&f.name)));
            if !seen.insert(name.clone()) {
                name = format!("{}-{i}.blurmap.png", super::stem(super::base_name(&f.name)));
            }
            artifacts.push(Artifact {
                name,
                media_type: "image/png".into(),
                data: caliper_core::blur::render_map_png(&gray, map)?.into(),
            });
        }
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
            artifacts,
        })
    }
}

/// A video dataset: every frame scored on its luma plane, the sharpest picked (exported as PNG
/// artifacts), and a time-series plot.
fn score_video(
    params: &BlurParams,
    input: &JobInput,
    progress: &dyn Progress,
) -> Result<JobOutput, JobError> {
    use caliper_core::video::{FrameFormat, FrameOptions, FrameReader, VideoLimits};
    let mut clip = super::spool::SpooledClip::new(input, &input.files[0])?;
    let limits = VideoLimits::default();
    let report = caliper_core::blur::clip::score_clip(clip.reader()?, &limits, params, progress)?;
    // The picked frames as PNG: a second pass that converts only those.
    let wanted: std::collections::BTreeSet<u64> = report
        .selected
        .iter()
        .map(|&i| report.frames[i].index)
        .collect();
    let mut artifacts = Vec::new();
    let options = FrameOptions {
        format: FrameFormat::Gray,
        indices: Some(wanted.clone()),
        ..FrameOptions::default()
    };
    let mut reader = FrameReader::open(clip.reader()?, &limits, options)
        .map_err(|e| JobError::from(caliper_core::CoreError::input(e.to_string())))?;
    while let Some(Ok(frame)) = reader.next_frame() {
        progress.check()?;
        if !wanted.contains(&frame.index) {
            continue;
        }
        let mut png = std::io::Cursor::new(Vec::new());
        frame
            .image
            .into_luma()
            .write_to(&mut png, image::ImageFormat::Png)
            .map_err(|e| JobError::Permanent {
                code: "internal_error",
                message: format!("png: {e}"),
            })?;
        artifacts.push(Artifact {
            name: format!("frame_{:06}.png", frame.index),
            media_type: "image/png".into(),
            data: png.into_inner().into(),
        });
    }
    artifacts.push(Artifact::svg("frames.svg", clip_svg(&report, params)));
    let quality = json!({
        "frames": report.frames.len(),
        "blurred": report.blurred_count,
        "selected": report.selected.len(),
        "laplacian_variance_median": median(report.frames.iter().map(|f| f.laplacian_variance).collect()),
    });
    Ok(JobOutput {
        parameters: to_value(&report)?,
        quality,
        artifacts,
    })
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Laplacian variance over time (log scale), the threshold, and the picked frames.
fn clip_svg(r: &caliper_core::blur::clip::ClipReport, params: &BlurParams) -> String {
    let (w, h, m) = (800.0, 300.0, 40.0);
    let t_max = r.frames.iter().map(|f| f.pts_s).fold(1e-9, f64::max);
    let ly = |v: f64| v.max(1e-3).log10();
    let (lo, hi) = r.frames.iter().fold(
        (
            ly(params.laplacian_threshold),
            ly(params.laplacian_threshold),
        ),
        |(a, b), f| {
            (
                a.min(ly(f.laplacian_variance)),
                b.max(ly(f.laplacian_variance)),
            )
        },
    );
    let span = (hi - lo).max(1e-6);
    let x = |t: f64| m + (w - 2.0 * m) * t / t_max;
    let y = |v: f64| h - m - (h - 2.0 * m) * (ly(v) - lo) / span;
    let points: Vec<String> = r
        .frames
        .iter()
        .map(|f| format!("{:.1},{:.1}", x(f.pts_s), y(f.laplacian_variance)))
        .collect();
    let mut svg = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" font-family=\"sans-serif\" font-size=\"12\">\
         <text x=\"{m}\" y=\"20\">Laplacian variance per frame (log scale) over {t_max:.1} s; picked frames in green</text>\
         <polyline fill=\"none\" stroke=\"#3366cc\" stroke-width=\"1\" points=\"{}\"/>\
         <line x1=\"{m}\" x2=\"{}\" y1=\"{:.1}\" y2=\"{:.1}\" stroke=\"#cc3333\" stroke-dasharray=\"4 3\"/>",
        points.join(" "),
        w - m,
        y(params.laplacian_threshold),
        y(params.laplacian_threshold)
    );
    for &i in &r.selected {
        let f = &r.frames[i];
        svg.push_str(&format!(
            "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"4\" fill=\"#22aa22\"/>",
            x(f.pts_s),
            y(f.laplacian_variance)
        ));
    }
    svg.push_str("</svg>");
    svg
}
