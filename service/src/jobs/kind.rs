//! What a job kind is, in one place.
//!
//! A kind is one type implementing [`Kind`]: its name, document schema, the dataset kind it
//! reads, its parameter type, its command-line flags, the exports its documents offer, and
//! `run`. The registry (`super::kinds`) wraps each in [`Registered`], the object-safe
//! [`JobKind`] that the router, the OpenAPI components, `GET /v1/job-kinds`, the offline
//! runner (`caliper run <kind>`) and the export dispatch all read. Adding a kind is one file
//! plus one registry line.

use caliper_core::{CoreError, Progress};
use clap::{ArgMatches, Args, FromArgMatches};
use serde::Serialize;
use serde::de::DeserializeOwned;
use serde_json::Value;
use utoipa::openapi::RefOr;
use utoipa::openapi::schema::Schema;

use super::{JobError, JobInput, JobOutput};
use crate::store::DatasetKind;

/// A parameter that cannot be used, with the path of the offending field from the request
/// body's root (`params.k`, `params.gyro.fx`). Neutral: the HTTP edge maps it to a 422
/// problem, the offline runner to a message and exit code 2.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field}: {message}")]
pub struct ParamError {
    pub field: String,
    pub message: String,
}

impl ParamError {
    /// An error on `params.<field>` (`field` relative to `params`; empty for `params` itself).
    pub fn new(field: &str, message: impl Into<String>) -> Self {
        Self {
            field: if field.is_empty() {
                "params".into()
            } else {
                format!("params.{field}")
            },
            message: message.into(),
        }
    }

    /// A core validation error, on `params.<prefix>.<field>` (`prefix` may be empty).
    pub fn from_core(prefix: &str, e: CoreError) -> Self {
        let join = |f: &str| match (prefix.is_empty(), f.is_empty()) {
            (true, _) => f.to_string(),
            (false, true) => prefix.to_string(),
            (false, false) => format!("{prefix}.{f}"),
        };
        match e {
            CoreError::InvalidParam { field, message } => Self::new(&join(&field), message),
            other => Self::new(prefix, other.to_string()),
        }
    }
}

/// One export format of a kind's documents (`?format=` and `caliper run … --export`).
#[derive(Clone, Copy)]
pub struct Export {
    /// The `format` value, e.g. `opencv-yaml`.
    pub format: &'static str,
    /// Media type of the rendered text.
    pub media_type: &'static str,
    /// Render a stored (sealed) document.
    pub render: fn(&Value) -> Result<String, ExportError>,
}

/// Why an export cannot be written.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The document lacks what the format needs (e.g. an undetermined random walk).
    #[error("{0}")]
    Unavailable(String),
    /// The stored document does not have the shape of its schema (a bug or a corrupt store).
    #[error("stored document unreadable: {0}")]
    Corrupt(String),
}

/// A second dataset a job reads besides its own, named in its parameters: deblurring a
/// clip frame by frame with method `gyro` reads the device's IMU log from an `imu_log`
/// dataset. The service checks that it exists, is visible to the caller and has the right
/// kind before queueing, and keeps it from being deleted while the job may run.
#[derive(Debug, Clone, PartialEq)]
pub struct AuxDataset {
    /// The parameter naming it, from the body's root (`params.gyro_clip.imu_dataset`).
    pub field: &'static str,
    pub id: uuid::Uuid,
    pub kind: DatasetKind,
}

/// Local context of an offline run, for kinds whose flags name files.
pub struct CliContext<'a> {
    /// The input files as given on the command line (directories not yet expanded).
    pub inputs: &'a [std::path::PathBuf],
}

/// Why an offline run failed (printed to stderr; exit code 2 for input problems).
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("{0}")]
    Input(String),
    #[error("{0}")]
    Job(String),
    #[error("i/o: {0}")]
    Io(#[from] std::io::Error),
}

impl From<ParamError> for RunError {
    fn from(e: ParamError) -> Self {
        RunError::Input(e.to_string())
    }
}

