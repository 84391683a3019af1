//! Tests of the motion check of `imu_noise`: synthetic static logs with realistic noise (white
//! noise, flicker bias instability, random walk, turn-on bias, thermal drift) must pass; logs
//! that rotate, vibrate or accelerate part of the time must be refused with the right
//! intervals, or analysed on their longest static stretch.

use std::fmt::Write as _;

use super::allan::{ImuNoiseParams, imu_noise};
use super::log::{ImuCsvParams, read_imu_log};
use super::motion::{MotionPolicy, detect_motion};
use super::tests::{HEADER, Rng};
use crate::error::CoreError;
use crate::progress::NoProgress;

/// Per-axis noise of the shared static log's truth (gyro x y z, accel x y z).
const N: [f64; 6] = [1.7e-4, 2.0e-4, 1.4e-4, 2.0e-3, 2.4e-3, 1.8e-3];
const B: [f64; 6] = [3e-5, 4e-5, 2.5e-5, 2.5e-4, 3e-4, 2e-4];
const K: [f64; 6] = [1.2e-6, 1.5e-6, 1.0e-6, 1e-5, 1.5e-5, 1.2e-5];
const TURN_ON: [f64; 6] = [0.01, -0.005, 0.003, 0.05, -0.08, 0.1];

/// A movement: rotation rate `peak` (rad/s, per axis) with a sin² profile over `[t0, t1]` s,
/// plus `vib` (rad/s and m/s²) of 37 Hz vibration and `lin` m/s² of linear acceleration along x.
#[derive(Clone, Copy, Default)]
struct Move {
    t0: f64,
    t1: f64,
    peak: [f64; 3],
    vib: f64,
    lin: f64,
}

/// A log at `rate` Hz for `secs` s, z up, with the noise above, a thermal drift of `drift`
/// (rad/s and 10 × that in m/s² over the log) and the given movements. Gravity is rotated into
/// the body frame by integrating the rate (dg/dt = −ω × g).
fn log_csv(rate: f64, secs: f64, drift: f64, moves: &[Move], seed: u64) -> String {
    let mut rng = Rng::new(seed);
    let n = (rate * secs) as usize;
    let dt = 1.0 / rate;
    // Flicker: Gauss-Markov processes with time constants spread over decades, equal variance.
    let tcs = [0.5, 5.0, 50.0, 500.0];
    let mut gm = [[0.0f64; 4]; 6];
    let mut rw = [0.0f64; 6];
    let mut g = [0.0, 0.0, 9.80665];
    let mut s = String::with_capacity(n * 120);
    s.push_str(HEADER);
    s.push('\n');
    for i in 0..n {
        let t = i as f64 * dt;
        let mut w = [0.0f64; 3];
        let mut extra = [0.0f64; 6];
        for m in moves.iter().filter(|m| t >= m.t0 && t <= m.t1) {
            let ph = (std::f64::consts::PI * (t - m.t0) / (m.t1 - m.t0)).sin();
            for (wc, p) in w.iter_mut().zip(m.peak) {
                *wc += p * ph * ph;
            }
            let v = (2.0 * std::f64::consts::PI * 37.0 * t).sin();
            for (c, e) in extra.iter_mut().enumerate() {
                *e += m.vib * v * if c < 3 { 1.0 } else { 10.0 };
            }
            extra[3] += m.lin * ph;
        }
        let cross = [
            w[1] * g[2] - w[2] * g[1],
            w[2] * g[0] - w[0] * g[2],
            w[0] * g[1] - w[1] * g[0],
        ];
        for c in 0..3 {
            g[c] -= cross[c] * dt;
        }
        let norm = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        for v in &mut g {
            *v *= 9.80665 / norm;
        }
        let _ = write!(s, "{}", 1_000_000_000i64 + (t * 1e9).round() as i64);
        for c in 0..6 {
            rw[c] += K[c] * dt.sqrt() * rng.normal();
            let mut flick = 0.0;
            for (j, tc) in tcs.iter().enumerate() {
                let a = (-dt / tc).exp();
                gm[c][j] = a * gm[c][j] + B[c] * (1.0 - a * a).sqrt() * rng.normal();
                flick += gm[c][j] / 2.0;
            }
            let truth = if c < 3 { w[c] } else { g[c - 3] };
            let thermal = drift * (t / secs) * if c < 3 { 1.0 } else { 10.0 };
            let v = truth
                + TURN_ON[c]
                + N[c] / dt.sqrt() * rng.normal()
                + flick
                + rw[c]
                + thermal
                + extra[c];
            let _ = write!(s, ",{v:.9e}");
        }
        s.push('\n');
    }
    s
}

fn scan(csv: &str, rate: f64) -> super::motion::MotionScan {
    let log = read_imu_log(csv.as_bytes(), &ImuCsvParams::default(), &NoProgress).expect("parse");
    detect_motion(&log, rate as usize, 3.0, &NoProgress)
        .expect("scan")
        .expect("enough windows")
}

fn secs(r: (usize, usize), rate: f64) -> (f64, f64) {
    (r.0 as f64 / rate, r.1 as f64 / rate)
}

