//! Job kinds and the worker pool.
//!
//! A job kind turns a dataset plus parameters into a parameter document. Kinds are plain
//! synchronous code over `caliper-core`; the worker pool runs them on blocking threads with
//! progress, cancellation and a time limit, and the offline CLI runs the very same code.

pub mod blur_score;
pub mod board_detection;
pub mod camera_calibration;
pub mod deblur;
mod debug;
pub mod document;
pub mod imu;
pub mod kind;
pub mod photometric;
pub mod rig_calibration;
mod spool;
pub mod worker;

use std::sync::Arc;

use bytes::Bytes;
use caliper_core::CoreError;
use serde_json::Value;

pub use kind::{
    AuxDataset, CliContext, Export, ExportError, JobKind, JsonParams, Kind, ParamError, Registered,
    RunError, parse_params,
};

use crate::store::DatasetFile;

/// Reads the bytes of a dataset file (from the blob store, or a local path offline).
pub type FileLoader = Arc<dyn Fn(&DatasetFile) -> std::io::Result<Vec<u8>> + Send + Sync>;

/// Opens a dataset file as a stream, for inputs too large to hold in memory (IMU logs).
pub type FileOpener =
    Arc<dyn Fn(&DatasetFile) -> std::io::Result<Box<dyn std::io::Read + Send>> + Send + Sync>;

/// Everything a job kind needs to run.
pub struct JobInput {
    pub files: Vec<DatasetFile>,
    /// The files of the second dataset the parameters name ([`AuxDataset`]), if any; read
    /// with the same `load` and `open`.
    pub aux_files: Vec<DatasetFile>,
    /// Parameters as normalised by [`JobKind::normalize_params`].
    pub params: Value,
    pub load: FileLoader,
    pub open: FileOpener,
}

/// A named output file of a job (plot, image, export).
#[derive(Debug, Clone)]
pub struct Artifact {
    pub name: String,
    pub media_type: String,
    pub data: Bytes,
}

impl Artifact {
    /// An SVG plot.
    pub fn svg(name: &str, text: String) -> Self {
        Self {
            name: name.into(),
            media_type: "image/svg+xml".into(),
            data: text.into_bytes().into(),
        }
    }
}

/// What a job kind produces: the document's `parameters` and `quality`, plus artifacts.
#[derive(Debug, Clone)]
pub struct JobOutput {
    pub parameters: Value,
    pub quality: Value,
    pub artifacts: Vec<Artifact>,
}

/// Why a job attempt did not produce output.
#[derive(Debug, thiserror::Error)]
pub enum JobError {
    /// Bad input or parameters: retrying cannot help.
    #[error("{code}: {message}")]
    Permanent { code: &'static str, message: String },
    /// Environment trouble (storage I/O): worth retrying.
    #[error("transient: {0}")]
    Transient(String),
    /// Stopped by a cancel flag (user, time limit, shutdown or lost lease).
    #[error("canceled")]
    Canceled,
}

impl From<CoreError> for JobError {
    fn from(e: CoreError) -> Self {
        match e {
            CoreError::Canceled => JobError::Canceled,
            CoreError::InvalidInput(m) => JobError::Permanent {
                code: "invalid_input",
                message: m,
            },
            CoreError::InvalidParam { field, message } => JobError::Permanent {
                code: "invalid_param",
                message: format!("{field}: {message}"),
            },
            CoreError::NoSolution(m) => JobError::Permanent {
                code: "no_solution",
                message: m,
            },
        }
    }
}

/// Every job kind this build knows: the one list that the router, the OpenAPI components,
/// `GET /v1/job-kinds`, `caliper run` and the export dispatch read.
pub fn kinds() -> &'static [&'static dyn JobKind] {
    static KINDS: &[&dyn JobKind] = &[
        &Registered(blur_score::BlurScore),
        &Registered(camera_calibration::CameraCalibration),
        &Registered(imu::ImuNoise),
        &Registered(imu::ImuIntrinsics),
        &Registered(imu::ImuThermal),
        &Registered(photometric::PhotometricResponse),
        &Registered(photometric::Vignetting),
        &Registered(photometric::PhotometricOnline),
        &Registered(photometric::PhotometricCorrect),
        &Registered(deblur::Deblur),
        &Registered(rig_calibration::RigCalibration),
        &Registered(board_detection::BoardDetection),
    ];
    KINDS
}

/// Find a kind by name.
pub fn find_kind(name: &str) -> Option<&'static dyn JobKind> {
    kinds().iter().copied().find(|k| k.name() == name)
}

/// Find a kind by name for this server: the public registry, plus the test-only kinds when
/// `config.debug_job_kinds` is set.
pub fn resolve_kind(config: &crate::config::Config, name: &str) -> Option<&'static dyn JobKind> {
    static DEBUG: &[&dyn JobKind] = &[&Registered(debug::DebugHang)];
    find_kind(name).or_else(|| {
        config
            .debug_job_kinds
            .then(|| DEBUG.iter().copied().find(|k| k.name() == name))
            .flatten()
    })
}

/// The export formats offered for documents of `schema`.
pub fn exports_for(schema: &str) -> &'static [Export] {
    kinds()
        .iter()
        .find(|k| k.schema() == schema)
        .map_or(&[], |k| k.exports())
}

/// Serialise a job result into the document's `parameters`.
pub fn to_value<T: serde::Serialize>(v: &T) -> Result<Value, JobError> {
    serde_json::to_value(v).map_err(|e| JobError::Permanent {
        code: "internal_error",
        message: e.to_string(),
    })
}

/// File name without the archive folders (`a/b/x.png` → `x.png`).
pub fn base_name(name: &str) -> &str {
    name.rsplit('/').next().unwrap_or(name)
}

/// Base name without its extension (`a/x.png` → `x`).
pub fn stem(name: &str) -> &str {
    let b = base_name(name);
    b.rsplit_once('.').map_or(b, |(s, _)| s)
}
