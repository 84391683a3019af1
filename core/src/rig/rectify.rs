//! Stereo rectification (Bouguet's method, as OpenCV `stereoRectify` computes it) for any pair
//! of calibrated cameras, the rectified epipolar error, and resampling of an image into the
//! rectified view.
//!
//! Bouguet splits the relative rotation evenly between the two cameras (each turns by half of
//! it), then turns both so the baseline lies along the image x axis (y for a vertical rig); the
//! rectified cameras are one virtual pinhole with a shared focal length and principal point, so
//! epipolar lines become image rows. Because the rectifying maps go through the models' own
//! `unproject`, the same construction serves fisheye and double-sphere cameras (their rectified
//! view is a virtual pinhole: the periphery beyond its field of view is cut).

use nalgebra::{Matrix3, Matrix3x4, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use super::problem::Obs;
use crate::camera::{Camera, CameraModel};
use crate::error::{CoreError, CoreResult};
use crate::io::Gray;
use crate::lie::{Se3, So3};

/// Rays this close to the rectified image plane (z of the unit bearing) are not projected.
const MIN_Z: f64 = 1e-3;

/// Rectification of a pair `(a, b)` with `x_b = R·x_a + T`, in OpenCV's names.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct Rectification {
    /// Size of the rectified images `[width, height]` (that of camera a).
    pub image_size: [u32; 2],
    /// `R`: rotation from camera a's frame to camera b's, row-major.
    pub r: [[f64; 3]; 3],
    /// `T`: translation of camera a's frame origin in camera b's frame, board units.
    pub t: [f64; 3],
    /// Essential matrix `E = [T]×·R`.
    pub e: [[f64; 3]; 3],
    /// Fundamental matrix `F = K_b⁻ᵀ·E·K_a⁻¹` between undistorted pixels (pinhole pairs only).
    pub f: Option<[[f64; 3]; 3]>,
    /// Rectifying rotation of camera a (OpenCV `R1`).
    pub r1: [[f64; 3]; 3],
    /// Rectifying rotation of camera b (`R2`).
    pub r2: [[f64; 3]; 3],
    /// Projection of the rectified camera a (`P1`, 3×4).
    pub p1: [[f64; 4]; 3],
    /// Projection of the rectified camera b (`P2`, 3×4; `P2[0][3] = f·Tx`, or `P2[1][3]` for a
    /// vertical rig).
    pub p2: [[f64; 4]; 3],
    /// Disparity-to-depth matrix (`Q`, 4×4).
    pub q: [[f64; 4]; 4],
    /// The baseline is mostly vertical: epipolar lines are columns instead of rows.
    pub vertical: bool,
}

impl Rectification {
    fn mat3(m: &[[f64; 3]; 3]) -> Matrix3<f64> {
        Matrix3::from_fn(|i, j| m[i][j])
    }

    /// `R1` (`b = false`) or `R2` as a matrix.
    pub fn rotation(&self, b: bool) -> Matrix3<f64> {
        Self::mat3(if b { &self.r2 } else { &self.r1 })
    }

    /// `P1` or `P2` as a matrix.
    pub fn projection(&self, b: bool) -> Matrix3x4<f64> {
        let p = if b { &self.p2 } else { &self.p1 };
        Matrix3x4::from_fn(|i, j| p[i][j])
    }
}

fn rows3(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))
}

/// The pinhole `K` of a camera (every model stores fx, fy, cx, cy first).
fn k_matrix(c: &Camera) -> Matrix3<f64> {
    let p = c.params();
    Matrix3::new(p[0], 0.0, p[2], 0.0, p[1], p[3], 0.0, 0.0, 1.0)
}

