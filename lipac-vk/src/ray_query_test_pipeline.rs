//! The `trace_test.comp` / `trace_counting.comp` pipeline: traces rays from a
//! buffer against a TLAS with counting-box pass-through and writes each ray's
//! closest real hit. Tests and examples use it; engines trace in their own
//! shaders with `lipac_counting.glsl`.

use crate::commands::Recorder;
use crate::compute::StorageSet;
use crate::context::DeviceContext;
use crate::counting::CountingBoxConfig;
use crate::error::{Result, VkError};
use crate::memory::Buffer;
use crate::ray_query::RayQueryPipeline;
use crate::shaders::{TRACE_COUNTING_SPV, TRACE_TEST_SPV};
use crate::tlas::GpuTlas;
use ash::vk;
use bytemuck::{Pod, Zeroable};

/// One ray as `trace_test.comp` reads it (32 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuRay {
    /// Origin.
    pub origin: [f32; 3],
    /// Smallest hit distance.
    pub t_min: f32,
    /// Direction (need not be normalised; `t` is in its units).
    pub direction: [f32; 3],
    /// Largest hit distance.
    pub t_max: f32,
}

/// One ray's result as `trace_test.comp` writes it (16 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuHit {
    /// Custom index of the hit instance; `u32::MAX` on a miss.
    pub custom_index: u32,
    /// SBT record offset of the hit instance; `u32::MAX` on a miss.
    pub sbt_offset: u32,
    /// Hit distance; -1 on a miss.
    pub t: f32,
    /// [`GpuHit::HIT`] | [`GpuHit::COUNTED_BOX`].
    pub flags: u32,
}

impl GpuHit {
    /// Flag: the ray hit real geometry.
    pub const HIT: u32 = 1;
    /// Flag: the ray counted a counting box.
    pub const COUNTED_BOX: u32 = 2;
    /// Whether the ray hit real geometry.
    pub fn is_hit(&self) -> bool {
        self.flags & Self::HIT != 0
    }
    /// Whether the ray counted a box.
    pub fn counted_box(&self) -> bool {
        self.flags & Self::COUNTED_BOX != 0
    }
}

const LOCAL_SIZE: u32 = 64;
const BINDINGS: u32 = 5;

/// Where a [`RayQueryTestPipeline`] counts hitbox-box hits
/// ([`RayQueryTestBuffers::hitbox_hits`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum HitboxCounting {
    /// `trace_test.comp`: one plain `u32` counter per hitbox (`atomicAdd`).
    #[default]
    Counters,
    /// `trace_counting.comp`: straight into the
    /// [`lipac_core::layout::HitboxRecord`] buffer that Algorithm 2 reads, a
    /// saturating add of one hit to the 24-bit count
    /// (`LIPAC_HITBOX_RECORDS` / `LIPAC_HITBOX_ADD_HITS`), active bit, streak
    /// and heights untouched. No host step between trace and Algorithm 2.
    Records,
}

/// The compiled `trace_test.comp` (or `trace_counting.comp`, see
/// [`HitboxCounting`]) compute pipeline for one [`CountingBoxConfig`].
#[derive(Debug)]
pub struct RayQueryTestPipeline {
    hitbox_counting: HitboxCounting,
    pipeline: RayQueryPipeline,
}

/// Buffers a trace reads and writes.
#[derive(Clone, Copy, Debug)]
pub struct RayQueryTestBuffers<'a> {
    /// The TLAS (built, with the build barrier recorded before the trace).
    pub tlas: &'a GpuTlas,
    /// [`GpuRay`]s (storage buffer).
    pub rays: &'a Buffer,
    /// [`GpuHit`]s, one per ray (storage buffer).
    pub results: &'a Buffer,
    /// `u32` hit counters indexed by instance slot (storage buffer).
    pub instance_hits: &'a Buffer,
    /// Hitbox hits, indexed by hitbox (storage buffer): `u32` counters for
    /// [`HitboxCounting::Counters`], the `HitboxRecord`s for
    /// [`HitboxCounting::Records`].
    pub hitbox_hits: &'a Buffer,
}

