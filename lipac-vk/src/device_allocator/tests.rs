use super::*;

#[test]
fn counters_are_exact() {
    let c = MemoryCounters::default();
    c.add(100);
    c.add(28);
    c.remove(100);
    let s = c.snapshot(Some(AllocatorBlocks {
        blocks: 1,
        bytes: 4096,
    }));
    assert_eq!((s.buffers, s.bytes), (1, 28));
    assert_eq!(s.block_overhead(), Some(4096 - 28));
    assert_eq!(c.snapshot(None).block_overhead(), None);
}

#[test]
fn locations_map_to_gpu_allocator() {
    use gpu_allocator::MemoryLocation as G;
    assert_eq!(gpu_location(MemoryLocation::GpuOnly), G::GpuOnly);
    assert_eq!(gpu_location(MemoryLocation::CpuToGpu), G::CpuToGpu);
    assert_eq!(gpu_location(MemoryLocation::GpuToCpu), G::GpuToCpu);
    assert!(
        required_flags(MemoryLocation::GpuToCpu).contains(vk::MemoryPropertyFlags::HOST_COHERENT)
    );
    assert_eq!(
        allocation_error(gpu_allocator::AllocationError::OutOfMemory),
        VkError::vk("gpu-allocator", vk::Result::ERROR_OUT_OF_DEVICE_MEMORY)
    );
}
