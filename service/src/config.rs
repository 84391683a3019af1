//! Service configuration: built-in defaults, then a TOML file, then `CALIPER_*` environment
//! variables, then command-line flags (each later source wins).
//!
//! clap already gives flags precedence over the environment (`#[arg(env)]`), so the flags
//! struct holds `Option`s and the file fills whatever neither set.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use clap::Args;
use serde::Deserialize;

/// Effective configuration of a running service.
#[derive(Debug, Clone)]
pub struct Config {
    /// Address to listen on.
    pub listen: SocketAddr,
    /// Directory holding the SQLite database and the blob store.
    pub data_dir: PathBuf,
    /// Number of jobs run at once.
    pub workers: usize,
    /// How long a worker's claim on a job lasts without a heartbeat.
    pub lease_secs: u64,
    /// Interval between heartbeats (also the progress flush interval).
    pub heartbeat_ms: u64,
    /// Attempts per job before a transient failure becomes final.
    pub max_attempts: u32,
    /// First retry delay; doubles per attempt up to `backoff_cap_ms`.
    pub backoff_base_ms: u64,
    /// Largest retry delay.
    pub backoff_cap_ms: u64,
    /// Queued jobs allowed before `POST /v1/jobs` answers 429.
    pub max_queued_jobs: u64,
    /// Run-time limit of a job attempt, unless `time_limits` names its kind.
    pub job_time_limit_secs: u64,
    /// Per-kind run-time limits in seconds (file only).
    pub time_limits: BTreeMap<String, u64>,
    /// Finished jobs older than this are pruned (with their artifacts).
    pub retention_days: u64,
    /// Largest request body of an upload.
    pub max_upload_bytes: u64,
    /// Most files in one dataset (after unpacking archives).
    pub max_files: usize,
    /// Largest image in pixels (width × height) accepted at upload.
    pub max_image_pixels: u64,
    /// Largest image side accepted at upload.
    pub max_image_side: u32,
    /// Largest total uncompressed size of an archive.
    pub max_archive_bytes: u64,
    /// Largest ratio of uncompressed to compressed size, per entry and in total.
    pub max_compression_ratio: u64,
    /// Finished jobs kept in memory for `GET /v1/jobs/{id}` (0 disables the cache).
    pub job_cache_entries: usize,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            listen: SocketAddr::from(([127, 0, 0, 1], 8080)),
            data_dir: PathBuf::from("./caliper-data"),
            workers: std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(2),
            lease_secs: 30,
            heartbeat_ms: 1000,
            max_attempts: 3,
            backoff_base_ms: 1000,
            backoff_cap_ms: 60_000,
            max_queued_jobs: 1000,
            job_time_limit_secs: 3600,
            time_limits: BTreeMap::new(),
            retention_days: 30,
            max_upload_bytes: 4 << 30,
            max_files: 5000,
            max_image_pixels: 50_000_000,
            max_image_side: 20_000,
            max_archive_bytes: 4 << 30,
            max_compression_ratio: 200,
            job_cache_entries: 10_000,
        }
    }
}

