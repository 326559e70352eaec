//! Device memory for lipac's buffers: the [`DeviceAllocator`] trait every
//! [`crate::Buffer`] allocates through, and [`GpuAllocator`], its default
//! implementation on the `gpu-allocator` crate.
//!
//! A [`DeviceContext`](crate::DeviceContext) holds one allocator.
//! [`DeviceContext::from_engine`](crate::DeviceContext::from_engine) and
//! [`HeadlessContext::new`](crate::HeadlessContext::new) create a
//! [`GpuAllocator`] of lipac's own. An engine that already has an allocator
//! (VMA, gpu-allocator, a custom one) implements [`DeviceAllocator`] on it
//! and binds with
//! [`DeviceContext::from_engine_with_allocator`](crate::DeviceContext::from_engine_with_allocator);
//! lipac's memory then comes out of the engine's blocks.
//!
//! For each buffer lipac creates the `VkBuffer` itself, asks the allocator
//! for memory fitting the buffer's `VkMemoryRequirements`
//! ([`AllocationRequest`]), binds the returned [`DeviceAllocation`] at its
//! offset, and hands it back to [`DeviceAllocator::free`] after destroying
//! the buffer.
//!
//! [`FailingAllocator`] wraps any of them and fails allocations on purpose
//! (from the n-th on, until restored): out-of-memory at every allocation of
//! a frame loop, for tests.
//!
//! lipac counts what it holds itself ([`DeviceMemoryStats`]): live buffers
//! and the bytes of their memory requirements, exact whatever the allocator
//! does. What the allocator took from the driver (its blocks, including free
//! space and padding) is reported separately ([`AllocatorBlocks`]) when the
//! allocator knows it.

use crate::error::{Result, VkError};
use crate::memory::MemoryLocation;
use ash::vk;
use std::collections::HashMap;
use std::ptr::NonNull;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};

/// What lipac asks an allocator for: memory for one buffer.
#[derive(Clone, Copy, Debug)]
#[non_exhaustive]
pub struct AllocationRequest<'a> {
    /// A name for debugging tools and allocator reports (e.g.
    /// `"lipac acceleration-structure pool block"`).
    pub name: &'a str,
    /// The buffer the memory is for, created but not bound yet (for
    /// allocators that make dedicated allocations,
    /// `VkMemoryDedicatedAllocateInfo`).
    pub buffer: vk::Buffer,
    /// The buffer's usage; always contains `SHADER_DEVICE_ADDRESS`.
    pub usage: vk::BufferUsageFlags,
    /// `vkGetBufferMemoryRequirements` of the buffer.
    pub requirements: vk::MemoryRequirements,
    /// Where the memory must live (and whether it must be mapped).
    pub location: MemoryLocation,
}

/// Memory an allocator handed out: a range of a `VkDeviceMemory`.
///
/// lipac binds its buffer at `memory` + `offset` and passes the value back
/// to [`DeviceAllocator::free`] unchanged, exactly once.
#[derive(Debug)]
pub struct DeviceAllocation {
    /// The memory object holding the range.
    pub memory: vk::DeviceMemory,
    /// Byte offset of the range in `memory`.
    pub offset: u64,
    /// Bytes of the range (at least the requested `requirements.size`).
    pub size: u64,
    /// Host address of byte `offset` for host-visible locations
    /// ([`MemoryLocation::CpuToGpu`], [`MemoryLocation::GpuToCpu`]); lipac
    /// ignores it for [`MemoryLocation::GpuOnly`].
    pub mapped: Option<NonNull<u8>>,
    /// The allocator's own key for the allocation (lipac never reads it).
    pub id: u64,
}

// SAFETY: the mapped pointer is an address, not a borrow; lipac dereferences
// it only through `Buffer`, whose methods serialise access (`&mut self` for
// writes). Vulkan handles are plain identifiers usable from any thread.
unsafe impl Send for DeviceAllocation {}
// SAFETY: see `Send`; a shared reference gives access to plain values only.
unsafe impl Sync for DeviceAllocation {}

