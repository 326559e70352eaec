//! Errors of trace reading, writing and validation.
//!
//! Every error says *where* (byte offset in a binary trace, 1-based line in a
//! JSON-lines trace), *in which frame* (the record's position in the stream
//! and, once read, the frame number it carries) and *what* was wrong.

use std::fmt;

/// Where in the input a problem was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TraceLocation {
    /// Byte offset from the start of a binary trace.
    Byte(u64),
    /// 1-based line number of a JSON-lines trace.
    Line(u64),
}

impl fmt::Display for TraceLocation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Byte(b) => write!(f, "byte {b}"),
            Self::Line(l) => write!(f, "line {l}"),
        }
    }
}

/// A trace that could not be read, written or validated.
#[derive(Clone, Debug, PartialEq)]
pub struct TraceError {
    /// Where the problem is: for a binary trace the offset of the first byte
    /// of the offending field (or of the record it belongs to); for JSON
    /// lines the line.
    pub location: TraceLocation,
    /// Position of the frame record in the stream (0 = first frame after the
    /// header); `None` for the preamble, the header and the end marker.
    pub frame_index: Option<u64>,
    /// The frame number the record carries, when it could be read.
    pub frame_number: Option<u64>,
    /// Index of the offending instance event within its frame, if any.
    pub event: Option<u32>,
    /// What was wrong.
    pub kind: TraceErrorKind,
}

impl TraceError {
    /// An error at `location` outside any frame.
    pub fn at(location: TraceLocation, kind: TraceErrorKind) -> Self {
        Self {
            location,
            frame_index: None,
            frame_number: None,
            event: None,
            kind,
        }
    }
}

impl fmt::Display for TraceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "trace error at {}", self.location)?;
        match (self.frame_index, self.frame_number) {
            (Some(i), Some(n)) => write!(f, " (frame record {i}, frame number {n}")?,
            (Some(i), None) => write!(f, " (frame record {i}")?,
            (None, Some(n)) => write!(f, " (frame number {n}")?,
            (None, None) => match &self.kind {
                TraceErrorKind::TrailingData => write!(f, " (after the end marker")?,
                TraceErrorKind::FrameCountMismatch { .. }
                | TraceErrorKind::Truncated {
                    what: "end marker frame count",
                    ..
                } => write!(f, " (end marker")?,
                _ => write!(f, " (header")?,
            },
        }
        if let Some(e) = self.event {
            write!(f, ", event {e}")?;
        }
        write!(f, "): {}", self.kind)
    }
}

impl std::error::Error for TraceError {}

