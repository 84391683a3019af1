//! Datasets and their files.

use async_trait::async_trait;
use sqlx::Row;
use sqlx::sqlite::SqliteRow;
use uuid::Uuid;

use super::{SqliteStore, parse_uuid, queue_gc};
use crate::store::*;

impl SqliteStore {
    async fn load_files(&self, id: Uuid) -> StoreResult<Vec<DatasetFile>> {
        let rows = sqlx::query(
            "SELECT name, sha256, size, media_type, image, video FROM dataset_files WHERE dataset_id = ? ORDER BY idx",
        )
        .bind(id.to_string())
        .fetch_all(&self.read)
        .await?;
        rows.iter()
            .map(|r| {
                let image: Option<String> = r.try_get("image")?;
                let video: Option<String> = r.try_get("video")?;
                Ok(DatasetFile {
                    name: r.try_get("name")?,
                    sha256: r.try_get("sha256")?,
                    size: r.try_get::<i64, _>("size")? as u64,
                    media_type: r.try_get("media_type")?,
                    image: image
                        .map(|t| serde_json::from_str(&t))
                        .transpose()
                        .map_err(|e| StoreError::Corrupt(e.to_string()))?,
                    video: video
                        .map(|t| serde_json::from_str(&t))
                        .transpose()
                        .map_err(|e| StoreError::Corrupt(e.to_string()))?,
                })
            })
            .collect()
    }

    fn dataset_from_row(r: &SqliteRow, files: Vec<DatasetFile>) -> StoreResult<DatasetRecord> {
        let kind: String = r.try_get("kind")?;
        let devices: Option<String> = r.try_get("devices")?;
        Ok(DatasetRecord {
            id: parse_uuid(&r.try_get::<String, _>("id")?)?,
            kind: DatasetKind::parse(&kind)
                .ok_or_else(|| StoreError::Corrupt(format!("bad dataset kind {kind}")))?,
            created_at: r.try_get("created_at")?,
            total_bytes: r.try_get::<i64, _>("total_bytes")? as u64,
            sha256: r.try_get("sha256")?,
            files,
            devices: devices
                .map(|d| serde_json::from_str(&d))
                .transpose()
                .map_err(|e| StoreError::Corrupt(e.to_string()))?,
        })
    }
}

#[async_trait]
impl DatasetStore for SqliteStore {
    async fn insert_dataset(&self, ds: &DatasetRecord) -> StoreResult<()> {
        let mut tx = self.write.begin().await?;
        sqlx::query(
            "INSERT INTO datasets (id, kind, created_at, total_bytes, sha256, file_count, devices) VALUES (?, ?, ?, ?, ?, ?, ?)",
        )
        .bind(ds.id.to_string())
        .bind(ds.kind.as_str())
        .bind(ds.created_at)
        .bind(ds.total_bytes as i64)
        .bind(&ds.sha256)
        .bind(ds.files.len() as i64)
        .bind(
            ds.devices
                .as_ref()
                .map(serde_json::to_string)
                .transpose()
                .map_err(|e| StoreError::Corrupt(e.to_string()))?,
        )
        .execute(&mut *tx)
        .await?;
        for (i, f) in ds.files.iter().enumerate() {
            let image = f
                .image
                .as_ref()
                .map(serde_json::to_string)
                .transpose()
                .map_err(|e| StoreError::Corrupt(e.to_string()))?;
            let video = f
                .video
                .as_ref()
                .map(serde_json::to_string)
                .transpose()
                .map_err(|e| StoreError::Corrupt(e.to_string()))?;
            sqlx::query(
                "INSERT INTO dataset_files (dataset_id, idx, name, sha256, size, media_type, image, video) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            )
            .bind(ds.id.to_string())
            .bind(i as i64)
            .bind(&f.name)
            .bind(&f.sha256)
            .bind(f.size as i64)
            .bind(&f.media_type)
            .bind(image)
            .bind(video)
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(())
    }

    async fn get_dataset(&self, id: Uuid) -> StoreResult<Option<DatasetRecord>> {
        let row = sqlx::query("SELECT * FROM datasets WHERE id = ?")
            .bind(id.to_string())
            .fetch_optional(&self.read)
            .await?;
        match row {
            None => Ok(None),
            Some(r) => {
                let files = self.load_files(id).await?;
                Ok(Some(Self::dataset_from_row(&r, files)?))
            }
        }
    }

    async fn list_datasets(
        &self,
        before_id: Option<Uuid>,
        limit: u32,
        only: Option<&[String]>,
    ) -> StoreResult<Vec<DatasetRecord>> {
        let only = only
            .map(serde_json::to_string)
            .transpose()
            .map_err(|e| StoreError::Corrupt(e.to_string()))?;
        let rows = sqlx::query(
            "SELECT * FROM datasets WHERE (?1 IS NULL OR id < ?1) AND (?2 IS NULL OR EXISTS \
             (SELECT 1 FROM json_each(datasets.devices) d WHERE d.value IN (SELECT value FROM json_each(?2)))) \
             ORDER BY id DESC LIMIT ?3",
        )
        .bind(before_id.map(|u| u.to_string()))
        .bind(only)
        .bind(limit as i64)
        .fetch_all(&self.read)
        .await?;
        let mut out = Vec::with_capacity(rows.len());
        for r in &rows {
            let id = parse_uuid(&r.try_get::<String, _>("id")?)?;
            let files = self.load_files(id).await?;
            out.push(Self::dataset_from_row(r, files)?);
        }
        Ok(out)
    }

    async fn delete_dataset(&self, id: Uuid) -> StoreResult<DeleteDataset> {
        let mut tx = self.write.begin().await?;
        let exists: Option<i64> = sqlx::query_scalar("SELECT 1 FROM datasets WHERE id = ?")
            .bind(id.to_string())
            .fetch_optional(&mut *tx)
            .await?;
        if exists.is_none() {
            return Ok(DeleteDataset::NotFound);
        }
        let users: Vec<String> = sqlx::query_scalar(
            "SELECT id FROM jobs WHERE (dataset_id = ? OR aux_dataset_id = ?) AND status IN ('queued', 'running') ORDER BY id",
        )
        .bind(id.to_string())
        .bind(id.to_string())
        .fetch_all(&mut *tx)
        .await?;
        if !users.is_empty() {
            let ids = users
                .iter()
                .map(|s| parse_uuid(s))
                .collect::<StoreResult<Vec<_>>>()?;
            return Ok(DeleteDataset::InUse(ids));
        }
        let shas: Vec<String> =
            sqlx::query_scalar("SELECT DISTINCT sha256 FROM dataset_files WHERE dataset_id = ?")
                .bind(id.to_string())
                .fetch_all(&mut *tx)
                .await?;
        sqlx::query("DELETE FROM dataset_files WHERE dataset_id = ?")
            .bind(id.to_string())
            .execute(&mut *tx)
            .await?;
        sqlx::query("DELETE FROM datasets WHERE id = ?")
            .bind(id.to_string())
            .execute(&mut *tx)
            .await?;
        queue_gc(&mut tx, &shas, crate::clock::now_ms()).await?;
        tx.commit().await?;
        Ok(DeleteDataset::Deleted)
    }
}
