//! Calibration targets described once, the same way for every job, and detected with one call.
//!
//! [`TargetSpec`] is the JSON description (`{"type": "chessboard" | "charuco" | "aprilgrid" |
//! "circles", …}`), also read from Kalibr's target yaml ([`TargetSpec::from_kalibr_yaml`]) and from
//! OpenCV's ChArUco parameters ([`TargetSpec::from_opencv_charuco`]). It knows every corner's
//! id and board position ([`TargetSpec::object_point`]), so that a partial view (ChArUco,
//! AprilGrid) calibrates like a full one. [`detect_target`] finds the corners of any target
//! in an image and says why when it finds none.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::aprilgrid::{AprilGrid, aprilgrid_corners};
use super::charuco::{CharucoBoard, charuco_corners};
use super::chessboard::{DetectOptions, detect_chessboard};
use super::circles::{CircleGrid, CirclesDetection, detect_circles};
use super::filter::gaussian_blur_gray;
use super::markers::{Dictionary, detect_markers, predict_missing};
use crate::calib::{CornerObservation, ViewObservations};
use crate::error::{CoreError, CoreResult};
use crate::io::Gray;

/// A calibration target.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum TargetSpec {
    /// A plain chessboard, as [`crate::calib::BoardGeometry`]: `cols × rows` inner corners,
    /// row-major ids, corner `(c, r)` at `(c, r)·square`.
    Chessboard {
        /// Inner corners per row.
        cols: usize,
        /// Inner corners per column.
        rows: usize,
        /// Square side (the unit of the board frame).
        square: f64,
    },
    /// An OpenCV ChArUco board (see [`crate::board::charuco`] for the layout and ids).
    Charuco {
        /// Squares per row (OpenCV `squaresX`).
        squares_x: usize,
        /// Squares per column (OpenCV `squaresY`).
        squares_y: usize,
        /// Square side (OpenCV `squareLength`).
        square: f64,
        /// Marker side (OpenCV `markerLength`), less than `square`.
        marker: f64,
        /// OpenCV dictionary name, e.g. `DICT_6X6_250`.
        dictionary: String,
        /// OpenCV's pre-4.6 layout (`setLegacyPattern(true)`), which differs for even
        /// `squares_y` only.
        #[serde(default)]
        legacy: bool,
    },
    /// A Kalibr AprilGrid (see [`crate::board::aprilgrid`] for the layout and ids).
    Aprilgrid {
        /// Rows of tags (Kalibr `tagRows`).
        tag_rows: usize,
        /// Columns of tags (Kalibr `tagCols`).
        tag_cols: usize,
        /// Tag side, outer edge of the black border (Kalibr `tagSize`).
        tag_size: f64,
        /// Gap between tags as a fraction of `tag_size` (Kalibr `tagSpacing`).
        tag_spacing: f64,
        /// Tag family; Kalibr's AprilGrid uses `tag36h11` only.
        #[serde(default = "tag36h11")]
        tag_family: String,
    },
    /// An OpenCV circle grid of dark circles on a light card (see [`crate::board::circles`]):
    /// `cols × rows` circles as OpenCV's `patternSize`, row-major ids `r·cols + c`, circle
    /// `(c, r)` at `(c, r)·spacing`, or `(2c + r mod 2, r)·spacing` in an asymmetric grid.
    /// Centres are corrected for perspective.
    Circles {
        /// Circles per row (OpenCV `patternSize.width`).
        cols: usize,
        /// Rows of circles (OpenCV `patternSize.height`).
        rows: usize,
        /// Centre distance between neighbouring rows (and columns of a symmetric grid; the
        /// circles of one row of an asymmetric grid are `2·spacing` apart).
        spacing: f64,
        /// Circle diameter, smaller than the nearest-centre distance.
        diameter: f64,
        /// OpenCV's `CALIB_CB_ASYMMETRIC_GRID`: odd rows shifted by `spacing`.
        #[serde(default)]
        asymmetric: bool,
    },
}

fn tag36h11() -> String {
    "tag36h11".to_owned()
}

fn positive(field: &str, v: f64) -> CoreResult<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(CoreError::param(
            field,
            format!("must be positive and finite, got {v}"),
        ))
    }
}

/// A target resolved to its layout.
enum Layout {
    Chessboard(usize, usize, f64),
    Charuco(CharucoBoard),
    Aprilgrid(AprilGrid),
    Circles(CircleGrid),
}

