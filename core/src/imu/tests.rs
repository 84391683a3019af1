//! Tests of the IMU module: parser edge cases, Allan deviation on generated noise, multi-position
//! and thermal recovery of known parameters, and checks on the shared sample data (over 600
//! lines: one file of tests for the whole module).

use std::fmt::Write as _;

use nalgebra::{Matrix3, Vector3};

use super::allan::{ImuNoiseParams, cluster_sizes, fit_noise, imu_noise, oavar_sums};
use super::log::{AccelUnit, GyroUnit, ImuColumns, ImuCsvParams, TimeUnit, read_imu_log};
use super::multipos::{ImuIntrinsicsParams, imu_intrinsics};
use super::thermal::{ImuThermalParams, imu_thermal};
use super::{allan_svg, thermal_svg};
use crate::error::CoreError;
use crate::lie::So3;
use crate::progress::NoProgress;

/// Deterministic generator: splitmix64 + Box-Muller.
pub(super) struct Rng(u64, Option<f64>);

impl Rng {
    pub(super) fn new(seed: u64) -> Self {
        Self(seed, None)
    }
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub(super) fn normal(&mut self) -> f64 {
        if let Some(v) = self.1.take() {
            return v;
        }
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        let r = (-2.0 * u1.ln()).sqrt();
        self.1 = Some(r * (2.0 * std::f64::consts::PI * u2).sin());
        r * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

pub(super) const HEADER: &str = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],\
                      a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]";

fn csv(rows: &[(i64, [f64; 6])]) -> String {
    let mut s = String::from(HEADER);
    s.push('\n');
    for (t, v) in rows {
        let _ = writeln!(
            s,
            "{t},{},{},{},{},{},{}",
            v[0], v[1], v[2], v[3], v[4], v[5]
        );
    }
    s
}

fn simple_rows(n: usize, dt_ns: i64) -> Vec<(i64, [f64; 6])> {
    (0..n)
        .map(|i| {
            (
                1_700_000_000_000_000_000 + i as i64 * dt_ns,
                [0.01, -0.02, 0.03, 0.1, 0.2, 9.8],
            )
        })
        .collect()
}

fn parse(s: &str) -> crate::error::CoreResult<super::ImuLog> {
    read_imu_log(s.as_bytes(), &ImuCsvParams::default(), &NoProgress)
}

// ------------------------------------------------------------------ parser

#[test]
fn parses_euroc_and_rate() {
    let log = parse(&csv(&simple_rows(1000, 5_000_000))).expect("parse");
    assert_eq!(log.len(), 1000);
    assert!((log.stats.rate_hz - 200.0).abs() < 1e-9);
    assert_eq!(log.stats.column_source, "header");
    assert!((log.value(5, 10) - 9.8).abs() < 1e-6);
    assert!((log.value(0, 999) - 0.01).abs() < 1e-9);
    assert_eq!(log.stats.gaps, 0);
}

#[test]
fn single_pass_line_parser_matches_the_values() {
    let mut rng = Rng::new(1);
    // The single-pass line parser (SWAR digits, one multiplication) against the printed values.
    let mut s = String::from(HEADER);
    s.push('\n');
    let mut want = Vec::new();
    for i in 0..5000i64 {
        let v: Vec<f64> = (0..6)
            .map(|_| rng.normal() * 10f64.powi((rng.uniform() * 6.0) as i32 - 3))
            .collect();
        let _ = writeln!(
            s,
            "{},{},{},{},{:.10},{:e},{}",
            1_234_567_890_123_456_789 + i * 5_000_000,
            v[0],
            v[1],
            v[2],
            v[3],
            v[4],
            v[5]
        );
        want.push(v);
    }
    let log = parse(&s).expect("parse");
    assert_eq!(log.len(), 5000);
    assert_eq!(log.t0_ns(), 1_234_567_890_123_456_789);
    let col_max: Vec<f64> = (0..6)
        .map(|c| want.iter().fold(0.0f64, |m, v| m.max(v[c].abs())))
        .collect();
    for (i, v) in want.iter().enumerate() {
        for c in 0..6 {
            let w = if c == 3 {
                format!("{:.10}", v[c]).parse().unwrap_or(f64::NAN)
            } else {
                v[c]
            };
            assert!(
                // f32 offsets from the reference: ~6e-8 of the column's range.
                (log.value(c, i) - w).abs() <= 2e-7 * (col_max[c] + w.abs()),
                "{i} {c}"
            );
        }
    }
}

