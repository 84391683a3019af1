//! `rig_calibration`: synchronised images of 2..N cameras (one folder per camera) → every
//! camera's intrinsics, the extrinsics `T_cam_i_cam0`, rectification and epipolar error.
//!
//! Frames are paired across cameras by natural name order (the n-th image of every folder is
//! one frame) or by a timestamp in the file names. Detection runs over all images in parallel;
//! the solve is `caliper_core::rig::calibrate_rig`. Artifacts: a rectified preview of each pair
//! (cam0, cam i) with horizontal guide lines, on which epipolar lines must be rows.

use std::collections::BTreeMap;

use caliper_core::Progress;
use caliper_core::board::{TargetOptions, TargetSpec, detect_target};
use caliper_core::calib::{CornerObservation, ModelKind, PlanarTarget, ViewObservations};
use caliper_core::camera::Camera;
use caliper_core::io::{Gray, ImageLimits, decode_gray8};
use caliper_core::rig::{RigCameraInput, RigOptions, calibrate_rig, rectify_gray};
use clap::Args;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};
use utoipa::ToSchema;

use super::camera_calibration::{BoardParams, board_or_target_flags, check_board_or_target};
use super::{
    Artifact, CliContext, Export, JobError, JobInput, JobOutput, Kind, ParamError, RunError,
};
use crate::store::DatasetKind;

mod pairing;

use pairing::{group, pair_by_order, pair_by_timestamp};

/// How images of different cameras are matched into frames.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Pairing {
    /// The n-th image of every folder (natural order: `2.png` before `10.png`) is frame n;
    /// every folder must hold the same number of images.
    #[default]
    Order,
    /// Images whose names carry the same timestamp (the longest digit run of the file stem,
    /// e.g. EuRoC's nanoseconds) form a frame; images without a partner in camera 0 are left
    /// out, with the reason.
    Timestamp,
}

/// Parameters of `rig_calibration`.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"board": {"cols": 9, "rows": 6, "square": 0.025, "unit": "m"}, "model": "pinhole_radtan"}))]
pub struct RigCalibParams {
    /// A chessboard. Give this or `target`.
    #[serde(default)]
    pub board: Option<BoardParams>,
    /// Any target (`{"type": "chessboard" | "charuco" | "aprilgrid", …}`); with ChArUco and
    /// AprilGrid, views where a camera sees part of the board count. Give this or `board`.
    #[serde(default)]
    pub target: Option<TargetSpec>,
    /// Model of every camera (default `pinhole_radtan`); see `models` for one per camera.
    #[serde(default = "default_model")]
    pub model: ModelKind,
    /// Model per camera folder, overriding `model` (e.g. `{"cam1": "kannala_brandt"}`).
    #[serde(default)]
    pub models: BTreeMap<String, ModelKind>,
    /// Camera folders to use, in order (the first is the reference); default: every folder in
    /// natural order.
    #[serde(default)]
    pub cameras: Option<Vec<String>>,
    /// How images are matched into frames.
    #[serde(default)]
    pub pairing: Pairing,
    /// With `pairing: timestamp`: largest difference between matched timestamps, in the
    /// names' own unit (default 0: equal).
    #[serde(default)]
    pub timestamp_tolerance: u64,
    /// Intrinsics to keep fixed, per camera folder, as a camera object of an earlier document
    /// (`parameters.camera` of a `caliper.camera/v1` document).
    #[serde(default)]
    pub fixed_intrinsics: BTreeMap<String, Camera>,
    /// Per-camera options, robust loss and outlier rejection.
    #[serde(default)]
    pub options: RigOptions,
}

fn default_model() -> ModelKind {
    ModelKind::PinholeRadTan
}

/// The `rig_calibration` job kind.
pub struct RigCalibration;

/// Flags of `caliper run rig-calibration` (inputs: one directory per camera, in order).
#[derive(Debug, Clone, Args)]
pub struct RigCalibrationArgs {
    /// Inner corners, COLSxROWS (e.g. 9x6), with `--square`; or give `--target`.
    #[arg(long)]
    pub board: Option<String>,
    /// Square side, in `--unit`.
    #[arg(long)]
    pub square: Option<f64>,
    /// The target as JSON instead of `--board` (see `board_detection`).
    #[arg(long)]
    pub target: Option<String>,
    /// Unit of `--square`: m, cm, mm, in, squares [default: m].
    #[arg(long)]
    pub unit: Option<String>,
    /// Model of every camera: pinhole_radtan, kannala_brandt or double_sphere.
    #[arg(long)]
    pub model: Option<String>,
    /// Pair frames by `order` (default) or `timestamp` in the file names.
    #[arg(long)]
    pub pairing: Option<String>,
    /// Rig options as JSON (see the `RigOptions` schema), e.g. '{"camera": {"fix_k3": true}}'.
    #[arg(long)]
    pub options: Option<String>,
}

