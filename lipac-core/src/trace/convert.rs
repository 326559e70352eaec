//! Conversion between the binary and JSON-lines encodings, frame by frame.

use super::binary::{TraceReader, TraceWriter};
use super::error::TraceError;
use super::jsonl::{JsonlReader, JsonlWriter};
use super::model::TraceLimits;
use super::TRACE_MAGIC;
use std::io::{Read, Write};

/// The two encodings of a trace.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TraceFormat {
    /// Binary (`.lipactrace`).
    Binary,
    /// JSON lines (`.jsonl`).
    Jsonl,
}

impl TraceFormat {
    /// The encoding whose beginning `prefix` is: binary if it starts with
    /// [`TRACE_MAGIC`] (or a non-empty prefix of it), JSON lines if its first
    /// non-whitespace byte is `{`.
    ///
    /// ```
    /// use lipac_core::trace::TraceFormat;
    /// assert_eq!(TraceFormat::detect(b"LIPACTRC\x01\x00"), Some(TraceFormat::Binary));
    /// assert_eq!(TraceFormat::detect(b"  {\"format\":"), Some(TraceFormat::Jsonl));
    /// assert_eq!(TraceFormat::detect(b"PK\x03\x04"), None);
    /// ```
    pub fn detect(prefix: &[u8]) -> Option<Self> {
        let n = prefix.len().min(TRACE_MAGIC.len());
        if n > 0 && prefix[..n] == TRACE_MAGIC[..n] {
            return Some(Self::Binary);
        }
        match prefix.iter().find(|b| !b.is_ascii_whitespace()) {
            Some(b'{') => Some(Self::Jsonl),
            _ => None,
        }
    }
}

/// Converts a binary trace into JSON lines, one frame at a time (memory
/// bounded by the largest frame); returns the sink. Every frame is checked
/// on reading and on writing. The conversion is lossless:
/// [`jsonl_to_binary`] of the result reproduces the input bytes.
pub fn binary_to_jsonl<R: Read, W: Write>(
    input: R,
    output: W,
    limits: TraceLimits,
) -> Result<W, TraceError> {
    let mut r = TraceReader::with_limits(input, limits)?;
    let mut w = JsonlWriter::with_limits(output, r.header(), limits)?;
    while let Some(frame) = r.next_frame()? {
        w.write_frame(&frame)?;
    }
    w.finish()
}

/// Converts a JSON-lines trace into binary, one frame at a time; returns the
/// sink. Lossless: every `f32` keeps its bits.
///
/// ```
/// use lipac_core::trace::{binary_to_jsonl, jsonl_to_binary, TraceLimits};
///
/// let text = concat!(
///     r#"{"format":"lipac-trace","version":1,"scene":"s","#,
///     r#""world":{"min":[0.0,0.0],"max":[32.0,32.0],"cell_size":16.0},"#,
///     r#""meshes":[{"id":5,"bounds":{"min":[-1.0,0.0,-1.0],"max":[1.0,2.0,1.0]},"lods":[{"triangles":2}]}]}"#, "\n",
///     r#"{"frame":0,"camera":{"position":[0.0,1.0,0.0],"orientation":[0.0,0.0,0.0,1.0],"vertical_fov":1.0,"aspect":1.5},"#,
///     r#""events":[{"add":{"id":1,"mesh":5,"lod":0,"flags":["static"],"transform":[1.0,0.0,0.0,8.0,0.0,1.0,0.0,0.0,0.0,0.0,1.0,8.0],"#,
///     r#""aabb":{"min":[7.0,0.0,7.0],"max":[9.0,2.0,9.0]}}}],"hits":[{"id":1,"hits":250}]}"#, "\n",
///     r#"{"end":{"frames":1}}"#, "\n",
/// );
/// let binary = jsonl_to_binary(text.as_bytes(), Vec::new(), TraceLimits::default())?;
/// let back = binary_to_jsonl(binary.as_slice(), Vec::new(), TraceLimits::default())?;
/// assert_eq!(String::from_utf8(back).unwrap(), text);
/// # Ok::<(), lipac_core::trace::TraceError>(())
/// ```
pub fn jsonl_to_binary<R: Read, W: Write>(
    input: R,
    output: W,
    limits: TraceLimits,
) -> Result<W, TraceError> {
    let mut r = JsonlReader::with_limits(input, limits)?;
    let mut w = TraceWriter::with_limits(output, r.header(), limits)?;
    while let Some(frame) = r.next_frame()? {
        w.write_frame(&frame)?;
    }
    w.finish()
}
