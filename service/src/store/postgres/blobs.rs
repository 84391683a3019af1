//! Blob lifetime across replicas: every pin and every collection of a blob takes the blob's
//! advisory lock, so a collection either sees a pin committed before it (and keeps the blob)
//! or finishes before the pin, whose writer then finds the blob gone and writes it again.

use async_trait::async_trait;
use uuid::Uuid;

use super::{PgStore, lock_blob, queue_gc};
use crate::store::*;

#[async_trait]
impl BlobRefs for PgStore {
    async fn pin_blobs(&self, token: Uuid, shas: &[String], expires_at: i64) -> StoreResult<()> {
        let mut tx = self.pool.begin().await?;
        // Sorted, so two writers pinning overlapping sets cannot deadlock on the locks.
        let mut sorted: Vec<&String> = shas.iter().collect();
        sorted.sort();
        sorted.dedup();
        for sha in sorted {
            lock_blob(&mut tx, sha).await?;
            sqlx::query(
                "INSERT INTO blob_pins (token, sha256, expires_at) VALUES ($1, $2, $3) \
                 ON CONFLICT (token, sha256) DO UPDATE SET expires_at = EXCLUDED.expires_at",
            )
            .bind(token.to_string())
            .bind(sha)
            .bind(expires_at)
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(())
    }

    async fn unpin_blobs(&self, token: Uuid, now: i64) -> StoreResult<()> {
        let mut tx = self.pool.begin().await?;
        let shas: Vec<String> =
            sqlx::query_scalar("DELETE FROM blob_pins WHERE token = $1 RETURNING sha256")
                .bind(token.to_string())
                .fetch_all(&mut *tx)
                .await?;
        queue_gc(&mut tx, &shas, now).await?;
        tx.commit().await?;
        Ok(())
    }

    async fn gc_candidates(
        &self,
        now: i64,
        due_before: i64,
        limit: u32,
    ) -> StoreResult<Vec<String>> {
        let mut tx = self.pool.begin().await?;
        let expired: Vec<String> =
            sqlx::query_scalar("DELETE FROM blob_pins WHERE expires_at <= $1 RETURNING sha256")
                .bind(now)
                .fetch_all(&mut *tx)
                .await?;
        queue_gc(&mut tx, &expired, now).await?;
        let due: Vec<String> = sqlx::query_scalar(
            "SELECT sha256 FROM blob_gc WHERE since <= $1 ORDER BY since, sha256 LIMIT $2",
        )
        .bind(due_before)
        .bind(i64::from(limit))
        .fetch_all(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(due)
    }

    async fn reap_blob(&self, sha: &str, now: i64, delete: BlobDeleter<'_>) -> StoreResult<bool> {
        let mut tx = self.pool.begin().await?;
        lock_blob(&mut tx, sha).await?;
        let used: Option<i32> = sqlx::query_scalar(
            "SELECT 1 FROM dataset_files WHERE sha256 = $1 UNION ALL \
             SELECT 1 FROM artifacts WHERE sha256 = $1 UNION ALL \
             SELECT 1 FROM blob_pins WHERE sha256 = $1 AND expires_at > $2 LIMIT 1",
        )
        .bind(sha)
        .bind(now)
        .fetch_optional(&mut *tx)
        .await?;
        let reaped = if used.is_none() {
            delete(sha.to_string())
                .await
                .map_err(|e| StoreError::Blob(e.to_string()))?;
            true
        } else {
            false
        };
        sqlx::query("DELETE FROM blob_gc WHERE sha256 = $1")
            .bind(sha)
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(reaped)
    }

    async fn clear_pins(&self, now: i64) -> StoreResult<()> {
        // Shared by replicas: another process's pins are alive. Only expired ones go (that
        // happens in gc_candidates); nothing to do here.
        let _ = now;
        Ok(())
    }
}
