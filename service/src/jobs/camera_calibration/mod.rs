//! `camera_calibration`: chessboard images → intrinsics and distortion with diagnostics.
//!
//! A video dataset (one clip) goes through [`clip`]: the views are chosen among its frames,
//! then solved the same way.
//!
//! Per image: decode, score blur (Laplacian variance, the foundation's measure), detect the
//! board. Then one joint solve over every usable view (`caliper_core::calib`), coverage of the
//! image by the observed corners, and three SVG artifacts. Frames much blurrier than the set
//! are left out of the solve (with the reason) because motion-blurred corners bias it.

use caliper_core::Progress;
use caliper_core::board::{TargetOptions, TargetSpec, detect_target};
use caliper_core::calib::report::{coverage, coverage_svg, residuals_svg, view_rms_svg};
use caliper_core::calib::{
    BoardGeometry, CalibOptions, CornerObservation, ModelKind, PlanarTarget, ViewObservations,
    calibrate,
};
use caliper_core::io::{ImageLimits, decode_gray8};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};
use utoipa::ToSchema;

use clap::Args;

use super::{
    Artifact, CliContext, Export, JobError, JobInput, JobOutput, Kind, ParamError, RunError,
};
use crate::store::DatasetKind;

mod clip;
pub use clip::ClipParams;

/// Unit of `board.square`; recorded in the document so extrinsics can be read in metres.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum LengthUnit {
    #[default]
    M,
    Cm,
    Mm,
    In,
    /// Board squares (when the size is unknown): translations come out in squares.
    Squares,
}

/// The calibration board: a chessboard given by its inner corners.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct BoardParams {
    /// Inner corners per row (OpenCV `patternSize.width`), e.g. 9.
    pub cols: usize,
    /// Inner corners per column, e.g. 6.
    pub rows: usize,
    /// Side of one square, in `unit`.
    pub square: f64,
    /// Unit of `square` (default `m`).
    #[serde(default)]
    pub unit: LengthUnit,
}

/// How blurred frames are treated.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields, default)]
pub struct BlurPolicy {
    /// Leave out frames much blurrier than the set (default true).
    pub exclude: bool,
    /// A frame is left out when its Laplacian variance is below this share of the set's
    /// median (default 0.2): relative, because absolute thresholds depend on the content.
    pub min_relative_sharpness: f64,
}

impl Default for BlurPolicy {
    fn default() -> Self {
        Self {
            exclude: true,
            min_relative_sharpness: 0.2,
        }
    }
}

fn default_model() -> ModelKind {
    ModelKind::PinholeRadTan
}

/// Parameters of `camera_calibration`.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"board": {"cols": 9, "rows": 6, "square": 0.025, "unit": "m"}, "model": "pinhole_radtan"}))]
pub struct CameraCalibParams {
    /// A chessboard (inner corners, square size, unit). Give this or `target`.
    #[serde(default)]
    pub board: Option<BoardParams>,
    /// Any target, described as for every job (`{"type": "chessboard" | "charuco" |
    /// "aprilgrid", …}`); partial views of ChArUco boards and AprilGrids count. Sizes in the
    /// unit translations should come out in. Give this or `board`.
    #[serde(default)]
    pub target: Option<TargetSpec>,
    /// `pinhole_radtan` (default; OpenCV k1 k2 p1 p2 k3), `kannala_brandt` (OpenCV fisheye
    /// k1..k4) or `double_sphere` (lenses near or past 180°).
    #[serde(default = "default_model")]
    pub model: ModelKind,
    /// Fixed parameters, robust loss and outlier rejection.
    #[serde(default)]
    pub options: CalibOptions,
    /// Treatment of blurred frames.
    #[serde(default)]
    pub blur: BlurPolicy,
    /// For a video dataset: how many frames are searched and how views are chosen.
    #[serde(default)]
    pub clip: ClipParams,
    /// Target detection settings, e.g. `{"chessboard": {"light_correction": true}}` to divide
    /// out vignetting or side light measured on the board before the sub-pixel fit.
    #[serde(default)]
    pub detection: TargetOptions,
}