/// Flags of `caliper serve`; each also reads a `CALIPER_*` environment variable.
#[derive(Debug, Clone, Default, Args)]
pub struct ConfigArgs {
    /// TOML configuration file (keys as the flags, with underscores).
    #[arg(long, env = "CALIPER_CONFIG")]
    pub config: Option<PathBuf>,
    /// Address to listen on [default: 127.0.0.1:8080].
    #[arg(long, env = "CALIPER_LISTEN")]
    pub listen: Option<SocketAddr>,
    /// Data directory: SQLite database and blobs [default: ./caliper-data].
    #[arg(long, env = "CALIPER_DATA_DIR")]
    pub data_dir: Option<PathBuf>,
    /// Jobs run at once [default: number of cores].
    #[arg(long, env = "CALIPER_WORKERS")]
    pub workers: Option<usize>,
    /// Lease of a running job without heartbeat, seconds [default: 30].
    #[arg(long, env = "CALIPER_LEASE_SECS")]
    pub lease_secs: Option<u64>,
    /// Heartbeat and progress interval, milliseconds [default: 1000].
    #[arg(long, env = "CALIPER_HEARTBEAT_MS")]
    pub heartbeat_ms: Option<u64>,
    /// Attempts per job for transient failures [default: 3].
    #[arg(long, env = "CALIPER_MAX_ATTEMPTS")]
    pub max_attempts: Option<u32>,
    /// First retry delay, milliseconds [default: 1000].
    #[arg(long, env = "CALIPER_BACKOFF_BASE_MS")]
    pub backoff_base_ms: Option<u64>,
    /// Largest retry delay, milliseconds [default: 60000].
    #[arg(long, env = "CALIPER_BACKOFF_CAP_MS")]
    pub backoff_cap_ms: Option<u64>,
    /// Queued jobs before 429 [default: 1000].
    #[arg(long, env = "CALIPER_MAX_QUEUED_JOBS")]
    pub max_queued_jobs: Option<u64>,
    /// Default run-time limit per job attempt, seconds [default: 3600].
    #[arg(long, env = "CALIPER_JOB_TIME_LIMIT_SECS")]
    pub job_time_limit_secs: Option<u64>,
    /// Days finished jobs are kept [default: 30].
    #[arg(long, env = "CALIPER_RETENTION_DAYS")]
    pub retention_days: Option<u64>,
    /// Largest upload body, bytes [default: 4294967296].
    #[arg(long, env = "CALIPER_MAX_UPLOAD_BYTES")]
    pub max_upload_bytes: Option<u64>,
    /// Most files per dataset [default: 5000].
    #[arg(long, env = "CALIPER_MAX_FILES")]
    pub max_files: Option<usize>,
    /// Largest image, pixels [default: 50000000].
    #[arg(long, env = "CALIPER_MAX_IMAGE_PIXELS")]
    pub max_image_pixels: Option<u64>,
    /// Largest image side, pixels [default: 20000].
    #[arg(long, env = "CALIPER_MAX_IMAGE_SIDE")]
    pub max_image_side: Option<u32>,
    /// Largest uncompressed archive, bytes [default: 4294967296].
    #[arg(long, env = "CALIPER_MAX_ARCHIVE_BYTES")]
    pub max_archive_bytes: Option<u64>,
    /// Largest compression ratio in archives [default: 200].
    #[arg(long, env = "CALIPER_MAX_COMPRESSION_RATIO")]
    pub max_compression_ratio: Option<u64>,
    /// Finished jobs cached in memory for reads; 0 disables [default: 10000].
    #[arg(long, env = "CALIPER_JOB_CACHE_ENTRIES")]
    pub job_cache_entries: Option<usize>,
}

/// The TOML file: the same keys as the flags, all optional.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileConfig {
    listen: Option<SocketAddr>,
    data_dir: Option<PathBuf>,
    workers: Option<usize>,
    lease_secs: Option<u64>,
    heartbeat_ms: Option<u64>,
    max_attempts: Option<u32>,
    backoff_base_ms: Option<u64>,
    backoff_cap_ms: Option<u64>,
    max_queued_jobs: Option<u64>,
    job_time_limit_secs: Option<u64>,
    #[serde(default)]
    time_limits: BTreeMap<String, u64>,
    retention_days: Option<u64>,
    max_upload_bytes: Option<u64>,
    max_files: Option<usize>,
    max_image_pixels: Option<u64>,
    max_image_side: Option<u32>,
    max_archive_bytes: Option<u64>,
    max_compression_ratio: Option<u64>,
    job_cache_entries: Option<usize>,
}

/// A configuration that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config file {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("invalid config file {path}: {source}")]
    Parse {
        path: PathBuf,
        source: toml::de::Error,
    },
    #[error("invalid configuration: {0}")]
    Invalid(String),
}

