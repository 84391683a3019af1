//! Finding the `cols × rows` lattice among the blobs and numbering its circles.
//!
//! Both kinds of grid are lattices: a symmetric grid with basis `(1, 0)`, `(0, 1)` (units of
//! spacing), an asymmetric one with basis `(1, 1)`, `(1, −1)` (its rows are the lattice's
//! diagonals). So one procedure serves both:
//!
//! 1. **Seed**: a blob, its nearest neighbour of similar size (`u`) and its nearest one not
//!    along `u` (`v`). In 2-D the shortest lattice vector and the shortest one not parallel to
//!    it form a basis (Lagrange–Gauss reduction), so `(u, v)` spans the lattice whatever the
//!    tilt, though which board vectors they are is not known yet.
//! 2. **Grow** breadth-first: from each node, predict its four neighbours with the local step
//!    vectors (updated at every step, so the prediction follows perspective and distortion) and
//!    take the nearest blob within a third of a step. Clutter off the lattice is never reached.
//! 3. **Number**: find the integer maps `M` (lattice coordinates → board coordinates, entries in
//!    −3..3, |det| 1 for symmetric, 2 for asymmetric grids) under which the grown nodes are
//!    exactly the pattern's `cols × rows` positions. A grid with more or fewer nodes is
//!    rejected: like OpenCV, a grid is found whole or not at all.
//! 4. **Order**: of the fitting maps, keep those whose numbering has the board's handedness in
//!    the image (the board seen from its printed side: `(p[1] − p[0]) × (p[cols] − p[0]) > 0`,
//!    x right, y down), then the one whose last row does not start above circle 0, then circle
//!    0 nearest the image top, then left. Only a pattern with a symmetry (every symmetric grid
//!    under a half turn, square ones under a quarter turn too; asymmetric grids with an even
//!    number of rows under a half turn) reaches the last two rules.

use std::collections::{HashMap, VecDeque};

use super::blobs::Blob;
use super::geometry::CircleGrid;

/// Seeds tried before giving up.
const MAX_SEEDS: usize = 400;
/// Accepted distance from a prediction, as a fraction of the shorter step.
const TOLERANCE: f64 = 0.33;
/// Neighbours of a seed must be within this factor of its area.
const AREA_RATIO: f64 = 3.0;

/// Uniform buckets of blob centres for nearest-neighbour queries.
struct Buckets {
    cell: f64,
    map: HashMap<(i64, i64), Vec<usize>>,
}

impl Buckets {
    fn new(blobs: &[Blob], cell: f64) -> Self {
        let mut map: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
        for (k, b) in blobs.iter().enumerate() {
            map.entry(Self::key(cell, b.c)).or_default().push(k);
        }
        Self { cell, map }
    }

    fn key(cell: f64, p: [f64; 2]) -> (i64, i64) {
        ((p[0] / cell).floor() as i64, (p[1] / cell).floor() as i64)
    }

    /// Blobs within `r` of `p` (`r` is capped at 8 cells to bound the scan).
    fn within(&self, blobs: &[Blob], p: [f64; 2], r: f64) -> Vec<usize> {
        let r = r.min(8.0 * self.cell);
        let (x0, y0) = Self::key(self.cell, [p[0] - r, p[1] - r]);
        let (x1, y1) = Self::key(self.cell, [p[0] + r, p[1] + r]);
        let mut out = Vec::new();
        for gx in x0..=x1 {
            for gy in y0..=y1 {
                for &k in self.map.get(&(gx, gy)).into_iter().flatten() {
                    let c = blobs[k].c;
                    if (c[0] - p[0]).hypot(c[1] - p[1]) <= r {
                        out.push(k);
                    }
                }
            }
        }
        out
    }
}

fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

fn norm(a: [f64; 2]) -> f64 {
    a[0].hypot(a[1])
}

fn cross(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}

fn similar(a: &Blob, b: &Blob) -> bool {
    a.area <= AREA_RATIO * b.area && b.area <= AREA_RATIO * a.area
}

