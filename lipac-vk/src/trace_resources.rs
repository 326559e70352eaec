//! [`TraceResources`]: the raw Vulkan handles an engine's own tracer binds
//! in a frame, with their descriptor types.

use crate::backend::LipacVk;
use crate::error::Result;
use crate::merged_boxes::MergedBoxes;
use ash::vk;

/// What an engine's tracer (ray queries or a ray-tracing pipeline) binds for
/// one frame, as raw handles: read it after [`LipacVk::record_frame`] and
/// write the frame's descriptor set from it (the buffers can change from
/// frame to frame when the tables grow). Every buffer is bound whole
/// (`offset 0`, `VK_WHOLE_SIZE`) as [`TraceResources::BUFFER_DESCRIPTOR`];
/// the TLAS as [`TraceResources::TLAS_DESCRIPTOR`].
///
/// | field | GLSL (`lipac_counting*.glsl`) | access |
/// | --- | --- | --- |
/// | `tlas` | `accelerationStructureEXT` | read |
/// | `instance_hits` | `uint[]` (`LIPAC_COUNT_INSTANCE`) | atomic add |
/// | `hitbox_records` | `LipacHitboxRecord[]` (`LIPAC_HITBOX_RECORDS`) | atomic compare-swap |
/// | `hitbox_bounds` | `vec4[]` (`LIPAC_HITBOX_BOUNDS`, merged boxes) | read |
/// | `instance_data` | the engine's geometry data (`uint[]`, say) | read |
/// | `data_offsets` | `uint[]`: byte offset of slot `i`'s data | read |
#[derive(Clone, Copy, Debug)]
pub struct TraceResources {
    /// The TLAS of the frame ([`LipacVk::tlas`]).
    pub tlas: vk::AccelerationStructureKHR,
    /// Per-slot `u32` hit counters ([`LipacVk::trace_targets`]`.0`).
    pub instance_hits: vk::Buffer,
    /// The hitbox records ([`LipacVk::hitbox_records`]).
    pub hitbox_records: vk::Buffer,
    /// The hitbox bounds ([`LipacVk::hitbox_bounds`]), read to resolve
    /// merged boxes.
    pub hitbox_bounds: vk::Buffer,
    /// The geometry-data buffer ([`LipacVk::trace_targets`]`.1`).
    pub instance_data: vk::Buffer,
    /// Per-slot `u32` byte offsets into it ([`LipacVk::trace_targets`]`.2`).
    pub data_offsets: vk::Buffer,
    /// The frame's merged-box values (push constants;
    /// [`MergedBoxes::OFF`] without adaptive hitboxes).
    pub merged_boxes: MergedBoxes,
}

impl TraceResources {
    /// The descriptor type of [`TraceResources::tlas`].
    pub const TLAS_DESCRIPTOR: vk::DescriptorType = vk::DescriptorType::ACCELERATION_STRUCTURE_KHR;
    /// The descriptor type of every buffer.
    pub const BUFFER_DESCRIPTOR: vk::DescriptorType = vk::DescriptorType::STORAGE_BUFFER;

    /// The resources of `lipac`'s current frame (after
    /// [`LipacVk::record_frame`]).
    ///
    /// # Errors
    ///
    /// As [`LipacVk::trace_targets`] (no frame recorded yet).
    pub fn of(lipac: &LipacVk) -> Result<Self> {
        let (hits, data, offsets) = lipac.trace_targets()?;
        Ok(Self {
            tlas: lipac.tlas().accel().raw(),
            instance_hits: hits.raw(),
            hitbox_records: lipac.hitbox_records().raw(),
            hitbox_bounds: lipac.hitbox_bounds().raw(),
            instance_data: data.raw(),
            data_offsets: offsets.raw(),
            merged_boxes: lipac.merged_boxes(),
        })
    }
}
