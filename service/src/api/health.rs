//! Liveness, readiness, metrics, and the problem-type pages.

use axum::extract::State;
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::extract::ApiPath;
use crate::error::{ApiError, PROBLEM_CODES, Problem};
use crate::state::AppState;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(healthz))
        .routes(routes!(readyz))
        .routes(routes!(metrics))
        .routes(routes!(problem_type))
}

/// Health status.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct Health {
    /// `ok` or `unavailable`.
    pub status: String,
    pub version: String,
}

/// Liveness: the process answers.
#[utoipa::path(get, path = "/healthz", tag = "operations",
    responses((status = 200, description = "Alive", body = Health)))]
pub async fn healthz() -> axum::Json<Health> {
    axum::Json(Health {
        status: "ok".into(),
        version: env!("CARGO_PKG_VERSION").into(),
    })
}

/// Readiness: the store answers.
#[utoipa::path(get, path = "/readyz", tag = "operations",
    responses((status = 200, description = "Ready", body = Health),
              (status = 503, description = "Store unreachable", body = Problem, content_type = "application/problem+json")))]
pub async fn readyz(State(state): State<AppState>) -> Result<axum::Json<Health>, ApiError> {
    state.store().ping().await.map_err(|e| {
        tracing::warn!(error = %e, "readiness check failed");
        ApiError::new("unavailable", "the store is not reachable")
    })?;
    Ok(axum::Json(Health {
        status: "ok".into(),
        version: env!("CARGO_PKG_VERSION").into(),
    }))
}

/// Prometheus metrics: HTTP requests and latencies, job durations, queue depth.
#[utoipa::path(get, path = "/metrics", tag = "operations",
    responses((status = 200, description = "Prometheus text format", content_type = "text/plain", body = String)))]
pub async fn metrics(State(state): State<AppState>) -> Response {
    if let Ok((q, r)) = state.store().queue_depth().await {
        ::metrics::gauge!("caliper_jobs_queued").set(q as f64);
        ::metrics::gauge!("caliper_jobs_running").set(r as f64);
    }
    let text = state.metrics().map(|h| h.render()).unwrap_or_default();
    (
        StatusCode::OK,
        [(header::CONTENT_TYPE, "text/plain; version=0.0.4")],
        text,
    )
        .into_response()
}

/// A problem type: its status, title and meaning (the `type` URI of problem details).
#[utoipa::path(get, path = "/problems/{code}", tag = "operations",
    params(("code" = String, Path, description = "Problem code")),
    responses((status = 200, description = "The problem type", body = Problem),
              (status = 404, description = "Unknown code", body = Problem, content_type = "application/problem+json")))]
pub async fn problem_type(ApiPath(code): ApiPath<String>) -> Result<axum::Json<Problem>, ApiError> {
    let (c, status, title) = PROBLEM_CODES
        .iter()
        .find(|(c, _, _)| *c == code)
        .ok_or_else(|| ApiError::not_found(format!("problem type {code:?}")))?;
    Ok(axum::Json(Problem {
        type_uri: format!("/problems/{c}"),
        title: (*title).into(),
        status: *status,
        detail: None,
        instance: None,
        code: (*c).into(),
        field: None,
    }))
}
