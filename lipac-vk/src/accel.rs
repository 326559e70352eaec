//! The acceleration-structure object shared by BLAS and TLAS, and its sizes.

use crate::as_pool::PoolRange;
use crate::commands::Recorder;
use crate::context::DeviceContext;
use crate::error::{Result, VkContext, VkError};
use crate::memory::{Buffer, MemoryLocation};
use ash::vk;

/// Byte sizes a build needs, as `vkGetAccelerationStructureBuildSizesKHR`
/// reports them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AsSizes {
    /// Size of the acceleration structure itself.
    pub acceleration_structure: u64,
    /// Scratch for a full build.
    pub build_scratch: u64,
    /// Scratch for an update (refit).
    pub update_scratch: u64,
}

impl From<vk::AccelerationStructureBuildSizesInfoKHR<'_>> for AsSizes {
    fn from(s: vk::AccelerationStructureBuildSizesInfoKHR<'_>) -> Self {
        Self {
            acceleration_structure: s.acceleration_structure_size,
            build_scratch: s.build_scratch_size,
            update_scratch: s.update_scratch_size,
        }
    }
}

/// The sizes a device build of `ty` with `geometries` and `counts`
/// (primitives or instances per geometry) needs. Addresses in the
/// geometries are ignored.
pub(crate) fn build_sizes(
    ctx: &DeviceContext,
    ty: vk::AccelerationStructureTypeKHR,
    geometries: &[vk::AccelerationStructureGeometryKHR<'_>],
    counts: &[u32],
    flags: vk::BuildAccelerationStructureFlagsKHR,
) -> AsSizes {
    let info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
        .ty(ty)
        .flags(flags)
        .mode(vk::BuildAccelerationStructureModeKHR::BUILD)
        .geometries(geometries);
    let mut sizes = vk::AccelerationStructureBuildSizesInfoKHR::default();
    // SAFETY: the geometry info is complete; `counts` has one entry per
    // geometry (ash asserts it); the function only computes sizes.
    unsafe {
        ctx.acceleration_structure()
            .get_acceleration_structure_build_sizes(
                vk::AccelerationStructureBuildTypeKHR::DEVICE,
                &info,
                counts,
                &mut sizes,
            )
    };
    sizes.into()
}

/// Where an acceleration structure's bytes live.
#[derive(Debug)]
enum Storage {
    /// A buffer of its own (memory from the context's allocator).
    Dedicated(Buffer),
    /// A range of an [`crate::AccelerationStructurePool`] block.
    Pooled(PoolRange),
}

/// A `VkAccelerationStructureKHR` with the storage holding it: a buffer of
/// its own ([`AccelerationStructure::new`]) or a range of an
/// [`crate::AccelerationStructurePool`] block.
///
/// Dropping destroys the object and frees its storage (or returns the range
/// to the pool): keep it alive until the GPU no longer uses it (builds,
/// copies, traces, and TLASes referencing it).
pub struct AccelerationStructure {
    ctx: DeviceContext,
    raw: vk::AccelerationStructureKHR,
    storage: Storage,
    size: u64,
    address: vk::DeviceAddress,
    ty: vk::AccelerationStructureTypeKHR,
}

impl std::fmt::Debug for AccelerationStructure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AccelerationStructure")
            .field("type", &self.ty)
            .field("size", &self.size)
            .field("address", &format_args!("{:#x}", self.address))
            .finish_non_exhaustive()
    }
}

impl AccelerationStructure {
    /// Creates an (unbuilt) acceleration structure of `size` bytes in a
    /// buffer of its own.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for size 0; as [`Buffer::new`];
    /// [`VkError::Vulkan`] when creation fails.
    pub fn new(
        ctx: &DeviceContext,
        ty: vk::AccelerationStructureTypeKHR,
        size: u64,
    ) -> Result<Self> {
        if size == 0 {
            return Err(VkError::InvalidArgument(
                "acceleration structure of size 0".into(),
            ));
        }
        let buffer = Buffer::named(
            ctx,
            "lipac acceleration structure",
            size,
            vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR,
            MemoryLocation::GpuOnly,
        )?;
        let raw_buffer = buffer.raw();
        Self::create(ctx, ty, raw_buffer, 0, size, Storage::Dedicated(buffer))
    }

