//! Monocular camera calibration from planar-board corners.
//!
//! The pipeline is Zhang's ("A flexible new technique for camera calibration", TPAMI 22(11),
//! 2000), with the refinements that mature tools (OpenCV `calibrateCamera`, Ceres, mrcal) add:
//!
//! 1. a homography per view by the normalised DLT, refined on the reprojection error
//!    ([`homography`]);
//! 2. a start for the camera that needs no guess: Zhang's closed-form intrinsics for the pinhole
//!    ([`zhang_intrinsics`], falling back to [`intrinsics_fixed_centre`]), and a focal-length
//!    search with an equidistant (or stereographic) start for the wide-angle models;
//! 3. a pose per view from the camera ([`estimate_pose`]);
//! 4. a joint Levenberg-Marquardt over intrinsics, distortion and every pose, the poses on
//!    SE(3), with a robust loss ([`crate::optim`]);
//! 5. outlier rejection (corners far beyond the robust residual spread, views far worse than the
//!    median view), each with its reason, and a re-solve;
//! 6. RMS recomputed from the final parameters, per-view and per-corner residuals, standard
//!    deviations of the intrinsics from `σ²·(JᵀJ)⁻¹` marginalised over the poses, and the
//!    resulting 1σ uncertainty of the projection at the image centre and corners (after mrcal's
//!    "projection uncertainty", here in its simplest form: a fixed ray in the camera frame).
//!
//! Board convention (OpenCV): inner corner `index = row·cols + col` sits at
//! `(col·square, row·square, 0)` in the board frame; poses are `T_cam_board`, reported as
//! OpenCV `rvec`/`tvec`.

mod homography;
mod init;
mod pnp;
mod problem;
pub mod report;
mod zhang;

#[cfg(test)]
mod tests;

use nalgebra::{DMatrix, Matrix2, Vector2, Vector3};
use serde::{Deserialize, Serialize};

pub use homography::{homography, homography_dlt, refine_homography, transfer};
pub use pnp::estimate_pose;
pub use zhang::{Intrinsics, intrinsics_fixed_centre, pose_from_homography, zhang_intrinsics};

use crate::camera::{Camera, CameraModel, DoubleSphere, KannalaBrandt, PinholeRadTan};
use crate::error::{CoreError, CoreResult};
use crate::lie::Se3;
use crate::optim::{
    LmOptions, RobustLoss, Termination, marginal_shared_covariance, solve as lm_solve,
};
use crate::progress::Progress;
use problem::{CalibProblem, ViewData};

/// Fewest corners a view needs to take part (a homography needs 4; 6 leaves some redundancy
/// to detect a bad view).
pub const MIN_CORNERS_PER_VIEW: usize = 6;
/// Fewest views a calibration needs (Zhang's closed form needs 2 without extra assumptions);
/// outlier rejection never goes below it.
pub const MIN_VIEWS: usize = 2;
/// MAD → σ for a normal distribution.
const MAD_TO_SIGMA: f64 = 1.482_602_218_505_602;

/// Which camera model to calibrate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum ModelKind {
    /// Pinhole with Brown-Conrady k1, k2, p1, p2, k3 ([`PinholeRadTan`]). Written
    /// `pinhole_rad_tan`; Kalibr's spelling `pinhole_radtan` is accepted too.
    #[serde(alias = "pinhole_radtan")]
    PinholeRadTan,
    /// Kannala-Brandt fisheye k1..k4 ([`KannalaBrandt`]).
    KannalaBrandt,
    /// Double sphere ξ, α ([`DoubleSphere`]).
    DoubleSphere,
}

impl ModelKind {
    /// Number of parameters of the model.
    pub fn num_params(&self) -> usize {
        match self {
            ModelKind::PinholeRadTan => 9,
            ModelKind::KannalaBrandt => 8,
            ModelKind::DoubleSphere => 6,
        }
    }

    /// A validated camera of this kind from its parameter vector.
    pub fn camera(&self, params: &[f64]) -> CoreResult<Camera> {
        Ok(match self {
            ModelKind::PinholeRadTan => PinholeRadTan::from_slice(params)?.into(),
            ModelKind::KannalaBrandt => KannalaBrandt::from_slice(params)?.into(),
            ModelKind::DoubleSphere => DoubleSphere::from_slice(params)?.into(),
        })
    }

