//! OpenCV `FileStorage` YAML, as OpenCV 4.x's calibration sample writes it.
//!
//! Field list and order: `saveCameraParams` in OpenCV's
//! `samples/cpp/tutorial_code/calib3d/camera_calibration/camera_calibration.cpp`
//! (summarised in `/work/shared/docs/formats.md`). The reader also accepts the spellings of the
//! OpenCV 2.x/3.x samples (`Camera_Matrix`, `Distortion_Coefficients`, `Avg_Reprojection_Error`,
//! `nrOfFrames`, `image_Width`, …) and of `samples/cpp/calibration.cpp` (`nframes`,
//! `aspectRatio`), which wrote the `left_intrinsics.yml` OpenCV ships.

use super::yaml::{self, Fields, NanStyle, fmt_f32, fmt_f64, opencv_matrix};
use super::{ExportInput, ImportedCamera, ImportedPose, in_format, intrinsics_from_k, model_error};
use crate::calib::CalibOptions;
use crate::camera::{Camera, CameraModel, KannalaBrandt, PinholeRadTan};
use crate::error::{CoreError, CoreResult};

const FMT: &str = "opencv-yaml";

// `cv::CALIB_*` (calib3d.hpp).
const CALIB_FIX_ASPECT_RATIO: i64 = 2;
const CALIB_FIX_PRINCIPAL_POINT: i64 = 4;
const CALIB_ZERO_TANGENT_DIST: i64 = 8;
const CALIB_FIX_K3: i64 = 128;
// `cv::fisheye::CALIB_*` (calib3d.hpp).
const FISHEYE_CALIB_FIX_SKEW: i64 = 1 << 3;
const FISHEYE_CALIB_FIX_PRINCIPAL_POINT: i64 = 1 << 9;

/// Which of the options that map to OpenCV flags were in force.
struct Fixed {
    aspect: bool,
    principal_point: bool,
    tangential: bool,
    k3: bool,
}

impl Fixed {
    /// From the options when known, else from the parameters marked fixed (which cannot show
    /// the aspect-ratio tie: fy stays a free-looking parameter there).
    fn of(input: &ExportInput<'_>) -> Self {
        if let Some(o) = input.options {
            return Self::from_options(o);
        }
        let fixed = |name: &str| {
            input
                .calibration
                .parameters
                .iter()
                .any(|p| p.name == name && p.fixed)
        };
        Self {
            aspect: false,
            principal_point: fixed("cx") && fixed("cy"),
            tangential: fixed("p1") && fixed("p2"),
            k3: fixed("k3"),
        }
    }

    fn from_options(o: &CalibOptions) -> Self {
        Self {
            aspect: o.fix_aspect_ratio,
            principal_point: o.fix_principal_point,
            tangential: o.zero_tangential,
            k3: o.fix_k3,
        }
    }
}

/// OpenCV's `flags` value and the words of the sample's `# flags:` comment.
///
/// The fisheye flags always include `FIX_SKEW`: Caliper's Kannala-Brandt has no skew, which is
/// exactly what that flag produces in `cv::fisheye::calibrate`. A fixed aspect ratio has no
/// fisheye flag and is left out for that model.
fn flags(fixed: &Fixed, fisheye: bool) -> (i64, Vec<&'static str>) {
    let mut value = 0;
    let mut words = Vec::new();
    let mut set = |on: bool, bit: i64, word: &'static str| {
        if on {
            value |= bit;
            words.push(word);
        }
    };
    if fisheye {
        set(true, FISHEYE_CALIB_FIX_SKEW, "+fix_skew");
        set(
            fixed.principal_point,
            FISHEYE_CALIB_FIX_PRINCIPAL_POINT,
            "+fix_principal_point",
        );
    } else {
        set(fixed.aspect, CALIB_FIX_ASPECT_RATIO, "+fix_aspectRatio");
        set(
            fixed.principal_point,
            CALIB_FIX_PRINCIPAL_POINT,
            "+fix_principal_point",
        );
        set(
            fixed.tangential,
            CALIB_ZERO_TANGENT_DIST,
            "+zero_tangent_dist",
        );
        set(fixed.k3, CALIB_FIX_K3, "+fix_k3");
    }
    (value, words)
}

/// Appends an `!!opencv-matrix` block.
pub(super) fn matrix(
    out: &mut String,
    key: &str,
    rows: usize,
    cols: usize,
    dt: char,
    data: &[String],
) {
    out.push_str(&format!(
        "{key}: {}\n   rows: {rows}\n   cols: {cols}\n   dt: {dt}\n   data: {}\n",
        yaml::OPENCV_MATRIX_TAG,
        yaml::flow_wrapped(data, 9, 7)
    ));
}