#[test]
fn a_spike_in_the_first_sample_does_not_cost_precision() {
    let mut rows = simple_rows(500, 5_000_000);
    rows[0].1[3] = 1.0e6;
    rows[7].1[3] = 0.1 + 1.234_567e-7;
    let log = parse(&csv(&rows)).expect("parse");
    assert!((log.value(3, 0) - 1.0e6).abs() < 0.1);
    assert!((log.value(3, 7) - (0.1 + 1.234_567e-7)).abs() < 1e-12);
}

#[test]
fn scientific_timestamps_are_exact() {
    let s = format!(
        "{HEADER}\n1.700000000000e+18,0,0,0,0,0,9.8\n1.700000000005e18,1e-3,0,0,0,0,9.8\n\
         1.70000000001E+18,0,0,0,0,0,9.8\n"
    );
    let log = parse(&s).expect("parse");
    assert_eq!(log.len(), 3);
    assert_eq!(log.t0_ns(), 1_700_000_000_000_000_000);
    let t = log.times_s();
    assert!((t[1] - 0.005).abs() < 1e-12 && (t[2] - 0.010).abs() < 1e-12);
    assert!((log.value(0, 1) - 1e-3).abs() < 1e-9); // f32 offset storage
}

#[test]
fn junk_blank_nan_duplicates_backwards_and_gaps() {
    let mut s = String::from(HEADER);
    s.push('\n');
    let t0: i64 = 1_000_000_000;
    let dt: i64 = 10_000_000;
    let mut t = t0;
    for i in 0..200 {
        if i == 50 {
            s.push_str("this is junk\n\n");
        }
        if i == 60 {
            let _ = writeln!(s, "{t},nan,0,0,0,0,9.8");
        }
        if i == 70 {
            let _ = writeln!(s, "{},0,0,0,0,0,9.8", t - dt); // duplicate of the previous kept
        }
        if i == 80 {
            let _ = writeln!(s, "{},0,0,0,0,0,9.8", t - 5 * dt); // backwards
        }
        if i == 100 {
            t += 20 * dt; // a gap
        }
        let _ = writeln!(s, "{t},0.001,0,0,0,0,9.8");
        t += dt;
    }
    s.push_str(",,,\n1;2;3\n");
    let log = parse(&s).expect("parse");
    let st = &log.stats;
    assert_eq!(log.len(), 200);
    assert_eq!(st.junk_rows, 3, "{st:?}");
    assert_eq!(st.junk_lines_first[0], 52);
    assert_eq!(st.blank_lines, 1);
    assert_eq!(st.nan_rows, 1);
    assert_eq!(st.duplicate_timestamps, 1);
    assert_eq!(st.backwards_timestamps, 1);
    assert_eq!(st.gaps, 1);
    let g = &st.gaps_first[0];
    assert_eq!(g.sample_index, 100);
    assert!((g.duration_s - 0.21).abs() < 1e-9);
    // Line of sample 100: header (1) + 100 samples + 6 skipped lines before it, 1-based.
    assert_eq!(g.line, Some(1 + 100 + 5 + 1));
    assert!((st.rate_hz - 100.0).abs() < 1e-9);
}