impl TargetSpec {
    fn layout(&self) -> CoreResult<Layout> {
        match self {
            Self::Chessboard { cols, rows, square } => {
                if *cols < 2 || *rows < 2 {
                    return Err(CoreError::param(
                        "cols",
                        format!("needs at least 2×2 inner corners, got {cols}×{rows}"),
                    ));
                }
                if cols.saturating_mul(*rows) > 1_000_000 {
                    return Err(CoreError::param("rows", "more than 10⁶ corners"));
                }
                positive("square", *square)?;
                Ok(Layout::Chessboard(*cols, *rows, *square))
            }
            Self::Charuco {
                squares_x,
                squares_y,
                square,
                marker,
                dictionary,
                legacy,
            } => {
                if *squares_x < 2 || *squares_y < 2 {
                    return Err(CoreError::param(
                        "squares_x",
                        format!("needs at least 2×2 squares, got {squares_x}×{squares_y}"),
                    ));
                }
                if squares_x.saturating_mul(*squares_y) > 100_000 {
                    return Err(CoreError::param("squares_y", "more than 10⁵ squares"));
                }
                positive("square", *square)?;
                positive("marker", *marker)?;
                if marker >= square {
                    return Err(CoreError::param(
                        "marker",
                        format!("the marker ({marker}) must be smaller than the square ({square})"),
                    ));
                }
                let dict = Dictionary::from_name(dictionary).ok_or_else(|| {
                    CoreError::param(
                        "dictionary",
                        format!(
                            "unknown dictionary {dictionary:?}; known: {}",
                            Dictionary::names().join(", ")
                        ),
                    )
                })?;
                let b = CharucoBoard {
                    squares_x: *squares_x,
                    squares_y: *squares_y,
                    square: *square,
                    marker: *marker,
                    dict,
                    legacy: *legacy,
                };
                if b.num_markers() > dict.len() {
                    return Err(CoreError::param(
                        "dictionary",
                        format!(
                            "{} has {} markers, the board needs {}",
                            dict.name(),
                            dict.len(),
                            b.num_markers()
                        ),
                    ));
                }
                Ok(Layout::Charuco(b))
            }
            Self::Aprilgrid {
                tag_rows,
                tag_cols,
                tag_size,
                tag_spacing,
                tag_family,
            } => {
                if *tag_rows < 1 || *tag_cols < 1 {
                    return Err(CoreError::param(
                        "tag_rows",
                        format!("needs at least one tag, got {tag_cols}×{tag_rows}"),
                    ));
                }
                positive("tag_size", *tag_size)?;
                if !(tag_spacing.is_finite() && *tag_spacing > 0.0 && *tag_spacing <= 1.0) {
                    return Err(CoreError::param(
                        "tag_spacing",
                        format!("is a fraction of tag_size in (0, 1], got {tag_spacing}"),
                    ));
                }
                let fam = tag_family.trim();
                if !(fam.eq_ignore_ascii_case("tag36h11") || fam.eq_ignore_ascii_case("t36h11")) {
                    return Err(CoreError::param(
                        "tag_family",
                        format!("AprilGrid supports tag36h11 only, got {tag_family:?}"),
                    ));
                }
                let dict = Dictionary::from_name("tag36h11")
                    .ok_or_else(|| CoreError::param("tag_family", "tag36h11 table missing"))?;
                if tag_rows.saturating_mul(*tag_cols) > dict.len() {
                    return Err(CoreError::param(
                        "tag_cols",
                        format!(
                            "{}×{} tags, tag36h11 has {}",
                            tag_cols,
                            tag_rows,
                            dict.len()
                        ),
                    ));
                }
                Ok(Layout::Aprilgrid(AprilGrid {
                    tag_rows: *tag_rows,
                    tag_cols: *tag_cols,
                    tag_size: *tag_size,
                    tag_spacing: *tag_spacing,
                    dict,
                }))
            }
            Self::Circles {
                cols,
                rows,
                spacing,
                diameter,
                asymmetric,
            } => {
                CircleGrid::new(*cols, *rows, *spacing, *diameter, *asymmetric).map(Layout::Circles)
            }
        }
    }

