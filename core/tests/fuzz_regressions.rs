//! Replays the fuzz corpora (`core/fuzz/corpus/<target>/`) and every input that once crashed a
//! fuzz target (`core/fuzz/regressions/<target>/`) through the same entry points the fuzzer
//! uses, so a fixed crash stays fixed without running a fuzzer. Also checks the zip checks'
//! verdicts on the hand-made archives of the corpus.

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

/// The fuzzers run with `-rss_limit_mb=1024`; an input that makes a parser ask for more is a
/// bug (a count from the file trusted before the bytes behind it). This allocator refuses
/// anything past that budget, so such a regression aborts this test at once instead of
/// swapping the machine to death.
struct Budgeted;

const BUDGET_BYTES: usize = 1 << 30;
static LIVE: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator; only the accounting is added.
unsafe impl GlobalAlloc for Budgeted {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let before = LIVE.fetch_add(layout.size(), Ordering::Relaxed);
        if before + layout.size() > BUDGET_BYTES {
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
            return std::ptr::null_mut();
        }
        // SAFETY: same layout contract as the caller's.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        // SAFETY: `ptr` came from `alloc` above with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Budgeted = Budgeted;

/// A fuzz entry point.
type Harness = fn(&[u8]);

fn replay(dir: &str, target: &str, run: Harness) -> usize {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz")
        .join(dir)
        .join(target);
    let Ok(entries) = std::fs::read_dir(&root) else {
        return 0;
    };
    let mut n = 0;
    for e in entries.flatten() {
        let p = e.path();
        if p.is_file() && p.file_name().is_some_and(|f| f != ".gitkeep") {
            let data = std::fs::read(&p).expect("read corpus file");
            run(&data);
            n += 1;
        }
    }
    n
}

#[test]
fn corpora_and_regressions_replay_without_panics() {
    use caliper_core::fuzz_harness as h;
    let targets: [(&str, Harness); 5] = [
        ("image", h::image),
        ("imu_log", h::imu_log),
        ("psf", h::psf),
        ("dso", h::dso),
        ("zip", h::zip),
    ];
    for (target, run) in targets {
        let corpus = replay("corpus", target, run);
        assert!(corpus > 0, "the {target} corpus is empty");
        replay("regressions", target, run);
    }
}

/// The video target (feature `video`): its corpus of small clips and every input that once
/// crashed it.
#[cfg(feature = "video")]
#[test]
fn video_corpus_and_regressions_replay_without_panics() {
    let run: Harness = caliper_core::fuzz_harness::video;
    let corpus = replay("corpus", "video", run);
    assert!(corpus > 0, "the video corpus is empty");
    replay("regressions", "video", run);
}

#[test]
fn hand_made_archives_get_the_right_verdict() {
    use caliper_core::io::archive::{ArchiveFault, ArchiveLimits, unpack};
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus/zip");
    let limits = ArchiveLimits {
        max_entries: 10,
        max_total_bytes: 1 << 20,
        max_ratio: 200,
    };
    let verdict = |name: &str| {
        let data = std::fs::read(dir.join(name)).expect("read");
        let mut names = Vec::new();
        let mut sink = |n: &str, r: &mut dyn std::io::Read| {
            names.push(n.to_string());
            Ok(std::io::copy(r, &mut std::io::sink()).expect("drain"))
        };
        unpack(
            std::io::Cursor::new(&data),
            data.len() as u64,
            name,
            limits,
            &mut sink,
        )
        .map_err(|e| e.fault)?;
        Ok::<_, ArchiveFault>(names)
    };
    assert_eq!(
        verdict("two.zip"),
        Ok(vec!["a/x.png".to_string(), "b.png".to_string()])
    );
    assert_eq!(verdict("duplicate.zip"), Err(ArchiveFault::DuplicateName));
    assert_eq!(verdict("absolute.zip"), Err(ArchiveFault::UnsafePath));
}