#[test]
fn units_columns_and_delimiters() {
    let s = "time,acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z,Temperature\n\
             0,0,0,1,180,0,0,25.5\n1000000,0,0,1,90,0,0,25.6\n2000000,0,0,1,0,0,0,25.7\n";
    let p = ImuCsvParams {
        gyro_unit: Some(GyroUnit::DegS),
        accel_unit: Some(AccelUnit::G),
        ..Default::default()
    };
    let log = read_imu_log(s.as_bytes(), &p, &NoProgress).expect("parse");
    assert_eq!(log.stats.columns, vec![0, 4, 5, 6, 1, 2, 3]);
    assert!((log.value(0, 0) - std::f64::consts::PI).abs() < 1e-6);
    assert!((log.value(5, 0) - 9.80665).abs() < 1e-5);
    assert_eq!(log.temperature().map(|t| t.len()), Some(3));

    // Explicit columns, seconds, semicolons, no header.
    let s = "0.000;9;0;0;1;0.1;0.2;0.3\n0.010;9;0;0;1;0.1;0.2;0.3\n";
    let p = ImuCsvParams {
        timestamp_unit: TimeUnit::S,
        columns: Some(ImuColumns {
            timestamp: 0,
            gyro: [5, 6, 7],
            accel: [1, 2, 3],
            temperature: Some(4),
        }),
        ..Default::default()
    };
    let log = read_imu_log(s.as_bytes(), &p, &NoProgress).expect("parse");
    assert_eq!(log.len(), 2);
    assert!((log.stats.rate_hz - 100.0).abs() < 1e-6);
    assert!((log.value(1, 1) - 0.2).abs() < 1e-7 && (log.value(3, 0) - 9.0).abs() < 1e-9);
}

#[test]
fn empty_and_unusable_inputs_fail_clearly() {
    for s in ["", "\n\n\n", HEADER, "#timestamp,w_x\n1,2\n"] {
        match parse(s) {
            Err(CoreError::InvalidInput(m)) => assert!(!m.is_empty()),
            other => panic!("{s:?}: expected InvalidInput, got {other:?}"),
        }
    }
    let junk = format!("{HEADER}\nfoo,bar\nbaz\n");
    match parse(&junk) {
        Err(CoreError::InvalidInput(m)) => assert!(m.contains("line 2"), "{m}"),
        other => panic!("expected InvalidInput, got {other:?}"),
    }
    // A forward glitch followed by normal data: most rows go backwards → rejected with a line.
    let mut rows = simple_rows(300, 1_000_000);
    rows[10].0 += 1_000_000_000_000;
    match parse(&csv(&rows)) {
        Err(CoreError::InvalidInput(m)) => {
            assert!(m.contains("backwards") && m.contains("line 13"), "{m}")
        }
        other => panic!("expected InvalidInput, got {other:?}"),
    }
}

#[test]
fn garbage_bytes_never_panic() {
    let mut rng = Rng::new(7);
    for round in 0..200 {
        let len = (rng.next_u64() % 4000) as usize;
        let mut bytes: Vec<u8> = (0..len).map(|_| rng.next_u64() as u8).collect();
        if round % 3 == 0 {
            // Mostly-valid text with random corruption.
            let mut s = csv(&simple_rows(50, 1_000_000)).into_bytes();
            for _ in 0..(rng.next_u64() % 20) {
                let i = (rng.next_u64() as usize) % s.len();
                s[i] = rng.next_u64() as u8;
            }
            bytes = s;
        }
        let _ = read_imu_log(&bytes[..], &ImuCsvParams::default(), &NoProgress);
        let _ = imu_noise(&bytes[..], &ImuNoiseParams::default(), &NoProgress);
    }
    // One over-long line without newline (longer than a batch).
    let long = vec![b'7'; 9 << 20];
    assert!(parse(std::str::from_utf8(&long).unwrap_or("")).is_err());
}

// ------------------------------------------------------------------ Allan

fn static_log(rate: f64, secs: f64, n_dens: [f64; 6], k_rw: [f64; 6], seed: u64) -> String {
    let mut rng = Rng::new(seed);
    let n = (rate * secs) as usize;
    let dt = 1.0 / rate;
    let mut rw = [0.0; 6];
    let mut s = String::with_capacity(n * 90);
    s.push_str(HEADER);
    s.push('\n');
    for i in 0..n {
        let t = 1_000_000_000_000i64 + (i as f64 * dt * 1e9).round() as i64;
        let _ = write!(s, "{t}");
        for c in 0..6 {
            rw[c] += k_rw[c] * dt.sqrt() * rng.normal();
            let v = n_dens[c] / dt.sqrt() * rng.normal() + rw[c] + if c == 5 { 9.81 } else { 0.0 };
            let _ = write!(s, ",{v:.9e}");
        }
        s.push('\n');
    }
    s
}

