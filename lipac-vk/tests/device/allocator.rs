//! Device allocators: every buffer (acceleration-structure pool blocks and
//! scratch included) takes its memory through the context's
//! `DeviceAllocator`. A counting test allocator (one `VkDeviceMemory` per
//! request) sees every allocation freed by the time the objects are
//! dropped and agrees with lipac's exact statistics; the default
//! gpu-allocator packs many buffers into few blocks.

use crate::common::*;
use ash::vk;
use glam::{Affine3A, Vec3};
use lipac_vk::{
    AccelerationStructurePool, AllocationRequest, AllocatorBlocks, BlasBatch, Buffer,
    CountingBoxConfig, DeviceAllocation, DeviceAllocator, GpuRay, HeadlessContext, MemoryLocation,
    OneShot, ScratchBuffer, Validation, VkError,
};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// What the test allocator saw; shared with the test, outlives the context.
#[derive(Default)]
struct Counts {
    allocations: AtomicU64,
    frees: AtomicU64,
    /// Make the next `allocate` fail.
    fail_next: AtomicBool,
    /// Return the next allocation at an offset breaking its alignment.
    misalign_next: AtomicBool,
    /// Live allocations when the allocator was dropped (`None` before).
    live_at_drop: Mutex<Option<usize>>,
    names: Mutex<Vec<String>>,
}

/// A custom allocator as an engine would write one: here one dedicated
/// `VkDeviceMemory` per request, counted.
struct CountingAllocator {
    device: ash::Device,
    props: vk::PhysicalDeviceMemoryProperties,
    counts: Arc<Counts>,
    /// id -> bytes of live allocations.
    live: Mutex<HashMap<u64, u64>>,
    next_id: AtomicU64,
}

impl CountingAllocator {
    fn memory_type(&self, bits: u32, location: MemoryLocation) -> Option<u32> {
        let want = match location {
            MemoryLocation::GpuOnly => vk::MemoryPropertyFlags::DEVICE_LOCAL,
            _ => vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT,
        };
        (0..self.props.memory_type_count).find(|&i| {
            bits & (1 << i) != 0
                && self.props.memory_types[i as usize]
                    .property_flags
                    .contains(want)
        })
    }
}

// SAFETY: memory comes from `device` (the context's), of a type in
// `memory_type_bits`, allocated with the DEVICE_ADDRESS flag, host-visible,
// coherent and mapped for host locations; each allocation is its own memory
// object at offset 0 (or, for the deliberately misaligned test answer, at
// offset 1 of an object large enough, which lipac must refuse), freed only
// in `free`.
unsafe impl DeviceAllocator for CountingAllocator {
    fn allocate(&self, request: &AllocationRequest<'_>) -> Result<DeviceAllocation, VkError> {
        if self.counts.fail_next.swap(false, Ordering::SeqCst) {
            return Err(VkError::Allocator(format!("{}: refused", request.name)));
        }
        let req = request.requirements;
        let type_index = self
            .memory_type(req.memory_type_bits, request.location)
            .ok_or(VkError::NoMemoryType {
                type_bits: req.memory_type_bits,
                required: vk::MemoryPropertyFlags::empty(),
            })?;
        let misalign = self.counts.misalign_next.swap(false, Ordering::SeqCst);
        let offset = u64::from(misalign);
        let size = req.size + req.alignment.max(1);
        let mut flags =
            vk::MemoryAllocateFlagsInfo::default().flags(vk::MemoryAllocateFlags::DEVICE_ADDRESS);
        let info = vk::MemoryAllocateInfo::default()
            .allocation_size(size)
            .memory_type_index(type_index)
            .push_next(&mut flags);
        // SAFETY: valid device with bufferDeviceAddress; the type index comes
        // from its memory properties.
        let memory = unsafe { self.device.allocate_memory(&info, None) }
            .map_err(|e| VkError::vk("vkAllocateMemory", e))?;
        let mapped = if request.location == MemoryLocation::GpuOnly {
            None
        } else {
            // SAFETY: host-visible memory just allocated, mapped once, whole range.
            let p = unsafe {
                self.device
                    .map_memory(memory, 0, vk::WHOLE_SIZE, vk::MemoryMapFlags::empty())
            };
            match p {
                // SAFETY: `offset` is inside the mapped allocation.
                Ok(p) => std::ptr::NonNull::new(unsafe { p.cast::<u8>().add(offset as usize) }),
                Err(e) => {
                    // SAFETY: the memory is not in use.
                    unsafe { self.device.free_memory(memory, None) };
                    return Err(VkError::vk("vkMapMemory", e));
                }
            }
        };
        let id = self.next_id.fetch_add(1, Ordering::SeqCst);
        self.live.lock().unwrap().insert(id, req.size);
        self.counts.allocations.fetch_add(1, Ordering::SeqCst);
        self.counts
            .names
            .lock()
            .unwrap()
            .push(request.name.to_owned());
        Ok(DeviceAllocation {
            memory,
            offset,
            size: size - offset,
            mapped,
            id,
        })
    }

