//! `caliper run <kind>`: run a job kind on local files, without a server, and print the
//! document the service would store (same core code, same validation, same document builder).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use clap::{Args, Subcommand};
use serde_json::{Value, json};

use crate::jobs::{JobInput, JobKind, document, find_kind};
use crate::store::DatasetFile;

/// Job kinds runnable offline.
#[derive(Debug, Subcommand)]
pub enum RunCommand {
    /// Score images for blur (Laplacian variance, singular-value feature) and rank them.
    BlurScore(BlurScoreArgs),
    /// Calibrate a camera from chessboard images.
    CameraCalibration(CameraCalibrationArgs),
    /// Allan deviation and noise model of a static IMU log (CSV or .csv.gz).
    ImuNoise(ImuArgs),
    /// Multi-position accelerometer and gyroscope calibration of an IMU log.
    ImuIntrinsics(ImuArgs),
    /// Bias against temperature of an IMU log with a temperature column.
    ImuThermal(ImuArgs),
    /// Deblur images; with `--out DIR` writes `DIR/NAME` (same format) and the kernel.
    Deblur(DeblurArgs),
    /// Camera response from a bracketed stack (exposure times from `--times` or `--exposures`).
    PhotometricResponse(PhotometricResponseArgs),
    /// Vignetting from flat-field images.
    Vignetting(PhotometricArgs),
    /// Response, vignetting and exposures of an auto-exposure image sequence; with `--out DIR`
    /// writes DSO's `pcalib.txt`, `vignette.png` and `times.txt`.
    PhotometricOnline(PhotometricArgs),
    /// Apply a photometric model (a photometric document) to images.
    PhotometricCorrect(PhotometricCorrectArgs),
}

/// Flags of `caliper run deblur`.
#[derive(Debug, Args)]
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
    /// Gyro trace for `--method gyro`: JSON with `samples` [{t, w: [x, y, z]}],
    /// `exposure_start_s`, `exposure_s` and (unless `--camera` gives them) fx, fy, cx, cy; or an
    /// IMU log (`.csv` / `.csv.gz`, the `imu-noise` formats: ns timestamps, gyro in rad/s),
    /// which then needs `--exposure-start-ns`, `--exposure-ms` and `--camera`.
    #[arg(long)]
    pub gyro: Option<PathBuf>,
    /// With an IMU log as `--gyro`: start of the exposure on the log's clock, ns.
    #[arg(long)]
    pub exposure_start_ns: Option<i64>,
    /// With an IMU log as `--gyro`: exposure time, ms.
    #[arg(long)]
    pub exposure_ms: Option<f64>,
    /// A `caliper.camera/v1` document whose intrinsics complete `--gyro`.
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// With `--gyro`: restore on a grid of NXxNY cells, each with the kernel drawn at its
    /// centre (blur that varies across the frame), e.g. `8x8`.
    #[arg(long, value_parser = parse_grid)]
    pub gyro_grid: Option<[usize; 2]>,
    #[command(flatten)]
    pub common: CommonArgs,
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

/// Flags of `caliper run vignetting` and `photometric-online`.
#[derive(Debug, Args)]
pub struct PhotometricArgs {
    /// Parameters as JSON (see `GET /v1/job-kinds`), e.g. '{"options": {"fit_center": true}}'.
    #[arg(long)]
    pub params: Option<String>,
    #[command(flatten)]
    pub common: CommonArgs,
}

/// Flags of `caliper run photometric-response`.
#[derive(Debug, Args)]
pub struct PhotometricResponseArgs {
    /// A `times.txt` (`id timestamp exposure` per line, ids = image file stems, or in image
    /// order when the ids do not match).
    #[arg(long)]
    pub times: Option<PathBuf>,
    /// Exposure times in natural file-name order, comma-separated.
    #[arg(long, value_delimiter = ',')]
    pub exposures: Option<Vec<f64>>,
    /// Fit options as JSON (`ResponseParams`).
    #[arg(long)]
    pub options: Option<String>,
    #[command(flatten)]
    pub common: CommonArgs,
}

/// Flags of `caliper run photometric-correct`.
#[derive(Debug, Args)]
pub struct PhotometricCorrectArgs {
    /// A photometric document (or its `parameters.model` object) as JSON.
    #[arg(long)]
    pub model: PathBuf,
    /// Output gain [default: 1].
    #[arg(long)]
    pub gain: Option<f64>,
    #[command(flatten)]
    pub common: CommonArgs,
}