/// What happened to one image.
#[derive(Debug, Clone, Serialize)]
struct ImageOutcome {
    name: String,
    camera: String,
    frame: Option<usize>,
    width: u32,
    height: u32,
    detected: bool,
    corners: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    reason: Option<String>,
}

impl Kind for RigCalibration {
    const NAME: &'static str = "rig_calibration";
    const SCHEMA: &'static str = "caliper.rig/v1";
    const DATASET: DatasetKind = DatasetKind::Images;
    const DESCRIPTION: &'static str = "Calibrate a stereo pair or multi-camera rig from synchronised chessboard images (one folder per camera): every camera's intrinsics, the extrinsics T_cam_i_cam0 with σ, rectification and epipolar error.";
    const EXPORTS: &'static [Export] = crate::exports::RIG_EXPORTS;
    type Params = RigCalibParams;
    type Cli = RigCalibrationArgs;

    fn check(p: &mut RigCalibParams) -> Result<(), ParamError> {
        check_board_or_target(p.board.as_ref(), p.target.as_ref())?;
        p.options
            .validate()
            .map_err(|e| ParamError::from_core("options", e))?;
        for m in std::iter::once(&p.model).chain(p.models.values()) {
            p.options
                .camera
                .validate(*m)
                .map_err(|e| ParamError::from_core("options.camera", e))?;
        }
        if p.options.camera.fix_aspect_ratio {
            return Err(ParamError::new(
                "options.camera.fix_aspect_ratio",
                "is not supported for rigs",
            ));
        }
        for (name, cam) in &p.fixed_intrinsics {
            // Re-validate through the model's constructor (finite, in its domain).
            ModelKind::of(cam)
                .camera(caliper_core::camera::CameraModel::params(cam.as_model()))
                .map_err(|e| ParamError::from_core(&format!("fixed_intrinsics.{name}"), e))?;
        }
        if let Some(c) = &p.cameras {
            if c.len() < 2 || c.len() > caliper_core::rig::MAX_CAMERAS {
                return Err(ParamError::new(
                    "cameras",
                    format!(
                        "name 2 to {} camera folders",
                        caliper_core::rig::MAX_CAMERAS
                    ),
                ));
            }
            let mut seen = std::collections::HashSet::new();
            if let Some(d) = c.iter().find(|n| !seen.insert(n.as_str())) {
                return Err(ParamError::new("cameras", format!("{d:?} is listed twice")));
            }
        }
        Ok(())
    }

    fn cli_params(a: &RigCalibrationArgs, ctx: &CliContext<'_>) -> Result<Value, RunError> {
        let mut params = board_or_target_flags(a.board.as_deref(), a.square, a.target.as_deref())?;
        if let Some(u) = &a.unit {
            params["board"]["unit"] = json!(u);
        }
        if let Some(m) = &a.model {
            params["model"] = json!(m);
        }
        if let Some(pr) = &a.pairing {
            params["pairing"] = json!(pr);
        }
        if let Some(o) = &a.options {
            params["options"] = crate::jobs::kind::json_flag("options", o)?;
        }
        // The camera order is the order of the directories on the command line.
        let dirs: Vec<String> = ctx
            .inputs
            .iter()
            .filter(|p| p.is_dir())
            .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .collect();
        if dirs.len() < 2 {
            return Err(RunError::Input(
                "give one directory per camera, e.g. `cam0/ cam1/`".into(),
            ));
        }
        params["cameras"] = json!(dirs);
        Ok(params)
    }

