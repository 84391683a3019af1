//! AprilGrid boards (Kalibr): a grid of AprilTag 36h11 tags (Olson 2011) with small black
//! squares between the tag corners, so that every tag corner is an X-junction.
//!
//! # Layout (Kalibr's `GridCalibrationTargetAprilgrid` and `kalibr_create_target_pdf`)
//!
//! Board frame x right, **y up**, origin at the bottom-left corner of tag 0. Tag `t` sits in
//! column `t % tag_cols` and row `t / tag_cols` (row 0 at the bottom), its bottom-left corner
//! at `(col, row)·(1 + tag_spacing)·tag_size`; `tag_spacing` is the gap between tags as a
//! fraction of `tag_size`. A tag is `tag_size` wide edge to edge: 6×6 data cells inside a
//! black border two cells wide (Kalibr's `blackTagBorder = 2`), so cells are `tag_size / 10`.
//! Kalibr draws the code of Kaess's tag36h11 table rotated by a half turn; that is exactly
//! OpenCV's `DICT_APRILTAG_36h11` code upright, rotated by a half turn (checked on all 587
//! codes), so a tag read upright by OpenCV's convention shows Kalibr's bottom-right corner at
//! its top-left. Black squares of side `tag_spacing·tag_size` touch every tag corner
//! diagonally.
//!
//! Corners: 4 per tag on a `2·tag_rows × 2·tag_cols` grid, id `r·2·tag_cols + c`, at
//! `x = ⌊c/2⌋·(1 + s)·size + (c mod 2)·size`, same for `y` with `r`; tag `t`'s corners
//! bottom-left, bottom-right, top-right, top-left have ids `base, base + 1,
//! base + 2·tag_cols + 1, base + 2·tag_cols` with `base = ⌊t/tag_cols⌋·4·tag_cols +
//! (t mod tag_cols)·2`.
//!
//! # Detection
//!
//! Tags ([`crate::board::markers`], border of 2 cells); each tag corner is refined by the
//! saddle fit (Lucchese & Mitra 2002): the squares Kalibr adds make it an X-junction, for which
//! the fit is unbiased under blur, whereas a corner of a lone black square is not. The window
//! stays within the tag's border and the spacing square; a corner is kept when the fit
//! converges near the tag's outline and the four regions around it have the right colours.

pub(crate) mod kalibr_yaml;

use super::filter::ImageF;
use super::markers::{Dictionary, Marker, SquareMap};
use crate::board::chessboard::subpix::SaddleFitter;

/// A validated AprilGrid layout.
#[derive(Clone, Debug)]
pub struct AprilGrid {
    pub(crate) tag_rows: usize,
    pub(crate) tag_cols: usize,
    pub(crate) tag_size: f64,
    pub(crate) tag_spacing: f64,
    pub(crate) dict: Dictionary,
}

impl AprilGrid {
    /// Number of corners (4 per tag).
    pub fn num_corners(&self) -> usize {
        4 * self.tag_rows * self.tag_cols
    }

    /// Board position of corner `id` (Kalibr's `createGridPoints`).
    pub fn corner_position(&self, id: usize) -> Option<[f64; 2]> {
        (id < self.num_corners()).then(|| {
            let gc = 2 * self.tag_cols;
            let (r, c) = (id / gc, id % gc);
            let pitch = (1.0 + self.tag_spacing) * self.tag_size;
            let f = |k: usize| (k / 2) as f64 * pitch + (k % 2) as f64 * self.tag_size;
            [f(c), f(r)]
        })
    }

    /// Corner ids of tag `t`: bottom-left, bottom-right, top-right, top-left.
    pub fn tag_corner_ids(&self, t: usize) -> [usize; 4] {
        let gc = 2 * self.tag_cols;
        let base = (t / self.tag_cols) * 2 * gc + (t % self.tag_cols) * 2;
        [base, base + 1, base + gc + 1, base + gc]
    }

    /// Board corners of tag `t` in the order of [`Marker::corners`] (OpenCV's top-left,
    /// top-right, bottom-right, bottom-left of the upright code, which are Kalibr's
    /// bottom-right, bottom-left, top-left, top-right).
    pub fn tag_outline(&self, t: usize) -> Option<[[f64; 2]; 4]> {
        if t >= self.tag_rows * self.tag_cols {
            return None;
        }
        let ids = self.tag_corner_ids(t);
        Some([
            self.corner_position(ids[1])?,
            self.corner_position(ids[0])?,
            self.corner_position(ids[3])?,
            self.corner_position(ids[2])?,
        ])
    }

    /// How far (board units) a missing tag may be from the decoded ones that place it: two
    /// tags along a row and diagonally.
    pub(crate) fn prediction_reach(&self) -> f64 {
        2.9 * (1.0 + self.tag_spacing) * self.tag_size
    }

