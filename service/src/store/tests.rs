//! Queue semantics of the SQLite store: exclusive claims, fencing, lease recovery, retries,
//! idempotency, cancellation, document revisions and pruning.

use serde_json::json;
use uuid::Uuid;

use super::*;

async fn store() -> (SqliteStore, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    let s = SqliteStore::open(&dir.path().join("t.db")).await.unwrap();
    (s, dir)
}

async fn dataset(s: &SqliteStore) -> Uuid {
    let id = Uuid::now_v7();
    s.insert_dataset(&DatasetRecord {
        id,
        kind: DatasetKind::Images,
        created_at: 0,
        total_bytes: 1,
        sha256: "x".into(),
        files: vec![DatasetFile {
            name: "a.png".into(),
            sha256: "abc".into(),
            size: 1,
            media_type: "image/png".into(),
            image: None,
            video: None,
        }],
        devices: None,
    })
    .await
    .unwrap();
    id
}

fn new_job(ds: Uuid, key: Option<&str>, hash: &str, now: i64) -> NewJob {
    NewJob {
        id: Uuid::now_v7(),
        kind: "blur_score".into(),
        dataset_id: ds,
        aux_dataset_id: None,
        device: Some("dev".into()),
        sensor: Some("cam0".into()),
        params: json!({}),
        max_attempts: 2,
        idempotency_key: key.map(String::from),
        request_hash: Some(hash.into()),
        now,
    }
}

async fn created(s: &SqliteStore, j: NewJob) -> JobRecord {
    match s.create_job(j, 100).await.unwrap() {
        CreateJob::Created(r) => r,
        other => panic!("expected Created, got {other:?}"),
    }
}

#[tokio::test]
async fn a_job_is_claimed_by_exactly_one_worker() {
    let (s, _d) = store().await;
    let ds = dataset(&s).await;
    let job = created(&s, new_job(ds, None, "h", 1000)).await;
    let (a, b) = (Uuid::now_v7(), Uuid::now_v7());
    let (ra, rb) = tokio::join!(s.claim_job(a, 2000, 9000), s.claim_job(b, 2000, 9000));
    let claims: Vec<_> = [ra.unwrap(), rb.unwrap()].into_iter().flatten().collect();
    assert_eq!(claims.len(), 1);
    assert_eq!(claims[0].id, job.id);
    assert_eq!(claims[0].attempt, 1);
    assert_eq!(claims[0].status, JobStatus::Running);
}

#[tokio::test]
async fn writes_from_an_expired_lease_are_fenced_off() {
    let (s, _d) = store().await;
    let ds = dataset(&s).await;
    let job = created(&s, new_job(ds, None, "h", 1000)).await;
    let old = Uuid::now_v7();
    s.claim_job(old, 2000, 3000).await.unwrap().unwrap();
    // The lease expires; recovery re-queues; another worker claims attempt 2.
    assert_eq!(s.recover_leases(5000, false).await.unwrap(), 1);
    let new = Uuid::now_v7();
    let j2 = s.claim_job(new, 5000, 9000).await.unwrap().unwrap();
    assert_eq!(j2.attempt, 2);
    // The old worker wakes up: heartbeat and completion are refused.
    assert_eq!(
        s.heartbeat(job.id, old, 1, 9999, None).await.unwrap(),
        Heartbeat::Lost
    );
    let late = || Finish::Succeeded {
        seal: crate::document::sealer(json!({"schema": "x"})),
        document: Some(NewDocument {
            device: "dev".into(),
            sensor: "cam0".into(),
            kind: "blur_score".into(),
            schema: "x".into(),
        }),
        artifacts: vec![],
    };
    assert!(!s.finish_job(job.id, old, 1, 6000, late()).await.unwrap());
    assert!(
        s.get_document("dev", "cam0", "blur_score", None)
            .await
            .unwrap()
            .is_none()
    );
    // The current holder completes it, once.
    assert_eq!(
        s.heartbeat(job.id, new, 2, 9999, Some(&json!({"percent": 50.0})))
            .await
            .unwrap(),
        Heartbeat::Renewed { cancel: false }
    );
    assert!(s.finish_job(job.id, new, 2, 7000, late()).await.unwrap());
    assert!(
        !s.finish_job(job.id, new, 2, 7001, late()).await.unwrap(),
        "a second completion is refused"
    );
    let revs = s.list_revisions("dev", "cam0", "blur_score").await.unwrap();
    assert_eq!(revs.len(), 1);
    let done = s.get_job(job.id).await.unwrap().unwrap();
    assert_eq!(done.status, JobStatus::Succeeded);
    assert_eq!(done.document_rev, Some(1));
}

