//! `/v1/datasets`: upload, read, list, delete.

use axum::extract::{Multipart, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::IntoResponse;
use serde::Deserialize;
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;
use uuid::Uuid;

use super::extract::{ApiPath, ApiQuery};
use super::views::{DatasetPage, DatasetView};
use crate::auth::Principal;
use crate::error::{ApiError, ApiResult, Problem};
use crate::state::AppState;
use crate::store::DeleteDataset;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(upload_dataset, list_datasets))
        .routes(routes!(get_dataset, delete_dataset))
        .routes(routes!(get_dataset_file))
}

/// Multipart form of an upload (for the OpenAPI description; the handler streams it).
#[derive(ToSchema)]
#[allow(dead_code)]
pub struct UploadForm {
    /// One or more files: images (PNG, JPEG, TIFF incl. 16-bit) or zip archives of images;
    /// or one IMU log (CSV, optionally gzip); or one video (MP4/MOV, MKV/WebM, AVI).
    #[schema(value_type = Vec<String>, format = Binary, min_items = 1)]
    file: Vec<Vec<u8>>,
    /// Optional: the expected dataset kind (`images`, `imu_log`, `video`); the content decides,
    /// and a mismatch is refused. Not nullable: a form field is text or absent, never null.
    #[schema(value_type = crate::store::DatasetKind, required = false)]
    kind: Option<String>,
}

/// Upload a dataset.
///
/// Files stream to storage while being hashed (SHA-256, content-addressed, deduplicated), and
/// are validated before anything is recorded: images are decoded within the size limits, zip
/// archives are checked for entry count, expansion ratio, total size and unsafe paths.
#[utoipa::path(
    post, path = "/v1/datasets", tag = "datasets",
    request_body(content = UploadForm, content_type = "multipart/form-data"),
    responses(
        (status = 201, description = "Dataset stored", body = DatasetView,
         headers(("Location" = String, description = "URL of the dataset"))),
        (status = 413, description = "Upload too large", body = Problem, content_type = "application/problem+json"),
        (status = 415, description = "Not multipart/form-data", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "Invalid content: empty_upload, unsupported_file, corrupt_image, image_too_large, too_many_files, mixed_dataset, duplicate_name, zip_bomb, zip_unsafe_path, corrupt_archive, invalid_imu_log", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn upload_dataset(
    State(state): State<AppState>,
    who: Principal,
    headers: HeaderMap,
    request: axum::extract::Request,
) -> ApiResult<impl IntoResponse> {
    let ct = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    if !ct.to_ascii_lowercase().starts_with("multipart/form-data") {
        return Err(ApiError::new(
            "unsupported_media_type",
            format!("expected multipart/form-data, got {ct:?}"),
        ));
    }
    let multipart =
        <Multipart as axum::extract::FromRequest<AppState>>::from_request(request, &state)
            .await
            .map_err(|e| ApiError::new("invalid_body", e.body_text()))?;
    let ds = crate::ingest::ingest(&state, multipart, who.devices.clone()).await?;
    metrics::counter!("caliper_datasets_uploaded_total", "kind" => ds.kind.as_str()).increment(1);
    let location = format!("/v1/datasets/{}", ds.id);
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, location)],
        axum::Json(DatasetView::from(ds)),
    ))
}

/// Paging of lists.
#[derive(Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct PageQuery {
    /// Page size, 1–100 (default 20).
    #[param(minimum = 1, maximum = 100)]
    pub limit: Option<u32>,
    /// `next_cursor` of the previous page.
    pub cursor: Option<Uuid>,
}

