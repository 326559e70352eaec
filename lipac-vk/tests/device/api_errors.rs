//! Caller mistakes come back as errors, and size queries are consistent.

use crate::common::*;
use ash::vk;
use lipac_vk::{
    Buffer, GpuBlas, GpuTlas, MemoryLocation, OneShot, ScratchBuffer, TriangleGeometry, VkError,
};

pub fn caller_mistakes_are_errors() {
    let h = headless("caller_mistakes_are_errors");
    let ctx = h.context();
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    assert!(matches!(
        Buffer::new(ctx, 0, storage, MemoryLocation::CpuToGpu),
        Err(VkError::InvalidArgument(_))
    ));
    let mut gpu_only = Buffer::new(ctx, 64, storage, MemoryLocation::GpuOnly).unwrap();
    assert_eq!(gpu_only.write(0, &[1u32]), Err(VkError::NotMapped));
    assert_eq!(gpu_only.read::<u32>(0, 1), Err(VkError::NotMapped));
    let mut mapped = Buffer::new(ctx, 64, storage, MemoryLocation::CpuToGpu).unwrap();
    assert!(matches!(
        mapped.write(60, &[1u32, 2]),
        Err(VkError::OutOfBounds { .. })
    ));
    assert!(matches!(
        mapped.read::<u32>(u64::MAX, 1),
        Err(VkError::OutOfBounds { .. })
    ));
    mapped.write(60, &[0xDEAD_BEEFu32]).unwrap();
    assert_eq!(mapped.read::<u32>(60, 1).unwrap(), vec![0xDEAD_BEEF]);
    assert_ne!(mapped.device_address(), 0);

    // A geometry from buffers without the build-input usage is refused.
    let quad = GpuMesh::new(&h, Mesh::quad());
    let no_usage = TriangleGeometry::indexed(
        &mapped,
        0,
        12,
        4,
        &quad.indices,
        0,
        lipac_vk::IndexFormat::U32,
        2,
    );
    assert!(matches!(no_usage, Err(VkError::MissingUsage(_))));
    // Indices past the end of their buffer are refused.
    let past_end = TriangleGeometry::indexed(
        &quad.vertices,
        0,
        12,
        4,
        &quad.indices,
        0,
        lipac_vk::IndexFormat::U32,
        3,
    );
    assert!(matches!(past_end, Err(VkError::OutOfBounds { .. })));

    // TLAS builds check the instance buffer's usage and size; nothing is recorded.
    let mut tlas = GpuTlas::new(ctx, 4, vk::BuildAccelerationStructureFlagsKHR::empty()).unwrap();
    let mut scratch = ScratchBuffer::new(ctx);
    let mut one_shot = OneShot::new(ctx).unwrap();
    let r = one_shot.run(|rec| tlas.record_build(rec, &mapped, 0, 1, &mut scratch));
    assert!(matches!(r, Err(VkError::MissingUsage(_))));
    let records = Buffer::new(ctx, 128, BUILD_INPUT, MemoryLocation::CpuToGpu).unwrap();
    let r = one_shot.run(|rec| tlas.record_build(rec, &records, 0, 3, &mut scratch));
    assert!(matches!(r, Err(VkError::OutOfBounds { .. })));
    assert_eq!(tlas.capacity(), 4, "a refused build does not grow the TLAS");
    drop((tlas, scratch, quad, records, mapped, gpu_only));
    assert_no_validation_errors(&h);
}

pub fn size_queries_match_builds_and_grow_with_content() {
    let h = headless("size_queries_match_builds_and_grow_with_content");
    let ctx = h.context();
    let flags = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE;
    let small = GpuMesh::new(&h, Mesh::bumpy_grid(2));
    let large = GpuMesh::new(&h, Mesh::bumpy_grid(12));
    let small_q = GpuBlas::query_sizes(ctx, &[small.geometry()], flags).unwrap();
    let large_q = GpuBlas::query_sizes(ctx, &[large.geometry()], flags).unwrap();
    assert!(large_q.acceleration_structure > small_q.acceleration_structure);
    let built = build_blases(&h, &[&small, &large], flags);
    assert_eq!(built[0].size(), small_q.acceleration_structure);
    assert_eq!(built[1].size(), large_q.acceleration_structure);
    assert!(built[1].accel().memory_bytes() >= built[1].size());

    let t1 = GpuTlas::query_sizes(ctx, 100, flags).unwrap();
    let t2 = GpuTlas::query_sizes(ctx, 200, flags).unwrap();
    assert!(t2.acceleration_structure > t1.acceleration_structure);
    let too_many = u32::try_from(ctx.limits().max_instance_count.saturating_add(1));
    if let Ok(n) = too_many {
        assert!(matches!(
            GpuTlas::query_sizes(ctx, n, flags),
            Err(VkError::InvalidArgument(_))
        ));
    }
    drop((built, small, large));
    assert_no_validation_errors(&h);
}
