//! The production profile: replicas (child processes) sharing one PostgreSQL database and one
//! blob directory. `CALIPER_TEST_POSTGRES_URL` (a server where the tests may create and drop
//! databases, e.g. `postgres://postgres@127.0.0.1:5432/test`) selects the server; `.ci/run`
//! sets it. Without it the tests say loudly that they did not run.

use std::time::{Duration, Instant};

use serde_json::{Value, json};
use sqlx::Connection;

use crate::common::*;

/// A fresh database on the test server, dropped at the end.
pub(crate) struct TestDb {
    admin_url: String,
    name: String,
    pub(crate) url: String,
}

impl TestDb {
    pub(crate) async fn create() -> Option<Self> {
        let Some(admin_url) = std::env::var("CALIPER_TEST_POSTGRES_URL")
            .ok()
            .filter(|u| !u.is_empty())
        else {
            eprintln!(
                "\n*** PostgreSQL tests NOT RUN: set CALIPER_TEST_POSTGRES_URL \
                 (e.g. postgres://postgres@127.0.0.1:5432/test; .ci/run does) ***\n"
            );
            return None;
        };
        let name = format!("caliper_t_{}", uuid_simple());
        let mut c = sqlx::PgConnection::connect(&admin_url)
            .await
            .expect("connect to the PostgreSQL test server");
        sqlx::query(sqlx::AssertSqlSafe(format!("CREATE DATABASE {name}")))
            .execute(&mut c)
            .await
            .expect("create database");
        let base = admin_url
            .rsplit_once('/')
            .map_or(admin_url.as_str(), |(b, _)| b);
        let url = format!("{base}/{name}");
        Some(Self {
            admin_url,
            name,
            url,
        })
    }

    pub(crate) async fn drop_db(self) {
        if let Ok(mut c) = sqlx::PgConnection::connect(&self.admin_url).await {
            let _ = sqlx::query(sqlx::AssertSqlSafe(format!(
                "DROP DATABASE IF EXISTS {} WITH (FORCE)",
                self.name
            )))
            .execute(&mut c)
            .await;
        }
    }
}

fn uuid_simple() -> String {
    // The clock alone is not enough: tests run in parallel threads, and two of them once read
    // the same time (CI: "database caliper_t_… already exists"). A counter keeps the names of
    // one process apart, the process id those of concurrent test binaries.
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    format!("{:x}{:x}_{n}", nanos, std::process::id())
}

/// The first admin token, made with the CLI against the shared store.
pub(crate) fn admin_token(url: &str) -> String {
    let out = std::process::Command::new(caliper_bin())
        .args([
            "token",
            "create",
            "--scope",
            "admin",
            "--name",
            "tests",
            "--database-url",
            url,
        ])
        .output()
        .expect("caliper token create");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).trim().to_owned()
}

fn replica(db: &TestDb, blobs: &std::path::Path, extra: &[&str]) -> (Proc, tempfile::TempDir) {
    replica_s3(db, blobs, None, extra)
}

/// A replica whose blobs go to S3 (`s3`: URL and endpoint) or to the shared directory.
pub(crate) fn replica_s3(
    db: &TestDb,
    blobs: &std::path::Path,
    s3: Option<(&str, &str)>,
    extra: &[&str],
) -> (Proc, tempfile::TempDir) {
    let data = tempfile::tempdir().expect("data dir");
    let blob_dir = blobs.to_string_lossy().into_owned();
    let (flag, target) = match s3 {
        Some((url, _)) => ("--blob-url", url.to_owned()),
        None => ("--blob-dir", blob_dir),
    };
    let env = s3
        .map(|(_, endpoint)| crate::s3::aws_env(endpoint))
        .unwrap_or_default();
    let env_refs: Vec<(&str, &str)> = env.iter().map(|(k, v)| (*k, v.as_str())).collect();
    let mut args = vec![
        "--database-url",
        db.url.as_str(),
        flag,
        target.as_str(),
        "--lease-secs",
        "3",
        "--rate-limit-per-sec",
        "0",
    ];
    args.extend_from_slice(extra);
    (
        spawn_caliper_env(&caliper_bin(), data.path(), &args, &env_refs),
        data,
    )
}

struct Api {
    client: reqwest::Client,
    token: String,
}

impl Api {
    async fn get(&self, base: &str, path: &str) -> (u16, Value) {
        let r = self
            .client
            .get(format!("{base}{path}"))
            .bearer_auth(&self.token)
            .send()
            .await
            .expect("get");
        let st = r.status().as_u16();
        (st, r.json().await.unwrap_or(Value::Null))
    }

