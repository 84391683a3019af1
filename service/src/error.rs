//! One error type for the HTTP surface, rendered as RFC 9457 `application/problem+json`.
//!
//! Every error carries a stable machine-readable `code`; the `type` URI is derived from it
//! (`/problems/{code}`, served by the API with a description), so clients switch on either.
//! 5xx bodies never contain internals: the detail is logged, the client gets a generic text.

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

/// The media type of every error body.
pub const PROBLEM_JSON: &str = "application/problem+json";

/// An RFC 9457 problem detail, as returned for every 4xx and 5xx response.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[schema(example = json!({
    "type": "/problems/invalid_param",
    "title": "Invalid job parameter",
    "status": 422,
    "detail": "`k` must be between 1 and 64",
    "code": "invalid_param",
    "field": "params.k"
}))]
pub struct Problem {
    /// URI reference identifying the problem type: `/problems/{code}`.
    #[serde(rename = "type")]
    pub type_uri: String,
    /// Short summary of the problem type (the same for every occurrence).
    pub title: String,
    /// HTTP status code.
    pub status: u16,
    /// Human-readable explanation of this occurrence.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub detail: Option<String>,
    /// The request path that produced the problem.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub instance: Option<String>,
    /// Stable machine-readable code; see the table in the README.
    pub code: String,
    /// The offending field (JSON path into the request body or the name of a query parameter).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub field: Option<String>,
}

/// Every problem code the API can return: (code, HTTP status, title). The README and
/// `GET /problems/{code}` are generated from this table, so it is the single source of truth.
pub const PROBLEM_CODES: &[(&str, u16, &str)] = &[
    ("malformed_json", 400, "Request body is not valid JSON"),
    ("invalid_query", 400, "Invalid query parameter"),
    ("invalid_header", 400, "Invalid request header"),
    (
        "unsupported_format",
        400,
        "Export format not available for this document",
    ),
    ("unauthorized", 401, "A valid bearer token is required"),
    ("forbidden", 403, "The token's scope does not allow this"),
    ("not_found", 404, "Resource not found"),
    ("route_not_found", 404, "No such route"),
    (
        "method_not_allowed",
        405,
        "Method not allowed on this route",
    ),
    ("result_not_ready", 409, "The job has no result yet"),
    (
        "idempotency_conflict",
        409,
        "Idempotency key reused with a different request",
    ),
    (
        "dataset_in_use",
        409,
        "Dataset is used by a queued or running job",
    ),
    ("job_finished", 409, "The job has already finished"),
    ("payload_too_large", 413, "Request body too large"),
    ("unsupported_media_type", 415, "Unsupported media type"),
    (
        "invalid_body",
        422,
        "Request body does not match the schema",
    ),
    ("unknown_job_kind", 422, "Unknown job kind"),
    ("invalid_param", 422, "Invalid job parameter"),
    ("unknown_dataset", 422, "Referenced dataset does not exist"),
    (
        "dataset_kind_mismatch",
        422,
        "Dataset kind does not fit the job kind",
    ),
    ("empty_upload", 422, "Upload contains no data"),
    ("unsupported_file", 422, "File type not supported"),
    ("corrupt_image", 422, "Image cannot be decoded"),
    ("image_too_large", 422, "Image dimensions exceed the limit"),
    (
        "trailing_data",
        422,
        "File holds far more data than its image",
    ),
    ("too_many_files", 422, "Too many files in the upload"),
    ("mixed_dataset", 422, "Upload mixes data kinds"),
    (
        "duplicate_name",
        422,
        "Two files in the upload have the same name",
    ),
    ("zip_bomb", 422, "Archive exceeds expansion limits"),
    ("zip_unsafe_path", 422, "Archive entry has an unsafe path"),
    ("corrupt_archive", 422, "Archive cannot be read"),
    ("invalid_imu_log", 422, "IMU log cannot be parsed"),
    ("video_io", 422, "Video file cannot be read"),
    (
        "video_container_unsupported",
        422,
        "Video container not supported (MP4 or MOV needed)",
    ),
    ("video_moov_missing", 422, "Video has no index (moov box)"),
    ("video_malformed", 422, "Video file is malformed"),
    (
        "video_fragmented_unsupported",
        422,
        "Fragmented MP4 is not supported",
    ),
    ("video_no_video_track", 422, "File has no video track"),
    ("video_codec_unsupported", 422, "Video codec not supported"),
    (
        "video_matrix_unsupported",
        422,
        "Video transform is not a rotation",
    ),
    ("video_too_long", 422, "Video exceeds the duration limit"),
    (
        "video_too_large",
        422,
        "Video frames exceed the pixel limit",
    ),
    (
        "video_too_many_frames",
        422,
        "Video exceeds the frame limit",
    ),
    (
        "video_decoded_bytes_over_limit",
        422,
        "Video would decode to too much data",
    ),
    (
        "video_sample_too_large",
        422,
        "Video sample exceeds the size limit",
    ),
    ("video_empty_sample", 422, "Video has an empty sample"),
    ("video_truncated", 422, "Video file is cut short"),
    (
        "video_no_decodable_frame",
        422,
        "Video has no decodable frame",
    ),
    ("video_canceled", 422, "Video reading was canceled"),
    ("video_encode_failed", 422, "Video could not be encoded"),
    ("queue_full", 429, "Job queue is full"),
    ("rate_limited", 429, "Too many requests for this token"),
    ("internal", 500, "Internal server error"),
    ("unavailable", 503, "Service unavailable"),
];

