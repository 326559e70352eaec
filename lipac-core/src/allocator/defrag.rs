//! Incremental defragmentation: relocate live ranges from the end of the
//! buffer into lower free blocks, within a byte budget per call.

use super::error::AllocError;
use super::tlsf::{AllocHandle, TlsfAllocator, NIL};

/// One relocation decided by [`TlsfAllocator::defragment`]: the backend
/// copies `len` bytes from `from` to `to` (the ranges never overlap) before
/// using the allocation's new offset. The handle stays valid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Move {
    /// The moved allocation (unchanged handle, new offset `to`).
    pub handle: AllocHandle,
    /// Old byte offset.
    pub from: u64,
    /// New byte offset (always below `from`).
    pub to: u64,
    /// Bytes to copy.
    pub len: u64,
}

impl TlsfAllocator {
    /// One incremental defragmentation step.
    ///
    /// Walks live allocations from the end of the buffer towards its start
    /// and moves each one into the lowest free block that lies below it and
    /// fits (with the allocation's original alignment). Allocations larger
    /// than what is left of `budget_bytes` are skipped. Moves are appended to
    /// `moves` in the order the backend must apply them: the two ranges of
    /// one move never overlap, and the destination is free when it is
    /// copied. Handles stay valid. Returns the bytes moved (at most
    /// `budget_bytes`).
    ///
    /// This is a maintenance operation, not an O(1) one: each candidate
    /// walks the blocks below it in address order. A candidate that finds
    /// no room makes later candidates of at least its size skip the walk.
    ///
    /// # Errors
    /// [`AllocError::TooManyBlocks`] if the node storage is exhausted (the
    /// moves made so far stay valid and are in `moves`).
    pub fn defragment(
        &mut self,
        budget_bytes: u64,
        moves: &mut Vec<Move>,
    ) -> Result<u64, AllocError> {
        let mut moved = 0u64;
        // Holes below the walk only shrink during a call, so a size that
        // found no hole cannot find one later.
        let mut smallest_failed = u64::MAX;
        let mut cur = self.last;
        while cur != NIL && moved < budget_bytes {
            let node = self.nodes[cur as usize];
            if !node.is_used() || node.size > budget_bytes - moved || node.size >= smallest_failed {
                cur = node.prev_phys;
                continue;
            }
            self.ensure_nodes(2)?;
            let align = 1u64 << node.align_log2();
            match self.lowest_fit_below(node.size, align, node.offset) {
                Some((dst, start)) => {
                    let freed = self.relocate(cur, dst, start);
                    moves.push(Move {
                        handle: self.allocation_at(cur).handle,
                        from: node.offset,
                        to: start,
                        len: node.size,
                    });
                    moved += node.size;
                    cur = self.nodes[freed as usize].prev_phys;
                }
                None => {
                    if align == 1 {
                        smallest_failed = node.size;
                    }
                    cur = node.prev_phys;
                }
            }
        }
        Ok(moved)
    }

    /// First-fit in address order among free blocks ending at or below
    /// `limit`: the node and the aligned start.
    fn lowest_fit_below(&self, size: u64, align: u64, limit: u64) -> Option<(u32, u64)> {
        let mut cur = self.first;
        while cur != NIL {
            let n = &self.nodes[cur as usize];
            if n.offset >= limit {
                return None;
            }
            if n.is_free() {
                let start = n.offset.checked_next_multiple_of(align)?;
                let end = start.checked_add(size)?;
                if end <= n.offset + n.size && end <= limit {
                    return Some((cur, start));
                }
            }
            cur = n.next_phys;
        }
        None
    }
}
