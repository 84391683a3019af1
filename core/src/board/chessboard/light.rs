//! The light falling on a chessboard, read off its white squares.
//!
//! Vignetting or a lamp to one side multiplies the image by a smooth `L(x)`; near a corner,
//! `L ≈ L(c)(1 + g·(x − c))` adds the mean grey level times the ramp `g` to the saddle fit's
//! gradient and moves the corner (see `subpix`). The centres of the white squares are flat,
//! far from every edge, and all print the same white, so their grey levels sample `L`
//! directly: a plane fitted to those near a corner (Gaussian weights, σ = 1.5 squares) gives `L`
//! and its gradient there, and `g = ∇L / L`. Black squares are left out: their low levels
//! make ratios noisy and blur from the white neighbours leaks into them.

use nalgebra::Vector2;

use super::subpix::SaddleFitter;
use crate::board::filter::ImageF;

/// Smallest white square (pixels) whose centre is read as light: on smaller squares blur from
/// the black neighbours reaches the centre, and a board shrinking with distance would pass
/// for a light ramp (on the BoofCV fisheye set, squares of 10–20 px made the calibration worse).
const MIN_SIDE_PX: f64 = 20.0;

/// Illumination over the board, sampled at the centres of its white squares.
pub(super) struct LightField {
    /// White square centres, their grey levels and the median square side.
    white: Vec<(Vector2<f64>, f64)>,
    side: f64,
}

impl LightField {
    /// Fits the field to the white squares of the grid `g[j][i]` (refined corners). `None` on
    /// boards too small to sample (fewer than 4 white squares of at least [`MIN_SIDE_PX`]) or without
    /// contrast.
    pub(super) fn fit(s: &ImageF, g: &[Vec<[f64; 2]>]) -> Option<Self> {
        let (gh, gw) = (g.len(), g.first()?.len());
        let mut squares = Vec::new();
        let mut sides = Vec::new();
        for j in 0..gh.saturating_sub(1) {
            for i in 0..gw.saturating_sub(1) {
                let q = [g[j][i], g[j][i + 1], g[j + 1][i + 1], g[j + 1][i]];
                let c = Vector2::new(
                    0.25 * q.iter().map(|p| p[0]).sum::<f64>(),
                    0.25 * q.iter().map(|p| p[1]).sum::<f64>(),
                );
                let side = (0..4)
                    .map(|k| {
                        let (a, b) = (q[k], q[(k + 1) % 4]);
                        (a[0] - b[0]).hypot(a[1] - b[1])
                    })
                    .fold(f64::MAX, f64::min);
                if side < MIN_SIDE_PX {
                    continue;
                }
                let d = 0.15 * side;
                let mut acc = 0.0;
                let mut ok = true;
                for (dx, dy) in [(0.0, 0.0), (d, 0.0), (-d, 0.0), (0.0, d), (0.0, -d)] {
                    if !s.contains(c.x + dx, c.y + dy, 1.0) {
                        ok = false;
                        break;
                    }
                    acc += f64::from(s.bilinear(c.x + dx, c.y + dy));
                }
                if ok {
                    squares.push((c, acc / 5.0));
                    sides.push(side);
                }
            }
        }
        let (lo, hi) = squares
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), q| (a.min(q.1), b.max(q.1)));
        if squares.is_empty() || hi - lo < 10.0 {
            return None;
        }
        let white: Vec<(Vector2<f64>, f64)> = squares
            .into_iter()
            .filter(|q| q.1 > 0.5 * (lo + hi))
            .collect();
        if white.len() < 4 {
            return None;
        }
        sides.sort_by(f64::total_cmp);
        Some(Self {
            side: sides[sides.len() / 2],
            white,
        })
    }

    /// The relative ramp `∇L / L` per pixel at image point `c`, from a plane through the white
    /// squares weighted by their distance to `c` (Gaussian, σ = 1.5 squares).
    pub(super) fn ramp_local(&self, c: [f64; 2]) -> Option<Vector2<f64>> {
        let c = Vector2::from(c);
        let sig = 1.5 * self.side;
        let mut ata = nalgebra::Matrix3::<f64>::zeros();
        let mut atb = nalgebra::Vector3::<f64>::zeros();
        for (p, v) in &self.white {
            let d = p - c;
            let w = (-d.norm_squared() / (2.0 * sig * sig)).exp();
            let a = nalgebra::Vector3::new(1.0, d.x / sig, d.y / sig);
            ata += w * a * a.transpose();
            atb += w * *v * a;
        }
        let x = ata.try_inverse()? * atb;
        (x[0] > 1.0).then(|| Vector2::new(x[1], x[2]) / (x[0] * sig))
    }
}

/// Refines every corner of the grid `g[j][i]` once more, from where the plain fit put it, with
/// the light ramp measured on the white squares divided out; a corner whose refit fails keeps
/// its plain position. `spacing(g, i, j)` is the distance to the nearest grid neighbour.
pub(super) fn relight(
    s: &ImageF,
    g: &mut [Vec<[f64; 2]>],
    fitters: &mut [Option<SaddleFitter>],
    spacing: impl Fn(&Vec<Vec<[f64; 2]>>, usize, usize) -> f64,
) {
    let first: Vec<Vec<[f64; 2]>> = g.to_vec();
    let Some(field) = LightField::fit(s, &first) else {
        return;
    };
    for (j, row) in g.iter_mut().enumerate() {
        for (i, corner) in row.iter_mut().enumerate() {
            let Some(ramp) = field.ramp_local(first[j][i]) else {
                continue;
            };
            let d = spacing(&first, i, j);
            let r0 = ((0.3 * d).round() as i32).clamp(2, 8);
            for radius in (2..=r0).rev() {
                let f = fitters[radius as usize].get_or_insert_with(|| SaddleFitter::new(radius));
                if let Some(p) = f.refine_lit(s, first[j][i], (0.1 * d).max(0.5), ramp) {
                    *corner = p;
                    break;
                }
            }
        }
    }
}
