//! Command recording: [`Recorder`] wraps a command buffer in the recording
//! state; [`OneShot`] records, submits and waits (for tests, examples and
//! setup work).

use crate::context::DeviceContext;
use crate::error::{Result, VkContext};
use ash::vk;

/// A command buffer in the recording state on a [`DeviceContext`]'s device.
///
/// lipac's `record_*` functions take a `Recorder`. Everything a recording
/// references (buffers, acceleration structures, scratch) must stay alive
/// until the GPU has finished executing it.
#[derive(Debug)]
pub struct Recorder<'a> {
    ctx: &'a DeviceContext,
    cmd: vk::CommandBuffer,
}

impl<'a> Recorder<'a> {
    /// Wraps an engine's command buffer.
    ///
    /// # Safety
    ///
    /// `cmd` must be a command buffer of `ctx`'s device in the recording state,
    /// from a pool whose queue family supports compute, outside a render pass,
    /// and must stay in the recording state while the `Recorder` is used.
    pub unsafe fn from_raw(ctx: &'a DeviceContext, cmd: vk::CommandBuffer) -> Self {
        Self { ctx, cmd }
    }

    /// The command buffer.
    pub fn raw(&self) -> vk::CommandBuffer {
        self.cmd
    }

    /// The context.
    pub fn context(&self) -> &'a DeviceContext {
        self.ctx
    }

    /// Records one global memory barrier (lipac's own, with flags valid
    /// for the features lipac requires).
    pub(crate) fn memory_barrier(
        &mut self,
        src_stage: vk::PipelineStageFlags2,
        src_access: vk::AccessFlags2,
        dst_stage: vk::PipelineStageFlags2,
        dst_access: vk::AccessFlags2,
    ) {
        let barrier = [vk::MemoryBarrier2::default()
            .src_stage_mask(src_stage)
            .src_access_mask(src_access)
            .dst_stage_mask(dst_stage)
            .dst_access_mask(dst_access)];
        let dep = vk::DependencyInfo::default().memory_barriers(&barrier);
        // SAFETY: `cmd` is recording on this device (constructor contract);
        // synchronization2 is enabled (context contract).
        unsafe { self.ctx.device().cmd_pipeline_barrier2(self.cmd, &dep) };
    }
}

/// A command pool, one command buffer and a fence: records a closure,
/// submits it to the context's queue and waits.
///
/// ```no_run
/// use lipac_vk::{HeadlessContext, OneShot, Validation};
/// let headless = HeadlessContext::new(Validation::Off)?;
/// let mut one_shot = OneShot::new(headless.context())?;
/// let cmd = one_shot.run(|rec| Ok(rec.raw()))?;
/// assert_ne!(cmd, ash::vk::CommandBuffer::null());
/// # Ok::<(), lipac_vk::VkError>(())
/// ```
#[derive(Debug)]
pub struct OneShot {
    ctx: DeviceContext,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
}

impl OneShot {
    /// Creates the pool, command buffer and fence on the context's queue family.
    ///
    /// # Errors
    ///
    /// [`crate::VkError::Vulkan`] when a creation call fails.
    pub fn new(ctx: &DeviceContext) -> Result<Self> {
        let device = ctx.device();
        let pool_info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(ctx.queue_family_index())
            .flags(vk::CommandPoolCreateFlags::TRANSIENT);
        // SAFETY: valid device and create info.
        let pool =
            unsafe { device.create_command_pool(&pool_info, None) }.ctx("vkCreateCommandPool")?;
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        // SAFETY: `pool` was just created on this device.
        let cmd = match unsafe { device.allocate_command_buffers(&alloc) } {
            Ok(v) if !v.is_empty() => v[0],
            Ok(_) | Err(_) => {
                // SAFETY: the pool is unused.
                unsafe { device.destroy_command_pool(pool, None) };
                return Err(crate::VkError::vk(
                    "vkAllocateCommandBuffers",
                    vk::Result::ERROR_OUT_OF_HOST_MEMORY,
                ));
            }
        };
        // SAFETY: valid device.
        let fence = match unsafe { device.create_fence(&vk::FenceCreateInfo::default(), None) } {
            Ok(f) => f,
            Err(e) => {
                // SAFETY: the pool and its buffer are unused.
                unsafe { device.destroy_command_pool(pool, None) };
                return Err(crate::VkError::vk("vkCreateFence", e));
            }
        };
        Ok(Self {
            ctx: ctx.clone(),
            pool,
            cmd,
            fence,
        })
    }