/// What an allocator took from the driver: its `VkDeviceMemory` blocks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AllocatorBlocks {
    /// `VkDeviceMemory` objects.
    pub blocks: usize,
    /// Their bytes (allocated ranges, padding and free space).
    pub bytes: u64,
}

/// The device memory a [`DeviceContext`](crate::DeviceContext)'s buffers
/// hold ([`DeviceContext::memory_stats`](crate::DeviceContext::memory_stats)).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DeviceMemoryStats {
    /// Live [`crate::Buffer`]s.
    pub buffers: u64,
    /// Sum of their memory requirements (`Buffer::allocation_size`): exactly
    /// the memory lipac holds, whatever the allocator's block layout.
    pub bytes: u64,
    /// The allocator's blocks, when it reports them
    /// ([`DeviceAllocator::blocks`]). With an allocator shared with the
    /// engine they hold the engine's resources too.
    pub allocator_blocks: Option<AllocatorBlocks>,
}

impl DeviceMemoryStats {
    /// Bytes of the allocator's blocks beyond what lipac's buffers hold
    /// (free space, alignment padding; the engine's resources when the
    /// allocator is shared). `None` when the allocator reports no blocks.
    pub fn block_overhead(&self) -> Option<u64> {
        self.allocator_blocks
            .map(|b| b.bytes.saturating_sub(self.bytes))
    }
}

