//! Access control: opaque bearer tokens with a scope, optionally limited to device serials.
//!
//! A token is `clp_` followed by 40 hex digits (160 random bits): greppable when leaked, and
//! far too long to guess, so the store keeps only its SHA-256 (a slow password hash would
//! add nothing for secrets of that entropy). Lookups are cached per replica, and a revocation
//! returns only once every caching replica has forgotten the token
//! ([`crate::token_cache`]), so it holds from the next request on every replica.
//!
//! A device-scoped token sees only its devices: their documents, their jobs, and the datasets
//! uploaded with such a token for them. Anything else answers 404 exactly as a missing
//! resource does (the store is queried either way), so statuses do not reveal what exists.

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::Instant;

use axum::extract::{FromRequestParts, Request, State};
use axum::http::request::Parts;
use axum::http::{HeaderValue, Method, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use rand::RngCore;
use uuid::Uuid;

use crate::error::ApiError;
use crate::state::AppState;
use crate::store::{Scope, TokenRecord};

/// Start of every token secret.
pub const TOKEN_PREFIX: &str = "clp_";

/// A new token: the record to store, its secret (shown once) and the hash stored.
pub struct NewToken {
    pub record: TokenRecord,
    pub secret: String,
    pub hash: String,
}

/// Why a token request is refused.
#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    #[error("name must be 1–64 printable characters")]
    Name,
    #[error(
        "device serials must be 1–128 characters of letters, digits, `.`, `_`, `-` (at most 1000)"
    )]
    Devices,
    #[error("a device-scoped token cannot be an admin token")]
    AdminDevices,
}

/// Make a token. `devices` limits it to those serials (not for `admin`).
pub fn generate(
    name: &str,
    scope: Scope,
    devices: Option<Vec<String>>,
    now: i64,
) -> Result<NewToken, TokenError> {
    let name = name.trim();
    if name.is_empty() || name.chars().count() > 64 || name.chars().any(char::is_control) {
        return Err(TokenError::Name);
    }
    if let Some(d) = &devices {
        if d.is_empty() || d.len() > 1000 || !d.iter().all(|s| crate::api::names::valid_name(s)) {
            return Err(TokenError::Devices);
        }
        if scope == Scope::Admin {
            return Err(TokenError::AdminDevices);
        }
    }
    let mut bytes = [0u8; 20];
    rand::rng().fill_bytes(&mut bytes);
    let secret = format!("{TOKEN_PREFIX}{}", hex::encode(bytes));
    let hash = crate::document::sha256_hex(secret.as_bytes());
    let mut devices = devices;
    if let Some(d) = &mut devices {
        d.sort();
        d.dedup();
    }
    Ok(NewToken {
        record: TokenRecord {
            id: Uuid::now_v7(),
            name: name.to_owned(),
            prefix: secret[..TOKEN_PREFIX.len() + 8].to_owned(),
            scope,
            devices,
            created_at: now,
            revoked_at: None,
        },
        secret,
        hash,
    })
}

/// Who is calling: the token's scope and device limit, or everything when auth is off.
#[derive(Debug, Clone, PartialEq)]
pub struct Principal {
    pub token: Option<Uuid>,
    pub scope: Scope,
    pub devices: Option<Vec<String>>,
}

impl Principal {
    /// Auth is off: full access.
    pub fn open() -> Self {
        Self {
            token: None,
            scope: Scope::Admin,
            devices: None,
        }
    }

    /// The device limit, if any.
    pub fn only(&self) -> Option<&[String]> {
        self.devices.as_deref()
    }

    /// May it see this device's documents?
    pub fn sees_device(&self, serial: &str) -> bool {
        self.devices
            .as_ref()
            .is_none_or(|d| d.iter().any(|s| s == serial))
    }

    /// May it see a job filed for `device` (a device-scoped token: only its devices' jobs)?
    pub fn sees_job(&self, device: Option<&str>) -> bool {
        match (&self.devices, device) {
            (None, _) => true,
            (Some(_), None) => false,
            (Some(_), Some(d)) => self.sees_device(d),
        }
    }