/// Flags of the `imu-*` commands.
#[derive(Debug, Args)]
pub struct ImuArgs {
    /// Parameters as JSON (see `GET /v1/job-kinds` for the schema), e.g. '{"rate_hz": 200}'.
    #[arg(long)]
    pub params: Option<String>,
    /// Print this export instead of the document (`imu-noise`: kalibr-yaml).
    #[arg(long)]
    pub export: Option<String>,
    #[command(flatten)]
    pub common: CommonArgs,
}

/// Flags of `caliper run camera-calibration`.
#[derive(Debug, Args)]
pub struct CameraCalibrationArgs {
    /// Inner corners, COLSxROWS (e.g. 9x6).
    #[arg(long)]
    pub board: String,
    /// Square side, in `--unit`.
    #[arg(long)]
    pub square: f64,
    /// Unit of `--square`: m, cm, mm, in, squares [default: m].
    #[arg(long)]
    pub unit: Option<String>,
    /// pinhole_radtan, kannala_brandt or double_sphere [default: pinhole_radtan].
    #[arg(long)]
    pub model: Option<String>,
    /// Calibration options as JSON (see the `CalibOptions` schema), e.g. '{"fix_k3": true}'.
    #[arg(long)]
    pub options: Option<String>,
    /// Print this export instead of the document: opencv-yaml, ros-yaml, kalibr-yaml, json.
    #[arg(long)]
    pub export: Option<String>,
    #[command(flatten)]
    pub common: CommonArgs,
}

/// Flags of `caliper run blur-score`.
#[derive(Debug, Args)]
pub struct BlurScoreArgs {
    /// Singular values in the numerator of β [default: 10].
    #[arg(long)]
    pub k: Option<usize>,
    /// Blurred if the Laplacian variance is below this [default: 100].
    #[arg(long)]
    pub laplacian_threshold: Option<f64>,
    /// Blurred if β is above this [default: 0.6].
    #[arg(long)]
    pub beta_threshold: Option<f64>,
    /// How the two verdicts combine: either, both, laplacian, beta [default: either].
    #[arg(long)]
    pub rule: Option<String>,
    #[command(flatten)]
    pub common: CommonArgs,
}

/// Flags shared by every offline kind.
#[derive(Debug, Args)]
pub struct CommonArgs {
    /// Write artifacts (plots) into this directory.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Pretty-print the document (default: canonical JSON, byte-identical to the service's).
    #[arg(long)]
    pub pretty: bool,
    /// Input files (directories are expanded to their files, sorted by name).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
}

/// An offline run failure, printed to stderr.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("{0}")]
    Input(String),
    #[error("{0}")]
    Job(String),
    #[error("i/o: {0}")]
    Io(#[from] std::io::Error),
}

/// Files named on the command line, plus the files of named directories (flagged `true`:
/// non-images among those are skipped rather than refused).
fn expand(inputs: &[PathBuf]) -> Result<Vec<(PathBuf, bool)>, RunError> {
    let mut out = Vec::new();
    for p in inputs {
        if p.is_dir() {
            let mut entries: Vec<PathBuf> = std::fs::read_dir(p)?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.is_file())
                .collect();
            entries.sort();
            out.extend(entries.into_iter().map(|e| (e, true)));
        } else if p.is_file() {
            out.push((p.clone(), false));
        } else {
            return Err(RunError::Input(format!("{} does not exist", p.display())));
        }
    }
    if out.is_empty() {
        return Err(RunError::Input("no input files".into()));
    }
    Ok(out)
}

/// Describe local image files as a dataset would (hash, size, validated header).
fn image_files(paths: &[(PathBuf, bool)]) -> Result<Vec<(DatasetFile, PathBuf)>, RunError> {
    let limits = crate::config::Config::default().image_limits();
    let mut files = Vec::new();
    let mut names = std::collections::HashSet::new();
    for (p, from_dir) in paths {
        let bytes = std::fs::read(p)?;
        if *from_dir && !crate::ingest::sniff::sniff(&bytes[..bytes.len().min(64)]).is_image() {
            eprintln!("caliper: skipping {} (not an image)", p.display());
            continue;
        }
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| p.display().to_string());
        if !names.insert(name.clone()) {
            return Err(RunError::Input(format!("two inputs are named {name:?}")));
        }
        let info = caliper_core::io::probe_image(std::io::Cursor::new(&bytes), &limits)
            .map_err(|e| RunError::Input(format!("{}: {e}", p.display())))?;
        files.push((
            DatasetFile {
                name,
                sha256: crate::document::sha256_hex(&bytes),
                size: bytes.len() as u64,
                media_type: format!("image/{}", info.format),
                image: Some(info),
            },
            p.clone(),
        ));
    }
    Ok(files)
}

