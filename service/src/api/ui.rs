//! The browser dashboard under `/ui`: static files compiled into the binary (no CDN, works
//! offline), served with a strict Content-Security-Policy. The page is built only on the
//! public API, so it is not part of the OpenAPI description.
//!
//! The files live in `service/ui/`; [`ASSETS`] lists every one of them (a test checks the list
//! against the directory, so a new file cannot be forgotten).

use axum::Router;
use axum::extract::Path;
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Redirect, Response};
use axum::routing::get;

use crate::error::ApiError;
use crate::state::AppState;

macro_rules! assets {
    ($($path:literal => $media:literal),* $(,)?) => {
        /// Every file of the dashboard: (path under `/ui/`, media type, bytes).
        pub const ASSETS: &[(&str, &str, &[u8])] = &[
            $(($path, $media, include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/ui/", $path)))),*
        ];
    };
}

assets! {
    "index.html" => "text/html; charset=utf-8",
    "style.css" => "text/css; charset=utf-8",
    "js/api.js" => "text/javascript; charset=utf-8",
    "js/app.js" => "text/javascript; charset=utf-8",
    "js/charts.js" => "text/javascript; charset=utf-8",
    "js/device.js" => "text/javascript; charset=utf-8",
    "js/dom.js" => "text/javascript; charset=utf-8",
    "js/fleet.js" => "text/javascript; charset=utf-8",
    "js/form.js" => "text/javascript; charset=utf-8",
    "js/jobs.js" => "text/javascript; charset=utf-8",
    "js/quality.js" => "text/javascript; charset=utf-8",
    "js/result.js" => "text/javascript; charset=utf-8",
    "js/run.js" => "text/javascript; charset=utf-8",
    "vendor/uPlot.iife.min.js" => "text/javascript; charset=utf-8",
    "vendor/uPlot.min.css" => "text/css; charset=utf-8",
    "vendor/uPlot.LICENSE" => "text/plain; charset=utf-8",
}

/// Only our own origin, no inline script or style, no framing: an injected string can
/// neither run nor load anything. `blob:` images are artifacts fetched with the token.
const CSP: &str = "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; \
     connect-src 'self'; font-src 'self'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'";

/// Routes of the dashboard (merged outside the OpenAPI router).
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/", get(|| async { Redirect::to("/ui/") }))
        .route("/ui", get(|| async { Redirect::to("/ui/") }))
        .route("/ui/", get(|| async { asset("index.html") }))
        .route(
            "/ui/{*path}",
            get(|Path(path): Path<String>| async move { asset(&path) }),
        )
}

fn asset(path: &str) -> Response {
    let Some((_, media, bytes)) = ASSETS.iter().find(|(p, _, _)| *p == path) else {
        return ApiError::new("route_not_found", format!("no dashboard file {path:?}"))
            .into_response();
    };
    let mut resp = (StatusCode::OK, *bytes).into_response();
    let h = resp.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(media));
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(CSP),
    );
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    // The files change only with the binary; revalidate so an upgrade shows at once.
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    resp
}

#[cfg(test)]
mod tests {
    use super::ASSETS;

    /// Every file under `service/ui/` is served, and every served file exists.
    #[test]
    fn asset_list_matches_the_directory() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("ui");
        let mut on_disk = Vec::new();
        let mut stack = vec![root.clone()];
        while let Some(dir) = stack.pop() {
            for e in std::fs::read_dir(&dir).expect("ui dir readable") {
                let p = e.expect("entry").path();
                if p.is_dir() {
                    stack.push(p);
                } else if let Ok(rel) = p.strip_prefix(&root) {
                    on_disk.push(rel.to_string_lossy().replace('\\', "/"));
                }
            }
        }
        on_disk.sort();
        let mut listed: Vec<String> = ASSETS.iter().map(|(p, _, _)| (*p).to_owned()).collect();
        listed.sort();
        assert_eq!(listed, on_disk, "update ASSETS in service/src/api/ui.rs");
    }
}
