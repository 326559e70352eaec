//! [`PipelineTestTracer`]: `pipeline_trace.rgen`, the ray-tracing-pipeline
//! twin of the ray-query test tracers (`trace_counting.comp`,
//! `trace_merged.comp`): rays from a buffer, each ray's closest real hit
//! written as a [`GpuHit`], counted as an engine counts in its hit shaders
//! (`lipac_counting_pipeline.glsl`): hitbox boxes into the hitbox records,
//! instance boxes and real hits into the per-slot counters, merged boxes
//! resolved when [`MergedBoxes`] says so. Tests compare it ray for ray with
//! the ray-query path; engines write their own pipelines with the include.

use crate::commands::Recorder;
use crate::compute::StorageSet;
use crate::context::DeviceContext;
use crate::counting::CountingBoxConfig;
use crate::counting_pipeline::{CountingPipeline, COUNTING_BINDINGS};
use crate::error::{Result, VkError};
use crate::memory::Buffer;
use crate::merged_boxes::MergedBoxes;
use crate::ray_query_test_pipeline::{GpuHit, GpuRay};
use crate::shaders::PIPELINE_TRACE_SPV;
use crate::tlas::GpuTlas;
use ash::vk;
use bytemuck::{Pod, Zeroable};

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct TracePush {
    merged: MergedBoxes,
    ray_count: u32,
    cull_mask: u32,
    ray_flags: u32,
}

/// Rays per trace at most (`vkCmdTraceRaysKHR`'s width stays within every
/// device's limits).
const MAX_RAYS: u32 = 65_535 * 64;

/// Buffers a [`PipelineTestTracer`] trace reads and writes (all need
/// `STORAGE_BUFFER`).
#[derive(Clone, Copy, Debug)]
pub struct PipelineTestBuffers<'a> {
    /// The TLAS (built, with the build barrier recorded before the trace).
    pub tlas: &'a GpuTlas,
    /// [`GpuRay`]s.
    pub rays: &'a Buffer,
    /// [`GpuHit`]s, one per ray.
    pub results: &'a Buffer,
    /// `u32` hit counters per instance slot.
    pub instance_hits: &'a Buffer,
    /// The `HitboxRecord`s; hitbox-box hits are added to their counts
    /// (saturating, as Algorithm 2 expects).
    pub hitboxes: &'a Buffer,
    /// The hitbox bounds ([`crate::hitbox_bounds`]), read to resolve merged
    /// boxes; bound always.
    pub hitbox_bounds: &'a Buffer,
}

/// A descriptor set bound to one [`PipelineTestBuffers`]; keep it and the
/// buffers alive until the traces recorded with it have executed.
#[derive(Debug)]
pub struct PipelineTestBindings {
    set: StorageSet,
    max_rays: u64,
    hitboxes: u64,
}

/// The `pipeline_trace.rgen` ray-tracing pipeline and its shader binding
/// table for one [`CountingBoxConfig`] and merged-box SBT offset.
#[derive(Debug)]
pub struct PipelineTestTracer {
    pipeline: CountingPipeline,
}

impl PipelineTestTracer {
    /// Creates the pipeline with `config` as specialization constants and
    /// a hit record for every SBT offset up to the largest box offset
    /// (`merged_sbt_offset`: that of merged boxes,
    /// `AdaptiveHitboxes::merged_box_sbt_offset`, 3 by default). Real
    /// instances must use SBT offsets below the largest box offset that are
    /// no box offset (0, say).
    ///
    /// # Errors
    ///
    /// [`VkError::MissingFeature`] without ray-tracing pipelines
    /// ([`DeviceContext::tracing`]); [`VkError::InvalidArgument`] for an
    /// invalid config or box offsets over
    /// [`crate::MAX_PIPELINE_SBT_OFFSET`]; [`VkError::Vulkan`].
    pub fn new(
        ctx: &DeviceContext,
        config: &CountingBoxConfig,
        merged_sbt_offset: u32,
    ) -> Result<Self> {
        Ok(Self {
            pipeline: CountingPipeline::new(
                ctx,
                "PipelineTestTracer",
                PIPELINE_TRACE_SPV,
                config,
                merged_sbt_offset,
                COUNTING_BINDINGS + 2,
                std::mem::size_of::<TracePush>() as u32,
            )?,
        })
    }

