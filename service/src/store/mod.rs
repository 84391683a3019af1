//! Persistence behind one trait, so that the embedded SQLite profile and a scale-out
//! PostgreSQL profile share handlers and workers.
//!
//! The SQL in [`sqlite`] avoids SQLite-only semantics in the queue: timestamps are integer
//! milliseconds computed by the caller, a claim is one `UPDATE … WHERE id = (SELECT … LIMIT 1)
//! RETURNING`, and every write by a worker is fenced by `(lease_owner, attempt)`, which is what
//! a PostgreSQL implementation (`FOR UPDATE SKIP LOCKED`) needs too.

pub mod postgres;
pub mod sqlite;

use async_trait::async_trait;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use utoipa::ToSchema;
use uuid::Uuid;

pub use postgres::PgStore;
pub use sqlite::SqliteStore;

/// Storage failure.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("{0} not found")]
    NotFound(String),
    #[error("database error: {0}")]
    Db(#[from] sqlx::Error),
    #[error("stored data is inconsistent: {0}")]
    Corrupt(String),
    #[error("blob store: {0}")]
    Blob(String),
}

/// Deletes one blob by key, for [`Store::reap_blob`] (called inside the store's transaction).
pub type BlobDeleter<'a> = &'a (
        dyn Fn(String) -> futures_util::future::BoxFuture<'static, std::io::Result<()>>
            + Send
            + Sync
    );

pub type StoreResult<T> = Result<T, StoreError>;

/// What a dataset holds, decided from the uploaded files' content.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum DatasetKind {
    /// One or more still images (PNG, JPEG, TIFF), possibly unpacked from zip archives.
    Images,
    /// One IMU log (CSV, optionally gzip-compressed).
    ImuLog,
    /// One video clip (kept as a blob).
    Video,
}

impl DatasetKind {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Images => "images",
            Self::ImuLog => "imu_log",
            Self::Video => "video",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "images" => Some(Self::Images),
            "imu_log" => Some(Self::ImuLog),
            "video" => Some(Self::Video),
            _ => None,
        }
    }
}

/// One stored file of a dataset.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct DatasetFile {
    /// File name as uploaded (for archive entries: the path inside the archive).
    pub name: String,
    /// SHA-256 of the content, hex; also the blob key.
    pub sha256: String,
    /// Size in bytes.
    pub size: u64,
    /// Detected media type (from content, not from the name).
    pub media_type: String,
    /// Image header facts, for images.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub image: Option<caliper_core::io::ImageInfo>,
    /// Video facts probed at upload (codec, profile, size, rotation, fps, duration, frame and
    /// keyframe counts), for videos.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub video: Option<serde_json::Value>,
}

/// A dataset row.
#[derive(Debug, Clone)]
pub struct DatasetRecord {
    pub id: Uuid,
    pub kind: DatasetKind,
    pub created_at: i64,
    pub total_bytes: u64,
    /// SHA-256 over the sorted `name:sha256` lines: identifies the content of the set.
    pub sha256: String,
    pub files: Vec<DatasetFile>,
    /// The devices of the device-scoped token that uploaded it (only such tokens of those
    /// devices see it); `None` for an upload with fleet-wide access.
    pub devices: Option<Vec<String>>,
}

/// Job lifecycle states.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum JobStatus {
    Queued,
    Running,
    Succeeded,
    Failed,
    Canceled,
}

impl JobStatus {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Queued => "queued",
            Self::Running => "running",
            Self::Succeeded => "succeeded",
            Self::Failed => "failed",
            Self::Canceled => "canceled",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "queued" => Some(Self::Queued),
            "running" => Some(Self::Running),
            "succeeded" => Some(Self::Succeeded),
            "failed" => Some(Self::Failed),
            "canceled" => Some(Self::Canceled),
            _ => None,
        }
    }

    pub fn is_terminal(self) -> bool {
        matches!(self, Self::Succeeded | Self::Failed | Self::Canceled)
    }
}

/// A job row.
#[derive(Debug, Clone)]
pub struct JobRecord {
    pub id: Uuid,
    pub kind: String,
    pub dataset_id: Uuid,
    pub device: Option<String>,
    pub sensor: Option<String>,
    pub params: Value,
    pub status: JobStatus,
    pub attempt: u32,
    pub max_attempts: u32,
    pub run_at: i64,
    pub lease_owner: Option<Uuid>,
    pub lease_expires_at: Option<i64>,
    pub cancel_requested: bool,
    pub progress: Option<Value>,
    pub error: Option<Value>,
    pub document_rev: Option<u64>,
    pub idempotency_key: Option<String>,
    pub request_hash: Option<String>,
    pub created_at: i64,
    pub started_at: Option<i64>,
    pub finished_at: Option<i64>,
}