    fn free(&self, allocation: DeviceAllocation) {
        let known = self.live.lock().unwrap().remove(&allocation.id).is_some();
        assert!(known, "free of an unknown or already freed allocation");
        self.counts.frees.fetch_add(1, Ordering::SeqCst);
        // SAFETY: lipac destroyed the buffer bound to it and the GPU is done
        // with it (the trait's promise); freeing unmaps.
        unsafe { self.device.free_memory(allocation.memory, None) };
    }

    fn blocks(&self) -> Option<AllocatorBlocks> {
        let live = self.live.lock().unwrap();
        // Report the requested bytes as the blocks: no overhead to show.
        Some(AllocatorBlocks {
            blocks: live.len(),
            bytes: live.values().sum(),
        })
    }
}

impl Drop for CountingAllocator {
    fn drop(&mut self) {
        *self.counts.live_at_drop.lock().unwrap() = Some(self.live.lock().unwrap().len());
    }
}

/// A headless context on the counting allocator (the harness made sure
/// there is a device).
fn counting_headless(test: &str) -> (HeadlessContext, Arc<Counts>) {
    let counts = Arc::new(Counts::default());
    let shared = counts.clone();
    let validation = if vulkan_required() {
        Validation::Required
    } else {
        Validation::IfAvailable
    };
    let made = HeadlessContext::with_allocator(validation, move |instance, device, pd| {
        // SAFETY: `pd` is the device's physical device of `instance`.
        let props = unsafe { instance.get_physical_device_memory_properties(pd) };
        Ok(Box::new(CountingAllocator {
            device: device.clone(),
            props,
            counts: shared,
            live: Mutex::new(HashMap::new()),
            next_id: AtomicU64::new(0),
        }))
    });
    match made {
        Ok(h) => (h, counts),
        Err(e) => panic!("{test}: no Vulkan context: {e}"),
    }
}

pub fn custom_allocator_serves_every_buffer_and_gets_every_allocation_back() {
    let (h, counts) =
        counting_headless("custom_allocator_serves_every_buffer_and_gets_every_allocation_back");
    let ctx = h.context();
    let allocations = || counts.allocations.load(Ordering::SeqCst);
    let frees = || counts.frees.load(Ordering::SeqCst);
    assert_eq!(ctx.memory_stats().buffers, 0);

    // Mapped and device-local buffers through the trait.
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let data: Vec<u32> = (0..100).collect();
    let mut mapped = Buffer::with_data(ctx, storage, MemoryLocation::CpuToGpu, &data).unwrap();
    assert_eq!(mapped.read::<u32>(0, 100).unwrap(), data);
    mapped.write(8, &[77u32]).unwrap();
    assert_eq!(mapped.read::<u32>(8, 1).unwrap(), [77]);
    let mut gpu_only = Buffer::new(ctx, 4096, storage, MemoryLocation::GpuOnly).unwrap();
    assert_eq!(gpu_only.write(0, &[1u32]), Err(VkError::NotMapped));
    assert_eq!(allocations(), 2);
    let stats = ctx.memory_stats();
    assert_eq!(stats.buffers, 2);
    assert_eq!(
        stats.bytes,
        mapped.allocation_size() + gpu_only.allocation_size()
    );
    assert_eq!(
        stats.allocator_blocks,
        Some(AllocatorBlocks {
            blocks: 2,
            bytes: stats.bytes
        })
    );
    assert_eq!(stats.block_overhead(), Some(0));

    // An allocator error comes back from the constructor; nothing leaks.
    counts.fail_next.store(true, Ordering::SeqCst);
    assert!(matches!(
        Buffer::new(ctx, 64, storage, MemoryLocation::GpuOnly),
        Err(VkError::Allocator(m)) if m.contains("refused")
    ));
    // An allocation breaking the contract is refused and returned.
    counts.misalign_next.store(true, Ordering::SeqCst);
    assert!(matches!(
        Buffer::new(ctx, 64, storage, MemoryLocation::CpuToGpu),
        Err(VkError::Allocator(m)) if m.contains("alignment")
    ));
    assert_eq!((allocations(), frees()), (3, 1));
    assert_eq!(ctx.memory_stats().buffers, 2);

    // Real GPU work on the allocator's memory: pooled BLASes (the pool's
    // blocks and the scratch come from it), a TLAS and a trace.
    let quad = GpuMesh::new(&h, Mesh::quad());
    let pool = AccelerationStructurePool::new(ctx, 64 << 10).unwrap();
    let mut batch = BlasBatch::new();
    for _ in 0..4 {
        batch
            .push(
                &[quad.geometry()],
                vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
            )
            .unwrap();
    }
    let mut scratch = ScratchBuffer::new(ctx);
    let built = OneShot::new(ctx)
        .unwrap()
        .run(|rec| batch.record_pooled(rec, &mut scratch, &pool))
        .unwrap();
    assert_eq!(pool.stats().allocation_count, 4);
    let names = counts.names.lock().unwrap().clone();
    for want in [
        "lipac acceleration-structure pool block",
        "lipac acceleration-structure build scratch",
    ] {
        assert!(names.iter().any(|n| n == want), "{want} not in {names:?}");
    }
    let pool_blocks = names
        .iter()
        .filter(|n| *n == "lipac acceleration-structure pool block")
        .count();
    assert_eq!(pool_blocks, pool.stats().blocks);
    let stats = ctx.memory_stats();
    assert_eq!(stats.buffers, allocations() - frees());
    assert_eq!(
        stats.allocator_blocks.map(|b| b.bytes),
        Some(stats.bytes),
        "lipac's bytes are the allocator's requested bytes"
    );

    let scene: Vec<SceneInstance> = (0..4)
        .map(|k| SceneInstance {
            mesh: Mesh::quad(),
            transform: Affine3A::from_translation(Vec3::new(3.0 * k as f32 - 4.5, 0.0, 5.0)),
            custom_index: 10 + k,
            sbt_offset: 0,
            active: true,
        })
        .collect();
    let records: Vec<_> = scene
        .iter()
        .zip(&built.blases)
        .map(|(i, b)| tlas_record(i, b, 0x01))
        .collect();
    let rays: Vec<GpuRay> = (0..4)
        .map(|k| GpuRay {
            origin: [3.0 * k as f32 - 4.5, 0.25, 0.0],
            t_min: 0.0,
            direction: [0.0, 0.0, 1.0],
            t_max: 100.0,
        })
        .collect();
    let pipeline = TestTracer::preferred(&h, &CountingBoxConfig::default());
    let (tlas, out) = trace(&h, &pipeline, &records, 4, &rays, 0xFF, 8);
    let hit: Vec<u32> = out.hits.iter().map(|h| h.custom_index).collect();
    assert_eq!(hit, [10, 11, 12, 13]);
    assert!(out.hits.iter().all(|h| (h.t - 5.0).abs() < 1e-4));

    // Dropping everything returns every allocation while the context lives.
    drop((tlas, pipeline, built, scratch, pool, quad, mapped, gpu_only));
    let stats = ctx.memory_stats();
    assert_eq!((stats.buffers, stats.bytes), (0, 0), "{stats:?}");
    assert_eq!(allocations(), frees());
    assert!(allocations() >= 10, "{}", allocations());
    assert_eq!(*counts.live_at_drop.lock().unwrap(), None);
    assert_no_validation_errors(&h);
    drop(h);
    // The context dropped its allocator (before the device) with nothing live.
    assert_eq!(*counts.live_at_drop.lock().unwrap(), Some(0));
}

