//! A self-contained Vulkan instance and device for examples and tests
//! ([`HeadlessContext`]), with an optional validation layer whose error
//! messages it records. Engines bind their own device with
//! [`DeviceContext::from_engine`] instead.

use crate::context::{
    preferred_queue_family, DeviceContext, EngineQueue, RAY_QUERY_EXTENSIONS,
    RAY_TRACING_PIPELINE_EXTENSIONS, REQUIRED_DEVICE_EXTENSIONS,
};
use crate::device_allocator::{DeviceAllocator, GpuAllocator};
use crate::error::{Result, VkContext, VkError};
use crate::tracing_paths::{TracingPath, TracingPaths};
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
/// Picks the best device (discrete, integrated, virtual, CPU; then the one
/// with more tracing paths) with Vulkan 1.3,
/// [`REQUIRED_DEVICE_EXTENSIONS`], buffer device address, timeline
/// semaphores, synchronization2, acceleration structures and at least one
/// tracing path: ray queries ([`crate::RAY_QUERY_EXTENSIONS`]) or
/// ray-tracing pipelines ([`crate::RAY_TRACING_PIPELINE_EXTENSIONS`]). It
/// enables the paths the device has and reports them
/// ([`DeviceContext::tracing`]). [`DEVICE_ENV`] (`LIPAC_VK_DEVICE`) picks a
/// device by index or name; [`HIDE_ENV`] (`LIPAC_VK_HIDE`) hides paths. When
/// `VK_EXT_debug_utils` is available a messenger records every
/// error-severity message (validation errors among them); see
/// [`HeadlessContext::validation_errors`].
///
/// ```no_run
/// use lipac_vk::{HeadlessContext, Validation};
/// let headless = HeadlessContext::new(Validation::IfAvailable)?;
/// println!("running on {}", headless.summary());
/// assert!(headless.validation_errors().is_empty());
/// # Ok::<(), lipac_vk::VkError>(())
/// ```
pub struct HeadlessContext {
    context: DeviceContext,
    log: Arc<Mutex<Vec<String>>>,
    validation: bool,
    debug_utils: Option<ash::ext::debug_utils::Instance>,
    device_index: usize,
    device_type: vk::PhysicalDeviceType,
    hidden: TracingPaths,
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

/// A physical device that qualifies, with the queue family lipac will use,
/// its rank (lower is better: discrete, integrated, virtual, CPU) and the
/// tracing paths it offers (hidden ones removed).
struct Candidate {
    physical_device: vk::PhysicalDevice,
    family: u32,
    rank: u32,
    index: usize,
    device_type: vk::PhysicalDeviceType,
    tracing: TracingPaths,
}

/// Whether `pd` (enumerated as `index`) has everything lipac needs and a
/// tracing path not in `hide`; the reason when it does not.
fn check_device(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
    index: usize,
    hide: TracingPaths,
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
    let has = |need: &CStr| exts.iter().any(|e| e.extension_name_as_c_str() == Ok(need));
    for need in REQUIRED_DEVICE_EXTENSIONS {
        if !has(need) {
            return Err(format!("{name}: lacks {}", need.to_string_lossy()));
        }
    }
    let has_rq_ext = RAY_QUERY_EXTENSIONS.iter().all(|n| has(n));
    let has_rt_ext = RAY_TRACING_PIPELINE_EXTENSIONS.iter().all(|n| has(n));
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
    let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
    let mut fas = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default();
    let mut frq = vk::PhysicalDeviceRayQueryFeaturesKHR::default();
    let mut frt = vk::PhysicalDeviceRayTracingPipelineFeaturesKHR::default();
    let mut f2 = vk::PhysicalDeviceFeatures2::default()
        .push_next(&mut f12)
        .push_next(&mut f13)
        .push_next(&mut fas);
    if has_rq_ext {
        f2 = f2.push_next(&mut frq);
    }
    if has_rt_ext {
        f2 = f2.push_next(&mut frt);
    }
    // SAFETY: as above; the chain holds valid output structs of supported
    // extensions.
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
        return Err(format!("{name}: lacks features {}", missing.join(", ")));
    }
    let offered = TracingPaths {
        ray_query: has_rq_ext && frq.ray_query == vk::TRUE,
        ray_tracing_pipeline: has_rt_ext && frt.ray_tracing_pipeline == vk::TRUE,
    };
    let tracing = TracingPaths {
        ray_query: offered.ray_query && !hide.ray_query,
        ray_tracing_pipeline: offered.ray_tracing_pipeline && !hide.ray_tracing_pipeline,
    };
    if !tracing.any() {
        let hidden = if offered.any() {
            format!(" ({offered} hidden by {HIDE_ENV})")
        } else {
            String::new()
        };
        return Err(format!(
            "{name}: lacks a tracing path (VK_KHR_ray_query with rayQuery, or \
             VK_KHR_ray_tracing_pipeline with rayTracingPipeline){hidden}"
        ));
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
        index,
        device_type: props.device_type,
        tracing,
    })
}

