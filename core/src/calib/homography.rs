//! Plane-to-image homographies: normalised DLT plus Gauss-Newton refinement.

use nalgebra::{DMatrix, Matrix2, Matrix3, SMatrix, SVector, Vector2, Vector3};

use crate::error::{CoreError, CoreResult};

/// Singular-value ratio below which a point set or a DLT system is called degenerate.
const DEGENERATE_RATIO: f64 = 1e-9;
/// Gauss-Newton refinement steps after the DLT.
const REFINE_ITERATIONS: usize = 10;

/// Hartley's normalising similarity: centroid to the origin, mean distance √2 (Hartley, "In
/// defense of the eight-point algorithm", TPAMI 1997). Without it the DLT's design matrix mixes
/// entries of order 1 and 10⁵ and the SVD loses most of its digits.
fn normaliser(pts: &[Vector2<f64>]) -> CoreResult<Matrix3<f64>> {
    let n = pts.len() as f64;
    let c = pts.iter().fold(Vector2::zeros(), |a, p| a + p) / n;
    let mean_dist = pts.iter().map(|p| (p - c).norm()).sum::<f64>() / n;
    if !(mean_dist.is_finite() && mean_dist > 0.0) {
        return Err(CoreError::NoSolution(
            "homography: all points coincide".into(),
        ));
    }
    let s = std::f64::consts::SQRT_2 / mean_dist;
    Ok(Matrix3::new(
        s,
        0.0,
        -s * c.x,
        0.0,
        s,
        -s * c.y,
        0.0,
        0.0,
        1.0,
    ))
}

fn apply(h: &Matrix3<f64>, p: &Vector2<f64>) -> Vector2<f64> {
    let q = h * Vector3::new(p.x, p.y, 1.0);
    Vector2::new(q.x / q.z, q.y / q.z)
}

/// Errors when the points are (nearly) collinear: a homography from them is not unique.
fn check_spread(pts: &[Vector2<f64>]) -> CoreResult<()> {
    let n = pts.len() as f64;
    let c = pts.iter().fold(Vector2::zeros(), |a, p| a + p) / n;
    let cov = pts.iter().fold(Matrix2::zeros(), |a, p| {
        let d = p - c;
        a + d * d.transpose()
    }) / n;
    let ev = cov.symmetric_eigenvalues();
    let (lo, hi) = (ev.min(), ev.max());
    if !(hi > 0.0 && lo > DEGENERATE_RATIO * hi) {
        return Err(CoreError::NoSolution(
            "homography: the points are collinear".into(),
        ));
    }
    Ok(())
}

/// Homography `H` with `dst ≃ H·src` by the normalised direct linear transform (Hartley &
/// Zisserman, "Multiple View Geometry", 2nd ed., Alg. 4.2): both point sets are normalised,
/// the 2n×9 system `A·h = 0` is solved by SVD (the right singular vector of the smallest singular
/// value), and the normalisation is undone. Needs ≥ 4 correspondences, not collinear on either
/// side. The result has unit Frobenius norm and `H[(2,2)] ≥ 0`.
pub fn homography_dlt(src: &[Vector2<f64>], dst: &[Vector2<f64>]) -> CoreResult<Matrix3<f64>> {
    if src.len() != dst.len() {
        return Err(CoreError::input(format!(
            "homography: {} source points but {} destination points",
            src.len(),
            dst.len()
        )));
    }
    if src.len() < 4 {
        return Err(CoreError::input(format!(
            "homography: needs at least 4 points, got {}",
            src.len()
        )));
    }
    if src
        .iter()
        .chain(dst)
        .any(|p| !(p.x.is_finite() && p.y.is_finite()))
    {
        return Err(CoreError::input("homography: non-finite point"));
    }
    check_spread(src)?;
    check_spread(dst)?;
    let ts = normaliser(src)?;
    let td = normaliser(dst)?;
    // At least 9 rows so that the SVD returns the full 9×9 right basis.
    let rows = (2 * src.len()).max(9);
    let mut a = DMatrix::<f64>::zeros(rows, 9);
    for (i, (s, d)) in src.iter().zip(dst).enumerate() {
        let s = apply(&ts, s);
        let d = apply(&td, d);
        let r = 2 * i;
        a.row_mut(r)
            .copy_from_slice(&[-s.x, -s.y, -1.0, 0.0, 0.0, 0.0, d.x * s.x, d.x * s.y, d.x]);
        a.row_mut(r + 1).copy_from_slice(&[
            0.0,
            0.0,
            0.0,
            -s.x,
            -s.y,
            -1.0,
            d.y * s.x,
            d.y * s.y,
            d.y,
        ]);
    }
    let svd = a.svd(false, true);
    let v_t = svd
        .v_t
        .ok_or_else(|| CoreError::NoSolution("homography: SVD failed".into()))?;
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&i, &j| svd.singular_values[i].total_cmp(&svd.singular_values[j]));
    let (smallest, second) = (order[0], order[1]);
    let largest = order[order.len() - 1];
    if svd.singular_values[second] <= DEGENERATE_RATIO * svd.singular_values[largest] {
        return Err(CoreError::NoSolution(
            "homography: degenerate configuration (the solution is not unique)".into(),
        ));
    }
    let h = v_t.row(smallest);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let td_inv = td
        .try_inverse()
        .ok_or_else(|| CoreError::NoSolution("homography: singular normaliser".into()))?;
    Ok(unit(td_inv * hn * ts))
}

