//! The TLSF range allocator: block records, bin lists, allocate/free/resize/grow.
//!
//! # Block records
//!
//! Every block (used or free) and every vacant record slot is one 32-byte,
//! 32-byte-aligned [`Node`], so one record never straddles two cache lines:
//! `u64` offset and size, the `u32` physical links, and two `u32` words whose
//! meaning depends on the block's state, which is encoded in the first one:
//!
//! | state  | `links[PREV]`                            | `links[NEXT]`        |
//! |--------|------------------------------------------|----------------------|
//! | free   | previous block on its bin list, or `NIL` | next on the bin list |
//! | used   | `MARK_BASE + log2(alignment)`            | allocation serial    |
//! | vacant | `VACANT`                                 | next vacant record   |
//!
//! Node indices stay below `MARK_BASE`, so the three cases cannot be
//! confused. The allocation serial is a per-allocator counter stamped on a
//! block when it is handed out and copied into its [`AllocHandle`]: a handle
//! is valid only while its record is used *and* carries the same serial, so a
//! second free, or any use of a handle whose record was since reused, is a
//! [`AllocError::StaleHandle`]. Vacant records form an intrusive stack
//! through `links[NEXT]`.
//!
//! # Serial epochs
//!
//! The serial is a `u32` (a wider one would not fit the 32-byte record). So
//! that a serial is never handed out twice under the same handle, the
//! allocator starts a new *epoch* when the counter runs out (every 2^32
//! allocations): it takes a fresh id (the handle's `owner`), restarts the
//! serials at 0 and remembers, per record, the old id of every allocation
//! live at that moment (`survivors`). A handle is valid when its owner is
//! the current id, or when it names a survivor with the id recorded for it;
//! freeing a survivor forgets it. A handle of an earlier epoch whose
//! allocation was freed is therefore stale for ever, however many
//! allocations follow. The hot paths pay one well-predicted branch on the
//! counter; the survivor map is only consulted for handles of earlier
//! epochs (a `HashMap` lookup).

use std::collections::HashMap;
use std::num::NonZeroU32;
use std::sync::atomic::{AtomicU32, Ordering};

use super::bins::{
    bin_floor_of, bin_min_size, flat_floor, flat_floor_ceil, BIN_COUNT, FL_COUNT, SL_BITS, SL_COUNT,
};
use super::error::AllocError;

/// "No node" link value.
pub(super) const NIL: u32 = u32::MAX;
/// First value of `Node::links[PREV]` that is a state mark, not a node index:
/// `MARK_BASE + a` (a < 64) marks a used block allocated with alignment
/// `2^a`, [`VACANT`] a vacant record.
const MARK_BASE: u32 = u32::MAX - 128;
/// `Node::links[PREV]` of a vacant record.
const VACANT: u32 = MARK_BASE + 64;
/// Index of the backward / forward link in `Node::links`.
const PREV: usize = 0;
const NEXT: usize = 1;
/// Node indices are below this (the values above are marks and `NIL`).
const MAX_NODES: usize = MARK_BASE as usize;

/// Source of allocator ids, so that handles of one allocator are recognised
/// as foreign by another.
static NEXT_ALLOCATOR_ID: AtomicU32 = AtomicU32::new(1);

fn next_allocator_id() -> NonZeroU32 {
    loop {
        // Skips 0 when the counter wraps.
        if let Some(id) = NonZeroU32::new(NEXT_ALLOCATOR_ID.fetch_add(1, Ordering::Relaxed)) {
            return id;
        }
    }
}

/// Names one live allocation of one [`TlsfAllocator`].
///
/// Cheap to copy (12 bytes; `Option<AllocHandle>` is 12 bytes too). Using a
/// handle after its allocation was freed is detected
/// ([`AllocError::StaleHandle`]), as is a handle of another allocator
/// ([`AllocError::ForeignHandle`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct AllocHandle {
    pub(super) index: u32,
    pub(super) serial: u32,
    pub(super) owner: NonZeroU32,
}

/// A live allocation: the byte range `offset..offset + size` of the buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Allocation {
    /// Names the allocation for [`TlsfAllocator::free`] and friends.
    pub handle: AllocHandle,
    /// Byte offset of the range in the buffer.
    pub offset: u64,
    /// Size of the range in bytes (exactly what was requested).
    pub size: u64,
}

impl Allocation {
    /// One past the last byte of the range.
    pub fn end(&self) -> u64 {
        self.offset + self.size
    }

    /// The byte range `offset..end`.
    pub fn range(&self) -> std::ops::Range<u64> {
        self.offset..self.end()
    }
}

/// A snapshot of an allocator's occupancy, from [`TlsfAllocator::stats`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AllocatorStats {
    /// Managed bytes (`used_bytes + free_bytes`).
    pub capacity: u64,
    /// Bytes in live allocations.
    pub used_bytes: u64,
    /// Bytes in free blocks (including alignment padding).
    pub free_bytes: u64,
    /// Size of the largest free block.
    pub largest_free_block: u64,
    /// Number of live allocations.
    pub allocation_count: usize,
    /// Number of free blocks.
    pub free_block_count: usize,
    /// External fragmentation `1 - largest_free_block / free_bytes`
    /// (0 when nothing is free).
    pub fragmentation: f64,
    /// Highest end offset any allocation ever reached (how much of the
    /// buffer has been needed so far).
    pub high_water_mark: u64,
    /// Largest `used_bytes` ever seen.
    pub peak_used_bytes: u64,
}