/// A descriptor set bound to one [`RayQueryTestBuffers`]; keep it (and the buffers)
/// alive until traces recorded with it have executed.
#[derive(Debug)]
pub struct RayQueryTestBindings {
    set: StorageSet,
    max_rays: u64,
}

impl RayQueryTestPipeline {
    /// Creates the `trace_test.comp` pipeline (plain hitbox counters) with
    /// `config` as specialization constants.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingFeature`] without ray queries
    /// ([`DeviceContext::tracing`]); [`VkError::InvalidArgument`] for an
    /// invalid config; [`VkError::Vulkan`].
    pub fn new(ctx: &DeviceContext, config: &CountingBoxConfig) -> Result<Self> {
        Self::with_hitbox_counting(ctx, config, HitboxCounting::Counters)
    }

    /// Creates the pipeline that counts hitbox hits as `counting` says, with
    /// `config` as specialization constants.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingFeature`] without ray queries
    /// ([`DeviceContext::tracing`]); [`VkError::InvalidArgument`] for an
    /// invalid config; [`VkError::Vulkan`].
    pub fn with_hitbox_counting(
        ctx: &DeviceContext,
        config: &CountingBoxConfig,
        counting: HitboxCounting,
    ) -> Result<Self> {
        let spv = match counting {
            HitboxCounting::Counters => TRACE_TEST_SPV,
            HitboxCounting::Records => TRACE_COUNTING_SPV,
        };
        Ok(Self {
            hitbox_counting: counting,
            pipeline: RayQueryPipeline::new(
                ctx,
                "RayQueryTestPipeline",
                spv,
                config,
                BINDINGS - 1,
                12,
            )?,
        })
    }

    /// Where this pipeline counts hitbox hits.
    pub fn hitbox_counting(&self) -> HitboxCounting {
        self.hitbox_counting
    }

    /// Creates a descriptor set for `buffers`.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingUsage`] when a buffer lacks `STORAGE_BUFFER`,
    /// [`VkError::WrongContext`], [`VkError::Vulkan`].
    pub fn bind(&self, buffers: &RayQueryTestBuffers<'_>) -> Result<RayQueryTestBindings> {
        let storage = [
            buffers.rays,
            buffers.results,
            buffers.instance_hits,
            buffers.hitbox_hits,
        ];
        let set =
            self.pipeline
                .bind(buffers.tlas, &storage, "STORAGE_BUFFER for a trace buffer")?;
        let max_rays = (buffers.rays.size() / std::mem::size_of::<GpuRay>() as u64)
            .min(buffers.results.size() / std::mem::size_of::<GpuHit>() as u64);
        Ok(RayQueryTestBindings { set, max_rays })
    }

    /// Records a trace of the first `ray_count` rays with cull mask
    /// `cull_mask` and GLSL ray flags `ray_flags`, then a barrier making the
    /// results and counters visible to the host.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] when the buffers hold fewer rays or
    /// results than `ray_count` or the dispatch is too large;
    /// [`VkError::WrongContext`].
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        bindings: &RayQueryTestBindings,
        ray_count: u32,
        cull_mask: u8,
        ray_flags: u32,
    ) -> Result<()> {
        self.pipeline.check_recorder(rec, &bindings.set)?;
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
        let push: [u32; 3] = [ray_count, u32::from(cull_mask), ray_flags];
        let push = bytemuck::cast_slice(&push);
        self.pipeline
            .dispatch(rec, &bindings.set, push, [groups, 1, 1]);
        rec.memory_barrier(
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::SHADER_STORAGE_WRITE,
            vk::PipelineStageFlags2::HOST,
            vk::AccessFlags2::HOST_READ,
        );
        Ok(())
    }
}