/// Scales to unit Frobenius norm with a non-negative last entry.
fn unit(h: Matrix3<f64>) -> Matrix3<f64> {
    let n = h.norm();
    if h[(2, 2)] < 0.0 { -h / n } else { h / n }
}

/// Sum of squared transfer errors `‖H·src − dst‖²`, or `None` if a point maps to infinity.
fn transfer_cost(h: &Matrix3<f64>, src: &[Vector2<f64>], dst: &[Vector2<f64>]) -> Option<f64> {
    let mut c = 0.0;
    for (s, d) in src.iter().zip(dst) {
        let q = h * Vector3::new(s.x, s.y, 1.0);
        if q.z.abs() < 1e-12 {
            return None;
        }
        c += (Vector2::new(q.x / q.z, q.y / q.z) - d).norm_squared();
    }
    c.is_finite().then_some(c)
}

/// Refines `h` by Gauss-Newton on the transfer error in the destination image (the maximum-
/// likelihood estimate when only the destination points are noisy, which is the case for a
/// printed board seen by a camera; Zhang 2000, §3.1). Works in Hartley-normalised coordinates
/// with `H[(2,2)] = 1` fixed (the board centroid is in front of the camera, so that entry is not
/// zero); every step must decrease the cost (halved until it does), and the DLT result is
/// returned unchanged when nothing improves it.
pub fn refine_homography(
    h: &Matrix3<f64>,
    src: &[Vector2<f64>],
    dst: &[Vector2<f64>],
) -> CoreResult<Matrix3<f64>> {
    let (Ok(ts), Ok(td)) = (normaliser(src), normaliser(dst)) else {
        return Ok(*h);
    };
    let (Some(ts_inv), Some(td_inv)) = (ts.try_inverse(), td.try_inverse()) else {
        return Ok(*h);
    };
    let s: Vec<Vector2<f64>> = src.iter().map(|p| apply(&ts, p)).collect();
    let d: Vec<Vector2<f64>> = dst.iter().map(|p| apply(&td, p)).collect();
    let mut hn = td * h * ts_inv;
    if hn[(2, 2)].abs() < 1e-8 * hn.norm() {
        return Ok(*h);
    }
    hn /= hn[(2, 2)];
    let Some(mut cost) = transfer_cost(&hn, &s, &d) else {
        return Ok(*h);
    };
    for _ in 0..REFINE_ITERATIONS {
        let mut jtj = SMatrix::<f64, 8, 8>::zeros();
        let mut jtr = SVector::<f64, 8>::zeros();
        for (p, q) in s.iter().zip(&d) {
            let w = hn * Vector3::new(p.x, p.y, 1.0);
            let (u, v) = (w.x / w.z, w.y / w.z);
            let iz = 1.0 / w.z;
            let ju = [
                p.x * iz,
                p.y * iz,
                iz,
                0.0,
                0.0,
                0.0,
                -u * p.x * iz,
                -u * p.y * iz,
            ];
            let jv = [
                0.0,
                0.0,
                0.0,
                p.x * iz,
                p.y * iz,
                iz,
                -v * p.x * iz,
                -v * p.y * iz,
            ];
            let (ru, rv) = (u - q.x, v - q.y);
            for i in 0..8 {
                jtr[i] += ju[i] * ru + jv[i] * rv;
                for j in 0..8 {
                    jtj[(i, j)] += ju[i] * ju[j] + jv[i] * jv[j];
                }
            }
        }
        let Some(chol) = jtj.cholesky() else {
            break;
        };
        let step = chol.solve(&(-jtr));
        let mut scale = 1.0;
        let mut improved = false;
        while scale > 1e-4 {
            let mut cand = hn;
            for k in 0..8 {
                cand[(k / 3, k % 3)] += scale * step[k];
            }
            if let Some(c) = transfer_cost(&cand, &s, &d)
                && c < cost
            {
                let done = cost - c <= 1e-14 * cost.max(1e-300);
                hn = cand;
                cost = c;
                improved = !done;
                break;
            }
            scale *= 0.5;
        }
        if !improved {
            break;
        }
    }
    Ok(unit(td_inv * hn * ts))
}

/// Normalised DLT followed by Gauss-Newton refinement of the transfer error
/// ([`homography_dlt`], [`refine_homography`]).
pub fn homography(src: &[Vector2<f64>], dst: &[Vector2<f64>]) -> CoreResult<Matrix3<f64>> {
    let h = homography_dlt(src, dst)?;
    refine_homography(&h, src, dst)
}

/// Applies a homography to a point (`None` if it maps to infinity).
pub fn transfer(h: &Matrix3<f64>, p: &Vector2<f64>) -> Option<Vector2<f64>> {
    let q = h * Vector3::new(p.x, p.y, 1.0);
    (q.z.abs() > 1e-300).then(|| Vector2::new(q.x / q.z, q.y / q.z))
}
