//! Pinhole camera with Brown-Conrady radial-tangential distortion (OpenCV `calib3d` model).

use nalgebra::{Matrix2, Matrix2x3, Matrix2xX, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use super::{
    CameraModel, ProjectionJacobians, UNPROJECT_MAX_ITERATIONS, UNPROJECT_TOLERANCE,
    checked_params, first_nonpositive, schema_via_params, solve_increasing,
};
use crate::error::{CoreError, CoreResult};

const NAMES: [&str; 9] = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"];

/// Points closer than this to the image plane z = 0 (relative to their distance) are rejected:
/// their normalised coordinates overflow any meaningful distortion polynomial.
const MIN_DEPTH_RATIO: f64 = 1e-9;

/// Pinhole projection with radial-tangential distortion, parameters
/// `[fx, fy, cx, cy, k1, k2, p1, p2, k3]` in OpenCV's order and conventions:
///
/// ```text
/// x = X/Z, y = Y/Z, r² = x² + y²
/// x″ = x(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²)
/// y″ = y(1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y
/// u = fx x″ + cx,  v = fy y″ + cy
/// ```
///
/// (Brown, "Decentering distortion of lenses", 1966; Zhang, "A flexible new technique for camera
/// calibration", TPAMI 2000.) No skew.
///
/// Valid domain: Z > 0 and r² below the first zero of `d(r·(1 + k1r² + k2r⁴ + k3r⁶))/dr`, where
/// the radial mapping stops being monotonic (computed once per parameter change). Tangential
/// terms are not part of that check; they are small for real lenses.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "PinholeRadTanParams", into = "PinholeRadTanParams")]
pub struct PinholeRadTan {
    params: [f64; 9],
    /// r² at which the radial mapping folds back (∞ if never).
    max_r2: f64,
}

/// Share of the fold radius² inside which points project. The radial derivative vanishes at
/// the fold, so just inside it a pixel's round-off becomes an unbounded error of its ray
/// (a random-model round trip found one 3·10⁻⁵ inside the fold that came back 10⁻⁶ off):
/// the last 1 % of r² is left out of the domain.
const FOLD_MARGIN: f64 = 0.99;

/// Document form of [`PinholeRadTan`]. Distortion coefficients default to 0.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct PinholeRadTanParams {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Radial coefficient of r².
    #[serde(default)]
    pub k1: f64,
    /// Radial coefficient of r⁴.
    #[serde(default)]
    pub k2: f64,
    /// First tangential coefficient.
    #[serde(default)]
    pub p1: f64,
    /// Second tangential coefficient.
    #[serde(default)]
    pub p2: f64,
    /// Radial coefficient of r⁶.
    #[serde(default)]
    pub k3: f64,
}

schema_via_params!(PinholeRadTan, PinholeRadTanParams, "PinholeRadTan");

impl TryFrom<PinholeRadTanParams> for PinholeRadTan {
    type Error = CoreError;
    fn try_from(p: PinholeRadTanParams) -> CoreResult<Self> {
        Self::from_slice(&[p.fx, p.fy, p.cx, p.cy, p.k1, p.k2, p.p1, p.p2, p.k3])
    }
}

impl From<PinholeRadTan> for PinholeRadTanParams {
    fn from(m: PinholeRadTan) -> Self {
        let [fx, fy, cx, cy, k1, k2, p1, p2, k3] = m.params;
        Self {
            fx,
            fy,
            cx,
            cy,
            k1,
            k2,
            p1,
            p2,
            k3,
        }
    }
}

/// Distorted normalised point and its 2×2 Jacobian with respect to the undistorted one.
struct Distorted {
    d: Vector2<f64>,
    jac: Matrix2<f64>,
}

