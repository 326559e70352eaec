//! A compute pipeline over one TLAS and storage buffers with the counting
//! configuration as specialization constants: the shape of lipac's tracers
//! ([`crate::RayQueryTestPipeline`], [`crate::CameraTracer`]).

use crate::accel::same_context;
use crate::commands::Recorder;
use crate::compute::{allocate_one_set, compute_pipeline_layout, record_dispatch, StorageSet};
use crate::context::DeviceContext;
use crate::counting::CountingBoxConfig;
use crate::error::{Result, VkContext, VkError};
use crate::memory::Buffer;
use crate::tlas::GpuTlas;
use ash::vk;

/// Set layout (binding 0: the TLAS, 1..: storage buffers), pipeline layout
/// with one push-constant block, and the pipeline. Freed on drop.
#[derive(Debug)]
pub(crate) struct RayQueryPipeline {
    ctx: DeviceContext,
    pub(crate) set_layout: vk::DescriptorSetLayout,
    pub(crate) layout: vk::PipelineLayout,
    pub(crate) pipeline: vk::Pipeline,
    storage_bindings: u32,
}

impl RayQueryPipeline {
    /// Creates the pipeline of `spv` (entry `main`, specialization constants
    /// 0..3 = omitted-box SBT offset, hitbox-box SBT offset, counting mask).
    pub(crate) fn new(
        ctx: &DeviceContext,
        spv: &[u8],
        config: &CountingBoxConfig,
        storage_bindings: u32,
        push_size: u32,
    ) -> Result<Self> {
        config.validate()?;
        let device = ctx.device();
        let mut bindings = vec![vk::DescriptorSetLayoutBinding::default()
            .binding(0)
            .descriptor_type(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
            .descriptor_count(1)
            .stage_flags(vk::ShaderStageFlags::COMPUTE)];
        for b in 1..=storage_bindings {
            bindings.push(
                vk::DescriptorSetLayoutBinding::default()
                    .binding(b)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .descriptor_count(1)
                    .stage_flags(vk::ShaderStageFlags::COMPUTE),
            );
        }
        let info = vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings);
        // SAFETY: valid device and create info.
        let set_layout = unsafe { device.create_descriptor_set_layout(&info, None) }
            .ctx("vkCreateDescriptorSetLayout")?;
        // From here on, Drop frees whatever was created (null handles are ignored).
        let mut this = Self {
            ctx: ctx.clone(),
            set_layout,
            layout: vk::PipelineLayout::null(),
            pipeline: vk::Pipeline::null(),
            storage_bindings,
        };
        this.layout = compute_pipeline_layout(ctx, set_layout, push_size)?;
        let words = crate::shaders::spirv_words(spv)?;
        let info = vk::ShaderModuleCreateInfo::default().code(&words);
        // SAFETY: valid device; `words` is embedded, validated SPIR-V.
        let module =
            unsafe { device.create_shader_module(&info, None) }.ctx("vkCreateShaderModule")?;
        let spec_data: [u32; 3] = [
            config.omitted_box_sbt_offset,
            config.hitbox_box_sbt_offset,
            u32::from(config.counting_mask),
        ];
        let entries: Vec<_> = (0..3u32)
            .map(|i| {
                vk::SpecializationMapEntry::default()
                    .constant_id(i)
                    .offset(4 * i)
                    .size(4)
            })
            .collect();
        let spec = vk::SpecializationInfo::default()
            .map_entries(&entries)
            .data(bytemuck::cast_slice(&spec_data));
        let stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(module)
            .name(c"main")
            .specialization_info(&spec);
        let info = [vk::ComputePipelineCreateInfo::default()
            .stage(stage)
            .layout(this.layout)];
        // SAFETY: valid device, module and layout matching the shader's interface.
        let created =
            unsafe { device.create_compute_pipelines(vk::PipelineCache::null(), &info, None) };
        // SAFETY: the module is no longer needed once pipeline creation returned.
        unsafe { device.destroy_shader_module(module, None) };
        let pipelines = created.map_err(|(_, e)| VkError::vk("vkCreateComputePipelines", e))?;
        this.pipeline = pipelines.first().copied().ok_or(VkError::vk(
            "vkCreateComputePipelines",
            vk::Result::ERROR_UNKNOWN,
        ))?;
        Ok(this)
    }
}

