//! Dark quadrilaterals: the outlines of candidate markers.
//!
//! 1. **Threshold** by local extrema (Wang & Olson, "AprilTag 2: efficient and robust fiducial
//!    detection", IROS 2016): the minimum and maximum of 4×4-pixel tiles, spread over the 3×3
//!    neighbouring tiles; a pixel is dark when it is below `min + 0.4·(max − min)` and the
//!    range is at least `min_contrast`. Flat regions (inside big black squares) stay
//!    undecided, which does not matter: only the outline of a dark region is used. The level
//!    below the midpoint separates regions that touch at a corner (ChArUco squares, the
//!    squares between AprilGrid tags), whose blurred X-junction sits at the midpoint.
//! 2. **Dark regions** as runs of dark pixels joined across rows (4-connectivity, union-find).
//! 3. **Outline** of every region of plausible size: the ends of its runs and the top and
//!    bottom of every column it covers.
//! 4. **Quad**: two opposite corners are the outline point farthest from the centroid and the
//!    point farthest from that one; the two others are the farthest from their diagonal on
//!    either side. Every outline point is given to its nearest side, each side is re-fitted
//!    as a total-least-squares line, the corners are the intersections; the region is a quad
//!    when every outline point lies close to its side.

use crate::io::Gray;

/// A dark quadrilateral: corners clockwise on screen (x right, y down), starting anywhere.
#[derive(Clone, Copy, Debug)]
pub struct Quad {
    pub corners: [[f64; 2]; 4],
}

const TILE: usize = 4;

/// The dark mask (1 = dark) of `img` by tile extrema (see the module docs).
fn dark_mask(img: &Gray, min_contrast: f64, level: f64) -> Vec<u8> {
    let (w, h) = (img.width as usize, img.height as usize);
    let (tw, th) = (w.div_ceil(TILE), h.div_ceil(TILE));
    let mut tmin = vec![255u8; tw * th];
    let mut tmax = vec![0u8; tw * th];
    for y in 0..h {
        let row = &img.data[y * w..(y + 1) * w];
        let trow = (y / TILE) * tw;
        for (t, chunk) in row.chunks(TILE).enumerate() {
            let (mut lo, mut hi) = (tmin[trow + t], tmax[trow + t]);
            for &v in chunk {
                lo = lo.min(v);
                hi = hi.max(v);
            }
            tmin[trow + t] = lo;
            tmax[trow + t] = hi;
        }
    }
    // Spread over the 3×3 neighbourhood of tiles.
    let mut nmin = vec![255u8; tw * th];
    let mut nmax = vec![0u8; tw * th];
    for ty in 0..th {
        for tx in 0..tw {
            let (mut lo, mut hi) = (255u8, 0u8);
            for yy in ty.saturating_sub(1)..(ty + 2).min(th) {
                for xx in tx.saturating_sub(1)..(tx + 2).min(tw) {
                    lo = lo.min(tmin[yy * tw + xx]);
                    hi = hi.max(tmax[yy * tw + xx]);
                }
            }
            nmin[ty * tw + tx] = lo;
            nmax[ty * tw + tx] = hi;
        }
    }
    // Per tile threshold (255 = nothing is dark there).
    let thr: Vec<u8> = nmin
        .iter()
        .zip(&nmax)
        .map(|(&lo, &hi)| {
            let range = f64::from(hi) - f64::from(lo);
            if range < min_contrast {
                0
            } else {
                (f64::from(lo) + level * range).round() as u8
            }
        })
        .collect();
    let mut mask = vec![0u8; w * h];
    for y in 0..h {
        let trow = &thr[(y / TILE) * tw..(y / TILE + 1) * tw];
        let src = &img.data[y * w..(y + 1) * w];
        let dst = &mut mask[y * w..(y + 1) * w];
        for (x, (d, &v)) in dst.iter_mut().zip(src).enumerate() {
            *d = u8::from(v < trow[x / TILE]);
        }
    }
    mask
}

