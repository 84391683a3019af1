//! The embedded profile's store: one SQLite file in WAL mode.
//!
//! Writes go through a pool of exactly one connection, so transactions never contend for the
//! write lock ("database is locked" cannot happen between our own writers) and every write
//! transaction is serialised with every other (blob garbage collection relies on that); reads
//! use a separate pool and proceed concurrently thanks to WAL. One file per concern:
//! [`datasets`], [`queue`] (jobs, attempts, artifacts), [`documents`] and [`blobs`] (blob
//! pins and garbage collection).

mod blobs;
mod datasets;
mod documents;
mod queue;
mod tokens;

use std::path::Path;
use std::str::FromStr;
use std::time::Duration;

use async_trait::async_trait;
use serde_json::Value;
use sqlx::SqlSafeStr;
use sqlx::migrate::{Migration, MigrationType, Migrator};
use sqlx::sqlite::{
    SqliteConnectOptions, SqliteJournalMode, SqlitePool, SqlitePoolOptions, SqliteSynchronous,
};
use uuid::Uuid;

use super::{Store, StoreError, StoreResult};

/// The schema migrations, embedded in the binary, numbered, applied in order at start by
/// sqlx's migrator (what `sqlx::migrate!` expands to, built here without the proc macro so
/// the build does not compile SQLite a second time for the host).
fn migrator() -> Migrator {
    let m = |version: i64, description: &'static str, sql: &'static str| {
        Migration::new(
            version,
            description.into(),
            MigrationType::Simple,
            sql.into_sql_str(),
            false,
        )
    };
    Migrator::with_migrations(vec![
        m(1, "initial", include_str!("migrations/0001_initial.sql")),
        m(
            2,
            "blob lifetime",
            include_str!("migrations/0002_blob_lifetime.sql"),
        ),
        m(3, "tokens", include_str!("migrations/0003_tokens.sql")),
        m(4, "video", include_str!("migrations/0004_video.sql")),
        m(
            5,
            "aux_dataset",
            include_str!("migrations/0005_aux_dataset.sql"),
        ),
    ])
}

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
        adopt_legacy_versions(&write).await?;
        migrator()
            .run(&write)
            .await
            .map_err(|e| StoreError::Corrupt(format!("schema migration failed: {e}")))?;
        let read = SqlitePoolOptions::new()
            .max_connections(8)
            .min_connections(2)
            .connect_with(opts.read_only(true))
            .await?;
        Ok(Self { write, read })
    }
}

/// Databases created before the migrator recorded their versions in `schema_migrations`:
/// record those versions in sqlx's table (with the checksums of the embedded scripts, which
/// are the same SQL) so they are not applied twice.
async fn adopt_legacy_versions(pool: &SqlitePool) -> StoreResult<()> {
    let legacy: Option<i64> = sqlx::query_scalar(
        "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'schema_migrations'",
    )
    .fetch_optional(pool)
    .await?;
    if legacy.is_none() {
        return Ok(());
    }
    let mut tx = pool.begin().await?;
    sqlx::query(
        "CREATE TABLE IF NOT EXISTS _sqlx_migrations (version BIGINT PRIMARY KEY, description TEXT NOT NULL, \
         installed_on TIMESTAMP NOT NULL DEFAULT CURRENT_TIMESTAMP, success BOOLEAN NOT NULL, \
         checksum BLOB NOT NULL, execution_time BIGINT NOT NULL)",
    )
    .execute(&mut *tx)
    .await?;
    let versions: Vec<i64> = sqlx::query_scalar("SELECT version FROM schema_migrations")
        .fetch_all(&mut *tx)
        .await?;
    for m in migrator().iter().filter(|m| versions.contains(&m.version)) {
        sqlx::query(
            "INSERT OR IGNORE INTO _sqlx_migrations (version, description, success, checksum, execution_time) \
             VALUES (?, ?, TRUE, ?, 0)",
        )
        .bind(m.version)
        .bind(m.description.as_ref())
        .bind(m.checksum.as_ref())
        .execute(&mut *tx)
        .await?;
    }
    sqlx::query("DROP TABLE schema_migrations")
        .execute(&mut *tx)
        .await?;
    tx.commit().await?;
    Ok(())
}

#[async_trait]
impl Store for SqliteStore {
    async fn ping(&self) -> StoreResult<()> {
        sqlx::query("SELECT 1").execute(&self.read).await?;
        Ok(())
    }
}

/// Record `shas` as candidates for garbage collection: they may just have lost their last
/// reference. Whether they really did is decided later, by [`Store::reap_blob`].
async fn queue_gc(
    tx: &mut sqlx::Transaction<'_, sqlx::Sqlite>,
    shas: &[String],
    now: i64,
) -> StoreResult<()> {
    for sha in shas {
        sqlx::query("INSERT OR IGNORE INTO blob_gc (sha256, since) VALUES (?, ?)")
            .bind(sha)
            .bind(now)
            .execute(&mut **tx)
            .await?;
    }
    Ok(())
}

fn parse_uuid(s: &str) -> StoreResult<Uuid> {
    Uuid::from_str(s).map_err(|e| StoreError::Corrupt(format!("bad uuid {s:?}: {e}")))
}

fn parse_json(s: Option<String>) -> StoreResult<Option<Value>> {
    s.map(|t| serde_json::from_str(&t).map_err(|e| StoreError::Corrupt(e.to_string())))
        .transpose()
}
