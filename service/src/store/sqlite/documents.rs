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

/// Columns of a [`DocumentSummary`]; the quality object is cut out of the body by SQLite's
/// JSON functions so a page of summaries never transfers whole documents.
const SUMMARY_COLUMNS: &str = "d.sensor AS sensor, d.kind AS kind, d.schema AS schema, \
     d.rev AS rev, d.etag AS etag, d.created_at AS created_at, d.job_id AS job_id, \
     json_extract(d.body, '$.quality') AS quality";

/// `d` is the newest revision of its (device, sensor, kind): a lookup on the primary key.
const IS_LATEST: &str = "d.rev = (SELECT MAX(x.rev) FROM documents x WHERE x.device = d.device \
     AND x.sensor = d.sensor AND x.kind = d.kind)";

/// A list of serials as a JSON array for `json_each` (SQLite has no array binds).
fn json_list(only: Option<&[String]>) -> StoreResult<Option<String>> {
    only.map(serde_json::to_string)
        .transpose()
        .map_err(|e| StoreError::Corrupt(e.to_string()))
}

fn summary_from_row(r: &SqliteRow) -> StoreResult<DocumentSummary> {
    let job: Option<String> = r.try_get("job_id")?;
    let quality: Option<String> = r.try_get("quality")?;
    Ok(DocumentSummary {
        sensor: r.try_get("sensor")?,
        kind: r.try_get("kind")?,
        schema: r.try_get("schema")?,
        latest_rev: r.try_get::<i64, _>("rev")? as u64,
        etag: r.try_get("etag")?,
        created_at: crate::clock::rfc3339(r.try_get("created_at")?),
        job: job.as_deref().map(parse_uuid).transpose()?,
        // A body is canonical JSON written by us; a quality that does not parse is left out
        // rather than failing the whole list.
        quality: quality.and_then(|q| serde_json::from_str(&q).ok()),
    })
}

#[async_trait]
impl DocumentStore for SqliteStore {
    async fn list_documents(&self, device: &str) -> StoreResult<Vec<DocumentSummary>> {
        let rows = sqlx::query(sqlx::AssertSqlSafe(format!(
            "SELECT {SUMMARY_COLUMNS} FROM documents d WHERE d.device = ? AND {IS_LATEST} \
             ORDER BY d.sensor, d.kind"
        )))
        .bind(device)
        .fetch_all(&self.read)
        .await?;
        rows.iter().map(summary_from_row).collect()
    }

    async fn list_devices(&self, q: &DeviceQuery) -> StoreResult<Vec<DeviceSummary>> {
        // One page of serials first (index order on the primary key), then the latest revision
        // of each of their documents: the cost is the page's, not the fleet's.
        let rows = sqlx::query(sqlx::AssertSqlSafe(format!(
            "WITH page AS (SELECT DISTINCT device FROM documents \
               WHERE (?1 IS NULL OR device > ?1) AND (?2 IS NULL OR instr(lower(device), lower(?2)) > 0) \
               AND (?4 IS NULL OR device IN (SELECT value FROM json_each(?4))) \
               ORDER BY device LIMIT ?3) \
             SELECT d.device AS device, {SUMMARY_COLUMNS} FROM documents d JOIN page p ON d.device = p.device \
             WHERE {IS_LATEST} ORDER BY d.device, d.sensor, d.kind"
        )))
        .bind(q.after.as_deref())
        .bind(q.search.as_deref())
        .bind(i64::from(q.limit))
        .bind(json_list(q.only.as_deref())?)
        .fetch_all(&self.read)
        .await?;
        let mut out: Vec<DeviceSummary> = Vec::new();
        for r in &rows {
            let serial: String = r.try_get("device")?;
            let doc = summary_from_row(r)?;
            match out.last_mut() {
                Some(d) if d.serial == serial => d.documents.push(doc),
                _ => out.push(DeviceSummary {
                    serial,
                    documents: vec![doc],
                }),
            }
        }
        Ok(out)
    }

    async fn count_devices(
        &self,
        search: Option<&str>,
        only: Option<&[String]>,
    ) -> StoreResult<u64> {
        let n: i64 = sqlx::query_scalar(
            "SELECT COUNT(DISTINCT device) FROM documents \
             WHERE (?1 IS NULL OR instr(lower(device), lower(?1)) > 0) \
             AND (?2 IS NULL OR device IN (SELECT value FROM json_each(?2)))",
        )
        .bind(search)
        .bind(json_list(only)?)
        .fetch_one(&self.read)
        .await?;
        Ok(n.max(0) as u64)
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