    fn run(
        &self,
        p: RigCalibParams,
        input: &JobInput,
        progress: &dyn Progress,
    ) -> Result<JobOutput, JobError> {
        let board: TargetSpec = match (&p.target, &p.board) {
            (Some(t), _) => t.clone(),
            (None, Some(b)) => b.target(),
            (None, None) => return Err(permanent("invalid_param", "no board or target")),
        };
        let (names, shots) = group(input, &p)?;
        let frames = match p.pairing {
            Pairing::Order => pair_by_order(&names, &shots)?,
            Pairing::Timestamp => pair_by_timestamp(&names, &shots, p.timestamp_tolerance)?,
        };
        let n_frames = frames.len();
        let limits = ImageLimits::default();
        let detect_opts = TargetOptions::default();
        let total = shots.len() as u64;
        let done = std::sync::atomic::AtomicU64::new(0);
        let frame_of: Vec<Option<usize>> = {
            let mut v = vec![None; shots.len()];
            for (f, row) in frames.iter().enumerate() {
                for s in row.iter().flatten() {
                    v[*s] = Some(f);
                }
            }
            v
        };
        type Detected = (ImageOutcome, Vec<CornerObservation>);
        let detected: Vec<Result<Detected, JobError>> = shots
            .par_iter()
            .enumerate()
            .map(|(k, s)| {
                progress.check()?;
                let f = &input.files[s.file];
                let gray = load_gray(input, s.file, &limits)?;
                let (points, reason) = if frame_of[k].is_none() {
                    (
                        Vec::new(),
                        Some("no matching frame in the other cameras".to_string()),
                    )
                } else {
                    let det = detect_target(&gray, &board, &detect_opts);
                    match det.reason {
                        None if !det.corners.is_empty() => (det.corners, None),
                        r => (
                            Vec::new(),
                            Some(format!("no board: {}", r.unwrap_or_default())),
                        ),
                    }
                };
                let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                progress.report("detecting", n, total);
                Ok((
                    ImageOutcome {
                        name: f.name.clone(),
                        camera: names[s.camera].clone(),
                        frame: frame_of[k],
                        width: gray.width,
                        height: gray.height,
                        detected: !points.is_empty(),
                        corners: points.len(),
                        reason,
                    },
                    points,
                ))
            })
            .collect();
        let detected = detected.into_iter().collect::<Result<Vec<_>, _>>()?;

        // Per camera: image size, views per frame.
        let mut inputs = Vec::with_capacity(names.len());
        for (c, name) in names.iter().enumerate() {
            let mine: Vec<usize> = (0..shots.len()).filter(|&k| shots[k].camera == c).collect();
            let (w, h) = (detected[mine[0]].0.width, detected[mine[0]].0.height);
            if let Some(&odd) = mine
                .iter()
                .find(|&&k| (detected[k].0.width, detected[k].0.height) != (w, h))
            {
                return Err(permanent(
                    "invalid_input",
                    format!(
                        "camera {name:?}: images differ in size: {} is {}×{}, {} is {w}×{h}",
                        detected[odd].0.name,
                        detected[odd].0.width,
                        detected[odd].0.height,
                        detected[mine[0]].0.name
                    ),
                ));
            }
            let mut views: Vec<Option<ViewObservations>> = vec![None; n_frames];
            for (f, row) in frames.iter().enumerate() {
                if let Some(k) = row[c]
                    && !detected[k].1.is_empty()
                {
                    views[f] = Some(ViewObservations {
                        name: detected[k].0.name.clone(),
                        corners: detected[k].1.clone(),
                    });
                }
            }
            if views.iter().all(Option::is_none) {
                return Err(permanent(
                    "no_solution",
                    format!(
                        "camera {name:?} never sees the {}",
                        PlanarTarget::describe(&board)
                    ),
                ));
            }
            let fixed = p.fixed_intrinsics.get(name).cloned();
            inputs.push(RigCameraInput {
                name: name.clone(),
                model: p.models.get(name).copied().unwrap_or(p.model),
                image_size: [w, h],
                views,
                fixed,
            });
        }
        if let Some(unknown) = p
            .fixed_intrinsics
            .keys()
            .chain(p.models.keys())
            .find(|k| !names.contains(k))
        {
            return Err(permanent(
                "invalid_param",
                format!("params names camera {unknown:?}, but the dataset's cameras are {names:?}"),
            ));
        }
        progress.report("solving", 0, 1);
        let rig = calibrate_rig(&inputs, &board, &p.options, progress)?;
        progress.report("solving", 1, 1);

        let mut artifacts = Vec::new();
        for pair in &rig.pairs {
            // The first frame where both cameras saw the board.
            let Some(f) = (0..n_frames)
                .find(|&f| inputs[pair.a].views[f].is_some() && inputs[pair.b].views[f].is_some())
            else {
                continue;
            };
            let (Some(ka), Some(kb)) = (frames[f][pair.a], frames[f][pair.b]) else {
                continue;
            };
            let ga = load_gray(input, shots[ka].file, &limits)?;
            let gb = load_gray(input, shots[kb].file, &limits)?;
            let r = &pair.rectification;
            let ra = rectify_gray(
                &ga,
                &rig.cameras[pair.a].camera,
                &r.rotation(false),
                &r.projection(false),
            );
            let rb = rectify_gray(
                &gb,
                &rig.cameras[pair.b].camera,
                &r.rotation(true),
                &r.projection(true),
            );
            artifacts.push(Artifact {
                name: format!("rectified_{}_{}.png", names[pair.a], names[pair.b]),
                media_type: "image/png".into(),
                data: preview_png(&ra, &rb, r.vertical)?.into(),
            });
        }
        let quality = json!({
            "rms": rig.rms,
            "epipolar_rms_px": rig.pairs.iter().map(|p| p.epipolar_rms_px).filter(|x| x.is_finite()).fold(0.0f64, f64::max),
            "cameras": rig.cameras.len(),
            "frames": n_frames,
            "frames_used": rig.frames.iter().filter(|f| f.used).count(),
            "baselines": rig.extrinsics.iter().skip(1).map(|e| e.baseline).collect::<Vec<_>>(),
        });
        let images: Vec<ImageOutcome> = detected.into_iter().map(|(o, _)| o).collect();
        let frame_files: Vec<Vec<Option<&str>>> = frames
            .iter()
            .map(|row| {
                row.iter()
                    .map(|k| k.map(|k| shots[k].name.as_str()))
                    .collect()
            })
            .collect();
        let parameters = json!({
            "cameras": rig.cameras.iter().map(|c| json!({"name": c.name, "camera": c.camera, "image_size": c.image_size})).collect::<Vec<_>>(),
            "extrinsics": rig.extrinsics,
            "board": p.board,
            "target": board,
            "rig": rig,
            "frames": frame_files,
            "images": images,
        });
        Ok(JobOutput {
            parameters,
            quality,
            artifacts,
        })
    }
}

