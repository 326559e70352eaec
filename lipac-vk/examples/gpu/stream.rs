//! The bandwidth reference: `stream_bytes.comp` (lipac-vk's
//! `shaders::STREAM_BYTES_SPV`) reading R bytes and writing W bytes, each
//! once, coalesced.

use ash::vk;
use lipac_vk::{Buffer, DeviceContext, Recorder, VkError};

/// Push constants of `stream_bytes.comp`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct StreamPush {
    src: u64,
    dst: u64,
    read_vec4s: u32,
    write_vec4s: u32,
    magic: u32,
    _pad: u32,
}

const LOCAL_SIZE: u64 = 256;
const MAX_GROUPS: u64 = 65_535;

/// The compute pipeline of the reference.
pub struct StreamKernel {
    ctx: DeviceContext,
    layout: vk::PipelineLayout,
    pipeline: vk::Pipeline,
}

impl StreamKernel {
    pub fn new(ctx: &DeviceContext) -> Result<Self, VkError> {
        let device = ctx.device();
        let words = lipac_vk::shaders::spirv_words(lipac_vk::shaders::STREAM_BYTES_SPV)?;
        let module_info = vk::ShaderModuleCreateInfo::default().code(&words);
        // SAFETY: valid device; the words are SPIR-V (checked by spirv_words
        // and by spirv-val when the module was built).
        let module = unsafe { device.create_shader_module(&module_info, None) }
            .map_err(|e| VkError::vk("vkCreateShaderModule", e))?;
        let range = [vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::COMPUTE)
            .size(std::mem::size_of::<StreamPush>() as u32)];
        let layout_info = vk::PipelineLayoutCreateInfo::default().push_constant_ranges(&range);
        // SAFETY: valid device and create info.
        let layout = match unsafe { device.create_pipeline_layout(&layout_info, None) } {
            Ok(l) => l,
            Err(e) => {
                // SAFETY: the module is unused.
                unsafe { device.destroy_shader_module(module, None) };
                return Err(VkError::vk("vkCreatePipelineLayout", e));
            }
        };
        let stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(module)
            .name(c"main");
        let info = [vk::ComputePipelineCreateInfo::default()
            .stage(stage)
            .layout(layout)];
        // SAFETY: valid device, module and layout.
        let made =
            unsafe { device.create_compute_pipelines(vk::PipelineCache::null(), &info, None) };
        // SAFETY: the module is no longer needed once the pipeline exists.
        unsafe { device.destroy_shader_module(module, None) };
        let pipeline = match made {
            Ok(p) => p[0],
            Err((_, e)) => {
                // SAFETY: the layout is unused.
                unsafe { device.destroy_pipeline_layout(layout, None) };
                return Err(VkError::vk("vkCreateComputePipelines", e));
            }
        };
        Ok(Self {
            ctx: ctx.clone(),
            layout,
            pipeline,
        })
    }

    /// Records one pass reading the first `read_bytes` of `src` and writing
    /// the first `write_bytes` of `dst` (both rounded down to 16 bytes),
    /// between two barriers (earlier writes of any stage finish first; the
    /// pass finishes before later commands).
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        src: &Buffer,
        dst: &Buffer,
        read_bytes: u64,
        write_bytes: u64,
    ) -> Result<(), VkError> {
        if read_bytes > src.size() || write_bytes > dst.size() || dst.size() < 16 {
            return Err(VkError::InvalidArgument(format!(
                "stream of {read_bytes} / {write_bytes} bytes over buffers of {} / {}",
                src.size(),
                dst.size()
            )));
        }
        let vec4s = |b: u64| {
            u32::try_from(b / 16)
                .map_err(|_| VkError::InvalidArgument(format!("{b} bytes in one stream")))
        };
        let push = StreamPush {
            src: src.device_address(),
            dst: dst.device_address(),
            read_vec4s: vec4s(read_bytes)?,
            write_vec4s: vec4s(write_bytes)?,
            magic: 0x9E37_79B9,
            _pad: 0,
        };
        let n = u64::from(push.read_vec4s.max(push.write_vec4s));
        let groups = n.div_ceil(LOCAL_SIZE).clamp(1, MAX_GROUPS) as u32;
        let device = self.ctx.device();
        barrier(rec);
        // SAFETY: recording on this device outside a render pass; the
        // pipeline and layout are this device's; the push constants match
        // the layout's range; the addresses are of live buffers with
        // SHADER_DEVICE_ADDRESS usage (every lipac buffer) covering the
        // bytes read and written (checked above), kept alive by the caller
        // until the submission completes.
        unsafe {
            device.cmd_bind_pipeline(rec.raw(), vk::PipelineBindPoint::COMPUTE, self.pipeline);
            device.cmd_push_constants(
                rec.raw(),
                self.layout,
                vk::ShaderStageFlags::COMPUTE,
                0,
                bytemuck::bytes_of(&push),
            );
            device.cmd_dispatch(rec.raw(), groups, 1, 1);
        }
        barrier(rec);
        Ok(())
    }
}

/// Everything before finishes (and is visible) before everything after.
pub fn barrier(rec: &mut Recorder<'_>) {
    let b = [vk::MemoryBarrier2::default()
        .src_stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)
        .src_access_mask(vk::AccessFlags2::MEMORY_WRITE)
        .dst_stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)
        .dst_access_mask(vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE)];
    let dep = vk::DependencyInfo::default().memory_barriers(&b);
    // SAFETY: recording on the recorder's device with synchronization2.
    unsafe {
        rec.context()
            .device()
            .cmd_pipeline_barrier2(rec.raw(), &dep)
    };
}

/// Records `vkCmdCopyBuffer` of `bytes` from `src` to `dst` between barriers.
pub fn copy(rec: &mut Recorder<'_>, src: &Buffer, dst: &Buffer, bytes: u64) {
    barrier(rec);
    let region = [vk::BufferCopy::default().size(bytes.min(src.size()).min(dst.size()))];
    // SAFETY: recording on this device; both buffers are live with
    // TRANSFER_SRC / TRANSFER_DST usage (the callers create them so) and
    // the region lies inside both.
    unsafe {
        rec.context()
            .device()
            .cmd_copy_buffer(rec.raw(), src.raw(), dst.raw(), &region)
    };
    barrier(rec);
}

impl Drop for StreamKernel {
    fn drop(&mut self) {
        // SAFETY: this device's objects, unused by pending work (every
        // submission was waited for).
        unsafe {
            self.ctx.device().destroy_pipeline(self.pipeline, None);
            self.ctx.device().destroy_pipeline_layout(self.layout, None);
        }
    }
}
