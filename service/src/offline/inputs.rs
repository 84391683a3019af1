//! Local input files described as a dataset would describe them (name, hash, size, media type,
//! image header), so that an offline run's document has the same provenance as the service's.

use std::path::PathBuf;

use crate::jobs::RunError;
use crate::store::DatasetFile;

/// Files named on the command line, plus the files of named directories (flagged `true`:
/// non-images among those are skipped rather than refused).
pub fn expand(inputs: &[PathBuf]) -> Result<Vec<(PathBuf, bool)>, RunError> {
    let mut out = Vec::new();
    for p in inputs {
        if p.is_dir() {
            let mut entries: Vec<PathBuf> = std::fs::read_dir(p)?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.is_file())
                .collect();
            entries.sort();
            out.extend(entries.into_iter().map(|e| (e, true)));
        } else if p.is_file() {
            out.push((p.clone(), false));
        } else {
            return Err(RunError::Input(format!("{} does not exist", p.display())));
        }
    }
    if out.is_empty() {
        return Err(RunError::Input("no input files".into()));
    }
    Ok(out)
}

/// Describe local image files as a dataset would (hash, size, validated header).
pub(super) fn image_files(
    paths: &[(PathBuf, bool)],
) -> Result<Vec<(DatasetFile, PathBuf)>, RunError> {
    let limits = crate::config::Config::default().image_limits();
    let mut files = Vec::new();
    let mut names = std::collections::HashSet::new();
    // Files of several directories keep their directory's name (`cam0/0001.png`), as the
    // entries of a zip do: a rig has one directory per camera, with the same file names.
    let dir_of = |p: &PathBuf| {
        p.parent()
            .and_then(|d| d.file_name())
            .map(|d| d.to_string_lossy().into_owned())
    };
    let dirs: std::collections::HashSet<Option<String>> = paths
        .iter()
        .filter(|(_, d)| *d)
        .map(|(p, _)| dir_of(p))
        .collect();
    for (p, from_dir) in paths {
        let bytes = std::fs::read(p)?;
        if *from_dir && !caliper_core::io::sniff(&bytes[..bytes.len().min(64)]).is_image() {
            eprintln!("caliper: skipping {} (not an image)", p.display());
            continue;
        }
        let mut name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| p.display().to_string());
        if *from_dir
            && dirs.len() > 1
            && let Some(d) = dir_of(p)
        {
            name = format!("{d}/{name}");
        }
        if !names.insert(name.clone()) {
            return Err(RunError::Input(format!("two inputs are named {name:?}")));
        }
        let info = caliper_core::io::probe_image(std::io::Cursor::new(&bytes), &limits)
            .map_err(|e| RunError::Input(format!("{}: {e}", p.display())))?;
        files.push((
            DatasetFile {
                name,
                sha256: crate::document::sha256_hex(&bytes),
                size: bytes.len() as u64,
                media_type: format!("image/{}", info.format),
                image: Some(info),
                video: None,
            },
            p.clone(),
        ));
    }
    Ok(files)
}

/// Describe one log file as a dataset would (hash, size, media type from content).
pub(super) fn log_file(paths: &[(PathBuf, bool)]) -> Result<Vec<(DatasetFile, PathBuf)>, RunError> {
    let [(p, _)] = paths else {
        return Err(RunError::Input(format!(
            "an IMU job reads exactly one log, got {} files",
            paths.len()
        )));
    };
    let mut f = std::fs::File::open(p)?;
    let mut head = [0u8; 64];
    let n = std::io::Read::read(&mut f, &mut head)?;
    let sniffed = caliper_core::io::sniff(&head[..n]);
    let gzip = sniffed == caliper_core::io::Sniffed::Gzip;
    if !gzip && sniffed != caliper_core::io::Sniffed::Text {
        return Err(RunError::Input(format!(
            "{} is not a CSV or gzip file",
            p.display()
        )));
    }
    // Hash as a stream: logs can be hundreds of MB.
    let mut hasher = <sha2::Sha256 as sha2::Digest>::new();
    let mut file = std::fs::File::open(p)?;
    let size = std::io::copy(&mut file, &mut hasher)?;
    Ok(vec![(
        DatasetFile {
            name: p
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            sha256: hex::encode(sha2::Digest::finalize(hasher)),
            size,
            media_type: sniffed.media_type().to_string(),
            image: None,
            video: None,
        },
        p.clone(),
    )])
}

/// One input file that is a video clip (by content).
pub(super) fn single_video(paths: &[(PathBuf, bool)]) -> bool {
    let [(p, _)] = paths else { return false };
    let mut head = [0u8; 64];
    let n = std::fs::File::open(p)
        .and_then(|mut f| std::io::Read::read(&mut f, &mut head))
        .unwrap_or(0);
    caliper_core::io::sniff(&head[..n]).is_video()
}

/// Describe one video clip as a dataset would (probed like an upload).
pub(super) fn video_file(
    paths: &[(PathBuf, bool)],
) -> Result<Vec<(DatasetFile, PathBuf)>, RunError> {
    let [(p, _)] = paths else {
        return Err(RunError::Input("give one video clip".into()));
    };
    let limits = crate::config::Config::default().video_limits();
    let info =
        caliper_core::video::probe(std::io::BufReader::new(std::fs::File::open(p)?), &limits)
            .map_err(|e| RunError::Input(format!("{}: {e}", p.display())))?;
    let mut head = [0u8; 64];
    let n = std::io::Read::read(&mut std::fs::File::open(p)?, &mut head)?;
    let mut hasher = <sha2::Sha256 as sha2::Digest>::new();
    let size = std::io::copy(&mut std::fs::File::open(p)?, &mut hasher)?;
    Ok(vec![(
        DatasetFile {
            name: p
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            sha256: hex::encode(sha2::Digest::finalize(hasher)),
            size,
            media_type: caliper_core::io::sniff(&head[..n]).media_type().to_string(),
            image: None,
            video: serde_json::to_value(&info).ok(),
        },
        p.clone(),
    )])
}
