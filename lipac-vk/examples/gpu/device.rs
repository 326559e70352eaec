//! A Vulkan instance and device of the GPU examples' own, bound to lipac
//! through `DeviceContext::from_engine_with_allocator`, as an engine binds
//! its device. It asks for what the measured work needs (acceleration
//! structures and compute: Vulkan 1.3, `VK_KHR_acceleration_structure`,
//! buffer device address, timeline semaphores, synchronization2) and
//! enables ray queries where the device has them, else ray-tracing
//! pipelines (`vkGetAccelerationStructureBuildSizesKHR` needs one of the two
//! features enabled), so it runs on GPUs that trace with ray-tracing
//! pipelines alone. Kept apart from
//! `HeadlessContext` on purpose: a device-creation helper the examples can
//! drop once `HeadlessContext` takes such devices.
//!
//! Device choice: a discrete GPU before an integrated, virtual or CPU one;
//! `LIPAC_DEVICE=TEXT` picks the first device whose name contains TEXT (or
//! whose index is TEXT). `LIPAC_VALIDATION=1` enables
//! `VK_LAYER_KHRONOS_validation` and counts its errors;
//! `LIPAC_NO_RAY_QUERY=1` leaves ray queries off where the device has them.

use ash::vk;
use lipac_vk::{DeviceAllocator, DeviceContext, EngineQueue, GpuAllocator, VkError};
use std::ffi::{c_void, CStr};
use std::sync::{Arc, Mutex};

/// What was chosen, for logs and JSON.
#[derive(Clone, Debug)]
pub struct DeviceInfo {
    /// Index among the physical devices.
    pub index: usize,
    pub name: String,
    pub device_type: String,
    pub vendor_id: u32,
    pub device_id: u32,
    pub driver: String,
    pub api_version: String,
    /// `VK_KHR_ray_query` present (and enabled).
    pub ray_query: bool,
    /// `VK_KHR_ray_tracing_pipeline` present (not enabled).
    pub ray_tracing_pipeline: bool,
    /// Nanoseconds per timestamp tick.
    pub timestamp_period_ns: f64,
    /// Valid bits of the queue family's timestamps (0: none).
    pub timestamp_valid_bits: u32,
    /// Bytes of each memory heap, `(size, device_local)`.
    pub heaps: Vec<(u64, bool)>,
    /// `maxBufferSize` (Vulkan 1.3).
    pub max_buffer_size: u64,
    /// `maxMemoryAllocationSize`.
    pub max_memory_allocation_size: u64,
    /// Devices not chosen, and why.
    pub others: Vec<String>,
}

impl DeviceInfo {
    /// The largest device-local heap.
    pub fn device_local_heap(&self) -> u64 {
        self.heaps
            .iter()
            .filter(|(_, local)| *local)
            .map(|(s, _)| *s)
            .max()
            .unwrap_or(0)
    }
    /// A CPU implementation (lavapipe, SwiftShader): its heap is host RAM.
    pub fn is_cpu(&self) -> bool {
        self.device_type == "cpu"
    }
}

/// The instance, the device and lipac's context on it. Drop it after every
/// lipac object made from [`GpuDevice::ctx`].
pub struct GpuDevice {
    ctx: Option<DeviceContext>,
    device: ash::Device,
    messenger: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    log: Arc<Mutex<Vec<String>>>,
    instance: ash::Instance,
    _entry: ash::Entry,
    pub info: DeviceInfo,
}

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// Records error-severity messages into the `Mutex<Vec<String>>` at `user`.
unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) && !user.is_null() {
        // SAFETY: the loader passes a valid callback-data pointer (or null)
        // for the duration of the call.
        let message = unsafe { data.as_ref() }
            // SAFETY: `p_message` is null or a NUL-terminated string (spec).
            .and_then(|d| unsafe { d.message_as_c_str() })
            .map(|m| m.to_string_lossy().into_owned())
            .unwrap_or_else(|| "<no message>".to_owned());
        // SAFETY: `user` is `Arc::as_ptr` of the log, which `GpuDevice` keeps
        // alive until after the messenger is destroyed.
        let log = unsafe { &*(user as *const Mutex<Vec<String>>) };
        log.lock().unwrap_or_else(|e| e.into_inner()).push(message);
    }
    vk::FALSE
}