/// What happened to one image.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct ImageOutcome {
    name: String,
    width: u32,
    height: u32,
    laplacian_variance: f64,
    detected: bool,
    corners: usize,
    /// Why the image is not in the solve (no board, blurred).
    #[serde(skip_serializing_if = "Option::is_none")]
    excluded: Option<String>,
    #[serde(skip)]
    points: Vec<CornerObservation>,
}

/// The `camera_calibration` job kind.
pub struct CameraCalibration;

/// Flags of `caliper run camera-calibration`.
#[derive(Debug, Clone, Args)]
pub struct CameraCalibrationArgs {
    /// Inner corners, COLSxROWS (e.g. 9x6), with `--square`; or give `--target`.
    #[arg(long)]
    pub board: Option<String>,
    /// Square side, in `--unit`.
    #[arg(long)]
    pub square: Option<f64>,
    /// The target as JSON instead of `--board`, e.g.
    /// '{"type": "charuco", "squares_x": 5, "squares_y": 7, "square": 0.04, "marker": 0.02, "dictionary": "DICT_6X6_250"}'.
    #[arg(long)]
    pub target: Option<String>,
    /// Unit of `--square`: m, cm, mm, in, squares [default: m].
    #[arg(long)]
    pub unit: Option<String>,
    /// pinhole_radtan, kannala_brandt or double_sphere [default: pinhole_radtan].
    #[arg(long)]
    pub model: Option<String>,
    /// Calibration options as JSON (see the `CalibOptions` schema), e.g. '{"fix_k3": true}'.
    #[arg(long)]
    pub options: Option<String>,
}

impl Kind for CameraCalibration {
    const NAME: &'static str = "camera_calibration";
    const SCHEMA: &'static str = "caliper.camera/v1";
    const DATASET: DatasetKind = DatasetKind::Images;
    const ALSO_VIDEO: bool = true;
    const DESCRIPTION: &'static str = "Calibrate a camera (pinhole + Brown-Conrady, Kannala-Brandt fisheye, double sphere) from target images or a video clip, with per-parameter uncertainty, coverage and residual diagnostics.";
    const EXPORTS: &'static [Export] = crate::exports::CAMERA_EXPORTS;
    type Params = CameraCalibParams;
    type Cli = CameraCalibrationArgs;

    fn check(p: &mut CameraCalibParams) -> Result<(), ParamError> {
        check_board_or_target(p.board.as_ref(), p.target.as_ref())?;
        p.detection
            .validate()
            .map_err(|e| ParamError::from_core("detection", e))?;
        p.options
            .validate(p.model)
            .map_err(|e| ParamError::from_core("", e))?;
        if !(p.blur.min_relative_sharpness.is_finite()
            && (0.0..1.0).contains(&p.blur.min_relative_sharpness))
        {
            return Err(ParamError::new(
                "blur.min_relative_sharpness",
                "must be in [0, 1)",
            ));
        }
        p.clip.check(p)
    }

    fn cli_params(a: &CameraCalibrationArgs, _: &CliContext<'_>) -> Result<Value, RunError> {
        let mut params = board_or_target_flags(a.board.as_deref(), a.square, a.target.as_deref())?;
        if let Some(u) = &a.unit {
            params["board"]["unit"] = json!(u);
        }
        if let Some(m) = &a.model {
            params["model"] = json!(m);
        }
        if let Some(o) = &a.options {
            params["options"] = crate::jobs::kind::json_flag("options", o)?;
        }
        Ok(params)
    }