impl PinholeRadTan {
    /// A validated model (see [`CameraModel::set_params`] for the checks).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        k1: f64,
        k2: f64,
        p1: f64,
        p2: f64,
        k3: f64,
    ) -> CoreResult<Self> {
        Self::from_slice(&[fx, fy, cx, cy, k1, k2, p1, p2, k3])
    }

    /// A validated model from `[fx, fy, cx, cy, k1, k2, p1, p2, k3]`.
    pub fn from_slice(params: &[f64]) -> CoreResult<Self> {
        let params = checked_params(params, &NAMES)?;
        Ok(Self {
            params,
            max_r2: Self::fold_radius2(&params),
        })
    }

    /// `[fx, fy, cx, cy]`.
    pub fn intrinsics(&self) -> [f64; 4] {
        [
            self.params[0],
            self.params[1],
            self.params[2],
            self.params[3],
        ]
    }

    /// OpenCV `distCoeffs` order `[k1, k2, p1, p2, k3]`.
    pub fn distortion(&self) -> [f64; 5] {
        [
            self.params[4],
            self.params[5],
            self.params[6],
            self.params[7],
            self.params[8],
        ]
    }

    /// The squared normalised radius beyond which projection is refused (∞ when the radial
    /// mapping is monotonic everywhere).
    pub fn max_radius_squared(&self) -> f64 {
        self.max_r2
    }

    /// First zero in s = r² of `d(r·D(r))/dr = 1 + 3k1 s + 5k2 s² + 7k3 s³`.
    fn fold_radius2(p: &[f64; 9]) -> f64 {
        let (k1, k2, k3) = (p[4], p[5], p[8]);
        first_nonpositive(
            |s| 1.0 + s * (3.0 * k1 + s * (5.0 * k2 + s * 7.0 * k3)),
            1e-8,
            1e8,
            4000,
        )
        .unwrap_or(f64::INFINITY)
    }

    /// Applies the distortion to a normalised point.
    fn distort(&self, x: f64, y: f64) -> Distorted {
        let [_, _, _, _, k1, k2, p1, p2, k3] = self.params;
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        // d(radial)/d(r²)
        let dradial = k1 + r2 * (2.0 * k2 + r2 * 3.0 * k3);
        let xy = x * y;
        let d = Vector2::new(
            x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy,
        );
        let cross = 2.0 * xy * dradial + 2.0 * p1 * x + 2.0 * p2 * y;
        let jac = Matrix2::new(
            radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x,
            cross,
            cross,
            radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x,
        );
        Distorted { d, jac }
    }

    /// Normalised coordinates of a point, or `None` outside the valid domain.
    fn normalise(&self, p: &Vector3<f64>) -> Option<(f64, f64)> {
        // Written as a positive test so that NaN coordinates are rejected too.
        let in_front = p.z > MIN_DEPTH_RATIO * p.norm();
        if !in_front {
            return None;
        }
        let (x, y) = (p.x / p.z, p.y / p.z);
        (x * x + y * y < self.max_r2 * FOLD_MARGIN).then_some((x, y))
    }
}