struct Candidate {
    pd: vk::PhysicalDevice,
    family: u32,
    rank: u32,
    ray_query: bool,
    /// Enable `VK_KHR_ray_tracing_pipeline` (without ray queries: the
    /// acceleration-structure size query needs one of the two features).
    ray_tracing_pipeline: bool,
    info: DeviceInfo,
}

fn type_name(t: vk::PhysicalDeviceType) -> (&'static str, u32) {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => ("discrete", 0),
        vk::PhysicalDeviceType::INTEGRATED_GPU => ("integrated", 1),
        vk::PhysicalDeviceType::VIRTUAL_GPU => ("virtual", 2),
        vk::PhysicalDeviceType::CPU => ("cpu", 3),
        _ => ("other", 4),
    }
}

fn check(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
    index: usize,
) -> Result<Candidate, String> {
    let mut driver = vk::PhysicalDeviceDriverProperties::default();
    let mut v13 = vk::PhysicalDeviceVulkan13Properties::default();
    let mut p2 = vk::PhysicalDeviceProperties2::default()
        .push_next(&mut driver)
        .push_next(&mut v13);
    // SAFETY: `pd` was enumerated from `instance`; the chain holds valid
    // output structs (Vulkan 1.2/1.3 core, checked below before use).
    unsafe { instance.get_physical_device_properties2(pd, &mut p2) };
    let props = p2.properties;
    let name = props
        .device_name_as_c_str()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    if props.api_version < vk::API_VERSION_1_3 {
        return Err(format!("{name}: Vulkan < 1.3"));
    }
    // SAFETY: as above.
    let exts = unsafe { instance.enumerate_device_extension_properties(pd) }
        .map_err(|e| format!("{name}: enumerating extensions: {e}"))?;
    let has = |n: &CStr| exts.iter().any(|e| e.extension_name_as_c_str() == Ok(n));
    for need in [
        ash::khr::acceleration_structure::NAME,
        ash::khr::deferred_host_operations::NAME,
    ] {
        if !has(need) {
            return Err(format!("{name}: lacks {}", need.to_string_lossy()));
        }
    }
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
    let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
    let mut fas = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default();
    let mut f2 = vk::PhysicalDeviceFeatures2::default()
        .push_next(&mut f12)
        .push_next(&mut f13)
        .push_next(&mut fas);
    // SAFETY: as above.
    unsafe { instance.get_physical_device_features2(pd, &mut f2) };
    let missing: Vec<&str> = [
        (f12.buffer_device_address, "bufferDeviceAddress"),
        (f12.timeline_semaphore, "timelineSemaphore"),
        (f13.synchronization2, "synchronization2"),
        (fas.acceleration_structure, "accelerationStructure"),
    ]
    .into_iter()
    .filter(|(on, _)| *on == vk::FALSE)
    .map(|(_, n)| n)
    .collect();
    if !missing.is_empty() {
        return Err(format!("{name}: lacks {}", missing.join(", ")));
    }
    // LIPAC_NO_RAY_QUERY=1: as on a device without them (to check on one
    // that has them that nothing here needs them).
    let mut ray_query = has(ash::khr::ray_query::NAME)
        && !std::env::var("LIPAC_NO_RAY_QUERY").is_ok_and(|v| v == "1");
    if ray_query {
        let mut frq = vk::PhysicalDeviceRayQueryFeaturesKHR::default();
        let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut frq);
        // SAFETY: as above; the extension is present.
        unsafe { instance.get_physical_device_features2(pd, &mut f2) };
        ray_query = frq.ray_query == vk::TRUE;
    }
    let mut ray_tracing_pipeline = false;
    if !ray_query && has(ash::khr::ray_tracing_pipeline::NAME) {
        let mut frt = vk::PhysicalDeviceRayTracingPipelineFeaturesKHR::default();
        let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut frt);
        // SAFETY: as above; the extension is present.
        unsafe { instance.get_physical_device_features2(pd, &mut f2) };
        ray_tracing_pipeline = frt.ray_tracing_pipeline == vk::TRUE;
    }
    if !ray_query && !ray_tracing_pipeline {
        // vkGetAccelerationStructureBuildSizesKHR needs either feature.
        return Err(format!(
            "{name}: neither rayQuery nor rayTracingPipeline (acceleration-structure sizes need one)"
        ));
    }
    let family = lipac_vk::preferred_queue_family(instance, pd)
        .ok_or_else(|| format!("{name}: no compute queue"))?;
    // SAFETY: as above.
    let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
    // SAFETY: as above.
    let memory = unsafe { instance.get_physical_device_memory_properties(pd) };
    let (type_str, rank) = type_name(props.device_type);
    let cstr = |b: &[std::ffi::c_char]| {
        // SAFETY: the driver name and info are NUL-terminated arrays (spec).
        unsafe { CStr::from_ptr(b.as_ptr()) }
            .to_string_lossy()
            .into_owned()
    };
    let info = DeviceInfo {
        index,
        name: name.clone(),
        device_type: type_str.to_owned(),
        vendor_id: props.vendor_id,
        device_id: props.device_id,
        driver: format!(
            "{} {} (driverVersion {:#x})",
            cstr(&driver.driver_name),
            cstr(&driver.driver_info),
            props.driver_version
        ),
        api_version: format!(
            "{}.{}.{}",
            vk::api_version_major(props.api_version),
            vk::api_version_minor(props.api_version),
            vk::api_version_patch(props.api_version)
        ),
        ray_query,
        ray_tracing_pipeline: has(ash::khr::ray_tracing_pipeline::NAME),
        timestamp_period_ns: f64::from(props.limits.timestamp_period),
        timestamp_valid_bits: families
            .get(family as usize)
            .map_or(0, |f| f.timestamp_valid_bits),
        heaps: memory.memory_heaps[..memory.memory_heap_count as usize]
            .iter()
            .map(|h| (h.size, h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL)))
            .collect(),
        max_buffer_size: v13.max_buffer_size,
        max_memory_allocation_size: 0,
        others: Vec::new(),
    };
    Ok(Candidate {
        pd,
        family,
        rank,
        ray_query,
        ray_tracing_pipeline,
        info,
    })
}

