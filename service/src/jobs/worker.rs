//! The in-process worker pool.
//!
//! Each worker claims a job (a lease), runs its kind on a blocking thread and, beside it,
//! renews the lease by heartbeat every `heartbeat_ms` while flushing progress and picking up
//! cancel requests. Every write is fenced by (lease owner, attempt): if the lease was lost
//! (another process re-claimed the job after expiry) the worker stops and writes nothing.
//! A maintenance task re-queues expired leases, prunes finished jobs and collects blobs.
//!
//! Job bodies run on threads of their own and are *abandonable*: a job asked to stop (cancel,
//! time limit, shutdown) that has not returned within `job_abandon_secs` (half a second at
//! shutdown) is failed, canceled or re-queued without it; its thread is left to finish or to
//! die with the process, and the worker takes the next job. The time limit is enforced here
//! as well as through the job's own cancellation checks, so a body that never checks cannot
//! outlive it (issue D1).

use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use caliper_core::Progress;
use rand::Rng;
use serde_json::{Value, json};
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;
use uuid::Uuid;

use super::{JobError, JobInput, document, resolve_kind};
use crate::clock::now_ms;
use crate::state::{AppState, JobEvent};
use crate::store::{ArtifactRecord, Finish, Heartbeat, JobRecord, JobStatus, NewDocument};

/// Why a running job was asked to stop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
enum StopReason {
    None = 0,
    Canceled = 1,
    TimeLimit = 2,
    Shutdown = 3,
    LeaseLost = 4,
}

impl StopReason {
    fn from_u8(v: u8) -> Self {
        match v {
            1 => Self::Canceled,
            2 => Self::TimeLimit,
            3 => Self::Shutdown,
            4 => Self::LeaseLost,
            _ => Self::None,
        }
    }
}

/// Life of a job thread, shared by the thread and its worker: whoever moves it away from
/// `RUNNING` first decides whether the result is taken or the thread abandoned.
const THREAD_RUNNING: u8 = 0;
const THREAD_DONE: u8 = 1;
const THREAD_ABANDONED: u8 = 2;

/// How long a job asked to stop by a shutdown may take before its thread is abandoned (the
/// shutdown grace period has already passed by then).
const SHUTDOWN_ABANDON: Duration = Duration::from_millis(500);

/// Progress and cancellation seen by the core algorithm.
struct JobProgress {
    flag: Arc<AtomicBool>,
    reason: Arc<AtomicU8>,
    deadline: Instant,
    latest: Arc<Mutex<Option<Value>>>,
}

impl JobProgress {
    fn stop(&self, why: StopReason) {
        let _ = self.reason.compare_exchange(
            StopReason::None as u8,
            why as u8,
            Ordering::SeqCst,
            Ordering::SeqCst,
        );
        self.flag.store(true, Ordering::SeqCst);
    }
}

impl Progress for JobProgress {
    fn report(&self, step: &str, done: u64, total: u64) {
        let percent = if total == 0 {
            0.0
        } else {
            (100.0 * done as f64 / total as f64).min(100.0)
        };
        if let Ok(mut l) = self.latest.lock() {
            *l = Some(
                json!({"step": step, "done": done, "total": total, "percent": (percent * 10.0).round() / 10.0}),
            );
        }
    }

    fn is_canceled(&self) -> bool {
        if self.flag.load(Ordering::Relaxed) {
            return true;
        }
        if Instant::now() >= self.deadline {
            self.stop(StopReason::TimeLimit);
            return true;
        }
        false
    }
}

/// Shutdown signals of the pool: `stop` ends claiming; `abort` (fired after a grace period)
/// stops running jobs, which are then re-queued for the next start.
#[derive(Clone, Default)]
pub struct Shutdown {
    pub stop: CancellationToken,
    pub abort: CancellationToken,
}

/// Start `config.workers` workers and the maintenance task.
pub fn start(state: AppState, shutdown: Shutdown, tracker: &TaskTracker) {
    let owner = Uuid::now_v7();
    tracing::info!(%owner, workers = state.config().workers, "starting worker pool");
    for n in 0..state.config().workers {
        let st = state.clone();
        let sd = shutdown.clone();
        tracker.spawn(async move { worker_loop(st, owner, n, sd).await });
    }
    let st = state.clone();
    tracker.spawn(async move { maintenance_loop(st, shutdown.stop).await });
}

