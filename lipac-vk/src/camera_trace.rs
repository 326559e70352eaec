//! [`CameraTracer`]: GPU ray generation with lipac's counting.

use crate::commands::Recorder;
use crate::compute::{compute_to_everything, StorageSet};
use crate::context::DeviceContext;
use crate::counting::CountingBoxConfig;
use crate::error::{Result, VkError};
use crate::memory::Buffer;
use crate::merged_boxes::MergedBoxes;
use crate::ray_query::RayQueryPipeline;
use crate::shaders::CAMERA_TRACE_SPV;
use crate::tlas::GpuTlas;
use ash::vk;
use bytemuck::{Pod, Zeroable};

/// Work-group size of `camera_trace.comp` (8 × 8 pixels).
const TILE: u32 = 8;

/// Buffers of one [`CameraTracer`] frame (all need `STORAGE_BUFFER`).
#[derive(Clone, Copy, Debug)]
pub struct CameraTraceBuffers<'a> {
    /// The TLAS to trace (built, its build barrier recorded).
    pub tlas: &'a GpuTlas,
    /// Per-slot `u32` hit counters.
    pub instance_hits: &'a Buffer,
    /// The hitbox records (box hits are added to their counts).
    pub hitboxes: &'a Buffer,
    /// The geometry-data buffer.
    pub data: &'a Buffer,
    /// Per-slot `u32` byte offsets into `data`.
    pub data_offsets: &'a Buffer,
    /// `width × height` RGBA8 pixels (`u32`, row 0 at the top).
    pub image: &'a Buffer,
    /// The hitbox bounds ([`crate::LipacVk::hitbox_bounds`]): read to
    /// resolve merged boxes (adaptive hitboxes), bound always.
    pub hitbox_bounds: &'a Buffer,
}

/// A descriptor set bound to one [`CameraTraceBuffers`]; keep it and the
/// buffers alive until the traces recorded with it have executed (e.g.
/// [`crate::LipacVk::retire_after_frame`]).
#[derive(Debug)]
pub struct CameraTraceBindings {
    set: StorageSet,
    pixels: u64,
    /// Hitboxes both the records and the bounds buffer hold.
    hitboxes: u64,
}

/// One frame's camera for [`CameraTracer::record`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraView {
    /// Eye position.
    pub origin: [f32; 3],
    /// Unit view direction.
    pub forward: [f32; 3],
    /// Right vector scaled by `tan(vfov / 2) · aspect`.
    pub right: [f32; 3],
    /// Up vector scaled by `tan(vfov / 2)`.
    pub up: [f32; 3],
    /// Unit direction towards the sun.
    pub sun: [f32; 3],
    /// Largest primary-ray distance.
    pub t_max: f32,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Seed of the bounce directions (e.g. the frame number).
    pub seed: u32,
    /// Trace the sun shadow rays.
    pub shadows: bool,
    /// Trace one diffuse bounce.
    pub bounce: bool,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Push {
    origin_t_max: [f32; 4],
    forward: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
    sun: [f32; 4],
    width: u32,
    height: u32,
    seed: u32,
    passes: u32,
    merged: MergedBoxes,
}

/// [`CameraTracer`]: a frame's rays generated and traced on the GPU
/// (`camera_trace.comp`), every ray through `lipac_counting.glsl`. It stands
/// in for an engine's own ray-query pass: one primary ray per pixel, a sun
/// shadow ray and one diffuse bounce from each primary hit, hits counted as
/// [`crate::LipacVk`] expects (instance boxes and committed hits into
/// [`crate::LipacVk::instance_hits`], hitbox boxes into
/// [`crate::LipacVk::hitbox_records`]), shading from the instances'
/// geometry data (4 `f32`: RGB albedo and one spare, at
/// [`crate::LipacVk::instance_data_offsets`]). Writes one RGBA8 `u32` per
/// pixel. With adaptive hitboxes ([`MergedBoxes`] on), a merged counting
/// box is resolved to its leaf hitboxes' boxes (`lipac_counting.glsl`'s
/// `LIPAC_SBT_MERGED_BOX` path, as `trace_merged.comp`): every ray counts the
/// hitbox it would count with one box per hitbox.
#[derive(Debug)]
pub struct CameraTracer {
    pipeline: RayQueryPipeline,
}