impl ConfigArgs {
    /// Resolve flags + environment over the file over the defaults.
    pub fn resolve(&self) -> Result<Config, ConfigError> {
        let file = match &self.config {
            Some(path) => load_file(path)?,
            None => FileConfig::default(),
        };
        let d = Config::default();
        let cfg = Config {
            listen: self.listen.or(file.listen).unwrap_or(d.listen),
            data_dir: self
                .data_dir
                .clone()
                .or(file.data_dir)
                .unwrap_or(d.data_dir),
            workers: self.workers.or(file.workers).unwrap_or(d.workers),
            lease_secs: self.lease_secs.or(file.lease_secs).unwrap_or(d.lease_secs),
            heartbeat_ms: self
                .heartbeat_ms
                .or(file.heartbeat_ms)
                .unwrap_or(d.heartbeat_ms),
            max_attempts: self
                .max_attempts
                .or(file.max_attempts)
                .unwrap_or(d.max_attempts),
            backoff_base_ms: self
                .backoff_base_ms
                .or(file.backoff_base_ms)
                .unwrap_or(d.backoff_base_ms),
            backoff_cap_ms: self
                .backoff_cap_ms
                .or(file.backoff_cap_ms)
                .unwrap_or(d.backoff_cap_ms),
            max_queued_jobs: self
                .max_queued_jobs
                .or(file.max_queued_jobs)
                .unwrap_or(d.max_queued_jobs),
            job_time_limit_secs: self
                .job_time_limit_secs
                .or(file.job_time_limit_secs)
                .unwrap_or(d.job_time_limit_secs),
            time_limits: file.time_limits,
            retention_days: self
                .retention_days
                .or(file.retention_days)
                .unwrap_or(d.retention_days),
            max_upload_bytes: self
                .max_upload_bytes
                .or(file.max_upload_bytes)
                .unwrap_or(d.max_upload_bytes),
            max_files: self.max_files.or(file.max_files).unwrap_or(d.max_files),
            max_image_pixels: self
                .max_image_pixels
                .or(file.max_image_pixels)
                .unwrap_or(d.max_image_pixels),
            max_image_side: self
                .max_image_side
                .or(file.max_image_side)
                .unwrap_or(d.max_image_side),
            max_archive_bytes: self
                .max_archive_bytes
                .or(file.max_archive_bytes)
                .unwrap_or(d.max_archive_bytes),
            max_compression_ratio: self
                .max_compression_ratio
                .or(file.max_compression_ratio)
                .unwrap_or(d.max_compression_ratio),
            job_cache_entries: self
                .job_cache_entries
                .or(file.job_cache_entries)
                .unwrap_or(d.job_cache_entries),
        };
        cfg.validate()?;
        Ok(cfg)
    }
}

impl Config {
    /// Reject values that would make the service misbehave.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |m: &str| Err(ConfigError::Invalid(m.to_string()));
        if self.workers == 0 {
            return bad("workers must be at least 1");
        }
        if self.heartbeat_ms == 0 || self.heartbeat_ms >= self.lease_secs * 1000 {
            return bad("heartbeat_ms must be positive and shorter than lease_secs");
        }
        if self.max_attempts == 0 {
            return bad("max_attempts must be at least 1");
        }
        if self.backoff_cap_ms < self.backoff_base_ms {
            return bad("backoff_cap_ms must be at least backoff_base_ms");
        }
        if self.max_compression_ratio < 2 {
            return bad("max_compression_ratio must be at least 2");
        }
        Ok(())
    }

    /// Run-time limit for a job kind.
    pub fn time_limit(&self, kind: &str) -> std::time::Duration {
        std::time::Duration::from_secs(
            self.time_limits
                .get(kind)
                .copied()
                .unwrap_or(self.job_time_limit_secs),
        )
    }

    /// Image limits for upload validation and decoding.
    pub fn image_limits(&self) -> caliper_core::io::ImageLimits {
        caliper_core::io::ImageLimits {
            max_width: self.max_image_side,
            max_height: self.max_image_side,
            max_pixels: self.max_image_pixels,
            ..Default::default()
        }
    }
}

fn load_file(path: &Path) -> Result<FileConfig, ConfigError> {
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    toml::from_str(&text).map_err(|source| ConfigError::Parse {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_win_over_file_and_file_over_defaults() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("caliper.toml");
        std::fs::write(
            &path,
            "workers = 7\nlease_secs = 99\n[time_limits]\nblur_score = 5\n",
        )
        .unwrap();
        let args = ConfigArgs {
            config: Some(path),
            workers: Some(3),
            ..Default::default()
        };
        let cfg = args.resolve().unwrap();
        assert_eq!(cfg.workers, 3);
        assert_eq!(cfg.lease_secs, 99);
        assert_eq!(cfg.max_attempts, Config::default().max_attempts);
        assert_eq!(cfg.time_limit("blur_score").as_secs(), 5);
        assert_eq!(cfg.time_limit("other").as_secs(), 3600);
    }

    #[test]
    fn unknown_file_keys_are_rejected() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.toml");
        std::fs::write(&path, "wrokers = 2\n").unwrap();
        let args = ConfigArgs {
            config: Some(path),
            ..Default::default()
        };
        assert!(matches!(args.resolve(), Err(ConfigError::Parse { .. })));
    }
}
