//! The embedded profile's store: one SQLite file in WAL mode.
//!
//! Writes go through a pool of exactly one connection, so transactions never contend for the
//! write lock ("database is locked" cannot happen between our own writers); reads use a
//! separate pool and proceed concurrently thanks to WAL.

use std::path::Path;
use std::str::FromStr;
use std::time::Duration;

use async_trait::async_trait;
use serde_json::Value;
use sqlx::sqlite::{
    SqliteConnectOptions, SqliteJournalMode, SqlitePool, SqlitePoolOptions, SqliteRow,
    SqliteSynchronous,
};
use sqlx::{AssertSqlSafe, Row};
use uuid::Uuid;

use super::*;
use crate::document;

/// Migrations in order; the index + 1 is the schema version.
const MIGRATIONS: &[&str] = &[include_str!("schema_v1.sql")];

const JOB_COLS: &str = "id, kind, dataset_id, device, sensor, params, status, attempt, max_attempts, \
    run_at, lease_owner, lease_expires_at, cancel_requested, progress, error, document_rev, \
    idempotency_key, request_hash, created_at, started_at, finished_at";

/// SQLite-backed [`Store`].
#[derive(Clone)]
pub struct SqliteStore {
    write: SqlitePool,
    read: SqlitePool,
}

impl SqliteStore {
    /// Open (creating if needed) the database file and bring its schema up to date.
    pub async fn open(path: &Path) -> StoreResult<Self> {
        let opts = SqliteConnectOptions::new()
            .filename(path)
            .create_if_missing(true)
            .journal_mode(SqliteJournalMode::Wal)
            .synchronous(SqliteSynchronous::Normal)
            .busy_timeout(Duration::from_secs(10))
            .foreign_keys(true);
        let write = SqlitePoolOptions::new()
            .max_connections(1)
            .connect_with(opts.clone())
            .await?;
        let store_tmp = Self {
            write: write.clone(),
            read: write.clone(),
        };
        store_tmp.migrate().await?;
        let read = SqlitePoolOptions::new()
            .max_connections(8)
            .min_connections(2)
            .connect_with(opts.read_only(true))
            .await?;
        Ok(Self { write, read })
    }

    async fn migrate(&self) -> StoreResult<()> {
        let mut tx = self.write.begin().await?;
        sqlx::query(
            "CREATE TABLE IF NOT EXISTS schema_migrations (version INTEGER PRIMARY KEY, applied_at INTEGER NOT NULL)",
        )
        .execute(&mut *tx)
        .await?;
        let current: i64 =
            sqlx::query_scalar("SELECT COALESCE(MAX(version), 0) FROM schema_migrations")
                .fetch_one(&mut *tx)
                .await?;
        for (i, sql) in MIGRATIONS.iter().enumerate() {
            let version = i as i64 + 1;
            if version <= current {
                continue;
            }
            for stmt in sql.split(';').map(str::trim).filter(|s| !only_comments(s)) {
                sqlx::query(AssertSqlSafe(stmt.to_string()))
                    .execute(&mut *tx)
                    .await?;
            }
            sqlx::query("INSERT INTO schema_migrations (version, applied_at) VALUES (?, ?)")
                .bind(version)
                .bind(crate::clock::now_ms())
                .execute(&mut *tx)
                .await?;
        }
        tx.commit().await?;
        Ok(())
    }
}

/// The blob keys among `shas` that no dataset file and no artifact references any more.
async fn unreferenced(
    tx: &mut sqlx::Transaction<'_, sqlx::Sqlite>,
    shas: Vec<String>,
) -> StoreResult<Vec<String>> {
    let mut orphans = Vec::new();
    for sha in shas {
        let used: Option<i64> = sqlx::query_scalar(
            "SELECT 1 FROM dataset_files WHERE sha256 = ? UNION ALL SELECT 1 FROM artifacts WHERE sha256 = ? LIMIT 1",
        )
        .bind(&sha)
        .bind(&sha)
        .fetch_optional(&mut **tx)
        .await?;
        if used.is_none() {
            orphans.push(sha);
        }
    }
    Ok(orphans)
}

fn only_comments(s: &str) -> bool {
    s.lines().all(|l| {
        let l = l.trim();
        l.is_empty() || l.starts_with("--")
    })
}