pub fn gpu_allocator_packs_buffers_into_blocks_with_exact_stats() {
    let h = headless("gpu_allocator_packs_buffers_into_blocks_with_exact_stats");
    let ctx = h.context();
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let mut buffers = Vec::new();
    for i in 0..64u64 {
        let location = if i % 2 == 0 {
            MemoryLocation::GpuOnly
        } else {
            MemoryLocation::CpuToGpu
        };
        buffers.push(Buffer::new(ctx, 1000 + 16 * i, storage, location).unwrap());
    }
    // Mapped writes land in each buffer's own range of the shared block.
    for (i, b) in buffers.iter_mut().enumerate().skip(1).step_by(2) {
        b.write(0, &[i as u32; 8]).unwrap();
    }
    for (i, b) in buffers.iter().enumerate().skip(1).step_by(2) {
        assert_eq!(b.read::<u32>(0, 8).unwrap(), [i as u32; 8]);
    }
    let stats = ctx.memory_stats();
    assert_eq!(stats.buffers, 64);
    assert_eq!(
        stats.bytes,
        buffers.iter().map(Buffer::allocation_size).sum::<u64>()
    );
    let blocks = stats
        .allocator_blocks
        .expect("gpu-allocator reports blocks");
    // 64 buffers, at most one block per memory type used (not one each).
    assert!(blocks.blocks >= 1 && blocks.blocks <= 4, "{blocks:?}");
    assert!(blocks.bytes >= stats.bytes);
    assert_eq!(stats.block_overhead(), Some(blocks.bytes - stats.bytes));
    // Distinct device addresses, no overlaps among buffers of one kind.
    let mut ranges: Vec<_> = buffers
        .iter()
        .map(|b| (b.device_address(), b.size()))
        .collect();
    ranges.sort();
    for w in ranges.windows(2) {
        assert!(w[0].0 + w[0].1 <= w[1].0, "{w:?}");
    }
    drop(buffers);
    let stats = ctx.memory_stats();
    assert_eq!((stats.buffers, stats.bytes), (0, 0));
    assert_no_validation_errors(&h);
}
