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
use crate::store::{PgStore, SqliteStore, Store};

/// Why the service could not start.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    #[error("data directory {0}: {1}")]
    DataDir(String, std::io::Error),
    #[error(
        "data directory {0} is in use by another caliper process (each process needs its own: give each replica its own --data-dir)"
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

/// Open the store and blobs: the embedded profile (SQLite + blobs in `config.data_dir`,
/// held exclusively), or a replica of the production profile (PostgreSQL shared with other
/// replicas; the data directory then holds only this process's temporary files). Either way
/// the data directory is held exclusively.
pub async fn open_state(config: Config) -> Result<(AppState, Option<File>), StartError> {
    let dir = config.data_dir.clone();
    let show = dir.display().to_string();
    std::fs::create_dir_all(dir.join("tmp")).map_err(|e| StartError::DataDir(show.clone(), e))?;
    let store: Arc<dyn Store> = if config.shared_store() {
        Arc::new(PgStore::connect(&config.database_url).await?)
    } else {
        Arc::new(SqliteStore::open(&dir.join("caliper.db")).await?)
    };
    // The data directory is one process's: with SQLite it holds the store, on the shared
    // profile this replica's temporary files. Holding it lets a restart clear what a killed
    // predecessor left in `tmp/` (interrupted uploads) without touching a live process's.
    let lock = File::create(dir.join("LOCK")).map_err(|e| StartError::DataDir(show.clone(), e))?;
    if lock.try_lock().is_err() {
        return Err(StartError::Locked(show));
    }
    if let Ok(entries) = std::fs::read_dir(dir.join("tmp")) {
        for e in entries.flatten() {
            let _ = std::fs::remove_file(e.path());
        }
    }
    let lock = if store.shared() {
        // Leases of a dead replica expire on the database clock; its pins expire too.
        Some(lock)
    } else {
        // We hold the store exclusively: any job still marked running belonged to a previous
        // process that died, so it can be re-queued now rather than after lease expiry.
        let recovered = store.recover_leases(crate::clock::now_ms(), true).await?;
        if recovered > 0 {
            tracing::warn!(
                jobs = recovered,
                "re-queued jobs left running by a previous process"
            );
        }
        // Pins belong to writers of a previous process: drop them; the blobs they protected
        // become GC candidates.
        store.clear_pins(crate::clock::now_ms()).await?;
        Some(lock)
    };
    let blobs = if config.blob_url.is_empty() {
        Blobs::local(&config.blob_path())?
    } else {
        Blobs::s3(&config.blob_url)?
    };
    // Blobs a killed process was writing: all of them when this process holds the blob
    // directory alone, those older than an hour in a directory shared by replicas.
    blobs.clear_partial(if store.shared() {
        Duration::from_secs(3600)
    } else {
        Duration::ZERO
    });
    let state = AppState::new(config, store, blobs, metrics_handle());
    Ok((state, lock))
}