/// An API error: a problem code plus the details of this occurrence.
#[derive(Debug, Clone)]
pub struct ApiError {
    pub status: StatusCode,
    pub code: &'static str,
    pub detail: Option<String>,
    pub field: Option<String>,
    pub retry_after: Option<u64>,
}

impl ApiError {
    /// An error with the given code; the status comes from [`PROBLEM_CODES`].
    pub fn new(code: &'static str, detail: impl Into<String>) -> Self {
        let status = PROBLEM_CODES
            .iter()
            .find(|(c, _, _)| *c == code)
            .and_then(|(_, s, _)| StatusCode::from_u16(*s).ok())
            .unwrap_or(StatusCode::INTERNAL_SERVER_ERROR);
        Self {
            status,
            code,
            detail: Some(detail.into()),
            field: None,
            retry_after: None,
        }
    }

    /// Attach the offending field.
    pub fn with_field(mut self, field: impl Into<String>) -> Self {
        self.field = Some(field.into());
        self
    }

    /// Shorthand for a 404 naming what was not found.
    pub fn not_found(what: impl std::fmt::Display) -> Self {
        Self::new("not_found", format!("{what} not found"))
    }

    /// A 500 whose cause is logged but not shown to the client.
    pub fn internal(cause: impl std::fmt::Display) -> Self {
        tracing::error!(error = %cause, "internal error");
        Self::new("internal", "an internal error occurred; it has been logged")
    }

    /// The title of this error's code.
    pub fn title(&self) -> &'static str {
        title_of(self.code)
    }

    /// Render as a [`Problem`] (without `instance`, which the middleware adds).
    pub fn to_problem(&self) -> Problem {
        Problem {
            type_uri: format!("/problems/{}", self.code),
            title: self.title().to_string(),
            status: self.status.as_u16(),
            detail: self.detail.clone(),
            instance: None,
            code: self.code.to_string(),
            field: self.field.clone(),
        }
    }
}

/// The title of a problem code.
pub fn title_of(code: &str) -> &'static str {
    PROBLEM_CODES
        .iter()
        .find(|(c, _, _)| *c == code)
        .map(|(_, _, t)| *t)
        .unwrap_or("Error")
}

impl std::fmt::Display for ApiError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.code, self.detail.as_deref().unwrap_or(""))
    }
}

impl std::error::Error for ApiError {}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let problem = self.to_problem();
        let body = serde_json::to_vec(&problem).unwrap_or_default();
        let mut resp = (self.status, body).into_response();
        resp.headers_mut()
            .insert(header::CONTENT_TYPE, HeaderValue::from_static(PROBLEM_JSON));
        if let Some(secs) = self.retry_after {
            resp.headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from(secs));
        }
        resp
    }
}

impl From<crate::jobs::ParamError> for ApiError {
    fn from(e: crate::jobs::ParamError) -> Self {
        ApiError::new("invalid_param", e.message).with_field(e.field)
    }
}

impl From<crate::store::StoreError> for ApiError {
    fn from(e: crate::store::StoreError) -> Self {
        match e {
            crate::store::StoreError::NotFound(what) => ApiError::not_found(what),
            other => ApiError::internal(other),
        }
    }
}

/// Result alias for handlers.
pub type ApiResult<T> = Result<T, ApiError>;
