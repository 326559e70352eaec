//! Binding to an engine's Vulkan device ([`DeviceContext`]): the queue lipac
//! submits to, the allocator its memory comes from, the device limits it
//! needs. A self-contained device for examples and tests is in
//! [`HeadlessContext`].

use crate::device_allocator::{DeviceAllocator, DeviceMemoryStats, GpuAllocator, MemoryCounters};
use crate::error::{Result, VkError};
use crate::headless::Owned;
use crate::tracing_paths::{RayTracingPipelineProperties, TracingPath, TracingPaths};
#[cfg(doc)]
use crate::HeadlessContext;
use ash::vk;
use std::ffi::CStr;
use std::sync::{Arc, Mutex, MutexGuard};

/// One queue the engine hands to lipac.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EngineQueue {
    /// The queue.
    pub queue: vk::Queue,
    /// Its queue family index.
    pub family_index: u32,
}

/// Acceleration-structure limits of the physical device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AccelerationStructureLimits {
    /// `minAccelerationStructureScratchOffsetAlignment`: every scratch
    /// address lipac hands to a build is a multiple of this.
    pub min_scratch_offset_alignment: u32,
    /// `maxInstanceCount` of one TLAS.
    pub max_instance_count: u64,
    /// `maxPrimitiveCount` of one BLAS.
    pub max_primitive_count: u64,
    /// `maxGeometryCount` of one BLAS.
    pub max_geometry_count: u64,
}

/// Extensions a device must enable for lipac (besides Vulkan 1.3 core):
/// what the culling loop uses (BLAS/TLAS builds, Algorithms 1 and 2,
/// uploads, read-back). Tracing is extra: [`RAY_QUERY_EXTENSIONS`] for
/// lipac's ray-query tracers, [`RAY_TRACING_PIPELINE_EXTENSIONS`] for its
/// pipeline tracers ([`TracingPaths`]).
pub const REQUIRED_DEVICE_EXTENSIONS: [&CStr; 2] = [
    ash::khr::acceleration_structure::NAME,
    ash::khr::deferred_host_operations::NAME,
];

/// The extension of the ray-query tracing path (feature `rayQuery`).
pub const RAY_QUERY_EXTENSIONS: [&CStr; 1] = [ash::khr::ray_query::NAME];

/// The extension of the ray-tracing-pipeline path (feature
/// `rayTracingPipeline`; its dependency `VK_KHR_spirv_1_4` is core in
/// Vulkan 1.2).
pub const RAY_TRACING_PIPELINE_EXTENSIONS: [&CStr; 1] = [ash::khr::ray_tracing_pipeline::NAME];

/// Device functions of the ray-tracing-pipeline path.
const PIPELINE_DEVICE_FUNCTIONS: [&CStr; 3] = [
    c"vkCreateRayTracingPipelinesKHR",
    c"vkGetRayTracingShaderGroupHandlesKHR",
    c"vkCmdTraceRaysKHR",
];

/// Device functions lipac calls; checked when binding to an engine's device.
const REQUIRED_DEVICE_FUNCTIONS: [&CStr; 6] = [
    c"vkCreateAccelerationStructureKHR",
    c"vkCmdBuildAccelerationStructuresKHR",
    c"vkCmdWriteAccelerationStructuresPropertiesKHR",
    c"vkGetBufferDeviceAddress",
    c"vkCmdPipelineBarrier2",
    c"vkQueueSubmit2",
];

/// lipac's handle on a Vulkan device: the engine's instance and device, the
/// queue lipac submits to, the [`DeviceAllocator`] its buffers' memory comes
/// from, the loaded `VK_KHR_acceleration_structure` function table, and the
/// device limits lipac needs.
///
/// Cheap to clone (reference counted). Every lipac object (buffers,
/// acceleration structures, pipelines) holds a clone and destroys its Vulkan
/// objects when dropped, so with a [`HeadlessContext`] the device is
/// destroyed only after the last object; with [`DeviceContext::from_engine`]
/// the engine must keep its device alive until all lipac objects are gone.
#[derive(Clone)]
pub struct DeviceContext {
    inner: Arc<Inner>,
}

