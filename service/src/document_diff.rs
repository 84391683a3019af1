//! Comparing two revisions of a document: the estimated values side by side, and each change
//! in units of its standard deviation where the document carries one.
//!
//! A document is a tree; what a calibration engineer compares are its named estimates
//! (`{"name": "fx", "value": 501.2, "std_dev": 0.4}`), its scalar fields (`rms`, `sigma`,
//! noise densities) and short vectors (distortion coefficients, a translation). Long arrays —
//! per-corner residuals, per-image lists — are left out: a diff of ten thousand residuals says
//! nothing a person can read, and the per-view plots show them better.

use serde::{Deserialize, Serialize};
use serde_json::Value;
use utoipa::ToSchema;

/// Arrays longer than this (of numbers or strings) are left out of a diff.
const MAX_VECTOR: usize = 16;
/// At most this many entries are compared (documents are bounded, but be safe).
const MAX_ENTRIES: usize = 2000;

/// One compared value.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct DiffEntry {
    /// Where the value lives, e.g. `parameters.calibration.parameters[fx]` or
    /// `quality.rms`; `[name]` selects a named estimate, `[3]` an index.
    pub path: String,
    /// The value in the older revision (absent when only the newer one has it).
    #[schema(value_type = Option<Object>)]
    pub from: Option<Value>,
    /// The value in the newer revision (absent when only the older one has it).
    #[schema(value_type = Option<Object>)]
    pub to: Option<Value>,
    /// `to − from` for numbers.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub delta: Option<f64>,
    /// Combined standard deviation √(σ_from² + σ_to²), where both revisions give one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sigma: Option<f64>,
    /// `delta / sigma`: how many standard deviations the value moved.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub delta_sigma: Option<f64>,
    /// Whether the values differ.
    pub changed: bool,
}

/// A value found in one document, with its σ if the document states one.
#[derive(Debug, Clone)]
struct Leaf {
    value: Value,
    sigma: Option<f64>,
}

/// Compare the `quality` and `parameters` of two documents.
pub fn diff(from: &Value, to: &Value) -> Vec<DiffEntry> {
    let a = leaves(from);
    let b = leaves(to);
    // Paths are looked up by map, not by scanning: documents can have thousands of leaves.
    let in_a: std::collections::HashSet<&str> = a.iter().map(|(p, _)| p.as_str()).collect();
    let in_b: std::collections::HashMap<&str, &Leaf> =
        b.iter().map(|(p, l)| (p.as_str(), l)).collect();
    let mut out = Vec::new();
    // Keep the older document's order, then what only the newer one has.
    for (path, la) in &a {
        out.push(entry(path, Some(la), in_b.get(path.as_str()).copied()));
    }
    for (path, lb) in &b {
        if !in_a.contains(path.as_str()) {
            out.push(entry(path, None, Some(lb)));
        }
    }
    out.truncate(MAX_ENTRIES);
    out
}

fn entry(path: &str, a: Option<&Leaf>, b: Option<&Leaf>) -> DiffEntry {
    let (mut delta, mut sigma, mut delta_sigma) = (None, None, None);
    if let (Some(x), Some(y)) = (
        a.and_then(|l| l.value.as_f64()),
        b.and_then(|l| l.value.as_f64()),
    ) {
        let d = y - x;
        delta = Some(d);
        if let (Some(sa), Some(sb)) = (a.and_then(|l| l.sigma), b.and_then(|l| l.sigma)) {
            let s = sa.hypot(sb);
            sigma = Some(s);
            if s > 0.0 {
                delta_sigma = Some(d / s);
            }
        }
    }
    let changed = match (a, b) {
        (Some(x), Some(y)) => match (x.value.as_f64(), y.value.as_f64()) {
            (Some(p), Some(q)) => p != q,
            _ => x.value != y.value,
        },
        _ => true,
    };
    DiffEntry {
        path: path.to_owned(),
        from: a.map(|l| l.value.clone()),
        to: b.map(|l| l.value.clone()),
        delta,
        sigma,
        delta_sigma,
        changed,
    }
}

fn leaves(doc: &Value) -> Vec<(String, Leaf)> {
    let mut out = Vec::new();
    for key in ["quality", "parameters"] {
        if let Some(v) = doc.get(key) {
            walk(key, v, &mut out);
        }
    }
    out
}

