//! Shader binding table layout ([`SbtLayout`]): record strides and region
//! offsets from a device's [`RayTracingPipelineProperties`], and the table's
//! bytes from the pipeline's group handles ([`SbtLayout::write`]). lipac's
//! pipeline tracers use it; an engine can lay out its own table with it.

use crate::error::{Result, VkError};
use crate::memory::align_up;
use crate::tracing_paths::RayTracingPipelineProperties;
use ash::vk;

/// One region of a shader binding table: `count` records of `stride` bytes
/// from `offset` (relative to the table's base address, a multiple of
/// `shaderGroupBaseAlignment`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct SbtRegion {
    /// Byte offset of the first record from the table's base.
    pub offset: u64,
    /// Bytes per record: the handle and the record's data, rounded up to
    /// `shaderGroupHandleAlignment`.
    pub stride: u64,
    /// Records.
    pub count: u32,
}

impl SbtRegion {
    /// Bytes of the region (`stride × count`).
    pub fn size(&self) -> u64 {
        self.stride * u64::from(self.count)
    }

    /// The `VkStridedDeviceAddressRegionKHR` of the region in a table at
    /// `base` (an all-zero region when it has no records).
    pub fn device_region(&self, base: vk::DeviceAddress) -> vk::StridedDeviceAddressRegionKHR {
        if self.count == 0 {
            return vk::StridedDeviceAddressRegionKHR::default();
        }
        vk::StridedDeviceAddressRegionKHR::default()
            .device_address(base + self.offset)
            .stride(self.stride)
            .size(self.size())
    }
}

/// The four regions of a shader binding table (ray generation, miss, hit,
/// callable) for a device's handle size and alignments.
///
/// Each record is a group handle followed by `data` bytes of shader-record
/// data (`shaderRecordEXT`); strides are rounded up to
/// `shaderGroupHandleAlignment`, regions start at multiples of
/// `shaderGroupBaseAlignment`, and the ray-generation region holds one
/// record whose size equals its stride, as `vkCmdTraceRaysKHR` requires.
///
/// ```
/// use lipac_vk::{RayTracingPipelineProperties, SbtLayout, SbtRecords};
/// // An NVIDIA-like device: 32-byte handles, 32-byte record alignment,
/// // 64-byte region alignment.
/// let props = RayTracingPipelineProperties {
///     handle_size: 32, handle_alignment: 32, base_alignment: 64,
///     max_stride: 4096, max_recursion_depth: 31,
/// };
/// let layout = SbtLayout::new(&props, &SbtRecords {
///     miss: 1, hit: 6, callable: 0, raygen_data: 0, miss_data: 0, hit_data: 4, callable_data: 0,
/// })?;
/// assert_eq!(layout.hit.stride, 64); // 32-byte handle + 4 bytes, rounded to 32
/// assert_eq!(layout.miss.offset, 64);
/// assert_eq!(layout.hit.offset, 128);
/// assert_eq!(layout.size(), 128 + 6 * 64);
/// # Ok::<(), lipac_vk::VkError>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct SbtLayout {
    /// The ray-generation region (one record).
    pub raygen: SbtRegion,
    /// The miss region.
    pub miss: SbtRegion,
    /// The hit-group region.
    pub hit: SbtRegion,
    /// The callable region.
    pub callable: SbtRegion,
    handle_size: u32,
    base_alignment: u64,
}

/// How many records each region holds and how many bytes of shader-record
/// data follow each handle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct SbtRecords {
    /// Miss records.
    pub miss: u32,
    /// Hit-group records.
    pub hit: u32,
    /// Callable records.
    pub callable: u32,
    /// Data bytes after the ray-generation handle.
    pub raygen_data: u32,
    /// Data bytes after each miss handle.
    pub miss_data: u32,
    /// Data bytes after each hit-group handle.
    pub hit_data: u32,
    /// Data bytes after each callable handle.
    pub callable_data: u32,
}

