#![no_main]
//! Fuzz target: see `caliper_core::fuzz_harness::zip`.

libfuzzer_sys::fuzz_target!(|data: &[u8]| caliper_core::fuzz_harness::zip(data));
