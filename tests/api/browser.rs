//! The dashboard in a real browser: Chromium driven over WebDriver (chromedriver) against a
//! real server. `CALIPER_CHROMEDRIVER` (path of chromedriver) and optionally
//! `CALIPER_CHROMIUM` (the browser binary) select them; `.ci/run` sets both. Without them the
//! tests say loudly that they did not run. `CALIPER_SCREENSHOTS_DIR` saves a screenshot of
//! each page there (the README's screenshots come from `tests/screenshots`).

use std::path::{Path, PathBuf};

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use fantoccini::elements::Element;
use fantoccini::wd::WebDriverCompatibleCommand;
use fantoccini::{Client, ClientBuilder, Locator};
use serde_json::{Value, json};

use crate::common::*;

/// chromedriver on a free port, killed on drop.
struct Driver {
    child: Child,
    url: String,
}

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn driver_path() -> Option<PathBuf> {
    match std::env::var_os("CALIPER_CHROMEDRIVER") {
        Some(p) if !p.is_empty() => Some(PathBuf::from(p)),
        _ => {
            eprintln!(
                "\n*** browser tests NOT RUN: set CALIPER_CHROMEDRIVER (and CALIPER_CHROMIUM) \
                 to run the dashboard in Chromium (.ci/run does) ***\n"
            );
            None
        }
    }
}