#[test]
fn white_noise_density_within_a_few_percent() {
    let dens = [1.7e-4, 2.0e-4, 1.4e-4, 2.0e-3, 2.4e-3, 1.8e-3];
    let s = static_log(100.0, 600.0, dens, [0.0; 6], 11);
    let r = imu_noise(s.as_bytes(), &ImuNoiseParams::default(), &NoProgress).expect("noise");
    assert_eq!(r.axes.len(), 6);
    for (a, d) in r.axes.iter().zip(dens) {
        let n = a.fit.n.expect("N determinable");
        assert!(
            (n / d - 1.0).abs() < 0.03,
            "{} {}: N {n} vs {d}",
            a.sensor,
            a.axis
        );
        let c = a.classic.n_at_tau1.expect("classic N");
        assert!((c / d - 1.0).abs() < 0.05, "classic {c} vs {d}");
        // Pure white noise over 10 min: no floor, no rising slope.
        assert!(a.fit.k.is_none() && a.fit.k_reason.is_some());
        assert!(a.fit.b.is_none() && a.fit.b_reason.is_some());
        assert!(a.k_upper_bound.is_some());
    }
    assert!(r.kalibr.gyroscope_random_walk.is_none());
    assert!(r.kalibr.gyroscope_random_walk_upper_bound.is_some());
    let g = r.kalibr.gyroscope_noise_density.expect("gyro N");
    assert!((g / 2.0e-4 - 1.0).abs() < 0.03);
    let svg = allan_svg(&r);
    assert!(svg.contains("<svg") && svg.len() > 2000);
    // Serialises (the job result).
    assert!(serde_json::to_string(&r).is_ok_and(|j| j.contains("caliper.imu_noise/v1")));
}

#[test]
fn short_log_reports_b_and_k_as_not_determinable() {
    let s = static_log(100.0, 20.0, [1e-3; 6], [1e-5; 6], 3);
    let r = imu_noise(s.as_bytes(), &ImuNoiseParams::default(), &NoProgress).expect("noise");
    for a in &r.axes {
        assert!(a.fit.b.is_none(), "{:?}", a.fit);
        assert!(a.fit.k.is_none());
        assert!(
            a.fit
                .k_reason
                .as_deref()
                .is_some_and(|m| m.contains("too short") || m.contains("not visible"))
        );
    }
    // Too short for any fit at all.
    let s = static_log(100.0, 0.2, [1e-3; 6], [0.0; 6], 3);
    let r = imu_noise(s.as_bytes(), &ImuNoiseParams::default(), &NoProgress).expect("noise");
    assert!(
        r.axes
            .iter()
            .all(|a| a.fit.n.is_none() && a.fit.n_reason.is_some())
    );
}

#[test]
fn random_walk_is_recovered_from_a_long_series() {
    // Direct on the engine (no CSV): 10 Hz, 20 h, N = 1e-3, K = 1e-4.
    let (rate, n) = (10.0f64, 720_000usize);
    let mut rng = Rng::new(5);
    let mut rw = 0.0;
    let dt = 1.0 / rate;
    let y: Vec<f32> = (0..n)
        .map(|_| {
            rw += 1e-4 * dt.sqrt() * rng.normal();
            (1e-3 / dt.sqrt() * rng.normal() + rw) as f32
        })
        .collect();
    let ms = cluster_sizes(n, 1);
    let mut x = super::allan::PhaseBuffer::default();
    let sums = oavar_sums(&y, &ms, &mut x, &NoProgress).expect("sums");
    let mut curve: Vec<_> = ms
        .iter()
        .zip(&sums)
        .map(|(&m, &s)| {
            let nt = (n + 1 - 2 * m) as u64;
            super::allan::AdevPoint {
                tau_s: m as f64 / rate,
                m: m as u64,
                adev: (s / (2.0 * (m * m) as f64 * nt as f64)).sqrt(),
                n_terms: nt,
                clusters: nt as f64 / m as f64,
                edf: 1.0,
                ci_low: None,
                ci_high: None,
                octave: true,
                fitted: false,
            }
        })
        .collect();
    let (fit, classic, _) = fit_noise(&mut curve, &ImuNoiseParams::default(), 1.0);
    let nn = fit.n.expect("N");
    assert!((nn / 1e-3 - 1.0).abs() < 0.03, "N {nn}");
    let k = fit.k.expect("K determinable");
    assert!((k / 1e-4 - 1.0).abs() < 0.3, "K {k}");
    assert!(classic.k_at_tau3.is_some());
    assert!(
        curve
            .iter()
            .filter(|p| p.fitted)
            .all(|p| p.ci_low.is_some_and(|l| l < p.adev))
    );
}

