//! The CPU's writes of instance state bits since the last upload, by slot.

use crate::layout::InstanceState;
use crate::memory::vec_bytes;

/// Marker in [`StateOverrides::by_slot`]: listed, but the write was
/// cancelled (the instance was removed).
const CANCELLED: u8 = 0xFF;

/// The CPU's state writes since the last [`StateOverrides::take`], last
/// write per slot winning.
///
/// One byte per slot and one list entry per slot written, instead of a hash
/// map: registering a scene writes one override per instance, and the slots
/// come in order, so a per-slot array is both smaller and far cheaper to
/// fill than hashed buckets. The list holds each slot at most once, so it
/// stays bounded by the slot count even when nothing takes it (a CPU
/// backend).
#[derive(Clone, Debug, Default)]
pub(super) struct StateOverrides {
    /// Per slot: 0 = not listed, `state + 1` = written, [`CANCELLED`].
    by_slot: Vec<u8>,
    /// Slots listed since the last take, each once, in write order.
    slots: Vec<u32>,
}

impl StateOverrides {
    /// Records that the CPU wrote `state` into `slot`'s record.
    pub(super) fn insert(&mut self, slot: u32, state: InstanceState) {
        let i = slot as usize;
        if i >= self.by_slot.len() {
            self.by_slot.resize(i + 1, 0);
        }
        if self.by_slot[i] == 0 {
            self.slots.push(slot);
        }
        self.by_slot[i] = state as u8 + 1;
    }

    /// Forgets the write to `slot` (its instance was removed).
    pub(super) fn remove(&mut self, slot: u32) {
        if let Some(v) = self.by_slot.get_mut(slot as usize) {
            if *v != 0 {
                *v = CANCELLED;
            }
        }
    }

    /// Room for slots below `slots` and `additional` more writes.
    pub(super) fn reserve(&mut self, slots: usize, additional: usize) {
        self.by_slot
            .reserve_exact(slots.saturating_sub(self.by_slot.len()));
        self.slots.reserve(additional);
    }

    /// The writes since the last take, by ascending slot; clears them
    /// (keeping the capacity).
    pub(super) fn take(&mut self) -> Vec<(u32, InstanceState)> {
        let mut out = Vec::with_capacity(self.slots.len());
        for &slot in &self.slots {
            let v = std::mem::take(&mut self.by_slot[slot as usize]);
            if v != 0 && v != CANCELLED {
                out.push((slot, InstanceState::from_bits(u32::from(v - 1))));
            }
        }
        self.slots.clear();
        out.sort_unstable_by_key(|&(s, _)| s);
        out
    }

    /// Heap bytes held.
    pub(super) fn heap_bytes(&self) -> u64 {
        vec_bytes::<u8>(self.by_slot.capacity()) + vec_bytes::<u32>(self.slots.capacity())
    }
}

#[cfg(test)]
mod tests;