    /// Errors (naming the field) for a target that cannot exist: too few squares or tags,
    /// non-positive or non-finite sizes, a marker not smaller than its square, an unknown
    /// dictionary or one with fewer markers than the board needs, circles that touch.
    pub fn validate(&self) -> CoreResult<()> {
        self.layout().map(|_| ())
    }

    /// Number of corner ids (0 for an invalid target).
    pub fn num_corners(&self) -> usize {
        match self.layout() {
            Ok(Layout::Chessboard(c, r, _)) => c * r,
            Ok(Layout::Charuco(b)) => b.num_corners(),
            Ok(Layout::Aprilgrid(g)) => g.num_corners(),
            Ok(Layout::Circles(g)) => g.len(),
            Err(_) => 0,
        }
    }

    /// Board-frame position of corner `id` (z = 0, in the unit of the sizes), `None` for an
    /// id past the last or an invalid target.
    pub fn object_point(&self, id: usize) -> Option<Vector3<f64>> {
        let p = match self.layout().ok()? {
            Layout::Chessboard(c, r, s) => {
                (id < c * r).then(|| [(id % c) as f64 * s, (id / c) as f64 * s])?
            }
            Layout::Charuco(b) => b.corner_position(id)?,
            Layout::Aprilgrid(g) => g.corner_position(id)?,
            Layout::Circles(g) => g.position(id)?,
        };
        Some(Vector3::new(p[0], p[1], 0.0))
    }

    /// Colour of the printed target at board point `(x, y)` (board units): `Some(true)` black,
    /// `Some(false)` white, `None` outside the pattern. For synthetic renders and overlays.
    /// Chessboards have their outer ring of squares, the square beyond corner 0 black; circle
    /// grids a white card reaching one spacing beyond the outer centres.
    pub fn is_black(&self, x: f64, y: f64) -> Option<bool> {
        match self.layout().ok()? {
            Layout::Chessboard(c, r, s) => {
                let (i, j) = ((x / s).floor() + 1.0, (y / s).floor() + 1.0);
                let inside = i >= 0.0 && j >= 0.0 && i <= c as f64 && j <= r as f64;
                inside.then(|| (i + j).rem_euclid(2.0) == 0.0)
            }
            Layout::Charuco(b) => b.is_black(x, y),
            Layout::Aprilgrid(g) => g.is_black(x, y),
            Layout::Circles(g) => g.is_black(x, y),
        }
    }

    /// Reads a Kalibr target yaml (`target_type: 'aprilgrid'` with `tagCols`, `tagRows`,
    /// `tagSize`, `tagSpacing`; `'checkerboard'` with `targetCols`, `targetRows`,
    /// `rowSpacingMeters`, `colSpacingMeters`, which must be equal here). The result is
    /// validated.
    pub fn from_kalibr_yaml(text: &str) -> CoreResult<Self> {
        super::aprilgrid::kalibr_yaml::from_kalibr(text)
    }

    /// Reads OpenCV ChArUco parameters as `key: value` lines (a FileStorage YAML or plain
    /// YAML): `squaresX`, `squaresY`, `squareLength`, `markerLength`, `dictionary` (a name
    /// such as `DICT_6X6_250` or OpenCV's `PredefinedDictionaryType` number) and optionally
    /// `legacyPattern`. The result is validated.
    pub fn from_opencv_charuco(text: &str) -> CoreResult<Self> {
        super::aprilgrid::kalibr_yaml::from_opencv_charuco(text)
    }
}

/// Settings of [`detect_target`] (every field has a default).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct TargetOptions {
    /// Least grey-level difference between a marker's black border and the white around it.
    pub min_contrast: f64,
    /// Least width and height of a marker or tag, pixels.
    pub min_marker_px: f64,
    /// Smoothing before the sub-pixel saddle fit of marker boards, pixels.
    pub sigma: f64,
    /// Options of the chessboard detector (chessboard targets).
    pub chessboard: DetectOptions,
}

impl Default for TargetOptions {
    fn default() -> Self {
        Self {
            min_contrast: 20.0,
            min_marker_px: 10.0,
            sigma: 1.0,
            chessboard: DetectOptions::default(),
        }
    }
}

