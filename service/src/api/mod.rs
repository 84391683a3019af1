//! The HTTP API: one module per resource, assembled into one router whose OpenAPI
//! description is generated from the handlers themselves (utoipa), so the spec cannot drift
//! from the code.

pub mod datasets;
pub mod devices;
pub mod documents;
pub mod extract;
pub mod health;
pub mod jobs;
pub(crate) mod names;
pub mod tokens;
pub mod ui;
pub mod views;

use std::time::Instant;

use axum::Router;
use axum::body::Body;
use axum::extract::{DefaultBodyLimit, MatchedPath, Request};
use axum::http::{HeaderValue, Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use utoipa::OpenApi;
use utoipa_axum::router::OpenApiRouter;
use utoipa_swagger_ui::SwaggerUi;

use crate::error::{ApiError, ApiResult, PROBLEM_JSON, Problem};
use crate::state::AppState;

#[derive(OpenApi)]
#[openapi(
    info(
        title = "Caliper",
        description = "Calibration service: upload sensor recordings (image sets, IMU logs, video), queue calibration jobs, and fetch versioned parameter documents.\n\nEvery error is `application/problem+json` (RFC 9457) with a stable `code`; `GET /problems/{code}` describes each.",
        license(name = "Apache-2.0", identifier = "Apache-2.0"),
    ),
    tags(
        (name = "datasets", description = "Uploaded recordings"),
        (name = "jobs", description = "Queued work and its results"),
        (name = "documents", description = "Versioned calibration documents per device"),
        (name = "tokens", description = "Access tokens (admin scope)"),
        (name = "operations", description = "Health, metrics, problem types"),
    ),
    components(schemas(Problem)),
    modifiers(&ProblemCodes, &BearerAuth)
)]
struct ApiDoc;

/// Adds every registered job kind's parameter schema (and the schemas it refers to) to the
/// components, and names them in the description of `CreateJobRequest.params`: the registry is
/// the one list of kinds. Applied after the routes are merged, when `CreateJobRequest` is among
/// the components.
fn add_kind_schemas(api: &mut utoipa::openapi::OpenApi) {
    use utoipa::openapi::RefOr;
    use utoipa::openapi::schema::Schema;
    let components = api.components.get_or_insert_with(Default::default);
    let mut found = Vec::new();
    let mut names = Vec::new();
    for k in crate::jobs::kinds() {
        let before = found.len();
        k.params_components(&mut found);
        if let Some((name, _)) = found.get(before) {
            names.push(format!("`{}` `{name}`", k.name()));
        }
    }
    for (name, schema) in found {
        components.schemas.entry(name).or_insert(schema);
    }
    let Some(RefOr::T(Schema::Object(req))) = components.schemas.get_mut("CreateJobRequest") else {
        return;
    };
    if let Some(RefOr::T(Schema::Object(params))) = req.properties.get_mut("params") {
        params.description = Some(format!(
            "Kind-specific parameters; omitted fields take their defaults. Schemas: {}.",
            names.join(", ")
        ));
    }
}

/// Declares the bearer scheme and applies it to every operation: servers with tokens on
/// (production, or `--auth`) require it everywhere but health, the spec and the dashboard.
struct BearerAuth;

impl utoipa::Modify for BearerAuth {
    fn modify(&self, api: &mut utoipa::openapi::OpenApi) {
        use utoipa::openapi::security::{
            HttpAuthScheme, HttpBuilder, SecurityRequirement, SecurityScheme,
        };
        let components = api.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(
                HttpBuilder::new()
                    .scheme(HttpAuthScheme::Bearer)
                    .description(Some(
                        "`clp_…` token from `caliper token create` or `POST /v1/tokens`; required when the server runs with tokens",
                    ))
                    .build(),
            ),
        );
        // Optional at the spec level: an embedded server on loopback runs open.
        api.security = Some(vec![
            SecurityRequirement::new("bearer", Vec::<String>::new()),
            SecurityRequirement::default(),
        ]);
    }
}

/// Publishes every problem code as the enum of `Problem.code`, so generated clients can
/// switch on them (the table in `error.rs` stays the single source).
struct ProblemCodes;

impl utoipa::Modify for ProblemCodes {
    fn modify(&self, api: &mut utoipa::openapi::OpenApi) {
        use utoipa::openapi::RefOr;
        use utoipa::openapi::schema::Schema;
        let Some(components) = api.components.as_mut() else {
            return;
        };
        let Some(RefOr::T(Schema::Object(problem))) = components.schemas.get_mut("Problem") else {
            return;
        };
        if let Some(RefOr::T(Schema::Object(code))) = problem.properties.get_mut("code") {
            code.enum_values = Some(
                crate::error::PROBLEM_CODES
                    .iter()
                    .map(|(c, _, _)| serde_json::Value::from(*c))
                    .collect(),
            );
        }
    }
}