    /// Records `f` into the command buffer, submits it and waits for it to
    /// finish. Returns what `f` returned; an error from `f` submits nothing.
    ///
    /// # Errors
    ///
    /// The error of `f`, or [`crate::VkError::Vulkan`] when recording,
    /// submission or the wait fails.
    pub fn run<T>(&mut self, f: impl FnOnce(&mut Recorder<'_>) -> Result<T>) -> Result<T> {
        let device = self.ctx.device();
        // SAFETY: the pool's only command buffer is not pending (every run waits
        // for its fence before returning).
        unsafe { device.reset_command_pool(self.pool, vk::CommandPoolResetFlags::empty()) }
            .ctx("vkResetCommandPool")?;
        let begin = vk::CommandBufferBeginInfo::default()
            .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        // SAFETY: the command buffer is in the initial state after the reset.
        unsafe { device.begin_command_buffer(self.cmd, &begin) }.ctx("vkBeginCommandBuffer")?;
        let mut rec = Recorder {
            ctx: &self.ctx,
            cmd: self.cmd,
        };
        let value = f(&mut rec)?;
        // SAFETY: the command buffer is recording.
        unsafe { device.end_command_buffer(self.cmd) }.ctx("vkEndCommandBuffer")?;
        let cmd_info = [vk::CommandBufferSubmitInfo::default().command_buffer(self.cmd)];
        let submit = [vk::SubmitInfo2::default().command_buffer_infos(&cmd_info)];
        {
            let _queue = self.ctx.lock_queue();
            // SAFETY: the command buffer is executable, the fence unsignalled, and
            // lipac holds the queue lock (engines keep off the queue meanwhile,
            // per the context contract).
            unsafe { device.queue_submit2(self.ctx.queue(), &submit, self.fence) }
                .ctx("vkQueueSubmit2")?;
        }
        self.ctx.count_host_wait();
        // SAFETY: the fence belongs to this device.
        unsafe { device.wait_for_fences(&[self.fence], true, u64::MAX) }.ctx("vkWaitForFences")?;
        // SAFETY: the fence is signalled and no longer used by a submission.
        unsafe { device.reset_fences(&[self.fence]) }.ctx("vkResetFences")?;
        Ok(value)
    }
}

impl Drop for OneShot {
    fn drop(&mut self) {
        let device = self.ctx.device();
        // SAFETY: `run` waits for its submission, so nothing is pending; the
        // objects belong to this device.
        unsafe {
            device.destroy_fence(self.fence, None);
            device.destroy_command_pool(self.pool, None);
        }
    }
}

/// Submits recordings without waiting for them: a ring of `depth` command
/// buffers with fences, each submission optionally waiting on and signalling
/// timeline semaphores. The host blocks only when it reuses a command buffer
/// whose submission (`depth` submissions ago) has not finished.
///
/// Dropping waits for every submission still in flight: signal whatever
/// they wait on first.
#[derive(Debug)]
pub struct FrameSubmitter {
    ctx: DeviceContext,
    pool: vk::CommandPool,
    cmds: Vec<vk::CommandBuffer>,
    fences: Vec<vk::Fence>,
    in_flight: Vec<bool>,
    next: usize,
    blocking_waits: u64,
}

impl FrameSubmitter {
    /// A submitter with `depth` command buffers (1..=16).
    ///
    /// # Errors
    ///
    /// [`crate::VkError::InvalidArgument`] for a depth outside 1..=16;
    /// [`crate::VkError::Vulkan`] when a creation call fails.
    pub fn new(ctx: &DeviceContext, depth: usize) -> Result<Self> {
        if !(1..=16).contains(&depth) {
            return Err(crate::VkError::InvalidArgument(format!(
                "submitter depth {depth} outside 1..=16"
            )));
        }
        let device = ctx.device();
        let pool_info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(ctx.queue_family_index())
            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
        // SAFETY: valid device and create info.
        let pool =
            unsafe { device.create_command_pool(&pool_info, None) }.ctx("vkCreateCommandPool")?;
        // Drop frees what exists from here on.
        let mut this = Self {
            ctx: ctx.clone(),
            pool,
            cmds: Vec::new(),
            fences: Vec::new(),
            in_flight: vec![false; depth],
            next: 0,
            blocking_waits: 0,
        };
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(depth as u32);
        // SAFETY: `pool` was just created on this device.
        this.cmds =
            unsafe { device.allocate_command_buffers(&alloc) }.ctx("vkAllocateCommandBuffers")?;
        for _ in 0..depth {
            // SAFETY: valid device.
            let fence = unsafe { device.create_fence(&vk::FenceCreateInfo::default(), None) }
                .ctx("vkCreateFence")?;
            this.fences.push(fence);
        }
        Ok(this)
    }