#[test]
fn blocked_sums_match_the_direct_formula() {
    let mut rng = Rng::new(8);
    let mut rw = 0.0;
    let y: Vec<f32> = (0..100_003)
        .map(|_| {
            rw += 0.01 * rng.normal();
            (rng.normal() + rw + 3.0) as f32
        })
        .collect();
    for per in [1, 3] {
        let ms = cluster_sizes(y.len(), per);
        let mut buf = super::allan::PhaseBuffer::default();
        let got = oavar_sums(&y, &ms, &mut buf, &NoProgress).expect("sums");
        let mean = y.iter().map(|&v| f64::from(v)).sum::<f64>() / y.len() as f64;
        let mut x = vec![0.0f64];
        for &v in &y {
            let l = x[x.len() - 1];
            x.push(l + f64::from(v) - mean);
        }
        for (k, &m) in ms.iter().enumerate() {
            let want: f64 = (0..x.len() - 2 * m)
                .map(|i| (x[i + 2 * m] - 2.0 * x[i + m] + x[i]).powi(2))
                .sum();
            assert!(
                (got[k] / want - 1.0).abs() < 1e-6,
                "m {m}: {} vs {want}",
                got[k]
            );
        }
    }
}

// ------------------------------------------------------------------ multi-position

fn t_acc(m: [f64; 3]) -> Matrix3<f64> {
    Matrix3::new(1.0, -m[0], m[1], 0.0, 1.0, -m[2], 0.0, 0.0, 1.0)
}
fn t_gyro(m: [f64; 6]) -> Matrix3<f64> {
    Matrix3::new(1.0, -m[0], m[1], m[3], 1.0, -m[2], -m[4], m[5], 1.0)
}

/// imu_tk-style sequence: 50 s rest, then `poses` attitudes joined by smooth fixed-axis
/// rotations; raw = inv(T·diag(s))·true + bias + noise.
fn multipos_csv(poses: usize, seed: u64) -> String {
    let mut rng = Rng::new(seed);
    let rate = 100.0f64;
    let dt = 1.0 / rate;
    let g = 9.80665;
    let ma =
        t_acc([0.004, -0.006, 0.003]) * Matrix3::from_diagonal(&Vector3::new(1.02, 0.985, 1.01));
    let mg = t_gyro([0.008, -0.005, 0.006, -0.004, 0.007, -0.003])
        * Matrix3::from_diagonal(&Vector3::new(0.98, 1.03, 1.01));
    let (ma_inv, mg_inv) = (
        ma.try_inverse().unwrap_or_else(Matrix3::identity),
        mg.try_inverse().unwrap_or_else(Matrix3::identity),
    );
    let (ba, bg) = (
        Vector3::new(0.15, -0.2, 0.3),
        Vector3::new(0.02, -0.015, 0.01),
    );
    let up = Vector3::new(0.0, 0.0, g);
    let mut r = So3::identity(); // body → world
    let mut rows: Vec<(i64, [f64; 6])> = Vec::new();
    let mut push = |w: Vector3<f64>, f: Vector3<f64>, rng: &mut Rng| {
        let wr = mg_inv * w + bg + Vector3::from_fn(|_, _| 1.7e-4 / dt.sqrt() * rng.normal());
        let fr = ma_inv * f + ba + Vector3::from_fn(|_, _| 2.0e-3 / dt.sqrt() * rng.normal());
        let t = 1_000_000_000i64 + rows.len() as i64 * 10_000_000;
        rows.push((t, [wr.x, wr.y, wr.z, fr.x, fr.y, fr.z]));
    };
    for _ in 0..5000 {
        push(Vector3::zeros(), r.inverse().act(&up), &mut rng);
    }
    for _ in 0..poses {
        let axis = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
        let angle = (40.0 + 80.0 * rng.uniform()).to_radians();
        let dur = 1.0 + rng.uniform();
        let k = (dur * rate) as usize;
        for i in 1..=k {
            let t = i as f64 * dt;
            let th = angle
                * (t / dur
                    - (2.0 * std::f64::consts::PI * t / dur).sin() / (2.0 * std::f64::consts::PI));
            let w = axis * (angle / dur * (1.0 - (2.0 * std::f64::consts::PI * t / dur).cos()));
            let ri = r.compose(&So3::exp(&(axis * th)));
            push(w, ri.inverse().act(&up), &mut rng);
        }
        r = r.compose(&So3::exp(&(axis * angle)));
        for _ in 0..(300 + (rng.uniform() * 300.0) as usize) {
            push(Vector3::zeros(), r.inverse().act(&up), &mut rng);
        }
    }
    csv(&rows)
}