/// A job to insert.
#[derive(Debug, Clone)]
pub struct NewJob {
    pub id: Uuid,
    pub kind: String,
    pub dataset_id: Uuid,
    /// A second dataset the job reads (see [`crate::jobs::AuxDataset`]); it cannot be deleted
    /// while the job is queued or running.
    pub aux_dataset_id: Option<Uuid>,
    pub device: Option<String>,
    pub sensor: Option<String>,
    pub params: Value,
    pub max_attempts: u32,
    pub idempotency_key: Option<String>,
    pub request_hash: Option<String>,
    pub now: i64,
}

/// Outcome of inserting a job.
#[derive(Debug)]
pub enum CreateJob {
    Created(JobRecord),
    /// Same idempotency key and same request: the earlier job.
    Existing(JobRecord),
    /// Same idempotency key, different request.
    Conflict(JobRecord),
    /// The queue holds `max_queued` jobs already.
    QueueFull,
    /// The dataset does not exist (or was deleted).
    UnknownDataset,
}

/// Filters of the job list.
#[derive(Debug, Clone, Default)]
pub struct JobFilter {
    pub statuses: Vec<JobStatus>,
    pub kinds: Vec<String>,
    pub device: Option<String>,
    /// Only jobs of these devices (a device-scoped token); `None`: all.
    pub devices: Option<Vec<String>>,
    pub dataset: Option<Uuid>,
    pub created_after: Option<i64>,
    pub created_before: Option<i64>,
    /// Keyset cursor: only jobs with a smaller id (ids are time-ordered UUIDv7).
    pub before_id: Option<Uuid>,
    pub limit: u32,
}

/// Outcome of a cancel request.
#[derive(Debug)]
pub enum CancelJob {
    /// A queued job, now canceled.
    Canceled(JobRecord),
    /// A running job, flagged; the worker stops at its next check.
    Requested(JobRecord),
    /// Already finished: nothing to cancel.
    Finished(JobRecord),
    NotFound,
}

/// Outcome of deleting a dataset.
#[derive(Debug)]
pub enum DeleteDataset {
    /// Deleted; its blobs are candidates for garbage collection ([`Store::reap_blob`]).
    Deleted,
    /// A queued or running job uses it.
    InUse(Vec<Uuid>),
    NotFound,
}

/// Where a succeeded job's document is filed; the store assigns the next `rev` in the same
/// transaction that completes the job and seals the body with it (see [`crate::document`]).
#[derive(Debug, Clone)]
pub struct NewDocument {
    pub device: String,
    pub sensor: String,
    pub kind: String,
    pub schema: String,
}

/// A stored document revision.
#[derive(Debug, Clone)]
pub struct DocumentRecord {
    pub device: String,
    pub sensor: String,
    pub kind: String,
    pub rev: u64,
    pub etag: String,
    pub schema: String,
    pub created_at: i64,
    pub job_id: Option<Uuid>,
    /// The full document, canonical JSON.
    pub body: String,
}

/// Summary of a device's documents (latest revision per sensor and kind).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct DocumentSummary {
    pub sensor: String,
    pub kind: String,
    pub schema: String,
    pub latest_rev: u64,
    pub etag: String,
    /// RFC 3339.
    pub created_at: String,
    /// The job that wrote the latest revision.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub job: Option<Uuid>,
    /// The document's `quality` object (headline numbers such as `rms` or `coverage`), so a
    /// fleet view can show a badge without fetching every document.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub quality: Option<Value>,
}

/// One device and the latest revision of each of its documents.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct DeviceSummary {
    pub serial: String,
    /// Latest revision per (sensor, kind), ordered by sensor then kind.
    pub documents: Vec<DocumentSummary>,
}

/// A page of devices in serial order.
#[derive(Debug, Clone, Default)]
pub struct DeviceQuery {
    /// Case-insensitive substring of the serial.
    pub search: Option<String>,
    /// Only serials after this one (the cursor).
    pub after: Option<String>,
    pub limit: u32,
    /// Only these serials (a device-scoped token); `None`: all.
    pub only: Option<Vec<String>>,
}

/// An artifact produced by a job (plot, image), stored as a content-addressed blob.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ArtifactRecord {
    pub name: String,
    pub media_type: String,
    pub sha256: String,
    pub size: u64,
}

/// Outcome of a heartbeat.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Heartbeat {
    /// Lease renewed; `cancel` tells whether cancellation was requested.
    Renewed { cancel: bool },
    /// The lease is no longer ours (expired and re-claimed, or job finished): stop at once.
    Lost,
}