    /// Records `f` into the next command buffer and submits it to the
    /// context's queue, waiting (on the GPU) for each `(semaphore, value)` in
    /// `waits` and signalling each in `signals` when done. Returns without
    /// waiting for the GPU. An error from `f` submits nothing.
    ///
    /// # Errors
    ///
    /// The error of `f`; [`crate::VkError::WrongContext`] for a semaphore of
    /// another context; [`crate::VkError::Vulkan`].
    pub fn submit<T>(
        &mut self,
        waits: &[(&crate::TimelineSemaphore, u64)],
        signals: &[(&crate::TimelineSemaphore, u64)],
        f: impl FnOnce(&mut Recorder<'_>) -> Result<T>,
    ) -> Result<T> {
        for (s, _) in waits.iter().chain(signals) {
            crate::accel::same_context(&self.ctx, s.context())?;
        }
        let i = self.next;
        if self.would_block()? {
            self.blocking_waits += 1;
            self.ctx.count_host_wait();
        }
        self.wait_slot(i)?;
        let device = self.ctx.device();
        let cmd = self.cmds[i];
        // SAFETY: the command buffer is not pending (its fence was waited for),
        // and the pool allows individual resets.
        unsafe { device.reset_command_buffer(cmd, vk::CommandBufferResetFlags::empty()) }
            .ctx("vkResetCommandBuffer")?;
        let begin = vk::CommandBufferBeginInfo::default()
            .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        // SAFETY: the command buffer is in the initial state after the reset.
        unsafe { device.begin_command_buffer(cmd, &begin) }.ctx("vkBeginCommandBuffer")?;
        let mut rec = Recorder {
            ctx: &self.ctx,
            cmd,
        };
        let value = f(&mut rec)?;
        // SAFETY: the command buffer is recording.
        unsafe { device.end_command_buffer(cmd) }.ctx("vkEndCommandBuffer")?;
        let infos = |list: &[(&crate::TimelineSemaphore, u64)]| -> Vec<_> {
            list.iter()
                .map(|(s, v)| {
                    vk::SemaphoreSubmitInfo::default()
                        .semaphore(s.raw())
                        .value(*v)
                        .stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)
                })
                .collect()
        };
        let (wait_infos, signal_infos) = (infos(waits), infos(signals));
        let cmd_info = [vk::CommandBufferSubmitInfo::default().command_buffer(cmd)];
        let submit = [vk::SubmitInfo2::default()
            .wait_semaphore_infos(&wait_infos)
            .command_buffer_infos(&cmd_info)
            .signal_semaphore_infos(&signal_infos)];
        {
            let _queue = self.ctx.lock_queue();
            // SAFETY: the command buffer is executable, its fence unsignalled
            // (reset after the last wait), the semaphores are timeline
            // semaphores of this device, and lipac holds the queue lock.
            unsafe { device.queue_submit2(self.ctx.queue(), &submit, self.fences[i]) }
                .ctx("vkQueueSubmit2")?;
        }
        self.in_flight[i] = true;
        self.next = (i + 1) % self.cmds.len();
        Ok(value)
    }

    /// Whether the next [`FrameSubmitter::submit`] would block the host
    /// (its command buffer's submission has not finished). Never waits.
    ///
    /// # Errors
    ///
    /// [`crate::VkError::Vulkan`] when the fence cannot be queried.
    pub fn would_block(&self) -> Result<bool> {
        let i = self.next;
        if !self.in_flight[i] {
            return Ok(false);
        }
        // SAFETY: the fence belongs to this device.
        let done = unsafe { self.ctx.device().get_fence_status(self.fences[i]) }
            .ctx("vkGetFenceStatus")?;
        Ok(!done)
    }

    /// How many times [`FrameSubmitter::submit`] blocked the host on an
    /// unfinished submission (`wait_idle` not counted).
    pub fn blocking_waits(&self) -> u64 {
        self.blocking_waits
    }

    fn wait_slot(&mut self, i: usize) -> Result<()> {
        if !self.in_flight[i] {
            return Ok(());
        }
        let device = self.ctx.device();
        // SAFETY: the fence belongs to this device and was submitted.
        unsafe { device.wait_for_fences(&[self.fences[i]], true, u64::MAX) }
            .ctx("vkWaitForFences")?;
        // SAFETY: the fence is signalled and no longer used by a submission.
        unsafe { device.reset_fences(&[self.fences[i]]) }.ctx("vkResetFences")?;
        self.in_flight[i] = false;
        Ok(())
    }

    /// Waits until every submission has finished.
    ///
    /// # Errors
    ///
    /// [`crate::VkError::Vulkan`] when a wait fails.
    pub fn wait_idle(&mut self) -> Result<()> {
        for i in 0..self.in_flight.len() {
            self.wait_slot(i)?;
        }
        Ok(())
    }
}

impl Drop for FrameSubmitter {
    fn drop(&mut self) {
        let _ = self.wait_idle();
        let device = self.ctx.device();
        // SAFETY: nothing is pending after the wait (a failed wait means a lost
        // device, where destruction is still allowed); objects of this device.
        unsafe {
            for &f in &self.fences {
                device.destroy_fence(f, None);
            }
            device.destroy_command_pool(self.pool, None);
        }
    }
}