fn v4(v: [f32; 3], w: f32) -> [f32; 4] {
    [v[0], v[1], v[2], w]
}

impl CameraTracer {
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
                "CameraTracer",
                CAMERA_TRACE_SPV,
                config,
                6,
                std::mem::size_of::<Push>() as u32,
            )?,
        })
    }

    /// Creates a descriptor set for `buffers`.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingUsage`] when a buffer lacks `STORAGE_BUFFER`,
    /// [`VkError::WrongContext`], [`VkError::Vulkan`].
    pub fn bind(&self, buffers: &CameraTraceBuffers<'_>) -> Result<CameraTraceBindings> {
        let storage = [
            buffers.instance_hits,
            buffers.hitboxes,
            buffers.data,
            buffers.data_offsets,
            buffers.image,
            buffers.hitbox_bounds,
        ];
        let set = self.pipeline.bind(
            buffers.tlas,
            &storage,
            "STORAGE_BUFFER for a camera trace buffer",
        )?;
        let hitboxes = (buffers.hitboxes.size()
            / std::mem::size_of::<lipac_core::layout::HitboxRecord>() as u64)
            .min(buffers.hitbox_bounds.size() / std::mem::size_of::<crate::HitboxBounds>() as u64);
        Ok(CameraTraceBindings {
            set,
            pixels: buffers.image.size() / 4,
            hitboxes,
        })
    }

    /// Records the frame's trace, with a barrier before (the TLAS build and
    /// the cleared counters) and after (counters, hitbox records and image
    /// visible to every later command and the host). `merged` describes the
    /// TLAS's merged boxes: [`crate::LipacVk::merged_boxes`] of the frame
    /// ([`MergedBoxes::OFF`] for a TLAS without them).
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] when the image buffer is smaller than
    /// `width × height` pixels, the hitbox records or bounds hold fewer
    /// hitboxes than `merged`'s grid, or the dispatch is too large;
    /// [`VkError::WrongContext`].
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        bindings: &CameraTraceBindings,
        view: &CameraView,
        merged: &MergedBoxes,
    ) -> Result<()> {
        self.pipeline.check_recorder(rec, &bindings.set)?;
        if merged.hitboxes_read() > bindings.hitboxes {
            return Err(VkError::InvalidArgument(format!(
                "merged boxes over a {} x {} grid but the hitbox records and bounds hold {}",
                merged.grid_nx, merged.grid_nz, bindings.hitboxes
            )));
        }
        let pixels = u64::from(view.width) * u64::from(view.height);
        let (gx, gy) = (view.width.div_ceil(TILE), view.height.div_ceil(TILE));
        if pixels == 0 || pixels > bindings.pixels || gx > 65_535 || gy > 65_535 {
            return Err(VkError::InvalidArgument(format!(
                "{}x{} pixels for an image of {} pixels",
                view.width, view.height, bindings.pixels
            )));
        }
        let push = Push {
            origin_t_max: v4(view.origin, view.t_max),
            forward: v4(view.forward, 0.0),
            right: v4(view.right, 0.0),
            up: v4(view.up, 0.0),
            sun: v4(view.sun, 0.0),
            width: view.width,
            height: view.height,
            seed: view.seed,
            passes: u32::from(view.shadows) | (u32::from(view.bounce) << 1),
            merged: *merged,
        };
        rec.memory_barrier(
            vk::PipelineStageFlags2::ALL_COMMANDS,
            vk::AccessFlags2::MEMORY_WRITE,
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::SHADER_STORAGE_READ
                | vk::AccessFlags2::SHADER_STORAGE_WRITE
                | vk::AccessFlags2::ACCELERATION_STRUCTURE_READ_KHR,
        );
        let push = bytemuck::bytes_of(&push);
        self.pipeline
            .dispatch(rec, &bindings.set, push, [gx, gy, 1]);
        compute_to_everything(rec);
        Ok(())
    }
}