/// Largest JSON body (job requests are small).
const JSON_BODY_LIMIT: usize = 1 << 20;

fn routes(max_upload: usize) -> OpenApiRouter<AppState> {
    OpenApiRouter::with_openapi(ApiDoc::openapi())
        .merge(
            datasets::router()
                .layer(DefaultBodyLimit::max(max_upload))
                .layer(axum::middleware::from_fn_with_state(
                    max_upload,
                    refuse_declared_oversize,
                )),
        )
        .merge(
            jobs::router()
                .layer(DefaultBodyLimit::max(JSON_BODY_LIMIT))
                .layer(axum::middleware::from_fn_with_state(
                    JSON_BODY_LIMIT,
                    refuse_declared_oversize,
                )),
        )
        .merge(devices::router())
        .merge(documents::router())
        .merge(
            tokens::router()
                .layer(DefaultBodyLimit::max(JSON_BODY_LIMIT))
                .layer(axum::middleware::from_fn_with_state(
                    JSON_BODY_LIMIT,
                    refuse_declared_oversize,
                )),
        )
        .merge(health::router())
}

/// The OpenAPI document of the API.
pub fn openapi() -> utoipa::openapi::OpenApi {
    let (_, mut api) = routes(JSON_BODY_LIMIT).split_for_parts();
    add_kind_schemas(&mut api);
    api
}

/// The application router with all middleware.
pub fn app(state: AppState) -> Router {
    let max_upload = usize::try_from(state.config().max_upload_bytes).unwrap_or(usize::MAX);
    let (router, mut api) = routes(max_upload).split_for_parts();
    add_kind_schemas(&mut api);
    let body_timeout = std::time::Duration::from_secs(state.config().body_timeout_secs);
    let cors = cors_layer(state.config());
    router
        .merge(SwaggerUi::new("/docs").url("/openapi.json", api))
        .merge(ui::router())
        .fallback(fallback)
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            crate::auth::authenticate,
        ))
        // A body that stalls (a trickled upload, a declared length never sent) is dropped
        // after `body_timeout_secs` without data, releasing its temporary file.
        .layer(tower_http::timeout::RequestBodyTimeoutLayer::new(
            body_timeout,
        ))
        .layer(axum::middleware::from_fn(problem_and_metrics))
        .layer(tower_http::catch_panic::CatchPanicLayer::custom(on_panic))
        .layer(tower_http::trace::TraceLayer::new_for_http())
        .layer(cors)
        .with_state(state)
}

/// CORS for the configured browser origins (none by default: the built-in dashboard is
/// same-origin). Preflights are answered here, before authentication.
fn cors_layer(cfg: &crate::config::Config) -> tower_http::cors::CorsLayer {
    use tower_http::cors::{AllowOrigin, CorsLayer};
    let origins: Vec<HeaderValue> = cfg
        .cors_list()
        .into_iter()
        .filter_map(|o| HeaderValue::from_str(o).ok())
        .collect();
    if origins.is_empty() {
        return CorsLayer::new();
    }
    CorsLayer::new()
        .allow_origin(AllowOrigin::list(origins))
        .allow_methods([Method::GET, Method::POST, Method::DELETE])
        .allow_headers([
            header::AUTHORIZATION,
            header::CONTENT_TYPE,
            header::IF_NONE_MATCH,
            axum::http::HeaderName::from_static("idempotency-key"),
        ])
        .expose_headers([header::ETAG, header::LOCATION, header::RETRY_AFTER])
        .max_age(std::time::Duration::from_secs(600))
}

/// Answer 413 at once when the declared `Content-Length` is over the route's limit, instead
/// of reading (or waiting for) a body that will be refused anyway.
async fn refuse_declared_oversize(
    axum::extract::State(limit): axum::extract::State<usize>,
    req: Request,
    next: Next,
) -> Response {
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    if let Some(n) = declared.filter(|&n| n > limit as u64) {
        let e = ApiError::new(
            "payload_too_large",
            format!("the declared body of {n} bytes exceeds the limit of {limit} bytes"),
        );
        // A body that is only somewhat too large is read and dropped first, so that the
        // client has finished writing when the answer comes. Closing with unread bytes makes
        // the kernel reset the connection, and the client then sees a broken pipe or a reset
        // instead of this 413. Anything larger, or slower, is cut off.
        if n <= (limit as u64).saturating_add(LINGER_BYTES) {
            let _ = tokio::time::timeout(LINGER_TIME, discard(req.into_body(), n)).await;
        }
        let mut resp = e.into_response();
        // The connection cannot be reused: the body may not have been read to its end.
        resp.headers_mut()
            .insert(header::CONNECTION, HeaderValue::from_static("close"));
        return resp;
    }
    next.run(req).await
}

/// How far beyond its route's limit a declared body is still read (and dropped) before the
/// 413, so that ordinary clients read the answer instead of a reset connection.
const LINGER_BYTES: u64 = 8 << 20;