/// A horizontal run of dark pixels `[x0, x1)` on row `y`.
#[derive(Clone, Copy)]
struct Run {
    y: u32,
    x0: u32,
    x1: u32,
}

fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let p = parent[parent[i as usize] as usize];
        parent[i as usize] = p;
        i = p;
    }
    i
}

/// Every dark quadrilateral of `img` whose bounding box is at least `min_side` pixels wide
/// and high, not touching the image border. Dark is below `min + level·(max − min)` locally
/// (0.4 in the module docs; lower separates X-junctions better where a tilt makes the white
/// wedges narrow, at the cost of thin dark lines).
pub fn find_quads(img: &Gray, min_contrast: f64, min_side: f64, level: f64) -> Vec<Quad> {
    let (w, h) = (img.width as usize, img.height as usize);
    if w < 8 || h < 8 {
        return Vec::new();
    }
    let mask = dark_mask(img, min_contrast, level);
    // Runs, row by row, joined to overlapping runs of the previous row.
    let mut runs: Vec<Run> = Vec::new();
    let mut parent: Vec<u32> = Vec::new();
    let mut prev = 0..0;
    for y in 0..h {
        let row = &mask[y * w..(y + 1) * w];
        let start = runs.len();
        let mut x = 0;
        while x < w {
            if row[x] == 0 {
                x += 1;
                continue;
            }
            let x0 = x;
            while x < w && row[x] != 0 {
                x += 1;
            }
            runs.push(Run {
                y: y as u32,
                x0: x0 as u32,
                x1: x as u32,
            });
            parent.push((runs.len() - 1) as u32);
        }
        let cur = start..runs.len();
        // Two-pointer merge with the previous row's runs.
        let (mut i, mut j) = (prev.start, cur.start);
        while i < prev.end && j < cur.end {
            let (a, b) = (runs[i], runs[j]);
            if a.x0 < b.x1 && b.x0 < a.x1 {
                let (ra, rb) = (find(&mut parent, i as u32), find(&mut parent, j as u32));
                if ra != rb {
                    parent[ra.max(rb) as usize] = ra.min(rb);
                }
            }
            if a.x1 < b.x1 {
                i += 1;
            } else {
                j += 1;
            }
        }
        prev = cur;
    }
    // Bounding boxes per region.
    let n = runs.len();
    let mut root = vec![0u32; n];
    for (i, r) in root.iter_mut().enumerate() {
        *r = find(&mut parent, i as u32);
    }
    let mut bbox: Vec<[u32; 4]> = vec![[u32::MAX, u32::MAX, 0, 0]; n];
    for (run, &r) in runs.iter().zip(&root) {
        let b = &mut bbox[r as usize];
        b[0] = b[0].min(run.x0);
        b[1] = b[1].min(run.y);
        b[2] = b[2].max(run.x1);
        b[3] = b[3].max(run.y + 1);
    }
    let max_side = 0.95 * w.max(h) as f64;
    let ok = |b: &[u32; 4]| {
        let (bw, bh) = (
            f64::from(b[2]) - f64::from(b[0]),
            f64::from(b[3]) - f64::from(b[1]),
        );
        b[0] > 0
            && b[1] > 0
            && (b[2] as usize) < w
            && (b[3] as usize) < h
            && bw >= min_side
            && bh >= min_side
            && bw <= max_side
            && bh <= max_side
    };
    // Group the runs of kept regions.
    let mut members: std::collections::HashMap<u32, Vec<usize>> = Default::default();
    for (i, &r) in root.iter().enumerate() {
        if bbox[r as usize][2] > 0 && ok(&bbox[r as usize]) {
            members.entry(r).or_default().push(i);
        }
    }
    let mut keys: Vec<u32> = members.keys().copied().collect();
    keys.sort_unstable();
    keys.into_iter()
        .filter_map(|r| {
            let b = bbox[r as usize];
            outline_quad(&runs, &members[&r], b)
        })
        .collect()
}

