//! Unit tests on clips made by the writer (no shared data needed).

use std::io::Cursor;

use image::{GrayImage, Luma, Rgb, RgbImage};

use super::*;

/// A gray test pattern that moves with `t`: a ramp plus a bright square.
pub(crate) fn pattern(w: u32, h: u32, t: u32) -> GrayImage {
    GrayImage::from_fn(w, h, |x, y| {
        let sq = (x + 3 * t) % w < w / 4 && y > h / 4 && y < h / 2;
        Luma([if sq {
            230
        } else {
            (40 + (x * 120 / w) + (y * 60 / h)) as u8
        }])
    })
}

pub(crate) fn psnr(a: &GrayImage, b: &GrayImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let mse = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(&p, &q)| (f64::from(p) - f64::from(q)).powi(2))
        .sum::<f64>()
        / a.as_raw().len() as f64;
    if mse == 0.0 {
        99.0
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

fn luma_frames(clip: &[u8], options: FrameOptions) -> (Vec<Frame>, Option<VideoError>) {
    let reader = FrameReader::open(Cursor::new(clip), &VideoLimits::default(), options).unwrap();
    let mut frames = Vec::new();
    let mut err = None;
    for f in reader {
        match f {
            Ok(f) => frames.push(f),
            Err(e) => err = Some(e),
        }
    }
    (frames, err)
}

#[test]
fn round_trip_gray_clip() {
    let src: Vec<GrayImage> = (0..20).map(|t| pattern(96, 64, t)).collect();
    let clip = encode_h264_mp4(&src, 25.0).unwrap();
    let info = probe(Cursor::new(&clip), &VideoLimits::default()).unwrap();
    assert_eq!((info.width, info.height, info.frame_count), (96, 64, 20));
    assert!((info.fps - 25.0).abs() < 1e-9, "{}", info.fps);
    assert!((info.duration_s - 0.8).abs() < 1e-9);
    assert!(matches!(info.codec, Codec::H264 { .. }), "{:?}", info.codec);
    assert!(info.keyframe_count >= 1 && !info.truncated);
    // The coded frames are most of the file (the rest is the index and headers).
    let file_bpp = clip.len() as f64 * 8.0 / (96.0 * 64.0 * 20.0);
    assert!(
        info.bits_per_pixel > 0.3 * file_bpp && info.bits_per_pixel < file_bpp,
        "{} bits per pixel, the file {file_bpp}",
        info.bits_per_pixel
    );
    let (frames, err) = luma_frames(&clip, FrameOptions::default());
    assert!(err.is_none(), "{err:?}");
    assert_eq!(frames.len(), 20);
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f.index, i as u64);
        assert!((f.pts_s - i as f64 / 25.0).abs() < 1e-9);
        let FrameImage::Luma(img) = &f.image else {
            panic!("luma expected")
        };
        let p = psnr(img, &src[i]);
        assert!(p > 35.0, "frame {i}: PSNR {p:.1}");
    }
    assert!(frames[0].keyframe);
}

/// A Motion-JPEG clip: every frame a keyframe, its samples full range (JFIF), decoded close to
/// the source with black and white kept; an H.264 clip from the writer says nothing of its
/// range.
#[test]
fn mjpeg_clip_is_intra_and_full_range() {
    let src: Vec<GrayImage> = (0..12)
        .map(|t| {
            let mut g = pattern(96, 64, t);
            // Black and white patches: a limited-range reading would move them.
            for y in 0..8 {
                for x in 0..8 {
                    g.put_pixel(x, y, Luma([0]));
                    g.put_pixel(95 - x, y, Luma([255]));
                }
            }
            g
        })
        .collect();
    let clip = encode_mjpeg_mov(&src, 30.0, 95).unwrap();
    let info = probe(Cursor::new(&clip), &VideoLimits::default()).unwrap();
    assert!(
        matches!(info.codec, Codec::Mjpeg { .. }),
        "{:?}",
        info.codec
    );
    assert_eq!((info.frame_count, info.keyframe_count), (12, 12));
    assert_eq!(info.full_range, Some(true));
    assert!(info.bits_per_pixel > 0.0);
    let (frames, err) = luma_frames(&clip, FrameOptions::default());
    assert!(err.is_none(), "{err:?}");
    assert_eq!(frames.len(), 12);
    for (i, f) in frames.iter().enumerate() {
        let FrameImage::Luma(img) = &f.image else {
            panic!("luma expected")
        };
        let p = psnr(img, &src[i]);
        assert!(p > 35.0, "frame {i}: PSNR {p:.1}");
        assert!(
            img.get_pixel(3, 3)[0] <= 4,
            "black {}",
            img.get_pixel(3, 3)[0]
        );
        assert!(
            img.get_pixel(92, 3)[0] >= 251,
            "white {}",
            img.get_pixel(92, 3)[0]
        );
    }
    let h264 = encode_h264_mp4(&src, 30.0).unwrap();
    let info = probe(Cursor::new(&h264), &VideoLimits::default()).unwrap();
    assert_ne!(info.full_range, Some(true));
}

