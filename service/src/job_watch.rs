//! One watcher per followed job, shared by all its event-stream clients (issue D3: each
//! `/events` stream polled the store on its own and outlived its client).
//!
//! The first client of a job starts a watcher task that listens to the in-process event bus
//! and polls the store every two seconds (changes made by another process); every client
//! reads the watcher's latest state from a `watch` channel. The watcher ends when its job
//! reaches a terminal status or when its last client is gone.

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::Duration;

use tokio::sync::watch;
use uuid::Uuid;

use crate::state::{AppState, JobEvent};
use crate::store::{JobRecord, JobStatus};

/// The latest state of a followed job: the event kind and its payload.
pub type Latest = Option<JobEvent>;

/// Watchers by job id.
#[derive(Default)]
pub struct Watchers {
    by_job: Mutex<HashMap<Uuid, watch::Sender<Latest>>>,
}

/// Follow `job` (as just read from the store): a receiver of its latest state, starting with
/// `job` itself. Subscribe to the bus before reading `job` so no change falls in between.
pub fn follow(
    state: &AppState,
    job: &JobRecord,
    bus: tokio::sync::broadcast::Receiver<JobEvent>,
) -> watch::Receiver<Latest> {
    let initial = Some(JobEvent {
        id: job.id,
        event: "status",
        status: job.status,
        progress: job.progress.clone(),
    });
    let watchers = state.watchers();
    let Ok(mut map) = watchers.by_job.lock() else {
        // A poisoned lock: serve a stream that only has the current state.
        return watch::channel(initial).1;
    };
    if let Some(tx) = map.get(&job.id) {
        return tx.subscribe();
    }
    let (tx, rx) = watch::channel(initial);
    map.insert(job.id, tx.clone());
    drop(map);
    let st = state.clone();
    let (id, status) = (job.id, job.status);
    tokio::spawn(async move {
        run(&st, id, status, bus, &tx).await;
        if let Ok(mut map) = st.watchers().by_job.lock() {
            map.remove(&id);
        }
    });
    rx
}

/// Number of jobs being watched (for tests and metrics).
pub fn active(state: &AppState) -> usize {
    state.watchers().by_job.lock().map(|m| m.len()).unwrap_or(0)
}

async fn run(
    state: &AppState,
    id: Uuid,
    mut last: JobStatus,
    mut bus: tokio::sync::broadcast::Receiver<JobEvent>,
    tx: &watch::Sender<Latest>,
) {
    if last.is_terminal() {
        return;
    }
    loop {
        tokio::select! {
            // Every client left: stop (unless one arrives while we deregister).
            _ = tx.closed() => {
                if let Ok(mut map) = state.watchers().by_job.lock()
                    && tx.receiver_count() == 0
                {
                    map.remove(&id);
                    return;
                }
            }
            ev = bus.recv() => match ev {
                Ok(ev) if ev.id == id => {
                    last = ev.status;
                    tx.send_replace(Some(ev));
                    if last.is_terminal() { return; }
                }
                Ok(_) | Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                Err(_) => return,
            },
            // Changes made by another process, or events we lagged behind on.
            _ = tokio::time::sleep(Duration::from_secs(2)) => {
                match state.store().get_job(id).await {
                    Ok(Some(j)) if j.status != last => {
                        last = j.status;
                        tx.send_replace(Some(JobEvent { id, event: "status", status: j.status, progress: j.progress }));
                        if last.is_terminal() { return; }
                    }
                    Ok(None) => return,
                    _ => {}
                }
            }
        }
    }
}