fn parse_uuid(s: &str) -> StoreResult<Uuid> {
    Uuid::from_str(s).map_err(|e| StoreError::Corrupt(format!("bad uuid {s:?}: {e}")))
}

fn parse_json(s: Option<String>) -> StoreResult<Option<Value>> {
    s.map(|t| serde_json::from_str(&t).map_err(|e| StoreError::Corrupt(e.to_string())))
        .transpose()
}

fn job_from_row(r: &SqliteRow) -> StoreResult<JobRecord> {
    let status: String = r.try_get("status")?;
    let owner: Option<String> = r.try_get("lease_owner")?;
    Ok(JobRecord {
        id: parse_uuid(&r.try_get::<String, _>("id")?)?,
        kind: r.try_get("kind")?,
        dataset_id: parse_uuid(&r.try_get::<String, _>("dataset_id")?)?,
        device: r.try_get("device")?,
        sensor: r.try_get("sensor")?,
        params: parse_json(Some(r.try_get("params")?))?.unwrap_or(Value::Null),
        status: JobStatus::parse(&status)
            .ok_or_else(|| StoreError::Corrupt(format!("bad status {status}")))?,
        attempt: r.try_get::<i64, _>("attempt")? as u32,
        max_attempts: r.try_get::<i64, _>("max_attempts")? as u32,
        run_at: r.try_get("run_at")?,
        lease_owner: owner.as_deref().map(parse_uuid).transpose()?,
        lease_expires_at: r.try_get("lease_expires_at")?,
        cancel_requested: r.try_get::<i64, _>("cancel_requested")? != 0,
        progress: parse_json(r.try_get("progress")?)?,
        error: parse_json(r.try_get("error")?)?,
        document_rev: r
            .try_get::<Option<i64>, _>("document_rev")?
            .map(|v| v as u64),
        idempotency_key: r.try_get("idempotency_key")?,
        request_hash: r.try_get("request_hash")?,
        created_at: r.try_get("created_at")?,
        started_at: r.try_get("started_at")?,
        finished_at: r.try_get("finished_at")?,
    })
}

fn doc_from_row(r: &SqliteRow) -> StoreResult<DocumentRecord> {
    let job: Option<String> = r.try_get("job_id")?;
    Ok(DocumentRecord {
        device: r.try_get("device")?,
        sensor: r.try_get("sensor")?,
        kind: r.try_get("kind")?,
        rev: r.try_get::<i64, _>("rev")? as u64,
        etag: r.try_get("etag")?,
        schema: r.try_get("schema")?,
        created_at: r.try_get("created_at")?,
        job_id: job.as_deref().map(parse_uuid).transpose()?,
        body: r.try_get("body")?,
    })
}

fn artifact_from_row(r: &SqliteRow) -> StoreResult<ArtifactRecord> {
    Ok(ArtifactRecord {
        name: r.try_get("name")?,
        media_type: r.try_get("media_type")?,
        sha256: r.try_get("sha256")?,
        size: r.try_get::<i64, _>("size")? as u64,
    })
}

impl SqliteStore {
    async fn load_files(&self, id: Uuid) -> StoreResult<Vec<DatasetFile>> {
        let rows = sqlx::query(
            "SELECT name, sha256, size, media_type, image FROM dataset_files WHERE dataset_id = ? ORDER BY idx",
        )
        .bind(id.to_string())
        .fetch_all(&self.read)
        .await?;
        rows.iter()
            .map(|r| {
                let image: Option<String> = r.try_get("image")?;
                Ok(DatasetFile {
                    name: r.try_get("name")?,
                    sha256: r.try_get("sha256")?,
                    size: r.try_get::<i64, _>("size")? as u64,
                    media_type: r.try_get("media_type")?,
                    image: image
                        .map(|t| serde_json::from_str(&t))
                        .transpose()
                        .map_err(|e| StoreError::Corrupt(e.to_string()))?,
                })
            })
            .collect()
    }

