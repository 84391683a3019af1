//! `deblur`: deconvolve every image of a set (Wiener, Richardson-Lucy, TV, blind, alternating-RL
//! blind, or a gyro-drawn kernel; science in `caliper_core::deconv`).
//!
//! Artifacts per input `NAME.EXT`: `NAME.EXT` (the deblurred image, same format and bit depth
//! as the input), `NAME.kernel.png` (the kernel, scaled to its peak) and `NAME.kernel.json`
//! (the exact weights), and `NAME.preview.png` (blurred | deblurred side by side, 8-bit,
//! at most 1024 px wide) for dashboards. A clip's chosen frames come out the same way, named
//! `frame_NNNNNN.png` ([`clip`]).

use std::io::Cursor;

use caliper_core::Progress;
use caliper_core::deconv::{DeblurParams, deblur_image, psf_png};
use caliper_core::io::ImageLimits;
use image::{DynamicImage, ImageFormat};
use serde_json::{Value, json};

use std::path::{Path, PathBuf};

use clap::Args;

use super::{
    Artifact, AuxDataset, CliContext, JobError, JobInput, JobOutput, Kind, ParamError, RunError,
    base_name, stem,
};
use crate::store::DatasetKind;

mod clip;

/// Widest before/after preview, px.
const PREVIEW_WIDTH: u32 = 1024;

/// The `deblur` job kind.
pub struct Deblur;

fn permanent(message: String) -> JobError {
    JobError::Permanent {
        code: "invalid_input",
        message,
    }
}

fn internal(e: impl std::fmt::Display) -> JobError {
    JobError::Permanent {
        code: "internal_error",
        message: e.to_string(),
    }
}

/// Decode an image keeping its pixel format, within the service's image limits.
pub fn decode_keep_format(
    bytes: &[u8],
    name: &str,
) -> Result<(DynamicImage, ImageFormat), JobError> {
    caliper_core::io::decode_image(bytes, &ImageLimits::default())
        .map_err(|e| permanent(format!("{name}: {e}")))
}

/// Encode in `format` (PNG, TIFF or JPEG; JPEG can only hold 8-bit grey/RGB, which is what a
/// JPEG decodes to anyway).
pub fn encode(
    img: &DynamicImage,
    format: ImageFormat,
) -> Result<(Vec<u8>, &'static str), JobError> {
    let (format, media) = match format {
        ImageFormat::Tiff => (ImageFormat::Tiff, "image/tiff"),
        ImageFormat::Jpeg => (ImageFormat::Jpeg, "image/jpeg"),
        _ => (ImageFormat::Png, "image/png"),
    };
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, format).map_err(internal)?;
    Ok((out.into_inner(), media))
}

/// Blurred | deblurred side by side, 8-bit RGB, scaled down to [`PREVIEW_WIDTH`].
fn preview(before: &DynamicImage, after: &DynamicImage) -> Result<Vec<u8>, JobError> {
    let (w, h) = (before.width(), before.height());
    let mut canvas = image::RgbImage::new(2 * w + 8, h);
    for p in canvas.pixels_mut() {
        *p = image::Rgb([255, 255, 255]);
    }
    image::imageops::replace(&mut canvas, &before.to_rgb8(), 0, 0);
    image::imageops::replace(&mut canvas, &after.to_rgb8(), i64::from(w) + 8, 0);
    let canvas = DynamicImage::ImageRgb8(canvas);
    let canvas = if canvas.width() > PREVIEW_WIDTH {
        let nh = (u64::from(canvas.height()) * u64::from(PREVIEW_WIDTH) / u64::from(canvas.width()))
            .max(1) as u32;
        canvas.resize_exact(PREVIEW_WIDTH, nh, image::imageops::FilterType::Triangle)
    } else {
        canvas
    };
    let mut out = Cursor::new(Vec::new());
    canvas
        .write_to(&mut out, ImageFormat::Png)
        .map_err(internal)?;
    Ok(out.into_inner())
}

impl Kind for Deblur {
    const NAME: &'static str = "deblur";
    const SCHEMA: &'static str = "caliper.deblur/v1";
    const DATASET: DatasetKind = DatasetKind::Images;
    const ALSO_VIDEO: bool = true;
    const DESCRIPTION: &'static str = "Deblur images or chosen frames of a clip: Wiener, Richardson-Lucy or TV with a known kernel, blind kernel estimation (L0 prior, coarse to fine), or a kernel drawn from a gyro trace; same format and bit depth out, with the kernel.";
    type Params = DeblurParams;
    type Cli = DeblurArgs;

