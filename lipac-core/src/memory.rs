//! CPU memory held by the per-frame loop, computed from the containers'
//! capacities (what is allocated, not what is used).
//!
//! [`crate::culling::Culling::memory_usage`] fills a [`MemoryUsage`]. Exact
//! for `Vec`, `VecDeque` and `BinaryHeap` (`capacity × element size`);
//! for the `slotmap` of handles it uses slotmap 1.x's slot layout (the value
//! and a `u32` version, rounded up to the value's alignment); for hash maps
//! it uses hashbrown's layout (one bucket of key and value plus one control
//! byte per bucket, buckets = the next power of two of capacity · 8/7); the
//! `BTreeSet` of pending command priorities has no capacity and is
//! estimated at 16 bytes per element (11 keys of 8 bytes per node, nodes
//! about two-thirds full). Allocator headers and padding are not counted.

use std::collections::{BTreeSet, HashMap};
use std::mem::size_of;

use crate::error::CoreError;

/// `v.try_reserve_exact(additional)`, a refusal as
/// [`CoreError::OutOfMemory`]: room a caller asks for is an error when it
/// cannot be had, never an abort.
pub(crate) fn try_reserve_exact<T>(
    v: &mut Vec<T>,
    additional: usize,
    what: &'static str,
) -> Result<(), CoreError> {
    v.try_reserve_exact(additional)
        .map_err(|_| CoreError::OutOfMemory { what, additional })
}

/// `v.try_reserve(additional)` (amortised growth), a refusal as
/// [`CoreError::OutOfMemory`].
pub(crate) fn try_reserve<T>(
    v: &mut Vec<T>,
    additional: usize,
    what: &'static str,
) -> Result<(), CoreError> {
    v.try_reserve(additional)
        .map_err(|_| CoreError::OutOfMemory { what, additional })
}

/// CPU bytes of the loop's containers; see the [module docs](self).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MemoryUsage {
    /// The CPU mirror of the GPU instance buffer: one 96-byte
    /// [`InstanceRecord`](crate::layout::InstanceRecord) per slot.
    pub records: u64,
    /// Handle map (`slotmap`): every instance's slot (the rest of its
    /// description is read back from its record and its slot's row).
    pub handles: u64,
    /// The per-slot table (`slot_table`): per slot its occupant (handle,
    /// registration serial, mesh), the command loop's view (commanded state,
    /// pending BLAS) and the Manager's state (LODs, data range, last hits).
    pub slot_occupants: u64,
    /// Free-slot heap and quarantine queue.
    pub free_lists: u64,
    /// Dirty-slot bitset and list of slots to upload.
    pub dirty: u64,
    /// Per-slot hit counters (the CPU copy of the paper's 4 bytes).
    pub instance_hits: u64,
    /// Per-slot "waiting for a BLAS" flags: 0 now, they are a column of
    /// the slot table, counted in [`MemoryUsage::slot_occupants`].
    pub awaiting: u64,
    /// Latency mitigation's per-slot visibility bits.
    pub latency_bits: u64,
    /// Hitbox records (12 bytes per hitbox, not per instance).
    pub hitboxes: u64,
    /// The bounded command buffer (its capacity, not per instance).
    pub command_buffer: u64,
    /// Pending commands (hash map by slot and ordered set by priority).
    pub command_queue: u64,
    /// CPU state-bit and hitbox overrides not yet taken by
    /// [`Culling::take_uploads`](crate::culling::Culling::take_uploads).
    pub overrides: u64,
    /// Scratch buffers.
    pub scratch: u64,
    /// The hitboxes' member lists that keep their extents
    /// ([`crate::hitbox_extents`]): 12 bytes per slot, 5 per hitbox, and
    /// the extents not yet taken for the GPU.
    pub extent_lists: u64,
}

impl MemoryUsage {
    /// Sum of all fields.
    pub fn total(&self) -> u64 {
        self.per_slot() + self.hitboxes + self.command_buffer
    }

    /// The fields that grow with the number of instance slots (everything
    /// but the hitboxes and the command buffer).
    pub fn per_slot(&self) -> u64 {
        self.records
            + self.handles
            + self.slot_occupants
            + self.free_lists
            + self.dirty
            + self.instance_hits
            + self.awaiting
            + self.latency_bits
            + self.command_queue
            + self.overrides
            + self.scratch
            + self.extent_lists
    }
}

/// Bytes of a `Vec`-like container.
pub(crate) fn vec_bytes<T>(capacity: usize) -> u64 {
    (capacity * size_of::<T>()) as u64
}

/// Bytes of a hashbrown `HashMap<K, V>` with this capacity.
pub(crate) fn hash_map_bytes<K, V>(map: &HashMap<K, V>) -> u64 {
    let cap = map.capacity();
    if cap == 0 {
        return 0;
    }
    let buckets = if cap < 8 {
        if cap < 4 {
            4
        } else {
            8
        }
    } else {
        (cap * 8 / 7).next_power_of_two()
    };
    (buckets * (size_of::<(K, V)>() + 1)) as u64
}

/// Estimated bytes of a `BTreeSet` (16 bytes per element).
pub(crate) fn btree_set_bytes<T>(set: &BTreeSet<T>) -> u64 {
    (set.len() * 16) as u64
}
