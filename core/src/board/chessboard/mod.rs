//! Chessboard detection with sub-pixel corners.
//!
//! [`detect_chessboard`] finds the `cols × rows` inner corners of a chessboard and returns them
//! in OpenCV's order, or says why it could not ([`Detection::NotFound`]); it never returns a
//! board of another size or a partial board. Pipeline:
//!
//! 1. Smooth the image (Gaussian, σ = [`DetectOptions::sigma`]) and compute a saddle response,
//!    `max(0, −det H)` of the Hessian; keep local maxima above a fraction of the strongest
//!    ([`candidates`]).
//! 2. Keep only maxima that are X-junctions: four alternating sectors on a circle around them,
//!    bounded by two lines (a ChESS-like test, Bennett & Lasenby, CVIU 2014); the lines are the
//!    local edge directions.
//! 3. Seed a grid with a candidate, its nearest neighbours along both edge lines and the
//!    diagonal neighbour, colours checked; grow it with local predictions that follow
//!    perspective and fisheye curvature ([`grid`]).
//! 4. Accept only a grid of exactly `cols × rows` (either way round) with no hole and nothing
//!    beyond it; refine every corner by an iterated quadratic saddle fit with a window scaled
//!    to the local spacing ([`subpix`], Lucchese & Mitra 2002); re-check the grid (smooth rows
//!    and columns, alternating square colours).
//! 5. Order the corners (below).
//!
//! # Corner order
//!
//! Row-major, `index = row·cols + col`, `cols` corners per row, as OpenCV's
//! `findChessboardCorners` and [`crate::calib::BoardGeometry`]. Of the orderings that fit the
//! pattern we pick, in this order of rules:
//!
//! 1. **Handedness**: `(p[1] − p[0]) × (p[cols] − p[0]) > 0` in image coordinates (x right,
//!    y down), i.e. the board's z axis points away from the camera. Every one of OpenCV's
//!    detections in the shared sets (26 stereo, 26 fisheye) has this handedness.
//! 2. **Colour**: the square between corners 0, 1, `cols`, `cols + 1` is black. When
//!    `cols + rows` is odd (e.g. 9×6) the board is not symmetric under a half turn and this
//!    fixes the order completely; it is what OpenCV returns on all 26 images of
//!    `opencv_stereo` (OpenCV starts from the corner of a black quadrilateral).
//! 3. For boards symmetric under a half turn (e.g. 4×6, `cols + rows` even), where the colours
//!    cannot tell, OpenCV 4's documented rule for even×even patterns: the first corner of the
//!    last row is not above corner 0 (`p[(rows−1)·cols].y ≥ p[0].y`). OpenCV 5 does not apply
//!    it consistently (2 of the 26 fisheye images differ), so for such boards the order can
//!    differ from OpenCV's by a half turn; for calibration this is immaterial.
//! 4. Square patterns (`cols == rows`): then the corner 0 nearest the image's top-left.
//!
//! # Robustness
//!
//! The response, the X test and the saddle fit all rely on the point symmetry of an
//! X-junction, which survives defocus, linear motion blur, uneven illumination (every test is
//! local and relative to the local contrast) and lens distortion (the grid is grown with local
//! predictions only). Corners missed by the candidate stage are recovered from their predicted
//! position.

mod candidates;
mod grid;
mod light;
mod order;
pub(crate) mod subpix;

#[cfg(test)]
mod tests;

use serde::{Deserialize, Serialize};

use super::filter::{ImageF, gaussian_blur_gray};
use crate::calib::ViewObservations;
use crate::error::{CoreError, CoreResult};
use crate::io::Gray;
use candidates::{Candidates, X_RADIUS, local_maxima, saddle_response};
use grid::{GrowCtx, Node, SpatialIndex, Trim, polarity, trim};
use order::order;
use subpix::SaddleFitter;

/// Settings of [`detect_chessboard`]; the defaults suit 8-bit images from VGA to a few
/// megapixels with squares of 8 px and more.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct DetectOptions {
    /// Smoothing scale of the saddle response and the sub-pixel fit, pixels.
    pub sigma: f64,
    /// Candidates need a response above this fraction of the strongest one.
    pub relative_threshold: f64,
    /// Most candidates kept (strongest first).
    pub max_candidates: usize,
    /// Most seeds tried before giving up.
    pub max_seeds: usize,
    /// Least grey-level difference between dark and bright squares around a corner.
    pub min_contrast: f64,
    /// Refine corners to sub-pixel accuracy (off: the candidate positions, ±1 px).
    pub refine: bool,
    /// Measure uneven light (vignetting, a lamp to one side) on the board's white squares and
    /// divide it out before the sub-pixel fit. Under a light ramp of 0.6 across a 640 px render
    /// it keeps corners at 0.021 px from the truth where they drift to 0.046 px without it; on
    /// the shared real sets it lowers the OpenCV stereo images' RMS (0.168 → 0.165, 0.172 →
    /// 0.164 px) but raises the BoofCV fisheye set's (0.205 → 0.231 px), hence off by default.
    pub light_correction: bool,
}