/// A clip coded at a lower bitrate reports fewer bits per pixel.
#[test]
fn bits_per_pixel_follow_the_bitrate() {
    // Fine texture moving 3 px per frame: costly enough that the bitrate decides the quality.
    let src: Vec<GrayImage> = (0..30u32)
        .map(|t| {
            GrayImage::from_fn(160, 120, |x, y| {
                let h = (x + 3 * t).wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503);
                Luma([(40 + (h >> 7) % 180) as u8])
            })
        })
        .collect();
    let bpp = |bitrate: u32| {
        let opts = WriterOptions {
            bitrate,
            ..Default::default()
        };
        let clip = encode_h264_mp4_with(&src, 30.0, &opts).unwrap();
        probe(Cursor::new(&clip), &VideoLimits::default())
            .unwrap()
            .bits_per_pixel
    };
    let (high, low) = (bpp(2_000_000), bpp(100_000));
    assert!(low > 0.0 && low < 0.6 * high, "{low} against {high}");
}

#[test]
fn round_trip_rgb_and_rotation() {
    let src: Vec<RgbImage> = (0..6)
        .map(|t| {
            RgbImage::from_fn(64, 48, |x, y| {
                Rgb([(x * 4) as u8, (y * 5) as u8, (t * 40) as u8])
            })
        })
        .collect();
    for rot in [0u16, 90, 180, 270] {
        let opts = WriterOptions {
            rotation_deg: rot,
            ..Default::default()
        };
        let clip = encode_h264_mp4_with(&src, 30.0, &opts).unwrap();
        let info = probe(Cursor::new(&clip), &VideoLimits::default()).unwrap();
        assert_eq!(info.rotation_deg, rot);
        let expect = if rot % 180 == 90 { (48, 64) } else { (64, 48) };
        assert_eq!((info.display_width, info.display_height), expect);
        let options = FrameOptions {
            format: FrameFormat::Rgb,
            ..Default::default()
        };
        let (frames, err) = luma_frames(&clip, options);
        assert!(err.is_none());
        assert_eq!(frames.len(), 6);
        let FrameImage::Rgb(img) = &frames[3].image else {
            panic!("rgb expected")
        };
        assert_eq!(img.dimensions(), expect);
        let want = match rot {
            90 => image::imageops::rotate90(&src[3]),
            180 => image::imageops::rotate180(&src[3]),
            270 => image::imageops::rotate270(&src[3]),
            _ => src[3].clone(),
        };
        let p = psnr(
            &image::DynamicImage::ImageRgb8(img.clone()).to_luma8(),
            &image::DynamicImage::ImageRgb8(want).to_luma8(),
        );
        assert!(p > 30.0, "rotation {rot}: PSNR {p:.1}");
    }
}

/// An RGB scene with pure black and white patches beside colours and a grey ramp.
fn extremes(w: u32, h: u32) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| match (x * 4 / w, y * 2 / h) {
        (0, 0) => Rgb([0, 0, 0]),
        (1, 0) => Rgb([255, 255, 255]),
        (2, 0) => Rgb([200, 40, 30]),
        (3, 0) => Rgb([20, 60, 220]),
        _ => {
            let v = (x * 255 / w) as u8;
            Rgb([v, v, v])
        }
    })
}

