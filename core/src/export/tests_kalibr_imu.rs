//! Tests of the public YAML number formatter ([`super::yaml_number`]) and of Kalibr's
//! `imu.yaml` writer ([`super::kalibr_imu_yaml`]).

use super::{KalibrImuValues, kalibr_imu_yaml, yaml_number};
use crate::error::CoreError;

/// YAML 1.1's float pattern for finite values, as PyYAML's resolver applies it:
/// `[-+]?[0-9][0-9_]*\.[0-9_]*([eE][-+][0-9]+)?` (the `.5` and sexagesimal forms left out,
/// since the formatter never writes them).
fn yaml11_float(s: &str) -> bool {
    let b = s.strip_prefix(['-', '+']).unwrap_or(s).as_bytes();
    // Digits (and `_` where the pattern allows it) from `*i`; returns how many.
    let digits = |b: &[u8], i: &mut usize, underscore: bool| {
        let start = *i;
        while *i < b.len() && (b[*i].is_ascii_digit() || (underscore && b[*i] == b'_')) {
            *i += 1;
        }
        *i - start
    };
    let mut i = 0;
    if b.first().is_none_or(|c| !c.is_ascii_digit()) {
        return false;
    }
    digits(b, &mut i, true);
    if b.get(i) != Some(&b'.') {
        return false;
    }
    i += 1;
    digits(b, &mut i, true);
    if i == b.len() {
        return true;
    }
    if !matches!(b[i], b'e' | b'E') || !matches!(b.get(i + 1), Some(b'-' | b'+')) {
        return false;
    }
    i += 2;
    digits(b, &mut i, false) > 0 && i == b.len()
}

/// OpenCV `FileStorage` (YAML) reads a plain scalar as a real when its leading digits (after an
/// optional sign) are followed by `.` or `e`.
fn opencv_real(s: &str) -> bool {
    let b = s.strip_prefix(['-', '+']).unwrap_or(s).as_bytes();
    let n = b.iter().take_while(|c| c.is_ascii_digit()).count();
    n > 0 && matches!(b.get(n), Some(b'.' | b'e'))
}

#[test]
fn yaml_number_is_a_float_everywhere_and_round_trips() {
    let cases: [(f64, Option<&str>); 22] = [
        (1e-3, Some("1.0e-03")),
        (2e-3, Some("2.0e-03")),
        (1e20, Some("1.0e+20")),
        (0.0, Some("0.0")),
        (-0.0, Some("-0.0")),
        (1.0, Some("1.0")),
        (123456789.0, Some("123456789.0")),
        (5e-324, Some("5.0e-324")),
        (200.0, Some("200.0")),
        (0.025, Some("2.5e-02")),
        (-2.5e-7, Some("-2.5e-07")),
        (1e15, Some("1.0e+15")),
        (999_999_999_999_999.0, Some("999999999999999.0")),
        (1.5, Some("1.5e+00")),
        (0.1 + 0.2, Some("3.0000000000000004e-01")),
        (f64::MIN_POSITIVE, None),
        (f64::MAX, None),
        (-f64::MAX, None),
        (f64::EPSILON, None),
        (1e-300, None),
        (1.5e300, None),
        (std::f64::consts::PI, None),
    ];
    for (v, want) in cases {
        let s = yaml_number(v);
        if let Some(w) = want {
            assert_eq!(s, w, "{v:e}");
        }
        assert!(yaml11_float(&s), "{s} is not a YAML 1.1 float");
        assert!(opencv_real(&s), "{s} is not an OpenCV real");
        let back: f64 = s.parse().expect("parses");
        assert_eq!(back.to_bits(), v.to_bits(), "{s}");
    }
    // Non-finite values in YAML 1.1 spelling.
    assert_eq!(yaml_number(f64::NAN), ".nan");
    assert_eq!(yaml_number(f64::INFINITY), ".inf");
    assert_eq!(yaml_number(f64::NEG_INFINITY), "-.inf");
    // The forms PyYAML would not type as floats are what the pattern check must catch.
    for not_float in ["2e-3", "1e-05", "640", "1.0e5", ".5e+1x"] {
        assert!(!yaml11_float(not_float), "{not_float}");
    }
}

#[test]
fn yaml_number_over_many_magnitudes() {
    // Every power of ten, its neighbours and a few mantissas: a float for every reader, and the
    // same bits back.
    for e in -324..=308 {
        for m in [
            1.0,
            2.0,
            2.5,
            9.999_999_999_999_999,
            1.234_567_890_123_456_7,
        ] {
            let v = m * 10f64.powi(e);
            if !v.is_finite() {
                continue;
            }
            for x in [v, -v, f64::from_bits(v.to_bits() + 1)] {
                let s = yaml_number(x);
                assert!(yaml11_float(&s) && opencv_real(&s), "{s}");
                let back: f64 = s.parse().expect("parses");
                assert_eq!(back.to_bits(), x.to_bits(), "{s}");
            }
        }
    }
}