/// Run a command; returns the document text to print.
pub fn run(cmd: RunCommand) -> Result<String, RunError> {
    match cmd {
        RunCommand::BlurScore(a) => {
            let mut params = serde_json::Map::new();
            if let Some(k) = a.k {
                params.insert("k".into(), json!(k));
            }
            if let Some(t) = a.laplacian_threshold {
                params.insert("laplacian_threshold".into(), json!(t));
            }
            if let Some(t) = a.beta_threshold {
                params.insert("beta_threshold".into(), json!(t));
            }
            if let Some(r) = &a.rule {
                params.insert("rule".into(), json!(r));
            }
            run_kind("blur_score", Value::Object(params), &a.common)
        }
        RunCommand::ImuNoise(a) => run_imu("imu_noise", &a),
        RunCommand::ImuIntrinsics(a) => run_imu("imu_intrinsics", &a),
        RunCommand::ImuThermal(a) => run_imu("imu_thermal", &a),
        RunCommand::Deblur(a) => run_deblur(&a),
        RunCommand::PhotometricResponse(a) => run_photometric_response(&a),
        RunCommand::Vignetting(a) => run_with_params("vignetting", a.params.as_deref(), &a.common),
        RunCommand::PhotometricOnline(a) => {
            run_with_params("photometric_online", a.params.as_deref(), &a.common)
        }
        RunCommand::PhotometricCorrect(a) => {
            let text = std::fs::read_to_string(&a.model)?;
            let v: Value = serde_json::from_str(&text)
                .map_err(|e| RunError::Input(format!("{} is not JSON: {e}", a.model.display())))?;
            // A whole document, or just its model.
            let model = v.pointer("/parameters/model").cloned().unwrap_or(v);
            let mut params = json!({"model": model});
            if let Some(g) = a.gain {
                params["gain"] = json!(g);
            }
            run_kind("photometric_correct", params, &a.common)
        }
        RunCommand::CameraCalibration(a) => {
            let (cols, rows) = a
                .board
                .split_once(['x', 'X'])
                .and_then(|(c, r)| {
                    Some((
                        c.trim().parse::<usize>().ok()?,
                        r.trim().parse::<usize>().ok()?,
                    ))
                })
                .ok_or_else(|| {
                    RunError::Input(format!("--board must be COLSxROWS, got {:?}", a.board))
                })?;
            let mut params = json!({"board": {"cols": cols, "rows": rows, "square": a.square}});
            if let Some(u) = &a.unit {
                params["board"]["unit"] = json!(u);
            }
            if let Some(m) = &a.model {
                params["model"] = json!(m);
            }
            if let Some(o) = &a.options {
                params["options"] = serde_json::from_str(o)
                    .map_err(|e| RunError::Input(format!("--options is not JSON: {e}")))?;
            }
            let doc = run_kind("camera_calibration", params, &a.common)?;
            match &a.export {
                None => Ok(doc),
                Some(f) => {
                    let v: Value =
                        serde_json::from_str(&doc).map_err(|e| RunError::Job(e.to_string()))?;
                    crate::exports::render(&v, f)
                        .map(|r| r.body)
                        .map_err(|e| RunError::Input(e.detail.unwrap_or_default()))
                }
            }
        }
    }
}

fn run_with_params(
    kind: &str,
    params: Option<&str>,
    common: &CommonArgs,
) -> Result<String, RunError> {
    let params = match params {
        Some(p) => serde_json::from_str(p)
            .map_err(|e| RunError::Input(format!("--params is not JSON: {e}")))?,
        None => json!({}),
    };
    run_kind(kind, params, common)
}