#[test]
fn multipos_recovers_scale_misalignment_and_bias() {
    let s = multipos_csv(30, 21);
    let r = imu_intrinsics(s.as_bytes(), &ImuIntrinsicsParams::default(), &NoProgress)
        .expect("intrinsics");
    let a = &r.accel;
    for (e, t) in a.scale.iter().zip([1.02, 0.985, 1.01]) {
        assert!((e - t).abs() < 5e-4, "accel scale {:?}", a.scale);
    }
    for (e, t) in a.misalignment_yz_zy_zx.iter().zip([0.004, -0.006, 0.003]) {
        assert!(
            (e - t).abs() < 5e-4,
            "accel mis {:?}",
            a.misalignment_yz_zy_zx
        );
    }
    for (e, t) in a.bias.iter().zip([0.15, -0.2, 0.3]) {
        assert!((e - t).abs() < 2e-3, "accel bias {:?}", a.bias);
    }
    let gy = r.gyro.as_ref().expect("gyro");
    for (e, t) in gy.scale.iter().zip([0.98, 1.03, 1.01]) {
        assert!((e - t).abs() < 5e-4, "gyro scale {:?}", gy.scale);
    }
    for (e, t) in gy
        .misalignment_yz_zy_zx_xz_xy_yx
        .iter()
        .zip([0.008, -0.005, 0.006, -0.004, 0.007, -0.003])
    {
        assert!(
            (e - t).abs() < 5e-4,
            "gyro mis {:?}",
            gy.misalignment_yz_zy_zx_xz_xy_yx
        );
    }
    for (e, t) in gy.bias.iter().zip([0.02, -0.015, 0.01]) {
        assert!((e - t).abs() < 2e-4, "gyro bias {:?}", gy.bias);
    }
    assert_eq!(r.usable_poses, 31);
    assert!(serde_json::to_string(&r).is_ok());
}

#[test]
fn multipos_with_too_few_poses_fails_clearly() {
    let s = multipos_csv(5, 4);
    match imu_intrinsics(s.as_bytes(), &ImuIntrinsicsParams::default(), &NoProgress) {
        Err(CoreError::NoSolution(m)) => assert!(m.contains("too few static poses"), "{m}"),
        other => panic!(
            "expected NoSolution, got {:?}",
            other.map(|r| r.usable_poses)
        ),
    }
}

// ------------------------------------------------------------------ thermal

