//! Counting boxes: the unit-cube BLAS and the TLAS instances that stretch it
//! over an omitted instance's AABB or an inactive hitbox.

use crate::blas::{IndexFormat, TriangleGeometry};
use crate::context::DeviceContext;
use crate::error::{Result, VkError};
use crate::memory::{Buffer, MemoryLocation};
use ash::vk;
use lipac_core::layout::{TlasInstance, VK_INSTANCE_CULL_DISABLE, VK_INSTANCE_FORCE_NO_OPAQUE};

/// Corners of the unit cube `[0,1]^3`; corner `i` has x = bit 0, y = bit 1, z = bit 2.
pub const UNIT_CUBE_VERTICES: [[f32; 3]; 8] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [1.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
    [1.0, 0.0, 1.0],
    [0.0, 1.0, 1.0],
    [1.0, 1.0, 1.0],
];

/// The 12 triangles of the unit cube, counter-clockwise seen from outside.
pub const UNIT_CUBE_INDICES: [u32; 36] = [
    0, 2, 1, 1, 2, 3, // z = 0
    4, 5, 6, 5, 7, 6, // z = 1
    0, 4, 2, 2, 4, 6, // x = 0
    1, 3, 5, 3, 7, 5, // x = 1
    0, 1, 4, 1, 5, 4, // y = 0
    2, 6, 3, 3, 6, 7, // y = 1
];

/// Vertex and index buffers of the unit cube, the one BLAS every counting
/// box instance references.
#[derive(Debug)]
pub struct UnitCube {
    vertices: Buffer,
    indices: Buffer,
}

impl UnitCube {
    /// Uploads the cube's vertices and indices (host-visible build inputs).
    ///
    /// # Errors
    ///
    /// As [`Buffer::with_data`].
    pub fn new(ctx: &DeviceContext) -> Result<Self> {
        let usage = vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR;
        Ok(Self {
            vertices: Buffer::with_data(ctx, usage, MemoryLocation::CpuToGpu, &UNIT_CUBE_VERTICES)?,
            indices: Buffer::with_data(ctx, usage, MemoryLocation::CpuToGpu, &UNIT_CUBE_INDICES)?,
        })
    }

    /// The cube's geometry for a [`crate::BlasBatch`] (opaque flag off:
    /// counting boxes are skipped as ray-query candidates).
    pub fn geometry(&self) -> TriangleGeometry {
        TriangleGeometry {
            vertex_address: self.vertices.device_address(),
            vertex_stride: 12,
            vertex_count: UNIT_CUBE_VERTICES.len() as u32,
            indices: Some((self.indices.device_address(), IndexFormat::U32)),
            triangle_count: (UNIT_CUBE_INDICES.len() / 3) as u32,
            opaque: false,
        }
    }
}

/// How shaders recognise counting boxes: the SBT record offsets of the two
/// kinds of boxes and the cull-mask bits only boxes carry. These are the
/// specialization constants of `trace_test.comp` and the macros of
/// `lipac_counting.glsl`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CountingBoxConfig {
    /// SBT record offset of omitted-instance boxes (24 bits).
    pub omitted_box_sbt_offset: u32,
    /// SBT record offset of hitbox boxes (24 bits, different from the above).
    pub hitbox_box_sbt_offset: u32,
    /// Visibility-mask bits of counting boxes (no real instance uses them).
    pub counting_mask: u8,
}

impl Default for CountingBoxConfig {
    fn default() -> Self {
        Self {
            omitted_box_sbt_offset: 1,
            hitbox_box_sbt_offset: 2,
            counting_mask: 0x80,
        }
    }
}

impl CountingBoxConfig {
    /// Checks that the offsets fit 24 bits and differ and the mask is non-zero.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`].
    pub fn validate(&self) -> Result<()> {
        let max = 0x00FF_FFFF;
        if self.omitted_box_sbt_offset > max || self.hitbox_box_sbt_offset > max {
            return Err(VkError::InvalidArgument("SBT offsets have 24 bits".into()));
        }
        if self.omitted_box_sbt_offset == self.hitbox_box_sbt_offset {
            return Err(VkError::InvalidArgument(
                "omitted-box and hitbox SBT offsets must differ".into(),
            ));
        }
        if self.counting_mask == 0 {
            return Err(VkError::InvalidArgument("counting mask 0".into()));
        }
        Ok(())
    }
}

/// Which counter a counting box feeds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CountingBoxKind {
    /// The box of an omitted instance; its custom index is the instance slot.
    OmittedInstance,
    /// The box of an inactive hitbox; its custom index is the hitbox index.
    Hitbox,
}

/// The TLAS record of a counting box: the unit cube (at `unit_cube_blas`)
/// scaled and moved onto `[min, max]`, culling disabled and forced
/// non-opaque, with the kind's SBT offset and the counting mask.
///
/// # Errors
///
/// [`VkError::InvalidArgument`] for non-finite corners, `min > max`, a
/// custom index over 24 bits, a zero BLAS address or an invalid config.
pub fn counting_box_instance(
    min: [f32; 3],
    max: [f32; 3],
    kind: CountingBoxKind,
    custom_index: u32,
    config: &CountingBoxConfig,
    unit_cube_blas: vk::DeviceAddress,
) -> Result<TlasInstance> {
    config.validate()?;
    if min.iter().chain(&max).any(|v| !v.is_finite()) {
        return Err(VkError::InvalidArgument(format!(
            "non-finite box {min:?}..{max:?}"
        )));
    }
    if min.iter().zip(&max).any(|(a, b)| a > b) {
        return Err(VkError::InvalidArgument(format!(
            "box min {min:?} > max {max:?}"
        )));
    }
    if custom_index > 0x00FF_FFFF {
        return Err(VkError::InvalidArgument(format!(
            "custom index {custom_index} over 24 bits"
        )));
    }
    if unit_cube_blas == 0 {
        return Err(VkError::InvalidArgument("unit cube BLAS address 0".into()));
    }
    let e = [max[0] - min[0], max[1] - min[1], max[2] - min[2]];
    let transform = [
        e[0], 0.0, 0.0, min[0], //
        0.0, e[1], 0.0, min[1], //
        0.0, 0.0, e[2], min[2],
    ];
    let sbt = match kind {
        CountingBoxKind::OmittedInstance => config.omitted_box_sbt_offset,
        CountingBoxKind::Hitbox => config.hitbox_box_sbt_offset,
    };
    Ok(TlasInstance::new(
        transform,
        custom_index,
        config.counting_mask,
        sbt,
        VK_INSTANCE_CULL_DISABLE | VK_INSTANCE_FORCE_NO_OPAQUE,
        unit_cube_blas,
    ))
}

#[cfg(test)]
mod tests;
