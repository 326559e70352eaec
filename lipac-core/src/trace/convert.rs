//! Conversion between the binary and JSON-lines encodings, frame by frame.

use super::binary::{TraceReader, TraceWriter};
use super::error::TraceError;
use super::jsonl::{JsonlReader, JsonlWriter};
use super::model::TraceLimits;
use super::TRACE_MAGIC;
use std::io::{self, Read, Write};

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

    /// Detects the encoding of the stream `r` by reading its first bytes
    /// (as [`TraceFormat::detect`], with any leading whitespace up to
    /// [`MAX_DETECT_WHITESPACE`] skipped), and returns a reader that yields
    /// all of `r` from its first byte: the bytes read are put back in front.
    /// The input is opened and read once, so pipes, FIFOs and standard
    /// input work. `None`: neither encoding (the reader is returned anyway).
    ///
    /// ```
    /// use lipac_core::trace::TraceFormat;
    /// use std::io::Read;
    /// let text = format!("{}{{\"format\":\"lipac-trace\"}}", " ".repeat(100));
    /// let (format, mut r) = TraceFormat::detect_stream(text.as_bytes())?;
    /// assert_eq!(format, Some(TraceFormat::Jsonl));
    /// let mut all = String::new();
    /// r.read_to_string(&mut all)?;
    /// assert_eq!(all, text);
    /// # Ok::<(), std::io::Error>(())
    /// ```
    pub fn detect_stream<R: Read>(mut r: R) -> io::Result<(Option<Self>, Peeked<R>)> {
        let mut seen: Vec<u8> = Vec::new();
        let mut chunk = [0u8; 512];
        // Bytes of `seen` known to be whitespace (scanned once each).
        let mut blank = 0;
        let format = loop {
            blank += seen[blank..]
                .iter()
                .take_while(|b| b.is_ascii_whitespace())
                .count();
            if blank < seen.len() {
                // The first byte that is not whitespace is in: decide, once
                // a possible magic is complete.
                if blank > 0 || seen[0] != TRACE_MAGIC[0] || seen.len() >= TRACE_MAGIC.len() {
                    break Self::detect(&seen);
                }
            } else if blank > MAX_DETECT_WHITESPACE {
                break None;
            }
            let n = match r.read(&mut chunk) {
                Ok(n) => n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            };
            if n == 0 {
                break Self::detect(&seen);
            }
            seen.extend_from_slice(&chunk[..n]);
        };
        Ok((format, io::Cursor::new(seen).chain(r)))
    }
}

/// Leading whitespace [`TraceFormat::detect_stream`] reads past before it
/// gives up (1 MiB): it keeps what it read in memory.
pub const MAX_DETECT_WHITESPACE: usize = 1 << 20;

/// A stream whose first bytes were read by [`TraceFormat::detect_stream`],
/// with those bytes put back in front.
pub type Peeked<R> = io::Chain<io::Cursor<Vec<u8>>, R>;

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
    let mut w = JsonlWriter::with_version(output, r.header(), limits, r.version())?;
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
    let mut w = TraceWriter::with_version(output, r.header(), limits, r.version())?;
    while let Some(frame) = r.next_frame()? {
        w.write_frame(&frame)?;
    }
    w.finish()
}
