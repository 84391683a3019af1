//! `/v1/devices/{serial}/documents`: immutable, versioned parameter documents.

use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::extract::{ApiPath, ApiQuery};
use crate::auth::Principal;
use crate::clock::rfc3339;
use crate::document_diff::DiffEntry;
use crate::error::{ApiError, ApiResult, Problem};
use crate::state::AppState;
use crate::store::DocumentSummary;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_device_documents))
        .routes(routes!(list_revisions))
        .routes(routes!(latest_document))
        .routes(routes!(diff_revisions))
        .routes(routes!(document_revision))
}

/// The documents of a device: the latest revision per sensor and kind.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct DeviceDocuments {
    pub device: String,
    pub documents: Vec<DocumentSummary>,
}

/// One revision in a revision list.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct RevisionView {
    pub rev: u64,
    pub etag: String,
    pub schema: String,
    /// RFC 3339.
    pub created_at: String,
    /// The job that wrote it.
    pub job: Option<uuid::Uuid>,
    /// The dataset it was computed from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dataset: Option<uuid::Uuid>,
    /// The software that wrote it, e.g. `caliper 0.1.0`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub software: Option<String>,
    /// The document's `quality` object.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub quality: Option<serde_json::Value>,
    pub href: String,
}

/// Two revisions of a document compared.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct RevisionDiff {
    pub device: String,
    pub sensor: String,
    pub kind: String,
    pub from: u64,
    pub to: u64,
    /// Values compared, the older revision's order first; see [`DiffEntry`].
    pub entries: Vec<DiffEntry>,
    /// How many of the entries differ.
    pub changed: usize,
}

/// `?from=&to=` of a diff.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct DiffQuery {
    /// The older revision, from 1.
    #[param(minimum = 1, maximum = 9223372036854775807_u64)]
    pub from: u64,
    /// The newer revision, from 1.
    #[param(minimum = 1, maximum = 9223372036854775807_u64)]
    pub to: u64,
}

/// `?format=` of document reads.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct FormatQuery {
    /// Export format instead of the JSON document: `opencv-yaml`, `ros-yaml`, `kalibr-yaml`
    /// or `json` (camera documents), `kalibr-yaml` (imu_noise documents: Kalibr's imu.yaml),
    /// `dso-pcalib` (photometric documents: DSO's pcalib.txt).
    pub format: Option<String>,
}

/// Respond with the document, or its export in `format`, with an ETag (the document's,
/// suffixed with the format for exports) and 304 handling.
pub fn document_response(
    body: String,
    etag: &str,
    format: Option<&str>,
    headers: &HeaderMap,
) -> ApiResult<Response> {
    let Some(format) = format else {
        return Ok(json_with_etag(body, etag, headers));
    };
    let doc: serde_json::Value = serde_json::from_str(&body).map_err(ApiError::internal)?;
    let out = crate::exports::render(&doc, format)?;
    let mut resp = json_with_etag(out.body, &format!("{etag}-{format}"), headers);
    if resp.status() == StatusCode::OK {
        resp.headers_mut().insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static(out.media_type),
        );
    }
    Ok(resp)
}

/// Respond with a JSON body and its ETag, or 304 if the client has it already.
pub fn json_with_etag(body: String, etag: &str, headers: &HeaderMap) -> Response {
    let quoted = format!("\"{etag}\"");
    let matches = headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| {
            v.split(',')
                .map(|t| t.trim().trim_start_matches("W/"))
                .any(|t| t == quoted || t == "*")
        });
    let etag_value = HeaderValue::from_str(&quoted).ok();
    let mut resp = if matches {
        StatusCode::NOT_MODIFIED.into_response()
    } else {
        let mut r = body.into_response();
        r.headers_mut().insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        );
        r
    };
    if let Some(v) = etag_value {
        resp.headers_mut().insert(header::ETAG, v);
    }
    resp.headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    resp
}

/// List a device's documents (latest revision of each sensor and kind).
#[utoipa::path(
    get, path = "/v1/devices/{serial}/documents", tag = "documents",
    params(("serial" = String, Path, description = "Device serial")),
    responses((status = 200, description = "Documents of the device (empty if none)", body = DeviceDocuments))
)]
pub async fn list_device_documents(
    State(state): State<AppState>,
    who: Principal,
    ApiPath(serial): ApiPath<String>,
) -> ApiResult<axum::Json<DeviceDocuments>> {
    let mut documents = state.store().list_documents(&serial).await?;
    if !who.sees_device(&serial) {
        documents.clear();
    }
    Ok(axum::Json(DeviceDocuments {
        device: serial,
        documents,
    }))
}