/// The outline of a region: the first and last dark pixel of every row and column it covers
/// (inner edges, around holes and white bits, are not part of it).
fn outline_quad(runs: &[Run], members: &[usize], b: [u32; 4]) -> Option<Quad> {
    let bw = (b[2] - b[0]) as usize;
    let bh = (b[3] - b[1]) as usize;
    let mut top = vec![u32::MAX; bw];
    let mut bottom = vec![0u32; bw];
    let mut left = vec![u32::MAX; bh];
    let mut right = vec![0u32; bh];
    let mut area = 0u64;
    for &i in members {
        let r = runs[i];
        area += u64::from(r.x1 - r.x0);
        let k = (r.y - b[1]) as usize;
        left[k] = left[k].min(r.x0);
        right[k] = right[k].max(r.x1);
        for x in r.x0..r.x1 {
            let k = (x - b[0]) as usize;
            top[k] = top[k].min(r.y);
            bottom[k] = bottom[k].max(r.y);
        }
    }
    // Pixel edges: the outline runs half a pixel outside the dark pixel centres.
    let mut pts: Vec<[f64; 2]> = Vec::with_capacity(2 * (bw + bh));
    for k in 0..bh {
        if left[k] != u32::MAX {
            let y = f64::from(b[1]) + k as f64;
            pts.push([f64::from(left[k]) - 0.5, y]);
            pts.push([f64::from(right[k]) - 0.5, y]);
        }
    }
    for k in 0..bw {
        if top[k] != u32::MAX {
            let x = f64::from(b[0]) + k as f64;
            pts.push([x, f64::from(top[k]) - 0.5]);
            pts.push([x, f64::from(bottom[k]) + 0.5]);
        }
    }
    fit_quad(&pts, area as f64)
}

fn d2(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)
}

/// Signed distance of `p` from the line through `a` and `b` (positive to the right on screen).
fn side(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len = dx.hypot(dy).max(1e-12);
    (dx * (p[1] - a[1]) - dy * (p[0] - a[0])) / len
}

/// A line `n·p = c` with unit normal `n` fitted by total least squares.
fn fit_line(pts: &[[f64; 2]]) -> Option<([f64; 2], f64)> {
    if pts.len() < 2 {
        return None;
    }
    let k = pts.len() as f64;
    let mx = pts.iter().map(|p| p[0]).sum::<f64>() / k;
    let my = pts.iter().map(|p| p[1]).sum::<f64>() / k;
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in pts {
        let (dx, dy) = (p[0] - mx, p[1] - my);
        sxx += dx * dx;
        sxy += dx * dy;
        syy += dy * dy;
    }
    // Direction of largest spread; the normal is perpendicular.
    let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let n = [-theta.sin(), theta.cos()];
    Some((n, n[0] * mx + n[1] * my))
}

fn intersect(a: ([f64; 2], f64), b: ([f64; 2], f64)) -> Option<[f64; 2]> {
    let det = a.0[0] * b.0[1] - a.0[1] * b.0[0];
    if det.abs() < 1e-9 {
        return None;
    }
    Some([
        (a.1 * b.0[1] - b.1 * a.0[1]) / det,
        (a.0[0] * b.1 - b.0[0] * a.1) / det,
    ])
}

