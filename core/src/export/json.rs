//! Caliper's own JSON document: the full [`Calibration`] plus what the other formats carry.
//!
//! The field list is [`CalibrationDocument`]; `format` and `format_version` let a reader
//! recognise the document and refuse one from a newer, incompatible Caliper.

use serde::{Deserialize, Serialize};

use super::ExportInput;
use crate::calib::{BoardGeometry, CalibOptions, Calibration};
use crate::error::{CoreError, CoreResult};

/// Value of [`CalibrationDocument::format`].
pub const CALIBRATION_DOCUMENT_FORMAT: &str = "caliper-calibration";
/// Current [`CalibrationDocument::format_version`]; bumped on incompatible changes.
pub const CALIBRATION_DOCUMENT_VERSION: u32 = 1;

/// The `json` export, as read back by [`read_json`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct CalibrationDocument {
    /// Always [`CALIBRATION_DOCUMENT_FORMAT`].
    pub format: String,
    /// [`CALIBRATION_DOCUMENT_VERSION`] of the writer.
    pub format_version: u32,
    /// The camera's name ([`ExportInput::camera_name`]).
    pub camera_name: String,
    /// When it was calibrated, as the caller gave it.
    pub calibration_time: Option<String>,
    /// The board.
    pub board: Option<BoardGeometry>,
    /// The options of the solve, when known.
    pub options: Option<CalibOptions>,
    /// The full result.
    pub calibration: Calibration,
}

/// Borrowing twin of [`CalibrationDocument`] so that writing does not clone the calibration.
/// The round-trip tests keep the two in step.
#[derive(Serialize)]
struct DocumentRef<'a> {
    format: &'a str,
    format_version: u32,
    camera_name: &'a str,
    calibration_time: Option<&'a str>,
    board: Option<&'a BoardGeometry>,
    options: Option<&'a CalibOptions>,
    calibration: &'a Calibration,
}

pub(super) fn write(input: &ExportInput<'_>) -> CoreResult<String> {
    let doc = DocumentRef {
        format: CALIBRATION_DOCUMENT_FORMAT,
        format_version: CALIBRATION_DOCUMENT_VERSION,
        camera_name: input.camera_name,
        calibration_time: input.calibration_time,
        board: input.board.as_ref(),
        options: input.options,
        calibration: input.calibration,
    };
    let mut text = serde_json::to_string_pretty(&doc)
        .map_err(|e| CoreError::NoSolution(format!("json export failed: {e}")))?;
    text.push('\n');
    Ok(text)
}

/// Reads a `json` export. Errors on malformed JSON, unknown fields, another `format` or a
/// newer `format_version`.
pub fn read_json(text: &str) -> CoreResult<CalibrationDocument> {
    let doc: CalibrationDocument =
        serde_json::from_str(text).map_err(|e| CoreError::input(format!("json: {e}")))?;
    if doc.format != CALIBRATION_DOCUMENT_FORMAT {
        return Err(CoreError::input(format!(
            "json: `format`: expected {CALIBRATION_DOCUMENT_FORMAT:?}, got {:?}",
            doc.format
        )));
    }
    if doc.format_version == 0 || doc.format_version > CALIBRATION_DOCUMENT_VERSION {
        return Err(CoreError::input(format!(
            "json: `format_version`: {} is not supported (this reader knows 1..={})",
            doc.format_version, CALIBRATION_DOCUMENT_VERSION
        )));
    }
    Ok(doc)
}