/// How long reading such a body may take before the 413 is sent anyway.
const LINGER_TIME: std::time::Duration = std::time::Duration::from_secs(2);

/// Reads and drops up to `max` bytes of `body`, stopping at its end or at an error.
async fn discard(body: axum::body::Body, max: u64) {
    use futures_util::StreamExt;
    let mut chunks = body.into_data_stream();
    let mut read = 0u64;
    while read < max {
        match chunks.next().await {
            Some(Ok(chunk)) => read += chunk.len() as u64,
            _ => break,
        }
    }
}

async fn fallback(req: Request) -> ApiError {
    ApiError::new(
        "route_not_found",
        format!("no route {} {}", req.method(), req.uri().path()),
    )
}

fn on_panic(_: Box<dyn std::any::Any + Send + 'static>) -> Response {
    ApiError::internal("handler panicked").into_response()
}

/// Page size check shared by list endpoints.
pub fn page_limit(limit: Option<u32>) -> ApiResult<u32> {
    match limit {
        None => Ok(20),
        Some(n @ 1..=100) => Ok(n),
        Some(n) => Err(
            ApiError::new("invalid_query", format!("limit must be 1–100, got {n}"))
                .with_field("limit"),
        ),
    }
}

/// Cut a page fetched with `limit + 1` rows down to `limit`, returning the cursor of the
/// next page when there is one (the id of the last row kept; ids are time-ordered UUIDv7).
pub fn paginate<T>(
    mut items: Vec<T>,
    limit: u32,
    id: impl Fn(&T) -> uuid::Uuid,
) -> (Vec<T>, Option<String>) {
    if items.len() > limit as usize {
        items.truncate(limit as usize);
        let next = items.last().map(|x| id(x).to_string());
        (items, next)
    } else {
        (items, None)
    }
}

/// Count and time every request, and make every error a problem document with `instance`:
/// responses produced by axum itself (405, 413 from body limits) become problem+json too.
async fn problem_and_metrics(req: Request, next: Next) -> Response {
    let start = Instant::now();
    // Only known methods become label values: an invented method per request would otherwise
    // create a new time series each (issue D4: 440k series from 20,000 requests).
    let method: &'static str = match *req.method() {
        Method::GET => "GET",
        Method::HEAD => "HEAD",
        Method::POST => "POST",
        Method::PUT => "PUT",
        Method::PATCH => "PATCH",
        Method::DELETE => "DELETE",
        Method::OPTIONS => "OPTIONS",
        _ => "other",
    };
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map(|m| m.as_str().to_owned())
        .unwrap_or_else(|| "unmatched".to_owned());
    let path = req.uri().path().to_owned();
    let resp = next.run(req).await;
    let status = resp.status();
    let resp = if status.is_client_error() || status.is_server_error() {
        to_problem(resp, &path).await
    } else {
        resp
    };
    let status_label = resp.status().as_u16().to_string();
    metrics::counter!("caliper_http_requests_total", "method" => method, "route" => route.clone(), "status" => status_label).increment(1);
    metrics::histogram!("caliper_http_request_duration_seconds", "method" => method, "route" => route)
        .record(start.elapsed().as_secs_f64());
    resp
}

async fn to_problem(resp: Response, path: &str) -> Response {
    let status = resp.status();
    let is_problem = resp
        .headers()
        .get(header::CONTENT_TYPE)
        .is_some_and(|v| v.as_bytes() == PROBLEM_JSON.as_bytes());
    let (mut parts, body) = resp.into_parts();
    let bytes = axum::body::to_bytes(body, 64 << 10)
        .await
        .unwrap_or_default();
    let mut problem: Problem = match serde_json::from_slice(&bytes) {
        Ok(p) if is_problem => p,
        _ => {
            let code = match status {
                StatusCode::NOT_FOUND => "route_not_found",
                StatusCode::METHOD_NOT_ALLOWED => "method_not_allowed",
                StatusCode::PAYLOAD_TOO_LARGE => "payload_too_large",
                StatusCode::UNSUPPORTED_MEDIA_TYPE => "unsupported_media_type",
                StatusCode::TOO_MANY_REQUESTS => "queue_full",
                s if s.is_server_error() => "internal",
                _ => "invalid_body",
            };
            let text = String::from_utf8_lossy(&bytes).trim().to_string();
            let mut e = ApiError::new(
                code,
                if text.is_empty() || status.is_server_error() {
                    crate::error::title_of(code).to_string()
                } else {
                    text
                },
            );
            e.status = status;
            e.to_problem()
        }
    };
    problem.instance = Some(path.to_string());
    let body = serde_json::to_vec(&problem).unwrap_or_default();
    parts
        .headers
        .insert(header::CONTENT_TYPE, HeaderValue::from_static(PROBLEM_JSON));
    parts.headers.remove(header::CONTENT_LENGTH);
    Response::from_parts(parts, Body::from(body))
}
