//! Growing a chessboard grid from a seed quad over the corner candidates.
//!
//! Each empty grid position next to the grown grid gets a predicted pixel position from the
//! accepted corners around it: quadratic extrapolation along a row or column when three
//! corners are known (follows the curvature of fisheye rows; a shrinking step is rescaled by
//! the cross-ratio, exact under perspective foreshortening), linear with two, and the
//! parallelogram rule from a diagonal neighbourhood otherwise. Predictions are local, so the
//! grid can bend arbitrarily over the whole board. The nearest candidate within 0.45 of the
//! local spacing is accepted if the four squares around it have the expected colours (dark
//! diagonal / bright diagonal, alternating with the parity of the position). When no candidate
//! is there (a corner lost to blur or glare), a saddle fit is run from the prediction and its
//! result must pass the same X-junction and colour tests. A position that failed is retried
//! once more corners are known along its row and column (a better prediction).

use std::collections::{BTreeMap, HashMap};

use nalgebra::Vector2;

use super::candidates::{Candidates, angle_diff_mod_pi, x_junction};
use super::subpix::SaddleFitter;
use crate::board::filter::ImageF;
use crate::calib::{homography_dlt, transfer};

/// Candidates bucketed on a square grid of cells, for radius and cone queries.
pub struct SpatialIndex {
    cell: f64,
    nx: usize,
    ny: usize,
    cells: Vec<Vec<u32>>,
}

impl SpatialIndex {
    pub fn new(points: &[[f64; 2]], w: usize, h: usize, cell: f64) -> Self {
        let nx = (w as f64 / cell).ceil().max(1.0) as usize;
        let ny = (h as f64 / cell).ceil().max(1.0) as usize;
        let mut cells = vec![Vec::new(); nx * ny];
        for (k, &p) in points.iter().enumerate() {
            let (cx, cy) = Self::cell_of(cell, nx, ny, p);
            cells[cy * nx + cx].push(k as u32);
        }
        Self {
            cell,
            nx,
            ny,
            cells,
        }
    }

    fn cell_of(cell: f64, nx: usize, ny: usize, p: [f64; 2]) -> (usize, usize) {
        let cx = ((p[0] / cell).floor().max(0.0) as usize).min(nx - 1);
        let cy = ((p[1] / cell).floor().max(0.0) as usize).min(ny - 1);
        (cx, cy)
    }

    /// Indices of points within `r` of `p`, nearest first.
    pub fn within(&self, points: &[[f64; 2]], p: [f64; 2], r: f64) -> Vec<(usize, f64)> {
        let (x0, y0) = Self::cell_of(self.cell, self.nx, self.ny, [p[0] - r, p[1] - r]);
        let (x1, y1) = Self::cell_of(self.cell, self.nx, self.ny, [p[0] + r, p[1] + r]);
        let mut out = Vec::new();
        for cy in y0..=y1 {
            for cx in x0..=x1 {
                for &k in &self.cells[cy * self.nx + cx] {
                    let q = points[k as usize];
                    let d = (q[0] - p[0]).hypot(q[1] - p[1]);
                    if d <= r {
                        out.push((k as usize, d));
                    }
                }
            }
        }
        out.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        out
    }

    /// The nearest candidate `q` with `q − p` within `max_angle` of `dir` (unit), at distance
    /// `min_dist..max_dist`, an X-junction whose own edge lines include the direction of `q − p`.
    pub fn nearest_along(
        &self,
        cands: &Candidates<'_>,
        p: [f64; 2],
        dir: [f64; 2],
        max_angle: f64,
        min_dist: f64,
        max_dist: f64,
    ) -> Option<usize> {
        let cos_min = max_angle.cos();
        let (pcx, pcy) = Self::cell_of(self.cell, self.nx, self.ny, p);
        let max_ring = (max_dist / self.cell).ceil() as isize + 1;
        let mut best: Option<(usize, f64)> = None;
        for ring in 0..=max_ring {
            // Every cell of this ring is at least (ring − 1)·cell away.
            if let Some((_, d)) = best
                && d < (ring as f64 - 1.0) * self.cell
            {
                break;
            }
            for cy in (pcy as isize - ring)..=(pcy as isize + ring) {
                for cx in (pcx as isize - ring)..=(pcx as isize + ring) {
                    let on_ring =
                        (cy - pcy as isize).abs() == ring || (cx - pcx as isize).abs() == ring;
                    if !on_ring
                        || cx < 0
                        || cy < 0
                        || cx >= self.nx as isize
                        || cy >= self.ny as isize
                    {
                        continue;
                    }
                    for &k in &self.cells[cy as usize * self.nx + cx as usize] {
                        let c = cands.p(k as usize);
                        let (dx, dy) = (c[0] - p[0], c[1] - p[1]);
                        let d = dx.hypot(dy);
                        if d < min_dist || d > max_dist {
                            continue;
                        }
                        if (dx * dir[0] + dy * dir[1]) / d < cos_min {
                            continue;
                        }
                        if best.is_some_and(|(_, bd)| d >= bd) {
                            continue;
                        }
                        let Some(lines) = cands.lines(k as usize) else {
                            continue;
                        };
                        let a = dy.atan2(dx);
                        if lines.iter().any(|&l| angle_diff_mod_pi(l, a) < max_angle) {
                            best = Some((k as usize, d));
                        }
                    }
                }
            }
        }
        best.map(|(k, _)| k)
    }
}