/// The allocator lipac takes every buffer's memory from.
///
/// lipac calls it from any thread ([`Send`] + [`Sync`]; use interior
/// locking), and promises to:
///
/// * pass each [`DeviceAllocation`] back to [`DeviceAllocator::free`]
///   exactly once, unchanged, after destroying the buffer bound to it and
///   once the GPU no longer uses it (lipac's drop rule);
/// * never pass an allocation it did not get from this allocator;
/// * read or write mapped memory only inside `offset .. offset +
///   requirements.size` of an allocation.
///
/// `DeviceContext::from_engine` and `HeadlessContext::new` use
/// [`GpuAllocator`]. To plug in an engine's allocator, implement the trait
/// and bind with `DeviceContext::from_engine_with_allocator`:
///
/// ```no_run
/// use std::sync::Arc;
/// use ash::vk;
/// use lipac_vk::{
///     AllocationRequest, DeviceAllocation, DeviceAllocator, DeviceContext, EngineQueue,
///     MemoryLocation, VkError,
/// };
///
/// /// The engine's allocator (VMA or its own), reduced to what lipac calls.
/// struct EngineAllocator { /* ... */ }
/// impl EngineAllocator {
///     fn alloc(&self, req: &vk::MemoryRequirements, host_visible: bool, name: &str)
///         -> Option<(vk::DeviceMemory, u64, *mut u8, u64)> { unimplemented!() }
///     fn release(&self, key: u64) { unimplemented!() }
/// }
///
/// // SAFETY: the engine allocator returns ranges of memory allocated with
/// // VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT (VMA: the allocator was created
/// // with VMA_ALLOCATOR_CREATE_BUFFER_DEVICE_ADDRESS_BIT), of a type in
/// // `memory_type_bits`, aligned, host-visible, coherent and persistently
/// // mapped when asked for, valid until `release`.
/// unsafe impl DeviceAllocator for EngineAllocator {
///     fn allocate(&self, request: &AllocationRequest<'_>) -> Result<DeviceAllocation, VkError> {
///         let host = request.location != MemoryLocation::GpuOnly;
///         let (memory, offset, mapped, key) = self
///             .alloc(&request.requirements, host, request.name)
///             .ok_or_else(|| VkError::Allocator(format!("{}: out of memory", request.name)))?;
///         Ok(DeviceAllocation {
///             memory,
///             offset,
///             size: request.requirements.size,
///             mapped: std::ptr::NonNull::new(mapped),
///             id: key,
///         })
///     }
///     fn free(&self, allocation: DeviceAllocation) {
///         self.release(allocation.id);
///     }
/// }
///
/// # fn bind(instance: &ash::Instance, device: &ash::Device, pd: vk::PhysicalDevice,
/// #         queues: &[EngineQueue], engine_allocator: Arc<EngineAllocator>) -> Result<(), VkError> {
/// // SAFETY: as `DeviceContext::from_engine`; the allocator allocates from `device`.
/// let ctx = unsafe {
///     DeviceContext::from_engine_with_allocator(instance, device, pd, queues, engine_allocator)?
/// };
/// println!("lipac holds {} bytes", ctx.memory_stats().bytes);
/// # Ok(()) }
/// ```
///
/// # Safety
///
/// lipac binds, maps and hands the memory to the GPU on the strength of
/// these promises, so an implementation must keep them for every
/// [`DeviceAllocation`] it returns from `allocate(request)`:
///
/// * `memory` is memory of the context's device, of a memory type in
///   `request.requirements.memory_type_bits`, allocated with
///   `VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT` (`VkMemoryAllocateFlagsInfo`):
///   every lipac buffer has `SHADER_DEVICE_ADDRESS` usage;
/// * `offset` is a multiple of `request.requirements.alignment`, and the
///   `request.requirements.size` bytes from it are used by no other live
///   allocation;
/// * for [`MemoryLocation::CpuToGpu`] and [`MemoryLocation::GpuToCpu`] the
///   memory type is `HOST_VISIBLE | HOST_COHERENT` (lipac does not flush)
///   and `mapped` is the host address of byte `offset` of a mapping;
/// * the memory (and its mapping) stays valid until lipac passes the
///   allocation to `free`.
///
/// lipac checks the alignment, the size and that a mapping is present, and
/// refuses an allocation that fails them ([`VkError::Allocator`]).
pub unsafe trait DeviceAllocator: Send + Sync {
    /// Allocates memory for one buffer.
    ///
    /// # Errors
    ///
    /// Any [`VkError`]; lipac returns it from the call that created the
    /// buffer. [`VkError::Allocator`] carries an allocator's own message.
    fn allocate(&self, request: &AllocationRequest<'_>) -> Result<DeviceAllocation>;

    /// Frees an allocation `allocate` returned. Called from `Drop`: must not
    /// panic.
    fn free(&self, allocation: DeviceAllocation);

    /// The allocator's blocks, for [`DeviceMemoryStats::allocator_blocks`];
    /// `None` (the default) when it does not report them.
    fn blocks(&self) -> Option<AllocatorBlocks> {
        None
    }
}

/// lipac's exact count of what its buffers hold, kept by the context.
#[derive(Debug, Default)]
pub(crate) struct MemoryCounters {
    buffers: AtomicU64,
    bytes: AtomicU64,
}

impl MemoryCounters {
    pub(crate) fn add(&self, bytes: u64) {
        self.buffers.fetch_add(1, Ordering::Relaxed);
        self.bytes.fetch_add(bytes, Ordering::Relaxed);
    }

    pub(crate) fn remove(&self, bytes: u64) {
        self.buffers.fetch_sub(1, Ordering::Relaxed);
        self.bytes.fetch_sub(bytes, Ordering::Relaxed);
    }