/// The seed basis of blob `s` (see the module docs).
fn seed_basis(blobs: &[Blob], idx: &Buckets, s: usize) -> Option<([f64; 2], [f64; 2])> {
    let b = &blobs[s];
    let (major, _) = b.axes();
    let mut near: Vec<(f64, [f64; 2])> = idx
        .within(blobs, b.c, 12.0 * major)
        .into_iter()
        .filter(|&k| k != s && similar(b, &blobs[k]))
        .map(|k| {
            let d = sub(blobs[k].c, b.c);
            (norm(d), d)
        })
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (lu, u) = *near.first()?;
    let (_, v) = near
        .iter()
        .skip(1)
        .find(|(l, d)| (cross(u, *d) / (lu * l)).abs() > 0.5 && *l <= 4.0 * lu)?;
    Some((u, *v))
}

/// A grown lattice: integer coordinates → blob.
type Nodes = HashMap<(i64, i64), usize>;

/// Grows the lattice from seed `s` (see the module docs); `None` when it becomes inconsistent
/// (a blob claimed twice); growth stops past `limit` nodes.
fn grow(blobs: &[Blob], idx: &Buckets, s: usize, limit: usize) -> Option<Nodes> {
    let (u, v) = seed_basis(blobs, idx, s)?;
    let mut nodes: Nodes = HashMap::new();
    let mut used: HashMap<usize, (i64, i64)> = HashMap::new();
    // Per node: its step vectors along +i and +j.
    let mut steps: HashMap<(i64, i64), ([f64; 2], [f64; 2])> = HashMap::new();
    nodes.insert((0, 0), s);
    used.insert(s, (0, 0));
    steps.insert((0, 0), (u, v));
    let mut queue = VecDeque::from([(0i64, 0i64)]);
    // Every node enters the queue once and nodes are capped at `limit`: bounded.
    while let Some(q) = queue.pop_front() {
        let p = blobs[nodes[&q]].c;
        let (su, sv) = steps[&q];
        for (di, dj) in [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)] {
            let n = (q.0 + di, q.1 + dj);
            if nodes.contains_key(&n) {
                continue;
            }
            let step = [
                di as f64 * su[0] + dj as f64 * sv[0],
                di as f64 * su[1] + dj as f64 * sv[1],
            ];
            let pred = [p[0] + step[0], p[1] + step[1]];
            let tol = TOLERANCE * norm(su).min(norm(sv));
            let Some(k) = idx
                .within(blobs, pred, tol)
                .into_iter()
                .filter(|&k| similar(&blobs[nodes[&q]], &blobs[k]))
                .min_by(|&a, &b| {
                    norm(sub(blobs[a].c, pred)).total_cmp(&norm(sub(blobs[b].c, pred)))
                })
            else {
                continue;
            };
            if let Some(&other) = used.get(&k) {
                if other != n {
                    return None;
                }
                continue;
            }
            let actual = sub(blobs[k].c, p);
            let ns = if di != 0 {
                ([actual[0] * di as f64, actual[1] * di as f64], sv)
            } else {
                (su, [actual[0] * dj as f64, actual[1] * dj as f64])
            };
            nodes.insert(n, k);
            used.insert(k, n);
            steps.insert(n, ns);
            if nodes.len() > limit {
                return Some(nodes);
            }
            queue.push_back(n);
        }
    }
    Some(nodes)
}

/// The numberings of `nodes` as `grid` (blob per circle id), one per fitting integer map.
fn numberings(nodes: &Nodes, grid: &CircleGrid) -> Vec<Vec<usize>> {
    let mut out = Vec::new();
    if nodes.len() != grid.len() {
        return out;
    }
    let want_det = if grid.asymmetric { 2 } else { 1 };
    let pts: Vec<((i64, i64), usize)> = nodes.iter().map(|(&q, &b)| (q, b)).collect();
    let r = -3i64..=3;
    for a in r.clone() {
        for b in r.clone() {
            for c in r.clone() {
                for d in r.clone() {
                    if (a * d - b * c).abs() != want_det {
                        continue;
                    }
                    // Asymmetric grids: both columns must be board lattice vectors (x + y even).
                    if grid.asymmetric && ((a + c) % 2 != 0 || (b + d) % 2 != 0) {
                        continue;
                    }
                    let mapped: Vec<([i64; 2], usize)> = pts
                        .iter()
                        .map(|&((i, j), k)| ([a * i + b * j, c * i + d * j], k))
                        .collect();
                    if let Some(ids) = fit(&mapped, grid) {
                        out.push(ids);
                    }
                }
            }
        }
    }
    out
}

