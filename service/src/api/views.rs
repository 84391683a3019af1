//! Response bodies of the API (the wire format, separate from the store's records).

use serde::{Deserialize, Serialize};
use serde_json::Value;
use utoipa::ToSchema;
use uuid::Uuid;

use crate::clock::rfc3339;
use crate::store::{ArtifactRecord, DatasetFile, DatasetKind, DatasetRecord, JobRecord, JobStatus};

/// A stored dataset.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
#[schema(example = json!({
    "id": "01935f2c-7a4e-7cc2-9d1e-3b8a2f6c1d00", "kind": "images",
    "created_at": "2026-11-28T21:00:00Z", "file_count": 1, "total_bytes": 48213,
    "sha256": "5d41402abc4b2a76b9719d911017c592b3b2f0a1e4c5d6e7f8091a2b3c4d5e6f",
    "files": [{"name": "left01.jpg", "sha256": "9f86d081884c7d659a2feaa0c55ad015a3bf4f1b2b0b822cd15d6c15b0f00a08",
               "size": 48213, "media_type": "image/jpeg",
               "image": {"format": "jpeg", "width": 640, "height": 480, "bit_depth": 8, "channels": 1}}]
}))]
pub struct DatasetView {
    pub id: Uuid,
    pub kind: DatasetKind,
    /// RFC 3339.
    pub created_at: String,
    pub file_count: usize,
    pub total_bytes: u64,
    /// SHA-256 of the manifest (`sha256  name` per file, in order).
    pub sha256: String,
    pub files: Vec<DatasetFile>,
}

impl From<DatasetRecord> for DatasetView {
    fn from(d: DatasetRecord) -> Self {
        Self {
            id: d.id,
            kind: d.kind,
            created_at: rfc3339(d.created_at),
            file_count: d.files.len(),
            total_bytes: d.total_bytes,
            sha256: d.sha256,
            files: d.files,
        }
    }
}

/// A page of datasets, newest first.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct DatasetPage {
    pub items: Vec<DatasetView>,
    /// Pass as `cursor` to get the next page; absent on the last page.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub next_cursor: Option<String>,
}

/// Progress of a running job.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct ProgressView {
    /// Name of the current step.
    pub step: String,
    pub done: u64,
    pub total: u64,
    /// 0–100.
    pub percent: f64,
}

/// Why a job failed or was canceled.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct JobErrorView {
    /// Stable code: `invalid_input`, `invalid_param`, `no_solution`, `time_limit_exceeded`,
    /// `unknown_dataset`, `lease_lost`, `transient`, `internal_error`, `canceled`, `shutdown`.
    pub code: String,
    pub message: String,
}

/// Where a job's document was filed.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct DocumentRef {
    pub device: String,
    pub sensor: String,
    pub kind: String,
    pub rev: u64,
    /// URL of this revision.
    pub href: String,
}

/// A job.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
#[schema(example = json!({
    "id": "01935f2c-8b11-7d20-a1b2-c3d4e5f60718", "kind": "blur_score",
    "dataset": "01935f2c-7a4e-7cc2-9d1e-3b8a2f6c1d00", "device": "cam-0042", "sensor": "cam0",
    "status": "running", "params": {"k": 10, "laplacian_threshold": 100.0, "beta_threshold": 0.6, "rule": "either"},
    "progress": {"step": "scoring", "done": 3, "total": 13, "percent": 23.1},
    "attempt": 1, "max_attempts": 3, "cancel_requested": false,
    "created_at": "2026-11-28T21:00:01Z", "started_at": "2026-11-28T21:00:01Z"
}))]
pub struct JobView {
    pub id: Uuid,
    pub kind: String,
    pub dataset: Uuid,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub device: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sensor: Option<String>,
    pub status: JobStatus,
    /// Parameters with defaults filled in.
    #[schema(value_type = Object)]
    pub params: Value,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub progress: Option<ProgressView>,
    /// Attempts started so far.
    pub attempt: u32,
    pub max_attempts: u32,
    pub cancel_requested: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<JobErrorView>,
    /// The document revision this job wrote (jobs with a device).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub document: Option<DocumentRef>,
    /// URL of the result document (succeeded jobs).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub result_href: Option<String>,
    /// RFC 3339.
    pub created_at: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub started_at: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub finished_at: Option<String>,
    /// Earliest time of the next attempt (queued jobs waiting for a retry).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub retry_at: Option<String>,
}

