//! The readback ring: Algorithm 2's commands travel back to the host a few
//! frames late, without the host ever waiting on the GPU.
//!
//! Each of the ring's slots is a host-visible buffer of `1 + capacity` words
//! (the command counter, then the command words). At the end of a frame,
//! [`CommandReadbackRing::record_copy`] records copies of the counter and the
//! command buffer into the next slot and returns a [`CommandReadbackTicket`]: the
//! submission holding that recording must signal [`CommandReadbackRing::semaphore`]
//! with the ticket's value. [`CommandReadbackRing::try_read`] then returns the slot's
//! [`CommandReadback`] once the semaphore's counter has reached that value
//! (`vkGetSemaphoreCounterValue`; it never waits), and frees the slot.
//!
//! A slot is never overwritten before it was read: `record_copy` into a slot
//! still holding an unread frame is refused ([`VkError::ReadbackSlotBusy`]),
//! so commands are never lost. A full command buffer (`counter > capacity`)
//! is reported by [`CommandReadback::overflowed`]; the core's overflow rule makes it
//! harmless (those instances kept their state and ask again).

use crate::commands::Recorder;
use crate::context::DeviceContext;
use crate::error::{Result, VkError};
use crate::memory::{Buffer, MemoryLocation};
use crate::timeline::TimelineSemaphore;
use ash::vk;

/// Where one frame's commands went: the ring slot and the timeline value the
/// submission must signal on [`CommandReadbackRing::semaphore`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CommandReadbackTicket {
    /// Ring slot written.
    pub slot: usize,
    /// Timeline value to signal when the copy has executed.
    pub value: u64,
}

/// One frame's commands as read back. Hand them to the manager as they are:
/// [`Manager::ingest_readback(frame, counter, words)`](lipac_core::manager::Manager::ingest_readback),
/// `frame` being the frame whose Algorithm 2 wrote them.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CommandReadback {
    value: u64,
    counter: u32,
    words: Vec<u32>,
    capacity: u32,
}

impl CommandReadback {
    /// The timeline value (frame) it belongs to.
    pub fn value(&self) -> u64 {
        self.value
    }
    /// The GPU's counter: commands requested, stored or not.
    pub fn counter(&self) -> u32 {
        self.counter
    }
    /// The stored command words (`min(counter, capacity)` of them).
    pub fn words(&self) -> &[u32] {
        &self.words
    }
    /// The command buffer's capacity.
    pub fn capacity(&self) -> u32 {
        self.capacity
    }
    /// Requests that did not fit (`counter − capacity`, or 0).
    pub fn overflowed(&self) -> u32 {
        self.counter.saturating_sub(self.capacity)
    }
    /// Whether the command buffer ran full.
    pub fn is_full(&self) -> bool {
        self.counter >= self.capacity
    }
}

#[derive(Debug)]
struct Slot {
    buffer: Buffer,
    /// Timeline value of the unread frame in this slot.
    pending: Option<u64>,
}

/// The readback ring: Algorithm 2's commands travel back to the host a few
/// frames late, without the host ever waiting on the GPU.
///
/// Each of the ring's slots is a host-visible buffer of `1 + capacity` words
/// (the command counter, then the command words). At the end of a frame,
/// [`CommandReadbackRing::record_copy`] records copies of the counter and the
/// command buffer into the next slot and returns a [`CommandReadbackTicket`]: the
/// submission holding that recording must signal [`CommandReadbackRing::semaphore`]
/// with the ticket's value. [`CommandReadbackRing::try_read`] then returns the slot's
/// [`CommandReadback`] once the semaphore's counter has reached that value
/// (`vkGetSemaphoreCounterValue`; it never waits), and frees the slot.
///
/// A slot is never overwritten before it was read: `record_copy` into a slot
/// still holding an unread frame is refused ([`VkError::ReadbackSlotBusy`]),
/// so commands are never lost. A full command buffer (`counter > capacity`)
/// is reported by [`CommandReadback::overflowed`]; the core's overflow rule makes it
/// harmless (those instances kept their state and ask again).
///
/// See also `docs/VULKAN.md`.
#[derive(Debug)]
pub struct CommandReadbackRing {
    semaphore: TimelineSemaphore,
    slots: Vec<Slot>,
    capacity: u32,
    next: usize,
    last_value: u64,
}

