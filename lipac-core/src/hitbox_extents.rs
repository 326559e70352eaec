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
//!   GLSL's ordered-key `atomicMin`/`atomicMax` gave when the GPU
//!   reduced); `(+∞, −∞)` (empty, `min_y > max_y`) without members;
//! * `cost`: per member [`hitbox_bits::COST_SHARED`] or
//!   [`hitbox_bits::COST_UNIQUE`], summed wrapping.
//!
//! [`write_extents`] computes every hitbox's extent from the instance arrays
//! in one pass (the specification, and what a caller of
//! [`crate::assembly::assemble_tlas`] without a [`crate::culling::Culling`]
//! runs after changing records). [`crate::culling::Culling`] keeps them
//! incrementally (`ExtentTracker`: per hitbox a list of its members and
//! each member's cached height keys, so that a written slot costs a
//! comparison, an update in place, or a walk over a hitbox's members where
//! one left the edge of its range); the extents that changed go to the GPU in
//! [`crate::culling::Uploads::hitbox_extents`].

use crate::layout::{
    hitbox_bits, instance_bits, HitboxRecord, InstanceArrays, InstanceBounds, InstanceHot,
};
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
}

impl Default for HitboxExtent {
    fn default() -> Self {
        Self::EMPTY
    }
}

/// The hitbox a slot is a member of: live, unpinned, hitbox index below
/// `hitbox_count` (and below 2^31, which no buffer of hitbox records
/// reaches: 43 GB; the tracker keeps a flag in the top bit).
#[inline(always)]
fn member_of(hot: &InstanceHot, hitbox_count: usize) -> Option<u32> {
    let p = hot.packed;
    let live_unpinned = p & (instance_bits::ALIVE | instance_bits::PINNED) == instance_bits::ALIVE;
    let in_range = (hot.hitbox as usize) < hitbox_count && hot.hitbox < UNIQUE;
    (live_unpinned && in_range).then_some(hot.hitbox)
}

/// A member's height keys `(min_key, max_key)` ([`height_keys`]), from its
/// AABB.
#[inline(always)]
fn member_keys(b: &InstanceBounds) -> [u32; 2] {
    [
        height_keys::min_key(b.aabb_min[1].to_bits()),
        height_keys::max_key(b.aabb_max[1].to_bits()),
    ]
}

/// A record's height range as keys (never a NaN's: a record holds a
/// reduction's result).
#[inline(always)]
fn record_keys(record: &HitboxRecord) -> [u32; 2] {
    [
        height_keys::min_key(record.min_y.to_bits()),
        height_keys::max_key(record.max_y.to_bits()),
    ]
}

/// Writes the height range `[lo, hi]` (keys) into `record`.
#[inline(always)]
fn set_range(record: &mut HitboxRecord, [lo, hi]: [u32; 2]) {
    record.min_y = f32::from_bits(height_keys::from_min_key(lo));
    record.max_y = f32::from_bits(height_keys::from_max_key(hi));
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

    /// Folds in a member with height keys `keys`, unique-BLAS or not.
    #[inline(always)]
    fn add(&mut self, [lo, hi]: [u32; 2], unique: bool) {
        self.min_key = self.min_key.min(lo);
        self.max_key = self.max_key.max(hi);
        self.cost = self.cost.wrapping_add(cost_of(unique));
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
    for (m, b) in instances.hot().iter().zip(instances.bounds()) {
        if let Some(h) = member_of(m, acc.len()) {
            let unique = m.packed & instance_bits::UNIQUE_BLAS != 0;
            acc[h as usize].add(member_keys(b), unique);
        }
    }
    for (record, r) in hitboxes.iter_mut().zip(&acc) {
        r.extent().write_to(record);
    }
}

/// "No slot" / "no hitbox" in the member lists.
const NONE: u32 = u32::MAX;

/// Bit of [`ExtentTracker`]'s per-slot hitbox word: the member counts as
/// unique-BLAS in its hitbox's cost word (members' hitbox indices are below
/// it, [`member_of`]).
const UNIQUE: u32 = 1 << 31;

/// The cost word's share of one member.
#[inline(always)]
fn cost_of(unique: bool) -> u32 {
    if unique {
        hitbox_bits::COST_UNIQUE
    } else {
        hitbox_bits::COST_SHARED
    }
}

/// What a refresh did to a hitbox it touched.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Touch {
    /// Not touched yet.
    No,
    /// Updated in place: members added (the range widened) or removed from
    /// inside the range (only the cost word changed).
    InPlace,
    /// A removed member was on the range's edge: recompute over the list.
    Recompute,
}

