//! Unit tests of the circle-grid stages on small hand-made inputs (the full pipeline on
//! rendered views is in `core/tests/targets_circles.rs`).

use super::blobs::{Blob, find_blobs};
use super::geometry::CircleGrid;
use super::lattice::find_lattice;
use super::subpix::refine;
use super::*;
use crate::board::filter::ImageF;

/// A light image (220) with dark (30) discs `[x, y, r]`, 8×8 supersampled.
fn discs(w: usize, h: usize, ds: &[[f64; 3]]) -> Gray {
    let mut data = vec![0u8; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut dark = 0;
            for sy in 0..8 {
                for sx in 0..8 {
                    let px = x as f64 - 0.5 + (sx as f64 + 0.5) / 8.0;
                    let py = y as f64 - 0.5 + (sy as f64 + 0.5) / 8.0;
                    if ds.iter().any(|d| (px - d[0]).hypot(py - d[1]) <= d[2]) {
                        dark += 1;
                    }
                }
            }
            data[y * w + x] = (220.0 - 190.0 * f64::from(dark) / 64.0).round() as u8;
        }
    }
    Gray {
        width: w as u32,
        height: h as u32,
        data,
    }
}

fn blob_at(c: [f64; 2], r: f64) -> Blob {
    Blob {
        c,
        cov: [r * r / 4.0, 0.0, r * r / 4.0],
        area: std::f64::consts::PI * r * r,
        repeats: 5,
    }
}

#[test]
fn geometry_positions_and_colours() {
    let g = CircleGrid::new(4, 5, 1.0, 0.5, true).expect("valid");
    assert_eq!(g.position(0), Some([0.0, 0.0]));
    assert_eq!(g.position(1), Some([2.0, 0.0]));
    assert_eq!(g.position(4), Some([1.0, 1.0]));
    assert_eq!(g.position(7), Some([7.0, 1.0]));
    assert_eq!(g.position(20), None);
    assert_eq!(g.is_black(1.0, 1.1), Some(true));
    assert_eq!(g.is_black(0.0, 1.0), Some(false));
    assert_eq!(g.is_black(7.0, 3.0), Some(true));
    assert_eq!(g.is_black(-1.5, 0.0), None);
    let s = CircleGrid::new(3, 2, 2.0, 1.0, false).expect("valid");
    assert_eq!(s.position(4), Some([2.0, 2.0]));
    assert_eq!(s.is_black(4.4, 2.0), Some(true));
    assert_eq!(s.is_black(3.0, 1.0), Some(false));
}

#[test]
fn geometry_rejects_touching_circles() {
    assert!(CircleGrid::new(4, 5, 1.0, 1.0, false).is_err());
    assert!(CircleGrid::new(4, 5, 1.0, 1.3, true).is_ok());
    assert!(CircleGrid::new(4, 5, 1.0, 1.42, true).is_err());
    assert!(CircleGrid::new(4, 2, 1.0, 0.5, true).is_err());
    assert!(CircleGrid::new(1, 5, 1.0, 0.5, false).is_err());
}

#[test]
fn blobs_found_once_each_and_lines_rejected() {
    let mut img = discs(120, 80, &[[30.0, 30.0, 8.0], [80.3, 40.6, 6.0]]);
    // A dark bar: not an ellipse.
    for y in 60..64 {
        for x in 10..110 {
            img.data[y * 120 + x] = 30;
        }
    }
    let scan = find_blobs(&img, 20.0);
    assert_eq!(scan.blobs.len(), 2, "{:?}", scan.blobs);
    let b = scan
        .blobs
        .iter()
        .find(|b| b.c[0] > 60.0)
        .expect("second disc");
    assert!(
        (b.c[0] - 80.3).abs() < 0.2 && (b.c[1] - 40.6).abs() < 0.2,
        "{b:?}"
    );
}

#[test]
fn subpix_centre_of_a_disc() {
    let img = discs(64, 64, &[[31.37, 30.81, 9.0]]);
    let f = ImageF::from_gray(&img);
    let r = refine(&f, &blob_at([31.0, 31.0], 9.0), 2.5).expect("fit");
    assert!(
        (r.c[0] - 31.37).abs() < 0.01 && (r.c[1] - 30.81).abs() < 0.01,
        "{:?}",
        r.c
    );
    assert!(r.contrast > 150.0);
    // Too close to the border: no fit rather than a clipped one.
    assert!(refine(&f, &blob_at([3.0, 31.0], 9.0), 2.5).is_none());
}

/// Blobs at the image positions `f(board position)` of every circle of `g`.
fn lattice_blobs(g: &CircleGrid, f: impl Fn([f64; 2]) -> [f64; 2]) -> Vec<Blob> {
    (0..g.len())
        .filter_map(|id| g.position(id))
        .map(|p| blob_at(f(p), 3.0))
        .collect()
}

