//! GPU Algorithm 1 (TLAS assembly): [`AssemblyPipeline`] records the three
//! compute passes that turn the instance and hitbox records into this frame's
//! TLAS instance buffer, matching [`lipac_core::assembly::assemble_tlas`]
//! record for record (as a multiset: the GPU appends in arbitrary order).
//!
//! Passes, in one recording ([`AssemblyPipeline::record`]):
//!
//! 1. zero the TLAS instance buffer and its counter (`vkCmdFillBuffer`);
//!    `hitbox_reset.comp` = [`lipac_core::assembly::begin_frame`];
//! 2. `assemble_instances.comp`: one thread per slot (active → its own TLAS
//!    record, copied; omitted → counting box over its bounds; inactive →
//!    nothing), reading every slot's hot record and the TLAS record or the
//!    bounds only of a slot that emits one ([`InstanceBuffers`]);
//! 3. `assemble_hitboxes.comp`: one thread per hitbox (a counting box for
//!    each inactive hitbox with a non-empty extent; the extents, heights and
//!    cost words, are the CPU's, [`lipac_core::hitbox_extents`], uploaded by
//!    [`crate::RecordUploader`]);
//! 4. with adaptive hitboxes ([`AssemblyPipeline::record_adaptive`],
//!    [`lipac_core::hitbox_tree`]) in place of pass 3:
//!    `assemble_merged.comp` (one thread per hitbox) emits the boxes, merged
//!    over cold quadtree nodes, matching
//!    [`lipac_core::assembly::assemble_tlas_adaptive`].
//!
//! Records past the counter stay zero, i.e. inactive (reference 0), so the
//! TLAS can be built over a fixed count (e.g. [`AssemblyBindings::tlas_capacity`])
//! without reading the counter back.

use crate::commands::Recorder;
use crate::compute::{
    compute_to_compute, compute_to_everything, record_zero, ComputeKernels, StorageSet,
};
use crate::context::DeviceContext;
use crate::error::{Result, VkError};
use crate::memory::Buffer;
use crate::shaders::{
    ASSEMBLE_HITBOXES_SPV, ASSEMBLE_INSTANCES_SPV, ASSEMBLE_MERGED_SPV, HITBOX_RESET_SPV,
};
use ash::vk;
use bytemuck::{Pod, Zeroable};
use lipac_core::assembly::AssemblyConfig;
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::hitbox_tree::HitboxTree;
use lipac_core::layout::{
    HitboxRecord, InstanceBounds, InstanceHot, InstanceTlas, TlasInstance, MAX_SLOTS,
};

const RESET: usize = 0;
const INSTANCES: usize = 1;
const HITBOXES: usize = 2;
const MERGED: usize = 3;
const BINDINGS: u32 = 7;

/// Push constants of the assembly passes (`lipac_assembly.glsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct AssemblyPush {
    unit_cube: [u32; 2],
    counting_mask: u32,
    omitted_sbt: u32,
    hitbox_sbt: u32,
    min_extent: f32,
    instance_count: u32,
    hitbox_count: u32,
    tlas_capacity: u32,
    adaptive_levels: u32,
    grid_nx: u32,
    grid_nz: u32,
    merged_sbt: u32,
}

/// One hitbox's cell in x/z as the GPU reads it: `[lo.x, lo.z, hi.x, hi.z]`
/// (16 bytes per hitbox). A hitbox the index has no bounds for is all NaN,
/// and then gets no box (as on the CPU).
pub type HitboxBounds = [f32; 4];

/// The x/z bounds of every hitbox of `index`, for the assembly's bounds
/// buffer (upload once; it changes only with the index).
///
/// ```
/// use glam::{Vec2, Vec3};
/// use lipac_core::hitbox_index::HitboxIndex;
/// struct Two;
/// impl HitboxIndex for Two {
///     fn len(&self) -> u32 { 2 }
///     fn hitbox_at(&self, _: Vec3) -> Option<u32> { None }
///     fn xz_bounds(&self, i: u32) -> Option<(Vec2, Vec2)> {
///         (i == 0).then_some((Vec2::new(1.0, 2.0), Vec2::new(3.0, 4.0)))
///     }
/// }
/// let b = lipac_vk::hitbox_bounds(&Two);
/// assert_eq!(b[0], [1.0, 2.0, 3.0, 4.0]);
/// assert!(b[1].iter().all(|v| v.is_nan()));
/// ```
pub fn hitbox_bounds(index: &impl HitboxIndex) -> Vec<HitboxBounds> {
    (0..index.len())
        .map(|i| match index.xz_bounds(i) {
            Some((lo, hi)) => [lo.x, lo.y, hi.x, hi.y],
            None => [f32::NAN; 4],
        })
        .collect()
}

