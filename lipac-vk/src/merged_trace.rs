//! [`MergedTraceTestPipeline`]: `trace_merged.comp`, the reference tracer
//! for adaptive hitboxes (`lipac_core::hitbox_tree`): `trace_counting.comp`
//! whose counting include resolves merged counting boxes to their leaf
//! hitboxes' boxes (`LIPAC_SBT_MERGED_BOX` in `lipac_counting.glsl`), so that
//! a ray counts the hitbox it would count with one box per hitbox. Tests and
//! examples use it; engines define the same macros in their own shaders.

use crate::commands::Recorder;
use crate::compute::StorageSet;
use crate::context::DeviceContext;
use crate::counting::CountingBoxConfig;
use crate::error::{Result, VkError};
use crate::memory::Buffer;
use crate::merged_boxes::MergedBoxes;
use crate::ray_query::RayQueryPipeline;
use crate::ray_query_test_pipeline::{GpuHit, GpuRay};
use crate::shaders::TRACE_MERGED_SPV;
use crate::tlas::GpuTlas;
use ash::vk;
use bytemuck::{Pod, Zeroable};
use lipac_core::assembly::AssemblyConfig;
use lipac_core::hitbox_tree::HitboxTree;

const LOCAL_SIZE: u32 = 64;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct MergedPush {
    ray_count: u32,
    cull_mask: u32,
    ray_flags: u32,
    merged: MergedBoxes,
}

/// Buffers a [`MergedTraceTestPipeline`] trace reads and writes.
#[derive(Clone, Copy, Debug)]
pub struct MergedTraceBuffers<'a> {
    /// The TLAS (built, with the build barrier recorded before the trace).
    pub tlas: &'a GpuTlas,
    /// [`GpuRay`]s.
    pub rays: &'a Buffer,
    /// [`GpuHit`]s, one per ray.
    pub results: &'a Buffer,
    /// `u32` hit counters per instance slot.
    pub instance_hits: &'a Buffer,
    /// The `HitboxRecord`s Algorithm 1 left (heights, active bits); hits
    /// are counted into them.
    pub hitboxes: &'a Buffer,
    /// The hitbox bounds ([`crate::hitbox_bounds`]).
    pub hitbox_bounds: &'a Buffer,
}

/// A descriptor set bound to one [`MergedTraceBuffers`].
#[derive(Debug)]
pub struct MergedTraceBindings {
    set: StorageSet,
    max_rays: u64,
    hitboxes: u64,
}

/// The compiled `trace_merged.comp` for one [`CountingBoxConfig`].
#[derive(Debug)]
pub struct MergedTraceTestPipeline {
    pipeline: RayQueryPipeline,
}

impl MergedTraceTestPipeline {
    /// Creates the pipeline with `config` as specialization constants.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingFeature`] without ray queries
    /// ([`DeviceContext::tracing`]); [`VkError::InvalidArgument`] for an
    /// invalid config; [`VkError::Vulkan`].
    pub fn new(ctx: &DeviceContext, config: &CountingBoxConfig) -> Result<Self> {
        Ok(Self {
            pipeline: RayQueryPipeline::new(
                ctx,
                "MergedTraceTestPipeline",
                TRACE_MERGED_SPV,
                config,
                5,
                std::mem::size_of::<MergedPush>() as u32,
            )?,
        })
    }

    /// Creates a descriptor set for `buffers`.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingUsage`] when a buffer lacks `STORAGE_BUFFER`,
    /// [`VkError::WrongContext`], [`VkError::Vulkan`].
    pub fn bind(&self, buffers: &MergedTraceBuffers<'_>) -> Result<MergedTraceBindings> {
        let storage = [
            buffers.rays,
            buffers.results,
            buffers.instance_hits,
            buffers.hitboxes,
            buffers.hitbox_bounds,
        ];
        let set =
            self.pipeline
                .bind(buffers.tlas, &storage, "STORAGE_BUFFER for a trace buffer")?;
        let max_rays = (buffers.rays.size() / std::mem::size_of::<GpuRay>() as u64)
            .min(buffers.results.size() / std::mem::size_of::<GpuHit>() as u64);
        let hitboxes = (buffers.hitboxes.size()
            / std::mem::size_of::<lipac_core::layout::HitboxRecord>() as u64)
            .min(buffers.hitbox_bounds.size() / std::mem::size_of::<crate::HitboxBounds>() as u64);
        Ok(MergedTraceBindings {
            set,
            max_rays,
            hitboxes,
        })
    }

    /// Records a trace of the first `ray_count` rays (cull mask, GLSL ray
    /// flags) against a TLAS assembled with `tree` and `assembly`, then a
    /// barrier making results and counters visible to the host.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] when the buffers hold fewer rays than
    /// `ray_count` or the dispatch is too large; [`VkError::WrongContext`].
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        bindings: &MergedTraceBindings,
        tree: &HitboxTree,
        assembly: &AssemblyConfig,
        ray_count: u32,
        cull_mask: u8,
        ray_flags: u32,
    ) -> Result<()> {
        let merged = MergedBoxes::new(Some(tree), assembly);
        self.record_merged(rec, bindings, &merged, ray_count, cull_mask, ray_flags)
    }

    /// As [`MergedTraceTestPipeline::record`], with the merged boxes' values
    /// as [`MergedBoxes`] ([`crate::LipacVk::merged_boxes`] of a frame;
    /// [`MergedBoxes::OFF`]: the leaf-only path).
    ///
    /// # Errors
    ///
    /// As [`MergedTraceTestPipeline::record`]; [`VkError::InvalidArgument`]
    /// when the hitbox buffers hold fewer hitboxes than `merged`'s grid.
    pub fn record_merged(
        &self,
        rec: &mut Recorder<'_>,
        bindings: &MergedTraceBindings,
        merged: &MergedBoxes,
        ray_count: u32,
        cull_mask: u8,
        ray_flags: u32,
    ) -> Result<()> {
        self.pipeline.check_recorder(rec, &bindings.set)?;
        if merged.hitboxes_read() > bindings.hitboxes {
            return Err(VkError::InvalidArgument(format!(
                "merged boxes over a {} x {} grid but the hitbox records and bounds hold {}",
                merged.grid_nx, merged.grid_nz, bindings.hitboxes
            )));
        }
        if u64::from(ray_count) > bindings.max_rays {
            return Err(VkError::InvalidArgument(format!(
                "{ray_count} rays but the buffers hold {}",
                bindings.max_rays
            )));
        }
        let groups = ray_count.div_ceil(LOCAL_SIZE);
        if groups > 65_535 {
            return Err(VkError::InvalidArgument(format!(
                "{ray_count} rays in one dispatch"
            )));
        }
        let push = MergedPush {
            ray_count,
            cull_mask: u32::from(cull_mask),
            ray_flags,
            merged: *merged,
        };
        self.pipeline.dispatch(
            rec,
            &bindings.set,
            bytemuck::bytes_of(&push),
            [groups, 1, 1],
        );
        rec.memory_barrier(
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::SHADER_STORAGE_WRITE,
            vk::PipelineStageFlags2::HOST,
            vk::AccessFlags2::HOST_READ,
        );
        Ok(())
    }
}