/// The quad through outline points `pts` of a region of `area` pixels, if it is one.
fn fit_quad(pts: &[[f64; 2]], area: f64) -> Option<Quad> {
    let k = pts.len() as f64;
    let c = [
        pts.iter().map(|p| p[0]).sum::<f64>() / k,
        pts.iter().map(|p| p[1]).sum::<f64>() / k,
    ];
    let far = |from: [f64; 2]| {
        pts.iter()
            .copied()
            .max_by(|a, b| d2(*a, from).total_cmp(&d2(*b, from)))
    };
    let a = far(c)?;
    let b = far(a)?;
    let mut right = (0.0f64, a);
    let mut left = (0.0f64, a);
    for &p in pts {
        let s = side(a, b, p);
        if s > right.0 {
            right = (s, p);
        }
        if s < left.0 {
            left = (s, p);
        }
    }
    let diag = d2(a, b).sqrt();
    if right.0 < 0.2 * diag || -left.0 < 0.2 * diag {
        return None;
    }
    // Clockwise on screen (x right, y down): a, left of a→b, b, right of a→b.
    let mut q = [a, left.1, b, right.1];
    // Two passes: assign points to sides, refit lines, intersect.
    for _ in 0..2 {
        let mut groups: [Vec<[f64; 2]>; 4] = Default::default();
        for &p in pts {
            let (mut best, mut bd) = (0, f64::MAX);
            for s in 0..4 {
                let d = seg_dist(q[s], q[(s + 1) % 4], p);
                if d < bd {
                    bd = d;
                    best = s;
                }
            }
            groups[best].push(p);
        }
        let mut lines = [([0.0; 2], 0.0); 4];
        for s in 0..4 {
            // Leave out the points near the ends: rounded corners bend the outline there.
            let (p0, p1) = (q[s], q[(s + 1) % 4]);
            let len = d2(p0, p1).sqrt();
            let inner: Vec<[f64; 2]> = groups[s]
                .iter()
                .copied()
                .filter(|&p| d2(p, p0).sqrt() > 0.15 * len && d2(p, p1).sqrt() > 0.15 * len)
                .collect();
            if (inner.len() as f64) < 0.3 * len {
                return None;
            }
            lines[s] = fit_line(&inner)?;
        }
        for s in 0..4 {
            q[(s + 1) % 4] = intersect(lines[s], lines[(s + 1) % 4])?;
        }
    }
    // Every outline point near its side; a convex quad of about the region's area.
    let perim: f64 = (0..4).map(|s| d2(q[s], q[(s + 1) % 4]).sqrt()).sum();
    let tol = 1.2 + 0.02 * perim;
    for &p in pts {
        let d = (0..4)
            .map(|s| seg_dist(q[s], q[(s + 1) % 4], p))
            .fold(f64::MAX, f64::min);
        if d > tol {
            return None;
        }
    }
    for s in 0..4 {
        if side(q[s], q[(s + 1) % 4], q[(s + 2) % 4]) <= 0.0 {
            return None;
        }
        if d2(q[s], q[(s + 1) % 4]).sqrt() < 0.15 * perim / 4.0 {
            return None;
        }
    }
    let qa = 0.5
        * (0..4)
            .map(|s| q[s][0] * q[(s + 1) % 4][1] - q[(s + 1) % 4][0] * q[s][1])
            .sum::<f64>();
    if qa.abs() < 0.5 * area {
        return None;
    }
    Some(Quad { corners: q })
}

/// Distance from `p` to the segment `a–b`.
fn seg_dist(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let l2 = dx * dx + dy * dy;
    let t = if l2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    d2(p, [a[0] + t * dx, a[1] + t * dy]).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_dark_square_is_one_quad_with_its_corners() {
        let (w, h) = (80u32, 60u32);
        let mut data = vec![200u8; (w * h) as usize];
        for y in 20..40 {
            for x in 30..55 {
                data[y * w as usize + x] = 20;
            }
        }
        let img = Gray {
            width: w,
            height: h,
            data,
        };
        let q = find_quads(&img, 10.0, 8.0, 0.4);
        assert_eq!(q.len(), 1);
        let mut c = q[0].corners.to_vec();
        c.sort_by(|a, b| (a[0] + 2.0 * a[1]).total_cmp(&(b[0] + 2.0 * b[1])));
        for (got, want) in c
            .iter()
            .zip([[29.5, 19.5], [54.5, 19.5], [29.5, 39.5], [54.5, 39.5]])
        {
            assert!(d2(*got, want).sqrt() < 0.3, "{got:?} vs {want:?}");
        }
    }
}
