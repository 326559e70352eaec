//! GPU Algorithm 2 (hit feedback): [`FeedbackPipeline`] records the three
//! compute passes that turn this frame's hit counts into hitbox and instance
//! transitions and commands, matching
//! [`lipac_core::feedback::process_feedback`].
//!
//! Passes, in one recording ([`FeedbackPipeline::record`]):
//!
//! 1. zero the command counter; `feedback_accumulate.comp` (lines 1–6): each
//!    live active/omitted instance's hits are added to its hitbox,
//!    saturating at 2^24 − 1 (an `atomicCompSwap` loop);
//! 2. `feedback_hitboxes.comp` (lines 7–13): hitbox activation/deactivation
//!    with the streak rules, or the decayed rate under
//!    [`DecisionRule::Decayed`] (also lines 29–37 then decide on the
//!    per-slot rates of [`FeedbackBuffers::instance_rates`]);
//! 3. `feedback_instances.comp` (lines 14–38): instance transitions; a
//!    transition that emits a command reserves a slot with `atomicAdd` on
//!    the counter and takes effect only if the slot is below the capacity
//!    (the overflow rule).
//!
//! The counter counts every request, so `counter > capacity` tells the host
//! that commands were left out; those instances kept their state and ask
//! again next frame. Which requests got a slot depends on GPU thread order,
//! so under overflow the stored commands are a subset of the CPU's, not
//! necessarily the same subset.

use crate::commands::Recorder;
use crate::compute::{
    compute_to_compute, compute_to_everything, record_zero, ComputeKernels, StorageSet,
};
use crate::context::DeviceContext;
use crate::error::{Result, VkError};
use crate::memory::Buffer;
use crate::shaders::{FEEDBACK_ACCUMULATE_SPV, FEEDBACK_HITBOXES_SPV, FEEDBACK_INSTANCES_SPV};
use ash::vk;
use bytemuck::{Pod, Zeroable};
use lipac_core::layout::{HitboxRecord, InstanceHot, MAX_SLOTS};
use lipac_core::thresholds::{DecayedRule, DecisionRule, Thresholds};

const ACCUMULATE: usize = 0;
const HITBOXES: usize = 1;
const INSTANCES: usize = 2;
const BINDINGS: u32 = 6;

/// Push constants of the feedback passes (`lipac_feedback.glsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct FeedbackPush {
    theta_a: u32,
    theta_d: u32,
    sigma_a: u32,
    sigma_o: u32,
    n_a: u32,
    n_d: u32,
    instance_count: u32,
    hitbox_count: u32,
    command_capacity: u32,
    rule: u32,
    decay_shift: u32,
    rate_activate: u32,
    rate_deactivate: u32,
    rate_instance_activate: u32,
    rate_instance_omit: u32,
    rate_per_shared: u32,
    rate_per_unique: u32,
    decay_rise_shift: u32,
}

/// Buffers Algorithm 2 reads and writes (all need `STORAGE_BUFFER` usage).
#[derive(Clone, Copy, Debug)]
pub struct FeedbackBuffers<'a> {
    /// The hot instance array: [`InstanceHot`]s, one per slot (state bits
    /// updated). Algorithm 2 reads nothing else of an instance
    /// (`docs/HOT_COLD.md`).
    pub instance_hot: &'a Buffer,
    /// `u32` hit counters, one per slot (read; see
    /// [`FeedbackPipeline::record_clear_instance_hits`]; also needs
    /// `TRANSFER_DST` for that).
    pub instance_hits: &'a Buffer,
    /// [`HitboxRecord`]s (hits accumulated, state and streak updated).
    pub hitboxes: &'a Buffer,
    /// Command words (`u32`); its size sets the capacity. Needs
    /// `TRANSFER_SRC` for a [`crate::CommandReadbackRing`] copy.
    pub commands: &'a Buffer,
    /// One `u32`: commands requested this frame. Needs `TRANSFER_DST` (zeroed
    /// first) and `TRANSFER_SRC` for the readback copy.
    pub command_counter: &'a Buffer,
    /// `u32` decayed hit rates (16.16), one per slot, kept across frames
    /// (zero them once at creation): the decayed rule's per-instance state
    /// ([`lipac_core::feedback::process_feedback_with_rates`]); untouched
    /// under the paper's rule.
    pub instance_rates: &'a Buffer,
}

/// A descriptor set bound to one [`FeedbackBuffers`]; keep it and the
/// buffers alive until recordings using it have executed.
#[derive(Debug)]
pub struct FeedbackBindings {
    set: StorageSet,
    slots: u32,
    hitboxes: u32,
    capacity: u32,
    instance_hits: vk::Buffer,
    instance_hits_clearable: bool,
    counter: vk::Buffer,
}

