//! The crate's error type.

use ash::vk;
use std::fmt;

/// Everything that can go wrong in `lipac-vk`.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum VkError {
    /// The Vulkan loader (`libvulkan.so.1` / `vulkan-1.dll`) could not be loaded.
    LoaderUnavailable(String),
    /// No physical device supports what [`crate::HeadlessContext`] needs
    /// (Vulkan 1.3, `VK_KHR_acceleration_structure`, buffer device address,
    /// timeline semaphores, synchronization2, a compute queue, and a tracing
    /// path: `VK_KHR_ray_query` or `VK_KHR_ray_tracing_pipeline`), or the
    /// device `LIPAC_VK_DEVICE` names does not. Holds one line per rejected
    /// device saying why.
    NoSuitableDevice {
        /// Why each enumerated device was rejected.
        rejected: Vec<String>,
    },
    /// The validation layer was required but is not installed.
    ValidationLayerMissing,
    /// A component needs a device feature the context does not offer (a
    /// tracer's tracing path, see [`crate::TracingPaths`]).
    MissingFeature {
        /// The component that needs it (e.g. `"CameraTracer"`).
        component: &'static str,
        /// What it needs (e.g. `"VK_KHR_ray_query"`).
        needs: &'static str,
        /// What the device offers instead (e.g. "ray-tracing pipelines only").
        offers: String,
    },
    /// A device function lipac needs is not loaded on the engine's device
    /// (its extension or Vulkan version was not enabled).
    MissingDeviceFunction(&'static str),
    /// None of the queues handed over supports compute.
    NoComputeQueue,
    /// A Vulkan call failed.
    Vulkan {
        /// What lipac was doing.
        context: &'static str,
        /// The result code.
        result: vk::Result,
    },
    /// No memory type satisfies the buffer's requirements and location.
    NoMemoryType {
        /// Memory type bits the buffer allows.
        type_bits: u32,
        /// Property flags that were required.
        required: vk::MemoryPropertyFlags,
    },
    /// The device allocator failed or returned memory that does not fit the
    /// buffer (its message; see [`crate::DeviceAllocator`]).
    Allocator(String),
    /// The buffer is not host-visible (mapped), so the CPU cannot read or write it.
    NotMapped,
    /// A read or write past the end of a buffer.
    OutOfBounds {
        /// First byte accessed.
        offset: u64,
        /// Bytes accessed.
        len: u64,
        /// Size of the buffer.
        size: u64,
    },
    /// An argument was invalid (zero size, non-finite value, too many items...).
    InvalidArgument(String),
    /// A buffer lacks a usage flag the operation needs, or has no device address.
    MissingUsage(&'static str),
    /// A compaction query was read before the GPU had written it.
    QueryNotReady,
    /// An object from another device context was passed.
    WrongContext,
    /// lipac-core's build scheduler refused an acknowledgement from the
    /// plan executor.
    Scheduler(lipac_core::build_plan::BuildPlanError),
    /// A readback slot still holds an unread frame; read it
    /// ([`crate::CommandReadbackRing::try_read`]) before reusing it.
    ReadbackSlotBusy {
        /// The slot.
        slot: usize,
        /// Timeline value of the unread frame.
        value: u64,
    },
}

impl VkError {
    /// Wraps a `vk::Result` with what lipac was doing.
    pub fn vk(context: &'static str, result: vk::Result) -> Self {
        Self::Vulkan { context, result }
    }

    /// Whether the error means "this machine cannot run lipac-vk" (no loader,
    /// no suitable device) rather than a bug or a failed call. Tests use it to
    /// skip.
    pub fn is_unsupported_machine(&self) -> bool {
        matches!(
            self,
            Self::LoaderUnavailable(_) | Self::NoSuitableDevice { .. }
        )
    }
}

impl fmt::Display for VkError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::LoaderUnavailable(e) => write!(f, "the Vulkan loader could not be loaded: {e}"),
            Self::NoSuitableDevice { rejected } => {
                write!(
                    f,
                    "no Vulkan device with acceleration structures and ray queries or ray-tracing pipelines"
                )?;
                if rejected.is_empty() {
                    write!(f, " (no physical devices)")
                } else {
                    write!(f, ": {}", rejected.join("; "))
                }
            }
            Self::MissingFeature {
                component,
                needs,
                offers,
            } => write!(f, "{component} needs {needs}; this device offers {offers}"),
            Self::ValidationLayerMissing => {
                write!(f, "VK_LAYER_KHRONOS_validation was required but is not installed")
            }
            Self::MissingDeviceFunction(name) => write!(
                f,
                "device function {name} is not loaded: enable its extension / Vulkan version on the device"
            ),
            Self::NoComputeQueue => write!(f, "none of the given queues supports compute"),
            Self::Vulkan { context, result } => write!(f, "{context} failed: {result}"),
            Self::NoMemoryType { type_bits, required } => write!(
                f,
                "no memory type in bits {type_bits:#x} has properties {required:?}"
            ),
            Self::Allocator(s) => write!(f, "device allocator: {s}"),
            Self::NotMapped => write!(f, "the buffer is not host-visible"),
            Self::OutOfBounds { offset, len, size } => write!(
                f,
                "access of {len} bytes at offset {offset} is outside a buffer of {size} bytes"
            ),
            Self::InvalidArgument(s) => write!(f, "invalid argument: {s}"),
            Self::MissingUsage(s) => write!(f, "buffer usage missing: {s}"),
            Self::QueryNotReady => write!(f, "the compaction query has not been written yet"),
            Self::WrongContext => write!(f, "object belongs to another device context"),
            Self::Scheduler(e) => write!(f, "build scheduler: {e}"),
            Self::ReadbackSlotBusy { slot, value } => write!(
                f,
                "readback slot {slot} still holds unread frame {value}; read it first"
            ),
        }
    }
}

impl std::error::Error for VkError {}

/// Shorthand for results in this crate.
pub type Result<T, E = VkError> = std::result::Result<T, E>;

/// Adds context to a `VkResult`.
pub(crate) trait VkContext<T> {
    fn ctx(self, context: &'static str) -> Result<T>;
}

impl<T> VkContext<T> for ash::prelude::VkResult<T> {
    fn ctx(self, context: &'static str) -> Result<T> {
        self.map_err(|r| VkError::vk(context, r))
    }
}