/// The GPU instance buffer as three arrays indexed by slot (the hot/cold
/// split of [`lipac_core::layout::InstanceArrays`], `docs/HOT_COLD.md`), all
/// with `STORAGE_BUFFER` usage.
#[derive(Clone, Copy, Debug)]
pub struct InstanceBuffers<'a> {
    /// [`InstanceHot`]s (8 bytes per slot): read by Algorithms 1 and 2,
    /// whose state bits Algorithm 2 writes.
    pub hot: &'a Buffer,
    /// [`InstanceTlas`]s (64 bytes per slot, the slot's own TLAS record):
    /// copied by Algorithm 1 for a slot it emits as active.
    pub tlas: &'a Buffer,
    /// [`InstanceBounds`]s (28 bytes per slot): read by Algorithm 1 for an
    /// omitted slot's counting box.
    pub bounds: &'a Buffer,
}

impl InstanceBuffers<'_> {
    /// Slots all three arrays hold (the fewest of the three).
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] when they hold more than 2^24 slots.
    pub fn slot_capacity(&self) -> Result<u32> {
        let n = (self.hot.size() / std::mem::size_of::<InstanceHot>() as u64)
            .min(self.tlas.size() / std::mem::size_of::<InstanceTlas>() as u64)
            .min(self.bounds.size() / std::mem::size_of::<InstanceBounds>() as u64);
        u32::try_from(n)
            .ok()
            .filter(|&n| n <= MAX_SLOTS)
            .ok_or_else(|| {
                VkError::InvalidArgument(format!("instance arrays: {n} slots exceed 2^24"))
            })
    }
}

/// Buffers Algorithm 1 reads and writes (all need `STORAGE_BUFFER` usage).
#[derive(Clone, Copy, Debug)]
pub struct AssemblyBuffers<'a> {
    /// The instance arrays (read: every hot record, the TLAS records or
    /// bounds of emitted slots).
    pub instances: InstanceBuffers<'a>,
    /// [`HitboxRecord`]s (hits zeroed; state, rate and extent kept).
    pub hitboxes: &'a Buffer,
    /// [`HitboxBounds`], at least one per hitbox record (read).
    pub hitbox_bounds: &'a Buffer,
    /// Output [`TlasInstance`]s; also needs `TRANSFER_DST` (zeroed first)
    /// and, for the TLAS build, `ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR`.
    pub tlas_instances: &'a Buffer,
    /// One `u32`: records appended (may exceed the capacity; only the first
    /// capacity are stored). Also needs `TRANSFER_DST`.
    pub tlas_counter: &'a Buffer,
}

/// A descriptor set bound to one [`AssemblyBuffers`]; keep it and the
/// buffers alive until recordings using it have executed.
#[derive(Debug)]
pub struct AssemblyBindings {
    set: StorageSet,
    slots: u32,
    hitboxes: u32,
    tlas_capacity: u32,
    tlas_instances: vk::Buffer,
    tlas_counter: vk::Buffer,
}

impl AssemblyBindings {
    /// Instance slots the instance buffer holds.
    pub fn slot_capacity(&self) -> u32 {
        self.slots
    }
    /// Hitboxes processed (the hitbox buffer's record count).
    pub fn hitbox_count(&self) -> u32 {
        self.hitboxes
    }
    /// TLAS records the output buffer holds.
    pub fn tlas_capacity(&self) -> u32 {
        self.tlas_capacity
    }
}

