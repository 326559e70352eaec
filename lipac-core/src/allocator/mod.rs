//! Two-level segregated fit (TLSF, Masmano et al. 2004) range allocator over
//! offsets in a GPU buffer.
//!
//! [`TlsfAllocator`] sub-allocates byte ranges (geometry-instance data, BLAS
//! storage) inside one large buffer. It is *sans-IO*: it only hands out `u64`
//! offsets and never touches memory, so its bookkeeping lives outside the
//! buffer and costs nothing on the GPU side.
//!
//! # Design
//!
//! **Blocks.** The buffer `[0, capacity)` is tiled by blocks, each used or
//! free, kept in a doubly linked list in address order (the *physical* list),
//! so that freeing merges a block with free physical neighbours in O(1). Two
//! free blocks are never adjacent. Block records live in a growable `Vec` of
//! nodes with a free-list of vacant nodes, so there is no fixed cap on the
//! number of live allocations.
//!
//! **Bins (first/second-level index).** Every free block is also on the list
//! of the size class ("bin") of its size `s`. With `SL_BITS = 5` (32
//! second-level bins per first-level class):
//!
//! * `s < 32`: `fl = 0`, `sl = s` (one exact bin per small size);
//! * otherwise, with `m = floor(log2 s) = 63 - s.leading_zeros()`:
//!   `fl = m - 4` and `sl = (s >> (m - 5)) - 32`. Each octave
//!   `[2^m, 2^(m+1))` is cut into 32 bins of width `2^(m-5)`, so a bin's
//!   sizes differ by less than 1/32 (≈ 3 %).
//!
//! A `u64` first-level bitmap marks classes with a non-empty bin and one
//! `u32` second-level bitmap per class marks its non-empty bins. Finding the
//! first non-empty bin at or above `(fl, sl)` is a mask plus one
//! `trailing_zeros` on the second-level bitmap, and if that is empty a mask
//! plus `trailing_zeros` on the first-level bitmap, then one more on the
//! chosen class: O(1), no loops.
//!
//! **Search (good fit + exact-bin head check).** Plain good-fit TLSF rounds a
//! request up to the next bin boundary (`s + 2^(m-5) - 1`) so that *any*
//! block of the bin found fits. For a size that falls between two bin
//! boundaries this means free blocks of exactly that size are filed in the
//! size's own (lower) bin and never reused for it: after churn of one such
//! size, utilisation at the first failure drops to about two thirds (the
//! known weakness of `offset-allocator`). Allocation therefore tries, in this
//! order, each step O(1):
//!
//! 1. the **head block of the exact bin** `s` maps to (rounding down): it is
//!    used if it is large enough (with alignment);
//! 2. the head of the first non-empty bin at or above the rounded-up bin of
//!    `s` (any block there is at least `s`; with alignment the head is
//!    checked);
//! 3. with alignment `a > 1`, the first non-empty bin at or above the
//!    rounded-up bin of `s + a - 1` (guaranteed to fit whatever the block's
//!    offset);
//! 4. the physically last block, if free (the end of the buffer: this makes
//!    the growth request below exact).
//!
//! To make step 1 succeed as often as possible a bin's list keeps a large
//! block at its head: a freed block goes to the front if it is at least as
//! large as the current head, else to the back (O(1) with a tail pointer).
//! With all blocks of one size, every block in that size's bin fits, so the
//! between-bins case reaches full utilisation. Like every good-fit TLSF, the
//! search does not look behind a bin's head: a request can still fail while
//! a block deeper in its own bin would fit; the growth request is then
//! conservative, never wrong.
//!
//! **Alignment.** [`TlsfAllocator::allocate_aligned`] takes a power-of-two
//! alignment and places the range at the first aligned offset of the chosen
//! block; the padding before it is split off as a free block (it is not lost,
//! and later requests can use it), the tail after it too. Offsets are aligned
//! as numbers: the backing buffer's base must be aligned at least as much as
//! the largest alignment requested.
//!
//! **Handles.** An allocation is named by an [`AllocHandle`]: node index,
//! node generation and the id of the allocator that issued it. Freeing bumps
//! the generation, so a second free, or any use of a handle after its range
//! was freed, is [`AllocError::StaleHandle`]; an index that was never issued
//! is [`AllocError::UnknownHandle`] and a handle of another allocator is
//! [`AllocError::ForeignHandle`]. None of these panic or corrupt state.
//!
//! **Growth.** When no block fits, allocation fails with
//! [`AllocError::OutOfSpace`], which carries the smallest capacity at which
//! the same request succeeds ([`AllocError::required_capacity`]); the caller
//! grows (or reallocates and copies) its backing buffer and calls
//! [`TlsfAllocator::grow`], which merges the new space into a free block at
//! the end. Existing offsets never change.
//!
//! **In-place resize.** [`TlsfAllocator::resize`] shrinks by returning the
//! tail to the free lists (merging with a free right neighbour) and grows in
//! place only when the right physical neighbour is free and large enough;
//! otherwise it returns [`AllocError::CannotGrowInPlace`] and the caller
//! allocates a new range and copies (LOD changes).
//!
//! **Defragmentation.** [`TlsfAllocator::defragment`] relocates live ranges
//! from the end of the buffer into lower free blocks, within a byte budget
//! per call, and returns the [`Move`]s the backend must copy.
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