    /// The kind of a camera.
    pub fn of(camera: &Camera) -> ModelKind {
        match camera {
            Camera::PinholeRadTan(_) => ModelKind::PinholeRadTan,
            Camera::KannalaBrandt(_) => ModelKind::KannalaBrandt,
            Camera::DoubleSphere(_) => ModelKind::DoubleSphere,
        }
    }
}

/// A chessboard's inner-corner grid.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct BoardGeometry {
    /// Inner corners per row.
    pub cols: usize,
    /// Inner corners per column.
    pub rows: usize,
    /// Corner spacing, in the unit the translations are reported in.
    pub square: f64,
}

impl BoardGeometry {
    /// Errors unless the grid is at least 2×2 and the square is positive and finite.
    pub fn validate(&self) -> CoreResult<()> {
        if self.cols < 2 || self.rows < 2 {
            return Err(CoreError::param(
                "board",
                format!(
                    "needs at least 2×2 inner corners, got {}×{}",
                    self.cols, self.rows
                ),
            ));
        }
        if self.cols.saturating_mul(self.rows) > 1_000_000 {
            return Err(CoreError::param("board", "more than 10⁶ corners"));
        }
        if !(self.square.is_finite() && self.square > 0.0) {
            return Err(CoreError::param(
                "board.square",
                format!("must be positive and finite, got {}", self.square),
            ));
        }
        Ok(())
    }

    /// Number of inner corners.
    pub fn num_corners(&self) -> usize {
        self.cols * self.rows
    }

    /// Board-frame position of corner `index` (row-major), or `None` past the last corner.
    pub fn object_point(&self, index: usize) -> Option<Vector3<f64>> {
        (index < self.num_corners()).then(|| {
            Vector3::new(
                (index % self.cols) as f64 * self.square,
                (index / self.cols) as f64 * self.square,
                0.0,
            )
        })
    }
}

/// One detected corner: its row-major board index and its pixel position.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct CornerObservation {
    /// `row·cols + col`.
    pub index: usize,
    /// Pixel `[x, y]` (pixel centres at integer coordinates, as OpenCV).
    pub pixel: [f64; 2],
}

/// The corners detected in one image. Partial views are fine.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ViewObservations {
    /// Image name, for reports.
    pub name: String,
    /// Detected corners, any order, each index at most once.
    pub corners: Vec<CornerObservation>,
}

impl ViewObservations {
    /// From a dense row-major list with `None` for corners not detected.
    pub fn from_dense(name: impl Into<String>, corners: &[Option<[f64; 2]>]) -> Self {
        Self {
            name: name.into(),
            corners: corners
                .iter()
                .enumerate()
                .filter_map(|(index, c)| c.map(|pixel| CornerObservation { index, pixel }))
                .collect(),
        }
    }
}

/// Settings of [`calibrate`]. Every field has a default (`{}` is a valid document).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct CalibOptions {
    /// Keep fx/fy at its initial value (1 for the pinhole, as OpenCV `CALIB_FIX_ASPECT_RATIO`
    /// without a guess).
    pub fix_aspect_ratio: bool,
    /// Keep the principal point at the image centre `((w−1)/2, (h−1)/2)`.
    pub fix_principal_point: bool,
    /// Pinhole only: keep k3 = 0 (OpenCV `CALIB_FIX_K3`), advisable for narrow lenses where k3
    /// only fits noise.
    pub fix_k3: bool,
    /// Pinhole only: keep p1 = p2 = 0 (OpenCV `CALIB_ZERO_TANGENT_DIST`).
    pub zero_tangential: bool,
    /// Robust loss of the joint optimisation (scale in pixels).
    pub loss: RobustLoss,
    /// Reject outlier corners and views and solve again.
    pub reject_outliers: bool,
    /// A corner is an outlier when its residual norm exceeds this many robust σ (σ per
    /// coordinate from the MAD of the residuals; for Gaussian noise the norm passes 5σ with
    /// probability e^(−12.5) ≈ 4·10⁻⁶).
    pub outlier_sigmas: f64,
    /// …and exceeds this many pixels (so that a nearly noise-free set does not lose corners to
    /// round-off).
    pub outlier_min_px: f64,
    /// A view is rejected when its RMS exceeds this multiple of the median view RMS…
    pub view_rms_factor: f64,
    /// …and exceeds this many pixels.
    pub view_rms_min_px: f64,
    /// Maximum number of reject-and-resolve rounds.
    pub max_rejection_rounds: usize,
    /// Iteration budget of each Levenberg-Marquardt solve.
    pub max_iterations: usize,
}