    /// May it see a dataset uploaded for `ds_devices` (`None`: uploaded fleet-wide)?
    pub fn sees_dataset(&self, ds_devices: Option<&[String]>) -> bool {
        match (&self.devices, ds_devices) {
            (None, _) => true,
            (Some(_), None) => false,
            (Some(mine), Some(theirs)) => theirs.iter().any(|t| mine.contains(t)),
        }
    }
}

/// Handlers take the caller as an argument; it is put there by [`authenticate`]. Missing —
/// a route the middleware treats as public — means no access: fail closed.
impl<S: Send + Sync> FromRequestParts<S> for Principal {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, Self::Rejection> {
        parts
            .extensions
            .get::<Principal>()
            .cloned()
            .ok_or_else(|| ApiError::new("unauthorized", "this route needs a bearer token"))
    }
}

/// Routes anyone may call: health, the API description, the problem catalogue and the
/// dashboard's static files (they hold no data; the page asks for a token itself).
fn is_public(path: &str, metrics_public: bool) -> bool {
    matches!(path, "/" | "/healthz" | "/readyz" | "/openapi.json" | "/ui")
        || path.starts_with("/ui/")
        || path.starts_with("/docs")
        || path.starts_with("/problems/")
        || (metrics_public && path == "/metrics")
}

/// The scope a request needs.
fn required_scope(method: &Method, path: &str) -> Scope {
    if path == "/v1/tokens" || path.starts_with("/v1/tokens/") {
        Scope::Admin
    } else if matches!(*method, Method::GET | Method::HEAD | Method::OPTIONS) {
        Scope::Read
    } else {
        Scope::Write
    }
}

/// Middleware: find the caller, check the scope and the rate, and hand the [`Principal`]
/// to the handlers.
pub async fn authenticate(State(state): State<AppState>, mut req: Request, next: Next) -> Response {
    let cfg = state.config();
    if !cfg.auth_required() {
        req.extensions_mut().insert(Principal::open());
        return next.run(req).await;
    }
    let path = req.uri().path().to_owned();
    if is_public(&path, cfg.metrics_public) || req.method() == Method::OPTIONS {
        return next.run(req).await;
    }
    let secret = req
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| {
            v.strip_prefix("Bearer ")
                .or_else(|| v.strip_prefix("bearer "))
        })
        .map(str::trim);
    let Some(secret) = secret.filter(|s| s.starts_with(TOKEN_PREFIX) && s.len() < 200) else {
        return unauthorized("send `Authorization: Bearer clp_…` (see `caliper token create`)");
    };
    let hash = crate::document::sha256_hex(secret.as_bytes());
    let cache = state.token_cache();
    let token = match cache.get(&hash) {
        Some(t) => t,
        None => {
            let generation = cache.generation();
            match state.store().token_by_hash(&hash).await {
                Ok(Some(t)) if t.revoked_at.is_none() => {
                    cache.put(&hash, &t, generation);
                    t
                }
                Ok(_) => return unauthorized("the token is unknown or revoked"),
                Err(e) => return ApiError::from(e).into_response(),
            }
        }
    };
    let need = required_scope(req.method(), &path);
    if token.scope < need {
        return ApiError::new(
            "forbidden",
            format!(
                "this request needs a token with scope {} (this one has {})",
                need.as_str(),
                token.scope.as_str()
            ),
        )
        .into_response();
    }
    if let Err(wait) = state.rate_limiter().check(token.id, cfg) {
        let mut e = ApiError::new(
            "rate_limited",
            format!(
                "over {} requests per second for this token; retry in {wait} s",
                cfg.rate_limit_per_sec
            ),
        );
        e.retry_after = Some(wait);
        return e.into_response();
    }
    req.extensions_mut().insert(Principal {
        token: Some(token.id),
        scope: token.scope,
        devices: token.devices,
    });
    next.run(req).await
}

