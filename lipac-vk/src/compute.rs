//! Compute kernels over storage buffers: one descriptor set layout (only
//! storage buffers), one push-constant block and several pipelines sharing
//! them. The Algorithm 1 and 2 passes are built on this.

use crate::accel::same_context;
use crate::commands::Recorder;
use crate::context::DeviceContext;
use crate::error::{Result, VkContext, VkError};
use crate::memory::Buffer;
use crate::shaders::spirv_words;
use ash::vk;

/// Work-group size of every lipac compute shader (`local_size_x`).
pub(crate) const LOCAL_SIZE: u32 = 64;
/// Work groups per dispatch at most; the shaders stride over larger counts.
const MAX_GROUPS: u32 = 65_535;

/// A descriptor set layout of compute-stage bindings: `kinds[i]` (one
/// descriptor each) at binding `i`.
pub(crate) fn compute_set_layout(
    ctx: &DeviceContext,
    kinds: &[vk::DescriptorType],
) -> Result<vk::DescriptorSetLayout> {
    let bindings: Vec<_> = kinds
        .iter()
        .enumerate()
        .map(|(b, &kind)| {
            vk::DescriptorSetLayoutBinding::default()
                .binding(b as u32)
                .descriptor_type(kind)
                .descriptor_count(1)
                .stage_flags(vk::ShaderStageFlags::COMPUTE)
        })
        .collect();
    let info = vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings);
    // SAFETY: valid device and create info.
    unsafe { ctx.device().create_descriptor_set_layout(&info, None) }
        .ctx("vkCreateDescriptorSetLayout")
}

/// The compute pipeline of `spv` (entry `main`) with `layout`, and the
/// specialization constants `spec` if any; the shader module is destroyed
/// again before this returns.
pub(crate) fn create_compute_pipeline(
    ctx: &DeviceContext,
    spv: &[u8],
    layout: vk::PipelineLayout,
    spec: Option<&vk::SpecializationInfo<'_>>,
) -> Result<vk::Pipeline> {
    let device = ctx.device();
    let words = spirv_words(spv)?;
    let info = vk::ShaderModuleCreateInfo::default().code(&words);
    // SAFETY: valid device; `words` is embedded SPIR-V checked by spirv-val.
    let module = unsafe { device.create_shader_module(&info, None) }.ctx("vkCreateShaderModule")?;
    let mut stage = vk::PipelineShaderStageCreateInfo::default()
        .stage(vk::ShaderStageFlags::COMPUTE)
        .module(module)
        .name(c"main");
    if let Some(spec) = spec {
        stage = stage.specialization_info(spec);
    }
    let info = [vk::ComputePipelineCreateInfo::default()
        .stage(stage)
        .layout(layout)];
    // SAFETY: valid device, module and a layout matching the shader's
    // interface (the callers' bindings and push block).
    let created =
        unsafe { device.create_compute_pipelines(vk::PipelineCache::null(), &info, None) };
    // SAFETY: the module is no longer needed once pipeline creation returned.
    unsafe { device.destroy_shader_module(module, None) };
    created
        .map_err(|(_, e)| VkError::vk("vkCreateComputePipelines", e))?
        .first()
        .copied()
        .ok_or(VkError::vk(
            "vkCreateComputePipelines",
            vk::Result::ERROR_UNKNOWN,
        ))
}

/// The pipeline layout of a compute pipeline: one descriptor set
/// (`set_layout`) and `push_size` bytes of compute push constants.
pub(crate) fn compute_pipeline_layout(
    ctx: &DeviceContext,
    set_layout: vk::DescriptorSetLayout,
    push_size: u32,
) -> Result<vk::PipelineLayout> {
    let set_layouts = [set_layout];
    let push = [vk::PushConstantRange::default()
        .stage_flags(vk::ShaderStageFlags::COMPUTE)
        .offset(0)
        .size(push_size)];
    let info = vk::PipelineLayoutCreateInfo::default()
        .set_layouts(&set_layouts)
        .push_constant_ranges(&push);
    // SAFETY: valid device; `set_layout` is a live layout of that device.
    unsafe { ctx.device().create_pipeline_layout(&info, None) }.ctx("vkCreatePipelineLayout")
}

/// Pipelines sharing one layout of `bindings` storage buffers and a
/// `push_size`-byte push-constant block.
#[derive(Debug)]
pub(crate) struct ComputeKernels {
    ctx: DeviceContext,
    set_layout: vk::DescriptorSetLayout,
    layout: vk::PipelineLayout,
    pipelines: Vec<vk::Pipeline>,
    bindings: u32,
}

/// A descriptor set (with its own pool) for [`ComputeKernels`] (storage
/// buffers) or a ray-query pipeline (a TLAS and storage buffers, see
/// `ray_query`); keep it alive until dispatches using it have executed.
#[derive(Debug)]
pub(crate) struct StorageSet {
    ctx: DeviceContext,
    pool: vk::DescriptorPool,
    set: vk::DescriptorSet,
}