async fn worker_loop(state: AppState, owner: Uuid, n: usize, sd: Shutdown) {
    let shutdown = &sd.stop;
    loop {
        if shutdown.is_cancelled() {
            break;
        }
        let now = now_ms();
        let lease_until = now + state.config().lease_secs as i64 * 1000;
        match state.store().claim_job(owner, now, lease_until).await {
            Ok(Some(job)) => {
                tracing::info!(job = %job.id, kind = %job.kind, attempt = job.attempt, worker = n, "claimed job");
                run_job(&state, owner, job, &sd.abort).await;
                continue;
            }
            Ok(None) => {}
            Err(e) => tracing::warn!(error = %e, "claim failed"),
        }
        tokio::select! {
            _ = shutdown.cancelled() => break,
            _ = state.wake().notified() => {}
            _ = tokio::time::sleep(Duration::from_millis(500)) => {}
        }
    }
}

async fn maintenance_loop(state: AppState, shutdown: CancellationToken) {
    let period = Duration::from_millis((state.config().lease_secs * 1000 / 2).max(200));
    let mut last_prune = Instant::now() - Duration::from_secs(3600);
    let mut last_gc = Instant::now();
    loop {
        tokio::select! {
            _ = shutdown.cancelled() => break,
            _ = tokio::time::sleep(period) => {}
        }
        match state.store().recover_leases(now_ms(), false).await {
            Ok(0) => {}
            Ok(n) => {
                tracing::warn!(jobs = n, "re-queued jobs with expired leases");
                state.wake_workers();
            }
            Err(e) => tracing::warn!(error = %e, "lease recovery failed"),
        }
        if last_prune.elapsed() >= Duration::from_secs(600) {
            last_prune = Instant::now();
            prune(&state).await;
        } else if last_gc.elapsed() >= Duration::from_secs(30) {
            last_gc = Instant::now();
            crate::blob_gc::collect(&state).await;
        }
        if let Ok((q, r)) = state.store().queue_depth().await {
            metrics::gauge!("caliper_jobs_queued").set(q as f64);
            metrics::gauge!("caliper_jobs_running").set(r as f64);
        }
    }
}

/// Delete finished jobs past retention (documents keep the jobs and artifacts they cite),
/// then collect the blobs nobody references any more.
pub async fn prune(state: &AppState) {
    let before = now_ms() - state.config().retention_days as i64 * 86_400_000;
    match state.store().prune_jobs(before).await {
        Ok(0) => {}
        Ok(n) => {
            tracing::info!(jobs = n, "pruned finished jobs past retention");
            state.clear_job_cache();
        }
        Err(e) => tracing::warn!(error = %e, "pruning failed"),
    }
    crate::blob_gc::collect(state).await;
}

/// Capped exponential backoff with up to 25 % jitter.
pub fn backoff_ms(base: u64, cap: u64, attempt: u32) -> u64 {
    let exp = base.saturating_mul(1u64 << attempt.saturating_sub(1).min(30));
    let d = exp.min(cap);
    let jitter = rand::rng().random_range(0.0..0.25);
    (d as f64 * (1.0 + jitter)) as u64
}

fn event(state: &AppState, id: Uuid, status: JobStatus, progress: Option<Value>) {
    state.publish(JobEvent {
        id,
        event: if progress.is_some() && status == JobStatus::Running {
            "progress"
        } else {
            "status"
        },
        status,
        progress,
    });
}

async fn run_job(state: &AppState, owner: Uuid, job: JobRecord, shutdown: &CancellationToken) {
    let token = pin_token(&job);
    let id = job.id;
    run_attempt(state, owner, job, shutdown).await;
    // The artifacts (if any) are referenced now, or were never recorded: GC decides.
    if let Err(e) = state.store().unpin_blobs(token, now_ms()).await {
        tracing::warn!(job = %id, error = %e, "cannot drop artifact pins; they expire");
    }
}

/// The pin token of a job attempt's artifacts.
fn pin_token(job: &JobRecord) -> Uuid {
    // Distinct per attempt, so that a late attempt cannot drop a newer one's pins.
    Uuid::from_u128(job.id.as_u128() ^ (u128::from(job.attempt) << 64))
}

/// How long pins of a writer last if it never drops them (a crash); far longer than any write.
const PIN_TTL_MS: i64 = 24 * 3_600_000;