impl Default for DetectOptions {
    fn default() -> Self {
        Self {
            sigma: 1.5,
            relative_threshold: 0.005,
            max_candidates: 4000,
            max_seeds: 400,
            min_contrast: 8.0,
            refine: true,
            light_correction: false,
        }
    }
}

impl DetectOptions {
    /// Errors on values outside their domain.
    pub fn validate(&self) -> CoreResult<()> {
        if !(self.sigma.is_finite() && self.sigma > 0.3 && self.sigma <= 10.0) {
            return Err(CoreError::param("sigma", "must be in (0.3, 10]"));
        }
        if !(self.relative_threshold.is_finite() && (0.0..1.0).contains(&self.relative_threshold)) {
            return Err(CoreError::param("relative_threshold", "must be in [0, 1)"));
        }
        if !(self.min_contrast.is_finite() && self.min_contrast >= 0.0) {
            return Err(CoreError::param("min_contrast", "must be ≥ 0"));
        }
        if self.max_candidates == 0 || self.max_seeds == 0 {
            return Err(CoreError::param(
                "max_candidates",
                "max_candidates and max_seeds must be positive",
            ));
        }
        Ok(())
    }
}

/// The outcome of [`detect_chessboard`] for one image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "outcome", rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum Detection {
    /// The whole board was found.
    Found {
        /// Pixel `[x, y]` of every inner corner, row-major (`row·cols + col`), pixel centres
        /// at integer coordinates (OpenCV's convention).
        corners: Vec<[f64; 2]>,
        /// Inner corners per row.
        cols: usize,
        /// Inner corners per column.
        rows: usize,
        /// Quality in (0, 1]: the weakest corner's colour contrast relative to the median
        /// one (low values point to glare, shadows or a corner at the edge of visibility).
        score: f64,
        /// Median grey-level difference between the bright and dark squares at the corners.
        contrast: f64,
    },
    /// No board of the requested size in the image.
    NotFound {
        /// Why, for the user.
        reason: String,
    },
}

impl Detection {
    /// The corners if found.
    pub fn corners(&self) -> Option<&[[f64; 2]]> {
        match self {
            Detection::Found { corners, .. } => Some(corners),
            Detection::NotFound { .. } => None,
        }
    }

    /// Whether the board was found.
    pub fn is_found(&self) -> bool {
        matches!(self, Detection::Found { .. })
    }

    /// Observations for [`crate::calib::calibrate`] (`None` if not found).
    pub fn to_observations(&self, name: impl Into<String>) -> Option<ViewObservations> {
        self.corners().map(|c| {
            let dense: Vec<Option<[f64; 2]>> = c.iter().copied().map(Some).collect();
            ViewObservations::from_dense(name, &dense)
        })
    }
}