struct Inner {
    instance: ash::Instance,
    device: ash::Device,
    physical_device: vk::PhysicalDevice,
    queue: EngineQueue,
    queue_lock: Mutex<()>,
    host_waits: std::sync::atomic::AtomicU64,
    accel: ash::khr::acceleration_structure::Device,
    limits: AccelerationStructureLimits,
    tracing: TracingPaths,
    /// Loaded when `tracing.ray_tracing_pipeline`.
    pipeline_fns: Option<ash::khr::ray_tracing_pipeline::Device>,
    pipeline_properties: Option<RayTracingPipelineProperties>,
    memory_properties: vk::PhysicalDeviceMemoryProperties,
    device_name: String,
    memory: MemoryCounters,
    /// Dropped before `_owned` (field order): frees its blocks while the
    /// device still exists.
    allocator: Arc<dyn DeviceAllocator>,
    /// Only held to be dropped last (destroys a headless device).
    _owned: Option<Owned>,
}

impl std::fmt::Debug for DeviceContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DeviceContext")
            .field("device", &self.inner.device_name)
            .field("queue_family", &self.inner.queue.family_index)
            .field("tracing", &self.inner.tracing)
            .field("limits", &self.inner.limits)
            .finish_non_exhaustive()
    }
}

/// The queue family lipac prefers on a physical device: a compute family
/// without graphics (async compute) when there is one, else a family with
/// graphics and compute. `None` when no family supports compute.
pub fn preferred_queue_family(
    instance: &ash::Instance,
    physical_device: vk::PhysicalDevice,
) -> Option<u32> {
    // SAFETY: `physical_device` was enumerated from `instance` (the caller's
    // contract for any Vulkan handle it passes); the call only reads properties.
    let families = unsafe { instance.get_physical_device_queue_family_properties(physical_device) };
    pick_family(
        families
            .iter()
            .enumerate()
            .map(|(i, f)| (i as u32, f.queue_flags)),
    )
}

fn pick_family(families: impl Iterator<Item = (u32, vk::QueueFlags)> + Clone) -> Option<u32> {
    let async_compute = families.clone().find(|(_, flags)| {
        flags.contains(vk::QueueFlags::COMPUTE) && !flags.contains(vk::QueueFlags::GRAPHICS)
    });
    async_compute
        .or_else(|| {
            families
                .clone()
                .find(|(_, flags)| flags.contains(vk::QueueFlags::COMPUTE))
        })
        .map(|(i, _)| i)
}

impl DeviceContext {
    /// Binds lipac to an engine's existing device.
    ///
    /// lipac submits its own work (BLAS/TLAS builds, compute passes) to one of
    /// `queues`: an async-compute queue (compute without graphics) when one is
    /// given, a graphics+compute queue otherwise. Checks that the device
    /// functions lipac calls are loaded (Vulkan 1.3 with `synchronization2`,
    /// `VK_KHR_acceleration_structure`, buffer device address) and loads the
    /// acceleration-structure function table. lipac's buffers take their
    /// memory from a [`GpuAllocator`] of its own (gpu-allocator); to use the
    /// engine's allocator instead, bind with
    /// [`DeviceContext::from_engine_with_allocator`].
    ///
    /// # Safety
    ///
    /// `instance`, `device` and `physical_device` must be valid and belong
    /// together; every queue must be a queue of `device` from the family it
    /// names. The device must have been created with the extensions in
    /// [`REQUIRED_DEVICE_EXTENSIONS`] and the features `bufferDeviceAddress`,
    /// `timelineSemaphore`, `synchronization2` and `accelerationStructure`
    /// enabled (ray queries and ray-tracing pipelines are not needed: the
    /// engine traces; to use lipac's own tracers too, declare the paths
    /// enabled with [`DeviceContext::with_tracing`]). The engine must keep the device alive until every
    /// lipac object created from this context is dropped, and must not use the
    /// chosen queue from another thread while a lipac call submits to it.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingDeviceFunction`] when a needed function is not
    /// loaded, [`VkError::NoComputeQueue`] when no queue supports compute,
    /// [`VkError::Allocator`] when gpu-allocator cannot be created.
    ///
    /// ```no_run
    /// # fn bind(instance: &ash::Instance, device: &ash::Device, pd: ash::vk::PhysicalDevice,
    /// #         queue: ash::vk::Queue, family: u32) -> Result<(), lipac_vk::VkError> {
    /// use lipac_vk::{DeviceContext, EngineQueue};
    /// // SAFETY: the engine created `device` with lipac's extensions and features
    /// // and outlives the context.
    /// let ctx = unsafe {
    ///     DeviceContext::from_engine(instance, device, pd, &[EngineQueue { queue, family_index: family }])?
    /// };
    /// println!("lipac submits to queue family {}", ctx.queue_family_index());
    /// # Ok(()) }
    /// ```
    pub unsafe fn from_engine(
        instance: &ash::Instance,
        device: &ash::Device,
        physical_device: vk::PhysicalDevice,
        queues: &[EngineQueue],
    ) -> Result<Self> {
        // SAFETY: forwarded from this function's contract (which includes
        // bufferDeviceAddress and the device outliving lipac's objects, hence
        // the allocator the context owns).
        let allocator = unsafe { GpuAllocator::new(instance, device, physical_device) }?;
        // SAFETY: forwarded from this function's contract; the allocator
        // allocates from `device`.
        unsafe {
            Self::bind(
                instance,
                device,
                physical_device,
                queues,
                Arc::new(allocator),
                TracingPaths::NONE,
                None,
            )
        }
    }

