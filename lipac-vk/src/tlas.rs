//! The TLAS, built from a buffer of [`TlasInstance`] records.

use crate::accel::{
    build_sizes, record_build_barrier, same_context, AccelerationStructure, AsSizes,
};
use crate::commands::Recorder;
use crate::context::DeviceContext;
use crate::error::{Result, VkError};
use crate::memory::{Buffer, ScratchBuffer};
use ash::vk;
use lipac_core::layout::TlasInstance;

// lipac-core's record is byte for byte the Vulkan instance the build reads.
const _: () = assert!(
    std::mem::size_of::<TlasInstance>()
        == std::mem::size_of::<vk::AccelerationStructureInstanceKHR>()
);
const _: () = assert!(std::mem::size_of::<TlasInstance>() == 64);
const _: () = assert!(std::mem::offset_of!(TlasInstance, custom_index_and_mask) == 48);
const _: () = assert!(std::mem::offset_of!(TlasInstance, sbt_offset_and_flags) == 52);
const _: () = assert!(std::mem::offset_of!(TlasInstance, acceleration_structure_reference) == 56);

fn instance_geometry(address: vk::DeviceAddress) -> vk::AccelerationStructureGeometryKHR<'static> {
    let instances = vk::AccelerationStructureGeometryInstancesDataKHR::default()
        .array_of_pointers(false)
        .data(vk::DeviceOrHostAddressConstKHR {
            device_address: address,
        });
    vk::AccelerationStructureGeometryKHR::default()
        .geometry_type(vk::GeometryTypeKHR::INSTANCES)
        .geometry(vk::AccelerationStructureGeometryDataKHR { instances })
}

/// A top-level acceleration structure with a capacity in instances.
///
/// The storage is sized for [`GpuTlas::capacity`] instances; a build with more
/// grows it geometrically (at least doubling) and retires the old storage.
/// Records whose `acceleration_structure_reference` is 0 are inactive: they
/// occupy a slot but nothing is hit.
#[derive(Debug)]
pub struct GpuTlas {
    ctx: DeviceContext,
    accel: AccelerationStructure,
    capacity: u32,
    flags: vk::BuildAccelerationStructureFlagsKHR,
    sizes: AsSizes,
    built_count: u32,
}

/// What [`GpuTlas::record_build`] retired.
#[derive(Debug, Default)]
pub struct TlasBuildOutput {
    /// Storage replaced because the TLAS grew: keep it until GPU work that
    /// used it has completed.
    pub retired_accel: Option<AccelerationStructure>,
    /// A scratch buffer replaced while growing; same rule.
    pub retired_scratch: Option<Buffer>,
}

impl GpuTlas {
    /// The sizes of a TLAS for `instance_count` instances with `flags`.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for a count over `maxInstanceCount`.
    pub fn query_sizes(
        ctx: &DeviceContext,
        instance_count: u32,
        flags: vk::BuildAccelerationStructureFlagsKHR,
    ) -> Result<AsSizes> {
        if u64::from(instance_count) > ctx.limits().max_instance_count {
            return Err(VkError::InvalidArgument(format!(
                "{instance_count} instances exceed maxInstanceCount {}",
                ctx.limits().max_instance_count
            )));
        }
        let geometry = [instance_geometry(0)];
        let top = vk::AccelerationStructureTypeKHR::TOP_LEVEL;
        Ok(build_sizes(ctx, top, &geometry, &[instance_count], flags))
    }

    /// Creates a TLAS with room for `capacity` instances (at least 1).
    ///
    /// # Errors
    ///
    /// As [`GpuTlas::query_sizes`] and [`AccelerationStructure::new`].
    pub fn new(
        ctx: &DeviceContext,
        capacity: u32,
        flags: vk::BuildAccelerationStructureFlagsKHR,
    ) -> Result<Self> {
        let capacity = capacity.max(1);
        let sizes = Self::query_sizes(ctx, capacity, flags)?;
        let accel = AccelerationStructure::new(
            ctx,
            vk::AccelerationStructureTypeKHR::TOP_LEVEL,
            sizes.acceleration_structure,
        )?;
        Ok(Self {
            ctx: ctx.clone(),
            accel,
            capacity,
            flags,
            sizes,
            built_count: 0,
        })
    }