impl ComputeKernels {
    /// Creates the layout and one pipeline per SPIR-V module (entry `main`).
    pub(crate) fn new(
        ctx: &DeviceContext,
        bindings: u32,
        push_size: u32,
        shaders: &[&[u8]],
    ) -> Result<Self> {
        let kinds = vec![vk::DescriptorType::STORAGE_BUFFER; bindings as usize];
        let set_layout = compute_set_layout(ctx, &kinds)?;
        // From here on, Drop frees whatever was created (null handles are ignored).
        let mut this = Self {
            ctx: ctx.clone(),
            set_layout,
            layout: vk::PipelineLayout::null(),
            pipelines: Vec::with_capacity(shaders.len()),
            bindings,
        };
        this.layout = compute_pipeline_layout(ctx, set_layout, push_size)?;
        for spv in shaders {
            let pipeline = create_compute_pipeline(ctx, spv, this.layout, None)?;
            this.pipelines.push(pipeline);
        }
        Ok(this)
    }

    pub(crate) fn context(&self) -> &DeviceContext {
        &self.ctx
    }

    /// A descriptor set with `buffers[i]` (whole) at binding `i`. Checks the
    /// context and `STORAGE_BUFFER` usage; `what` names the buffers in errors.
    pub(crate) fn bind(&self, buffers: &[&Buffer], what: &'static str) -> Result<StorageSet> {
        if buffers.len() != self.bindings as usize {
            return Err(VkError::InvalidArgument(format!(
                "{} buffers for {} bindings",
                buffers.len(),
                self.bindings
            )));
        }
        for b in buffers {
            same_context(&self.ctx, b.context())?;
            if !b.usage().contains(vk::BufferUsageFlags::STORAGE_BUFFER) {
                return Err(VkError::MissingUsage(what));
            }
        }
        let device = self.ctx.device();
        let sizes = [vk::DescriptorPoolSize::default()
            .ty(vk::DescriptorType::STORAGE_BUFFER)
            .descriptor_count(self.bindings)];
        let (pool, set) = allocate_one_set(&self.ctx, &sizes, self.set_layout)?;
        let infos: Vec<[vk::DescriptorBufferInfo; 1]> = buffers
            .iter()
            .map(|b| {
                [vk::DescriptorBufferInfo::default()
                    .buffer(b.raw())
                    .offset(0)
                    .range(vk::WHOLE_SIZE)]
            })
            .collect();
        let writes: Vec<_> = infos
            .iter()
            .enumerate()
            .map(|(i, info)| {
                vk::WriteDescriptorSet::default()
                    .dst_set(set)
                    .dst_binding(i as u32)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .buffer_info(info)
            })
            .collect();
        // SAFETY: the set is fresh and unused; every write matches the layout.
        unsafe { device.update_descriptor_sets(&writes, &[]) };
        Ok(StorageSet::new(&self.ctx, pool, set))
    }

    /// Records a dispatch of pipeline `kernel` over `items` items (nothing
    /// for 0), with `push` as push constants.
    pub(crate) fn dispatch(
        &self,
        rec: &mut Recorder<'_>,
        set: &StorageSet,
        kernel: usize,
        push: &[u8],
        items: u32,
    ) -> Result<()> {
        same_context(rec.context(), &self.ctx)?;
        same_context(&set.ctx, &self.ctx)?;
        let pipeline = *self
            .pipelines
            .get(kernel)
            .ok_or_else(|| VkError::InvalidArgument(format!("no compute kernel {kernel}")))?;
        if items == 0 {
            return Ok(());
        }
        let groups = items.div_ceil(LOCAL_SIZE).min(MAX_GROUPS);
        // Checked above: recorder and set are of this device.
        record_dispatch(rec, pipeline, self.layout, set, push, [groups, 1, 1]);
        Ok(())
    }
}

impl StorageSet {
    /// Takes ownership of `set` and the `pool` it was allocated from (the
    /// pool is destroyed on drop).
    pub(crate) fn new(
        ctx: &DeviceContext,
        pool: vk::DescriptorPool,
        set: vk::DescriptorSet,
    ) -> Self {
        Self {
            ctx: ctx.clone(),
            pool,
            set,
        }
    }

    pub(crate) fn context(&self) -> &DeviceContext {
        &self.ctx
    }

    /// The descriptor set.
    pub(crate) fn raw(&self) -> vk::DescriptorSet {
        self.set
    }
}