fn run_photometric_response(a: &PhotometricResponseArgs) -> Result<String, RunError> {
    let times = match (&a.times, &a.exposures) {
        (Some(_), Some(_)) => {
            return Err(RunError::Input(
                "give --times or --exposures, not both".into(),
            ));
        }
        (None, None) => {
            return Err(RunError::Input(
                "photometric-response needs exposure times: --times FILE or --exposures a,b,c"
                    .into(),
            ));
        }
        (None, Some(e)) => json!(e),
        (Some(path), None) => {
            let text = std::fs::read_to_string(path)?;
            let entries = caliper_core::photometric::dso::read_times(&text)
                .map_err(|e| RunError::Input(format!("{}: {e}", path.display())))?;
            // Ids that name the images map by name; otherwise the order is the image order.
            let images: Vec<String> = expand(&a.common.inputs)?
                .iter()
                .filter_map(|(p, _)| p.file_name().map(|n| n.to_string_lossy().into_owned()))
                .collect();
            let stems: std::collections::HashMap<String, String> = images
                .iter()
                .map(|n| {
                    (
                        n.rsplit_once('.').map_or(n.as_str(), |x| x.0).to_string(),
                        n.clone(),
                    )
                })
                .collect();
            if entries.iter().all(|e| stems.contains_key(&e.id)) {
                let map: serde_json::Map<String, Value> = entries
                    .iter()
                    .filter_map(|e| stems.get(&e.id).map(|n| (n.clone(), json!(e.exposure_ms))))
                    .collect();
                Value::Object(map)
            } else {
                json!(entries.iter().map(|e| e.exposure_ms).collect::<Vec<_>>())
            }
        }
    };
    let mut params = json!({"exposure_times": times});
    if let Some(o) = &a.options {
        params["options"] = serde_json::from_str(o)
            .map_err(|e| RunError::Input(format!("--options is not JSON: {e}")))?;
    }
    run_kind("photometric_response", params, &a.common)
}

fn run_deblur(a: &DeblurArgs) -> Result<String, RunError> {
    use caliper_core::deconv::Psf;
    let mut params = json!({});
    if let Some(m) = &a.method {
        params["method"] = json!(m);
    }
    if let Some(path) = &a.psf {
        let bytes = std::fs::read(path)?;
        let bad = |e: caliper_core::CoreError| RunError::Input(format!("{}: {e}", path.display()));
        let head = &bytes[..bytes.len().min(64)];
        let psf = if crate::ingest::sniff::sniff(head).is_image() {
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
        ("gyro_grid", a.gyro_grid.map(|v| json!(v))),
    ] {
        if let Some(v) = v {
            params[key] = v;
        }
    }
    if let Some(path) = &a.gyro {
        let name = path.to_string_lossy().to_ascii_lowercase();
        let mut g: Value = if name.ends_with(".csv") || name.ends_with(".csv.gz") {
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
                let v = intr.get(k).cloned().ok_or_else(|| {
                    RunError::Input(format!("{}: the camera has no {k}", cam.display()))
                })?;
                g[k] = v;
            }
        }
        params["gyro"] = g;
    }
    run_kind("deblur", params, &a.common)
}

/// The gyro samples of an IMU log over one exposure (`start_ns` on the log's clock, plus
/// `exposure_s`), with one sample either side so the trace spans it, as a gyro trace whose
/// times count from the exposure start.
fn gyro_from_log(path: &Path, start_ns: i64, exposure_s: f64) -> Result<Value, RunError> {
    use caliper_core::imu::{ImuCsvParams, read_imu_log};
    if !(exposure_s.is_finite() && exposure_s > 0.0) {
        return Err(RunError::Input("--exposure-ms must be > 0".into()));
    }
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
    let log = read_imu_log(reader, &ImuCsvParams::default(), &caliper_core::NoProgress)
        .map_err(|e| RunError::Input(format!("{}: {e}", path.display())))?;
    let t = log.times_s();
    let a = (start_ns - log.t0_ns()) as f64 * 1e-9;
    let b = a + exposure_s;
    let (t_first, t_last) = (t[0], t[t.len() - 1]);
    if a < t_first || b > t_last {
        return Err(RunError::Input(format!(
            "{}: the log covers {t_first:.6}–{t_last:.6} s from its first sample, the exposure \
             needs {a:.6}–{b:.6} s",
            path.display()
        )));
    }
    let first = t.partition_point(|&x| x < a).saturating_sub(1);
    let end = (t.partition_point(|&x| x <= b) + 1).min(t.len());
    let samples: Vec<Value> = (first..end)
        .map(|i| json!({"t": t[i] - a, "w": [log.value(0, i), log.value(1, i), log.value(2, i)]}))
        .collect();
    Ok(json!({"samples": samples, "exposure_start_s": 0.0, "exposure_s": exposure_s}))
}

fn run_imu(kind: &str, a: &ImuArgs) -> Result<String, RunError> {
    let params = match &a.params {
        Some(p) => serde_json::from_str(p)
            .map_err(|e| RunError::Input(format!("--params is not JSON: {e}")))?,
        None => json!({}),
    };
    let doc = run_kind(kind, params, &a.common)?;
    match &a.export {
        None => Ok(doc),
        Some(f) => {
            let v: Value = serde_json::from_str(&doc).map_err(|e| RunError::Job(e.to_string()))?;
            crate::exports::render(&v, f)
                .map(|r| r.body)
                .map_err(|e| RunError::Input(e.detail.unwrap_or_default()))
        }
    }
}

