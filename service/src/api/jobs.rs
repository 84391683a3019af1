//! `/v1/jobs`: queue, read, list, cancel, follow (SSE), results and artifacts.
//!
//! Over 600 lines because the resource has nine routes, each with its OpenAPI annotation and
//! query types beside its (short) handler; they change together.

use std::convert::Infallible;
use std::time::Duration;

use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use futures_util::Stream;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;
use uuid::Uuid;

use super::extract::{ApiJson, ApiPath, ApiQuery};
use super::names::valid_name;
use super::views::{ArtifactList, ArtifactView, JobKindView, JobPage, JobView};
use crate::auth::Principal;
use crate::error::{ApiError, ApiResult, Problem};
use crate::jobs::{kinds, resolve_kind};
use crate::state::AppState;
use crate::store::{CancelJob, CreateJob, JobFilter, JobStatus, NewJob};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(create_job, list_jobs))
        .routes(routes!(get_job))
        .routes(routes!(cancel_job))
        .routes(routes!(job_events))
        .routes(routes!(job_result))
        .routes(routes!(list_artifacts))
        .routes(routes!(get_artifact))
        .routes(routes!(list_job_kinds))
}

/// Body of `POST /v1/jobs`.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({
    "kind": "blur_score", "dataset": "01935f2c-7a4e-7cc2-9d1e-3b8a2f6c1d00",
    "params": {"k": 10}, "device": "cam-0042", "sensor": "cam0"
}))]
pub struct CreateJobRequest {
    /// Job kind (see `GET /v1/job-kinds`).
    pub kind: String,
    /// Dataset id.
    pub dataset: Uuid,
    /// Kind-specific parameters; omitted fields take their defaults (the schema of each kind's
    /// parameters is listed here from the job-kind registry when the spec is generated).
    #[serde(default = "empty_object")]
    #[schema(value_type = Object)]
    pub params: Value,
    /// Device serial: a succeeded job files its document under this device.
    /// Letters, digits, `.`, `_`, `-`; at most 128.
    #[serde(default)]
    pub device: Option<String>,
    /// Sensor name on the device (default `default`); same alphabet as `device`.
    #[serde(default)]
    pub sensor: Option<String>,
}

fn empty_object() -> Value {
    Value::Object(Default::default())
}

