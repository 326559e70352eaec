//! Binding to an engine's Vulkan device ([`DeviceContext`]) and a small
//! self-contained device for examples and tests ([`HeadlessContext`]).

use crate::device_allocator::{DeviceAllocator, DeviceMemoryStats, GpuAllocator, MemoryCounters};
use crate::error::{Result, VkContext, VkError};
use ash::vk;
use std::ffi::{c_void, CStr};
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

/// Extensions a device must enable for lipac (besides Vulkan 1.3 core).
pub const REQUIRED_DEVICE_EXTENSIONS: [&CStr; 3] = [
    ash::khr::acceleration_structure::NAME,
    ash::khr::ray_query::NAME,
    ash::khr::deferred_host_operations::NAME,
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
    accel: ash::khr::acceleration_structure::Device,
    limits: AccelerationStructureLimits,
    memory_properties: vk::PhysicalDeviceMemoryProperties,
    device_name: String,
    memory: MemoryCounters,
    /// Dropped before `_owned` (field order): frees its blocks while the
    /// device still exists.
    allocator: Arc<dyn DeviceAllocator>,
    /// Only held to be dropped last (destroys a headless device).
    _owned: Option<Owned>,
}

/// Handles a [`HeadlessContext`] created; destroyed when the context is
/// (after its allocator), or on an error path of `HeadlessContext::new`.
struct Owned {
    _entry: ash::Entry,
    instance: ash::Instance,
    device: ash::Device,
    messenger: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    _log: Arc<Mutex<Vec<String>>>,
}

