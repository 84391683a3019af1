//! Safe unpacking of zip archives of images.
//!
//! Archives are untrusted: entry count, declared and actual uncompressed sizes, compression
//! ratios and paths are all checked, and decompression is capped at the declared size + 1
//! byte, so an archive that lies about its sizes is caught without filling the disk.

use std::fs::File;
use std::io::{Read, Write};
use std::path::Path;

use sha2::{Digest, Sha256};

use crate::error::ApiError;

/// Limits applied to one archive.
#[derive(Debug, Clone, Copy)]
pub struct ArchiveLimits {
    pub max_entries: usize,
    pub max_total_bytes: u64,
    pub max_ratio: u64,
}

/// One unpacked entry, written to a temporary file in `tmp_dir`.
#[derive(Debug)]
pub struct Entry {
    pub name: String,
    pub sha256: String,
    pub size: u64,
    pub file: tempfile::NamedTempFile,
}

fn is_ignorable(name: &str) -> bool {
    let base = name.rsplit('/').next().unwrap_or(name);
    name.starts_with("__MACOSX/") || base.starts_with('.') || base.eq_ignore_ascii_case("thumbs.db")
}

/// Unpack every file entry of `archive` into temporary files (blocking; call from a blocking
/// thread). Directory entries and OS metadata (`__MACOSX/`, dot files) are skipped.
pub fn unpack(
    archive: &Path,
    archive_name: &str,
    tmp_dir: &Path,
    limits: ArchiveLimits,
) -> Result<Vec<Entry>, ApiError> {
    let corrupt =
        |e: zip::result::ZipError| ApiError::new("corrupt_archive", format!("{archive_name}: {e}"));
    let file = File::open(archive).map_err(ApiError::internal)?;
    let compressed_total = file.metadata().map_err(ApiError::internal)?.len().max(1);
    let mut zip = zip::ZipArchive::new(file).map_err(corrupt)?;
    if zip.len() > limits.max_entries {
        return Err(ApiError::new(
            "too_many_files",
            format!(
                "{archive_name} has {} entries; the limit is {}",
                zip.len(),
                limits.max_entries
            ),
        ));
    }
    // First pass over the central directory: paths and declared sizes, before writing anything.
    let mut declared_total: u64 = 0;
    for i in 0..zip.len() {
        let entry = zip.by_index_raw(i).map_err(corrupt)?;
        let raw_name = entry.name().map_err(corrupt)?.to_string();
        if entry.enclosed_name().is_none() || raw_name.contains('\\') {
            return Err(ApiError::new(
                "zip_unsafe_path",
                format!(
                    "{archive_name}: entry {raw_name:?} escapes the archive (absolute path or `..`)"
                ),
            ));
        }
        if entry.is_dir() {
            continue;
        }
        let ratio = entry.size() / entry.compressed_size().max(1);
        if ratio > limits.max_ratio {
            return Err(ApiError::new(
                "zip_bomb",
                format!(
                    "{archive_name}: entry {raw_name:?} expands {ratio}× (limit {}×)",
                    limits.max_ratio
                ),
            ));
        }
        declared_total = declared_total.saturating_add(entry.size());
    }
    if declared_total > limits.max_total_bytes
        || declared_total / compressed_total > limits.max_ratio
    {
        return Err(ApiError::new(
            "zip_bomb",
            format!(
                "{archive_name}: expands to {declared_total} bytes from {compressed_total} (limits: {} bytes, {}×)",
                limits.max_total_bytes, limits.max_ratio
            ),
        ));
    }
    let mut out = Vec::new();
    let mut actual_total: u64 = 0;
    for i in 0..zip.len() {
        let mut entry = zip.by_index(i).map_err(corrupt)?;
        if entry.is_dir() {
            continue;
        }
        let name = entry
            .enclosed_name()
            .map(|p| p.to_string_lossy().replace('\\', "/"))
            .unwrap_or_default();
        if is_ignorable(&name) {
            continue;
        }
        let declared = entry.size();
        let mut tmp = tempfile::NamedTempFile::new_in(tmp_dir).map_err(ApiError::internal)?;
        let mut hasher = Sha256::new();
        let mut buf = vec![0u8; 256 << 10];
        let mut written: u64 = 0;
        let mut limited = (&mut entry).take(declared + 1);
        loop {
            let n = limited.read(&mut buf).map_err(|e| {
                ApiError::new("corrupt_archive", format!("{archive_name}: {name}: {e}"))
            })?;
            if n == 0 {
                break;
            }
            written += n as u64;
            if written > declared {
                return Err(ApiError::new(
                    "zip_bomb",
                    format!("{archive_name}: entry {name:?} is larger than it declares"),
                ));
            }
            hasher.update(&buf[..n]);
            tmp.write_all(&buf[..n]).map_err(ApiError::internal)?;
        }
        actual_total += written;
        if actual_total > limits.max_total_bytes {
            return Err(ApiError::new(
                "zip_bomb",
                format!("{archive_name}: too large when unpacked"),
            ));
        }
        out.push(Entry {
            name,
            sha256: hex::encode(hasher.finalize()),
            size: written,
            file: tmp,
        });
    }
    Ok(out)
}