    pub(crate) fn snapshot(&self, allocator_blocks: Option<AllocatorBlocks>) -> DeviceMemoryStats {
        DeviceMemoryStats {
            buffers: self.buffers.load(Ordering::Relaxed),
            bytes: self.bytes.load(Ordering::Relaxed),
            allocator_blocks,
        }
    }
}

/// Smallest `VkDeviceMemory` block [`GpuAllocator::new`] allocates for
/// device-local memory: 32 MiB (later blocks double, up to 256 MiB).
pub const GPU_ALLOCATOR_DEVICE_BLOCK_BYTES: u64 = 32 << 20;
/// Smallest block [`GpuAllocator::new`] allocates for host-visible memory:
/// 8 MiB (later blocks double, up to 64 MiB).
pub const GPU_ALLOCATOR_HOST_BLOCK_BYTES: u64 = 8 << 20;

/// lipac's default [`DeviceAllocator`]: the `gpu-allocator` crate's Vulkan
/// allocator (free-list sub-allocation in large blocks), created with
/// buffer-device-address support.
///
/// Requests larger than a block get a block of their own. Blocks are
/// released when their last allocation is freed (gpu-allocator keeps one
/// empty general block per memory type) and all remaining ones when the
/// allocator is dropped.
pub struct GpuAllocator {
    state: Mutex<GpuAllocatorState>,
}

struct GpuAllocatorState {
    allocator: gpu_allocator::vulkan::Allocator,
    live: HashMap<u64, gpu_allocator::vulkan::Allocation>,
    next_id: u64,
}

impl std::fmt::Debug for GpuAllocator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuAllocator")
            .field("live", &self.lock().live.len())
            .field("blocks", &self.blocks())
            .finish_non_exhaustive()
    }
}

impl GpuAllocator {
    /// A gpu-allocator on `device` with lipac's block sizes
    /// ([`GPU_ALLOCATOR_DEVICE_BLOCK_BYTES`], [`GPU_ALLOCATOR_HOST_BLOCK_BYTES`],
    /// doubling per block up to 256 / 64 MiB).
    ///
    /// # Safety
    ///
    /// `instance`, `device` and `physical_device` must be valid and belong
    /// together, and `device` must have `bufferDeviceAddress` enabled. The
    /// allocator frees its blocks when dropped: the device must outlive it.
    ///
    /// # Errors
    ///
    /// [`VkError::Allocator`] when gpu-allocator refuses the description.
    pub unsafe fn new(
        instance: &ash::Instance,
        device: &ash::Device,
        physical_device: vk::PhysicalDevice,
    ) -> Result<Self> {
        // SAFETY: forwarded from this function's contract.
        unsafe {
            Self::with_block_sizes(
                instance,
                device,
                physical_device,
                GPU_ALLOCATOR_DEVICE_BLOCK_BYTES,
                GPU_ALLOCATOR_HOST_BLOCK_BYTES,
            )
        }
    }

    /// As [`GpuAllocator::new`] with the first block sizes given
    /// (gpu-allocator rounds them up to a multiple of 4 MiB within 4 to
    /// 256 MiB; later blocks double up to 256 MiB for device memory and
    /// 64 MiB, or the first size when larger, for host memory).
    ///
    /// # Safety
    ///
    /// As [`GpuAllocator::new`].
    ///
    /// # Errors
    ///
    /// As [`GpuAllocator::new`].
    pub unsafe fn with_block_sizes(
        instance: &ash::Instance,
        device: &ash::Device,
        physical_device: vk::PhysicalDevice,
        device_block_bytes: u64,
        host_block_bytes: u64,
    ) -> Result<Self> {
        let sizes = gpu_allocator::AllocationSizes::new(device_block_bytes, host_block_bytes)
            .with_max_device_memblock_size(256 << 20)
            .with_max_host_memblock_size(64 << 20);
        let mut debug_settings = gpu_allocator::AllocatorDebugSettings::default();
        // lipac frees everything it allocates; leaks are counted by the
        // context, not logged.
        debug_settings.log_leaks_on_shutdown = false;
        let desc = gpu_allocator::vulkan::AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device,
            debug_settings,
            buffer_device_address: true,
            allocation_sizes: sizes,
        };
        // gpu-allocator only queries the physical device here; the handles are
        // valid by this function's contract.
        let allocator = gpu_allocator::vulkan::Allocator::new(&desc).map_err(allocation_error)?;
        Ok(Self {
            state: Mutex::new(GpuAllocatorState {
                allocator,
                live: HashMap::new(),
                next_id: 0,
            }),
        })
    }

    fn lock(&self) -> MutexGuard<'_, GpuAllocatorState> {
        // A panic while the lock was held cannot leave gpu-allocator's state
        // worse than losing the allocator would; keep going.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Live allocations (handed out and not yet freed).
    pub fn live_allocations(&self) -> usize {
        self.lock().live.len()
    }
}