    fn check(p: &mut DeblurParams) -> Result<(), ParamError> {
        p.validate().map_err(|e| ParamError::from_core("", e))?;
        // One spelling of the IMU dataset's id, so equal requests hash alike.
        if let Some(g) = p.gyro_clip.as_mut()
            && let Some(id) = g.imu_dataset.as_mut()
        {
            *id = uuid::Uuid::parse_str(id)
                .map_err(|e| ParamError::new("gyro_clip.imu_dataset", format!("not a UUID: {e}")))?
                .to_string();
        }
        // Store the kernel normalised (sum 1), so the job and its document use the same one.
        if let Some(k) = p.psf.take() {
            p.psf = Some(
                caliper_core::deconv::Psf::from_weights(k.width, k.height, k.data)
                    .map_err(|e| ParamError::new("psf", e.to_string()))?,
            );
        }
        Ok(())
    }

    fn cli_params(a: &DeblurArgs, _: &CliContext<'_>) -> Result<Value, RunError> {
        params_from_flags(a)
    }

    fn aux_dataset(p: &DeblurParams) -> Result<Option<AuxDataset>, ParamError> {
        let Some(g) = &p.gyro_clip else {
            return Ok(None);
        };
        const FIELD: &str = "params.gyro_clip.imu_dataset";
        let id = g.imu_dataset.as_deref().ok_or_else(|| {
            ParamError::new(
                "gyro_clip.imu_dataset",
                "name the imu_log dataset holding the device's gyro log",
            )
        })?;
        let id = uuid::Uuid::parse_str(id)
            .map_err(|e| ParamError::new("gyro_clip.imu_dataset", format!("not a UUID: {e}")))?;
        Ok(Some(AuxDataset {
            field: FIELD,
            id,
            kind: DatasetKind::ImuLog,
        }))
    }

    fn cli_aux_file(a: &DeblurArgs, params: &Value) -> Option<PathBuf> {
        params.get("gyro_clip").and(a.gyro.clone())
    }

    fn run(
        &self,
        p: DeblurParams,
        input: &JobInput,
        progress: &dyn Progress,
    ) -> Result<JobOutput, JobError> {
        let clip = super::spool::single_clip(input);
        match (clip, &p.frames) {
            (Some(f), Some(pick)) => return clip::deblur_clip(&p, pick, input, f, progress),
            (Some(_), None) => {
                return Err(permanent(
                    "a video dataset needs params.frames: {\"every\": N}, {\"times\": [s, …]} \
                     or \"blurred\""
                        .into(),
                ));
            }
            (None, Some(_)) => {
                return Err(permanent(
                    "params.frames is for video datasets; this one holds images".into(),
                ));
            }
            (None, None) => {}
        }
        let mut artifacts = Vec::new();
        let mut images = Vec::new();
        let total = input.files.len() as u64;
        let mut seen = std::collections::HashSet::new();
        for (i, f) in input.files.iter().enumerate() {
            progress.check()?;
            progress.report("deblur", i as u64, total);
            let out_name = unique_name(base_name(&f.name), &mut seen);
            let bytes = (input.load)(f).map_err(|e| {
                JobError::Transient(format!("storage: cannot read {}: {e}", f.name))
            })?;
            let (img, format) = decode_keep_format(&bytes, &f.name)?;
            let mut entry = restore(
                &img,
                format,
                &f.name,
                &p,
                &out_name,
                &mut artifacts,
                progress,
            )?;
            entry["file"] = json!(f.name);
            images.push(entry);
        }
        progress.report("deblur", total, total);
        let quality = quality(&images, &p);
        Ok(JobOutput {
            parameters: json!({"method": p.method, "images": images}),
            quality,
            artifacts,
        })
    }
}

/// The document's `quality`: how many images, the method, and for `blind` how many kernels
/// came out uncertain (the two candidate kernels disagree, see `kernel.agreement`).
pub(crate) fn quality(images: &[Value], p: &DeblurParams) -> Value {
    let mut q = json!({"images": images.len(), "method": p.method});
    if images
        .iter()
        .any(|e| e["kernel"].get("uncertain").is_some())
    {
        let uncertain = images
            .iter()
            .filter(|e| e["kernel"]["uncertain"] == json!(true))
            .count();
        q["uncertain_kernels"] = json!(uncertain);
    }
    q
}

