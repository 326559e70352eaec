//! The record upload scatter: [`RecordUploader`] is the GPU version of
//! [`lipac_core::culling::apply_uploads`]. It stages the CPU's changed
//! instance records (joined, 96 bytes each) and scatters them into the GPU's
//! three instance arrays ([`InstanceBuffers`]: hot, TLAS records, bounds) **keeping the state bits** of the GPU's hot records (Algorithm 2
//! owns them), then applies the CPU's explicit state overrides and hitbox
//! active overrides, raises decayed rates to the CPU's rate floors (a held
//! warm start) and writes the hitbox extents that changed (the counting
//! boxes' heights and cost words, the CPU's).

use crate::accel::same_context;
use crate::assembly::InstanceBuffers;
use crate::commands::Recorder;
use crate::compute::{compute_to_compute, compute_to_everything, ComputeKernels, StorageSet};
use crate::context::DeviceContext;
use crate::error::{Result, VkError};
use crate::memory::{Buffer, MemoryLocation};
use crate::shaders::UPLOAD_RECORDS_SPV;
use ash::vk;
use bytemuck::{Pod, Zeroable};
use lipac_core::culling::Uploads;
use lipac_core::hitbox_extents::HitboxExtent;
use lipac_core::layout::{HitboxRecord, InstanceArrays, InstanceRecord};

const BINDINGS: u32 = 12;
const RECORD_BYTES: u64 = std::mem::size_of::<InstanceRecord>() as u64;

/// Push constants of `upload_records.comp`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct UploadPush {
    pass: u32,
    record_count: u32,
    state_count: u32,
    hitbox_count: u32,
    slot_capacity: u32,
    hitbox_capacity: u32,
    hitbox_floor_count: u32,
    instance_floor_count: u32,
    extent_count: u32,
}

/// The GPU buffers an upload writes (all need `STORAGE_BUFFER` usage; any
/// memory location, `GpuOnly` included).
#[derive(Clone, Copy, Debug)]
pub struct UploadTargets<'a> {
    /// The GPU's instance arrays, one entry of each per slot.
    pub instances: InstanceBuffers<'a>,
    /// The GPU's [`HitboxRecord`]s.
    pub hitboxes: &'a Buffer,
    /// The GPU's per-slot decayed hit rates (one `u32` per slot, at least
    /// as many as the instance arrays hold).
    pub instance_rates: &'a Buffer,
}

/// A descriptor set bound to one [`UploadTargets`], with its own host-visible
/// staging buffers (sized for every slot and hitbox, so any [`Uploads`]
/// fits). [`RecordUploader::record`] writes the staging on the host while
/// recording: use one `UploadBindings` per frame in flight, and keep it (and
/// the targets) alive until the uploads recorded with it have executed.
#[derive(Debug)]
pub struct UploadBindings {
    set: StorageSet,
    records: Buffer,
    slots: Buffer,
    state_overrides: Buffer,
    hitbox_overrides: Buffer,
    hitbox_floors: Buffer,
    instance_floors: Buffer,
    extents: Buffer,
    slot_capacity: u32,
    hitbox_capacity: u32,
}

impl UploadBindings {
    /// Instance slots the target instance buffer holds.
    pub fn slot_capacity(&self) -> u32 {
        self.slot_capacity
    }
    /// Hitboxes the target hitbox buffer holds.
    pub fn hitbox_capacity(&self) -> u32 {
        self.hitbox_capacity
    }
    /// Device memory of the staging buffers, in bytes.
    pub fn staging_bytes(&self) -> u64 {
        self.records.size()
            + self.slots.size()
            + self.state_overrides.size()
            + self.hitbox_overrides.size()
            + self.hitbox_floors.size()
            + self.instance_floors.size()
            + self.extents.size()
    }
}