/// Colour polarity of a corner with grid axes `u` (towards +i) and `v` (towards +j): +1 when
/// the squares along `±(u + v)` are brighter than those along `±(u − v)`, −1 for the opposite,
/// 0 when the four squares do not form a clear chessboard pattern (both squares of one
/// diagonal must be brighter than both of the other by a quarter of the local contrast).
pub fn polarity(s: &ImageF, p: [f64; 2], u: [f64; 2], v: [f64; 2], min_contrast: f64) -> i8 {
    let a = 0.3;
    let q = |k1: f64, k2: f64| -> Option<f64> {
        let x = p[0] + a * (k1 * u[0] + k2 * v[0]);
        let y = p[1] + a * (k1 * u[1] + k2 * v[1]);
        s.contains(x, y, 0.0).then(|| f64::from(s.bilinear(x, y)))
    };
    let (Some(a1), Some(a2), Some(b1), Some(b2)) =
        (q(1.0, 1.0), q(-1.0, -1.0), q(1.0, -1.0), q(-1.0, 1.0))
    else {
        return 0;
    };
    let hi = a1.max(a2).max(b1).max(b2);
    let lo = a1.min(a2).min(b1).min(b2);
    if hi - lo < min_contrast {
        return 0;
    }
    let m = 0.25 * (hi - lo);
    if a1.min(a2) > b1.max(b2) + m {
        1
    } else if b1.min(b2) > a1.max(a2) + m {
        -1
    } else {
        0
    }
}

/// A grid position.
pub type Pos = (i32, i32);

/// An accepted corner of a growing grid.
#[derive(Clone, Copy, Debug)]
pub struct Node {
    pub p: [f64; 2],
    pub cand: Option<usize>,
}

/// The outcome of growing a grid.
pub struct Grown {
    pub nodes: HashMap<Pos, Node>,
    /// A corner was found beyond the extent the pattern allows.
    pub too_large: bool,
}

impl Grown {
    /// `(min_i, min_j, width, height)`.
    pub fn extent(&self) -> (i32, i32, usize, usize) {
        let (mut i0, mut j0, mut i1, mut j1) = (i32::MAX, i32::MAX, i32::MIN, i32::MIN);
        for &(i, j) in self.nodes.keys() {
            i0 = i0.min(i);
            j0 = j0.min(j);
            i1 = i1.max(i);
            j1 = j1.max(j);
        }
        if self.nodes.is_empty() {
            return (0, 0, 0, 0);
        }
        (i0, j0, (i1 - i0 + 1) as usize, (j1 - j0 + 1) as usize)
    }
}

/// Everything the growth needs.
pub struct GrowCtx<'a> {
    pub s: &'a ImageF,
    pub cands: &'a Candidates<'a>,
    pub index: &'a SpatialIndex,
    pub fitter: &'a SaddleFitter,
    pub min_contrast: f64,
    pub x_radius: f64,
    /// The pattern, `(cols, rows)`.
    pub pattern: (usize, usize),
}

fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

fn norm(a: [f64; 2]) -> f64 {
    a[0].hypot(a[1])
}

