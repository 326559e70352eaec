//! Buffers with device addresses, and host-visible upload/readback.
//!
//! lipac allocates its own memory, one dedicated `VkDeviceMemory` per
//! [`Buffer`]. lipac's buffers are few and large (acceleration-structure
//! storage, scratch, instance and counter arrays), the sizes it reports are
//! then exactly what it holds, and no allocator dependency is needed. (A
//! suballocator for many small BLASes is the natural next step; the
//! [`MemoryLocation`] interface does not change with it.)

use crate::context::DeviceContext;
use crate::error::{Result, VkContext, VkError};
use ash::vk;
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

/// A `VkBuffer` with its own memory and a device address.
///
/// Every buffer is created with `SHADER_DEVICE_ADDRESS` usage (added to what
/// the caller asks for). Dropping it frees the buffer and its memory: keep it
/// alive until the GPU has finished every submission that uses it.
pub struct Buffer {
    ctx: DeviceContext,
    raw: vk::Buffer,
    memory: vk::DeviceMemory,
    size: u64,
    allocation_size: u64,
    address: vk::DeviceAddress,
    usage: vk::BufferUsageFlags,
    location: MemoryLocation,
    mapped: *mut u8,
}

// SAFETY: the mapped pointer is only dereferenced through `&mut self` (writes)
// or `&self` (reads of plain bytes); Vulkan handles are plain identifiers that
// may be used from any thread.
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

fn find_memory_type(
    props: &vk::PhysicalDeviceMemoryProperties,
    type_bits: u32,
    required: vk::MemoryPropertyFlags,
    preferred: vk::MemoryPropertyFlags,
) -> Result<u32> {
    let count = (props.memory_type_count as usize).min(props.memory_types.len());
    let fits = |i: usize, flags: vk::MemoryPropertyFlags| {
        type_bits & (1 << i) != 0 && props.memory_types[i].property_flags.contains(flags)
    };
    (0..count)
        .find(|&i| fits(i, required | preferred))
        .or_else(|| (0..count).find(|&i| fits(i, required)))
        .map(|i| i as u32)
        .ok_or(VkError::NoMemoryType {
            type_bits,
            required,
        })
}

impl Buffer {
    /// Creates a buffer of `size` bytes (`size > 0`).
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for size 0, [`VkError::NoMemoryType`],
    /// [`VkError::Vulkan`] when creation, allocation or mapping fails.
    pub fn new(
        ctx: &DeviceContext,
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
            // SAFETY: `raw` was created above and is not bound or used yet.
            unsafe { device.destroy_buffer(raw, None) }
        };
        // SAFETY: `raw` is a valid buffer of `device`.
        let req = unsafe { device.get_buffer_memory_requirements(raw) };
        let (required, preferred) = match location {
            MemoryLocation::GpuOnly => (
                vk::MemoryPropertyFlags::empty(),
                vk::MemoryPropertyFlags::DEVICE_LOCAL,
            ),
            MemoryLocation::CpuToGpu => (
                vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT,
                vk::MemoryPropertyFlags::empty(),
            ),
            MemoryLocation::GpuToCpu => (
                vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT,
                vk::MemoryPropertyFlags::HOST_CACHED,
            ),
        };
        let type_index = match find_memory_type(
            ctx.memory_properties(),
            req.memory_type_bits,
            required,
            preferred,
        ) {
            Ok(i) => i,
            Err(e) => {
                destroy_buffer();
                return Err(e);
            }
        };
        let mut flags =
            vk::MemoryAllocateFlagsInfo::default().flags(vk::MemoryAllocateFlags::DEVICE_ADDRESS);
        let alloc = vk::MemoryAllocateInfo::default()
            .allocation_size(req.size)
            .memory_type_index(type_index)
            .push_next(&mut flags);
        // SAFETY: valid device; the memory type index comes from the device's
        // own memory properties; bufferDeviceAddress is enabled (context contract).
        let memory = match unsafe { device.allocate_memory(&alloc, None) } {
            Ok(m) => m,
            Err(e) => {
                destroy_buffer();
                return Err(VkError::vk("vkAllocateMemory", e));
            }
        };
        let free_all = || {
            // SAFETY: both objects were created above and are not in use.
            unsafe {
                device.destroy_buffer(raw, None);
                device.free_memory(memory, None);
            }
        };
        // SAFETY: fresh memory of a type the buffer allows, offset 0, size from
        // the buffer's requirements.
        if let Err(e) = unsafe { device.bind_buffer_memory(raw, memory, 0) } {
            free_all();
            return Err(VkError::vk("vkBindBufferMemory", e));
        }
        let mapped = if location == MemoryLocation::GpuOnly {
            std::ptr::null_mut()
        } else {
            // SAFETY: host-visible memory, not mapped yet, whole range.
            match unsafe {
                device.map_memory(memory, 0, vk::WHOLE_SIZE, vk::MemoryMapFlags::empty())
            } {
                Ok(p) => p.cast::<u8>(),
                Err(e) => {
                    free_all();
                    return Err(VkError::vk("vkMapMemory", e));
                }
            }
        };
        // SAFETY: the buffer has SHADER_DEVICE_ADDRESS usage and bound memory
        // allocated with the DEVICE_ADDRESS flag.
        let address = unsafe {
            device.get_buffer_device_address(&vk::BufferDeviceAddressInfo::default().buffer(raw))
        };
        Ok(Self {
            ctx: ctx.clone(),
            raw,
            memory,
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
    /// Bytes of device memory the buffer holds (its memory requirement).
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
        let device = self.ctx.device();
        // SAFETY: the buffer and memory belong to this device and, by the type's
        // contract, the GPU no longer uses them. Freeing memory unmaps it.
        unsafe {
            device.destroy_buffer(self.raw, None);
            device.free_memory(self.memory, None);
        }
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
        let new = Buffer::new(
            &self.ctx,
            size,
            vk::BufferUsageFlags::STORAGE_BUFFER,
            MemoryLocation::GpuOnly,
        )?;
        Ok(self.buffer.replace(new))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn align_up_rounds() {
        assert_eq!(align_up(0, 256), Some(0));
        assert_eq!(align_up(1, 256), Some(256));
        assert_eq!(align_up(256, 256), Some(256));
        assert_eq!(align_up(257, 8), Some(264));
        assert_eq!(align_up(5, 0), Some(5));
        assert_eq!(align_up(u64::MAX, 2), None);
    }

    #[test]
    fn memory_type_prefers_then_falls_back() {
        let mut props = vk::PhysicalDeviceMemoryProperties {
            memory_type_count: 3,
            ..Default::default()
        };
        props.memory_types[0].property_flags = vk::MemoryPropertyFlags::DEVICE_LOCAL;
        props.memory_types[1].property_flags =
            vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
        props.memory_types[2].property_flags = vk::MemoryPropertyFlags::HOST_VISIBLE
            | vk::MemoryPropertyFlags::HOST_COHERENT
            | vk::MemoryPropertyFlags::HOST_CACHED;
        let hv = vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
        let cached = vk::MemoryPropertyFlags::HOST_CACHED;
        assert_eq!(find_memory_type(&props, 0b111, hv, cached), Ok(2));
        assert_eq!(find_memory_type(&props, 0b011, hv, cached), Ok(1));
        assert!(find_memory_type(&props, 0b001, hv, cached).is_err());
    }
}