    /// Binds lipac to an engine's existing device, taking every buffer's
    /// memory from the engine's `allocator` instead of a [`GpuAllocator`] of
    /// lipac's own (see [`DeviceAllocator`] for what to implement).
    ///
    /// lipac keeps the `Arc` until the last object of this context is
    /// dropped; every allocation it made is freed by then.
    ///
    /// # Safety
    ///
    /// As [`DeviceContext::from_engine`]; besides, `allocator` must allocate
    /// from `device`.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingDeviceFunction`], [`VkError::NoComputeQueue`] as
    /// for [`DeviceContext::from_engine`].
    pub unsafe fn from_engine_with_allocator(
        instance: &ash::Instance,
        device: &ash::Device,
        physical_device: vk::PhysicalDevice,
        queues: &[EngineQueue],
        allocator: Arc<dyn DeviceAllocator>,
    ) -> Result<Self> {
        // SAFETY: forwarded from this function's contract.
        unsafe {
            Self::bind(
                instance,
                device,
                physical_device,
                queues,
                allocator,
                TracingPaths::NONE,
                None,
            )
        }
    }

    /// Declares the tracing paths the engine enabled on its device, so that
    /// lipac's own tracers ([`crate::CameraTracer`],
    /// [`crate::PipelineCameraTracer`], the test tracers) can run on it; call
    /// it on the context [`DeviceContext::from_engine`] returned, before
    /// cloning it. Loads the `VK_KHR_ray_tracing_pipeline` functions and
    /// reads the pipeline properties when `paths.ray_tracing_pipeline`.
    ///
    /// # Safety
    ///
    /// For `paths.ray_query` the device must have been created with
    /// `VK_KHR_ray_query` and the `rayQuery` feature; for
    /// `paths.ray_tracing_pipeline` with `VK_KHR_ray_tracing_pipeline` and the
    /// `rayTracingPipeline` feature.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] when the context was cloned already;
    /// [`VkError::MissingDeviceFunction`] when a pipeline function is not
    /// loaded.
    ///
    /// ```no_run
    /// # fn bind(instance: &ash::Instance, device: &ash::Device, pd: ash::vk::PhysicalDevice,
    /// #         queues: &[lipac_vk::EngineQueue]) -> Result<(), lipac_vk::VkError> {
    /// use lipac_vk::{DeviceContext, TracingPaths};
    /// // SAFETY: the engine created `device` with lipac's extensions and features,
    /// // VK_KHR_ray_tracing_pipeline and rayTracingPipeline, and outlives the context.
    /// let ctx = unsafe {
    ///     DeviceContext::from_engine(instance, device, pd, queues)?
    ///         .with_tracing(TracingPaths { ray_query: false, ray_tracing_pipeline: true })?
    /// };
    /// assert!(ctx.tracing().ray_tracing_pipeline);
    /// # Ok(()) }
    /// ```
    pub unsafe fn with_tracing(mut self, paths: TracingPaths) -> Result<Self> {
        let inner = Arc::get_mut(&mut self.inner).ok_or_else(|| {
            VkError::InvalidArgument(
                "declare the tracing paths before cloning the device context".into(),
            )
        })?;
        let (fns, props) = if paths.ray_tracing_pipeline {
            // SAFETY: the handles are valid (from_engine's contract) and the
            // device enabled the pipeline extension (this function's).
            let (fns, props) = unsafe {
                load_pipeline_path(&inner.instance, &inner.device, inner.physical_device)
            }?;
            (Some(fns), Some(props))
        } else {
            (None, None)
        };
        inner.tracing = paths;
        inner.pipeline_fns = fns;
        inner.pipeline_properties = props;
        Ok(self)
    }

