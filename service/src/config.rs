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

/// Declares every setting once: the effective [`Config`] field with its default, the
/// `caliper serve` flag with its `CALIPER_*` variable and help text, and the TOML key.
macro_rules! settings {
    ($(
        $(#[doc = $doc:literal])*
        $name:ident: $ty:ty = $default:expr, env $env:literal, help $help:literal;
    )*) => {
        /// Effective configuration of a running service.
        #[derive(Debug, Clone)]
        pub struct Config {
            $( $(#[doc = $doc])* pub $name: $ty, )*
            /// Per-kind run-time limits in seconds (file only).
            pub time_limits: BTreeMap<String, u64>,
            /// Enables the `debug_hang` job kind (never returns, ignores cancellation) used by
            /// the test-suite to prove the worker's watchdog; never listed in the API or spec.
            pub debug_job_kinds: bool,
            /// Require bearer tokens even on a loopback address (always required beyond it,
            /// unless `insecure_no_auth`).
            pub auth: bool,
            /// Serve without tokens on a non-loopback address (a lab behind its own gate).
            pub insecure_no_auth: bool,
            /// Serve `/metrics` without a token when auth is on.
            pub metrics_public: bool,
        }

        impl Default for Config {
            fn default() -> Self {
                Self {
                    $( $name: $default, )*
                    time_limits: BTreeMap::new(),
                    debug_job_kinds: false,
                    auth: false,
                    insecure_no_auth: false,
                    metrics_public: false,
                }
            }
        }

        /// Flags of `caliper serve`; each also reads a `CALIPER_*` environment variable.
        #[derive(Debug, Clone, Default, Args)]
        pub struct ConfigArgs {
            /// TOML configuration file (keys as the flags, with underscores).
            #[arg(long, env = "CALIPER_CONFIG")]
            pub config: Option<PathBuf>,
            $(
                #[doc = $help]
                #[arg(long, env = $env)]
                pub $name: Option<$ty>,
            )*
            /// Test-suite only: enable the `debug_hang` job kind.
            #[arg(long, env = "CALIPER_DEBUG_JOB_KINDS", hide = true)]
            pub debug_job_kinds: bool,
            /// Require bearer tokens even on loopback (always required on other addresses).
            #[arg(long, env = "CALIPER_AUTH")]
            pub auth: bool,
            /// Serve without tokens on a non-loopback address (refused otherwise).
            #[arg(long, env = "CALIPER_INSECURE_NO_AUTH", conflicts_with = "auth")]
            pub insecure_no_auth: bool,
            /// Serve /metrics without a token when tokens are required.
            #[arg(long, env = "CALIPER_METRICS_PUBLIC")]
            pub metrics_public: bool,
        }

        /// The TOML file: the same keys as the flags, all optional.
        #[derive(Debug, Default, Deserialize)]
        #[serde(deny_unknown_fields)]
        struct FileConfig {
            $( $name: Option<$ty>, )*
            #[serde(default)]
            time_limits: BTreeMap<String, u64>,
        }

        impl ConfigArgs {
            /// Flags and environment over the file over the defaults.
            fn merge(&self, file: FileConfig) -> Config {
                let d = Config::default();
                Config {
                    $( $name: self.$name.clone().or(file.$name).unwrap_or(d.$name), )*
                    time_limits: file.time_limits,
                    debug_job_kinds: self.debug_job_kinds,
                    auth: self.auth,
                    insecure_no_auth: self.insecure_no_auth,
                    metrics_public: self.metrics_public,
                }
            }
        }
    };
}

settings! {
    /// Address to listen on.
    listen: SocketAddr = SocketAddr::from(([127, 0, 0, 1], 8080)),
        env "CALIPER_LISTEN", help "Address to listen on [default: 127.0.0.1:8080].";
    /// Directory holding the SQLite database and the blob store.
    data_dir: PathBuf = PathBuf::from("./caliper-data"),
        env "CALIPER_DATA_DIR", help "Data directory: SQLite database and blobs [default: ./caliper-data].";
    /// Number of jobs run at once.
    workers: usize = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(2),
        env "CALIPER_WORKERS", help "Jobs run at once [default: number of cores].";
    /// How long a worker's claim on a job lasts without a heartbeat.
    lease_secs: u64 = 30,
        env "CALIPER_LEASE_SECS", help "Lease of a running job without heartbeat, seconds [default: 30].";
    /// Interval between heartbeats (also the progress flush interval).
    heartbeat_ms: u64 = 1000,
        env "CALIPER_HEARTBEAT_MS", help "Heartbeat and progress interval, milliseconds [default: 1000].";
    /// Attempts per job before a transient failure becomes final.
    max_attempts: u32 = 3,
        env "CALIPER_MAX_ATTEMPTS", help "Attempts per job for transient failures [default: 3].";
    /// First retry delay; doubles per attempt up to `backoff_cap_ms`.
    backoff_base_ms: u64 = 1000,
        env "CALIPER_BACKOFF_BASE_MS", help "First retry delay, milliseconds [default: 1000].";
    /// Largest retry delay.
    backoff_cap_ms: u64 = 60_000,
        env "CALIPER_BACKOFF_CAP_MS", help "Largest retry delay, milliseconds [default: 60000].";
    /// Queued jobs allowed before `POST /v1/jobs` answers 429.
    max_queued_jobs: u64 = 1000,
        env "CALIPER_MAX_QUEUED_JOBS", help "Queued jobs before 429 [default: 1000].";
    /// Run-time limit of a job attempt, unless `time_limits` names its kind.
    job_time_limit_secs: u64 = 3600,
        env "CALIPER_JOB_TIME_LIMIT_SECS", help "Default run-time limit per job attempt, seconds [default: 3600].";
    /// Seconds a job asked to stop (cancel, time limit) may take before the worker abandons
    /// its thread, fails or cancels the job and takes the next one.
    job_abandon_secs: u64 = 10,
        env "CALIPER_JOB_ABANDON_SECS", help "Seconds a job asked to stop may take before its thread is abandoned [default: 10].";
    /// Finished jobs older than this are pruned (with their artifacts), unless a document
    /// cites them.
    retention_days: u64 = 30,
        env "CALIPER_RETENTION_DAYS", help "Days finished jobs are kept [default: 30].";
    /// Seconds an unreferenced blob is kept before garbage collection deletes it.
    blob_gc_grace_secs: u64 = 60,
        env "CALIPER_BLOB_GC_GRACE_SECS", help "Seconds an unreferenced blob is kept before it is deleted [default: 60].";
    /// Largest request body of an upload.
    max_upload_bytes: u64 = 4 << 30,
        env "CALIPER_MAX_UPLOAD_BYTES", help "Largest upload body, bytes [default: 4294967296].";
    /// Most files in one dataset (after unpacking archives).
    max_files: usize = 5000,
        env "CALIPER_MAX_FILES", help "Most files per dataset [default: 5000].";
    /// Largest image in pixels (width × height) accepted at upload.
    max_image_pixels: u64 = 50_000_000,
        env "CALIPER_MAX_IMAGE_PIXELS", help "Largest image, pixels [default: 50000000].";
    /// Largest image side accepted at upload (and by every job).
    max_image_side: u32 = 16_384,
        env "CALIPER_MAX_IMAGE_SIDE", help "Largest image side, pixels [default: 16384].";
    /// Longest video clip accepted at upload, seconds.
    video_max_duration_secs: u64 = 300,
        env "CALIPER_VIDEO_MAX_DURATION_SECS", help "Longest video clip, seconds [default: 300].";
    /// Most frames in a video clip accepted at upload.
    video_max_frames: u64 = 18_000,
        env "CALIPER_VIDEO_MAX_FRAMES", help "Most frames in a video clip [default: 18000].";
    /// Largest total uncompressed size of an archive.
    max_archive_bytes: u64 = 4 << 30,
        env "CALIPER_MAX_ARCHIVE_BYTES", help "Largest uncompressed archive, bytes [default: 4294967296].";
    /// Largest ratio of uncompressed to compressed size, per entry and in total.
    max_compression_ratio: u64 = 200,
        env "CALIPER_MAX_COMPRESSION_RATIO", help "Largest compression ratio in archives [default: 200].";
    /// Finished jobs kept in memory for `GET /v1/jobs/{id}` (0 disables the cache).
    job_cache_entries: usize = 10_000,
        env "CALIPER_JOB_CACHE_ENTRIES", help "Finished jobs cached in memory for reads; 0 disables [default: 10000].";
    /// Seconds a client has to send a request's headers; also how long an idle keep-alive
    /// connection stays open.
    header_timeout_secs: u64 = 30,
        env "CALIPER_HEADER_TIMEOUT_SECS", help "Seconds to send request headers; idle keep-alive limit [default: 30].";
    /// Seconds a request body may go without sending data before the request is dropped.
    body_timeout_secs: u64 = 60,
        env "CALIPER_BODY_TIMEOUT_SECS", help "Seconds a request body may stall before it is dropped [default: 60].";
    /// Seconds between keep-alive comments on event streams (how soon a vanished client is
    /// noticed when its job does not change).
    sse_keepalive_secs: u64 = 15,
        env "CALIPER_SSE_KEEPALIVE_SECS", help "Seconds between keep-alives on event streams [default: 15].";
    /// Open HTTP connections at most; further ones wait in the kernel's backlog.
    max_connections: usize = 512,
        env "CALIPER_MAX_CONNECTIONS", help "Open HTTP connections at most [default: 512].";
    /// PostgreSQL URL (`postgres://user@host/db`) of a store shared by replicas; empty: the
    /// embedded SQLite store in `data_dir`. Tokens are required when it is set.
    database_url: String = String::new(),
        env "CALIPER_DATABASE_URL", help "PostgreSQL URL of a store shared by replicas; default: embedded SQLite in the data directory.";
    /// Directory of the content-addressed blobs; empty: `data_dir/blobs`. Replicas on one
    /// PostgreSQL share it (a network file system), as they would share an S3 bucket.
    blob_dir: String = String::new(),
        env "CALIPER_BLOB_DIR", help "Directory of the blobs; default: DATA_DIR/blobs.";
    /// Blobs in S3 or an S3-compatible server: `s3://bucket/prefix` (endpoint, region and
    /// credentials from the `AWS_*` variables); overrides `blob_dir`.
    blob_url: String = String::new(),
        env "CALIPER_BLOB_URL", help "s3://bucket/prefix for blobs in S3 (AWS_* variables give endpoint and credentials); default: local files.";
    /// Requests per second each token may make on average (0: no limit); over it, 429 with
    /// `Retry-After`. Applies when tokens are required.
    rate_limit_per_sec: u32 = 100,
        env "CALIPER_RATE_LIMIT_PER_SEC", help "Requests per second per token when tokens are required; 0 = unlimited [default: 100].";
    /// Requests a token may make in a burst above the average rate.
    rate_limit_burst: u32 = 200,
        env "CALIPER_RATE_LIMIT_BURST", help "Burst of requests per token above the rate [default: 200].";
    /// Browser origins allowed to call the API (CORS), comma-separated, e.g.
    /// `https://dash.example.com`; empty: none (the built-in dashboard is same-origin).
    cors_origins: String = String::new(),
        env "CALIPER_CORS_ORIGINS", help "Comma-separated origins allowed by CORS [default: none].";
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
        let cfg = self.merge(file);
        cfg.validate()?;
        Ok(cfg)
    }
}

impl Config {
    /// Reject values that would make the service misbehave.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |m: &str| Err(ConfigError::Invalid(m.to_string()));
        // Durations are added to millisecond clocks and to `Instant`s: keep every one far
        // from overflow (ten years is more than any real setting).
        const TEN_YEARS_SECS: u64 = 10 * 366 * 86_400;
        for (name, secs) in [
            ("lease_secs", self.lease_secs),
            ("job_time_limit_secs", self.job_time_limit_secs),
            ("job_abandon_secs", self.job_abandon_secs),
            ("blob_gc_grace_secs", self.blob_gc_grace_secs),
            ("header_timeout_secs", self.header_timeout_secs),
            ("body_timeout_secs", self.body_timeout_secs),
            ("sse_keepalive_secs", self.sse_keepalive_secs),
            ("retention_days", self.retention_days.saturating_mul(86_400)),
            ("backoff_cap_ms", self.backoff_cap_ms / 1000),
            ("heartbeat_ms", self.heartbeat_ms / 1000),
        ]
        .into_iter()
        .chain(self.time_limits.iter().map(|(k, v)| (k.as_str(), *v)))
        {
            if secs > TEN_YEARS_SECS {
                return Err(ConfigError::Invalid(format!(
                    "{name} is too large (at most ten years)"
                )));
            }
        }
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
        if self.lease_secs == 0 {
            return bad("lease_secs must be at least 1");
        }
        if self.header_timeout_secs == 0
            || self.body_timeout_secs == 0
            || self.sse_keepalive_secs == 0
        {
            return bad(
                "header_timeout_secs, body_timeout_secs and sse_keepalive_secs must be at least 1",
            );
        }
        if self.max_connections == 0 {
            return bad("max_connections must be at least 1");
        }
        if self.rate_limit_per_sec > 0 && self.rate_limit_burst == 0 {
            return bad("rate_limit_burst must be at least 1 when rate_limit_per_sec is set");
        }
        if !(self.blob_url.is_empty() || self.blob_url.starts_with("s3://")) {
            return bad("blob_url must be an s3://bucket/prefix URL");
        }
        let url = &self.database_url;
        if !(url.is_empty() || url.starts_with("postgres://") || url.starts_with("postgresql://")) {
            return bad("database_url must be a postgres:// URL");
        }
        for o in self.cors_list() {
            if !(o.starts_with("http://") || o.starts_with("https://"))
                || o.ends_with('/')
                || o.chars().any(|c| c.is_whitespace())
            {
                return Err(ConfigError::Invalid(format!(
                    "cors_origins: {o:?} is not an origin like https://dash.example.com"
                )));
            }
        }

        if self.max_image_pixels > caliper_core::io::MAX_IMAGE_PIXELS {
            return Err(ConfigError::Invalid(format!(
                "max_image_pixels is at most {} (the largest image any job accepts)",
                caliper_core::io::MAX_IMAGE_PIXELS
            )));
        }
        if self.max_image_side > caliper_core::io::MAX_IMAGE_SIDE {
            return Err(ConfigError::Invalid(format!(
                "max_image_side is at most {} (the largest side any job accepts)",
                caliper_core::io::MAX_IMAGE_SIDE
            )));
        }
        Ok(())
    }

    /// Whether requests need a bearer token: asked for, or listening beyond loopback without
    /// `insecure_no_auth`.
    pub fn auth_required(&self) -> bool {
        self.auth
            || (!self.insecure_no_auth && (self.shared_store() || !self.listen.ip().is_loopback()))
    }

    /// A store shared with other replicas (PostgreSQL)?
    pub fn shared_store(&self) -> bool {
        !self.database_url.is_empty()
    }

    /// Where blobs live.
    pub fn blob_path(&self) -> PathBuf {
        if self.blob_dir.is_empty() {
            self.data_dir.join("blobs")
        } else {
            PathBuf::from(&self.blob_dir)
        }
    }

    /// The CORS origins, split.
    pub fn cors_list(&self) -> Vec<&str> {
        self.cors_origins
            .split(',')
            .map(str::trim)
            .filter(|o| !o.is_empty())
            .collect()
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

    /// Video limits for upload probing and decoding (frame size as for images).
    pub fn video_limits(&self) -> caliper_core::video::VideoLimits {
        caliper_core::video::VideoLimits {
            max_duration_s: self.video_max_duration_secs as f64,
            max_frames: self.video_max_frames,
            max_pixels: self.max_image_pixels,
            ..Default::default()
        }
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
