//! ChArUco boards (OpenCV): a chessboard whose white squares hold ArUco markers, so that
//! every inner corner is identified by the markers next to it and a partial view still gives
//! its corners with ids.
//!
//! # Layout (OpenCV ≥ 4.6, checked against OpenCV 5's `CharucoBoard`)
//!
//! `squares_x × squares_y` squares of side `square`, board frame x right and y down from the
//! board's top-left corner. Square `(i, j)` (column, row) is black when `i` and `j` have the
//! same parity; with `legacy` and an even number of rows (OpenCV's `setLegacyPattern`, the
//! layout before 4.6) when they do not. The white squares hold markers of side `marker`,
//! centred, numbered 0, 1, … row-major, upright (bit row 0 towards y = 0). Inner corner
//! `(a, b)` (1 ≤ a < squares_x, 1 ≤ b < squares_y) sits at `(a·square, b·square)` and has id
//! `(b − 1)·(squares_x − 1) + a − 1`.
//!
//! # Detection
//!
//! Markers ([`crate::board::markers`]); every inner corner of a marker's square is predicted
//! by the homography of that marker (averaged over the two markers next to a corner when
//! both are seen), refined by the saddle fit of the chessboard detector (Lucchese & Mitra
//! 2002) with a window that stays inside the white margin around the markers, and kept only
//! when the fit converges near the prediction and the squares around it show the expected
//! colours.

use super::filter::ImageF;
use super::markers::{Dictionary, Marker};
use crate::board::chessboard::subpix::SaddleFitter;

/// A validated ChArUco layout.
#[derive(Clone, Debug)]
pub struct CharucoBoard {
    pub(crate) squares_x: usize,
    pub(crate) squares_y: usize,
    pub(crate) square: f64,
    pub(crate) marker: f64,
    pub(crate) dict: Dictionary,
    pub(crate) legacy: bool,
}

impl CharucoBoard {
    /// Whether square `(i, j)` is black.
    pub fn square_is_black(&self, i: usize, j: usize) -> bool {
        if self.legacy && self.squares_y.is_multiple_of(2) {
            (j + 1) % 2 == i % 2
        } else {
            j % 2 == i % 2
        }
    }

    /// Number of markers (white squares).
    pub fn num_markers(&self) -> usize {
        (0..self.squares_y)
            .flat_map(|j| (0..self.squares_x).map(move |i| (i, j)))
            .filter(|&(i, j)| !self.square_is_black(i, j))
            .count()
    }

    /// The square of marker `id`.
    pub fn marker_square(&self, id: usize) -> Option<(usize, usize)> {
        (0..self.squares_y)
            .flat_map(|j| (0..self.squares_x).map(move |i| (i, j)))
            .filter(|&(i, j)| !self.square_is_black(i, j))
            .nth(id)
    }

    /// Board corners of marker `id` (top-left, top-right, bottom-right, bottom-left as
    /// printed: the order of [`Marker::corners`]).
    pub fn marker_outline(&self, id: usize) -> Option<[[f64; 2]; 4]> {
        let (i, j) = self.marker_square(id)?;
        let d = 0.5 * (self.square - self.marker);
        let (x, y) = (i as f64 * self.square + d, j as f64 * self.square + d);
        let m = self.marker;
        Some([[x, y], [x + m, y], [x + m, y + m], [x, y + m]])
    }

    /// How far (board units) a missing marker may be from the decoded ones that place it: two
    /// squares along a row and diagonally.
    pub(crate) fn prediction_reach(&self) -> f64 {
        2.9 * self.square
    }

    /// Id of the marker in white square `(i, j)`: the white squares before it, row-major.
    fn marker_id(&self, i: usize, j: usize) -> usize {
        // In a row starting with a black square the white ones are the odd columns.
        let whites = |r: usize, k: usize| {
            if self.square_is_black(0, r) {
                k / 2
            } else {
                k.div_ceil(2)
            }
        };
        (0..j).map(|r| whites(r, self.squares_x)).sum::<usize>() + whites(j, i)
    }

    /// Inner corners.
    pub fn num_corners(&self) -> usize {
        (self.squares_x - 1) * (self.squares_y - 1)
    }

    /// Id of inner corner `(a, b)` if it is one.
    pub fn corner_id(&self, a: usize, b: usize) -> Option<usize> {
        (a >= 1 && b >= 1 && a < self.squares_x && b < self.squares_y)
            .then(|| (b - 1) * (self.squares_x - 1) + a - 1)
    }

    /// Board position of corner `id`.
    pub fn corner_position(&self, id: usize) -> Option<[f64; 2]> {
        let c = self.squares_x - 1;
        (id < self.num_corners()).then(|| {
            [
                ((id % c) + 1) as f64 * self.square,
                ((id / c) + 1) as f64 * self.square,
            ]
        })
    }

    /// Colour of the printed board at board point `(x, y)`: `Some(true)` black, `Some(false)`
    /// white, `None` outside the squares.
    pub fn is_black(&self, x: f64, y: f64) -> Option<bool> {
        let (fi, fj) = ((x / self.square).floor(), (y / self.square).floor());
        if fi < 0.0 || fj < 0.0 || fi >= self.squares_x as f64 || fj >= self.squares_y as f64 {
            return None;
        }
        let (i, j) = (fi as usize, fj as usize);
        if self.square_is_black(i, j) {
            return Some(true);
        }
        let d = 0.5 * (self.square - self.marker);
        let (lx, ly) = (x - fi * self.square - d, y - fj * self.square - d);
        if lx < 0.0 || ly < 0.0 || lx >= self.marker || ly >= self.marker {
            return Some(false);
        }
        let n = self.dict.bits() + 2;
        let cell = self.marker / n as f64;
        let (cx, cy) = ((lx / cell) as usize, (ly / cell) as usize);
        if cx == 0 || cy == 0 || cx >= n - 1 || cy >= n - 1 {
            return Some(true);
        }
        Some(!self.dict.is_white(self.marker_id(i, j), cy - 1, cx - 1))
    }
}