    /// # Safety
    /// As [`DeviceContext::from_engine_with_allocator`].
    pub(crate) unsafe fn bind(
        instance: &ash::Instance,
        device: &ash::Device,
        physical_device: vk::PhysicalDevice,
        queues: &[EngineQueue],
        allocator: Arc<dyn DeviceAllocator>,
        tracing: TracingPaths,
        owned: Option<Owned>,
    ) -> Result<Self> {
        for name in REQUIRED_DEVICE_FUNCTIONS {
            // SAFETY: `device` is a valid device of `instance` (caller contract);
            // the name is a NUL-terminated string.
            let f = unsafe {
                (instance.fp_v1_0().get_device_proc_addr)(device.handle(), name.as_ptr())
            };
            if f.is_none() {
                // The names are static C string literals of ASCII text.
                return Err(VkError::MissingDeviceFunction(name.to_str().unwrap_or("?")));
            }
        }
        // SAFETY: valid physical device of `instance` (caller contract).
        let families =
            unsafe { instance.get_physical_device_queue_family_properties(physical_device) };
        let family_flags = |q: &EngineQueue| {
            families
                .get(q.family_index as usize)
                .map_or(vk::QueueFlags::empty(), |f| f.queue_flags)
        };
        let chosen = pick_family(queues.iter().map(|q| (q.family_index, family_flags(q))))
            .ok_or(VkError::NoComputeQueue)?;
        let queue = *queues
            .iter()
            .find(|q| q.family_index == chosen)
            .ok_or(VkError::NoComputeQueue)?;

        let mut as_props = vk::PhysicalDeviceAccelerationStructurePropertiesKHR::default();
        let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut as_props);
        // SAFETY: valid physical device; the chain holds one valid output struct.
        unsafe { instance.get_physical_device_properties2(physical_device, &mut props2) };
        let device_name = props2
            .properties
            .device_name_as_c_str()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let limits = AccelerationStructureLimits {
            min_scratch_offset_alignment: as_props
                .min_acceleration_structure_scratch_offset_alignment
                .max(1),
            max_instance_count: as_props.max_instance_count,
            max_primitive_count: as_props.max_primitive_count,
            max_geometry_count: as_props.max_geometry_count,
        };
        // SAFETY: valid physical device.
        let memory_properties =
            unsafe { instance.get_physical_device_memory_properties(physical_device) };
        let accel = ash::khr::acceleration_structure::Device::new(instance, device);
        let (pipeline_fns, pipeline_properties) = if tracing.ray_tracing_pipeline {
            // SAFETY: valid handles (caller contract), the pipeline extension
            // enabled (the caller's `tracing`).
            let (fns, props) = unsafe { load_pipeline_path(instance, device, physical_device) }?;
            (Some(fns), Some(props))
        } else {
            (None, None)
        };
        Ok(Self {
            inner: Arc::new(Inner {
                instance: instance.clone(),
                device: device.clone(),
                physical_device,
                queue,
                queue_lock: Mutex::new(()),
                host_waits: std::sync::atomic::AtomicU64::new(0),
                accel,
                limits,
                tracing,
                pipeline_fns,
                pipeline_properties,
                memory_properties,
                device_name,
                memory: MemoryCounters::default(),
                allocator,
                _owned: owned,
            }),
        })
    }

    /// The instance.
    pub fn instance(&self) -> &ash::Instance {
        &self.inner.instance
    }
    /// The device.
    pub fn device(&self) -> &ash::Device {
        &self.inner.device
    }
    /// The physical device.
    pub fn physical_device(&self) -> vk::PhysicalDevice {
        self.inner.physical_device
    }
    /// The queue lipac submits to.
    pub fn queue(&self) -> vk::Queue {
        self.inner.queue.queue
    }
    /// The family of [`DeviceContext::queue`]; command pools for lipac's
    /// recordings come from this family.
    pub fn queue_family_index(&self) -> u32 {
        self.inner.queue.family_index
    }
    /// The loaded `VK_KHR_acceleration_structure` functions.
    pub fn acceleration_structure(&self) -> &ash::khr::acceleration_structure::Device {
        &self.inner.accel
    }
    /// The tracing paths lipac's tracers may use on this device.
    pub fn tracing(&self) -> TracingPaths {
        self.inner.tracing
    }
    /// `Ok` when this device offers `path`; else
    /// [`VkError::MissingFeature`] naming `component`.
    ///
    /// # Errors
    ///
    /// [`VkError::MissingFeature`].
    pub fn require_tracing(&self, path: TracingPath, component: &'static str) -> Result<()> {
        self.inner.tracing.require(path, component)
    }
    /// The ray-tracing-pipeline properties (shader group handle size and
    /// alignments), when the pipeline path is enabled.
    pub fn ray_tracing_pipeline_properties(&self) -> Option<&RayTracingPipelineProperties> {
        self.inner.pipeline_properties.as_ref()
    }
    /// The loaded `VK_KHR_ray_tracing_pipeline` functions, when the pipeline
    /// path is enabled.
    pub fn ray_tracing_pipeline(&self) -> Option<&ash::khr::ray_tracing_pipeline::Device> {
        self.inner.pipeline_fns.as_ref()
    }
    /// Acceleration-structure limits of the device.
    pub fn limits(&self) -> &AccelerationStructureLimits {
        &self.inner.limits
    }
    /// Memory types and heaps of the device.
    pub fn memory_properties(&self) -> &vk::PhysicalDeviceMemoryProperties {
        &self.inner.memory_properties
    }
    /// The device's name (e.g. `llvmpipe (LLVM 15.0.6, 256 bits)`).
    pub fn device_name(&self) -> &str {
        &self.inner.device_name
    }
    /// The allocator every buffer of this context takes its memory from.
    pub fn allocator(&self) -> &dyn DeviceAllocator {
        &*self.inner.allocator
    }
    /// The device memory this context's buffers hold: live buffers and the
    /// exact bytes of their memory requirements, with the allocator's blocks
    /// when it reports them.
    pub fn memory_stats(&self) -> DeviceMemoryStats {
        self.inner.memory.snapshot(self.inner.allocator.blocks())
    }
    pub(crate) fn memory_counters(&self) -> &MemoryCounters {
        &self.inner.memory
    }
    /// Whether two contexts are the same binding.
    pub fn same_as(&self, other: &DeviceContext) -> bool {
        Arc::ptr_eq(&self.inner, &other.inner)
    }
    /// Locks lipac's use of the queue (held while lipac submits).
    /// How many times lipac blocked the host on this device's GPU work
    /// ([`crate::OneShot::run`], and [`crate::FrameSubmitter::submit`] when
    /// its command buffer was still in flight). [`crate::LipacVk`]'s frame
    /// calls never do: the count moves only at its set-up.
    pub fn host_waits(&self) -> u64 {
        self.inner
            .host_waits
            .load(std::sync::atomic::Ordering::Relaxed)
    }

    pub(crate) fn count_host_wait(&self) {
        self.inner
            .host_waits
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    }

    pub(crate) fn lock_queue(&self) -> MutexGuard<'_, ()> {
        // A poisoned lock only means another submit panicked; the queue is fine.
        self.inner
            .queue_lock
            .lock()
            .unwrap_or_else(|e| e.into_inner())
    }
}