/// The hitboxes' member lists and each member's contribution, kept in step
/// with the instance arrays: the incremental form of [`write_extents`]
/// that [`crate::culling::Culling`] runs (see the [module docs](self)).
///
/// A written slot whose hitbox, heights and kind did not change costs a
/// comparison; one that joins a hitbox or grows its range, an update in
/// place; one that leaves a hitbox or shrinks from the edge of its range, a
/// walk over that hitbox's members' cached contributions.
///
/// Memory: 20 bytes per slot (its hitbox and kind, its height keys, its
/// neighbours in the list) and 5 bytes per hitbox (list head, mark), CPU
/// only ([`ExtentTracker::heap_bytes`]).
#[derive(Clone, Debug, Default)]
pub(crate) struct ExtentTracker {
    /// Per slot: the hitbox whose list holds it (with [`UNIQUE`]), or
    /// [`NONE`].
    linked: Vec<u32>,
    /// Per slot: its height keys `(min_key, max_key)` while linked.
    keys: Vec<[u32; 2]>,
    /// Per slot: next and previous slot in its hitbox's list.
    next: Vec<u32>,
    prev: Vec<u32>,
    /// Per hitbox: first slot of its list.
    head: Vec<u32>,
    /// Per hitbox: what the running refresh did to it.
    touch: Vec<Touch>,
    /// The hitboxes the running refresh touched, with their extent's words
    /// before it.
    touched: Vec<(u32, [u32; 3])>,
}

impl ExtentTracker {
    /// Heap bytes held.
    pub(crate) fn heap_bytes(&self) -> u64 {
        vec_bytes::<u32>(self.linked.capacity())
            + vec_bytes::<[u32; 2]>(self.keys.capacity())
            + vec_bytes::<u32>(self.next.capacity())
            + vec_bytes::<u32>(self.prev.capacity())
            + vec_bytes::<u32>(self.head.capacity())
            + vec_bytes::<Touch>(self.touch.capacity())
            + vec_bytes::<(u32, [u32; 3])>(self.touched.capacity())
    }

    /// Reserves room for `slots` slots in all.
    pub(crate) fn reserve_slots(&mut self, slots: usize) -> Result<(), crate::error::CoreError> {
        use crate::memory::try_reserve_exact;
        for v in [&mut self.linked, &mut self.next, &mut self.prev] {
            let n = slots.saturating_sub(v.len());
            try_reserve_exact(v, n, "hitbox extent links")?;
        }
        let n = slots.saturating_sub(self.keys.len());
        try_reserve_exact(&mut self.keys, n, "hitbox extent keys")
    }

    /// Notes that the refresh changes `hitbox` (its words before, once).
    fn touch(&mut self, hitbox: u32, record: &HitboxRecord) {
        let h = hitbox as usize;
        if h >= self.touch.len() {
            self.touch.resize(h + 1, Touch::No);
        }
        if self.touch[h] == Touch::No {
            self.touch[h] = Touch::InPlace;
            self.touched
                .push((hitbox, HitboxExtent::of(record).to_words()));
        }
    }

    fn unlink(&mut self, slot: u32, hitbox: u32) {
        let s = slot as usize;
        let (next, prev) = (self.next[s], self.prev[s]);
        if prev == NONE {
            if let Some(head) = self.head.get_mut(hitbox as usize) {
                *head = next;
            }
        } else {
            self.next[prev as usize] = next;
        }
        if next != NONE {
            self.prev[next as usize] = prev;
        }
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
    }