impl TargetOptions {
    /// Errors on values outside their domain.
    pub fn validate(&self) -> CoreResult<()> {
        if !(self.min_contrast.is_finite() && self.min_contrast >= 0.0) {
            return Err(CoreError::param("min_contrast", "must be ≥ 0"));
        }
        if !(self.min_marker_px.is_finite() && self.min_marker_px >= 4.0) {
            return Err(CoreError::param("min_marker_px", "must be ≥ 4"));
        }
        if !(self.sigma.is_finite() && self.sigma > 0.3 && self.sigma <= 5.0) {
            return Err(CoreError::param("sigma", "must be in (0.3, 5]"));
        }
        self.chessboard.validate()
    }
}

/// The corners of a target found in one image.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct TargetDetection {
    /// Corners found, sorted by id ([`TargetSpec::object_point`] gives their board position).
    pub corners: Vec<CornerObservation>,
    /// Markers or tags decoded and used (0 for chessboards).
    pub markers_found: usize,
    /// Why no corner was found (`None` when there are corners).
    pub reason: Option<String>,
    /// Things the user should know even when corners were found (duplicate ids, markers not
    /// on this board, corners that failed the sub-pixel fit).
    pub warnings: Vec<String>,
}

impl TargetDetection {
    /// Observations for calibration: index = corner id.
    pub fn to_observations(&self, name: impl Into<String>) -> ViewObservations {
        ViewObservations {
            name: name.into(),
            corners: self.corners.clone(),
        }
    }

    fn failed(reason: impl Into<String>) -> Self {
        Self {
            reason: Some(reason.into()),
            ..Self::default()
        }
    }
}

/// Finds the corners of `spec` in `img`.
///
/// Chessboards go to [`detect_chessboard`] and circle grids to [`detect_circles`] (all
/// corners or none; circle centres corrected for perspective). ChArUco boards and
/// AprilGrids yield every corner next to a decoded marker, or next to a marker placed by
/// decoded ones nearby (too small or blurred to read), so partial views count. Never
/// fails: an invalid spec, invalid options or an image without the target give no corners and
/// a `reason`.
pub fn detect_target(img: &Gray, spec: &TargetSpec, opts: &TargetOptions) -> TargetDetection {
    if let Err(e) = opts.validate() {
        return TargetDetection::failed(format!("invalid detection options: {e}"));
    }
    let layout = match spec.layout() {
        Ok(l) => l,
        Err(e) => return TargetDetection::failed(format!("invalid target: {e}")),
    };
    let (w, h) = (img.width as usize, img.height as usize);
    if img.data.len() != w * h || w < 16 || h < 16 {
        return TargetDetection::failed("invalid image: empty, too small or the wrong size");
    }
    let (dict, border, num_ids) = match &layout {
        Layout::Chessboard(c, r, _) => {
            let d = detect_chessboard(img, *c, *r, &opts.chessboard);
            return match d.corners() {
                Some(c) => TargetDetection {
                    corners: c
                        .iter()
                        .enumerate()
                        .map(|(index, &pixel)| CornerObservation { index, pixel })
                        .collect(),
                    ..TargetDetection::default()
                },
                None => TargetDetection::failed(match d {
                    super::Detection::NotFound { reason } => reason,
                    super::Detection::Found { .. } => String::new(),
                }),
            };
        }
        Layout::Charuco(b) => (b.dict, 1, b.num_markers()),
        Layout::Aprilgrid(g) => (g.dict, 2, g.tag_rows * g.tag_cols),
        Layout::Circles(g) => {
            return match detect_circles(img, g, opts.min_contrast) {
                CirclesDetection::Found(cs) => TargetDetection {
                    corners: cs
                        .iter()
                        .map(|c| CornerObservation {
                            index: c.id,
                            pixel: c.corrected,
                        })
                        .collect(),
                    ..TargetDetection::default()
                },
                CirclesDetection::NotFound(reason) => TargetDetection::failed(reason),
            };
        }
    };
    let scan = detect_markers(img, &dict, border, opts.min_contrast, opts.min_marker_px);
    let mut warnings = Vec::new();
    if !scan.duplicates.is_empty() {
        warnings.push(format!(
            "marker ids {:?} seen more than once (a second board or a stray marker?): dropped",
            scan.duplicates
        ));
    }
    let (mine, foreign): (Vec<_>, Vec<_>) = scan.markers.into_iter().partition(|m| m.id < num_ids);
    if !foreign.is_empty() {
        warnings.push(format!(
            "{} markers of {} with ids not on this board (ids {:?}) ignored",
            foreign.len(),
            dict.name(),
            foreign.iter().map(|m| m.id).collect::<Vec<_>>()
        ));
    }
    let kind = if border == 2 { "tag" } else { "marker" };
    if mine.is_empty() {
        let reason = if scan.undecoded > 0 {
            format!(
                "no {kind} decoded from {}; {} quads looked like markers — wrong dictionary?",
                dict.name(),
                scan.undecoded
            )
        } else if !scan.duplicates.is_empty() {
            format!("every {kind} id was seen more than once")
        } else if !foreign.is_empty() {
            format!("only {kind}s with ids not on this board")
        } else {
            format!(
                "no {kind} found ({} dark quadrilaterals; the board is not in view, too small \
                 (markers under {} px), or too blurred)",
                scan.quads, opts.min_marker_px
            )
        };
        return TargetDetection {
            reason: Some(reason),
            warnings,
            ..TargetDetection::default()
        };
    }
    // Markers the decoder missed (tiny far-side cells on a tilted board) are placed by their
    // decoded neighbours; their corners must pass the same fit and colour checks.
    let predicted = match &layout {
        Layout::Charuco(b) => predict_missing(
            &mine,
            num_ids,
            |id| b.marker_outline(id),
            b.prediction_reach(),
            (w, h),
        ),
        Layout::Aprilgrid(g) => predict_missing(
            &mine,
            num_ids,
            |t| g.tag_outline(t),
            g.prediction_reach(),
            (w, h),
        ),
        Layout::Chessboard(..) | Layout::Circles(..) => Vec::new(),
    };
    let placed: Vec<_> = mine.iter().cloned().chain(predicted).collect();
    let s = gaussian_blur_gray(img, opts.sigma);
    let (corners, rejected) = match &layout {
        Layout::Charuco(b) => charuco_corners(&s, b, &placed, opts.min_contrast),
        Layout::Aprilgrid(g) => aprilgrid_corners(&s, g, &placed, opts.min_contrast),
        Layout::Chessboard(..) | Layout::Circles(..) => (Vec::new(), 0),
    };
    if rejected > 0 {
        warnings.push(format!(
            "{rejected} corners next to decoded {kind}s failed the sub-pixel fit or the colour \
             check (blur, glare or occlusion)"
        ));
    }
    let reason = corners.is_empty().then(|| {
        format!(
            "{} {kind}s decoded but no corner passed the sub-pixel fit",
            mine.len()
        )
    });
    TargetDetection {
        corners: corners
            .into_iter()
            .map(|(index, pixel)| CornerObservation { index, pixel })
            .collect(),
        markers_found: mine.len(),
        reason,
        warnings,
    }
}