/// Checks that the pipeline path's functions are loaded, loads them and
/// reads the pipeline properties.
///
/// # Safety
///
/// Valid handles that belong together; the device enabled
/// `VK_KHR_ray_tracing_pipeline`.
unsafe fn load_pipeline_path(
    instance: &ash::Instance,
    device: &ash::Device,
    physical_device: vk::PhysicalDevice,
) -> Result<(
    ash::khr::ray_tracing_pipeline::Device,
    RayTracingPipelineProperties,
)> {
    for name in PIPELINE_DEVICE_FUNCTIONS {
        // SAFETY: valid device of `instance`; NUL-terminated name.
        let f =
            unsafe { (instance.fp_v1_0().get_device_proc_addr)(device.handle(), name.as_ptr()) };
        if f.is_none() {
            return Err(VkError::MissingDeviceFunction(name.to_str().unwrap_or("?")));
        }
    }
    let mut rt = vk::PhysicalDeviceRayTracingPipelinePropertiesKHR::default();
    let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut rt);
    // SAFETY: valid physical device supporting the extension; one output struct.
    unsafe { instance.get_physical_device_properties2(physical_device, &mut props2) };
    let props = RayTracingPipelineProperties {
        handle_size: rt.shader_group_handle_size,
        handle_alignment: rt.shader_group_handle_alignment.max(1),
        base_alignment: rt.shader_group_base_alignment.max(1),
        max_stride: rt.max_shader_group_stride,
        max_recursion_depth: rt.max_ray_recursion_depth,
    };
    Ok((
        ash::khr::ray_tracing_pipeline::Device::new(instance, device),
        props,
    ))
}

#[cfg(test)]
mod tests;