    /// Creates an acceleration structure in a pool range (the pool checked
    /// the block's usage, the bounds and the 256-byte offset alignment).
    pub(crate) fn in_pool_range(
        ctx: &DeviceContext,
        ty: vk::AccelerationStructureTypeKHR,
        block: vk::Buffer,
        range: PoolRange,
    ) -> Result<Self> {
        let (offset, size) = (range.offset, range.size);
        Self::create(ctx, ty, block, offset, size, Storage::Pooled(range))
    }

    fn create(
        ctx: &DeviceContext,
        ty: vk::AccelerationStructureTypeKHR,
        buffer: vk::Buffer,
        offset: u64,
        size: u64,
        storage: Storage,
    ) -> Result<Self> {
        let info = vk::AccelerationStructureCreateInfoKHR::default()
            .buffer(buffer)
            .offset(offset)
            .size(size)
            .ty(ty);
        let accel = ctx.acceleration_structure();
        // SAFETY: `buffer` has ACCELERATION_STRUCTURE_STORAGE usage and bound
        // memory, and `offset..offset + size` lies inside it with `offset` a
        // multiple of 256 (dedicated: offset 0; pooled: the pool's TLSF range
        // allocated with 256-byte alignment). `storage` keeps it alive.
        let raw = unsafe { accel.create_acceleration_structure(&info, None) }
            .ctx("vkCreateAccelerationStructureKHR")?;
        let addr_info =
            vk::AccelerationStructureDeviceAddressInfoKHR::default().acceleration_structure(raw);
        // SAFETY: `raw` is a valid acceleration structure of this device.
        let address = unsafe { accel.get_acceleration_structure_device_address(&addr_info) };
        Ok(Self {
            ctx: ctx.clone(),
            raw,
            storage,
            size,
            address,
            ty,
        })
    }

    /// The `VkAccelerationStructureKHR` (for descriptor writes).
    pub fn raw(&self) -> vk::AccelerationStructureKHR {
        self.raw
    }
    /// Its device address (what TLAS instances reference).
    pub fn device_address(&self) -> vk::DeviceAddress {
        self.address
    }
    /// Its size in bytes.
    pub fn size(&self) -> u64 {
        self.size
    }
    /// Bytes of device memory held: the storage buffer's allocation, or
    /// the size of the pool range.
    pub fn memory_bytes(&self) -> u64 {
        match &self.storage {
            Storage::Dedicated(b) => b.allocation_size(),
            Storage::Pooled(r) => r.size,
        }
    }
    /// Byte offset inside its pool block, or `None` for a dedicated buffer.
    pub fn pool_offset(&self) -> Option<u64> {
        match &self.storage {
            Storage::Dedicated(_) => None,
            Storage::Pooled(r) => Some(r.offset),
        }
    }
    /// BLAS or TLAS.
    pub fn ty(&self) -> vk::AccelerationStructureTypeKHR {
        self.ty
    }
    /// The context it belongs to.
    pub fn context(&self) -> &DeviceContext {
        &self.ctx
    }
}

impl Drop for AccelerationStructure {
    fn drop(&mut self) {
        // SAFETY: created on this device; by the type's contract the GPU no
        // longer uses it. The storage is freed (or its pool range returned)
        // afterwards, by the field drop.
        unsafe {
            self.ctx
                .acceleration_structure()
                .destroy_acceleration_structure(self.raw, None)
        };
    }
}

/// Records the barrier lipac puts after a batch of builds or copies: build
/// writes become visible to later builds, copies and shaders (ray queries).
pub(crate) fn record_build_barrier(rec: &mut Recorder<'_>) {
    rec.memory_barrier(
        vk::PipelineStageFlags2::ACCELERATION_STRUCTURE_BUILD_KHR,
        vk::AccessFlags2::ACCELERATION_STRUCTURE_WRITE_KHR,
        vk::PipelineStageFlags2::ALL_COMMANDS,
        vk::AccessFlags2::ACCELERATION_STRUCTURE_READ_KHR
            | vk::AccessFlags2::ACCELERATION_STRUCTURE_WRITE_KHR
            | vk::AccessFlags2::SHADER_READ,
    );
}

/// Checks that a recorder and an object share a context.
pub(crate) fn same_context(a: &DeviceContext, b: &DeviceContext) -> Result<()> {
    if a.same_as(b) {
        Ok(())
    } else {
        Err(VkError::WrongContext)
    }
}