#[tokio::test]
async fn retries_wait_for_their_time_and_attempts_run_out() {
    let (s, _d) = store().await;
    let ds = dataset(&s).await;
    let job = created(&s, new_job(ds, None, "h", 1000)).await;
    let w = Uuid::now_v7();
    s.claim_job(w, 1000, 9000).await.unwrap().unwrap();
    let retry = || Finish::Retry {
        error: json!({"code": "transient", "message": "io"}),
        run_at: 5000,
    };
    assert!(s.finish_job(job.id, w, 1, 1100, retry()).await.unwrap());
    assert!(
        s.claim_job(w, 4999, 9000).await.unwrap().is_none(),
        "not before run_at"
    );
    let j = s.claim_job(w, 5000, 9000).await.unwrap().unwrap();
    assert_eq!(j.attempt, 2);
    // max_attempts = 2: the next transient failure is final.
    assert!(s.finish_job(job.id, w, 2, 5100, retry()).await.unwrap());
    let j = s.get_job(job.id).await.unwrap().unwrap();
    assert_eq!(j.status, JobStatus::Failed);
    assert_eq!(j.error.unwrap()["attempts_exhausted"], 2);
}

#[tokio::test]
async fn lost_leases_fail_once_attempts_are_used_up() {
    let (s, _d) = store().await;
    let ds = dataset(&s).await;
    let job = created(&s, new_job(ds, None, "h", 1000)).await;
    for attempt in 1..=2 {
        let t = 3000 * attempt as i64;
        let j = s
            .claim_job(Uuid::now_v7(), t, t + 1000)
            .await
            .unwrap()
            .unwrap();
        assert_eq!(j.attempt, attempt);
        assert_eq!(s.recover_leases(t + 2000, false).await.unwrap(), 1);
    }
    let j = s.get_job(job.id).await.unwrap().unwrap();
    assert_eq!(j.status, JobStatus::Failed);
    assert_eq!(j.error.unwrap()["code"], "lease_lost");
    // A live lease is left alone.
    let other = created(&s, new_job(ds, None, "h2", 1000)).await;
    s.claim_job(Uuid::now_v7(), 9000, 20_000)
        .await
        .unwrap()
        .unwrap();
    assert_eq!(s.recover_leases(10_000, false).await.unwrap(), 0);
    assert_eq!(
        s.recover_leases(10_000, true).await.unwrap(),
        1,
        "start-up recovery takes all"
    );
    assert_eq!(
        s.get_job(other.id).await.unwrap().unwrap().status,
        JobStatus::Queued
    );
}

#[tokio::test]
async fn idempotency_keys_and_the_queue_bound() {
    let (s, _d) = store().await;
    let ds = dataset(&s).await;
    let first = created(&s, new_job(ds, Some("k"), "h1", 1000)).await;
    match s
        .create_job(new_job(ds, Some("k"), "h1", 1001), 100)
        .await
        .unwrap()
    {
        CreateJob::Existing(j) => assert_eq!(j.id, first.id),
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        s.create_job(new_job(ds, Some("k"), "h2", 1002), 100)
            .await
            .unwrap(),
        CreateJob::Conflict(_)
    ));
    assert!(matches!(
        s.create_job(new_job(ds, None, "h3", 1003), 1)
            .await
            .unwrap(),
        CreateJob::QueueFull
    ));
    assert!(matches!(
        s.create_job(new_job(Uuid::now_v7(), None, "h4", 1003), 100)
            .await
            .unwrap(),
        CreateJob::UnknownDataset
    ));
}

#[tokio::test]
async fn cancel_queued_running_and_finished() {
    let (s, _d) = store().await;
    let ds = dataset(&s).await;
    let a = created(&s, new_job(ds, None, "a", 1000)).await;
    let w = Uuid::now_v7();
    s.claim_job(w, 1000, 9000).await.unwrap().unwrap();
    let b = created(&s, new_job(ds, None, "b", 1001)).await;
    assert!(matches!(
        s.cancel_job(b.id, 1100).await.unwrap(),
        CancelJob::Canceled(_)
    ));
    assert!(matches!(
        s.cancel_job(a.id, 1100).await.unwrap(),
        CancelJob::Requested(_)
    ));
    assert_eq!(
        s.heartbeat(a.id, w, 1, 9000, None).await.unwrap(),
        Heartbeat::Renewed { cancel: true }
    );
    assert!(
        s.finish_job(a.id, w, 1, 1200, Finish::Canceled)
            .await
            .unwrap()
    );
    assert!(matches!(
        s.cancel_job(a.id, 1300).await.unwrap(),
        CancelJob::Finished(_)
    ));
    assert!(matches!(
        s.cancel_job(Uuid::now_v7(), 1300).await.unwrap(),
        CancelJob::NotFound
    ));
    // A canceled job is never claimed.
    assert!(s.claim_job(w, 2000, 9000).await.unwrap().is_none());
}

