//! Parameter documents: canonical JSON, revision and entity tag.
//!
//! A document's `etag` is the SHA-256 of its canonical JSON (object keys sorted, no
//! whitespace) with the `etag` field removed, so anyone can verify it and the same content
//! always has the same tag. Documents are immutable once sealed.

use serde_json::Value;
use sha2::{Digest, Sha256};

/// Serialize with object keys sorted recursively and no insignificant whitespace.
pub fn canonical_json(v: &Value) -> String {
    let mut out = String::new();
    write_canonical(v, &mut out);
    out
}

fn write_canonical(v: &Value, out: &mut String) {
    match v {
        Value::Object(map) => {
            let mut keys: Vec<&String> = map.keys().collect();
            keys.sort();
            out.push('{');
            for (i, k) in keys.iter().enumerate() {
                if i > 0 {
                    out.push(',');
                }
                out.push_str(&Value::String((*k).clone()).to_string());
                out.push(':');
                if let Some(x) = map.get(*k) {
                    write_canonical(x, out);
                }
            }
            out.push('}');
        }
        Value::Array(items) => {
            out.push('[');
            for (i, x) in items.iter().enumerate() {
                if i > 0 {
                    out.push(',');
                }
                write_canonical(x, out);
            }
            out.push(']');
        }
        other => out.push_str(&other.to_string()),
    }
}

/// Hex SHA-256 of a byte string.
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

/// Set `rev`, compute the `etag` and return (canonical body including the etag, etag).
pub fn seal(mut doc: Value, rev: Option<u64>) -> (String, String) {
    if let Value::Object(map) = &mut doc {
        map.remove("etag");
        map.insert("rev".into(), rev.map_or(Value::Null, Value::from));
    }
    let etag = sha256_hex(canonical_json(&doc).as_bytes());
    if let Value::Object(map) = &mut doc {
        map.insert("etag".into(), Value::String(etag.clone()));
    }
    (canonical_json(&doc), etag)
}

/// The store's [`crate::store::Seal`] for `doc`: seals it with the `rev` the store assigns.
pub fn sealer(doc: Value) -> crate::store::Seal {
    Box::new(move |rev| {
        let (body, etag) = seal(doc, rev);
        crate::store::Sealed { body, etag }
    })
}

/// SHA-256 over `sha256  name` lines in dataset order (the `sha256sum` layout): identifies
/// a dataset's content independently of where it is stored.
pub fn manifest_sha256(files: &[crate::store::DatasetFile]) -> String {
    let mut manifest = String::new();
    for f in files {
        manifest.push_str(&format!("{}  {}\n", f.sha256, f.name));
    }
    sha256_hex(manifest.as_bytes())
}

/// Check that a sealed document's `etag` matches its content.
pub fn verify(body: &Value) -> bool {
    let Some(tag) = body.get("etag").and_then(Value::as_str) else {
        return false;
    };
    let mut copy = body.clone();
    if let Value::Object(map) = &mut copy {
        map.remove("etag");
    }
    sha256_hex(canonical_json(&copy).as_bytes()) == tag
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn canonical_form_sorts_keys_at_every_level() {
        let v = json!({"b": 1, "a": {"d": [1, {"z": 0, "y": "s"}], "c": null}});
        assert_eq!(
            canonical_json(&v),
            r#"{"a":{"c":null,"d":[1,{"y":"s","z":0}]},"b":1}"#
        );
    }

    #[test]
    fn seal_is_verifiable_and_content_sensitive() {
        let (body, etag) = seal(json!({"schema": "x/v1", "p": 1.5}), Some(3));
        let v: Value = serde_json::from_str(&body).unwrap();
        assert_eq!(v["rev"], 3);
        assert_eq!(v["etag"], etag);
        assert!(verify(&v));
        let (_, other) = seal(json!({"schema": "x/v1", "p": 1.6}), Some(3));
        assert_ne!(etag, other);
        let mut tampered = v.clone();
        tampered["p"] = json!(2.0);
        assert!(!verify(&tampered));
    }
}
