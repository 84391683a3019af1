//! Content-addressed blob storage over `object_store`.
//!
//! Keys are the SHA-256 of the content, so identical uploads are stored once and writes are
//! idempotent (a retried job that re-uploads an artifact writes the same key). The embedded
//! profile uses the local filesystem under the data directory; S3-compatible stores plug in
//! through the same [`ObjectStore`] trait.

use std::path::Path as FsPath;
use std::sync::Arc;

use bytes::Bytes;
use object_store::local::LocalFileSystem;
use object_store::path::Path;
use object_store::{ObjectStore, ObjectStoreExt, WriteMultipart};
use tokio::io::AsyncReadExt;

/// Blob store failure.
#[derive(Debug, thiserror::Error)]
pub enum BlobError {
    #[error("blob {0} not found")]
    NotFound(String),
    #[error("blob store: {0}")]
    Store(#[from] object_store::Error),
    #[error("blob i/o: {0}")]
    Io(#[from] std::io::Error),
    #[error("blob store configuration: {0}")]
    Config(String),
}

/// Blobs keyed by their hex SHA-256.
#[derive(Clone, Debug)]
pub struct Blobs {
    store: Arc<dyn ObjectStore>,
    /// Root directory when the store is the local filesystem: uploads are then moved into
    /// place with a rename instead of being copied (half the disk traffic of a large upload).
    local_root: Option<std::path::PathBuf>,
}

fn key(sha256: &str) -> Path {
    let a = sha256.get(0..2).unwrap_or("xx");
    let b = sha256.get(2..4).unwrap_or("xx");
    Path::from(format!("sha256/{a}/{b}/{sha256}"))
}

/// Directory of a local blob store holding half-written blobs (outside the `sha256/` keys).
const PARTIAL_DIR: &str = ".partial";

impl Blobs {
    /// Blobs in a local directory (created if missing).
    pub fn local(dir: &FsPath) -> Result<Self, BlobError> {
        std::fs::create_dir_all(dir)?;
        Ok(Self {
            store: Arc::new(LocalFileSystem::new_with_prefix(dir)?),
            local_root: Some(dir.to_path_buf()),
        })
    }

    /// Remove the half-written files of [`Blobs::put_bytes`] that a killed process left in
    /// a local blob directory, when older than `age` (zero: all, for a process that holds the
    /// directory alone; replicas sharing one leave a live writer's files alone).
    pub fn clear_partial(&self, age: std::time::Duration) {
        let Some(root) = &self.local_root else {
            return;
        };
        let Ok(entries) = std::fs::read_dir(root.join(PARTIAL_DIR)) else {
            return;
        };
        for e in entries.flatten() {
            let old = e
                .metadata()
                .and_then(|m| m.modified())
                .ok()
                .and_then(|t| t.elapsed().ok())
                .is_none_or(|a| a >= age);
            if old {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }

    /// Blobs in any object store (S3, in-memory for tests).
    /// Blobs in an S3 bucket: `s3://bucket` or `s3://bucket/prefix`. Endpoint, region,
    /// credentials and `AWS_ALLOW_HTTP` come from the standard `AWS_*` variables (an
    /// S3-compatible server: `AWS_ENDPOINT=http://host:port`, `AWS_ALLOW_HTTP=true`); requests
    /// are path-style, which every S3-compatible server accepts.
    pub fn s3(url: &str) -> Result<Self, BlobError> {
        // TLS on ring; installing twice is harmless (the first provider stays).
        let _ = rustls::crypto::ring::default_provider().install_default();
        let rest = url
            .strip_prefix("s3://")
            .ok_or_else(|| BlobError::Config(format!("{url:?} is not an s3:// URL")))?;
        let (bucket, prefix) = rest.split_once('/').unwrap_or((rest, ""));
        if bucket.is_empty() {
            return Err(BlobError::Config(format!("{url:?} names no bucket")));
        }
        let s3 = object_store::aws::AmazonS3Builder::from_env()
            .with_bucket_name(bucket)
            .with_virtual_hosted_style_request(false)
            .build()?;
        let prefix = prefix.trim_matches('/');
        let store: Arc<dyn ObjectStore> = if prefix.is_empty() {
            Arc::new(s3)
        } else {
            Arc::new(object_store::prefix::PrefixStore::new(s3, prefix))
        };
        Ok(Self::new(store))
    }

    pub fn new(store: Arc<dyn ObjectStore>) -> Self {
        Self {
            store,
            local_root: None,
        }
    }

    /// Whether a blob exists.
    pub async fn exists(&self, sha256: &str) -> Result<bool, BlobError> {
        match self.store.head(&key(sha256)).await {
            Ok(_) => Ok(true),
            Err(object_store::Error::NotFound { .. }) => Ok(false),
            Err(e) => Err(e.into()),
        }
    }

    /// Store a temporary file under its (already computed) hash. On the local filesystem the
    /// file is renamed into place (it must live on the same filesystem, as `data_dir/tmp`
    /// does); elsewhere it is streamed in chunks so memory stays bounded whatever the size.
    /// A blob that exists is not written again.
    pub async fn put_file(&self, sha256: &str, file: &FsPath) -> Result<(), BlobError> {
        if self.exists(sha256).await? {
            return Ok(());
        }
        if let Some(root) = &self.local_root {
            let dest = root.join(key(sha256).as_ref());
            if let Some(parent) = dest.parent() {
                tokio::fs::create_dir_all(parent).await?;
            }
            // A rename is atomic: readers see the whole blob or none. The content and the
            // directory entry reach the disk before we return, so the database commit that
            // follows never refers to a blob a power loss could take away.
            tokio::fs::File::open(file).await?.sync_all().await?;
            if tokio::fs::rename(file, &dest).await.is_ok() {
                sync_dir(&dest).await?;
                return Ok(());
            }
            // Different filesystem or another failure: fall back to copying.
        }
        let upload = self.store.put_multipart(&key(sha256)).await?;
        let mut writer = WriteMultipart::new_with_chunk_size(upload, 8 << 20);
        let mut f = tokio::fs::File::open(file).await?;
        let mut buf = vec![0u8; 1 << 20];
        loop {
            let n = f.read(&mut buf).await?;
            if n == 0 {
                break;
            }
            writer.wait_for_capacity(2).await?;
            writer.write(&buf[..n]);
        }
        writer.finish().await?;
        Ok(())
    }

    /// Store bytes (small artifacts) under their hash, durably on the local filesystem (as
    /// [`Blobs::put_file`]); returns the hash.
    pub async fn put_bytes(&self, data: Bytes) -> Result<String, BlobError> {
        let sha = crate::document::sha256_hex(&data);
        if self.exists(&sha).await? {
            return Ok(sha);
        }
        if let Some(root) = &self.local_root {
            let dest = root.join(key(&sha).as_ref());
            let root = root.clone();
            tokio::task::spawn_blocking(move || -> std::io::Result<()> {
                use std::io::Write;
                let parent = dest.parent().unwrap_or(&root);
                std::fs::create_dir_all(parent)?;
                // Written beside the blobs (one filesystem: the rename is atomic), in a
                // directory of its own that start-up clears after a kill.
                let staging = root.join(PARTIAL_DIR);
                std::fs::create_dir_all(&staging)?;
                let mut tmp = tempfile::NamedTempFile::new_in(&staging)?;
                tmp.write_all(&data)?;
                tmp.as_file().sync_all()?;
                tmp.persist(&dest).map_err(|e| e.error)?;
                std::fs::File::open(parent)?.sync_all()
            })
            .await
            .map_err(std::io::Error::other)??;
            return Ok(sha);
        }
        self.store.put(&key(&sha), data.into()).await?;
        Ok(sha)
    }

    /// Read a whole blob.
    pub async fn get(&self, sha256: &str) -> Result<Bytes, BlobError> {
        match self.store.get(&key(sha256)).await {
            Ok(r) => Ok(r.bytes().await?),
            Err(object_store::Error::NotFound { .. }) => Err(BlobError::NotFound(sha256.into())),
            Err(e) => Err(e.into()),
        }
    }

    /// A whole blob, for job code on a blocking thread: read straight into one buffer on the
    /// local filesystem (no second copy), fetched through the runtime `handle` elsewhere.
    pub fn read_blocking(
        &self,
        sha256: &str,
        handle: &tokio::runtime::Handle,
    ) -> Result<Vec<u8>, BlobError> {
        if let Some(root) = &self.local_root {
            return match std::fs::read(root.join(key(sha256).as_ref())) {
                Ok(v) => Ok(v),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                    Err(BlobError::NotFound(sha256.into()))
                }
                Err(e) => Err(e.into()),
            };
        }
        handle.block_on(self.get(sha256)).map(Vec::from)
    }

    /// A blob as a stream of chunks (downloads of large artifacts: never loaded whole).
    pub async fn stream(
        &self,
        sha256: &str,
    ) -> Result<futures_util::stream::BoxStream<'static, Result<Bytes, std::io::Error>>, BlobError>
    {
        use futures_util::{StreamExt, TryStreamExt};
        match self.store.get(&key(sha256)).await {
            Ok(r) => Ok(r.into_stream().map_err(std::io::Error::other).boxed()),
            Err(object_store::Error::NotFound { .. }) => Err(BlobError::NotFound(sha256.into())),
            Err(e) => Err(e.into()),
        }
    }

    /// A blocking reader over a blob, for job code running on a blocking thread: large inputs
    /// (IMU logs of hundreds of MB) are streamed, never loaded whole. Must not be called from
    /// an async task (it blocks on the runtime `handle` for remote stores).
    pub fn open_blocking(
        &self,
        sha256: &str,
        handle: &tokio::runtime::Handle,
    ) -> Result<Box<dyn std::io::Read + Send>, BlobError> {
        if let Some(root) = &self.local_root {
            let path = root.join(key(sha256).as_ref());
            return match std::fs::File::open(path) {
                Ok(f) => Ok(Box::new(f)),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                    Err(BlobError::NotFound(sha256.into()))
                }
                Err(e) => Err(e.into()),
            };
        }
        let store = self.store.clone();
        let k = key(sha256);
        let result = handle.block_on(async move { store.get(&k).await });
        let stream = match result {
            Ok(r) => r.into_stream(),
            Err(object_store::Error::NotFound { .. }) => {
                return Err(BlobError::NotFound(sha256.into()));
            }
            Err(e) => return Err(e.into()),
        };
        use futures_util::TryStreamExt;
        let reader = tokio_util::io::StreamReader::new(stream.map_err(std::io::Error::other));
        Ok(Box::new(tokio_util::io::SyncIoBridge::new_with_handle(
            reader,
            handle.clone(),
        )))
    }

    /// Delete a blob; a missing blob is not an error.
    pub async fn delete(&self, sha256: &str) -> Result<(), BlobError> {
        match self.store.delete(&key(sha256)).await {
            Ok(()) | Err(object_store::Error::NotFound { .. }) => Ok(()),
            Err(e) => Err(e.into()),
        }
    }
}

/// Flush the directory entry of `path` (a rename is durable only once its directory is).
async fn sync_dir(path: &FsPath) -> std::io::Result<()> {
    match path.parent() {
        Some(dir) => tokio::fs::File::open(dir).await?.sync_all().await,
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn put_get_dedupe_delete() {
        let dir = tempfile::tempdir().unwrap();
        let blobs = Blobs::local(&dir.path().join("blobs")).unwrap();
        let sha = blobs.put_bytes(Bytes::from_static(b"hello")).await.unwrap();
        assert_eq!(
            sha,
            "2cf24dba5fb0a30e26e83b2ac5b9e29e1b161e5c1fa7425e73043362938b9824"
        );
        assert_eq!(&blobs.get(&sha).await.unwrap()[..], b"hello");
        let f = dir.path().join("f");
        std::fs::write(&f, b"hello").unwrap();
        blobs.put_file(&sha, &f).await.unwrap();
        blobs.delete(&sha).await.unwrap();
        assert!(matches!(blobs.get(&sha).await, Err(BlobError::NotFound(_))));
        blobs.delete(&sha).await.unwrap();
    }

    #[tokio::test]
    async fn half_written_blobs_are_staged_apart_and_cleared_at_start() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("blobs");
        let blobs = Blobs::local(&root).unwrap();
        blobs.put_bytes(Bytes::from_static(b"x")).await.unwrap();
        // What a kill in the middle of a write leaves.
        let partial = root.join(PARTIAL_DIR);
        std::fs::write(partial.join(".tmpA1b2C3"), b"half").unwrap();
        blobs.clear_partial(std::time::Duration::from_secs(3600));
        assert!(
            partial.join(".tmpA1b2C3").exists(),
            "a fresh file may be a live write"
        );
        blobs.clear_partial(std::time::Duration::ZERO);
        assert_eq!(std::fs::read_dir(&partial).unwrap().count(), 0);
        assert!(
            blobs
                .exists(&crate::document::sha256_hex(b"x"))
                .await
                .unwrap()
        );
    }
}