/// GPU Algorithm 1 (TLAS assembly): [`AssemblyPipeline`] records the three
/// compute passes that turn the instance and hitbox records into this frame's
/// TLAS instance buffer, matching [`lipac_core::assembly::assemble_tlas`]
/// record for record (as a multiset: the GPU appends in arbitrary order).
///
/// Passes, in one recording ([`AssemblyPipeline::record`]):
///
/// 1. zero the TLAS instance buffer and its counter (`vkCmdFillBuffer`);
///    `hitbox_reset.comp` = [`lipac_core::assembly::begin_frame`];
/// 2. `assemble_instances.comp`: one thread per slot (active → its own TLAS
///    record, copied; omitted → counting box; inactive → nothing);
/// 3. `assemble_hitboxes.comp`: one thread per hitbox (a counting box for
///    each inactive hitbox with a non-empty extent, the CPU's).
///
/// Records past the counter stay zero, i.e. inactive (reference 0), so the
/// TLAS can be built over a fixed count (e.g. [`AssemblyBindings::tlas_capacity`])
/// without reading the counter back.
///
/// See also `docs/VULKAN.md`.
#[derive(Debug)]
pub struct AssemblyPipeline {
    kernels: ComputeKernels,
}

fn count_of<T>(buffer: &Buffer, what: &str) -> Result<u32> {
    let n = buffer.size() / std::mem::size_of::<T>() as u64;
    u32::try_from(n)
        .ok()
        .filter(|&n| n <= MAX_SLOTS)
        .ok_or_else(|| VkError::InvalidArgument(format!("{what}: {n} records exceed 2^24")))
}

impl AssemblyPipeline {
    /// Creates the pipelines.
    ///
    /// # Errors
    ///
    /// [`VkError::Vulkan`] when creation fails.
    pub fn new(ctx: &DeviceContext) -> Result<Self> {
        let kernels = ComputeKernels::new(
            ctx,
            BINDINGS,
            std::mem::size_of::<AssemblyPush>() as u32,
            &[
                HITBOX_RESET_SPV,
                ASSEMBLE_INSTANCES_SPV,
                ASSEMBLE_HITBOXES_SPV,
                ASSEMBLE_MERGED_SPV,
            ],
        )?;
        Ok(Self { kernels })
    }

    /// Creates a descriptor set for `buffers`.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingUsage`] (`STORAGE_BUFFER` on all, `TRANSFER_DST` on
    /// the TLAS buffer and counter), [`VkError::InvalidArgument`] when the
    /// bounds buffer holds fewer entries than there are hitbox records or a
    /// buffer holds more than 2^24 records, [`VkError::WrongContext`],
    /// [`VkError::Vulkan`].
    pub fn bind(&self, buffers: &AssemblyBuffers<'_>) -> Result<AssemblyBindings> {
        for b in [buffers.tlas_instances, buffers.tlas_counter] {
            if !b.usage().contains(vk::BufferUsageFlags::TRANSFER_DST) {
                return Err(VkError::MissingUsage(
                    "TRANSFER_DST on the TLAS instance buffer and counter",
                ));
            }
        }
        let slots = buffers.instances.slot_capacity()?;
        let hitboxes = count_of::<HitboxRecord>(buffers.hitboxes, "hitbox buffer")?;
        let bounds = buffers.hitbox_bounds.size() / std::mem::size_of::<HitboxBounds>() as u64;
        if bounds < u64::from(hitboxes) {
            return Err(VkError::InvalidArgument(format!(
                "{bounds} hitbox bounds for {hitboxes} hitbox records"
            )));
        }
        let tlas_capacity = u32::try_from(
            buffers.tlas_instances.size() / std::mem::size_of::<TlasInstance>() as u64,
        )
        .unwrap_or(u32::MAX);
        if tlas_capacity == 0 || buffers.tlas_counter.size() < 4 {
            return Err(VkError::InvalidArgument(
                "TLAS instance buffer or counter too small".into(),
            ));
        }
        let set = self.kernels.bind(
            &[
                buffers.instances.hot,
                buffers.hitboxes,
                buffers.hitbox_bounds,
                buffers.tlas_instances,
                buffers.tlas_counter,
                buffers.instances.bounds,
                buffers.instances.tlas,
            ],
            "STORAGE_BUFFER on an assembly buffer",
        )?;
        Ok(AssemblyBindings {
            set,
            slots,
            hitboxes,
            tlas_capacity,
            tlas_instances: buffers.tlas_instances.raw(),
            tlas_counter: buffers.tlas_counter.raw(),
        })
    }