impl CameraModel for PinholeRadTan {
    fn name(&self) -> &'static str {
        "pinhole_radtan"
    }

    fn param_names(&self) -> &'static [&'static str] {
        &NAMES
    }

    fn params(&self) -> &[f64] {
        &self.params
    }

    fn set_params(&mut self, params: &[f64]) -> CoreResult<()> {
        *self = Self::from_slice(params)?;
        Ok(())
    }

    fn project(&self, p: &Vector3<f64>) -> Option<Vector2<f64>> {
        let (x, y) = self.normalise(p)?;
        let d = self.distort(x, y).d;
        let [fx, fy, cx, cy, ..] = self.params;
        Some(Vector2::new(fx * d.x + cx, fy * d.y + cy))
    }

    /// Inverts the distortion in two stages. First the radial part alone, `r·D(r) = |x″|`, is
    /// solved on the monotonic interval `[0, r_max)` by safeguarded Newton, which cannot jump to
    /// the folded-back branch the way a plain Newton start from `x″` does for strong
    /// distortion. Then Newton's method on the full 2×2 system `distort(x) = x″` (tangential terms
    /// included) polishes that guess, halving steps that would not reduce the residual or would
    /// leave the domain. Converged when the residual is below [`UNPROJECT_TOLERANCE`] times
    /// `max(1, |x″|)` within [`UNPROJECT_MAX_ITERATIONS`] steps; `None` otherwise.
    fn unproject(&self, px: &Vector2<f64>) -> Option<Vector3<f64>> {
        let [fx, fy, cx, cy, k1, k2, _, _, k3] = self.params;
        let target = Vector2::new((px.x - cx) / fx, (px.y - cy) / fy);
        let rd = target.norm();
        if !rd.is_finite() {
            return None;
        }
        let mut x = if rd > UNPROJECT_TOLERANCE {
            let radial = |r: f64| {
                let r2 = r * r;
                r * (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
            };
            let dradial = |r: f64| {
                let r2 = r * r;
                1.0 + r2 * (3.0 * k1 + r2 * (5.0 * k2 + r2 * 7.0 * k3))
            };
            let r_hi = if self.max_r2.is_finite() {
                self.max_r2.sqrt()
            } else {
                let mut hi = rd.max(1.0);
                while radial(hi) < rd {
                    hi *= 2.0;
                    if hi > 1e8 {
                        return None;
                    }
                }
                hi
            };
            // Past the radial fold the tangential terms may still bring the solution inside;
            // start just inside the domain and let the 2-D iteration decide.
            let r = solve_increasing(radial, dradial, rd, 0.0, r_hi, rd).unwrap_or(0.999 * r_hi);
            target * (r / rd)
        } else {
            target
        };
        // Relative to the target, as in `solve_increasing`: far out on a strongly distorted
        // lens |x″| reaches 10³ and rounding alone leaves residuals above 10⁻¹².
        let tol = UNPROJECT_TOLERANCE * rd.max(1.0);
        let mut cur = self.distort(x.x, x.y);
        let mut res = cur.d - target;
        for _ in 0..UNPROJECT_MAX_ITERATIONS {
            if res.norm() <= tol {
                // The same domain as `project`: no ray from the ill-conditioned band at the fold.
                return (x.norm_squared() < self.max_r2 * FOLD_MARGIN)
                    .then(|| Vector3::new(x.x, x.y, 1.0).normalize());
            }
            let step = cur.jac.try_inverse()? * res;
            let mut scale = 1.0;
            loop {
                let cand = x - step * scale;
                let next = self.distort(cand.x, cand.y);
                let next_res = next.d - target;
                if cand.norm_squared() < self.max_r2 && next_res.norm() < res.norm() {
                    x = cand;
                    cur = next;
                    res = next_res;
                    break;
                }
                scale *= 0.5;
                if scale < 1e-6 {
                    return None;
                }
            }
        }
        None
    }

    fn project_with_jacobians(&self, p: &Vector3<f64>) -> Option<ProjectionJacobians> {
        let (x, y) = self.normalise(p)?;
        let Distorted { d, jac } = self.distort(x, y);
        let [fx, fy, cx, cy, ..] = self.params;
        let pixel = Vector2::new(fx * d.x + cx, fy * d.y + cy);

        // ∂(x, y)/∂(X, Y, Z)
        let iz = 1.0 / p.z;
        let dn = Matrix2x3::new(iz, 0.0, -x * iz, 0.0, iz, -y * iz);
        let d_point = Matrix2::new(fx, 0.0, 0.0, fy) * jac * dn;

        let r2 = x * x + y * y;
        let r4 = r2 * r2;
        let r6 = r4 * r2;
        let xy2 = 2.0 * x * y;
        #[rustfmt::skip]
        let d_params = Matrix2xX::from_row_slice(&[
            // fx   fy   cx   cy   k1          k2          p1                        p2                        k3
            d.x, 0.0, 1.0, 0.0, fx * x * r2, fx * x * r4, fx * xy2,                 fx * (r2 + 2.0 * x * x), fx * x * r6,
            0.0, d.y, 0.0, 1.0, fy * y * r2, fy * y * r4, fy * (r2 + 2.0 * y * y), fy * xy2,                 fy * y * r6,
        ]);
        Some((pixel, d_point, d_params))
    }
}
