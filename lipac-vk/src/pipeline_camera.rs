//! [`PipelineCameraTracer`]: [`crate::CameraTracer`]'s frame traced with a
//! ray-tracing pipeline (`pipeline_camera.rgen` and lipac's counting hit
//! groups), for devices without ray queries; [`AnyCameraTracer`] picks the
//! path.

use crate::camera_trace::{CameraTraceBindings, CameraTraceBuffers, CameraTracer, CameraView};
use crate::commands::Recorder;
use crate::compute::StorageSet;
use crate::context::DeviceContext;
use crate::counting::CountingBoxConfig;
use crate::counting_pipeline::{CountingPipeline, COUNTING_BINDINGS};
use crate::error::{Result, VkError};
use crate::merged_boxes::MergedBoxes;
use crate::pipeline_test_tracer::check_merged;
use crate::shaders::PIPELINE_CAMERA_SPV;
use crate::tracing_paths::TracingPath;
use ash::vk;
use bytemuck::{Pod, Zeroable};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct CameraPush {
    merged: MergedBoxes,
    width: u32,
    height: u32,
    seed: u32,
    origin_t_max: [f32; 4],
    forward: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
    sun: [f32; 4],
    passes: u32,
}

fn v4(v: [f32; 3], w: f32) -> [f32; 4] {
    [v[0], v[1], v[2], w]
}

/// [`crate::CameraTracer`]'s frame with a ray-tracing pipeline: per pixel a
/// primary ray, a sun shadow ray and one diffuse bounce, generated in
/// `pipeline_camera.rgen`, counted in the hit and miss shaders as the paper
/// does (`lipac_counting_pipeline.glsl`), shaded from the instances'
/// geometry data. The same rays, hit counts, hitbox records and pixels as
/// the ray-query [`crate::CameraTracer`] (tests compare them bit for bit).
/// Real instances must use SBT offsets below the largest box offset that
/// are no box offset (0, say): the hit region has one record per offset up
/// to it.
#[derive(Debug)]
pub struct PipelineCameraTracer {
    pipeline: CountingPipeline,
}

/// A descriptor set bound to one [`CameraTraceBuffers`] for a
/// [`PipelineCameraTracer`]; keep it and the buffers alive until the traces
/// recorded with it have executed.
#[derive(Debug)]
pub struct PipelineCameraBindings {
    set: StorageSet,
    pixels: u64,
    hitboxes: u64,
}

impl PipelineCameraTracer {
    /// Creates the pipeline with `config` as specialization constants and
    /// merged boxes at `merged_sbt_offset`
    /// (`AdaptiveHitboxes::merged_box_sbt_offset`, 3 by default).
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
                "PipelineCameraTracer",
                PIPELINE_CAMERA_SPV,
                config,
                merged_sbt_offset,
                COUNTING_BINDINGS + 3,
                std::mem::size_of::<CameraPush>() as u32,
            )?,
        })
    }

    /// Creates a descriptor set for `buffers`.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingUsage`] when a buffer lacks `STORAGE_BUFFER`,
    /// [`VkError::WrongContext`], [`VkError::Vulkan`].
    pub fn bind(&self, buffers: &CameraTraceBuffers<'_>) -> Result<PipelineCameraBindings> {
        let storage = [
            buffers.instance_hits,
            buffers.hitboxes,
            buffers.hitbox_bounds,
            buffers.data,
            buffers.data_offsets,
            buffers.image,
        ];
        let set = self.pipeline.bind(
            buffers.tlas,
            &storage,
            "STORAGE_BUFFER for a camera trace buffer",
        )?;
        let hitboxes = (buffers.hitboxes.size()
            / std::mem::size_of::<lipac_core::layout::HitboxRecord>() as u64)
            .min(buffers.hitbox_bounds.size() / std::mem::size_of::<crate::HitboxBounds>() as u64);
        Ok(PipelineCameraBindings {
            set,
            pixels: buffers.image.size() / 4,
            hitboxes,
        })
    }

    /// Records the frame's trace as [`crate::CameraTracer::record`] does,
    /// with a barrier before (the TLAS build, the cleared counters) and
    /// after (counters, hitbox records and image visible to every later
    /// command and the host).
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] when the image buffer is smaller than
    /// `width × height` pixels, the hitbox records or bounds hold fewer
    /// hitboxes than `merged`'s grid, or `merged` names another merged-box
    /// SBT offset than the pipeline's; [`VkError::WrongContext`].
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        bindings: &PipelineCameraBindings,
        view: &CameraView,
        merged: &MergedBoxes,
    ) -> Result<()> {
        self.pipeline.check_recorder(rec, &bindings.set)?;
        check_merged(&self.pipeline, merged, bindings.hitboxes)?;
        let pixels = u64::from(view.width) * u64::from(view.height);
        if pixels == 0
            || pixels > bindings.pixels
            || view.width > 65_535 * 8
            || view.height > 65_535 * 8
        {
            return Err(VkError::InvalidArgument(format!(
                "{}x{} pixels for an image of {} pixels",
                view.width, view.height, bindings.pixels
            )));
        }
        let push = CameraPush {
            merged: *merged,
            width: view.width,
            height: view.height,
            seed: view.seed,
            origin_t_max: v4(view.origin, view.t_max),
            forward: v4(view.forward, 0.0),
            right: v4(view.right, 0.0),
            up: v4(view.up, 0.0),
            sun: v4(view.sun, 0.0),
            passes: u32::from(view.shadows) | (u32::from(view.bounce) << 1),
        };
        rec.memory_barrier(
            vk::PipelineStageFlags2::ALL_COMMANDS,
            vk::AccessFlags2::MEMORY_WRITE,
            vk::PipelineStageFlags2::RAY_TRACING_SHADER_KHR,
            vk::AccessFlags2::SHADER_STORAGE_READ
                | vk::AccessFlags2::SHADER_STORAGE_WRITE
                | vk::AccessFlags2::ACCELERATION_STRUCTURE_READ_KHR,
        );
        self.pipeline.trace(
            rec,
            &bindings.set,
            bytemuck::bytes_of(&push),
            [view.width, view.height, 1],
        );
        rec.memory_barrier(
            vk::PipelineStageFlags2::RAY_TRACING_SHADER_KHR,
            vk::AccessFlags2::SHADER_STORAGE_WRITE,
            vk::PipelineStageFlags2::ALL_COMMANDS | vk::PipelineStageFlags2::HOST,
            vk::AccessFlags2::MEMORY_READ
                | vk::AccessFlags2::MEMORY_WRITE
                | vk::AccessFlags2::HOST_READ,
        );
        Ok(())
    }
}