impl Drop for RayQueryPipeline {
    fn drop(&mut self) {
        let device = self.ctx.device();
        // SAFETY: created on this device (null handles are ignored by Vulkan);
        // not in use by the GPU per the crate's drop contract.
        unsafe {
            device.destroy_pipeline(self.pipeline, None);
            device.destroy_pipeline_layout(self.layout, None);
            device.destroy_descriptor_set_layout(self.set_layout, None);
        }
    }
}

impl RayQueryPipeline {
    /// A descriptor set for this pipeline: `tlas` at binding 0, `storage[i]`
    /// at binding `i + 1` (whole buffers, each of this context with
    /// `STORAGE_BUFFER` usage, else [`VkError::MissingUsage`]`(missing_usage)`).
    pub(crate) fn bind(
        &self,
        tlas: &GpuTlas,
        storage: &[&Buffer],
        missing_usage: &'static str,
    ) -> Result<StorageSet> {
        for b in storage {
            same_context(&self.ctx, b.context())?;
            if !b.usage().contains(vk::BufferUsageFlags::STORAGE_BUFFER) {
                return Err(VkError::MissingUsage(missing_usage));
            }
        }
        let (pool, set) = bind_ray_query_set(&self.ctx, self, tlas, storage)?;
        Ok(StorageSet::new(&self.ctx, pool, set))
    }

    /// Checks that `rec` records on this pipeline's device and `set` was
    /// made there (call before recording anything, so that a refused
    /// trace records nothing).
    pub(crate) fn check_recorder(&self, rec: &Recorder<'_>, set: &StorageSet) -> Result<()> {
        same_context(rec.context(), &self.ctx)?;
        same_context(rec.context(), set.context())
    }

    /// Records binding the pipeline and `set`, the push constants `push`
    /// and a dispatch of `groups` work groups (checked by
    /// [`check_recorder`](Self::check_recorder)).
    pub(crate) fn dispatch(
        &self,
        rec: &mut Recorder<'_>,
        set: &StorageSet,
        push: &[u8],
        groups: [u32; 3],
    ) {
        record_dispatch(rec, self.pipeline, self.layout, set, push, groups);
    }
}

/// A descriptor set (with its own pool) for `pipeline`: `tlas` at binding 0,
/// `storage[i]` at binding `i + 1` (whole buffers). The caller checked the
/// buffers' context and usage.
fn bind_ray_query_set(
    ctx: &DeviceContext,
    pipeline: &RayQueryPipeline,
    tlas: &GpuTlas,
    storage: &[&Buffer],
) -> Result<(vk::DescriptorPool, vk::DescriptorSet)> {
    same_context(ctx, tlas.accel().context())?;
    if storage.len() != pipeline.storage_bindings as usize {
        return Err(VkError::InvalidArgument(format!(
            "{} storage buffers for {} bindings",
            storage.len(),
            pipeline.storage_bindings
        )));
    }
    let sizes = [
        vk::DescriptorPoolSize::default()
            .ty(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
            .descriptor_count(1),
        vk::DescriptorPoolSize::default()
            .ty(vk::DescriptorType::STORAGE_BUFFER)
            .descriptor_count(pipeline.storage_bindings),
    ];
    let (pool, set) = allocate_one_set(ctx, &sizes, pipeline.set_layout)?;
    let accels = [tlas.accel().raw()];
    let mut as_write =
        vk::WriteDescriptorSetAccelerationStructureKHR::default().acceleration_structures(&accels);
    let infos: Vec<[vk::DescriptorBufferInfo; 1]> = storage
        .iter()
        .map(|b| {
            [vk::DescriptorBufferInfo::default()
                .buffer(b.raw())
                .offset(0)
                .range(vk::WHOLE_SIZE)]
        })
        .collect();
    let mut writes = vec![vk::WriteDescriptorSet::default()
        .dst_set(set)
        .dst_binding(0)
        .descriptor_type(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
        .descriptor_count(1)
        .push_next(&mut as_write)];
    for (i, info) in infos.iter().enumerate() {
        writes.push(
            vk::WriteDescriptorSet::default()
                .dst_set(set)
                .dst_binding(i as u32 + 1)
                .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                .buffer_info(info),
        );
    }
    // SAFETY: the set is fresh and unused; every write matches the layout.
    unsafe { ctx.device().update_descriptor_sets(&writes, &[]) };
    Ok((pool, set))
}