impl GrowCtx<'_> {
    /// Growth stops (the board is too large) well past the pattern: partial extra lines are
    /// clutter next to the board and are trimmed afterwards ([`trim`]); this only bounds the
    /// work.
    fn fits(&self, w: usize, h: usize) -> bool {
        let m = self.pattern.0.max(self.pattern.1) + 4;
        w <= m && h <= m
    }

    /// Grows from the seed quad `(0,0), (1,0), (0,1), (1,1)` whose corner `(0,0)` has
    /// polarity `pol`.
    pub fn grow(&self, seed: [Node; 4], pol: i8) -> Grown {
        let mut nodes: HashMap<Pos, Node> = HashMap::new();
        nodes.insert((0, 0), seed[0]);
        nodes.insert((1, 0), seed[1]);
        nodes.insert((0, 1), seed[2]);
        nodes.insert((1, 1), seed[3]);
        let mut used: Vec<usize> = seed.iter().filter_map(|n| n.cand).collect();
        // Positions that failed, with their support then: the known corners along the four
        // rows and columns through them, up to three positions away (what the extrapolation
        // uses). They are retried when it grows (a better prediction).
        let mut failed: HashMap<Pos, usize> = HashMap::new();
        let support = |nodes: &HashMap<Pos, Node>, q: Pos| -> usize {
            [(1, 0), (-1, 0), (0, 1), (0, -1)]
                .into_iter()
                .map(|(di, dj)| {
                    (1..=3)
                        .take_while(|&k| nodes.contains_key(&(q.0 + k * di, q.1 + k * dj)))
                        .count()
                })
                .sum()
        };
        let mut extent = (0i32, 0i32, 1i32, 1i32);
        loop {
            let mut frontier: BTreeMap<Pos, usize> = BTreeMap::new();
            for &(i, j) in nodes.keys() {
                for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                    let q = (i + di, j + dj);
                    if !nodes.contains_key(&q) {
                        *frontier.entry(q).or_insert(0) += 1;
                    }
                }
            }
            let mut order: Vec<(Pos, usize)> = frontier
                .into_iter()
                .filter(|(q, _)| failed.get(q).is_none_or(|&f| support(&nodes, *q) > f))
                .collect();
            if order.is_empty() {
                break;
            }
            order.sort_by(|a, b| {
                b.1.cmp(&a.1)
                    .then(a.0.1.cmp(&b.0.1))
                    .then(a.0.0.cmp(&b.0.0))
            });
            let mut added = false;
            for (q, _) in order {
                let Some(node) = self.try_fill(&nodes, &used, q, pol) else {
                    failed.insert(q, support(&nodes, q));
                    continue;
                };
                let e = (
                    extent.0.min(q.0),
                    extent.1.min(q.1),
                    extent.2.max(q.0),
                    extent.3.max(q.1),
                );
                let (w, h) = ((e.2 - e.0 + 1) as usize, (e.3 - e.1 + 1) as usize);
                if !self.fits(w, h) {
                    return Grown {
                        nodes,
                        too_large: true,
                    };
                }
                extent = e;
                if let Some(c) = node.cand {
                    used.push(c);
                }
                nodes.insert(q, node);
                added = true;
            }
            if !added {
                break;
            }
        }
        Grown {
            nodes,
            too_large: false,
        }
    }

    /// Predicted position of `q` and the local spacing.
    ///
    /// In order of preference: quadratic extrapolation along rows/columns with three known
    /// corners (follows curved fisheye rows), a homography fitted to the known corners within
    /// two positions (follows perspective foreshortening, which linear extrapolation from two
    /// corners underestimates badly on steep views), then linear extrapolation and the
    /// parallelogram rule.
    fn predict(nodes: &HashMap<Pos, Node>, q: Pos) -> Option<([f64; 2], f64)> {
        let at = |i: i32, j: i32| nodes.get(&(i, j)).map(|n| n.p);
        let mut quad: Vec<[f64; 2]> = Vec::new();
        let mut lin: Vec<[f64; 2]> = Vec::new();
        let mut step = f64::MAX;
        for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
            let a = at(q.0 - di, q.1 - dj);
            let b = at(q.0 - 2 * di, q.1 - 2 * dj);
            let c = at(q.0 - 3 * di, q.1 - 3 * dj);
            if let Some(a) = a {
                step = step.min(match b {
                    Some(b) => norm(sub(a, b)),
                    None => f64::MAX,
                });
            }
            if let (Some(a), Some(b)) = (a, b) {
                match c {
                    Some(c) => quad.push(extrapolate3(a, b, c)),
                    None => lin.push([2.0 * a[0] - b[0], 2.0 * a[1] - b[1]]),
                }
            }
        }
        let mean = |v: &[[f64; 2]]| {
            let n = v.len() as f64;
            [
                v.iter().map(|p| p[0]).sum::<f64>() / n,
                v.iter().map(|p| p[1]).sum::<f64>() / n,
            ]
        };
        let pred = if !quad.is_empty() {
            Some(mean(&quad))
        } else {
            Self::homography_prediction(nodes, q).or_else(|| (!lin.is_empty()).then(|| mean(&lin)))
        };
        let pred = match pred {
            Some(p) => p,
            None => {
                let mut par = Vec::new();
                for (di, dj) in [(1, 1), (1, -1), (-1, 1), (-1, -1)] {
                    let a = at(q.0 - di, q.1);
                    let b = at(q.0, q.1 - dj);
                    let c = at(q.0 - di, q.1 - dj);
                    if let (Some(a), Some(b), Some(c)) = (a, b, c) {
                        par.push([a[0] + b[0] - c[0], a[1] + b[1] - c[1]]);
                        step = step.min(norm(sub(a, c)).min(norm(sub(b, c))));
                    }
                }
                if par.is_empty() {
                    return None;
                }
                mean(&par)
            }
        };
        // The spacing at the prediction: its distance to the nearest known direct neighbour.
        for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
            if let Some(a) = at(q.0 + di, q.1 + dj) {
                step = step.min(norm(sub(pred, a)));
            }
        }
        (step < f64::MAX).then_some((pred, step))
    }

    /// A homography from grid to pixel coordinates fitted (normalised DLT) to the known corners
    /// within two positions of `q`, evaluated at `q`. Needs corners on at least two rows and two
    /// columns.
    fn homography_prediction(nodes: &HashMap<Pos, Node>, q: Pos) -> Option<[f64; 2]> {
        let mut src = Vec::new();
        let mut dst = Vec::new();
        let (mut is, mut js) = (Vec::new(), Vec::new());
        for dj in -2..=2 {
            for di in -2..=2 {
                if let Some(n) = nodes.get(&(q.0 + di, q.1 + dj)) {
                    src.push(Vector2::new(f64::from(di), f64::from(dj)));
                    dst.push(Vector2::new(n.p[0], n.p[1]));
                    if !is.contains(&di) {
                        is.push(di);
                    }
                    if !js.contains(&dj) {
                        js.push(dj);
                    }
                }
            }
        }
        if src.len() < 5 || is.len() < 2 || js.len() < 2 {
            return None;
        }
        let h = homography_dlt(&src, &dst).ok()?;
        let p = transfer(&h, &Vector2::new(0.0, 0.0))?;
        Some([p.x, p.y])
    }

    /// Grid axis (`(1, 0)` or `(0, 1)`) at `q` predicted at `p`: from a direct neighbour, else
    /// from the same axis at a neighbouring corner.
    fn axis(nodes: &HashMap<Pos, Node>, q: Pos, p: [f64; 2], d: Pos) -> Option<[f64; 2]> {
        let at = |i: i32, j: i32| nodes.get(&(i, j)).map(|n| n.p);
        if let Some(a) = at(q.0 - d.0, q.1 - d.1) {
            return Some(sub(p, a));
        }
        if let Some(b) = at(q.0 + d.0, q.1 + d.1) {
            return Some(sub(b, p));
        }
        let other = (d.1, d.0);
        for s in [1, -1] {
            let n = (q.0 + s * other.0, q.1 + s * other.1);
            let Some(np) = at(n.0, n.1) else { continue };
            if let Some(a) = at(n.0 - d.0, n.1 - d.1) {
                return Some(sub(np, a));
            }
            if let Some(b) = at(n.0 + d.0, n.1 + d.1) {
                return Some(sub(b, np));
            }
        }
        None
    }

    fn try_fill(
        &self,
        nodes: &HashMap<Pos, Node>,
        used: &[usize],
        q: Pos,
        pol: i8,
    ) -> Option<Node> {
        let (pred, step) = Self::predict(nodes, q)?;
        let expected = if (q.0 + q.1).rem_euclid(2) == 0 {
            pol
        } else {
            -pol
        };
        // Direct neighbours have the opposite colour polarity, so up to half the spacing the
        // search cannot pick a neighbouring corner by mistake.
        let radius = (0.45 * step).max(1.5);
        // Checks a corner at `p` with edge lines `lines`: the lines must follow the grid axes
        // (the chords to the neighbours; tangents of curved fisheye rows differ by half the
        // turning angle) and the four squares around it must have the expected colours.
        let accept = |p: [f64; 2], lines: [f64; 2]| -> bool {
            let (Some(u), Some(v)) = (
                Self::axis(nodes, q, p, (1, 0)),
                Self::axis(nodes, q, p, (0, 1)),
            ) else {
                return false;
            };
            let (au, av) = (u[1].atan2(u[0]), v[1].atan2(v[0]));
            let tol = 0.5;
            let aligned = (angle_diff_mod_pi(lines[0], au) < tol
                && angle_diff_mod_pi(lines[1], av) < tol)
                || (angle_diff_mod_pi(lines[1], au) < tol && angle_diff_mod_pi(lines[0], av) < tol);
            aligned && polarity(self.s, p, u, v, self.min_contrast) == expected
        };
        for (k, _) in self.index.within(&self.cands.points, pred, radius) {
            if used.contains(&k) {
                continue;
            }
            let Some(lines) = self.cands.lines(k) else {
                continue;
            };
            let p = self.cands.p(k);
            if accept(p, lines) {
                return Some(Node { p, cand: Some(k) });
            }
        }
        // Recovery: no candidate (lost to blur, glare or suppression by a stronger neighbour).
        let p = self.fitter.refine(self.s, pred, radius)?;
        let lines = x_junction(self.s, p, self.x_radius.min(0.3 * step), self.min_contrast)?;
        accept(p, lines).then_some(Node { p, cand: None })
    }
}

