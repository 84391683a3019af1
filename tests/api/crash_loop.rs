//! Crash loop: SIGKILL the service at random moments during uploads and jobs, 50 times, then
//! check that nothing was lost or corrupted — every job ends in one terminal state, no job
//! filed two revisions, every document verifies, every referenced blob exists, and no
//! temporary upload file is left behind. Both profiles: embedded (SQLite + local files), and
//! production (PostgreSQL + S3, when `.ci/run` gives their addresses).

use std::path::Path;
use std::time::{Duration, Instant};

use serde_json::{Value, json};

use crate::common::*;

const CYCLES: usize = 50;

/// A tiny deterministic generator (xorshift): random kill moments that a failure can replay.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

/// Drive one process for a moment: upload, queue, and let jobs run; killed at a random time.
async fn cycle(
    c: &reqwest::Client,
    base: &str,
    token: Option<&str>,
    files: &[(String, Vec<u8>)],
    kill_after: Duration,
    jobs: &mut Vec<String>,
) {
    let auth = |r: reqwest::RequestBuilder| match token {
        Some(t) => r.bearer_auth(t),
        None => r,
    };
    let work = async {
        for round in 0.. {
            let mut form = reqwest::multipart::Form::new();
            for (name, bytes) in files {
                form = form.part(
                    "file",
                    reqwest::multipart::Part::bytes(bytes.clone()).file_name(name.clone()),
                );
            }
            let Ok(r) = auth(c.post(format!("{base}/v1/datasets")))
                .multipart(form)
                .send()
                .await
            else {
                return;
            };
            let Ok(ds) = r.json::<Value>().await else {
                return;
            };
            let Some(ds) = ds["id"].as_str() else {
                continue;
            };
            let body = json!({"kind": "blur_score", "dataset": ds,
                              "device": format!("crash-{}", round % 3), "sensor": "cam0"});
            let Ok(r) = auth(c.post(format!("{base}/v1/jobs")))
                .json(&body)
                .send()
                .await
            else {
                return;
            };
            if let Ok(j) = r.json::<Value>().await
                && let Some(id) = j["id"].as_str()
            {
                jobs.push(id.to_owned());
            }
        }
    };
    let _ = tokio::time::timeout(kill_after, work).await;
}

