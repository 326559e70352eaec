//! Each hitbox's *extent*: the y range of its counting box and its cost
//! word, kept by the CPU where instances change instead of being reduced
//! over every slot every frame.
//!
//! A hitbox's counting box spans its cell in x/z and, in y, the AABBs of
//! the instances it stands for; its cost word counts them by kind
//! ([`HitboxRecord::cost`], read by the cost-aware rule). Only an
//! **inactive** hitbox emits a box or has its cost read, and in an inactive
//! hitbox every live, unpinned instance counts as inactive, whatever its
//! state bits (`docs/ALGORITHMS.md`, Algorithm 1). So the extent is the
//! reduction over the hitbox's *members* — live, unpinned instances whose
//! hitbox index is in range — and depends only on CPU-written fields
//! (liveness, pin, hitbox, heights, the unique-BLAS bit), never on
//! Algorithm 2's state bits:
//!
//! * `min_y` / `max_y`: the lowest AABB minimum and highest AABB maximum
//!   height of the members; NaN heights never win, −0 is below +0 (the
//!   order of `height_keys`: the IEEE order on non-NaN floats, the order
//!   GLSL's ordered-key `atomicMin`/`atomicMax` gave when the GPU reduced); `(+∞, −∞)` (empty, `min_y > max_y`) without members;
//! * `cost`: per member [`hitbox_bits::COST_SHARED`] or
//!   [`hitbox_bits::COST_UNIQUE`], summed wrapping.
//!
//! [`write_extents`] computes every hitbox's extent from the instance arrays
//! in one pass (the specification, and what a caller of
//! [`crate::assembly::assemble_tlas`] without a [`crate::culling::Culling`]
//! runs after changing records). [`crate::culling::Culling`] keeps them
//! incrementally ([`ExtentTracker`]): per hitbox a list of its members, so
//! that a changed slot costs a relink and a walk over its old and new
//! hitboxes' members; the extents that changed go to the GPU in
//! [`crate::culling::Uploads::hitbox_extents`].

use crate::layout::{hitbox_bits, instance_bits, HitboxRecord, InstanceArrays, InstanceHot};
use crate::memory::vec_bytes;

/// The CPU-owned part of a [`HitboxRecord`]: its counting box's y range and
/// its cost word (see the [module docs](self)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HitboxExtent {
    /// Lowest AABB minimum height of the members (+∞ without members).
    pub min_y: f32,
    /// Highest AABB maximum height of the members (−∞ without members).
    pub max_y: f32,
    /// Members by kind: shared-BLAS in the low 16 bits, unique-BLAS in the
    /// high 16 bits (wrapping counts).
    pub cost: u32,
}

impl HitboxExtent {
    /// The extent of a hitbox without members.
    pub const EMPTY: HitboxExtent = HitboxExtent {
        min_y: f32::INFINITY,
        max_y: f32::NEG_INFINITY,
        cost: 0,
    };

    /// The extent stored in `record`.
    pub fn of(record: &HitboxRecord) -> Self {
        Self {
            min_y: record.min_y,
            max_y: record.max_y,
            cost: record.cost,
        }
    }

    /// Writes the extent into `record`, leaving its GPU-owned words
    /// (`packed`, `rate`) alone.
    pub fn write_to(&self, record: &mut HitboxRecord) {
        record.min_y = self.min_y;
        record.max_y = self.max_y;
        record.cost = self.cost;
    }

    /// Whether no member has a non-NaN height (`min_y > max_y`): no counting
    /// box.
    pub fn is_empty(&self) -> bool {
        self.min_y > self.max_y
    }

    /// The words the GPU stores: `[min_y bits, max_y bits, cost]`.
    pub fn to_words(&self) -> [u32; 3] {
        [self.min_y.to_bits(), self.max_y.to_bits(), self.cost]
    }

    /// Bitwise equality (the heights compared as bits, so −0 ≠ +0).
    fn same_bits(&self, other: &Self) -> bool {
        self.to_words() == other.to_words()
    }
}

impl Default for HitboxExtent {
    fn default() -> Self {
        Self::EMPTY
    }
}