/// A record's state, decoded from its `links[PREV]` word (invariant checks).
#[cfg(test)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum State {
    /// Record not in use (on the vacant stack).
    Vacant,
    /// A free block, on its bin's list.
    Free,
    /// A live allocation.
    Used,
}

/// One block record (see the module docs for the state encoding).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
pub(super) struct Node {
    pub offset: u64,
    pub size: u64,
    pub prev_phys: u32,
    pub next_phys: u32,
    /// `links[PREV]`: free: previous on the bin list (`NIL` at the head);
    /// used: `MARK_BASE + log2(alignment)`; vacant: `VACANT`.
    /// `links[NEXT]`: free: next on the bin list; used: the allocation
    /// serial; vacant: next vacant record. An array so that the link to
    /// rewrite can be chosen by index instead of by a branch.
    links: [u32; 2],
}

impl Node {
    #[inline]
    fn end(&self) -> u64 {
        self.offset + self.size
    }

    /// Whether this is a free block (`links[PREV]` is a node index or `NIL`).
    #[inline]
    pub fn is_free(&self) -> bool {
        self.links[PREV].wrapping_sub(MARK_BASE) > VACANT - MARK_BASE
    }

    /// Whether this is a live allocation.
    #[inline]
    pub fn is_used(&self) -> bool {
        self.links[PREV].wrapping_sub(MARK_BASE) < VACANT - MARK_BASE
    }

    #[cfg(test)]
    pub fn state(&self) -> State {
        if self.is_used() {
            State::Used
        } else if self.is_free() {
            State::Free
        } else {
            State::Vacant
        }
    }

    /// log2 of the alignment a used block was allocated with.
    #[inline]
    pub fn align_log2(&self) -> u32 {
        debug_assert!(self.is_used());
        self.links[PREV] - MARK_BASE
    }
}

/// Two-level segregated fit range allocator over `[0, capacity)`.
///
/// Allocate and free are O(1) (bounded work, no loops over blocks or bins);
/// the design is in `docs/ALLOCATOR.md`.
#[derive(Debug)]
pub struct TlsfAllocator {
    id: NonZeroU32,
    capacity: u64,
    pub(super) nodes: Vec<Node>,
    /// Top of the intrusive stack of vacant records (`NIL` if none).
    vacant_head: u32,
    vacant_count: usize,
    /// Serial stamped on the next allocation.
    next_serial: u32,
    /// What earlier serial epochs left (`None` until the first 2^32
    /// allocations; boxed to keep the hot struct small).
    epochs: Option<Box<PastEpochs>>,
    fl_bitmap: u64,
    sl_bitmaps: [u32; FL_COUNT],
    /// One free list per bin, by flat bin index.
    bins: Box<[BinList; BIN_COUNT]>,
    /// Physically first / last block (`NIL` iff capacity is 0).
    pub(super) first: u32,
    pub(super) last: u32,
    used_bytes: u64,
    live: usize,
    free_blocks: usize,
    peak_used: u64,
    high_water: u64,
}

/// What earlier serial epochs left behind (see the module docs).
#[derive(Debug, Default)]
struct PastEpochs {
    /// Allocations live when an earlier epoch ended: record index -> the
    /// allocator id of their epoch.
    survivors: HashMap<u32, NonZeroU32>,
    /// The ids of the earlier epochs (one per 2^32 allocations), so that
    /// their stale handles are told from foreign ones.
    ids: Vec<NonZeroU32>,
}

/// A bin's free list, last in first out, and its *best* block: the block
/// the exact-bin check of the search tries, with its size cached (0 when the
/// list is empty) so that the check and the choice of a new best need not
/// touch the node. A block filed in the bin becomes the best if it is at
/// least as large as the current one; when the best leaves the list, the
/// list's head takes over. The best is on the list whenever the list is
/// not empty.
#[derive(Clone, Copy, Debug)]
struct BinList {
    best_size: u64,
    best: u32,
    head: u32,
}

impl BinList {
    const EMPTY: BinList = BinList {
        best_size: 0,
        best: NIL,
        head: NIL,
    };
}

#[inline]
fn align_up(offset: u64, align: u64) -> Option<u64> {
    Some(offset.checked_add(align - 1)? & !(align - 1))
}

impl TlsfAllocator {
    /// An allocator managing `capacity` bytes, all free. A capacity of 0 is
    /// allowed (every allocation then asks to [`grow`](Self::grow)).
    pub fn new(capacity: u64) -> Self {
        let mut this = TlsfAllocator {
            id: next_allocator_id(),
            capacity: 0,
            nodes: Vec::new(),
            vacant_head: NIL,
            vacant_count: 0,
            next_serial: 0,
            epochs: None,
            fl_bitmap: 0,
            sl_bitmaps: [0; FL_COUNT],
            bins: Box::new([BinList::EMPTY; BIN_COUNT]),
            first: NIL,
            last: NIL,
            used_bytes: 0,
            live: 0,
            free_blocks: 0,
            peak_used: 0,
            high_water: 0,
        };
        if capacity > 0 {
            // A fresh allocator has no nodes, so this cannot hit the node cap.
            let i = this.push_node(0, capacity, NIL, NIL);
            this.first = i;
            this.last = i;
            this.capacity = capacity;
            this.insert_free(i, capacity);
        }
        this
    }

