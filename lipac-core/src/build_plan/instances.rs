//! The scheduler's per-instance table: dense by key, packed by instance.
//!
//! The [`crate::Manager`] keys the scheduler by GPU slot
//! ([`InstanceKey`]`(slot)`), so a key is at most [`MAX_SLOTS`]` - 1`. The
//! table holds one `u32` per key up to the largest one activated (the
//! position of its state, or none) and the states of the active instances
//! packed in one `Vec` (removal swaps the last one in): every lookup is two
//! array reads, and a pass over the active instances touches only them,
//! never the inactive slots. It replaces a `BTreeMap` keyed by instance
//! (a tree search per lookup, a node allocation per activation). Iteration
//! order is the packing order; every caller that needs an order sorts.

use crate::blas_ids::InstanceKey;
use crate::layout::MAX_SLOTS;

/// Dense per-key positions of packed per-instance states `T`.
#[derive(Clone, Debug)]
pub(super) struct Instances<T> {
    /// Per key: 1 + the position in `rows`, 0 = not active.
    index: Vec<u32>,
    /// The active instances' states, packed.
    rows: Vec<(InstanceKey, T)>,
}

impl<T> Default for Instances<T> {
    fn default() -> Self {
        Self {
            index: Vec::new(),
            rows: Vec::new(),
        }
    }
}

impl<T> Instances<T> {
    /// Whether `key` can be held: keys are GPU slots, below [`MAX_SLOTS`].
    pub(super) fn in_range(key: InstanceKey) -> bool {
        key.0 < MAX_SLOTS
    }

    fn position(&self, key: &InstanceKey) -> Option<usize> {
        match self.index.get(key.0 as usize) {
            Some(&p) if p != 0 => Some(p as usize - 1),
            _ => None,
        }
    }

    /// Whether `key` is active.
    pub(super) fn contains_key(&self, key: &InstanceKey) -> bool {
        self.position(key).is_some()
    }

    /// The state of `key`, if active.
    pub(super) fn get(&self, key: &InstanceKey) -> Option<&T> {
        self.position(key).map(|p| &self.rows[p].1)
    }

    /// The state of `key`, if active, for writing.
    pub(super) fn get_mut(&mut self, key: &InstanceKey) -> Option<&mut T> {
        self.position(key).map(|p| &mut self.rows[p].1)
    }

    /// Makes `key` active with `value` (replacing a state it had). The
    /// caller checked [`Instances::in_range`].
    pub(super) fn insert(&mut self, key: InstanceKey, value: T) {
        if let Some(p) = self.position(&key) {
            self.rows[p].1 = value;
            return;
        }
        let i = key.0 as usize;
        if self.index.len() <= i {
            self.index.resize(i + 1, 0);
        }
        self.rows.push((key, value));
        // At most MAX_SLOTS rows: the position fits a u32.
        self.index[i] = self.rows.len() as u32;
    }

    /// Makes `key` inactive and returns its state.
    pub(super) fn remove(&mut self, key: &InstanceKey) -> Option<T> {
        let p = self.position(key)?;
        self.index[key.0 as usize] = 0;
        let (_, value) = self.rows.swap_remove(p);
        if let Some(&(moved, _)) = self.rows.get(p) {
            self.index[moved.0 as usize] = p as u32 + 1;
        }
        Some(value)
    }

    /// The active instances, in packing order.
    pub(super) fn iter(&self) -> impl Iterator<Item = (&InstanceKey, &T)> {
        self.rows.iter().map(|(k, v)| (k, v))
    }

    /// Number of active instances.
    pub(super) fn len(&self) -> usize {
        self.rows.len()
    }
}

#[cfg(test)]
mod tests;