    fn run(
        &self,
        p: CameraCalibParams,
        input: &JobInput,
        progress: &dyn Progress,
    ) -> Result<JobOutput, JobError> {
        if let Some(f) = super::spool::single_clip(input) {
            return clip::run_clip(&p, input, f, progress);
        }
        let board = target_of(&p);
        let limits = ImageLimits::default();
        let total = input.files.len() as u64;
        let done = std::sync::atomic::AtomicU64::new(0);
        let detect_opts = p.detection.clone();
        let outcomes: Vec<Result<ImageOutcome, JobError>> = input
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
                let lap = caliper_core::blur::laplacian_variance(&gray);
                let det = detect_target(&gray, &board, &detect_opts);
                let (detected, points, excluded) = match det.reason {
                    None if !det.corners.is_empty() => (true, det.corners, None),
                    reason => (
                        false,
                        Vec::new(),
                        Some(format!("no board: {}", reason.unwrap_or_default())),
                    ),
                };
                let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                progress.report("detecting", n, total);
                Ok(ImageOutcome {
                    name: f.name.clone(),
                    width: gray.width,
                    height: gray.height,
                    laplacian_variance: lap,
                    detected,
                    corners: points.len(),
                    excluded,
                    points,
                })
            })
            .collect();
        let mut images = outcomes.into_iter().collect::<Result<Vec<_>, _>>()?;
        let (w, h) = match images.first() {
            Some(i) => (i.width, i.height),
            None => return Err(permanent("invalid_input", "the dataset has no images")),
        };
        if let Some(odd) = images.iter().find(|i| (i.width, i.height) != (w, h)) {
            return Err(permanent(
                "invalid_input",
                format!(
                    "images differ in size: {} is {}×{}, {} is {w}×{h}; one camera, one resolution",
                    odd.name, odd.width, odd.height, images[0].name
                ),
            ));
        }
        apply_blur_policy(&mut images, &p.blur);
        let used: Vec<&ImageOutcome> = images.iter().filter(|i| i.excluded.is_none()).collect();
        if used.len() < caliper_core::calib::MIN_VIEWS {
            return Err(permanent(
                "no_solution",
                format!(
                    "{} of {} images have a usable {}; at least {} are needed",
                    used.len(),
                    images.len(),
                    PlanarTarget::describe(&board),
                    caliper_core::calib::MIN_VIEWS
                ),
            ));
        }
        let observations: Vec<ViewObservations> = used
            .iter()
            .map(|i| ViewObservations {
                name: i.name.clone(),
                corners: i.points.clone(),
            })
            .collect();
        let detected = images.iter().filter(|i| i.detected).count();
        let evidence = Evidence {
            looked_at: images.len(),
            detected,
            images: json!(images),
            clip: None,
        };
        solve_and_document(&p, &board, &observations, (w, h), evidence, progress)
    }
}

/// What the views came from, for the document.
pub(super) struct Evidence {
    /// Images (or searched frames) looked at.
    pub looked_at: usize,
    /// Of those, with a board.
    pub detected: usize,
    /// Per image (or frame): what happened to it.
    pub images: Value,
    /// For a clip: the clip, its frames and the selection.
    pub clip: Option<Value>,
}

/// The solve, the diagnostics and the document: the same for stills and clips.
pub(super) fn solve_and_document(
    p: &CameraCalibParams,
    board: &TargetSpec,
    observations: &[ViewObservations],
    (w, h): (u32, u32),
    evidence: Evidence,
    progress: &dyn Progress,
) -> Result<JobOutput, JobError> {
    progress.report("solving", 0, 1);
    let calib = calibrate(observations, board, p.model, (w, h), &p.options, progress)?;
    progress.report("solving", 1, 1);
    let cov = coverage(observations, &calib, 16, 12);
    let artifacts = vec![
        Artifact::svg("residuals.svg", residuals_svg(observations, &calib)),
        Artifact::svg("view_rms.svg", view_rms_svg(&calib)),
        Artifact::svg("coverage.svg", coverage_svg(&cov, calib.image_size)),
    ];
    let mut quality = json!({
        "rms": calib.rms,
        "rms_all": calib.rms_all,
        "sigma": calib.sigma,
        "images": evidence.looked_at,
        "boards_detected": evidence.detected,
        "views_used": calib.views.iter().filter(|v| v.used).count(),
        "coverage": cov.fraction,
        "projection_uncertainty_px": calib.projection_uncertainty.iter().map(|u| u.std_major).fold(0.0f64, f64::max),
    });
    let mut parameters = json!({
        "camera": calib.camera,
        "image_size": calib.image_size,
        "board": p.board,
        "target": board,
        "calibration": calib,
        "coverage": cov,
        "images": evidence.images,
        "observations": observations,
    });
    if let Some(clip) = evidence.clip {
        quality["frames_decoded"] = clip["frames_decoded"].clone();
        parameters["clip"] = clip;
    }
    Ok(JobOutput {
        parameters,
        quality,
        artifacts,
    })
}