    /// Makes sure at least `additional` more block records (each live
    /// allocation and each free block is one) exist beyond those in use, so
    /// that the record storage does not have to grow (reallocate and copy)
    /// later. The records are created and written now, so the first
    /// allocations that use them do not take page faults either (what a
    /// frame loop wants). Optional: storage grows on demand without it.
    /// [`AllocError::CapacityOverflow`] (nothing changed) when the memory
    /// for the records cannot be had.
    pub fn reserve_blocks(&mut self, additional: usize) -> Result<(), AllocError> {
        let missing = additional
            .saturating_sub(self.vacant_count)
            .min(MAX_NODES - self.nodes.len());
        let start = self.nodes.len();
        self.nodes
            .try_reserve_exact(missing)
            .map_err(|_| AllocError::CapacityOverflow)?;
        let blank = Node {
            offset: 0,
            size: 0,
            prev_phys: NIL,
            next_phys: NIL,
            links: [NIL, NIL],
        };
        self.nodes.resize(start + missing, blank);
        // Written now, so the memory is touched here and not on first use;
        // released highest first, so the lowest index is on top.
        for i in (start..start + missing).rev() {
            self.release_node(i as u32);
        }
        Ok(())
    }

    /// Managed bytes.
    pub fn capacity(&self) -> u64 {
        self.capacity
    }

    /// Bytes in live allocations.
    pub fn used_bytes(&self) -> u64 {
        self.used_bytes
    }

    /// Bytes not in live allocations.
    pub fn free_bytes(&self) -> u64 {
        self.capacity - self.used_bytes
    }

    /// Number of live allocations.
    pub fn allocation_count(&self) -> usize {
        self.live
    }

    /// The smallest size filed in the same size class (bin) as `size`; 0 for
    /// `size == 0`. A request is "between bins" when this is below `size`:
    /// plain good-fit TLSF would then round it up to the next class.
    pub fn size_class_floor(size: u64) -> u64 {
        if size == 0 {
            0
        } else {
            bin_min_size(bin_floor_of(size))
        }
    }

    /// Allocates `size` bytes (alignment 1). O(1).
    ///
    /// # Errors
    /// [`AllocError::ZeroSize`]; [`AllocError::OutOfSpace`] with the capacity
    /// to [`grow`](Self::grow) to; [`AllocError::CapacityOverflow`];
    /// [`AllocError::TooManyBlocks`].
    #[inline]
    pub fn allocate(&mut self, size: u64) -> Result<Allocation, AllocError> {
        self.allocate_log2(size, 0)
    }

    /// Allocates `size` bytes at an offset that is a multiple of `align` (a
    /// power of two). O(1). Padding before the range stays a free block.
    ///
    /// # Errors
    /// [`AllocError::ZeroSize`], [`AllocError::InvalidAlignment`],
    /// [`AllocError::OutOfSpace`] with the capacity to
    /// [`grow`](Self::grow) to, [`AllocError::CapacityOverflow`],
    /// [`AllocError::TooManyBlocks`].
    pub fn allocate_aligned(&mut self, size: u64, align: u64) -> Result<Allocation, AllocError> {
        if !align.is_power_of_two() {
            return Err(AllocError::InvalidAlignment { align });
        }
        self.allocate_log2(size, align.trailing_zeros())
    }

    /// Allocation with alignment `2^align_log2`; inlined into both entry
    /// points so that `allocate` runs the alignment-free search.
    #[inline(always)]
    fn allocate_log2(&mut self, size: u64, align_log2: u32) -> Result<Allocation, AllocError> {
        if size == 0 {
            return Err(AllocError::ZeroSize);
        }
        // Up to two new nodes (padding and tail remainder).
        self.ensure_nodes(2)?;
        match self.find_block(size, align_log2) {
            Some((i, bin, start)) => {
                let serial = self.next_serial;
                let a = self.take_block(i, bin, start, size, align_log2, serial);
                match serial.checked_add(1) {
                    Some(next) => self.next_serial = next,
                    None => self.next_epoch(),
                }
                Ok(a)
            }
            None => Err(self.out_of_space(size, 1 << align_log2)),
        }
    }

    /// Frees an allocation; its range merges with free physical neighbours.
    /// O(1).
    ///
    /// # Errors
    /// [`AllocError::StaleHandle`] (double free), [`AllocError::UnknownHandle`],
    /// [`AllocError::ForeignHandle`]; the allocator is unchanged then.
    #[inline]
    pub fn free(&mut self, handle: AllocHandle) -> Result<(), AllocError> {
        if handle.owner != self.id {
            return self.free_earlier_epoch(handle);
        }
        let i = self.validate(handle)?;
        self.release_used(i);
        Ok(())
    }

    /// Frees used node `i`, whose handle was validated.
    #[inline(always)]
    fn release_used(&mut self, i: u32) {
        self.used_bytes -= self.nodes[i as usize].size;
        self.live -= 1;
        self.release_free_range(i);
    }

    /// The current range of a live allocation.
    ///
    /// # Errors
    /// As [`free`](Self::free).
    pub fn get(&self, handle: AllocHandle) -> Result<Allocation, AllocError> {
        let i = self.validate(handle)?;
        Ok(self.allocation_at(i))
    }

    /// Whether `handle` names a live allocation of this allocator.
    pub fn is_live(&self, handle: AllocHandle) -> bool {
        self.validate(handle).is_ok()
    }