/// Run a GC pass over every due candidate; returns the keys it deleted.
async fn reap_all(s: &SqliteStore, now: i64) -> Vec<String> {
    let deleted = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let d2 = deleted.clone();
    let delete = move |sha: String| {
        d2.lock().unwrap().push(sha);
        let fut: futures_util::future::BoxFuture<'static, std::io::Result<()>> =
            Box::pin(async { Ok(()) });
        fut
    };
    for sha in s.gc_candidates(now, now, 1000).await.unwrap() {
        s.reap_blob(&sha, now, &delete).await.unwrap();
    }
    let mut out = deleted.lock().unwrap().clone();
    out.sort();
    out
}

#[tokio::test]
async fn pruning_removes_old_finished_jobs_and_collects_orphan_artifacts() {
    let (s, _d) = store().await;
    let ds = dataset(&s).await;
    let j = created(&s, new_job(ds, None, "a", 1000)).await;
    let w = Uuid::now_v7();
    s.claim_job(w, 1000, 9000).await.unwrap().unwrap();
    let fin = Finish::Succeeded {
        seal: crate::document::sealer(json!({})),
        document: None,
        artifacts: vec![ArtifactRecord {
            name: "p.svg".into(),
            media_type: "image/svg+xml".into(),
            sha256: "feed".into(),
            size: 4,
        }],
    };
    assert!(s.finish_job(j.id, w, 1, 2000, fin).await.unwrap());
    assert_eq!(s.prune_jobs(1500).await.unwrap(), 0, "too recent");
    assert!(s.get_job(j.id).await.unwrap().is_some());
    assert_eq!(s.prune_jobs(2500).await.unwrap(), 1);
    assert!(s.get_job(j.id).await.unwrap().is_none());
    assert_eq!(reap_all(&s, i64::MAX / 2).await, vec!["feed".to_string()]);
    assert!(
        reap_all(&s, i64::MAX / 2).await.is_empty(),
        "candidate dropped"
    );
}

#[tokio::test]
async fn pruning_keeps_jobs_that_documents_cite() {
    let (s, _d) = store().await;
    let ds = dataset(&s).await;
    let j = created(&s, new_job(ds, Some("dev-1"), "a", 1000)).await;
    let w = Uuid::now_v7();
    s.claim_job(w, 1000, 9000).await.unwrap().unwrap();
    let fin = Finish::Succeeded {
        seal: crate::document::sealer(json!({})),
        document: Some(NewDocument {
            device: "dev-1".into(),
            sensor: "default".into(),
            kind: "blur_score".into(),
            schema: "caliper.blur_score/v1".into(),
        }),
        artifacts: vec![ArtifactRecord {
            name: "p.svg".into(),
            media_type: "image/svg+xml".into(),
            sha256: "feed".into(),
            size: 4,
        }],
    };
    assert!(s.finish_job(j.id, w, 1, 2000, fin).await.unwrap());
    assert_eq!(s.prune_jobs(i64::MAX / 2).await.unwrap(), 0);
    assert!(s.get_artifact(j.id, "p.svg").await.unwrap().is_some());
    assert!(reap_all(&s, i64::MAX / 2).await.is_empty());
}

#[tokio::test]
async fn a_dataset_a_job_reads_besides_its_own_cannot_be_deleted_until_it_ends() {
    let (s, _d) = store().await;
    let (clip, log) = (dataset(&s).await, dataset(&s).await);
    let mut j = new_job(clip, None, "h", 1);
    j.aux_dataset_id = Some(log);
    let job = created(&s, j).await;
    match s.delete_dataset(log).await.unwrap() {
        DeleteDataset::InUse(ids) => assert_eq!(ids, vec![job.id]),
        other => panic!("the IMU log of a queued job was not protected: {other:?}"),
    }
    assert!(s.cancel_job(job.id, 2).await.is_ok());
    assert!(matches!(
        s.delete_dataset(log).await.unwrap(),
        DeleteDataset::Deleted
    ));
}

