//! What [`Manager::stats`](super::Manager::stats) reports.

use crate::controller::{ControllerStats, EscapeSample};

/// Memory by category, in bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MemoryStats {
    /// Uncompacted shared BLASes (built, or reserved while building).
    pub blas_shared: u64,
    /// Unique BLASes (built, or reserved while building).
    pub blas_unique: u64,
    /// Compacted shared BLASes (and reserved compaction targets).
    pub blas_compacted: u64,
    /// Scratch of builds handed out and not acknowledged.
    pub blas_scratch: u64,
    /// BLASes released and waiting for the frames in flight before they
    /// are freed (not counted against the BLAS budget).
    pub blas_pending_free: u64,
    /// Capacity of the geometry-data buffer the allocator manages.
    pub data_capacity: u64,
    /// Geometry-data bytes in live ranges.
    pub data_used: u64,
    /// Geometry-data bytes free.
    pub data_free: u64,
    /// Largest free geometry-data block.
    pub data_largest_free: u64,
    /// `1 - largest free block / free bytes` (0 = one free block).
    pub data_fragmentation: f64,
    /// Hitbox records (12 bytes each).
    pub hitbox_bytes: u64,
    /// Per-slot hit feedback counters (4 bytes per slot).
    pub feedback_bytes: u64,
    /// Instance arrays: hot, heights and cold, 104 bytes per slot
    /// ([`crate::layout::INSTANCE_SLOT_BYTES`]).
    pub instance_record_bytes: u64,
}

/// Instances by state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InstanceCounts {
    /// Live (registered) instances.
    pub live: usize,
    /// Of those, active.
    pub active: usize,
    /// Omitted (counting box).
    pub omitted: usize,
    /// Inactive.
    pub inactive: usize,
    /// Holding a BLAS address (traced with it when active).
    pub with_blas: usize,
    /// Waiting for a BLAS build.
    pub awaiting_blas: usize,
    /// Known to the build scheduler (holding or waiting for a BLAS).
    pub scheduled: usize,
    /// GPU slots in quarantine after a removal.
    pub quarantined_slots: u32,
}

/// A snapshot of the manager.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ManagerStats {
    /// Memory by category.
    pub memory: MemoryStats,
    /// Instances by state.
    pub instances: InstanceCounts,
    /// Commands waiting for the per-frame command budget.
    pub commands_pending: usize,
    /// BLAS builds waiting to be planned.
    pub builds_queued: usize,
    /// Builds and compactions handed out and not yet acknowledged.
    pub builds_in_flight: usize,
    /// BLAS cache entries (shared and unique, any state).
    pub blas_entries: usize,
    /// BLAS frees waiting for the frames in flight.
    pub blas_pending_frees: usize,
    /// Geometry-data ranges allocated (one per live instance).
    pub data_ranges: usize,
    /// Free blocks in the geometry-data buffer.
    pub data_free_blocks: usize,
    /// The closed-loop controller (with a
    /// [`ManagerConfig::target`](super::ManagerConfig::target)): scale,
    /// measurement, "budget unreachable".
    pub controller: Option<ControllerStats>,
    /// The newest counted hits (escape fraction), from
    /// [`Manager::process_feedback`](super::Manager::process_feedback) or
    /// [`Manager::observe_escape`](super::Manager::observe_escape).
    pub escape: Option<EscapeSample>,
}