/// `LIPAC_DEVICE`: a device index, or text its name contains.
fn wanted(c: &Candidate, pick: &str) -> bool {
    pick.parse::<usize>()
        .map_or_else(|_| c.info.name.contains(pick), |i| i == c.info.index)
}

impl GpuDevice {
    /// The chosen device with lipac's [`GpuAllocator`].
    pub fn new() -> Result<Self, VkError> {
        Self::with_allocator(|instance, device, pd| {
            // SAFETY: the handles belong together; the device has
            // bufferDeviceAddress; the context owns the allocator and is
            // dropped before the device is destroyed.
            let a = unsafe { GpuAllocator::new(instance, device, pd) }?;
            Ok(Arc::new(a))
        })
    }

    /// The chosen device with the allocator `make` returns.
    pub fn with_allocator(
        make: impl FnOnce(
            &ash::Instance,
            &ash::Device,
            vk::PhysicalDevice,
        ) -> Result<Arc<dyn DeviceAllocator>, VkError>,
    ) -> Result<Self, VkError> {
        // SAFETY: loads the system's Vulkan loader; the entry lives in `Self`
        // (last field) so the library stays loaded while it is used.
        let entry =
            unsafe { ash::Entry::load() }.map_err(|e| VkError::LoaderUnavailable(e.to_string()))?;
        let validation = std::env::var("LIPAC_VALIDATION").is_ok_and(|v| v == "1");
        // SAFETY: entry-level enumeration with a loaded entry.
        let layers = unsafe { entry.enumerate_instance_layer_properties() }
            .map_err(|e| VkError::vk("vkEnumerateInstanceLayerProperties", e))?;
        if validation
            && !layers
                .iter()
                .any(|l| l.layer_name_as_c_str() == Ok(VALIDATION_LAYER))
        {
            return Err(VkError::ValidationLayerMissing);
        }
        // SAFETY: as above.
        let exts = unsafe { entry.enumerate_instance_extension_properties(None) }
            .map_err(|e| VkError::vk("vkEnumerateInstanceExtensionProperties", e))?;
        let debug_utils = exts
            .iter()
            .any(|e| e.extension_name_as_c_str() == Ok(ash::ext::debug_utils::NAME));
        let app = vk::ApplicationInfo::default()
            .application_name(c"lipac gpu examples")
            .engine_name(c"lipac")
            .api_version(vk::API_VERSION_1_3);
        let layer_ptrs: Vec<*const i8> = if validation {
            vec![VALIDATION_LAYER.as_ptr()]
        } else {
            vec![]
        };
        let ext_ptrs: Vec<*const i8> = if debug_utils {
            vec![ash::ext::debug_utils::NAME.as_ptr()]
        } else {
            vec![]
        };
        let create = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layer_ptrs)
            .enabled_extension_names(&ext_ptrs);
        // SAFETY: the create info points at live NUL-terminated names.
        let instance = unsafe { entry.create_instance(&create, None) }
            .map_err(|e| VkError::vk("vkCreateInstance", e))?;
        let log = Arc::new(Mutex::new(Vec::new()));
        // From here `partial` destroys what exists on an error path.
        let mut partial = Partial {
            instance: Some(instance.clone()),
            messenger: None,
            device: None,
        };
        if debug_utils {
            let loader = ash::ext::debug_utils::Instance::new(&entry, &instance);
            let info = vk::DebugUtilsMessengerCreateInfoEXT::default()
                .message_severity(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR)
                .message_type(
                    vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                        | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION,
                )
                .pfn_user_callback(Some(debug_callback))
                .user_data(Arc::as_ptr(&log) as *mut c_void);
            // SAFETY: valid instance with debug utils; the log outlives the
            // messenger (destroyed first in `Drop`).
            let m = unsafe { loader.create_debug_utils_messenger(&info, None) }
                .map_err(|e| VkError::vk("vkCreateDebugUtilsMessengerEXT", e))?;
            partial.messenger = Some((loader, m));
        }
        // SAFETY: valid instance.
        let devices = unsafe { instance.enumerate_physical_devices() }
            .map_err(|e| VkError::vk("vkEnumeratePhysicalDevices", e))?;
        let pick = std::env::var("LIPAC_DEVICE").ok();
        let mut rejected = Vec::new();
        let mut best: Option<Candidate> = None;
        for (i, pd) in devices.into_iter().enumerate() {
            match check(&instance, pd, i) {
                Ok(c) if pick.as_deref().is_some_and(|p| !wanted(&c, p)) => {
                    rejected.push(format!("{}: not LIPAC_DEVICE", c.info.name))
                }
                Ok(c) => {
                    if let Some(b) = &best {
                        if c.rank >= b.rank {
                            rejected.push(format!("{}: another device ranks first", c.info.name));
                            continue;
                        }
                        rejected.push(format!("{}: another device ranks first", b.info.name));
                    }
                    best = Some(c);
                }
                Err(why) => rejected.push(why),
            }
        }
        let Some(mut chosen) = best else {
            return Err(VkError::NoRayQueryDevice { rejected });
        };
        chosen.info.others = rejected;
        let mut maint3 = vk::PhysicalDeviceMaintenance3Properties::default();
        let mut p2 = vk::PhysicalDeviceProperties2::default().push_next(&mut maint3);
        // SAFETY: valid physical device; Vulkan 1.1 core struct.
        unsafe { instance.get_physical_device_properties2(chosen.pd, &mut p2) };
        chosen.info.max_memory_allocation_size = maint3.max_memory_allocation_size;