fn allocation_error(e: gpu_allocator::AllocationError) -> VkError {
    match e {
        gpu_allocator::AllocationError::OutOfMemory => {
            VkError::vk("gpu-allocator", vk::Result::ERROR_OUT_OF_DEVICE_MEMORY)
        }
        e => VkError::Allocator(format!("gpu-allocator: {e}")),
    }
}

fn gpu_location(location: MemoryLocation) -> gpu_allocator::MemoryLocation {
    match location {
        MemoryLocation::GpuOnly => gpu_allocator::MemoryLocation::GpuOnly,
        MemoryLocation::CpuToGpu => gpu_allocator::MemoryLocation::CpuToGpu,
        MemoryLocation::GpuToCpu => gpu_allocator::MemoryLocation::GpuToCpu,
    }
}

/// Property flags gpu-allocator requires at least for a location (reported
/// when no memory type fits).
fn required_flags(location: MemoryLocation) -> vk::MemoryPropertyFlags {
    match location {
        MemoryLocation::GpuOnly => vk::MemoryPropertyFlags::DEVICE_LOCAL,
        MemoryLocation::CpuToGpu | MemoryLocation::GpuToCpu => {
            vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT
        }
    }
}

// SAFETY: gpu-allocator was created with `buffer_device_address: true`, so
// every block is allocated with VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT; it
// picks a memory type from `memory_type_bits`, aligns the offset to
// `requirements.alignment`, requires HOST_VISIBLE | HOST_COHERENT for
// CpuToGpu/GpuToCpu and maps such blocks persistently (`mapped_ptr` is the
// address of the allocation's offset); a range stays valid until freed.
// The state is behind a mutex.
unsafe impl DeviceAllocator for GpuAllocator {
    fn allocate(&self, request: &AllocationRequest<'_>) -> Result<DeviceAllocation> {
        let desc = gpu_allocator::vulkan::AllocationCreateDesc {
            name: request.name,
            requirements: request.requirements,
            location: gpu_location(request.location),
            linear: true,
            allocation_scheme: gpu_allocator::vulkan::AllocationScheme::GpuAllocatorManaged,
        };
        let mut state = self.lock();
        let allocation = state.allocator.allocate(&desc).map_err(|e| match e {
            gpu_allocator::AllocationError::NoCompatibleMemoryTypeFound => VkError::NoMemoryType {
                type_bits: request.requirements.memory_type_bits,
                required: required_flags(request.location),
            },
            e => allocation_error(e),
        })?;
        let id = state.next_id;
        state.next_id += 1;
        let out = DeviceAllocation {
            // SAFETY: the allocation is live (just returned) and stays in `live`
            // until `free`, so its memory object is valid.
            memory: unsafe { allocation.memory() },
            offset: allocation.offset(),
            size: allocation.size(),
            mapped: allocation.mapped_ptr().map(|p| p.cast::<u8>()),
            id,
        };
        state.live.insert(id, allocation);
        Ok(out)
    }

    fn free(&self, allocation: DeviceAllocation) {
        let mut state = self.lock();
        if let Some(a) = state.live.remove(&allocation.id) {
            // gpu-allocator only fails to free a range it does not know; the
            // range came from it and is freed once (the `live` entry is gone).
            let _ = state.allocator.free(a);
        }
    }

    fn blocks(&self) -> Option<AllocatorBlocks> {
        let report = self.lock().allocator.generate_report();
        Some(AllocatorBlocks {
            blocks: report.blocks.len(),
            bytes: report.total_capacity_bytes,
        })
    }
}

mod failing;
pub use failing::FailingAllocator;

#[cfg(test)]
mod tests;