/// What was wrong with a trace.
///
/// `#[non_exhaustive]`: match with a wildcard arm.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum TraceErrorKind {
    /// The underlying reader or writer failed.
    Io {
        /// The `std::io::ErrorKind`.
        kind: std::io::ErrorKind,
        /// The error's message.
        message: String,
    },
    /// The input ended inside a field or record.
    Truncated {
        /// What was being read.
        what: &'static str,
        /// Bytes it needed from the location on.
        needed: u64,
        /// Bytes that were there.
        available: u64,
    },
    /// The input ended without the end-of-trace marker (the writer did not
    /// finish, or the file was cut at a record boundary).
    MissingEnd {
        /// Complete frames read before the input ended.
        frames: u64,
    },
    /// The end marker's frame count differs from the frames read.
    FrameCountMismatch {
        /// Count stored in the end marker.
        recorded: u64,
        /// Frames actually read.
        read: u64,
    },
    /// Bytes (or lines) after the end marker.
    TrailingData,
    /// Not a lipac trace: the first bytes are not [`super::TRACE_MAGIC`]
    /// (binary) or the first line is not a lipac trace header (JSON lines).
    BadMagic {
        /// The first bytes found (up to 8).
        found: Vec<u8>,
    },
    /// A format version this reader does not support.
    UnsupportedVersion {
        /// Version in the input.
        found: u64,
        /// The version this reader supports ([`super::TRACE_VERSION`]).
        supported: u16,
    },
    /// A count or size above its configured limit
    /// ([`super::TraceLimits`]).
    LimitExceeded {
        /// The counted thing, e.g. `"events in frame"`.
        what: &'static str,
        /// The value in the input.
        value: u64,
        /// The limit.
        limit: u64,
    },
    /// A count that claims more elements than the rest of its record can
    /// hold.
    CountExceedsRecord {
        /// The counted thing.
        what: &'static str,
        /// The count in the input.
        count: u64,
        /// Smallest encoded size of one element.
        min_element_bytes: u64,
        /// Bytes left in the record after the count.
        remaining: u64,
    },
    /// A record whose fields end before its length prefix says.
    TrailingBytes {
        /// The record, e.g. `"frame"`.
        what: &'static str,
        /// Unused bytes at its end.
        count: u64,
    },
    /// An enumeration tag or option bit set with no meaning in this version.
    InvalidTag {
        /// The field, e.g. `"event tag"`.
        what: &'static str,
        /// The value in the input.
        value: u64,
    },
    /// A NaN or infinite value.
    NonFinite {
        /// The field, e.g. `"transform element 3"`.
        what: String,
        /// Its value.
        value: f64,
    },
    /// A box with a non-finite corner, `min > max` on an axis, or an extent
    /// above [`super::TraceLimits::max_aabb_extent`].
    InvalidAabb {
        /// Which box, e.g. `"instance AABB"`.
        what: &'static str,
        /// Its minimum corner.
        min: [f32; 3],
        /// Its maximum corner.
        max: [f32; 3],
        /// What is wrong with it.
        reason: String,
    },
    /// Any other field value that breaks a rule of the format.
    InvalidValue {
        /// The field.
        what: String,
        /// The rule it breaks.
        reason: String,
    },
    /// A mesh id the header does not declare.
    UnknownMesh {
        /// The mesh id.
        mesh: u32,
    },
    /// The header declares the same mesh id twice.
    DuplicateMesh {
        /// The mesh id.
        mesh: u32,
    },
    /// A level of detail the mesh does not have.
    LodOutOfRange {
        /// The mesh id.
        mesh: u32,
        /// The LOD asked for.
        lod: u32,
        /// LODs the mesh has.
        lods: u32,
    },
    /// An `add` of an instance id that is already live.
    DuplicateInstance {
        /// The engine's instance id.
        id: u64,
    },
    /// An update, remove or hit count for an id that is not live (never
    /// added, or already removed).
    UnknownInstance {
        /// The operation, `"update"`, `"remove"` or `"hits"`.
        op: &'static str,
        /// The engine's instance id.
        id: u64,
    },
    /// Two hit counts for one instance in one frame.
    DuplicateHits {
        /// The engine's instance id.
        id: u64,
    },
    /// Frame numbers must increase strictly.
    FrameOrder {
        /// The previous frame's number.
        previous: u64,
        /// This frame's number.
        given: u64,
    },
    /// An `add` (version 2) with a slot another live instance holds.
    SlotInUse {
        /// The slot.
        slot: u32,
        /// The live instance that holds it.
        id: u64,
    },
    /// Hits (version 2, [`super::SlotHits`]) for a slot that no live
    /// instance holds.
    UnknownSlot {
        /// The slot.
        slot: u32,
        /// Its hit count.
        hits: u32,
    },
    /// A field of a later format version in a trace of an earlier one.
    NotInVersion {
        /// The field, e.g. `"add slot"`.
        what: &'static str,
        /// The trace's version.
        version: u16,
    },
    /// More live instances than [`super::TraceLimits::max_live_instances`].
    TooManyLiveInstances {
        /// The limit.
        limit: u64,
    },
    /// A JSON line that is not valid JSON or does not match the schema.
    Json {
        /// 1-based column within the line (0 when unknown).
        column: u64,
        /// serde_json's message.
        message: String,
    },
}

