//! DSO calibration files (Engel, Koltun & Cremers, "Direct Sparse Odometry", PAMI 2018; file
//! layouts of tum-vision/mono_dataset_code): `pcalib.txt`, `vignette.png`, `times.txt`.
//! Writers produce exactly what DSO accepts; readers validate with messages that say what to
//! fix.

use std::fmt::Write as _;
use std::io::Cursor;

use image::{ImageBuffer, ImageFormat, Luma};

use super::PhotoImage;
use super::response::InverseResponse;
use super::vignette::VignetteModel;
use crate::error::{CoreError, CoreResult};
use crate::io::ImageLimits;

/// `pcalib.txt`: one line of the inverse response over 0..255 scaled to 0..255 (DSO rescales
/// anyway), strictly increasing. Tables with other than 256 levels are resampled to 256.
pub fn write_pcalib(inverse: &InverseResponse) -> String {
    let t = if inverse.values.len() == 256 {
        inverse.clone()
    } else {
        inverse.resample(256)
    };
    let mut s = String::with_capacity(256 * 12);
    for (i, v) in t.values.iter().enumerate() {
        if i > 0 {
            s.push(' ');
        }
        let _ = write!(s, "{:.9}", v * 255.0);
    }
    s.push('\n');
    s
}

/// Parse a `pcalib.txt`: ≥ 256 whitespace-separated finite numbers on the first line,
/// strictly increasing (the first offending index is named). Returns the table normalised to
/// `[0, 1]` (first value 0, last 1) with as many levels as the file has values.
pub fn read_pcalib(text: &str) -> CoreResult<InverseResponse> {
    let line = text
        .lines()
        .find(|l| !l.trim().is_empty())
        .ok_or_else(|| CoreError::input("pcalib.txt is empty"))?;
    let mut vals = Vec::new();
    for (i, tok) in line.split_whitespace().enumerate() {
        let v: f64 = tok.parse().map_err(|_| {
            CoreError::input(format!("pcalib.txt value {i} (`{tok}`) is not a number"))
        })?;
        if !v.is_finite() {
            return Err(CoreError::input(format!(
                "pcalib.txt value {i} is not finite"
            )));
        }
        vals.push(v);
    }
    if vals.len() < 256 {
        return Err(CoreError::input(format!(
            "pcalib.txt has {} values; DSO needs at least 256",
            vals.len()
        )));
    }
    if let Some(i) = vals.windows(2).position(|w| w[1] <= w[0]) {
        return Err(CoreError::input(format!(
            "pcalib.txt is not strictly increasing at index {}: {} follows {} (DSO rejects it)",
            i + 1,
            vals[i + 1],
            vals[i]
        )));
    }
    let (a, b) = (vals[0], vals[vals.len() - 1]);
    InverseResponse::new(vals.iter().map(|v| (v - a) / (b - a)).collect())
}

/// 16-bit grey PNG of a map `width × height`, scaled so that its maximum is 65535 (DSO's and
/// `vignetteCalib`'s convention: only the relative attenuation matters).
pub fn map_png16(width: usize, height: usize, map: &[f32]) -> CoreResult<Vec<u8>> {
    if map.len() != width * height || map.is_empty() {
        return Err(CoreError::input("map size does not match width × height"));
    }
    let max = map.iter().copied().fold(0.0f32, f32::max);
    if !(max.is_finite() && max > 0.0) {
        return Err(CoreError::input("map has no positive finite maximum"));
    }
    let data: Vec<u16> = map
        .iter()
        .map(|v| ((v / max).clamp(0.0, 1.0) * 65535.0).round() as u16)
        .collect();
    let buf: ImageBuffer<Luma<u16>, Vec<u16>> =
        ImageBuffer::from_raw(width as u32, height as u32, data)
            .ok_or_else(|| CoreError::input("map size does not match width × height"))?;
    let mut out = Vec::new();
    buf.write_to(&mut Cursor::new(&mut out), ImageFormat::Png)
        .map_err(|e| CoreError::input(format!("cannot encode PNG: {e}")))?;
    Ok(out)
}

/// DSO `vignette.png` of a model: 16-bit, the model's image size, `V / max V · 65535`.
pub fn write_vignette_png(model: &VignetteModel) -> CoreResult<Vec<u8>> {
    model.validate()?;
    map_png16(model.width, model.height, &model.map())
}

/// A dense attenuation map read from a `vignette.png`, normalised to maximum 1.
#[derive(Debug, Clone, PartialEq)]
pub struct VignetteMap {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Attenuation per pixel, row-major, max 1.
    pub data: Vec<f32>,
}

/// Read a DSO `vignette.png` (8- or 16-bit grey). Rejects maps with zero pixels (DSO divides
/// by them) and, if `expect` is given, a size other than the images'.
pub fn read_vignette_png(
    bytes: &[u8],
    limits: &ImageLimits,
    expect: Option<(usize, usize)>,
) -> CoreResult<VignetteMap> {
    let img = PhotoImage::decode(bytes, limits)?;
    if let Some((w, h)) = expect
        && (img.width, img.height) != (w, h)
    {
        return Err(CoreError::input(format!(
            "vignette.png is {}×{} but the images are {w}×{h}",
            img.width, img.height
        )));
    }
    if let Some(i) = img.data.iter().position(|&v| v == 0) {
        return Err(CoreError::input(format!(
            "vignette.png pixel ({}, {}) is 0: the attenuation must be positive everywhere",
            i % img.width,
            i / img.width
        )));
    }
    let max = f32::from(img.data.iter().copied().max().unwrap_or(1));
    Ok(VignetteMap {
        width: img.width,
        height: img.height,
        data: img.data.iter().map(|&v| f32::from(v) / max).collect(),
    })
}

/// One line of `times.txt`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct TimeEntry {
    /// Frame id (image file stem, e.g. `00042`).
    pub id: String,
    /// Timestamp in seconds.
    pub timestamp: f64,
    /// Exposure time in milliseconds.
    pub exposure_ms: f64,
}

/// `times.txt` in the TUM monoVO layout: `id timestamp exposure_ms` per line.
pub fn write_times(entries: &[TimeEntry]) -> String {
    let mut s = String::with_capacity(entries.len() * 32);
    for e in entries {
        let _ = writeln!(s, "{} {:.6} {:.6}", e.id, e.timestamp, e.exposure_ms);
    }
    s
}

/// Parse `times.txt`: three columns per non-empty line (`#` comments allowed), exposure > 0.
pub fn read_times(text: &str) -> CoreResult<Vec<TimeEntry>> {
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let cols: Vec<&str> = line.split_whitespace().collect();
        if cols.len() != 3 {
            return Err(CoreError::input(format!(
                "times.txt line {}: expected `id timestamp exposure_ms`, got {} columns",
                n + 1,
                cols.len()
            )));
        }
        let num = |s: &str, what: &str| -> CoreResult<f64> {
            s.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    CoreError::input(format!(
                        "times.txt line {}: {what} `{s}` is not a number",
                        n + 1
                    ))
                })
        };
        let timestamp = num(cols[1], "timestamp")?;
        let exposure_ms = num(cols[2], "exposure")?;
        if exposure_ms <= 0.0 {
            return Err(CoreError::input(format!(
                "times.txt line {}: exposure {exposure_ms} must be > 0",
                n + 1
            )));
        }
        out.push(TimeEntry {
            id: cols[0].to_string(),
            timestamp,
            exposure_ms,
        });
    }
    if out.is_empty() {
        return Err(CoreError::input("times.txt has no entries"));
    }
    Ok(out)
}
