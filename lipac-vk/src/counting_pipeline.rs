//! [`CountingPipeline`]: a ray-tracing pipeline over one TLAS and storage
//! buffers with lipac's counting hit groups (`lipac_counting_pipeline.glsl`)
//! and its shader binding table: the shape of lipac's pipeline tracers
//! ([`crate::PipelineTestTracer`], [`crate::PipelineCameraTracer`]).
//!
//! Shader groups: 0 the ray generation shader, 1 the miss shader
//! (`pipeline_miss.rmiss`), 2 real geometry (`pipeline_hit.rchit`, and
//! `pipeline_hit.rahit`, which skips real instances in the boxes-alone
//! trace of merged boxes), 3–5 the
//! omitted-instance, hitbox and merged box kinds (`pipeline_box.rahit` and
//! `.rchit`, specialised per kind). The hit region has one record per SBT
//! offset up to the largest box offset: a box offset's record runs its box
//! group, every other record real geometry's, its data the record's offset
//! (reported as the hit's SBT offset). Traces use SBT record offset and
//! stride 0, so an instance's own SBT offset selects its record.

use crate::accel::same_context;
use crate::commands::Recorder;
use crate::compute::StorageSet;
use crate::context::DeviceContext;
use crate::counting::CountingBoxConfig;
use crate::error::{Result, VkContext, VkError};
use crate::memory::{Buffer, MemoryLocation};
use crate::ray_query::bind_tlas_set;
use crate::sbt::{SbtLayout, SbtRecords};
use crate::shaders::{
    spirv_words, PIPELINE_BOX_AHIT_SPV, PIPELINE_BOX_CHIT_SPV, PIPELINE_HIT_AHIT_SPV,
    PIPELINE_HIT_SPV, PIPELINE_MISS_SPV,
};
use crate::tlas::GpuTlas;
use crate::tracing_paths::TracingPath;
use ash::vk;

/// The largest SBT offset (of a counting-box kind) lipac's pipeline tracers
/// lay a hit record out for: their hit region has one record per offset up
/// to the largest box offset.
pub const MAX_PIPELINE_SBT_OFFSET: u32 = 4095;

/// Every stage of lipac's pipeline tracers.
pub(crate) const STAGES: vk::ShaderStageFlags = vk::ShaderStageFlags::from_raw(
    vk::ShaderStageFlags::RAYGEN_KHR.as_raw()
        | vk::ShaderStageFlags::ANY_HIT_KHR.as_raw()
        | vk::ShaderStageFlags::CLOSEST_HIT_KHR.as_raw()
        | vk::ShaderStageFlags::MISS_KHR.as_raw(),
);

/// The counting bindings every stage declares (`pipeline_common.glsl`):
/// instance hit counters, hitbox records, hitbox bounds.
pub(crate) const COUNTING_BINDINGS: u32 = 3;

/// A ray-tracing pipeline with lipac's counting hit groups, its layouts and
/// its shader binding table. Freed on drop.
#[derive(Debug)]
pub(crate) struct CountingPipeline {
    ctx: DeviceContext,
    set_layout: vk::DescriptorSetLayout,
    layout: vk::PipelineLayout,
    pipeline: vk::Pipeline,
    storage_bindings: u32,
    merged_sbt_offset: u32,
    /// Keeps the table's memory; `regions` point into it.
    _sbt: Option<Buffer>,
    regions: [vk::StridedDeviceAddressRegionKHR; 4],
}

/// The shader modules of a pipeline, destroyed on drop.
struct Modules<'a> {
    device: &'a ash::Device,
    modules: Vec<vk::ShaderModule>,
}

impl Modules<'_> {
    fn load(&mut self, spv: &[u8]) -> Result<vk::ShaderModule> {
        let words = spirv_words(spv)?;
        let info = vk::ShaderModuleCreateInfo::default().code(&words);
        // SAFETY: valid device; embedded SPIR-V checked by spirv-val.
        let m =
            unsafe { self.device.create_shader_module(&info, None) }.ctx("vkCreateShaderModule")?;
        self.modules.push(m);
        Ok(m)
    }
}

impl Drop for Modules<'_> {
    fn drop(&mut self) {
        for &m in &self.modules {
            // SAFETY: created here; pipeline creation has returned.
            unsafe { self.device.destroy_shader_module(m, None) };
        }
    }
}

