//! Markers the decoder missed, predicted from the markers around them.
//!
//! On a strongly tilted board the far markers shrink to cells of two or three pixels; blur then
//! merges their bits (or their outline) and they are not decoded, although their corners — the
//! larger, high-contrast chessboard or AprilGrid junctions — are still sharp enough for the
//! saddle fit. As in OpenCV's `refineDetectedMarkers` (Garrido-Jurado et al. 2014, §4), the
//! board layout tells where each missing marker must be: a homography fitted to the decoded
//! markers *near* it (a local plane-to-image map, so lens distortion over the whole board does
//! not bias the prediction; Hartley & Zisserman, Alg. 4.2) places its outline. Nothing here is
//! trusted on its own: the corners of a predicted marker go through the same sub-pixel fit and
//! colour checks as those of a decoded one, which refuse occluded, out-of-view or blank places.

use nalgebra::Vector2;

use super::Marker;
use crate::calib::{homography_dlt, transfer};

/// Fewest decoded markers a prediction is fitted to (8 points: the homography is
/// over-determined, so one badly placed outline cannot steer it alone).
const MIN_NEIGHBOURS: usize = 2;
/// Most decoded markers a prediction uses: the nearest, so the local map follows distortion.
const MAX_NEIGHBOURS: usize = 6;
/// A marker's four corners (board or pixel), in the order of [`Marker::corners`].
type Outline = [[f64; 2]; 4];

/// Smallest predicted marker side in pixels worth trying: below it no corner fit is reliable.
const MIN_SIDE_PX: f64 = 6.0;

/// Outlines of the board's markers that are not in `decoded`, each predicted from the decoded
/// markers whose centres lie within `reach` (board units) of its centre, nearest first.
///
/// `outline(id)` gives marker `id`'s four board corners in the order [`Marker::corners`] uses
/// (or `None` for an id not on the board); `num_ids` is the number of markers on the board;
/// `(w, h)` the image size. A predicted outline that falls partly outside the image or is
/// smaller than a few pixels is left out. Predicted markers have `bit_errors` = `u32::MAX`
/// (never read).
pub(crate) fn predict_missing(
    decoded: &[Marker],
    num_ids: usize,
    outline: impl Fn(usize) -> Option<Outline>,
    reach: f64,
    (w, h): (usize, usize),
) -> Vec<Marker> {
    let centre = |q: &Outline| {
        [
            0.25 * q.iter().map(|p| p[0]).sum::<f64>(),
            0.25 * q.iter().map(|p| p[1]).sum::<f64>(),
        ]
    };
    // Board outline and board centre of every decoded marker.
    let known: Vec<(&Marker, Outline, [f64; 2])> = decoded
        .iter()
        .filter_map(|m| outline(m.id).map(|b| (m, b, centre(&b))))
        .collect();
    if known.len() < MIN_NEIGHBOURS {
        return Vec::new();
    }
    let have: std::collections::HashSet<usize> = decoded.iter().map(|m| m.id).collect();
    let mut out = Vec::new();
    for id in (0..num_ids).filter(|id| !have.contains(id)) {
        let Some(board) = outline(id) else {
            continue;
        };
        let c = centre(&board);
        let mut near: Vec<(f64, usize)> = known
            .iter()
            .enumerate()
            .map(|(k, (_, _, kc))| ((kc[0] - c[0]).hypot(kc[1] - c[1]), k))
            .filter(|&(d, _)| d <= reach)
            .collect();
        if near.len() < MIN_NEIGHBOURS {
            continue;
        }
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
        near.truncate(MAX_NEIGHBOURS);
        let mut src = Vec::with_capacity(4 * near.len());
        let mut dst = Vec::with_capacity(4 * near.len());
        for &(_, k) in &near {
            let (m, b, _) = &known[k];
            for (p, q) in b.iter().zip(&m.corners) {
                src.push(Vector2::new(p[0], p[1]));
                dst.push(Vector2::new(q[0], q[1]));
            }
        }
        let Ok(hm) = homography_dlt(&src, &dst) else {
            continue;
        };
        let mut corners = [[0.0; 2]; 4];
        let mut ok = true;
        for (p, q) in board.iter().zip(corners.iter_mut()) {
            match transfer(&hm, &Vector2::new(p[0], p[1])) {
                Some(v)
                    if v.x >= 1.0 && v.y >= 1.0 && v.x < w as f64 - 2.0 && v.y < h as f64 - 2.0 =>
                {
                    *q = [v.x, v.y];
                }
                _ => ok = false,
            }
        }
        let side = (0..4)
            .map(|k| {
                let (a, b) = (corners[k], corners[(k + 1) % 4]);
                (a[0] - b[0]).hypot(a[1] - b[1])
            })
            .fold(f64::MAX, f64::min);
        if ok && side >= MIN_SIDE_PX {
            out.push(Marker {
                id,
                corners,
                bit_errors: u32::MAX,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Markers on a 4×4 grid of pitch 2 (side 1) seen through a perspective map; one missing.
    #[test]
    fn a_missing_marker_is_placed_by_its_neighbours() {
        let h = |x: f64, y: f64| {
            let z = 1.0 + 0.05 * x + 0.02 * y;
            [
                (40.0 * x + 5.0 * y + 30.0) / z,
                (3.0 * x + 38.0 * y + 20.0) / z,
            ]
        };
        let outline = |id: usize| {
            (id < 16).then(|| {
                let (x, y) = ((id % 4) as f64 * 2.0, (id / 4) as f64 * 2.0);
                [[x, y], [x + 1.0, y], [x + 1.0, y + 1.0], [x, y + 1.0]]
            })
        };
        let decoded: Vec<Marker> = (0..16)
            .filter(|&id| id != 6)
            .filter_map(|id| {
                outline(id).map(|b| Marker {
                    id,
                    corners: b.map(|p| h(p[0], p[1])),
                    bit_errors: 0,
                })
            })
            .collect();
        let got = predict_missing(&decoded, 16, outline, 3.0, (640, 480));
        assert_eq!(got.len(), 1);
        assert_eq!(got[0].id, 6);
        let truth = outline(6).map(|b| b.map(|p| h(p[0], p[1])));
        for (p, t) in got[0].corners.iter().zip(truth.iter().flatten()) {
            assert!((p[0] - t[0]).hypot(p[1] - t[1]) < 1e-6, "{p:?} vs {t:?}");
        }
        // Too far from any decoded marker: nothing predicted.
        assert!(predict_missing(&decoded, 16, outline, 1.5, (640, 480)).is_empty());
        // Outside the image: nothing predicted.
        assert!(predict_missing(&decoded, 16, outline, 3.0, (100, 100)).is_empty());
    }
}
