//! Dataset uploads: stream each multipart file to a temporary file while hashing it, decide
//! what it is from its content, validate it within limits, then move it into the blob store.
//!
//! Nothing is recorded until every file has passed: a rejected upload leaves no dataset row
//! and no half-written blob (blobs are written under their hash only after validation, and a
//! blob without a dataset row is harmless: it is content-addressed and can be written again).

pub mod archive;
pub mod imu;

use std::collections::HashSet;
use std::io::Read;
use std::path::PathBuf;

use axum::extract::Multipart;
use axum::extract::multipart::MultipartError;
use sha2::{Digest, Sha256};
use tokio::io::AsyncWriteExt;
use uuid::Uuid;

use crate::error::{ApiError, ApiResult};
use crate::state::AppState;
use crate::store::{DatasetFile, DatasetKind, DatasetRecord};
use caliper_core::io::{Sniffed, sniff};

/// One received file, in a temporary file until validated.
struct Received {
    name: String,
    sha256: String,
    size: u64,
    file: tempfile::NamedTempFile,
}

fn multipart_error(e: MultipartError) -> ApiError {
    let status = e.status();
    if status == axum::http::StatusCode::PAYLOAD_TOO_LARGE {
        ApiError::new("payload_too_large", e.body_text())
    } else {
        ApiError::new(
            "invalid_body",
            format!("malformed multipart body: {}", e.body_text()),
        )
    }
}

fn tmp_dir(state: &AppState) -> PathBuf {
    state.config().data_dir.join("tmp")
}

/// Receive, validate and store an upload; returns the new dataset.
pub async fn ingest(
    state: &AppState,
    mut multipart: Multipart,
    devices: Option<Vec<String>>,
) -> ApiResult<DatasetRecord> {
    let cfg = state.config().clone();
    let tmp = tmp_dir(state);
    tokio::fs::create_dir_all(&tmp)
        .await
        .map_err(ApiError::internal)?;
    let mut received: Vec<Received> = Vec::new();
    let mut kind_hint: Option<DatasetKind> = None;
    let mut total: u64 = 0;
    while let Some(mut field) = multipart.next_field().await.map_err(multipart_error)? {
        let field_name = field.name().unwrap_or("").to_string();
        let Some(file_name) = field.file_name().map(sanitize_name) else {
            if field_name == "kind" {
                if kind_hint.is_some() {
                    return Err(ApiError::new(
                        "invalid_body",
                        "`kind` given more than once: send one value",
                    )
                    .with_field("kind"));
                }
                let text = field.text().await.map_err(multipart_error)?;
                kind_hint = Some(DatasetKind::parse(text.trim()).ok_or_else(|| {
                    ApiError::new(
                        "invalid_body",
                        format!("`kind` must be images, imu_log or video, not {text:?}"),
                    )
                    .with_field("kind")
                })?);
                continue;
            }
            return Err(ApiError::new(
                "invalid_body",
                format!("unexpected form field {field_name:?}: send files as parts with a filename (field `file`), and optionally a `kind` field"),
            )
            .with_field(field_name));
        };
        if received.len() >= cfg.max_files {
            return Err(ApiError::new(
                "too_many_files",
                format!("more than {} files in one upload", cfg.max_files),
            ));
        }
        let tmpfile = tempfile::NamedTempFile::new_in(&tmp).map_err(ApiError::internal)?;
        let std_file = tmpfile.reopen().map_err(ApiError::internal)?;
        let mut out = tokio::fs::File::from_std(std_file);
        let mut hasher = Sha256::new();
        let mut size: u64 = 0;
        while let Some(chunk) = field.chunk().await.map_err(multipart_error)? {
            size += chunk.len() as u64;
            total += chunk.len() as u64;
            if total > cfg.max_upload_bytes {
                return Err(ApiError::new(
                    "payload_too_large",
                    format!("upload exceeds {} bytes", cfg.max_upload_bytes),
                ));
            }
            hasher.update(&chunk);
            out.write_all(&chunk).await.map_err(ApiError::internal)?;
        }
        out.flush().await.map_err(ApiError::internal)?;
        if size == 0 {
            return Err(ApiError::new(
                "empty_upload",
                format!("file {file_name:?} is empty"),
            ));
        }
        received.push(Received {
            name: file_name,
            sha256: hex::encode(hasher.finalize()),
            size,
            file: tmpfile,
        });
    }
    if received.is_empty() {
        return Err(ApiError::new(
            "empty_upload",
            "no files in the upload: send multipart/form-data with one or more `file` parts",
        ));
    }
    let state2 = state.clone();
    let (kind, files) = tokio::task::spawn_blocking(move || validate(&state2, received, kind_hint))
        .await
        .map_err(ApiError::internal)??;
    // Pin the keys before storing: a GC pass that runs meanwhile then keeps a blob that
    // already exists (and that we therefore do not write again) until the dataset row
    // references it. Unpinned whatever happens below.
    let token = Uuid::now_v7();
    let shas: Vec<String> = files.iter().map(|(m, _)| m.sha256.clone()).collect();
    let now = crate::clock::now_ms();
    state
        .store()
        .pin_blobs(token, &shas, now + UPLOAD_PIN_TTL_MS)
        .await?;
    let stored = store_files(state, files).await;
    let inserted = match stored {
        Ok((stored, total_bytes)) => {
            let ds = DatasetRecord {
                id: Uuid::now_v7(),
                kind,
                created_at: crate::clock::now_ms(),
                total_bytes,
                sha256: crate::document::manifest_sha256(&stored),
                files: stored,
                devices,
            };
            state
                .store()
                .insert_dataset(&ds)
                .await
                .map(|()| ds)
                .map_err(ApiError::from)
        }
        Err(e) => Err(e),
    };
    if let Err(e) = state
        .store()
        .unpin_blobs(token, crate::clock::now_ms())
        .await
    {
        tracing::warn!(error = %e, "cannot drop upload pins; they expire");
    }
    let ds = inserted?;
    Ok(ds)
}

