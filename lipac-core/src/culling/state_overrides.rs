//! The CPU's writes of instance state bits since the last upload, by slot.

use crate::layout::InstanceState;
use crate::memory::vec_bytes;
use crate::slot_table::SlotRow;

/// Marker in a slot's [`SlotView::state_override`](super::SlotView):
/// listed, but the write was cancelled (the instance was removed).
const CANCELLED: u8 = 0xFF;

/// The CPU's state writes since the last [`StateOverrides::take`], last
/// write per slot winning.
///
/// One byte per slot, in the slot's row of the slot table
/// ([`crate::slot_table`]; 0 = not listed, `state + 1` = written,
/// [`CANCELLED`]), and one list entry per slot written, instead of a hash
/// map: registering a scene writes one override per instance, and the slots
/// come in order, so a per-slot byte is both smaller and far cheaper to fill
/// than hashed buckets. The list holds each slot at most once, so it stays
/// bounded by the slot count even when nothing takes it (a CPU backend).
#[derive(Clone, Debug, Default)]
pub(super) struct StateOverrides {
    /// Slots listed since the last take, each once, in write order.
    slots: Vec<u32>,
}

impl StateOverrides {
    /// Records that the CPU wrote `state` into `slot`'s record (a slot of
    /// `rows`; the registry made its row).
    pub(super) fn insert(&mut self, rows: &mut [SlotRow], slot: u32, state: InstanceState) {
        let Some(row) = rows.get_mut(slot as usize) else {
            return;
        };
        let v = &mut row.view.state_override;
        if *v == 0 {
            self.slots.push(slot);
        }
        *v = state as u8 + 1;
    }

    /// Forgets the write to `slot` (its instance was removed).
    pub(super) fn remove(&mut self, rows: &mut [SlotRow], slot: u32) {
        if let Some(row) = rows.get_mut(slot as usize) {
            let v = &mut row.view.state_override;
            if *v != 0 {
                *v = CANCELLED;
            }
        }
    }

    /// Room for `additional` more writes.
    pub(super) fn reserve(&mut self, additional: usize) -> Result<(), crate::error::CoreError> {
        crate::memory::try_reserve(&mut self.slots, additional, "state overrides")
    }

    /// The writes since the last take, by ascending slot; clears them
    /// (keeping the capacity).
    pub(super) fn take(&mut self, rows: &mut [SlotRow]) -> Vec<(u32, InstanceState)> {
        let mut out = Vec::with_capacity(self.slots.len());
        for &slot in &self.slots {
            let Some(row) = rows.get_mut(slot as usize) else {
                continue;
            };
            let v = std::mem::take(&mut row.view.state_override);
            if v != 0 && v != CANCELLED {
                out.push((slot, InstanceState::from_bits(u32::from(v - 1))));
            }
        }
        self.slots.clear();
        out.sort_unstable_by_key(|&(s, _)| s);
        out
    }

    /// Heap bytes held (the per-slot bytes are the slot table's).
    pub(super) fn heap_bytes(&self) -> u64 {
        vec_bytes::<u32>(self.slots.capacity())
    }
}

#[cfg(test)]
mod tests;
