//! Buffers with device addresses, and host-visible upload/readback.
//!
//! Every [`Buffer`] takes its memory from the context's
//! [`DeviceAllocator`](crate::DeviceAllocator) ([`crate::GpuAllocator`] on
//! gpu-allocator unless the engine plugged in its own), bound at the offset
//! the allocator returns. The sizes lipac reports are the buffers' memory
//! requirements, exact whatever the allocator's blocks look like
//! ([`crate::DeviceContext::memory_stats`]).

use crate::context::DeviceContext;
use crate::device_allocator::{AllocationRequest, DeviceAllocation};
use crate::error::{Result, VkContext, VkError};
use ash::vk;
#[cfg(test)]
use ash::vk::Handle;
use bytemuck::Pod;

/// Where a buffer's memory lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MemoryLocation {
    /// Device-local, not mapped.
    GpuOnly,
    /// Host-visible and coherent, mapped: the CPU writes, the GPU reads.
    CpuToGpu,
    /// Host-visible and coherent (cached where possible), mapped: the GPU
    /// writes, the CPU reads.
    GpuToCpu,
}

/// A `VkBuffer` with device memory from the context's allocator and a
/// device address.
///
/// Every buffer is created with `SHADER_DEVICE_ADDRESS` usage (added to what
/// the caller asks for). Dropping it destroys the buffer and returns its
/// memory to the allocator: keep it alive until the GPU has finished every
/// submission that uses it.
pub struct Buffer {
    ctx: DeviceContext,
    raw: vk::Buffer,
    /// `Some` until dropped.
    allocation: Option<DeviceAllocation>,
    size: u64,
    allocation_size: u64,
    address: vk::DeviceAddress,
    usage: vk::BufferUsageFlags,
    location: MemoryLocation,
    mapped: *mut u8,
}

// SAFETY: the mapped pointer is only dereferenced through `&mut self` (writes)
// or `&self` (reads of plain bytes); Vulkan handles are plain identifiers that
// may be used from any thread; the allocator is `Send + Sync`.
unsafe impl Send for Buffer {}
// SAFETY: see `Send`; shared references only read.
unsafe impl Sync for Buffer {}

impl std::fmt::Debug for Buffer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Buffer")
            .field("size", &self.size)
            .field("address", &format_args!("{:#x}", self.address))
            .field("usage", &self.usage)
            .field("location", &self.location)
            .finish_non_exhaustive()
    }
}

/// Checks an allocator's answer against the request (the parts lipac can
/// check; see the [`crate::DeviceAllocator`] contract).
fn check_allocation(
    a: &DeviceAllocation,
    req: &vk::MemoryRequirements,
    location: MemoryLocation,
    name: &str,
) -> Result<()> {
    if a.memory == vk::DeviceMemory::null() {
        return Err(VkError::Allocator(format!("{name}: null memory")));
    }
    if req.alignment > 1 && a.offset % req.alignment != 0 {
        return Err(VkError::Allocator(format!(
            "{name}: offset {} is not a multiple of the alignment {}",
            a.offset, req.alignment
        )));
    }
    if a.size < req.size {
        return Err(VkError::Allocator(format!(
            "{name}: {} bytes for a requirement of {}",
            a.size, req.size
        )));
    }
    if location != MemoryLocation::GpuOnly && a.mapped.is_none() {
        return Err(VkError::Allocator(format!(
            "{name}: {location:?} memory without a mapping"
        )));
    }
    Ok(())
}

impl Buffer {
    /// Creates a buffer of `size` bytes (`size > 0`), named `"lipac buffer"`
    /// in the allocator.
    ///
    /// # Errors
    ///
    /// As [`Buffer::named`].
    pub fn new(
        ctx: &DeviceContext,
        size: u64,
        usage: vk::BufferUsageFlags,
        location: MemoryLocation,
    ) -> Result<Self> {
        Self::named(ctx, "lipac buffer", size, usage, location)
    }