/// How long an upload's pins last if the process dies before dropping them.
const UPLOAD_PIN_TTL_MS: i64 = 24 * 3_600_000;

/// Move validated files into the blob store (durably: see [`crate::blobs::Blobs::put_file`]).
async fn store_files(
    state: &AppState,
    files: Vec<(DatasetFile, tempfile::NamedTempFile)>,
) -> ApiResult<(Vec<DatasetFile>, u64)> {
    let mut stored = Vec::with_capacity(files.len());
    let mut total_bytes = 0;
    for (meta, tmpfile) in files {
        state
            .blobs()
            .put_file(&meta.sha256, tmpfile.path())
            .await
            .map_err(ApiError::internal)?;
        total_bytes += meta.size;
        stored.push(meta);
    }
    Ok((stored, total_bytes))
}

/// Keep the base name only, without control characters (names are labels, never paths).
fn sanitize_name(raw: &str) -> String {
    let base = raw.rsplit(['/', '\\']).next().unwrap_or(raw);
    let clean: String = base.chars().filter(|c| !c.is_control()).collect();
    if clean.is_empty() {
        "unnamed".to_string()
    } else {
        clean
    }
}

fn read_head(path: &std::path::Path) -> ApiResult<Vec<u8>> {
    let mut f = std::fs::File::open(path).map_err(ApiError::internal)?;
    let mut head = vec![0u8; 64];
    let mut n = 0;
    while n < head.len() {
        let k = f.read(&mut head[n..]).map_err(ApiError::internal)?;
        if k == 0 {
            break;
        }
        n += k;
    }
    head.truncate(n);
    Ok(head)
}

type Validated = (DatasetKind, Vec<(DatasetFile, tempfile::NamedTempFile)>);

/// Classify and validate every received file (blocking).
fn validate(
    state: &AppState,
    received: Vec<Received>,
    hint: Option<DatasetKind>,
) -> ApiResult<Validated> {
    let cfg = state.config();
    let limits = cfg.image_limits();
    let tmp = tmp_dir(state);
    let mut images: Vec<Received> = Vec::new();
    let mut others: Vec<(Received, Sniffed)> = Vec::new();
    for r in received {
        let s = sniff(&read_head(r.file.path())?);
        match s {
            s if s.is_image() => images.push(r),
            Sniffed::Zip => {
                let check = |e: &archive::Entry| -> ApiResult<()> {
                    if !sniff(&read_head(e.file.path())?).is_image() {
                        return Err(ApiError::new(
                            "unsupported_file",
                            format!(
                                "{}: entry {:?} is not a PNG, JPEG or TIFF image",
                                r.name, e.name
                            ),
                        ));
                    }
                    Ok(())
                };
                let entries = archive::unpack(
                    r.file.path(),
                    &r.name,
                    &tmp,
                    caliper_core::io::archive::ArchiveLimits {
                        max_entries: cfg.max_files,
                        max_total_bytes: cfg.max_archive_bytes,
                        max_ratio: cfg.max_compression_ratio,
                    },
                    &check,
                )?;
                for e in entries {
                    if e.size == 0 {
                        continue;
                    }
                    images.push(Received {
                        name: e.name,
                        sha256: e.sha256,
                        size: e.size,
                        file: e.file,
                    });
                }
            }
            Sniffed::Unknown => {
                return Err(ApiError::new(
                    "unsupported_file",
                    format!(
                        "{:?} is not a supported image (PNG, JPEG, TIFF), zip of images, IMU log (CSV or gzip) or video (MP4, MOV, MKV, AVI)",
                        r.name
                    ),
                ));
            }
            other => others.push((r, other)),
        }
    }
    if !images.is_empty() && !others.is_empty() {
        return Err(ApiError::new(
            "mixed_dataset",
            "an upload holds either images (and zips of them), or one IMU log, or one video",
        ));
    }
    if !images.is_empty() {
        if hint.is_some_and(|h| h != DatasetKind::Images) {
            return Err(ApiError::new(
                "mixed_dataset",
                "`kind` says otherwise, but the upload holds images",
            ));
        }
        if images.len() > cfg.max_files {
            return Err(ApiError::new(
                "too_many_files",
                format!("{} images; the limit is {}", images.len(), cfg.max_files),
            ));
        }
        let mut names = HashSet::new();
        for im in &images {
            if !names.insert(im.name.clone()) {
                return Err(ApiError::new(
                    "duplicate_name",
                    format!(
                        "two files are named {:?}; names identify images in results",
                        im.name
                    ),
                ));
            }
        }
        use rayon::prelude::*;
        let infos: Vec<ApiResult<caliper_core::io::ImageInfo>> = images
            .par_iter()
            .map(|im| validate_image(im, &limits))
            .collect();
        let mut out = Vec::with_capacity(images.len());
        for (im, info) in images.into_iter().zip(infos) {
            let info = info?;
            out.push((
                DatasetFile {
                    name: im.name,
                    sha256: im.sha256,
                    size: im.size,
                    media_type: format!("image/{}", info.format),
                    image: Some(info),
                    video: None,
                },
                im.file,
            ));
        }
        return Ok((DatasetKind::Images, out));
    }
    if others.len() != 1 {
        return Err(ApiError::new(
            "mixed_dataset",
            format!(
                "{} non-image files: an IMU log or a video dataset holds exactly one file",
                others.len()
            ),
        ));
    }
    let Some((r, s)) = others.pop() else {
        return Err(ApiError::new("empty_upload", "no files"));
    };
    let mut video = None;
    let kind = if s.is_video() {
        video = Some(probe_video(&r, &cfg.video_limits())?);
        DatasetKind::Video
    } else {
        imu::validate(r.file.path(), s == Sniffed::Gzip)
            .map_err(|m| ApiError::new("invalid_imu_log", format!("{:?}: {m}", r.name)))?;
        DatasetKind::ImuLog
    };
    if hint.is_some_and(|h| h != kind) {
        return Err(ApiError::new(
            "mixed_dataset",
            format!(
                "`kind` does not match the content, which is {}",
                kind.as_str()
            ),
        ));
    }
    Ok((
        kind,
        vec![(
            DatasetFile {
                name: r.name,
                sha256: r.sha256,
                size: r.size,
                media_type: s.media_type().to_string(),
                image: None,
                video,
            },
            r.file,
        )],
    ))
}

