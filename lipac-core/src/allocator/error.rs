//! The allocator's error type.

use std::fmt;

/// Why an allocator operation was refused. The allocator's state is unchanged
/// whenever one of these is returned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum AllocError {
    /// A size of zero bytes was requested.
    ZeroSize,
    /// The alignment is zero or not a power of two.
    InvalidAlignment {
        /// The alignment that was asked for.
        align: u64,
    },
    /// No free block fits the request: the backing buffer must grow to at
    /// least `required_capacity` bytes, then [`grow`] makes the same request
    /// succeed.
    ///
    /// [`grow`]: crate::allocator::TlsfAllocator::grow
    OutOfSpace {
        /// Requested size in bytes.
        size: u64,
        /// Requested alignment in bytes.
        align: u64,
        /// Current capacity in bytes.
        capacity: u64,
        /// Smallest capacity at which the request succeeds.
        required_capacity: u64,
    },
    /// The request cannot be satisfied by any capacity representable in a
    /// `u64` (size plus alignment padding overflows), or the allocator's own
    /// records for it cannot be had
    /// ([`TlsfAllocator::reserve_blocks`](crate::allocator::TlsfAllocator::reserve_blocks)).
    CapacityOverflow,
    /// The handle's allocation was already freed (double free) or the handle
    /// is otherwise out of date.
    StaleHandle,
    /// The handle names an allocation slot this allocator never handed out.
    UnknownHandle,
    /// The handle was issued by a different allocator.
    ForeignHandle,
    /// An in-place resize could not grow the range: its right physical
    /// neighbour is not free or too small. Allocate a new range and copy.
    CannotGrowInPlace {
        /// The requested new size.
        requested: u64,
        /// The largest size reachable in place right now.
        available: u64,
    },
    /// [`grow`] was called with a capacity below the current one.
    ///
    /// [`grow`]: crate::allocator::TlsfAllocator::grow
    CannotShrinkCapacity {
        /// Current capacity in bytes.
        capacity: u64,
        /// The capacity that was asked for.
        requested: u64,
    },
    /// The node storage would exceed `u32::MAX - 128` block records.
    TooManyBlocks,
}

impl AllocError {
    /// For [`AllocError::OutOfSpace`], the smallest capacity at which the
    /// failed request succeeds; `None` for every other error.
    pub fn required_capacity(&self) -> Option<u64> {
        match *self {
            AllocError::OutOfSpace {
                required_capacity, ..
            } => Some(required_capacity),
            _ => None,
        }
    }

    /// For [`AllocError::OutOfSpace`], by how many bytes the backing buffer
    /// must grow at least; `None` for every other error.
    pub fn additional_bytes(&self) -> Option<u64> {
        match *self {
            AllocError::OutOfSpace {
                capacity,
                required_capacity,
                ..
            } => Some(required_capacity - capacity),
            _ => None,
        }
    }
}

impl fmt::Display for AllocError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            AllocError::ZeroSize => write!(f, "cannot allocate zero bytes"),
            AllocError::InvalidAlignment { align } => {
                write!(f, "alignment {align} is not a non-zero power of two")
            }
            AllocError::OutOfSpace {
                size,
                align,
                capacity,
                required_capacity,
            } => write!(
                f,
                "out of space for {size} bytes (align {align}) in a buffer of {capacity} bytes: \
                 grow the buffer to at least {required_capacity} bytes (+{})",
                required_capacity - capacity
            ),
            AllocError::CapacityOverflow => {
                write!(f, "request exceeds any capacity representable in u64")
            }
            AllocError::StaleHandle => {
                write!(f, "stale allocation handle (already freed: double free?)")
            }
            AllocError::UnknownHandle => {
                write!(
                    f,
                    "allocation handle was never handed out by this allocator"
                )
            }
            AllocError::ForeignHandle => {
                write!(f, "allocation handle belongs to a different allocator")
            }
            AllocError::CannotGrowInPlace {
                requested,
                available,
            } => write!(
                f,
                "cannot grow in place to {requested} bytes (at most {available} available): \
                 allocate a new range and copy"
            ),
            AllocError::CannotShrinkCapacity {
                capacity,
                requested,
            } => write!(
                f,
                "cannot shrink capacity from {capacity} to {requested} bytes"
            ),
            AllocError::TooManyBlocks => write!(f, "too many blocks (node storage exhausted)"),
        }
    }
}

impl std::error::Error for AllocError {}