#[test]
fn realistic_static_logs_are_not_flagged() {
    // Two rates, several seeds, with and without a strong thermal drift (0.02 rad/s and
    // 0.2 m/s² over the log: far more than the noise σ per sample).
    for (rate, len, drift, seed) in [
        (200.0, 300.0, 0.0, 1),
        (200.0, 300.0, 0.02, 2),
        (100.0, 900.0, 0.02, 3),
        (400.0, 120.0, 0.005, 4),
        (100.0, 600.0, 0.0, 5),
    ] {
        let csv = log_csv(rate, len, drift, &[], seed);
        let sc = scan(&csv, rate);
        let flagged = sc.moving.iter().filter(|&&m| m).count();
        assert_eq!(flagged, 0, "rate {rate} seed {seed}: {:?}", sc.moving_runs);
        assert_eq!(sc.static_runs.len(), 1);
        // The floor is the white noise σ per sample (N √rate), within the sampling scatter and
        // the small flicker share.
        let want = N[0] * rate.sqrt();
        assert!(
            (sc.gyro_floor[0] / want - 1.0).abs() < 0.1,
            "floor {} vs {want}",
            sc.gyro_floor[0]
        );
        // And imu_noise runs with the default policy (refuse).
        let r = imu_noise(csv.as_bytes(), &ImuNoiseParams::default(), &NoProgress)
            .expect("a static log passes");
        assert!(r.static_analysis.checked);
        assert!(r.static_analysis.moving_intervals_s.is_empty());
        assert_eq!(r.samples, (rate * len) as usize);
    }
}

#[test]
fn rotation_in_the_middle_is_refused_with_its_interval() {
    let rate = 200.0;
    // A 90° turn about x (peak 0.3 rad/s over ~10.5 s: ∫ sin² = half the peak × length).
    let mv = Move {
        t0: 120.3,
        t1: 130.8,
        peak: [0.3, 0.0, 0.0],
        ..Default::default()
    };
    let csv = log_csv(rate, 300.0, 0.005, &[mv], 7);
    let sc = scan(&csv, rate);
    assert_eq!(sc.moving_runs.len(), 1, "{:?}", sc.moving_runs);
    let (a, b) = secs(sc.moving_runs[0], rate);
    // Within one window (1 s) of the truth at both ends.
    assert!(
        (a - mv.t0).abs() <= 1.0 && (b - mv.t1).abs() <= 1.0,
        "{a}–{b}"
    );
    let err = imu_noise(csv.as_bytes(), &ImuNoiseParams::default(), &NoProgress)
        .expect_err("a moving log is refused");
    let CoreError::InvalidInput(msg) = err else {
        panic!("not invalid_input: {err}");
    };
    assert!(msg.contains(&format!("{a:.1}–{b:.1} s")), "{msg}");
    assert!(msg.contains("longest_static"), "{msg}");
}

#[test]
fn slow_steady_rotation_vibration_and_linear_acceleration_are_caught() {
    let rate = 100.0;
    let moves = [
        // A slow turn (peak 1.1 °/s over 20 s): hardly any extra spread inside a window, only
        // the mean moves (criterion 2).
        Move {
            t0: 60.0,
            t1: 80.0,
            peak: [0.0, 0.0, 0.02],
            ..Default::default()
        },
        // Vibration only (criterion 1).
        Move {
            t0: 150.0,
            t1: 155.0,
            vib: 0.01,
            ..Default::default()
        },
        // A push along x, no rotation: only the accelerometer sees it (‖a‖ hardly: x ⊥ g).
        Move {
            t0: 220.0,
            t1: 224.0,
            lin: 0.5,
            ..Default::default()
        },
    ];
    let csv = log_csv(rate, 300.0, 0.0, &moves, 8);
    let sc = scan(&csv, rate);
    for m in &moves {
        let hit = sc.moving_runs.iter().any(|&r| {
            let (a, b) = secs(r, rate);
            a < m.t1 && b > m.t0
        });
        assert!(hit, "{}–{} s not flagged: {:?}", m.t0, m.t1, sc.moving_runs);
    }
    // Nothing far from the movements.
    for &r in &sc.moving_runs {
        let (a, b) = secs(r, rate);
        assert!(
            moves.iter().any(|m| a < m.t1 + 2.0 && b > m.t0 - 2.0),
            "spurious {a}–{b}"
        );
    }
}

#[test]
fn a_log_that_moves_all_the_time_is_refused() {
    // A flight-like log: continuous rotations about all axes (no static window at all), so the
    // median floor is the motion itself; the low-frequency test must still see it.
    let rate = 200.0;
    let moves: Vec<Move> = (0..60)
        .map(|i| Move {
            t0: i as f64 * 3.0,
            t1: i as f64 * 3.0 + 3.5,
            peak: [
                0.8 * ((i % 3) as f64 - 1.0),
                0.5 * ((i % 5) as f64 - 2.0),
                0.3,
            ],
            vib: 0.005,
            lin: 1.0,
        })
        .collect();
    let csv = log_csv(rate, 180.0, 0.0, &moves, 9);
    let sc = scan(&csv, rate);
    let share = sc.moving.iter().filter(|&&m| m).count() as f64 / sc.moving.len() as f64;
    assert!(share > 0.3, "only {:.0} % flagged", 100.0 * share);
    let err = imu_noise(csv.as_bytes(), &ImuNoiseParams::default(), &NoProgress);
    assert!(matches!(err, Err(CoreError::InvalidInput(_))));
}