    /// Creates a buffer of `size` bytes (`size > 0`) with memory from the
    /// context's allocator, which sees `name` (debugging tools, allocator
    /// reports).
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for size 0; [`VkError::Vulkan`] when
    /// creation or binding fails; the allocator's error
    /// ([`VkError::NoMemoryType`], [`VkError::Vulkan`] out of memory,
    /// [`VkError::Allocator`]).
    pub fn named(
        ctx: &DeviceContext,
        name: &str,
        size: u64,
        usage: vk::BufferUsageFlags,
        location: MemoryLocation,
    ) -> Result<Self> {
        if size == 0 {
            return Err(VkError::InvalidArgument("buffer size 0".into()));
        }
        let usage = usage | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS;
        let device = ctx.device();
        let info = vk::BufferCreateInfo::default()
            .size(size)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: valid device; the create info is fully initialised.
        let raw = unsafe { device.create_buffer(&info, None) }.ctx("vkCreateBuffer")?;
        // From here, destroy `raw` on every error path.
        let destroy_buffer = || {
            // SAFETY: `raw` was created above; the GPU never used it.
            unsafe { device.destroy_buffer(raw, None) }
        };
        // SAFETY: `raw` is a valid buffer of `device`.
        let req = unsafe { device.get_buffer_memory_requirements(raw) };
        let allocator = ctx.allocator();
        let request = AllocationRequest {
            name,
            buffer: raw,
            usage,
            requirements: req,
            location,
        };
        let allocation = match allocator.allocate(&request) {
            Ok(a) => a,
            Err(e) => {
                destroy_buffer();
                return Err(e);
            }
        };
        let bound = check_allocation(&allocation, &req, location, name).and_then(|()| {
            // SAFETY: by the allocator's contract (and the checks above) the
            // range is memory of this device, of a type the buffer allows,
            // aligned, at least `req.size` bytes and used by nothing else.
            unsafe { device.bind_buffer_memory(raw, allocation.memory, allocation.offset) }
                .ctx("vkBindBufferMemory")
        });
        if let Err(e) = bound {
            destroy_buffer();
            allocator.free(allocation);
            return Err(e);
        }
        let mapped = match (location, allocation.mapped) {
            (MemoryLocation::GpuOnly, _) | (_, None) => std::ptr::null_mut(),
            (_, Some(p)) => p.as_ptr(),
        };
        // SAFETY: the buffer has SHADER_DEVICE_ADDRESS usage and bound memory
        // allocated with the DEVICE_ADDRESS flag (allocator contract).
        let address = unsafe {
            device.get_buffer_device_address(&vk::BufferDeviceAddressInfo::default().buffer(raw))
        };
        ctx.memory_counters().add(req.size);
        Ok(Self {
            ctx: ctx.clone(),
            raw,
            allocation: Some(allocation),
            size,
            allocation_size: req.size,
            address,
            usage,
            location,
            mapped,
        })
    }

    /// Creates a mapped buffer holding `data` (`CpuToGpu` or `GpuToCpu`).
    ///
    /// # Errors
    ///
    /// As [`Buffer::new`]; [`VkError::NotMapped`] for `GpuOnly` and
    /// [`VkError::InvalidArgument`] for empty data.
    pub fn with_data<T: Pod>(
        ctx: &DeviceContext,
        usage: vk::BufferUsageFlags,
        location: MemoryLocation,
        data: &[T],
    ) -> Result<Self> {
        if location == MemoryLocation::GpuOnly {
            return Err(VkError::NotMapped);
        }
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let mut buffer = Self::new(ctx, bytes.len() as u64, usage, location)?;
        buffer.write(0, data)?;
        Ok(buffer)
    }

    /// The `VkBuffer`.
    pub fn raw(&self) -> vk::Buffer {
        self.raw
    }
    /// Size in bytes as requested.
    pub fn size(&self) -> u64 {
        self.size
    }
    /// Bytes of device memory the buffer holds: its memory requirement
    /// (the allocator's range may be larger, its block much larger).
    pub fn allocation_size(&self) -> u64 {
        self.allocation_size
    }
    /// The buffer's device address.
    pub fn device_address(&self) -> vk::DeviceAddress {
        self.address
    }
    /// The usage flags it was created with (including `SHADER_DEVICE_ADDRESS`).
    pub fn usage(&self) -> vk::BufferUsageFlags {
        self.usage
    }
    /// Where its memory lives.
    pub fn location(&self) -> MemoryLocation {
        self.location
    }
    /// The context it belongs to.
    pub fn context(&self) -> &DeviceContext {
        &self.ctx
    }

    fn check_range(&self, offset: u64, len: u64) -> Result<()> {
        if self.mapped.is_null() {
            return Err(VkError::NotMapped);
        }
        match offset.checked_add(len) {
            Some(end) if end <= self.size => Ok(()),
            _ => Err(VkError::OutOfBounds {
                offset,
                len,
                size: self.size,
            }),
        }
    }

