//! Zhang's closed-form intrinsics from plane homographies, and the pose of a plane from its
//! homography.

use nalgebra::{DMatrix, Matrix2, Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{CoreError, CoreResult};
use crate::lie::{Se3, So3};

/// Singular-value ratio below which the constraint system is called rank-deficient.
const DEGENERATE_RATIO: f64 = 1e-9;

/// Linear pinhole intrinsics `K = [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct Intrinsics {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Skew (γ in Zhang's paper); Caliper's models have none, so it is reported, then dropped.
    pub skew: f64,
}

impl Intrinsics {
    /// The 3×3 camera matrix.
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::new(
            self.fx, self.skew, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0,
        )
    }
}

/// The similarity taking pixels to a frame centred on the image with unit scale ≈ image size,
/// and its inverse. Zhang's system mixes products of homography entries of very different
/// magnitudes; in this frame they are all of order 1.
fn image_frame(image_size: (u32, u32)) -> (Matrix3<f64>, f64, Vector2<f64>) {
    let (w, h) = (f64::from(image_size.0), f64::from(image_size.1));
    let s = w.max(h).max(1.0);
    let c = Vector2::new((w - 1.0).max(0.0) * 0.5, (h - 1.0).max(0.0) * 0.5);
    (
        Matrix3::new(
            1.0 / s,
            0.0,
            -c.x / s,
            0.0,
            1.0 / s,
            -c.y / s,
            0.0,
            0.0,
            1.0,
        ),
        s,
        c,
    )
}

/// `v_ij` of Zhang (2000), eq. (8): `h_iᵀ B h_j = v_ijᵀ b`, `b = [B11, B12, B22, B13, B23, B33]`.
fn vij(h: &Matrix3<f64>, i: usize, j: usize) -> [f64; 6] {
    let (hi, hj) = (h.column(i), h.column(j));
    [
        hi[0] * hj[0],
        hi[0] * hj[1] + hi[1] * hj[0],
        hi[1] * hj[1],
        hi[2] * hj[0] + hi[0] * hj[2],
        hi[2] * hj[1] + hi[1] * hj[2],
        hi[2] * hj[2],
    ]
}

/// Closed-form intrinsics from ≥ 2 homographies board plane → pixels (Zhang, "A flexible new
/// technique for camera calibration", TPAMI 22(11), 2000, §3.1 and Appendix B).
///
/// Each view gives two linear constraints on the symmetric `B = K⁻ᵀK⁻¹`; `b` is the right
/// singular vector of the smallest singular value of the stacked 2n×6 matrix V. With 3 or more
/// views all five intrinsics (skew included) are solved; with 2 the zero-skew row `[0,1,0,0,0,0]`
/// is added, as the paper suggests. Homographies are first mapped to an image-centred frame of
/// unit scale for conditioning and the result mapped back.
///
/// Errors with [`CoreError::NoSolution`] when the views do not constrain K (all boards parallel,
/// or pure translation: the null space of V is not one-dimensional) or when the recovered B is
/// not positive definite (noise larger than the perspective effect, e.g. boards seen frontally
/// from far away); callers then fall back to [`intrinsics_fixed_centre`].
pub fn zhang_intrinsics(
    homographies: &[Matrix3<f64>],
    image_size: (u32, u32),
) -> CoreResult<Intrinsics> {
    let n = homographies.len();
    if n < 2 {
        return Err(CoreError::NoSolution(format!(
            "Zhang's method needs at least 2 views, got {n}"
        )));
    }
    let (norm, s, c) = image_frame(image_size);
    let mut rows: Vec<[f64; 6]> = Vec::with_capacity(2 * n + 1);
    for h in homographies {
        let hn = norm * h;
        let hn = hn / hn.norm();
        let v12 = vij(&hn, 0, 1);
        let v11 = vij(&hn, 0, 0);
        let v22 = vij(&hn, 1, 1);
        rows.push(v12);
        rows.push(std::array::from_fn(|k| v11[k] - v22[k]));
    }
    if n == 2 {
        rows.push([0.0, 1.0, 0.0, 0.0, 0.0, 0.0]);
    }
    let m = rows.len().max(6);
    let mut v = DMatrix::<f64>::zeros(m, 6);
    for (i, r) in rows.iter().enumerate() {
        v.row_mut(i).copy_from_slice(r);
    }
    let svd = v.svd(false, true);
    let v_t = svd
        .v_t
        .ok_or_else(|| CoreError::NoSolution("Zhang: SVD failed".into()))?;
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&i, &j| svd.singular_values[i].total_cmp(&svd.singular_values[j]));
    let sv = |k: usize| svd.singular_values[order[k]];
    if sv(1) <= DEGENERATE_RATIO * sv(order.len() - 1) {
        return Err(CoreError::NoSolution(
            "Zhang: the views do not constrain the intrinsics (boards parallel or too few distinct orientations)"
                .into(),
        ));
    }
    let row = v_t.row(order[0]);
    let mut b = [row[0], row[1], row[2], row[3], row[4], row[5]];
    if b[0] < 0.0 {
        b.iter_mut().for_each(|x| *x = -*x);
    }
    let [b11, b12, b22, b13, b23, b33] = b;
    let den = b11 * b22 - b12 * b12;
    let not_pd = || {
        CoreError::NoSolution(
            "Zhang: the estimated B = K⁻ᵀK⁻¹ is not positive definite (too little perspective in the views)"
                .into(),
        )
    };
    if !(b11 > 0.0 && den > 0.0) {
        return Err(not_pd());
    }
    let v0 = (b12 * b13 - b11 * b23) / den;
    let lambda = b33 - (b13 * b13 + v0 * (b12 * b13 - b11 * b23)) / b11;
    let ratio = lambda / b11;
    if ratio.is_nan() || ratio <= 0.0 {
        return Err(not_pd());
    }
    let alpha = (lambda / b11).sqrt();
    let beta = (lambda * b11 / den).sqrt();
    let gamma = -b12 * alpha * alpha * beta / lambda;
    let u0 = gamma * v0 / beta - b13 * alpha * alpha / lambda;
    let k = Intrinsics {
        fx: alpha * s,
        fy: beta * s,
        cx: u0 * s + c.x,
        cy: v0 * s + c.y,
        skew: gamma * s,
    };
    if [k.fx, k.fy, k.cx, k.cy, k.skew]
        .iter()
        .all(|x| x.is_finite())
    {
        Ok(k)
    } else {
        Err(not_pd())
    }
}

