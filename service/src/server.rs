//! Starting and stopping the service: data directory, store, blobs, workers, listener.

use std::fs::File;
use std::net::SocketAddr;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use metrics_exporter_prometheus::{PrometheusBuilder, PrometheusHandle};
use tokio::task::JoinHandle;
use tokio_util::task::TaskTracker;

use crate::blobs::Blobs;
use crate::config::Config;
use crate::jobs::worker::{self, Shutdown};
use crate::state::AppState;
use crate::store::{SqliteStore, Store};

/// Why the service could not start.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    #[error("data directory {0}: {1}")]
    DataDir(String, std::io::Error),
    #[error(
        "data directory {0} is in use by another caliper process (the embedded profile needs it exclusively)"
    )]
    Locked(String),
    #[error("store: {0}")]
    Store(#[from] crate::store::StoreError),
    #[error("blobs: {0}")]
    Blobs(#[from] crate::blobs::BlobError),
    #[error("cannot listen on {0}: {1}")]
    Listen(SocketAddr, std::io::Error),
}

/// The process-wide Prometheus recorder (installed once, shared by every app in the process).
pub fn metrics_handle() -> Option<PrometheusHandle> {
    static HANDLE: OnceLock<Option<PrometheusHandle>> = OnceLock::new();
    HANDLE
        .get_or_init(|| {
            let recorder = PrometheusBuilder::new()
                .set_buckets(&[
                    0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0,
                    10.0, 30.0, 60.0, 300.0, 1800.0,
                ])
                .ok()?
                .build_recorder();
            let handle = recorder.handle();
            metrics::set_global_recorder(recorder).ok()?;
            Some(handle)
        })
        .clone()
}

/// Open the store and blobs of the embedded profile in `config.data_dir`.
pub async fn open_state(config: Config) -> Result<(AppState, File), StartError> {
    let dir = config.data_dir.clone();
    let show = dir.display().to_string();
    std::fs::create_dir_all(dir.join("tmp")).map_err(|e| StartError::DataDir(show.clone(), e))?;
    let lock = File::create(dir.join("LOCK")).map_err(|e| StartError::DataDir(show.clone(), e))?;
    if lock.try_lock().is_err() {
        return Err(StartError::Locked(show));
    }
    // Leftovers of interrupted uploads.
    if let Ok(entries) = std::fs::read_dir(dir.join("tmp")) {
        for e in entries.flatten() {
            let _ = std::fs::remove_file(e.path());
        }
    }
    let store = SqliteStore::open(&dir.join("caliper.db")).await?;
    // We hold the data directory exclusively: any job still marked running belonged to a
    // previous process that died, so it can be re-queued now rather than after lease expiry.
    let recovered = store.recover_leases(crate::clock::now_ms(), true).await?;
    if recovered > 0 {
        tracing::warn!(
            jobs = recovered,
            "re-queued jobs left running by a previous process"
        );
    }
    let blobs = Blobs::local(&dir.join("blobs"))?;
    let state = AppState::new(config, Arc::new(store), blobs, metrics_handle());
    Ok((state, lock))
}

/// A running service.
pub struct Server {
    pub addr: SocketAddr,
    pub state: AppState,
    shutdown: Shutdown,
    http_stop: tokio_util::sync::CancellationToken,
    http: JoinHandle<()>,
    tracker: TaskTracker,
    _lock: File,
}

/// Start the service: workers and the HTTP listener.
pub async fn start(config: Config) -> Result<Server, StartError> {
    let listen = config.listen;
    let (state, lock) = open_state(config).await?;
    let shutdown = Shutdown::default();
    let tracker = TaskTracker::new();
    worker::start(state.clone(), shutdown.clone(), &tracker);
    let listener = tokio::net::TcpListener::bind(listen)
        .await
        .map_err(|e| StartError::Listen(listen, e))?;
    let addr = listener
        .local_addr()
        .map_err(|e| StartError::Listen(listen, e))?;
    let app = crate::api::app(state.clone());
    let http_stop = tokio_util::sync::CancellationToken::new();
    let stop = http_stop.clone();
    let http = tokio::spawn(async move {
        let r = axum::serve(listener, app)
            .with_graceful_shutdown(async move { stop.cancelled().await })
            .await;
        if let Err(e) = r {
            tracing::error!(error = %e, "http server failed");
        }
    });
    Ok(Server {
        addr,
        state,
        shutdown,
        http_stop,
        http,
        tracker,
        _lock: lock,
    })
}

impl Server {
    /// Graceful shutdown: stop taking jobs and requests, give running jobs `grace` to finish,
    /// then stop them (they are re-queued for the next start).
    pub async fn shutdown(self, grace: Duration) {
        self.shutdown.stop.cancel();
        self.http_stop.cancel();
        self.tracker.close();
        if tokio::time::timeout(grace, self.tracker.wait())
            .await
            .is_err()
        {
            tracing::warn!("running jobs did not finish within the grace period; re-queuing them");
            self.shutdown.abort.cancel();
            self.tracker.wait().await;
        }
        let _ = tokio::time::timeout(Duration::from_secs(5), self.http).await;
    }
}
