//! Shared application state: configuration, store, blobs, the job event bus and the
//! in-process cancel flags of running jobs.

use std::collections::HashMap;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex, RwLock};

use bytes::Bytes;

use metrics_exporter_prometheus::PrometheusHandle;
use serde::Serialize;
use tokio::sync::{Notify, broadcast};
use uuid::Uuid;

use crate::blobs::Blobs;
use crate::config::Config;
use crate::store::Store;

/// A change of a job's status or progress, fanned out to SSE subscribers.
#[derive(Debug, Clone, Serialize)]
pub struct JobEvent {
    pub id: Uuid,
    /// `status` or `progress`.
    #[serde(skip)]
    pub event: &'static str,
    pub status: crate::store::JobStatus,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub progress: Option<serde_json::Value>,
}

struct Inner {
    config: Config,
    store: Arc<dyn Store>,
    blobs: Blobs,
    events: broadcast::Sender<JobEvent>,
    wake: Notify,
    metrics: Option<PrometheusHandle>,
    cancel_flags: Mutex<HashMap<Uuid, Arc<AtomicBool>>>,
    finished_jobs: RwLock<HashMap<Uuid, Bytes>>,
    watchers: crate::job_watch::Watchers,
    rate_limiter: crate::auth::RateLimiter,
    token_cache: crate::token_cache::TokenCache,
}

/// Cheap-to-clone handle on everything a handler or worker needs.
#[derive(Clone)]
pub struct AppState {
    inner: Arc<Inner>,
}

impl AppState {
    pub fn new(
        config: Config,
        store: Arc<dyn Store>,
        blobs: Blobs,
        metrics: Option<PrometheusHandle>,
    ) -> Self {
        let (events, _) = broadcast::channel(1024);
        Self {
            inner: Arc::new(Inner {
                config,
                store,
                blobs,
                events,
                wake: Notify::new(),
                metrics,
                cancel_flags: Mutex::new(HashMap::new()),
                finished_jobs: RwLock::new(HashMap::new()),
                watchers: Default::default(),
                rate_limiter: Default::default(),
                token_cache: Default::default(),
            }),
        }
    }

    /// Shared watchers of followed jobs (see [`crate::job_watch`]).
    pub fn watchers(&self) -> &crate::job_watch::Watchers {
        &self.inner.watchers
    }

    /// Per-token request budgets (see [`crate::auth`]).
    /// Token lookups of this replica (see [`crate::token_cache`]).
    pub fn token_cache(&self) -> &crate::token_cache::TokenCache {
        &self.inner.token_cache
    }

    pub fn rate_limiter(&self) -> &crate::auth::RateLimiter {
        &self.inner.rate_limiter
    }

    pub fn config(&self) -> &Config {
        &self.inner.config
    }

    pub fn store(&self) -> &dyn Store {
        self.inner.store.as_ref()
    }

    pub fn blobs(&self) -> &Blobs {
        &self.inner.blobs
    }

    pub fn metrics(&self) -> Option<&PrometheusHandle> {
        self.inner.metrics.as_ref()
    }

    /// Publish a job event (no-op without subscribers).
    pub fn publish(&self, ev: JobEvent) {
        let _ = self.inner.events.send(ev);
    }

    pub fn subscribe(&self) -> broadcast::Receiver<JobEvent> {
        self.inner.events.subscribe()
    }

    /// Wake an idle worker (a job was queued).
    pub fn wake_workers(&self) {
        self.inner.wake.notify_one();
    }

    pub fn wake(&self) -> &Notify {
        &self.inner.wake
    }

    /// The serialized view of a finished job, if cached. Finished jobs never change (until
    /// retention deletes them, which clears the cache), so this is safe across replicas too.
    pub fn cached_job(&self, id: &Uuid) -> Option<Bytes> {
        self.inner.finished_jobs.read().ok()?.get(id).cloned()
    }

    /// Cache the serialized view of a finished job; the cache is bounded by
    /// `job_cache_entries` and simply starts over when full.
    pub fn cache_job(&self, id: Uuid, view: Bytes) {
        let cap = self.inner.config.job_cache_entries;
        if cap == 0 {
            return;
        }
        if let Ok(mut m) = self.inner.finished_jobs.write() {
            if m.len() >= cap {
                m.clear();
            }
            m.insert(id, view);
        }
    }

    /// Forget cached jobs (after pruning).
    pub fn clear_job_cache(&self) {
        if let Ok(mut m) = self.inner.finished_jobs.write() {
            m.clear();
        }
    }

    /// Register the cancel flag of a job running in this process.
    pub fn register_cancel(&self, id: Uuid, flag: Arc<AtomicBool>) {
        if let Ok(mut m) = self.inner.cancel_flags.lock() {
            m.insert(id, flag);
        }
    }

    pub fn unregister_cancel(&self, id: Uuid) {
        if let Ok(mut m) = self.inner.cancel_flags.lock() {
            m.remove(&id);
        }
    }

    /// Raise the cancel flag of a job if it runs in this process (others notice at heartbeat).
    pub fn signal_cancel(&self, id: Uuid) {
        if let Ok(m) = self.inner.cancel_flags.lock()
            && let Some(f) = m.get(&id)
        {
            f.store(true, std::sync::atomic::Ordering::SeqCst);
        }
    }
}
