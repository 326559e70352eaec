//! The GPU hitbox tables of [`crate::LipacVk`]: the hitbox records and the
//! per-hitbox bounds, kept in step with a manager whose hitbox index grows
//! and reuses indices ([`lipac_core::hashed_hitboxes::HashedHitboxes`]) as
//! well as with a fixed grid, in one code path.
//!
//! Per frame ([`HitboxTables::record`], before the record uploads):
//!
//! * **growth**: when [`HitboxIndex::len`] passes the capacity, both buffers
//!   are replaced by ones of at least twice the capacity. The records are
//!   copied GPU to GPU (`vkCmdCopyBuffer`), not re-uploaded from the
//!   manager's CPU copy: their state bits, streaks and decayed rates are
//!   Algorithm 2's on the GPU, newer than anything the host has (frames in
//!   flight). The bounds are re-uploaded whole from the index (the host is
//!   their only source). The old buffers are retired by timeline value,
//!   never waited for. The new records are written as
//!   [`lipac_core::layout::HitboxRecord::default`] (the empty extent; a
//!   zeroed record would be a counting box at height 0). Records past
//!   [`HitboxIndex::len`] stay so: no instance points at them.
//! * **resets**: the records of the hitboxes the index evicted at this
//!   frame's start are reset to [`lipac_core::layout::HitboxRecord::default`],
//!   as the CPU resets them (an evicted hitbox has no members, so its extent
//!   is the empty one); the manager's override clears the active bit as
//!   before.
//! * **bounds**: the bounds of the indices in the index's change log
//!   ([`HitboxIndex::bounds_changes`]) since the last frame, and of indices
//!   new since, are staged and copied in (one region per run of indices);
//!   everything when the log lost changes or the buffers grew. The grid
//!   logs nothing: its bounds are uploaded at the first frame only.

use crate::assembly::{hitbox_bounds, HitboxBounds};
use crate::commands::Recorder;
use crate::context::DeviceContext;
use crate::error::{Result, VkError};
use crate::lifetimes::Retirement;
use crate::memory::{Buffer, MemoryLocation};
use ash::vk;
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::layout::{HitboxRecord, MAX_SLOTS};

const RECORD_BYTES: u64 = std::mem::size_of::<HitboxRecord>() as u64;
const BOUNDS_BYTES: u64 = std::mem::size_of::<HitboxBounds>() as u64;

/// Usage of both tables: storage for the shaders, transfer for growth
/// copies, fills and bounds uploads.
const USAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::from_raw(
    vk::BufferUsageFlags::STORAGE_BUFFER.as_raw()
        | vk::BufferUsageFlags::TRANSFER_SRC.as_raw()
        | vk::BufferUsageFlags::TRANSFER_DST.as_raw(),
);

/// What one [`HitboxTables::record`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct HitboxFrame {
    /// Whether the buffers were replaced (bindings to them must be redone).
    pub grew: bool,
    /// Hitbox bounds written.
    pub bounds_written: u32,
    /// Evicted hitbox records reset to the default.
    pub records_reset: u32,
}

/// The hitbox records and bounds on the GPU; see the [module docs](self).
#[derive(Debug)]
pub(crate) struct HitboxTables {
    capacity: u32,
    count: u32,
    records: Buffer,
    bounds: Buffer,
    /// The index's change total the bounds are current with; `None`: every
    /// bound is written at the next frame.
    bounds_seen: Option<u64>,
    /// Indices `0..bounds_len` have had their bounds written.
    bounds_len: u32,
    /// Whether the records have been initialised (at the first frame).
    initialised: bool,
}

fn table(ctx: &DeviceContext, name: &str, bytes: u64) -> Result<Buffer> {
    Buffer::named(ctx, name, bytes.max(4), USAGE, MemoryLocation::GpuOnly)
}

fn all_to_transfer(rec: &mut Recorder<'_>) {
    rec.memory_barrier(
        vk::PipelineStageFlags2::ALL_COMMANDS,
        vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE,
        vk::PipelineStageFlags2::TRANSFER,
        vk::AccessFlags2::TRANSFER_READ | vk::AccessFlags2::TRANSFER_WRITE,
    );
}

fn transfer_to_all(rec: &mut Recorder<'_>) {
    rec.memory_barrier(
        vk::PipelineStageFlags2::TRANSFER,
        vk::AccessFlags2::TRANSFER_WRITE,
        vk::PipelineStageFlags2::ALL_COMMANDS,
        vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE,
    );
}