    async fn post(&self, base: &str, path: &str, body: &Value) -> (u16, Value) {
        let r = self
            .client
            .post(format!("{base}{path}"))
            .bearer_auth(&self.token)
            .json(body)
            .send()
            .await
            .expect("post");
        let st = r.status().as_u16();
        (st, r.json().await.unwrap_or(Value::Null))
    }

    async fn upload(&self, base: &str, files: Vec<(String, Vec<u8>)>) -> String {
        let mut form = reqwest::multipart::Form::new();
        for (name, bytes) in files {
            form = form.part(
                "file",
                reqwest::multipart::Part::bytes(bytes).file_name(name),
            );
        }
        let r = self
            .client
            .post(format!("{base}/v1/datasets"))
            .bearer_auth(&self.token)
            .multipart(form)
            .send()
            .await
            .expect("upload");
        assert_eq!(r.status(), 201);
        let v: Value = r.json().await.expect("json");
        v["id"].as_str().expect("id").to_owned()
    }

    async fn wait_terminal(&self, base: &str, id: &str, timeout: Duration) -> Value {
        let start = Instant::now();
        loop {
            let (st, j) = self.get(base, &format!("/v1/jobs/{id}")).await;
            assert_eq!(st, 200, "{j}");
            if matches!(
                j["status"].as_str(),
                Some("succeeded" | "failed" | "canceled")
            ) {
                return j;
            }
            assert!(start.elapsed() < timeout, "job {id} still {j}");
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_replicas_share_one_store_and_run_each_job_once() {
    let Some(db) = TestDb::create().await else {
        return;
    };
    let blobs = tempfile::tempdir().expect("blobs");
    let token = admin_token(&db.url);
    // Blobs in S3 when the tests have an S3-compatible server, else in a shared directory.
    let s3 = crate::s3::bucket().await;
    let s3_url = s3.as_ref().map(|(_, b)| format!("s3://{b}/replicas"));
    let target = s3
        .as_ref()
        .zip(s3_url.as_deref())
        .map(|((endpoint, _), url)| (url, endpoint.as_str()));
    let reps: Vec<_> = (0..3)
        .map(|_| replica_s3(&db, blobs.path(), target, &["--max-queued-jobs", "5000"]))
        .collect();
    let bases: Vec<String> = reps.iter().map(|(p, _)| p.base.clone()).collect();
    let api = Api {
        client: reqwest::Client::new(),
        token,
    };

    // Upload on one replica, queue on another, read on the third.
    let ds = api
        .upload(&bases[0], vec![("a.png".into(), png(&sharp_image(96, 72)))])
        .await;
    // 1,000 jobs from 20 concurrent clients, each client on its own replica in turn.
    let n = 1000;
    let clients = 20;
    let mut tasks = Vec::new();
    for k in 0..clients {
        let (bases, ds) = (bases.clone(), ds.clone());
        let (client, token) = (api.client.clone(), api.token.clone());
        tasks.push(tokio::spawn(async move {
            let mut ids = Vec::new();
            for i in 0..n / clients {
                let base = &bases[(k + i) % 3];
                let r = client
                    .post(format!("{base}/v1/jobs"))
                    .bearer_auth(&token)
                    .json(&json!({"kind": "blur_score", "dataset": ds, "device": "cam-pg", "sensor": "cam0"}))
                    .send()
                    .await
                    .expect("post");
                assert_eq!(r.status(), 202);
                let j: Value = r.json().await.expect("json");
                ids.push(j["id"].as_str().expect("id").to_owned());
            }
            ids
        }));
    }
    let mut ids = Vec::new();
    for t in tasks {
        ids.extend(t.await.expect("client"));
    }
    // A client on one replica follows a job over SSE to its end, whichever replica runs it.
    let followed = ids[n - 1].clone();
    let sse = api
        .client
        .get(format!("{}/v1/jobs/{followed}/events", bases[0]))
        .bearer_auth(&api.token)
        .send()
        .await
        .expect("events");
    let stream_text = tokio::time::timeout(Duration::from_secs(300), sse.text())
        .await
        .expect("the event stream ends with the job")
        .expect("stream");
    assert!(
        stream_text.contains("\"succeeded\""),
        "no terminal event: {stream_text}"
    );
    let mut revs = Vec::new();
    for (i, id) in ids.iter().enumerate() {
        let j = api
            .wait_terminal(&bases[(i + 2) % 3], id, Duration::from_secs(300))
            .await;
        assert_eq!(j["status"], "succeeded", "{j}");
        assert_eq!(j["attempt"], 1, "ran once: {j}");
        revs.push(j["document"]["rev"].as_u64().expect("rev"));
    }
    // Every job filed exactly one revision: 1..=n, no gap, no duplicate.
    revs.sort_unstable();
    assert_eq!(revs, (1..=n as u64).collect::<Vec<_>>());
    let (_, list) = api
        .get(&bases[1], "/v1/devices/cam-pg/documents/cam0/blur_score")
        .await;
    assert_eq!(list.as_array().expect("revisions").len(), n);
    // Which replicas ran them: the attempts table is the record (more than one did).
    let mut c = sqlx::PgConnection::connect(&db.url).await.expect("connect");
    let workers: i64 = sqlx::query_scalar("SELECT COUNT(DISTINCT worker) FROM job_attempts")
        .fetch_one(&mut c)
        .await
        .expect("count");
    let attempts: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM job_attempts")
        .fetch_one(&mut c)
        .await
        .expect("count");
    assert_eq!(attempts, n as i64, "one attempt per job");
    eprintln!(
        "{n} jobs ran on {workers} workers across 3 replicas (blobs in {})",
        if s3.is_some() {
            "S3"
        } else {
            "a shared directory"
        }
    );
    // Every artifact of every job can be read from any replica (shared blobs).
    for (i, id) in ids.iter().enumerate().take(5) {
        let (_, arts) = api
            .get(&bases[i % 3], &format!("/v1/jobs/{id}/artifacts"))
            .await;
        let name = arts["items"][0]["name"]
            .as_str()
            .expect("artifact")
            .to_owned();
        let r = api
            .client
            .get(format!(
                "{}/v1/jobs/{id}/artifacts/{name}",
                bases[(i + 1) % 3]
            ))
            .bearer_auth(&api.token)
            .send()
            .await
            .expect("artifact");
        assert_eq!(r.status(), 200);
    }
    drop(reps);
    db.drop_db().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_killed_replica_job_is_finished_by_another_after_its_lease() {
    let Some(db) = TestDb::create().await else {
        return;
    };
    let blobs = tempfile::tempdir().expect("blobs");
    let token = admin_token(&db.url);
    // The first replica takes the job (the only one running at first) and dies mid-job.
    let (mut first, _d1) = replica(&db, blobs.path(), &[]);
    let api = Api {
        client: reqwest::Client::new(),
        token,
    };
    let files: Vec<(String, Vec<u8>)> = slow_dataset(60);
    let ds = api.upload(&first.base, files).await;
    let (st, j) = api
        .post(
            &first.base,
            "/v1/jobs",
            &json!({"kind": "blur_score", "dataset": ds, "device": "cam-kill", "sensor": "cam0"}),
        )
        .await;
    assert_eq!(st, 202, "{j}");
    let id = j["id"].as_str().expect("id").to_owned();
    let start = Instant::now();
    loop {
        let (_, j) = api.get(&first.base, &format!("/v1/jobs/{id}")).await;
        if j["status"] == "running" {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(30), "{j}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let _ = first.child.kill();
    let _ = first.child.wait();
    let (second, _d2) = replica(&db, blobs.path(), &[]);
    let done = api
        .wait_terminal(&second.base, &id, Duration::from_secs(120))
        .await;
    assert_eq!(done["status"], "succeeded", "{done}");
    assert_eq!(done["document"]["rev"], 1, "{done}");
    // The first attempt was lost with its replica; the second, on the other replica, won.
    let mut c = sqlx::PgConnection::connect(&db.url).await.expect("connect");
    let outcomes: Vec<Option<String>> =
        sqlx::query_scalar("SELECT outcome FROM job_attempts WHERE job_id = $1 ORDER BY attempt")
            .bind(&id)
            .fetch_all(&mut c)
            .await
            .expect("attempts");
    assert_eq!(
        outcomes.first().cloned().flatten().as_deref(),
        Some("lease_lost"),
        "{outcomes:?}"
    );
    assert_eq!(outcomes.len(), 2, "{outcomes:?}");
    let docs: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM documents WHERE device = 'cam-kill'")
        .fetch_one(&mut c)
        .await
        .expect("docs");
    assert_eq!(docs, 1, "one revision");
    assert_eq!(outcomes[1].as_deref(), Some("succeeded"));
    drop(second);
    db.drop_db().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_revoked_token_stops_on_every_replica_at_once() {
    let Some(db) = TestDb::create().await else {
        return;
    };
    let blobs = tempfile::tempdir().expect("blobs");
    let admin = admin_token(&db.url);
    let reps: Vec<_> = (0..2).map(|_| replica(&db, blobs.path(), &[])).collect();
    let api = Api {
        client: reqwest::Client::new(),
        token: admin.clone(),
    };
    let (st, t) = api
        .post(
            &reps[0].0.base,
            "/v1/tokens",
            &json!({"name": "ro", "scope": "read"}),
        )
        .await;
    assert_eq!(st, 201, "{t}");
    let reader = Api {
        client: reqwest::Client::new(),
        token: t["token"].as_str().expect("secret").to_owned(),
    };
    for (p, _) in &reps {
        assert_eq!(reader.get(&p.base, "/v1/jobs").await.0, 200);
    }
    let r = api
        .client
        .delete(format!(
            "{}/v1/tokens/{}",
            reps[1].0.base,
            t["id"].as_str().expect("id")
        ))
        .bearer_auth(&admin)
        .send()
        .await
        .expect("revoke");
    assert_eq!(r.status(), 204);
    for (p, _) in &reps {
        assert_eq!(reader.get(&p.base, "/v1/jobs").await.0, 401);
    }
    // The replicas cache token lookups: a revocation made by the command line, beside every
    // running replica, must end a token they have just served just the same (it waits for
    // their acknowledgements as the API does).
    let (st, t2) = api
        .post(
            &reps[0].0.base,
            "/v1/tokens",
            &json!({"name": "ro2", "scope": "read"}),
        )
        .await;
    assert_eq!(st, 201, "{t2}");
    let reader2 = Api {
        client: reqwest::Client::new(),
        token: t2["token"].as_str().expect("secret").to_owned(),
    };
    for _ in 0..3 {
        for (p, _) in &reps {
            assert_eq!(reader2.get(&p.base, "/v1/jobs").await.0, 200);
        }
    }
    let out = std::process::Command::new(caliper_bin())
        .args([
            "token",
            "revoke",
            t2["id"].as_str().expect("id"),
            "--database-url",
        ])
        .arg(&db.url)
        .output()
        .expect("caliper token revoke");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for (p, _) in &reps {
        assert_eq!(reader2.get(&p.base, "/v1/jobs").await.0, 401);
    }
    // Without a token nothing but health answers.
    let r = reqwest::get(format!("{}/v1/jobs", reps[0].0.base))
        .await
        .expect("get");
    assert_eq!(r.status(), 401);
    let r = reqwest::get(format!("{}/readyz", reps[0].0.base))
        .await
        .expect("get");
    assert_eq!(r.status(), 200);
    // Both replicas are registered as caching; a killed one never acknowledges, yet a
    // revocation on the survivor still completes once the dead one's lease (5 s) runs out.
    let mut c = sqlx::PgConnection::connect(&db.url).await.expect("connect");
    let caching: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM token_caches")
        .fetch_one(&mut c)
        .await
        .expect("count");
    assert_eq!(caching, 2, "both replicas registered as caching");
    let mut reps = reps;
    let _ = reps[0].0.child.kill();
    let _ = reps[0].0.child.wait();
    let (st, t3) = api
        .post(
            &reps[1].0.base,
            "/v1/tokens",
            &json!({"name": "ro3", "scope": "read"}),
        )
        .await;
    assert_eq!(st, 201, "{t3}");
    let reader3 = Api {
        client: reqwest::Client::new(),
        token: t3["token"].as_str().expect("secret").to_owned(),
    };
    assert_eq!(reader3.get(&reps[1].0.base, "/v1/jobs").await.0, 200);
    let started = Instant::now();
    let r = api
        .client
        .delete(format!(
            "{}/v1/tokens/{}",
            reps[1].0.base,
            t3["id"].as_str().expect("id")
        ))
        .bearer_auth(&admin)
        .send()
        .await
        .expect("revoke");
    assert_eq!(r.status(), 204);
    assert!(
        started.elapsed() < Duration::from_secs(20),
        "a dead replica held a revocation for {:?}",
        started.elapsed()
    );
    assert_eq!(reader3.get(&reps[1].0.base, "/v1/jobs").await.0, 401);
    drop(reps);
    db.drop_db().await;
}
