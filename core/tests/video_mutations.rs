//! Mutated clips (made by the writer, and the shared sample clips when present) go through
//! the fuzz entry point without panicking, in bounded time. Also regenerates the fuzz seed
//! corpus on request: `cargo test -p caliper-core --features video --test video_mutations
//! -- --ignored write_fuzz_seeds`.
#![cfg(feature = "video")]

use std::path::PathBuf;
use std::time::{Duration, Instant};

use caliper_core::fuzz_harness;
use caliper_core::video::{WriterOptions, encode_h264_mp4_with};
use image::{GrayImage, Luma};

fn small_clip(frames: u32, w: u32, h: u32, rotation_deg: u16) -> Vec<u8> {
    let src: Vec<GrayImage> = (0..frames)
        .map(|t| GrayImage::from_fn(w, h, |x, y| Luma([((x * 7 + y * 3 + t * 11) % 256) as u8])))
        .collect();
    let opts = WriterOptions {
        rotation_deg,
        keyframe_interval: 4,
        ..Default::default()
    };
    encode_h264_mp4_with(&src, 10.0, &opts).unwrap()
}

/// A deterministic xorshift generator: the test must be reproducible.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

fn mutate(rng: &mut Rng, clip: &[u8]) -> Vec<u8> {
    let mut m = clip.to_vec();
    match rng.below(5) {
        // Flip bytes, mostly in the index (the first part of a writer clip).
        0 | 1 => {
            let span = if rng.below(2) == 0 {
                m.len().min(600)
            } else {
                m.len()
            };
            for _ in 0..1 + rng.below(8) {
                let i = rng.below(span);
                m[i] ^= 1 << rng.below(8);
            }
        }
        // Overwrite a 32-bit field with an extreme value.
        2 => {
            let i = rng.below(m.len().saturating_sub(4));
            let v: [u8; 4] = match rng.below(4) {
                0 => [0, 0, 0, 0],
                1 => [0xFF; 4],
                2 => [0x7F, 0xFF, 0xFF, 0xFF],
                _ => [0, 0, 0, 1],
            };
            m[i..i + 4].copy_from_slice(&v);
        }
        // Truncate.
        3 => m.truncate(rng.below(m.len())),
        // Duplicate a slice somewhere else.
        _ => {
            let a = rng.below(m.len());
            let b = rng.below(m.len());
            let len = rng.below(64).min(m.len() - a.max(b));
            let chunk = m[a..a + len].to_vec();
            m[b..b + len].copy_from_slice(&chunk);
        }
    }
    m
}

#[test]
fn mutated_clips_never_panic() {
    let mut clips = vec![small_clip(6, 32, 32, 0), small_clip(9, 48, 32, 90)];
    let shared = std::env::var_os("CALIPER_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"));
    match std::fs::read(shared.join("video/ae_seq_seed0.mp4")) {
        // The head of the file (index and first frames, index at the end is cut: this
        // exercises the missing-index path) and the whole clip.
        Ok(real) => clips.push(real),
        Err(_) => eprintln!("\n*** shared clips not found: mutating writer clips only ***\n"),
    }
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let deadline = Instant::now() + Duration::from_secs(25);
    let mut runs = 0;
    while Instant::now() < deadline && runs < 400 {
        let clip = &clips[runs % clips.len()];
        let m = mutate(&mut rng, clip);
        let t0 = Instant::now();
        fuzz_harness::video(&m);
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "one input took {:?}",
            t0.elapsed()
        );
        runs += 1;
    }
    assert!(runs >= 20, "only {runs} mutations ran");
    eprintln!("{runs} mutated clips decoded without a panic");
}

#[test]
#[ignore = "writes the fuzz seed corpus; run on request"]
fn write_fuzz_seeds() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus/video");
    std::fs::create_dir_all(&dir).unwrap();
    let seeds = [
        ("seed_gray_32x32.mp4", small_clip(4, 32, 32, 0)),
        ("seed_rot90_48x32.mp4", small_clip(5, 48, 32, 90)),
        ("seed_rot270_16x16.mp4", small_clip(3, 16, 16, 270)),
        ("seed_one_frame.mp4", small_clip(1, 16, 16, 0)),
    ];
    for (name, data) in seeds {
        std::fs::write(dir.join(name), data).unwrap();
    }
}