fn walk(path: &str, v: &Value, out: &mut Vec<(String, Leaf)>) {
    if out.len() >= MAX_ENTRIES {
        return;
    }
    match v {
        Value::Object(map) => {
            for (k, x) in map {
                // `foo_std` / `foo_sigma` next to `foo` are its σ, not values of their own.
                if (k.ends_with("_std") || k.ends_with("_sigma")) && sigma_target(map, k).is_some()
                {
                    continue;
                }
                let p = format!("{path}.{k}");
                match x {
                    Value::Number(_) => out.push((
                        p,
                        Leaf {
                            value: x.clone(),
                            sigma: sibling_sigma(map, k),
                        },
                    )),
                    _ => walk(&p, x, out),
                }
            }
        }
        Value::Array(items) => {
            if let Some(estimates) = named_estimates(items) {
                for (name, value, sigma) in estimates {
                    out.push((format!("{path}[{name}]"), Leaf { value, sigma }));
                }
            } else if items.len() <= MAX_VECTOR && items.iter().all(is_scalar) {
                for (i, x) in items.iter().enumerate() {
                    out.push((
                        format!("{path}[{i}]"),
                        Leaf {
                            value: x.clone(),
                            sigma: None,
                        },
                    ));
                }
            }
        }
        Value::Null => {}
        other => out.push((
            path.to_owned(),
            Leaf {
                value: other.clone(),
                sigma: None,
            },
        )),
    }
}

fn is_scalar(v: &Value) -> bool {
    matches!(v, Value::Number(_) | Value::String(_) | Value::Bool(_))
}

/// `[{"name", "value", "std_dev"?}, …]`: the shape of Caliper's parameter estimates.
fn named_estimates(items: &[Value]) -> Option<Vec<(String, Value, Option<f64>)>> {
    if items.is_empty() {
        return None;
    }
    items
        .iter()
        .map(|x| {
            let name = x.get("name")?.as_str()?;
            let value = x.get("value").filter(|v| v.is_number())?;
            let sigma = x.get("std_dev").and_then(Value::as_f64);
            Some((name.to_owned(), value.clone(), sigma))
        })
        .collect()
}

fn sigma_target<'a>(map: &'a serde_json::Map<String, Value>, key: &str) -> Option<&'a Value> {
    let base = key
        .strip_suffix("_std")
        .or_else(|| key.strip_suffix("_sigma"))?;
    map.get(base).filter(|v| v.is_number())
}

fn sibling_sigma(map: &serde_json::Map<String, Value>, key: &str) -> Option<f64> {
    ["_std", "_sigma"]
        .iter()
        .find_map(|s| map.get(&format!("{key}{s}")).and_then(Value::as_f64))
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn named_estimates_change_in_sigma_units() {
        let a = json!({"quality": {"rms": 0.2}, "parameters": {"calibration": {"parameters": [
            {"name": "fx", "value": 500.0, "std_dev": 0.3},
            {"name": "fy", "value": 501.0, "std_dev": 0.4}]}}});
        let b = json!({"quality": {"rms": 0.25}, "parameters": {"calibration": {"parameters": [
            {"name": "fx", "value": 502.0, "std_dev": 0.4},
            {"name": "fy", "value": 501.0, "std_dev": 0.4}]}}});
        let d = diff(&a, &b);
        let fx = d
            .iter()
            .find(|e| e.path == "parameters.calibration.parameters[fx]")
            .expect("fx compared");
        assert_eq!(fx.delta, Some(2.0));
        assert!((fx.sigma.expect("σ") - 0.5).abs() < 1e-12);
        assert!((fx.delta_sigma.expect("Δσ") - 4.0).abs() < 1e-12);
        assert!(fx.changed);
        let fy = d
            .iter()
            .find(|e| e.path.ends_with("[fy]"))
            .expect("fy compared");
        assert!(!fy.changed);
        let rms = d
            .iter()
            .find(|e| e.path == "quality.rms")
            .expect("rms compared");
        assert!(rms.changed && rms.sigma.is_none());
    }

    #[test]
    fn long_arrays_are_left_out_and_missing_values_reported() {
        let long: Vec<f64> = (0..100).map(f64::from).collect();
        let a = json!({"parameters": {"residuals": long, "k": [1.0, 2.0], "model": "pinhole"}});
        let b = json!({"parameters": {"k": [1.0, 2.5], "model": "fisheye", "extra": 3}});
        let d = diff(&a, &b);
        assert!(d.iter().all(|e| !e.path.contains("residuals")));
        let k1 = d
            .iter()
            .find(|e| e.path == "parameters.k[1]")
            .expect("k[1]");
        assert_eq!(k1.delta, Some(0.5));
        let model = d
            .iter()
            .find(|e| e.path == "parameters.model")
            .expect("model");
        assert!(model.changed && model.delta.is_none());
        let extra = d
            .iter()
            .find(|e| e.path == "parameters.extra")
            .expect("extra");
        assert!(extra.from.is_none() && extra.changed);
    }

    #[test]
    fn sibling_std_is_the_sigma_of_its_value() {
        let a = json!({"quality": {"n": 1.0, "n_std": 0.1}});
        let b = json!({"quality": {"n": 1.3, "n_std": 0.2}});
        let d = diff(&a, &b);
        assert_eq!(d.len(), 1, "{d:?}");
        let s = d[0].sigma.expect("σ");
        assert!((s - 0.05f64.sqrt()).abs() < 1e-12);
    }
}
