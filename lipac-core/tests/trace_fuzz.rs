//! A stable-Rust mutation fuzzer over both trace readers: deterministic,
//! seeded mutations of valid traces (bit flips, interesting integers and
//! floats, deletions, duplications, insertions, splices, truncations; for
//! JSON lines also token and line mutations), each read by both readers
//! directly and through stream detection.
//!
//! Oracles, for every mutated input:
//! * no panic (the test would fail);
//! * an error names a location inside the input (byte offset at most its
//!   length, line at most its line count + 1) and renders;
//! * reading through [`TraceFormat::detect_stream`] gives the same result
//!   as the reader the input's encoding names;
//! * an input that reads fully converts to the other encoding and back to
//!   the same frames (lossless).
//!
//! CI runs a few thousand cases in seconds. Longer runs (see
//! `docs/trace-format.md`, "Fuzzing"):
//!
//! ```text
//! LIPAC_TRACE_FUZZ_CASES=2000000 LIPAC_TRACE_FUZZ_SEED=7 \
//!     cargo test --release -p lipac-core --test trace_fuzz -- --nocapture
//! ```
//!
//! A failure prints the seed and case number; the case replays alone with
//! `LIPAC_TRACE_FUZZ_SEED=<seed> LIPAC_TRACE_FUZZ_ONLY=<case>`.

mod trace_common;

use lipac_core::trace::*;
use std::io::Read;
use trace_common::*;

fn env_u64(name: &str) -> Option<u64> {
    std::env::var(name).ok().and_then(|v| v.trim().parse().ok())
}

/// Small limits, so that a mutated count cannot make one case slow.
fn limits() -> TraceLimits {
    TraceLimits {
        max_header_bytes: 1 << 20,
        max_frame_bytes: 1 << 20,
        max_events_per_frame: 1 << 14,
        max_hits_per_frame: 1 << 14,
        max_live_instances: 1 << 14,
        max_grid_cells: 1 << 20,
        ..TraceLimits::default()
    }
}

type ReadResult = Result<(TraceHeader, Vec<Frame>), TraceError>;

fn read_binary_from<R: Read>(r: R) -> ReadResult {
    let mut r = TraceReader::with_limits(r, limits())?;
    let mut frames = Vec::new();
    while let Some(f) = r.next_frame()? {
        frames.push(f);
    }
    Ok((r.header().clone(), frames))
}

fn read_jsonl_from<R: Read>(r: R) -> ReadResult {
    let mut r = JsonlReader::with_limits(r, limits())?;
    let mut frames = Vec::new();
    while let Some(f) = r.next_frame()? {
        frames.push(f);
    }
    Ok((r.header().clone(), frames))
}

/// Checks one input against every oracle; `Ok(true)` if it read fully in
/// some encoding.
fn check(input: &[u8]) -> Result<bool, String> {
    let len = input.len() as u64;
    let lines = input.iter().filter(|&&b| b == b'\n').count() as u64 + 1;
    let located = |e: &TraceError| -> Result<(), String> {
        let text = e.to_string();
        if text.is_empty() {
            return Err("empty error message".into());
        }
        match e.location {
            TraceLocation::Byte(o) if o > len => {
                Err(format!("offset {o} beyond {len} bytes: {text}"))
            }
            TraceLocation::Line(l) if l == 0 || l > lines + 1 => {
                Err(format!("line {l} of {lines}: {text}"))
            }
            _ => Ok(()),
        }
    };
    let bin = read_binary_from(input);
    let json = read_jsonl_from(input);
    for r in [&bin, &json] {
        if let Err(e) = r {
            located(e)?;
        }
    }
    let (format, peeked) =
        TraceFormat::detect_stream(input).map_err(|e| format!("detect_stream: {e}"))?;
    let via_stream = match format {
        Some(TraceFormat::Binary) => Some((read_binary_from(peeked), &bin)),
        Some(TraceFormat::Jsonl) => Some((read_jsonl_from(peeked), &json)),
        None => None,
    };
    if let Some((streamed, direct)) = via_stream {
        // (Compared as text: an error may carry a NaN, which is not equal
        // to itself.)
        if format!("{streamed:?}") != format!("{direct:?}") {
            return Err(format!(
                "{format:?} read through detect_stream differs from the direct read: \
                 {:?} vs {:?}",
                streamed.as_ref().err(),
                direct.as_ref().err()
            ));
        }
    }
    let mut ok = false;
    for (r, from_binary) in [(&bin, true), (&json, false)] {
        let Ok((h, frames)) = r else { continue };
        ok = true;
        let other = if from_binary {
            binary_to_jsonl(input, Vec::new(), limits())
        } else {
            jsonl_to_binary(input, Vec::new(), limits())
        }
        .map_err(|e| format!("a trace that reads does not convert: {e}"))?;
        let back = if from_binary {
            read_jsonl_from(other.as_slice())
        } else {
            read_binary_from(other.as_slice())
        }
        .map_err(|e| format!("converted trace does not read: {e}"))?;
        if back.0 != *h || back.1 != *frames {
            return Err("conversion is not lossless".into());
        }
    }
    Ok(ok)
}

const INTERESTING_U32: [u32; 9] = [
    0,
    1,
    2,
    0x7F,
    0xFF,
    0xFFFF,
    0x7FFF_FFFF,
    0x8000_0000,
    u32::MAX,
];

const INTERESTING_F32: [f32; 10] = [
    0.0,
    -0.0,
    1e-45,
    f32::MIN_POSITIVE,
    3e38,
    -3e38,
    f32::MAX,
    f32::INFINITY,
    f32::NAN,
    1e6,
];