async fn start_driver(path: &Path) -> Driver {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("free port")
        .port();
    let child = Command::new(path)
        .arg(format!("--port={port}"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("chromedriver starts");
    let url = format!("http://127.0.0.1:{port}");
    let client = reqwest::Client::new();
    let start = Instant::now();
    while client.get(format!("{url}/status")).send().await.is_err() {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "chromedriver did not answer"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    Driver { child, url }
}

async fn browser(driver: &Driver, downloads: &Path) -> Client {
    let mut chrome = json!({
        "args": ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                 "--window-size=1280,1000", "--disable-extensions"],
        "prefs": {"download.default_directory": downloads.to_string_lossy(),
                  "download.prompt_for_download": false},
    });
    if let Some(bin) = std::env::var_os("CALIPER_CHROMIUM").filter(|b| !b.is_empty()) {
        chrome["binary"] = Value::from(bin.to_string_lossy().into_owned());
    }
    let caps = json!({"goog:chromeOptions": chrome, "goog:loggingPrefs": {"browser": "ALL"}});
    let Value::Object(caps) = caps else {
        unreachable!("a JSON object literal")
    };
    ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new())
        .capabilities(caps)
        .connect(&driver.url)
        .await
        .expect("browser session")
}

/// Chromedriver's console log (`goog:loggingPrefs`), a vendor command fantoccini lacks.
#[derive(Debug)]
struct BrowserLog;

impl WebDriverCompatibleCommand for BrowserLog {
    fn endpoint(
        &self,
        base: &url::Url,
        session: Option<&str>,
    ) -> Result<url::Url, url::ParseError> {
        base.join(&format!("session/{}/se/log", session.unwrap_or_default()))
    }
    fn method_and_body(&self, _: &url::Url) -> (http::Method, Option<String>) {
        (http::Method::POST, Some(r#"{"type":"browser"}"#.into()))
    }
}

/// Console messages at level SEVERE (errors, failed loads, CSP violations).
async fn console_errors(c: &Client) -> Vec<String> {
    let log = c.issue_cmd(BrowserLog).await.expect("browser log");
    log.as_array()
        .into_iter()
        .flatten()
        .filter(|e| e["level"] == "SEVERE")
        .map(|e| e["message"].as_str().unwrap_or("").to_owned())
        .collect()
}

async fn wait_css(c: &Client, css: &str) -> Element {
    c.wait()
        .at_most(Duration::from_secs(30))
        .for_element(Locator::Css(css))
        .await
        .unwrap_or_else(|e| panic!("{css} never appeared: {e}"))
}

/// Poll a JavaScript expression until it is truthy; returns its value.
async fn wait_js(c: &Client, expr: &str, timeout: Duration) -> Value {
    let start = Instant::now();
    loop {
        let v = c
            .execute(&format!("return ({expr});"), vec![])
            .await
            .expect("script runs");
        if v.as_bool() != Some(false) && !v.is_null() && v != json!(0) && v != json!("") {
            return v;
        }
        assert!(start.elapsed() < timeout, "timed out waiting for {expr}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

async fn text(c: &Client, css: &str) -> String {
    wait_css(c, css).await.text().await.expect("text")
}

async fn screenshot(c: &Client, name: &str) {
    let Some(dir) = std::env::var_os("CALIPER_SCREENSHOTS_DIR") else {
        return;
    };
    let png = c.screenshot().await.expect("screenshot");
    std::fs::create_dir_all(&dir).expect("screenshot dir");
    std::fs::write(Path::new(&dir).join(format!("{name}.png")), png).expect("write screenshot");
}

async fn wait_download(dir: &Path, name: &str) -> Vec<u8> {
    let path = dir.join(name);
    let start = Instant::now();
    loop {
        if let Ok(bytes) = std::fs::read(&path) {
            // Chromium writes NAME.crdownload and renames it when complete.
            if !bytes.is_empty() {
                return bytes;
            }
        }
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "{name} was not downloaded; found {:?}",
            std::fs::read_dir(dir).map(|d| d.flatten().map(|e| e.file_name()).collect::<Vec<_>>())
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dashboard_runs_a_calibration_end_to_end() {
    let Some(driver_bin) = driver_path() else {
        return;
    };
    let s = start_with(|c| c.debug_job_kinds = true).await;
    let driver = start_driver(&driver_bin).await;
    let downloads = tempfile::tempdir().expect("downloads");
    let c = browser(&driver, downloads.path()).await;

    // `/` leads to the dashboard; an empty fleet says so.
    c.goto(&s.url("/")).await.expect("open /");
    let url = c.current_url().await.expect("url");
    assert!(url.path().starts_with("/ui/"), "{url}");
    assert_eq!(text(&c, "#fleet-count").await, "0 devices");

    // Upload a dataset from the page, queue a camera calibration with the generated form.
    let files = crate::camera::renders();
    let dir = tempfile::tempdir().expect("images");
    let paths: Vec<String> = files
        .iter()
        .map(|(name, bytes)| {
            let p = dir.path().join(name);
            std::fs::write(&p, bytes).expect("write image");
            p.to_string_lossy().into_owned()
        })
        .collect();
    c.goto(&s.url("/ui/#/run")).await.expect("run page");
    let input = wait_css(&c, "#run-files").await;
    input
        .send_keys(&paths.join("\n"))
        .await
        .expect("choose files");
    wait_css(&c, "#upload-status[data-dataset]").await;
    let upload_pct = c
        .execute(
            "return document.getElementById('upload-progress').value;",
            vec![],
        )
        .await
        .expect("progress value");
    assert_eq!(
        upload_pct.as_f64(),
        Some(100.0),
        "upload progress ends at 100 %"
    );
    let kind = wait_css(&c, "#run-kind").await;
    kind.select_by_value("camera_calibration")
        .await
        .expect("select kind");
    screenshot(&c, "run").await;
    for (name, value) in [
        ("board.cols", "9"),
        ("board.rows", "6"),
        ("board.square", "0.025"),
    ] {
        wait_css(&c, &format!("[name='{name}']"))
            .await
            .send_keys(value)
            .await
            .expect("type param");
    }
    wait_css(&c, "#run-device")
        .await
        .send_keys("cam-ui")
        .await
        .expect("device");
    wait_css(&c, "#run-sensor")
        .await
        .send_keys("cam0")
        .await
        .expect("sensor");
    wait_css(&c, "#run-submit")
        .await
        .click()
        .await
        .expect("submit");

    // The job page follows the job live to 100 % and renders the document.
    let hash = wait_js(
        &c,
        "location.hash.startsWith('#/jobs/') && location.hash",
        Duration::from_secs(20),
    )
    .await;
    let job_id = hash
        .as_str()
        .expect("hash")
        .trim_start_matches("#/jobs/")
        .to_owned();
    wait_js(
        &c,
        "document.querySelector('#job-table progress') && document.querySelector('#job-table progress').value === 100",
        Duration::from_secs(90),
    )
    .await;
    // Progress reaches 100 while the result is still being filed: the status follows.
    wait_js(
        &c,
        "(() => { const s = document.querySelector('#job-table .status'); \
         return s && s.textContent.trim() !== 'running' && s.textContent.trim(); })()",
        Duration::from_secs(30),
    )
    .await;
    assert_eq!(text(&c, "#job-table .status").await, "succeeded");
    wait_css(&c, "#job-result .bar-chart").await;
    let (_, result) = s.get_json(&format!("/v1/jobs/{job_id}/result")).await;
    let views = result["parameters"]["calibration"]["views"]
        .as_array()
        .expect("views")
        .len();
    let bars = c
        .find_all(Locator::Css("#job-result .bar-chart rect.bar"))
        .await
        .expect("bars")
        .len();
    assert_eq!(bars, views, "one bar per view");
    assert!(views >= 8, "{views} views");
    c.execute(
        "document.querySelector('#job-result .bar-chart').scrollIntoView({block: 'center'});",
        vec![],
    )
    .await
    .expect("scroll");
    screenshot(&c, "result").await;

    // A second revision from fewer views, so the two differ.
    let ds2 = s.dataset(as_refs(&files[..8])).await;
    let j2 = s
        .job(json!({"kind": "camera_calibration", "dataset": ds2, "device": "cam-ui", "sensor": "cam0",
                    "params": {"board": {"cols": 9, "rows": 6, "square": 0.025}}}))
        .await;
    assert_eq!(s.wait_terminal(&j2).await["status"], "succeeded");

    // Fleet → device → diff of r1 and r2, as the API computes it.
    c.goto(&s.url("/ui/#/fleet")).await.expect("fleet");
    assert_eq!(text(&c, "#fleet-count").await, "1 device");
    screenshot(&c, "fleet").await;
    wait_css(&c, "tr[data-serial='cam-ui'] a")
        .await
        .click()
        .await
        .expect("open device");
    wait_css(&c, ".diff-form button").await;
    screenshot(&c, "device").await;
    wait_css(&c, ".diff-form button")
        .await
        .click()
        .await
        .expect("diff");
    wait_css(&c, "#diff-table").await;
    let (_, diff) = s
        .get_json("/v1/devices/cam-ui/documents/cam0/camera_calibration/diff?from=1&to=2")
        .await;
    let changed = diff["changed"].as_u64().expect("changed");
    assert!(changed > 0, "{diff}");
    let summary = text(&c, "#diff-summary").await;
    assert!(summary.starts_with(&format!("{changed} of ")), "{summary}");
    let rows = c
        .find_all(Locator::Css("#diff-table tbody tr"))
        .await
        .expect("rows")
        .len();
    assert_eq!(rows as u64, changed, "the page shows the changed values");
    assert!(
        c.source()
            .await
            .expect("source")
            .contains("parameters.calibration.parameters[fx]")
    );
    screenshot(&c, "diff").await;

    // Download an export from the document page: the same bytes as the API's.
    c.goto(&s.url("/ui/#/devices/cam-ui/cam0/camera_calibration/2"))
        .await
        .expect("document page");
    wait_css(&c, "#intrinsics").await;
    screenshot(&c, "document").await;
    wait_css(&c, "button[data-export='opencv-yaml']")
        .await
        .click()
        .await
        .expect("download");
    let got = wait_download(downloads.path(), "cam-ui_cam0_camera_calibration_r2.yaml").await;
    let want = s
        .client
        .get(s.url("/v1/devices/cam-ui/documents/cam0/camera_calibration/2?format=opencv-yaml"))
        .send()
        .await
        .expect("export")
        .bytes()
        .await
        .expect("bytes");
    assert_eq!(
        got,
        want.to_vec(),
        "downloaded export differs from the API's"
    );

    // Cancel a running job from the live jobs page.
    let ds3 = s.dataset(as_refs(&files[..1])).await;
    let hang = s.job(json!({"kind": "debug_hang", "dataset": ds3})).await;
    s.wait_for(&hang, Duration::from_secs(20), |j| j["status"] == "running")
        .await;
    c.goto(&s.url("/ui/#/jobs")).await.expect("jobs page");
    screenshot(&c, "jobs").await;
    wait_css(&c, &format!("button[data-cancel='{hang}']"))
        .await
        .click()
        .await
        .expect("cancel");
    let ended = s.wait_terminal(&hang).await;
    assert_eq!(ended["status"], "canceled", "{ended}");
    // The row learns it live (SSE or the periodic refresh).
    wait_js(
        &c,
        &format!("document.querySelector(\"tr[data-job='{hang}']\").dataset.status === 'canceled'"),
        Duration::from_secs(20),
    )
    .await;

    // A phone-sized screen: every page fits its width (tables scroll inside their box).
    c.set_window_size(390, 844).await.expect("phone size");
    for page in [
        "#/fleet",
        "#/devices/cam-ui",
        "#/devices/cam-ui/cam0/camera_calibration/2",
        "#/jobs",
        "#/run",
    ] {
        c.goto(&s.url(&format!("/ui/{page}"))).await.expect("page");
        wait_js(&c, "document.querySelector('main h1') && !document.querySelector('main p.muted:only-child')", Duration::from_secs(10)).await;
        let fits = c
            .execute(
                "return document.documentElement.scrollWidth <= window.innerWidth + 1;",
                vec![],
            )
            .await
            .expect("width");
        assert_eq!(fits, json!(true), "{page} is wider than a phone screen");
        if page == "#/devices/cam-ui" {
            screenshot(&c, "phone-device").await;
        }
    }

    let errors = console_errors(&c).await;
    assert!(errors.is_empty(), "console errors: {errors:?}");
    c.close().await.expect("close");
    s.stop().await;
}

/// 10,000 devices: the fleet page reads one page of the API and is on screen well within a
/// second on loopback. The time is printed (the README reports it); the assertion only
/// catches a page that would fetch the whole fleet.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fleet_of_ten_thousand_devices_pages() {
    let Some(driver_bin) = driver_path() else {
        return;
    };
    let s = start().await;
    seed_devices(&s, 10_000).await;
    let driver = start_driver(&driver_bin).await;
    let downloads = tempfile::tempdir().expect("downloads");
    let c = browser(&driver, downloads.path()).await;

    c.goto(&s.url("/ui/#/fleet")).await.expect("fleet");
    wait_css(&c, "#fleet-table").await;
    let painted = c
        .execute(
            "const m = performance.getEntriesByName('caliper:page:fleet'); return m.length ? m[0].startTime : null;",
            vec![],
        )
        .await
        .expect("mark")
        .as_f64()
        .expect("the fleet page marks when it is on screen");
    eprintln!(
        "fleet page of 10,000 devices on screen after {painted:.0} ms (from navigation start)"
    );
    assert!(painted < 5000.0, "fleet page took {painted} ms");
    assert_eq!(text(&c, "#fleet-count").await, "10000 devices");
    let rows = c
        .find_all(Locator::Css("#fleet-table tbody tr"))
        .await
        .expect("rows");
    assert_eq!(rows.len(), 50);
    assert_eq!(
        rows[0].attr("data-serial").await.expect("attr").as_deref(),
        Some("dev-00000")
    );
    wait_css(&c, "#fleet-next")
        .await
        .click()
        .await
        .expect("next page");
    wait_js(
        &c,
        "document.querySelector('#fleet-table tbody tr') && document.querySelector('#fleet-table tbody tr').dataset.serial === 'dev-00050'",
        Duration::from_secs(10),
    )
    .await;
    // Search narrows on the server.
    c.goto(&s.url("/ui/#/fleet?q=dev-0999"))
        .await
        .expect("search");
    wait_js(
        &c,
        "document.getElementById('fleet-count') && document.getElementById('fleet-count').textContent.startsWith('10 devices')",
        Duration::from_secs(10),
    )
    .await;
    let errors = console_errors(&c).await;
    assert!(errors.is_empty(), "console errors: {errors:?}");
    c.close().await.expect("close");
    s.stop().await;
}

/// Write `n` devices with two documents each straight into the store's database (running
/// jobs for 10,000 devices would take minutes and test nothing more).
async fn seed_devices(s: &TestServer, n: usize) {
    use sqlx::Connection;
    let rows = (0..n).flat_map(|i| {
        let serial = format!("dev-{i:05}");
        [
            (
                "cam0",
                "camera_calibration",
                json!({"rms": 0.2 + (i % 7) as f64 * 0.1, "coverage": 0.7}),
            ),
            ("imu0", "imu_noise", json!({"warnings": i % 3})),
        ]
        .map(|(sensor, kind, quality)| {
            let body = json!({"schema": "seed", "kind": kind, "device": serial, "sensor": sensor,
                              "quality": quality, "parameters": {}});
            (
                serial.clone(),
                sensor,
                kind,
                format!("e{i}"),
                body.to_string(),
            )
        })
    });
    if let Some(db) = &s.db {
        let mut conn = sqlx::PgConnection::connect(&db.url)
            .await
            .expect("open store");
        let mut tx = conn.begin().await.expect("tx");
        for (serial, sensor, kind, etag, body) in rows {
            sqlx::query(
                "INSERT INTO documents (device, sensor, kind, rev, etag, schema, created_at, job_id, body) \
                 VALUES ($1, $2, $3, 1, $4, 'seed', 1764547200000, NULL, $5)",
            )
            .bind(serial)
            .bind(sensor)
            .bind(kind)
            .bind(etag)
            .bind(body)
            .execute(&mut *tx)
            .await
            .expect("insert");
        }
        tx.commit().await.expect("commit");
        return;
    }
    let path = s.dir.path().join("data").join("caliper.db");
    let mut conn = sqlx::SqliteConnection::connect(&format!("sqlite://{}", path.display()))
        .await
        .expect("open store");
    let mut tx = conn.begin().await.expect("tx");
    for (serial, sensor, kind, etag, body) in rows {
        sqlx::query(
            "INSERT INTO documents (device, sensor, kind, rev, etag, schema, created_at, job_id, body) \
             VALUES (?, ?, ?, 1, ?, 'seed', 1764547200000, NULL, ?)",
        )
        .bind(serial)
        .bind(sensor)
        .bind(kind)
        .bind(etag)
        .bind(body)
        .execute(&mut *tx)
        .await
        .expect("insert");
    }
    tx.commit().await.expect("commit");
}