/// A clip's facts from its index (codec, size, rotation, rate, counts), or a 422 that names
/// what is wrong: an unsupported codec or container (with the command that converts it), a
/// clip over the limits, a damaged or truncated file. No frame is decoded here: decoding
/// happens in the workers.
fn probe_video(
    r: &Received,
    limits: &caliper_core::video::VideoLimits,
) -> ApiResult<serde_json::Value> {
    let file = std::fs::File::open(r.file.path()).map_err(ApiError::internal)?;
    let info = caliper_core::video::probe(std::io::BufReader::new(file), limits)
        .map_err(|e| ApiError::new(e.code(), format!("{:?}: {e}", r.name)))?;
    if info.truncated {
        return Err(ApiError::new(
            "video_truncated",
            format!(
                "{:?} ends before its last frame (only {} of {} frames are in the file): upload the whole clip",
                r.name, info.frames_in_file, info.frame_count
            ),
        ));
    }
    serde_json::to_value(&info).map_err(ApiError::internal)
}

/// Header within limits, then a full decode: a truncated or corrupt image is refused at
/// upload instead of failing a job later.
/// The largest file an image of `width` × `height` can honestly need: four 16-bit channels
/// stored uncompressed, 10 % for the worst compressor's expansion, and 4 MiB for metadata
/// (EXIF thumbnails, ICC profiles, XMP).
pub fn max_encoded_size(width: u32, height: u32) -> u64 {
    let raw = u64::from(width) * u64::from(height) * 8;
    raw + raw / 10 + (4 << 20)
}

fn validate_image(
    im: &Received,
    limits: &caliper_core::io::ImageLimits,
) -> ApiResult<caliper_core::io::ImageInfo> {
    let reader =
        std::io::BufReader::new(std::fs::File::open(im.file.path()).map_err(ApiError::internal)?);
    let info = caliper_core::io::probe_image(reader, limits).map_err(|e| {
        let msg = e.to_string();
        let code = if msg.contains("limit") {
            "image_too_large"
        } else {
            "corrupt_image"
        };
        ApiError::new(code, format!("{:?}: {msg}", im.name))
    })?;
    // Refuse files far larger than their picture can need (a small image followed by
    // hundreds of MB of junk, issue D6): the bytes are read whole below and by every job.
    let most = max_encoded_size(info.width, info.height);
    if im.size > most {
        return Err(ApiError::new(
            "trailing_data",
            format!(
                "{:?} is {} bytes, more than a {}×{} image can take ({most} bytes at most): it carries data after the image",
                im.name, im.size, info.width, info.height
            ),
        ));
    }
    let bytes = std::fs::read(im.file.path()).map_err(ApiError::internal)?;
    caliper_core::io::decode_gray8(&bytes, limits)
        .map_err(|e| ApiError::new("corrupt_image", format!("{:?}: {e}", im.name)))?;
    Ok(info)
}
