//! IMU job kinds end to end: a synthetic static log with known white-noise densities is
//! uploaded (gzip), its noise model comes back, and Kalibr's imu.yaml is exported.

use serde_json::{Value, json};

use crate::common::*;
use crate::datasets::flate2_gzip;

/// Deterministic standard normal samples (LCG + Box-Muller).
struct Gauss(u64);

impl Gauss {
    fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn next(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    }
}

const RATE: f64 = 200.0;
const GYRO_N: f64 = 2.0e-4; // rad/s/√Hz
const ACCEL_N: f64 = 2.0e-3; // m/s²/√Hz

/// `seconds` of a static EuRoC log: white noise only, z axis up.
fn static_log(seconds: f64, temperature: bool) -> String {
    let mut g = Gauss(42);
    let n = (seconds * RATE) as usize;
    let (sg, sa) = (GYRO_N * RATE.sqrt(), ACCEL_N * RATE.sqrt());
    let mut out = String::from(
        "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]",
    );
    out.push_str(if temperature {
        ",temperature [degC]\n"
    } else {
        "\n"
    });
    for i in 0..n {
        let t = 1_000_000_000u64 + (i as f64 * 1e9 / RATE) as u64;
        out.push_str(&format!(
            "{t},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9}",
            sg * g.next(),
            sg * g.next(),
            sg * g.next(),
            sa * g.next(),
            sa * g.next(),
            9.81 + sa * g.next()
        ));
        if temperature {
            out.push_str(&format!(",{:.3}", 20.0 + 30.0 * i as f64 / n as f64));
        }
        out.push('\n');
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn imu_noise_recovers_white_noise_density_and_exports_kalibr() {
    let s = start().await;
    let log = static_log(300.0, false);
    let ds = s
        .dataset(vec![("static.csv.gz", flate2_gzip(log.as_bytes()))])
        .await;
    let id = s
        .job(json!({"kind": "imu_noise", "dataset": ds, "device": "imu-1", "sensor": "imu0"}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let (_, doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    assert_eq!(doc["schema"], "caliper.imu_noise/v1");
    let k = &doc["parameters"]["kalibr"];
    let gn = k["gyroscope_noise_density"].as_f64().unwrap();
    let an = k["accelerometer_noise_density"].as_f64().unwrap();
    // Worst of three axes of a 5 min log: within a few percent of the truth.
    assert!((gn / GYRO_N - 1.0).abs() < 0.05, "gyro N {gn} vs {GYRO_N}");
    assert!(
        (an / ACCEL_N - 1.0).abs() < 0.05,
        "accel N {an} vs {ACCEL_N}"
    );
    assert!((k["update_rate"].as_f64().unwrap() - RATE).abs() < 1e-6);
    let r = s
        .client
        .get(s.url("/v1/devices/imu-1/documents/imu0/imu_noise/latest?format=kalibr-yaml"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let yaml = r.text().await.unwrap();
    assert!(yaml.contains("gyroscope_noise_density: "), "{yaml}");
    assert!(yaml.contains("update_rate: 200"), "{yaml}");
    // Kalibr reads this with PyYAML (YAML 1.1), where a float needs a dot: `2e-3` would be a
    // string. Every number must carry one.
    for line in yaml.lines().filter(|l| !l.starts_with('#')) {
        let (key, value) = line.split_once(": ").expect("key: value");
        let value = value.split('#').next().unwrap_or("").trim();
        if key != "rostopic" {
            assert!(
                value.contains('.') && value.parse::<f64>().is_ok(),
                "{key}: {value:?} is not a YAML 1.1 float"
            );
        }
    }
    let (_, arts) = s.get_json(&format!("/v1/jobs/{id}/artifacts")).await;
    assert_eq!(arts["items"][0]["name"], "allan.svg");
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn imu_jobs_fail_clearly_on_unsuitable_logs() {
    let s = start().await;
    // A static log has no poses to calibrate scale from, and no temperature column.
    let ds = s
        .dataset(vec![("still.csv", static_log(20.0, false).into_bytes())])
        .await;
    for kind in ["imu_intrinsics", "imu_thermal"] {
        let id = s.job(json!({"kind": kind, "dataset": ds})).await;
        let done: Value = s.wait_terminal(&id).await;
        assert_eq!(done["status"], "failed", "{kind}: {done}");
        assert_eq!(done["attempt"], 1, "{kind}: bad input is not retried");
        assert!(
            matches!(
                done["error"]["code"].as_str(),
                Some("no_solution" | "invalid_input" | "invalid_param")
            ),
            "{kind}: {done}"
        );
    }
    // Wrong parameter types are refused before queueing.
    let (st, p) = s
        .post_json(
            "/v1/jobs",
            &json!({"kind": "imu_noise", "dataset": ds, "params": {"rate_hz": "fast"}}),
        )
        .await;
    assert_eq!(st, 422, "{p}");
    assert_eq!(p["field"], "params.rate_hz");
    // Out-of-range values too.
    let (st, p) = s
        .post_json(
            "/v1/jobs",
            &json!({"kind": "imu_noise", "dataset": ds, "params": {"taus_per_octave": 0}}),
        )
        .await;
    assert_eq!(st, 422, "{p}");
    assert_eq!(p["code"], "invalid_param");
    s.stop().await;
}

/// `seconds` of log that rests, turns about z (0.5 rad/s peak, sin² profile) during
/// `[t0, t1]` s, and rests again.
fn log_with_turn(seconds: f64, t0: f64, t1: f64) -> String {
    let mut g = Gauss(7);
    let n = (seconds * RATE) as usize;
    let (sg, sa) = (GYRO_N * RATE.sqrt(), ACCEL_N * RATE.sqrt());
    let mut out = String::from(
        "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n",
    );
    for i in 0..n {
        let t = i as f64 / RATE;
        let wz = if (t0..=t1).contains(&t) {
            0.5 * (std::f64::consts::PI * (t - t0) / (t1 - t0)).sin().powi(2)
        } else {
            0.0
        };
        out.push_str(&format!(
            "{},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9}\n",
            1_000_000_000u64 + (i as f64 * 1e9 / RATE) as u64,
            sg * g.next(),
            sg * g.next(),
            wz + sg * g.next(),
            sa * g.next(),
            sa * g.next(),
            9.81 + sa * g.next()
        ));
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn imu_noise_refuses_a_moving_log_or_uses_its_longest_static_stretch() {
    let s = start().await;
    let ds = s
        .dataset(vec![(
            "turn.csv.gz",
            flate2_gzip(log_with_turn(240.0, 60.0, 70.0).as_bytes()),
        )])
        .await;
    let id = s.job(json!({"kind": "imu_noise", "dataset": ds})).await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "failed", "{done}");
    assert_eq!(done["attempt"], 1, "bad input is not retried");
    assert_eq!(done["error"]["code"], "invalid_input", "{done}");
    let msg = done["error"]["message"].as_str().unwrap_or_default();
    // The message names the moving interval (≈ 60–70 s, to within the 1 s window).
    let named = msg
        .split("moving ")
        .nth(1)
        .and_then(|r| r.split(" s").next())
        .and_then(|r| r.split_once('–'))
        .and_then(|(a, b)| Some((a.parse::<f64>().ok()?, b.parse::<f64>().ok()?)));
    let Some((a, b)) = named else {
        panic!("no interval in {msg}");
    };
    assert!((a - 60.0).abs() <= 1.5 && (b - 70.0).abs() <= 1.5, "{msg}");
    assert!(msg.contains("longest_static"), "{msg}");

    let id = s
        .job(json!({"kind": "imu_noise", "dataset": ds, "params": {"motion": "longest_static"}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let (_, doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    let sa = &doc["parameters"]["static_analysis"];
    assert_eq!(sa["moving_intervals_s"].as_array().map(Vec::len), Some(1));
    let used: Vec<f64> = serde_json::from_value(sa["used_interval_s"].clone()).expect("interval");
    // The stretch after the turn (70–240 s) is the longest.
    assert!(
        used[0] >= 70.0 && used[0] <= 73.0 && used[1] > 238.0,
        "{used:?}"
    );
    let gn = doc["parameters"]["kalibr"]["gyroscope_noise_density"]
        .as_f64()
        .expect("gyro N");
    assert!((gn / GYRO_N - 1.0).abs() < 0.06, "gyro N {gn} vs {GYRO_N}");
    // Unknown policies are refused before queueing.
    let (st, p) = s
        .post_json(
            "/v1/jobs",
            &json!({"kind": "imu_noise", "dataset": ds, "params": {"motion": "hope"}}),
        )
        .await;
    assert_eq!(st, 422, "{p}");
    s.stop().await;
}
