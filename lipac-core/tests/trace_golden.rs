//! The committed golden traces in `tests/data/` still parse to the content
//! they were made from, and writing that content reproduces their bytes:
//! any drift of the format fails here. `tiny.*` are version 1 (written
//! before version 2 existed: they must keep reading identically, and a
//! version-1 writer must keep reproducing them), `tiny-v2.*` version 2.
//!
//! Regenerate (after a deliberate format change, with a version bump) with
//! `LIPAC_BLESS_TRACES=1 cargo test -p lipac-core --test trace_golden`; this
//! writes only the version-2 files (version 1's are history) and rewrites
//! the fuzz seed corpus in `fuzz/corpus/trace_parser/`.

mod trace_common;

use lipac_core::trace::*;
use std::fs;
use trace_common::*;

const BIN: &str = "tiny.lipactrace";
const JSONL: &str = "tiny.jsonl";
const BIN2: &str = "tiny-v2.lipactrace";
const JSONL2: &str = "tiny-v2.jsonl";

fn bless() {
    if std::env::var_os("LIPAC_BLESS_TRACES").is_none() {
        return;
    }
    let (h, f) = tiny_v2_trace();
    let dir = data_dir();
    fs::create_dir_all(&dir).unwrap();
    fs::write(dir.join(BIN2), to_binary(&h, &f)).unwrap();
    fs::write(dir.join(JSONL2), to_jsonl(&h, &f)).unwrap();
    let corpus = dir.join("../../fuzz/corpus/trace_parser");
    fs::create_dir_all(&corpus).unwrap();
    fs::write(corpus.join("tiny-v2"), to_binary(&h, &f)).unwrap();
    let (h, f) = tiny_trace();
    fs::write(corpus.join("tiny"), to_binary_v(1, &h, &f)).unwrap();
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
    assert_eq!(TraceReader::new(bytes.as_slice()).unwrap().version(), 1);
    // PartialEq treats -0.0 == 0.0; the bytes of the re-encoding settle bits.
    assert_eq!(to_binary_v(1, &rh, &rf), bytes);
}

#[test]
fn writing_the_tiny_trace_reproduces_the_golden_bytes() {
    let (h, f) = tiny_trace();
    assert_eq!(to_binary_v(1, &h, &f), golden(BIN), "binary format drifted");
    assert_eq!(
        to_jsonl_v(1, &h, &f),
        golden(JSONL),
        "JSON-lines format drifted"
    );
    let (h, f) = tiny_v2_trace();
    assert_eq!(to_binary(&h, &f), golden(BIN2), "binary v2 format drifted");
    assert_eq!(to_jsonl(&h, &f), golden(JSONL2), "JSON-lines v2 drifted");
}

#[test]
fn version_2_differs_from_version_1_only_where_it_adds() {
    // Content without slots writes the same bytes in both versions but
    // the version field.
    let (h, f) = tiny_trace();
    let mut v2 = to_binary(&h, &f);
    assert_eq!(&v2[8..10], &[2, 0]);
    v2[8] = 1;
    assert_eq!(v2, golden(BIN));
    // A version-1 writer refuses version 2's fields.
    let (h, f) = tiny_v2_trace();
    let mut w = TraceWriter::with_version(Vec::new(), &h, TraceLimits::default(), 1).unwrap();
    let e = w.write_frame(&f[0]).unwrap_err();
    assert_eq!(
        e.kind,
        TraceErrorKind::NotInVersion {
            what: "add slot",
            version: 1
        },
        "{e}"
    );
    let mut w = JsonlWriter::with_version(Vec::new(), &h, TraceLimits::default(), 1).unwrap();
    assert!(w.write_frame(&f[0]).is_err());
    assert!(TraceWriter::with_version(Vec::new(), &h, TraceLimits::default(), 3).is_err());
}

#[test]
fn golden_v2_files_parse_to_the_tiny_v2_trace() {
    let (h, f) = tiny_v2_trace();
    for (name, bytes) in [(BIN2, golden(BIN2)), (JSONL2, golden(JSONL2))] {
        let (rh, rf) = if name == BIN2 {
            read_binary(&bytes)
        } else {
            read_jsonl(&bytes)
        }
        .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!((&rh, &rf), (&h, &f), "{name}");
    }
    // The derived hits of the last frame: the box's 10 hits go to
    // instance 2 (no hits of its own), instance u64::MAX keeps its 7.
    assert_eq!(
        f[3].hits.as_deref(),
        Some(
            &[
                InstanceHits { id: 2, hits: 10 },
                InstanceHits {
                    id: u64::MAX,
                    hits: 7
                }
            ][..]
        )
    );
    let text = String::from_utf8(golden(JSONL2)).unwrap();
    assert!(text.starts_with(r#"{"format":"lipac-trace","version":2,"#));
    assert!(text.contains(r#""slot":5,"#), "{text}");
    assert!(
        text.contains(r#""slot_hits":{"slots":[0,0,0,0,0,7],"boxes":[[9,10]]}"#),
        "{text}"
    );
    let limits = TraceLimits::default();
    let (bin, jsonl) = (golden(BIN2), golden(JSONL2));
    assert_eq!(
        binary_to_jsonl(bin.as_slice(), Vec::new(), limits).unwrap(),
        jsonl
    );
    assert_eq!(
        jsonl_to_binary(jsonl.as_slice(), Vec::new(), limits).unwrap(),
        bin
    );
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
