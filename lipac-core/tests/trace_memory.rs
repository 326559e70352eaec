//! Readers stay within a small multiple of the largest record they allow,
//! checked with a counting global allocator: a record that is going to be
//! rejected is rejected before it is decoded (binary) or parsed (JSON lines)
//! in full.
//!
//! The allocator ([`cap::Cap`]) is limited around each read: an allocation
//! past the budget fails, which aborts the process ("memory allocation of N
//! bytes failed") instead of letting a regression take the machine's
//! memory. Each case runs in a child process of the test binary, so an abort
//! fails the test cleanly and no other test's allocations are counted.

mod trace_common;

use cap::Cap;
use lipac_core::trace::*;
use std::alloc::System;
use trace_common::*;

#[global_allocator]
static ALLOC: Cap<System> = Cap::new(System, usize::MAX);

/// Runs `f` with at most `budget` bytes allocated on top of what is live
/// now.
fn within<T>(budget: usize, f: impl FnOnce() -> T) -> T {
    let base = ALLOC.allocated();
    ALLOC
        .set_limit(base + budget)
        .expect("limit above what is allocated");
    let out = f();
    ALLOC.set_limit(usize::MAX).expect("lift the limit");
    out
}

const RECORD: u32 = 4 << 20;

/// The first bytes of a JSON line the reader holds before it parses the
/// rest as it reads it (`TraceLimits::max_buffered_line_bytes`).
const BUFFERED: usize = 64 << 10;

fn limits() -> TraceLimits {
    TraceLimits {
        max_frame_bytes: RECORD,
        max_buffered_line_bytes: BUFFERED as u32,
        ..TraceLimits::default()
    }
}

fn camera() -> Camera {
    Camera::look_to(glam::Vec3::ZERO, glam::Vec3::NEG_Z, glam::Vec3::Y, 1.0, 1.5)
}

/// A valid header and frame 0, then one frame record of as many removes of
/// never-added instances as fit in [`RECORD`] bytes: event 0 is already
/// invalid.
fn binary_removes() -> Vec<u8> {
    let (h, _) = tiny_trace();
    let mut w = TraceWriter::new(Vec::new(), &h).unwrap();
    w.write_frame(&Frame {
        number: 0,
        camera: camera(),
        events: vec![],
        hits: None,
        slot_hits: None,
    })
    .unwrap();
    let mut bytes = w.finish().unwrap();
    bytes.truncate(bytes.len() - 12); // drop the end marker
                                      // Frame 0's record: length 4, number 8, camera 36, count 4, hits flag 1.
    let at = bytes.len() - 53;
    let first_len = u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    assert_eq!(first_len, 8 + 36 + 4 + 1, "frame 0 record length");
    let camera = bytes[at + 12..at + 48].to_vec();
    let n = (RECORD as usize - (8 + 36 + 4 + 1)) / 9;
    let len = 8 + 36 + 4 + n * 9 + 1;
    bytes.reserve_exact(4 + len + 12);
    bytes.extend_from_slice(&(len as u32).to_le_bytes());
    bytes.extend_from_slice(&1u64.to_le_bytes());
    bytes.extend_from_slice(&camera);
    bytes.extend_from_slice(&(n as u32).to_le_bytes());
    for i in 0..n {
        bytes.push(3); // remove
        bytes.extend_from_slice(&(1_000_000 + i as u64).to_le_bytes());
    }
    bytes.push(0); // no hits
    bytes.extend_from_slice(&0u32.to_le_bytes());
    bytes.extend_from_slice(&2u64.to_le_bytes());
    bytes
}

