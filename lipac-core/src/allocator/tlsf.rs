//! The TLSF range allocator: block records, bin lists, allocate/free/resize/grow.

use std::sync::atomic::{AtomicU32, Ordering};

use super::bins::{bin_ceil_of, bin_floor_of, bin_min_size, Bin, BIN_COUNT, FL_COUNT};
use super::error::AllocError;

/// "No node" link value.
pub(super) const NIL: u32 = u32::MAX;
/// Largest node index we hand out (`NIL` is reserved).
const MAX_NODES: usize = (u32::MAX - 1) as usize;

/// Source of allocator ids, so that handles of one allocator are recognised
/// as foreign by another.
static NEXT_ALLOCATOR_ID: AtomicU32 = AtomicU32::new(1);

/// Names one live allocation of one [`TlsfAllocator`].
///
/// Cheap to copy. Using a handle after its allocation was freed is detected
/// ([`AllocError::StaleHandle`]), as is a handle of another allocator
/// ([`AllocError::ForeignHandle`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct AllocHandle {
    pub(super) index: u32,
    pub(super) generation: u32,
    pub(super) owner: u32,
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

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum State {
    /// Node slot not in use (on the vacant list).
    Vacant,
    /// A free block, on its bin's list.
    Free,
    /// A live allocation.
    Used,
}

#[derive(Clone, Copy, Debug)]
pub(super) struct Node {
    pub offset: u64,
    pub size: u64,
    pub prev_phys: u32,
    pub next_phys: u32,
    prev_free: u32,
    next_free: u32,
    generation: u32,
    /// log2 of the alignment a used block was allocated with.
    pub align_log2: u8,
    pub state: State,
}

impl Node {
    fn end(&self) -> u64 {
        self.offset + self.size
    }
}

/// Two-level segregated fit range allocator over `[0, capacity)`.
///
/// Allocate and free are O(1) (bounded work, no loops over blocks or bins);
/// see the [module documentation](super) for the design.
#[derive(Debug)]
pub struct TlsfAllocator {
    id: u32,
    capacity: u64,
    pub(super) nodes: Vec<Node>,
    vacant: Vec<u32>,
    fl_bitmap: u64,
    sl_bitmaps: [u32; FL_COUNT],
    /// One free list per bin.
    bins: Vec<BinList>,
    /// Physically first / last block (`NIL` iff capacity is 0).
    pub(super) first: u32,
    pub(super) last: u32,
    used_bytes: u64,
    live: usize,
    free_blocks: usize,
    peak_used: u64,
    high_water: u64,
}

/// A bin's free list: head, tail, and the head's size cached so that the
/// exact-bin check and the front/back insertion choice need not touch the
/// head node.
#[derive(Clone, Copy, Debug)]
struct BinList {
    head_size: u64,
    head: u32,
    tail: u32,
}

impl BinList {
    const EMPTY: BinList = BinList {
        head_size: 0,
        head: NIL,
        tail: NIL,
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
            id: NEXT_ALLOCATOR_ID.fetch_add(1, Ordering::Relaxed),
            capacity: 0,
            nodes: Vec::new(),
            vacant: Vec::new(),
            fl_bitmap: 0,
            sl_bitmaps: [0; FL_COUNT],
            bins: vec![BinList::EMPTY; BIN_COUNT],
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
            let i = this.push_node(0, capacity);
            this.first = i;
            this.last = i;
            this.capacity = capacity;
            this.insert_free(i);
        }
        this
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
    /// to [`grow`](Self::grow) to; [`AllocError::CapacityOverflow`].
    pub fn allocate(&mut self, size: u64) -> Result<Allocation, AllocError> {
        self.allocate_aligned(size, 1)
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
        if size == 0 {
            return Err(AllocError::ZeroSize);
        }
        if !align.is_power_of_two() {
            return Err(AllocError::InvalidAlignment { align });
        }
        // Up to two new nodes (padding and tail remainder).
        self.ensure_nodes(2)?;
        match self.find_block(size, align) {
            Some((i, start)) => Ok(self.take_block(i, start, size, align)),
            None => Err(self.out_of_space(size, align)),
        }
    }