/// List all revisions of one document, newest first.
#[utoipa::path(
    get, path = "/v1/devices/{serial}/documents/{sensor}/{kind}", tag = "documents",
    params(("serial" = String, Path, description = "Device serial"),
           ("sensor" = String, Path, description = "Sensor name"),
           ("kind" = String, Path, description = "Job kind")),
    responses(
        (status = 200, description = "Revisions", body = Vec<RevisionView>),
        (status = 404, description = "No such document", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn list_revisions(
    State(state): State<AppState>,
    who: Principal,
    ApiPath((serial, sensor, kind)): ApiPath<(String, String, String)>,
) -> ApiResult<axum::Json<Vec<RevisionView>>> {
    let revs = state
        .store()
        .list_revisions(&serial, &sensor, &kind)
        .await?;
    if revs.is_empty() || !who.sees_device(&serial) {
        return Err(ApiError::not_found(format!(
            "document {kind} of {serial}/{sensor}"
        )));
    }
    Ok(axum::Json(
        revs.into_iter()
            .map(|d| {
                // Provenance is read from the sealed body: the store keeps it only there.
                let body: serde_json::Value =
                    serde_json::from_str(&d.body).unwrap_or(serde_json::Value::Null);
                let prov = &body["provenance"];
                let software = prov["software"]["name"].as_str().map(|n| {
                    format!(
                        "{n} {}",
                        prov["software"]["version"].as_str().unwrap_or("?")
                    )
                });
                RevisionView {
                    href: format!("/v1/devices/{serial}/documents/{sensor}/{kind}/{}", d.rev),
                    rev: d.rev,
                    etag: d.etag,
                    schema: d.schema,
                    created_at: rfc3339(d.created_at),
                    job: d.job_id,
                    dataset: prov["dataset"]
                        .as_str()
                        .and_then(|s| uuid::Uuid::parse_str(s).ok()),
                    software,
                    quality: body.get("quality").cloned().filter(|q| !q.is_null()),
                }
            })
            .collect(),
    ))
}

/// The latest revision of a document. Supports `If-None-Match` (304).
#[utoipa::path(
    get, path = "/v1/devices/{serial}/documents/{sensor}/{kind}/latest", tag = "documents",
    params(("serial" = String, Path, description = "Device serial"),
           ("sensor" = String, Path, description = "Sensor name"),
           ("kind" = String, Path, description = "Job kind, e.g. blur_score"),
           FormatQuery,
           ("If-None-Match" = Option<String>, Header, description = "ETag from an earlier response")),
    responses(
        (status = 200, description = "The document", body = Object, headers(("ETag" = String, description = "Quoted document etag"))),
        (status = 304, description = "Not modified"),
        (status = 400, description = "Format not available for this document (`unsupported_format`)", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "No such document", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn latest_document(
    State(state): State<AppState>,
    who: Principal,
    ApiPath((serial, sensor, kind)): ApiPath<(String, String, String)>,
    ApiQuery(q): ApiQuery<FormatQuery>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let d = state
        .store()
        .get_document(&serial, &sensor, &kind, None)
        .await?
        .filter(|_| who.sees_device(&serial))
        .ok_or_else(|| ApiError::not_found(format!("document {kind} of {serial}/{sensor}")))?;
    document_response(d.body, &d.etag, q.format.as_deref(), &headers)
}

/// A pinned revision of a document. Supports `If-None-Match` (304).
#[utoipa::path(
    get, path = "/v1/devices/{serial}/documents/{sensor}/{kind}/{rev}", tag = "documents",
    params(("serial" = String, Path, description = "Device serial"),
           ("sensor" = String, Path, description = "Sensor name"),
           ("kind" = String, Path, description = "Job kind"),
           ("rev" = u64, Path, description = "Revision, from 1"),
           FormatQuery,
           ("If-None-Match" = Option<String>, Header, description = "ETag from an earlier response")),
    responses(
        (status = 200, description = "The document", body = Object, headers(("ETag" = String, description = "Quoted document etag"))),
        (status = 304, description = "Not modified"),
        (status = 400, description = "Format not available for this document (`unsupported_format`)", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "No such document or revision", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn document_revision(
    State(state): State<AppState>,
    who: Principal,
    ApiPath((serial, sensor, kind, rev)): ApiPath<(String, String, String, u64)>,
    ApiQuery(q): ApiQuery<FormatQuery>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let d = state
        .store()
        .get_document(&serial, &sensor, &kind, Some(rev))
        .await?
        .filter(|_| who.sees_device(&serial))
        .ok_or_else(|| {
            ApiError::not_found(format!(
                "revision {rev} of document {kind} of {serial}/{sensor}"
            ))
        })?;
    document_response(d.body, &d.etag, q.format.as_deref(), &headers)
}

/// Compare two revisions of a document: every estimated value side by side, with its change
/// in standard deviations where the document gives σ.
#[utoipa::path(
    get, path = "/v1/devices/{serial}/documents/{sensor}/{kind}/diff", tag = "documents",
    params(("serial" = String, Path, description = "Device serial"),
           ("sensor" = String, Path, description = "Sensor name"),
           ("kind" = String, Path, description = "Job kind"),
           DiffQuery),
    responses(
        (status = 200, description = "The comparison", body = RevisionDiff),
        (status = 400, description = "Invalid query", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "No such document or revision", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn diff_revisions(
    State(state): State<AppState>,
    who: Principal,
    ApiPath((serial, sensor, kind)): ApiPath<(String, String, String)>,
    ApiQuery(q): ApiQuery<DiffQuery>,
) -> ApiResult<axum::Json<RevisionDiff>> {
    for (name, rev) in [("from", q.from), ("to", q.to)] {
        if rev == 0 || rev > i64::MAX as u64 {
            return Err(ApiError::new(
                "invalid_query",
                format!("{name} must be a revision, from 1"),
            )
            .with_field(name));
        }
    }
    let mut docs = Vec::with_capacity(2);
    for rev in [q.from, q.to] {
        let d = state
            .store()
            .get_document(&serial, &sensor, &kind, Some(rev))
            .await?
            .filter(|_| who.sees_device(&serial))
            .ok_or_else(|| {
                ApiError::not_found(format!(
                    "revision {rev} of document {kind} of {serial}/{sensor}"
                ))
            })?;
        let body: serde_json::Value = serde_json::from_str(&d.body).map_err(ApiError::internal)?;
        docs.push(body);
    }
    let entries = crate::document_diff::diff(&docs[0], &docs[1]);
    let changed = entries.iter().filter(|e| e.changed).count();
    Ok(axum::Json(RevisionDiff {
        device: serial,
        sensor,
        kind,
        from: q.from,
        to: q.to,
        entries,
        changed,
    }))
}