pub(super) fn write(input: &ExportInput<'_>) -> CoreResult<String> {
    let c = input.calibration;
    let p = c.camera.params();
    let (fisheye, dist) = match &c.camera {
        Camera::PinholeRadTan(m) => (false, m.distortion().to_vec()),
        Camera::KannalaBrandt(_) => (true, p[4..8].to_vec()),
        Camera::DoubleSphere(_) => {
            return Err(CoreError::param(
                "format",
                "the double-sphere camera has no OpenCV form (OpenCV's calib3d and fisheye \
                 modules implement only the pinhole and Kannala-Brandt models); export \
                 kalibr-yaml (camera_model: ds) or json instead",
            ));
        }
    };
    let num = |v: f64| fmt_f64(v, NanStyle::OpenCv);
    // OpenCV only stores views that took part; rows of the two per-view matrices must agree.
    let views: Vec<_> = c
        .views
        .iter()
        .filter(|v| v.used)
        .filter_map(|v| Some((v.rvec?, v.tvec?, v.rms?)))
        .collect();

    let mut out = String::from("%YAML:1.0\n---\n");
    if let Some(t) = input.calibration_time {
        out.push_str(&format!(
            "calibration_time: {}\n",
            yaml::quote("calibration_time", t)?
        ));
    }
    if !views.is_empty() {
        out.push_str(&format!("nr_of_frames: {}\n", views.len()));
    }
    let [w, h] = c.image_size;
    out.push_str(&format!("image_width: {w}\nimage_height: {h}\n"));
    if let Some(b) = &input.board {
        out.push_str(&format!(
            "board_width: {}\nboard_height: {}\nsquare_size: {}\n",
            b.cols,
            b.rows,
            num(b.square)
        ));
    }
    let fixed = Fixed::of(input);
    if fixed.aspect && !fisheye {
        out.push_str(&format!("fix_aspect_ratio: {}\n", num(p[0] / p[1])));
    }
    let (flag_value, words) = flags(&fixed, fisheye);
    if words.is_empty() {
        out.push_str("# flags: none\n");
    } else {
        out.push_str(&format!("# flags: {}\n", words.join(" ")));
    }
    out.push_str(&format!(
        "flags: {flag_value}\nfisheye_model: {}\n",
        i32::from(fisheye)
    ));
    let k = [p[0], 0.0, p[2], 0.0, p[1], p[3], 0.0, 0.0, 1.0];
    let k: Vec<String> = k.iter().map(|v| num(*v)).collect();
    matrix(&mut out, "camera_matrix", 3, 3, 'd', &k);
    let d: Vec<String> = dist.iter().map(|v| num(*v)).collect();
    matrix(&mut out, "distortion_coefficients", d.len(), 1, 'd', &d);
    out.push_str(&format!("avg_reprojection_error: {}\n", num(c.rms)));
    if !views.is_empty() {
        let errors: Vec<String> = views
            .iter()
            .map(|(_, _, rms)| fmt_f32(*rms as f32, NanStyle::OpenCv))
            .collect();
        matrix(
            &mut out,
            "per_view_reprojection_errors",
            views.len(),
            1,
            'f',
            &errors,
        );
        let poses: Vec<String> = views
            .iter()
            .flat_map(|(r, t, _)| r.iter().chain(t.iter()).map(|v| num(*v)))
            .collect();
        matrix(
            &mut out,
            "extrinsic_parameters",
            views.len(),
            6,
            'd',
            &poses,
        );
    }
    Ok(out)
}

