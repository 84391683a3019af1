//! The job queue: creation with idempotency keys, claims with leases, heartbeats, fenced
//! completion, lease recovery, retention, and the artifacts of finished jobs.

use async_trait::async_trait;
use serde_json::Value;
use sqlx::sqlite::SqliteRow;
use sqlx::{AssertSqlSafe, Row};
use uuid::Uuid;

use super::{SqliteStore, parse_json, parse_uuid, queue_gc};
use crate::store::*;

const JOB_COLS: &str = "id, kind, dataset_id, device, sensor, params, status, attempt, max_attempts, \
    run_at, lease_owner, lease_expires_at, cancel_requested, progress, error, document_rev, \
    idempotency_key, request_hash, created_at, started_at, finished_at";

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

fn artifact_from_row(r: &SqliteRow) -> StoreResult<ArtifactRecord> {
    Ok(ArtifactRecord {
        name: r.try_get("name")?,
        media_type: r.try_get("media_type")?,
        sha256: r.try_get("sha256")?,
        size: r.try_get::<i64, _>("size")? as u64,
    })
}

#[async_trait]
impl JobQueue for SqliteStore {
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
             idempotency_key, request_hash, created_at, aux_dataset_id) VALUES (?, ?, ?, ?, ?, ?, 'queued', ?, ?, ?, ?, ?, ?) \
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
            .bind(job.aux_dataset_id.map(|u| u.to_string()))
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
        if f.devices.is_some() {
            q.push_str(" AND device IN (SELECT value FROM json_each(?))");
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
        if let Some(d) = &f.devices {
            query = query
                .bind(serde_json::to_string(d).map_err(|e| StoreError::Corrupt(e.to_string()))?);
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
            Finish::Requeue { error } => ("shutdown", Some(error.to_string())),
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
                seal,
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
                let Sealed { body, etag } = seal(rev);
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
            Finish::Requeue { error } => {
                sqlx::query(
                    "UPDATE jobs SET status = 'queued', error = ?, run_at = ?, lease_owner = NULL, \
                     lease_expires_at = NULL, max_attempts = max_attempts + 1 WHERE id = ?",
                )
                .bind(error.to_string())
                .bind(now)
                .bind(id.to_string())
                .execute(&mut *tx)
                .await?;
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

    async fn prune_jobs(&self, before: i64) -> StoreResult<u64> {
        let mut tx = self.write.begin().await?;
        let ids: Vec<String> = sqlx::query_scalar(
            "SELECT id FROM jobs WHERE status IN ('succeeded', 'failed', 'canceled') AND finished_at < ? \
             AND id NOT IN (SELECT job_id FROM documents WHERE job_id IS NOT NULL)",
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
        queue_gc(&mut tx, &candidates, crate::clock::now_ms()).await?;
        tx.commit().await?;
        Ok(ids.len() as u64)
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
}
