//! Acceleration-structure storage sub-allocated from large buffers.
//!
//! A [`AccelerationStructurePool`] owns a few large `GpuOnly` buffers
//! ("blocks", each with memory from the context's
//! [`DeviceAllocator`](crate::DeviceAllocator)), hands out 256-byte aligned
//! ranges inside them with lipac-core's [`TlsfAllocator`] (one allocator per
//! block), and creates `VkAccelerationStructureKHR` objects at those offsets.
//! When no block has room, a new block is added (`block_size` bytes, or the
//! request rounded up to 256 when it is larger). Dropping a pooled
//! [`AccelerationStructure`] destroys the object and returns its range.
//! Empty blocks are released by [`AccelerationStructurePool::trim`].
//!
//! Many small BLASes then cost a few allocator calls instead of one each,
//! structures share blocks without the device allocator's per-allocation
//! bookkeeping, and the pool reports its occupancy ([`PoolStats`]).

use crate::accel::AccelerationStructure;
use crate::context::DeviceContext;
use crate::error::{Result, VkError};
use crate::memory::{align_up, Buffer, MemoryLocation};
use ash::vk;
use lipac_core::allocator::{AllocError, AllocHandle, TlsfAllocator};
use std::sync::{Arc, Mutex, MutexGuard};

/// Offset alignment of an acceleration structure inside its buffer
/// (`VkAccelerationStructureCreateInfoKHR::offset` must be a multiple of 256).
pub const AS_OFFSET_ALIGNMENT: u64 = 256;

/// Default size of one pool block: 64 MiB.
pub const DEFAULT_POOL_BLOCK_SIZE: u64 = 64 << 20;

#[derive(Debug)]
struct PoolBlock {
    id: u64,
    buffer: Buffer,
    alloc: TlsfAllocator,
}

#[derive(Debug)]
struct PoolState {
    blocks: Vec<PoolBlock>,
    next_id: u64,
}

#[derive(Debug)]
pub(crate) struct PoolShared {
    ctx: DeviceContext,
    block_size: u64,
    state: Mutex<PoolState>,
}

impl PoolShared {
    fn lock(&self) -> MutexGuard<'_, PoolState> {
        // A panic while holding the lock cannot leave the allocator half
        // updated in a way that matters more than losing the pool: keep going.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// A range of a pool block held by one acceleration structure; returned to
/// the pool on drop (after the structure itself was destroyed).
#[derive(Debug)]
pub(crate) struct PoolRange {
    pool: Arc<PoolShared>,
    block: u64,
    handle: AllocHandle,
    pub(crate) offset: u64,
    pub(crate) size: u64,
}

impl Drop for PoolRange {
    fn drop(&mut self) {
        let mut state = self.pool.lock();
        if let Some(b) = state.blocks.iter_mut().find(|b| b.id == self.block) {
            // A range is freed exactly once (here), so the handle is live.
            let _ = b.alloc.free(self.handle);
        }
    }
}

/// Occupancy of an [`AccelerationStructurePool`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PoolStats {
    /// Blocks (buffers with memory from the context's allocator).
    pub blocks: usize,
    /// Bytes of all blocks.
    pub capacity_bytes: u64,
    /// Bytes in live acceleration structures.
    pub used_bytes: u64,
    /// Free bytes (including alignment padding).
    pub free_bytes: u64,
    /// Largest free range of any block.
    pub largest_free_range: u64,
    /// Free ranges over all blocks.
    pub free_ranges: usize,
    /// Live acceleration structures.
    pub allocation_count: usize,
    /// External fragmentation `1 - largest_free_range / free_bytes` over all
    /// blocks (0 when nothing is free).
    pub fragmentation: f64,
}

/// Acceleration-structure storage in large blocks; see the module docs.
///
/// Cloning gives another handle to the same pool. Structures it created keep
/// the pool alive.
///
/// ```no_run
/// use ash::vk;
/// use lipac_vk::{AccelerationStructurePool, HeadlessContext, Validation};
/// let headless = HeadlessContext::new(Validation::Off)?;
/// let pool = AccelerationStructurePool::new(headless.context(), 1 << 20)?;
/// let a = pool.create(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL, 1000)?;
/// let b = pool.create(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL, 1000)?;
/// assert_eq!(b.pool_offset(), Some(1024)); // 256-byte aligned, same block
/// assert_eq!(pool.stats().used_bytes, 2000);
/// drop(a);
/// assert_eq!(pool.stats().allocation_count, 1);
/// # Ok::<(), lipac_vk::VkError>(())
/// ```
#[derive(Clone, Debug)]
pub struct AccelerationStructurePool {
    shared: Arc<PoolShared>,
}

