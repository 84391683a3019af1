//! Blob lifetime: pins of writers in flight and garbage collection of unreferenced blobs
//! (see [`crate::blob_gc`]).

use async_trait::async_trait;
use uuid::Uuid;

use super::{SqliteStore, queue_gc};
use crate::store::*;

#[async_trait]
impl BlobRefs for SqliteStore {
    async fn pin_blobs(&self, token: Uuid, shas: &[String], expires_at: i64) -> StoreResult<()> {
        let mut tx = self.write.begin().await?;
        for sha in shas {
            sqlx::query(
                "INSERT OR REPLACE INTO blob_pins (token, sha256, expires_at) VALUES (?, ?, ?)",
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
        let mut tx = self.write.begin().await?;
        let shas: Vec<String> =
            sqlx::query_scalar("DELETE FROM blob_pins WHERE token = ? RETURNING sha256")
                .bind(token.to_string())
                .fetch_all(&mut *tx)
                .await?;
        // Whoever pinned may have failed before referencing the blob: let GC decide.
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
        let mut tx = self.write.begin().await?;
        // Pins of writers that died (or overran their expiry) stop protecting their blobs.
        let expired: Vec<String> =
            sqlx::query_scalar("DELETE FROM blob_pins WHERE expires_at <= ? RETURNING sha256")
                .bind(now)
                .fetch_all(&mut *tx)
                .await?;
        queue_gc(&mut tx, &expired, now).await?;
        let due: Vec<String> = sqlx::query_scalar(
            "SELECT sha256 FROM blob_gc WHERE since <= ? ORDER BY since, sha256 LIMIT ?",
        )
        .bind(due_before)
        .bind(i64::from(limit))
        .fetch_all(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(due)
    }

    async fn reap_blob(&self, sha: &str, now: i64, delete: BlobDeleter<'_>) -> StoreResult<bool> {
        // The single write connection serialises this transaction with every pin and every
        // reference insert: a pin committed before it keeps the blob; a pin committed after
        // it finds the blob gone and writes it again. Nothing can slip between the check and
        // the deletion.
        let mut tx = self.write.begin().await?;
        let used: Option<i64> = sqlx::query_scalar(
            "SELECT 1 FROM dataset_files WHERE sha256 = ?1 UNION ALL \
             SELECT 1 FROM artifacts WHERE sha256 = ?1 UNION ALL \
             SELECT 1 FROM blob_pins WHERE sha256 = ?1 AND expires_at > ?2 LIMIT 1",
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
        sqlx::query("DELETE FROM blob_gc WHERE sha256 = ?")
            .bind(sha)
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(reaped)
    }

    async fn clear_pins(&self, now: i64) -> StoreResult<()> {
        let mut tx = self.write.begin().await?;
        let shas: Vec<String> = sqlx::query_scalar("DELETE FROM blob_pins RETURNING sha256")
            .fetch_all(&mut *tx)
            .await?;
        queue_gc(&mut tx, &shas, now).await?;
        tx.commit().await?;
        Ok(())
    }
}