impl Drop for Owned {
    fn drop(&mut self) {
        // SAFETY: the headless context created this device and instance. The
        // `Owned` is dropped last of the context's parts, after every lipac
        // object (each holds an Arc of the context) and after the allocator
        // freed its memory. Waiting for idle first makes sure no submitted
        // work still uses the device.
        unsafe {
            let _ = self.device.device_wait_idle();
            self.device.destroy_device(None);
            if let Some((loader, messenger)) = &self.messenger {
                loader.destroy_debug_utils_messenger(*messenger, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}

impl std::fmt::Debug for DeviceContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DeviceContext")
            .field("device", &self.inner.device_name)
            .field("queue_family", &self.inner.queue.family_index)
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
    /// `timelineSemaphore`, `synchronization2`, `accelerationStructure` and
    /// `rayQuery` enabled. The engine must keep the device alive until every
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
        unsafe { Self::bind(instance, device, physical_device, queues, allocator, None) }
    }

    /// # Safety
    /// As [`DeviceContext::from_engine_with_allocator`].
    unsafe fn bind(
        instance: &ash::Instance,
        device: &ash::Device,
        physical_device: vk::PhysicalDevice,
        queues: &[EngineQueue],
        allocator: Arc<dyn DeviceAllocator>,
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
        Ok(Self {
            inner: Arc::new(Inner {
                instance: instance.clone(),
                device: device.clone(),
                physical_device,
                queue,
                queue_lock: Mutex::new(()),
                accel,
                limits,
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
    pub(crate) fn lock_queue(&self) -> MutexGuard<'_, ()> {
        // A poisoned lock only means another submit panicked; the queue is fine.
        self.inner
            .queue_lock
            .lock()
            .unwrap_or_else(|e| e.into_inner())
    }
}

/// Whether [`HeadlessContext::new`] enables `VK_LAYER_KHRONOS_validation`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Validation {
    /// Never.
    Off,
    /// When the layer is installed.
    #[default]
    IfAvailable,
    /// Always; [`VkError::ValidationLayerMissing`] when it is not installed.
    Required,
}

/// A Vulkan instance and device of lipac's own, for examples and tests
/// (engines use [`DeviceContext::from_engine`] instead).
///
/// Picks the best device (discrete, integrated, virtual, CPU) with Vulkan
/// 1.3, [`REQUIRED_DEVICE_EXTENSIONS`], buffer device address, timeline
/// semaphores, synchronization2, acceleration structures and ray queries.
/// When `VK_EXT_debug_utils` is available a messenger records every
/// error-severity message (validation errors among them); see
/// [`HeadlessContext::validation_errors`].
///
/// ```no_run
/// use lipac_vk::{HeadlessContext, Validation};
/// let headless = HeadlessContext::new(Validation::IfAvailable)?;
/// println!("running on {}", headless.context().device_name());
/// assert!(headless.validation_errors().is_empty());
/// # Ok::<(), lipac_vk::VkError>(())
/// ```
pub struct HeadlessContext {
    context: DeviceContext,
    log: Arc<Mutex<Vec<String>>>,
    validation: bool,
    debug_utils: Option<ash::ext::debug_utils::Instance>,
}

impl std::fmt::Debug for HeadlessContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HeadlessContext")
            .field("context", &self.context)
            .field("validation", &self.validation)
            .finish_non_exhaustive()
    }
}

/// Records error-severity messages into the `Mutex<Vec<String>>` at `user`.
unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) && !user.is_null() {
        // SAFETY: the loader passes a valid callback-data pointer (or null) for
        // the duration of the call.
        let message = unsafe { data.as_ref() }
            // SAFETY: `p_message` is null or a NUL-terminated string (spec).
            .and_then(|d| unsafe { d.message_as_c_str() })
            .map(|m| m.to_string_lossy().into_owned())
            .unwrap_or_else(|| "<no message>".to_owned());
        // SAFETY: `user` is `Arc::as_ptr` of the log, which the context keeps
        // alive until after the messenger is destroyed.
        let log = unsafe { &*(user as *const Mutex<Vec<String>>) };
        log.lock().unwrap_or_else(|e| e.into_inner()).push(message);
    }
    vk::FALSE
}

struct Candidate {
    physical_device: vk::PhysicalDevice,
    family: u32,
    rank: u32,
}

fn check_device(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
) -> std::result::Result<Candidate, String> {
    // SAFETY: `pd` was enumerated from `instance`.
    let props = unsafe { instance.get_physical_device_properties(pd) };
    let name = props
        .device_name_as_c_str()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    if props.api_version < vk::API_VERSION_1_3 {
        return Err(format!(
            "{name}: Vulkan {}.{} < 1.3",
            vk::api_version_major(props.api_version),
            vk::api_version_minor(props.api_version)
        ));
    }
    // SAFETY: as above.
    let exts = unsafe { instance.enumerate_device_extension_properties(pd) }
        .map_err(|e| format!("{name}: enumerating extensions failed: {e}"))?;
    for need in REQUIRED_DEVICE_EXTENSIONS {
        if !exts.iter().any(|e| e.extension_name_as_c_str() == Ok(need)) {
            return Err(format!("{name}: lacks {}", need.to_string_lossy()));
        }
    }
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
    let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
    let mut fas = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default();
    let mut frq = vk::PhysicalDeviceRayQueryFeaturesKHR::default();
    let mut f2 = vk::PhysicalDeviceFeatures2::default()
        .push_next(&mut f12)
        .push_next(&mut f13)
        .push_next(&mut fas)
        .push_next(&mut frq);
    // SAFETY: as above; the chain holds valid output structs.
    unsafe { instance.get_physical_device_features2(pd, &mut f2) };
    let missing: Vec<&str> = [
        (f12.buffer_device_address, "bufferDeviceAddress"),
        (f12.timeline_semaphore, "timelineSemaphore"),
        (f13.synchronization2, "synchronization2"),
        (fas.acceleration_structure, "accelerationStructure"),
        (frq.ray_query, "rayQuery"),
    ]
    .into_iter()
    .filter(|(on, _)| *on == vk::FALSE)
    .map(|(_, n)| n)
    .collect();
    if !missing.is_empty() {
        return Err(format!("{name}: lacks features {}", missing.join(", ")));
    }
    let family =
        preferred_queue_family(instance, pd).ok_or_else(|| format!("{name}: no compute queue"))?;
    let rank = match props.device_type {
        vk::PhysicalDeviceType::DISCRETE_GPU => 0,
        vk::PhysicalDeviceType::INTEGRATED_GPU => 1,
        vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
        vk::PhysicalDeviceType::CPU => 3,
        _ => 4,
    };
    Ok(Candidate {
        physical_device: pd,
        family,
        rank,
    })
}

impl HeadlessContext {
    /// Creates an instance and a device for lipac.
    ///
    /// # Errors
    ///
    /// [`VkError::LoaderUnavailable`] without a Vulkan loader,
    /// [`VkError::NoRayQueryDevice`] when no device qualifies (with the reason
    /// for each), [`VkError::ValidationLayerMissing`] for
    /// [`Validation::Required`] without the layer, [`VkError::Vulkan`] when a
    /// creation call fails.
    pub fn new(validation: Validation) -> Result<Self> {
        Self::with_allocator(validation, |instance, device, physical_device| {
            // SAFETY: the handles belong together and the device has
            // bufferDeviceAddress enabled; the context owns the allocator and
            // drops it before destroying the device.
            let a = unsafe { GpuAllocator::new(instance, device, physical_device) }?;
            Ok(Box::new(a))
        })
    }