impl SbtLayout {
    /// Lays out `records` for a device with `props`.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] when a stride exceeds
    /// `maxShaderGroupStride`, an alignment is not a power of two, the
    /// handle size is 0, or the table's size overflows.
    pub fn new(props: &RayTracingPipelineProperties, records: &SbtRecords) -> Result<Self> {
        let handle_align = u64::from(props.handle_alignment.max(1));
        let base_align = u64::from(props.base_alignment.max(1));
        if !handle_align.is_power_of_two() || !base_align.is_power_of_two() {
            return Err(VkError::InvalidArgument(format!(
                "shader group alignments {handle_align} / {base_align} are not powers of two"
            )));
        }
        if props.handle_size == 0 {
            return Err(VkError::InvalidArgument(
                "shader group handle size 0".into(),
            ));
        }
        let overflow = || VkError::InvalidArgument("shader binding table too large".into());
        let stride = |data: u32| -> Result<u64> {
            let s = align_up(u64::from(props.handle_size) + u64::from(data), handle_align)
                .ok_or_else(overflow)?;
            if s > u64::from(props.max_stride) {
                return Err(VkError::InvalidArgument(format!(
                    "shader record of {s} bytes exceeds maxShaderGroupStride {}",
                    props.max_stride
                )));
            }
            Ok(s)
        };
        let mut offset = 0u64;
        let mut region = |count: u32, data: u32| -> Result<SbtRegion> {
            let r = SbtRegion {
                offset,
                stride: stride(data)?,
                count,
            };
            let end = r
                .stride
                .checked_mul(u64::from(count))
                .and_then(|s| s.checked_add(offset))
                .ok_or_else(overflow)?;
            offset = align_up(end, base_align).ok_or_else(overflow)?;
            Ok(r)
        };
        let raygen = region(1, records.raygen_data)?;
        let miss = region(records.miss, records.miss_data)?;
        let hit = region(records.hit, records.hit_data)?;
        let callable = region(records.callable, records.callable_data)?;
        Ok(Self {
            raygen,
            miss,
            hit,
            callable,
            handle_size: props.handle_size,
            base_alignment: base_align,
        })
    }

    /// Bytes from the table's base to the end of its last region.
    pub fn size(&self) -> u64 {
        [self.raygen, self.miss, self.hit, self.callable]
            .iter()
            .map(|r| r.offset + r.size())
            .max()
            .unwrap_or(0)
    }

    /// Bytes to allocate so that a base aligned to
    /// `shaderGroupBaseAlignment` fits in a buffer at any address that is a
    /// multiple of `buffer_alignment`: [`SbtLayout::size`] plus the slack
    /// [`SbtLayout::base_offset`] may skip.
    pub fn allocation_size(&self, buffer_alignment: u64) -> u64 {
        let slack = self
            .base_alignment
            .saturating_sub(buffer_alignment.max(1).min(self.base_alignment));
        self.size() + slack
    }

    /// Offset of the table's base within a buffer at `buffer_address`: up
    /// to the next multiple of `shaderGroupBaseAlignment`.
    pub fn base_offset(&self, buffer_address: vk::DeviceAddress) -> u64 {
        buffer_address.next_multiple_of(self.base_alignment) - buffer_address
    }

    /// The four regions in a table whose base is at `base`, in
    /// `vkCmdTraceRaysKHR`'s order (ray generation, miss, hit, callable).
    pub fn device_regions(
        &self,
        base: vk::DeviceAddress,
    ) -> [vk::StridedDeviceAddressRegionKHR; 4] {
        [
            self.raygen.device_region(base),
            self.miss.device_region(base),
            self.hit.device_region(base),
            self.callable.device_region(base),
        ]
    }

    /// The table's bytes ([`SbtLayout::size`]): each region's records as
    /// `groups(region)[i] = (group index, data)`, the handle of that group
    /// taken from `handles` (`vkGetRayTracingShaderGroupHandlesKHR` of every
    /// group, `handle_size` bytes each) and the data after it.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] when a region gets another number of
    /// records than laid out, a group index is past `handles`, or data is
    /// longer than the record's room.
    pub fn write(&self, handles: &[u8], records: [&[(u32, &[u8])]; 4]) -> Result<Vec<u8>> {
        let size = usize::try_from(self.size())
            .map_err(|_| VkError::InvalidArgument("shader binding table too large".into()))?;
        let mut out = vec![0u8; size];
        let hs = self.handle_size as usize;
        let regions = [self.raygen, self.miss, self.hit, self.callable];
        for (k, (region, recs)) in regions.iter().zip(records).enumerate() {
            if recs.len() != region.count as usize {
                return Err(VkError::InvalidArgument(format!(
                    "SBT region {k}: {} records for {} laid out",
                    recs.len(),
                    region.count
                )));
            }
            for (i, (group, data)) in recs.iter().enumerate() {
                let src = (*group as usize)
                    .checked_mul(hs)
                    .and_then(|s| handles.get(s..s + hs))
                    .ok_or_else(|| {
                        VkError::InvalidArgument(format!("SBT group {group} has no handle"))
                    })?;
                if hs + data.len() > region.stride as usize {
                    return Err(VkError::InvalidArgument(format!(
                        "SBT region {k} record {i}: {} data bytes do not fit a {}-byte record",
                        data.len(),
                        region.stride
                    )));
                }
                let at = (region.offset + region.stride * i as u64) as usize;
                out[at..at + hs].copy_from_slice(src);
                out[at + hs..at + hs + data.len()].copy_from_slice(data);
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests;
