//! The one per-slot table: everything lipac keeps about a GPU slot, in one
//! row per slot of one `Vec`.
//!
//! A slot's bookkeeping used to live in four parallel tables (the registry's
//! occupants, the command loop's views, the Manager's per-slot state and the
//! BLAS scheduler's `BTreeMap` by instance); each row now holds what the
//! parts know about that slot, one column per part, and each column's type
//! is defined by (and written only by) the part that owns it:
//!
//! | column | type | written by | what |
//! | --- | --- | --- | --- |
//! | [`SlotRow::occupant`] | [`SlotOccupant`] | [`crate::registry`] | the live instance's handle key, its registration serial, its mesh |
//! | [`SlotRow::view`] | [`SlotView`] | [`crate::culling`] | the commanded state, the pending BLAS promise, the frame of the loop's last decision, the CPU's state-bit write not yet uploaded |
//! | [`SlotRow::managed`] | [`ManagedSlot`] | [`crate::manager`] | requested and traced LOD, geometry-data range, own-BLAS variant, last hits, dirty flag |
//!
//! The table is owned by the [`InstanceRegistry`](crate::registry::InstanceRegistry),
//! which creates a row whenever it creates a slot (rows and the GPU records
//! always have the same length, the slot count), and reached by the command
//! loop and the Manager through crate-private accessors. A standalone
//! [`Culling`](crate::culling::Culling) leaves the Manager's column at its
//! default.
//!
//! What is **not** in the table:
//!
//! * the GPU-facing per-slot arrays (the registry's instance records, the
//!   hit counters, the decayed rates): they are the buffers a GPU backend
//!   uploads and reads in their own layout, not bookkeeping;
//! * the BLAS residency of active instances (current, pending and desired
//!   BLAS, build priority, refit timer): the
//!   [`BuildScheduler`](crate::build_plan::BuildScheduler) keeps it, because
//!   it stays usable on its own (its tests, benches and lipac-vk's executor
//!   tests drive it without a Manager), in a dense table of its own (a
//!   position per key, the active instances packed). The Manager keys it by
//!   slot and holds none of it: whether a slot is scheduled, its BLAS
//!   address and its traced LOD are asked of the scheduler, an O(1) lookup.

use std::ops::{Deref, DerefMut};

pub(crate) use crate::culling::SlotView;
pub(crate) use crate::manager::ManagedSlot;
pub(crate) use crate::registry::SlotOccupant;

/// Everything kept about one GPU slot (see the [module docs](self)).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct SlotRow {
    /// The registry's: who lives in the slot.
    pub(crate) occupant: SlotOccupant,
    /// The command loop's: commanded state and pending BLAS.
    pub(crate) view: SlotView,
    /// The Manager's: LODs, data range, last hits.
    pub(crate) managed: ManagedSlot,
}

/// One [`SlotRow`] per slot, indexed by slot (see the [module docs](self)).
/// Derefs to the rows; only the registry adds rows.
#[derive(Clone, Debug, Default)]
pub(crate) struct SlotTable {
    rows: Vec<SlotRow>,
}

impl SlotTable {
    /// Appends the row of a new slot (the registry, with its record).
    pub(crate) fn push_slot(&mut self) {
        self.rows.push(SlotRow::default());
    }

    /// Room for `additional` more slots.
    pub(crate) fn reserve_exact(
        &mut self,
        additional: usize,
    ) -> Result<(), crate::error::CoreError> {
        self.rows
            .try_reserve_exact(additional)
            .map_err(|_| crate::error::CoreError::OutOfMemory {
                what: "slot table rows",
                additional,
            })
    }

    /// Slots the table holds without reallocating.
    pub(crate) fn capacity(&self) -> usize {
        self.rows.capacity()
    }

    /// Heap bytes held (from the capacity, see [`crate::memory`]).
    pub(crate) fn heap_bytes(&self) -> u64 {
        crate::memory::vec_bytes::<SlotRow>(self.rows.capacity())
    }
}

impl Deref for SlotTable {
    type Target = [SlotRow];
    fn deref(&self) -> &[SlotRow] {
        &self.rows
    }
}

impl DerefMut for SlotTable {
    fn deref_mut(&mut self) -> &mut [SlotRow] {
        &mut self.rows
    }
}