    /// Creates a descriptor set for `buffers`.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingUsage`] when a buffer lacks `STORAGE_BUFFER`,
    /// [`VkError::WrongContext`], [`VkError::Vulkan`].
    pub fn bind(&self, buffers: &PipelineTestBuffers<'_>) -> Result<PipelineTestBindings> {
        let storage = [
            buffers.instance_hits,
            buffers.hitboxes,
            buffers.hitbox_bounds,
            buffers.rays,
            buffers.results,
        ];
        let set =
            self.pipeline
                .bind(buffers.tlas, &storage, "STORAGE_BUFFER for a trace buffer")?;
        let max_rays = (buffers.rays.size() / std::mem::size_of::<GpuRay>() as u64)
            .min(buffers.results.size() / std::mem::size_of::<GpuHit>() as u64);
        let hitboxes = (buffers.hitboxes.size()
            / std::mem::size_of::<lipac_core::layout::HitboxRecord>() as u64)
            .min(buffers.hitbox_bounds.size() / std::mem::size_of::<crate::HitboxBounds>() as u64);
        Ok(PipelineTestBindings {
            set,
            max_rays,
            hitboxes,
        })
    }

    /// Records a trace of the first `ray_count` rays (cull mask, GLSL ray
    /// flags) against a TLAS whose merged boxes `merged` describes
    /// ([`MergedBoxes::OFF`]: none), then a barrier making results and
    /// counters visible to the host.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] when the buffers hold fewer rays than
    /// `ray_count`, the hitbox records or bounds fewer hitboxes than
    /// `merged`'s grid, `merged` names another merged-box SBT offset than
    /// the pipeline's, or there are too many rays; [`VkError::WrongContext`].
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        bindings: &PipelineTestBindings,
        merged: &MergedBoxes,
        ray_count: u32,
        cull_mask: u8,
        ray_flags: u32,
    ) -> Result<()> {
        self.pipeline.check_recorder(rec, &bindings.set)?;
        check_merged(&self.pipeline, merged, bindings.hitboxes)?;
        if u64::from(ray_count) > bindings.max_rays || ray_count > MAX_RAYS {
            return Err(VkError::InvalidArgument(format!(
                "{ray_count} rays but the buffers hold {} (at most {MAX_RAYS} per trace)",
                bindings.max_rays
            )));
        }
        let push = TracePush {
            merged: *merged,
            ray_count,
            cull_mask: u32::from(cull_mask),
            ray_flags,
        };
        rec.memory_barrier(
            vk::PipelineStageFlags2::ALL_COMMANDS,
            vk::AccessFlags2::MEMORY_WRITE,
            vk::PipelineStageFlags2::RAY_TRACING_SHADER_KHR,
            vk::AccessFlags2::SHADER_STORAGE_READ
                | vk::AccessFlags2::SHADER_STORAGE_WRITE
                | vk::AccessFlags2::ACCELERATION_STRUCTURE_READ_KHR,
        );
        if ray_count > 0 {
            self.pipeline.trace(
                rec,
                &bindings.set,
                bytemuck::bytes_of(&push),
                [ray_count, 1, 1],
            );
        }
        rec.memory_barrier(
            vk::PipelineStageFlags2::RAY_TRACING_SHADER_KHR,
            vk::AccessFlags2::SHADER_STORAGE_WRITE,
            vk::PipelineStageFlags2::ALL_COMMANDS | vk::PipelineStageFlags2::HOST,
            vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::HOST_READ,
        );
        Ok(())
    }
}

/// Checks `merged` against the pipeline's merged-box offset and the bound
/// hitbox records and bounds.
pub(crate) fn check_merged(
    pipeline: &CountingPipeline,
    merged: &MergedBoxes,
    hitboxes: u64,
) -> Result<()> {
    if merged.levels != 0 && merged.merged_sbt_offset != pipeline.merged_sbt_offset() {
        return Err(VkError::InvalidArgument(format!(
            "merged boxes at SBT offset {} but the pipeline's table has them at {}",
            merged.merged_sbt_offset,
            pipeline.merged_sbt_offset()
        )));
    }
    if merged.hitboxes_read() > hitboxes {
        return Err(VkError::InvalidArgument(format!(
            "merged boxes over a {} x {} grid but the hitbox records and bounds hold {hitboxes}",
            merged.grid_nx, merged.grid_nz
        )));
    }
    Ok(())
}
