//! `/v1/devices`: the fleet, one page at a time — every device that has a document, with the
//! latest revision of each (sensor, kind) and its quality numbers. A dashboard of 10,000
//! devices reads 50 of them, never the whole table.

use axum::extract::State;
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::extract::ApiQuery;
use crate::auth::Principal;
use crate::error::{ApiError, ApiResult, Problem};
use crate::state::AppState;
use crate::store::{DeviceQuery, DeviceSummary};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(list_devices))
}

/// Query of the device list.
#[derive(Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct DeviceListQuery {
    /// Page size, 1–100 (default 20).
    #[param(minimum = 1, maximum = 100)]
    pub limit: Option<u32>,
    /// `next_cursor` of the previous page (a serial).
    #[param(pattern = r"^[A-Za-z0-9._-]{1,128}$")]
    pub cursor: Option<String>,
    /// Only serials containing this text (case-insensitive), at most 128 characters.
    #[param(max_length = 128)]
    pub q: Option<String>,
}

/// A page of devices in serial order.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
#[schema(example = json!({
    "items": [{"serial": "cam-0042", "documents": [{"sensor": "cam0", "kind": "camera_calibration",
        "schema": "caliper.camera/v1", "latest_rev": 3, "etag": "5d41402a…",
        "created_at": "2026-11-28T21:00:05Z", "job": "01935f2c-8b11-7d20-a1b2-c3d4e5f60718",
        "quality": {"rms": 0.21, "coverage": 0.74}}]}],
    "total": 1
}))]
pub struct DevicePage {
    pub items: Vec<DeviceSummary>,
    /// Devices matching the query in all pages.
    pub total: u64,
    /// Pass as `cursor` to get the next page; absent on the last page.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub next_cursor: Option<String>,
}

/// List devices with the latest revision of each of their documents.
#[utoipa::path(
    get, path = "/v1/devices", tag = "documents", params(DeviceListQuery),
    responses(
        (status = 200, description = "A page of devices", body = DevicePage),
        (status = 400, description = "Invalid query", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn list_devices(
    State(state): State<AppState>,
    who: Principal,
    ApiQuery(q): ApiQuery<DeviceListQuery>,
) -> ApiResult<axum::Json<DevicePage>> {
    let limit = super::page_limit(q.limit)?;
    let cursor = q.cursor.clone();
    // The cursor is only a key to list after (serials sort as strings), so any string the
    // spec's pattern admits is a valid cursor, even "." or ".." which are never serials.
    if let Some(c) = &cursor
        && !super::names::name_pattern(c)
    {
        return Err(ApiError::new(
            "invalid_query",
            "cursor must be the next_cursor of an earlier page",
        )
        .with_field("cursor"));
    }
    let search = match q.q.as_deref().map(str::trim) {
        None | Some("") => None,
        Some(s) if s.chars().count() > 128 => {
            return Err(
                ApiError::new("invalid_query", "q must be at most 128 characters").with_field("q"),
            );
        }
        Some(s) => Some(s.to_owned()),
    };
    let store = state.store();
    let rows = store
        .list_devices(&DeviceQuery {
            search: search.clone(),
            after: cursor,
            limit: limit + 1,
            only: who.devices.clone(),
        })
        .await?;
    let total = store.count_devices(search.as_deref(), who.only()).await?;
    let (items, next_cursor) = cut_page(rows, limit);
    Ok(axum::Json(DevicePage {
        items,
        total,
        next_cursor,
    }))
}

/// Keep `limit` devices; the cursor of the next page is the last serial kept.
fn cut_page(mut rows: Vec<DeviceSummary>, limit: u32) -> (Vec<DeviceSummary>, Option<String>) {
    if rows.len() > limit as usize {
        rows.truncate(limit as usize);
        let next = rows.last().map(|d| d.serial.clone());
        (rows, next)
    } else {
        (rows, None)
    }
}