fn unauthorized(detail: &str) -> Response {
    let mut resp = ApiError::new("unauthorized", detail).into_response();
    resp.headers_mut().insert(
        header::WWW_AUTHENTICATE,
        HeaderValue::from_static("Bearer realm=\"caliper\""),
    );
    resp
}

/// Token buckets per token, in this process (each replica limits what it serves; behind a
/// balancer spreading load evenly, the fleet-wide limit is replicas × the rate).
#[derive(Default)]
pub struct RateLimiter {
    buckets: Mutex<HashMap<Uuid, (f64, Instant)>>,
}

impl RateLimiter {
    /// Take one request from `token`'s bucket, or say how many seconds until one is free.
    pub fn check(&self, token: Uuid, cfg: &crate::config::Config) -> Result<(), u64> {
        if cfg.rate_limit_per_sec == 0 {
            return Ok(());
        }
        let rate = f64::from(cfg.rate_limit_per_sec);
        let burst = f64::from(cfg.rate_limit_burst.max(1));
        let now = Instant::now();
        let mut map = self
            .buckets
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        // Bounded memory: forget buckets that have refilled (idle tokens) when the map grows.
        if map.len() > 10_000 {
            map.retain(|_, (level, at)| {
                *level + now.duration_since(*at).as_secs_f64() * rate < burst
            });
        }
        let (level, at) = map.entry(token).or_insert((burst, now));
        *level = (*level + now.duration_since(*at).as_secs_f64() * rate).min(burst);
        *at = now;
        if *level >= 1.0 {
            *level -= 1.0;
            Ok(())
        } else {
            Err(((1.0 - *level) / rate).ceil().max(1.0) as u64)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_are_prefixed_random_and_hashed() {
        let a = generate("ci", Scope::Write, None, 0).expect("token");
        let b = generate("ci", Scope::Write, None, 0).expect("token");
        assert!(a.secret.starts_with("clp_") && a.secret.len() == 44);
        assert_ne!(a.secret, b.secret);
        assert_eq!(a.hash, crate::document::sha256_hex(a.secret.as_bytes()));
        assert!(a.secret.starts_with(&a.record.prefix));
        assert!(generate(" ", Scope::Read, None, 0).is_err());
        assert!(generate("x", Scope::Admin, Some(vec!["d1".into()]), 0).is_err());
        assert!(generate("x", Scope::Read, Some(vec!["../d".into()]), 0).is_err());
        assert!(generate("x", Scope::Read, Some(vec![]), 0).is_err());
    }

    #[test]
    fn device_scoped_principals_see_only_their_devices() {
        let p = Principal {
            token: None,
            scope: Scope::Write,
            devices: Some(vec!["cam-1".into()]),
        };
        assert!(p.sees_device("cam-1") && !p.sees_device("cam-2"));
        assert!(p.sees_job(Some("cam-1")) && !p.sees_job(None) && !p.sees_job(Some("cam-2")));
        assert!(p.sees_dataset(Some(&["cam-1".to_string()])));
        assert!(!p.sees_dataset(None) && !p.sees_dataset(Some(&["cam-2".to_string()])));
        let open = Principal::open();
        assert!(open.sees_device("any") && open.sees_job(None) && open.sees_dataset(None));
    }

    #[test]
    fn rate_limiter_refuses_past_the_burst_and_says_when() {
        let cfg = crate::config::Config {
            rate_limit_per_sec: 1,
            rate_limit_burst: 3,
            ..Default::default()
        };
        let l = RateLimiter::default();
        let t = Uuid::now_v7();
        for _ in 0..3 {
            assert!(l.check(t, &cfg).is_ok());
        }
        assert_eq!(l.check(t, &cfg), Err(1));
        // Another token has its own bucket.
        assert!(l.check(Uuid::now_v7(), &cfg).is_ok());
    }
}
