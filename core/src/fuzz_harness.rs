//! Entry points for fuzzing every parser of untrusted input, shared by the `cargo fuzz`
//! targets (`core/fuzz/`) and by the regression test that replays the committed corpora and
//! every input that ever crashed one of them (`core/tests/fuzz_regressions.rs`). Each takes raw
//! bytes and must return — an error is fine, a panic, a hang or an unbounded allocation is a
//! bug. Not part of the API.

use crate::io::ImageLimits;
use crate::progress::NoProgress;

/// Limits small enough that a fuzzer cannot make a decoder allocate much.
fn small_limits() -> ImageLimits {
    ImageLimits {
        max_width: 512,
        max_height: 512,
        max_pixels: 512 * 512,
        max_alloc_bytes: 16 << 20,
    }
}

/// Image sniffing, header probe and both decoders.
pub fn image(data: &[u8]) {
    let kind = crate::io::sniff(&data[..data.len().min(64)]);
    let limits = small_limits();
    let _ = crate::io::probe_image(std::io::Cursor::new(data), &limits);
    if kind.is_image() {
        let _ = crate::io::decode_gray8(data, &limits);
        let _ = crate::io::decode_image(data, &limits);
        let _ = crate::photometric::dso::read_vignette_png(data, &limits, None);
    }
}

/// IMU CSV logs (header detection, line parsing, accumulation).
pub fn imu_log(data: &[u8]) {
    let _ = crate::imu::read_imu_log(data, &crate::imu::ImuCsvParams::default(), &NoProgress);
}

/// Kernel files: text matrices and JSON.
pub fn psf(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = crate::deconv::Psf::parse_text(text);
        let _ = crate::deconv::Psf::parse_json(text);
    }
}

/// DSO's text files (`pcalib.txt`, `times.txt`).
pub fn dso(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = crate::photometric::dso::read_pcalib(text);
        let _ = crate::photometric::dso::read_times(text);
    }
}

/// Every function above, for a corpus replay that does not know which target an input is for.
pub fn all(data: &[u8]) {
    image(data);
    imu_log(data);
    psf(data);
    dso(data);
    zip(data);
}

/// Zip archives: every check of `io::archive`, entries drained with a byte cap.
pub fn zip(data: &[u8]) {
    let limits = crate::io::archive::ArchiveLimits {
        max_entries: 64,
        max_total_bytes: 1 << 20,
        max_ratio: 200,
    };
    let mut sink = |_: &str, r: &mut dyn std::io::Read| {
        std::io::copy(r, &mut std::io::sink()).map_err(|e| crate::io::archive::ArchiveError {
            fault: crate::io::archive::ArchiveFault::Corrupt,
            message: e.to_string(),
        })
    };
    let _ = crate::io::archive::unpack(
        std::io::Cursor::new(data),
        data.len() as u64,
        "fuzz.zip",
        limits,
        &mut sink,
    );
}

/// MP4/MOV demuxing and decoding (feature `video`): probe, then every frame, with limits small
/// enough that a fuzzer cannot make the decoder allocate or work much.
#[cfg(feature = "video")]
pub fn video(data: &[u8]) {
    use crate::video::{FrameFormat, FrameOptions, FrameReader, VideoLimits};
    let limits = VideoLimits {
        max_duration_s: 600.0,
        max_pixels: 640 * 480,
        max_frames: 400,
        max_decoded_bytes: 256 << 20,
        max_sample_bytes: 1 << 20,
    };
    let _ = crate::video::inspect(std::io::Cursor::new(data), &limits);
    if crate::video::probe(std::io::Cursor::new(data), &limits).is_err() {
        return;
    }
    let format = match data.len() % 3 {
        0 => FrameFormat::Luma,
        1 => FrameFormat::Gray,
        _ => FrameFormat::Rgb,
    };
    let options = FrameOptions {
        format,
        ..Default::default()
    };
    if let Ok(reader) = FrameReader::open(std::io::Cursor::new(data), &limits, options) {
        for item in reader.take(1000) {
            if item.is_err() {
                break;
            }
        }
    }
}