    /// Takes the slots in `touched` (every slot whose record the CPU wrote
    /// since the last call; others are assumed unchanged, so a slot whose
    /// hitbox index was out of range stays no member until it is written
    /// again, as the registry does when it places it) into the lists,
    /// updates the extents of the hitboxes they left or are in, in
    /// `hitboxes`, and appends each that changed (bitwise) to `changed` as
    /// `(hitbox, extent)`, each once, in no particular order.
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
            self.keys.resize(slots, [0; 2]);
            self.next.resize(slots, NONE);
            self.prev.resize(slots, NONE);
        }
        let hitbox_count = hitboxes.len();
        for slot in touched {
            let s = slot as usize;
            let (Some(m), Some(b)) = (instances.hot().get(s), instances.bounds().get(s)) else {
                continue;
            };
            let now = match member_of(m, hitbox_count) {
                Some(hitbox) if m.packed & instance_bits::UNIQUE_BLAS != 0 => hitbox | UNIQUE,
                Some(hitbox) => hitbox,
                None => NONE,
            };
            let keys = member_keys(b);
            let before = self.linked[s];
            if before == now && (now == NONE || self.keys[s] == keys) {
                continue; // nothing this hitbox's extent depends on changed
            }
            let (old, new) = (before & !UNIQUE, now & !UNIQUE);
            if before != NONE && now != NONE && old == new {
                // The same hitbox: its heights or its kind changed.
                self.replace(new, [before, now], [self.keys[s], keys], hitboxes);
                self.keys[s] = keys;
                self.linked[s] = now;
                continue;
            }
            if before != NONE {
                self.remove(old, before & UNIQUE != 0, self.keys[s], hitboxes);
                if new != old {
                    self.unlink(slot, old);
                }
            }
            if now != NONE {
                if before == NONE || new != old {
                    self.link(slot, new);
                }
                self.add(new, now & UNIQUE != 0, keys, hitboxes);
                self.keys[s] = keys;
            }
            self.linked[s] = now;
        }
        for i in 0..self.touched.len() {
            let (hitbox, before) = self.touched[i];
            let h = hitbox as usize;
            let how = std::mem::replace(&mut self.touch[h], Touch::No);
            let Some(record) = hitboxes.get_mut(h) else {
                continue;
            };
            if how == Touch::Recompute {
                self.recompute(hitbox).write_to(record);
            }
            let extent = HitboxExtent::of(record);
            if extent.to_words() != before {
                changed.push((hitbox, extent));
            }
        }
        self.touched.clear();
    }

    /// Takes a member with `keys` (unique-BLAS or not) out of `hitbox`'s
    /// extent: its cost share in place; its range only by a recompute, and
    /// only if it was on an edge of the range.
    fn remove(&mut self, hitbox: u32, unique: bool, keys: [u32; 2], hitboxes: &mut [HitboxRecord]) {
        let Some(record) = hitboxes.get_mut(hitbox as usize) else {
            return;
        };
        self.touch(hitbox, record);
        record.cost = record.cost.wrapping_sub(cost_of(unique));
        let [lo, hi] = record_keys(record);
        if keys[0] == lo || keys[1] == hi {
            self.touch[hitbox as usize] = Touch::Recompute;
        }
    }

    /// Replaces a member's contribution to `hitbox` (its hitbox words
    /// `[before, now]`, its keys `[old, new]`): the cost share in place; the
    /// range in place unless the old keys were on an edge the new ones do
    /// not reach, which needs a recompute.
    fn replace(
        &mut self,
        hitbox: u32,
        words: [u32; 2],
        keys: [[u32; 2]; 2],
        hitboxes: &mut [HitboxRecord],
    ) {
        let Some(record) = hitboxes.get_mut(hitbox as usize) else {
            return;
        };
        self.touch(hitbox, record);
        record.cost = record
            .cost
            .wrapping_sub(cost_of(words[0] & UNIQUE != 0))
            .wrapping_add(cost_of(words[1] & UNIQUE != 0));
        if self.touch[hitbox as usize] != Touch::InPlace {
            return;
        }
        let [old, new] = keys;
        let [lo, hi] = record_keys(record);
        if (old[0] == lo && new[0] > lo) || (old[1] == hi && new[1] < hi) {
            self.touch[hitbox as usize] = Touch::Recompute;
            return;
        }
        set_range(record, [lo.min(new[0]), hi.max(new[1])]);
    }

    /// Adds a member with `keys` to `hitbox`'s extent in place (a hitbox
    /// marked for a recompute gets its range there).
    fn add(&mut self, hitbox: u32, unique: bool, keys: [u32; 2], hitboxes: &mut [HitboxRecord]) {
        let Some(record) = hitboxes.get_mut(hitbox as usize) else {
            return;
        };
        self.touch(hitbox, record);
        record.cost = record.cost.wrapping_add(cost_of(unique));
        if self.touch[hitbox as usize] == Touch::InPlace {
            let [lo, hi] = record_keys(record);
            set_range(record, [lo.min(keys[0]), hi.max(keys[1])]);
        }
    }

    /// `hitbox`'s extent from its members' cached contributions.
    fn recompute(&self, hitbox: u32) -> HitboxExtent {
        let mut r = Reduction::EMPTY;
        let mut slot = self.head.get(hitbox as usize).copied().unwrap_or(NONE);
        while slot != NONE {
            let s = slot as usize;
            r.add(self.keys[s], self.linked[s] & UNIQUE != 0);
            slot = self.next[s];
        }
        r.extent()
    }
}

mod height_keys;

#[cfg(test)]
mod tests;