/// Wait until every job is terminal, on a fresh process.
async fn settle(
    c: &reqwest::Client,
    base: &str,
    token: Option<&str>,
    jobs: &[String],
) -> Vec<Value> {
    let mut out = Vec::new();
    for id in jobs {
        let start = Instant::now();
        loop {
            let mut r = c.get(format!("{base}/v1/jobs/{id}"));
            if let Some(t) = token {
                r = r.bearer_auth(t);
            }
            let j: Value = r.send().await.expect("get").json().await.expect("json");
            if matches!(
                j["status"].as_str(),
                Some("succeeded" | "failed" | "canceled")
            ) {
                out.push(j);
                break;
            }
            // A 202 means the job was committed: it must still be there.
            assert_ne!(
                j["code"], "not_found",
                "job {id} was accepted and then lost"
            );
            assert!(
                start.elapsed() < Duration::from_secs(120),
                "job {id} stuck: {j}"
            );
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }
    out
}

fn assert_no_temp_files(data: &Path) {
    let tmp = data.join("tmp");
    let left = count_files(&tmp);
    assert_eq!(left, 0, "temporary files left in {}", tmp.display());
    let strays = stray_blob_files(&data.join("blobs"));
    assert!(
        strays.is_empty(),
        "half-written blob files left: {strays:?}"
    );
}

/// Files of the blob directory that are not blobs (temporary files of interrupted writes).
fn stray_blob_files(dir: &Path) -> Vec<String> {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    rd.flatten()
        .flat_map(|e| {
            let p = e.path();
            if p.is_dir() {
                stray_blob_files(&p)
            } else {
                let name = e.file_name().to_string_lossy().into_owned();
                let is_blob = name.len() == 64 && name.bytes().all(|b| b.is_ascii_hexdigit());
                if is_blob {
                    Vec::new()
                } else {
                    vec![p.display().to_string()]
                }
            }
        })
        .collect()
}

/// Every job ran to one end and filed at most one revision; every document verifies.
async fn check(
    c: &reqwest::Client,
    base: &str,
    token: Option<&str>,
    ended: &[Value],
) -> (usize, usize) {
    let get = |path: String| {
        let mut r = c.get(format!("{base}{path}"));
        if let Some(t) = token {
            r = r.bearer_auth(t);
        }
        r.send()
    };
    let mut docs = 0;
    for d in 0..3 {
        let path = format!("/v1/devices/crash-{d}/documents/cam0/blur_score");
        let r = get(path.clone()).await.expect("revisions");
        if r.status() == 404 {
            continue;
        }
        let revs: Vec<Value> = r.json().await.expect("json");
        let mut jobs: Vec<String> = revs
            .iter()
            .map(|r| r["job"].as_str().unwrap_or("").to_owned())
            .collect();
        let n = jobs.len();
        jobs.sort();
        jobs.dedup();
        assert_eq!(jobs.len(), n, "a job filed two revisions of crash-{d}");
        // Revisions run 1..=n without gaps.
        let mut nums: Vec<u64> = revs.iter().filter_map(|r| r["rev"].as_u64()).collect();
        nums.sort_unstable();
        assert_eq!(nums, (1..=n as u64).collect::<Vec<_>>(), "crash-{d}");
        for rev in &revs {
            let doc: Value = get(format!("{path}/{}", rev["rev"]))
                .await
                .expect("doc")
                .json()
                .await
                .expect("json");
            assert!(
                caliper_service::document::verify(&doc),
                "corrupt document {doc}"
            );
        }
        docs += n;
    }
    // Every succeeded job's artifacts and every dataset file can be read: no blob is
    // referenced but missing.
    let mut blobs = 0;
    for j in ended.iter().filter(|j| j["status"] == "succeeded") {
        let id = j["id"].as_str().expect("id");
        let arts: Value = get(format!("/v1/jobs/{id}/artifacts"))
            .await
            .expect("artifacts")
            .json()
            .await
            .expect("json");
        for a in arts["items"].as_array().into_iter().flatten() {
            let r = get(format!(
                "/v1/jobs/{id}/artifacts/{}",
                a["name"].as_str().unwrap_or("")
            ))
            .await
            .expect("artifact");
            assert_eq!(r.status(), 200, "artifact {a} of {id} is missing");
            blobs += 1;
        }
        let ds = j["dataset"].as_str().expect("dataset");
        let r = get(format!("/v1/datasets/{ds}/files/0"))
            .await
            .expect("file");
        assert_eq!(r.status(), 200, "dataset {ds} lost its file");
    }
    (docs, blobs)
}

/// Start a process with `spawn` and kill it at a random moment of uploads and jobs, `CYCLES`
/// times (kill moments from `seed`), then start one more and check everything (see the
/// module docs), the temporary files of `data` included.
async fn kill_loop_and_check(
    profile: &str,
    token: Option<&str>,
    seed: u64,
    data: &Path,
    spawn: impl Fn() -> Proc,
) {
    let c = reqwest::Client::builder()
        .timeout(Duration::from_secs(10))
        .build()
        .expect("client");
    let files = vec![
        ("a.png".to_string(), png(&sharp_image(320, 240))),
        (
            "b.png".to_string(),
            png(&box_blur(&sharp_image(320, 240), 3)),
        ),
    ];
    let mut rng = Rng(seed);
    let mut jobs = Vec::new();
    for _ in 0..CYCLES {
        let mut p = spawn();
        let kill_after = Duration::from_millis(50 + rng.next() % 700);
        cycle(&c, &p.base, token, &files, kill_after, &mut jobs).await;
        let _ = p.child.kill();
        let _ = p.child.wait();
    }
    let p = spawn();
    let ended = settle(&c, &p.base, token, &jobs).await;
    let (docs, blobs) = check(&c, &p.base, token, &ended).await;
    assert_no_temp_files(data);
    let succeeded = ended.iter().filter(|j| j["status"] == "succeeded").count();
    eprintln!(
        "crash loop ({profile}): {CYCLES} kills, {} jobs accepted, {} ended ({succeeded} \
         succeeded), {docs} revisions, {blobs} artifacts read back",
        jobs.len(),
        ended.len()
    );
    assert!(succeeded > 0, "no job got through the loop");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fifty_kills_lose_and_corrupt_nothing_embedded() {
    let bin = caliper_bin();
    let data = tempfile::tempdir().expect("data");
    kill_loop_and_check("embedded", None, 0x9e37_79b9_7f4a_7c15, data.path(), || {
        spawn_caliper(&bin, data.path(), &["--lease-secs", "2"])
    })
    .await;
    assert!(
        count_files(&data.path().join("blobs")) > 0,
        "the blob directory was not where the check looked"
    );
}

/// The same loop on the production profile: each process a replica on one PostgreSQL
/// database, blobs in an S3 bucket (moto), tokens required; killed 50 times at random moments.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fifty_kills_lose_and_corrupt_nothing_on_postgres_and_s3() {
    let Some(db) = crate::postgres::TestDb::create().await else {
        return;
    };
    let Some((endpoint, bucket)) = crate::s3::bucket().await else {
        db.drop_db().await;
        return;
    };
    let token = crate::postgres::admin_token(&db.url);
    let url = format!("s3://{bucket}/crash");
    let env = crate::s3::aws_env(&endpoint);
    let env: Vec<(&str, &str)> = env.iter().map(|(k, v)| (*k, v.as_str())).collect();
    // One host's data directory across restarts, as a replica restarted in place has: its
    // temporary files are its own to clean up.
    let data = tempfile::tempdir().expect("data");
    let bin = caliper_bin();
    let spawn = || {
        let args = [
            "--database-url",
            db.url.as_str(),
            "--blob-url",
            url.as_str(),
            "--lease-secs",
            "2",
            "--rate-limit-per-sec",
            "0",
        ];
        spawn_caliper_env(&bin, data.path(), &args, &env)
    };
    kill_loop_and_check(
        "PostgreSQL + S3",
        Some(&token),
        0x2545_f491_4f6c_dd1d,
        data.path(),
        spawn,
    )
    .await;
    db.drop_db().await;
}
