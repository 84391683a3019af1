//! Unpacking uploaded zip archives of images into temporary files: the checks live in
//! `caliper_core::io::archive` (fuzzed); here each entry is streamed to a temporary file while
//! being hashed, and handed to the caller's `check` as soon as it is complete.

use std::fs::File;
use std::io::{Read, Write};
use std::path::Path;

use caliper_core::io::archive::{ArchiveError, ArchiveFault, ArchiveLimits};
use sha2::{Digest, Sha256};

use crate::error::ApiError;

/// One unpacked entry, written to a temporary file in `tmp_dir`.
#[derive(Debug)]
pub struct Entry {
    pub name: String,
    pub sha256: String,
    pub size: u64,
    pub file: tempfile::NamedTempFile,
}

/// Unpack every file entry of `archive` into temporary files (blocking; call from a blocking
/// thread). `check` sees each entry as soon as it is written and may refuse it: a bad entry
/// stops the unpacking there.
pub fn unpack(
    archive: &Path,
    archive_name: &str,
    tmp_dir: &Path,
    limits: ArchiveLimits,
    check: &dyn Fn(&Entry) -> Result<(), ApiError>,
) -> Result<Vec<Entry>, ApiError> {
    let file = File::open(archive).map_err(ApiError::internal)?;
    let size = file.metadata().map_err(ApiError::internal)?.len();
    let mut out = Vec::new();
    // The refusal of `check`, kept whole (its own code) while core sees a plain refusal.
    let mut refused: Option<ApiError> = None;
    let storage = |e: std::io::Error| ArchiveError {
        fault: ArchiveFault::Storage,
        message: e.to_string(),
    };
    let mut sink = |name: &str, data: &mut dyn Read| -> Result<u64, ArchiveError> {
        let mut tmp = tempfile::NamedTempFile::new_in(tmp_dir).map_err(storage)?;
        let mut hasher = Sha256::new();
        let mut buf = vec![0u8; 256 << 10];
        let mut written: u64 = 0;
        loop {
            let n = data.read(&mut buf).map_err(|e| ArchiveError {
                fault: ArchiveFault::Corrupt,
                message: format!("{archive_name}: {name}: {e}"),
            })?;
            if n == 0 {
                break;
            }
            written += n as u64;
            hasher.update(&buf[..n]);
            tmp.write_all(&buf[..n]).map_err(storage)?;
        }
        let e = Entry {
            name: name.to_string(),
            sha256: hex::encode(hasher.finalize()),
            size: written,
            file: tmp,
        };
        if let Err(err) = check(&e) {
            let message = err.detail.clone().unwrap_or_default();
            refused = Some(err);
            return Err(ArchiveError {
                fault: ArchiveFault::Refused,
                message,
            });
        }
        out.push(e);
        Ok(written)
    };
    let result = caliper_core::io::archive::unpack(file, size, archive_name, limits, &mut sink);
    match result {
        Ok(()) => Ok(out),
        Err(e) => Err(match e.fault {
            ArchiveFault::Refused => refused.unwrap_or_else(|| ApiError::internal(e.message)),
            ArchiveFault::Storage => ApiError::internal(e.message),
            ArchiveFault::TooManyEntries => ApiError::new("too_many_files", e.message),
            ArchiveFault::DuplicateName => ApiError::new("duplicate_name", e.message),
            ArchiveFault::UnsafePath => ApiError::new("zip_unsafe_path", e.message),
            ArchiveFault::Bomb => ApiError::new("zip_bomb", e.message),
            ArchiveFault::Corrupt => ApiError::new("corrupt_archive", e.message),
        }),
    }
}
