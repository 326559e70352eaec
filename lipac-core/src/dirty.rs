//! Tracking which records of a GPU buffer mirror changed since the last
//! upload (crate-private: the registry's dirty ranges).

use std::ops::Range;

/// A set of dirty record indices, taken as sorted, coalesced ranges.
///
/// Marking is O(1) and idempotent; taking is O(d log d) in the number of
/// dirty indices, independent of the buffer size.
#[derive(Clone, Debug, Default)]
pub struct DirtySet {
    bits: Vec<u64>,
    list: Vec<u32>,
}

impl DirtySet {
    /// Marks index `i` dirty. `u32::MAX` cannot end a half-open `u32` range
    /// and is ignored (GPU slots stay below [`crate::layout::MAX_SLOTS`]).
    pub fn mark(&mut self, i: u32) {
        if i == u32::MAX {
            return;
        }
        let word = (i / 64) as usize;
        if word >= self.bits.len() {
            self.bits.resize(word + 1, 0);
        }
        let bit = 1u64 << (i % 64);
        if self.bits[word] & bit == 0 {
            self.bits[word] |= bit;
            self.list.push(i);
        }
    }

    /// Reserves room for indices below `len` and for `additional` more
    /// dirty indices before the next take.
    pub fn reserve(
        &mut self,
        len: usize,
        additional: usize,
    ) -> Result<(), crate::error::CoreError> {
        let words = len.div_ceil(64).saturating_sub(self.bits.len());
        crate::memory::try_reserve_exact(&mut self.bits, words, "dirty-slot bits")?;
        crate::memory::try_reserve(&mut self.list, additional, "dirty slots")
    }

    /// Whether index `i` is dirty.
    #[cfg(test)]
    pub fn contains(&self, i: u32) -> bool {
        self.bits
            .get((i / 64) as usize)
            .is_some_and(|w| w & (1u64 << (i % 64)) != 0)
    }

    /// Heap bytes held (bitset and list capacities).
    pub(crate) fn heap_bytes(&self) -> u64 {
        crate::memory::vec_bytes::<u64>(self.bits.capacity())
            + crate::memory::vec_bytes::<u32>(self.list.capacity())
    }

    /// Number of dirty indices.
    #[cfg(test)]
    pub fn len(&self) -> usize {
        self.list.len()
    }

    /// Whether nothing is dirty.
    pub fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

    /// Takes the dirty indices as sorted, disjoint ranges, merging adjacent
    /// ones, and clears the set.
    pub fn take(&mut self) -> Vec<Range<u32>> {
        self.take_merged(0)
    }

    /// Like [`DirtySet::take`], but also merges ranges separated by at most
    /// `max_gap` clean indices (fewer, larger copy regions; the clean records
    /// in the gaps are uploaded unchanged).
    pub fn take_merged(&mut self, max_gap: u32) -> Vec<Range<u32>> {
        let mut list = std::mem::take(&mut self.list);
        for &i in &list {
            self.bits[(i / 64) as usize] &= !(1u64 << (i % 64));
        }
        list.sort_unstable();
        let mut out: Vec<Range<u32>> = Vec::new();
        for i in list.drain(..) {
            match out.last_mut() {
                Some(r) if u64::from(i) <= u64::from(r.end) + u64::from(max_gap) => r.end = i + 1,
                _ => out.push(i..i + 1),
            }
        }
        // Keep the allocation for the next frame.
        self.list = list;
        out
    }
}

#[cfg(test)]
mod tests;