impl CommandReadbackRing {
    /// A ring of `slots` slots (1..=16; 3–4 covers the usual frames in
    /// flight) for command buffers of `capacity` words (≥ 1).
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`]; as [`Buffer::new`] and
    /// [`TimelineSemaphore::new`].
    pub fn new(ctx: &DeviceContext, slots: usize, capacity: u32) -> Result<Self> {
        if !(1..=16).contains(&slots) || capacity == 0 {
            return Err(VkError::InvalidArgument(format!(
                "readback ring of {slots} slots (1..=16) and capacity {capacity} (>= 1)"
            )));
        }
        let bytes = 4 * (u64::from(capacity) + 1);
        let slots = (0..slots)
            .map(|_| {
                Ok(Slot {
                    buffer: Buffer::new(
                        ctx,
                        bytes,
                        vk::BufferUsageFlags::TRANSFER_DST,
                        MemoryLocation::GpuToCpu,
                    )?,
                    pending: None,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            semaphore: TimelineSemaphore::new(ctx, 0)?,
            slots,
            capacity,
            next: 0,
            last_value: 0,
        })
    }

    /// The timeline semaphore submissions signal with their ticket's value.
    pub fn semaphore(&self) -> &TimelineSemaphore {
        &self.semaphore
    }

    /// Number of slots.
    pub fn slot_count(&self) -> usize {
        self.slots.len()
    }

    /// Command words a slot holds.
    pub fn capacity(&self) -> u32 {
        self.capacity
    }

    /// The timeline value the next [`CommandReadbackRing::record_copy`]
    /// returns (one more than the last one).
    pub fn next_value(&self) -> u64 {
        self.last_value + 1
    }

    /// The slot the next [`CommandReadbackRing::record_copy`] writes.
    pub fn next_slot(&self) -> usize {
        self.next
    }

    /// The timeline value of the unread frame in `slot`, if any.
    pub fn pending(&self, slot: usize) -> Option<u64> {
        self.slots.get(slot).and_then(|s| s.pending)
    }

    /// Records copies of `counter` (one `u32`) and the first
    /// [`CommandReadbackRing::capacity`] words of `commands` into the next slot,
    /// then a barrier making them visible to the host. Record it after
    /// [`crate::FeedbackPipeline::record`] (whose final barrier covers the
    /// copy) and signal [`CommandReadbackRing::semaphore`] with the returned value
    /// in the submission that holds it. Timeline values grow by one per call;
    /// submit the recordings in that order. A recording that is never
    /// submitted leaves its slot pending, and once a later value is signalled
    /// that slot reads back whatever the buffer held: do not drop one.
    ///
    /// # Errors
    ///
    /// [`VkError::ReadbackSlotBusy`] when the next slot still holds an unread
    /// frame (read it with [`CommandReadbackRing::try_read`] first);
    /// [`VkError::MissingUsage`] without `TRANSFER_SRC`;
    /// [`VkError::InvalidArgument`] when `commands` is smaller than the
    /// capacity or `counter` smaller than 4 bytes; [`VkError::WrongContext`].
    pub fn record_copy(
        &mut self,
        rec: &mut Recorder<'_>,
        commands: &Buffer,
        counter: &Buffer,
    ) -> Result<CommandReadbackTicket> {
        let ctx = self.semaphore.context();
        for b in [commands, counter] {
            crate::accel::same_context(ctx, b.context())?;
            if !b.usage().contains(vk::BufferUsageFlags::TRANSFER_SRC) {
                return Err(VkError::MissingUsage(
                    "TRANSFER_SRC on the command buffer and counter",
                ));
            }
        }
        crate::accel::same_context(ctx, rec.context())?;
        let words_bytes = 4 * u64::from(self.capacity);
        if commands.size() < words_bytes || counter.size() < 4 {
            return Err(VkError::InvalidArgument(format!(
                "command buffer of {} bytes for a ring capacity of {} words, counter of {} bytes",
                commands.size(),
                self.capacity,
                counter.size()
            )));
        }
        let slot = self.next;
        let s = &self.slots[slot];
        if let Some(value) = s.pending {
            return Err(VkError::ReadbackSlotBusy { slot, value });
        }
        let device = ctx.device();
        // SAFETY: recording on this device (checked above); both sources have
        // TRANSFER_SRC, the slot buffer TRANSFER_DST; the regions lie inside
        // the buffers (sizes checked above; the slot holds 1 + capacity words).
        unsafe {
            device.cmd_copy_buffer(
                rec.raw(),
                counter.raw(),
                s.buffer.raw(),
                &[vk::BufferCopy::default().size(4)],
            );
            device.cmd_copy_buffer(
                rec.raw(),
                commands.raw(),
                s.buffer.raw(),
                &[vk::BufferCopy::default().dst_offset(4).size(words_bytes)],
            );
        }
        rec.memory_barrier(
            vk::PipelineStageFlags2::TRANSFER,
            vk::AccessFlags2::TRANSFER_WRITE,
            vk::PipelineStageFlags2::HOST,
            vk::AccessFlags2::HOST_READ,
        );
        self.last_value += 1;
        self.slots[slot].pending = Some(self.last_value);
        self.next = (slot + 1) % self.slots.len();
        Ok(CommandReadbackTicket {
            slot,
            value: self.last_value,
        })
    }

    /// The frame in `slot` if the GPU has signalled its value, freeing the
    /// slot; `None` if the slot is empty or the GPU is not there yet. Never
    /// waits.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for a slot out of range;
    /// [`VkError::Vulkan`] when the semaphore cannot be queried.
    pub fn try_read(&mut self, slot: usize) -> Result<Option<CommandReadback>> {
        let count = self.slots.len();
        let s = self
            .slots
            .get_mut(slot)
            .ok_or_else(|| VkError::InvalidArgument(format!("slot {slot} of {count}")))?;
        let Some(value) = s.pending else {
            return Ok(None);
        };
        if self.semaphore.value()? < value {
            return Ok(None);
        }
        let counter = s.buffer.read::<u32>(0, 1)?[0];
        let stored = counter.min(self.capacity) as usize;
        let words = s.buffer.read::<u32>(4, stored)?;
        s.pending = None;
        Ok(Some(CommandReadback {
            value,
            counter,
            words,
            capacity: self.capacity,
        }))
    }
}
