//! Procedural scenes of the synthetic auto-exposure video: radiance patterns in `[0, 1]` over
//! the plane the camera glides over, each a function of a seed and a point (the dead leaves
//! cache the discs of each cell they have drawn) so that any frame can be rendered without
//! storing the plane.

use std::cell::RefCell;
use std::collections::HashMap;

use super::Rng;

/// A generator for one cell `(i, j)` of a scene and a salt.
fn cell_rng(seed: u64, i: i64, j: i64, k: u64) -> Rng {
    Rng::new(seed ^ (i as u64).wrapping_mul(0x9E37_79B9) ^ (j as u64).wrapping_mul(0x85EB_CA6B) ^ k)
}

/// A uniform number in (0, 1] from the seed, two integer coordinates and a salt.
fn hash(seed: u64, i: i64, j: i64, k: u64) -> f64 {
    cell_rng(seed, i, j, k).uniform()
}

/// Soft Voronoi patches: cells of 40 units, one jittered site and one radiance per cell.
pub(super) fn patches(seed: u64, u: f64, v: f64) -> f64 {
    const CELL: f64 = 40.0;
    let hash = |i: i64, j: i64, k: u64| hash(seed, i, j, k);
    let (ci, cj) = ((u / CELL).floor() as i64, (v / CELL).floor() as i64);
    let mut best = [(f64::MAX, 0.0); 2];
    for di in -1..=1 {
        for dj in -1..=1 {
            let (i, j) = (ci + di, cj + dj);
            let (px, py) = (
                (i as f64 + hash(i, j, 1)) * CELL,
                (j as f64 + hash(i, j, 2)) * CELL,
            );
            let d = ((u - px).powi(2) + (v - py).powi(2)).sqrt();
            let q = hash(i, j, 3);
            if d < best[0].0 {
                best[1] = best[0];
                best[0] = (d, q);
            } else if d < best[1].0 {
                best[1] = (d, q);
            }
        }
    }
    // Blend across a ~3 unit wide edge.
    let s = ((best[1].0 - best[0].0) / 3.0).tanh();
    best[0].1 * (0.5 + 0.5 * s) + best[1].1 * (0.5 - 0.5 * s)
}

/// Mondrian blocks: bands 30 units high, each with its own offset and cell width (20–50
/// units), one radiance per cell, edges blended over ~1.5 units.
pub(super) fn blocks(seed: u64, u: f64, v: f64) -> f64 {
    const BAND: f64 = 30.0;
    const EDGE: f64 = 1.5;
    let hash = |i: i64, j: i64, k: u64| hash(seed, i, j, k);
    // Weights of the previous and next cell at distance `a` from the start and `b` from the
    // end of the current one.
    let blend = |a: f64, b: f64| (0.5 - 0.5 * (a / EDGE).tanh(), 0.5 - 0.5 * (b / EDGE).tanh());
    let row = |j: i64| {
        let off = 60.0 * hash(j, 0, 11);
        let w = 20.0 + 30.0 * hash(j, 0, 12);
        let x = (u + off) / w;
        let i = x.floor();
        let f = (x - i) * w;
        let i = i as i64;
        let (wl, wr) = blend(f, w - f);
        hash(i, j, 13) * (1.0 - wl - wr) + hash(i - 1, j, 13) * wl + hash(i + 1, j, 13) * wr
    };
    let y = v / BAND;
    let j = y.floor();
    let f = (y - j) * BAND;
    let j = j as i64;
    let (wu, wd) = blend(f, BAND - f);
    row(j) * (1.0 - wu - wd) + row(j - 1) * wu + row(j + 1) * wd
}

/// One leaf of [`DeadLeaves`]: centre, radius, depth (larger is on top) and radiance.
#[derive(Debug, Clone, Copy)]
struct Leaf {
    x: f64,
    y: f64,
    r: f64,
    depth: f64,
    value: f64,
}

/// Dead leaves ([`super::SceneForm::Discs`]): every 32-unit cell drops [`DISCS_PER_CELL`]
/// discs at random positions and depths, with radii from a truncated `r⁻³` law over 4–32
/// units (scale invariant, as natural images are); a point takes the radiance of the topmost
/// disc covering it, blended with the next one below across a ~1.5-unit edge. Points no disc
/// covers (rare) take a per-cell background. The leaves of a cell are drawn once and cached:
/// a frame asks for every pixel, and each pixel looks at nine cells.
pub(super) struct DeadLeaves {
    seed: u64,
    cells: RefCell<HashMap<(i64, i64), Vec<Leaf>>>,
}

impl DeadLeaves {
    /// The field of a seed.
    pub(super) fn new(seed: u64) -> Self {
        Self {
            seed,
            cells: RefCell::new(HashMap::new()),
        }
    }

    /// Radiance pattern at `(u, v)`, in `[0, 1]`.
    pub(super) fn at(&self, u: f64, v: f64) -> f64 {
        const EDGE: f64 = 1.5;
        let (ci, cj) = ((u / CELL).floor() as i64, (v / CELL).floor() as i64);
        // (depth, signed distance inside the edge, radiance) of the two topmost covering discs.
        let mut top: [Option<(f64, f64, f64)>; 2] = [None, None];
        let mut cells = self.cells.borrow_mut();
        for di in -1..=1 {
            for dj in -1..=1 {
                let (i, j) = (ci + di, cj + dj);
                let leaves = cells
                    .entry((i, j))
                    .or_insert_with(|| cell_leaves(self.seed, i, j));
                for l in leaves.iter() {
                    let inside = l.r - ((u - l.x).powi(2) + (v - l.y).powi(2)).sqrt();
                    if inside <= -EDGE {
                        continue;
                    }
                    let leaf = (l.depth, inside, l.value);
                    if top[0].is_none_or(|t| leaf.0 > t.0) {
                        top[1] = top[0];
                        top[0] = Some(leaf);
                    } else if top[1].is_none_or(|t| leaf.0 > t.0) {
                        top[1] = Some(leaf);
                    }
                }
            }
        }
        let background = hash(self.seed, ci, cj, 99);
        match top {
            [None, _] => background,
            [Some(a), below] => {
                let under = below.map_or(background, |b| b.2);
                let w = 0.5 + 0.5 * (a.1 / EDGE).tanh();
                a.2 * w + under * (1.0 - w)
            }
        }
    }
}

/// Cell side of [`DeadLeaves`]: no larger than the largest radius, so a disc reaches at most
/// the neighbouring cells.
const CELL: f64 = 32.0;

/// The leaves of cell `(i, j)`.
fn cell_leaves(seed: u64, i: i64, j: i64) -> Vec<Leaf> {
    let mut rng = cell_rng(seed, i, j, 0xD15C);
    let (r0, r1) = (4.0f64, 32.0f64);
    (0..DISCS_PER_CELL)
        .map(|_| {
            let x = (i as f64 + rng.uniform()) * CELL;
            let y = (j as f64 + rng.uniform()) * CELL;
            // Inverse CDF of p(r) ∝ r⁻³ on [r0, r1].
            let q = rng.uniform();
            let r = 1.0 / (r0.powi(-2) - q * (r0.powi(-2) - r1.powi(-2))).sqrt();
            Leaf {
                x,
                y,
                r,
                depth: rng.uniform(),
                value: rng.uniform(),
            }
        })
        .collect()
}

/// Discs dropped per cell of [`DeadLeaves`]: the mean disc covers ~210 square units, so 24
/// per 32-unit cell cover the plane about five times over.
const DISCS_PER_CELL: usize = 24;