impl Default for CalibOptions {
    fn default() -> Self {
        Self {
            fix_aspect_ratio: false,
            fix_principal_point: false,
            fix_k3: false,
            zero_tangential: false,
            loss: RobustLoss::Huber { scale: 1.0 },
            reject_outliers: true,
            outlier_sigmas: 5.0,
            outlier_min_px: 0.5,
            view_rms_factor: 5.0,
            view_rms_min_px: 1.0,
            max_rejection_rounds: 3,
            max_iterations: 100,
        }
    }
}

impl CalibOptions {
    /// Checks the numbers and that the pinhole-only flags are not set for another model.
    pub fn validate(&self, model: ModelKind) -> CoreResult<()> {
        self.loss.validate()?;
        let positive = [
            ("outlier_sigmas", self.outlier_sigmas),
            ("view_rms_factor", self.view_rms_factor),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(CoreError::param(name, format!("must be positive, got {v}")));
            }
        }
        let non_negative = [
            ("outlier_min_px", self.outlier_min_px),
            ("view_rms_min_px", self.view_rms_min_px),
        ];
        for (name, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(CoreError::param(name, format!("must be ≥ 0, got {v}")));
            }
        }
        if self.max_iterations == 0 {
            return Err(CoreError::param("max_iterations", "must be at least 1"));
        }
        if model != ModelKind::PinholeRadTan {
            if self.fix_k3 {
                return Err(CoreError::param(
                    "fix_k3",
                    "applies to the pinhole model only",
                ));
            }
            if self.zero_tangential {
                return Err(CoreError::param(
                    "zero_tangential",
                    "applies to the pinhole model only",
                ));
            }
        }
        Ok(())
    }
}

/// One estimated parameter.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ParameterEstimate {
    /// Parameter name ([`CameraModel::param_names`]).
    pub name: String,
    /// Estimated value.
    pub value: f64,
    /// 1σ standard deviation from `σ²·(JᵀJ)⁻¹` marginalised over the poses; 0 for a fixed
    /// parameter; `None` when the covariance is not available (see the warnings).
    pub std_dev: Option<f64>,
    /// Held fixed by the options.
    pub fixed: bool,
}

/// Result for one view.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ViewResult {
    /// Image name.
    pub name: String,
    /// Whether the view took part in the final solve.
    pub used: bool,
    /// OpenCV `rvec` of `T_cam_board` (for a rejected view: its pose for the final camera, if
    /// one could be fitted).
    pub rvec: Option<[f64; 3]>,
    /// OpenCV `tvec` of `T_cam_board`, in board units.
    pub tvec: Option<[f64; 3]>,
    /// RMS reprojection error over the view's inlier corners (all corners for a rejected
    /// view), pixels.
    pub rms: Option<f64>,
    /// Corners observed.
    pub num_corners: usize,
    /// Corners used in the final solve.
    pub num_inliers: usize,
}

/// The reprojection residual of one corner.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct CornerResidual {
    /// View number (position in the input).
    pub view: usize,
    /// Board corner index.
    pub index: usize,
    /// `projected − measured`, pixels; `None` if the corner does not project.
    pub residual: Option<[f64; 2]>,
    /// Used in the final solve.
    pub inlier: bool,
}

/// A corner left out of the solve.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct RejectedCorner {
    /// View number.
    pub view: usize,
    /// View name.
    pub view_name: String,
    /// Board corner index.
    pub index: usize,
    /// Why.
    pub reason: String,
}

/// A view left out of the solve.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct RejectedView {
    /// View number.
    pub view: usize,
    /// View name.
    pub name: String,
    /// Why.
    pub reason: String,
}

/// 1σ uncertainty of the projection of the fixed ray through a pixel, due to the intrinsic
/// covariance alone.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ProjectionUncertainty {
    /// `centre`, `top_left`, `top_right`, `bottom_left`, `bottom_right`.
    pub location: String,
    /// The pixel whose ray is projected.
    pub pixel: [f64; 2],
    /// Standard deviation along x, pixels.
    pub std_x: f64,
    /// Standard deviation along y, pixels.
    pub std_y: f64,
    /// Standard deviation along the major axis of the 2×2 covariance, pixels.
    pub std_major: f64,
}

