//! A self-contained Vulkan instance and device for examples and tests
//! ([`HeadlessContext`]), with an optional validation layer whose error
//! messages it records. Engines bind their own device with
//! [`DeviceContext::from_engine`] instead.

use crate::context::{
    preferred_queue_family, DeviceContext, EngineQueue, REQUIRED_DEVICE_EXTENSIONS,
};
use crate::device_allocator::{DeviceAllocator, GpuAllocator};
use crate::error::{Result, VkContext, VkError};
use ash::vk;
use std::ffi::{c_void, CStr};
use std::sync::{Arc, Mutex};

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

/// A physical device that qualifies, with the queue family lipac will use
/// and its rank (lower is better: discrete, integrated, virtual, CPU).
struct Candidate {
    physical_device: vk::PhysicalDevice,
    family: u32,
    rank: u32,
}

/// Whether `pd` has everything lipac needs; the reason when it does not.
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

/// Handles a [`HeadlessContext`] created; destroyed when the context is
/// (after its allocator), or on an error path of
/// [`HeadlessContext::with_allocator`] with whatever exists by then.
pub(crate) struct Owned {
    instance: ash::Instance,
    /// `None` until the device is created.
    device: Option<ash::Device>,
    messenger: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    /// The messenger's user data: kept alive as long as the messenger.
    log: Arc<Mutex<Vec<String>>>,
    /// Keeps the loader library loaded; dropped after the instance is
    /// destroyed (last field).
    _entry: ash::Entry,
}

impl Owned {
    /// Creates the messenger that records error-severity messages into
    /// `self.log`; returns the debug-utils loader.
    fn create_messenger(&mut self) -> Result<ash::ext::debug_utils::Instance> {
        let loader = ash::ext::debug_utils::Instance::new(&self._entry, &self.instance);
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
            .user_data(Arc::as_ptr(&self.log) as *mut c_void);
        // SAFETY: valid instance with debug_utils enabled; the user data
        // outlives the messenger (`self` holds the log Arc and destroys the
        // messenger first).
        let messenger = unsafe { loader.create_debug_utils_messenger(&info, None) }
            .ctx("vkCreateDebugUtilsMessengerEXT")?;
        self.messenger = Some((loader.clone(), messenger));
        Ok(loader)
    }
}

