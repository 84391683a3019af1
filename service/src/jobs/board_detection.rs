//! `board_detection`: what an operator checks before a capture session. Per image, the target's
//! corners found with their ids, the markers decoded, a reason when nothing is found, warnings
//! (duplicate ids, markers of another board), and an overlay PNG with the corners drawn on the
//! image. Works for every target (`chessboard`, `charuco`, `aprilgrid`).

use caliper_core::Progress;
use caliper_core::board::{TargetDetection, TargetOptions, TargetSpec, detect_target};
use caliper_core::io::{Gray, ImageLimits, decode_gray8};
use clap::Args;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};
use utoipa::ToSchema;

use super::{
    Artifact, CliContext, Export, JobError, JobInput, JobOutput, Kind, ParamError, RunError,
};
use crate::store::DatasetKind;

/// Parameters of `board_detection`.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"target": {"type": "charuco", "squares_x": 5, "squares_y": 7, "square": 0.04, "marker": 0.02, "dictionary": "DICT_6X6_250"}}))]
pub struct BoardDetectionParams {
    /// The target, described as for every job.
    pub target: TargetSpec,
    /// Detector settings.
    #[serde(default)]
    pub options: TargetOptions,
    /// Write an overlay PNG per image (default true).
    #[serde(default = "yes")]
    pub overlays: bool,
}

fn yes() -> bool {
    true
}

/// The `board_detection` job kind.
pub struct BoardDetection;

/// Flags of `caliper run board-detection`.
#[derive(Debug, Clone, Args)]
pub struct BoardDetectionArgs {
    /// The target as JSON, e.g. '{"type": "chessboard", "cols": 9, "rows": 6, "square": 0.025}'.
    #[arg(long)]
    pub target: String,
}

/// One image's detection, as the document lists it.
#[derive(Debug, Serialize)]
struct ImageResult {
    name: String,
    width: u32,
    height: u32,
    corners_found: usize,
    #[serde(flatten)]
    detection: TargetDetection,
}

impl Kind for BoardDetection {
    const NAME: &'static str = "board_detection";
    const SCHEMA: &'static str = "caliper.board_detection/v1";
    const DATASET: DatasetKind = DatasetKind::Images;
    const DESCRIPTION: &'static str = "Find a calibration target (chessboard, ChArUco, AprilGrid) in each image: corners with ids, markers decoded, the reason when nothing is found, and an overlay PNG.";
    const EXPORTS: &'static [Export] = &[];
    type Params = BoardDetectionParams;
    type Cli = BoardDetectionArgs;

    fn check(p: &mut BoardDetectionParams) -> Result<(), ParamError> {
        p.target
            .validate()
            .map_err(|e| ParamError::from_core("target", e))?;
        p.options
            .validate()
            .map_err(|e| ParamError::from_core("options", e))
    }

    fn cli_params(a: &BoardDetectionArgs, _: &CliContext<'_>) -> Result<Value, RunError> {
        Ok(json!({"target": crate::jobs::kind::json_flag("target", &a.target)?}))
    }

    fn run(
        &self,
        p: BoardDetectionParams,
        input: &JobInput,
        progress: &dyn Progress,
    ) -> Result<JobOutput, JobError> {
        let limits = ImageLimits::default();
        let total = input.files.len() as u64;
        let done = std::sync::atomic::AtomicU64::new(0);
        let results: Vec<Result<(ImageResult, Option<Artifact>), JobError>> = input
            .files
            .par_iter()
            .map(|f| {
                progress.check()?;
                let bytes = (input.load)(f).map_err(|e| {
                    JobError::Transient(format!("storage: cannot read {}: {e}", f.name))
                })?;
                let gray = decode_gray8(&bytes, &limits).map_err(|e| {
                    JobError::from(caliper_core::CoreError::input(format!("{}: {e}", f.name)))
                })?;
                let detection = detect_target(&gray, &p.target, &p.options);
                let overlay = if p.overlays {
                    Some(Artifact {
                        name: format!("{}.overlay.png", f.name.replace('/', "_")),
                        media_type: "image/png".into(),
                        data: overlay_png(&gray, &detection)?.into(),
                    })
                } else {
                    None
                };
                let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                progress.report("detecting", n, total);
                Ok((
                    ImageResult {
                        name: f.name.clone(),
                        width: gray.width,
                        height: gray.height,
                        corners_found: detection.corners.len(),
                        detection,
                    },
                    overlay,
                ))
            })
            .collect();
        let mut images = Vec::with_capacity(results.len());
        let mut artifacts = Vec::new();
        for r in results {
            let (img, art) = r?;
            images.push(img);
            artifacts.extend(art);
        }
        let with_corners = images.iter().filter(|i| i.corners_found > 0).count();
        let corners: usize = images.iter().map(|i| i.corners_found).sum();
        let quality = json!({
            "images": images.len(),
            "images_with_corners": with_corners,
            "corners": corners,
            "corners_per_image": if images.is_empty() { 0.0 } else { corners as f64 / images.len() as f64 },
            "target_corners": p.target.num_corners(),
        });
        let parameters = json!({
            "target": p.target,
            "images": images,
        });
        Ok(JobOutput {
            parameters,
            quality,
            artifacts,
        })
    }
}

/// The image in grey with every corner found marked by a cross (green) and, when nothing was
/// found, a red frame.
fn overlay_png(g: &Gray, d: &TargetDetection) -> Result<Vec<u8>, JobError> {
    let (w, h) = (g.width, g.height);
    let mut img = image::RgbImage::from_fn(w, h, |x, y| {
        let v = g.data[(y * w + x) as usize] / 2 + 64;
        image::Rgb([v, v, v])
    });
    let mut put = |x: i64, y: i64, c: [u8; 3]| {
        if x >= 0 && y >= 0 && (x as u32) < w && (y as u32) < h {
            img.put_pixel(x as u32, y as u32, image::Rgb(c));
        }
    };
    let arm = (w.min(h) / 120).clamp(3, 12) as i64;
    for c in &d.corners {
        let (x, y) = (c.pixel[0].round() as i64, c.pixel[1].round() as i64);
        for k in -arm..=arm {
            put(x + k, y, [0, 230, 0]);
            put(x, y + k, [0, 230, 0]);
        }
    }
    if d.corners.is_empty() {
        for t in 0..4i64 {
            for x in 0..i64::from(w) {
                put(x, t, [220, 0, 0]);
                put(x, i64::from(h) - 1 - t, [220, 0, 0]);
            }
            for y in 0..i64::from(h) {
                put(t, y, [220, 0, 0]);
                put(i64::from(w) - 1 - t, y, [220, 0, 0]);
            }
        }
    }
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .map_err(|e| JobError::Permanent {
            code: "internal_error",
            message: format!("png: {e}"),
        })?;
    Ok(out.into_inner())
}
