//! Blob garbage collection (issue D2: a delete racing a re-upload of the same bytes lost the
//! blob).
//!
//! Blobs are content-addressed and shared, so nothing deletes one directly. Deleting a dataset
//! or pruning a job only *nominates* its blobs; writers pin the keys they are about to store
//! before storing them. A collection pass takes the nominations older than the grace period
//! and lets the store decide, under its write lock, whether each is still unreferenced and
//! unpinned, deleting it while that lock is held. The grace period leaves downloads that
//! already started time to finish.

use std::sync::Arc;

use crate::clock::now_ms;
use crate::state::AppState;

/// Candidates examined per store round trip.
const BATCH: u32 = 256;

/// Run one collection pass; returns how many blobs were deleted.
pub async fn collect(state: &AppState) -> u64 {
    let grace_ms = state.config().blob_gc_grace_secs.saturating_mul(1000) as i64;
    let blobs = Arc::new(state.blobs().clone());
    let delete = move |sha: String| {
        let blobs = blobs.clone();
        let fut: futures_util::future::BoxFuture<'static, std::io::Result<()>> =
            Box::pin(async move { blobs.delete(&sha).await.map_err(std::io::Error::other) });
        fut
    };
    let mut deleted = 0u64;
    loop {
        let now = now_ms();
        let due = match state
            .store()
            .gc_candidates(now, now - grace_ms, BATCH)
            .await
        {
            Ok(d) => d,
            Err(e) => {
                tracing::warn!(error = %e, "blob GC: cannot list candidates");
                return deleted;
            }
        };
        let n = due.len();
        let mut failed = false;
        for sha in due {
            match state.store().reap_blob(&sha, now_ms(), &delete).await {
                Ok(true) => deleted += 1,
                Ok(false) => {}
                Err(e) => {
                    // The candidate stays queued; the next pass tries again.
                    tracing::warn!(error = %e, %sha, "blob GC: cannot delete blob");
                    failed = true;
                }
            }
        }
        if n < BATCH as usize || failed {
            break;
        }
    }
    if deleted > 0 {
        metrics::counter!("caliper_blobs_collected_total").increment(deleted);
        tracing::info!(deleted, "blob GC: deleted unreferenced blobs");
    }
    deleted
}