/// The hitbox a slot is a member of: live, unpinned, hitbox index below
/// `hitbox_count`.
#[inline(always)]
fn member_of(hot: &InstanceHot, hitbox_count: usize) -> Option<u32> {
    let p = hot.packed;
    let live_unpinned = p & (instance_bits::ALIVE | instance_bits::PINNED) == instance_bits::ALIVE;
    (live_unpinned && (hot.hitbox as usize) < hitbox_count).then_some(hot.hitbox)
}

/// An extent being reduced: height keys ([`height_keys`]) and the cost word.
#[derive(Clone, Copy)]
struct Reduction {
    min_key: u32,
    max_key: u32,
    cost: u32,
}

impl Reduction {
    const EMPTY: Reduction = Reduction {
        min_key: height_keys::MIN_KEY_EMPTY,
        max_key: height_keys::MAX_KEY_EMPTY,
        cost: 0,
    };

    /// Folds in the member in slot `slot` of `instances`.
    #[inline(always)]
    fn add(&mut self, instances: &InstanceArrays, slot: usize) {
        let (Some(m), Some(h)) = (instances.hot().get(slot), instances.heights().get(slot)) else {
            return;
        };
        self.min_key = self.min_key.min(height_keys::min_key(h.min_y.to_bits()));
        self.max_key = self.max_key.max(height_keys::max_key(h.max_y.to_bits()));
        let unique = m.packed & instance_bits::UNIQUE_BLAS != 0;
        self.cost = self.cost.wrapping_add(if unique {
            hitbox_bits::COST_UNIQUE
        } else {
            hitbox_bits::COST_SHARED
        });
    }

    fn extent(&self) -> HitboxExtent {
        HitboxExtent {
            min_y: f32::from_bits(height_keys::from_min_key(self.min_key)),
            max_y: f32::from_bits(height_keys::from_max_key(self.max_key)),
            cost: self.cost,
        }
    }
}

/// Writes every hitbox's extent (see the [module docs](self)) into
/// `hitboxes`, from all slots of `instances`; the GPU-owned words stay.
/// Members whose hitbox index is not below `hitboxes.len()` are ignored.
///
/// ```
/// use lipac_core::hitbox_extents::write_extents;
/// use lipac_core::layout::{instance_bits, HitboxRecord, InstanceArrays, InstanceRecord};
///
/// let record = |y0: f32, y1: f32, hitbox: u32| InstanceRecord {
///     aabb_min: [0.0, y0, 0.0], aabb_max: [1.0, y1, 1.0], hitbox,
///     packed: instance_bits::ALIVE, ..Default::default()
/// };
/// let instances = InstanceArrays::from_records(&[record(2.0, 5.0, 1), record(-1.0, 3.0, 1)]);
/// let mut hitboxes = [HitboxRecord::default(); 2];
/// write_extents(&instances, &mut hitboxes);
/// assert_eq!((hitboxes[1].min_y, hitboxes[1].max_y, hitboxes[1].cost), (-1.0, 5.0, 2));
/// assert!(hitboxes[0].min_y > hitboxes[0].max_y); // no members: empty
/// ```
pub fn write_extents(instances: &InstanceArrays, hitboxes: &mut [HitboxRecord]) {
    let mut acc = vec![Reduction::EMPTY; hitboxes.len()];
    for (slot, m) in instances.hot().iter().enumerate() {
        if let Some(h) = member_of(m, acc.len()) {
            acc[h as usize].add(instances, slot);
        }
    }
    for (record, r) in hitboxes.iter_mut().zip(&acc) {
        r.extent().write_to(record);
    }
}

/// "No slot" / "no hitbox" in the member lists.
const NONE: u32 = u32::MAX;

/// The hitboxes' member lists, kept in step with the instance arrays: the
/// incremental form of [`write_extents`] that [`crate::culling::Culling`]
/// runs (see the [module docs](self)).
///
/// Memory: 12 bytes per slot (the hitbox a slot is linked into, and its
/// neighbours in that list) and 5 bytes per hitbox (list head, dirty mark),
/// CPU only ([`ExtentTracker::heap_bytes`]).
#[derive(Clone, Debug, Default)]
pub(crate) struct ExtentTracker {
    /// Per slot: the hitbox whose list holds it, or [`NONE`].
    linked: Vec<u32>,
    /// Per slot: next and previous slot in its hitbox's list.
    next: Vec<u32>,
    prev: Vec<u32>,
    /// Per hitbox: first slot of its list.
    head: Vec<u32>,
    /// Hitboxes whose extent must be recomputed, each once.
    dirty: Vec<u32>,
    is_dirty: Vec<bool>,
}