/// A JSON-lines trace whose second frame line (just under `bytes` bytes)
/// holds more events than `max_events` allows (at least five times).
fn jsonl_many_events(max_events: u32, bytes: usize) -> Vec<u8> {
    let (h, _) = tiny_trace();
    let mut w = JsonlWriter::new(Vec::new(), &h).unwrap();
    w.write_frame(&Frame {
        number: 0,
        camera: camera(),
        events: vec![],
        hits: None,
        slot_hits: None,
    })
    .unwrap();
    let text = String::from_utf8(w.finish().unwrap()).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let frame1 = lines[1].replace(r#""frame":0"#, r#""frame":1"#);
    let (head, tail) = frame1.split_once(r#""events":[]"#).unwrap();
    let ev = r#"{"remove":{"id":7}},"#;
    let n = (bytes - head.len() - 64) / ev.len();
    assert!(n > max_events as usize * 5, "{n} events fit");
    let mut out = String::with_capacity(bytes + 4096);
    out.push_str(lines[0]);
    out.push('\n');
    out.push_str(lines[1]);
    out.push('\n');
    out.push_str(head);
    out.push_str("\"events\":[");
    for _ in 0..n {
        out.push_str(ev);
    }
    out.pop();
    out.push(']');
    out.push_str(tail);
    out.push_str("\n{\"end\":{\"frames\":2}}\n");
    out.into_bytes()
}

/// Runs one case (in the child process the test starts).
fn run_case(case: &str) {
    match case {
        "binary" => {
            // A 4 MiB record of ~466k removes; event 0 removes an instance
            // that was never added. Decoding all of them first would take
            // ~45 MiB (an `InstanceEvent` is far larger than its 9 bytes).
            let bytes = binary_removes();
            let e = within(3 * RECORD as usize, || {
                let mut r = TraceReader::with_limits(bytes.as_slice(), limits()).unwrap();
                r.next_frame().unwrap();
                r.next_frame().unwrap_err()
            });
            assert_eq!(
                e.kind,
                TraceErrorKind::UnknownInstance {
                    op: "remove",
                    id: 1_000_000
                },
                "{e}"
            );
            assert_eq!((e.frame_index, e.event), (Some(1), Some(0)), "{e}");
        }
        "jsonl" => {
            // A 4 MiB line of 20 times the allowed events; the limit fires
            // while the line is parsed, not after every event was built.
            let max_events = 10_000;
            let text = jsonl_many_events(max_events, RECORD as usize);
            let limits = TraceLimits {
                max_events_per_frame: max_events,
                ..limits()
            };
            // The events allowed, as built (a `Vec` grows by doubling), the
            // first BUFFERED bytes of the line, and a little more: not the
            // 4 MiB line, which is parsed as it is read after those (the
            // reader held it whole before).
            let events = 2 * max_events as usize * std::mem::size_of::<InstanceEvent>();
            let e = within(BUFFERED + events + (256 << 10), || {
                let mut r = JsonlReader::with_limits(text.as_slice(), limits).unwrap();
                r.next_frame().unwrap();
                r.next_frame().unwrap_err()
            });
            assert!(
                matches!(
                    e.kind,
                    TraceErrorKind::LimitExceeded {
                        what: "events in frame",
                        limit: 10_000,
                        ..
                    }
                ),
                "{e}"
            );
            assert_eq!(e.location, TraceLocation::Line(3), "{e}");
        }
        "jsonl-string" => {
            // A frame line of one 4 MiB string: refused once the string
            // passes the longest a frame line holds, before anything
            // copies it (it cost three times its size: the line, serde's
            // copy, and the error quoting it whole).
            let (h, _) = tiny_trace();
            let head =
                String::from_utf8(JsonlWriter::new(Vec::new(), &h).unwrap().finish().unwrap())
                    .unwrap();
            let mut text = head.lines().next().unwrap().as_bytes().to_vec();
            text.extend_from_slice(b"\n{\"frame\":\"");
            text.resize(text.len() + (4 << 20), b'a');
            text.extend_from_slice(b"\"}\n");
            let e = within(BUFFERED + (256 << 10), || {
                let mut r = JsonlReader::with_limits(
                    text.as_slice(),
                    TraceLimits {
                        max_frame_bytes: 128 << 20,
                        ..limits()
                    },
                )
                .unwrap();
                r.next_frame().unwrap_err()
            });
            assert!(e.to_string().contains("longer than"), "{e}");
            assert!(e.to_string().len() < 1000, "{e}");
        }
        "jsonl-long-line" => {
            // A 4 MiB line of whitespace against a 1 MiB limit: refused
            // at the limit, having held only its first BUFFERED bytes.
            let (h, _) = tiny_trace();
            let head =
                String::from_utf8(JsonlWriter::new(Vec::new(), &h).unwrap().finish().unwrap())
                    .unwrap();
            let mut text = head.lines().next().unwrap().as_bytes().to_vec();
            text.push(b'\n');
            text.push(b'{');
            text.resize(text.len() + (4 << 20), b' ');
            text.extend_from_slice(b"}\n");
            let limit = 1 << 20;
            let e = within(BUFFERED + (256 << 10), || {
                let mut r = JsonlReader::with_limits(
                    text.as_slice(),
                    TraceLimits {
                        max_frame_bytes: limit,
                        ..limits()
                    },
                )
                .unwrap();
                r.next_frame().unwrap_err()
            });
            assert!(
                matches!(
                    e.kind,
                    TraceErrorKind::LimitExceeded {
                        what: "frame line bytes",
                        limit,
                        ..
                    } if limit == 1 << 20
                ),
                "{e}"
            );
        }
        other => panic!("unknown case {other}"),
    }
    println!("{case}: ok");
}

const CASE_VAR: &str = "LIPAC_TRACE_MEMORY_CASE";

/// Each case runs in a child process of this test binary, so that an
/// allocation past the budget (which aborts) fails the test cleanly and no
/// other test's allocations are counted.
#[test]
fn rejected_records_cost_a_small_multiple_of_their_size() {
    if let Ok(case) = std::env::var(CASE_VAR) {
        run_case(&case);
        return;
    }
    for case in ["binary", "jsonl", "jsonl-string", "jsonl-long-line"] {
        let mut child = std::process::Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "rejected_records_cost_a_small_multiple_of_their_size",
                "--nocapture",
                "--test-threads=1",
            ])
            .env(CASE_VAR, case)
            .env("RUST_BACKTRACE", "0")
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let start = std::time::Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break Some(s);
            }
            if start.elapsed().as_secs() > 120 {
                let _ = child.kill();
                break None;
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        };
        let out = child.wait_with_output().unwrap();
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(
            status.is_some_and(|s| s.success()) && text.contains(&format!("{case}: ok")),
            "case {case} failed or went past its memory budget ({status:?}):\n{text}"
        );
    }
}