/// What one [`RecordUploader::record`] staged (after removing duplicates).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UploadStats {
    /// Records scattered (distinct slots of the ranges).
    pub records: u32,
    /// State overrides applied (distinct slots, inside the buffer).
    pub state_overrides: u32,
    /// Hitbox overrides applied (distinct hitboxes, inside the buffer).
    pub hitbox_overrides: u32,
    /// Rate floors applied, hitboxes' and instances' (distinct indices and
    /// slots, inside the buffers).
    pub rate_floors: u32,
    /// Hitbox extents written (distinct indices, inside the buffer).
    pub extents: u32,
}

/// The GPU version of [`lipac_core::culling::apply_uploads`]
/// (`upload_records.comp`): scatters CPU-written record ranges into the GPU
/// instance buffer without overwriting its state bits, then applies state
/// and hitbox active overrides. The result equals `apply_uploads` bit for
/// bit when the GPU instance buffer holds `records.len()` records.
///
/// Two passes, in one recording ([`RecordUploader::record`]):
///
/// 1. every record of `uploads.records` (clamped to `records.len()`) is
///    copied word for word, except that the two state bits of `packed` stay
///    those of the GPU copy; every hitbox override sets the active bit and
///    zeroes the streak, keeping the hit count and heights; every rate
///    floor raises a hitbox's or a slot's rate to at least its value; every
///    hitbox extent replaces that record's `min_y`, `max_y` and `cost`;
/// 2. every state override replaces the two state bits.
///
/// Duplicates are removed on the host (overrides: the last one wins, as in
/// the CPU's sequential loop; floors: the largest), so no two threads
/// write the same word.
/// Overrides past the buffers are ignored, as on the CPU.
///
/// See also `docs/VULKAN.md`.
#[derive(Debug)]
pub struct RecordUploader {
    kernels: ComputeKernels,
}

impl RecordUploader {
    /// Creates the pipeline.
    ///
    /// # Errors
    ///
    /// [`VkError::Vulkan`] when creation fails.
    pub fn new(ctx: &DeviceContext) -> Result<Self> {
        let kernels = ComputeKernels::new(
            ctx,
            BINDINGS,
            std::mem::size_of::<UploadPush>() as u32,
            &[UPLOAD_RECORDS_SPV],
        )?;
        Ok(Self { kernels })
    }

    /// Creates the staging buffers and a descriptor set for `targets`.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingUsage`] without `STORAGE_BUFFER`,
    /// [`VkError::InvalidArgument`] when a buffer holds no record or more
    /// than 2^24, or fewer rates than instance slots,
    /// [`VkError::WrongContext`], [`VkError::Vulkan`],
    /// [`VkError::NoMemoryType`].
    pub fn bind(&self, targets: &UploadTargets<'_>) -> Result<UploadBindings> {
        let ctx = self.kernels.context();
        let i = &targets.instances;
        for b in [
            i.hot,
            i.tlas,
            i.bounds,
            targets.hitboxes,
            targets.instance_rates,
        ] {
            same_context(ctx, b.context())?;
        }
        let slots = u64::from(i.slot_capacity()?);
        let hitboxes = targets.hitboxes.size() / std::mem::size_of::<HitboxRecord>() as u64;
        if slots == 0 || hitboxes == 0 {
            return Err(VkError::InvalidArgument(format!(
                "upload targets hold {slots} instance slots and {hitboxes} hitbox records"
            )));
        }
        if hitboxes > u64::from(lipac_core::layout::MAX_SLOTS) {
            return Err(VkError::InvalidArgument(format!(
                "{hitboxes} hitboxes exceed 2^24"
            )));
        }
        let rates = targets.instance_rates.size() / 4;
        if rates < slots {
            return Err(VkError::InvalidArgument(format!(
                "{rates} instance rates for {slots} instance slots"
            )));
        }
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let staging = |bytes: u64| Buffer::new(ctx, bytes, storage, MemoryLocation::CpuToGpu);
        let records = staging(slots * RECORD_BYTES)?;
        let slot_list = staging(slots * 4)?;
        let state_overrides = staging(slots * 8)?;
        let hitbox_overrides = staging(hitboxes * 8)?;
        let hitbox_floors = staging(hitboxes * 8)?;
        let instance_floors = staging(slots * 8)?;
        let extents = staging(hitboxes * 16)?;
        let set = self.kernels.bind(
            &[
                i.hot,
                targets.hitboxes,
                &records,
                &slot_list,
                &state_overrides,
                &hitbox_overrides,
                i.tlas,
                targets.instance_rates,
                &hitbox_floors,
                &instance_floors,
                i.bounds,
                &extents,
            ],
            "STORAGE_BUFFER on an upload target",
        )?;
        Ok(UploadBindings {
            set,
            records,
            slots: slot_list,
            state_overrides,
            hitbox_overrides,
            hitbox_floors,
            instance_floors,
            extents,
            slot_capacity: slots as u32,
            hitbox_capacity: hitboxes as u32,
        })
    }