    /// Instances the current storage holds.
    pub fn capacity(&self) -> u32 {
        self.capacity
    }
    /// Instance records in the last recorded build.
    pub fn built_count(&self) -> u32 {
        self.built_count
    }
    /// Sizes for the current capacity.
    pub fn sizes(&self) -> AsSizes {
        self.sizes
    }
    /// The acceleration structure (bind `accel().raw()` to shaders).
    pub fn accel(&self) -> &AccelerationStructure {
        &self.accel
    }
    /// The build flags.
    pub fn build_flags(&self) -> vk::BuildAccelerationStructureFlagsKHR {
        self.flags
    }

    /// Records a build from `count` [`TlasInstance`] records at byte `offset`
    /// of `instances`, then a barrier making it visible to shaders.
    ///
    /// `instances` needs `ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR`
    /// usage and a 16-byte aligned address at `offset`. Host writes before the
    /// submission are visible to the build; GPU writes (a compute pass filling
    /// the records) need their own barrier before this call. Every non-zero
    /// reference must be the address of a live BLAS.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingUsage`], [`VkError::OutOfBounds`],
    /// [`VkError::InvalidArgument`] (alignment, count over the limit),
    /// [`VkError::WrongContext`], creation errors when growing. Nothing is
    /// recorded on error.
    pub fn record_build(
        &mut self,
        rec: &mut Recorder<'_>,
        instances: &Buffer,
        offset: u64,
        count: u32,
        scratch: &mut ScratchBuffer,
    ) -> Result<TlasBuildOutput> {
        let ctx = rec.context();
        same_context(ctx, &self.ctx)?;
        same_context(ctx, instances.context())?;
        if !instances
            .usage()
            .contains(vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR)
        {
            return Err(VkError::MissingUsage(
                "ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR",
            ));
        }
        let len = u64::from(count) * std::mem::size_of::<TlasInstance>() as u64;
        match offset.checked_add(len) {
            Some(end) if end <= instances.size() => {}
            _ => {
                return Err(VkError::OutOfBounds {
                    offset,
                    len,
                    size: instances.size(),
                })
            }
        }
        let address = instances.device_address() + offset;
        if address % 16 != 0 {
            return Err(VkError::InvalidArgument(format!(
                "instance records at {address:#x} are not 16-byte aligned"
            )));
        }
        let mut out = TlasBuildOutput::default();
        if count > self.capacity {
            let max = u32::try_from(ctx.limits().max_instance_count).unwrap_or(u32::MAX);
            if count > max {
                return Err(VkError::InvalidArgument(format!(
                    "{count} instances exceed maxInstanceCount {max}"
                )));
            }
            let capacity = count.max(self.capacity.saturating_mul(2)).min(max);
            let sizes = Self::query_sizes(ctx, capacity, self.flags)?;
            let accel = AccelerationStructure::new(
                ctx,
                vk::AccelerationStructureTypeKHR::TOP_LEVEL,
                sizes.acceleration_structure,
            )?;
            out.retired_accel = Some(std::mem::replace(&mut self.accel, accel));
            self.capacity = capacity;
            self.sizes = sizes;
        }
        out.retired_scratch = scratch.reserve(self.sizes.build_scratch.max(1))?;
        let geometry = [instance_geometry(address)];
        let info = [vk::AccelerationStructureBuildGeometryInfoKHR::default()
            .ty(vk::AccelerationStructureTypeKHR::TOP_LEVEL)
            .flags(self.flags)
            .mode(vk::BuildAccelerationStructureModeKHR::BUILD)
            .dst_acceleration_structure(self.accel.raw())
            .geometries(&geometry)
            .scratch_data(vk::DeviceOrHostAddressKHR {
                device_address: scratch.base_address(),
            })];
        let range = [vk::AccelerationStructureBuildRangeInfoKHR::default().primitive_count(count)];
        // SAFETY: recording on this device; the destination holds `capacity >=
        // count` instances; scratch is aligned and large enough for the
        // capacity's build; the instance records are in bounds and 16-aligned
        // (checked above) and the caller keeps them and the referenced BLASes
        // alive until execution.
        unsafe {
            ctx.acceleration_structure()
                .cmd_build_acceleration_structures(rec.raw(), &info, &[&range])
        };
        record_build_barrier(rec);
        self.built_count = count;
        Ok(out)
    }
}
