//! Choosing calibration views from many candidates (the frames of a clip).
//!
//! A clip of a board holds hundreds of frames, most nearly the same view as their neighbours;
//! solving with all of them costs time and weights the poses the operator lingered on. What
//! constrains the intrinsics is *diversity*: the board at many positions, distances and tilts,
//! and corners over the whole image, where the distortion lives (Zhang 2000, §5; the view
//! planning of Richardson, Strom & Olson, "AprilCal", IROS 2013, and of mrcal's docs make the
//! same point).
//!
//! Every candidate is described by where the whole board lands in the image: the homography
//! board → image maps the four corners of the board's bounding box to a quadrilateral. Two
//! views whose quadrilaterals are close (mean corner distance, in units of the image diagonal)
//! are nearly the same pose — position, scale, in-plane rotation and tilt all move the quad —
//! and this needs no intrinsics. Selection is greedy farthest-point: start with the view
//! covering most of the image, then repeatedly add the view farthest from every view kept,
//! plus a bonus for image cells its corners cover that no kept view covers, until the cap or
//! until every remaining view is a near-duplicate; of the near-identical frames of a pose, the
//! sharpest is the one used. Blurred views (sharpness far below the
//! candidates' median) are left out first, because motion-blurred corners bias the solve.

use nalgebra::Vector2;
use serde::{Deserialize, Serialize};

use super::{CornerObservation, PlanarTarget, homography_dlt, transfer};
use crate::error::{CoreError, CoreResult};

/// Settings of [`select_views`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ViewSelection {
    /// Most views kept (default 40).
    pub max_views: usize,
    /// Two views whose board quadrilaterals differ by less than this share of the image
    /// diagonal (mean corner distance) are near-duplicates (default 0.02: about 13 px at
    /// 640×480, 44 px at 1080p).
    pub min_difference: f64,
    /// A view whose sharpness (Laplacian variance) is below this share of the candidates'
    /// median is left out as blurred (default 0.3; 0 keeps every view).
    pub min_relative_sharpness: f64,
}

impl Default for ViewSelection {
    fn default() -> Self {
        Self {
            max_views: 40,
            min_difference: 0.02,
            min_relative_sharpness: 0.3,
        }
    }
}

impl ViewSelection {
    /// Errors naming the field for values out of range.
    pub fn validate(&self) -> CoreResult<()> {
        if !(3..=500).contains(&self.max_views) {
            return Err(CoreError::param(
                "max_views",
                format!("must be in [3, 500], got {}", self.max_views),
            ));
        }
        if !(self.min_difference.is_finite() && (0.0..=0.5).contains(&self.min_difference)) {
            return Err(CoreError::param(
                "min_difference",
                format!("must be in [0, 0.5], got {}", self.min_difference),
            ));
        }
        if !(self.min_relative_sharpness.is_finite()
            && (0.0..1.0).contains(&self.min_relative_sharpness))
        {
            return Err(CoreError::param(
                "min_relative_sharpness",
                format!("must be in [0, 1), got {}", self.min_relative_sharpness),
            ));
        }
        Ok(())
    }
}

/// One candidate view: its corners and how sharp it is.
#[derive(Clone, Debug)]
pub struct ViewCandidate {
    /// Corners detected (ids as the target numbers them).
    pub corners: Vec<CornerObservation>,
    /// Laplacian variance (or any sharpness measure where higher is sharper).
    pub sharpness: f64,
}

/// What [`select_views`] decided for one candidate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "decision", rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum ViewDecision {
    /// In the solve; `order` is when the greedy choice took it (0 first).
    Used {
        /// Rank in the greedy choice.
        order: usize,
    },
    /// Sharpness below `min_relative_sharpness` × the median.
    Blurred {
        /// This view's sharpness over the candidates' median.
        relative_sharpness: f64,
    },
    /// Nearly the same board pose as a view already used.
    NearDuplicate {
        /// Index (into the candidates) of the view it duplicates.
        of: usize,
        /// Mean quadrilateral corner distance / image diagonal.
        difference: f64,
    },
    /// Distinct, but `max_views` views were already used.
    CapReached,
    /// Too few corners, or corners in a degenerate layout (no board pose can be read).
    Degenerate,
}