/// Queue a job.
///
/// Parameters are validated before queueing. With an `Idempotency-Key` header, repeating the
/// same request returns the job created the first time (200); the same key with a different
/// body is a 409.
#[utoipa::path(
    post, path = "/v1/jobs", tag = "jobs",
    request_body = CreateJobRequest,
    params(("Idempotency-Key" = Option<String>, Header, pattern = "^[!-~]{1,255}$", description = "Client-chosen key (1–255 visible ASCII characters, no spaces) making the request safe to retry")),
    responses(
        (status = 202, description = "Queued", body = JobView, headers(("Location" = String, description = "URL of the job"))),
        (status = 200, description = "Same Idempotency-Key and body as an earlier request: that job", body = JobView),
        (status = 400, description = "Malformed JSON or header", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "Idempotency key reused with another body", body = Problem, content_type = "application/problem+json"),
        (status = 415, description = "Not JSON", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "invalid_body, unknown_job_kind, invalid_param, unknown_dataset, dataset_kind_mismatch", body = Problem, content_type = "application/problem+json"),
        (status = 429, description = "Queue full; see Retry-After", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn create_job(
    State(state): State<AppState>,
    who: Principal,
    headers: HeaderMap,
    ApiJson(req): ApiJson<CreateJobRequest>,
) -> ApiResult<Response> {
    // Keys are per token: one client's key can neither collide with nor reveal another's job.
    let key =
        idempotency_key(&headers)?.map(|k| who.token.map_or(k.clone(), |t| format!("{t}:{k}")));
    let kind = resolve_kind(state.config(), &req.kind).ok_or_else(|| {
        let known: Vec<&str> = kinds().iter().map(|k| k.name()).collect();
        ApiError::new(
            "unknown_job_kind",
            format!(
                "unknown job kind {:?}; known: {}",
                req.kind,
                known.join(", ")
            ),
        )
        .with_field("kind")
    })?;
    check_request(&req)?;
    if who.devices.is_some() && !req.device.as_deref().is_some_and(|d| who.sees_device(d)) {
        return Err(ApiError::new(
            "forbidden",
            "this token may queue jobs only for its own devices: set `device` to one of them",
        )
        .with_field("device"));
    }
    let params = kind.normalize_params(&req.params).map_err(ApiError::from)?;
    let dataset = dataset_for_job(&state, &who, req.dataset, "dataset").await?;
    let video_ok = kind.accepts_video() && dataset.kind == crate::store::DatasetKind::Video;
    if dataset.kind != kind.dataset_kind() && !video_ok {
        return Err(ApiError::new(
            "dataset_kind_mismatch",
            format!(
                "{} needs a dataset of kind {}{}, but {} holds {}",
                kind.name(),
                kind.dataset_kind().as_str(),
                if kind.accepts_video() {
                    " or video"
                } else {
                    ""
                },
                dataset.id,
                dataset.kind.as_str()
            ),
        )
        .with_field("dataset"));
    }
    let aux = match kind.aux_dataset(&params).map_err(ApiError::from)? {
        Some(aux) => Some(check_aux_dataset(&state, &who, &aux).await?),
        None => None,
    };
    let sensor = req
        .device
        .as_ref()
        .map(|_| req.sensor.clone().unwrap_or_else(|| "default".into()));
    let request_hash = crate::document::sha256_hex(
        crate::document::canonical_json(&serde_json::json!({
            "kind": kind.name(), "dataset": dataset.id, "params": params,
            "device": req.device, "sensor": sensor,
        }))
        .as_bytes(),
    );
    let new = NewJob {
        id: Uuid::now_v7(),
        kind: kind.name().to_string(),
        dataset_id: dataset.id,
        aux_dataset_id: aux,
        device: req.device.clone(),
        sensor,
        params,
        max_attempts: state.config().max_attempts,
        idempotency_key: key,
        request_hash: Some(request_hash),
        now: crate::clock::now_ms(),
    };
    let created = state
        .store()
        .create_job(new, state.config().max_queued_jobs)
        .await?;
    created_response(&state, created, req.dataset)
}

/// A dataset a job request names in `field`, if the caller may see it; `unknown_dataset`
/// otherwise (the same answer for another device's dataset as for a missing one).
async fn dataset_for_job(
    state: &AppState,
    who: &Principal,
    id: Uuid,
    field: &str,
) -> ApiResult<crate::store::DatasetRecord> {
    state
        .store()
        .get_dataset(id)
        .await?
        .filter(|d| who.sees_dataset(d.devices.as_deref()))
        .ok_or_else(|| {
            ApiError::new("unknown_dataset", format!("dataset {id} does not exist"))
                .with_field(field)
        })
}

/// The second dataset a job's parameters name: it must exist, be visible to the caller and
/// hold the kind of data the job reads from it; errors name the parameter.
async fn check_aux_dataset(
    state: &AppState,
    who: &Principal,
    aux: &crate::jobs::AuxDataset,
) -> ApiResult<Uuid> {
    let d = dataset_for_job(state, who, aux.id, aux.field).await?;
    if d.kind != aux.kind {
        return Err(ApiError::new(
            "dataset_kind_mismatch",
            format!(
                "{} must name a dataset of kind {}, but {} holds {}",
                aux.field,
                aux.kind.as_str(),
                d.id,
                d.kind.as_str()
            ),
        )
        .with_field(aux.field));
    }
    Ok(d.id)
}

/// The `Idempotency-Key` header, if any, checked.
fn idempotency_key(headers: &HeaderMap) -> ApiResult<Option<String>> {
    let Some(v) = headers.get("idempotency-key") else {
        return Ok(None);
    };
    v.to_str()
        .ok()
        .filter(|s| (1..=255).contains(&s.len()) && s.bytes().all(|b| b.is_ascii_graphic()))
        .map(|s| Some(s.to_string()))
        .ok_or_else(|| {
            ApiError::new(
                "invalid_header",
                "Idempotency-Key must be 1–255 visible ASCII characters (no spaces)",
            )
            .with_field("Idempotency-Key")
        })
}

/// The parts of a job request that do not depend on its kind.
fn check_request(req: &CreateJobRequest) -> ApiResult<()> {
    if !req.params.is_object() {
        return Err(
            ApiError::new("invalid_param", "params must be a JSON object").with_field("params"),
        );
    }
    for (name, v) in [("device", &req.device), ("sensor", &req.sensor)] {
        if let Some(s) = v
            && !valid_name(s)
        {
            return Err(ApiError::new(
                "invalid_body",
                format!("{name} must be 1–128 characters of letters, digits, `.`, `_`, `-`"),
            )
            .with_field(name));
        }
    }
    if req.sensor.is_some() && req.device.is_none() {
        return Err(ApiError::new("invalid_body", "sensor requires device").with_field("sensor"));
    }
    Ok(())
}

/// The response to what the store made of a job request.
fn created_response(state: &AppState, created: CreateJob, dataset: Uuid) -> ApiResult<Response> {
    match created {
        CreateJob::Created(job) => {
            state.wake_workers();
            metrics::counter!("caliper_jobs_created_total", "kind" => job.kind.clone())
                .increment(1);
            let location = format!("/v1/jobs/{}", job.id);
            Ok((
                StatusCode::ACCEPTED,
                [(header::LOCATION, location)],
                axum::Json(JobView::from(&job)),
            )
                .into_response())
        }
        CreateJob::Existing(job) => {
            let location = format!("/v1/jobs/{}", job.id);
            Ok((
                StatusCode::OK,
                [(header::LOCATION, location)],
                axum::Json(JobView::from(&job)),
            )
                .into_response())
        }
        CreateJob::Conflict(job) => Err(ApiError::new(
            "idempotency_conflict",
            format!(
                "Idempotency-Key was used for job {} with a different request",
                job.id
            ),
        )
        .with_field("Idempotency-Key")),
        CreateJob::QueueFull => {
            let mut e = ApiError::new(
                "queue_full",
                format!(
                    "{} jobs are queued; try again later",
                    state.config().max_queued_jobs
                ),
            );
            e.retry_after = Some(5);
            Err(e)
        }
        CreateJob::UnknownDataset => Err(ApiError::new(
            "unknown_dataset",
            format!("dataset {dataset} does not exist"),
        )
        .with_field("dataset")),
    }
}

/// Filters of the job list.
#[derive(Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct JobQuery {
    /// Comma-separated statuses: queued, running, succeeded, failed, canceled.
    #[param(
        pattern = "^(queued|running|succeeded|failed|canceled)(,(queued|running|succeeded|failed|canceled))*$"
    )]
    pub status: Option<String>,
    /// Comma-separated job kinds.
    pub kind: Option<String>,
    /// Device serial.
    pub device: Option<String>,
    /// Dataset id.
    pub dataset: Option<Uuid>,
    /// Created at or after this time (RFC 3339).
    #[param(format = DateTime)]
    pub created_after: Option<String>,
    /// Created before this time (RFC 3339).
    #[param(format = DateTime)]
    pub created_before: Option<String>,
    /// Page size, 1–100 (default 20).
    #[param(minimum = 1, maximum = 100)]
    pub limit: Option<u32>,
    /// `next_cursor` of the previous page.
    pub cursor: Option<Uuid>,
}

