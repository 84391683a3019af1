use super::*;
use image::ExtendedColorType;
use image::ImageEncoder;
use image::codecs::jpeg::JpegEncoder;
use image::codecs::png::PngEncoder;
use image::codecs::tiff::TiffEncoder;

fn png(data: &[u8], w: u32, h: u32, ct: ExtendedColorType) -> Vec<u8> {
    let mut out = Vec::new();
    PngEncoder::new(&mut out)
        .write_image(data, w, h, ct)
        .unwrap();
    out
}

fn ramp(w: u32, h: u32) -> Vec<u8> {
    (0..w * h).map(|i| (i * 7 % 251) as u8).collect()
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xedb8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

#[test]
fn png_probes_and_decodes() {
    let data = ramp(13, 7);
    let bytes = png(&data, 13, 7, ExtendedColorType::L8);
    let info = probe_image(Cursor::new(&bytes), &ImageLimits::default()).unwrap();
    assert_eq!(
        info,
        ImageInfo {
            format: "png".into(),
            width: 13,
            height: 7,
            bit_depth: 8,
            channels: 1
        }
    );
    let g = decode_gray8(&bytes, &ImageLimits::default()).unwrap();
    assert_eq!((g.width, g.height), (13, 7));
    assert_eq!(g.data, data);
}

#[test]
fn truncated_png_and_jpeg_are_invalid_input() {
    let bytes = png(&ramp(64, 64), 64, 64, ExtendedColorType::L8);
    for cut in [8, 30, bytes.len() / 2, bytes.len() - 13] {
        let e = decode_gray8(&bytes[..cut], &ImageLimits::default()).unwrap_err();
        assert!(matches!(e, CoreError::InvalidInput(_)), "cut {cut}: {e:?}");
    }
    let mut jpg = Vec::new();
    JpegEncoder::new_with_quality(&mut jpg, 90)
        .write_image(&ramp(64, 64), 64, 64, ExtendedColorType::L8)
        .unwrap();
    assert!(decode_gray8(&jpg, &ImageLimits::default()).is_ok());
    for cut in [3, 100, jpg.len() / 2] {
        let e = decode_gray8(&jpg[..cut], &ImageLimits::default()).unwrap_err();
        assert!(matches!(e, CoreError::InvalidInput(_)), "cut {cut}: {e:?}");
    }
    let e = decode_gray8(b"not an image at all", &ImageLimits::default()).unwrap_err();
    assert!(matches!(e, CoreError::InvalidInput(_)));
    let e = decode_gray8(&[], &ImageLimits::default()).unwrap_err();
    assert!(matches!(e, CoreError::InvalidInput(_)));
}

/// A tiny PNG whose IHDR is patched to claim 10000×10000 (with a valid CRC): the header alone
/// must be enough to reject it.
fn png_claiming(w: u32, h: u32) -> Vec<u8> {
    let mut bytes = png(&ramp(4, 4), 4, 4, ExtendedColorType::L8);
    assert_eq!(&bytes[12..16], b"IHDR");
    bytes[16..20].copy_from_slice(&w.to_be_bytes());
    bytes[20..24].copy_from_slice(&h.to_be_bytes());
    let crc = crc32(&bytes[12..29]);
    bytes[29..33].copy_from_slice(&crc.to_be_bytes());
    bytes
}

#[test]
fn huge_header_rejected_without_allocating() {
    // 10000×10000 is exactly 100 Mpx, the default limit (inclusive): use a 64 Mpx limit here
    // and check the default limits on a 20000×20000 header (would need 400 MB of grey pixels).
    let bytes = png_claiming(10_000, 10_000);
    let limits = ImageLimits {
        max_pixels: 64_000_000,
        ..ImageLimits::default()
    };
    let e = probe_image(Cursor::new(&bytes), &limits).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, CoreError::InvalidInput(_)), "{msg}");
    assert!(
        msg.contains("10000×10000") && msg.contains("64 Mpx"),
        "{msg}"
    );
    let e = probe_image(
        Cursor::new(png_claiming(20_000, 20_000)),
        &ImageLimits::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("20000×20000"), "{e}");
    assert!(matches!(
        decode_gray8(&bytes, &limits),
        Err(CoreError::InvalidInput(_))
    ));
    // Within a generous pixel limit the header is accepted (proving the CRC patch is valid),
    // while the small side limit still rejects it.
    let big = ImageLimits::default();
    let info = probe_image(Cursor::new(&bytes), &big).unwrap();
    assert_eq!((info.width, info.height), (10_000, 10_000));
    let narrow = ImageLimits {
        max_width: 100,
        ..big
    };
    assert!(probe_image(Cursor::new(&bytes), &narrow).is_err());
}

#[test]
fn sixteen_bit_png_decodes_like_opencv() {
    let vals: Vec<u16> = vec![0, 255, 256, 0x1234, 0xfeff, 0xffff];
    let raw: Vec<u8> = vals.iter().flat_map(|v| v.to_ne_bytes()).collect();
    let bytes = png(&raw, 3, 2, ExtendedColorType::L16);
    let info = probe_image(Cursor::new(&bytes), &ImageLimits::default()).unwrap();
    assert_eq!((info.bit_depth, info.channels), (16, 1));
    let g = decode_gray8(&bytes, &ImageLimits::default()).unwrap();
    assert_eq!(g.data, vec![0, 0, 1, 0x12, 0xfe, 0xff]);
}

