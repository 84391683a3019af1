use nalgebra::Vector3;

use super::*;
use crate::camera::PinholeRadTan;
use crate::lie::So3;

fn camera() -> Camera {
    PinholeRadTan::new(500.0, 500.0, 319.5, 239.5, -0.2, 0.05, 0.0, 0.0, 0.0)
        .map(Camera::from)
        .expect("valid camera")
}

fn pose() -> Se3 {
    Se3::new(
        So3::from_rotation_vector(&Vector3::new(0.2, -0.3, 0.1)),
        Vector3::new(-4.0, -2.5, 12.0),
    )
}

#[test]
fn corners_are_projections_and_colours_follow_the_convention() {
    let v = render_chessboard(
        &camera(),
        &pose(),
        (9, 6, 1.0),
        (640, 480),
        &RenderOptions::default(),
    )
    .expect("render");
    assert!(v.all_visible());
    assert_eq!(v.corners.len(), 54);
    // The cell between corners 0, 1, 9, 10 is black, its neighbour along the row white.
    let c = |k: usize| v.corners[k].expect("visible");
    let centre = |a: usize| {
        let (p, q, r, s) = (c(a), c(a + 1), c(a + 9), c(a + 10));
        let x = ((p[0] + q[0] + r[0] + s[0]) / 4.0).round() as usize;
        let y = ((p[1] + q[1] + r[1] + s[1]) / 4.0).round() as usize;
        v.image.data[y * 640 + x]
    };
    assert_eq!(centre(0), 30);
    assert_eq!(centre(1), 220);
    assert_eq!(centre(10), 30);
}

#[test]
fn noise_is_seeded_and_blur_preserves_the_mean() {
    let opts = RenderOptions {
        noise_sigma: 2.0,
        seed: 7,
        blur_sigma: 1.0,
        ..RenderOptions::default()
    };
    let a = render_chessboard(&camera(), &pose(), (9, 6, 1.0), (640, 480), &opts).expect("a");
    let b = render_chessboard(&camera(), &pose(), (9, 6, 1.0), (640, 480), &opts).expect("b");
    assert_eq!(a.image, b.image);
    let c = render_chessboard(
        &camera(),
        &pose(),
        (9, 6, 1.0),
        (640, 480),
        &RenderOptions { seed: 8, ..opts },
    )
    .expect("c");
    assert_ne!(a.image, c.image);
    let flat = Gray::new(64, 64, vec![100; 64 * 64]).expect("gray");
    assert_eq!(blur_gray(&flat, 3.0), flat);
    assert_eq!(motion_blur_gray(&flat, 9.0), flat);
}

#[test]
fn invalid_options_are_rejected() {
    let bad = RenderOptions {
        supersample: 0,
        ..RenderOptions::default()
    };
    assert!(render_chessboard(&camera(), &pose(), (9, 6, 1.0), (640, 480), &bad).is_err());
    assert!(
        render_chessboard(
            &camera(),
            &pose(),
            (1, 6, 1.0),
            (640, 480),
            &RenderOptions::default()
        )
        .is_err()
    );
}