/// Focal lengths from ≥ 1 homography with the principal point known and zero skew: B is then
/// diagonal, `diag(1/fx², 1/fy², 1)` in a frame centred on c, and Zhang's two constraints per
/// view are linear in `(1/fx², 1/fy²)` (least squares over all views). This is also how
/// OpenCV initialises `calibrateCamera`; it is the fallback when the full closed form is
/// degenerate, and the initialisation under "fix principal point".
pub fn intrinsics_fixed_centre(
    homographies: &[Matrix3<f64>],
    centre: Vector2<f64>,
    image_size: (u32, u32),
) -> CoreResult<Intrinsics> {
    let (_, s, _) = image_frame(image_size);
    let norm = Matrix3::new(
        1.0 / s,
        0.0,
        -centre.x / s,
        0.0,
        1.0 / s,
        -centre.y / s,
        0.0,
        0.0,
        1.0,
    );
    let mut ata = Matrix2::<f64>::zeros();
    let mut atb = Vector2::<f64>::zeros();
    for h in homographies {
        let hn = norm * h;
        let hn = hn / hn.norm();
        let (h1, h2) = (hn.column(0), hn.column(1));
        let rows = [
            ([h1[0] * h2[0], h1[1] * h2[1]], -h1[2] * h2[2]),
            (
                [h1[0] * h1[0] - h2[0] * h2[0], h1[1] * h1[1] - h2[1] * h2[1]],
                -(h1[2] * h1[2] - h2[2] * h2[2]),
            ),
        ];
        for (a, y) in rows {
            let a = Vector2::new(a[0], a[1]);
            ata += a * a.transpose();
            atb += a * y;
        }
    }
    let x = ata
        .try_inverse()
        .map(|inv| inv * atb)
        .filter(|x| x[0] > 0.0 && x[1] > 0.0)
        .ok_or_else(|| {
            CoreError::NoSolution(
                "focal length cannot be estimated from these views (boards seen frontally?)".into(),
            )
        })?;
    Ok(Intrinsics {
        fx: s / x[0].sqrt(),
        fy: s / x[1].sqrt(),
        cx: centre.x,
        cy: centre.y,
        skew: 0.0,
    })
}

/// Pose of the board plane (z = 0) from its homography and K (Zhang 2000, §3.1):
/// `[r1 r2 t] = λ·K⁻¹H` with λ = 2/(‖K⁻¹h1‖ + ‖K⁻¹h2‖), sign chosen so the board is in front
/// of the camera, `r3 = r1 × r2`, and R the nearest rotation to `[r1 r2 r3]` (by SVD, Zhang's
/// Appendix C). Errors when K is singular or H is degenerate.
pub fn pose_from_homography(h: &Matrix3<f64>, k: &Matrix3<f64>) -> CoreResult<Se3> {
    let kinv = k
        .try_inverse()
        .ok_or_else(|| CoreError::NoSolution("pose: singular camera matrix".into()))?;
    let m = kinv * h;
    let (m1, m2, m3): (Vector3<f64>, Vector3<f64>, Vector3<f64>) =
        (m.column(0).into(), m.column(1).into(), m.column(2).into());
    let norms = m1.norm() + m2.norm();
    if !(norms.is_finite() && norms > 0.0) {
        return Err(CoreError::NoSolution("pose: degenerate homography".into()));
    }
    let mut lambda = 2.0 / norms;
    if m3.z * lambda < 0.0 {
        lambda = -lambda;
    }
    let r1 = m1 * lambda;
    let r2 = m2 * lambda;
    let r3 = r1.cross(&r2);
    let r = Matrix3::from_columns(&[r1, r2, r3]);
    let rotation = So3::from_matrix(&r).map_err(|e| CoreError::NoSolution(format!("pose: {e}")))?;
    Ok(Se3::new(rotation, m3 * lambda))
}