/// The board's bounding-box quadrilateral in the image, or `None` when the corners do not fix
/// a homography (fewer than 4, collinear).
fn board_quad<T: PlanarTarget + ?Sized>(
    corners: &[CornerObservation],
    target: &T,
) -> Option<[Vector2<f64>; 4]> {
    let (mut src, mut dst) = (Vec::new(), Vec::new());
    for c in corners {
        let p = target.object_point(c.index)?;
        src.push(Vector2::new(p.x, p.y));
        dst.push(Vector2::new(c.pixel[0], c.pixel[1]));
    }
    if src.len() < 4 {
        return None;
    }
    let h = homography_dlt(&src, &dst).ok()?;
    let (mut lo, mut hi) = (
        Vector2::repeat(f64::INFINITY),
        Vector2::repeat(f64::NEG_INFINITY),
    );
    for id in 0..target.num_points() {
        let p = target.object_point(id)?;
        lo = lo.inf(&Vector2::new(p.x, p.y));
        hi = hi.sup(&Vector2::new(p.x, p.y));
    }
    let box_corners = [lo, Vector2::new(hi.x, lo.y), hi, Vector2::new(lo.x, hi.y)];
    let mut quad = [Vector2::zeros(); 4];
    for (q, b) in quad.iter_mut().zip(box_corners) {
        *q = transfer(&h, &b)?;
        if !(q.x.is_finite() && q.y.is_finite()) {
            return None;
        }
    }
    Some(quad)
}

/// Mean distance between matching corners of two quads, over the four cyclic relabellings
/// (a chessboard turned by a half-turn is numbered from the other end: same pose).
fn quad_distance(a: &[Vector2<f64>; 4], b: &[Vector2<f64>; 4]) -> f64 {
    (0..4)
        .map(|s| (0..4).map(|k| (a[k] - b[(k + s) % 4]).norm()).sum::<f64>() / 4.0)
        .fold(f64::INFINITY, f64::min)
}

/// Image cells (a `GRID`×`GRID` grid) holding at least one corner, as a bit set.
const GRID: usize = 8;

fn cells(corners: &[CornerObservation], size: (u32, u32)) -> u64 {
    let (w, h) = (f64::from(size.0.max(1)), f64::from(size.1.max(1)));
    corners.iter().fold(0u64, |acc, c| {
        let cx = ((c.pixel[0] / w) * GRID as f64).floor();
        let cy = ((c.pixel[1] / h) * GRID as f64).floor();
        if (0.0..GRID as f64).contains(&cx) && (0.0..GRID as f64).contains(&cy) {
            acc | 1u64 << (cy as usize * GRID + cx as usize)
        } else {
            acc
        }
    })
}