#[test]
fn thermal_recovers_a_known_cubic() {
    let mut rng = Rng::new(9);
    let (rate, secs) = (50.0, 1200.0);
    let n = (rate * secs) as usize;
    let coeffs: [[f64; 4]; 6] = [
        [0.010, 2.0e-4, -5.0e-6, 1.0e-7],
        [-0.005, -1.5e-4, 4.0e-6, -5.0e-8],
        [0.003, 1.0e-4, 2.0e-6, 0.0],
        [0.05, 2.0e-3, -4.0e-5, 1.0e-6],
        [-0.08, -1.0e-3, 3.0e-5, 0.0],
        [0.10, 3.0e-3, 5.0e-5, -8.0e-7],
    ];
    let mut s = format!("{HEADER},temperature [degC]\n");
    for i in 0..n {
        let tt = i as f64 / rate;
        let temp = 10.0 + 45.0 * (0.5 * (1.0 - (-tt / 240.0).exp()) + 0.5 * tt / secs);
        let d = temp - 25.0;
        let _ = write!(s, "{}", 1_000_000_000i64 + i as i64 * 20_000_000);
        for (c, k) in coeffs.iter().enumerate() {
            let noise = if c < 3 { 1.7e-4 } else { 2.0e-3 } * rate.sqrt() * rng.normal();
            let v = k[0]
                + k[1] * d
                + k[2] * d * d
                + k[3] * d * d * d
                + noise
                + if c == 5 { 9.80665 } else { 0.0 };
            let _ = write!(s, ",{v:.10e}");
        }
        let _ = writeln!(s, ",{:.4}", temp + 0.02 * rng.normal());
    }
    let r = imu_thermal(s.as_bytes(), &ImuThermalParams::default(), &NoProgress).expect("thermal");
    assert_eq!(r.gravity_removed.as_deref(), Some("+z"));
    for (a, k) in r.axes.iter().zip(coeffs) {
        let tol0 = if a.sensor == "gyro" { 1e-4 } else { 1e-3 };
        assert!(
            (a.coeffs[0] - k[0]).abs() < tol0,
            "{} {} c0 {:?}",
            a.sensor,
            a.axis,
            a.coeffs
        );
        assert!(
            (a.coeffs[1] / k[1] - 1.0).abs() < 0.05,
            "{} {} c1 {:?}",
            a.sensor,
            a.axis,
            a.coeffs
        );
    }
    assert!(r.valid_range_c[0] < 10.2 && r.valid_range_c[1] > 54.0);
    assert!(thermal_svg(&r).contains("<svg"));
    // No temperature column → clear error.
    let s = csv(&simple_rows(100, 1_000_000));
    assert!(matches!(
        imu_thermal(s.as_bytes(), &ImuThermalParams::default(), &NoProgress),
        Err(CoreError::InvalidInput(_))
    ));
}

// ------------------------------------------------------------------ shared sample data

fn shared(name: &str) -> Option<(std::path::PathBuf, serde_json::Value)> {
    let csv = crate::test_env::shared_data(&format!("imu/{name}.csv"))?;
    let truth = crate::test_env::shared_data(&format!("imu/{name}_truth.json"))?;
    let t = std::fs::read_to_string(&truth)
        .ok()
        .and_then(|s| serde_json::from_str(&s).ok())?;
    Some((csv, t))
}

fn open(p: &std::path::Path) -> std::io::BufReader<std::fs::File> {
    std::io::BufReader::new(std::fs::File::open(p).expect("open"))
}

#[test]
fn shared_static_5min() {
    let Some((csv, truth)) = shared("static_5min_200hz") else {
        return;
    };
    let r = imu_noise(open(&csv), &ImuNoiseParams::default(), &NoProgress).expect("noise");
    for a in &r.axes {
        let i = ["x", "y", "z"]
            .iter()
            .position(|x| *x == a.axis)
            .unwrap_or(0);
        let tn = truth["params"][&a.sensor]["noise_density"][i]
            .as_f64()
            .unwrap_or(f64::NAN);
        let n = a.fit.n.unwrap_or(f64::NAN);
        println!(
            "{} {}: N {n:.4e} (truth {tn:.4e}, {:+.2} %), classic {:+.2} %, B {:?} ({:?}), K {:?}",
            a.sensor,
            a.axis,
            100.0 * (n / tn - 1.0),
            100.0 * (a.classic.n_at_tau1.unwrap_or(f64::NAN) / tn - 1.0),
            a.fit.b,
            a.fit.b_reason,
            a.fit.k
        );
        assert!((n / tn - 1.0).abs() < 0.03);
        assert!(a.fit.b.is_none() && a.fit.k.is_none());
    }
    let svg = std::env::temp_dir().join("caliper_allan_static_5min.svg");
    if std::fs::write(&svg, allan_svg(&r)).is_ok() {
        println!("Allan plot: {}", svg.display());
    }
}