/// A pixel of `cam` in the rectified view given by rotation `r` and projection `p`, or `None`
/// when its ray does not reach the rectified image plane.
pub fn rectify_pixel(
    cam: &Camera,
    r: &Matrix3<f64>,
    p: &Matrix3x4<f64>,
    px: &Vector2<f64>,
) -> Option<Vector2<f64>> {
    let b = r * cam.unproject(px)?;
    if b.z < MIN_Z {
        return None;
    }
    Some(Vector2::new(
        p[(0, 0)] * b.x / b.z + p[(0, 2)],
        p[(1, 1)] * b.y / b.z + p[(1, 2)],
    ))
}

/// Bouguet rectification of cameras a and b, where `t_ba` maps camera a's frame into camera
/// b's (`x_b = R·x_a + T`), for rectified images of `size`. The focal length is the smaller of
/// the two cameras' (so no direction is magnified), the principal point the one that centres
/// the mean of both images' rectified borders (OpenCV's `CALIB_ZERO_DISPARITY`: one principal
/// point for both).
pub fn stereo_rectify(
    a: &Camera,
    b: &Camera,
    t_ba: &Se3,
    size: [u32; 2],
) -> CoreResult<Rectification> {
    let r = t_ba.rotation.matrix();
    let t = t_ba.translation;
    if t.norm() <= 0.0 || !t.norm().is_finite() {
        return Err(CoreError::NoSolution(
            "the two cameras have the same optical centre: no baseline to rectify".into(),
        ));
    }
    // Half of the inverse rotation: R = r_r⁻², so R2·R = R1 below.
    let r_r = So3::exp(&(-0.5 * t_ba.rotation.log())).matrix();
    let t_half = r_r * t;
    let vertical = t_half.y.abs() > t_half.x.abs();
    let idx = usize::from(vertical);
    let c = t_half[idx];
    let mut uu = Vector3::zeros();
    uu[idx] = if c > 0.0 { 1.0 } else { -1.0 };
    let ww = t_half.cross(&uu);
    let nw = ww.norm();
    let w_r = if nw > 0.0 {
        So3::exp(&(ww * ((c.abs() / t_half.norm()).clamp(-1.0, 1.0).acos() / nw))).matrix()
    } else {
        Matrix3::identity()
    };
    let r1 = w_r * r_r.transpose();
    let r2 = w_r * r_r;
    let t_new = r2 * t;

    // Focal: the smaller focal across the epipolar direction's normal.
    let pa = a.params();
    let pb = b.params();
    let fsel = if vertical { 0 } else { 1 };
    let f = pa[fsel].min(pb[fsel]);
    // Principal point: centre the rectified borders of both images.
    let (w, h) = (f64::from(size[0]), f64::from(size[1]));
    let mut sum = Vector2::zeros();
    let mut n = 0.0;
    let unit = Matrix3x4::new(f, 0.0, 0.0, 0.0, 0.0, f, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0);
    for (cam, rot) in [(a, &r1), (b, &r2)] {
        for k in 0..16 {
            let s = k as f64 / 4.0;
            let px = match k / 4 {
                0 => Vector2::new(s.fract() * (w - 1.0), 0.0),
                1 => Vector2::new(w - 1.0, s.fract() * (h - 1.0)),
                2 => Vector2::new((1.0 - s.fract()) * (w - 1.0), h - 1.0),
                _ => Vector2::new(0.0, (1.0 - s.fract()) * (h - 1.0)),
            };
            if let Some(q) = rectify_pixel(cam, rot, &unit, &px) {
                sum += q;
                n += 1.0;
            }
        }
    }
    if n == 0.0 {
        return Err(CoreError::NoSolution(
            "no image border point reaches the rectified view".into(),
        ));
    }
    let centre = Vector2::new(0.5 * (w - 1.0), 0.5 * (h - 1.0)) - sum / n;
    let (cx, cy) = (centre.x, centre.y);
    let p1 = [[f, 0.0, cx, 0.0], [0.0, f, cy, 0.0], [0.0, 0.0, 1.0, 0.0]];
    let mut p2 = p1;
    p2[idx][3] = t_new[idx] * f;
    let tx = t_new[idx];
    let q = [
        [1.0, 0.0, 0.0, -cx],
        [0.0, 1.0, 0.0, -cy],
        [0.0, 0.0, 0.0, f],
        [0.0, 0.0, -1.0 / tx, 0.0],
    ];
    let e = So3::hat(&t) * r;
    let pinholes = matches!(a, Camera::PinholeRadTan(_)) && matches!(b, Camera::PinholeRadTan(_));
    let fm = if pinholes {
        let ka = k_matrix(a).try_inverse();
        let kb = k_matrix(b).try_inverse();
        ka.zip(kb).map(|(ka, kb)| {
            let m = kb.transpose() * e * ka;
            let s = m[(2, 2)];
            rows3(&if s.abs() > 1e-12 { m / s } else { m })
        })
    } else {
        None
    };
    Ok(Rectification {
        image_size: size,
        r: rows3(&r),
        t: t.into(),
        e: rows3(&e),
        f: fm,
        r1: rows3(&r1),
        r2: rows3(&r2),
        p1,
        p2,
        q,
        vertical,
    })
}