/// List jobs, newest first, with filters and cursor paging.
#[utoipa::path(
    get, path = "/v1/jobs", tag = "jobs", params(JobQuery),
    responses(
        (status = 200, description = "A page of jobs", body = JobPage),
        (status = 400, description = "Invalid query", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn list_jobs(
    State(state): State<AppState>,
    who: Principal,
    ApiQuery(q): ApiQuery<JobQuery>,
) -> ApiResult<axum::Json<JobPage>> {
    let limit = super::page_limit(q.limit)?;
    let split = |s: &Option<String>| -> Vec<String> {
        s.as_deref()
            .map(|v| {
                v.split(',')
                    .map(str::trim)
                    .filter(|x| !x.is_empty())
                    .map(String::from)
                    .collect()
            })
            .unwrap_or_default()
    };
    // A given but empty list is a mistake, not "any status" (the spec's pattern says so).
    if q.status.as_deref().is_some_and(|v| v.trim().is_empty()) {
        return Err(
            ApiError::new("invalid_query", "status must name at least one status")
                .with_field("status"),
        );
    }
    let statuses = split(&q.status)
        .iter()
        .map(|s| {
            JobStatus::parse(s).ok_or_else(|| {
                ApiError::new("invalid_query", format!("unknown status {s:?}")).with_field("status")
            })
        })
        .collect::<ApiResult<Vec<_>>>()?;
    let time = |s: &Option<String>, name: &str| -> ApiResult<Option<i64>> {
        s.as_deref()
            .map(|t| {
                crate::clock::parse_rfc3339(t).ok_or_else(|| {
                    ApiError::new(
                        "invalid_query",
                        format!("{name} must be an RFC 3339 time, got {t:?}"),
                    )
                    .with_field(name)
                })
            })
            .transpose()
    };
    let filter = JobFilter {
        statuses,
        kinds: split(&q.kind),
        device: q.device.clone(),
        devices: who.devices.clone(),
        dataset: q.dataset,
        created_after: time(&q.created_after, "created_after")?,
        created_before: time(&q.created_before, "created_before")?,
        before_id: q.cursor,
        limit: limit + 1,
    };
    let rows = state.store().list_jobs(&filter).await?;
    let (items, next_cursor) = super::paginate(rows, limit, |j| j.id);
    Ok(axum::Json(JobPage {
        items: items.iter().map(JobView::from).collect(),
        next_cursor,
    }))
}

/// Read a job the caller may see, or answer 404.
async fn load_job(
    state: &AppState,
    who: &Principal,
    id: Uuid,
) -> ApiResult<crate::store::JobRecord> {
    state
        .store()
        .get_job(id)
        .await?
        .filter(|j| who.sees_job(j.device.as_deref()))
        .ok_or_else(|| ApiError::not_found(format!("job {id}")))
}

/// Get a job.
#[utoipa::path(
    get, path = "/v1/jobs/{id}", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "The job", body = JobView),
        (status = 404, description = "No such job", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_job(
    State(state): State<AppState>,
    who: Principal,
    ApiPath(id): ApiPath<Uuid>,
) -> ApiResult<Response> {
    // The cache holds bodies, not owners: device-scoped callers always read the store.
    let cached = who
        .devices
        .is_none()
        .then(|| state.cached_job(&id))
        .flatten();
    let body = match cached {
        Some(body) => body,
        None => {
            let job = load_job(&state, &who, id).await?;
            let body = bytes::Bytes::from(
                serde_json::to_vec(&JobView::from(&job)).map_err(ApiError::internal)?,
            );
            if job.status.is_terminal() {
                state.cache_job(id, body.clone());
            }
            body
        }
    };
    Ok((
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        body,
    )
        .into_response())
}

/// Cancel a job.
///
/// A queued job is canceled at once (200). A running job is flagged (202): the algorithm stops
/// at its next check and the job ends `canceled`. A finished job cannot be canceled (409).
#[utoipa::path(
    post, path = "/v1/jobs/{id}/cancel", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "Canceled", body = JobView),
        (status = 202, description = "Cancellation requested; the job stops shortly", body = JobView),
        (status = 404, description = "No such job", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "Already finished (`job_finished`)", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn cancel_job(
    State(state): State<AppState>,
    who: Principal,
    ApiPath(id): ApiPath<Uuid>,
) -> ApiResult<Response> {
    load_job(&state, &who, id).await?;
    match state.store().cancel_job(id, crate::clock::now_ms()).await? {
        CancelJob::NotFound => Err(ApiError::not_found(format!("job {id}"))),
        CancelJob::Canceled(job) => {
            state.publish(crate::state::JobEvent {
                id,
                event: "status",
                status: job.status,
                progress: None,
            });
            Ok((StatusCode::OK, axum::Json(JobView::from(&job))).into_response())
        }
        CancelJob::Requested(job) => {
            state.signal_cancel(id);
            Ok((StatusCode::ACCEPTED, axum::Json(JobView::from(&job))).into_response())
        }
        CancelJob::Finished(job) => Err(ApiError::new(
            "job_finished",
            format!("job {id} already ended as {}", job.status.as_str()),
        )),
    }
}

/// Follow a job: Server-Sent Events.
///
/// Sends the current state first (`event: status`), then `progress` and `status` events as
/// they happen, and closes after the terminal status. Each `data` is
/// `{"id", "status", "progress"?}`.
#[utoipa::path(
    get, path = "/v1/jobs/{id}/events", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "Event stream", content_type = "text/event-stream", body = String),
        (status = 404, description = "No such job", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn job_events(
    State(state): State<AppState>,
    who: Principal,
    ApiPath(id): ApiPath<Uuid>,
) -> ApiResult<Sse<impl Stream<Item = Result<Event, Infallible>>>> {
    // Subscribe before reading the current state so no change falls between the two.
    let bus = state.subscribe();
    let job = load_job(&state, &who, id).await?;
    let rx = crate::job_watch::follow(&state, &job, bus);
    // The stream owns only a receiver: when the client goes, the stream is dropped, and the
    // shared watcher notices its last receiver is gone. Keep-alives (below) make a vanished
    // client visible even when the job does not change.
    let stream =
        futures_util::stream::unfold((rx, true, false), |(mut rx, first, done)| async move {
            if done {
                return None;
            }
            if !first && rx.changed().await.is_err() {
                // The watcher ended (terminal status already sent, or the job is gone).
                return None;
            }
            let ev = rx.borrow_and_update().clone()?;
            let data =
                serde_json::json!({"id": ev.id, "status": ev.status, "progress": ev.progress});
            let terminal = ev.status.is_terminal();
            Some((
                Ok::<_, Infallible>(Event::default().event(ev.event).data(data.to_string())),
                (rx, false, terminal),
            ))
        });
    let every = Duration::from_secs(state.config().sse_keepalive_secs);
    Ok(Sse::new(stream).keep_alive(KeepAlive::new().interval(every)))
}

/// The result document of a succeeded job (the same body as its device document revision,
/// if it has one). Supports `If-None-Match`.
#[utoipa::path(
    get, path = "/v1/jobs/{id}/result", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id"),
           super::documents::FormatQuery,
           ("If-None-Match" = Option<String>, Header, description = "ETag from an earlier response")),
    responses(
        (status = 200, description = "The document", body = Object, headers(("ETag" = String, description = "Quoted document etag"))),
        (status = 304, description = "Not modified"),
        (status = 400, description = "Invalid query, or format not available for this document (`invalid_query`, `unsupported_format`)", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "No such job", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "The job has not succeeded (`result_not_ready`)", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn job_result(
    State(state): State<AppState>,
    who: Principal,
    ApiPath(id): ApiPath<Uuid>,
    ApiQuery(q): ApiQuery<super::documents::FormatQuery>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let job = load_job(&state, &who, id).await?;
    let result = match job.status {
        JobStatus::Succeeded => state.store().get_job_result(id).await?,
        _ => None,
    };
    let Some(body) = result else {
        return Err(ApiError::new(
            "result_not_ready",
            format!(
                "job {id} is {}; a result exists once it has succeeded",
                job.status.as_str()
            ),
        ));
    };
    let etag = serde_json::from_str::<Value>(&body)
        .ok()
        .and_then(|v| v.get("etag").and_then(Value::as_str).map(String::from))
        .unwrap_or_default();
    super::documents::document_response(body, &etag, q.format.as_deref(), &headers)
}

/// List a job's artifacts.
#[utoipa::path(
    get, path = "/v1/jobs/{id}/artifacts", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "Artifacts", body = ArtifactList),
        (status = 404, description = "No such job", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn list_artifacts(
    State(state): State<AppState>,
    who: Principal,
    ApiPath(id): ApiPath<Uuid>,
) -> ApiResult<axum::Json<ArtifactList>> {
    load_job(&state, &who, id).await?;
    let items = state
        .store()
        .list_artifacts(id)
        .await?
        .into_iter()
        .map(|a| ArtifactView {
            href: format!("/v1/jobs/{id}/artifacts/{}", a.name),
            artifact: a,
        })
        .collect();
    Ok(axum::Json(ArtifactList { items }))
}

/// Download an artifact (plots are SVG).
#[utoipa::path(
    get, path = "/v1/jobs/{id}/artifacts/{name}", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id"), ("name" = String, Path, description = "Artifact name")),
    responses(
        (status = 200, description = "The artifact, with its media type", content_type = "*/*", body = Vec<u8>),
        (status = 404, description = "No such job or artifact", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_artifact(
    State(state): State<AppState>,
    who: Principal,
    ApiPath((id, name)): ApiPath<(Uuid, String)>,
) -> ApiResult<Response> {
    load_job(&state, &who, id).await?;
    let a = state
        .store()
        .get_artifact(id, &name)
        .await?
        .ok_or_else(|| ApiError::not_found(format!("artifact {name:?} of job {id}")))?;
    // Streamed: an artifact (a deblurred 16-bit TIFF) can be large; memory stays bounded.
    let stream = state
        .blobs()
        .stream(&a.sha256)
        .await
        .map_err(ApiError::internal)?;
    let mut resp = axum::body::Body::from_stream(stream).into_response();
    if let Ok(v) = HeaderValue::from_str(&a.size.to_string()) {
        resp.headers_mut().insert(header::CONTENT_LENGTH, v);
    }
    if let Ok(v) = HeaderValue::from_str(&a.media_type) {
        resp.headers_mut().insert(header::CONTENT_TYPE, v);
    }
    if let Ok(v) = HeaderValue::from_str(&format!("\"{}\"", a.sha256)) {
        resp.headers_mut().insert(header::ETAG, v);
    }
    Ok(resp)
}

/// The job kinds this server runs, with their parameter schemas.
#[utoipa::path(
    get, path = "/v1/job-kinds", tag = "jobs",
    responses((status = 200, description = "Job kinds", body = Vec<JobKindView>))
)]
pub async fn list_job_kinds() -> axum::Json<Vec<JobKindView>> {
    axum::Json(
        kinds()
            .iter()
            .map(|k| JobKindView {
                name: k.name().into(),
                schema: k.schema().into(),
                dataset_kind: k.dataset_kind(),
                description: k.description().into(),
                params_schema: k.params_schema(),
                exports: k.exports().iter().map(Into::into).collect(),
            })
            .collect(),
    )
}