/// Decides, for every candidate, whether it is used and why not (see the module docs).
///
/// The result has one decision per candidate, in the candidates' order. Errors only on invalid
/// settings.
pub fn select_views<T: PlanarTarget + ?Sized>(
    candidates: &[ViewCandidate],
    target: &T,
    image_size: (u32, u32),
    settings: &ViewSelection,
) -> CoreResult<Vec<ViewDecision>> {
    settings.validate()?;
    let n = candidates.len();
    let mut decision: Vec<Option<ViewDecision>> = vec![None; n];
    let quads: Vec<Option<[Vector2<f64>; 4]>> = candidates
        .iter()
        .map(|c| {
            if c.corners.len() < super::MIN_CORNERS_PER_VIEW {
                None
            } else {
                board_quad(&c.corners, target)
            }
        })
        .collect();
    for (d, q) in decision.iter_mut().zip(&quads) {
        if q.is_none() {
            *d = Some(ViewDecision::Degenerate);
        }
    }
    let mut sharp: Vec<f64> = (0..n)
        .filter(|&i| decision[i].is_none())
        .map(|i| candidates[i].sharpness)
        .filter(|s| s.is_finite())
        .collect();
    sharp.sort_by(f64::total_cmp);
    if let Some(&median) = sharp.get(sharp.len() / 2)
        && median > 0.0
        && sharp.len() >= 3
    {
        for i in 0..n {
            let rel = candidates[i].sharpness / median;
            // NaN sharpness counts as blurred.
            let sharp_enough = rel.is_finite() && rel >= settings.min_relative_sharpness;
            if decision[i].is_none() && !sharp_enough {
                decision[i] = Some(ViewDecision::Blurred {
                    relative_sharpness: if rel.is_finite() { rel } else { 0.0 },
                });
            }
        }
    }
    let diag = f64::from(image_size.0)
        .hypot(f64::from(image_size.1))
        .max(1.0);
    let cover: Vec<u64> = candidates
        .iter()
        .map(|c| cells(&c.corners, image_size))
        .collect();
    // Farthest-point greedy: `gap[i]` = distance (÷ diagonal) from candidate i to the nearest
    // used view, `nearest[i]` that view.
    let mut gap = vec![f64::INFINITY; n];
    let mut nearest = vec![usize::MAX; n];
    let mut covered = 0u64;
    let mut used = 0usize;
    loop {
        let open = (0..n).filter(|&i| decision[i].is_none() && gap[i] >= settings.min_difference);
        // Score: distance to the used set (capped at 1: beyond that every view is "new") plus
        // the share of the grid that only this view covers; the first pick is the widest view.
        let best = open
            .map(|i| {
                let new_cells = (cover[i] & !covered).count_ones() as f64 / (GRID * GRID) as f64;
                (i, gap[i].min(1.0) + new_cells)
            })
            .max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)));
        let Some((first, _)) = best else { break };
        if used == settings.max_views {
            break;
        }
        // Of the open views that are nearly this one (the frames of one held pose), use the
        // sharpest: the pose is what the greedy choice is about, the frame should be the best.
        let pick = match quads[first] {
            Some(qf) => (0..n)
                .filter(|&j| decision[j].is_none() && gap[j] >= settings.min_difference)
                .filter(|&j| {
                    quads[j]
                        .is_some_and(|qj| quad_distance(&qj, &qf) / diag <= settings.min_difference)
                })
                .max_by(|&a, &b| {
                    candidates[a]
                        .sharpness
                        .total_cmp(&candidates[b].sharpness)
                        .then(b.cmp(&a))
                })
                .unwrap_or(first),
            None => first,
        };
        decision[pick] = Some(ViewDecision::Used { order: used });
        used += 1;
        covered |= cover[pick];
        let Some(qp) = quads[pick] else { continue };
        for i in 0..n {
            if let Some(qi) = &quads[i] {
                let d = quad_distance(qi, &qp) / diag;
                if d < gap[i] {
                    gap[i] = d;
                    nearest[i] = pick;
                }
            }
        }
    }
    Ok(decision
        .into_iter()
        .enumerate()
        .map(|(i, d)| {
            d.unwrap_or(
                if gap[i] < settings.min_difference && nearest[i] != usize::MAX {
                    ViewDecision::NearDuplicate {
                        of: nearest[i],
                        difference: gap[i],
                    }
                } else {
                    ViewDecision::CapReached
                },
            )
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::BoardGeometry;

    const BOARD: BoardGeometry = BoardGeometry {
        cols: 9,
        rows: 6,
        square: 1.0,
    };

    /// The board seen at an offset and scale (a fronto-parallel view).
    fn view(dx: f64, dy: f64, scale: f64, sharpness: f64) -> ViewCandidate {
        let corners = (0..54)
            .map(|index| CornerObservation {
                index,
                pixel: [
                    dx + scale * (index % 9) as f64,
                    dy + scale * (index / 9) as f64,
                ],
            })
            .collect();
        ViewCandidate { corners, sharpness }
    }

    #[test]
    fn duplicates_blur_and_cap_are_told_apart() {
        let c = vec![
            view(100.0, 100.0, 30.0, 100.0),
            view(101.0, 100.5, 30.0, 110.0), // the same pose a frame later
            view(350.0, 250.0, 20.0, 90.0),
            view(20.0, 300.0, 15.0, 95.0),
            view(300.0, 40.0, 25.0, 5.0), // blurred
            ViewCandidate {
                corners: Vec::new(),
                sharpness: 100.0,
            },
        ];
        let d = select_views(&c, &BOARD, (640, 480), &ViewSelection::default()).expect("ok");
        assert!(
            matches!(d[4], ViewDecision::Blurred { relative_sharpness } if relative_sharpness < 0.1)
        );
        assert_eq!(d[5], ViewDecision::Degenerate);
        let used: Vec<usize> = (0..6)
            .filter(|&i| matches!(d[i], ViewDecision::Used { .. }))
            .collect();
        assert_eq!(used.len(), 3, "{d:?}");
        // One of the two near-identical views is used, the other names it.
        let dup = if used.contains(&0) { 1 } else { 0 };
        assert!(
            matches!(d[dup], ViewDecision::NearDuplicate { of, difference } if of == 1 - dup && difference < 0.01),
            "{d:?}"
        );
        let capped = select_views(
            &c,
            &BOARD,
            (640, 480),
            &ViewSelection {
                max_views: 3,
                min_difference: 0.0,
                ..ViewSelection::default()
            },
        )
        .expect("ok");
        assert_eq!(
            capped
                .iter()
                .filter(|d| matches!(d, ViewDecision::Used { .. }))
                .count(),
            3
        );
        assert!(capped.contains(&ViewDecision::CapReached));
    }

    #[test]
    fn spread_views_win_over_clustered_ones() {
        // Twenty views in one corner of the image, four far apart: the far ones are taken
        // before a second view of the cluster.
        let mut c: Vec<ViewCandidate> = (0..20)
            .map(|k| view(40.0 + 3.0 * k as f64, 40.0, 10.0, 100.0))
            .collect();
        for (x, y) in [(400.0, 40.0), (40.0, 350.0), (400.0, 350.0), (220.0, 200.0)] {
            c.push(view(x, y, 20.0, 100.0));
        }
        let s = ViewSelection {
            max_views: 5,
            min_difference: 0.0,
            ..ViewSelection::default()
        };
        let d = select_views(&c, &BOARD, (640, 480), &s).expect("ok");
        for (i, di) in d.iter().enumerate().skip(20) {
            assert!(matches!(di, ViewDecision::Used { .. }), "view {i}: {di:?}");
        }
    }

    #[test]
    fn the_sharpest_frame_of_a_held_pose_is_used() {
        let c = vec![
            view(100.0, 100.0, 30.0, 60.0),
            view(100.5, 100.0, 30.0, 100.0),
            view(100.0, 100.5, 30.0, 70.0),
            view(350.0, 250.0, 20.0, 90.0),
        ];
        let d = select_views(&c, &BOARD, (640, 480), &ViewSelection::default()).expect("ok");
        assert!(matches!(d[1], ViewDecision::Used { .. }), "{d:?}");
        assert!(
            matches!(d[0], ViewDecision::NearDuplicate { of: 1, .. }),
            "{d:?}"
        );
        assert!(
            matches!(d[2], ViewDecision::NearDuplicate { of: 1, .. }),
            "{d:?}"
        );
    }

    #[test]
    fn half_turned_numbering_is_the_same_pose() {
        let a = view(100.0, 100.0, 30.0, 1.0);
        let mut b = a.clone();
        for c in &mut b.corners {
            c.index = 53 - c.index;
        }
        let qa = board_quad(&a.corners, &BOARD).expect("quad");
        let qb = board_quad(&b.corners, &BOARD).expect("quad");
        assert!(quad_distance(&qa, &qb) < 1e-6);
    }

    #[test]
    fn bad_settings_name_the_field() {
        let e = ViewSelection {
            max_views: 1,
            ..ViewSelection::default()
        }
        .validate()
        .expect_err("refused");
        assert!(e.to_string().contains("max_views"));
        let e = ViewSelection {
            min_difference: f64::NAN,
            ..ViewSelection::default()
        }
        .validate()
        .expect_err("refused");
        assert!(e.to_string().contains("min_difference"));
    }
}