const JSON_TOKENS: [&str; 16] = [
    "0",
    "-1",
    "1e-45",
    "3e38",
    "-3e38",
    "1e999",
    "18446744073709551615",
    "18446744073709551616",
    "4294967296",
    "null",
    "true",
    "\"\"",
    "[]",
    "{}",
    "[0.0,0.0,0.0]",
    " ",
];

/// One mutation of `b` (`others` for splices).
fn mutate(rng: &mut Rng, b: &mut Vec<u8>, others: &[Vec<u8>], text: bool) {
    if b.is_empty() {
        b.push(rng.next_u64() as u8);
        return;
    }
    let at = rng.below(b.len() as u64) as usize;
    let ops = if text { 12 } else { 9 };
    match rng.below(ops) {
        0 => b[at] ^= 1 << rng.below(8),
        1 => b[at] = [0u8, 0xFF, 0x7F, 0x80, 1][rng.below(5) as usize],
        2 if b.len() >= 4 => {
            let at = at.min(b.len() - 4);
            let v = INTERESTING_U32[rng.below(INTERESTING_U32.len() as u64) as usize];
            b[at..at + 4].copy_from_slice(&v.to_le_bytes());
        }
        3 if b.len() >= 4 => {
            let at = at.min(b.len() - 4);
            let v = INTERESTING_F32[rng.below(INTERESTING_F32.len() as u64) as usize];
            b[at..at + 4].copy_from_slice(&v.to_le_bytes());
        }
        4 => {
            let n = 1 + rng.below(32) as usize;
            b.drain(at..(at + n).min(b.len()));
        }
        5 => {
            let n = (1 + rng.below(64) as usize).min(b.len() - at);
            let dup = b[at..at + n].to_vec();
            b.splice(at..at, dup);
        }
        6 => {
            let n = 1 + rng.below(16) as usize;
            let junk: Vec<u8> = (0..n).map(|_| rng.next_u64() as u8).collect();
            b.splice(at..at, junk);
        }
        7 => {
            let other = &others[rng.below(others.len() as u64) as usize];
            if !other.is_empty() {
                let from = rng.below(other.len() as u64) as usize;
                b.truncate(at);
                b.extend_from_slice(&other[from..]);
            }
        }
        8 => b.truncate(at),
        // JSON lines only: tokens and lines.
        9 => {
            // Replace the number or token starting at a digit near `at`.
            let start = (at..b.len()).find(|&i| b[i].is_ascii_digit() || b[i] == b'-');
            if let Some(s) = start {
                let end = (s + 1..b.len())
                    .find(|&i| !(b[i].is_ascii_alphanumeric() || b"-+.".contains(&b[i])))
                    .unwrap_or(b.len());
                let t = JSON_TOKENS[rng.below(JSON_TOKENS.len() as u64) as usize];
                b.splice(s..end, t.bytes());
            }
        }
        10 => {
            // Duplicate, drop or swap whole lines.
            let mut lines: Vec<Vec<u8>> = b.split(|&c| c == b'\n').map(<[u8]>::to_vec).collect();
            let i = rng.below(lines.len() as u64) as usize;
            let j = rng.below(lines.len() as u64) as usize;
            match rng.below(3) {
                0 => {
                    let l = lines[i].clone();
                    lines.insert(j, l);
                }
                1 => {
                    lines.remove(i);
                }
                _ => lines.swap(i, j),
            }
            *b = lines.join(&b'\n');
        }
        11 => {
            // Structural characters.
            b[at] = b"{}[]\":, \n\r\t"[rng.below(11) as usize];
        }
        _ => b[at] = rng.next_u64() as u8,
    }
}

#[test]
fn mutated_traces_never_panic_and_errors_say_where() {
    let cases = env_u64("LIPAC_TRACE_FUZZ_CASES").unwrap_or(4000);
    let seed = env_u64("LIPAC_TRACE_FUZZ_SEED").unwrap_or(0x5EED);
    let only = env_u64("LIPAC_TRACE_FUZZ_ONLY");
    let mut base: Vec<(Vec<u8>, bool)> = Vec::new();
    let (h, f) = tiny_trace();
    base.push((to_binary(&h, &f), false));
    base.push((to_jsonl(&h, &f), true));
    for s in 0..6 {
        let (h, f) = random_trace(seed.wrapping_add(s), 1 + s as usize * 2);
        base.push((to_binary(&h, &f), false));
        base.push((to_jsonl(&h, &f), true));
    }
    let others: Vec<Vec<u8>> = base.iter().map(|(b, _)| b.clone()).collect();
    // Every base input is valid in its own encoding.
    for (b, _) in &base {
        assert_eq!(check(b), Ok(true));
    }
    let (mut valid, mut invalid) = (0u64, 0u64);
    for case in 0..cases {
        if only.is_some_and(|o| o != case) {
            continue;
        }
        // One generator per case: any case replays alone.
        let mut rng = Rng::from_seed(seed ^ case.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let (b0, text) = &base[rng.below(base.len() as u64) as usize];
        let mut b = b0.clone();
        for _ in 0..1 + rng.below(4) {
            mutate(&mut rng, &mut b, &others, *text);
        }
        match check(&b) {
            Ok(true) => valid += 1,
            Ok(false) => invalid += 1,
            Err(why) => panic!(
                "seed {seed} case {case} ({} bytes): {why}\n\
                 replay with LIPAC_TRACE_FUZZ_SEED={seed} LIPAC_TRACE_FUZZ_ONLY={case}",
                b.len()
            ),
        }
    }
    println!("{cases} cases from seed {seed}: {valid} still valid, {invalid} rejected");
    if only.is_none() && cases >= 1000 {
        // The mutations mostly break a trace, and some leave it valid (a
        // flipped mantissa bit): both sides of every oracle are exercised.
        assert!(
            invalid > valid && valid > 0,
            "{valid} valid, {invalid} rejected"
        );
    }
}