impl From<&JobRecord> for JobView {
    fn from(j: &JobRecord) -> Self {
        let progress = j
            .progress
            .as_ref()
            .and_then(|p| serde_json::from_value::<ProgressView>(p.clone()).ok());
        let error = j
            .error
            .as_ref()
            .and_then(|e| serde_json::from_value::<JobErrorView>(e.clone()).ok());
        let document = match (&j.device, j.document_rev) {
            (Some(device), Some(rev)) => {
                let sensor = j.sensor.clone().unwrap_or_else(|| "default".into());
                Some(DocumentRef {
                    href: format!("/v1/devices/{device}/documents/{sensor}/{}/{rev}", j.kind),
                    device: device.clone(),
                    sensor,
                    kind: j.kind.clone(),
                    rev,
                })
            }
            _ => None,
        };
        let retry_at = (j.status == JobStatus::Queued && j.attempt > 0).then(|| rfc3339(j.run_at));
        Self {
            id: j.id,
            kind: j.kind.clone(),
            dataset: j.dataset_id,
            device: j.device.clone(),
            sensor: j.sensor.clone(),
            status: j.status,
            params: j.params.clone(),
            progress,
            attempt: j.attempt,
            max_attempts: j.max_attempts,
            cancel_requested: j.cancel_requested,
            error,
            document,
            result_href: (j.status == JobStatus::Succeeded)
                .then(|| format!("/v1/jobs/{}/result", j.id)),
            created_at: rfc3339(j.created_at),
            started_at: j.started_at.map(rfc3339),
            finished_at: j.finished_at.map(rfc3339),
            retry_at,
        }
    }
}

/// A page of jobs, newest first.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct JobPage {
    pub items: Vec<JobView>,
    /// Pass as `cursor` to get the next page; absent on the last page.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub next_cursor: Option<String>,
}

/// Artifacts of a job.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct ArtifactList {
    pub items: Vec<ArtifactView>,
}

/// One artifact.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct ArtifactView {
    #[serde(flatten)]
    pub artifact: ArtifactRecord,
    pub href: String,
}

/// A job kind this server runs.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct JobKindView {
    pub name: String,
    /// Schema name of the documents it writes.
    pub schema: String,
    /// Dataset kind it reads.
    pub dataset_kind: DatasetKind,
    pub description: String,
    /// JSON Schema of `params`.
    #[schema(value_type = Object)]
    pub params_schema: Value,
    /// Export formats of its documents (`?format=` of the document routes).
    #[serde(default)]
    pub exports: Vec<ExportView>,
}

/// An export format of a kind's documents.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct ExportView {
    /// The `format` query value, e.g. `opencv-yaml`.
    pub format: String,
    /// Media type of the export.
    pub media_type: String,
    /// A file name extension for it, e.g. `yaml`.
    pub extension: String,
}

impl From<&crate::jobs::Export> for ExportView {
    fn from(e: &crate::jobs::Export) -> Self {
        let essence = e.media_type.split(';').next().unwrap_or("").trim();
        let extension = match essence {
            "application/json" => "json",
            "application/yaml" | "text/yaml" | "application/x-yaml" => "yaml",
            _ if e.format.ends_with("yaml") => "yaml",
            _ => "txt",
        };
        Self {
            format: e.format.to_owned(),
            media_type: e.media_type.to_owned(),
            extension: extension.to_owned(),
        }
    }
}
