//! Immutable document revisions per (device, sensor, kind).

use async_trait::async_trait;
use sqlx::Row;
use sqlx::sqlite::SqliteRow;

use super::{SqliteStore, parse_uuid};
use crate::store::*;

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

#[async_trait]
impl DocumentStore for SqliteStore {
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