impl AccelerationStructurePool {
    /// A pool adding blocks of `block_size` bytes (at least 256; rounded up to
    /// a multiple of 256). No memory is allocated before the first
    /// [`AccelerationStructurePool::create`].
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for a block size below 256.
    pub fn new(ctx: &DeviceContext, block_size: u64) -> Result<Self> {
        if block_size < AS_OFFSET_ALIGNMENT {
            return Err(VkError::InvalidArgument(format!(
                "pool block size {block_size} below {AS_OFFSET_ALIGNMENT}"
            )));
        }
        let block_size = align_up(block_size, AS_OFFSET_ALIGNMENT)
            .ok_or_else(|| VkError::InvalidArgument("pool block size overflows".into()))?;
        Ok(Self {
            shared: Arc::new(PoolShared {
                ctx: ctx.clone(),
                block_size,
                state: Mutex::new(PoolState {
                    blocks: Vec::new(),
                    next_id: 0,
                }),
            }),
        })
    }

    /// The size of a regular block.
    pub fn block_size(&self) -> u64 {
        self.shared.block_size
    }

    /// The context it belongs to.
    pub fn context(&self) -> &DeviceContext {
        &self.shared.ctx
    }

    /// Whether two handles name the same pool.
    pub fn same_as(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.shared, &other.shared)
    }

    /// Creates an (unbuilt) acceleration structure of `size` bytes at a
    /// 256-byte aligned offset of a block, adding a block when none has room.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for size 0; as [`Buffer::new`] when a
    /// block is added; [`VkError::Vulkan`] when creation fails (the range is
    /// returned).
    pub fn create(
        &self,
        ty: vk::AccelerationStructureTypeKHR,
        size: u64,
    ) -> Result<AccelerationStructure> {
        let range = self.allocate(size)?;
        let buffer = {
            let state = self.shared.lock();
            state
                .blocks
                .iter()
                .find(|b| b.id == range.block)
                .map(|b| b.buffer.raw())
                .ok_or_else(|| VkError::InvalidArgument("pool block vanished".into()))?
        };
        AccelerationStructure::in_pool_range(&self.shared.ctx, ty, buffer, range)
    }

    fn allocate(&self, size: u64) -> Result<PoolRange> {
        if size == 0 {
            return Err(VkError::InvalidArgument(
                "acceleration structure of size 0".into(),
            ));
        }
        let alloc_err = |e: AllocError| VkError::InvalidArgument(format!("pool allocation: {e}"));
        let mut state = self.shared.lock();
        for b in &mut state.blocks {
            match b.alloc.allocate_aligned(size, AS_OFFSET_ALIGNMENT) {
                Ok(a) => {
                    return Ok(PoolRange {
                        pool: self.shared.clone(),
                        block: b.id,
                        handle: a.handle,
                        offset: a.offset,
                        size,
                    })
                }
                Err(AllocError::OutOfSpace { .. }) => {}
                Err(e) => return Err(alloc_err(e)),
            }
        }
        // No room anywhere: add a block (large requests get one of their own size).
        let block_bytes = align_up(size, AS_OFFSET_ALIGNMENT)
            .ok_or_else(|| VkError::InvalidArgument(format!("structure of {size} bytes")))?
            .max(self.shared.block_size);
        let buffer = Buffer::named(
            &self.shared.ctx,
            "lipac acceleration-structure pool block",
            block_bytes,
            vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR,
            MemoryLocation::GpuOnly,
        )?;
        let mut alloc = TlsfAllocator::new(block_bytes);
        let a = alloc
            .allocate_aligned(size, AS_OFFSET_ALIGNMENT)
            .map_err(alloc_err)?;
        let id = state.next_id;
        state.next_id += 1;
        state.blocks.push(PoolBlock { id, buffer, alloc });
        Ok(PoolRange {
            pool: self.shared.clone(),
            block: id,
            handle: a.handle,
            offset: a.offset,
            size,
        })
    }

    /// Releases blocks holding no acceleration structure; returns how many.
    /// (Their structures were dropped, which by the drop rule means the GPU
    /// no longer uses them.)
    pub fn trim(&self) -> usize {
        let mut state = self.shared.lock();
        let before = state.blocks.len();
        state.blocks.retain(|b| b.alloc.allocation_count() > 0);
        before - state.blocks.len()
    }

    /// Occupancy over all blocks.
    pub fn stats(&self) -> PoolStats {
        let state = self.shared.lock();
        let mut s = PoolStats {
            blocks: state.blocks.len(),
            ..PoolStats::default()
        };
        for b in &state.blocks {
            let a = b.alloc.stats();
            s.capacity_bytes += a.capacity;
            s.used_bytes += a.used_bytes;
            s.free_bytes += a.free_bytes;
            s.largest_free_range = s.largest_free_range.max(a.largest_free_block);
            s.free_ranges += a.free_block_count;
            s.allocation_count += a.allocation_count;
        }
        if s.free_bytes > 0 {
            s.fragmentation = 1.0 - s.largest_free_range as f64 / s.free_bytes as f64;
        }
        s
    }

    /// Bytes of device memory the blocks hold (their buffers' memory
    /// requirements, exact; the allocator's own blocks are in
    /// [`DeviceContext::memory_stats`]).
    pub fn memory_bytes(&self) -> u64 {
        let state = self.shared.lock();
        state
            .blocks
            .iter()
            .map(|b| b.buffer.allocation_size())
            .sum()
    }
}