fn not_found(reason: impl Into<String>) -> Detection {
    Detection::NotFound {
        reason: reason.into(),
    }
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// Finds the `cols × rows` inner corners of a chessboard in `img` (see the module docs for
/// the method and the corner order).
///
/// Returns [`Detection::NotFound`] with a reason when there is no complete board of that size,
/// and also for invalid arguments (pattern smaller than 2×2 or above 10⁴ corners, options out
/// of range: check them up front with [`DetectOptions::validate`]), so that one bad image or
/// setting never aborts a batch.
pub fn detect_chessboard(img: &Gray, cols: usize, rows: usize, opts: &DetectOptions) -> Detection {
    if let Err(e) = opts.validate() {
        return not_found(format!("invalid detection options: {e}"));
    }
    if cols < 2 || rows < 2 || cols * rows > 10_000 {
        return not_found(format!(
            "invalid pattern {cols}×{rows}: needs 2×2 to 10⁴ inner corners"
        ));
    }
    let (w, h) = (img.width as usize, img.height as usize);
    if img.data.len() != w * h {
        return not_found("invalid image: the buffer does not match its size");
    }
    if w < 16 || h < 16 {
        return not_found(format!("image {w}×{h} is too small"));
    }
    let s = gaussian_blur_gray(img, opts.sigma);

    // 1–2. Candidates.
    let r = saddle_response(&s);
    let rmax = max_or_zero(&r.data);
    if rmax <= 0.0 {
        return not_found("no saddle points: the image is flat");
    }
    let threshold = (opts.relative_threshold as f32 * rmax).max(1e-3);
    let maxima = local_maxima(&r, threshold, opts.max_candidates);
    let cands = Candidates::new(
        &s,
        maxima.into_iter().map(|(p, _response)| p).collect(),
        opts.min_contrast,
    );
    // The X test runs lazily: here only until four candidates pass.
    let num_x = (0..cands.len())
        .filter(|&k| cands.lines(k).is_some())
        .take(4)
        .count();
    if num_x < 4 {
        return not_found(format!("{num_x} X-junction candidates: no chessboard"));
    }
    let index = SpatialIndex::new(&cands.points, w, h, 8.0);
    let fitter = SaddleFitter::new(3);
    let ctx = GrowCtx {
        s: &s,
        cands: &cands,
        index: &index,
        fitter: &fitter,
        min_contrast: opts.min_contrast,
        x_radius: X_RADIUS,
        pattern: (cols, rows),
    };

    // 3. Seeds, strongest first.
    let mut consumed = vec![false; cands.len()];
    let mut best_partial: Option<(usize, usize, usize)> = None;
    let mut too_large = false;
    let mut incomplete = false;
    let max_dist = 0.35 * w.max(h) as f64;
    let mut seeds = 0;
    for k in 0..cands.len() {
        if consumed[k] {
            continue;
        }
        if seeds >= opts.max_seeds {
            break;
        }
        if cands.lines(k).is_none() {
            continue;
        }
        seeds += 1;
        let Some((seed, pol)) = find_seed(&ctx, k, max_dist) else {
            continue;
        };
        let grown = ctx.grow(seed, pol);
        for n in grown.nodes.values() {
            if let Some(c) = n.cand {
                consumed[c] = true;
            }
        }
        let ext = grown.extent();
        if grown.too_large {
            too_large = true;
            continue;
        }
        let mut complete = None;
        for (tw, th) in [(cols, rows), (rows, cols)] {
            match trim(&grown.nodes, ext, tw, th) {
                Trim::Complete(i0, j0) => {
                    complete = Some((i0, j0, tw, th));
                    break;
                }
                Trim::TooLarge => too_large = true,
                Trim::Partial(n, gw, gh) => {
                    if (gw == tw && gh == th) || (gw == th && gh == tw) {
                        incomplete = true;
                    }
                    if best_partial.is_none_or(|b| n > b.0) {
                        best_partial = Some((n, gw, gh));
                    }
                }
            }
        }
        let Some((i0, j0, gw, gh)) = complete else {
            continue;
        };
        // Dense grid, [j][i].
        let mut g: Vec<Vec<[f64; 2]>> = vec![vec![[0.0; 2]; gw]; gh];
        for (j, row) in g.iter_mut().enumerate() {
            for (i, cell) in row.iter_mut().enumerate() {
                if let Some(node) = grown.nodes.get(&(i0 + i as i32, j0 + j as i32)) {
                    *cell = node.p;
                }
            }
        }
        return finish(&s, g, cols, rows, pol, i0 + j0, opts);
    }
    if too_large {
        return not_found(format!(
            "a chessboard with more inner corners than {cols}×{rows} is visible: check the \
             pattern size"
        ));
    }
    if incomplete {
        return not_found(format!(
            "a {cols}×{rows} board was found with corners missing (occlusion, glare or blur)"
        ));
    }
    match best_partial {
        Some((n, gw, gh)) if n >= 4 => not_found(format!(
            "no complete {cols}×{rows} board: the largest chessboard grid has {gw}×{gh} corners \
             ({n} found); is the board partly outside the image or occluded?"
        )),
        _ => not_found(format!("no {cols}×{rows} chessboard found")),
    }
}

/// The largest value of `d` and 0 (NaN ignored), in lanes that vectorise.
fn max_or_zero(d: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    let chunks = d.chunks_exact(8);
    let rest = chunks.remainder();
    for ch in chunks {
        for (a, &v) in acc.iter_mut().zip(ch) {
            *a = if v > *a { v } else { *a };
        }
    }
    acc.iter().chain(rest).copied().fold(0.0f32, f32::max)
}

/// A seed quad around candidate `k`: itself, its nearest neighbours along its two edge lines
/// and the diagonal neighbour, with consistent colours. Returns the quad and the polarity of
/// its first corner.
fn find_seed(ctx: &GrowCtx<'_>, k: usize, max_dist: f64) -> Option<([Node; 4], i8)> {
    let c = ctx.cands.p(k);
    let lines = ctx.cands.lines(k)?;
    let dirs = lines.map(|a| [a.cos(), a.sin()]);
    let max_angle = 0.35;
    for s1 in [1.0, -1.0] {
        let d1 = [s1 * dirs[0][0], s1 * dirs[0][1]];
        let Some(n1) = ctx
            .index
            .nearest_along(ctx.cands, c, d1, max_angle, 3.0, max_dist)
        else {
            continue;
        };
        for s2 in [1.0, -1.0] {
            let d2 = [s2 * dirs[1][0], s2 * dirs[1][1]];
            let Some(n2) = ctx
                .index
                .nearest_along(ctx.cands, c, d2, max_angle, 3.0, max_dist)
            else {
                continue;
            };
            let (p1, p2) = (ctx.cands.p(n1), ctx.cands.p(n2));
            let u = [p1[0] - c[0], p1[1] - c[1]];
            let v = [p2[0] - c[0], p2[1] - c[1]];
            let (lu, lv) = (u[0].hypot(u[1]), v[0].hypot(v[1]));
            if lu > 4.0 * lv || lv > 4.0 * lu {
                continue;
            }
            let pol = polarity(ctx.s, c, u, v, ctx.min_contrast);
            if pol == 0
                || polarity(ctx.s, p1, u, v, ctx.min_contrast) != -pol
                || polarity(ctx.s, p2, u, v, ctx.min_contrast) != -pol
            {
                continue;
            }
            let diag = [c[0] + u[0] + v[0], c[1] + u[1] + v[1]];
            let n3 = ctx
                .index
                .within(&ctx.cands.points, diag, 0.35 * lu.min(lv))
                .into_iter()
                .map(|(q, _)| q)
                .find(|&q| {
                    q != k
                        && q != n1
                        && q != n2
                        && ctx.cands.lines(q).is_some()
                        && polarity(ctx.s, ctx.cands.p(q), u, v, ctx.min_contrast) == pol
                });
            let Some(n3) = n3 else { continue };
            let node = |q: usize| Node {
                p: ctx.cands.p(q),
                cand: Some(q),
            };
            return Some(([node(k), node(n1), node(n2), node(n3)], pol));
        }
    }
    None
}

/// Refines, validates and orders a complete grid `g[j][i]` whose corner at grid position
/// `(i, j)` has polarity `pol·(−1)^(i + j + parity0)`.
fn finish(
    s: &ImageF,
    mut g: Vec<Vec<[f64; 2]>>,
    cols: usize,
    rows: usize,
    pol: i8,
    parity0: i32,
    opts: &DetectOptions,
) -> Detection {
    let gh = g.len();
    let gw = g[0].len();
    // Local spacing: the distance to the nearest grid neighbour.
    let spacing = |g: &Vec<Vec<[f64; 2]>>, i: usize, j: usize| -> f64 {
        let mut d = f64::MAX;
        if i > 0 {
            d = d.min(dist(g[j][i], g[j][i - 1]));
        }
        if i + 1 < gw {
            d = d.min(dist(g[j][i], g[j][i + 1]));
        }
        if j > 0 {
            d = d.min(dist(g[j][i], g[j - 1][i]));
        }
        if j + 1 < gh {
            d = d.min(dist(g[j][i], g[j + 1][i]));
        }
        d
    };

    // 4. Sub-pixel refinement.
    if opts.refine {
        let mut fitters: Vec<Option<SaddleFitter>> = (0..=8).map(|_| None).collect();
        let coarse = g.clone();
        for j in 0..gh {
            for i in 0..gw {
                let d = spacing(&coarse, i, j);
                let r0 = ((0.3 * d).round() as i32).clamp(2, 8);
                let mut done = None;
                for radius in (2..=r0).rev() {
                    let f =
                        fitters[radius as usize].get_or_insert_with(|| SaddleFitter::new(radius));
                    if let Some(p) = f.refine(s, coarse[j][i], (0.25 * d).max(1.5)) {
                        done = Some(p);
                        break;
                    }
                }
                match done {
                    Some(p) => g[j][i] = p,
                    None => {
                        return not_found(format!(
                            "corner ({i}, {j}) of the grid could not be refined to a saddle point"
                        ));
                    }
                }
            }
        }
        // Uneven light (vignetting, a lamp to one side) moves saddle points: measure it on the
        // board's white squares and refine once more with it divided out.
        if opts.light_correction {
            light::relight(s, &mut g, &mut fitters, |g, i, j| spacing(g, i, j));
        }
    }

    // Validation: rows and columns are smooth (no corner off by a fraction of a square).
    for j in 0..gh {
        for i in 0..gw {
            let p = g[j][i];
            let mut checks = Vec::with_capacity(2);
            if i > 0 && i + 1 < gw {
                checks.push((g[j][i - 1], g[j][i + 1]));
            }
            if j > 0 && j + 1 < gh {
                checks.push((g[j - 1][i], g[j + 1][i]));
            }
            for (a, b) in checks {
                let dd = (a[0] - 2.0 * p[0] + b[0]).hypot(a[1] - 2.0 * p[1] + b[1]);
                let step = dist(a, p).max(dist(p, b));
                if dd > 0.5 * step {
                    return not_found("the grid is not smooth: inconsistent corner positions");
                }
            }
        }
    }

    // Validation: colours alternate between neighbouring squares, and every corner shows
    // the expected colour pattern after refinement.
    let mut contrasts = Vec::with_capacity(gw * gh);
    for j in 0..gh {
        for i in 0..gw {
            let u = if i + 1 < gw {
                [g[j][i + 1][0] - g[j][i][0], g[j][i + 1][1] - g[j][i][1]]
            } else {
                [g[j][i][0] - g[j][i - 1][0], g[j][i][1] - g[j][i - 1][1]]
            };
            let v = if j + 1 < gh {
                [g[j + 1][i][0] - g[j][i][0], g[j + 1][i][1] - g[j][i][1]]
            } else {
                [g[j][i][0] - g[j - 1][i][0], g[j][i][1] - g[j - 1][i][1]]
            };
            let expected = if (i as i32 + j as i32 + parity0).rem_euclid(2) == 0 {
                pol
            } else {
                -pol
            };
            if polarity(s, g[j][i], u, v, opts.min_contrast) != expected {
                return not_found(format!(
                    "corner ({i}, {j}): the squares around it do not alternate in colour"
                ));
            }
            contrasts.push(corner_contrast(s, g[j][i], u, v));
        }
    }
    let cell_value = |i: usize, j: usize| -> f64 {
        let c = [g[j][i], g[j][i + 1], g[j + 1][i], g[j + 1][i + 1]];
        let x = c.iter().map(|p| p[0]).sum::<f64>() / 4.0;
        let y = c.iter().map(|p| p[1]).sum::<f64>() / 4.0;
        f64::from(s.bilinear(x, y))
    };
    // Cell (i, j) between corners (i, j) and (i+1, j+1) is bright when the corner (i, j) has
    // polarity +1 (its +(u+v) diagonal is bright).
    let cell_bright = |i: usize, j: usize| -> bool {
        let e = if (i as i32 + j as i32 + parity0).rem_euclid(2) == 0 {
            pol
        } else {
            -pol
        };
        e > 0
    };
    for j in 0..gh - 1 {
        for i in 0..gw - 1 {
            let a = cell_value(i, j);
            for (ni, nj) in [(i + 1, j), (i, j + 1)] {
                if ni + 1 >= gw || nj + 1 >= gh {
                    continue;
                }
                let b = cell_value(ni, nj);
                let ok = if cell_bright(i, j) { a > b } else { b > a };
                if !ok {
                    return not_found("square colours do not alternate across the board");
                }
            }
        }
    }
    contrasts.sort_by(f64::total_cmp);
    let contrast = contrasts[contrasts.len() / 2];
    let score = if contrast > 0.0 {
        (contrasts[0] / contrast).clamp(0.0, 1.0)
    } else {
        0.0
    };

    // 5. Ordering.
    let corners = order(&g, cols, rows, &|i, j| !cell_bright(i, j));
    Detection::Found {
        corners,
        cols,
        rows,
        score,
        contrast,
    }
}

/// Bright minus dark grey level around a corner.
fn corner_contrast(s: &ImageF, p: [f64; 2], u: [f64; 2], v: [f64; 2]) -> f64 {
    let q = |k1: f64, k2: f64| {
        f64::from(s.bilinear(
            p[0] + 0.3 * (k1 * u[0] + k2 * v[0]),
            p[1] + 0.3 * (k1 * u[1] + k2 * v[1]),
        ))
    };
    (0.5 * (q(1.0, 1.0) + q(-1.0, -1.0)) - 0.5 * (q(1.0, -1.0) + q(-1.0, 1.0))).abs()
}