    /// Colour of the printed board at board point `(x, y)` (y up): `Some(true)` black,
    /// `Some(false)` white, `None` outside the pattern (tags and corner squares).
    pub fn is_black(&self, x: f64, y: f64) -> Option<bool> {
        let ts = self.tag_size;
        let pitch = (1.0 + self.tag_spacing) * ts;
        let sq = self.tag_spacing * ts;
        let span = |v: f64, n: usize| v >= -sq && v < n as f64 * pitch;
        if !span(x, self.tag_cols) || !span(y, self.tag_rows) {
            return None;
        }
        let (col, row) = ((x / pitch).floor(), (y / pitch).floor());
        let (fx, fy) = (x - col * pitch, y - row * pitch);
        let in_tag = |f: f64, k: f64| k >= 0.0 && f < ts;
        let (tx, ty) = (in_tag(fx, col), in_tag(fy, row));
        if !tx && !ty {
            return Some(true);
        }
        if !(tx && ty) {
            return Some(false);
        }
        let cell = ts / 10.0;
        let cx = ((fx / cell) as usize).min(9);
        let top = 9 - ((fy / cell) as usize).min(9);
        if !(2..8).contains(&cx) || !(2..8).contains(&top) {
            return Some(true);
        }
        let t = row as usize * self.tag_cols + col as usize;
        // Kalibr's upright tag is OpenCV's code turned by a half turn.
        Some(!self.dict.is_white(t, 7 - top, 7 - cx))
    }
}

/// Refined corners of the AprilGrid from its decoded tags (ids on the board only): `(id,
/// pixel)` sorted by id, and the number of tag corners rejected by the refinement.
pub(crate) fn aprilgrid_corners(
    s: &ImageF,
    grid: &AprilGrid,
    tags: &[Marker],
    min_contrast: f64,
) -> (Vec<(usize, [f64; 2])>, usize) {
    let mut fitters: Vec<Option<SaddleFitter>> = (0..=8).map(|_| None).collect();
    let mut out = Vec::with_capacity(4 * tags.len());
    let mut rejected = 0;
    let pure = grid.tag_spacing.min(0.2);
    for tag in tags {
        // Corners of a predicted tag failing their checks are expected (occluded, blank).
        let counts = usize::from(!tag.is_predicted());
        let Some(map) = SquareMap::new(&tag.corners) else {
            rejected += 4 * counts;
            continue;
        };
        let c = &tag.corners;
        let side = (0..4)
            .map(|k| (c[k][0] - c[(k + 1) % 4][0]).hypot(c[k][1] - c[(k + 1) % 4][1]))
            .fold(f64::MAX, f64::min);
        let r0 = ((0.9 * pure * side).round() as i32).clamp(2, 8);
        // The outline's corner can sit a few pixels off the junction: at a steep tilt the small
        // square touching it merges with the border; the nearest other junction is a spacing
        // square (≥ 0.3 side along the board) away, and the colour check below rejects it.
        let max_shift = (0.2 * side).max(1.5);
        // OpenCV's top-left, top-right, bottom-right, bottom-left are Kalibr's bottom-right,
        // bottom-left, top-left, top-right.
        let ids = grid.tag_corner_ids(tag.id);
        let kalibr = [ids[1], ids[0], ids[3], ids[2]];
        // Unit-square position of each corner in the tag's (OpenCV) frame.
        let unit = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        for k in 0..4 {
            let mut done = None;
            for radius in (2..=r0).rev() {
                let f = fitters[radius as usize].get_or_insert_with(|| SaddleFitter::new(radius));
                if let Some(p) = f.refine(s, c[k], max_shift) {
                    done = Some(p);
                    break;
                }
            }
            let Some(p) = done else {
                rejected += counts;
                continue;
            };
            // Colours: inside the tag and the spacing square dark, the two gaps bright.
            let [u, v] = unit[k];
            let (su, sv) = (
                if u > 0.5 { -1.0 } else { 1.0 },
                if v > 0.5 { -1.0 } else { 1.0 },
            );
            let off = 0.5 * pure;
            let shift = [p[0] - c[k][0], p[1] - c[k][1]];
            let at = |du: f64, dv: f64| {
                let q = map.map(u + du, v + dv);
                let (x, y) = (q[0] + shift[0], q[1] + shift[1]);
                s.contains(x, y, 0.0).then(|| f64::from(s.bilinear(x, y)))
            };
            let vals = (
                at(su * off, sv * off),
                at(-su * off, -sv * off),
                at(su * off, -sv * off),
                at(-su * off, sv * off),
            );
            let ok = match vals {
                (Some(d1), Some(d2), Some(b1), Some(b2)) => {
                    b1.min(b2) - d1.max(d2) >= 0.5 * min_contrast
                }
                _ => false,
            };
            if ok {
                out.push((kalibr[k], p));
            } else {
                rejected += counts;
            }
        }
    }
    out.sort_by_key(|&(id, _)| id);
    (out, rejected)
}
