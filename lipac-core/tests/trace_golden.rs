//! The committed golden traces in `tests/data/` still parse to the content
//! they were made from, and writing that content reproduces their bytes:
//! any drift of the format fails here.
//!
//! Regenerate (after a deliberate format change, with a version bump) with
//! `LIPAC_BLESS_TRACES=1 cargo test -p lipac-core --test trace_golden`; this
//! also rewrites the fuzz seed corpus in `fuzz/corpus/trace_parser/`.

mod trace_common;

use lipac_core::trace::*;
use std::fs;
use trace_common::*;

const BIN: &str = "tiny.lipactrace";
const JSONL: &str = "tiny.jsonl";

fn bless() {
    if std::env::var_os("LIPAC_BLESS_TRACES").is_none() {
        return;
    }
    let (h, f) = tiny_trace();
    let dir = data_dir();
    fs::create_dir_all(&dir).unwrap();
    fs::write(dir.join(BIN), to_binary(&h, &f)).unwrap();
    fs::write(dir.join(JSONL), to_jsonl(&h, &f)).unwrap();
    let corpus = dir.join("../../fuzz/corpus/trace_parser");
    fs::create_dir_all(&corpus).unwrap();
    fs::write(corpus.join("tiny"), to_binary(&h, &f)).unwrap();
    fs::write(corpus.join("empty"), to_binary(&h, &[])).unwrap();
    for seed in 1..=4 {
        let (h, f) = random_trace(seed, 4);
        fs::write(corpus.join(format!("random{seed}")), to_binary(&h, &f)).unwrap();
    }
}

fn golden(name: &str) -> Vec<u8> {
    bless();
    let path = data_dir().join(name);
    fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn golden_binary_parses_to_the_tiny_trace() {
    let bytes = golden(BIN);
    let (h, f) = tiny_trace();
    let (rh, rf) = read_binary(&bytes).expect("golden binary parses");
    assert_eq!(rh, h);
    assert_eq!(rf, f);
    // PartialEq treats -0.0 == 0.0; the bytes of the re-encoding settle bits.
    assert_eq!(to_binary(&rh, &rf), bytes);
}

#[test]
fn writing_the_tiny_trace_reproduces_the_golden_bytes() {
    let (h, f) = tiny_trace();
    assert_eq!(to_binary(&h, &f), golden(BIN), "binary format drifted");
    assert_eq!(to_jsonl(&h, &f), golden(JSONL), "JSON-lines format drifted");
}

#[test]
fn golden_jsonl_parses_to_the_tiny_trace() {
    let bytes = golden(JSONL);
    let (h, f) = tiny_trace();
    let (rh, rf) = read_jsonl(&bytes).expect("golden jsonl parses");
    assert_eq!((rh, rf), (h, f));
    let text = String::from_utf8(bytes).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    // Header, three frames, end line (docs/trace-format.md).
    assert_eq!(lines.len(), 5);
    assert!(lines[0].starts_with(r#"{"format":"lipac-trace","version":1,"#));
    assert!(lines[1].starts_with(r#"{"frame":10,"camera":"#));
    assert_eq!(lines[4], r#"{"end":{"frames":3}}"#);
    // Values that print exactly are written as such.
    assert!(lines[0].contains(r#""cell_size":16.0"#));
    assert!(lines[2].contains(r#"{"id":1,"hits":1234}"#));
}

#[test]
fn golden_binary_layout_matches_the_documented_framing() {
    let b = golden(BIN);
    let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
    let u64_at = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().unwrap());
    assert_eq!(&b[..8], b"LIPACTRC");
    assert_eq!(&b[8..12], &[1, 0, 0, 0]); // version 1, reserved 0
                                          // Header: scene name length + UTF-8 first.
    let header_len = u64_at(12) as usize;
    let name = "tiny — golden";
    assert_eq!(u32_at(20) as usize, name.len());
    assert_eq!(&b[24..24 + name.len()], name.as_bytes());
    // Walk the frame records by their length prefixes; each starts with its
    // frame number.
    let mut o = 20 + header_len;
    let mut numbers = Vec::new();
    loop {
        let len = u32_at(o) as usize;
        if len == 0 {
            break;
        }
        numbers.push(u64_at(o + 4));
        o += 4 + len;
    }
    assert_eq!(numbers, vec![10, 11, 13]);
    // End marker: length 0, then the frame count, then end of file.
    assert_eq!(u64_at(o + 4), 3);
    assert_eq!(o + 12, b.len());
}

#[test]
fn golden_files_convert_into_each_other() {
    let (bin, jsonl) = (golden(BIN), golden(JSONL));
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