/// Reads an OpenCV calibration file (either the pinhole or the fisheye form).
///
/// Required: `camera_matrix` (3×3, no skew), `distortion_coefficients`, `image_width`,
/// `image_height`. The model is Kannala-Brandt when `fisheye_model: 1` (4 coefficients),
/// else pinhole: 4, 5, 8, 12 or 14 coefficients, of which those beyond `k1 k2 p1 p2 k3`
/// (rational and thin-prism terms Caliper does not model) must be zero. Files without
/// `fisheye_model` predate the fisheye sample and are pinhole.
pub fn read_opencv_yaml(text: &str) -> CoreResult<ImportedCamera> {
    let entries = yaml::parse(text).map_err(in_format(FMT))?;
    let f = Fields::new(FMT, &entries);

    let fisheye = match f.int(&["fisheye_model"])? {
        None | Some(0) => false,
        Some(1) => true,
        Some(v) => {
            return Err(yaml::bad(
                FMT,
                "fisheye_model",
                format!("must be 0 or 1, got {v}"),
            ));
        }
    };
    let (k_key, k_node) = f.require(&["camera_matrix", "Camera_Matrix"])?;
    let [fx, fy, cx, cy] = intrinsics_from_k(FMT, k_key, &opencv_matrix(FMT, k_key, k_node)?)?;
    let (d_key, d_node) = f.require(&["distortion_coefficients", "Distortion_Coefficients"])?;
    let d_matrix = opencv_matrix(FMT, d_key, d_node)?;
    let d = d_matrix.vector(FMT, d_key)?;
    let camera: Camera = if fisheye {
        let [k1, k2, k3, k4] = <[f64; 4]>::try_from(d).map_err(|_| {
            yaml::bad(
                FMT,
                d_key,
                format!("the fisheye model has 4 coefficients, got {}", d.len()),
            )
        })?;
        KannalaBrandt::new(fx, fy, cx, cy, k1, k2, k3, k4)
            .map_err(model_error(FMT, k_key))?
            .into()
    } else {
        if ![4, 5, 8, 12, 14].contains(&d.len()) {
            return Err(yaml::bad(
                FMT,
                d_key,
                format!("expected 4, 5, 8, 12 or 14 coefficients, got {}", d.len()),
            ));
        }
        if let Some((i, v)) = d.iter().enumerate().skip(5).find(|(_, v)| **v != 0.0) {
            return Err(yaml::bad(
                FMT,
                d_key,
                format!(
                    "coefficient {} is {v}: only k1 k2 p1 p2 k3 are supported (rational and \
                     thin-prism terms must be 0)",
                    i + 1
                ),
            ));
        }
        let k3 = d.get(4).copied().unwrap_or(0.0);
        PinholeRadTan::new(fx, fy, cx, cy, d[0], d[1], d[2], d[3], k3)
            .map_err(model_error(FMT, d_key))?
            .into()
    };

    let image_size = [
        f.size(&["image_width", "image_Width"])?,
        f.size(&["image_height", "image_Height"])?,
    ];
    let mut out = ImportedCamera::new(camera, image_size);
    out.calibration_time = f.string(&["calibration_time", "calibration_Time"])?;
    out.flags = f.int(&["flags", "flagValue"])?;
    out.fixed_aspect_ratio = f.f64(&["fix_aspect_ratio", "aspectRatio", "FixAspectRatio"])?;
    out.avg_reprojection_error = f.f64(&["avg_reprojection_error", "Avg_Reprojection_Error"])?;
    out.board = read_board(&f)?;
    out.num_frames = match f.find(&["nr_of_frames", "nrOfFrames", "nframes"])? {
        Some((k, v)) => Some(
            usize::try_from(yaml::as_int(FMT, k, v)?)
                .map_err(|_| yaml::bad(FMT, k, "must be ≥ 0"))?,
        ),
        None => None,
    };
    if let Some((k, v)) = f.find(&[
        "per_view_reprojection_errors",
        "Per_View_Reprojection_Errors",
    ])? {
        out.per_view_reprojection_errors = opencv_matrix(FMT, k, v)?.vector(FMT, k)?.to_vec();
    }
    if let Some((k, v)) = f.find(&["extrinsic_parameters", "Extrinsic_Parameters"])? {
        let m = opencv_matrix(FMT, k, v)?;
        if m.cols != 6 {
            return Err(yaml::bad(
                FMT,
                k,
                format!(
                    "expected N×6 (rvec | tvec per view), got {}×{}",
                    m.rows, m.cols
                ),
            ));
        }
        out.extrinsics = m
            .data
            .chunks_exact(6)
            .map(|r| ImportedPose {
                rvec: [r[0], r[1], r[2]],
                tvec: [r[3], r[4], r[5]],
            })
            .collect();
    }
    let per_view = [
        (
            "per_view_reprojection_errors",
            out.per_view_reprojection_errors.len(),
        ),
        ("extrinsic_parameters", out.extrinsics.len()),
    ];
    for (key, n) in per_view {
        if n > 0 && out.num_frames.is_some_and(|f| f != n) {
            return Err(yaml::bad(
                FMT,
                key,
                format!(
                    "{n} views, but nr_of_frames is {}",
                    out.num_frames.unwrap_or(0)
                ),
            ));
        }
    }
    Ok(out)
}

/// The board, when all three of its keys are present (none is fine; some is an error).
fn read_board(f: &Fields<'_>) -> CoreResult<Option<crate::calib::BoardGeometry>> {
    let cols = f.find(&["board_width", "board_Width"])?;
    let rows = f.find(&["board_height", "board_Height"])?;
    let square = f.find(&["square_size", "square_Size"])?;
    let (cols, rows, square) = match (cols, rows, square) {
        (None, None, None) => return Ok(None),
        (Some(c), Some(r), Some(s)) => (c, r, s),
        (c, r, _) => {
            let missing = if c.is_none() {
                "board_width"
            } else if r.is_none() {
                "board_height"
            } else {
                "square_size"
            };
            return Err(CoreError::input(format!(
                "{FMT}: missing key `{missing}` (the board keys come together)"
            )));
        }
    };
    let count = |(k, v): (&str, &yaml::Node)| -> CoreResult<usize> {
        let n = yaml::as_int(FMT, k, v)?;
        usize::try_from(n).map_err(|_| yaml::bad(FMT, k, format!("must be ≥ 0, got {n}")))
    };
    let board = crate::calib::BoardGeometry {
        cols: count(cols)?,
        rows: count(rows)?,
        square: yaml::as_f64(FMT, square.0, square.1)?,
    };
    board
        .validate()
        .map_err(|e| CoreError::input(format!("{FMT}: board: {e}")))?;
    Ok(Some(board))
}