/// Records binding compute `pipeline` (of `layout`) and `set`, the push
/// constants `push` at offset 0 and a dispatch of `groups` work groups. The
/// caller checked that `rec` records on the device of the pipeline and the
/// set, and that `push` fits the layout's push range (each passes its
/// fixed-size push struct).
pub(crate) fn record_dispatch(
    rec: &mut Recorder<'_>,
    pipeline: vk::Pipeline,
    layout: vk::PipelineLayout,
    set: &StorageSet,
    push: &[u8],
    groups: [u32; 3],
) {
    let device = set.ctx.device();
    // SAFETY: recording on this device (Recorder contract, checked by the
    // caller); pipeline, layout and set are live and compatible; `push` fits
    // the layout's push range.
    unsafe {
        device.cmd_bind_pipeline(rec.raw(), vk::PipelineBindPoint::COMPUTE, pipeline);
        device.cmd_bind_descriptor_sets(
            rec.raw(),
            vk::PipelineBindPoint::COMPUTE,
            layout,
            0,
            &[set.set],
            &[],
        );
        device.cmd_push_constants(rec.raw(), layout, vk::ShaderStageFlags::COMPUTE, 0, push);
        device.cmd_dispatch(rec.raw(), groups[0], groups[1], groups[2]);
    }
}

impl Drop for ComputeKernels {
    fn drop(&mut self) {
        let device = self.ctx.device();
        // SAFETY: created on this device (null handles are ignored by Vulkan);
        // not in use by the GPU per the crate's drop contract.
        unsafe {
            for &p in &self.pipelines {
                device.destroy_pipeline(p, None);
            }
            device.destroy_pipeline_layout(self.layout, None);
            device.destroy_descriptor_set_layout(self.set_layout, None);
        }
    }
}

impl Drop for StorageSet {
    fn drop(&mut self) {
        // SAFETY: created on this device; frees the set with the pool; not in
        // use by the GPU per the crate's drop contract.
        unsafe { self.ctx.device().destroy_descriptor_pool(self.pool, None) };
    }
}

/// Records `vkCmdFillBuffer(buffer, offset, size, 0)`; the buffer needs
/// `TRANSFER_DST` usage (checked by the callers' `bind`).
/// Creates a descriptor pool with `sizes` and allocates one set of `layout`
/// from it; the pool is destroyed again if the allocation fails.
pub(crate) fn allocate_one_set(
    ctx: &DeviceContext,
    sizes: &[vk::DescriptorPoolSize],
    layout: vk::DescriptorSetLayout,
) -> Result<(vk::DescriptorPool, vk::DescriptorSet)> {
    let device = ctx.device();
    let info = vk::DescriptorPoolCreateInfo::default()
        .max_sets(1)
        .pool_sizes(sizes);
    // SAFETY: valid device and create info.
    let pool =
        unsafe { device.create_descriptor_pool(&info, None) }.ctx("vkCreateDescriptorPool")?;
    let layouts = [layout];
    let alloc = vk::DescriptorSetAllocateInfo::default()
        .descriptor_pool(pool)
        .set_layouts(&layouts);
    // SAFETY: the pool has room for one set of this layout.
    match unsafe { device.allocate_descriptor_sets(&alloc) } {
        Ok(s) if !s.is_empty() => Ok((pool, s[0])),
        other => {
            // SAFETY: the pool is unused.
            unsafe { device.destroy_descriptor_pool(pool, None) };
            let e = other.err().unwrap_or(vk::Result::ERROR_OUT_OF_POOL_MEMORY);
            Err(VkError::vk("vkAllocateDescriptorSets", e))
        }
    }
}

pub(crate) fn record_zero(rec: &mut Recorder<'_>, buffer: vk::Buffer, offset: u64, size: u64) {
    // SAFETY: recording on this device (Recorder contract); callers pass a
    // live buffer of this device (held by their bindings) with TRANSFER_DST
    // usage, and offset/size multiples of 4 inside it (or WHOLE_SIZE).
    unsafe {
        rec.context()
            .device()
            .cmd_fill_buffer(rec.raw(), buffer, offset, size, 0)
    };
}

/// Barrier between two of lipac's compute passes (and the fills before).
pub(crate) fn compute_to_compute(rec: &mut Recorder<'_>, after_fill: bool) {
    let (stage, access) = if after_fill {
        (
            vk::PipelineStageFlags2::COMPUTE_SHADER | vk::PipelineStageFlags2::TRANSFER,
            vk::AccessFlags2::SHADER_STORAGE_WRITE | vk::AccessFlags2::TRANSFER_WRITE,
        )
    } else {
        (
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::SHADER_STORAGE_WRITE,
        )
    };
    rec.memory_barrier(
        stage,
        access,
        vk::PipelineStageFlags2::COMPUTE_SHADER,
        vk::AccessFlags2::SHADER_STORAGE_READ | vk::AccessFlags2::SHADER_STORAGE_WRITE,
    );
}

/// Barrier after lipac's last compute pass: its writes are visible to every
/// later command (TLAS builds, traces in any stage, copies) and the host.
pub(crate) fn compute_to_everything(rec: &mut Recorder<'_>) {
    rec.memory_barrier(
        vk::PipelineStageFlags2::COMPUTE_SHADER,
        vk::AccessFlags2::SHADER_STORAGE_WRITE,
        vk::PipelineStageFlags2::ALL_COMMANDS | vk::PipelineStageFlags2::HOST,
        vk::AccessFlags2::MEMORY_READ
            | vk::AccessFlags2::MEMORY_WRITE
            | vk::AccessFlags2::HOST_READ,
    );
}