/// Blob per id when the mapped points, translated so that row 0 starts at x = 0, are exactly
/// the pattern's positions.
fn fit(mapped: &[([i64; 2], usize)], grid: &CircleGrid) -> Option<Vec<usize>> {
    let y0 = mapped.iter().map(|(p, _)| p[1]).min()?;
    let x0 = mapped
        .iter()
        .filter(|(p, _)| p[1] == y0)
        .map(|(p, _)| p[0])
        .min()?;
    let mut ids = vec![usize::MAX; grid.len()];
    for &(p, k) in mapped {
        let (x, y) = (p[0] - x0, p[1] - y0);
        if !(0..grid.rows as i64).contains(&y) {
            return None;
        }
        let r = y as usize;
        let shift = if grid.asymmetric { y % 2 } else { 0 };
        let step = if grid.asymmetric { 2 } else { 1 };
        if (x - shift) % step != 0 || x < shift {
            return None;
        }
        let c = ((x - shift) / step) as usize;
        if c >= grid.cols || ids[r * grid.cols + c] != usize::MAX {
            return None;
        }
        ids[r * grid.cols + c] = k;
    }
    Some(ids)
}

/// Picks the numbering by the rules of the module docs; `centres[k]` is blob k's centre.
fn choose(cands: Vec<Vec<usize>>, centres: &[[f64; 2]], grid: &CircleGrid) -> Option<Vec<usize>> {
    let cols = grid.cols;
    // (handedness, last row not above, −y0, −x0): lexicographically larger is better.
    type Key = (bool, bool, f64, f64);
    let mut best: Option<(Key, Vec<usize>)> = None;
    for ids in cands {
        let p = |id: usize| centres[ids[id]];
        let mut hand = 0.0;
        for r in 0..grid.rows - 1 {
            for c in 0..cols - 1 {
                let o = p(r * cols + c);
                hand += cross(sub(p(r * cols + c + 1), o), sub(p((r + 1) * cols + c), o));
            }
        }
        let first = p(0);
        let key = (
            hand > 0.0,
            p((grid.rows - 1) * cols)[1] >= first[1],
            -first[1],
            -first[0],
        );
        if best
            .as_ref()
            .is_none_or(|(bk, _)| key.partial_cmp(bk) == Some(std::cmp::Ordering::Greater))
        {
            best = Some((key, ids));
        }
    }
    best.filter(|(k, _)| k.0).map(|(_, ids)| ids)
}

/// Why no lattice was found, or the blob index of every circle id.
pub(super) fn find_lattice(blobs: &[Blob], grid: &CircleGrid) -> Result<Vec<usize>, String> {
    if blobs.len() < grid.len() {
        return Err(format!(
            "{} dark round blobs, the grid has {} circles",
            blobs.len(),
            grid.len()
        ));
    }
    let mut majors: Vec<f64> = blobs.iter().map(|b| b.axes().0).collect();
    majors.sort_by(f64::total_cmp);
    let cell = (4.0 * majors[majors.len() / 2]).max(4.0);
    let idx = Buckets::new(blobs, cell);
    let centres: Vec<[f64; 2]> = blobs.iter().map(|b| b.c).collect();
    let mut order: Vec<usize> = (0..blobs.len()).collect();
    order.sort_by_key(|&k| std::cmp::Reverse(blobs[k].repeats));
    let mut largest = 0;
    // A seed next to clutter can grow a wrong lattice through grid circles, so every blob
    // stays a candidate seed; growth is cheap and the number of seeds bounded.
    for s in order.into_iter().take(MAX_SEEDS) {
        let Some(nodes) = grow(blobs, &idx, s, grid.len()) else {
            continue;
        };
        largest = largest.max(nodes.len());
        if let Some(ids) = choose(numberings(&nodes, grid), &centres, grid) {
            return Ok(ids);
        }
    }
    Err(if largest > grid.len() {
        format!(
            "more than the {} circles of the grid form a lattice (a larger grid, or dark dots \
             on the lattice next to it)",
            grid.len()
        )
    } else if largest < grid.len() {
        format!(
            "the largest lattice of round blobs has {largest} of the {} circles (the grid is \
             partly out of view, occluded, too blurred, or not a {}×{} {} grid)",
            grid.len(),
            grid.cols,
            grid.rows,
            if grid.asymmetric {
                "asymmetric"
            } else {
                "symmetric"
            }
        )
    } else {
        format!(
            "{} blobs form a lattice, but not the {}×{} pattern (wrong size or kind of grid?)",
            largest, grid.cols, grid.rows
        )
    })
}