/// Deblurs one picture, pushing its artifacts (`out_name`, kernel PNG and JSON, preview);
/// returns its entry in the document. `label` names it in errors.
pub(crate) fn restore(
    img: &DynamicImage,
    format: ImageFormat,
    label: &str,
    p: &DeblurParams,
    out_name: &str,
    artifacts: &mut Vec<Artifact>,
    progress: &dyn Progress,
) -> Result<Value, JobError> {
    let out = deblur_image(img, p, progress).map_err(|e| match e {
        caliper_core::CoreError::InvalidInput(m) => permanent(format!("{label}: {m}")),
        other => other.into(),
    })?;
    let (data, media) = encode(&out.image, format)?;
    artifacts.push(Artifact {
        name: out_name.to_string(),
        media_type: media.into(),
        data: data.into(),
    });
    let s = stem(out_name);
    artifacts.push(Artifact {
        name: format!("{s}.kernel.png"),
        media_type: "image/png".into(),
        data: psf_png(&out.psf)?.into(),
    });
    artifacts.push(Artifact {
        name: format!("{s}.kernel.json"),
        media_type: "application/json".into(),
        data: out.psf.to_json().to_string().into_bytes().into(),
    });
    artifacts.push(Artifact {
        name: format!("{s}.preview.png"),
        media_type: "image/png".into(),
        data: preview(img, &out.image)?.into(),
    });
    let mut kernel = json!({
        "width": out.psf.width,
        "height": out.psf.height,
        "artifact_png": format!("{s}.kernel.png"),
        "artifact_json": format!("{s}.kernel.json"),
    });
    if let Some(t) = out.kernel_threshold {
        // Which of the blind estimates was kept (or the one asked for).
        kernel["cleaning_threshold"] = json!(t);
    }
    if let Some(r) = out.kernel_region {
        // The part of the photo the kernel was estimated on (`kernel_region`).
        kernel["region"] = json!({"x": r.x, "y": r.y, "width": r.width, "height": r.height});
    }
    if let (Some(a), Some(below)) = (out.kernel_agreement, out.kernel_uncertain_below) {
        // The two blind candidates disagree more than this photo's noise explains: the kernel
        // (and so the restoration) is doubtful.
        kernel["agreement"] = json!(a);
        kernel["uncertain_below"] = json!(below);
        kernel["uncertain"] = json!(a < below);
    }
    Ok(json!({
        "artifact": out_name,
        "width": img.width(),
        "height": img.height(),
        "color": format!("{:?}", img.color()),
        "kernel": kernel,
    }))
}

/// Archive entries may share a base name (`a/x.png`, `b/x.png`): number the later ones.
fn unique_name(name: &str, seen: &mut std::collections::HashSet<String>) -> String {
    if seen.insert(name.to_string()) {
        return name.to_string();
    }
    let (s, ext) = name.rsplit_once('.').unwrap_or((name, ""));
    for k in 2.. {
        let candidate = if ext.is_empty() {
            format!("{s}-{k}")
        } else {
            format!("{s}-{k}.{ext}")
        };
        if seen.insert(candidate.clone()) {
            return candidate;
        }
    }
    name.to_string()
}

/// Flags of `caliper run deblur`.
#[derive(Debug, Clone, Args)]
pub struct DeblurArgs {
    /// wiener, richardson_lucy, tv, blind, blind_rl or gyro [default: tv].
    #[arg(long)]
    pub method: Option<String>,
    /// Kernel file: a text matrix (as `numpy.savetxt` writes), JSON ({width, height, data}) or
    /// a grey PNG.
    #[arg(long)]
    pub psf: Option<PathBuf>,
    /// Iterations (RL, TV, alternating RL).
    #[arg(long)]
    pub iterations: Option<usize>,
    /// Wiener noise-to-signal ratio [default: estimated].
    #[arg(long)]
    pub nsr: Option<f64>,
    /// TV weight [default: from the estimated noise].
    #[arg(long)]
    pub tv_lambda: Option<f64>,
    /// Kernel side for the blind methods (odd).
    #[arg(long)]
    pub kernel_size: Option<usize>,
    /// For `--method blind`: kernel entries below this fraction of the peak are dropped
    /// (0.01–0.5) [default: both 0.1 and 0.05 tried, the blindly better kept].
    #[arg(long)]
    pub kernel_threshold: Option<f64>,
    /// For `--method blind`: side (px) of the region of a larger photo the kernel is
    /// estimated on (128–16384; at least 16 kernel windows) [default: 2048].
    #[arg(long)]
    pub kernel_region: Option<usize>,
    /// Level (0.5–1) at and above which pixels count as clipped highlights, or `off`
    /// [default: 0.99].
    #[arg(long, value_parser = parse_saturation)]
    pub saturation: Option<Value>,
    /// Gyro trace for `--method gyro`: JSON with `samples` [{t, w: [x, y, z]}],
    /// `exposure_start_s`, `exposure_s` and (unless `--camera` gives them) fx, fy, cx, cy; or an
    /// IMU log (`.csv` / `.csv.gz`, the `imu-noise` formats: ns timestamps, gyro in rad/s),
    /// which then needs `--exposure-start-ns`, `--exposure-ms` and `--camera`.
    #[arg(long)]
    pub gyro: Option<PathBuf>,
    /// With an IMU log as `--gyro`: start of the exposure on the log's clock, ns.
    #[arg(long)]
    pub exposure_start_ns: Option<i64>,
    /// With an IMU log as `--gyro` and a clip as input: log-clock time at which the exposure
    /// of the frame shown at 0 s starts, ns (each frame then gets its own kernel).
    #[arg(long)]
    pub clip_start_ns: Option<i64>,
    /// With an IMU log as `--gyro`: exposure time, ms.
    #[arg(long)]
    pub exposure_ms: Option<f64>,
    /// For a clip: which frames to restore: `every:N`, `times:T1,T2,…` (seconds) or
    /// `blurred` (the frames the blur verdict flags).
    #[arg(long, value_parser = parse_frames)]
    pub frames: Option<caliper_core::deconv::FramePick>,
    /// A `caliper.camera/v1` document whose intrinsics complete `--gyro`.
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// With `--gyro`: restore on a grid of NXxNY cells, each with the kernel drawn at its
    /// centre (blur that varies across the frame), e.g. `8x8`.
    #[arg(long, value_parser = parse_grid)]
    pub gyro_grid: Option<[usize; 2]>,
}

