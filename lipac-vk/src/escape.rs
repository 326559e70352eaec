//! The escape fraction's sums on the GPU ([`EscapeSums`],
//! `escape_sums.comp`): per frame, after the trace and before Algorithm 2,
//! the counting-box hits and the traced hits that
//! [`lipac_core::manager::Manager::process_feedback`] samples on the CPU
//! ([`lipac_core::controller::EscapeSample`]), summed into four words (two
//! 64-bit sums) that travel back with the frame's commands
//! ([`crate::FrameReadback::escape`]) and reach the manager through
//! [`lipac_core::manager::Manager::observe_escape`]
//! ([`crate::Polled::deliver`]).
//!
//! The sums are those of the CPU exactly: box hits are every hitbox's
//! (saturated 24-bit) count plus the hits of live omitted instances, traced
//! hits those of the other live instances; integer adds, so the order of
//! the GPU's threads does not matter.

use crate::commands::Recorder;
use crate::compute::{ComputeKernels, StorageSet};
use crate::context::DeviceContext;
use crate::error::{Result, VkError};
use crate::memory::Buffer;
use crate::shaders::ESCAPE_SUMS_SPV;
use ash::vk;
use bytemuck::{Pod, Zeroable};
use lipac_core::controller::EscapeSample;

/// Bytes of the sums: `[box low, box high, traced low, traced high]`.
pub(crate) const SUMS_BYTES: u64 = 16;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct EscapePush {
    instance_count: u32,
    hitbox_count: u32,
}

/// The sums' pipeline.
#[derive(Debug)]
pub(crate) struct EscapeSums {
    kernels: ComputeKernels,
}

/// A descriptor set over one frame's instance records, hit counters,
/// hitbox records and the 16-byte sums buffer.
#[derive(Debug)]
pub(crate) struct EscapeBindings {
    set: StorageSet,
    slots: u32,
    hitboxes: u32,
}

/// The sample the four words read back hold.
pub(crate) fn sample_of(words: [u32; 4]) -> EscapeSample {
    let boxes = u64::from(words[0]) | u64::from(words[1]) << 32;
    let traced = u64::from(words[2]) | u64::from(words[3]) << 32;
    EscapeSample {
        box_hits: boxes,
        total_hits: boxes.saturating_add(traced),
    }
}

impl EscapeSums {
    /// Creates the pipeline.
    pub(crate) fn new(ctx: &DeviceContext) -> Result<Self> {
        let kernels = ComputeKernels::new(
            ctx,
            4,
            std::mem::size_of::<EscapePush>() as u32,
            &[ESCAPE_SUMS_SPV],
        )?;
        Ok(Self { kernels })
    }

    /// Binds the buffers (all `STORAGE_BUFFER`; `sums` at least 16 bytes).
    pub(crate) fn bind(
        &self,
        instance_hot: &Buffer,
        instance_hits: &Buffer,
        hitboxes: &Buffer,
        sums: &Buffer,
    ) -> Result<EscapeBindings> {
        if sums.size() < SUMS_BYTES {
            return Err(VkError::InvalidArgument(format!(
                "escape sums buffer of {} bytes",
                sums.size()
            )));
        }
        let record = std::mem::size_of::<lipac_core::layout::InstanceHot>() as u64;
        let hitbox = std::mem::size_of::<lipac_core::layout::HitboxRecord>() as u64;
        let slots = (instance_hot.size() / record).min(instance_hits.size() / 4);
        let set = self.kernels.bind(
            &[instance_hot, instance_hits, hitboxes, sums],
            "STORAGE_BUFFER on an escape-sums buffer",
        )?;
        Ok(EscapeBindings {
            set,
            slots: u32::try_from(slots).unwrap_or(u32::MAX),
            hitboxes: u32::try_from(hitboxes.size() / hitbox).unwrap_or(u32::MAX),
        })
    }

    /// Records the zeroing of `sums` (the buffer bound as `bindings`' sums)
    /// and the pass over the first `slots` slots and `hitboxes` hitboxes,
    /// with barriers: the trace's writes before, the sums visible to
    /// transfers (the read-back copy) after.
    pub(crate) fn record(
        &self,
        rec: &mut Recorder<'_>,
        bindings: &EscapeBindings,
        sums: &Buffer,
        slots: u32,
        hitboxes: u32,
    ) -> Result<()> {
        if slots > bindings.slots || hitboxes > bindings.hitboxes {
            return Err(VkError::InvalidArgument(format!(
                "escape sums over {slots} slots and {hitboxes} hitboxes; bound {} and {}",
                bindings.slots, bindings.hitboxes
            )));
        }
        crate::compute::record_zero(rec, sums.raw(), 0, SUMS_BYTES);
        rec.memory_barrier(
            vk::PipelineStageFlags2::ALL_COMMANDS,
            vk::AccessFlags2::MEMORY_WRITE,
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::SHADER_STORAGE_READ | vk::AccessFlags2::SHADER_STORAGE_WRITE,
        );
        let push = EscapePush {
            instance_count: slots,
            hitbox_count: hitboxes,
        };
        self.kernels.dispatch(
            rec,
            &bindings.set,
            0,
            bytemuck::bytes_of(&push),
            slots.saturating_add(hitboxes),
        )?;
        rec.memory_barrier(
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::SHADER_STORAGE_WRITE,
            vk::PipelineStageFlags2::TRANSFER,
            vk::AccessFlags2::TRANSFER_READ,
        );
        Ok(())
    }
}

#[cfg(test)]
mod tests;
