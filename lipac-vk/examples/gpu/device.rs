//! The GPU examples' device: lipac's `HeadlessContext` (acceleration
//! structures and compute, with ray queries or ray-tracing pipelines,
//! whichever the device has: the measured work traces nothing) and what the
//! examples read of it: timestamp period and bits, memory heaps, buffer
//! limits.
//!
//! `LIPAC_VK_DEVICE` picks the device (index or name), `LIPAC_VK_HIDE`
//! hides tracing paths (`ray-query` runs as on a GPU without them);
//! `LIPAC_VALIDATION=1` enables `VK_LAYER_KHRONOS_validation` and the
//! examples fail on its errors.

use ash::vk;
use lipac_vk::{DeviceContext, HeadlessContext, HeadlessOptions, Validation, VkError};
use std::ffi::CStr;

/// What the examples read of the device, for logs and JSON.
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
    /// Ray queries enabled.
    pub ray_query: bool,
    /// Ray-tracing pipelines enabled.
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
    /// `HeadlessContext::summary`.
    pub summary: String,
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

    fn query(h: &HeadlessContext) -> Self {
        let ctx = h.context();
        let (instance, pd) = (ctx.instance(), ctx.physical_device());
        let mut driver = vk::PhysicalDeviceDriverProperties::default();
        let mut v13 = vk::PhysicalDeviceVulkan13Properties::default();
        let mut maint3 = vk::PhysicalDeviceMaintenance3Properties::default();
        let mut p2 = vk::PhysicalDeviceProperties2::default()
            .push_next(&mut driver)
            .push_next(&mut v13)
            .push_next(&mut maint3);
        // SAFETY: the context's physical device of its instance; the chain
        // holds valid output structs of Vulkan 1.1–1.3 core, which the
        // device supports (the context requires 1.3).
        unsafe { instance.get_physical_device_properties2(pd, &mut p2) };
        let props = p2.properties;
        // SAFETY: as above.
        let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
        let memory = ctx.memory_properties();
        let cstr = |b: &[std::ffi::c_char]| {
            // SAFETY: the driver name and info are NUL-terminated arrays (spec).
            unsafe { CStr::from_ptr(b.as_ptr()) }
                .to_string_lossy()
                .into_owned()
        };
        let device_type = match props.device_type {
            vk::PhysicalDeviceType::DISCRETE_GPU => "discrete",
            vk::PhysicalDeviceType::INTEGRATED_GPU => "integrated",
            vk::PhysicalDeviceType::VIRTUAL_GPU => "virtual",
            vk::PhysicalDeviceType::CPU => "cpu",
            _ => "other",
        };
        let tracing = ctx.tracing();
        Self {
            index: h.device_index(),
            name: ctx.device_name().to_owned(),
            device_type: device_type.into(),
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
            ray_query: tracing.ray_query,
            ray_tracing_pipeline: tracing.ray_tracing_pipeline,
            timestamp_period_ns: f64::from(props.limits.timestamp_period),
            timestamp_valid_bits: families
                .get(ctx.queue_family_index() as usize)
                .map_or(0, |f| f.timestamp_valid_bits),
            heaps: memory.memory_heaps[..memory.memory_heap_count as usize]
                .iter()
                .map(|h| (h.size, h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL)))
                .collect(),
            max_buffer_size: v13.max_buffer_size,
            max_memory_allocation_size: maint3.max_memory_allocation_size,
            summary: h.summary(),
        }
    }
}

/// The device (drop it after every lipac object made from
/// [`GpuDevice::ctx`]) and what was read of it.
pub struct GpuDevice {
    headless: HeadlessContext,
    pub info: DeviceInfo,
}

impl GpuDevice {
    /// The device `LIPAC_VK_DEVICE` names, or the best there is.
    pub fn new() -> Result<Self, VkError> {
        let validation = if std::env::var("LIPAC_VALIDATION").is_ok_and(|v| v == "1") {
            Validation::Required
        } else {
            Validation::Off
        };
        let headless = HeadlessContext::with_options(&HeadlessOptions::from_env(validation)?)?;
        let info = DeviceInfo::query(&headless);
        Ok(Self { headless, info })
    }

    /// lipac's context on the device.
    pub fn ctx(&self) -> &DeviceContext {
        self.headless.context()
    }

    /// Validation (and other error-severity) messages so far.
    pub fn validation_errors(&self) -> Vec<String> {
        self.headless.validation_errors()
    }

    /// One line for logs.
    pub fn describe(&self) -> String {
        format!(
            "{}; driver {}; Vulkan {}",
            self.info.summary, self.info.driver, self.info.api_version
        )
    }
}
