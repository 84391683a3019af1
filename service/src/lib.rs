//! Caliper's service: the HTTP API, the job queue and worker pool, storage, and the
//! offline runner behind the `caliper` binary.
//!
//! Layout: [`api`] (one module per resource), [`jobs`] (job kinds and workers), [`store`]
//! (the `Store` trait and its SQLite implementation), [`blobs`] (content-addressed files),
//! [`ingest`] (upload validation), [`server`] (start/stop), [`offline`] (`caliper run`).

pub mod api;
pub mod auth;
pub mod blob_gc;
pub mod blobs;
pub mod clock;
pub mod config;
pub mod document;
pub mod document_diff;
pub mod error;
pub mod exports;
pub mod http_server;
pub mod ingest;
pub mod job_watch;
pub mod jobs;
pub mod offline;
pub mod server;
pub mod state;
pub mod store;
pub mod token_cache;
pub mod token_cli;

pub use api::{app, openapi};
pub use config::Config;
pub use state::AppState;

/// The OpenAPI document as pretty JSON with a trailing newline (what `caliper openapi` prints
/// and `openapi/openapi.json` holds).
pub fn openapi_json() -> String {
    let mut s = openapi()
        .to_pretty_json()
        .unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"));
    s.push('\n');
    s
}
