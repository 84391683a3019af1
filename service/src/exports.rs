//! Export formats of documents (`?format=`): rendered from a stored document on request.

use serde_json::Value;

use crate::error::ApiError;

/// Render a document in an export format; returns the text.
pub fn render(doc: &Value, format: &str) -> Result<String, ApiError> {
    let schema = doc.get("schema").and_then(Value::as_str).unwrap_or("");
    Err(ApiError::new(
        "unsupported_format",
        format!("documents of schema {schema:?} have no {format:?} export"),
    )
    .with_field("format"))
}