/// RMS of the across-epipolar-line difference (y for a horizontal rig) of every corner seen by
/// both cameras `a` and `b` in the same frame, after rectification; and how many pairs.
pub(super) fn epipolar_rms(
    cam_a: &Camera,
    cam_b: &Camera,
    rect: &Rectification,
    blocks: &[Vec<Obs>],
    a: usize,
    b: usize,
) -> (f64, usize) {
    let (ra, rb) = (rect.rotation(false), rect.rotation(true));
    let (pa, pb) = (rect.projection(false), rect.projection(true));
    let across = usize::from(!rect.vertical);
    let (mut s, mut n) = (0.0, 0usize);
    for obs in blocks {
        for oa in obs.iter().filter(|o| o.camera == a) {
            if let Some(ob) = obs.iter().find(|o| o.camera == b && o.index == oa.index)
                && let (Some(qa), Some(qb)) = (
                    rectify_pixel(cam_a, &ra, &pa, &oa.pixel),
                    rectify_pixel(cam_b, &rb, &pb, &ob.pixel),
                )
            {
                s += (qa[across] - qb[across]).powi(2);
                n += 1;
            }
        }
    }
    (
        if n > 0 {
            (s / n as f64).sqrt()
        } else {
            f64::NAN
        },
        n,
    )
}

/// Resamples `img` from camera `cam` into the rectified view (`r`, `p`) of the same size,
/// bilinearly; pixels without a source are black. This is the rectification map applied once.
pub fn rectify_gray(img: &Gray, cam: &Camera, r: &Matrix3<f64>, p: &Matrix3x4<f64>) -> Gray {
    let (w, h) = (img.width as usize, img.height as usize);
    let mut out = vec![0u8; w * h];
    let rt = r.transpose();
    let (f, fy, cx, cy) = (p[(0, 0)], p[(1, 1)], p[(0, 2)], p[(1, 2)]);
    for v in 0..h {
        for u in 0..w {
            let ray = rt * Vector3::new((u as f64 - cx) / f, (v as f64 - cy) / fy, 1.0);
            let Some(src) = cam.project(&ray) else {
                continue;
            };
            let (x, y) = (src.x, src.y);
            if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f64 && y <= (h - 1) as f64) {
                continue;
            }
            let (x0, y0) = (x.floor() as usize, y.floor() as usize);
            let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
            let (ax, ay) = (x - x0 as f64, y - y0 as f64);
            let g = |xx: usize, yy: usize| f64::from(img.data[yy * w + xx]);
            let val = (1.0 - ay) * ((1.0 - ax) * g(x0, y0) + ax * g(x1, y0))
                + ay * ((1.0 - ax) * g(x0, y1) + ax * g(x1, y1));
            out[v * w + u] = val.round().clamp(0.0, 255.0) as u8;
        }
    }
    Gray {
        width: img.width,
        height: img.height,
        data: out,
    }
}