/// The outcome of [`calibrate`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct Calibration {
    /// The calibrated camera.
    pub camera: Camera,
    /// Image size `[width, height]`.
    pub image_size: [u32; 2],
    /// Each parameter with its standard deviation.
    pub parameters: Vec<ParameterEstimate>,
    /// RMS reprojection error over the inlier corners of the used views, recomputed from the
    /// final parameters, pixels (OpenCV's definition: √(Σ‖r‖²/N)).
    pub rms: f64,
    /// RMS over every corner that has a residual (rejected ones included), pixels.
    pub rms_all: f64,
    /// Residual standard deviation per coordinate, `√(Σ‖r‖²/(2N − p))` with p free parameters
    /// (poses included): the σ of the covariance.
    pub sigma: f64,
    /// Corners used in the final solve.
    pub num_inliers: usize,
    /// Corners observed in all views.
    pub num_corners: usize,
    /// Per view, in input order.
    pub views: Vec<ViewResult>,
    /// Per corner, in input order.
    pub residuals: Vec<CornerResidual>,
    /// Corners rejected, with reasons.
    pub rejected_corners: Vec<RejectedCorner>,
    /// Views rejected, with reasons.
    pub rejected_views: Vec<RejectedView>,
    /// Projection uncertainty at the image centre and corners (where the model has a ray).
    pub projection_uncertainty: Vec<ProjectionUncertainty>,
    /// Levenberg-Marquardt iterations over all solves.
    pub iterations: usize,
    /// How the last solve ended.
    pub termination: Termination,
    /// The starting camera of the joint optimisation.
    pub initial_camera: Camera,
    /// Anything the caller should know (e.g. no covariance).
    pub warnings: Vec<String>,
}

/// Working state of one input view.
struct ViewState {
    name: String,
    indices: Vec<usize>,
    data: ViewData,
    inlier: Vec<bool>,
    pose: Option<Se3>,
    rejected: Option<String>,
}

impl ViewState {
    fn active(&self) -> bool {
        self.rejected.is_none() && self.pose.is_some()
    }

