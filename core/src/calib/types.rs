//! The calibration's inputs (board, observations, options) and its report ([`Calibration`]).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::camera::{Camera, DoubleSphere, KannalaBrandt, PinholeRadTan};
use crate::error::{CoreError, CoreResult};
use crate::optim::{RobustLoss, Termination};
// Items the doc comments link to. The comments themselves stay as they are: with the `schema`
// feature they are the OpenAPI descriptions.
#[cfg(doc)]
use super::calibrate;
#[cfg(doc)]
use crate::camera::CameraModel;

/// Fewest corners a view needs to take part (a homography needs 4; 6 leaves some redundancy
/// to detect a bad view).
pub const MIN_CORNERS_PER_VIEW: usize = 6;
/// Fewest views a calibration needs (Zhang's closed form needs 2 without extra assumptions);
/// outlier rejection never goes below it.
pub const MIN_VIEWS: usize = 2;

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

/// A planar calibration target as the solvers see it: numbered points on the plane z = 0.
///
/// Chessboards ([`BoardGeometry`]) and the targets of [`crate::board`] (ChArUco, AprilGrid,
/// circle grids) implement it, so every solver serves every target.
pub trait PlanarTarget: Sync {
    /// Errors unless the target can exist (sizes positive and finite, counts in range).
    fn validate(&self) -> CoreResult<()>;
    /// Number of point ids (`0..num_points`).
    fn num_points(&self) -> usize;
    /// Board-frame position of point `id`, or `None` for an id the target does not have.
    fn object_point(&self, id: usize) -> Option<Vector3<f64>>;
    /// Short description for messages ("9×6 chessboard").
    fn describe(&self) -> String;
    /// When a detector cannot tell the target from itself turned by a half-turn (a chessboard
    /// has no marked corner), the rigid motion of the board plane that maps point k to point
    /// `num_points − 1 − k`; `None` for targets whose ids are unambiguous.
    fn half_turn(&self) -> Option<crate::lie::Se3> {
        None
    }
}

impl PlanarTarget for BoardGeometry {
    fn validate(&self) -> CoreResult<()> {
        BoardGeometry::validate(self)
    }

    fn num_points(&self) -> usize {
        self.num_corners()
    }

    fn object_point(&self, id: usize) -> Option<Vector3<f64>> {
        BoardGeometry::object_point(self, id)
    }

    fn describe(&self) -> String {
        format!("{}×{} chessboard", self.cols, self.rows)
    }

    fn half_turn(&self) -> Option<crate::lie::Se3> {
        Some(crate::lie::Se3::new(
            crate::lie::So3::exp(&Vector3::new(0.0, 0.0, std::f64::consts::PI)),
            Vector3::new(
                (self.cols - 1) as f64 * self.square,
                (self.rows - 1) as f64 * self.square,
                0.0,
            ),
        ))
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