/// Reference values from `cv2.imread(.., IMREAD_GRAYSCALE)` (OpenCV 5.0.0) on the same RGB
/// pixels written as PNG and as TIFF.
#[test]
fn colour_conversion_matches_opencv() {
    let rgb: [[u8; 3]; 10] = [
        [0, 15, 106],
        [216, 22, 0],
        [49, 27, 0],
        [255, 255, 255],
        [3, 0, 0],
        [4, 0, 0],
        [100, 200, 50],
        [255, 0, 0],
        [0, 255, 0],
        [0, 0, 255],
    ];
    let raw: Vec<u8> = rgb.iter().flatten().copied().collect();
    let bytes = png(&raw, 10, 1, ExtendedColorType::Rgb8);
    let g = decode_gray8(&bytes, &ImageLimits::default()).unwrap();
    assert_eq!(g.data, vec![20, 77, 30, 255, 0, 1, 152, 76, 149, 29]);

    let mut tif = Cursor::new(Vec::new());
    TiffEncoder::new(&mut tif)
        .write_image(&raw, 10, 1, ExtendedColorType::Rgb8)
        .unwrap();
    let tif = tif.into_inner();
    let info = probe_image(Cursor::new(&tif), &ImageLimits::default()).unwrap();
    assert_eq!((info.format.as_str(), info.channels), ("tiff", 3));
    let g = decode_gray8(&tif, &ImageLimits::default()).unwrap();
    assert_eq!(g.data, vec![21, 77, 30, 255, 1, 1, 153, 76, 150, 29]);

    // Alpha is ignored.
    let rgba: Vec<u8> = rgb.iter().flat_map(|p| [p[0], p[1], p[2], 7]).collect();
    let bytes = png(&rgba, 10, 1, ExtendedColorType::Rgba8);
    let g = decode_gray8(&bytes, &ImageLimits::default()).unwrap();
    assert_eq!(g.data, vec![20, 77, 30, 255, 0, 1, 152, 76, 149, 29]);
}

#[test]
fn gray_new_checks_length() {
    assert!(Gray::new(2, 2, vec![0; 4]).is_ok());
    assert!(Gray::new(2, 2, vec![0; 3]).is_err());
}

/// A colour JPEG of a chessboard edge with lateral chromatic aberration (red and blue fringes
/// a pixel either side): our grey is OpenCV's luma plane to within one level (the IDCTs
/// differ), where converting the decoded RGB strays further. Runs with `CALIPER_PYTHON`.
#[test]
fn colour_jpeg_grey_is_the_luma_plane_like_opencv() {
    let (w, h) = (96u32, 64u32);
    let mut rgb = Vec::with_capacity((w * h * 3) as usize);
    for y in 0..h {
        for x in 0..w {
            let edge = |dx: f64| {
                let u = f64::from(x) + dx - 0.37 * f64::from(y) - 30.0;
                let t = (u / 0.6).tanh() * 0.5 + 0.5;
                (5.0 + 245.0 * t).round() as u8
            };
            rgb.extend([edge(2.5), edge(0.0), edge(-2.5)]);
        }
    }
    let mut jpg = Vec::new();
    JpegEncoder::new_with_quality(&mut jpg, 85)
        .write_image(&rgb, w, h, ExtendedColorType::Rgb8)
        .unwrap();
    let ours = decode_gray8(&jpg, &ImageLimits::default()).unwrap();
    assert_eq!((ours.width, ours.height), (w, h));
    let Some(py) = crate::test_env::python("cv2,numpy") else {
        return;
    };
    let dir = std::env::temp_dir().join(format!("caliper-jpeg-luma-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("fringe.jpg");
    std::fs::write(&path, &jpg).unwrap();
    let out = std::process::Command::new(py)
        .args([
            "-c",
            "import cv2,sys; g=cv2.imread(sys.argv[1], cv2.IMREAD_GRAYSCALE); \
             print(' '.join(str(int(v)) for v in g.ravel()))",
            path.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    std::fs::remove_dir_all(&dir).ok();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let cv: Vec<i32> = String::from_utf8_lossy(&out.stdout)
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    assert_eq!(cv.len(), ours.data.len());
    let diff = |g: &[u8]| {
        g.iter()
            .zip(&cv)
            .map(|(&a, &b)| (i32::from(a) - b).abs())
            .max()
            .unwrap_or(0)
    };
    let (img, format) = decode_image(&jpg, &ImageLimits::default()).unwrap();
    let via_rgb = to_gray(img, format);
    eprintln!(
        "max |ours − OpenCV| {}, via RGB {}",
        diff(&ours.data),
        diff(&via_rgb)
    );
    assert!(diff(&ours.data) <= 1, "luma plane differs from OpenCV's");
}