impl FeedbackBindings {
    /// Instance slots the instance and hit buffers hold.
    pub fn slot_capacity(&self) -> u32 {
        self.slots
    }
    /// Hitboxes processed (the hitbox buffer's record count).
    pub fn hitbox_count(&self) -> u32 {
        self.hitboxes
    }
    /// Commands the command buffer holds.
    pub fn command_capacity(&self) -> u32 {
        self.capacity
    }
}

/// GPU Algorithm 2 (hit feedback): [`FeedbackPipeline`] records the three
/// compute passes that turn this frame's hit counts into hitbox and instance
/// transitions and commands, matching
/// [`lipac_core::feedback::process_feedback`].
///
/// Passes, in one recording ([`FeedbackPipeline::record`]):
///
/// 1. zero the command counter; `feedback_accumulate.comp` (lines 1–6): each
///    live active/omitted instance's hits are added to its hitbox,
///    saturating at 2^24 − 1 (an `atomicCompSwap` loop);
/// 2. `feedback_hitboxes.comp` (lines 7–13): hitbox activation/deactivation
///    with the streak rules;
/// 3. `feedback_instances.comp` (lines 14–38): instance transitions; a
///    transition that emits a command reserves a slot with `atomicAdd` on
///    the counter and takes effect only if the slot is below the capacity
///    (the overflow rule).
///
/// The counter counts every request, so `counter > capacity` tells the host
/// that commands were left out; those instances kept their state and ask
/// again next frame. Which requests got a slot depends on GPU thread order,
/// so under overflow the stored commands are a subset of the CPU's, not
/// necessarily the same subset.
///
/// See also `docs/VULKAN.md`.
#[derive(Debug)]
pub struct FeedbackPipeline {
    kernels: ComputeKernels,
}

impl FeedbackPipeline {
    /// Creates the pipelines.
    ///
    /// # Errors
    ///
    /// [`VkError::Vulkan`] when creation fails.
    pub fn new(ctx: &DeviceContext) -> Result<Self> {
        let kernels = ComputeKernels::new(
            ctx,
            BINDINGS,
            std::mem::size_of::<FeedbackPush>() as u32,
            &[
                FEEDBACK_ACCUMULATE_SPV,
                FEEDBACK_HITBOXES_SPV,
                FEEDBACK_INSTANCES_SPV,
            ],
        )?;
        Ok(Self { kernels })
    }

    /// Creates a descriptor set for `buffers`.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingUsage`] (`STORAGE_BUFFER` on all, `TRANSFER_DST` on
    /// the counter), [`VkError::InvalidArgument`] when the hit buffer holds
    /// fewer counters than the instance buffer has slots, a buffer holds more
    /// than 2^24 records or the counter is smaller than 4 bytes,
    /// [`VkError::WrongContext`], [`VkError::Vulkan`].
    pub fn bind(&self, buffers: &FeedbackBuffers<'_>) -> Result<FeedbackBindings> {
        if !buffers
            .command_counter
            .usage()
            .contains(vk::BufferUsageFlags::TRANSFER_DST)
        {
            return Err(VkError::MissingUsage("TRANSFER_DST on the command counter"));
        }
        let slots = buffers.instance_hot.size() / std::mem::size_of::<InstanceHot>() as u64;
        let hits = buffers.instance_hits.size() / 4;
        let hitboxes = buffers.hitboxes.size() / std::mem::size_of::<HitboxRecord>() as u64;
        if slots > u64::from(MAX_SLOTS) || hitboxes > u64::from(MAX_SLOTS) {
            return Err(VkError::InvalidArgument(format!(
                "{slots} slots / {hitboxes} hitboxes exceed 2^24"
            )));
        }
        if hits < slots {
            return Err(VkError::InvalidArgument(format!(
                "{hits} hit counters for {slots} instance slots"
            )));
        }
        let rates = buffers.instance_rates.size() / 4;
        if rates < slots {
            return Err(VkError::InvalidArgument(format!(
                "{rates} instance rates for {slots} instance slots"
            )));
        }
        if buffers.command_counter.size() < 4 {
            return Err(VkError::InvalidArgument(
                "command counter smaller than 4 bytes".into(),
            ));
        }
        let capacity = u32::try_from(buffers.commands.size() / 4).unwrap_or(u32::MAX);
        let set = self.kernels.bind(
            &[
                buffers.instance_hot,
                buffers.instance_hits,
                buffers.hitboxes,
                buffers.commands,
                buffers.command_counter,
                buffers.instance_rates,
            ],
            "STORAGE_BUFFER on a feedback buffer",
        )?;
        Ok(FeedbackBindings {
            set,
            slots: slots as u32,
            hitboxes: hitboxes as u32,
            capacity,
            instance_hits: buffers.instance_hits.raw(),
            instance_hits_clearable: buffers
                .instance_hits
                .usage()
                .contains(vk::BufferUsageFlags::TRANSFER_DST),
            counter: buffers.command_counter.raw(),
        })
    }