/// Corners of a ChArUco board from its decoded markers (ids on the board only), with the
/// smoothed image `s` for the saddle fit. Returns `(id, pixel)` sorted by id, and the number
/// of corners predicted but rejected by the refinement.
pub(crate) fn charuco_corners(
    s: &ImageF,
    board: &CharucoBoard,
    markers: &[Marker],
    min_contrast: f64,
) -> (Vec<(usize, [f64; 2])>, usize) {
    use super::markers::SquareMap;
    let d = 0.5 * (board.square - board.marker);
    // Per corner: sum of predictions, count, smallest square size in pixels, a marker map
    // and the marker's square, for the colour check.
    #[derive(Clone)]
    struct Acc {
        sum: [f64; 2],
        preds: Vec<[f64; 2]>,
        spacing: f64,
        map: SquareMap,
        origin: [f64; 2],
        /// A decoded (not predicted) marker is next to it: only then is a rejection news.
        read: bool,
    }
    let mut acc: std::collections::BTreeMap<usize, Acc> = Default::default();
    for m in markers {
        let Some((i, j)) = board.marker_square(m.id) else {
            continue;
        };
        let Some(map) = SquareMap::new(&m.corners) else {
            continue;
        };
        let origin = [i as f64 * board.square + d, j as f64 * board.square + d];
        let to_img = |x: f64, y: f64| {
            map.map(
                (x - origin[0]) / board.marker,
                (y - origin[1]) / board.marker,
            )
        };
        for (a, b) in [(i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1)] {
            let Some(id) = board.corner_id(a, b) else {
                continue;
            };
            let (x, y) = (a as f64 * board.square, b as f64 * board.square);
            let p = to_img(x, y);
            let px = to_img(x + board.square, y);
            let py = to_img(x, y + board.square);
            let sp = (px[0] - p[0])
                .hypot(px[1] - p[1])
                .min((py[0] - p[0]).hypot(py[1] - p[1]));
            let fresh = Acc {
                sum: [0.0; 2],
                preds: Vec::new(),
                spacing: f64::MAX,
                map,
                origin,
                read: !m.is_predicted(),
            };
            let e = acc.entry(id).or_insert_with(|| fresh.clone());
            // A corner next to a decoded marker is placed by decoded markers only: a placed
            // neighbour's outline is less exact and must not veto it through the spread check.
            if e.read && m.is_predicted() {
                continue;
            }
            if !e.read && !m.is_predicted() {
                *e = fresh;
            }
            e.sum = [e.sum[0] + p[0], e.sum[1] + p[1]];
            e.preds.push(p);
            e.spacing = e.spacing.min(sp);
        }
    }
    let mut fitters: Vec<Option<SaddleFitter>> = (0..=8).map(|_| None).collect();
    let mut out = Vec::with_capacity(acc.len());
    let mut rejected = 0;
    for (id, a) in acc {
        let k = a.preds.len() as f64;
        let pred = [a.sum[0] / k, a.sum[1] / k];
        let spread = a
            .preds
            .iter()
            .map(|p| (p[0] - pred[0]).hypot(p[1] - pred[1]))
            .fold(0.0, f64::max);
        if spread > 0.2 * a.spacing || a.spacing < 4.0 {
            rejected += usize::from(a.read);
            continue;
        }
        let margin_px = a.spacing * d / board.square;
        let r0 = ((0.3 * a.spacing).min(0.9 * margin_px).round() as i32).clamp(2, 8);
        let max_shift = (0.2 * a.spacing).max(1.5);
        let mut done = None;
        for radius in (2..=r0).rev() {
            let f = fitters[radius as usize].get_or_insert_with(|| SaddleFitter::new(radius));
            if let Some(p) = f.refine(s, pred, max_shift) {
                done = Some(p);
                break;
            }
        }
        let Some(p) = done else {
            rejected += usize::from(a.read);
            continue;
        };
        // Colours: the squares around the corner, sampled inside the white margin.
        let Some([x, y]) = board.corner_position(id) else {
            continue;
        };
        let (a_, b_) = (
            (x / board.square).round() as usize,
            (y / board.square).round() as usize,
        );
        let off = 0.6 * d;
        let shift = [p[0] - pred[0], p[1] - pred[1]];
        let mut dark = f64::MIN;
        let mut bright = f64::MAX;
        let mut inside = true;
        for (di, dj, sx, sy) in [
            (0, 0, -1.0, -1.0),
            (1, 0, 1.0, -1.0),
            (0, 1, -1.0, 1.0),
            (1, 1, 1.0, 1.0),
        ] {
            let q = a.map.map(
                (x + sx * off - a.origin[0]) / board.marker,
                (y + sy * off - a.origin[1]) / board.marker,
            );
            let (qx, qy) = (q[0] + shift[0], q[1] + shift[1]);
            if !s.contains(qx, qy, 0.0) {
                inside = false;
                break;
            }
            let v = f64::from(s.bilinear(qx, qy));
            if board.square_is_black(a_ + di - 1, b_ + dj - 1) {
                dark = dark.max(v);
            } else {
                bright = bright.min(v);
            }
        }
        if !inside || bright - dark < 0.5 * min_contrast {
            rejected += usize::from(a.read);
            continue;
        }
        out.push((id, p));
    }
    (out, rejected)
}
