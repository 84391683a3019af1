#![no_main]
//! Fuzz target: see `caliper_core::fuzz_harness::video`.

libfuzzer_sys::fuzz_target!(|data: &[u8]| caliper_core::fuzz_harness::video(data));