/// Mean absolute difference over a patch interior (away from chroma edges).
fn patch_error(a: &RgbImage, b: &RgbImage, x0: u32, y0: u32, side: u32) -> f64 {
    let mut sum = 0.0;
    for y in y0..y0 + side {
        for x in x0..x0 + side {
            for c in 0..3 {
                sum += (f64::from(a.get_pixel(x, y)[c]) - f64::from(b.get_pixel(x, y)[c])).abs();
            }
        }
    }
    sum / f64::from(3 * side * side)
}

#[test]
fn clips_are_converted_with_the_signalled_range_and_matrix() {
    let src: Vec<RgbImage> = (0..4).map(|_| extremes(64, 48)).collect();
    for (full_range, bt709) in [(false, false), (true, false), (false, true), (true, true)] {
        let opts = WriterOptions {
            full_range,
            bt709,
            ..Default::default()
        };
        let clip = encode_h264_mp4_with(&src, 30.0, &opts).unwrap();
        let info = probe(Cursor::new(&clip), &VideoLimits::default()).unwrap();
        let signalled = full_range || bt709;
        assert_eq!(info.full_range, signalled.then_some(full_range), "{info:?}");
        let matrix = signalled.then_some(if bt709 { 1 } else { 6 });
        assert_eq!(info.matrix_coefficients, matrix, "{info:?}");
        let rgb = FrameOptions {
            format: FrameFormat::Rgb,
            ..Default::default()
        };
        let (frames, err) = luma_frames(&clip, rgb);
        assert!(err.is_none());
        let FrameImage::Rgb(img) = &frames[2].image else {
            panic!("rgb expected")
        };
        // Black, white and both colours come back in either range and matrix: each patch's
        // interior within a few levels (a full-range clip read as limited is stretched by
        // 255/219: its red patch comes back 11 levels off, and levels near black and white
        // clip; a BT.709 clip read with BT.601 shifts saturated colours).
        for (i, x0) in [4u32, 20, 36, 52].into_iter().enumerate() {
            let e = patch_error(img, &src[2], x0, 6, 8);
            assert!(e < 4.0, "{opts:?}, patch {i}: {e:.2} levels off");
        }
        // `Gray` gives the luma as a player shows it in either range.
        let gray = FrameOptions {
            format: FrameFormat::Gray,
            ..Default::default()
        };
        let (frames, _) = luma_frames(&clip, gray);
        let FrameImage::Luma(g) = &frames[2].image else {
            panic!("luma expected")
        };
        // The luma of the matrix the writer codes with.
        let (kr, kb) = if bt709 {
            (0.2126, 0.0722)
        } else {
            (0.299, 0.114)
        };
        let want = GrayImage::from_fn(64, 48, |x, y| {
            let [r, g, b] = src[2].get_pixel(x, y).0.map(f64::from);
            Luma([(kr * r + (1.0 - kr - kb) * g + kb * b).round() as u8])
        });
        let p = psnr(g, &want);
        assert!(p > 30.0, "{opts:?}: gray PSNR {p:.1}");
    }
}

#[test]
fn selection_stride_range_and_indices() {
    let src: Vec<GrayImage> = (0..30).map(|t| pattern(64, 48, t)).collect();
    let clip = encode_h264_mp4(&src, 30.0).unwrap();
    let idx = |o: FrameOptions| {
        luma_frames(&clip, o)
            .0
            .iter()
            .map(|f| f.index)
            .collect::<Vec<_>>()
    };
    assert_eq!(
        idx(FrameOptions {
            stride: 10,
            ..Default::default()
        }),
        vec![0, 10, 20]
    );
    assert_eq!(
        idx(FrameOptions {
            time_range: Some((0.5, 0.6)),
            ..Default::default()
        }),
        vec![15, 16, 17, 18]
    );
    assert_eq!(
        idx(FrameOptions {
            indices: Some([3, 29].into()),
            ..Default::default()
        }),
        vec![3, 29]
    );
}

#[test]
fn cancel_hook_stops() {
    let src: Vec<GrayImage> = (0..10).map(|t| pattern(32, 32, t)).collect();
    let clip = encode_h264_mp4(&src, 10.0).unwrap();
    let mut reader = FrameReader::open(
        Cursor::new(&clip),
        &VideoLimits::default(),
        FrameOptions::default(),
    )
    .unwrap();
    let calls = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let c = calls.clone();
    reader.set_cancel(move || c.fetch_add(1, std::sync::atomic::Ordering::SeqCst) >= 3);
    let items: Vec<_> = reader.collect();
    assert!(matches!(items.last(), Some(Err(VideoError::Canceled))));
    assert!(items.len() <= 4);
}

