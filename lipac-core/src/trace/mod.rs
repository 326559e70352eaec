//! Recorded instance traces: what an engine did, frame by frame, in a
//! documented, versioned, streamable format that lipac replays.
//!
//! A trace is a [`TraceHeader`] (scene name, hitbox grid of the world,
//! meshes with their LODs' triangle counts, local bounds and optional
//! geometry) followed by [`Frame`]s (frame number, [`Camera`], instance
//! [`InstanceEvent`]s — add, update, remove — and optionally the engine's
//! own per-instance hit counts).
//!
//! Two encodings carry the same content losslessly (every `f32` bit-exact):
//!
//! * **binary** ([`TraceWriter`], [`TraceReader`]): little-endian, magic
//!   [`TRACE_MAGIC`], version [`TRACE_VERSION`], a length-prefixed header
//!   and length-prefixed frame records, closed by an end marker holding the
//!   frame count. Readers stream frame by frame and can skip frames unread.
//! * **JSON lines** ([`JsonlWriter`], [`JsonlReader`]): the header object on
//!   line 1, one object per frame, an end line; for hand-written cases and
//!   readable diffs.
//!
//! [`binary_to_jsonl`] and [`jsonl_to_binary`] convert either way.
//!
//! Engines record with `lipac-core` as their only lipac dependency. The byte
//! layout, JSON schema, limits and versioning policy are specified in
//! `docs/trace-format.md`.
//!
//! # Untrusted input
//!
//! Readers never panic and never allocate by an untrusted count: every count
//! is capped by a configurable [`TraceLimits`] *and* by the bytes left in its
//! length-prefixed record, and record payloads are read in bounded steps, so
//! memory follows the bytes actually present. Frames are checked while they
//! are decoded (binary) or parsed (JSON lines), so a record that is rejected
//! costs no more than its own bytes. [`TraceFormat::detect_stream`] detects
//! the encoding in one pass over any stream. Every frame passes through a
//! [`TraceValidator`] (finite values, valid boxes, declared meshes and LODs,
//! live-instance bookkeeping, frame order). Every [`TraceError`] names the
//! byte offset (binary) or line (JSON lines), the frame and what was wrong.

mod binary;
mod convert;
mod error;
mod jsonl;
mod model;
mod validate;

pub use binary::{TraceReader, TraceWriter, PREAMBLE_BYTES};
pub use convert::{binary_to_jsonl, jsonl_to_binary, Peeked, TraceFormat, MAX_DETECT_WHITESPACE};
pub use error::{TraceError, TraceErrorKind, TraceLocation};
pub use jsonl::{JsonlReader, JsonlWriter, JSONL_FORMAT_NAME};
pub(crate) use model::{check_aabb, check_camera};
pub use model::{
    AddInstance, BoxHits, Camera, Frame, InstanceEvent, InstanceHits, LodGeometry, LodInfo,
    MeshInfo, Pose, SlotHits, TraceHeader, TraceLimits, UpdateInstance, WorldInfo,
};
pub use validate::{FrameFault, TraceValidator};

/// The first 8 bytes of every binary trace.
pub const TRACE_MAGIC: [u8; 8] = *b"LIPACTRC";

/// The format version this crate writes by default and the newest it reads
/// (binary `u16` after the magic; `"version"` of the JSON-lines header).
/// Version 2 adds instance slots and the compact [`SlotHits`].
pub const TRACE_VERSION: u16 = 2;

/// The oldest format version this crate reads (and can write, for content
/// without later features: [`TraceWriter::with_version`]).
pub const OLDEST_TRACE_VERSION: u16 = 1;
