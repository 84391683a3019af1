//! OpenCV circle grids (symmetric and asymmetric), detected whole with perspective-corrected
//! centres.
//!
//! [`detect_circles`] finds every circle of a [`CircleGrid`] or says why not. Pipeline:
//!
//! 1. **Blobs** ([`blobs`]): dark, filled-ellipse components at several threshold levels.
//! 2. **Lattice** ([`lattice`]): the `cols × rows` lattice among the blobs, grown with local
//!    predictions (perspective up to 60° and more, lens distortion), clutter ignored, ids
//!    numbered as OpenCV's `findCirclesGrid` and calibration sample: row-major, `cols` circles
//!    per row, board position `(c, r)·spacing` or, asymmetric, `(2c + r mod 2, r)·spacing`.
//! 3. **Ellipse centres** ([`subpix`]): the sub-pixel centroid of each circle's darkness
//!    against a locally fitted card brightness.
//! 4. **Perspective correction** ([`perspective`]): an ellipse centre is not the projected
//!    circle centre; the bias predicted by the image conic of each circle under the fitted
//!    homography is removed (Heikkilä 2000).
//!
//! Both the raw ellipse centres and the corrected centres are returned ([`CircleCentre`]):
//! calibration uses the corrected ones, the raw ones show what the correction did.

mod blobs;
mod geometry;
mod lattice;
pub mod perspective;
mod subpix;

#[cfg(test)]
mod tests;

pub use geometry::CircleGrid;

use super::filter::ImageF;
use crate::io::Gray;

/// One circle found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CircleCentre {
    /// Circle id, `r·cols + c`.
    pub id: usize,
    /// Centre of the imaged ellipse, pixels (biased under perspective).
    pub raw: [f64; 2],
    /// Projected circle centre: `raw` corrected for perspective, pixels.
    pub corrected: [f64; 2],
}

/// The result of [`detect_circles`].
#[derive(Clone, Debug, PartialEq)]
pub enum CirclesDetection {
    /// Every circle, sorted by id.
    Found(Vec<CircleCentre>),
    /// Why the grid was not found.
    NotFound(String),
}

/// Finds the whole grid `grid` in `img` (see the module docs); circles need a contrast of
/// `min_contrast` grey levels against the card. Never panics on any image.
pub fn detect_circles(img: &Gray, grid: &CircleGrid, min_contrast: f64) -> CirclesDetection {
    let (w, h) = (img.width as usize, img.height as usize);
    if img.data.len() != w * h || w < 8 || h < 8 {
        return CirclesDetection::NotFound(
            "invalid image: empty, too small or the wrong size".into(),
        );
    }
    let scan = blobs::find_blobs(img, min_contrast);
    if scan.too_many {
        return CirclesDetection::NotFound(format!(
            "more than {} blobs at one threshold: texture or noise, not a circle grid",
            blobs::MAX_BLOBS
        ));
    }
    if scan.contrast < min_contrast {
        return CirclesDetection::NotFound(format!(
            "the image's contrast ({:.0} grey levels) is under min_contrast ({min_contrast})",
            scan.contrast
        ));
    }
    let ids = match lattice::find_lattice(&scan.blobs, grid) {
        Ok(ids) => ids,
        Err(reason) => return CirclesDetection::NotFound(reason),
    };
    let f = ImageF::from_gray(img);
    let mut raw = Vec::with_capacity(ids.len());
    for (id, &k) in ids.iter().enumerate() {
        let b = &scan.blobs[k];
        // The window may reach half-way to the nearest other blob (in this blob's ellipse
        // metric), where a neighbour of the same shape begins to be as close as this one.
        let nearest = scan
            .blobs
            .iter()
            .enumerate()
            .filter(|&(j, _)| j != k)
            .map(|(_, o)| b.rho2(o.c))
            .fold(f64::INFINITY, f64::min)
            .sqrt();
        let outer = (nearest / 2.0).clamp(1.2, 2.5);
        match subpix::refine(&f, b, outer) {
            Some(r) if r.contrast >= min_contrast => raw.push(r.c),
            Some(r) => {
                return CirclesDetection::NotFound(format!(
                    "circle {id} has a contrast of {:.0} grey levels, under min_contrast \
                     ({min_contrast})",
                    r.contrast
                ));
            }
            None => {
                return CirclesDetection::NotFound(format!(
                    "circle {id} failed the sub-pixel fit (too close to the image border?)"
                ));
            }
        }
    }
    let board: Vec<[f64; 2]> = (0..grid.len()).filter_map(|id| grid.position(id)).collect();
    let Some(corrected) = perspective::correct(&raw, &board, grid.diameter / 2.0) else {
        return CirclesDetection::NotFound(
            "no homography fits the circle centres (degenerate view)".into(),
        );
    };
    CirclesDetection::Found(
        raw.into_iter()
            .zip(corrected)
            .enumerate()
            .map(|(id, (raw, corrected))| CircleCentre { id, raw, corrected })
            .collect(),
    )
}
