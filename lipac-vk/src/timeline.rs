//! Timeline semaphores: the host polls how far the GPU has got without
//! waiting ([`TimelineSemaphore::value`]), which is what the readback ring
//! is built on.

use crate::context::DeviceContext;
use crate::error::{Result, VkContext};
use ash::vk;
use std::sync::Arc;

/// A `VkSemaphore` of type `TIMELINE` (Vulkan 1.2 core; the
/// `timelineSemaphore` feature is part of lipac's device contract).
///
/// Cheap to clone (reference counted); the last clone dropped destroys it:
/// keep one alive until no submission waits on or signals it.
#[derive(Clone, Debug)]
pub struct TimelineSemaphore {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    ctx: DeviceContext,
    raw: vk::Semaphore,
}

impl TimelineSemaphore {
    /// Creates a timeline semaphore with counter value `initial`.
    ///
    /// # Errors
    ///
    /// [`crate::VkError::Vulkan`] when creation fails.
    pub fn new(ctx: &DeviceContext, initial: u64) -> Result<Self> {
        let mut ty = vk::SemaphoreTypeCreateInfo::default()
            .semaphore_type(vk::SemaphoreType::TIMELINE)
            .initial_value(initial);
        let info = vk::SemaphoreCreateInfo::default().push_next(&mut ty);
        // SAFETY: valid device; timelineSemaphore is enabled (context contract).
        let raw = unsafe { ctx.device().create_semaphore(&info, None) }.ctx("vkCreateSemaphore")?;
        Ok(Self {
            inner: Arc::new(Inner {
                ctx: ctx.clone(),
                raw,
            }),
        })
    }

    /// The `VkSemaphore`, for an engine's own `VkSemaphoreSubmitInfo`.
    pub fn raw(&self) -> vk::Semaphore {
        self.inner.raw
    }

    /// The context it belongs to.
    pub fn context(&self) -> &DeviceContext {
        &self.inner.ctx
    }

    /// The current counter value (`vkGetSemaphoreCounterValue`); never waits.
    ///
    /// # Errors
    ///
    /// [`crate::VkError::Vulkan`] (e.g. device lost).
    pub fn value(&self) -> Result<u64> {
        // SAFETY: a timeline semaphore of this device.
        unsafe {
            self.context()
                .device()
                .get_semaphore_counter_value(self.raw())
        }
        .ctx("vkGetSemaphoreCounterValue")
    }

    /// Signals `value` from the host (`vkSignalSemaphore`); it must be
    /// greater than the current value and than every pending signal.
    ///
    /// # Errors
    ///
    /// [`crate::VkError::InvalidArgument`] when `value` is not above the
    /// current value; [`crate::VkError::Vulkan`].
    pub fn signal(&self, value: u64) -> Result<()> {
        let current = self.value()?;
        if value <= current {
            return Err(crate::VkError::InvalidArgument(format!(
                "timeline signal {value} not above the current value {current}"
            )));
        }
        let info = vk::SemaphoreSignalInfo::default()
            .semaphore(self.raw())
            .value(value);
        // SAFETY: a timeline semaphore of this device; the value is above the
        // current one (checked; pending GPU signals are the caller's contract).
        unsafe { self.context().device().signal_semaphore(&info) }.ctx("vkSignalSemaphore")
    }
}

impl Drop for Inner {
    fn drop(&mut self) {
        // SAFETY: created on this device; the last clone is gone and, per the
        // type's contract, no pending submission uses it.
        unsafe { self.ctx.device().destroy_semaphore(self.raw, None) };
    }
}
