//! Datasets and their files.

use async_trait::async_trait;
use sqlx::Row;
use sqlx::postgres::PgRow;
use uuid::Uuid;

use super::{PgStore, parse_uuid, queue_gc};
use crate::store::*;

impl PgStore {
    async fn load_files(&self, id: Uuid) -> StoreResult<Vec<DatasetFile>> {
        let rows = sqlx::query(
            "SELECT name, sha256, size, media_type, image, video FROM dataset_files WHERE dataset_id = $1 ORDER BY idx",
        )
        .bind(id.to_string())
        .fetch_all(&self.pool)
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

    fn dataset_from_row(r: &PgRow, files: Vec<DatasetFile>) -> StoreResult<DatasetRecord> {
        let kind: String = r.try_get("kind")?;
        Ok(DatasetRecord {
            id: parse_uuid(&r.try_get::<String, _>("id")?)?,
            kind: DatasetKind::parse(&kind)
                .ok_or_else(|| StoreError::Corrupt(format!("bad dataset kind {kind}")))?,
            created_at: r.try_get("created_at")?,
            total_bytes: r.try_get::<i64, _>("total_bytes")? as u64,
            sha256: r.try_get("sha256")?,
            files,
            devices: r.try_get("devices")?,
        })
    }
}

#[async_trait]
impl DatasetStore for PgStore {
    async fn insert_dataset(&self, ds: &DatasetRecord) -> StoreResult<()> {
        let mut tx = self.pool.begin().await?;
        sqlx::query(
            "INSERT INTO datasets (id, kind, created_at, total_bytes, sha256, file_count, devices) \
             VALUES ($1, $2, $3, $4, $5, $6, $7)",
        )
        .bind(ds.id.to_string())
        .bind(ds.kind.as_str())
        .bind(ds.created_at)
        .bind(ds.total_bytes as i64)
        .bind(&ds.sha256)
        .bind(ds.files.len() as i64)
        .bind(&ds.devices)
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
                "INSERT INTO dataset_files (dataset_id, idx, name, sha256, size, media_type, image, video) \
                 VALUES ($1, $2, $3, $4, $5, $6, $7, $8)",
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
        let row = sqlx::query("SELECT * FROM datasets WHERE id = $1")
            .bind(id.to_string())
            .fetch_optional(&self.pool)
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
        let rows = sqlx::query(
            "SELECT * FROM datasets WHERE ($1::TEXT IS NULL OR id < $1) \
             AND ($2::TEXT[] IS NULL OR devices && $2) ORDER BY id DESC LIMIT $3",
        )
        .bind(before_id.map(|u| u.to_string()))
        .bind(only.map(<[String]>::to_vec))
        .bind(limit as i64)
        .fetch_all(&self.pool)
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
        let mut tx = self.pool.begin().await?;
        // The row lock keeps a job from being queued on it meanwhile (create_job locks it too).
        let exists: Option<String> =
            sqlx::query_scalar("SELECT id FROM datasets WHERE id = $1 FOR UPDATE")
                .bind(id.to_string())
                .fetch_optional(&mut *tx)
                .await?;
        if exists.is_none() {
            return Ok(DeleteDataset::NotFound);
        }
        let users: Vec<String> = sqlx::query_scalar(
            "SELECT id FROM jobs WHERE (dataset_id = $1 OR aux_dataset_id = $1) AND status IN ('queued', 'running') ORDER BY id",
        )
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
            sqlx::query_scalar("SELECT DISTINCT sha256 FROM dataset_files WHERE dataset_id = $1")
                .bind(id.to_string())
                .fetch_all(&mut *tx)
                .await?;
        sqlx::query("DELETE FROM dataset_files WHERE dataset_id = $1")
            .bind(id.to_string())
            .execute(&mut *tx)
            .await?;
        sqlx::query("DELETE FROM datasets WHERE id = $1")
            .bind(id.to_string())
            .execute(&mut *tx)
            .await?;
        queue_gc(&mut tx, &shas, crate::clock::now_ms()).await?;
        tx.commit().await?;
        Ok(DeleteDataset::Deleted)
    }
}
