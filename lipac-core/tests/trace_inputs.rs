//! Inputs read once from a stream (pipes, FIFOs, standard input), headers
//! that would make a replay allocate without bound, and error labels after
//! the end marker (issue 12).

mod trace_common;

use lipac_core::trace::*;
use std::io::Read;
use trace_common::*;

/// A reader that hands out one byte per call and cannot seek: a pipe.
struct Trickle<'a>(&'a [u8]);

impl Read for Trickle<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match (self.0.split_first(), buf.is_empty()) {
            (Some((b, rest)), false) => {
                buf[0] = *b;
                self.0 = rest;
                Ok(1)
            }
            _ => Ok(0),
        }
    }
}

fn tiny_binary() -> Vec<u8> {
    let (h, f) = tiny_trace();
    to_binary(&h, &f)
}

fn tiny_jsonl() -> Vec<u8> {
    let (h, f) = tiny_trace();
    to_jsonl(&h, &f)
}

#[test]
fn format_is_detected_from_one_pass_over_a_stream() {
    let (h, frames) = tiny_trace();
    for (bytes, format) in [
        (tiny_binary(), TraceFormat::Binary),
        (tiny_jsonl(), TraceFormat::Jsonl),
    ] {
        let (got, r) = TraceFormat::detect_stream(Trickle(&bytes)).unwrap();
        assert_eq!(got, Some(format));
        // The peeked bytes are given back: the whole trace reads.
        let read = match format {
            TraceFormat::Binary => {
                let mut r = TraceReader::new(r).unwrap();
                assert_eq!(r.header(), &h);
                std::iter::from_fn(|| r.next_frame().unwrap()).collect::<Vec<_>>()
            }
            TraceFormat::Jsonl => {
                let mut r = JsonlReader::new(r).unwrap();
                assert_eq!(r.header(), &h);
                std::iter::from_fn(|| r.next_frame().unwrap()).collect::<Vec<_>>()
            }
        };
        assert_eq!(read, frames);
    }
    let (got, mut r) = TraceFormat::detect_stream(&b"PK\x03\x04zip"[..]).unwrap();
    assert_eq!(got, None);
    let mut all = Vec::new();
    r.read_to_end(&mut all).unwrap();
    assert_eq!(all, b"PK\x03\x04zip");
}

#[test]
fn jsonl_after_long_leading_whitespace_is_detected() {
    // More than 64 bytes of blanks before the header object (the old
    // detection looked at 64 bytes only and called it neither format).
    for blanks in [65, 200, 70_000] {
        let mut text = " \t".repeat(blanks / 2).into_bytes();
        text.extend_from_slice(&tiny_jsonl());
        let (got, r) = TraceFormat::detect_stream(Trickle(&text)).unwrap();
        assert_eq!(got, Some(TraceFormat::Jsonl), "{blanks} blanks");
        let mut r = JsonlReader::new(r).unwrap();
        let mut n = 0;
        while r.next_frame().unwrap().is_some() {
            n += 1;
        }
        assert_eq!(n, 3);
    }
    // Whitespace only, past the cap: neither (and memory stays bounded).
    let blank = vec![b' '; MAX_DETECT_WHITESPACE + 10];
    assert_eq!(
        TraceFormat::detect_stream(blank.as_slice()).unwrap().0,
        None
    );
}

/// The world grid's five `f64`s start after the preamble and the scene
/// name.
fn world_at(bytes: &[u8]) -> usize {
    let name_len = u32::from_le_bytes(bytes[20..24].try_into().unwrap()) as usize;
    24 + name_len
}

#[test]
fn a_huge_world_grid_is_refused_naming_its_size() {
    // 65535 x 65535 one-metre cells: a few hundred valid bytes that would
    // make a replay allocate 51.5 GB of hitbox state.
    let mut bytes = tiny_binary();
    let at = world_at(&bytes);
    for (i, v) in [0.0f64, 0.0, 65535.0, 65535.0, 1.0].into_iter().enumerate() {
        bytes[at + 8 * i..at + 8 * i + 8].copy_from_slice(&v.to_le_bytes());
    }
    let e = TraceReader::new(bytes.as_slice()).unwrap_err();
    assert_eq!(e.location, TraceLocation::Byte(at as u64), "{e}");
    let text = e.to_string();
    assert!(text.contains("65535 x 65535 = 4294836225 cells"), "{text}");
    assert!(text.contains("85896724500 bytes"), "{text}");
    assert!(text.contains("limit of 16777216 cells"), "{text}");
    // The limit is configurable.
    let limits = TraceLimits {
        max_grid_cells: u64::from(u32::MAX),
        ..TraceLimits::default()
    };
    assert!(TraceReader::with_limits(bytes.as_slice(), limits).is_ok());

    // The same in JSON lines.
    let text = String::from_utf8(tiny_jsonl()).unwrap().replacen(
        r#""world":{"min":[-64.0,-64.0],"max":[64.0,64.0],"cell_size":16.0}"#,
        r#""world":{"min":[0.0,0.0],"max":[65535.0,65535.0],"cell_size":1.0}"#,
        1,
    );
    let e = JsonlReader::new(text.as_bytes()).unwrap_err();
    assert_eq!(e.location, TraceLocation::Line(1));
    assert!(e.to_string().contains("4294836225 cells"), "{e}");
}

#[test]
fn errors_at_and_after_the_end_marker_say_so() {
    let mut bytes = tiny_binary();
    bytes.push(0);
    let e = read_binary(&bytes).unwrap_err();
    assert_eq!(e.kind, TraceErrorKind::TrailingData);
    let text = e.to_string();
    assert!(text.contains("(after the end marker)"), "{text}");
    assert!(!text.contains("header"), "{text}");

    let mut bytes = tiny_binary();
    let n = bytes.len();
    bytes[n - 8..].copy_from_slice(&9u64.to_le_bytes());
    let text = read_binary(&bytes).unwrap_err().to_string();
    assert!(text.contains("(end marker)"), "{text}");
    assert!(!text.contains("header"), "{text}");

    let mut text = tiny_jsonl();
    text.extend_from_slice(b"{}\n");
    let text = read_jsonl(&text).unwrap_err().to_string();
    assert!(text.contains("(after the end marker)"), "{text}");
}