    /// Records Algorithm 2 over the first `slot_count` slots and all
    /// hitboxes, with barriers: one before (the trace's counter writes, in
    /// any stage, and an earlier readback copy of the commands, finish
    /// first), one between passes, one after (instance/hitbox records,
    /// commands and counter visible to every later command, the readback
    /// copy included, and to the host).
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] when the thresholds fail
    /// [`Thresholds::validate`] or `slot_count` exceeds the buffers;
    /// [`VkError::WrongContext`].
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        bindings: &FeedbackBindings,
        thresholds: &Thresholds,
        slot_count: u32,
    ) -> Result<()> {
        thresholds
            .validate()
            .map_err(|e| VkError::InvalidArgument(format!("thresholds: {e}")))?;
        if slot_count > bindings.slots {
            return Err(VkError::InvalidArgument(format!(
                "{slot_count} slots but the instance buffer holds {}",
                bindings.slots
            )));
        }
        crate::accel::same_context(rec.context(), self.kernels.context())?;
        let decayed = match thresholds.rule {
            DecisionRule::Paper => None,
            DecisionRule::Decayed(r) => Some(r),
        };
        let d = decayed.unwrap_or(DecayedRule {
            shift: 0,
            rise_shift: 0,
            activate: 0,
            deactivate: 0,
            instance_activate: 0,
            instance_omit: 0,
            per_shared: 0,
            per_unique: 0,
        });
        let push = FeedbackPush {
            theta_a: thresholds.theta_a,
            theta_d: thresholds.theta_d,
            sigma_a: thresholds.sigma_a,
            sigma_o: thresholds.sigma_o,
            n_a: thresholds.n_a,
            n_d: thresholds.n_d,
            instance_count: slot_count,
            hitbox_count: bindings.hitboxes,
            command_capacity: bindings.capacity,
            rule: u32::from(decayed.is_some()),
            decay_shift: d.shift,
            rate_activate: d.activate,
            rate_deactivate: d.deactivate,
            rate_instance_activate: d.instance_activate,
            rate_instance_omit: d.instance_omit,
            rate_per_shared: d.per_shared,
            rate_per_unique: d.per_unique,
            decay_rise_shift: d.rise_shift,
        };
        let push = bytemuck::bytes_of(&push);
        rec.memory_barrier(
            vk::PipelineStageFlags2::ALL_COMMANDS,
            vk::AccessFlags2::MEMORY_WRITE,
            vk::PipelineStageFlags2::TRANSFER | vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::TRANSFER_WRITE
                | vk::AccessFlags2::SHADER_STORAGE_READ
                | vk::AccessFlags2::SHADER_STORAGE_WRITE,
        );
        record_zero(rec, bindings.counter, 0, 4);
        let set = &bindings.set;
        self.kernels
            .dispatch(rec, set, ACCUMULATE, push, slot_count)?;
        compute_to_compute(rec, true);
        self.kernels
            .dispatch(rec, set, HITBOXES, push, bindings.hitboxes)?;
        compute_to_compute(rec, false);
        self.kernels
            .dispatch(rec, set, INSTANCES, push, slot_count)?;
        compute_to_everything(rec);
        Ok(())
    }

    /// Records zeroing the per-instance hit counters (before this frame's
    /// trace; lipac-core leaves that to the backend) and a barrier making the
    /// zeros visible to every later command.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingUsage`] when the hit buffer lacks `TRANSFER_DST`.
    pub fn record_clear_instance_hits(
        &self,
        rec: &mut Recorder<'_>,
        bindings: &FeedbackBindings,
    ) -> Result<()> {
        if !bindings.instance_hits_clearable {
            return Err(VkError::MissingUsage("TRANSFER_DST on the instance hits"));
        }
        crate::accel::same_context(rec.context(), self.kernels.context())?;
        rec.memory_barrier(
            vk::PipelineStageFlags2::ALL_COMMANDS,
            vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE,
            vk::PipelineStageFlags2::TRANSFER,
            vk::AccessFlags2::TRANSFER_WRITE,
        );
        record_zero(rec, bindings.instance_hits, 0, vk::WHOLE_SIZE);
        rec.memory_barrier(
            vk::PipelineStageFlags2::TRANSFER,
            vk::AccessFlags2::TRANSFER_WRITE,
            vk::PipelineStageFlags2::ALL_COMMANDS,
            vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE,
        );
        Ok(())
    }
}