        let priorities = [1.0f32];
        let queue_info = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(chosen.family)
            .queue_priorities(&priorities)];
        let mut names = vec![
            ash::khr::acceleration_structure::NAME.as_ptr(),
            ash::khr::deferred_host_operations::NAME.as_ptr(),
        ];
        if chosen.ray_query {
            names.push(ash::khr::ray_query::NAME.as_ptr());
        }
        if chosen.ray_tracing_pipeline {
            names.push(ash::khr::ray_tracing_pipeline::NAME.as_ptr());
        }
        let mut f12 = vk::PhysicalDeviceVulkan12Features::default()
            .buffer_device_address(true)
            .timeline_semaphore(true);
        let mut f13 = vk::PhysicalDeviceVulkan13Features::default().synchronization2(true);
        let mut fas = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default()
            .acceleration_structure(true);
        let mut frq = vk::PhysicalDeviceRayQueryFeaturesKHR::default().ray_query(true);
        let mut frt = vk::PhysicalDeviceRayTracingPipelineFeaturesKHR::default()
            .ray_tracing_pipeline(true);
        let mut device_info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queue_info)
            .enabled_extension_names(&names)
            .push_next(&mut f12)
            .push_next(&mut f13)
            .push_next(&mut fas);
        if chosen.ray_query {
            device_info = device_info.push_next(&mut frq);
        }
        if chosen.ray_tracing_pipeline {
            device_info = device_info.push_next(&mut frt);
        }
        // SAFETY: every extension and feature enabled was checked above;
        // the pointers are live.
        let device = unsafe { instance.create_device(chosen.pd, &device_info, None) }
            .map_err(|e| VkError::vk("vkCreateDevice", e))?;
        partial.device = Some(device.clone());
        // SAFETY: queue 0 of the family was requested.
        let queue = unsafe { device.get_device_queue(chosen.family, 0) };
        let allocator = make(&instance, &device, chosen.pd)?;
        // SAFETY: the device was created above with acceleration structures,
        // buffer device address, timeline semaphores and synchronization2;
        // the allocator allocates from it; `Self` drops the context before
        // destroying the device.
        let ctx = unsafe {
            DeviceContext::from_engine_with_allocator(
                &instance,
                &device,
                chosen.pd,
                &[EngineQueue {
                    queue,
                    family_index: chosen.family,
                }],
                allocator,
            )
        }?;
        let messenger = partial.messenger.take();
        partial.device = None;
        partial.instance = None;
        Ok(Self {
            ctx: Some(ctx),
            device,
            messenger,
            log,
            instance,
            _entry: entry,
            info: chosen.info,
        })
    }

    /// lipac's context on the device.
    pub fn ctx(&self) -> &DeviceContext {
        self.ctx
            .as_ref()
            .expect("the context lives until the device is dropped")
    }

    /// Validation (and other error-severity) messages so far.
    pub fn validation_errors(&self) -> Vec<String> {
        self.log.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// One line for logs.
    pub fn describe(&self) -> String {
        let i = &self.info;
        format!(
            "device {} ({}, {} GPU, Vulkan {}, driver {}); ray queries: {}; ray-tracing pipelines: {}",
            i.index,
            i.name,
            i.device_type,
            i.api_version,
            i.driver,
            if i.ray_query { "yes" } else { "no" },
            if i.ray_tracing_pipeline { "yes" } else { "no" },
        )
    }
}

