//! The registry of replicas that cache token lookups, and the acknowledgements that make a
//! revocation hold on every replica before it returns ([`crate::token_cache`] has the protocol).

use std::time::Duration;

use sqlx::{AssertSqlSafe, Row};

use super::{DB_NOW, PgStore};
use crate::store::StoreResult;
use crate::token_cache::LEASE;

/// Rows of replicas silent this long are deleted when another replica joins.
const FORGET_MS: i64 = 3_600_000;

fn lease_ms() -> i64 {
    i64::try_from(LEASE.as_millis()).unwrap_or(i64::MAX)
}

impl PgStore {
    /// Register `replica` as caching, having applied every revocation committed so far (its
    /// cache is empty and its `LISTEN` is already up, so it hears every later one).
    pub async fn join_token_caches(&self, replica: &str) -> StoreResult<()> {
        sqlx::query(AssertSqlSafe(format!(
            "DELETE FROM token_caches WHERE heartbeat_ms < {DB_NOW} - $1"
        )))
        .bind(FORGET_MS)
        .execute(&self.pool)
        .await?;
        sqlx::query(AssertSqlSafe(format!(
            "INSERT INTO token_caches (replica, applied, heartbeat_ms) \
             SELECT $1, n, {DB_NOW} FROM token_revocations \
             ON CONFLICT (replica) DO UPDATE SET applied = EXCLUDED.applied, \
             heartbeat_ms = EXCLUDED.heartbeat_ms"
        )))
        .bind(replica)
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// Stamp `replica` as alive; false when its row is gone (it must join again).
    pub async fn token_cache_heartbeat(&self, replica: &str) -> StoreResult<bool> {
        let r = sqlx::query(AssertSqlSafe(format!(
            "UPDATE token_caches SET heartbeat_ms = {DB_NOW} WHERE replica = $1"
        )))
        .bind(replica)
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() > 0)
    }

    /// Record that `replica` emptied its cache for revocation `n` (and so all before it).
    pub async fn ack_token_revocation(&self, replica: &str, n: i64) -> StoreResult<()> {
        sqlx::query(AssertSqlSafe(format!(
            "UPDATE token_caches SET applied = GREATEST(applied, $2), heartbeat_ms = {DB_NOW} \
             WHERE replica = $1"
        )))
        .bind(replica)
        .bind(n)
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// Unregister `replica` (it stops caching: shutdown).
    pub async fn leave_token_caches(&self, replica: &str) -> StoreResult<()> {
        sqlx::query("DELETE FROM token_caches WHERE replica = $1")
            .bind(replica)
            .execute(&self.pool)
            .await?;
        Ok(())
    }

    /// Wait until no live caching replica can still serve a token revoked by revocation `n`:
    /// each has acknowledged `n` or has been silent longer than [`LEASE`] (and so has stopped
    /// serving from its cache by itself). Bounded by the lease plus a margin.
    pub(super) async fn wait_for_token_caches(&self, n: i64) -> StoreResult<()> {
        let deadline = tokio::time::Instant::now() + LEASE + Duration::from_secs(2);
        let mut pause = Duration::from_millis(1);
        loop {
            let row = sqlx::query(AssertSqlSafe(format!(
                "SELECT count(*) AS c FROM token_caches \
                 WHERE applied < $1 AND heartbeat_ms > {DB_NOW} - $2"
            )))
            .bind(n)
            .bind(lease_ms())
            .fetch_one(&self.pool)
            .await?;
            let pending: i64 = row.try_get("c")?;
            if pending == 0 {
                return Ok(());
            }
            if tokio::time::Instant::now() >= deadline {
                tracing::warn!(
                    replicas = pending,
                    "replicas did not acknowledge a token revocation within their lease"
                );
                return Ok(());
            }
            tokio::time::sleep(pause).await;
            pause = (pause * 2).min(Duration::from_millis(20));
        }
    }
}