/// How a job attempt ended, as recorded by [`JobQueue::finish_job`].
pub enum Finish {
    Succeeded {
        /// Seals the document once its `rev` is known.
        seal: Seal,
        document: Option<NewDocument>,
        artifacts: Vec<ArtifactRecord>,
    },
    /// Failed for good.
    Failed {
        error: Value,
    },
    /// Transient failure: queue again at `run_at` (unless attempts are exhausted).
    Retry {
        error: Value,
        run_at: i64,
    },
    Canceled,
    /// Interrupted by a shutdown of the service: queue again at once. The interrupted attempt
    /// does not count against `max_attempts` (the store grants one more), so graceful restarts
    /// never turn a healthy job into a failed one.
    Requeue {
        error: Value,
    },
}

/// What the store needs from the caller to file a succeeded job's document: given the `rev`
/// the store assigns (inside its transaction), the body to store and its etag. The document
/// format is the caller's business ([`crate::document`]), not the store's.
pub type Seal = Box<dyn FnOnce(Option<u64>) -> Sealed + Send>;

/// A sealed document: its stored body and entity tag.
#[derive(Debug, Clone)]
pub struct Sealed {
    pub body: String,
    pub etag: String,
}

/// Datasets and their files.
#[async_trait]
pub trait DatasetStore: Send + Sync {
    async fn insert_dataset(&self, ds: &DatasetRecord) -> StoreResult<()>;
    async fn get_dataset(&self, id: Uuid) -> StoreResult<Option<DatasetRecord>>;
    /// Newest first; with `only`, just the datasets uploaded for one of those devices.
    async fn list_datasets(
        &self,
        before_id: Option<Uuid>,
        limit: u32,
        only: Option<&[String]>,
    ) -> StoreResult<Vec<DatasetRecord>>;
    /// Delete a dataset no queued or running job uses; its blobs become GC candidates.
    async fn delete_dataset(&self, id: Uuid) -> StoreResult<DeleteDataset>;
}

/// The job queue: jobs, attempts, leases and the artifacts of finished jobs.
#[async_trait]
pub trait JobQueue: Send + Sync {
    async fn create_job(&self, job: NewJob, max_queued: u64) -> StoreResult<CreateJob>;
    /// A job's row without its result (the document can be large; see
    /// [`JobQueue::get_job_result`]).
    async fn get_job(&self, id: Uuid) -> StoreResult<Option<JobRecord>>;
    /// The sealed result document (canonical JSON) of a succeeded job.
    async fn get_job_result(&self, id: Uuid) -> StoreResult<Option<String>>;
    async fn list_jobs(&self, filter: &JobFilter) -> StoreResult<Vec<JobRecord>>;
    async fn cancel_job(&self, id: Uuid, now: i64) -> StoreResult<CancelJob>;
    async fn queue_depth(&self) -> StoreResult<(u64, u64)>;

    /// Claim the next runnable job for `owner` until `lease_until`.
    async fn claim_job(
        &self,
        owner: Uuid,
        now: i64,
        lease_until: i64,
    ) -> StoreResult<Option<JobRecord>>;
    /// Renew a lease and store progress; fenced by owner and attempt.
    async fn heartbeat(
        &self,
        id: Uuid,
        owner: Uuid,
        attempt: u32,
        lease_until: i64,
        progress: Option<&Value>,
    ) -> StoreResult<Heartbeat>;
    /// Record the end of an attempt; fenced. Returns false if the lease was lost (nothing
    /// written). A succeeded job's document is filed with the next `rev` of its
    /// (device, sensor, kind), assigned in the same transaction.
    async fn finish_job(
        &self,
        id: Uuid,
        owner: Uuid,
        attempt: u32,
        now: i64,
        finish: Finish,
    ) -> StoreResult<bool>;
    /// Re-queue running jobs whose lease expired (or all running jobs when `all`, used at
    /// start-up by the exclusive embedded profile). Jobs out of attempts fail. Returns how many
    /// changed.
    async fn recover_leases(&self, now: i64, all: bool) -> StoreResult<u64>;
    /// Delete finished jobs older than `before` (except those a document refers to) with
    /// their artifacts, whose blobs become GC candidates; returns how many jobs went.
    async fn prune_jobs(&self, before: i64) -> StoreResult<u64>;

    async fn list_artifacts(&self, job: Uuid) -> StoreResult<Vec<ArtifactRecord>>;
    async fn get_artifact(&self, job: Uuid, name: &str) -> StoreResult<Option<ArtifactRecord>>;
}

