//! [`FailingAllocator`]: fault injection for device memory.

use super::{AllocationRequest, AllocatorBlocks, DeviceAllocation, DeviceAllocator};
use crate::error::{Result, VkError};
use ash::vk;
use std::sync::atomic::{AtomicU64, Ordering};

/// A [`DeviceAllocator`] that makes allocations fail on purpose: it passes
/// every request to `inner` until the `n`-th (counting from 1 since it was
/// made), then answers that one and every later one with
/// `ERROR_OUT_OF_DEVICE_MEMORY` (as a driver whose memory ran out) until
/// [`FailingAllocator::restore`]. For testing that every lipac call (and an
/// engine's handling of it) survives running out of memory at any
/// allocation: run a frame loop once to count its allocations
/// ([`FailingAllocator::attempts`]), then once per `n`.
///
/// ```no_run
/// use std::sync::Arc;
/// use lipac_vk::{FailingAllocator, GpuAllocator, HeadlessContext, Validation};
/// let mut probe = None;
/// let headless = HeadlessContext::with_allocator(Validation::Off, |instance, device, pd| {
///     // SAFETY: the handles belong together; the context drops the
///     // allocator before it destroys the device.
///     let inner = unsafe { GpuAllocator::new(instance, device, pd) }?;
///     let failing = Arc::new(FailingAllocator::new(inner));
///     failing.fail_from(3);
///     probe = Some(failing.clone());
///     Ok(Box::new(failing))
/// })?;
/// // ... the third allocation and every later one fail until `restore`.
/// # Ok::<(), lipac_vk::VkError>(())
/// ```
#[derive(Debug)]
pub struct FailingAllocator<A> {
    inner: A,
    attempts: AtomicU64,
    failures: AtomicU64,
    live: AtomicU64,
    /// 0: never fail; n: the n-th attempt and later ones fail.
    fail_from: AtomicU64,
}

impl<A: DeviceAllocator> FailingAllocator<A> {
    /// Passes every request to `inner` until told to fail.
    pub fn new(inner: A) -> Self {
        Self {
            inner,
            attempts: AtomicU64::new(0),
            failures: AtomicU64::new(0),
            live: AtomicU64::new(0),
            fail_from: AtomicU64::new(0),
        }
    }

    /// The `n`-th allocation attempt (counting from 1 since the allocator
    /// was made, [`FailingAllocator::attempts`] so far) and every later one
    /// fail until [`FailingAllocator::restore`]; `n = 0` never fails.
    pub fn fail_from(&self, n: u64) {
        self.fail_from.store(n, Ordering::SeqCst);
    }

    /// Memory is back: allocations pass to the inner allocator again.
    pub fn restore(&self) {
        self.fail_from.store(0, Ordering::SeqCst);
    }

    /// Allocation attempts so far (failed ones included).
    pub fn attempts(&self) -> u64 {
        self.attempts.load(Ordering::SeqCst)
    }

    /// Attempts answered with an injected failure.
    pub fn failures(&self) -> u64 {
        self.failures.load(Ordering::SeqCst)
    }

    /// Allocations handed out and not yet freed.
    pub fn live(&self) -> u64 {
        self.live.load(Ordering::SeqCst)
    }

    /// The wrapped allocator.
    pub fn inner(&self) -> &A {
        &self.inner
    }
}

// SAFETY: every allocation handed out is the inner allocator's, unchanged
// (so it keeps the inner allocator's promises), and is freed by it.
unsafe impl<A: DeviceAllocator> DeviceAllocator for FailingAllocator<A> {
    fn allocate(&self, request: &AllocationRequest<'_>) -> Result<DeviceAllocation> {
        let n = self.attempts.fetch_add(1, Ordering::SeqCst) + 1;
        let from = self.fail_from.load(Ordering::SeqCst);
        if from != 0 && n >= from {
            self.failures.fetch_add(1, Ordering::SeqCst);
            return Err(VkError::vk(
                "FailingAllocator (injected)",
                vk::Result::ERROR_OUT_OF_DEVICE_MEMORY,
            ));
        }
        let a = self.inner.allocate(request)?;
        self.live.fetch_add(1, Ordering::SeqCst);
        Ok(a)
    }

    fn free(&self, allocation: DeviceAllocation) {
        self.live.fetch_sub(1, Ordering::SeqCst);
        self.inner.free(allocation);
    }

    fn blocks(&self) -> Option<AllocatorBlocks> {
        self.inner.blocks()
    }
}

// An `Arc` of an allocator is one too: tests keep a handle on the one the
// context owns.
// SAFETY: forwards to the allocator the `Arc` holds, which keeps its
// promises.
unsafe impl<A: DeviceAllocator + ?Sized> DeviceAllocator for std::sync::Arc<A> {
    fn allocate(&self, request: &AllocationRequest<'_>) -> Result<DeviceAllocation> {
        (**self).allocate(request)
    }

    fn free(&self, allocation: DeviceAllocation) {
        (**self).free(allocation);
    }

    fn blocks(&self) -> Option<AllocatorBlocks> {
        (**self).blocks()
    }
}