#[test]
fn truncated_clip_decodes_a_prefix_and_reports_the_break() {
    let src: Vec<GrayImage> = (0..24).map(|t| pattern(64, 48, t)).collect();
    let clip = encode_h264_mp4(&src, 24.0).unwrap();
    for frac in [0.5, 0.8, 0.95] {
        let cut = &clip[..(clip.len() as f64 * frac) as usize];
        let info = probe(Cursor::new(cut), &VideoLimits::default()).unwrap();
        assert!(info.truncated && info.frames_in_file < 24);
        let (frames, err) = luma_frames(cut, FrameOptions::default());
        assert!(
            !frames.is_empty() && frames.len() < 24,
            "{frac}: {}",
            frames.len()
        );
        match err {
            Some(VideoError::Truncated { after_frame, .. }) => {
                assert_eq!(after_frame, frames.last().map(|f| f.index));
            }
            other => panic!("{frac}: expected Truncated, got {other:?}"),
        }
    }
    // Cut inside the index: refused up front.
    let e = probe(Cursor::new(&clip[..200]), &VideoLimits::default()).unwrap_err();
    assert!(
        matches!(e.code(), "video_malformed" | "video_moov_missing"),
        "{e}"
    );
}

#[test]
fn limits_are_enforced_at_probe() {
    let src: Vec<GrayImage> = (0..10).map(|t| pattern(64, 48, t)).collect();
    let clip = encode_h264_mp4(&src, 10.0).unwrap();
    let lim = |f: fn(&mut VideoLimits)| {
        let mut l = VideoLimits::default();
        f(&mut l);
        probe(Cursor::new(&clip), &l).unwrap_err().code()
    };
    assert_eq!(lim(|l| l.max_duration_s = 0.5), "video_too_long");
    assert_eq!(lim(|l| l.max_pixels = 1000), "video_too_large");
    assert_eq!(lim(|l| l.max_frames = 5), "video_too_many_frames");
    assert_eq!(
        lim(|l| l.max_decoded_bytes = 1000),
        "video_decoded_bytes_over_limit"
    );
    assert_eq!(lim(|l| l.max_sample_bytes = 10), "video_sample_too_large");
}

#[test]
fn garbage_and_other_containers_are_refused() {
    let e = probe(
        Cursor::new(b"RIFF\0\0\0\0AVI LIST".to_vec()),
        &VideoLimits::default(),
    )
    .unwrap_err();
    assert_eq!(e.code(), "video_container_unsupported");
    assert!(e.to_string().contains("AVI"));
    let e = probe(Cursor::new(vec![7u8; 100]), &VideoLimits::default()).unwrap_err();
    assert_eq!(e.code(), "video_container_unsupported");
    let e = probe(Cursor::new(Vec::new()), &VideoLimits::default()).unwrap_err();
    assert_eq!(e.code(), "video_container_unsupported");
    // An mdat cut short with no index: the interrupted recording.
    let mut cut = b"\0\0\0\x10ftypisom\0\0\0\0".to_vec();
    cut.extend_from_slice(b"\0\x10\0\0mdat");
    cut.extend_from_slice(&[0u8; 100]);
    let e = probe(Cursor::new(cut), &VideoLimits::default()).unwrap_err();
    assert!(
        matches!(e, VideoError::MoovMissing { mdat_cut: true }),
        "{e}"
    );
}

/// Re-encodes the `moov` of a writer clip after `edit` (its size must not change for the
/// chunk offsets to stay right, which holds for edits of fixed-size fields).
pub(crate) fn edit_moov(clip: &[u8], edit: impl FnOnce(&mut mp4_atom::Moov)) -> Vec<u8> {
    use mp4_atom::{Decode, Encode};
    let ftyp_len = u32::from_be_bytes(clip[0..4].try_into().unwrap()) as usize;
    let moov_len = u32::from_be_bytes(clip[ftyp_len..ftyp_len + 4].try_into().unwrap()) as usize;
    let mut moov = mp4_atom::Moov::decode(&mut &clip[ftyp_len..ftyp_len + moov_len]).unwrap();
    edit(&mut moov);
    let mut out = clip[..ftyp_len].to_vec();
    moov.encode(&mut out).unwrap();
    out.extend_from_slice(&clip[ftyp_len + moov_len..]);
    out
}

