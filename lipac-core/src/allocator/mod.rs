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
//! 32-byte, cache-line-aligned nodes with an intrusive stack of vacant
//! nodes, so there is no fixed cap on the number of live allocations
//! ([`TlsfAllocator::reserve_blocks`] can pre-size the storage).
//!
//! **Bins (first/second-level index).** Every free block is also on the list
//! of the size class ("bin") of its size `s`. With `SL_BITS = 3` (8
//! second-level bins per first-level class):
//!
//! * `s < 8`: `fl = 0`, `sl = s` (one exact bin per small size);
//! * otherwise, with `m = floor(log2 s) = 63 - s.leading_zeros()`:
//!   `fl = m - 2` and `sl = (s >> (m - 3)) - 8`. Each octave
//!   `[2^m, 2^(m+1))` is cut into 8 bins of width `2^(m-3)`, so a bin's
//!   sizes differ by less than 1/8 (12.5 %).
//!
//! Eight bins per octave rather than 32: with the exact-bin check below the
//! finer classes bought little utilisation (at most 1.3 points at the first
//! failure on the churn benchmarks, none on the between-bins ones) but cost
//! memory traffic: bin lists were shorter, so the block chosen had less
//! often been touched recently, and the bin table was four times larger
//! (see docs/BENCHMARKS.md).
//!
//! A `u64` first-level bitmap marks classes with a non-empty bin and one
//! `u32` second-level bitmap per class marks its non-empty bins. Finding the
//! first non-empty bin at or above `(fl, sl)` is a mask plus one
//! `trailing_zeros` on the second-level bitmap, and if that is empty a mask
//! plus `trailing_zeros` on the first-level bitmap, then one more on the
//! chosen class: O(1), no loops.
//!
//! **Search (good fit + exact-bin head check).** Plain good-fit TLSF rounds a
//! request up to the next bin boundary (`s + 2^(m-3) - 1`) so that *any*
//! block of the bin found fits. For a size that falls between two bin
//! boundaries this means free blocks of exactly that size are filed in the
//! size's own (lower) bin and never reused for it: after churn of one such
//! size, utilisation at the first failure drops to about two thirds (the
//! known weakness of `offset-allocator`). Allocation therefore tries, in this
//! order, each step O(1):
//!
//! 1. the **best block of the exact bin** `s` maps to (rounding down): it is
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
//! Bin lists are last in, first out (a freed block goes to the front, whose
//! old head was touched recently, so this stays cache-warm). To make step 1
//! succeed as often as possible each bin also remembers a *best* block, with
//! its size cached next to the list head: a block filed in the bin becomes
//! the best if it is at least as large as the current best; when the best
//! leaves the list, the list's head takes over. With all blocks of one size,
//! every block in that size's bin fits, so the between-bins case reaches full
//! utilisation. Like every good-fit TLSF, the search does not look at the
//! other blocks of a bin: a request can still fail while one of them would
//! fit; the growth request is then conservative, never wrong.
//!
//! The hot paths avoid poorly predictable branches: the bin index is
//! computed without the small-size branch, the choice between steps 1 and 2
//! (without alignment) and the best-block bookkeeping are selects.
//!
//! **Alignment.** [`TlsfAllocator::allocate_aligned`] takes a power-of-two
//! alignment and places the range at the first aligned offset of the chosen
//! block; the padding before it is split off as a free block (it is not lost,
//! and later requests can use it), the tail after it too. Offsets are aligned
//! as numbers: the backing buffer's base must be aligned at least as much as
//! the largest alignment requested.
//!
//! **Handles.** An allocation is named by an [`AllocHandle`] (12 bytes): node
//! index, the allocation's serial (a per-allocator counter stamped on the
//! node while it is used) and the id of the allocator that issued it. A
//! handle is valid only while its node is used with the same serial, so a
//! second free, or any use of a handle after its range was freed, is
//! [`AllocError::StaleHandle`]; an index that was never issued
//! is [`AllocError::UnknownHandle`] and a handle of another allocator is
//! [`AllocError::ForeignHandle`]. None of these panic or corrupt state.
//! When the `u32` serial counter runs out (every 2^32 allocations) the
//! allocator starts a new epoch under a fresh id and keeps the handles of
//! the allocations then live valid, so a freed handle never comes back to
//! life (see the `tlsf` module's "Serial epochs").
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