fn copy(rec: &mut Recorder<'_>, src: &Buffer, dst: &Buffer, regions: &[vk::BufferCopy]) {
    if regions.is_empty() {
        return;
    }
    // SAFETY: recording on this device (Recorder contract); both buffers are
    // of this device with TRANSFER_SRC / TRANSFER_DST usage, the regions lie
    // inside both, and the caller keeps both alive (retirement) until the GPU
    // has run the copy.
    unsafe {
        rec.context()
            .device()
            .cmd_copy_buffer(rec.raw(), src.raw(), dst.raw(), regions)
    };
}

/// A host-visible copy source holding `data`, for the transfers below.
fn staging<T: bytemuck::Pod>(ctx: &DeviceContext, data: &[T]) -> Result<Buffer> {
    Buffer::with_data(
        ctx,
        vk::BufferUsageFlags::TRANSFER_SRC,
        MemoryLocation::CpuToGpu,
        data,
    )
}

/// Records copies of [`HitboxRecord::default`] into the runs `(first
/// record, count)` of `records` (one staging buffer of the longest run,
/// retired after `value`). The default, not zeros: its empty extent
/// (`min_y = +inf`, `max_y = -inf`) means "no counting box", a zeroed one
/// would be a box at height 0 (the extents are the CPU's and arrive only
/// where they change, [`lipac_core::culling::Uploads::hitbox_extents`]).
fn write_defaults(
    ctx: &DeviceContext,
    rec: &mut Recorder<'_>,
    records: &Buffer,
    runs: &[(u64, u64)],
    retirement: &mut Retirement,
    value: u64,
) -> Result<()> {
    let longest = runs.iter().map(|r| r.1).max().unwrap_or(0);
    if longest == 0 {
        return Ok(());
    }
    let staging = staging(ctx, &vec![HitboxRecord::default(); longest as usize])?;
    let regions: Vec<vk::BufferCopy> = runs
        .iter()
        .filter(|r| r.1 > 0)
        .map(|&(first, count)| {
            vk::BufferCopy::default()
                .dst_offset(first * RECORD_BYTES)
                .size(count * RECORD_BYTES)
        })
        .collect();
    copy(rec, &staging, records, &regions);
    retirement.retire(value, staging);
    Ok(())
}

/// Sorted, distinct `indices` below `n` as runs `(first, count)`.
fn runs(mut indices: Vec<u32>, n: u32) -> Vec<(u32, u32)> {
    indices.retain(|&i| i < n);
    indices.sort_unstable();
    indices.dedup();
    let mut out: Vec<(u32, u32)> = Vec::new();
    for i in indices {
        match out.last_mut() {
            Some((first, count)) if *first + *count == i => *count += 1,
            _ => out.push((i, 1)),
        }
    }
    out
}

/// The bounds of hitbox `i` as [`hitbox_bounds`] writes them.
fn bounds_of(index: &impl HitboxIndex, i: u32) -> HitboxBounds {
    match index.xz_bounds(i) {
        Some((lo, hi)) => [lo.x, lo.y, hi.x, hi.y],
        None => [f32::NAN; 4],
    }
}

impl HitboxTables {
    /// Tables for `index` with room for at least `initial_capacity`
    /// hitboxes (and at least 1); contents are written at the first
    /// [`HitboxTables::record`].
    pub(crate) fn new(
        ctx: &DeviceContext,
        index: &impl HitboxIndex,
        initial_capacity: u32,
    ) -> Result<Self> {
        let count = index.len();
        if count > MAX_SLOTS || initial_capacity > MAX_SLOTS {
            return Err(VkError::InvalidArgument(format!(
                "{count} hitboxes (initial capacity {initial_capacity}): at most 2^24"
            )));
        }
        let capacity = count.max(initial_capacity).max(1);
        Ok(Self {
            capacity,
            count,
            records: table(
                ctx,
                "lipac hitbox records",
                u64::from(capacity) * RECORD_BYTES,
            )?,
            bounds: table(
                ctx,
                "lipac hitbox bounds",
                u64::from(capacity) * BOUNDS_BYTES,
            )?,
            bounds_seen: None,
            bounds_len: 0,
            initialised: false,
        })
    }

    /// Hitboxes the buffers hold.
    pub(crate) fn capacity(&self) -> u32 {
        self.capacity
    }

    /// Hitboxes of the index at the last [`HitboxTables::record`]
    /// ([`HitboxIndex::len`]).
    pub(crate) fn count(&self) -> u32 {
        self.count
    }

    /// The [`HitboxRecord`]s (`capacity` of them).
    pub(crate) fn records(&self) -> &Buffer {
        &self.records
    }