#[test]
fn longest_static_analyses_the_right_stretch_and_recovers_n() {
    let rate = 200.0;
    let moves = [
        Move {
            t0: 40.0,
            t1: 52.0,
            peak: [0.0, 0.4, 0.1],
            ..Default::default()
        },
        Move {
            t0: 250.0,
            t1: 256.0,
            peak: [0.2, 0.0, -0.3],
            vib: 0.003,
            ..Default::default()
        },
    ];
    let csv = log_csv(rate, 330.0, 0.005, &moves, 10);
    let params = ImuNoiseParams {
        motion: MotionPolicy::LongestStatic,
        ..Default::default()
    };
    let r = imu_noise(csv.as_bytes(), &params, &NoProgress).expect("longest static stretch");
    let sa = &r.static_analysis;
    assert_eq!(
        sa.moving_intervals_s.len(),
        2,
        "{:?}",
        sa.moving_intervals_s
    );
    let [a, b] = sa.used_interval_s;
    // 52–250 s minus up to one guard window (plus the window the movement ends in) per side.
    assert!(
        (52.0..=54.0).contains(&a) && (248.0..=250.0).contains(&b),
        "{a}–{b}"
    );
    assert_eq!(r.samples, sa.used_samples);
    assert!((r.duration_s - (b - a)).abs() < 0.01);
    assert!(r.warnings.iter().any(|w| w.contains("longest static")));
    // The white-noise density on the ~196 s stretch: within 5 % of the truth on every axis.
    for (ax, n) in r.axes.iter().zip(N) {
        let est = ax.fit.n.expect("N");
        assert!(
            (est / n - 1.0).abs() < 0.05,
            "{} {}: {est} vs {n}",
            ax.sensor,
            ax.axis
        );
    }
    // The same log analysed whole (ignore) gets a gyro N far from the truth: the check matters.
    let whole = ImuNoiseParams {
        motion: MotionPolicy::Ignore,
        ..Default::default()
    };
    let r = imu_noise(csv.as_bytes(), &whole, &NoProgress).expect("ignore");
    assert_eq!(r.samples, (330.0 * rate) as usize);
    assert!(r.warnings.iter().any(|w| w.contains("moves")));
    let worst = r.axes[..3]
        .iter()
        .zip(N)
        .map(|(ax, n)| ax.fit.n.map_or(f64::INFINITY, |e| (e / n - 1.0).abs()))
        .fold(0.0f64, f64::max);
    assert!(worst > 0.05, "motion should spoil the whole-log fit");
}

#[test]
fn motion_params_are_validated() {
    for (w, k) in [
        (0.0, 3.0),
        (f64::NAN, 3.0),
        (1.0, 1.0),
        (1.0, f64::INFINITY),
    ] {
        let p = ImuNoiseParams {
            motion_window_s: w,
            motion_k: k,
            ..Default::default()
        };
        assert!(matches!(p.validate(), Err(CoreError::InvalidParam { .. })));
    }
    let p: ImuNoiseParams =
        serde_json::from_str(r#"{"motion": "longest_static"}"#).expect("deserialises");
    assert_eq!(p.motion, MotionPolicy::LongestStatic);
    assert!(serde_json::from_str::<ImuNoiseParams>(r#"{"motion": "maybe"}"#).is_err());
}

// ------------------------------------------------------------------ shared sample data

#[test]
fn shared_logs_static_pass_multipos_refused() {
    let open = |name: &str| {
        crate::test_env::shared_data(&format!("imu/{name}.csv"))
            .and_then(|p| std::fs::File::open(p).ok())
            .map(std::io::BufReader::new)
    };
    for name in ["static_5min_200hz", "thermal_50hz"] {
        let Some(f) = open(name) else { return };
        let r = imu_noise(f, &ImuNoiseParams::default(), &NoProgress);
        let r = r.unwrap_or_else(|e| panic!("{name}: {e}"));
        println!(
            "{name}: {} windows, none moving, gyro floor {:?}",
            r.static_analysis.windows, r.static_analysis.gyro_std_floor
        );
        assert!(r.static_analysis.moving_intervals_s.is_empty());
    }
    let Some(f) = open("multipos_100hz") else {
        return;
    };
    let err = imu_noise(f, &ImuNoiseParams::default(), &NoProgress);
    let Err(CoreError::InvalidInput(msg)) = err else {
        panic!("multipos accepted: {err:?}");
    };
    println!("multipos_100hz: {msg}");
    // Truth: the first rest ends at sample 4999 (50 s): the first motion starts there.
    assert!(
        msg.contains("moving 49.") || msg.contains("moving 50."),
        "{msg}"
    );
}