/// A job kind, typed. Implement this (one file in `jobs/`) and add one line to the registry.
pub trait Kind: Send + Sync + 'static {
    /// Name in the API (`blur_score`); the offline command is the kebab-case form.
    const NAME: &'static str;
    /// Schema of the documents it writes (`caliper.blur_score/v1`).
    const SCHEMA: &'static str;
    /// The dataset kind it reads.
    const DATASET: DatasetKind;
    /// It also reads a video dataset (one clip) in place of `DATASET`.
    const ALSO_VIDEO: bool = false;
    /// One line for `GET /v1/job-kinds` and `caliper run --help`.
    const DESCRIPTION: &'static str;
    /// Export formats of its documents.
    const EXPORTS: &'static [Export] = &[];
    /// Parameters (an OpenAPI component; omitted fields take their defaults).
    type Params: Serialize + DeserializeOwned + utoipa::ToSchema + 'static;
    /// Flags of `caliper run <kind>` (besides the common `--out`, `--pretty`, `--export`).
    type Cli: Args + FromArgMatches + 'static;

    /// Check parameters; may canonicalise them (e.g. normalise a kernel) so that the job and
    /// its document use the same values.
    fn check(params: &mut Self::Params) -> Result<(), ParamError>;

    /// The parameters object the flags stand for (files they name are read here).
    fn cli_params(cli: &Self::Cli, ctx: &CliContext<'_>) -> Result<Value, RunError>;

    /// The second dataset checked parameters name, if any; an error when the service needs
    /// one the parameters do not name (offline runs give a file instead and never ask).
    fn aux_dataset(_params: &Self::Params) -> Result<Option<AuxDataset>, ParamError> {
        Ok(None)
    }

    /// Offline, the local file that stands in for [`Kind::aux_dataset`] (read as the
    /// dataset kind it names), if the flags give one.
    fn cli_aux_file(_cli: &Self::Cli, _params: &Value) -> Option<std::path::PathBuf> {
        None
    }

    /// Run on the input (blocking; the worker calls it on a thread of its own).
    fn run(
        &self,
        params: Self::Params,
        input: &JobInput,
        progress: &dyn Progress,
    ) -> Result<JobOutput, JobError>;
}

/// The object-safe face of a registered kind.
pub trait JobKind: Send + Sync + 'static {
    fn name(&self) -> &'static str;
    fn schema(&self) -> &'static str;
    fn dataset_kind(&self) -> DatasetKind;
    /// Also reads a video dataset.
    fn accepts_video(&self) -> bool;
    fn description(&self) -> &'static str;
    fn exports(&self) -> &'static [Export];
    /// JSON Schema of the parameters, for `GET /v1/job-kinds`.
    fn params_schema(&self) -> Value;
    /// The parameter type's OpenAPI components (itself and what it refers to).
    fn params_components(&self, out: &mut Vec<(String, RefOr<Schema>)>);
    /// Check parameters and fill in defaults.
    fn normalize_params(&self, params: &Value) -> Result<Value, ParamError>;
    /// The `caliper run` subcommand: the kind's flags (common flags are added by the runner).
    fn cli_command(&self) -> clap::Command;
    /// The parameters object of a parsed `caliper run` subcommand.
    fn cli_params(&self, m: &ArgMatches, ctx: &CliContext<'_>) -> Result<Value, RunError>;
    /// The second dataset normalised parameters name, if any (see [`Kind::aux_dataset`]).
    fn aux_dataset(&self, params: &Value) -> Result<Option<AuxDataset>, ParamError>;
    /// Offline, the local file standing in for it.
    fn cli_aux_file(&self, m: &ArgMatches, params: &Value) -> Option<std::path::PathBuf>;
    /// Run on normalised parameters.
    fn run(&self, input: &JobInput, progress: &dyn Progress) -> Result<JobOutput, JobError>;
}