    /// Stages `uploads` (the CPU's `records` of its ranges and its
    /// overrides) into `bindings`' staging buffers and records the two passes
    /// with barriers: one before (every earlier command's reads and writes of
    /// the targets, e.g. Algorithm 2's state writes, finish first), one
    /// between, one after (the records visible to every later command and
    /// the host). Records nothing but the barriers for empty uploads.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] when a range (clamped to `records.len()`)
    /// reaches past the target instance buffer; [`VkError::WrongContext`].
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        bindings: &mut UploadBindings,
        uploads: &Uploads,
        records: &InstanceArrays,
    ) -> Result<UploadStats> {
        same_context(rec.context(), self.kernels.context())?;
        let (slots, staged) = stage_records(uploads, records, bindings.slot_capacity)?;
        let states = last_wins(
            uploads
                .state_overrides
                .iter()
                .map(|&(slot, state)| [slot, state as u32]),
            bindings.slot_capacity,
        );
        let hitboxes = last_wins(
            uploads
                .hitbox_overrides
                .iter()
                .map(|&(index, active)| [index, u32::from(active)]),
            bindings.hitbox_capacity,
        );
        if !slots.is_empty() {
            bindings.slots.write(0, &slots)?;
            bindings.records.write(0, &staged)?;
        }
        if !states.is_empty() {
            bindings.state_overrides.write(0, &states)?;
        }
        if !hitboxes.is_empty() {
            bindings.hitbox_overrides.write(0, &hitboxes)?;
        }
        let hitbox_floors = max_wins(&uploads.hitbox_rate_floors, bindings.hitbox_capacity);
        let instance_floors = max_wins(&uploads.instance_rate_floors, bindings.slot_capacity);
        if !hitbox_floors.is_empty() {
            bindings.hitbox_floors.write(0, &hitbox_floors)?;
        }
        if !instance_floors.is_empty() {
            bindings.instance_floors.write(0, &instance_floors)?;
        }
        let extents = extent_words(&uploads.hitbox_extents, bindings.hitbox_capacity);
        if !extents.is_empty() {
            bindings.extents.write(0, &extents)?;
        }
        let mut push = UploadPush {
            pass: 0,
            record_count: slots.len() as u32,
            state_count: states.len() as u32,
            hitbox_count: hitboxes.len() as u32,
            slot_capacity: bindings.slot_capacity,
            hitbox_capacity: bindings.hitbox_capacity,
            hitbox_floor_count: hitbox_floors.len() as u32,
            instance_floor_count: instance_floors.len() as u32,
            extent_count: extents.len() as u32,
        };
        rec.memory_barrier(
            vk::PipelineStageFlags2::ALL_COMMANDS,
            vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE,
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::SHADER_STORAGE_READ | vk::AccessFlags2::SHADER_STORAGE_WRITE,
        );
        let set = &bindings.set;
        self.kernels.dispatch(
            rec,
            set,
            0,
            bytemuck::bytes_of(&push),
            push.record_count
                + push.hitbox_count
                + push.hitbox_floor_count
                + push.instance_floor_count
                + push.extent_count,
        )?;
        compute_to_compute(rec, false);
        push.pass = 1;
        self.kernels
            .dispatch(rec, set, 0, bytemuck::bytes_of(&push), push.state_count)?;
        compute_to_everything(rec);
        Ok(UploadStats {
            records: push.record_count,
            state_overrides: push.state_count,
            hitbox_overrides: push.hitbox_count,
            rate_floors: push.hitbox_floor_count + push.instance_floor_count,
            extents: push.extent_count,
        })
    }
}