/// Describe one log file as a dataset would (hash, size, media type from content).
fn log_file(paths: &[(PathBuf, bool)]) -> Result<Vec<(DatasetFile, PathBuf)>, RunError> {
    let [(p, _)] = paths else {
        return Err(RunError::Input(format!(
            "an IMU job reads exactly one log, got {} files",
            paths.len()
        )));
    };
    let mut f = std::fs::File::open(p)?;
    let mut head = [0u8; 64];
    let n = std::io::Read::read(&mut f, &mut head)?;
    let sniffed = crate::ingest::sniff::sniff(&head[..n]);
    let gzip = sniffed == crate::ingest::sniff::Sniffed::Gzip;
    if !gzip && sniffed != crate::ingest::sniff::Sniffed::Text {
        return Err(RunError::Input(format!(
            "{} is not a CSV or gzip file",
            p.display()
        )));
    }
    // Hash as a stream: logs can be hundreds of MB.
    let mut hasher = <sha2::Sha256 as sha2::Digest>::new();
    let mut file = std::fs::File::open(p)?;
    let size = std::io::copy(&mut file, &mut hasher)?;
    Ok(vec![(
        DatasetFile {
            name: p
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            sha256: hex::encode(sha2::Digest::finalize(hasher)),
            size,
            media_type: sniffed.media_type().to_string(),
            image: None,
        },
        p.clone(),
    )])
}

fn run_kind(kind_name: &str, params: Value, common: &CommonArgs) -> Result<String, RunError> {
    let kind: &dyn JobKind =
        find_kind(kind_name).ok_or_else(|| RunError::Job(format!("unknown kind {kind_name}")))?;
    let params = kind.normalize_params(&params).map_err(|e| {
        RunError::Input(format!(
            "{}: {}",
            e.field.unwrap_or_default(),
            e.detail.unwrap_or_default()
        ))
    })?;
    let paths = expand(&common.inputs)?;
    let described = match kind.dataset_kind() {
        crate::store::DatasetKind::Images => image_files(&paths)?,
        _ => log_file(&paths)?,
    };
    if described.is_empty() {
        return Err(RunError::Input("no images among the inputs".into()));
    }
    let by_sha: std::collections::HashMap<String, PathBuf> = described
        .iter()
        .map(|(f, p)| (f.sha256.clone(), p.clone()))
        .collect();
    let by_sha2 = by_sha.clone();
    let files: Vec<DatasetFile> = described.into_iter().map(|(f, _)| f).collect();
    let input = JobInput {
        files: files.clone(),
        params: params.clone(),
        load: Arc::new(move |f| {
            let p = by_sha
                .get(&f.sha256)
                .ok_or_else(|| std::io::Error::other("unknown file"))?;
            std::fs::read(p)
        }),
        open: Arc::new(move |f| {
            let p = by_sha2
                .get(&f.sha256)
                .ok_or_else(|| std::io::Error::other("unknown file"))?;
            Ok(Box::new(std::fs::File::open(p)?) as Box<dyn std::io::Read + Send>)
        }),
    };
    let output = kind
        .run(&input, &caliper_core::NoProgress)
        .map_err(|e| RunError::Job(e.to_string()))?;
    if let Some(dir) = &common.out {
        write_artifacts(dir, &output.artifacts)?;
    }
    let manifest = document::manifest_sha256(&files);
    let doc = document::build(
        kind,
        &output,
        &document::Provenance {
            job: None,
            dataset: None,
            dataset_sha256: Some(&manifest),
            files: &files,
            params: &params,
            device: None,
            sensor: None,
        },
        crate::clock::now_ms(),
    );
    let (body, _) = crate::document::seal(doc, None);
    if common.pretty {
        let v: Value = serde_json::from_str(&body).map_err(|e| RunError::Job(e.to_string()))?;
        Ok(serde_json::to_string_pretty(&v).unwrap_or(body))
    } else {
        Ok(body)
    }
}

fn write_artifacts(dir: &Path, artifacts: &[crate::jobs::Artifact]) -> Result<(), RunError> {
    std::fs::create_dir_all(dir)?;
    for a in artifacts {
        std::fs::write(dir.join(&a.name), &a.data)?;
    }
    Ok(())
}