    /// As [`HeadlessContext::new`], with every buffer's memory from the
    /// allocator `make_allocator` creates on the new device (tests of
    /// custom [`DeviceAllocator`]s). The context owns the allocator and
    /// drops it, after the last lipac object and before destroying the
    /// device.
    ///
    /// # Errors
    ///
    /// As [`HeadlessContext::new`]; the error of `make_allocator`.
    pub fn with_allocator(
        validation: Validation,
        make_allocator: impl FnOnce(
            &ash::Instance,
            &ash::Device,
            vk::PhysicalDevice,
        ) -> Result<Box<dyn DeviceAllocator>>,
    ) -> Result<Self> {
        // SAFETY: loading the system's Vulkan loader library; ash keeps it loaded
        // for the Entry's lifetime and the Entry lives in the context.
        let entry =
            unsafe { ash::Entry::load() }.map_err(|e| VkError::LoaderUnavailable(e.to_string()))?;
        // SAFETY: entry-level enumeration with a loaded entry.
        let layers = unsafe { entry.enumerate_instance_layer_properties() }
            .ctx("vkEnumerateInstanceLayerProperties")?;
        let validation_name = c"VK_LAYER_KHRONOS_validation";
        let have_validation = layers
            .iter()
            .any(|l| l.layer_name_as_c_str() == Ok(validation_name));
        let enable_validation = match validation {
            Validation::Off => false,
            Validation::IfAvailable => have_validation,
            Validation::Required if have_validation => true,
            Validation::Required => return Err(VkError::ValidationLayerMissing),
        };
        // SAFETY: as above.
        let inst_exts = unsafe { entry.enumerate_instance_extension_properties(None) }
            .ctx("vkEnumerateInstanceExtensionProperties")?;
        let have_debug_utils = inst_exts
            .iter()
            .any(|e| e.extension_name_as_c_str() == Ok(ash::ext::debug_utils::NAME));

        let app = vk::ApplicationInfo::default()
            .application_name(c"lipac")
            .engine_name(c"lipac")
            .api_version(vk::API_VERSION_1_3);
        let layer_ptrs: Vec<*const i8> = if enable_validation {
            vec![validation_name.as_ptr()]
        } else {
            vec![]
        };
        let ext_ptrs: Vec<*const i8> = if have_debug_utils {
            vec![ash::ext::debug_utils::NAME.as_ptr()]
        } else {
            vec![]
        };
        let create = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layer_ptrs)
            .enabled_extension_names(&ext_ptrs);
        // SAFETY: the create info points at live, NUL-terminated names.
        let instance = match unsafe { entry.create_instance(&create, None) } {
            Ok(i) => i,
            // The loader found no driver at all.
            Err(vk::Result::ERROR_INCOMPATIBLE_DRIVER) => {
                return Err(VkError::NoRayQueryDevice {
                    rejected: vec![
                        "no Vulkan 1.3 driver (vkCreateInstance: ERROR_INCOMPATIBLE_DRIVER)".into(),
                    ],
                })
            }
            Err(e) => return Err(VkError::vk("vkCreateInstance", e)),
        };

        let log: Arc<Mutex<Vec<String>>> = Arc::new(Mutex::new(Vec::new()));
        let mut messenger = None;
        let mut debug_utils = None;
        if have_debug_utils {
            let loader = ash::ext::debug_utils::Instance::new(&entry, &instance);
            let info = vk::DebugUtilsMessengerCreateInfoEXT::default()
                .message_severity(
                    vk::DebugUtilsMessageSeverityFlagsEXT::ERROR
                        | vk::DebugUtilsMessageSeverityFlagsEXT::WARNING,
                )
                .message_type(
                    vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                        | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                        | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
                )
                .pfn_user_callback(Some(debug_callback))
                .user_data(Arc::as_ptr(&log) as *mut c_void);
            // SAFETY: valid instance with debug_utils enabled; the user data
            // outlives the messenger (the log Arc is kept in `Owned`).
            match unsafe { loader.create_debug_utils_messenger(&info, None) } {
                Ok(m) => messenger = Some((loader.clone(), m)),
                Err(e) => {
                    // SAFETY: nothing else was created from the instance yet.
                    unsafe { instance.destroy_instance(None) };
                    return Err(VkError::vk("vkCreateDebugUtilsMessengerEXT", e));
                }
            }
            debug_utils = Some(loader);
        }
        // From here on `Owned`'s drop (through `cleanup`) destroys what exists.
        let cleanup = |instance: &ash::Instance,
                       messenger: &Option<(
            ash::ext::debug_utils::Instance,
            vk::DebugUtilsMessengerEXT,
        )>| {
            // SAFETY: only the messenger and the instance exist; destroyed in order.
            unsafe {
                if let Some((loader, m)) = messenger {
                    loader.destroy_debug_utils_messenger(*m, None);
                }
                instance.destroy_instance(None);
            }
        };