    /// All live allocations in address order. O(number of blocks).
    pub fn allocations(&self) -> impl Iterator<Item = Allocation> + '_ {
        let mut cur = self.first;
        std::iter::from_fn(move || {
            while cur != NIL {
                let i = cur;
                cur = self.nodes[i as usize].next_phys;
                if self.nodes[i as usize].is_used() {
                    return Some(self.allocation_at(i));
                }
            }
            None
        })
    }

    /// Resizes a live allocation in place, keeping its offset and handle.
    ///
    /// Shrinking always succeeds and returns the tail to the free lists
    /// (merged with a free right neighbour). Growing succeeds only when the
    /// right physical neighbour is free and large enough. O(1).
    ///
    /// # Errors
    /// [`AllocError::ZeroSize`], [`AllocError::CannotGrowInPlace`] (then
    /// allocate a new range and copy), handle errors as [`free`](Self::free),
    /// [`AllocError::TooManyBlocks`].
    pub fn resize(&mut self, handle: AllocHandle, new_size: u64) -> Result<Allocation, AllocError> {
        let i = self.validate(handle)?;
        if new_size == 0 {
            return Err(AllocError::ZeroSize);
        }
        let Node {
            offset,
            size,
            next_phys: right,
            ..
        } = self.nodes[i as usize];
        let right_free = right != NIL && self.nodes[right as usize].is_free();
        if new_size < size {
            let delta = size - new_size;
            if right_free {
                self.remove_free_node(right);
                let r = &mut self.nodes[right as usize];
                r.offset -= delta;
                r.size += delta;
                let r_size = r.size;
                self.insert_free(right, r_size);
            } else {
                self.ensure_nodes(1)?;
                let t = self.push_node(offset + new_size, delta, i, right);
                self.nodes[i as usize].next_phys = t;
                if right == NIL {
                    self.last = t;
                } else {
                    self.nodes[right as usize].prev_phys = t;
                }
                self.insert_free(t, delta);
            }
            self.nodes[i as usize].size = new_size;
            self.used_bytes -= delta;
        } else if new_size > size {
            let delta = new_size - size;
            let available = if right_free {
                self.nodes[right as usize].size
            } else {
                0
            };
            if available < delta {
                return Err(AllocError::CannotGrowInPlace {
                    requested: new_size,
                    available: size + available,
                });
            }
            self.remove_free_node(right);
            if available == delta {
                self.unlink(right);
                self.release_node(right);
            } else {
                let r = &mut self.nodes[right as usize];
                r.offset += delta;
                r.size -= delta;
                let r_size = r.size;
                self.insert_free(right, r_size);
            }
            self.nodes[i as usize].size = new_size;
            self.used_bytes += delta;
            self.note_used(offset + new_size);
        }
        Ok(self.allocation_at(i))
    }

    /// Extends the managed range to `new_capacity` bytes (after the backing
    /// buffer grew); the new space joins a free block at the end. Existing
    /// offsets are unchanged. O(1).
    ///
    /// # Errors
    /// [`AllocError::CannotShrinkCapacity`] if `new_capacity` is below the
    /// current capacity, [`AllocError::TooManyBlocks`].
    pub fn grow(&mut self, new_capacity: u64) -> Result<(), AllocError> {
        if new_capacity < self.capacity {
            return Err(AllocError::CannotShrinkCapacity {
                capacity: self.capacity,
                requested: new_capacity,
            });
        }
        let delta = new_capacity - self.capacity;
        if delta == 0 {
            return Ok(());
        }
        if self.last != NIL && self.nodes[self.last as usize].is_free() {
            let l = self.last;
            self.remove_free_node(l);
            self.nodes[l as usize].size += delta;
            let l_size = self.nodes[l as usize].size;
            self.insert_free(l, l_size);
        } else {
            self.ensure_nodes(1)?;
            let last = self.last;
            let t = self.push_node(self.capacity, delta, last, NIL);
            if last == NIL {
                self.first = t;
            } else {
                self.nodes[last as usize].next_phys = t;
            }
            self.last = t;
            self.insert_free(t, delta);
        }
        self.capacity = new_capacity;
        Ok(())
    }

    /// Occupancy statistics. O(1) except for the largest free block, which
    /// walks the highest non-empty bin's list.
    pub fn stats(&self) -> AllocatorStats {
        let free_bytes = self.free_bytes();
        let largest = self.largest_free_block();
        let fragmentation = if free_bytes == 0 {
            0.0
        } else {
            1.0 - largest as f64 / free_bytes as f64
        };
        AllocatorStats {
            capacity: self.capacity,
            used_bytes: self.used_bytes,
            free_bytes,
            largest_free_block: largest,
            allocation_count: self.live,
            free_block_count: self.free_blocks,
            fragmentation,
            high_water_mark: self.high_water,
            peak_used_bytes: self.peak_used,
        }
    }

    /// Size of the largest free block (0 if none).
    pub fn largest_free_block(&self) -> u64 {
        if self.fl_bitmap == 0 {
            return 0;
        }
        let fl = (63 - self.fl_bitmap.leading_zeros()) as usize;
        let sl = (31 - self.sl_bitmaps[fl].leading_zeros()) as usize;
        let mut cur = self.bins[(fl << SL_BITS) | sl].head;
        let mut best = 0;
        while cur != NIL {
            let n = &self.nodes[cur as usize];
            best = best.max(n.size);
            cur = n.links[NEXT];
        }
        best
    }

    // ---- internals -------------------------------------------------------

    /// The allocation held by used node `i`.
    pub(super) fn allocation_at(&self, i: u32) -> Allocation {
        let n = &self.nodes[i as usize];
        let owner = match &self.epochs {
            None => self.id,
            Some(e) => e.survivors.get(&i).copied().unwrap_or(self.id),
        };
        Allocation {
            handle: AllocHandle {
                index: i,
                serial: n.links[NEXT],
                owner,
            },
            offset: n.offset,
            size: n.size,
        }
    }

    #[inline]
    fn validate(&self, h: AllocHandle) -> Result<u32, AllocError> {
        if h.owner != self.id {
            return self.validate_earlier_epoch(h);
        }
        let n = self
            .nodes
            .get(h.index as usize)
            .ok_or(AllocError::UnknownHandle)?;
        if !n.is_used() || n.links[NEXT] != h.serial {
            return Err(AllocError::StaleHandle);
        }
        Ok(h.index)
    }

    /// [`validate`](Self::validate) for a handle that is not of the current
    /// epoch: a survivor of an earlier one, a stale handle of an earlier
    /// one, or a foreign handle.
    #[cold]
    #[inline(never)]
    fn validate_earlier_epoch(&self, h: AllocHandle) -> Result<u32, AllocError> {
        let Some(epochs) = self.epochs.as_deref() else {
            return Err(AllocError::ForeignHandle);
        };
        if !epochs.ids.contains(&h.owner) {
            return Err(AllocError::ForeignHandle);
        }
        let survivor = epochs.survivors.get(&h.index) == Some(&h.owner);
        match self.nodes.get(h.index as usize) {
            Some(n) if survivor && n.is_used() && n.links[NEXT] == h.serial => Ok(h.index),
            _ => Err(AllocError::StaleHandle),
        }
    }

    /// [`free`](Self::free) of a handle that is not of the current epoch.
    #[cold]
    #[inline(never)]
    fn free_earlier_epoch(&mut self, handle: AllocHandle) -> Result<(), AllocError> {
        let i = self.validate_earlier_epoch(handle)?;
        if let Some(e) = self.epochs.as_mut() {
            e.survivors.remove(&i);
        }
        self.release_used(i);
        Ok(())
    }

    /// The serial counter ran out: start a new epoch (see the module docs).
    /// O(blocks), once every 2^32 allocations.
    #[cold]
    #[inline(never)]
    fn next_epoch(&mut self) {
        let old = self.id;
        let epochs = self.epochs.get_or_insert_with(Box::default);
        let mut cur = self.first;
        while cur != NIL {
            let n = &self.nodes[cur as usize];
            if n.is_used() {
                epochs.survivors.entry(cur).or_insert(old);
            }
            cur = n.next_phys;
        }
        epochs.ids.push(old);
        self.id = next_allocator_id();
        self.next_serial = 0;
    }

    #[inline]
    pub(super) fn ensure_nodes(&self, n: usize) -> Result<(), AllocError> {
        if self.vacant_count + (MAX_NODES - self.nodes.len()) >= n {
            Ok(())
        } else {
            Err(AllocError::TooManyBlocks)
        }
    }

    /// A new node with the given range and physical links, not on any bin
    /// list yet (callers ran `ensure_nodes` first and file it next).
    #[inline]
    fn push_node(&mut self, offset: u64, size: u64, prev_phys: u32, next_phys: u32) -> u32 {
        let node = Node {
            offset,
            size,
            prev_phys,
            next_phys,
            links: [NIL, NIL],
        };
        if self.vacant_head != NIL {
            let i = self.vacant_head;
            let slot = &mut self.nodes[i as usize];
            self.vacant_head = slot.links[NEXT];
            *slot = node;
            self.vacant_count -= 1;
            i
        } else {
            self.nodes.push(node);
            (self.nodes.len() - 1) as u32
        }
    }

    /// Puts node `i` (no longer linked anywhere) on the vacant stack.
    #[inline]
    fn release_node(&mut self, i: u32) {
        let n = &mut self.nodes[i as usize];
        n.links[PREV] = VACANT;
        n.links[NEXT] = self.vacant_head;
        self.vacant_head = i;
        self.vacant_count += 1;
    }

    /// Removes `i` from the physical list.
    fn unlink(&mut self, i: u32) {
        let Node {
            prev_phys,
            next_phys,
            ..
        } = self.nodes[i as usize];
        if prev_phys == NIL {
            self.first = next_phys;
        } else {
            self.nodes[prev_phys as usize].next_phys = next_phys;
        }
        if next_phys == NIL {
            self.last = prev_phys;
        } else {
            self.nodes[next_phys as usize].prev_phys = prev_phys;
        }
    }

    /// Files node `i`, a free block of `size` bytes, at the front of its
    /// bin's list (the old head was touched recently, so this is usually
    /// cache-warm), and makes it the bin's best block if it is at least as
    /// large as the current best.
    ///
    /// The back link of a list's head is not maintained (it may name the
    /// previous head; it is always a node index or `NIL`, never a state
    /// mark): list removal recognises the head by `BinList::head`.
    /// Written without data-dependent branches: with an empty list the back
    /// link written is `i`'s own, which is then overwritten.
    #[inline(always)]
    fn insert_free(&mut self, i: u32, size: u64) {
        debug_assert_eq!(self.nodes[i as usize].size, size);
        let b = flat_floor(size);
        let list = self.bins[b];
        let other = if list.head == NIL { i } else { list.head };
        self.nodes[other as usize].links[PREV] = i;
        self.nodes[i as usize].links = [NIL, list.head];
        let better = size >= list.best_size;
        self.bins[b] = BinList {
            best_size: if better { size } else { list.best_size },
            best: if better { i } else { list.best },
            head: i,
        };
        let (fl, sl) = (b >> SL_BITS, b & (SL_COUNT - 1));
        self.fl_bitmap |= 1 << fl;
        self.sl_bitmaps[fl] |= 1 << sl;
        self.free_blocks += 1;
    }

    /// Takes free node `i` off the list of bin `b` (its flat bin index).
    #[inline(always)]
    fn remove_free(&mut self, i: u32, b: usize) {
        let [prev, next] = self.nodes[i as usize].links;
        let list = &mut self.bins[b];
        if list.head == i {
            // The head's back link is not kept (see `insert_free`), so the
            // new head's node need not be touched here.
            list.head = next;
        } else {
            self.nodes[prev as usize].links[NEXT] = next;
            if next != NIL {
                self.nodes[next as usize].links[PREV] = prev;
            }
        }
        if list.best == i {
            // The head takes over; without a branch on whether the list
            // just became empty (then `i`'s own, warm, node is probed).
            let head = list.head;
            let empty = head == NIL;
            let probe = if empty { i } else { head };
            let probe_size = self.nodes[probe as usize].size;
            list.best = head;
            list.best_size = if empty { 0 } else { probe_size };
            let (fl, sl) = (b >> SL_BITS, b & (SL_COUNT - 1));
            self.sl_bitmaps[fl] &= !(u32::from(empty) << sl);
            self.fl_bitmap &= !(u64::from(self.sl_bitmaps[fl] == 0) << fl);
        }
        self.free_blocks -= 1;
    }

    /// Takes free node `i` off its bin list.
    fn remove_free_node(&mut self, i: u32) {
        let b = flat_floor(self.nodes[i as usize].size);
        self.remove_free(i, b);
    }

    /// First non-empty bin at or above flat bin `b` (`b <= BIN_COUNT`): two
    /// masked `trailing_zeros`.
    #[inline]
    fn first_nonempty_from(&self, b: usize) -> Option<usize> {
        let (fl, sl) = (b >> SL_BITS, b & (SL_COUNT - 1));
        if fl >= FL_COUNT {
            return None;
        }
        let sl_map = self.sl_bitmaps[fl] & (u32::MAX << sl);
        if sl_map != 0 {
            return Some((fl << SL_BITS) | sl_map.trailing_zeros() as usize);
        }
        // fl + 1 <= FL_COUNT < 64, so the shift cannot overflow.
        let fl_map = self.fl_bitmap & (u64::MAX << (fl + 1));
        if fl_map == 0 {
            return None;
        }
        let fl = fl_map.trailing_zeros() as usize;
        debug_assert!(self.sl_bitmaps[fl] != 0);
        Some((fl << SL_BITS) | self.sl_bitmaps[fl].trailing_zeros() as usize)
    }

    /// Aligned start of a `size`-byte range in free node `i`, if it fits.
    #[inline]
    fn fit(&self, i: u32, size: u64, align: u64) -> Option<u64> {
        let n = &self.nodes[i as usize];
        let start = align_up(n.offset, align)?;
        (start.checked_add(size)? <= n.end()).then_some(start)
    }

    /// The constant-step search described in `docs/ALLOCATOR.md`: the chosen
    /// free node (always a bin's head except in step 4), its flat bin index
    /// and the aligned start.
    #[inline(always)]
    pub(super) fn find_block(&self, size: u64, align_log2: u32) -> Option<(u32, usize, u64)> {
        let (floor, ceil) = flat_floor_ceil(size);
        // 1. Head of the exact (rounded-down) bin; its cached size (0 when
        //    empty; size > 0) decides without touching the node.
        // 2. First non-empty bin whose blocks are all >= size.
        let exact = self.bins[floor];
        let exact_fits = exact.best_size >= size;
        if align_log2 == 0 {
            // Any block of at least `size` bytes fits: choose between the
            // two candidates without a (poorly predictable) branch.
            let above = self.first_nonempty_from(ceil).unwrap_or(BIN_COUNT);
            let above_head = self.bins.get(above).map_or(NIL, |list| list.head);
            let (i, b) = if exact_fits {
                (exact.best, floor)
            } else {
                (above_head, above)
            };
            if i != NIL {
                return Some((i, b, self.nodes[i as usize].offset));
            }
        } else {
            let align = 1u64 << align_log2;
            if exact_fits {
                if let Some(start) = self.fit(exact.best, size, align) {
                    return Some((exact.best, floor, start));
                }
            }
            if let Some(b) = self.first_nonempty_from(ceil) {
                let h = self.bins[b].head;
                if let Some(start) = self.fit(h, size, align) {
                    return Some((h, b, start));
                }
            }
        }
        self.find_block_slow(size, 1 << align_log2)
    }

    /// Steps 3 and 4 of the search (rarely reached).
    #[cold]
    #[inline(never)]
    fn find_block_slow(&self, size: u64, align: u64) -> Option<(u32, usize, u64)> {
        // 3. With alignment: a bin whose blocks fit wherever they start.
        if align > 1 {
            if let Some(worst) = size.checked_add(align - 1) {
                if let Some(b) = self.first_nonempty_from(flat_floor_ceil(worst).1) {
                    let h = self.bins[b].head;
                    if let Some(start) = self.fit(h, size, align) {
                        return Some((h, b, start));
                    }
                }
            }
        }
        // 4. The free block at the end of the buffer.
        if self.last != NIL && self.nodes[self.last as usize].is_free() {
            if let Some(start) = self.fit(self.last, size, align) {
                let b = flat_floor(self.nodes[self.last as usize].size);
                return Some((self.last, b, start));
            }
        }
        None
    }

    /// Turns free node `i` (on the list of flat bin `bin`) into a used
    /// `[start, start + size)` allocated with alignment `2^align_log2` and
    /// stamped with `serial`, splitting off the padding before and the
    /// remainder after as free blocks. Callers ran `ensure_nodes(2)` first
    /// and advance the serial counter themselves.
    #[inline(always)]
    pub(super) fn take_block(
        &mut self,
        i: u32,
        bin: usize,
        start: u64,
        size: u64,
        align_log2: u32,
        serial: u32,
    ) -> Allocation {
        self.remove_free(i, bin);
        let Node {
            offset: block_start,
            size: block_size,
            mut prev_phys,
            mut next_phys,
            ..
        } = self.nodes[i as usize];
        let block_end = block_start + block_size;
        if start > block_start {
            let pad = start - block_start;
            let p = self.push_node(block_start, pad, prev_phys, i);
            if prev_phys == NIL {
                self.first = p;
            } else {
                self.nodes[prev_phys as usize].next_phys = p;
            }
            prev_phys = p;
            self.insert_free(p, pad);
        }
        let end = start + size;
        if end < block_end {
            let rest = block_end - end;
            let t = self.push_node(end, rest, i, next_phys);
            if next_phys == NIL {
                self.last = t;
            } else {
                self.nodes[next_phys as usize].prev_phys = t;
            }
            next_phys = t;
            self.insert_free(t, rest);
        }
        self.nodes[i as usize] = Node {
            offset: start,
            size,
            prev_phys,
            next_phys,
            links: [MARK_BASE + align_log2, serial],
        };
        self.used_bytes += size;
        self.live += 1;
        self.note_used(end);
        Allocation {
            handle: AllocHandle {
                index: i,
                serial,
                owner: self.id,
            },
            offset: start,
            size,
        }
    }

    #[inline]
    fn note_used(&mut self, end: u64) {
        self.peak_used = self.peak_used.max(self.used_bytes);
        self.high_water = self.high_water.max(end);
    }

    /// Node `i` just stopped being used (its record still holds the range):
    /// merge it with free physical neighbours and file the result in its
    /// bin. Returns the node that holds the merged free block.
    #[inline]
    pub(super) fn release_free_range(&mut self, i: u32) -> u32 {
        let Node {
            mut offset,
            mut size,
            prev_phys: mut left,
            next_phys: right,
            ..
        } = self.nodes[i as usize];
        let mut keep = i;
        if left != NIL {
            let l = self.nodes[left as usize];
            if l.is_free() {
                self.remove_free(left, flat_floor(l.size));
                self.release_node(i);
                keep = left;
                offset = l.offset;
                size += l.size;
                left = l.prev_phys;
            }
        }
        let mut next = right;
        if right != NIL {
            let r = self.nodes[right as usize];
            if r.is_free() {
                self.remove_free(right, flat_floor(r.size));
                self.release_node(right);
                size += r.size;
                next = r.next_phys;
            }
        }
        // The left side's links are unchanged (whoever precedes `keep`
        // already points at it); the right side's point past the merge.
        // Written even without a merge (then it is the same value), which
        // costs less than a poorly predictable branch on "merged?".
        if next == NIL {
            self.last = keep;
        } else {
            self.nodes[next as usize].prev_phys = keep;
        }
        let n = &mut self.nodes[keep as usize];
        n.offset = offset;
        n.size = size;
        n.prev_phys = left;
        n.next_phys = next;
        self.insert_free(keep, size);
        keep
    }

    #[cold]
    #[inline(never)]
    fn out_of_space(&self, size: u64, align: u64) -> AllocError {
        let tail_start = if self.last != NIL && self.nodes[self.last as usize].is_free() {
            self.nodes[self.last as usize].offset
        } else {
            self.capacity
        };
        match align_up(tail_start, align).and_then(|s| s.checked_add(size)) {
            Some(required_capacity) => AllocError::OutOfSpace {
                size,
                align,
                capacity: self.capacity,
                required_capacity,
            },
            None => AllocError::CapacityOverflow,
        }
    }

    /// Moves live allocation `i` (keeping its handle) to free node `dst` at
    /// `start`; its old range becomes free and merges with free neighbours.
    /// Returns the node holding that merged free block. Callers ran
    /// `ensure_nodes(2)` first. Used by defragmentation.
    pub(super) fn relocate(&mut self, i: u32, dst: u32, start: u64) -> u32 {
        let Node {
            size,
            links: [mark, serial],
            ..
        } = self.nodes[i as usize];
        let align_log2 = self.nodes[i as usize].align_log2();
        let peak = self.peak_used;
        let bin = flat_floor(self.nodes[dst as usize].size);
        let t = self
            .take_block(dst, bin, start, size, align_log2, serial)
            .handle
            .index;
        self.used_bytes -= size;
        self.live -= 1;
        self.peak_used = peak;
        // Swap places so that index `i` (the handle) names the new range and
        // `t` the old one, which is then freed.
        self.swap_identity(i, t);
        let n = &mut self.nodes[i as usize];
        n.links[PREV] = mark;
        n.links[NEXT] = serial;
        self.release_free_range(t)
    }

    /// Swaps the physical positions of nodes `a` and `b` (offset, size and
    /// physical links), so that index `a` names what `b` named and vice versa.
    fn swap_identity(&mut self, a: u32, b: u32) {
        // Collect neighbours, then rewrite links; handles adjacency.
        let na = self.nodes[a as usize];
        let nb = self.nodes[b as usize];
        let map = |x: u32| {
            if x == a {
                b
            } else if x == b {
                a
            } else {
                x
            }
        };
        let (a_prev, a_next) = (map(na.prev_phys), map(na.next_phys));
        let (b_prev, b_next) = (map(nb.prev_phys), map(nb.next_phys));
        // Node a takes b's place and vice versa.
        {
            let n = &mut self.nodes[a as usize];
            n.offset = nb.offset;
            n.size = nb.size;
            n.prev_phys = b_prev;
            n.next_phys = b_next;
        }
        {
            let n = &mut self.nodes[b as usize];
            n.offset = na.offset;
            n.size = na.size;
            n.prev_phys = a_prev;
            n.next_phys = a_next;
        }
        for (x, prev, next) in [(a, b_prev, b_next), (b, a_prev, a_next)] {
            if prev == NIL {
                self.first = x;
            } else if prev != a && prev != b {
                self.nodes[prev as usize].next_phys = x;
            }
            if next == NIL {
                self.last = x;
            } else if next != a && next != b {
                self.nodes[next as usize].prev_phys = x;
            }
        }
    }

    /// Makes `serial` the next allocation serial, standing in for the
    /// allocations that would lead there; test support.
    #[cfg(test)]
    pub(super) fn skip_serials_to(&mut self, serial: u32) {
        self.next_serial = serial;
    }

    /// Checks every structural invariant; test support.
    #[cfg(test)]
    pub(super) fn check_invariants(&self) {
        use super::bins::Bin;
        let mut cur = self.first;
        let mut prev = NIL;
        let mut expected_offset = 0;
        let (mut used, mut live, mut free_blocks) = (0, 0, 0);
        let mut prev_free = false;
        while cur != NIL {
            let n = &self.nodes[cur as usize];
            assert_eq!(n.prev_phys, prev, "physical back link");
            assert_eq!(n.offset, expected_offset, "blocks tile the buffer");
            assert!(n.size > 0, "empty block");
            match n.state() {
                State::Used => {
                    assert!(n.align_log2() < 64);
                    assert_eq!(n.offset % (1 << n.align_log2()), 0, "alignment");
                    used += n.size;
                    live += 1;
                    prev_free = false;
                }
                State::Free => {
                    assert!(!prev_free, "two adjacent free blocks");
                    prev_free = true;
                    free_blocks += 1;
                    // On the right bin list.
                    let b = bin_floor_of(n.size).flat();
                    let mut c = self.bins[b].head;
                    let mut found = false;
                    while c != NIL {
                        found |= c == cur;
                        c = self.nodes[c as usize].links[NEXT];
                    }
                    assert!(found, "free block missing from its bin");
                }
                State::Vacant => panic!("vacant node linked"),
            }
            expected_offset = n.end();
            prev = cur;
            cur = n.next_phys;
        }
        assert_eq!(self.last, prev);
        assert_eq!(expected_offset, self.capacity);
        assert_eq!(used, self.used_bytes);
        assert_eq!(live, self.live);
        assert_eq!(free_blocks, self.free_blocks);
        // The vacant stack holds exactly the vacant records.
        let mut vacant = 0;
        let mut v = self.vacant_head;
        while v != NIL {
            assert_eq!(self.nodes[v as usize].state(), State::Vacant);
            vacant += 1;
            v = self.nodes[v as usize].links[NEXT];
        }
        assert_eq!(vacant, self.vacant_count);
        let vacant_records = self
            .nodes
            .iter()
            .filter(|n| n.state() == State::Vacant)
            .count();
        assert_eq!(vacant, vacant_records);
        assert_eq!(vacant + live + free_blocks, self.nodes.len());
        for (&i, owner) in self.epochs.iter().flat_map(|e| &e.survivors) {
            assert!(self.nodes[i as usize].is_used(), "survivor {i} not live");
            let ids = &self.epochs.as_ref().unwrap().ids;
            assert!(ids.contains(owner) && *owner != self.id);
        }
        // Bitmaps agree with the lists; list links are consistent.
        for fl in 0..FL_COUNT {
            for sl in 0..SL_COUNT {
                let b = Bin { fl, sl };
                let list = self.bins[b.flat()];
                let nonempty = list.head != NIL;
                assert_eq!(nonempty, self.sl_bitmaps[fl] & (1 << sl) != 0);
                if nonempty {
                    let head_back = self.nodes[list.head as usize].links[PREV];
                    assert!(head_back == NIL || (head_back as usize) < self.nodes.len());
                    assert_eq!(self.nodes[list.best as usize].size, list.best_size);
                    let mut c = list.head;
                    let mut p = NIL;
                    let mut best_listed = false;
                    while c != NIL {
                        let n = &self.nodes[c as usize];
                        assert_eq!(n.state(), State::Free);
                        if p != NIL {
                            assert_eq!(n.links[PREV], p, "bin list back link");
                        }
                        assert_eq!(bin_floor_of(n.size).flat(), b.flat(), "node in wrong bin");
                        best_listed |= c == list.best;
                        p = c;
                        c = n.links[NEXT];
                    }
                    assert!(best_listed, "best block not on its bin's list");
                } else {
                    assert_eq!((list.best_size, list.best), (0, NIL));
                }
            }
            assert_eq!(self.sl_bitmaps[fl] != 0, self.fl_bitmap & (1 << fl) != 0);
        }
    }
}