async fn run_attempt(state: &AppState, owner: Uuid, job: JobRecord, shutdown: &CancellationToken) {
    let started = Instant::now();
    let id = job.id;
    let attempt = job.attempt;
    event(state, id, JobStatus::Running, None);
    let outcome = execute(state, owner, &job, shutdown).await;
    let now = now_ms();
    let (finish, label) = match outcome {
        Outcome::Done(finish) => {
            let label = match &finish {
                Finish::Succeeded { .. } => "succeeded",
                Finish::Failed { .. } => "failed",
                Finish::Retry { .. } => "retry",
                Finish::Canceled => "canceled",
                Finish::Requeue { .. } => "requeued",
            };
            (finish, label)
        }
        Outcome::LeaseLost => {
            tracing::warn!(job = %id, "lease lost; dropping this attempt's result");
            return;
        }
    };
    match state
        .store()
        .finish_job(id, owner, attempt, now, finish)
        .await
    {
        Ok(true) => {}
        Ok(false) => {
            tracing::warn!(job = %id, "lease lost before completion; result discarded");
            return;
        }
        Err(e) => {
            // The lease will expire and the job will be retried by the maintenance task.
            tracing::error!(job = %id, error = %e, "cannot record job completion");
            return;
        }
    }
    metrics::histogram!("caliper_job_duration_seconds", "kind" => job.kind.clone(), "outcome" => label)
        .record(started.elapsed().as_secs_f64());
    if let Ok(Some(j)) = state.store().get_job(id).await {
        event(state, id, j.status, j.progress.clone());
        if j.status == JobStatus::Queued {
            state.wake_workers();
        }
    }
}

enum Outcome {
    Done(Finish),
    LeaseLost,
}

fn permanent(code: &str, message: impl Into<String>) -> Finish {
    Finish::Failed {
        error: json!({"code": code, "message": message.into()}),
    }
}

