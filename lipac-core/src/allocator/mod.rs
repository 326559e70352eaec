//! Two-level segregated fit (TLSF, Masmano et al. 2004) range allocator over
//! offsets in a GPU buffer.
//!
//! [`TlsfAllocator`] sub-allocates byte ranges (geometry-instance data, BLAS
//! storage) inside one large buffer. It is *sans-IO*: it only hands out `u64`
//! offsets and never touches memory, so its bookkeeping lives outside the
//! buffer and costs nothing on the GPU side.
//!
//! # What a caller must know
//!
//! * Offsets are aligned as numbers: the backing buffer's base must be aligned
//!   at least as much as the largest alignment requested
//!   ([`TlsfAllocator::allocate_aligned`] takes a power of two).
//! * **Growth.** When no block fits, allocation fails with
//!   [`AllocError::OutOfSpace`], carrying the smallest capacity at which the
//!   same request succeeds ([`AllocError::required_capacity`]); grow the
//!   backing buffer, then call [`TlsfAllocator::grow`]. Existing offsets never
//!   change.
//! * [`TlsfAllocator::resize`] shrinks in place and grows in place only into a
//!   free right neighbour, else [`AllocError::CannotGrowInPlace`] (allocate
//!   and copy). [`TlsfAllocator::defragment`] returns the [`Move`]s to copy,
//!   within a byte budget per call.
//! * An [`AllocHandle`] is valid only while its allocation lives: a second
//!   free or use after free is [`AllocError::StaleHandle`], a never-issued one
//!   [`AllocError::UnknownHandle`], another allocator's
//!   [`AllocError::ForeignHandle`]; none panics or corrupts state.
//!
//! Allocation and free are O(1). The design (bins, the exact-bin check,
//! alignment, serial epochs) and why: `docs/ALLOCATOR.md`.
//!
//! # Example
//!
//! ```
//! use lipac_core::allocator::{AllocError, TlsfAllocator};
//!
//! # fn main() -> Result<(), AllocError> {
//! let mut alloc = TlsfAllocator::new(1024);
//! let a = alloc.allocate(100)?;
//! let b = alloc.allocate_aligned(200, 256)?;
//! assert_eq!(a.offset, 0);
//! assert_eq!(b.offset % 256, 0);
//! assert!(b.offset >= a.offset + a.size);
//!
//! // Out of space: the error says how large the buffer must become.
//! let err = alloc.allocate(2000).unwrap_err();
//! let needed = err.required_capacity().expect("an out-of-space error");
//! alloc.grow(needed)?; // after growing the GPU buffer itself
//! let c = alloc.allocate(2000)?;
//! assert!(c.offset + c.size <= alloc.capacity());
//!
//! // LOD change: shrink in place, then a double free is caught.
//! let a = alloc.resize(a.handle, 40)?;
//! assert_eq!(a.size, 40);
//! alloc.free(a.handle)?;
//! assert_eq!(alloc.free(a.handle), Err(AllocError::StaleHandle));
//!
//! let stats = alloc.stats();
//! assert_eq!(stats.used_bytes, 200 + 2000);
//! assert_eq!(stats.allocation_count, 2);
//! # Ok(())
//! # }
//! ```

mod bins;
mod defrag;
mod error;
mod tlsf;

#[cfg(test)]
mod tests;

pub use defrag::Move;
pub use error::AllocError;
pub use tlsf::{AllocHandle, Allocation, AllocatorStats, TlsfAllocator};