impl ExtentTracker {
    /// Heap bytes held.
    pub(crate) fn heap_bytes(&self) -> u64 {
        vec_bytes::<u32>(self.linked.capacity())
            + vec_bytes::<u32>(self.next.capacity())
            + vec_bytes::<u32>(self.prev.capacity())
            + vec_bytes::<u32>(self.head.capacity())
            + vec_bytes::<u32>(self.dirty.capacity())
            + vec_bytes::<bool>(self.is_dirty.capacity())
    }

    /// Reserves room for `slots` slots in all.
    pub(crate) fn reserve_slots(&mut self, slots: usize) {
        for v in [&mut self.linked, &mut self.next, &mut self.prev] {
            v.reserve_exact(slots.saturating_sub(v.len()));
        }
    }

    fn mark(&mut self, hitbox: u32) {
        let h = hitbox as usize;
        if h >= self.is_dirty.len() {
            self.is_dirty.resize(h + 1, false);
        }
        if !self.is_dirty[h] {
            self.is_dirty[h] = true;
            self.dirty.push(hitbox);
        }
    }

    fn unlink(&mut self, slot: u32) {
        let s = slot as usize;
        let hitbox = self.linked[s];
        if hitbox == NONE {
            return;
        }
        let (next, prev) = (self.next[s], self.prev[s]);
        if prev == NONE {
            self.head[hitbox as usize] = next;
        } else {
            self.next[prev as usize] = next;
        }
        if next != NONE {
            self.prev[next as usize] = prev;
        }
        self.linked[s] = NONE;
        self.mark(hitbox);
    }

    fn link(&mut self, slot: u32, hitbox: u32) {
        let (s, h) = (slot as usize, hitbox as usize);
        if h >= self.head.len() {
            self.head.resize(h + 1, NONE);
        }
        let first = self.head[h];
        self.next[s] = first;
        self.prev[s] = NONE;
        if first != NONE {
            self.prev[first as usize] = slot;
        }
        self.head[h] = slot;
        self.linked[s] = hitbox;
        self.mark(hitbox);
    }

    /// Takes the slots in `touched` (every slot whose record the CPU wrote
    /// since the last call; others are assumed unchanged, so a slot whose
    /// hitbox index was out of range stays no member until it is written
    /// again, as the registry does when it places it) into the lists,
    /// recomputes the extents of the hitboxes they left or are in, writes
    /// those into `hitboxes` and appends each that changed (bitwise) to
    /// `changed` as `(hitbox, extent)`, in no particular order.
    pub(crate) fn refresh(
        &mut self,
        instances: &InstanceArrays,
        touched: impl IntoIterator<Item = u32>,
        hitboxes: &mut [HitboxRecord],
        changed: &mut Vec<(u32, HitboxExtent)>,
    ) {
        let slots = instances.len();
        if self.linked.len() < slots {
            self.linked.resize(slots, NONE);
            self.next.resize(slots, NONE);
            self.prev.resize(slots, NONE);
        }
        let hitbox_count = hitboxes.len();
        for slot in touched {
            let s = slot as usize;
            let Some(m) = instances.hot().get(s) else {
                continue;
            };
            let now = member_of(m, hitbox_count).unwrap_or(NONE);
            let before = self.linked[s];
            if now != before {
                self.unlink(slot);
                if now != NONE {
                    self.link(slot, now);
                }
            } else if now != NONE {
                // Same hitbox: its heights or kind may have changed.
                self.mark(now);
            }
        }
        for i in 0..self.dirty.len() {
            let hitbox = self.dirty[i];
            self.is_dirty[hitbox as usize] = false;
            let Some(record) = hitboxes.get_mut(hitbox as usize) else {
                continue;
            };
            let mut r = Reduction::EMPTY;
            let mut slot = self.head.get(hitbox as usize).copied().unwrap_or(NONE);
            while slot != NONE {
                r.add(instances, slot as usize);
                slot = self.next[slot as usize];
            }
            let extent = r.extent();
            if !extent.same_bits(&HitboxExtent::of(record)) {
                extent.write_to(record);
                changed.push((hitbox, extent));
            }
        }
        self.dirty.clear();
    }
}

mod height_keys;

#[cfg(test)]
mod tests;