/// The environment variable that picks the device: an index into the
/// enumerated devices (`vulkaninfo --summary` order) or a case-insensitive
/// substring of its name.
pub const DEVICE_ENV: &str = "LIPAC_VK_DEVICE";
/// The environment variable that hides tracing paths the device has, as if
/// it lacked them (comma-separated `ray-query`, `pipeline`): to check on
/// one device what another without them does.
pub const HIDE_ENV: &str = "LIPAC_VK_HIDE";

/// How [`HeadlessContext::with_options`] creates its device.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct HeadlessOptions {
    /// The validation layer.
    pub validation: Validation,
    /// The device to use: its index among the enumerated devices, or a
    /// case-insensitive substring of its name; `None`: the best that
    /// qualifies (discrete, integrated, virtual, CPU; then more tracing
    /// paths; then enumeration order).
    pub device: Option<String>,
    /// Tracing paths to treat as absent even where the device has them.
    pub hide: TracingPaths,
}

impl HeadlessOptions {
    /// `validation`, with the device from [`DEVICE_ENV`] and the hidden
    /// paths from [`HIDE_ENV`] when set.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for an unknown path in [`HIDE_ENV`].
    pub fn from_env(validation: Validation) -> Result<Self> {
        let device = std::env::var(DEVICE_ENV)
            .ok()
            .filter(|v| !v.trim().is_empty());
        let mut hide = TracingPaths::NONE;
        if let Ok(v) = std::env::var(HIDE_ENV) {
            for part in v.split(',').map(str::trim).filter(|p| !p.is_empty()) {
                match part
                    .parse::<TracingPath>()
                    .map_err(|e| VkError::InvalidArgument(format!("{HIDE_ENV}: {e}")))?
                {
                    TracingPath::RayQuery => hide.ray_query = true,
                    TracingPath::RayTracingPipeline => hide.ray_tracing_pipeline = true,
                }
            }
        }
        Ok(Self {
            validation,
            device,
            hide,
        })
    }
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
        Err(vk::Result::ERROR_INCOMPATIBLE_DRIVER) => Err(VkError::NoSuitableDevice {
            rejected: vec![
                "no Vulkan 1.3 driver (vkCreateInstance: ERROR_INCOMPATIBLE_DRIVER)".into(),
            ],
        }),
        Err(e) => Err(VkError::vk("vkCreateInstance", e)),
    }
}

