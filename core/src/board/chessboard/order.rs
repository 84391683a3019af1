//! The order of the corners of a found board: of the orderings of the grid that fit the
//! `cols × rows` pattern, the one the rules of the parent module's "Corner order" section pick
//! (handedness, colour of the first square, OpenCV 4's rule for boards symmetric under a half
//! turn, then the corner nearest the image's top-left for square patterns).

/// Chooses the corner order (see the parent module docs): `g[j][i]` is the grid, `dark(i, j)`
/// whether the cell between grid corners `(i, j)` and `(i + 1, j + 1)` is dark.
pub(super) fn order(
    g: &[Vec<[f64; 2]>],
    cols: usize,
    rows: usize,
    dark: &dyn Fn(usize, usize) -> bool,
) -> Vec<[f64; 2]> {
    let gh = g.len();
    let gw = g[0].len();
    // A candidate order maps (col, row) to grid (i, j).
    type Map = Box<dyn Fn(usize, usize) -> (usize, usize)>;
    let mut maps: Vec<Map> = Vec::new();
    for flip_a in [false, true] {
        for flip_b in [false, true] {
            if gw == cols && gh == rows {
                maps.push(Box::new(move |c, r| {
                    (
                        if flip_a { cols - 1 - c } else { c },
                        if flip_b { rows - 1 - r } else { r },
                    )
                }));
            }
            if gw == rows && gh == cols {
                maps.push(Box::new(move |c, r| {
                    (
                        if flip_b { rows - 1 - r } else { r },
                        if flip_a { cols - 1 - c } else { c },
                    )
                }));
            }
        }
    }
    let build = |m: &Map| -> Vec<[f64; 2]> {
        (0..rows * cols)
            .map(|k| {
                let (i, j) = m(k % cols, k / cols);
                g[j][i]
            })
            .collect()
    };
    // (handedness, cell 0 dark, last row below, −y0, −x0): lexicographically larger is better.
    type Key = (bool, bool, bool, f64, f64);
    let mut best: Option<(Key, Vec<[f64; 2]>)> = None;
    for m in &maps {
        let c = build(m);
        // Handedness summed over all cells (robust to local noise).
        let mut cross = 0.0;
        for r in 0..rows - 1 {
            for col in 0..cols - 1 {
                let p = c[r * cols + col];
                let a = c[r * cols + col + 1];
                let b = c[(r + 1) * cols + col];
                cross += (a[0] - p[0]) * (b[1] - p[1]) - (a[1] - p[1]) * (b[0] - p[0]);
            }
        }
        // Colour of the cell between corners 0, 1, cols, cols+1, in grid terms.
        let (i0, j0) = m(0, 0);
        let (i1, j1) = m(1, 1);
        let cell_dark = dark(i0.min(i1), j0.min(j1));
        let dy_ok = c[(rows - 1) * cols][1] >= c[0][1];
        let key = (cross > 0.0, cell_dark, dy_ok, -c[0][1], -c[0][0]);
        let better = match &best {
            None => true,
            Some((bk, _)) => key.partial_cmp(bk) == Some(std::cmp::Ordering::Greater),
        };
        if better {
            best = Some((key, c));
        }
    }
    best.map(|(_, c)| c).unwrap_or_default()
}
