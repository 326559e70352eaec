//! Feeds arbitrary bytes to the binary and JSON-lines trace readers (each
//! frame passes the validator). A panic, an abort or an allocation beyond
//! libFuzzer's limit is a bug; errors must name a location inside the input.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lipac_core::trace::{JsonlReader, TraceLimits, TraceLocation, TraceReader};

fn limits() -> TraceLimits {
    // Small enough that a valid-looking count cannot make a test case slow.
    TraceLimits {
        max_header_bytes: 1 << 20,
        max_frame_bytes: 1 << 20,
        max_events_per_frame: 1 << 14,
        max_hits_per_frame: 1 << 14,
        max_live_instances: 1 << 14,
        ..TraceLimits::default()
    }
}

fuzz_target!(|data: &[u8]| {
    let len = data.len() as u64;
    let check = |e: &lipac_core::trace::TraceError| {
        let _ = e.to_string();
        match e.location {
            TraceLocation::Byte(o) => assert!(o <= len, "offset {o} beyond input of {len} bytes: {e}"),
            TraceLocation::Line(l) => assert!(l >= 1 && l <= len + 1, "line {l}: {e}"),
        }
    };
    match TraceReader::with_limits(data, limits()) {
        Ok(mut r) => loop {
            match r.next_frame() {
                Ok(Some(_)) => {}
                Ok(None) => break,
                Err(e) => {
                    check(&e);
                    break;
                }
            }
        },
        Err(e) => check(&e),
    }
    match JsonlReader::with_limits(data, limits()) {
        Ok(mut r) => loop {
            match r.next_frame() {
                Ok(Some(_)) => {}
                Ok(None) => break,
                Err(e) => {
                    check(&e);
                    break;
                }
            }
        },
        Err(e) => check(&e),
    }
});
