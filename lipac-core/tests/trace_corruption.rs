//! Thousands of corrupted traces from a seeded generator: the readers never
//! panic, every error names a location inside the input (and a frame once
//! past the header), and every valid trace parses fully.

mod trace_common;

use lipac_core::trace::*;
use trace_common::*;

/// Reads a whole binary trace; on error checks what the error names.
fn check_binary(bytes: &[u8]) -> Result<usize, TraceError> {
    let header_end = 20
        + bytes
            .get(12..20)
            .map_or(0, |b| u64::from_le_bytes(b.try_into().unwrap()));
    let res = read_binary(bytes).map(|(_, f)| f.len());
    if let Err(e) = &res {
        let TraceLocation::Byte(at) = e.location else {
            panic!("binary error with a line: {e}")
        };
        assert!(
            at <= bytes.len() as u64,
            "offset {at} beyond {} bytes: {e}",
            bytes.len()
        );
        let end_marker = matches!(
            e.kind,
            TraceErrorKind::TrailingData | TraceErrorKind::FrameCountMismatch { .. }
        ) || matches!(
            e.kind,
            TraceErrorKind::Truncated {
                what: "end marker frame count",
                ..
            }
        );
        if at > header_end && !end_marker {
            assert!(
                e.frame_index.is_some(),
                "error past the header names no frame: {e}"
            );
        }
        assert!(!e.to_string().is_empty());
    }
    res
}

fn check_jsonl(bytes: &[u8]) -> Result<usize, TraceError> {
    let res = read_jsonl(bytes).map(|(_, f)| f.len());
    if let Err(e) = &res {
        let TraceLocation::Line(line) = e.location else {
            panic!("jsonl error with a byte offset: {e}")
        };
        let lines = bytes.iter().filter(|&&b| b == b'\n').count() as u64 + 1;
        // (One past the last line: the line that is missing.)
        assert!(
            (1..=lines + 1).contains(&line),
            "line {line} of {lines}: {e}"
        );
        if line > 1
            && !matches!(
                e.kind,
                TraceErrorKind::TrailingData | TraceErrorKind::FrameCountMismatch { .. }
            )
        {
            assert!(e.frame_index.is_some(), "{e}");
        }
    }
    res
}

#[test]
fn valid_random_traces_parse_fully_in_both_encodings() {
    for seed in 0..50 {
        let (h, frames) = random_trace(seed, 1 + seed as usize % 20);
        let bin = to_binary(&h, &frames);
        let (rh, rf) = read_binary(&bin).expect("valid binary");
        assert_eq!((&rh, &rf), (&h, &frames));
        let jsonl = to_jsonl(&h, &frames);
        let (jh, jf) = read_jsonl(&jsonl).expect("valid jsonl");
        assert_eq!((&jh, &jf), (&h, &frames));
        // Lossless both ways, bit for bit.
        let limits = TraceLimits::default();
        assert_eq!(
            binary_to_jsonl(bin.as_slice(), Vec::new(), limits).unwrap(),
            jsonl
        );
        assert_eq!(
            jsonl_to_binary(jsonl.as_slice(), Vec::new(), limits).unwrap(),
            bin
        );
    }
}

#[test]
fn every_truncation_is_an_error() {
    let (h, frames) = random_trace(7, 5);
    let bin = to_binary(&h, &frames);
    for cut in 0..bin.len() {
        assert!(
            check_binary(&bin[..cut]).is_err(),
            "cut at {cut} of {} parsed",
            bin.len()
        );
    }
    assert_eq!(check_binary(&bin).unwrap(), frames.len());
    let jsonl = to_jsonl(&h, &frames);
    for cut in 0..jsonl.len() - 1 {
        // (Only the final newline may go.)
        assert!(
            check_jsonl(&jsonl[..cut]).is_err(),
            "jsonl cut at {cut} parsed"
        );
    }
}

#[test]
fn byte_flips_overwrites_and_splices_never_panic() {
    let mut rng = Rng::from_seed(0xC0FFEE);
    let traces: Vec<Vec<u8>> = (0..8)
        .map(|s| {
            let (h, f) = random_trace(100 + s, 1 + s as usize);
            to_binary(&h, &f)
        })
        .collect();
    let huge: [[u8; 4]; 5] = [
        u32::MAX.to_le_bytes(),
        0x8000_0000u32.to_le_bytes(),
        0x7FFF_FFFFu32.to_le_bytes(),
        0x0100_0000u32.to_le_bytes(),
        [0, 0, 0, 0],
    ];
    let (mut ok, mut failed) = (0, 0);
    for i in 0..6000 {
        let base = &traces[i % traces.len()];
        let mut b = base.clone();
        match i % 4 {
            0 => {
                for _ in 0..1 + rng.below(4) {
                    let at = rng.below(b.len() as u64) as usize;
                    b[at] ^= 1 << rng.below(8);
                }
            }
            1 => {
                let at = rng.below(b.len() as u64 - 4) as usize;
                b[at..at + 4].copy_from_slice(&huge[rng.below(5) as usize]);
            }
            2 => {
                let other = &traces[rng.below(traces.len() as u64) as usize];
                let cut = rng.below(b.len() as u64) as usize;
                let from = rng.below(other.len() as u64) as usize;
                b.truncate(cut);
                b.extend_from_slice(&other[from..]);
            }
            _ => {
                let at = rng.below(b.len() as u64) as usize;
                let n = 1 + rng.below(16) as usize;
                if rng.chance_percent(50) {
                    b.drain(at..(at + n).min(b.len()));
                } else {
                    let junk: Vec<u8> = (0..n).map(|_| rng.next_u64() as u8).collect();
                    b.splice(at..at, junk);
                }
            }
        }
        match check_binary(&b) {
            Ok(_) => ok += 1,
            Err(_) => failed += 1,
        }
    }
    // The corruptions mostly break the trace; a few (e.g. a flipped hit
    // count or transform mantissa bit) leave a valid one.
    assert!(failed > ok, "{failed} errors, {ok} valid");
}

#[test]
fn jsonl_byte_flips_never_panic() {
    let mut rng = Rng::from_seed(42);
    let (h, f) = random_trace(9, 6);
    let text = to_jsonl(&h, &f);
    let alphabet = b"{}[]\":,0123456789-.eE \nxa";
    for _ in 0..3000 {
        let mut b = text.clone();
        for _ in 0..1 + rng.below(3) {
            let at = rng.below(b.len() as u64) as usize;
            b[at] = alphabet[rng.below(alphabet.len() as u64) as usize];
        }
        let _ = check_jsonl(&b);
    }
}
