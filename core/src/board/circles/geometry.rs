//! The layout of an OpenCV circle grid: where each circle is on the board, which board points
//! are printed black, and which rigid motions of the board leave the pattern unchanged.

use nalgebra::Vector3;

use crate::error::{CoreError, CoreResult};

/// A validated circle grid (see [`crate::board::TargetSpec::Circles`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CircleGrid {
    /// Circles per row (OpenCV `patternSize.width`).
    pub cols: usize,
    /// Rows (OpenCV `patternSize.height`).
    pub rows: usize,
    /// Distance between neighbouring circle centres along a column (board units); in an
    /// asymmetric grid the circles of one row are `2·spacing` apart.
    pub spacing: f64,
    /// Circle diameter (board units).
    pub diameter: f64,
    /// OpenCV's `CALIB_CB_ASYMMETRIC_GRID`: odd rows shifted by `spacing`.
    pub asymmetric: bool,
}

impl CircleGrid {
    /// Checks the counts and sizes and that no two circles touch, naming the field at fault.
    pub fn new(
        cols: usize,
        rows: usize,
        spacing: f64,
        diameter: f64,
        asymmetric: bool,
    ) -> CoreResult<Self> {
        if cols < 2 || rows < 2 {
            return Err(CoreError::param(
                "cols",
                format!("needs at least 2×2 circles, got {cols}×{rows}"),
            ));
        }
        // Two rows of an asymmetric grid are a zig-zag line that cannot be told from a
        // symmetric grid seen obliquely; OpenCV's asymmetric patterns have many rows.
        if asymmetric && rows < 3 {
            return Err(CoreError::param(
                "rows",
                format!("an asymmetric grid needs at least 3 rows, got {rows}"),
            ));
        }
        if cols.saturating_mul(rows) > 100_000 {
            return Err(CoreError::param("rows", "more than 10⁵ circles"));
        }
        for (field, v) in [("spacing", spacing), ("diameter", diameter)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(CoreError::param(
                    field,
                    format!("must be positive and finite, got {v}"),
                ));
            }
        }
        // Nearest centres: `spacing` apart in a symmetric grid, `√2·spacing` (the diagonal
        // to the next row) in an asymmetric one.
        let gap = if asymmetric {
            std::f64::consts::SQRT_2 * spacing
        } else {
            spacing
        };
        if diameter >= gap {
            return Err(CoreError::param(
                "diameter",
                format!(
                    "circles of diameter {diameter} touch: neighbouring centres are {gap} apart \
                     ({} grid of spacing {spacing})",
                    if asymmetric {
                        "asymmetric"
                    } else {
                        "symmetric"
                    }
                ),
            ));
        }
        Ok(Self {
            cols,
            rows,
            spacing,
            diameter,
            asymmetric,
        })
    }

    /// Number of circles.
    pub fn len(&self) -> usize {
        self.cols * self.rows
    }

    /// Always false (a valid grid has at least 4 circles); for clippy's `len` rule.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Board position of circle `(c, r)` in units of `spacing`, as OpenCV's calibration
    /// sample builds it: `(c, r)` or `(2c + r mod 2, r)`.
    pub fn lattice(&self, c: usize, r: usize) -> [i64; 2] {
        let (c, r) = (c as i64, r as i64);
        if self.asymmetric {
            [2 * c + r % 2, r]
        } else {
            [c, r]
        }
    }

    /// Board position of circle `id` (`r·cols + c`), `None` past the last.
    pub fn position(&self, id: usize) -> Option<[f64; 2]> {
        (id < self.len()).then(|| {
            let [x, y] = self.lattice(id % self.cols, id / self.cols);
            [x as f64 * self.spacing, y as f64 * self.spacing]
        })
    }

    /// Width and height spanned by the centres (board units).
    fn span(&self) -> [f64; 2] {
        // The last circle of an odd row of an asymmetric grid is at x = 2·cols − 1.
        let w = if self.asymmetric {
            2 * self.cols - 1
        } else {
            self.cols - 1
        };
        [
            w as f64 * self.spacing,
            (self.rows - 1) as f64 * self.spacing,
        ]
    }

    /// Printed colour at `(x, y)`: black inside a circle, white on the card (the centres'
    /// bounding box grown by one spacing), `None` beyond.
    pub fn is_black(&self, x: f64, y: f64) -> Option<bool> {
        let s = self.spacing;
        let [sw, sh] = self.span();
        if !(x >= -s && y >= -s && x <= sw + s && y <= sh + s) {
            return None;
        }
        let r2 = (self.diameter / 2.0).powi(2);
        let row0 = (y / s).round() as i64;
        // Circles are smaller than the nearest-centre distance, so the nearest row and its two
        // neighbours hold every circle that can contain the point.
        let black = (row0 - 1..=row0 + 1)
            .filter(|r| (0..self.rows as i64).contains(r))
            .any(|r| {
                let shift = if self.asymmetric { r % 2 } else { 0 };
                let step = if self.asymmetric { 2.0 } else { 1.0 };
                let c = ((x / s - shift as f64) / step).round() as i64;
                (c - 1..=c + 1)
                    .filter(|c| (0..self.cols as i64).contains(c))
                    .any(|c| {
                        let cx = (c as f64 * step + shift as f64) * s;
                        let cy = r as f64 * s;
                        (x - cx).powi(2) + (y - cy).powi(2) <= r2
                    })
            });
        Some(black)
    }

    /// The half turn about the board normal that maps circle `k` to circle `len − 1 − k`,
    /// when the pattern is symmetric under it (a detector cannot then tell the two apart).
    ///
    /// A symmetric grid always is, like a chessboard. An asymmetric grid is only when it has
    /// an even number of rows: turning it swaps row `r` with row `rows − 1 − r`, which has the
    /// other shift exactly when `rows` is even. With an odd number of rows (OpenCV's 4×11) the
    /// first and last rows are both unshifted, the turn moves them onto shifted positions, and
    /// no rigid motion of the plane other than the identity maps the pattern onto itself.
    pub fn half_turn(&self) -> Option<crate::lie::Se3> {
        if self.asymmetric && self.rows % 2 == 1 {
            return None;
        }
        let [sw, sh] = self.span();
        Some(crate::lie::Se3::new(
            crate::lie::So3::exp(&Vector3::new(0.0, 0.0, std::f64::consts::PI)),
            Vector3::new(sw, sh, 0.0),
        ))
    }
}
