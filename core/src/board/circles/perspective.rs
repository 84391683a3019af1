//! Perspective correction of circle centres.
//!
//! A circle seen in perspective is an ellipse, but the centre of that ellipse is not the image
//! of the circle's centre: the near half of the circle looks bigger than the far half, so the
//! ellipse centre lies on the near side of the projected centre (away from the vanishing line),
//! by an amount that grows with the circle's size and the tilt
//! (Heikkilä, "Geometric camera calibration using circular control points", IEEE PAMI 22(10),
//! 2000; Mallon & Whelan, "Which pattern? Biasing aspects of planar calibration patterns and
//! detection methods", Pattern Recognition Letters 28, 2007).
//!
//! The bias follows from the conic. The circle of centre `o` and radius `R` on the board is the
//! conic `C`; under the board-to-image homography `H` it becomes `C' = H⁻ᵀ·C·H⁻¹`, whose centre
//! is the pole of the line at infinity, `C'⁻¹·(0, 0, 1)ᵀ = H·C⁻¹·Hᵀ·(0, 0, 1)ᵀ` (the dual conic
//! `C⁻¹` maps through `H` without inverses). So with `H` estimated from the measured centres,
//! `bias = centre(H·C·Hᵀ) − H·o` for every circle, and `measured − bias` is the projected
//! centre. `H` is then re-estimated from the corrected centres and the bias recomputed from the
//! raw ones; three rounds make the bias converge far below the noise (its error is second order
//! in the error of `H`). Lens distortion is ignored here: it bends the lattice over the whole
//! board but changes the bias, a local quantity, very little.

use nalgebra::{Matrix3, Vector2, Vector3};

/// Rounds of homography estimate and bias correction.
const ROUNDS: usize = 3;

/// Image of the centre of the ellipse that `h` maps the circle `(o, radius)` to.
pub fn ellipse_centre(h: &Matrix3<f64>, o: [f64; 2], radius: f64) -> Option<[f64; 2]> {
    // Dual conic of the circle (x − o)² = R²: adj of [[1, 0, −ox], [0, 1, −oy], [−ox, −oy,
    // |o|² − R²]] up to scale.
    let dual = Matrix3::new(
        o[0] * o[0] - radius * radius,
        o[0] * o[1],
        o[0],
        o[0] * o[1],
        o[1] * o[1] - radius * radius,
        o[1],
        o[0],
        o[1],
        1.0,
    );
    let c = h * dual * h.transpose() * Vector3::z();
    (c.z.abs() > f64::EPSILON * c.norm()).then(|| [c.x / c.z, c.y / c.z])
}

/// Image of the board point `o`.
pub fn project(h: &Matrix3<f64>, o: [f64; 2]) -> Option<[f64; 2]> {
    let p = h * Vector3::new(o[0], o[1], 1.0);
    (p.z.abs() > f64::EPSILON * p.norm()).then(|| [p.x / p.z, p.y / p.z])
}

/// Projected circle centres from measured ellipse centres `raw` of circles of `radius` at board
/// positions `board` (see the module docs). `None` when no homography fits.
pub fn correct(raw: &[[f64; 2]], board: &[[f64; 2]], radius: f64) -> Option<Vec<[f64; 2]>> {
    let src: Vec<Vector2<f64>> = board.iter().map(|p| Vector2::new(p[0], p[1])).collect();
    let mut out = raw.to_vec();
    for _ in 0..ROUNDS {
        let dst: Vec<Vector2<f64>> = out.iter().map(|p| Vector2::new(p[0], p[1])).collect();
        let h = crate::calib::homography(&src, &dst).ok()?;
        for ((o, m), q) in board.iter().zip(raw).zip(out.iter_mut()) {
            let e = ellipse_centre(&h, *o, radius)?;
            let p = project(&h, *o)?;
            *q = [m[0] - (e[0] - p[0]), m[1] - (e[1] - p[1])];
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tilted view: the ellipse centre of the image conic equals the centre of the ellipse
    /// through projected circle points (checked by fitting), and differs from `H·o`.
    #[test]
    fn conic_centre_matches_projected_points() {
        let r = nalgebra::Rotation3::new(Vector3::new(1.0, 0.3, 0.0));
        let k = Matrix3::new(800.0, 0.0, 400.0, 0.0, 800.0, 300.0, 0.0, 0.0, 1.0);
        let t = Vector3::new(-0.05, -0.02, 0.4);
        let m = Matrix3::from_columns(&[
            r.matrix().column(0).into_owned(),
            r.matrix().column(1).into_owned(),
            t,
        ]);
        let h = k * m;
        let (o, rad) = ([0.03, 0.02], 0.01);
        // Extreme points of the projected circle along x and y give the ellipse centre as the
        // midpoints of the extremes.
        let pts: Vec<[f64; 2]> = (0..20_000)
            .filter_map(|i| {
                let a = i as f64 / 20_000.0 * std::f64::consts::TAU;
                project(&h, [o[0] + rad * a.cos(), o[1] + rad * a.sin()])
            })
            .collect();
        let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for p in &pts {
            x0 = x0.min(p[0]);
            x1 = x1.max(p[0]);
            y0 = y0.min(p[1]);
            y1 = y1.max(p[1]);
        }
        let e = ellipse_centre(&h, o, rad).expect("finite");
        assert!((e[0] - (x0 + x1) / 2.0).abs() < 1e-4, "{e:?} {x0} {x1}");
        assert!((e[1] - (y0 + y1) / 2.0).abs() < 1e-4, "{e:?} {y0} {y1}");
        let p = project(&h, o).expect("finite");
        assert!((e[0] - p[0]).hypot(e[1] - p[1]) > 0.1, "{e:?} {p:?}");
    }

    /// Exact ellipse centres of a tilted grid are corrected to the projected centres.
    #[test]
    fn correction_recovers_projected_centres() {
        let r = nalgebra::Rotation3::new(Vector3::new(1.05, 0.0, 0.2));
        let k = Matrix3::new(900.0, 0.0, 640.0, 0.0, 900.0, 480.0, 0.0, 0.0, 1.0);
        let t = Vector3::new(-0.1, -0.05, 0.35);
        let m = Matrix3::from_columns(&[
            r.matrix().column(0).into_owned(),
            r.matrix().column(1).into_owned(),
            t,
        ]);
        let h = k * m;
        let board: Vec<[f64; 2]> = (0..35)
            .map(|i| [(i % 7) as f64 * 0.03, (i / 7) as f64 * 0.03])
            .collect();
        let rad = 0.01;
        let raw: Vec<[f64; 2]> = board
            .iter()
            .map(|o| ellipse_centre(&h, *o, rad).expect("finite"))
            .collect();
        let truth: Vec<[f64; 2]> = board
            .iter()
            .map(|o| project(&h, *o).expect("finite"))
            .collect();
        let fixed = correct(&raw, &board, rad).expect("homography");
        let worst_raw = raw
            .iter()
            .zip(&truth)
            .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
            .fold(0.0, f64::max);
        let worst = fixed
            .iter()
            .zip(&truth)
            .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
            .fold(0.0, f64::max);
        assert!(worst_raw > 0.1, "raw bias {worst_raw}");
        assert!(worst < 1e-3, "corrected {worst}");
    }
}