#[tokio::test]
async fn gc_deletes_only_unreferenced_unpinned_blobs() {
    let (s, _d) = store().await;
    // Deletion nominates with the wall clock; run the passes a little later than that.
    let t = crate::clock::now_ms() + 60_000;
    let a = dataset(&s).await;
    let b = dataset(&s).await;
    assert!(matches!(
        s.delete_dataset(a).await.unwrap(),
        DeleteDataset::Deleted
    ));
    assert!(reap_all(&s, t).await.is_empty(), "b still uses it");
    // A writer pins the key (a re-upload of the same bytes) before b goes.
    let token = Uuid::now_v7();
    s.pin_blobs(token, &["abc".to_string()], t + 50_000)
        .await
        .unwrap();
    assert!(matches!(
        s.delete_dataset(b).await.unwrap(),
        DeleteDataset::Deleted
    ));
    assert!(reap_all(&s, t).await.is_empty(), "pinned");
    // An expired pin protects nothing; the key is nominated again when the pin expires.
    assert_eq!(reap_all(&s, t + 60_000).await, vec!["abc".to_string()]);
    s.unpin_blobs(token, t + 70_000).await.unwrap();
    // Candidates not yet due are left alone.
    let later = Uuid::now_v7();
    s.pin_blobs(later, &["def".to_string()], t + 99_000)
        .await
        .unwrap();
    s.unpin_blobs(later, t + 80_000).await.unwrap();
    assert!(
        s.gc_candidates(t + 80_000, t + 79_999, 10)
            .await
            .unwrap()
            .is_empty()
    );
    assert_eq!(reap_all(&s, t + 80_000).await, vec!["def".to_string()]);
    assert!(matches!(
        s.delete_dataset(b).await.unwrap(),
        DeleteDataset::NotFound
    ));
}

#[tokio::test]
async fn tokens_are_found_by_hash_listed_and_revoked() {
    let (s, _d) = store().await;
    let new =
        crate::auth::generate("ci", Scope::Write, Some(vec!["cam-1".into()]), 5).expect("token");
    s.insert_token(&new.record, &new.hash).await.unwrap();
    let found = s.token_by_hash(&new.hash).await.unwrap().expect("found");
    assert_eq!(found, new.record);
    assert!(s.token_by_hash("nope").await.unwrap().is_none());
    assert_eq!(s.list_tokens().await.unwrap().len(), 1);
    assert!(s.revoke_token(new.record.id, 9).await.unwrap());
    assert_eq!(
        s.token_by_hash(&new.hash)
            .await
            .unwrap()
            .expect("still there")
            .revoked_at,
        Some(9)
    );
    // Revoking twice keeps the first time.
    assert!(s.revoke_token(new.record.id, 12).await.unwrap());
    assert_eq!(s.list_tokens().await.unwrap()[0].revoked_at, Some(9));
    assert!(!s.revoke_token(Uuid::now_v7(), 12).await.unwrap());
}

#[tokio::test]
async fn datasets_of_device_tokens_are_listed_only_for_their_devices() {
    let (s, _d) = store().await;
    let fleet = dataset(&s).await;
    let mine = Uuid::now_v7();
    s.insert_dataset(&DatasetRecord {
        id: mine,
        kind: DatasetKind::Images,
        created_at: 0,
        total_bytes: 1,
        sha256: "y".into(),
        files: vec![],
        devices: Some(vec!["cam-1".into(), "cam-2".into()]),
    })
    .await
    .unwrap();
    let ids = |v: Vec<DatasetRecord>| v.into_iter().map(|d| d.id).collect::<Vec<_>>();
    assert_eq!(
        ids(s.list_datasets(None, 10, None).await.unwrap()),
        [mine, fleet]
    );
    let only = ["cam-2".to_string()];
    assert_eq!(
        ids(s.list_datasets(None, 10, Some(&only)).await.unwrap()),
        [mine]
    );
    let other = ["cam-9".to_string()];
    assert!(
        s.list_datasets(None, 10, Some(&other))
            .await
            .unwrap()
            .is_empty()
    );
    assert_eq!(
        s.get_dataset(mine).await.unwrap().expect("there").devices,
        Some(vec!["cam-1".to_string(), "cam-2".to_string()])
    );
}