impl fmt::Display for TraceErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Io { kind, message } => write!(f, "I/O error ({kind:?}): {message}"),
            Self::Truncated {
                what,
                needed,
                available,
            } => write!(
                f,
                "truncated: {what} needs {needed} bytes, only {available} remain"
            ),
            Self::MissingEnd { frames } => write!(
                f,
                "input ends after {frames} complete frames without the end-of-trace marker \
                 (writer not finished, or file cut short)"
            ),
            Self::FrameCountMismatch { recorded, read } => write!(
                f,
                "end marker records {recorded} frames but {read} were read"
            ),
            Self::TrailingData => write!(f, "data after the end-of-trace marker"),
            Self::BadMagic { found } => write!(
                f,
                "not a lipac trace: starts with {:?}, expected {:?}",
                String::from_utf8_lossy(found),
                String::from_utf8_lossy(&super::TRACE_MAGIC)
            ),
            Self::UnsupportedVersion { found, supported } => write!(
                f,
                "unsupported trace format version {found} (this reader supports versions {} to {supported})",
                super::OLDEST_TRACE_VERSION
            ),
            Self::LimitExceeded { what, value, limit } => {
                write!(f, "{what} = {value} exceeds the limit {limit}")
            }
            Self::CountExceedsRecord {
                what,
                count,
                min_element_bytes,
                remaining,
            } => write!(
                f,
                "{what} = {count} cannot fit: each takes at least {min_element_bytes} bytes \
                 and only {remaining} bytes remain in the record"
            ),
            Self::TrailingBytes { what, count } => {
                write!(f, "{count} unused bytes at the end of the {what} record")
            }
            Self::InvalidTag { what, value } => write!(f, "invalid {what} {value:#x}"),
            Self::NonFinite { what, value } => {
                write!(f, "{what} is {value}; it must be finite")
            }
            Self::InvalidAabb {
                what,
                min,
                max,
                reason,
            } => write!(f, "invalid {what} (min {min:?}, max {max:?}): {reason}"),
            Self::InvalidValue { what, reason } => write!(f, "invalid {what}: {reason}"),
            Self::UnknownMesh { mesh } => {
                write!(f, "mesh id {mesh} is not declared in the trace header")
            }
            Self::DuplicateMesh { mesh } => {
                write!(f, "mesh id {mesh} is declared twice in the trace header")
            }
            Self::LodOutOfRange { mesh, lod, lods } => {
                write!(f, "mesh {mesh} has {lods} LODs; LOD {lod} does not exist")
            }
            Self::DuplicateInstance { id } => {
                write!(f, "add of instance {id}, which is already live")
            }
            Self::UnknownInstance { op, id } => write!(
                f,
                "{op} of instance {id}, which is not live (never added, or removed)"
            ),
            Self::DuplicateHits { id } => {
                write!(f, "two hit counts for instance {id} in one frame")
            }
            Self::FrameOrder { previous, given } => write!(
                f,
                "frame number {given} does not follow {previous}; frame numbers must increase"
            ),
            Self::SlotInUse { slot, id } => {
                write!(f, "add in slot {slot}, which live instance {id} holds")
            }
            Self::UnknownSlot { slot, hits } => write!(
                f,
                "{hits} hits for slot {slot}, which no live instance holds"
            ),
            Self::NotInVersion { what, version } => write!(
                f,
                "{what} is not part of trace format version {version} (it needs version 2)"
            ),
            Self::TooManyLiveInstances { limit } => {
                write!(f, "more than {limit} live instances")
            }
            Self::Json { column, message } => write!(f, "column {column}: {message}"),
        }
    }
}

impl TraceErrorKind {
    pub(crate) fn io(e: &std::io::Error) -> Self {
        Self::Io {
            kind: e.kind(),
            message: e.to_string(),
        }
    }
}