    /// Frees an allocation; its range merges with free physical neighbours.
    /// O(1).
    ///
    /// # Errors
    /// [`AllocError::StaleHandle`] (double free), [`AllocError::UnknownHandle`],
    /// [`AllocError::ForeignHandle`]; the allocator is unchanged then.
    pub fn free(&mut self, handle: AllocHandle) -> Result<(), AllocError> {
        let i = self.validate(handle)?;
        let node = &mut self.nodes[i as usize];
        node.state = State::Free;
        node.generation = node.generation.wrapping_add(1);
        self.used_bytes -= node.size;
        self.live -= 1;
        self.release_free_range(i);
        Ok(())
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
                if self.nodes[i as usize].state == State::Used {
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
        if new_size < size {
            let delta = size - new_size;
            if right != NIL && self.nodes[right as usize].state == State::Free {
                self.remove_free(right);
                let r = &mut self.nodes[right as usize];
                r.offset -= delta;
                r.size += delta;
                self.insert_free(right);
            } else {
                self.ensure_nodes(1)?;
                let t = self.push_node(offset + new_size, delta);
                self.link_after(i, t);
                self.insert_free(t);
            }
            self.nodes[i as usize].size = new_size;
            self.used_bytes -= delta;
        } else if new_size > size {
            let delta = new_size - size;
            let right_free = if right != NIL && self.nodes[right as usize].state == State::Free {
                self.nodes[right as usize].size
            } else {
                0
            };
            if right_free < delta {
                return Err(AllocError::CannotGrowInPlace {
                    requested: new_size,
                    available: size + right_free,
                });
            }
            self.remove_free(right);
            if right_free == delta {
                self.unlink(right);
                self.release_node(right);
            } else {
                let r = &mut self.nodes[right as usize];
                r.offset += delta;
                r.size -= delta;
                self.insert_free(right);
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
        if self.last != NIL && self.nodes[self.last as usize].state == State::Free {
            let l = self.last;
            self.remove_free(l);
            self.nodes[l as usize].size += delta;
            self.insert_free(l);
        } else {
            self.ensure_nodes(1)?;
            let t = self.push_node(self.capacity, delta);
            if self.last == NIL {
                self.first = t;
                self.last = t;
            } else {
                self.link_after(self.last, t);
            }
            self.insert_free(t);
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
        let mut cur = self.bins[Bin { fl, sl }.flat()].head;
        let mut best = 0;
        while cur != NIL {
            let n = &self.nodes[cur as usize];
            best = best.max(n.size);
            cur = n.next_free;
        }
        best
    }

    // ---- internals -------------------------------------------------------

    pub(super) fn allocation_at(&self, i: u32) -> Allocation {
        let n = &self.nodes[i as usize];
        Allocation {
            handle: AllocHandle {
                index: i,
                generation: n.generation,
                owner: self.id,
            },
            offset: n.offset,
            size: n.size,
        }
    }

    fn validate(&self, h: AllocHandle) -> Result<u32, AllocError> {
        if h.owner != self.id {
            return Err(AllocError::ForeignHandle);
        }
        let n = self
            .nodes
            .get(h.index as usize)
            .ok_or(AllocError::UnknownHandle)?;
        if n.generation != h.generation || n.state != State::Used {
            return Err(AllocError::StaleHandle);
        }
        Ok(h.index)
    }

    pub(super) fn ensure_nodes(&self, n: usize) -> Result<(), AllocError> {
        if self.vacant.len() + (MAX_NODES - self.nodes.len()) >= n {
            Ok(())
        } else {
            Err(AllocError::TooManyBlocks)
        }
    }

    /// A new unlinked free-state node (callers ran `ensure_nodes` first).
    fn push_node(&mut self, offset: u64, size: u64) -> u32 {
        let fresh = |generation| Node {
            offset,
            size,
            prev_phys: NIL,
            next_phys: NIL,
            prev_free: NIL,
            next_free: NIL,
            generation,
            align_log2: 0,
            state: State::Free,
        };
        if let Some(i) = self.vacant.pop() {
            let g = self.nodes[i as usize].generation;
            self.nodes[i as usize] = fresh(g);
            i
        } else {
            self.nodes.push(fresh(0));
            (self.nodes.len() - 1) as u32
        }
    }

    fn release_node(&mut self, i: u32) {
        let n = &mut self.nodes[i as usize];
        n.state = State::Vacant;
        n.generation = n.generation.wrapping_add(1);
        self.vacant.push(i);
    }

    /// Inserts unlinked node `t` physically right after `i`.
    fn link_after(&mut self, i: u32, t: u32) {
        let next = self.nodes[i as usize].next_phys;
        self.nodes[t as usize].prev_phys = i;
        self.nodes[t as usize].next_phys = next;
        self.nodes[i as usize].next_phys = t;
        if next == NIL {
            self.last = t;
        } else {
            self.nodes[next as usize].prev_phys = t;
        }
    }

    /// Inserts unlinked node `t` physically right before `i`.
    fn link_before(&mut self, i: u32, t: u32) {
        let prev = self.nodes[i as usize].prev_phys;
        self.nodes[t as usize].next_phys = i;
        self.nodes[t as usize].prev_phys = prev;
        self.nodes[i as usize].prev_phys = t;
        if prev == NIL {
            self.first = t;
        } else {
            self.nodes[prev as usize].next_phys = t;
        }
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

    /// Files free node `i` in its bin: at the front if at least as large as
    /// the head (keeps a large block at the head for the exact-bin check),
    /// else at the back.
    fn insert_free(&mut self, i: u32) {
        let size = self.nodes[i as usize].size;
        let bin = bin_floor_of(size);
        let list = &mut self.bins[bin.flat()];
        let (head, tail) = (list.head, list.tail);
        if head == NIL {
            *list = BinList {
                head_size: size,
                head: i,
                tail: i,
            };
            self.fl_bitmap |= 1 << bin.fl;
            self.sl_bitmaps[bin.fl] |= 1 << bin.sl;
            let n = &mut self.nodes[i as usize];
            n.prev_free = NIL;
            n.next_free = NIL;
        } else if size >= list.head_size {
            list.head = i;
            list.head_size = size;
            let n = &mut self.nodes[i as usize];
            n.prev_free = NIL;
            n.next_free = head;
            self.nodes[head as usize].prev_free = i;
        } else {
            list.tail = i;
            let n = &mut self.nodes[i as usize];
            n.prev_free = tail;
            n.next_free = NIL;
            self.nodes[tail as usize].next_free = i;
        }
        self.free_blocks += 1;
    }

    /// Takes free node `i` off its bin list.
    fn remove_free(&mut self, i: u32) {
        let Node {
            size,
            prev_free,
            next_free,
            ..
        } = self.nodes[i as usize];
        let bin = bin_floor_of(size);
        let b = bin.flat();
        if prev_free == NIL {
            self.bins[b].head = next_free;
            if next_free != NIL {
                self.bins[b].head_size = self.nodes[next_free as usize].size;
            }
        } else {
            self.nodes[prev_free as usize].next_free = next_free;
        }
        if next_free == NIL {
            self.bins[b].tail = prev_free;
        } else {
            self.nodes[next_free as usize].prev_free = prev_free;
        }
        if self.bins[b].head == NIL {
            self.sl_bitmaps[bin.fl] &= !(1 << bin.sl);
            if self.sl_bitmaps[bin.fl] == 0 {
                self.fl_bitmap &= !(1 << bin.fl);
            }
        }
        self.free_blocks -= 1;
    }

    /// First non-empty bin at or above `bin`: two masked `trailing_zeros`.
    #[inline]
    fn first_nonempty_from(&self, bin: Bin) -> Option<Bin> {
        let sl_map = self.sl_bitmaps[bin.fl] & (u32::MAX << bin.sl);
        if sl_map != 0 {
            return Some(Bin {
                fl: bin.fl,
                sl: sl_map.trailing_zeros() as usize,
            });
        }
        let above = bin.fl + 1;
        if above >= FL_COUNT {
            return None;
        }
        let fl_map = self.fl_bitmap & (u64::MAX << above);
        if fl_map == 0 {
            return None;
        }
        let fl = fl_map.trailing_zeros() as usize;
        debug_assert!(self.sl_bitmaps[fl] != 0);
        Some(Bin {
            fl,
            sl: self.sl_bitmaps[fl].trailing_zeros() as usize,
        })
    }

    /// Aligned start of a `size`-byte range in free node `i`, if it fits.
    #[inline]
    fn fit(&self, i: u32, size: u64, align: u64) -> Option<u64> {
        let n = &self.nodes[i as usize];
        let start = align_up(n.offset, align)?;
        (start.checked_add(size)? <= n.end()).then_some(start)
    }

    /// The constant-step search described in the module docs.
    pub(super) fn find_block(&self, size: u64, align: u64) -> Option<(u32, u64)> {
        // 1. Head of the exact (rounded-down) bin; without alignment its
        //    cached size decides without touching the node.
        let exact = &self.bins[bin_floor_of(size).flat()];
        let head = exact.head;
        if head != NIL && exact.head_size >= size {
            if let Some(start) = self.fit(head, size, align) {
                return Some((head, start));
            }
        }
        // 2. First non-empty bin whose blocks are all >= size.
        if let Some(bin) = bin_ceil_of(size).and_then(|c| self.first_nonempty_from(c)) {
            let h = self.bins[bin.flat()].head;
            if let Some(start) = self.fit(h, size, align) {
                return Some((h, start));
            }
        }
        // 3. With alignment: a bin whose blocks fit wherever they start.
        if align > 1 {
            let worst = size.checked_add(align - 1);
            if let Some(bin) = worst
                .and_then(bin_ceil_of)
                .and_then(|c| self.first_nonempty_from(c))
            {
                let h = self.bins[bin.flat()].head;
                if let Some(start) = self.fit(h, size, align) {
                    return Some((h, start));
                }
            }
        }
        // 4. The free block at the end of the buffer.
        if self.last != NIL && self.nodes[self.last as usize].state == State::Free {
            if let Some(start) = self.fit(self.last, size, align) {
                return Some((self.last, start));
            }
        }
        None
    }

    /// Turns free node `i` into a used `[start, start + size)`, splitting off
    /// the padding before and the remainder after as free blocks.
    pub(super) fn take_block(&mut self, i: u32, start: u64, size: u64, align: u64) -> Allocation {
        self.remove_free(i);
        let Node {
            offset: block_start,
            ..
        } = self.nodes[i as usize];
        let block_end = self.nodes[i as usize].end();
        if start > block_start {
            let p = self.push_node(block_start, start - block_start);
            self.link_before(i, p);
            self.insert_free(p);
        }
        let end = start + size;
        if end < block_end {
            let t = self.push_node(end, block_end - end);
            self.link_after(i, t);
            self.insert_free(t);
        }
        let n = &mut self.nodes[i as usize];
        n.offset = start;
        n.size = size;
        n.state = State::Used;
        n.align_log2 = align.trailing_zeros() as u8;
        self.used_bytes += size;
        self.live += 1;
        self.note_used(end);
        self.allocation_at(i)
    }

    fn note_used(&mut self, end: u64) {
        self.peak_used = self.peak_used.max(self.used_bytes);
        self.high_water = self.high_water.max(end);
    }

    /// Node `i` just became free (state already set): merge it with free
    /// physical neighbours and file the result in its bin. Returns the node
    /// that holds the merged free block.
    pub(super) fn release_free_range(&mut self, i: u32) -> u32 {
        let mut cur = i;
        let left = self.nodes[cur as usize].prev_phys;
        if left != NIL && self.nodes[left as usize].state == State::Free {
            self.remove_free(left);
            self.nodes[left as usize].size += self.nodes[cur as usize].size;
            self.unlink(cur);
            self.release_node(cur);
            cur = left;
        }
        let right = self.nodes[cur as usize].next_phys;
        if right != NIL && self.nodes[right as usize].state == State::Free {
            self.remove_free(right);
            self.nodes[cur as usize].size += self.nodes[right as usize].size;
            self.unlink(right);
            self.release_node(right);
        }
        self.insert_free(cur);
        cur
    }

    fn out_of_space(&self, size: u64, align: u64) -> AllocError {
        let tail_start = if self.last != NIL && self.nodes[self.last as usize].state == State::Free
        {
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
            generation,
            align_log2,
            ..
        } = self.nodes[i as usize];
        let peak = self.peak_used;
        let t = self
            .take_block(dst, start, size, 1u64 << align_log2)
            .handle
            .index;
        self.used_bytes -= size;
        self.live -= 1;
        self.peak_used = peak;
        // Swap places so that index `i` (the handle) names the new range and
        // `t` the old one, which is then freed.
        let old_gen_t = self.nodes[t as usize].generation;
        self.swap_identity(i, t);
        self.nodes[i as usize].generation = generation;
        self.nodes[t as usize].generation = old_gen_t.wrapping_add(1);
        self.nodes[t as usize].state = State::Free;
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

    /// Checks every structural invariant; test support.
    #[cfg(test)]
    pub(super) fn check_invariants(&self) {
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
            match n.state {
                State::Used => {
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
                        c = self.nodes[c as usize].next_free;
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
        // Bitmaps agree with the lists.
        for fl in 0..FL_COUNT {
            for sl in 0..super::bins::SL_COUNT {
                let b = Bin { fl, sl };
                let list = self.bins[b.flat()];
                let nonempty = list.head != NIL;
                assert_eq!(nonempty, self.sl_bitmaps[fl] & (1 << sl) != 0);
                if nonempty {
                    assert_eq!(self.nodes[list.tail as usize].next_free, NIL);
                    assert_eq!(self.nodes[list.head as usize].size, list.head_size);
                }
            }
            assert_eq!(self.sl_bitmaps[fl] != 0, self.fl_bitmap & (1 << fl) != 0);
        }
    }
}
