//! The HTTP API: one module per resource, assembled into one router whose OpenAPI
//! description is generated from the handlers themselves (utoipa), so the spec cannot drift
//! from the code.

pub mod datasets;
pub mod documents;
pub mod extract;
pub mod health;
pub mod jobs;
pub mod views;

use std::time::Instant;

use axum::Router;
use axum::body::Body;
use axum::extract::{DefaultBodyLimit, MatchedPath, Request};
use axum::http::{HeaderValue, StatusCode, header};
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
        (name = "operations", description = "Health, metrics, problem types"),
    ),
    components(schemas(
        Problem,
        caliper_core::blur::BlurParams,
        crate::jobs::camera_calibration::CameraCalibParams,
        caliper_core::imu::ImuNoiseParams,
        caliper_core::imu::ImuIntrinsicsParams,
        caliper_core::imu::ImuThermalParams,
        crate::jobs::photometric::ResponseJobParams,
        crate::jobs::photometric::VignettingJobParams,
        crate::jobs::photometric::OnlineJobParams,
        crate::jobs::photometric::CorrectJobParams,
        caliper_core::deconv::DeblurParams
    )),
    modifiers(&ProblemCodes)
)]
struct ApiDoc;

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
        .merge(datasets::router().layer(DefaultBodyLimit::max(max_upload)))
        .merge(jobs::router().layer(DefaultBodyLimit::max(JSON_BODY_LIMIT)))
        .merge(documents::router())
        .merge(health::router())
}

/// The OpenAPI document of the API.
pub fn openapi() -> utoipa::openapi::OpenApi {
    let (_, api) = routes(JSON_BODY_LIMIT).split_for_parts();
    api
}

/// The application router with all middleware.
pub fn app(state: AppState) -> Router {
    let max_upload = usize::try_from(state.config().max_upload_bytes).unwrap_or(usize::MAX);
    let (router, api) = routes(max_upload).split_for_parts();
    router
        .merge(SwaggerUi::new("/docs").url("/openapi.json", api))
        .fallback(fallback)
        .layer(axum::middleware::from_fn(problem_and_metrics))
        .layer(tower_http::catch_panic::CatchPanicLayer::custom(on_panic))
        .layer(tower_http::trace::TraceLayer::new_for_http())
        .with_state(state)
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
    let method = req.method().to_string();
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
    metrics::counter!("caliper_http_requests_total", "method" => method.clone(), "route" => route.clone(), "status" => status_label).increment(1);
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