    /// Writes `data` at byte `offset` of a mapped buffer.
    ///
    /// The memory is host-coherent: writes are visible to the GPU for every
    /// later queue submission. Do not write while the GPU reads the range.
    ///
    /// # Errors
    ///
    /// [`VkError::NotMapped`], [`VkError::OutOfBounds`].
    pub fn write<T: Pod>(&mut self, offset: u64, data: &[T]) -> Result<()> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        self.check_range(offset, bytes.len() as u64)?;
        // SAFETY: the range is inside the mapped allocation (checked above) and
        // `&mut self` excludes other CPU access through this buffer.
        unsafe {
            std::ptr::copy_nonoverlapping(
                bytes.as_ptr(),
                self.mapped.add(offset as usize),
                bytes.len(),
            )
        };
        Ok(())
    }

    /// Fills `len` bytes at `offset` of a mapped buffer with zero.
    ///
    /// # Errors
    ///
    /// [`VkError::NotMapped`], [`VkError::OutOfBounds`].
    pub fn zero(&mut self, offset: u64, len: u64) -> Result<()> {
        self.check_range(offset, len)?;
        // SAFETY: range checked; exclusive access through `&mut self`.
        unsafe { std::ptr::write_bytes(self.mapped.add(offset as usize), 0, len as usize) };
        Ok(())
    }

    /// Reads `count` values of `T` at byte `offset` of a mapped buffer.
    ///
    /// Call after the GPU work writing the range has completed (fence or
    /// semaphore wait) and was made host-visible with a barrier.
    ///
    /// # Errors
    ///
    /// [`VkError::NotMapped`], [`VkError::OutOfBounds`].
    pub fn read<T: Pod>(&self, offset: u64, count: usize) -> Result<Vec<T>> {
        let len = (count as u64).saturating_mul(std::mem::size_of::<T>() as u64);
        self.check_range(offset, len)?;
        let mut out = vec![T::zeroed(); count];
        let dst: &mut [u8] = bytemuck::cast_slice_mut(&mut out);
        // SAFETY: the range is inside the mapped allocation (checked above);
        // `dst` has exactly `len` bytes; the byte copy needs no alignment.
        unsafe {
            std::ptr::copy_nonoverlapping(
                self.mapped.add(offset as usize),
                dst.as_mut_ptr(),
                dst.len(),
            )
        };
        Ok(out)
    }
}

impl Drop for Buffer {
    fn drop(&mut self) {
        // SAFETY: the buffer belongs to this device and, by the type's
        // contract, the GPU no longer uses it.
        unsafe { self.ctx.device().destroy_buffer(self.raw, None) };
        if let Some(allocation) = self.allocation.take() {
            // The buffer bound to the range is gone: return it, exactly once.
            self.ctx.allocator().free(allocation);
        }
        self.ctx.memory_counters().remove(self.allocation_size);
    }
}

/// Rounds `value` up to a multiple of `align` (a power of two or any
/// non-zero value); `None` on overflow.
pub(crate) fn align_up(value: u64, align: u64) -> Option<u64> {
    let align = align.max(1);
    value.checked_add(align - 1).map(|v| v / align * align)
}

/// A growable scratch buffer for acceleration-structure builds.
///
/// [`ScratchBuffer::reserve`] hands out aligned scratch addresses; the buffer
/// grows geometrically, and a replaced buffer is returned to the caller, who
/// keeps it until the GPU work recorded with it has completed.
#[derive(Debug)]
pub struct ScratchBuffer {
    ctx: DeviceContext,
    buffer: Option<Buffer>,
    alignment: u64,
}

impl ScratchBuffer {
    /// An empty scratch buffer (allocates on first use).
    pub fn new(ctx: &DeviceContext) -> Self {
        Self {
            ctx: ctx.clone(),
            buffer: None,
            alignment: u64::from(ctx.limits().min_scratch_offset_alignment).max(1),
        }
    }

    /// Alignment of every scratch address it hands out
    /// (`minAccelerationStructureScratchOffsetAlignment`).
    pub fn alignment(&self) -> u64 {
        self.alignment
    }

    /// Usable bytes from the aligned base address.
    pub fn capacity(&self) -> u64 {
        self.buffer.as_ref().map_or(0, |b| {
            b.size() - (self.aligned_base_of(b) - b.device_address())
        })
    }

    fn aligned_base_of(&self, b: &Buffer) -> u64 {
        // Addresses are far from u64::MAX; saturate rather than wrap.
        align_up(b.device_address(), self.alignment).unwrap_or(u64::MAX)
    }

    /// The aligned base device address (0 before the first reserve).
    pub fn base_address(&self) -> vk::DeviceAddress {
        self.buffer.as_ref().map_or(0, |b| self.aligned_base_of(b))
    }

    /// Makes at least `bytes` bytes available from [`ScratchBuffer::base_address`].
    /// Returns the previous buffer when it had to be replaced: keep it alive
    /// until GPU work already recorded with it has completed.
    ///
    /// # Errors
    ///
    /// As [`Buffer::new`].
    pub fn reserve(&mut self, bytes: u64) -> Result<Option<Buffer>> {
        if bytes <= self.capacity() {
            return Ok(None);
        }
        let grown = bytes.max(self.capacity().saturating_mul(2));
        let size = grown
            .checked_add(self.alignment)
            .ok_or_else(|| VkError::InvalidArgument(format!("scratch of {bytes} bytes")))?;
        let new = Buffer::named(
            &self.ctx,
            "lipac acceleration-structure build scratch",
            size,
            vk::BufferUsageFlags::STORAGE_BUFFER,
            MemoryLocation::GpuOnly,
        )?;
        Ok(self.buffer.replace(new))
    }
}

#[cfg(test)]
mod tests;
