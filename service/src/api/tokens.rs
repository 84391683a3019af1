//! `/v1/tokens`: access tokens (admin scope). The secret is in the creation response only;
//! the store keeps its hash.

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::IntoResponse;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;
use uuid::Uuid;

use super::extract::{ApiJson, ApiPath};
use crate::clock::rfc3339;
use crate::error::{ApiError, ApiResult, Problem};
use crate::state::AppState;
use crate::store::{Scope, TokenRecord};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(create_token, list_tokens))
        .routes(routes!(revoke_token))
}

/// A token to create.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"name": "provisioning", "scope": "read", "devices": ["cam-0042"]}))]
pub struct CreateTokenRequest {
    /// What it is for, 1–64 characters (shown in lists).
    pub name: String,
    pub scope: Scope,
    /// Limit it to these device serials (not for `admin`); absent: the whole fleet.
    #[serde(default)]
    pub devices: Option<Vec<String>>,
}

/// A token as listed (never with its secret).
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct TokenView {
    pub id: Uuid,
    pub name: String,
    /// The start of the secret, to recognise a leaked token.
    pub prefix: String,
    pub scope: Scope,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub devices: Option<Vec<String>>,
    /// RFC 3339.
    pub created_at: String,
    /// RFC 3339; absent while the token works.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub revoked_at: Option<String>,
}

impl From<TokenRecord> for TokenView {
    fn from(t: TokenRecord) -> Self {
        Self {
            id: t.id,
            name: t.name,
            prefix: t.prefix,
            scope: t.scope,
            devices: t.devices,
            created_at: rfc3339(t.created_at),
            revoked_at: t.revoked_at.map(rfc3339),
        }
    }
}

/// A created token, with its secret: shown this once.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct CreatedToken {
    #[serde(flatten)]
    pub view: TokenView,
    /// The bearer secret (`clp_…`). It cannot be read again.
    pub token: String,
}

/// Create a token.
#[utoipa::path(
    post, path = "/v1/tokens", tag = "tokens", request_body = CreateTokenRequest,
    responses(
        (status = 201, description = "Created; `token` is the secret, shown once", body = CreatedToken),
        (status = 400, description = "Malformed JSON", body = Problem, content_type = "application/problem+json"),
        (status = 415, description = "Not JSON", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "Invalid name, scope or devices", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn create_token(
    State(state): State<AppState>,
    ApiJson(req): ApiJson<CreateTokenRequest>,
) -> ApiResult<impl IntoResponse> {
    let field = if req.devices.is_some() {
        "devices"
    } else {
        "name"
    };
    let new = crate::auth::generate(&req.name, req.scope, req.devices, crate::clock::now_ms())
        .map_err(|e| ApiError::new("invalid_body", e.to_string()).with_field(field))?;
    state.store().insert_token(&new.record, &new.hash).await?;
    Ok((
        StatusCode::CREATED,
        axum::Json(CreatedToken {
            view: new.record.into(),
            token: new.secret,
        }),
    ))
}

/// List tokens, newest first.
#[utoipa::path(
    get, path = "/v1/tokens", tag = "tokens",
    responses((status = 200, description = "Tokens (without secrets)", body = Vec<TokenView>))
)]
pub async fn list_tokens(State(state): State<AppState>) -> ApiResult<axum::Json<Vec<TokenView>>> {
    let tokens = state.store().list_tokens().await?;
    Ok(axum::Json(
        tokens.into_iter().map(TokenView::from).collect(),
    ))
}

/// Revoke a token: it stops working at once, on every replica.
#[utoipa::path(
    delete, path = "/v1/tokens/{id}", tag = "tokens",
    params(("id" = Uuid, Path, description = "Token id")),
    responses(
        (status = 204, description = "Revoked (or already revoked)"),
        (status = 404, description = "No such token", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn revoke_token(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<Uuid>,
) -> ApiResult<StatusCode> {
    if state
        .store()
        .revoke_token(id, crate::clock::now_ms())
        .await?
    {
        // This replica forgets at once; the others when the store's notification arrives.
        state.token_cache().invalidate();
        Ok(StatusCode::NO_CONTENT)
    } else {
        Err(ApiError::not_found(format!("token {id}")))
    }
}