/// Every target calibrates: its ids and board positions are what the solvers need. A plain
/// chessboard and circle grids symmetric under a half turn are ambiguous under it (marker
/// boards carry their ids).
impl crate::calib::PlanarTarget for TargetSpec {
    fn validate(&self) -> CoreResult<()> {
        TargetSpec::validate(self)
    }

    fn num_points(&self) -> usize {
        self.num_corners()
    }

    fn object_point(&self, id: usize) -> Option<Vector3<f64>> {
        TargetSpec::object_point(self, id)
    }

    fn describe(&self) -> String {
        match self {
            Self::Chessboard { cols, rows, .. } => format!("{cols}×{rows} chessboard"),
            Self::Charuco {
                squares_x,
                squares_y,
                dictionary,
                ..
            } => format!("{squares_x}×{squares_y} ChArUco board ({dictionary})"),
            Self::Aprilgrid {
                tag_cols, tag_rows, ..
            } => format!("{tag_cols}×{tag_rows} AprilGrid"),
            Self::Circles {
                cols,
                rows,
                asymmetric,
                ..
            } => format!(
                "{cols}×{rows} {} circle grid",
                if *asymmetric {
                    "asymmetric"
                } else {
                    "symmetric"
                }
            ),
        }
    }

    fn half_turn(&self) -> Option<crate::lie::Se3> {
        match self {
            Self::Chessboard { cols, rows, square } => {
                crate::calib::PlanarTarget::half_turn(&crate::calib::BoardGeometry {
                    cols: *cols,
                    rows: *rows,
                    square: *square,
                })
            }
            Self::Circles { .. } => match self.layout() {
                Ok(Layout::Circles(g)) => g.half_turn(),
                _ => None,
            },
            _ => None,
        }
    }
}