#[test]
fn bad_tables_and_matrices_are_refused() {
    use mp4_atom::StszSamples;
    let src: Vec<GrayImage> = (0..8).map(|t| pattern(32, 32, t)).collect();
    let clip = encode_h264_mp4(&src, 8.0).unwrap();
    let code = |c: &[u8]| probe(Cursor::new(c), &VideoLimits::default()).unwrap_err();

    let sheared = edit_moov(&clip, |m| m.trak[0].tkhd.matrix.b = 1 << 14);
    let e = code(&sheared);
    assert_eq!(e.code(), "video_matrix_unsupported", "{e}");
    let mirrored = edit_moov(&clip, |m| m.trak[0].tkhd.matrix.a = -(1 << 16));
    assert_eq!(code(&mirrored).code(), "video_matrix_unsupported");

    let empty = edit_moov(&clip, |m| {
        if let StszSamples::Different { sizes } = &mut m.trak[0].mdia.minf.stbl.stsz.samples {
            sizes[3] = 0;
        }
    });
    assert_eq!(code(&empty).code(), "video_empty_sample");

    let huge = edit_moov(&clip, |m| {
        m.trak[0].mdia.minf.stbl.stsz.samples = StszSamples::Identical {
            count: u32::MAX,
            size: 100,
        };
    });
    assert_eq!(code(&huge).code(), "video_too_many_frames");
    let few = VideoLimits {
        max_frames: u64::MAX,
        ..Default::default()
    };
    let e = probe(Cursor::new(&huge), &few).unwrap_err();
    assert_eq!(e.code(), "video_malformed", "{e}");

    let absurd = edit_moov(&clip, |m| {
        if let StszSamples::Different { sizes } = &mut m.trak[0].mdia.minf.stbl.stsz.samples {
            sizes[2] = u32::MAX;
        }
    });
    assert_eq!(code(&absurd).code(), "video_sample_too_large");

    let short_stts = edit_moov(&clip, |m| {
        m.trak[0].mdia.minf.stbl.stts.entries[0].sample_count = 3
    });
    assert_eq!(code(&short_stts).code(), "video_malformed");

    // An Apple ProRes sample entry: the `avc1` code after `stsd` renamed.
    let mut hevc = clip.clone();
    let stsd = hevc.windows(4).position(|w| w == b"stsd").unwrap();
    let at = stsd + hevc[stsd..].windows(4).position(|w| w == b"avc1").unwrap();
    hevc[at..at + 4].copy_from_slice(b"apcn");
    let e = code(&hevc);
    assert_eq!(e.code(), "video_codec_unsupported");
    assert!(
        e.to_string().contains("ProRes") && e.to_string().contains("ffmpeg -i in.mov -c:v libx264"),
        "{e}"
    );
    let info = inspect(Cursor::new(&hevc), &VideoLimits::default()).unwrap();
    assert_eq!((info.width, info.height), (32, 32));
}

#[test]
fn no_decodable_frame_is_reported() {
    let src: Vec<GrayImage> = (0..8).map(|t| pattern(32, 32, t)).collect();
    let mut clip = encode_h264_mp4(&src, 8.0).unwrap();
    // Overwrite the media data (after the 8-byte mdat header) with noise.
    let ftyp_len = u32::from_be_bytes(clip[0..4].try_into().unwrap()) as usize;
    let moov_len = u32::from_be_bytes(clip[ftyp_len..ftyp_len + 4].try_into().unwrap()) as usize;
    let start = ftyp_len + moov_len + 8;
    let mut x = 12345u32;
    for b in &mut clip[start..] {
        x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
        *b = (x >> 16) as u8;
    }
    let (frames, err) = luma_frames(&clip, FrameOptions::default());
    assert!(frames.is_empty());
    let e = err.expect("an error");
    assert_eq!(e.code(), "video_no_decodable_frame", "{e}");
}
