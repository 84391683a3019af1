//! Access tokens: looked up by the hash of their secret on every request, so a revocation
//! takes effect at once for every process sharing the database.

use async_trait::async_trait;
use sqlx::Row;
use sqlx::sqlite::SqliteRow;
use uuid::Uuid;

use super::{SqliteStore, parse_uuid};
use crate::store::*;

fn token_from_row(r: &SqliteRow) -> StoreResult<TokenRecord> {
    let scope: String = r.try_get("scope")?;
    let devices: Option<String> = r.try_get("devices")?;
    Ok(TokenRecord {
        id: parse_uuid(&r.try_get::<String, _>("id")?)?,
        name: r.try_get("name")?,
        prefix: r.try_get("prefix")?,
        scope: Scope::parse(&scope)
            .ok_or_else(|| StoreError::Corrupt(format!("bad token scope {scope:?}")))?,
        devices: devices
            .map(|d| serde_json::from_str(&d))
            .transpose()
            .map_err(|e| StoreError::Corrupt(e.to_string()))?,
        created_at: r.try_get("created_at")?,
        revoked_at: r.try_get("revoked_at")?,
    })
}

#[async_trait]
impl TokenStore for SqliteStore {
    async fn insert_token(&self, t: &TokenRecord, hash: &str) -> StoreResult<()> {
        let devices = t
            .devices
            .as_ref()
            .map(serde_json::to_string)
            .transpose()
            .map_err(|e| StoreError::Corrupt(e.to_string()))?;
        sqlx::query(
            "INSERT INTO tokens (id, name, prefix, hash, scope, devices, created_at, revoked_at) \
             VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
        )
        .bind(t.id.to_string())
        .bind(&t.name)
        .bind(&t.prefix)
        .bind(hash)
        .bind(t.scope.as_str())
        .bind(devices)
        .bind(t.created_at)
        .bind(t.revoked_at)
        .execute(&self.write)
        .await?;
        Ok(())
    }

    async fn token_by_hash(&self, hash: &str) -> StoreResult<Option<TokenRecord>> {
        let row = sqlx::query("SELECT * FROM tokens WHERE hash = ?")
            .bind(hash)
            .fetch_optional(&self.read)
            .await?;
        row.as_ref().map(token_from_row).transpose()
    }

    async fn list_tokens(&self) -> StoreResult<Vec<TokenRecord>> {
        let rows = sqlx::query("SELECT * FROM tokens ORDER BY created_at DESC, id DESC")
            .fetch_all(&self.read)
            .await?;
        rows.iter().map(token_from_row).collect()
    }

    async fn revoke_token(&self, id: Uuid, now: i64) -> StoreResult<bool> {
        let r = sqlx::query("UPDATE tokens SET revoked_at = COALESCE(revoked_at, ?) WHERE id = ?")
            .bind(now)
            .bind(id.to_string())
            .execute(&self.write)
            .await?;
        Ok(r.rows_affected() > 0)
    }
}