fn permanent(code: &'static str, message: impl Into<String>) -> JobError {
    JobError::Permanent {
        code,
        message: message.into(),
    }
}

fn load_gray(input: &JobInput, file: usize, limits: &ImageLimits) -> Result<Gray, JobError> {
    let f = &input.files[file];
    let bytes = (input.load)(f)
        .map_err(|e| JobError::Transient(format!("storage: cannot read {}: {e}", f.name)))?;
    decode_gray8(&bytes, limits)
        .map_err(|e| JobError::from(caliper_core::CoreError::input(format!("{}: {e}", f.name))))
}

/// The two rectified images side by side (stacked for a vertical rig) with guide lines every
/// 32 px along the epipolar direction.
fn preview_png(a: &Gray, b: &Gray, vertical: bool) -> Result<Vec<u8>, JobError> {
    let (w, h) = (a.width, a.height);
    let (cw, ch) = if vertical {
        (w, 2 * h + 8)
    } else {
        (2 * w + 8, h)
    };
    let mut img = image::RgbImage::new(cw, ch);
    let (ox, oy) = if vertical { (0, h + 8) } else { (w + 8, 0) };
    for (g, x0, y0) in [(a, 0, 0), (b, ox, oy)] {
        for y in 0..g.height.min(h) {
            for x in 0..g.width.min(w) {
                let v = g.data[(y * g.width + x) as usize];
                img.put_pixel(x0 + x, y0 + y, image::Rgb([v, v, v]));
            }
        }
    }
    let line = image::Rgb([0u8, 200, 0]);
    if vertical {
        for x in (16..cw).step_by(32) {
            for y in 0..ch {
                img.put_pixel(x, y, line);
            }
        }
    } else {
        for y in (16..ch).step_by(32) {
            for x in 0..cw {
                img.put_pixel(x, y, line);
            }
        }
    }
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .map_err(|e| permanent("internal_error", format!("png: {e}")))?;
    Ok(out.into_inner())
}