/// The distinct slots of `uploads.records` (clamped to `records.len()`, as
/// `apply_uploads` does), ascending, and their records.
fn stage_records(
    uploads: &Uploads,
    records: &InstanceArrays,
    capacity: u32,
) -> Result<(Vec<u32>, Vec<InstanceRecord>)> {
    let len = u32::try_from(records.len()).unwrap_or(u32::MAX);
    let mut slots: Vec<u32> = Vec::new();
    let mut sorted = true;
    for range in &uploads.records {
        let hi = range.end.min(len);
        let lo = range.start.min(hi);
        if lo < hi && hi > capacity {
            return Err(VkError::InvalidArgument(format!(
                "upload range {lo}..{hi} reaches past the {capacity} GPU instance records"
            )));
        }
        sorted &= slots.last().is_none_or(|&l| l < lo);
        slots.extend(lo..hi);
    }
    if !sorted {
        slots.sort_unstable();
        slots.dedup();
    }
    // Every staged slot is below `records.len()` (clamped above).
    let staged = slots
        .iter()
        .filter_map(|&s| records.get(s as usize))
        .collect();
    Ok((slots, staged))
}

/// The staged words of hitbox extents, `[index, min_y bits, max_y bits,
/// cost]`, indices below `capacity`, one per index (the last one given, as
/// `apply_uploads`' loop leaves it), by ascending index.
fn extent_words(extents: &[(u32, HitboxExtent)], capacity: u32) -> Vec<[u32; 4]> {
    let words = extents.iter().map(|(i, e)| (*i, e.to_words()));
    one_per_key(words, capacity, |_, new| new)
        .into_iter()
        .map(|(i, [lo, hi, cost])| [i, lo, hi, cost])
        .collect()
}

/// `(key, value)` pairs with keys below `capacity`, one per key (the last
/// one given, as a sequential loop would leave it), by ascending key.
fn last_wins(pairs: impl Iterator<Item = [u32; 2]>, capacity: u32) -> Vec<[u32; 2]> {
    let pairs = pairs.map(|[k, v]| (k, v));
    one_per_key(pairs, capacity, |_, new| new)
        .into_iter()
        .map(|(k, v)| [k, v])
        .collect()
}

/// `(key, floor)` pairs with keys below `capacity`, one per key (the
/// largest floor: applying them one by one as `max` gives the same), by
/// ascending key.
fn max_wins(pairs: &[(u32, u32)], capacity: u32) -> Vec<[u32; 2]> {
    one_per_key(pairs.iter().copied(), capacity, u32::max)
        .into_iter()
        .map(|(k, v)| [k, v])
        .collect()
}

/// `(key, value)` pairs with keys below `capacity`, by ascending key, the
/// values of equal keys folded in the order given: `merge(earlier, later)`.
fn one_per_key<V: Copy>(
    pairs: impl Iterator<Item = (u32, V)>,
    capacity: u32,
    merge: impl Fn(V, V) -> V,
) -> Vec<(u32, V)> {
    let mut v: Vec<(u32, V)> = pairs.filter(|p| p.0 < capacity).collect();
    v.sort_by_key(|p| p.0); // stable: equal keys keep their order
    let mut out: Vec<(u32, V)> = Vec::with_capacity(v.len());
    for (k, value) in v {
        match out.last_mut() {
            Some(last) if last.0 == k => last.1 = merge(last.1, value),
            _ => out.push((k, value)),
        }
    }
    out
}

#[cfg(test)]
mod tests;