#[test]
fn lattice_numbering_follows_the_board() {
    for asym in [false, true] {
        let g = CircleGrid::new(4, 5, 1.0, 0.5, asym).expect("valid");
        // Rotated by 100°, foreshortened along one axis, plus clutter.
        let (s, c) = 100f64.to_radians().sin_cos();
        let f = |p: [f64; 2]| {
            let (x, y) = (p[0] * 20.0, p[1] * 11.0);
            [300.0 + c * x - s * y, 200.0 + s * x + c * y]
        };
        let mut blobs = lattice_blobs(&g, f);
        blobs.push(blob_at([520.0, 420.0], 3.0));
        blobs.push(blob_at([100.0, 100.0], 3.0));
        let ids = find_lattice(&blobs, &g).expect("lattice");
        let n_expected = g.len();
        assert_eq!(ids.len(), n_expected);
        // Handedness of the board is kept: either the true numbering or, for patterns with
        // the symmetry, its half turn.
        let identity = ids.iter().enumerate().all(|(i, &k)| i == k);
        let turned = ids
            .iter()
            .enumerate()
            .all(|(i, &k)| n_expected - 1 - i == k);
        assert!(
            identity || (turned && g.half_turn().is_some()),
            "{asym}: {ids:?}"
        );
    }
}

/// A mirrored view (the board seen from behind, or a mirror): an asymmetric grid with an odd
/// number of rows is symmetric about its middle row, so it is still found, numbered with the
/// handedness of a view from the printed side.
#[test]
fn lattice_numbering_keeps_handedness_in_a_mirrored_view() {
    let g = CircleGrid::new(4, 5, 1.0, 0.5, true).expect("valid");
    let blobs = lattice_blobs(&g, |p| [500.0 - 15.0 * p[0], 100.0 + 15.0 * p[1]]);
    let ids = find_lattice(&blobs, &g).expect("lattice");
    let c: Vec<[f64; 2]> = ids.iter().map(|&k| blobs[k].c).collect();
    let (o, a, b) = (c[0], c[1], c[4]);
    let cross = (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
    assert!(cross > 0.0);
    // Row 0 of the numbering is the image's bottom row (the mirror of the top one).
    assert!(o[1] > c[16][1]);
}

#[test]
fn lattice_too_small_or_too_big() {
    let g = CircleGrid::new(4, 4, 1.0, 0.5, false).expect("valid");
    let small = CircleGrid::new(3, 3, 1.0, 0.5, false).expect("valid");
    let blobs = lattice_blobs(&g, |p| [100.0 + 12.0 * p[0], 100.0 + 12.0 * p[1]]);
    assert!(find_lattice(&blobs, &small).is_err());
    let big = CircleGrid::new(5, 4, 1.0, 0.5, false).expect("valid");
    assert!(find_lattice(&blobs, &big).is_err());
}

#[test]
fn detect_on_a_flat_view() {
    let g = CircleGrid::new(5, 4, 1.0, 0.5, false).expect("valid");
    let ds: Vec<[f64; 3]> = (0..g.len())
        .filter_map(|id| g.position(id))
        .map(|p| [40.0 + 30.0 * p[0], 30.0 + 30.0 * p[1], 7.5])
        .collect();
    let img = discs(220, 150, &ds);
    match detect_circles(&img, &g, 20.0) {
        CirclesDetection::Found(cs) => {
            for (c, d) in cs.iter().zip(&ds) {
                // A fronto-parallel view: no perspective bias, raw and corrected agree.
                assert!(
                    (c.raw[0] - d[0]).hypot(c.raw[1] - d[1]) < 0.02,
                    "{c:?} {d:?}"
                );
                assert!((c.corrected[0] - d[0]).hypot(c.corrected[1] - d[1]) < 0.02);
            }
        }
        CirclesDetection::NotFound(r) => panic!("{r}"),
    }
}

#[test]
fn detect_never_panics_on_odd_images() {
    let g = CircleGrid::new(4, 3, 1.0, 0.5, false).expect("valid");
    let imgs = [
        Gray {
            width: 0,
            height: 0,
            data: vec![],
        },
        Gray {
            width: 3,
            height: 3,
            data: vec![0; 4],
        },
        Gray {
            width: 9,
            height: 9,
            data: vec![128; 81],
        },
        discs(40, 30, &[[0.0, 0.0, 50.0]]),
    ];
    for img in &imgs {
        assert!(matches!(
            detect_circles(img, &g, 20.0),
            CirclesDetection::NotFound(_)
        ));
    }
}
