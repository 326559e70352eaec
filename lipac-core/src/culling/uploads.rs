//! What a GPU backend uploads before Algorithm 1 ([`Uploads`], from
//! [`Culling::take_uploads`]) and how it must apply them ([`apply_uploads`],
//! the specification of the scatter shader).
//!
//! The rule: the state bits of an instance record belong to Algorithm 2 (the
//! GPU). Upload [`Uploads::records`] (all three arrays of
//! [`InstanceArrays`]: hot, TLAS records, bounds) *keeping* the state bits of the
//! GPU copy's hot record (bits [`instance_bits::STATE_MASK`]), then apply
//! [`Uploads::state_overrides`] and [`Uploads::hitbox_overrides`], which are
//! exactly the CPU's writes since the last take, and raise the decayed
//! rates to [`Uploads::hitbox_rate_floors`] and
//! [`Uploads::instance_rate_floors`] (a held warm start). The hitbox
//! extents ([`Uploads::hitbox_extents`]: a hitbox's counting-box heights and
//! cost word) are the CPU's alone and are written as they are. Why:
//! `docs/ARCHITECTURE.md`, "Who owns the state bits".

use std::ops::Range;

use crate::hitbox_extents::HitboxExtent;
use crate::layout::{hitbox_bits, instance_bits, HitboxRecord, InstanceArrays, InstanceState};

#[cfg(doc)]
use super::Culling;

/// What a GPU backend uploads before Algorithm 1, from
/// [`Culling::take_uploads`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Uploads {
    /// Slot ranges whose records changed (sorted, disjoint): upload those
    /// slots of `registry().records()` (hot, TLAS records and bounds), **keeping the
    /// state bits** of the GPU copy (see [`apply_uploads`]).
    pub records: Vec<Range<u32>>,
    /// The CPU's writes of state bits since the last take, by ascending slot
    /// (registration → inactive, latency mitigation → active); apply after
    /// the records.
    pub state_overrides: Vec<(u32, InstanceState)>,
    /// Hitboxes whose active bit the CPU set, by ascending index, as
    /// `(index, active)`: set the active bit and zero the streak, keeping the
    /// hit count and heights.
    pub hitbox_overrides: Vec<(u32, bool)>,
    /// Least decayed rates of hitboxes, by ascending index, as `(index,
    /// rate)`: a held warm start ([`super::CullingConfig::warm_start_hold`]).
    /// Raise the GPU record's `rate` to at least `rate` (the GPU's rate is
    /// Algorithm 2's: a floor, not a value).
    pub hitbox_rate_floors: Vec<(u32, u32)>,
    /// Least decayed rates of unique-BLAS instances, by ascending slot, as
    /// `(slot, rate)`: raise the GPU's per-slot rate to at least `rate`.
    pub instance_rate_floors: Vec<(u32, u32)>,
    /// Hitbox extents that changed since the last take (the counting box's
    /// y range and the cost word, [`crate::hitbox_extents`]), by ascending
    /// index, each index once, as `(index, extent)`: write the record's
    /// `min_y`, `max_y` and `cost`, nothing else. A record no extent was
    /// ever uploaded for must hold [`HitboxRecord::default`]'s (the empty
    /// extent), not zeros.
    pub hitbox_extents: Vec<(u32, HitboxExtent)>,
}

/// Writes `uploads` into a GPU-side copy of the instance arrays, the
/// per-slot rates and the hitbox buffer the way a GPU backend must: the
/// slots of the record ranges (hot, TLAS records, bounds) without their state
/// bits, then the overrides, then the rate floors, then the hitbox extents. `records` is the CPU's
/// instance buffer; `gpu_instances` and `gpu_rates` are grown to its length
/// (new rates 0). Entries past the buffers are ignored. Used by tests and
/// as the specification of the scatter shader.
pub fn apply_uploads(
    uploads: &Uploads,
    records: &InstanceArrays,
    gpu_instances: &mut InstanceArrays,
    gpu_rates: &mut Vec<u32>,
    gpu_hitboxes: &mut [HitboxRecord],
) {
    if gpu_instances.len() < records.len() {
        gpu_instances.resize(records.len());
    }
    if gpu_rates.len() < gpu_instances.len() {
        gpu_rates.resize(gpu_instances.len(), 0);
    }
    for range in &uploads.records {
        let (lo, hi) = (
            range.start as usize,
            (range.end as usize).min(records.len()),
        );
        for slot in lo.min(hi)..hi {
            let (Some(mut src), Some(dst)) = (records.get(slot), gpu_instances.hot().get(slot))
            else {
                continue;
            };
            let state = dst.packed & instance_bits::STATE_MASK;
            src.packed = (src.packed & !instance_bits::STATE_MASK) | state;
            gpu_instances.set(slot, &src);
        }
    }
    for &(slot, state) in &uploads.state_overrides {
        gpu_instances.set_state(slot as usize, state);
    }
    for &(index, active) in &uploads.hitbox_overrides {
        if let Some(h) = gpu_hitboxes.get_mut(index as usize) {
            h.packed &=
                !((hitbox_bits::STREAK_MAX << hitbox_bits::STREAK_SHIFT) | hitbox_bits::ACTIVE);
            h.packed |= u32::from(active);
        }
    }
    for &(index, rate) in &uploads.hitbox_rate_floors {
        if let Some(h) = gpu_hitboxes.get_mut(index as usize) {
            h.rate = h.rate.max(rate);
        }
    }
    for &(slot, rate) in &uploads.instance_rate_floors {
        if let Some(r) = gpu_rates.get_mut(slot as usize) {
            *r = (*r).max(rate);
        }
    }
    for (index, extent) in &uploads.hitbox_extents {
        if let Some(h) = gpu_hitboxes.get_mut(*index as usize) {
            extent.write_to(h);
        }
    }
}