    /// The [`HitboxBounds`] (`capacity` of them).
    pub(crate) fn bounds(&self) -> &Buffer {
        &self.bounds
    }

    /// Bytes of both buffers.
    pub(crate) fn bytes(&self) -> u64 {
        self.records.size() + self.bounds.size()
    }

    /// Growth, resets of `evicted` and bounds writes for this frame of
    /// `index` (see the [module docs](self)); replaced buffers and the
    /// staging go to `retirement` until the GPU passes `value`.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for more than 2^24 hitboxes; Vulkan and
    /// allocation errors (nothing recorded is lost: the old buffers stay).
    pub(crate) fn record(
        &mut self,
        ctx: &DeviceContext,
        rec: &mut Recorder<'_>,
        index: &impl HitboxIndex,
        evicted: &[u32],
        retirement: &mut Retirement,
        value: u64,
    ) -> Result<HitboxFrame> {
        let n = index.len();
        if n > MAX_SLOTS {
            return Err(VkError::InvalidArgument(format!(
                "{n} hitboxes: at most 2^24"
            )));
        }
        let mut out = HitboxFrame::default();
        if n > self.capacity {
            let capacity = n.max(self.capacity.saturating_mul(2)).min(MAX_SLOTS);
            let records = table(
                ctx,
                "lipac hitbox records",
                u64::from(capacity) * RECORD_BYTES,
            )?;
            let bounds = table(
                ctx,
                "lipac hitbox bounds",
                u64::from(capacity) * BOUNDS_BYTES,
            )?;
            all_to_transfer(rec);
            let kept = if self.initialised {
                u64::from(self.capacity) * RECORD_BYTES
            } else {
                0
            };
            if kept > 0 {
                copy(
                    rec,
                    &self.records,
                    &records,
                    &[vk::BufferCopy::default().size(kept)],
                );
            }
            let first = kept / RECORD_BYTES;
            write_defaults(
                ctx,
                rec,
                &records,
                &[(first, u64::from(capacity) - first)],
                retirement,
                value,
            )?;
            transfer_to_all(rec);
            retirement.retire(value, std::mem::replace(&mut self.records, records));
            retirement.retire(value, std::mem::replace(&mut self.bounds, bounds));
            self.capacity = capacity;
            self.initialised = true;
            self.bounds_seen = None;
            self.bounds_len = 0;
            out.grew = true;
        }
        self.count = n;

        let resets = runs(evicted.to_vec(), n);
        let log = index.bounds_changes();
        let changed = self.bounds_seen.and_then(|seen| log.since(seen));
        let writes = match changed {
            Some(changed) => {
                let mut list = changed.to_vec();
                list.extend(self.bounds_len.min(n)..n);
                runs(list, n)
            }
            None if n > 0 => vec![(0, n)],
            None => Vec::new(),
        };
        let first_frame = !self.initialised;
        if first_frame || !resets.is_empty() || !writes.is_empty() {
            all_to_transfer(rec);
            if first_frame {
                let all = [(0, u64::from(self.capacity))];
                write_defaults(ctx, rec, &self.records, &all, retirement, value)?;
                self.initialised = true;
            } else {
                let runs: Vec<(u64, u64)> = resets
                    .iter()
                    .map(|&(first, count)| (u64::from(first), u64::from(count)))
                    .collect();
                write_defaults(ctx, rec, &self.records, &runs, retirement, value)?;
                out.records_reset += resets.iter().map(|r| r.1).sum::<u32>();
            }
            if !writes.is_empty() {
                let staged: Vec<HitboxBounds> = if changed.is_none() {
                    hitbox_bounds(index)
                } else {
                    writes
                        .iter()
                        .flat_map(|&(first, count)| first..first + count)
                        .map(|i| bounds_of(index, i))
                        .collect()
                };
                let staging = staging(ctx, &staged)?;
                let mut at = 0u64;
                let regions: Vec<vk::BufferCopy> = writes
                    .iter()
                    .map(|&(first, count)| {
                        let bytes = u64::from(count) * BOUNDS_BYTES;
                        let r = vk::BufferCopy::default()
                            .src_offset(at)
                            .dst_offset(u64::from(first) * BOUNDS_BYTES)
                            .size(bytes);
                        at += bytes;
                        r
                    })
                    .collect();
                copy(rec, &staging, &self.bounds, &regions);
                out.bounds_written = staged.len() as u32;
                retirement.retire(value, staging);
            }
            transfer_to_all(rec);
        }
        self.bounds_seen = Some(log.total);
        self.bounds_len = n;
        Ok(out)
    }
}

#[cfg(test)]
mod tests;