    fn dataset_from_row(r: &SqliteRow, files: Vec<DatasetFile>) -> StoreResult<DatasetRecord> {
        let kind: String = r.try_get("kind")?;
        Ok(DatasetRecord {
            id: parse_uuid(&r.try_get::<String, _>("id")?)?,
            kind: DatasetKind::parse(&kind)
                .ok_or_else(|| StoreError::Corrupt(format!("bad dataset kind {kind}")))?,
            created_at: r.try_get("created_at")?,
            total_bytes: r.try_get::<i64, _>("total_bytes")? as u64,
            sha256: r.try_get("sha256")?,
            files,
        })
    }
}

#[async_trait]
impl Store for SqliteStore {
    async fn ping(&self) -> StoreResult<()> {
        sqlx::query("SELECT 1").execute(&self.read).await?;
        Ok(())
    }

    async fn insert_dataset(&self, ds: &DatasetRecord) -> StoreResult<()> {
        let mut tx = self.write.begin().await?;
        sqlx::query(
            "INSERT INTO datasets (id, kind, created_at, total_bytes, sha256, file_count) VALUES (?, ?, ?, ?, ?, ?)",
        )
        .bind(ds.id.to_string())
        .bind(ds.kind.as_str())
        .bind(ds.created_at)
        .bind(ds.total_bytes as i64)
        .bind(&ds.sha256)
        .bind(ds.files.len() as i64)
        .execute(&mut *tx)
        .await?;
        for (i, f) in ds.files.iter().enumerate() {
            let image = f
                .image
                .as_ref()
                .map(serde_json::to_string)
                .transpose()
                .map_err(|e| StoreError::Corrupt(e.to_string()))?;
            sqlx::query(
                "INSERT INTO dataset_files (dataset_id, idx, name, sha256, size, media_type, image) VALUES (?, ?, ?, ?, ?, ?, ?)",
            )
            .bind(ds.id.to_string())
            .bind(i as i64)
            .bind(&f.name)
            .bind(&f.sha256)
            .bind(f.size as i64)
            .bind(&f.media_type)
            .bind(image)
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(())
    }

    async fn get_dataset(&self, id: Uuid) -> StoreResult<Option<DatasetRecord>> {
        let row = sqlx::query("SELECT * FROM datasets WHERE id = ?")
            .bind(id.to_string())
            .fetch_optional(&self.read)
            .await?;
        match row {
            None => Ok(None),
            Some(r) => {
                let files = self.load_files(id).await?;
                Ok(Some(Self::dataset_from_row(&r, files)?))
            }
        }
    }

    async fn list_datasets(
        &self,
        before_id: Option<Uuid>,
        limit: u32,
    ) -> StoreResult<Vec<DatasetRecord>> {
        let rows = sqlx::query(
            "SELECT * FROM datasets WHERE (? IS NULL OR id < ?) ORDER BY id DESC LIMIT ?",
        )
        .bind(before_id.map(|u| u.to_string()))
        .bind(before_id.map(|u| u.to_string()))
        .bind(limit as i64)
        .fetch_all(&self.read)
        .await?;
        let mut out = Vec::with_capacity(rows.len());
        for r in &rows {
            let id = parse_uuid(&r.try_get::<String, _>("id")?)?;
            let files = self.load_files(id).await?;
            out.push(Self::dataset_from_row(r, files)?);
        }
        Ok(out)
    }

    async fn delete_dataset(&self, id: Uuid) -> StoreResult<DeleteDataset> {
        let mut tx = self.write.begin().await?;
        let exists: Option<i64> = sqlx::query_scalar("SELECT 1 FROM datasets WHERE id = ?")
            .bind(id.to_string())
            .fetch_optional(&mut *tx)
            .await?;
        if exists.is_none() {
            return Ok(DeleteDataset::NotFound);
        }
        let users: Vec<String> = sqlx::query_scalar(
            "SELECT id FROM jobs WHERE dataset_id = ? AND status IN ('queued', 'running') ORDER BY id",
        )
        .bind(id.to_string())
        .fetch_all(&mut *tx)
        .await?;
        if !users.is_empty() {
            let ids = users
                .iter()
                .map(|s| parse_uuid(s))
                .collect::<StoreResult<Vec<_>>>()?;
            return Ok(DeleteDataset::InUse(ids));
        }
        let shas: Vec<String> =
            sqlx::query_scalar("SELECT DISTINCT sha256 FROM dataset_files WHERE dataset_id = ?")
                .bind(id.to_string())
                .fetch_all(&mut *tx)
                .await?;
        sqlx::query("DELETE FROM dataset_files WHERE dataset_id = ?")
            .bind(id.to_string())
            .execute(&mut *tx)
            .await?;
        sqlx::query("DELETE FROM datasets WHERE id = ?")
            .bind(id.to_string())
            .execute(&mut *tx)
            .await?;
        let orphans = unreferenced(&mut tx, shas).await?;
        tx.commit().await?;
        Ok(DeleteDataset::Deleted {
            orphan_blobs: orphans,
        })
    }

    async fn create_job(&self, job: NewJob, max_queued: u64) -> StoreResult<CreateJob> {
        let mut tx = self.write.begin().await?;
        if let Some(key) = &job.idempotency_key {
            let q = format!("SELECT {JOB_COLS} FROM jobs WHERE idempotency_key = ?");
            if let Some(r) = sqlx::query(AssertSqlSafe(q))
                .bind(key)
                .fetch_optional(&mut *tx)
                .await?
            {
                let existing = job_from_row(&r)?;
                return Ok(if existing.request_hash == job.request_hash {
                    CreateJob::Existing(existing)
                } else {
                    CreateJob::Conflict(existing)
                });
            }
        }
        let ds: Option<i64> = sqlx::query_scalar("SELECT 1 FROM datasets WHERE id = ?")
            .bind(job.dataset_id.to_string())
            .fetch_optional(&mut *tx)
            .await?;
        if ds.is_none() {
            return Ok(CreateJob::UnknownDataset);
        }
        let queued: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM jobs WHERE status = 'queued'")
            .fetch_one(&mut *tx)
            .await?;
        if queued as u64 >= max_queued {
            return Ok(CreateJob::QueueFull);
        }
        let q = format!(
            "INSERT INTO jobs (id, kind, dataset_id, device, sensor, params, status, max_attempts, run_at, \
             idempotency_key, request_hash, created_at) VALUES (?, ?, ?, ?, ?, ?, 'queued', ?, ?, ?, ?, ?) \
             RETURNING {JOB_COLS}"
        );
        let row = sqlx::query(AssertSqlSafe(q))
            .bind(job.id.to_string())
            .bind(&job.kind)
            .bind(job.dataset_id.to_string())
            .bind(&job.device)
            .bind(&job.sensor)
            .bind(job.params.to_string())
            .bind(job.max_attempts as i64)
            .bind(job.now)
            .bind(&job.idempotency_key)
            .bind(&job.request_hash)
            .bind(job.now)
            .fetch_one(&mut *tx)
            .await?;
        let rec = job_from_row(&row)?;
        tx.commit().await?;
        Ok(CreateJob::Created(rec))
    }

    async fn get_job(&self, id: Uuid) -> StoreResult<Option<JobRecord>> {
        let q = format!("SELECT {JOB_COLS} FROM jobs WHERE id = ?");
        sqlx::query(AssertSqlSafe(q))
            .bind(id.to_string())
            .fetch_optional(&self.read)
            .await?
            .as_ref()
            .map(job_from_row)
            .transpose()
    }

    async fn get_job_result(&self, id: Uuid) -> StoreResult<Option<String>> {
        let r: Option<Option<String>> =
            sqlx::query_scalar("SELECT result FROM jobs WHERE id = ? AND status = 'succeeded'")
                .bind(id.to_string())
                .fetch_optional(&self.read)
                .await?;
        Ok(r.flatten())
    }

    async fn list_jobs(&self, f: &JobFilter) -> StoreResult<Vec<JobRecord>> {
        // Built from fixed fragments only; every value is bound.
        let mut q = format!("SELECT {JOB_COLS} FROM jobs WHERE 1 = 1");
        if !f.statuses.is_empty() {
            q.push_str(&format!(
                " AND status IN ({})",
                vec!["?"; f.statuses.len()].join(", ")
            ));
        }
        if !f.kinds.is_empty() {
            q.push_str(&format!(
                " AND kind IN ({})",
                vec!["?"; f.kinds.len()].join(", ")
            ));
        }
        if f.device.is_some() {
            q.push_str(" AND device = ?");
        }
        if f.dataset.is_some() {
            q.push_str(" AND dataset_id = ?");
        }
        if f.created_after.is_some() {
            q.push_str(" AND created_at >= ?");
        }
        if f.created_before.is_some() {
            q.push_str(" AND created_at < ?");
        }
        if f.before_id.is_some() {
            q.push_str(" AND id < ?");
        }
        q.push_str(" ORDER BY id DESC LIMIT ?");
        let mut query = sqlx::query(AssertSqlSafe(q));
        for s in &f.statuses {
            query = query.bind(s.as_str());
        }
        for k in &f.kinds {
            query = query.bind(k.clone());
        }
        if let Some(d) = &f.device {
            query = query.bind(d.clone());
        }
        if let Some(d) = f.dataset {
            query = query.bind(d.to_string());
        }
        if let Some(t) = f.created_after {
            query = query.bind(t);
        }
        if let Some(t) = f.created_before {
            query = query.bind(t);
        }
        if let Some(id) = f.before_id {
            query = query.bind(id.to_string());
        }
        query = query.bind(f.limit as i64);
        let rows = query.fetch_all(&self.read).await?;
        rows.iter().map(job_from_row).collect()
    }

    async fn cancel_job(&self, id: Uuid, now: i64) -> StoreResult<CancelJob> {
        let mut tx = self.write.begin().await?;
        let q = format!("SELECT {JOB_COLS} FROM jobs WHERE id = ?");
        let Some(row) = sqlx::query(AssertSqlSafe(q))
            .bind(id.to_string())
            .fetch_optional(&mut *tx)
            .await?
        else {
            return Ok(CancelJob::NotFound);
        };
        let job = job_from_row(&row)?;
        let outcome = match job.status {
            JobStatus::Queued => {
                let q = format!(
                    "UPDATE jobs SET status = 'canceled', cancel_requested = 1, finished_at = ?, \
                     error = ? WHERE id = ? AND status = 'queued' RETURNING {JOB_COLS}"
                );
                let err = serde_json::json!({"code": "canceled", "message": "canceled before it started"});
                let r = sqlx::query(AssertSqlSafe(q))
                    .bind(now)
                    .bind(err.to_string())
                    .bind(id.to_string())
                    .fetch_one(&mut *tx)
                    .await?;
                CancelJob::Canceled(job_from_row(&r)?)
            }
            JobStatus::Running => {
                let q = format!(
                    "UPDATE jobs SET cancel_requested = 1 WHERE id = ? RETURNING {JOB_COLS}"
                );
                let r = sqlx::query(AssertSqlSafe(q))
                    .bind(id.to_string())
                    .fetch_one(&mut *tx)
                    .await?;
                CancelJob::Requested(job_from_row(&r)?)
            }
            _ => CancelJob::Finished(job),
        };
        tx.commit().await?;
        Ok(outcome)
    }

    async fn queue_depth(&self) -> StoreResult<(u64, u64)> {
        let row = sqlx::query(
            "SELECT COALESCE(SUM(status = 'queued'), 0) AS q, COALESCE(SUM(status = 'running'), 0) AS r \
             FROM jobs WHERE status IN ('queued', 'running')",
        )
        .fetch_one(&self.read)
        .await?;
        Ok((
            row.try_get::<i64, _>("q")? as u64,
            row.try_get::<i64, _>("r")? as u64,
        ))
    }

    async fn claim_job(
        &self,
        owner: Uuid,
        now: i64,
        lease_until: i64,
    ) -> StoreResult<Option<JobRecord>> {
        let mut tx = self.write.begin().await?;
        let q = format!(
            "UPDATE jobs SET status = 'running', attempt = attempt + 1, lease_owner = ?, \
             lease_expires_at = ?, started_at = COALESCE(started_at, ?), progress = NULL \
             WHERE id = (SELECT id FROM jobs WHERE status = 'queued' AND run_at <= ? \
                         ORDER BY run_at, id LIMIT 1) \
             RETURNING {JOB_COLS}"
        );
        let row = sqlx::query(AssertSqlSafe(q))
            .bind(owner.to_string())
            .bind(lease_until)
            .bind(now)
            .bind(now)
            .fetch_optional(&mut *tx)
            .await?;
        let Some(row) = row else {
            return Ok(None);
        };
        let job = job_from_row(&row)?;
        sqlx::query(
            "INSERT OR REPLACE INTO job_attempts (job_id, attempt, worker, started_at) VALUES (?, ?, ?, ?)",
        )
        .bind(job.id.to_string())
        .bind(job.attempt as i64)
        .bind(owner.to_string())
        .bind(now)
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(Some(job))
    }

    async fn heartbeat(
        &self,
        id: Uuid,
        owner: Uuid,
        attempt: u32,
        lease_until: i64,
        progress: Option<&Value>,
    ) -> StoreResult<Heartbeat> {
        let row = sqlx::query(
            "UPDATE jobs SET lease_expires_at = ?, progress = COALESCE(?, progress) \
             WHERE id = ? AND status = 'running' AND lease_owner = ? AND attempt = ? \
             RETURNING cancel_requested",
        )
        .bind(lease_until)
        .bind(progress.map(Value::to_string))
        .bind(id.to_string())
        .bind(owner.to_string())
        .bind(attempt as i64)
        .fetch_optional(&self.write)
        .await?;
        Ok(match row {
            None => Heartbeat::Lost,
            Some(r) => Heartbeat::Renewed {
                cancel: r.try_get::<i64, _>("cancel_requested")? != 0,
            },
        })
    }

    async fn finish_job(
        &self,
        id: Uuid,
        owner: Uuid,
        attempt: u32,
        now: i64,
        finish: Finish,
    ) -> StoreResult<bool> {
        let mut tx = self.write.begin().await?;
        // Fence: only the current lease holder may finish the attempt.
        let current: Option<(i64, i64, String)> = sqlx::query_as(
            "SELECT attempt, max_attempts, kind FROM jobs WHERE id = ? AND status = 'running' \
             AND lease_owner = ? AND attempt = ?",
        )
        .bind(id.to_string())
        .bind(owner.to_string())
        .bind(attempt as i64)
        .fetch_optional(&mut *tx)
        .await?;
        let Some((attempt_now, max_attempts, _kind)) = current else {
            return Ok(false);
        };
        let (outcome, error_text) = match &finish {
            Finish::Succeeded { .. } => ("succeeded", None),
            Finish::Failed { error } => ("failed", Some(error.to_string())),
            Finish::Retry { error, .. } => ("retry", Some(error.to_string())),
            Finish::Canceled => ("canceled", None),
        };
        sqlx::query(
            "UPDATE job_attempts SET finished_at = ?, outcome = ?, error = ? WHERE job_id = ? AND attempt = ?",
        )
        .bind(now)
        .bind(outcome)
        .bind(&error_text)
        .bind(id.to_string())
        .bind(attempt as i64)
        .execute(&mut *tx)
        .await?;
        match finish {
            Finish::Succeeded {
                result,
                document,
                artifacts,
            } => {
                let rev = match &document {
                    Some(d) => {
                        let max: i64 = sqlx::query_scalar(
                            "SELECT COALESCE(MAX(rev), 0) FROM documents WHERE device = ? AND sensor = ? AND kind = ?",
                        )
                        .bind(&d.device)
                        .bind(&d.sensor)
                        .bind(&d.kind)
                        .fetch_one(&mut *tx)
                        .await?;
                        Some(max as u64 + 1)
                    }
                    None => None,
                };
                let (body, etag) = document::seal(result, rev);
                if let (Some(d), Some(rev)) = (&document, rev) {
                    sqlx::query(
                        "INSERT INTO documents (device, sensor, kind, rev, etag, schema, created_at, job_id, body) \
                         VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    )
                    .bind(&d.device)
                    .bind(&d.sensor)
                    .bind(&d.kind)
                    .bind(rev as i64)
                    .bind(&etag)
                    .bind(&d.schema)
                    .bind(now)
                    .bind(id.to_string())
                    .bind(&body)
                    .execute(&mut *tx)
                    .await?;
                }
                for a in &artifacts {
                    sqlx::query(
                        "INSERT OR REPLACE INTO artifacts (job_id, name, media_type, sha256, size) VALUES (?, ?, ?, ?, ?)",
                    )
                    .bind(id.to_string())
                    .bind(&a.name)
                    .bind(&a.media_type)
                    .bind(&a.sha256)
                    .bind(a.size as i64)
                    .execute(&mut *tx)
                    .await?;
                }
                sqlx::query(
                    "UPDATE jobs SET status = 'succeeded', result = ?, document_rev = ?, finished_at = ?, \
                     lease_owner = NULL, lease_expires_at = NULL, error = NULL, \
                     progress = json_set(COALESCE(progress, '{}'), '$.percent', 100.0) WHERE id = ?",
                )
                .bind(body)
                .bind(rev.map(|r| r as i64))
                .bind(now)
                .bind(id.to_string())
                .execute(&mut *tx)
                .await?;
            }
            Finish::Failed { error } => {
                sqlx::query(
                    "UPDATE jobs SET status = 'failed', error = ?, finished_at = ?, lease_owner = NULL, \
                     lease_expires_at = NULL WHERE id = ?",
                )
                .bind(error.to_string())
                .bind(now)
                .bind(id.to_string())
                .execute(&mut *tx)
                .await?;
            }
            Finish::Retry { error, run_at } => {
                if attempt_now >= max_attempts {
                    let mut e = error.clone();
                    if let Value::Object(m) = &mut e {
                        m.insert("attempts_exhausted".into(), Value::from(attempt_now));
                    }
                    sqlx::query(
                        "UPDATE jobs SET status = 'failed', error = ?, finished_at = ?, lease_owner = NULL, \
                         lease_expires_at = NULL WHERE id = ?",
                    )
                    .bind(e.to_string())
                    .bind(now)
                    .bind(id.to_string())
                    .execute(&mut *tx)
                    .await?;
                } else {
                    sqlx::query(
                        "UPDATE jobs SET status = 'queued', error = ?, run_at = ?, lease_owner = NULL, \
                         lease_expires_at = NULL WHERE id = ?",
                    )
                    .bind(error.to_string())
                    .bind(run_at)
                    .bind(id.to_string())
                    .execute(&mut *tx)
                    .await?;
                }
            }
            Finish::Canceled => {
                let err =
                    serde_json::json!({"code": "canceled", "message": "canceled while running"});
                sqlx::query(
                    "UPDATE jobs SET status = 'canceled', error = ?, finished_at = ?, lease_owner = NULL, \
                     lease_expires_at = NULL WHERE id = ?",
                )
                .bind(err.to_string())
                .bind(now)
                .bind(id.to_string())
                .execute(&mut *tx)
                .await?;
            }
        }
        tx.commit().await?;
        Ok(true)
    }

    async fn recover_leases(&self, now: i64, all: bool) -> StoreResult<u64> {
        let mut tx = self.write.begin().await?;
        let cond = if all {
            "status = 'running'"
        } else {
            "status = 'running' AND lease_expires_at < ?"
        };
        let err = serde_json::json!({"code": "lease_lost", "message": "the worker running this job stopped (crash or restart); attempts exhausted"});
        let attempt_close = format!(
            "UPDATE job_attempts SET finished_at = ?, outcome = 'lease_lost' WHERE finished_at IS NULL \
             AND job_id IN (SELECT id FROM jobs WHERE {cond})"
        );
        let mut q = sqlx::query(AssertSqlSafe(attempt_close)).bind(now);
        if !all {
            q = q.bind(now);
        }
        q.execute(&mut *tx).await?;
        let fail = format!(
            "UPDATE jobs SET status = 'failed', finished_at = ?, error = ?, lease_owner = NULL, \
             lease_expires_at = NULL WHERE {cond} AND attempt >= max_attempts"
        );
        let mut q = sqlx::query(AssertSqlSafe(fail))
            .bind(now)
            .bind(err.to_string());
        if !all {
            q = q.bind(now);
        }
        let failed = q.execute(&mut *tx).await?.rows_affected();
        let requeue = format!(
            "UPDATE jobs SET status = 'queued', run_at = ?, lease_owner = NULL, lease_expires_at = NULL \
             WHERE {cond}"
        );
        let mut q = sqlx::query(AssertSqlSafe(requeue)).bind(now);
        if !all {
            q = q.bind(now);
        }
        let requeued = q.execute(&mut *tx).await?.rows_affected();
        tx.commit().await?;
        Ok(failed + requeued)
    }

    async fn prune_jobs(&self, before: i64) -> StoreResult<Vec<String>> {
        let mut tx = self.write.begin().await?;
        let ids: Vec<String> = sqlx::query_scalar(
            "SELECT id FROM jobs WHERE status IN ('succeeded', 'failed', 'canceled') AND finished_at < ?",
        )
        .bind(before)
        .fetch_all(&mut *tx)
        .await?;
        let mut candidates = Vec::new();
        for id in &ids {
            let shas: Vec<String> =
                sqlx::query_scalar("SELECT sha256 FROM artifacts WHERE job_id = ?")
                    .bind(id)
                    .fetch_all(&mut *tx)
                    .await?;
            candidates.extend(shas);
            for table in [
                "DELETE FROM artifacts WHERE job_id = ?",
                "DELETE FROM job_attempts WHERE job_id = ?",
                "DELETE FROM jobs WHERE id = ?",
            ] {
                sqlx::query(table).bind(id).execute(&mut *tx).await?;
            }
        }
        candidates.sort();
        candidates.dedup();
        let orphans = unreferenced(&mut tx, candidates).await?;
        tx.commit().await?;
        Ok(orphans)
    }

    async fn list_artifacts(&self, job: Uuid) -> StoreResult<Vec<ArtifactRecord>> {
        let rows = sqlx::query("SELECT * FROM artifacts WHERE job_id = ? ORDER BY name")
            .bind(job.to_string())
            .fetch_all(&self.read)
            .await?;
        rows.iter().map(artifact_from_row).collect()
    }

    async fn get_artifact(&self, job: Uuid, name: &str) -> StoreResult<Option<ArtifactRecord>> {
        sqlx::query("SELECT * FROM artifacts WHERE job_id = ? AND name = ?")
            .bind(job.to_string())
            .bind(name)
            .fetch_optional(&self.read)
            .await?
            .as_ref()
            .map(artifact_from_row)
            .transpose()
    }

    async fn list_documents(&self, device: &str) -> StoreResult<Vec<DocumentSummary>> {
        let rows = sqlx::query(
            "SELECT d.* FROM documents d JOIN (SELECT sensor, kind, MAX(rev) AS rev FROM documents \
             WHERE device = ? GROUP BY sensor, kind) m ON d.sensor = m.sensor AND d.kind = m.kind \
             AND d.rev = m.rev WHERE d.device = ? ORDER BY d.sensor, d.kind",
        )
        .bind(device)
        .bind(device)
        .fetch_all(&self.read)
        .await?;
        rows.iter()
            .map(|r| {
                let d = doc_from_row(r)?;
                Ok(DocumentSummary {
                    sensor: d.sensor,
                    kind: d.kind,
                    schema: d.schema,
                    latest_rev: d.rev,
                    etag: d.etag,
                    created_at: crate::clock::rfc3339(d.created_at),
                })
            })
            .collect()
    }

    async fn get_document(
        &self,
        device: &str,
        sensor: &str,
        kind: &str,
        rev: Option<u64>,
    ) -> StoreResult<Option<DocumentRecord>> {
        let row = match rev {
            Some(rev) => {
                sqlx::query(
                    "SELECT * FROM documents WHERE device = ? AND sensor = ? AND kind = ? AND rev = ?",
                )
                .bind(device)
                .bind(sensor)
                .bind(kind)
                .bind(rev as i64)
                .fetch_optional(&self.read)
                .await?
            }
            None => {
                sqlx::query(
                    "SELECT * FROM documents WHERE device = ? AND sensor = ? AND kind = ? ORDER BY rev DESC LIMIT 1",
                )
                .bind(device)
                .bind(sensor)
                .bind(kind)
                .fetch_optional(&self.read)
                .await?
            }
        };
        row.as_ref().map(doc_from_row).transpose()
    }

    async fn list_revisions(
        &self,
        device: &str,
        sensor: &str,
        kind: &str,
    ) -> StoreResult<Vec<DocumentRecord>> {
        let rows = sqlx::query(
            "SELECT * FROM documents WHERE device = ? AND sensor = ? AND kind = ? ORDER BY rev DESC",
        )
        .bind(device)
        .bind(sensor)
        .bind(kind)
        .fetch_all(&self.read)
        .await?;
        rows.iter().map(doc_from_row).collect()
    }
}