/// The corner after `c, b, a` (consecutive corners of a row or column, `a` last).
///
/// Quadratic extrapolation `3a − 3b + c` follows the curvature of fisheye rows, but under
/// strong foreshortening it underestimates how fast the spacing shrinks (at squares of a few
/// pixels its prediction lands half a square off). For a shrinking spacing the step is
/// therefore rescaled to the length that the cross-ratio of four equally spaced points on a
/// line gives (exact under perspective): with `d₁ = |b − c|`, `d₂ = |a − b|`,
/// `d₃ = d₂(d₁ + d₂)/(3d₁ − d₂)`. A growing spacing keeps the quadratic step: there, fisheye
/// compression towards the image border counteracts the perspective growth.
fn extrapolate3(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> [f64; 2] {
    let q = [
        3.0 * a[0] - 3.0 * b[0] + c[0],
        3.0 * a[1] - 3.0 * b[1] + c[1],
    ];
    let (d1, d2) = (norm(sub(b, c)), norm(sub(a, b)));
    let step = sub(q, a);
    let l = norm(step);
    if d2 >= d1 || l <= 0.0 {
        return q;
    }
    let d3 = d2 * (d1 + d2) / (3.0 * d1 - d2);
    let f = d3 / l;
    [a[0] + f * step[0], a[1] + f * step[1]]
}

/// The outcome of [`trim`].
pub enum Trim {
    /// A complete window `(i0, j0)` of the target size.
    Complete(i32, i32),
    /// The grid, trimmed of partial lines, is still larger than the target.
    TooLarge,
    /// Smaller than the target or with holes: `(found, width, height)`.
    Partial(usize, usize, usize),
}

/// Fits a `tw × th` window into a grown grid by dropping its outer lines (rows or columns)
/// that are not complete, the emptiest first. Corners next to the board (its outline against
/// the background, clutter) can pass the corner tests and extend the grid by a few positions;
/// they never form a whole extra line the way a larger board does. A complete extra line
/// means the board is larger than the pattern.
pub fn trim(
    nodes: &HashMap<Pos, Node>,
    ext: (i32, i32, usize, usize),
    tw: usize,
    th: usize,
) -> Trim {
    let (mut i0, mut j0, mut w, mut h) = (ext.0, ext.1, ext.2 as i32, ext.3 as i32);
    let count_col = |i: i32, j0: i32, h: i32| {
        (j0..j0 + h)
            .filter(|&j| nodes.contains_key(&(i, j)))
            .count()
    };
    let count_row = |j: i32, i0: i32, w: i32| {
        (i0..i0 + w)
            .filter(|&i| nodes.contains_key(&(i, j)))
            .count()
    };
    while w > tw as i32 || h > th as i32 {
        // (fraction occupied, which line)
        let mut lines: Vec<(f64, u8)> = Vec::new();
        if w > tw as i32 {
            lines.push((count_col(i0, j0, h) as f64 / h as f64, 0));
            lines.push((count_col(i0 + w - 1, j0, h) as f64 / h as f64, 1));
        }
        if h > th as i32 {
            lines.push((count_row(j0, i0, w) as f64 / w as f64, 2));
            lines.push((count_row(j0 + h - 1, i0, w) as f64 / w as f64, 3));
        }
        lines.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let (frac, which) = lines[0];
        if frac >= 1.0 {
            return Trim::TooLarge;
        }
        match which {
            0 => {
                i0 += 1;
                w -= 1;
            }
            1 => w -= 1,
            2 => {
                j0 += 1;
                h -= 1;
            }
            _ => h -= 1,
        }
    }
    let found = (j0..j0 + h)
        .flat_map(|j| (i0..i0 + w).map(move |i| (i, j)))
        .filter(|q| nodes.contains_key(q))
        .count();
    if w == tw as i32 && h == th as i32 && found == tw * th {
        Trim::Complete(i0, j0)
    } else {
        Trim::Partial(found, w as usize, h as usize)
    }
}