#[test]
fn shared_multipos() {
    let Some((csv, truth)) = shared("multipos_100hz") else {
        return;
    };
    let r = imu_intrinsics(open(&csv), &ImuIntrinsicsParams::default(), &NoProgress)
        .expect("intrinsics");
    let f = |v: &serde_json::Value| -> Vec<f64> {
        v.as_array()
            .map(|a| a.iter().filter_map(|x| x.as_f64()).collect())
            .unwrap_or_default()
    };
    let diff = |a: &[f64], b: &[f64]| -> f64 {
        a.iter()
            .zip(b)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
    };
    let (ta, tg) = (&truth["accel"], &truth["gyro"]);
    let a = &r.accel;
    let g = r.gyro.as_ref().expect("gyro");
    let es = diff(&a.scale, &f(&ta["scale"]));
    let em = diff(
        &a.misalignment_yz_zy_zx,
        &f(&ta["mis_yz_zy_zx_xz_xy_yx"])[..3],
    );
    let eb = diff(&a.bias, &f(&ta["bias"]));
    let gs = diff(&g.scale, &f(&tg["scale"]));
    let gm = diff(
        &g.misalignment_yz_zy_zx_xz_xy_yx,
        &f(&tg["mis_yz_zy_zx_xz_xy_yx"]),
    );
    let gb = diff(&g.bias, &f(&tg["bias"]));
    println!(
        "multipos: {} poses (×{} threshold), accel scale {es:.2e} mis {em:.2e} bias {eb:.2e} m/s² \
         (residual rms {:.4}); gyro scale {gs:.2e} mis {gm:.2e} bias {gb:.2e} rad/s (rms {:.2e})",
        r.usable_poses, r.static_detection.threshold_multiplier, a.residual.rms, g.residual.rms
    );
    assert!(es < 5e-4 && em < 5e-4 && eb < 2e-3 && gs < 5e-4 && gm < 5e-4);
}

#[test]
fn shared_thermal() {
    let Some((csv, truth)) = shared("thermal_50hz") else {
        return;
    };
    let r = imu_thermal(open(&csv), &ImuThermalParams::default(), &NoProgress).expect("thermal");
    for a in &r.axes {
        let i = ["x", "y", "z"]
            .iter()
            .position(|x| *x == a.axis)
            .unwrap_or(0);
        let key = if a.sensor == "gyro" {
            "gyro_coeffs"
        } else {
            "accel_coeffs"
        };
        let t: Vec<f64> = (0..4)
            .map(|j| truth["params"][key][i][j].as_f64().unwrap_or(f64::NAN))
            .collect();
        println!(
            "{} {}: c0 {:.5e} (truth {:.5e}, Δ {:.2e}), c1 {:.4e} (truth {:.4e}, {:+.2} %), c2 {:.3e} ({:.3e}), c3 {:.3e} ({:.3e})",
            a.sensor,
            a.axis,
            a.coeffs[0],
            t[0],
            a.coeffs[0] - t[0],
            a.coeffs[1],
            t[1],
            100.0 * (a.coeffs[1] / t[1] - 1.0),
            a.coeffs[2],
            t[2],
            a.coeffs[3],
            t[3]
        );
        assert!((a.coeffs[0] - t[0]).abs() < 1e-3);
        assert!((a.coeffs[1] / t[1] - 1.0).abs() < 0.05);
    }
    println!(
        "valid range {:?} °C, gravity removed {:?}",
        r.valid_range_c, r.gravity_removed
    );
    let svg = std::env::temp_dir().join("caliper_thermal_50hz.svg");
    if std::fs::write(&svg, thermal_svg(&r)).is_ok() {
        println!("thermal plot: {}", svg.display());
    }
}