/// A [`Kind`] in the registry.
pub struct Registered<K: Kind>(pub K);

impl<K: Kind> JobKind for Registered<K> {
    fn name(&self) -> &'static str {
        K::NAME
    }
    fn schema(&self) -> &'static str {
        K::SCHEMA
    }
    fn dataset_kind(&self) -> DatasetKind {
        K::DATASET
    }
    fn accepts_video(&self) -> bool {
        K::ALSO_VIDEO
    }
    fn description(&self) -> &'static str {
        K::DESCRIPTION
    }
    fn exports(&self) -> &'static [Export] {
        K::EXPORTS
    }
    fn params_schema(&self) -> Value {
        serde_json::to_value(<K::Params as utoipa::PartialSchema>::schema()).unwrap_or(Value::Null)
    }
    fn params_components(&self, out: &mut Vec<(String, RefOr<Schema>)>) {
        out.push((
            <K::Params as utoipa::ToSchema>::name().into_owned(),
            <K::Params as utoipa::PartialSchema>::schema(),
        ));
        <K::Params as utoipa::ToSchema>::schemas(out);
    }
    fn normalize_params(&self, params: &Value) -> Result<Value, ParamError> {
        let mut p: K::Params = parse_params(params)?;
        K::check(&mut p)?;
        serde_json::to_value(&p).map_err(|e| ParamError::new("", e.to_string()))
    }
    fn cli_command(&self) -> clap::Command {
        K::Cli::augment_args(clap::Command::new(K::NAME.replace('_', "-"))).about(K::DESCRIPTION)
    }
    fn cli_params(&self, m: &ArgMatches, ctx: &CliContext<'_>) -> Result<Value, RunError> {
        let cli = K::Cli::from_arg_matches(m).map_err(|e| RunError::Input(e.to_string()))?;
        K::cli_params(&cli, ctx)
    }
    fn aux_dataset(&self, params: &Value) -> Result<Option<AuxDataset>, ParamError> {
        let p: K::Params = parse_params(params)?;
        K::aux_dataset(&p)
    }
    fn cli_aux_file(&self, m: &ArgMatches, params: &Value) -> Option<std::path::PathBuf> {
        let cli = K::Cli::from_arg_matches(m).ok()?;
        K::cli_aux_file(&cli, params)
    }
    fn run(&self, input: &JobInput, progress: &dyn Progress) -> Result<JobOutput, JobError> {
        let p: K::Params =
            serde_json::from_value(input.params.clone()).map_err(|e| JobError::Permanent {
                code: "invalid_param",
                message: e.to_string(),
            })?;
        self.0.run(p, input, progress)
    }
}

/// Deserialize `params` into `T`, reporting the path of the offending field.
pub fn parse_params<T: DeserializeOwned>(params: &Value) -> Result<T, ParamError> {
    let text = params.to_string();
    let mut de = serde_json::Deserializer::from_str(&text);
    serde_path_to_error::deserialize(&mut de).map_err(|e| {
        let path = e.path().to_string();
        let field = if path == "." { String::new() } else { path };
        ParamError::new(&field, e.inner().to_string())
    })
}

/// Flags of kinds whose parameters are given whole, as JSON.
#[derive(Debug, Clone, Args)]
pub struct JsonParams {
    /// Parameters as JSON (see `GET /v1/job-kinds` for the schema), e.g. '{"rate_hz": 200}'.
    #[arg(long)]
    pub params: Option<String>,
}

impl JsonParams {
    /// The parameters object (`{}` when none given).
    pub fn value(&self) -> Result<Value, RunError> {
        match &self.params {
            Some(p) => json_flag("params", p),
            None => Ok(Value::Object(Default::default())),
        }
    }
}

/// The JSON value of the command-line flag `--<name>`.
pub fn json_flag(name: &str, text: &str) -> Result<Value, RunError> {
    serde_json::from_str(text).map_err(|e| RunError::Input(format!("--{name} is not JSON: {e}")))
}