/// List datasets, newest first.
#[utoipa::path(
    get, path = "/v1/datasets", tag = "datasets", params(PageQuery),
    responses(
        (status = 200, description = "A page of datasets", body = DatasetPage),
        (status = 400, description = "Invalid query", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn list_datasets(
    State(state): State<AppState>,
    who: Principal,
    ApiQuery(q): ApiQuery<PageQuery>,
) -> ApiResult<axum::Json<DatasetPage>> {
    let limit = super::page_limit(q.limit)?;
    let rows = state
        .store()
        .list_datasets(q.cursor, limit + 1, who.only())
        .await?;
    let (items, next_cursor) = super::paginate(rows, limit, |d| d.id);
    Ok(axum::Json(DatasetPage {
        items: items.into_iter().map(DatasetView::from).collect(),
        next_cursor,
    }))
}

/// Get a dataset.
#[utoipa::path(
    get, path = "/v1/datasets/{id}", tag = "datasets",
    params(("id" = Uuid, Path, description = "Dataset id")),
    responses(
        (status = 200, description = "The dataset", body = DatasetView),
        (status = 404, description = "No such dataset", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_dataset(
    State(state): State<AppState>,
    who: Principal,
    ApiPath(id): ApiPath<Uuid>,
) -> ApiResult<axum::Json<DatasetView>> {
    let ds = visible_dataset(&state, &who, id).await?;
    Ok(axum::Json(ds.into()))
}

/// Download one file of a dataset, by its position in `files` (from 0).
///
/// The bytes as uploaded (for a zip upload: the extracted file), with the media type found
/// at upload and the file's SHA-256 as its ETag.
#[utoipa::path(
    get, path = "/v1/datasets/{id}/files/{index}", tag = "datasets",
    params(("id" = Uuid, Path, description = "Dataset id"),
           ("index" = u32, Path, description = "Position of the file in the dataset's `files`, from 0")),
    responses(
        (status = 200, description = "The file, with the media type found at upload", content_type = "*/*", body = Vec<u8>),
        (status = 404, description = "No such dataset or file", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_dataset_file(
    State(state): State<AppState>,
    who: Principal,
    ApiPath((id, index)): ApiPath<(Uuid, u32)>,
) -> ApiResult<axum::response::Response> {
    use axum::http::HeaderValue;
    let ds = visible_dataset(&state, &who, id).await?;
    let f = ds
        .files
        .get(index as usize)
        .ok_or_else(|| ApiError::not_found(format!("file {index} of dataset {id}")))?;
    let stream = state
        .blobs()
        .stream(&f.sha256)
        .await
        .map_err(|_| ApiError::not_found(format!("file {index} of dataset {id}")))?;
    let mut resp = axum::body::Body::from_stream(stream).into_response();
    let h = resp.headers_mut();
    if let Ok(v) = HeaderValue::from_str(&f.size.to_string()) {
        h.insert(header::CONTENT_LENGTH, v);
    }
    if let Ok(v) = HeaderValue::from_str(&f.media_type) {
        h.insert(header::CONTENT_TYPE, v);
    }
    if let Ok(v) = HeaderValue::from_str(&format!("\"{}\"", f.sha256)) {
        h.insert(header::ETAG, v);
    }
    Ok(resp)
}

/// Delete a dataset.
///
/// Refused with 409 while a queued or running job uses it. Blobs no other dataset or artifact
/// references are deleted too. Finished jobs keep their results and documents.
#[utoipa::path(
    delete, path = "/v1/datasets/{id}", tag = "datasets",
    params(("id" = Uuid, Path, description = "Dataset id")),
    responses(
        (status = 204, description = "Deleted"),
        (status = 404, description = "No such dataset", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "A queued or running job uses it (`dataset_in_use`)", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn delete_dataset(
    State(state): State<AppState>,
    who: Principal,
    ApiPath(id): ApiPath<Uuid>,
) -> ApiResult<StatusCode> {
    visible_dataset(&state, &who, id).await?;
    match state.store().delete_dataset(id).await? {
        DeleteDataset::NotFound => Err(ApiError::not_found(format!("dataset {id}"))),
        DeleteDataset::InUse(jobs) => Err(ApiError::new(
            "dataset_in_use",
            format!(
                "dataset {id} is used by {} queued or running job(s): {}; cancel them or wait",
                jobs.len(),
                jobs.iter()
                    .map(Uuid::to_string)
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )),
        DeleteDataset::Deleted => {
            // Its blobs were nominated for collection; collect what is due now (everything,
            // with a zero grace period) rather than waiting for the maintenance task.
            crate::blob_gc::collect(&state).await;
            Ok(StatusCode::NO_CONTENT)
        }
    }
}

/// The dataset, if it exists and the caller may see it; 404 alike otherwise.
pub async fn visible_dataset(
    state: &AppState,
    who: &Principal,
    id: Uuid,
) -> ApiResult<crate::store::DatasetRecord> {
    state
        .store()
        .get_dataset(id)
        .await?
        .filter(|d| who.sees_dataset(d.devices.as_deref()))
        .ok_or_else(|| ApiError::not_found(format!("dataset {id}")))
}
