//! A clip from the blob store as a seekable local file.
//!
//! Demuxing MP4 needs to seek (the `moov` box may sit after `mdat`) while blob stores stream,
//! so a clip is copied once to an anonymous temporary file (deleted when dropped) and never
//! held in memory.

use std::fs::File;
use std::io::{BufReader, Seek};

use super::{JobError, JobInput};
use crate::store::DatasetFile;

/// A spooled clip: open it as many times as the job reads it.
pub(crate) struct SpooledClip {
    file: File,
    name: String,
}

impl SpooledClip {
    /// Copies `f` of `input` to a temporary file.
    pub(crate) fn new(input: &JobInput, f: &DatasetFile) -> Result<Self, JobError> {
        let name = f.name.clone();
        let mut file = tempfile::tempfile().map_err(|e| storage(&name, e))?;
        let mut src = (input.open)(f).map_err(|e| storage(&name, e))?;
        std::io::copy(&mut src, &mut file).map_err(|e| storage(&name, e))?;
        Ok(Self { file, name })
    }

    /// A reader from the start of the clip.
    pub(crate) fn reader(&mut self) -> Result<BufReader<File>, JobError> {
        self.file.rewind().map_err(|e| storage(&self.name, e))?;
        let f = self.file.try_clone().map_err(|e| storage(&self.name, e))?;
        Ok(BufReader::new(f))
    }
}

fn storage(name: &str, e: std::io::Error) -> JobError {
    JobError::Transient(format!("storage: cannot read {name}: {e}"))
}

/// The one clip of a video dataset, if the input is one.
pub(crate) fn single_clip(input: &JobInput) -> Option<&DatasetFile> {
    match input.files.as_slice() {
        [f] if f.media_type.starts_with("video/") => Some(f),
        _ => None,
    }
}

/// A decoder error as the job's error: cancellation stays cancellation, anything else is the
/// clip's fault (`invalid_input`).
pub(crate) fn video_error(e: caliper_core::video::VideoError) -> JobError {
    match e {
        caliper_core::video::VideoError::Canceled => JobError::Canceled,
        other => JobError::from(caliper_core::CoreError::input(other.to_string())),
    }
}