/// A camera tracer on either path: [`CameraTracer`] (ray queries) or
/// [`PipelineCameraTracer`] (ray-tracing pipelines), the same frame either
/// way.
#[derive(Debug)]
pub enum AnyCameraTracer {
    /// Ray queries.
    RayQuery(CameraTracer),
    /// A ray-tracing pipeline.
    Pipeline(PipelineCameraTracer),
}

/// Bindings of an [`AnyCameraTracer`].
#[derive(Debug)]
pub enum AnyCameraBindings {
    /// Of a [`CameraTracer`].
    RayQuery(CameraTraceBindings),
    /// Of a [`PipelineCameraTracer`].
    Pipeline(PipelineCameraBindings),
}

impl AnyCameraTracer {
    /// A tracer on `path`, or on the device's preferred path
    /// ([`crate::TracingPaths::preferred`]: ray queries when offered) for
    /// `None`.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingFeature`] when the device lacks the path (or both);
    /// as [`CameraTracer::new`] and [`PipelineCameraTracer::new`].
    pub fn new(
        ctx: &DeviceContext,
        config: &CountingBoxConfig,
        merged_sbt_offset: u32,
        path: Option<TracingPath>,
    ) -> Result<Self> {
        let path = match path.or_else(|| ctx.tracing().preferred()) {
            Some(p) => p,
            None => {
                return Err(VkError::MissingFeature {
                    component: "AnyCameraTracer",
                    needs: "VK_KHR_ray_query or VK_KHR_ray_tracing_pipeline",
                    offers: ctx.tracing().to_string(),
                })
            }
        };
        Ok(match path {
            TracingPath::RayQuery => Self::RayQuery(CameraTracer::new(ctx, config)?),
            TracingPath::RayTracingPipeline => {
                Self::Pipeline(PipelineCameraTracer::new(ctx, config, merged_sbt_offset)?)
            }
        })
    }

    /// The path it traces with.
    pub fn path(&self) -> TracingPath {
        match self {
            Self::RayQuery(_) => TracingPath::RayQuery,
            Self::Pipeline(_) => TracingPath::RayTracingPipeline,
        }
    }

    /// As [`CameraTracer::bind`].
    ///
    /// # Errors
    ///
    /// As [`CameraTracer::bind`].
    pub fn bind(&self, buffers: &CameraTraceBuffers<'_>) -> Result<AnyCameraBindings> {
        Ok(match self {
            Self::RayQuery(t) => AnyCameraBindings::RayQuery(t.bind(buffers)?),
            Self::Pipeline(t) => AnyCameraBindings::Pipeline(t.bind(buffers)?),
        })
    }

    /// As [`CameraTracer::record`].
    ///
    /// # Errors
    ///
    /// As [`CameraTracer::record`]; [`VkError::InvalidArgument`] for
    /// bindings of the other path.
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        bindings: &AnyCameraBindings,
        view: &CameraView,
        merged: &MergedBoxes,
    ) -> Result<()> {
        match (self, bindings) {
            (Self::RayQuery(t), AnyCameraBindings::RayQuery(b)) => t.record(rec, b, view, merged),
            (Self::Pipeline(t), AnyCameraBindings::Pipeline(b)) => t.record(rec, b, view, merged),
            _ => Err(VkError::InvalidArgument(
                "camera bindings of the other tracing path".into(),
            )),
        }
    }
}