/// The device `options.device` names, or the best qualifying one; the
/// reason for each rejected one when none qualifies.
fn pick_device(instance: &ash::Instance, options: &HeadlessOptions) -> Result<Candidate> {
    // SAFETY: valid instance.
    let devices =
        unsafe { instance.enumerate_physical_devices() }.ctx("vkEnumeratePhysicalDevices")?;
    if let Some(want) = &options.device {
        let want = want.trim();
        let by_index = want.parse::<usize>().ok();
        let mut names = Vec::new();
        for (i, &pd) in devices.iter().enumerate() {
            // SAFETY: enumerated from `instance`.
            let props = unsafe { instance.get_physical_device_properties(pd) };
            let name = props
                .device_name_as_c_str()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            let hit = match by_index {
                Some(k) => k == i,
                None => name.to_lowercase().contains(&want.to_lowercase()),
            };
            if hit {
                return check_device(instance, pd, i, options.hide).map_err(|why| {
                    VkError::NoSuitableDevice {
                        rejected: vec![format!("{DEVICE_ENV}={want} chose device {i}, {why}")],
                    }
                });
            }
            names.push(format!("{i}: {name}"));
        }
        return Err(VkError::NoSuitableDevice {
            rejected: vec![format!(
                "{DEVICE_ENV}={want} names no device (devices: {})",
                if names.is_empty() {
                    "none".to_owned()
                } else {
                    names.join(", ")
                }
            )],
        });
    }
    let mut rejected = Vec::new();
    let mut best: Option<Candidate> = None;
    let paths =
        |c: &Candidate| u32::from(c.tracing.ray_query) + u32::from(c.tracing.ray_tracing_pipeline);
    for (i, pd) in devices.into_iter().enumerate() {
        match check_device(instance, pd, i, options.hide) {
            Ok(c) => {
                let better = best.as_ref().is_none_or(|b| {
                    (c.rank, std::cmp::Reverse(paths(&c))) < (b.rank, std::cmp::Reverse(paths(b)))
                });
                if better {
                    best = Some(c);
                }
            }
            Err(why) => rejected.push(why),
        }
    }
    best.ok_or(VkError::NoSuitableDevice { rejected })
}

/// A device on `candidate` with one queue of its family, lipac's
/// extensions and features.
fn create_device(instance: &ash::Instance, candidate: &Candidate) -> Result<ash::Device> {
    let priorities = [1.0f32];
    let queue_info = [vk::DeviceQueueCreateInfo::default()
        .queue_family_index(candidate.family)
        .queue_priorities(&priorities)];
    let tracing = candidate.tracing;
    let mut ext_ptrs: Vec<*const i8> = REQUIRED_DEVICE_EXTENSIONS
        .iter()
        .map(|n| n.as_ptr())
        .collect();
    if tracing.ray_query {
        ext_ptrs.extend(RAY_QUERY_EXTENSIONS.iter().map(|n| n.as_ptr()));
    }
    if tracing.ray_tracing_pipeline {
        ext_ptrs.extend(RAY_TRACING_PIPELINE_EXTENSIONS.iter().map(|n| n.as_ptr()));
    }
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default()
        .buffer_device_address(true)
        .timeline_semaphore(true);
    let mut f13 = vk::PhysicalDeviceVulkan13Features::default().synchronization2(true);
    let mut fas =
        vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default().acceleration_structure(true);
    let mut frq = vk::PhysicalDeviceRayQueryFeaturesKHR::default().ray_query(true);
    let mut frt =
        vk::PhysicalDeviceRayTracingPipelineFeaturesKHR::default().ray_tracing_pipeline(true);
    let mut device_info = vk::DeviceCreateInfo::default()
        .queue_create_infos(&queue_info)
        .enabled_extension_names(&ext_ptrs)
        .push_next(&mut f12)
        .push_next(&mut f13)
        .push_next(&mut fas);
    if tracing.ray_query {
        device_info = device_info.push_next(&mut frq);
    }
    if tracing.ray_tracing_pipeline {
        device_info = device_info.push_next(&mut frt);
    }
    // SAFETY: the physical device supports every extension and feature
    // enabled here (checked by `check_device`); pointers are live.
    unsafe { instance.create_device(candidate.physical_device, &device_info, None) }
        .ctx("vkCreateDevice")
}

