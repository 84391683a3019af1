//! Job kinds and the worker pool.
//!
//! A job kind turns a dataset plus parameters into a parameter document. Kinds are plain
//! synchronous code over `caliper-core`; the worker pool runs them on blocking threads with
//! progress, cancellation and a time limit, and the offline CLI runs the very same code.

pub mod blur_score;
pub mod camera_calibration;
pub mod deblur;
pub mod document;
pub mod imu;
pub mod photometric;
pub mod worker;

use std::sync::Arc;

use bytes::Bytes;
use caliper_core::{CoreError, Progress};
use serde_json::Value;

use crate::error::ApiError;
use crate::store::{DatasetFile, DatasetKind};

/// Reads the bytes of a dataset file (from the blob store, or a local path offline).
pub type FileLoader = Arc<dyn Fn(&DatasetFile) -> std::io::Result<Vec<u8>> + Send + Sync>;

/// Opens a dataset file as a stream, for inputs too large to hold in memory (IMU logs).
pub type FileOpener =
    Arc<dyn Fn(&DatasetFile) -> std::io::Result<Box<dyn std::io::Read + Send>> + Send + Sync>;

/// Everything a job kind needs to run.
pub struct JobInput {
    pub files: Vec<DatasetFile>,
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

/// One kind of job.
pub trait JobKind: Send + Sync + 'static {
    /// The kind's name in the API (`blur_score`).
    fn name(&self) -> &'static str;
    /// The document schema it writes (`caliper.blur_score/v1`).
    fn schema(&self) -> &'static str;
    /// What kind of dataset it reads.
    fn dataset_kind(&self) -> DatasetKind;
    /// One-line description for `GET /v1/job-kinds`.
    fn description(&self) -> &'static str;
    /// JSON Schema of the parameters.
    fn params_schema(&self) -> Value;
    /// Check parameters and fill in defaults; errors name the offending field.
    fn normalize_params(&self, params: &Value) -> Result<Value, ApiError>;
    /// Run on the input (blocking; call from a blocking thread).
    fn run(&self, input: &JobInput, progress: &dyn Progress) -> Result<JobOutput, JobError>;
}

/// Every job kind this build knows.
pub fn kinds() -> &'static [&'static dyn JobKind] {
    static KINDS: [&dyn JobKind; 10] = [
        &blur_score::BlurScore,
        &camera_calibration::CameraCalibration,
        &imu::ImuNoise,
        &imu::ImuIntrinsics,
        &imu::ImuThermal,
        &photometric::PhotometricResponse,
        &photometric::Vignetting,
        &photometric::PhotometricOnline,
        &photometric::PhotometricCorrect,
        &deblur::Deblur,
    ];
    &KINDS
}

/// Find a kind by name.
pub fn find_kind(name: &str) -> Option<&'static dyn JobKind> {
    kinds().iter().copied().find(|k| k.name() == name)
}

/// Deserialize `params` into `T`, reporting the path of the offending field.
pub fn parse_params<T: serde::de::DeserializeOwned>(params: &Value) -> Result<T, ApiError> {
    let text = params.to_string();
    let mut de = serde_json::Deserializer::from_str(&text);
    serde_path_to_error::deserialize(&mut de).map_err(|e| {
        let path = e.path().to_string();
        let field = if path == "." || path.is_empty() {
            "params".to_string()
        } else {
            format!("params.{path}")
        };
        ApiError::new("invalid_param", e.inner().to_string()).with_field(field)
    })
}

/// Read the normalised parameters stored on a job.
pub fn stored_params<T: serde::de::DeserializeOwned>(params: &Value) -> Result<T, JobError> {
    serde_json::from_value(params.clone()).map_err(|e| JobError::Permanent {
        code: "invalid_param",
        message: e.to_string(),
    })
}

/// Serialise a job result into the document's `parameters`.
pub fn to_value<T: serde::Serialize>(v: &T) -> Result<Value, JobError> {
    serde_json::to_value(v).map_err(|e| JobError::Permanent {
        code: "internal_error",
        message: e.to_string(),
    })
}

/// JSON Schema of a parameter type, for `GET /v1/job-kinds`.
pub fn schema_of<T: utoipa::PartialSchema>() -> Value {
    serde_json::to_value(T::schema()).unwrap_or(Value::Null)
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

/// Map a core validation error to an API error on `params.<field>`.
pub fn param_error(e: CoreError) -> ApiError {
    match e {
        CoreError::InvalidParam { field, message } => {
            ApiError::new("invalid_param", message).with_field(format!("params.{field}"))
        }
        other => ApiError::new("invalid_param", other.to_string()).with_field("params"),
    }
}
