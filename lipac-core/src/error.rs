//! The crate-wide error type.
//!
//! Every fallible operation of `lipac-core` returns [`CoreError`]. Errors name
//! the offending value so that a log line alone tells what was wrong, and an
//! operation that fails leaves the state it was called on unchanged.

use glam::Vec3;
use std::fmt;

/// Errors of `lipac-core`.
///
/// The enum is `#[non_exhaustive]`: other modules add variants as they grow,
/// so match with a wildcard arm.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum CoreError {
    /// A handle whose object was removed (or that belongs to another
    /// container).
    StaleHandle {
        /// What the handle refers to, e.g. `"instance"`.
        kind: &'static str,
        /// The handle's raw key (`slotmap::KeyData::as_ffi`: version in the
        /// high 32 bits, index in the low 32 bits).
        key: u64,
    },
    /// A GPU slot that holds no live instance (never used, removed, or
    /// quarantined).
    NoInstanceAtSlot {
        /// The slot asked for.
        slot: u32,
    },
    /// A transform with a NaN or infinite element.
    NonFiniteTransform {
        /// Index of the first non-finite element in the row-major 3x4 matrix.
        element: usize,
        /// Its value.
        value: f32,
    },
    /// An axis-aligned box that is non-finite, inverted or absurdly large.
    InvalidAabb {
        /// The box's minimum corner as given.
        min: Vec3,
        /// The box's maximum corner as given.
        max: Vec3,
        /// What is wrong with it.
        reason: String,
    },
    /// A position (an instance's AABB centre) outside the region the hitbox
    /// index covers.
    OutsideWorld {
        /// The offending position.
        center: Vec3,
    },
    /// A hitbox structure that creates hitboxes as cells get occupied
    /// ([`crate::hashed_hitboxes::HashedHitboxes`]) has reached its cell
    /// limit.
    TooManyHitboxes {
        /// The cell limit.
        limit: u32,
        /// The position (an instance's AABB centre) whose cell was new.
        center: Vec3,
    },
    /// Every GPU slot is in use or waiting in quarantine.
    TooManyInstances {
        /// The slot limit (at most [`crate::layout::MAX_SLOTS`]).
        limit: u32,
        /// Slots that are free again once their quarantine ends.
        quarantined: u32,
    },
    /// A value that does not fit its GPU bit field.
    FieldOutOfRange {
        /// The field, e.g. `"sbt_offset"`.
        field: &'static str,
        /// The value given.
        value: u64,
        /// The largest value the field holds.
        max: u64,
    },
    /// A non-finite input other than a transform (camera position,
    /// view-projection matrix, ...).
    NonFinite {
        /// What was not finite.
        what: &'static str,
    },
    /// Frame numbers must not go backwards.
    FrameOrder {
        /// The frame the container is at.
        current: u64,
        /// The earlier frame that was passed.
        given: u64,
    },
    /// A configuration that cannot work.
    InvalidConfig {
        /// What is wrong, naming the offending value.
        what: String,
    },
    /// A per-frame step called out of order (e.g. hit feedback processed
    /// twice in one frame, or before the last frame's commands were taken).
    CallOrder {
        /// What was out of order.
        what: String,
    },
    /// Room a caller asked for (a reservation, a capacity) cannot be had:
    /// the allocator refused it, or it is beyond what the address space
    /// holds. Nothing was changed.
    OutOfMemory {
        /// What the room was for, e.g. `"instance slots"`.
        what: &'static str,
        /// How many more elements were asked for.
        additional: usize,
    },
    /// Algorithm 1 rejected its inputs.
    Assembly(crate::assembly::AssemblyError),
    /// Algorithm 2 rejected its inputs.
    Feedback(crate::feedback::FeedbackError),
}

impl fmt::Display for CoreError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::StaleHandle { kind, key } => write!(
                f,
                "stale {kind} handle (index {}, version {}): it was removed or never belonged here",
                key & 0xFFFF_FFFF,
                key >> 32
            ),
            Self::NoInstanceAtSlot { slot } => {
                write!(f, "GPU slot {slot} holds no live instance")
            }
            Self::NonFiniteTransform { element, value } => write!(
                f,
                "transform element {element} (row {}, column {}) is {value}; transforms must be finite",
                element / 4,
                element % 4
            ),
            Self::InvalidAabb { min, max, reason } => {
                write!(f, "invalid AABB (min {min}, max {max}): {reason}")
            }
            Self::OutOfMemory { what, additional } => write!(
                f,
                "cannot reserve room for {additional} more {what}: the memory cannot be had"
            ),
            Self::OutsideWorld { center } => write!(
                f,
                "position {center} lies outside the region covered by the hitbox index"
            ),
            Self::TooManyHitboxes { limit, center } => write!(
                f,
                "too many hitboxes: the cell of {center} would be a new hitbox, but all \
                 {limit} hitboxes of the index are occupied"
            ),
            Self::TooManyInstances { limit, quarantined } => write!(
                f,
                "too many instances: all {limit} GPU slots are in use ({quarantined} of them \
                 still quarantined after removal)"
            ),
            Self::FieldOutOfRange { field, value, max } => {
                write!(f, "{field} = {value} does not fit its GPU field (max {max})")
            }
            Self::NonFinite { what } => write!(f, "{what} is not finite (NaN or infinity)"),
            Self::FrameOrder { current, given } => write!(
                f,
                "frame {given} is before the current frame {current}; frames must not go backwards"
            ),
            Self::InvalidConfig { what } => write!(f, "invalid configuration: {what}"),
            Self::CallOrder { what } => write!(f, "call out of order: {what}"),
            Self::Assembly(e) => write!(f, "TLAS assembly: {e}"),
            Self::Feedback(e) => write!(f, "feedback processing: {e}"),
        }
    }
}

impl std::error::Error for CoreError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Assembly(e) => Some(e),
            Self::Feedback(e) => Some(e),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests;