    fn inlier_data(&self) -> ViewData {
        let mut d = ViewData::default();
        for (k, ok) in self.inlier.iter().enumerate() {
            if *ok {
                d.object.push(self.data.object[k]);
                d.pixels.push(self.data.pixels[k]);
            }
        }
        d
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Validates and converts the input views.
fn parse_views(
    observations: &[ViewObservations],
    board: &BoardGeometry,
) -> CoreResult<Vec<ViewState>> {
    let n = board.num_corners();
    observations
        .iter()
        .map(|view| {
            let mut seen = vec![false; n];
            let mut st = ViewState {
                name: view.name.clone(),
                indices: Vec::with_capacity(view.corners.len()),
                data: ViewData::default(),
                inlier: Vec::with_capacity(view.corners.len()),
                pose: None,
                rejected: None,
            };
            for c in &view.corners {
                let Some(x) = board.object_point(c.index) else {
                    return Err(CoreError::input(format!(
                        "view `{}`: corner index {} outside the {}×{} board",
                        view.name, c.index, board.cols, board.rows
                    )));
                };
                if std::mem::replace(&mut seen[c.index], true) {
                    return Err(CoreError::input(format!(
                        "view `{}`: corner {} given twice",
                        view.name, c.index
                    )));
                }
                if !(c.pixel[0].is_finite() && c.pixel[1].is_finite()) {
                    return Err(CoreError::input(format!(
                        "view `{}`: corner {} has a non-finite pixel",
                        view.name, c.index
                    )));
                }
                st.indices.push(c.index);
                st.data.object.push(x);
                st.data.pixels.push(Vector2::new(c.pixel[0], c.pixel[1]));
                st.inlier.push(true);
            }
            if st.indices.len() < MIN_CORNERS_PER_VIEW {
                st.rejected = Some(format!(
                    "only {} corners (at least {MIN_CORNERS_PER_VIEW} needed)",
                    st.indices.len()
                ));
            }
            Ok(st)
        })
        .collect()
}

/// Calibrates one camera from chessboard corners (see the module docs for the method).
///
/// Errors: [`CoreError::InvalidInput`] / [`CoreError::InvalidParam`] for malformed input or
/// options, [`CoreError::NoSolution`] when fewer than [`MIN_VIEWS`] views are usable or the
/// views do not determine the camera, [`CoreError::Canceled`].
pub fn calibrate(
    observations: &[ViewObservations],
    board: &BoardGeometry,
    model: ModelKind,
    image_size: (u32, u32),
    options: &CalibOptions,
    progress: &dyn Progress,
) -> CoreResult<Calibration> {
    board.validate()?;
    options.validate(model)?;
    if image_size.0 == 0 || image_size.1 == 0 {
        return Err(CoreError::param(
            "image_size",
            "width and height must be positive",
        ));
    }
    let mut views = parse_views(observations, board)?;
    let usable = |views: &[ViewState]| views.iter().filter(|v| v.rejected.is_none()).count();
    if usable(&views) < MIN_VIEWS {
        return Err(CoreError::NoSolution(format!(
            "{} usable views (with at least {MIN_CORNERS_PER_VIEW} corners); at least {MIN_VIEWS} needed",
            usable(&views)
        )));
    }
    progress.check()?;

    // 1. Initial camera.
    let start_data: Vec<ViewData> = views
        .iter()
        .filter(|v| v.rejected.is_none())
        .map(|v| v.data.clone())
        .collect();
    let mut initial = match model {
        ModelKind::PinholeRadTan => {
            let k = init::pinhole_start(&start_data, image_size, options.fix_principal_point)?;
            let (mut fx, mut fy) = (k.fx, k.fy);
            if options.fix_aspect_ratio {
                fx = 0.5 * (fx + fy);
                fy = fx;
            }
            model.camera(&[fx, fy, k.cx, k.cy, 0.0, 0.0, 0.0, 0.0, 0.0])?
        }
        _ => init::focal_sweep(model, image_size, &start_data, progress)?,
    };
    if options.fix_principal_point {
        let c = init::image_centre(image_size);
        let mut p = initial.params().to_vec();
        p[2] = c.x;
        p[3] = c.y;
        initial = model.camera(&p)?;
    }

    // 2. Initial poses.
    for v in views.iter_mut().filter(|v| v.rejected.is_none()) {
        match pnp::pose_for_view(&initial, &v.data, 50, progress) {
            Ok((pose, _)) => v.pose = Some(pose),
            Err(CoreError::Canceled) => return Err(CoreError::Canceled),
            Err(e) => v.rejected = Some(format!("no initial pose: {e}")),
        }
    }
    if usable(&views) < MIN_VIEWS {
        return Err(CoreError::NoSolution(format!(
            "only {} views could be posed with the initial camera; at least {MIN_VIEWS} needed",
            usable(&views)
        )));
    }

    // 3. Parameterisation.
    let names = initial.param_names();
    let mut fixed = vec![false; names.len()];
    let mut fix = |name: &str| {
        if let Some(k) = names.iter().position(|n| *n == name) {
            fixed[k] = true;
        }
    };
    if options.fix_principal_point {
        fix("cx");
        fix("cy");
    }
    if options.fix_k3 {
        fix("k3");
    }
    if options.zero_tangential {
        fix("p1");
        fix("p2");
    }
    let aspect = if options.fix_aspect_ratio {
        fix("fy");
        let p = initial.params();
        Some(p[1] / p[0])
    } else {
        None
    };
    let mut shared = initial.params().to_vec();
    let lm_options = LmOptions {
        max_iterations: options.max_iterations,
        loss: options.loss,
        ..LmOptions::default()
    };

    // 4. Solve, reject, re-solve.
    let mut iterations = 0;
    let mut termination = Termination::MaxIterations;
    let mut rejected_corners = Vec::new();
    // The camera of the current `shared`, when built (saves rebuilding it, see `known`).
    let mut current: Option<Camera> = Some(initial.clone());
    for round in 0..=options.max_rejection_rounds {
        progress.report(
            "calibrate",
            round as u64,
            options.max_rejection_rounds as u64 + 1,
        );
        let active: Vec<usize> = (0..views.len()).filter(|&i| views[i].active()).collect();
        let data: Vec<ViewData> = active.iter().map(|&i| views[i].inlier_data()).collect();
        let mut poses: Vec<Se3> = active.iter().filter_map(|&i| views[i].pose).collect();
        let problem = CalibProblem {
            kind: model,
            views: &data,
            aspect,
            known: current.as_ref(),
        };
        let summary = lm_solve(
            &problem,
            &mut shared,
            &fixed,
            &mut poses,
            &lm_options,
            progress,
        )?;
        iterations += summary.iterations;
        termination = summary.termination;
        for (&i, p) in active.iter().zip(&poses) {
            views[i].pose = Some(*p);
        }
        if !options.reject_outliers || round == options.max_rejection_rounds {
            break;
        }
        let camera = model.camera(&problem.camera_params(&shared))?;
        let changed = reject(&mut views, &active, &camera, options, &mut rejected_corners);
        current = Some(camera);
        if !changed {
            break;
        }
    }

    // 5. Report.
    let params = CalibProblem {
        kind: model,
        views: &[],
        aspect,
        known: None,
    }
    .camera_params(&shared);
    let camera = match current {
        Some(c) if c.params() == params.as_slice() => c,
        _ => model.camera(&params)?,
    };
    finish(
        views,
        camera,
        initial,
        model,
        image_size,
        &shared,
        &fixed,
        aspect,
        iterations,
        termination,
        rejected_corners,
        progress,
    )
}

/// One round of outlier rejection on the active views; returns whether anything was rejected.
///
/// Corners first: a corner is an outlier when its residual norm exceeds
/// `max(outlier_sigmas·σ, outlier_min_px)`, σ the robust (MAD) spread of the residual
/// coordinates of all inliers. Then views, judged on the corners that survive: a view whose RMS
/// exceeds `view_rms_factor` × the median view RMS (and `view_rms_min_px`) is dropped whole,
/// worst first, never below [`MIN_VIEWS`] views; so is a view left with fewer than
/// [`MIN_CORNERS_PER_VIEW`] inliers. Judging views after the corners keeps one mis-detected
/// corner from condemning a good view, while a view that is bad throughout (wrong ordering,
/// motion blur) still goes, with one reason instead of dozens.
fn reject(
    views: &mut [ViewState],
    active: &[usize],
    camera: &Camera,
    options: &CalibOptions,
    rejected_corners: &mut Vec<RejectedCorner>,
) -> bool {
    // Residuals of every corner of the active views.
    let residuals: Vec<Vec<Option<Vector2<f64>>>> = active
        .iter()
        .map(|&i| {
            let v = &views[i];
            let pose = v.pose.unwrap_or_default();
            v.data
                .object
                .iter()
                .zip(&v.data.pixels)
                .map(|(x, px)| camera.project(&pose.act(x)).map(|p| p - px))
                .collect()
        })
        .collect();
    let mut components = Vec::new();
    for (a, &i) in active.iter().enumerate() {
        for (k, r) in residuals[a].iter().enumerate() {
            if views[i].inlier[k]
                && let Some(r) = r
            {
                components.push(r.x.abs());
                components.push(r.y.abs());
            }
        }
    }
    let sigma = MAD_TO_SIGMA * median(components);
    let threshold = (options.outlier_sigmas * sigma).max(options.outlier_min_px);

    // Tentative corner outliers and the RMS of what survives, per view.
    let mut new_outliers: Vec<Vec<(usize, String)>> = Vec::with_capacity(active.len());
    let mut view_rms = Vec::with_capacity(active.len());
    let mut survivors = Vec::with_capacity(active.len());
    for (a, &i) in active.iter().enumerate() {
        let v = &views[i];
        let mut out = Vec::new();
        let (mut sum, mut n) = (0.0, 0usize);
        for (k, r) in residuals[a].iter().enumerate() {
            if !v.inlier[k] {
                continue;
            }
            match r {
                None => out.push((k, "does not project with the current estimate".to_string())),
                Some(r) if r.norm() > threshold => out.push((
                    k,
                    format!(
                        "residual {:.3} px > {threshold:.3} px ({}·σ, robust σ = {sigma:.3} px)",
                        r.norm(),
                        options.outlier_sigmas
                    ),
                )),
                Some(r) => {
                    sum += r.norm_squared();
                    n += 1;
                }
            }
        }
        view_rms.push(if n > 0 {
            (sum / n as f64).sqrt()
        } else {
            f64::INFINITY
        });
        survivors.push(n);
        new_outliers.push(out);
    }
    let med_view = median(view_rms.iter().copied().filter(|x| x.is_finite()).collect());

    let mut changed = false;
    let mut remaining = active.len();
    let mut drop_view: Vec<(f64, usize, String)> = Vec::new();
    for (a, &rms) in view_rms.iter().enumerate() {
        if survivors[a] < MIN_CORNERS_PER_VIEW {
            drop_view.push((
                f64::INFINITY,
                a,
                format!(
                    "only {} inlier corners left (at least {MIN_CORNERS_PER_VIEW} needed)",
                    survivors[a]
                ),
            ));
        } else if rms > options.view_rms_factor * med_view && rms > options.view_rms_min_px {
            drop_view.push((
                rms,
                a,
                format!(
                    "RMS {rms:.3} px is more than {}× the median view RMS {med_view:.3} px",
                    options.view_rms_factor
                ),
            ));
        }
    }
    drop_view.sort_by(|x, y| y.0.total_cmp(&x.0));
    for (_, a, reason) in drop_view {
        if remaining <= MIN_VIEWS {
            break;
        }
        views[active[a]].rejected = Some(reason);
        remaining -= 1;
        changed = true;
    }
    for (a, &i) in active.iter().enumerate() {
        let v = &mut views[i];
        if v.rejected.is_some() {
            continue;
        }
        for (k, reason) in new_outliers[a].drain(..) {
            v.inlier[k] = false;
            changed = true;
            rejected_corners.push(RejectedCorner {
                view: i,
                view_name: v.name.clone(),
                index: v.indices[k],
                reason,
            });
        }
    }
    changed
}

/// Residuals, RMS, covariance and projection uncertainty of the final estimate.
#[allow(clippy::too_many_arguments)]
fn finish(
    mut views: Vec<ViewState>,
    camera: Camera,
    initial: Camera,
    model: ModelKind,
    image_size: (u32, u32),
    shared: &[f64],
    fixed: &[bool],
    aspect: Option<f64>,
    iterations: usize,
    termination: Termination,
    rejected_corners: Vec<RejectedCorner>,
    progress: &dyn Progress,
) -> CoreResult<Calibration> {
    let mut warnings = Vec::new();
    // Rejected views get a pose for the final camera, so their residuals mean something.
    for v in views.iter_mut().filter(|v| v.rejected.is_some()) {
        if v.data.object.len() >= 4 {
            match pnp::pose_for_view(&camera, &v.data, 50, progress) {
                Ok((pose, _)) => v.pose = Some(pose),
                Err(CoreError::Canceled) => return Err(CoreError::Canceled),
                Err(_) => v.pose = None,
            }
        }
    }

    let mut residuals = Vec::new();
    let mut view_results = Vec::with_capacity(views.len());
    let (mut sum_in, mut n_in, mut sum_all, mut n_all) = (0.0, 0usize, 0.0, 0usize);
    let mut num_corners = 0;
    for (i, v) in views.iter().enumerate() {
        num_corners += v.indices.len();
        let used = v.active();
        let (mut vs, mut vn) = (0.0, 0usize);
        for (k, (x, px)) in v.data.object.iter().zip(&v.data.pixels).enumerate() {
            let inlier = used && v.inlier[k];
            let r = v
                .pose
                .and_then(|pose| camera.project(&pose.act(x)))
                .map(|p| p - px);
            if let Some(r) = r {
                let s = r.norm_squared();
                sum_all += s;
                n_all += 1;
                if inlier {
                    sum_in += s;
                    n_in += 1;
                }
                if inlier || !used {
                    vs += s;
                    vn += 1;
                }
            }
            residuals.push(CornerResidual {
                view: i,
                index: v.indices[k],
                residual: r.map(|r| [r.x, r.y]),
                inlier,
            });
        }
        let rt = v.pose.map(|p| p.to_rvec_tvec());
        view_results.push(ViewResult {
            name: v.name.clone(),
            used,
            rvec: rt.map(|(r, _)| [r.x, r.y, r.z]),
            tvec: rt.map(|(_, t)| [t.x, t.y, t.z]),
            rms: (vn > 0).then(|| (vs / vn as f64).sqrt()),
            num_corners: v.indices.len(),
            num_inliers: if used {
                v.inlier.iter().filter(|x| **x).count()
            } else {
                0
            },
        });
    }
    let rms = if n_in > 0 {
        (sum_in / n_in as f64).sqrt()
    } else {
        f64::NAN
    };
    let rms_all = if n_all > 0 {
        (sum_all / n_all as f64).sqrt()
    } else {
        f64::NAN
    };

    // Covariance of the camera parameters, marginalised over the poses.
    let active: Vec<usize> = (0..views.len()).filter(|&i| views[i].active()).collect();
    let data: Vec<ViewData> = active.iter().map(|&i| views[i].inlier_data()).collect();
    let poses: Vec<Se3> = active.iter().filter_map(|&i| views[i].pose).collect();
    let problem = CalibProblem {
        kind: model,
        views: &data,
        aspect,
        known: Some(&camera),
    };
    let free = fixed.iter().filter(|f| !**f).count() + 6 * poses.len();
    let dof = 2 * n_in as isize - free as isize;
    let sigma = if dof > 0 {
        (sum_in / dof as f64).sqrt()
    } else {
        f64::NAN
    };
    let covariance = if dof <= 0 {
        warnings.push(format!(
            "no covariance: {} residuals for {free} free parameters",
            2 * n_in
        ));
        None
    } else {
        match marginal_shared_covariance(&problem, shared, fixed, &poses) {
            Ok(c) => {
                // Solver parameters → camera parameters (the aspect tie makes fy = ratio·fx).
                let n = c.nrows();
                let mut m = DMatrix::<f64>::identity(n, n);
                if let Some(ratio) = aspect {
                    m[(1, 0)] = ratio;
                    m[(1, 1)] = 0.0;
                }
                Some(&m * c * m.transpose() * (sigma * sigma))
            }
            Err(e) => {
                warnings.push(format!("no covariance: {e}"));
                None
            }
        }
    };
    let names = camera.param_names();
    let parameters = names
        .iter()
        .enumerate()
        .map(|(k, name)| ParameterEstimate {
            name: (*name).to_string(),
            value: camera.params()[k],
            std_dev: covariance.as_ref().map(|c| c[(k, k)].max(0.0).sqrt()),
            fixed: fixed[k] && !(k == 1 && aspect.is_some()),
        })
        .collect();

    let projection_uncertainty = covariance
        .as_ref()
        .map(|c| projection_uncertainty(&camera, image_size, c))
        .unwrap_or_default();

    let rejected_views = views
        .iter()
        .enumerate()
        .filter_map(|(i, v)| {
            v.rejected.as_ref().map(|r| RejectedView {
                view: i,
                name: v.name.clone(),
                reason: r.clone(),
            })
        })
        .collect();

    Ok(Calibration {
        camera,
        image_size: [image_size.0, image_size.1],
        parameters,
        rms,
        rms_all,
        sigma,
        num_inliers: n_in,
        num_corners,
        views: view_results,
        residuals,
        rejected_corners,
        rejected_views,
        projection_uncertainty,
        iterations,
        termination,
        initial_camera: initial,
        warnings,
    })
}

/// `J Σ Jᵀ` of the projection of the fixed rays through the image centre and corners, J the
/// 2×N Jacobian of the pixel with respect to the camera parameters.
///
/// This is the first-order propagation of the intrinsic covariance only; mrcal ("projection
/// uncertainty", Kogan) additionally accounts for the uncertainty of the reference frame the ray
/// is fixed in (through the board poses), which makes its numbers larger at short range.
fn projection_uncertainty(
    camera: &Camera,
    image_size: (u32, u32),
    cov: &DMatrix<f64>,
) -> Vec<ProjectionUncertainty> {
    let (w, h) = (f64::from(image_size.0) - 1.0, f64::from(image_size.1) - 1.0);
    let c = init::image_centre(image_size);
    let spots = [
        ("centre", c.x, c.y),
        ("top_left", 0.0, 0.0),
        ("top_right", w, 0.0),
        ("bottom_left", 0.0, h),
        ("bottom_right", w, h),
    ];
    spots
        .iter()
        .filter_map(|(label, x, y)| {
            let ray = camera.unproject(&Vector2::new(*x, *y))?;
            let (_, _, j) = camera.project_with_jacobians(&ray)?;
            let s = &j * cov * j.transpose();
            let s = Matrix2::new(s[(0, 0)], s[(0, 1)], s[(1, 0)], s[(1, 1)]);
            let major = s.symmetric_eigenvalues().max().max(0.0).sqrt();
            Some(ProjectionUncertainty {
                location: (*label).to_string(),
                pixel: [*x, *y],
                std_x: s[(0, 0)].max(0.0).sqrt(),
                std_y: s[(1, 1)].max(0.0).sqrt(),
                std_major: major,
            })
        })
        .collect()
}