/// `every:N`, `times:T1,T2,…` or `blurred` → a frame choice.
fn parse_frames(s: &str) -> Result<caliper_core::deconv::FramePick, String> {
    use caliper_core::deconv::FramePick;
    let bad = || format!("{s:?}: expected every:N, times:T1,T2,… or blurred");
    match s.split_once(':') {
        None if s == "blurred" => Ok(FramePick::Blurred),
        Some(("every", n)) => n.trim().parse().map(FramePick::Every).map_err(|_| bad()),
        Some(("times", t)) => t
            .split(',')
            .map(|v| v.trim().parse::<f64>().map_err(|_| bad()))
            .collect::<Result<Vec<_>, _>>()
            .map(FramePick::Times),
        _ => Err(bad()),
    }
}

/// `off` → `null` (every pixel linear), else the level as a number (range-checked with the
/// other parameters).
fn parse_saturation(s: &str) -> Result<Value, String> {
    if s.eq_ignore_ascii_case("off") {
        return Ok(Value::Null);
    }
    s.trim()
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .map(|v| json!(v))
        .ok_or_else(|| format!("{s:?}: expected a level such as 0.99, or off"))
}

/// `NXxNY` → `[nx, ny]`.
fn parse_grid(s: &str) -> Result<[usize; 2], String> {
    let (a, b) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("{s:?}: expected NXxNY, e.g. 8x8"))?;
    let n = |v: &str| {
        v.trim()
            .parse::<usize>()
            .map_err(|_| format!("{s:?}: {v:?} is not a cell count"))
    };
    Ok([n(a)?, n(b)?])
}

