//! The document a job produces, built the same way by the worker and by `caliper run`.

use serde_json::{Value, json};
use uuid::Uuid;

use super::{JobKind, JobOutput};
use crate::store::DatasetFile;

/// Where a document came from.
pub struct Provenance<'a> {
    pub job: Option<Uuid>,
    pub dataset: Option<Uuid>,
    pub dataset_sha256: Option<&'a str>,
    pub files: &'a [DatasetFile],
    pub params: &'a Value,
    pub device: Option<&'a str>,
    pub sensor: Option<&'a str>,
}

/// The unsealed document (`rev` and `etag` are added by [`crate::document::seal`]).
pub fn build(kind: &dyn JobKind, out: &JobOutput, prov: &Provenance<'_>, now_ms: i64) -> Value {
    json!({
        "schema": kind.schema(),
        "kind": kind.name(),
        "device": prov.device,
        "sensor": prov.sensor,
        "created_at": crate::clock::rfc3339(now_ms),
        "provenance": {
            "job": prov.job,
            "dataset": prov.dataset,
            "dataset_sha256": prov.dataset_sha256,
            "files": prov.files.iter().map(|f| json!({"name": f.name, "sha256": f.sha256})).collect::<Vec<_>>(),
            "params": prov.params,
            "software": {"name": "caliper", "version": env!("CARGO_PKG_VERSION")},
        },
        "quality": out.quality,
        "parameters": out.parameters,
        "artifacts": out.artifacts.iter().map(|a| json!({"name": a.name, "media_type": a.media_type})).collect::<Vec<_>>(),
    })
}