/// Wake this replica's workers when any replica queues a job (`LISTEN`), polling staying the
/// fallback if the connection drops; and keep the token cache in the revocation protocol of
/// [`crate::token_cache`]: registered and heartbeating while the connection is up, emptied
/// and acknowledged on every revocation, not serving otherwise.
fn listen_for_jobs(
    state: &AppState,
    tracker: &TaskTracker,
    stop: tokio_util::sync::CancellationToken,
) {
    let Some(pg) = state.store().as_pg() else {
        return;
    };
    let pg = pg.clone();
    let state = state.clone();
    let replica = uuid::Uuid::now_v7().to_string();
    tracker.spawn(async move {
        loop {
            let mut listener = match sqlx::postgres::PgListener::connect_with(pg.pool()).await {
                Ok(l) => l,
                Err(e) => {
                    tracing::warn!(error = %e, "LISTEN connection failed; retrying");
                    tokio::select! {
                        _ = stop.cancelled() => return,
                        _ = tokio::time::sleep(Duration::from_secs(1)) => continue,
                    }
                }
            };
            let channels = [
                crate::store::postgres::JOBS_CHANNEL,
                crate::store::postgres::TOKENS_CHANNEL,
            ];
            if let Err(e) = listener.listen_all(channels).await {
                tracing::warn!(error = %e, "LISTEN failed; retrying");
                continue;
            }
            // Revocations are heard from now on: once registered, lookups may be cached.
            let cache = state.token_cache();
            let mut beat = tokio::time::interval(crate::token_cache::HEARTBEAT);
            beat.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            let mut joined = false;
            loop {
                tokio::select! {
                    _ = stop.cancelled() => {
                        cache.stop();
                        let leave = pg.leave_token_caches(&replica);
                        let _ = tokio::time::timeout(Duration::from_secs(1), leave).await;
                        return;
                    }
                    _ = beat.tick() => {
                        let sent = std::time::Instant::now();
                        let alive = if joined {
                            pg.token_cache_heartbeat(&replica).await
                        } else {
                            pg.join_token_caches(&replica).await.map(|()| true)
                        };
                        match alive {
                            Ok(true) => {
                                joined = true;
                                cache.renew(sent);
                            }
                            // The row was removed (by a replica that took us for dead).
                            Ok(false) => joined = false,
                            Err(e) => tracing::warn!(error = %e, "token cache heartbeat failed"),
                        }
                    }
                    // `try_recv`, not `recv`: the latter reconnects silently, and a
                    // revocation sent meanwhile would be lost without our knowing.
                    n = listener.try_recv() => match n {
                        Ok(Some(n)) if n.channel() == crate::store::postgres::TOKENS_CHANNEL => {
                            cache.invalidate();
                            if let Ok(seq) = n.payload().parse::<i64>()
                                && let Err(e) = pg.ack_token_revocation(&replica, seq).await
                            {
                                tracing::warn!(error = %e, "could not acknowledge a token revocation");
                            }
                        }
                        Ok(Some(_)) => state.wake_workers(),
                        Ok(None) | Err(_) => {
                            // Until a new connection listens, stop caching.
                            cache.stop();
                            tracing::warn!("LISTEN connection lost; reconnecting");
                            break;
                        }
                    },
                }
            }
        }
    });
}

/// A running service.
pub struct Server {
    pub addr: SocketAddr,
    pub state: AppState,
    shutdown: Shutdown,
    http_stop: tokio_util::sync::CancellationToken,
    http: JoinHandle<()>,
    tracker: TaskTracker,
    _lock: Option<File>,
}

/// Start the service: workers and the HTTP listener.
pub async fn start(config: Config) -> Result<Server, StartError> {
    let listen = config.listen;
    let (state, lock) = open_state(config).await?;
    let shutdown = Shutdown::default();
    let tracker = TaskTracker::new();
    worker::start(state.clone(), shutdown.clone(), &tracker);
    listen_for_jobs(&state, &tracker, shutdown.stop.clone());
    let listener = tokio::net::TcpListener::bind(listen)
        .await
        .map_err(|e| StartError::Listen(listen, e))?;
    let addr = listener
        .local_addr()
        .map_err(|e| StartError::Listen(listen, e))?;
    let app = crate::api::app(state.clone());
    let http_stop = tokio_util::sync::CancellationToken::new();
    let stop = http_stop.clone();
    let limits = crate::http_server::ConnLimits {
        header_timeout: Duration::from_secs(state.config().header_timeout_secs),
        max_connections: state.config().max_connections,
    };
    let http = tokio::spawn(crate::http_server::serve(listener, app, limits, stop));
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
    /// Graceful shutdown within `grace`, whatever the running jobs do: stop taking jobs and
    /// requests, give running jobs most of `grace` to finish, then ask them to stop (they are
    /// re-queued without losing an attempt); a job that ignores the request has its thread
    /// abandoned (it dies with the process) and open connections are dropped at the deadline.
    pub async fn shutdown(self, grace: Duration) {
        let deadline = tokio::time::Instant::now() + grace;
        // Time kept back for stopping jobs and writing their re-queue.
        let reserve = (grace / 2).min(Duration::from_secs(2));
        self.shutdown.stop.cancel();
        self.http_stop.cancel();
        self.tracker.close();
        if tokio::time::timeout_at(deadline - reserve, self.tracker.wait())
            .await
            .is_err()
        {
            tracing::warn!("running jobs did not finish within the grace period; re-queuing them");
            self.shutdown.abort.cancel();
            if tokio::time::timeout_at(deadline, self.tracker.wait())
                .await
                .is_err()
            {
                tracing::error!(
                    "workers did not stop by the end of the grace period; their jobs are re-queued at the next start"
                );
            }
        }
        let http = self.http;
        let abort = http.abort_handle();
        if tokio::time::timeout_at(
            deadline.max(tokio::time::Instant::now() + Duration::from_millis(200)),
            http,
        )
        .await
        .is_err()
        {
            // Long-lived connections (event streams) are cut rather than waited for.
            abort.abort();
        }
    }
}
