//! The job queue on PostgreSQL: idempotent creation, `SKIP LOCKED` claims, leases on the
//! database clock, fenced completion, gap-free document revisions, retention, artifacts.

use async_trait::async_trait;
use serde_json::Value;
use sqlx::postgres::PgRow;
use sqlx::{AssertSqlSafe, Row};
use uuid::Uuid;

use super::{DB_NOW, JOBS_CHANNEL, PgStore, parse_json, parse_uuid, queue_gc};
use crate::store::*;

const JOB_COLS: &str = "id, kind, dataset_id, device, sensor, params, status, attempt, max_attempts, \
    run_at, lease_owner, lease_expires_at, cancel_requested, progress, error, document_rev, \
    idempotency_key, request_hash, created_at, started_at, finished_at";

fn job_from_row(r: &PgRow) -> StoreResult<JobRecord> {
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
        cancel_requested: r.try_get("cancel_requested")?,
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

fn artifact_from_row(r: &PgRow) -> StoreResult<ArtifactRecord> {
    Ok(ArtifactRecord {
        name: r.try_get("name")?,
        media_type: r.try_get("media_type")?,
        sha256: r.try_get("sha256")?,
        size: r.try_get::<i64, _>("size")? as u64,
    })
}

/// Set a job's terminal or queued state after its attempt; `status`, `error`, times.
async fn set_job(
    tx: &mut sqlx::Transaction<'_, sqlx::Postgres>,
    sql: &'static str,
    error: Option<String>,
    time: i64,
    id: Uuid,
) -> StoreResult<()> {
    sqlx::query(sql)
        .bind(error)
        .bind(time)
        .bind(id.to_string())
        .execute(&mut **tx)
        .await?;
    Ok(())
}

#[async_trait]
impl JobQueue for PgStore {
    async fn create_job(&self, job: NewJob, max_queued: u64) -> StoreResult<CreateJob> {
        let mut tx = self.pool.begin().await?;
        if let Some(key) = &job.idempotency_key {
            // Two replicas given the same key at once: the loser waits here for the winner's
            // commit, then finds its job.
            sqlx::query("SELECT pg_advisory_xact_lock(hashtextextended('idem:' || $1, 0))")
                .bind(key)
                .execute(&mut *tx)
                .await?;
            let q = format!("SELECT {JOB_COLS} FROM jobs WHERE idempotency_key = $1");
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
        // Share-lock the dataset row: a concurrent delete waits, or we see it gone.
        let ds: Option<String> =
            sqlx::query_scalar("SELECT id FROM datasets WHERE id = $1 FOR SHARE")
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
             idempotency_key, request_hash, created_at, aux_dataset_id) VALUES ($1, $2, $3, $4, $5, $6, 'queued', $7, $8, $9, $10, $8, $11) \
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
            .bind(job.aux_dataset_id.map(|u| u.to_string()))
            .fetch_one(&mut *tx)
            .await?;
        let rec = job_from_row(&row)?;
        tx.commit().await?;
        self.notify(JOBS_CHANNEL, &rec.id.to_string()).await;
        Ok(CreateJob::Created(rec))
    }

    async fn get_job(&self, id: Uuid) -> StoreResult<Option<JobRecord>> {
        let q = format!("SELECT {JOB_COLS} FROM jobs WHERE id = $1");
        sqlx::query(AssertSqlSafe(q))
            .bind(id.to_string())
            .fetch_optional(&self.pool)
            .await?
            .as_ref()
            .map(job_from_row)
            .transpose()
    }

    async fn get_job_result(&self, id: Uuid) -> StoreResult<Option<String>> {
        let r: Option<Option<String>> =
            sqlx::query_scalar("SELECT result FROM jobs WHERE id = $1 AND status = 'succeeded'")
                .bind(id.to_string())
                .fetch_optional(&self.pool)
                .await?;
        Ok(r.flatten())
    }

    async fn list_jobs(&self, f: &JobFilter) -> StoreResult<Vec<JobRecord>> {
        let statuses: Vec<&str> = f.statuses.iter().map(|s| s.as_str()).collect();
        let q = format!(
            "SELECT {JOB_COLS} FROM jobs WHERE \
             (cardinality($1::TEXT[]) = 0 OR status = ANY($1)) \
             AND (cardinality($2::TEXT[]) = 0 OR kind = ANY($2)) \
             AND ($3::TEXT IS NULL OR device = $3) \
             AND ($4::TEXT[] IS NULL OR device = ANY($4)) \
             AND ($5::TEXT IS NULL OR dataset_id = $5) \
             AND ($6::BIGINT IS NULL OR created_at >= $6) \
             AND ($7::BIGINT IS NULL OR created_at < $7) \
             AND ($8::TEXT IS NULL OR id < $8) \
             ORDER BY id DESC LIMIT $9"
        );
        let rows = sqlx::query(AssertSqlSafe(q))
            .bind(statuses)
            .bind(&f.kinds)
            .bind(&f.device)
            .bind(&f.devices)
            .bind(f.dataset.map(|d| d.to_string()))
            .bind(f.created_after)
            .bind(f.created_before)
            .bind(f.before_id.map(|d| d.to_string()))
            .bind(f.limit as i64)
            .fetch_all(&self.pool)
            .await?;
        rows.iter().map(job_from_row).collect()
    }

    async fn cancel_job(&self, id: Uuid, now: i64) -> StoreResult<CancelJob> {
        let mut tx = self.pool.begin().await?;
        let q = format!("SELECT {JOB_COLS} FROM jobs WHERE id = $1 FOR UPDATE");
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
                    "UPDATE jobs SET status = 'canceled', cancel_requested = TRUE, finished_at = $1, \
                     error = $2 WHERE id = $3 RETURNING {JOB_COLS}"
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
                    "UPDATE jobs SET cancel_requested = TRUE WHERE id = $1 RETURNING {JOB_COLS}"
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
            "SELECT COUNT(*) FILTER (WHERE status = 'queued') AS q, \
             COUNT(*) FILTER (WHERE status = 'running') AS r \
             FROM jobs WHERE status IN ('queued', 'running')",
        )
        .fetch_one(&self.pool)
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
        let lease_ms = (lease_until - now).max(1);
        let mut tx = self.pool.begin().await?;
        let q = format!(
            "UPDATE jobs SET status = 'running', attempt = attempt + 1, lease_owner = $1, \
             lease_expires_at = {DB_NOW} + $2, started_at = COALESCE(started_at, $3), progress = NULL \
             WHERE id = (SELECT id FROM jobs WHERE status = 'queued' AND run_at <= $3 \
                         ORDER BY run_at, id LIMIT 1 FOR UPDATE SKIP LOCKED) \
             RETURNING {JOB_COLS}"
        );
        let row = sqlx::query(AssertSqlSafe(q))
            .bind(owner.to_string())
            .bind(lease_ms)
            .bind(now)
            .fetch_optional(&mut *tx)
            .await?;
        let Some(row) = row else {
            return Ok(None);
        };
        let job = job_from_row(&row)?;
        sqlx::query(
            "INSERT INTO job_attempts (job_id, attempt, worker, started_at) VALUES ($1, $2, $3, $4) \
             ON CONFLICT (job_id, attempt) DO UPDATE SET worker = EXCLUDED.worker, \
             started_at = EXCLUDED.started_at, finished_at = NULL, outcome = NULL, error = NULL",
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
        let lease_ms = (lease_until - crate::clock::now_ms()).max(1);
        let q = format!(
            "UPDATE jobs SET lease_expires_at = {DB_NOW} + $1, progress = COALESCE($2, progress) \
             WHERE id = $3 AND status = 'running' AND lease_owner = $4 AND attempt = $5 \
             RETURNING cancel_requested"
        );
        let row = sqlx::query(AssertSqlSafe(q))
            .bind(lease_ms)
            .bind(progress.map(Value::to_string))
            .bind(id.to_string())
            .bind(owner.to_string())
            .bind(attempt as i64)
            .fetch_optional(&self.pool)
            .await?;
        Ok(match row {
            None => Heartbeat::Lost,
            Some(r) => Heartbeat::Renewed {
                cancel: r.try_get("cancel_requested")?,
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
        let mut tx = self.pool.begin().await?;
        // Fence: only the current lease holder may finish the attempt; the row lock keeps a
        // concurrent lease recovery from re-queueing it meanwhile.
        let current: Option<(i64, i64)> = sqlx::query_as(
            "SELECT attempt, max_attempts FROM jobs WHERE id = $1 AND status = 'running' \
             AND lease_owner = $2 AND attempt = $3 FOR UPDATE",
        )
        .bind(id.to_string())
        .bind(owner.to_string())
        .bind(attempt as i64)
        .fetch_optional(&mut *tx)
        .await?;
        let Some((attempt_now, max_attempts)) = current else {
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
            "UPDATE job_attempts SET finished_at = $1, outcome = $2, error = $3 WHERE job_id = $4 AND attempt = $5",
        )
        .bind(now)
        .bind(outcome)
        .bind(&error_text)
        .bind(id.to_string())
        .bind(attempt as i64)
        .execute(&mut *tx)
        .await?;
        let mut requeued = false;
        match finish {
            Finish::Succeeded {
                seal,
                document,
                artifacts,
            } => {
                let rev = match &document {
                    Some(d) => {
                        // One writer per (device, sensor, kind) at a time: the next rev is
                        // MAX + 1 with neither gaps nor duplicates across replicas.
                        sqlx::query(
                            "SELECT pg_advisory_xact_lock(hashtextextended('doc:' || $1 || '/' || $2 || '/' || $3, 0))",
                        )
                        .bind(&d.device)
                        .bind(&d.sensor)
                        .bind(&d.kind)
                        .execute(&mut *tx)
                        .await?;
                        let max: i64 = sqlx::query_scalar(
                            "SELECT COALESCE(MAX(rev), 0) FROM documents WHERE device = $1 AND sensor = $2 AND kind = $3",
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
                         VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9)",
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
                        "INSERT INTO artifacts (job_id, name, media_type, sha256, size) VALUES ($1, $2, $3, $4, $5) \
                         ON CONFLICT (job_id, name) DO UPDATE SET media_type = EXCLUDED.media_type, \
                         sha256 = EXCLUDED.sha256, size = EXCLUDED.size",
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
                    "UPDATE jobs SET status = 'succeeded', result = $1, document_rev = $2, finished_at = $3, \
                     lease_owner = NULL, lease_expires_at = NULL, error = NULL, \
                     progress = (COALESCE(progress::jsonb, '{}'::jsonb) || '{\"percent\": 100.0}'::jsonb)::text \
                     WHERE id = $4",
                )
                .bind(body)
                .bind(rev.map(|r| r as i64))
                .bind(now)
                .bind(id.to_string())
                .execute(&mut *tx)
                .await?;
            }
            Finish::Failed { error } => {
                set_job(
                    &mut tx,
                    "UPDATE jobs SET status = 'failed', error = $1, finished_at = $2, lease_owner = NULL, \
                     lease_expires_at = NULL WHERE id = $3",
                    Some(error.to_string()),
                    now,
                    id,
                )
                .await?;
            }
            Finish::Retry { error, run_at } => {
                if attempt_now >= max_attempts {
                    let mut e = error.clone();
                    if let Value::Object(m) = &mut e {
                        m.insert("attempts_exhausted".into(), Value::from(attempt_now));
                    }
                    set_job(
                        &mut tx,
                        "UPDATE jobs SET status = 'failed', error = $1, finished_at = $2, lease_owner = NULL, \
                         lease_expires_at = NULL WHERE id = $3",
                        Some(e.to_string()),
                        now,
                        id,
                    )
                    .await?;
                } else {
                    set_job(
                        &mut tx,
                        "UPDATE jobs SET status = 'queued', error = $1, run_at = $2, lease_owner = NULL, \
                         lease_expires_at = NULL WHERE id = $3",
                        Some(error.to_string()),
                        run_at,
                        id,
                    )
                    .await?;
                    requeued = true;
                }
            }
            Finish::Requeue { error } => {
                set_job(
                    &mut tx,
                    "UPDATE jobs SET status = 'queued', error = $1, run_at = $2, lease_owner = NULL, \
                     lease_expires_at = NULL, max_attempts = max_attempts + 1 WHERE id = $3",
                    Some(error.to_string()),
                    now,
                    id,
                )
                .await?;
                requeued = true;
            }
            Finish::Canceled => {
                let err =
                    serde_json::json!({"code": "canceled", "message": "canceled while running"});
                set_job(
                    &mut tx,
                    "UPDATE jobs SET status = 'canceled', error = $1, finished_at = $2, lease_owner = NULL, \
                     lease_expires_at = NULL WHERE id = $3",
                    Some(err.to_string()),
                    now,
                    id,
                )
                .await?;
            }
        }
        tx.commit().await?;
        if requeued {
            self.notify(JOBS_CHANNEL, &id.to_string()).await;
        }
        Ok(true)
    }

    async fn recover_leases(&self, now: i64, all: bool) -> StoreResult<u64> {
        // Shared by replicas: "all running jobs" would steal live leases of other replicas,
        // so only expired leases are ever recovered here (by the database's clock).
        let _ = all;
        let mut tx = self.pool.begin().await?;
        let expired: Vec<String> = sqlx::query_scalar(AssertSqlSafe(format!(
            "SELECT id FROM jobs WHERE status = 'running' AND lease_expires_at < {DB_NOW} FOR UPDATE SKIP LOCKED"
        )))
        .fetch_all(&mut *tx)
        .await?;
        if expired.is_empty() {
            return Ok(0);
        }
        let err = serde_json::json!({"code": "lease_lost", "message": "the worker running this job stopped (crash or restart); attempts exhausted"});
        sqlx::query(
            "UPDATE job_attempts SET finished_at = $1, outcome = 'lease_lost' WHERE finished_at IS NULL \
             AND job_id = ANY($2)",
        )
        .bind(now)
        .bind(&expired)
        .execute(&mut *tx)
        .await?;
        let failed = sqlx::query(
            "UPDATE jobs SET status = 'failed', finished_at = $1, error = $2, lease_owner = NULL, \
             lease_expires_at = NULL WHERE id = ANY($3) AND attempt >= max_attempts",
        )
        .bind(now)
        .bind(err.to_string())
        .bind(&expired)
        .execute(&mut *tx)
        .await?
        .rows_affected();
        let requeued = sqlx::query(
            "UPDATE jobs SET status = 'queued', run_at = $1, lease_owner = NULL, lease_expires_at = NULL \
             WHERE id = ANY($2) AND status = 'running'",
        )
        .bind(now)
        .bind(&expired)
        .execute(&mut *tx)
        .await?
        .rows_affected();
        tx.commit().await?;
        if requeued > 0 {
            self.notify(JOBS_CHANNEL, "recovered").await;
        }
        Ok(failed + requeued)
    }

    async fn prune_jobs(&self, before: i64) -> StoreResult<u64> {
        let mut tx = self.pool.begin().await?;
        let ids: Vec<String> = sqlx::query_scalar(
            "SELECT id FROM jobs WHERE status IN ('succeeded', 'failed', 'canceled') AND finished_at < $1 \
             AND id NOT IN (SELECT job_id FROM documents WHERE job_id IS NOT NULL) FOR UPDATE SKIP LOCKED",
        )
        .bind(before)
        .fetch_all(&mut *tx)
        .await?;
        let mut candidates: Vec<String> =
            sqlx::query_scalar("SELECT DISTINCT sha256 FROM artifacts WHERE job_id = ANY($1)")
                .bind(&ids)
                .fetch_all(&mut *tx)
                .await?;
        for sql in [
            "DELETE FROM artifacts WHERE job_id = ANY($1)",
            "DELETE FROM job_attempts WHERE job_id = ANY($1)",
            "DELETE FROM jobs WHERE id = ANY($1)",
        ] {
            sqlx::query(sql).bind(&ids).execute(&mut *tx).await?;
        }
        candidates.sort();
        queue_gc(&mut tx, &candidates, crate::clock::now_ms()).await?;
        tx.commit().await?;
        Ok(ids.len() as u64)
    }

    async fn list_artifacts(&self, job: Uuid) -> StoreResult<Vec<ArtifactRecord>> {
        let rows = sqlx::query("SELECT * FROM artifacts WHERE job_id = $1 ORDER BY name")
            .bind(job.to_string())
            .fetch_all(&self.pool)
            .await?;
        rows.iter().map(artifact_from_row).collect()
    }

    async fn get_artifact(&self, job: Uuid, name: &str) -> StoreResult<Option<ArtifactRecord>> {
        sqlx::query("SELECT * FROM artifacts WHERE job_id = $1 AND name = $2")
            .bind(job.to_string())
            .bind(name)
            .fetch_optional(&self.pool)
            .await?
            .as_ref()
            .map(artifact_from_row)
            .transpose()
    }
}