/// Immutable document revisions.
#[async_trait]
pub trait DocumentStore: Send + Sync {
    async fn list_documents(&self, device: &str) -> StoreResult<Vec<DocumentSummary>>;
    /// Devices that have documents, in serial order, at most `limit` (callers ask one more
    /// to learn whether a next page exists), with their latest documents.
    async fn list_devices(&self, q: &DeviceQuery) -> StoreResult<Vec<DeviceSummary>>;
    /// How many devices match `search` (all devices when `None`).
    async fn count_devices(
        &self,
        search: Option<&str>,
        only: Option<&[String]>,
    ) -> StoreResult<u64>;
    async fn get_document(
        &self,
        device: &str,
        sensor: &str,
        kind: &str,
        rev: Option<u64>,
    ) -> StoreResult<Option<DocumentRecord>>;
    async fn list_revisions(
        &self,
        device: &str,
        sensor: &str,
        kind: &str,
    ) -> StoreResult<Vec<DocumentRecord>>;
}

/// Blob lifetime. A writer pins the keys it is about to store before it stores them, then
/// references them (dataset, artifacts) and unpins; GC removes only candidates that are
/// neither referenced nor pinned, checking and deleting under the store's write lock.
#[async_trait]
pub trait BlobRefs: Send + Sync {
    /// Pin `shas` for `token` until `expires_at` (or [`BlobRefs::unpin_blobs`]).
    async fn pin_blobs(&self, token: Uuid, shas: &[String], expires_at: i64) -> StoreResult<()>;
    /// Drop the pins of `token`; their keys become GC candidates.
    async fn unpin_blobs(&self, token: Uuid, now: i64) -> StoreResult<()>;
    /// Expire stale pins, then list up to `limit` candidates queued at or before `due_before`.
    async fn gc_candidates(
        &self,
        now: i64,
        due_before: i64,
        limit: u32,
    ) -> StoreResult<Vec<String>>;
    /// Delete the blob `sha` with `delete` if nothing references or pins it, atomically with
    /// respect to pins and references; drops the candidate either way. True if deleted.
    async fn reap_blob(&self, sha: &str, now: i64, delete: BlobDeleter<'_>) -> StoreResult<bool>;
    /// Drop every pin (at start, when this process owns the store alone).
    async fn clear_pins(&self, now: i64) -> StoreResult<()>;
}

/// What a token may do. `admin` manages tokens (and may do everything else), `write` uploads,
/// queues and cancels (and reads), `read` reads datasets, jobs and documents.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Scope {
    Read,
    Write,
    Admin,
}

impl Scope {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Read => "read",
            Self::Write => "write",
            Self::Admin => "admin",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "read" => Some(Self::Read),
            "write" => Some(Self::Write),
            "admin" => Some(Self::Admin),
            _ => None,
        }
    }
}

/// A stored access token (its secret is kept only as a hash).
#[derive(Debug, Clone, PartialEq)]
pub struct TokenRecord {
    pub id: Uuid,
    pub name: String,
    /// The first characters of the secret, shown in lists so a leaked token can be matched.
    pub prefix: String,
    pub scope: Scope,
    /// Device serials it is limited to; `None`: the whole fleet.
    pub devices: Option<Vec<String>>,
    pub created_at: i64,
    pub revoked_at: Option<i64>,
}

/// Access tokens.
#[async_trait]
pub trait TokenStore: Send + Sync {
    /// Store a new token under the SHA-256 `hash` of its secret.
    async fn insert_token(&self, token: &TokenRecord, hash: &str) -> StoreResult<()>;
    /// The token whose secret hashes to `hash`, revoked or not.
    async fn token_by_hash(&self, hash: &str) -> StoreResult<Option<TokenRecord>>;
    /// Every token, newest first.
    async fn list_tokens(&self) -> StoreResult<Vec<TokenRecord>>;
    /// Revoke a token; false if there is no such token.
    async fn revoke_token(&self, id: Uuid, now: i64) -> StoreResult<bool>;
}

/// The whole storage interface used by handlers and workers: one trait per concern, so a
/// second implementation (PostgreSQL) plugs in concern by concern.
#[async_trait]
pub trait Store:
    DatasetStore + JobQueue + DocumentStore + BlobRefs + TokenStore + Send + Sync + 'static
{
    /// Can we reach the database?
    async fn ping(&self) -> StoreResult<()>;

    /// Do other processes share this store (replicas on one PostgreSQL)? Then nothing may be
    /// assumed about jobs or pins at start: another replica may own them.
    fn shared(&self) -> bool {
        false
    }

    /// The PostgreSQL store behind this one, for `LISTEN`.
    fn as_pg(&self) -> Option<&PgStore> {
        None
    }
}

#[cfg(test)]
mod tests;