fn values() -> KalibrImuValues {
    KalibrImuValues {
        accelerometer_noise_density: 2e-3,
        accelerometer_random_walk: Some(3e-5),
        accelerometer_random_walk_upper_bound: Some(4e-5),
        gyroscope_noise_density: 1.7e-4,
        gyroscope_random_walk: Some(2e-6),
        gyroscope_random_walk_upper_bound: None,
        update_rate: 200.0,
        rostopic: "/imu0".to_string(),
    }
}

#[test]
fn kalibr_imu_yaml_writes_every_field_as_a_float() {
    let text = kalibr_imu_yaml(&values()).expect("writes");
    assert_eq!(
        text,
        "# Kalibr imu.yaml written by Caliper from an imu_noise document\n\
         accelerometer_noise_density: 2.0e-03\n\
         accelerometer_random_walk: 3.0e-05\n\
         gyroscope_noise_density: 1.7e-04\n\
         gyroscope_random_walk: 2.0e-06\n\
         rostopic: /imu0\n\
         update_rate: 200.0\n"
    );
}

#[test]
fn kalibr_imu_yaml_upper_bounds_and_refusals() {
    let mut v = values();
    v.accelerometer_random_walk = None;
    let text = kalibr_imu_yaml(&v).expect("writes");
    assert!(
        text.contains(
            "\naccelerometer_random_walk: 4.0e-05  # upper bound: the log is too short to \
             determine it\n"
        ),
        "{text}"
    );

    v.gyroscope_random_walk = None;
    match kalibr_imu_yaml(&v) {
        Err(CoreError::InvalidInput(m)) => assert_eq!(
            m,
            "gyroscope_random_walk could not be determined from this log; no Kalibr file can \
             be written"
        ),
        other => panic!("{other:?}"),
    }

    let mut v = values();
    v.gyroscope_noise_density = f64::NAN;
    assert!(matches!(
        kalibr_imu_yaml(&v),
        Err(CoreError::InvalidInput(m)) if m.contains("gyroscope_noise_density")
    ));

    let mut v = values();
    v.rostopic = String::new();
    assert!(matches!(
        kalibr_imu_yaml(&v),
        Err(CoreError::InvalidParam { field, .. }) if field == "rostopic"
    ));
    v.rostopic = "imu: 0".to_string();
    let text = kalibr_imu_yaml(&v).expect("writes");
    assert!(text.contains("\nrostopic: \"imu: 0\"\n"), "{text}");
}

/// Loads `text` with PyYAML's `safe_load` and returns `{key: [type name, value]}` as JSON, or
/// None (with a notice) when python3 or PyYAML is missing.
fn pyyaml_types(text: &str) -> Option<serde_json::Value> {
    use std::io::Write as _;
    use std::process::{Command, Stdio};
    const SCRIPT: &str = "import json, sys, yaml\n\
        doc = yaml.safe_load(sys.stdin)\n\
        print(json.dumps({k: [type(v).__name__, v] for k, v in doc.items()}))\n";
    let py = crate::test_env::python("yaml")?;
    let child = Command::new(py)
        .args(["-c", SCRIPT])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn();
    let Ok(mut child) = child else {
        eprintln!("\n*** SKIPPED: no python3 ***\n");
        return None;
    };
    child
        .stdin
        .take()
        .expect("stdin")
        .write_all(text.as_bytes())
        .expect("written");
    let out = child.wait_with_output().expect("python3 ran");
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        if err.contains("No module named 'yaml'") {
            eprintln!("\n*** SKIPPED: python3 has no PyYAML ***\n");
            return None;
        }
        panic!("PyYAML failed: {err}");
    }
    Some(serde_json::from_slice(&out.stdout).expect("json"))
}

#[test]
fn pyyaml_reads_yaml_number_and_imu_yaml_as_floats() {
    let numbers = [
        1e-3,
        2e-3,
        1e20,
        0.0,
        -0.0,
        1.0,
        123456789.0,
        5e-324,
        f64::MIN_POSITIVE,
        f64::MAX,
        -2.5e-7,
        1e15,
        0.1 + 0.2,
    ];
    let text: String = numbers
        .iter()
        .enumerate()
        .map(|(i, v)| format!("v{i}: {}\n", yaml_number(*v)))
        .collect();
    let Some(doc) = pyyaml_types(&text) else {
        return;
    };
    for (i, v) in numbers.iter().enumerate() {
        let got = &doc[format!("v{i}")];
        assert_eq!(got[0], "float", "{text}");
        assert_eq!(
            got[1].as_f64().map(f64::to_bits),
            Some(v.to_bits()),
            "{text}"
        );
    }

    let mut v = values();
    v.accelerometer_random_walk = None;
    let text = kalibr_imu_yaml(&v).expect("writes");
    let Some(doc) = pyyaml_types(&text) else {
        return;
    };
    for key in [
        "accelerometer_noise_density",
        "accelerometer_random_walk",
        "gyroscope_noise_density",
        "gyroscope_random_walk",
        "update_rate",
    ] {
        assert_eq!(doc[key][0], "float", "{key}: {text}");
    }
    assert_eq!(doc["accelerometer_random_walk"][1].as_f64(), Some(4e-5));
    assert_eq!(doc["rostopic"], serde_json::json!(["str", "/imu0"]));
}