impl CountingPipeline {
    /// Creates the pipeline of the ray generation shader `raygen_spv` for
    /// `component`, with `storage_bindings` storage buffers after the TLAS
    /// (the counting ones first) and `push_size` bytes of push constants
    /// (lipac_vk::MergedBoxes first). `merged_sbt_offset` is the SBT
    /// offset of merged boxes ([`crate::MergedBoxes::merged_sbt_offset`]).
    pub(crate) fn new(
        ctx: &DeviceContext,
        component: &'static str,
        raygen_spv: &[u8],
        config: &CountingBoxConfig,
        merged_sbt_offset: u32,
        storage_bindings: u32,
        push_size: u32,
    ) -> Result<Self> {
        ctx.require_tracing(TracingPath::RayTracingPipeline, component)?;
        config.validate()?;
        let offsets = [
            config.omitted_box_sbt_offset,
            config.hitbox_box_sbt_offset,
            merged_sbt_offset,
        ];
        if offsets.iter().any(|&o| o > MAX_PIPELINE_SBT_OFFSET) {
            return Err(VkError::InvalidArgument(format!(
                "{component}: box SBT offsets {offsets:?} over {MAX_PIPELINE_SBT_OFFSET}"
            )));
        }
        if merged_sbt_offset == offsets[0] || merged_sbt_offset == offsets[1] {
            return Err(VkError::InvalidArgument(format!(
                "{component}: merged-box SBT offset {merged_sbt_offset} equals another box kind's"
            )));
        }
        let props = *ctx
            .ray_tracing_pipeline_properties()
            .ok_or(VkError::MissingFeature {
                component,
                needs: TracingPath::RayTracingPipeline.extension(),
                offers: ctx.tracing().to_string(),
            })?;
        let fns = ctx.ray_tracing_pipeline().ok_or(VkError::MissingFeature {
            component,
            needs: TracingPath::RayTracingPipeline.extension(),
            offers: ctx.tracing().to_string(),
        })?;
        let device = ctx.device();

        let mut bindings = vec![vk::DescriptorSetLayoutBinding::default()
            .binding(0)
            .descriptor_type(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
            .descriptor_count(1)
            .stage_flags(STAGES)];
        for b in 1..=storage_bindings {
            bindings.push(
                vk::DescriptorSetLayoutBinding::default()
                    .binding(b)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .descriptor_count(1)
                    .stage_flags(STAGES),
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
            merged_sbt_offset,
            _sbt: None,
            regions: Default::default(),
        };
        let set_layouts = [set_layout];
        let push = [vk::PushConstantRange::default()
            .stage_flags(STAGES)
            .offset(0)
            .size(push_size)];
        let info = vk::PipelineLayoutCreateInfo::default()
            .set_layouts(&set_layouts)
            .push_constant_ranges(&push);
        // SAFETY: valid device; live set layout.
        this.layout =
            unsafe { device.create_pipeline_layout(&info, None) }.ctx("vkCreatePipelineLayout")?;

        let mut modules = Modules {
            device,
            modules: Vec::new(),
        };
        let raygen = modules.load(raygen_spv)?;
        let miss = modules.load(PIPELINE_MISS_SPV)?;
        let hit = modules.load(PIPELINE_HIT_SPV)?;
        let hit_ahit = modules.load(PIPELINE_HIT_AHIT_SPV)?;
        let box_ahit = modules.load(PIPELINE_BOX_AHIT_SPV)?;
        let box_chit = modules.load(PIPELINE_BOX_CHIT_SPV)?;

        let entries: Vec<_> = (0..4u32)
            .map(|i| {
                vk::SpecializationMapEntry::default()
                    .constant_id(i)
                    .offset(4 * i)
                    .size(4)
            })
            .collect();
        let mask = u32::from(config.counting_mask);
        let base_data = [offsets[0], offsets[1], mask];
        let kind_data: [[u32; 4]; 3] = offsets.map(|kind| [offsets[0], offsets[1], mask, kind]);
        let base_spec = vk::SpecializationInfo::default()
            .map_entries(&entries[..3])
            .data(bytemuck::cast_slice(&base_data));
        let kind_specs: Vec<vk::SpecializationInfo<'_>> = kind_data
            .iter()
            .map(|d| {
                vk::SpecializationInfo::default()
                    .map_entries(&entries)
                    .data(bytemuck::cast_slice(d))
            })
            .collect();
        let stage = |flags: vk::ShaderStageFlags, module, spec| {
            vk::PipelineShaderStageCreateInfo::default()
                .stage(flags)
                .module(module)
                .name(c"main")
                .specialization_info(spec)
        };
        let mut stages = vec![
            stage(vk::ShaderStageFlags::RAYGEN_KHR, raygen, &base_spec),
            stage(vk::ShaderStageFlags::MISS_KHR, miss, &base_spec),
            stage(vk::ShaderStageFlags::CLOSEST_HIT_KHR, hit, &base_spec),
            stage(vk::ShaderStageFlags::ANY_HIT_KHR, hit_ahit, &base_spec),
        ];
        for spec in &kind_specs {
            stages.push(stage(vk::ShaderStageFlags::ANY_HIT_KHR, box_ahit, spec));
            stages.push(stage(vk::ShaderStageFlags::CLOSEST_HIT_KHR, box_chit, spec));
        }
        let general = |s: u32| {
            vk::RayTracingShaderGroupCreateInfoKHR::default()
                .ty(vk::RayTracingShaderGroupTypeKHR::GENERAL)
                .general_shader(s)
                .closest_hit_shader(vk::SHADER_UNUSED_KHR)
                .any_hit_shader(vk::SHADER_UNUSED_KHR)
                .intersection_shader(vk::SHADER_UNUSED_KHR)
        };
        let triangles = |chit: u32, ahit: u32| {
            vk::RayTracingShaderGroupCreateInfoKHR::default()
                .ty(vk::RayTracingShaderGroupTypeKHR::TRIANGLES_HIT_GROUP)
                .general_shader(vk::SHADER_UNUSED_KHR)
                .closest_hit_shader(chit)
                .any_hit_shader(ahit)
                .intersection_shader(vk::SHADER_UNUSED_KHR)
        };
        let groups = [
            general(0),
            general(1),
            triangles(2, 3),
            triangles(5, 4),
            triangles(7, 6),
            triangles(9, 8),
        ];
        let info = [vk::RayTracingPipelineCreateInfoKHR::default()
            .stages(&stages)
            .groups(&groups)
            .max_pipeline_ray_recursion_depth(1)
            .layout(this.layout)];
        // SAFETY: valid device with the pipeline extension enabled (checked
        // above); stages, groups and layout match the shaders' interfaces.
        let created = unsafe {
            fns.create_ray_tracing_pipelines(
                vk::DeferredOperationKHR::null(),
                vk::PipelineCache::null(),
                &info,
                None,
            )
        };
        drop(modules);
        this.pipeline = match created {
            Ok(p) => p.first().copied().unwrap_or_default(),
            Err((p, e)) => {
                for q in p {
                    // SAFETY: created above (or null), never used.
                    unsafe { device.destroy_pipeline(q, None) };
                }
                return Err(VkError::vk("vkCreateRayTracingPipelinesKHR", e));
            }
        };

        // The shader binding table.
        let hit_records = offsets.iter().max().copied().unwrap_or(0) + 1;
        let layout = SbtLayout::new(
            &props,
            &SbtRecords {
                miss: 1,
                hit: hit_records,
                hit_data: 4,
                ..Default::default()
            },
        )?;
        let handle_bytes = props.handle_size as usize * groups.len();
        // SAFETY: live pipeline of this device with `groups.len()` groups.
        let handles = unsafe {
            fns.get_ray_tracing_shader_group_handles(
                this.pipeline,
                0,
                groups.len() as u32,
                handle_bytes,
            )
        }
        .ctx("vkGetRayTracingShaderGroupHandlesKHR")?;
        let data: Vec<[u8; 4]> = (0..hit_records).map(u32::to_le_bytes).collect();
        let hit: Vec<(u32, &[u8])> = data
            .iter()
            .enumerate()
            .map(|(i, d)| {
                let group = match offsets.iter().position(|&o| o as usize == i) {
                    Some(kind) => 3 + kind as u32,
                    None => 2,
                };
                (group, &d[..])
            })
            .collect();
        let table = layout.write(&handles, [&[(0, &[])], &[(1, &[])], &hit, &[]])?;
        let mut sbt = Buffer::named(
            ctx,
            "lipac shader binding table",
            layout.allocation_size(1),
            vk::BufferUsageFlags::SHADER_BINDING_TABLE_KHR,
            MemoryLocation::CpuToGpu,
        )?;
        let base_offset = layout.base_offset(sbt.device_address());
        sbt.write(base_offset, &table)?;
        this.regions = layout.device_regions(sbt.device_address() + base_offset);
        this._sbt = Some(sbt);
        Ok(this)
    }

    /// The SBT offset of merged boxes this pipeline's table was laid out for.
    pub(crate) fn merged_sbt_offset(&self) -> u32 {
        self.merged_sbt_offset
    }

    /// A descriptor set: `tlas` at binding 0, `storage[i]` at binding `i + 1`
    /// (each with `STORAGE_BUFFER` usage, else
    /// [`VkError::MissingUsage`]`(missing_usage)`).
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
    /// made there.
    pub(crate) fn check_recorder(&self, rec: &Recorder<'_>, set: &StorageSet) -> Result<()> {
        same_context(rec.context(), &self.ctx)?;
        same_context(rec.context(), set.context())
    }

    /// Records binding the pipeline and `set`, the push constants `push`
    /// (all stages) and `vkCmdTraceRaysKHR` of `size` rays (checked by
    /// [`check_recorder`](Self::check_recorder)).
    pub(crate) fn trace(
        &self,
        rec: &mut Recorder<'_>,
        set: &StorageSet,
        push: &[u8],
        size: [u32; 3],
    ) {
        let device = self.ctx.device();
        let Some(fns) = self.ctx.ray_tracing_pipeline() else {
            return;
        };
        let bind = vk::PipelineBindPoint::RAY_TRACING_KHR;
        let [raygen, miss, hit, callable] = &self.regions;
        // SAFETY: recording on this device (checked by the caller); the
        // pipeline, layout, set and table are live and compatible; `push`
        // is the layout's push block.
        unsafe {
            device.cmd_bind_pipeline(rec.raw(), bind, self.pipeline);
            device.cmd_bind_descriptor_sets(rec.raw(), bind, self.layout, 0, &[set.raw()], &[]);
            device.cmd_push_constants(rec.raw(), self.layout, STAGES, 0, push);
            fns.cmd_trace_rays(
                rec.raw(),
                raygen,
                miss,
                hit,
                callable,
                size[0],
                size[1],
                size[2],
            );
        }
    }
}

impl Drop for CountingPipeline {
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