impl Drop for GpuDevice {
    fn drop(&mut self) {
        // SAFETY: waits for all work, then drops lipac's context (its
        // allocator frees its blocks) before destroying the device, the
        // messenger and the instance this value created. Every lipac object
        // was dropped before (the examples' rule), so the context drop is
        // the last reference.
        unsafe {
            let _ = self.device.device_wait_idle();
            drop(self.ctx.take());
            self.device.destroy_device(None);
            if let Some((loader, m)) = self.messenger.take() {
                loader.destroy_debug_utils_messenger(m, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}

/// Destroys a half-made device and instance on an error path of
/// [`GpuDevice::with_allocator`].
struct Partial {
    instance: Option<ash::Instance>,
    messenger: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    device: Option<ash::Device>,
}

impl Drop for Partial {
    fn drop(&mut self) {
        // SAFETY: whatever is still here was created by `with_allocator` and
        // is used by nothing (the error path returned before a context
        // existed, or the allocator failed before lipac used it).
        unsafe {
            if let Some(d) = self.device.take() {
                d.destroy_device(None);
            }
            if let Some((loader, m)) = self.messenger.take() {
                loader.destroy_debug_utils_messenger(m, None);
            }
            if let Some(i) = self.instance.take() {
                i.destroy_instance(None);
            }
        }
    }
}
