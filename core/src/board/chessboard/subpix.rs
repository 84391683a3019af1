//! Sub-pixel corner refinement by fitting a quadratic saddle to the smoothed image.
//!
//! Method (Lucchese & Mitra, "Using saddle points for subpixel feature detection in camera
//! calibration targets", APCCAS 2002): fit `I ≈ a₀ + a₁x + a₂y + a₃x² + a₄xy + a₅y²` by
//! Gaussian-weighted least squares on a window around the current estimate and move to the
//! stationary point of the quadratic; iterate with the window re-centred (bilinear resampling)
//! until the step is below 10⁻³ px.
//!
//! Why it is unbiased where gradient-orthogonality (OpenCV `cornerSubPix`) is not: the image of
//! an X-junction of two straight edges is point-symmetric about the junction, and so is any
//! point-symmetric blur of it (defocus, linear motion, the smoothing we apply). A window
//! centred exactly on the junction therefore sees point-symmetric samples (bilinear
//! resampling at mirrored offsets uses mirrored weights), the odd coefficients a₁, a₂ vanish
//! and the junction is a fixed point of the iteration, whatever the angle between the edges
//! and the contrast. cornerSubPix's fixed 11×11 window instead reaches the neighbouring edges
//! on foreshortened rows and slides along them. Our window is scaled to the local corner
//! spacing so that it stays inside the four squares around the corner.
//!
//! The weighted least-squares operator depends only on the window, so it is computed once per
//! radius: each iteration is six dot products.

use nalgebra::{Matrix2, Matrix6, Vector2, Vector6};

use crate::board::filter::ImageF;

/// Precomputed least-squares operator for one window radius.
pub struct SaddleFitter {
    radius: i32,
    /// Rows: the six coefficients; columns: the window samples in raster order.
    op: Vec<[f64; 6]>,
}

impl SaddleFitter {
    /// Window `[-radius, radius]²` with Gaussian weights of σ = `radius / 1.5`.
    pub fn new(radius: i32) -> Self {
        let radius = radius.max(1);
        let sw = f64::from(radius) / 1.5;
        let mut ata = Matrix6::<f64>::zeros();
        let mut rows = Vec::new();
        for dy in -radius..=radius {
            for dx in -radius..=radius {
                let (x, y) = (f64::from(dx), f64::from(dy));
                let w = (-(x * x + y * y) / (2.0 * sw * sw)).exp();
                let a = Vector6::new(1.0, x, y, x * x, x * y, y * y);
                ata += w * a * a.transpose();
                rows.push((a, w));
            }
        }
        // The window is symmetric and has ≥ 9 samples, so AᵀWA is positive definite.
        let inv = ata.try_inverse().unwrap_or_else(Matrix6::zeros);
        let op = rows
            .into_iter()
            .map(|(a, w)| {
                let c = inv * a * w;
                [c[0], c[1], c[2], c[3], c[4], c[5]]
            })
            .collect();
        Self { radius, op }
    }

    /// The quadratic's coefficients on the window centred at `c` (inside the image with a
    /// margin of `radius`).
    fn fit(&self, s: &ImageF, c: [f64; 2], ramp: Vector2<f64>) -> [f64; 6] {
        let rad = self.radius;
        let mut coef = [0.0f64; 6];
        let (xs, ys) = (c[0] - f64::from(rad), c[1] - f64::from(rad));
        let (x0, y0) = (xs.floor(), ys.floor());
        let n = 2 * rad as usize + 1;
        if x0 < 0.0 || y0 < 0.0 || x0 as usize + n >= s.w || y0 as usize + n >= s.h {
            // At the far border the bilinear cell is clamped: sample by sample.
            let mut k = 0;
            for dy in -rad..=rad {
                let y = c[1] + f64::from(dy);
                for dx in -rad..=rad {
                    let v = f64::from(s.bilinear(c[0] + f64::from(dx), y))
                        / light(ramp, f64::from(dx), f64::from(dy));
                    for (ci, oi) in coef.iter_mut().zip(&self.op[k]) {
                        *ci += oi * v;
                    }
                    k += 1;
                }
            }
            return coef;
        }
        // Integer offsets share the fractional part: fixed bilinear weights over a window of
        // whole pixels.
        let (fx, fy) = ((xs - x0) as f32, (ys - y0) as f32);
        let (x0, y0) = (x0 as usize, y0 as usize);
        let w = s.w;
        let mut ops = self.op.chunks_exact(n);
        for j in 0..n {
            let r0 = &s.data[(y0 + j) * w + x0..(y0 + j) * w + x0 + n + 1];
            let r1 = &s.data[(y0 + j + 1) * w + x0..(y0 + j + 1) * w + x0 + n + 1];
            let Some(ops_row) = ops.next() else { break };
            let dy = j as f64 - f64::from(rad);
            for (i, o) in ops_row.iter().enumerate() {
                let a = r0[i] + fx * (r0[i + 1] - r0[i]);
                let b = r1[i] + fx * (r1[i + 1] - r1[i]);
                let v = f64::from(a + fy * (b - a)) / light(ramp, i as f64 - f64::from(rad), dy);
                for (ci, oi) in coef.iter_mut().zip(o) {
                    *ci += oi * v;
                }
            }
        }
        coef
    }

    /// Refines `start` to the saddle point of `s`. `None` when the window leaves the image,
    /// the fitted quadratic is not a saddle, or the estimate moves more than `max_shift` pixels
    /// from `start`.
    pub fn refine(&self, s: &ImageF, start: [f64; 2], max_shift: f64) -> Option<[f64; 2]> {
        self.refine_lit(s, start, max_shift, Vector2::zeros())
    }

    /// [`SaddleFitter::refine`] under a known relative light ramp `(g, h)` per pixel (the
    /// image is `L₀(1 + g·x + h·y)` times the pattern near the corner): every sample of the
    /// window is divided by the ramp before the fit, so the junction stays the fixed point under
    /// uneven light.
    pub fn refine_lit(
        &self,
        s: &ImageF,
        start: [f64; 2],
        max_shift: f64,
        ramp: Vector2<f64>,
    ) -> Option<[f64; 2]> {
        let r = f64::from(self.radius);
        let mut c = start;
        for _ in 0..20 {
            if !s.contains(c[0], c[1], r) {
                return None;
            }
            let coef = self.fit(s, c, ramp);
            let hess = Matrix2::new(2.0 * coef[3], coef[4], coef[4], 2.0 * coef[5]);
            let det = hess.determinant();
            // A saddle has eigenvalues of opposite signs.
            if det >= 0.0 || !det.is_finite() {
                return None;
            }
            let g = Vector2::new(coef[1], coef[2]);
            let inv = hess.try_inverse()?;
            let mut step = -(inv * g);
            // Damp large steps: the quadratic model only holds near the centre.
            let n = step.norm();
            if n > 0.5 * r {
                step *= 0.5 * r / n;
            }
            c = [c[0] + step.x, c[1] + step.y];
            if (c[0] - start[0]).hypot(c[1] - start[1]) > max_shift {
                return None;
            }
            if n < 1e-3 {
                return Some(c);
            }
        }
        Some(c)
    }
}

/// The light ramp's factor `1 + g·dx + h·dy` at offset `(dx, dy)` from the window's centre
/// (kept away from zero: a ramp is a few percent per pixel at most).
#[inline]
fn light(ramp: Vector2<f64>, dx: f64, dy: f64) -> f64 {
    (1.0 + ramp.x * dx + ramp.y * dy).max(0.1)
}