        let picked = (|| {
            // SAFETY: valid instance.
            let devices = unsafe { instance.enumerate_physical_devices() }
                .ctx("vkEnumeratePhysicalDevices")?;
            let mut rejected = Vec::new();
            let mut best: Option<Candidate> = None;
            for pd in devices {
                match check_device(&instance, pd) {
                    Ok(c) => {
                        if best.as_ref().is_none_or(|b| c.rank < b.rank) {
                            best = Some(c);
                        }
                    }
                    Err(why) => rejected.push(why),
                }
            }
            best.ok_or(VkError::NoRayQueryDevice { rejected })
        })();
        let candidate = match picked {
            Ok(c) => c,
            Err(e) => {
                cleanup(&instance, &messenger);
                return Err(e);
            }
        };

        let priorities = [1.0f32];
        let queue_info = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(candidate.family)
            .queue_priorities(&priorities)];
        let ext_ptrs: Vec<*const i8> = REQUIRED_DEVICE_EXTENSIONS
            .iter()
            .map(|n| n.as_ptr())
            .collect();
        let mut f12 = vk::PhysicalDeviceVulkan12Features::default()
            .buffer_device_address(true)
            .timeline_semaphore(true);
        let mut f13 = vk::PhysicalDeviceVulkan13Features::default().synchronization2(true);
        let mut fas = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default()
            .acceleration_structure(true);
        let mut frq = vk::PhysicalDeviceRayQueryFeaturesKHR::default().ray_query(true);
        let device_info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queue_info)
            .enabled_extension_names(&ext_ptrs)
            .push_next(&mut f12)
            .push_next(&mut f13)
            .push_next(&mut fas)
            .push_next(&mut frq);
        // SAFETY: the physical device supports every extension and feature
        // enabled here (checked by `check_device`); pointers are live.
        let device = match unsafe {
            instance.create_device(candidate.physical_device, &device_info, None)
        } {
            Ok(d) => d,
            Err(e) => {
                cleanup(&instance, &messenger);
                return Err(VkError::vk("vkCreateDevice", e));
            }
        };
        // SAFETY: queue 0 of the family was requested at device creation.
        let queue = unsafe { device.get_device_queue(candidate.family, 0) };
        // From here `owned` destroys the device and instance when dropped
        // (on an error path, or with the context).
        let owned = Owned {
            _entry: entry,
            instance: instance.clone(),
            device: device.clone(),
            messenger,
            _log: log.clone(),
        };
        let allocator: Arc<dyn DeviceAllocator> =
            match make_allocator(&instance, &device, candidate.physical_device) {
                Ok(a) => Arc::from(a),
                Err(e) => {
                    drop(owned);
                    return Err(e);
                }
            };
        // SAFETY: handles were just created together, with lipac's extensions
        // and features; the allocator was made for this device; `owned` makes
        // the context destroy them last, after the allocator.
        let context = unsafe {
            DeviceContext::bind(
                &instance,
                &device,
                candidate.physical_device,
                &[EngineQueue {
                    queue,
                    family_index: candidate.family,
                }],
                allocator,
                Some(owned),
            )
        }?;
        Ok(Self {
            context,
            log,
            validation: enable_validation,
            debug_utils,
        })
    }

    /// The device context (clone it to share).
    pub fn context(&self) -> &DeviceContext {
        &self.context
    }

    /// Whether `VK_LAYER_KHRONOS_validation` is enabled.
    pub fn validation_enabled(&self) -> bool {
        self.validation
    }

    /// Whether error messages are being recorded (`VK_EXT_debug_utils` present).
    pub fn records_messages(&self) -> bool {
        self.debug_utils.is_some()
    }

    /// Error-severity messages recorded so far (validation errors among them).
    pub fn validation_errors(&self) -> Vec<String> {
        self.log.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Submits a message of the given severity through `VK_EXT_debug_utils`,
    /// as a layer would; tests use it to check that errors are recorded.
    /// Returns `false` when debug utils are not available.
    pub fn submit_debug_message(
        &self,
        severity: vk::DebugUtilsMessageSeverityFlagsEXT,
        message: &CStr,
    ) -> bool {
        let Some(loader) = &self.debug_utils else {
            return false;
        };
        let data = vk::DebugUtilsMessengerCallbackDataEXT::default().message(message);
        // SAFETY: the instance has debug utils enabled; `data` points at a live
        // NUL-terminated message.
        unsafe {
            loader.submit_debug_utils_message(
                severity,
                vk::DebugUtilsMessageTypeFlagsEXT::GENERAL,
                &data,
            )
        };
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prefers_async_compute_family() {
        let g = vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE | vk::QueueFlags::TRANSFER;
        let c = vk::QueueFlags::COMPUTE | vk::QueueFlags::TRANSFER;
        let t = vk::QueueFlags::TRANSFER;
        let fams = [(0, g), (1, c), (2, t)];
        assert_eq!(pick_family(fams.iter().copied()), Some(1));
        assert_eq!(pick_family([(0, t), (1, g)].iter().copied()), Some(1));
        assert_eq!(pick_family([(0, t)].iter().copied()), None);
    }
}
