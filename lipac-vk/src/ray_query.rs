//! A compute pipeline over one TLAS and storage buffers with the counting
//! configuration as specialization constants: the shape of lipac's tracers
//! ([`crate::RayQueryTestPipeline`], [`crate::CameraTracer`]).

use crate::accel::same_context;
use crate::commands::Recorder;
use crate::compute::{
    allocate_one_set, compute_pipeline_layout, compute_set_layout, create_compute_pipeline,
    record_dispatch, StorageSet,
};
use crate::context::DeviceContext;
use crate::counting::CountingBoxConfig;
use crate::error::{Result, VkError};
use crate::memory::Buffer;
use crate::tlas::GpuTlas;
use crate::tracing_paths::TracingPath;
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
    /// 0..3 = omitted-box SBT offset, hitbox-box SBT offset, counting mask)
    /// for `component`; [`VkError::MissingFeature`] without ray queries.
    pub(crate) fn new(
        ctx: &DeviceContext,
        component: &'static str,
        spv: &[u8],
        config: &CountingBoxConfig,
        storage_bindings: u32,
        push_size: u32,
    ) -> Result<Self> {
        ctx.require_tracing(TracingPath::RayQuery, component)?;
        config.validate()?;
        let mut kinds = vec![vk::DescriptorType::ACCELERATION_STRUCTURE_KHR];
        kinds.resize(
            1 + storage_bindings as usize,
            vk::DescriptorType::STORAGE_BUFFER,
        );
        let set_layout = compute_set_layout(ctx, &kinds)?;
        // From here on, Drop frees whatever was created (null handles are ignored).
        let mut this = Self {
            ctx: ctx.clone(),
            set_layout,
            layout: vk::PipelineLayout::null(),
            pipeline: vk::Pipeline::null(),
            storage_bindings,
        };
        this.layout = compute_pipeline_layout(ctx, set_layout, push_size)?;
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
        this.pipeline = create_compute_pipeline(ctx, spv, this.layout, Some(&spec))?;
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
        let (pool, set) = bind_tlas_set(
            &self.ctx,
            self.set_layout,
            self.storage_bindings,
            tlas,
            storage,
        )?;
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

/// A descriptor set (with its own pool) of `set_layout`: `tlas` at binding
/// 0, `storage[i]` at binding `i + 1` (whole buffers, `storage_bindings` of
/// them). The caller checked the buffers' context and usage.
pub(crate) fn bind_tlas_set(
    ctx: &DeviceContext,
    set_layout: vk::DescriptorSetLayout,
    storage_bindings: u32,
    tlas: &GpuTlas,
    storage: &[&Buffer],
) -> Result<(vk::DescriptorPool, vk::DescriptorSet)> {
    same_context(ctx, tlas.accel().context())?;
    if storage.len() != storage_bindings as usize {
        return Err(VkError::InvalidArgument(format!(
            "{} storage buffers for {} bindings",
            storage.len(),
            storage_bindings
        )));
    }
    let sizes = [
        vk::DescriptorPoolSize::default()
            .ty(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
            .descriptor_count(1),
        vk::DescriptorPoolSize::default()
            .ty(vk::DescriptorType::STORAGE_BUFFER)
            .descriptor_count(storage_bindings),
    ];
    let (pool, set) = allocate_one_set(ctx, &sizes, set_layout)?;
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
