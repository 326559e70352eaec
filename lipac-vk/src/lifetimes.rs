//! Object lifetimes across frames in flight: [`Retirement`], a deferred
//! destruction queue keyed by timeline value, and [`TlasPair`], a
//! double-buffered TLAS.
//!
//! lipac never waits on the host for the GPU. An object that recorded work
//! may still use (a replaced TLAS or scratch buffer, a BLAS the cache freed,
//! a pool range) is handed to [`Retirement::retire`] with the timeline value
//! the *last submission that may use it* signals. [`Retirement::collect`]
//! (or [`Retirement::collect_signalled`], which reads the semaphore without
//! waiting) drops everything whose value the GPU has passed.

use crate::commands::Recorder;
use crate::context::DeviceContext;
use crate::error::Result;
use crate::memory::{Buffer, ScratchBuffer};
use crate::timeline::TimelineSemaphore;
use crate::tlas::GpuTlas;
use ash::vk;
use std::any::Any;
use std::collections::BTreeMap;

/// Deferred destruction: objects dropped once the GPU has passed a timeline
/// value. Any `Send` object can be retired (BLASes, acceleration
/// structures, buffers, compaction queries, descriptor bindings).
///
/// Dropping the queue drops what it still holds at once: drop it only when
/// the GPU is idle (or after a final [`Retirement::collect`] with the last
/// value).
///
/// ```
/// use lipac_vk::Retirement;
/// let mut r = Retirement::new();
/// r.retire(3, vec![0u8; 16]); // used by the submission signalling 3
/// r.retire(5, String::from("scratch"));
/// assert_eq!(r.collect(2), 0);
/// assert_eq!(r.collect(4), 1);
/// assert_eq!(r.pending(), 1);
/// assert_eq!(r.oldest_pending(), Some(5));
/// ```
#[derive(Default)]
pub struct Retirement {
    queue: BTreeMap<u64, Vec<Box<dyn Any + Send>>>,
    pending: usize,
    destroyed: u64,
}

impl std::fmt::Debug for Retirement {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Retirement")
            .field("pending", &self.pending)
            .field("oldest", &self.oldest_pending())
            .field("destroyed", &self.destroyed)
            .finish()
    }
}

impl Retirement {
    /// An empty queue.
    pub fn new() -> Self {
        Self::default()
    }

    /// Keeps `object` until the GPU has passed timeline value `after` (the
    /// value signalled by the last submission that may use it).
    pub fn retire<T: Send + 'static>(&mut self, after: u64, object: T) {
        self.queue.entry(after).or_default().push(Box::new(object));
        self.pending += 1;
    }

    /// [`Retirement::retire`] for an optional object (what growth returns).
    pub fn retire_opt<T: Send + 'static>(&mut self, after: u64, object: Option<T>) {
        if let Some(o) = object {
            self.retire(after, o);
        }
    }

    /// Drops every object whose value is at most `completed` (the value the
    /// GPU has reached); returns how many.
    pub fn collect(&mut self, completed: u64) -> usize {
        let keep = self.queue.split_off(&completed.saturating_add(1));
        let done = std::mem::replace(&mut self.queue, keep);
        let n: usize = done.values().map(Vec::len).sum();
        drop(done);
        self.pending -= n;
        self.destroyed += n as u64;
        n
    }

    /// [`Retirement::collect`] with the semaphore's current value
    /// (`vkGetSemaphoreCounterValue`; never waits).
    ///
    /// # Errors
    ///
    /// [`crate::VkError::Vulkan`] when the value cannot be read.
    pub fn collect_signalled(&mut self, semaphore: &TimelineSemaphore) -> Result<usize> {
        Ok(self.collect(semaphore.value()?))
    }

    /// Objects waiting.
    pub fn pending(&self) -> usize {
        self.pending
    }

    /// The smallest value an object waits for.
    pub fn oldest_pending(&self) -> Option<u64> {
        self.queue.keys().next().copied()
    }

    /// Objects destroyed so far.
    pub fn destroyed(&self) -> u64 {
        self.destroyed
    }
}

/// Two TLASes used alternately: frame `n` builds into the one frame `n - 1`
/// did not use, so a trace of frame `n - 1` still in flight keeps reading an
/// intact structure while frame `n`'s is built. Each grows geometrically on
/// its own; replaced storage and scratch go to a [`Retirement`] queue.
///
/// The custom index of an instance record is its stable registry slot
/// (24 bits; lipac-core's registry refuses more than 2^24 slots, and GPU
/// Algorithm 1 refuses instance buffers over 2^24 records).
#[derive(Debug)]
pub struct TlasPair {
    tlases: [GpuTlas; 2],
    current: usize,
    builds: u64,
}

impl TlasPair {
    /// Two TLASes of `capacity` instances each.
    ///
    /// # Errors
    ///
    /// As [`GpuTlas::new`].
    pub fn new(
        ctx: &DeviceContext,
        capacity: u32,
        flags: vk::BuildAccelerationStructureFlagsKHR,
    ) -> Result<Self> {
        Ok(Self {
            tlases: [
                GpuTlas::new(ctx, capacity, flags)?,
                GpuTlas::new(ctx, capacity, flags)?,
            ],
            current: 1,
            builds: 0,
        })
    }

    /// The TLAS of the last recorded build (bind it for this frame's traces).
    pub fn current(&self) -> &GpuTlas {
        &self.tlases[self.current]
    }

    /// The TLAS of the build before (frames in flight may still read it).
    pub fn previous(&self) -> &GpuTlas {
        &self.tlases[1 - self.current]
    }

    /// Builds recorded so far.
    pub fn builds(&self) -> u64 {
        self.builds
    }

    /// Bytes of device memory both TLASes hold.
    pub fn memory_bytes(&self) -> u64 {
        self.tlases.iter().map(|t| t.accel().memory_bytes()).sum()
    }

    /// Records a build of `count` records at byte `offset` of `instances`
    /// into the TLAS not used by the previous build, which then becomes
    /// [`TlasPair::current`]. Storage or scratch replaced by growth is
    /// retired until timeline value `retire_after` (the value this frame's
    /// submission signals).
    ///
    /// # Errors
    ///
    /// As [`GpuTlas::record_build`]; nothing changes on error.
    #[allow(clippy::too_many_arguments)]
    pub fn record_build(
        &mut self,
        rec: &mut Recorder<'_>,
        instances: &Buffer,
        offset: u64,
        count: u32,
        scratch: &mut ScratchBuffer,
        retirement: &mut Retirement,
        retire_after: u64,
    ) -> Result<()> {
        let back = 1 - self.current;
        let out = self.tlases[back].record_build(rec, instances, offset, count, scratch)?;
        retirement.retire_opt(retire_after, out.retired_accel);
        retirement.retire_opt(retire_after, out.retired_scratch);
        self.current = back;
        self.builds += 1;
        Ok(())
    }
}

#[cfg(test)]
mod tests;