/// The parameters object of `caliper run deblur`'s flags (kernel and trace files read here).
fn params_from_flags(a: &DeblurArgs) -> Result<Value, RunError> {
    use caliper_core::deconv::Psf;
    let mut params = json!({});
    if let Some(m) = &a.method {
        params["method"] = json!(m);
    }
    if let Some(path) = &a.psf {
        let bytes = std::fs::read(path)?;
        let bad = |e: caliper_core::CoreError| RunError::Input(format!("{}: {e}", path.display()));
        let head = &bytes[..bytes.len().min(64)];
        let psf = if caliper_core::io::sniff(head).is_image() {
            let limits = caliper_core::io::ImageLimits::default();
            let g = caliper_core::io::decode_gray8(&bytes, &limits).map_err(bad)?;
            Psf::from_gray(&g).map_err(bad)?
        } else {
            let text = String::from_utf8(bytes)
                .map_err(|_| RunError::Input(format!("{} is not text", path.display())))?;
            if text.trim_start().starts_with('{') {
                // `{width, height, data}` (the API's form) or `{kernel: [[…]]}`.
                match serde_json::from_str::<Psf>(&text) {
                    Ok(k) => Psf::from_weights(k.width, k.height, k.data).map_err(bad)?,
                    Err(_) => Psf::parse_json(&text).map_err(bad)?,
                }
            } else {
                Psf::parse_text(&text).map_err(bad)?
            }
        };
        params["psf"] = serde_json::to_value(&psf).map_err(|e| RunError::Job(e.to_string()))?;
    }
    for (key, v) in [
        ("iterations", a.iterations.map(|v| json!(v))),
        ("nsr", a.nsr.map(|v| json!(v))),
        ("tv_lambda", a.tv_lambda.map(|v| json!(v))),
        ("kernel_size", a.kernel_size.map(|v| json!(v))),
        ("kernel_threshold", a.kernel_threshold.map(|v| json!(v))),
        ("kernel_region", a.kernel_region.map(|v| json!(v))),
        ("saturation", a.saturation.clone()),
        ("gyro_grid", a.gyro_grid.map(|v| json!(v))),
    ] {
        if let Some(v) = v {
            params[key] = v;
        }
    }
    if let Some(f) = &a.frames {
        params["frames"] = serde_json::to_value(f).map_err(|e| RunError::Job(e.to_string()))?;
    }
    if let Some(path) = &a.gyro {
        let name = path.to_string_lossy().to_ascii_lowercase();
        let is_log = name.ends_with(".csv") || name.ends_with(".csv.gz");
        if let Some(start) = a.clip_start_ns {
            // A clip: the log is read by the job (as the service reads the IMU dataset).
            let (true, Some(cam), Some(ms)) = (is_log, &a.camera, a.exposure_ms) else {
                return Err(RunError::Input(
                    "--clip-start-ns needs an IMU log as --gyro, --camera and --exposure-ms".into(),
                ));
            };
            let mut g = json!({"clip_start_ns": start, "exposure_s": ms * 1e-3});
            copy_intrinsics(cam, &mut g)?;
            params["gyro_clip"] = g;
            return Ok(params);
        }
        let mut g: Value = if is_log {
            if a.camera.is_none() {
                return Err(RunError::Input(
                    "an IMU log as --gyro needs --camera for the intrinsics".into(),
                ));
            }
            let (Some(start), Some(ms)) = (a.exposure_start_ns, a.exposure_ms) else {
                return Err(RunError::Input(
                    "an IMU log as --gyro needs --exposure-start-ns and --exposure-ms".into(),
                ));
            };
            gyro_from_log(path, start, ms * 1e-3)?
        } else {
            let text = std::fs::read_to_string(path)?;
            serde_json::from_str(&text)
                .map_err(|e| RunError::Input(format!("{} is not JSON: {e}", path.display())))?
        };
        if let Some(cam) = &a.camera {
            copy_intrinsics(cam, &mut g)?;
        }
        params["gyro"] = g;
    }
    Ok(params)
}

/// Copy fx, fy, cx, cy of the `caliper.camera/v1` document at `cam` into `g`.
fn copy_intrinsics(cam: &Path, g: &mut Value) -> Result<(), RunError> {
    let text = std::fs::read_to_string(cam)?;
    let doc: Value = serde_json::from_str(&text)
        .map_err(|e| RunError::Input(format!("{} is not JSON: {e}", cam.display())))?;
    let intr = doc
        .pointer("/parameters/camera")
        .or_else(|| doc.get("camera"))
        .ok_or_else(|| {
            RunError::Input(format!(
                "{} is not a caliper.camera/v1 document (no parameters.camera)",
                cam.display()
            ))
        })?;
    for k in ["fx", "fy", "cx", "cy"] {
        let v = intr
            .get(k)
            .cloned()
            .ok_or_else(|| RunError::Input(format!("{}: the camera has no {k}", cam.display())))?;
        g[k] = v;
    }
    Ok(())
}

/// The gyro trace of an IMU log file (CSV or gzip) over one exposure, as the `gyro` object.
fn gyro_from_log(path: &Path, start_ns: i64, exposure_s: f64) -> Result<Value, RunError> {
    let mut f = std::fs::File::open(path)?;
    let mut head = [0u8; 2];
    let n = std::io::Read::read(&mut f, &mut head)?;
    let f = std::fs::File::open(path)?;
    let reader: Box<dyn std::io::BufRead> = if n == 2 && head == [0x1f, 0x8b] {
        Box::new(std::io::BufReader::new(flate2::read::MultiGzDecoder::new(
            f,
        )))
    } else {
        Box::new(std::io::BufReader::new(f))
    };
    let samples = caliper_core::deconv::gyro_trace_from_log(
        reader,
        start_ns,
        exposure_s,
        &caliper_core::NoProgress,
    )
    .map_err(|e| RunError::Input(format!("{}: {e}", path.display())))?;
    Ok(json!({"samples": samples, "exposure_start_s": 0.0, "exposure_s": exposure_s}))
}
