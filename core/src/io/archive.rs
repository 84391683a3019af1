//! Safe reading of zip archives of images.
//!
//! Archives are untrusted: entry count, duplicate names, declared and actual uncompressed
//! sizes, compression ratios and paths are all checked, decompression of each entry is capped
//! at its declared size + 1 byte (so an archive that lies about its sizes is caught without
//! filling the disk), and the running total is checked while data flows. Entries are handed to
//! a caller's sink one by one as streams; the sink may refuse an entry, which stops the
//! unpacking there instead of after gigabytes of later entries.

use std::io::{Read, Seek};

/// Limits applied to one archive.
#[derive(Debug, Clone, Copy)]
pub struct ArchiveLimits {
    pub max_entries: usize,
    pub max_total_bytes: u64,
    pub max_ratio: u64,
}

/// What went wrong with an archive; the service maps each to a problem code.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArchiveFault {
    /// More entries than allowed (`too_many_files`).
    TooManyEntries,
    /// Two entries with one name (`duplicate_name`).
    DuplicateName,
    /// An absolute path, `..`, or a backslash (`zip_unsafe_path`).
    UnsafePath,
    /// Expands beyond the limits, or lies about its sizes (`zip_bomb`).
    Bomb,
    /// Not a readable zip (`corrupt_archive`).
    Corrupt,
    /// The sink refused an entry (its own message).
    Refused,
    /// The sink could not store an entry (its disk, not the archive, is at fault).
    Storage,
}

/// An archive that cannot be unpacked, with a message naming the entry at fault.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct ArchiveError {
    pub fault: ArchiveFault,
    pub message: String,
}

fn fail(fault: ArchiveFault, message: String) -> ArchiveError {
    ArchiveError { fault, message }
}

/// OS metadata that is skipped (`__MACOSX/`, dot files, `Thumbs.db`).
fn is_ignorable(name: &str) -> bool {
    let base = name.rsplit('/').next().unwrap_or(name);
    name.starts_with("__MACOSX/") || base.starts_with('.') || base.eq_ignore_ascii_case("thumbs.db")
}

/// Unpack every file entry of the archive `reader` (of `compressed_size` bytes, named
/// `archive_name` in messages): `sink(name, data)` receives each non-empty file entry (name
/// with `/` separators) and returns how many bytes it consumed, or refuses it. Directory
/// entries and OS metadata are skipped.
pub fn unpack<R: Read + Seek>(
    reader: R,
    compressed_size: u64,
    archive_name: &str,
    limits: ArchiveLimits,
    sink: &mut dyn FnMut(&str, &mut dyn Read) -> Result<u64, ArchiveError>,
) -> Result<(), ArchiveError> {
    use ArchiveFault::*;
    let corrupt = |e: zip::result::ZipError| fail(Corrupt, format!("{archive_name}: {e}"));
    let compressed_total = compressed_size.max(1);
    let mut zip = zip::ZipArchive::new(reader).map_err(corrupt)?;
    if zip.len() > limits.max_entries {
        return Err(fail(
            TooManyEntries,
            format!(
                "{archive_name} has {} entries; the limit is {}",
                zip.len(),
                limits.max_entries
            ),
        ));
    }
    // The zip reader indexes entries by name, so a second `x.png` would silently replace the
    // first: names identify images in results, refuse instead.
    if zip.has_duplicate_names() {
        return Err(fail(
            DuplicateName,
            format!(
                "{archive_name}: two entries have the same name; names identify images in results"
            ),
        ));
    }
    // First pass over the central directory: paths and declared sizes, before reading data.
    let mut declared_total: u64 = 0;
    for i in 0..zip.len() {
        let entry = zip.by_index_raw(i).map_err(corrupt)?;
        let raw_name = entry.name().map_err(corrupt)?.to_string();
        // Absolute paths are refused, not made relative.
        let absolute = raw_name.starts_with('/') || raw_name.as_bytes().get(1) == Some(&b':');
        if absolute || entry.enclosed_name().is_none() || raw_name.contains('\\') {
            return Err(fail(
                UnsafePath,
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
            return Err(fail(
                Bomb,
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
        return Err(fail(
            Bomb,
            format!(
                "{archive_name}: expands to {declared_total} bytes from {compressed_total} (limits: {} bytes, {}×)",
                limits.max_total_bytes, limits.max_ratio
            ),
        ));
    }
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
        if is_ignorable(&name) || entry.size() == 0 {
            continue;
        }
        let declared = entry.size();
        // The sink reads at most the declared size + 1: one byte more means the entry lies.
        let budget = declared.saturating_add(1).min(
            limits
                .max_total_bytes
                .saturating_sub(actual_total)
                .saturating_add(1),
        );
        let mut limited = (&mut entry).take(budget);
        let written = sink(&name, &mut limited)?;
        if written > declared {
            return Err(fail(
                Bomb,
                format!("{archive_name}: entry {name:?} is larger than it declares"),
            ));
        }
        actual_total += written;
        if actual_total > limits.max_total_bytes {
            return Err(fail(
                Bomb,
                format!("{archive_name}: too large when unpacked"),
            ));
        }
    }
    Ok(())
}