impl Drop for Owned {
    fn drop(&mut self) {
        // SAFETY: the headless context created this device, messenger and
        // instance. The `Owned` is dropped last of the context's parts, after
        // every lipac object (each holds an Arc of the context) and after the
        // allocator freed its memory (on an error path before the context
        // exists, nothing else was created from them). Waiting for idle
        // first makes sure no submitted work still uses the device.
        unsafe {
            if let Some(device) = &self.device {
                let _ = device.device_wait_idle();
                device.destroy_device(None);
            }
            if let Some((loader, messenger)) = &self.messenger {
                loader.destroy_debug_utils_messenger(*messenger, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}

/// What the loader offers that the headless instance uses.
struct InstanceSupport {
    /// Enable `VK_LAYER_KHRONOS_validation`.
    validation: bool,
    /// `VK_EXT_debug_utils` is available (the message recorder).
    debug_utils: bool,
}

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

impl InstanceSupport {
    /// Queries layers and instance extensions and applies `validation`.
    fn query(entry: &ash::Entry, validation: Validation) -> Result<Self> {
        // SAFETY: entry-level enumeration with a loaded entry.
        let layers = unsafe { entry.enumerate_instance_layer_properties() }
            .ctx("vkEnumerateInstanceLayerProperties")?;
        let have_validation = layers
            .iter()
            .any(|l| l.layer_name_as_c_str() == Ok(VALIDATION_LAYER));
        let validation = match validation {
            Validation::Off => false,
            Validation::IfAvailable => have_validation,
            Validation::Required if have_validation => true,
            Validation::Required => return Err(VkError::ValidationLayerMissing),
        };
        // SAFETY: as above.
        let exts = unsafe { entry.enumerate_instance_extension_properties(None) }
            .ctx("vkEnumerateInstanceExtensionProperties")?;
        let debug_utils = exts
            .iter()
            .any(|e| e.extension_name_as_c_str() == Ok(ash::ext::debug_utils::NAME));
        Ok(Self {
            validation,
            debug_utils,
        })
    }
}

/// A Vulkan 1.3 instance with the validation layer and debug utils where
/// `support` says so.
fn create_instance(entry: &ash::Entry, support: &InstanceSupport) -> Result<ash::Instance> {
    let app = vk::ApplicationInfo::default()
        .application_name(c"lipac")
        .engine_name(c"lipac")
        .api_version(vk::API_VERSION_1_3);
    let layer_ptrs: Vec<*const i8> = if support.validation {
        vec![VALIDATION_LAYER.as_ptr()]
    } else {
        vec![]
    };
    let ext_ptrs: Vec<*const i8> = if support.debug_utils {
        vec![ash::ext::debug_utils::NAME.as_ptr()]
    } else {
        vec![]
    };
    let create = vk::InstanceCreateInfo::default()
        .application_info(&app)
        .enabled_layer_names(&layer_ptrs)
        .enabled_extension_names(&ext_ptrs);
    // SAFETY: the create info points at live, NUL-terminated names.
    match unsafe { entry.create_instance(&create, None) } {
        Ok(i) => Ok(i),
        // The loader found no driver at all.
        Err(vk::Result::ERROR_INCOMPATIBLE_DRIVER) => Err(VkError::NoRayQueryDevice {
            rejected: vec![
                "no Vulkan 1.3 driver (vkCreateInstance: ERROR_INCOMPATIBLE_DRIVER)".into(),
            ],
        }),
        Err(e) => Err(VkError::vk("vkCreateInstance", e)),
    }
}

/// The best qualifying physical device; the reason for each rejected one
/// when none qualifies.
fn pick_device(instance: &ash::Instance) -> Result<Candidate> {
    // SAFETY: valid instance.
    let devices =
        unsafe { instance.enumerate_physical_devices() }.ctx("vkEnumeratePhysicalDevices")?;
    let mut rejected = Vec::new();
    let mut best: Option<Candidate> = None;
    for pd in devices {
        match check_device(instance, pd) {
            Ok(c) => {
                if best.as_ref().is_none_or(|b| c.rank < b.rank) {
                    best = Some(c);
                }
            }
            Err(why) => rejected.push(why),
        }
    }
    best.ok_or(VkError::NoRayQueryDevice { rejected })
}

/// A device on `candidate` with one queue of its family, lipac's
/// extensions and features.
fn create_device(instance: &ash::Instance, candidate: &Candidate) -> Result<ash::Device> {
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
    let mut fas =
        vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default().acceleration_structure(true);
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
    unsafe { instance.create_device(candidate.physical_device, &device_info, None) }
        .ctx("vkCreateDevice")
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
        let support = InstanceSupport::query(&entry, validation)?;
        let instance = create_instance(&entry, &support)?;
        // From here on `owned`'s drop destroys whatever was created, on every
        // error path and, with the context, at the end.
        let mut owned = Owned {
            instance,
            device: None,
            messenger: None,
            log: Arc::new(Mutex::new(Vec::new())),
            _entry: entry,
        };
        let debug_utils = if support.debug_utils {
            Some(owned.create_messenger()?)
        } else {
            None
        };
        let candidate = pick_device(&owned.instance)?;
        let device = create_device(&owned.instance, &candidate)?;
        owned.device = Some(device.clone());
        // SAFETY: queue 0 of the family was requested at device creation.
        let queue = unsafe { device.get_device_queue(candidate.family, 0) };
        let instance = owned.instance.clone();
        let allocator: Arc<dyn DeviceAllocator> = Arc::from(make_allocator(
            &instance,
            &device,
            candidate.physical_device,
        )?);
        let log = owned.log.clone();
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
            validation: support.validation,
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