impl HeadlessContext {
    /// Creates an instance and a device for lipac, the device chosen as
    /// [`HeadlessOptions::from_env`] says.
    ///
    /// # Errors
    ///
    /// [`VkError::LoaderUnavailable`] without a Vulkan loader,
    /// [`VkError::NoSuitableDevice`] when no device qualifies (with the reason
    /// for each), [`VkError::ValidationLayerMissing`] for
    /// [`Validation::Required`] without the layer, [`VkError::InvalidArgument`]
    /// for a malformed [`HIDE_ENV`], [`VkError::Vulkan`] when a creation call
    /// fails.
    pub fn new(validation: Validation) -> Result<Self> {
        Self::with_options(&HeadlessOptions::from_env(validation)?)
    }

    /// Creates an instance and a device for lipac as `options` say (no
    /// environment variables read).
    ///
    /// # Errors
    ///
    /// As [`HeadlessContext::new`].
    pub fn with_options(options: &HeadlessOptions) -> Result<Self> {
        Self::with_options_and_allocator(options, |instance, device, physical_device| {
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
        Self::with_options_and_allocator(&HeadlessOptions::from_env(validation)?, make_allocator)
    }

    /// As [`HeadlessContext::with_allocator`], the device chosen as
    /// `options` say.
    ///
    /// # Errors
    ///
    /// As [`HeadlessContext::with_allocator`].
    pub fn with_options_and_allocator(
        options: &HeadlessOptions,
        make_allocator: impl FnOnce(
            &ash::Instance,
            &ash::Device,
            vk::PhysicalDevice,
        ) -> Result<Box<dyn DeviceAllocator>>,
    ) -> Result<Self> {
        let validation = options.validation;
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
        let candidate = pick_device(&owned.instance, options)?;
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
                candidate.tracing,
                Some(owned),
            )
        }?;
        Ok(Self {
            context,
            log,
            validation: support.validation,
            debug_utils,
            device_index: candidate.index,
            device_type: candidate.device_type,
            hidden: options.hide,
        })
    }

    /// The device's index among the enumerated physical devices (what
    /// [`DEVICE_ENV`] takes).
    pub fn device_index(&self) -> usize {
        self.device_index
    }

    /// The device's type (discrete, integrated, virtual, CPU).
    pub fn device_type(&self) -> vk::PhysicalDeviceType {
        self.device_type
    }

    /// The tracing paths hidden by [`HeadlessOptions::hide`] (or [`HIDE_ENV`]).
    pub fn hidden_tracing(&self) -> TracingPaths {
        self.hidden
    }

    /// One line naming the device, its type and index, the tracing paths
    /// enabled (and hidden) and whether validation is on, e.g.
    /// `llvmpipe (LLVM 15.0.6, 256 bits) (CPU, device 0); tracing: ray
    /// queries and ray-tracing pipelines; validation on`. Tests and
    /// examples print it so that every log says where it ran.
    pub fn summary(&self) -> String {
        let kind = match self.device_type {
            vk::PhysicalDeviceType::DISCRETE_GPU => "discrete GPU",
            vk::PhysicalDeviceType::INTEGRATED_GPU => "integrated GPU",
            vk::PhysicalDeviceType::VIRTUAL_GPU => "virtual GPU",
            vk::PhysicalDeviceType::CPU => "CPU",
            _ => "other",
        };
        let hidden: Vec<String> = [TracingPath::RayQuery, TracingPath::RayTracingPipeline]
            .into_iter()
            .filter(|p| self.hidden.has(*p))
            .map(|p| p.to_string())
            .collect();
        let hidden = if hidden.is_empty() {
            String::new()
        } else {
            format!(" ({} hidden by {HIDE_ENV})", hidden.join(" and "))
        };
        format!(
            "{} ({kind}, device {}); tracing: {}{hidden}; validation {}",
            self.context.device_name(),
            self.device_index,
            self.context.tracing(),
            if self.validation { "on" } else { "off" }
        )
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
