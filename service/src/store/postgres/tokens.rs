//! Access tokens; a revocation holds on every replica before it returns (see
//! [`crate::token_cache`]).

use async_trait::async_trait;
use sqlx::Row;
use sqlx::postgres::PgRow;
use uuid::Uuid;

use super::{PgStore, parse_uuid};
use crate::store::*;

fn token_from_row(r: &PgRow) -> StoreResult<TokenRecord> {
    let scope: String = r.try_get("scope")?;
    Ok(TokenRecord {
        id: parse_uuid(&r.try_get::<String, _>("id")?)?,
        name: r.try_get("name")?,
        prefix: r.try_get("prefix")?,
        scope: Scope::parse(&scope)
            .ok_or_else(|| StoreError::Corrupt(format!("bad token scope {scope:?}")))?,
        devices: r.try_get("devices")?,
        created_at: r.try_get("created_at")?,
        revoked_at: r.try_get("revoked_at")?,
    })
}

#[async_trait]
impl TokenStore for PgStore {
    async fn insert_token(&self, t: &TokenRecord, hash: &str) -> StoreResult<()> {
        sqlx::query(
            "INSERT INTO tokens (id, name, prefix, hash, scope, devices, created_at, revoked_at) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, $8)",
        )
        .bind(t.id.to_string())
        .bind(&t.name)
        .bind(&t.prefix)
        .bind(hash)
        .bind(t.scope.as_str())
        .bind(&t.devices)
        .bind(t.created_at)
        .bind(t.revoked_at)
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    async fn token_by_hash(&self, hash: &str) -> StoreResult<Option<TokenRecord>> {
        let row = sqlx::query("SELECT * FROM tokens WHERE hash = $1")
            .bind(hash)
            .fetch_optional(&self.pool)
            .await?;
        row.as_ref().map(token_from_row).transpose()
    }

    async fn list_tokens(&self) -> StoreResult<Vec<TokenRecord>> {
        let rows = sqlx::query("SELECT * FROM tokens ORDER BY created_at DESC, id DESC")
            .fetch_all(&self.pool)
            .await?;
        rows.iter().map(token_from_row).collect()
    }

    async fn revoke_token(&self, id: Uuid, now: i64) -> StoreResult<bool> {
        // The revocation takes the next number in commit order (the counter's row lock
        // serialises revocations) and announces it at commit; it returns once every caching
        // replica has emptied its cache (`caliper token revoke` included).
        let mut tx = self.pool.begin().await?;
        let r =
            sqlx::query("UPDATE tokens SET revoked_at = COALESCE(revoked_at, $1) WHERE id = $2")
                .bind(now)
                .bind(id.to_string())
                .execute(&mut *tx)
                .await?;
        if r.rows_affected() == 0 {
            return Ok(false);
        }
        let n: i64 = sqlx::query("UPDATE token_revocations SET n = n + 1 RETURNING n")
            .fetch_one(&mut *tx)
            .await?
            .try_get("n")?;
        sqlx::query("SELECT pg_notify($1, $2)")
            .bind(super::TOKENS_CHANNEL)
            .bind(n.to_string())
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        self.wait_for_token_caches(n).await?;
        Ok(true)
    }
}
