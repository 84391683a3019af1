//! The production profile's store: PostgreSQL, shared by any number of replicas.
//!
//! What SQLite gets from its single writer, PostgreSQL gets from row locks and advisory locks:
//! claims take the oldest runnable job with `FOR UPDATE SKIP LOCKED` (replicas never block
//! each other or claim twice), a document's next `rev` is computed under a transaction-scoped
//! advisory lock on its (device, sensor, kind) so revisions have neither gaps nor duplicates,
//! and a blob's pins and its garbage collection serialise on an advisory lock of its key.
//! Leases and heartbeats are stamped with the database's clock, so replicas whose clocks
//! disagree still agree on who holds a lease. Migrations run at start under an advisory lock
//! (sqlx's migrator takes one), so replicas starting together do not race.
//!
//! New jobs and job events are announced with `NOTIFY` ([`JOBS_CHANNEL`], [`EVENTS_CHANNEL`]);
//! the server listens and wakes its workers and event streams (polling remains the fallback).
//! One file per concern, as for SQLite.

mod blobs;
mod datasets;
mod documents;
mod queue;
mod token_caches;
mod tokens;

use std::str::FromStr;
use std::time::Duration;

use async_trait::async_trait;
use serde_json::Value;
use sqlx::SqlSafeStr;
use sqlx::migrate::{Migration, MigrationType, Migrator};
use sqlx::postgres::{PgPool, PgPoolOptions};
use uuid::Uuid;

use super::{Store, StoreError, StoreResult};

/// Channel on which a new or re-queued job is announced (payload: the job id).
pub const JOBS_CHANNEL: &str = "caliper_jobs";
/// Channel on which job status and progress changes are announced (payload: a JSON
/// [`crate::state::JobEvent`]).
pub const EVENTS_CHANNEL: &str = "caliper_job_events";
/// `NOTIFY` channel of token revocations (payload: the revocation's number in commit order);
/// replicas empty their token cache on it and acknowledge ([`crate::token_cache`]).
pub const TOKENS_CHANNEL: &str = "caliper_tokens";

fn migrator() -> Migrator {
    let m = |version, name: &str, sql: &'static str| {
        Migration::new(
            version,
            name.to_string().into(),
            MigrationType::Simple,
            sql.into_sql_str(),
            false,
        )
    };
    Migrator::with_migrations(vec![
        m(1, "initial", include_str!("migrations/0001_initial.sql")),
        m(2, "video", include_str!("migrations/0002_video.sql")),
        m(
            3,
            "aux_dataset",
            include_str!("migrations/0003_aux_dataset.sql"),
        ),
        m(
            4,
            "token_caches",
            include_str!("migrations/0004_token_caches.sql"),
        ),
    ])
}

/// The database's clock in milliseconds since the epoch.
pub(crate) const DB_NOW: &str = "(EXTRACT(EPOCH FROM clock_timestamp()) * 1000)::BIGINT";

/// PostgreSQL-backed [`Store`].
#[derive(Clone)]
pub struct PgStore {
    pool: PgPool,
}

impl PgStore {
    /// Connect and bring the schema up to date (under the migrator's advisory lock).
    pub async fn connect(url: &str) -> StoreResult<Self> {
        let pool = PgPoolOptions::new()
            .max_connections(16)
            .acquire_timeout(Duration::from_secs(10))
            .connect(url)
            .await?;
        migrator()
            .run(&pool)
            .await
            .map_err(|e| StoreError::Corrupt(format!("schema migration failed: {e}")))?;
        Ok(Self { pool })
    }

    /// The pool, for `LISTEN` connections.
    pub fn pool(&self) -> &PgPool {
        &self.pool
    }

    /// Announce on `channel` (best effort: listeners also poll).
    pub(crate) async fn notify(&self, channel: &str, payload: &str) {
        if let Err(e) = sqlx::query("SELECT pg_notify($1, $2)")
            .bind(channel)
            .bind(payload)
            .execute(&self.pool)
            .await
        {
            tracing::warn!(error = %e, channel, "NOTIFY failed");
        }
    }
}

#[async_trait]
impl Store for PgStore {
    async fn ping(&self) -> StoreResult<()> {
        sqlx::query("SELECT 1").execute(&self.pool).await?;
        Ok(())
    }

    fn shared(&self) -> bool {
        true
    }

    fn as_pg(&self) -> Option<&PgStore> {
        Some(self)
    }
}

/// Record `shas` as garbage-collection candidates (see the SQLite store).
async fn queue_gc(
    tx: &mut sqlx::Transaction<'_, sqlx::Postgres>,
    shas: &[String],
    now: i64,
) -> StoreResult<()> {
    for sha in shas {
        sqlx::query("INSERT INTO blob_gc (sha256, since) VALUES ($1, $2) ON CONFLICT DO NOTHING")
            .bind(sha)
            .bind(now)
            .execute(&mut **tx)
            .await?;
    }
    Ok(())
}

/// Serialise with everyone else touching blob `sha` until the transaction ends.
async fn lock_blob(tx: &mut sqlx::Transaction<'_, sqlx::Postgres>, sha: &str) -> StoreResult<()> {
    sqlx::query("SELECT pg_advisory_xact_lock(hashtextextended('blob:' || $1, 0))")
        .bind(sha)
        .execute(&mut **tx)
        .await?;
    Ok(())
}

fn parse_uuid(s: &str) -> StoreResult<Uuid> {
    Uuid::from_str(s).map_err(|e| StoreError::Corrupt(format!("bad uuid {s:?}: {e}")))
}

fn parse_json(s: Option<String>) -> StoreResult<Option<Value>> {
    s.map(|t| serde_json::from_str(&t).map_err(|e| StoreError::Corrupt(e.to_string())))
        .transpose()
}