/// The target of the parameters (`board` is a chessboard target).
pub(super) fn target_of(p: &CameraCalibParams) -> TargetSpec {
    match (&p.target, &p.board) {
        (Some(t), _) => t.clone(),
        (None, Some(b)) => b.target(),
        // `check` refuses parameters with neither.
        (None, None) => TargetSpec::Chessboard {
            cols: 0,
            rows: 0,
            square: 0.0,
        },
    }
}

impl BoardParams {
    /// The board as a target description.
    pub fn target(&self) -> TargetSpec {
        TargetSpec::Chessboard {
            cols: self.cols,
            rows: self.rows,
            square: self.square,
        }
    }

    /// The board as core describes it (the unit only labels the document).
    pub fn geometry(&self) -> BoardGeometry {
        BoardGeometry {
            cols: self.cols,
            rows: self.rows,
            square: self.square,
        }
    }
}

/// `--board COLSxROWS` of the CLI.
pub(super) fn board_flag(board: &str) -> Result<(usize, usize), RunError> {
    board
        .split_once(['x', 'X'])
        .and_then(|(c, r)| {
            Some((
                c.trim().parse::<usize>().ok()?,
                r.trim().parse::<usize>().ok()?,
            ))
        })
        .ok_or_else(|| RunError::Input(format!("--board must be COLSxROWS, got {board:?}")))
}

fn permanent(code: &'static str, message: impl Into<String>) -> JobError {
    JobError::Permanent {
        code,
        message: message.into(),
    }
}

/// Mark frames whose Laplacian variance is below `min_relative_sharpness` × the median of
/// the frames with a board.
fn apply_blur_policy(images: &mut [ImageOutcome], policy: &BlurPolicy) {
    if !policy.exclude {
        return;
    }
    let mut lv: Vec<f64> = images
        .iter()
        .filter(|i| i.detected)
        .map(|i| i.laplacian_variance)
        .collect();
    if lv.len() < 3 {
        return;
    }
    lv.sort_by(f64::total_cmp);
    let median = lv[lv.len() / 2];
    let cut = policy.min_relative_sharpness * median;
    for i in images
        .iter_mut()
        .filter(|i| i.detected && i.excluded.is_none())
    {
        if i.laplacian_variance < cut {
            i.excluded = Some(format!(
                "blurred: Laplacian variance {:.1} is below {:.0} % of the set's median {:.1}",
                i.laplacian_variance,
                100.0 * policy.min_relative_sharpness,
                median
            ));
        }
    }
}

/// `board` or `target`, exactly one, valid: the check every board-reading kind makes.
pub(super) fn check_board_or_target(
    board: Option<&BoardParams>,
    target: Option<&TargetSpec>,
) -> Result<(), ParamError> {
    match (board, target) {
        (Some(b), None) => b
            .geometry()
            .validate()
            .map_err(|e| ParamError::from_core("", e)),
        (None, Some(t)) => t.validate().map_err(|e| ParamError::from_core("target", e)),
        _ => Err(ParamError::new(
            "board",
            "give either `board` (a chessboard) or `target` (any target), not both",
        )),
    }
}

/// The `board`/`target` parameters of the CLI flags `--board COLSxROWS --square S` or
/// `--target JSON`.
pub(super) fn board_or_target_flags(
    board: Option<&str>,
    square: Option<f64>,
    target: Option<&str>,
) -> Result<Value, RunError> {
    match (board, square, target) {
        (Some(b), Some(square), None) => {
            let (cols, rows) = board_flag(b)?;
            Ok(json!({"board": {"cols": cols, "rows": rows, "square": square}}))
        }
        (None, None, Some(t)) => Ok(json!({"target": crate::jobs::kind::json_flag("target", t)?})),
        _ => Err(RunError::Input(
            "give --board COLSxROWS with --square, or --target JSON".into(),
        )),
    }
}