    /// Records Algorithm 1 over the first `slot_count` slots and all
    /// hitboxes, with barriers: one before (earlier writes of any stage, and
    /// the previous TLAS build reading the output, finish first), one
    /// between passes, one after (results visible to every later command,
    /// the TLAS build included, and to the host).
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] when `slot_count` exceeds the instance
    /// buffer; [`VkError::WrongContext`].
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        bindings: &AssemblyBindings,
        config: &AssemblyConfig,
        slot_count: u32,
    ) -> Result<()> {
        self.record_adaptive(rec, bindings, config, None, slot_count)
    }

    /// [`Self::record`] with adaptive hitboxes: with `tree`, the hitbox
    /// boxes are merged over cold quadtree nodes as
    /// [`lipac_core::assembly::assemble_tlas_adaptive`] does
    /// (`assemble_merged.comp` in place of `assemble_hitboxes.comp`) over
    /// the first `nx · nz` hitbox records
    /// (the tree's grid; records beyond it, spare capacity, are left alone);
    /// `None` is [`Self::record`].
    ///
    /// # Errors
    ///
    /// As [`Self::record`]; [`VkError::InvalidArgument`] when the tree's
    /// grid has more cells than the hitbox buffer has records.
    pub fn record_adaptive(
        &self,
        rec: &mut Recorder<'_>,
        bindings: &AssemblyBindings,
        config: &AssemblyConfig,
        tree: Option<&HitboxTree>,
        slot_count: u32,
    ) -> Result<()> {
        let (grid_nx, grid_nz, adaptive_levels, merged_sbt) = match tree {
            Some(t) => {
                let (nx, nz) = t.leaf_dims();
                if u64::from(nx) * u64::from(nz) > u64::from(bindings.hitboxes) {
                    return Err(VkError::InvalidArgument(format!(
                        "adaptive hitbox tree over {nx} x {nz} cells but {} hitbox records",
                        bindings.hitboxes
                    )));
                }
                (
                    nx,
                    nz,
                    u32::from(t.levels()),
                    t.config().merged_box_sbt_offset,
                )
            }
            None => (1, 1, 0, 0),
        };
        // The tree's grid (at most the buffer's records, checked above).
        let hitbox_count = if tree.is_some() {
            grid_nx * grid_nz
        } else {
            bindings.hitboxes
        };
        if slot_count > bindings.slots {
            return Err(VkError::InvalidArgument(format!(
                "{slot_count} slots but the instance buffer holds {}",
                bindings.slots
            )));
        }
        crate::accel::same_context(rec.context(), self.kernels.context())?;
        // As lipac_core::assembly::axis_map sanitises it.
        let min_extent = if config.min_box_extent.is_finite() && config.min_box_extent > 0.0 {
            config.min_box_extent
        } else {
            0.0
        };
        let push = AssemblyPush {
            unit_cube: [
                config.unit_cube_blas as u32,
                (config.unit_cube_blas >> 32) as u32,
            ],
            counting_mask: u32::from(config.counting_mask),
            omitted_sbt: config.omitted_box_sbt_offset,
            hitbox_sbt: config.hitbox_sbt_offset,
            min_extent,
            instance_count: slot_count,
            hitbox_count,
            tlas_capacity: bindings.tlas_capacity,
            adaptive_levels,
            grid_nx,
            grid_nz,
            merged_sbt,
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
        record_zero(rec, bindings.tlas_instances, 0, vk::WHOLE_SIZE);
        record_zero(rec, bindings.tlas_counter, 0, 4);
        let sets = &bindings.set;
        self.kernels
            .dispatch(rec, sets, RESET, push, hitbox_count)?;
        compute_to_compute(rec, true);
        self.kernels
            .dispatch(rec, sets, INSTANCES, push, slot_count)?;
        compute_to_compute(rec, false);
        // Pass 2: leaf boxes, or with adaptive hitboxes merged boxes over
        // cold quadtree nodes (assemble_hitboxes.comp emits nothing then).
        let pass2 = if adaptive_levels > 0 {
            MERGED
        } else {
            HITBOXES
        };
        self.kernels
            .dispatch(rec, sets, pass2, push, hitbox_count)?;
        compute_to_everything(rec);
        Ok(())
    }
}