async fn execute(
    state: &AppState,
    owner: Uuid,
    job: &JobRecord,
    shutdown: &CancellationToken,
) -> Outcome {
    let Some(kind) = resolve_kind(state.config(), &job.kind) else {
        return Outcome::Done(permanent(
            "unknown_job_kind",
            format!("this server does not know job kind {:?}", job.kind),
        ));
    };
    let dataset = match state.store().get_dataset(job.dataset_id).await {
        Ok(Some(d)) => d,
        Ok(None) => {
            return Outcome::Done(permanent(
                "unknown_dataset",
                "the dataset was deleted before the job ran",
            ));
        }
        Err(e) => {
            return Outcome::Done(retry(state, job, format!("store: {e}")));
        }
    };
    // The second dataset the parameters name (the IMU log of a clip). Deletion is refused
    // while the job is queued or running; one can only go missing in the moment between the
    // check at queueing and the insert.
    let aux_files = match kind.aux_dataset(&job.params) {
        Err(e) => return Outcome::Done(permanent("invalid_param", e.to_string())),
        Ok(None) => Vec::new(),
        Ok(Some(aux)) => match state.store().get_dataset(aux.id).await {
            Ok(Some(d)) => d.files,
            Ok(None) => {
                return Outcome::Done(permanent(
                    "unknown_dataset",
                    format!("{}: dataset {} no longer exists", aux.field, aux.id),
                ));
            }
            Err(e) => return Outcome::Done(retry(state, job, format!("store: {e}"))),
        },
    };
    let blobs = state.blobs().clone();
    let handle = tokio::runtime::Handle::current();
    let (blobs2, handle2) = (blobs.clone(), handle.clone());
    let input = JobInput {
        files: dataset.files.clone(),
        aux_files,
        params: job.params.clone(),
        load: Arc::new(move |f| {
            blobs
                .read_blocking(&f.sha256, &handle)
                .map_err(std::io::Error::other)
        }),
        open: Arc::new(move |f| {
            blobs2
                .open_blocking(&f.sha256, &handle2)
                .map_err(std::io::Error::other)
        }),
    };
    let flag = Arc::new(AtomicBool::new(job.cancel_requested));
    let reason = Arc::new(AtomicU8::new(if job.cancel_requested {
        StopReason::Canceled as u8
    } else {
        0
    }));
    let latest = Arc::new(Mutex::new(None));
    let progress = Arc::new(JobProgress {
        flag: flag.clone(),
        reason: reason.clone(),
        deadline: Instant::now() + state.config().time_limit(&job.kind),
        latest: latest.clone(),
    });
    state.register_cancel(job.id, flag.clone());
    let deadline = tokio::time::Instant::from_std(progress.deadline);
    let prog = progress.clone();
    let life = Arc::new(AtomicU8::new(THREAD_RUNNING));
    let (tx, mut rx) = tokio::sync::oneshot::channel();
    let thread_life = life.clone();
    // A plain thread, not `spawn_blocking`: a job body that never returns must be abandonable
    // without holding up the runtime's shutdown (tokio waits for its blocking pool).
    let spawned = std::thread::Builder::new()
        .name(format!("job-{}", job.kind))
        .spawn(move || {
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                kind.run(&input, prog.as_ref())
            }));
            let _ = tx.send(r);
            if thread_life
                .compare_exchange(
                    THREAD_RUNNING,
                    THREAD_DONE,
                    Ordering::SeqCst,
                    Ordering::SeqCst,
                )
                .is_err()
            {
                // The worker gave up on this thread long ago; it has finally returned.
                metrics::gauge!("caliper_job_threads_abandoned").decrement(1.0);
                tracing::warn!("an abandoned job thread returned at last");
            }
        });
    if let Err(e) = spawned {
        state.unregister_cancel(job.id);
        return Outcome::Done(retry(state, job, format!("cannot start a job thread: {e}")));
    }
    let mut tick = tokio::time::interval(Duration::from_millis(state.config().heartbeat_ms));
    tick.tick().await;
    let mut failures = 0u32;
    let mut last_sent: Option<Value> = None;
    // When the job was asked to stop and must be gone by (cooperative stop, then abandonment).
    let mut abandon_at: Option<tokio::time::Instant> = None;
    let far = tokio::time::Instant::now() + Duration::from_secs(86_400 * 365);
    let result = loop {
        if abandon_at.is_none() && flag.load(Ordering::SeqCst) {
            let window =
                if StopReason::from_u8(reason.load(Ordering::SeqCst)) == StopReason::Shutdown {
                    SHUTDOWN_ABANDON
                } else {
                    Duration::from_secs(state.config().job_abandon_secs)
                };
            abandon_at = Some(tokio::time::Instant::now() + window);
        }
        tokio::select! {
            r = &mut rx => break Some(r),
            _ = shutdown.cancelled(), if !flag.load(Ordering::SeqCst) => {
                progress.stop(StopReason::Shutdown);
            }
            // The time limit holds even for a job that never asks whether it should stop.
            _ = tokio::time::sleep_until(deadline), if !flag.load(Ordering::SeqCst) => {
                progress.stop(StopReason::TimeLimit);
            }
            _ = tokio::time::sleep_until(abandon_at.unwrap_or(far)), if abandon_at.is_some() => {
                if life
                    .compare_exchange(THREAD_RUNNING, THREAD_ABANDONED, Ordering::SeqCst, Ordering::SeqCst)
                    .is_ok()
                {
                    metrics::counter!("caliper_jobs_abandoned_total", "kind" => job.kind.clone()).increment(1);
                    metrics::gauge!("caliper_job_threads_abandoned").increment(1.0);
                    tracing::error!(job = %job.id, kind = %job.kind, "the job ignored its stop request; abandoning its thread and freeing the worker");
                    break None;
                }
                // It finished in this very instant: take its result.
            }
            _ = tick.tick() => {
                // Progress is only written when it changed; the lease is renewed every tick.
                let snapshot = latest.lock().ok().and_then(|l| l.clone());
                let changed = snapshot.is_some() && snapshot != last_sent;
                let lease_until = now_ms() + state.config().lease_secs as i64 * 1000;
                match state.store().heartbeat(job.id, owner, job.attempt, lease_until, if changed { snapshot.as_ref() } else { None }).await {
                    Ok(Heartbeat::Renewed { cancel }) => {
                        failures = 0;
                        if cancel {
                            progress.stop(StopReason::Canceled);
                        }
                        if changed {
                            event(state, job.id, JobStatus::Running, snapshot.clone());
                            last_sent = snapshot;
                        }
                    }
                    Ok(Heartbeat::Lost) => progress.stop(StopReason::LeaseLost),
                    Err(e) => {
                        failures += 1;
                        tracing::warn!(job = %job.id, error = %e, failures, "heartbeat failed");
                        // Without heartbeats our lease will expire and another worker may take
                        // the job: stop before that can produce two results.
                        if failures >= 3 {
                            progress.stop(StopReason::LeaseLost);
                        }
                    }
                }
            }
        }
    };
    state.unregister_cancel(job.id);
    let why = StopReason::from_u8(reason.load(Ordering::SeqCst));
    if why == StopReason::LeaseLost {
        return Outcome::LeaseLost;
    }
    let stopped = |abandoned: bool| {
        let note = if abandoned {
            " (it did not stop when asked; its thread was abandoned)"
        } else {
            ""
        };
        Outcome::Done(match why {
            StopReason::TimeLimit => permanent(
                "time_limit_exceeded",
                format!(
                    "the job ran longer than its limit of {} s{note}",
                    state.config().time_limit(&job.kind).as_secs()
                ),
            ),
            // Re-queue at once without counting the attempt; the next start picks it up.
            StopReason::Shutdown => Finish::Requeue {
                error: json!({"code": "shutdown", "message": format!("the service shut down while the job ran; re-queued{note}")}),
            },
            _ => Finish::Canceled,
        })
    };
    let output = match result {
        None => return stopped(true),
        Some(Err(_)) | Some(Ok(Err(_))) => {
            tracing::error!(job = %job.id, "job panicked");
            return Outcome::Done(permanent(
                "internal_error",
                "the job crashed; this is a bug and has been logged",
            ));
        }
        Some(Ok(Ok(Err(JobError::Canceled)))) => return stopped(false),
        Some(Ok(Ok(Err(JobError::Permanent { code, message })))) => {
            return Outcome::Done(permanent(code, message));
        }
        Some(Ok(Ok(Err(JobError::Transient(m))))) => return Outcome::Done(retry(state, job, m)),
        Some(Ok(Ok(Ok(out)))) => out,
    };
    // Pin the artifact keys before storing them, so that a concurrent GC pass cannot delete
    // a blob we skip writing because it already exists (unpinned in `run_job`).
    let shas: Vec<String> = output
        .artifacts
        .iter()
        .map(|a| crate::document::sha256_hex(&a.data))
        .collect();
    if !shas.is_empty()
        && let Err(e) = state
            .store()
            .pin_blobs(pin_token(job), &shas, now_ms() + PIN_TTL_MS)
            .await
    {
        return Outcome::Done(retry(state, job, format!("pinning artifacts: {e}")));
    }
    let mut artifacts = Vec::new();
    for a in &output.artifacts {
        match state.blobs().put_bytes(a.data.clone()).await {
            Ok(sha) => artifacts.push(ArtifactRecord {
                name: a.name.clone(),
                media_type: a.media_type.clone(),
                sha256: sha,
                size: a.data.len() as u64,
            }),
            Err(e) => return Outcome::Done(retry(state, job, format!("storing artifact: {e}"))),
        }
    }
    let doc = document::build(
        kind,
        &output,
        &document::Provenance {
            job: Some(job.id),
            dataset: Some(dataset.id),
            dataset_sha256: Some(&dataset.sha256),
            files: &dataset.files,
            params: &job.params,
            device: job.device.as_deref(),
            sensor: job.sensor.as_deref(),
        },
        now_ms(),
    );
    let target = job.device.as_ref().map(|device| NewDocument {
        device: device.clone(),
        sensor: job.sensor.clone().unwrap_or_else(|| "default".into()),
        kind: kind.name().to_string(),
        schema: kind.schema().to_string(),
    });
    Outcome::Done(Finish::Succeeded {
        seal: crate::document::sealer(doc),
        document: target,
        artifacts,
    })
}

fn retry(state: &AppState, job: &JobRecord, message: String) -> Finish {
    let cfg = state.config();
    let delay = backoff_ms(cfg.backoff_base_ms, cfg.backoff_cap_ms, job.attempt);
    tracing::warn!(job = %job.id, attempt = job.attempt, delay_ms = delay, %message, "transient failure; will retry");
    Finish::Retry {
        error: json!({"code": "transient", "message": message}),
        run_at: now_ms() + delay as i64,
    }
}

#[cfg(test)]
mod tests {
    use super::backoff_ms;

    #[test]
    fn backoff_doubles_and_is_capped() {
        for attempt in 1..=12 {
            let d = backoff_ms(100, 5_000, attempt);
            let nominal = (100u64 << (attempt - 1)).min(5_000);
            assert!(
                d >= nominal && d <= nominal * 5 / 4,
                "attempt {attempt}: {d}"
            );
        }
    }
}
