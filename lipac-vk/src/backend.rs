//! The engine-facing object, [`LipacVk`] (its docs describe the frame).

use crate::as_pool::AccelerationStructurePool;
use crate::assembly::{AssemblyBindings, AssemblyBuffers, AssemblyPipeline, InstanceBuffers};
use crate::blas::{BlasBatch, GpuBlas};
use crate::commands::{OneShot, Recorder};
use crate::context::DeviceContext;
use crate::counting::{CountingBoxConfig, UnitCube};
use crate::error::{Result, VkError};
use crate::escape::{EscapeBindings, EscapeSums};
use crate::executor::{BlasGeometrySource, ExecutedFrame, ExecutorStats, PlanExecutor};
use crate::feedback::{FeedbackBindings, FeedbackBuffers, FeedbackPipeline};
use crate::hitbox_tables::HitboxTables;
use crate::lifetimes::{Retirement, TlasPair};
use crate::memory::{Buffer, MemoryLocation, ScratchBuffer};
use crate::merged_boxes::MergedBoxes;
use crate::readback::{CommandReadback, CommandReadbackRing};
use crate::timeline::TimelineSemaphore;
use crate::tlas::GpuTlas;
use crate::upload::{RecordUploader, UploadBindings, UploadTargets};
use ash::vk;
use lipac_core::controller::EscapeSample;
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::layout::{HitboxRecord, InstanceBounds, InstanceHot, InstanceTlas, TlasInstance};
use lipac_core::manager::{Ack, DataUpload, Manager, ManagerPlan};
use lipac_core::thresholds::Thresholds;

const HOT_BYTES: u64 = std::mem::size_of::<InstanceHot>() as u64;
const SLOT_TLAS_BYTES: u64 = std::mem::size_of::<InstanceTlas>() as u64;
const BOUNDS_BYTES: u64 = std::mem::size_of::<InstanceBounds>() as u64;
const HITBOX_BYTES: u64 = std::mem::size_of::<HitboxRecord>() as u64;
const TLAS_RECORD_BYTES: u64 = std::mem::size_of::<TlasInstance>() as u64;
/// Words of a read-back slot's counters before the hit counters: the TLAS
/// record count and the four words of the escape sums.
const COUNTER_HEADER_WORDS: u64 = 5;

const STORAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::STORAGE_BUFFER;
const TRANSFER: vk::BufferUsageFlags = vk::BufferUsageFlags::from_raw(
    vk::BufferUsageFlags::TRANSFER_SRC.as_raw() | vk::BufferUsageFlags::TRANSFER_DST.as_raw(),
);

/// Settings of a [`LipacVk`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LipacVkConfig {
    /// Slots the per-slot GPU tables hold at first; they grow (at least
    /// doubling) when the manager's registry has more.
    pub initial_slot_capacity: u32,
    /// Hitboxes the hitbox tables hold at first, at least the index's
    /// [`HitboxIndex::len`] at creation (0: just that). They grow (at least
    /// doubling) when the index grows (a hashed index creating cells).
    pub initial_hitbox_capacity: u32,
    /// Read-back ring slots: at least the engine's frames in flight plus
    /// one, so that [`LipacVk::record_feedback`] never finds its slot unread
    /// (2..=16).
    pub readback_slots: usize,
    /// Command words Algorithm 2 can write per frame: the manager's
    /// [`lipac_core::culling::CullingConfig::command_capacity`] (checked
    /// every frame).
    pub command_capacity: u32,
    /// Block size of the acceleration-structure pool.
    pub pool_block_size: u64,
    /// SBT offsets and mask of the counting boxes (must match the manager's
    /// [`lipac_core::assembly::AssemblyConfig`]; checked every frame).
    pub counting: CountingBoxConfig,
    /// Build flags of the TLAS.
    pub tlas_flags: vk::BuildAccelerationStructureFlagsKHR,
    /// Also read back, per frame, the assembled TLAS records and the hitbox
    /// records as the trace left them (before Algorithm 2): for tests and
    /// debugging ([`FrameReadback::diagnostics`]). Costs a copy of both.
    pub read_back_diagnostics: bool,
}

impl Default for LipacVkConfig {
    /// 1024 slots, the index's hitboxes, 4 read-back slots (3 frames in flight), 65 536 command
    /// words (the manager's default), 64 MiB pool
    /// blocks, the default counting configuration, a fast-trace TLAS, no
    /// diagnostics.
    fn default() -> Self {
        Self {
            initial_slot_capacity: 1024,
            initial_hitbox_capacity: 0,
            readback_slots: 4,
            command_capacity: 65_536,
            pool_block_size: crate::as_pool::DEFAULT_POOL_BLOCK_SIZE,
            counting: CountingBoxConfig::default(),
            tlas_flags: vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
            read_back_diagnostics: false,
        }
    }
}

/// Where [`LipacVk::record_frame`] gets each instance's geometry data: fill
/// `out` (`upload.bytes` bytes, zeroed) with the data of `upload.mesh` at LOD
/// `upload.lod` for the instance `upload.handle` (e.g. material and vertex
/// buffer addresses for hit shaders).
pub trait InstanceDataSource {
    /// Writes the instance's data into `out`.
    fn write_instance_data(&self, upload: &DataUpload, out: &mut [u8]);
}

impl<F: Fn(&DataUpload, &mut [u8])> InstanceDataSource for F {
    fn write_instance_data(&self, upload: &DataUpload, out: &mut [u8]) {
        self(upload, out)
    }
}

/// What the frame's last submission must signal: [`LipacVk::timeline`] with
/// `value`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameSignal {
    /// The timeline semaphore ([`LipacVk::timeline`]).
    pub semaphore: vk::Semaphore,
    /// The value to signal.
    pub value: u64,
}

/// What [`LipacVk::record_frame`] recorded.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RecordedFrame {
    /// The frame's timeline value (signal it, see [`FrameSignal`]).
    pub value: u64,
    /// The BLAS part of the plan.
    pub blas: ExecutedFrame,
    /// Instance records uploaded.
    pub uploaded_records: u32,
    /// Geometry-data ranges written.
    pub data_uploads: usize,
    /// Whether the per-slot tables grew this frame.
    pub slot_tables_grew: bool,
    /// Whether the geometry-data buffer grew this frame.
    pub data_grew: bool,
    /// Whether the hitbox records and bounds grew this frame (the index
    /// has more hitboxes; [`LipacVk::hitbox_records`] is a new buffer).
    pub hitbox_tables_grew: bool,
    /// Hitbox bounds written this frame (all at the first frame and after
    /// growth, then those of the index's new, reused and evicted cells).
    pub hitbox_bounds_written: u32,
    /// Slots Algorithm 1 ran over.
    pub slots: u32,
    /// A capacity, not a count: the TLAS records the build runs over
    /// (slots + hitboxes, the most Algorithm 1 can emit; those past its
    /// counter are inactive zeros). The count Algorithm 1 appended comes
    /// back with the frame's read-back ([`FrameReadback::tlas_records`]).
    pub tlas_records: u32,
}

/// Per-frame copies for tests and debugging
/// ([`LipacVkConfig::read_back_diagnostics`]).
#[derive(Clone, Debug, PartialEq)]
pub struct FrameDiagnostics {
    /// Algorithm 1's TLAS records (the first `tlas_records` of the buffer).
    pub tlas_instances: Vec<TlasInstance>,
    /// The hitbox records after the trace, before Algorithm 2 (their hit
    /// counts are the trace's box hits).
    pub hitboxes: Vec<HitboxRecord>,
}

/// One finished frame, read back without waiting.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameReadback {
    /// The manager's frame ([`ManagerPlan::frame`]).
    pub frame: u64,
    /// Algorithm 2's commands: hand `frame`, `counter()` and `words()` to
    /// [`Manager::ingest_readback`].
    pub commands: CommandReadback,
    /// The per-slot hit counters of the trace: hand them to
    /// [`Manager::record_hits`] (build priorities).
    pub instance_hits: Vec<u32>,
    /// A count: the TLAS records Algorithm 1 appended (instances and
    /// counting boxes; counting boxes = this − the instances with a BLAS).
    pub tlas_records: u32,
    /// The escape fraction's sums of the frame, summed on the GPU after the
    /// trace: counting-box hits and all counted hits, the sample
    /// [`Manager::process_feedback`] takes on the CPU. [`Polled::deliver`]
    /// hands it to [`Manager::observe_escape`] (the closed-loop
    /// [`lipac_core::controller::ControlTarget::EscapeFraction`]).
    pub escape: EscapeSample,
    /// The diagnostics copies, if enabled.
    pub diagnostics: Option<FrameDiagnostics>,
}

/// What [`LipacVk::poll`] found.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Polled {
    /// The timeline value the GPU has reached.
    pub completed: u64,
    /// Acknowledgements for [`Manager::handle_ack`], in this order.
    pub acks: Vec<Ack>,
    /// Finished frames, oldest first.
    pub readbacks: Vec<FrameReadback>,
    /// Retired objects destroyed.
    pub destroyed: usize,
}

impl Polled {
    /// Hands everything to `manager`: acknowledgements first, then each
    /// read-back's commands with the frame that wrote them
    /// ([`Manager::ingest_readback`], the same call as for CPU backends: the
    /// commands set the manager's commanded state), hit counters
    /// ([`Manager::record_hits`]) and escape sums
    /// ([`Manager::observe_escape`], the newest read-back's last).
    ///
    /// # Errors
    ///
    /// The first refused acknowledgement ([`Manager::handle_ack`]); the rest
    /// is still delivered.
    pub fn deliver<H: HitboxIndex>(
        &self,
        manager: &mut Manager<H>,
    ) -> std::result::Result<(), lipac_core::manager::ManagerError> {
        let mut result = Ok(());
        for &ack in &self.acks {
            if let Err(e) = manager.handle_ack(ack) {
                if result.is_ok() {
                    result = Err(e);
                }
            }
        }
        for r in &self.readbacks {
            manager.ingest_readback(r.frame, r.commands.counter(), r.commands.words());
            manager.record_hits(&r.instance_hits);
            manager.observe_escape(r.escape);
        }
        result
    }
}

/// Counters and device memory of a [`LipacVk`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LipacVkStats {
    /// The BLAS executor (live BLASes, pool, scratch, pending work).
    pub executor: ExecutorStats,
    /// Slots the per-slot tables hold.
    pub slot_capacity: u32,
    /// Bytes of the per-slot tables, hitbox records and bounds, and command
    /// buffer.
    pub table_bytes: u64,
    /// Bytes of the geometry-data buffer.
    pub data_bytes: u64,
    /// Bytes of both TLASes.
    pub tlas_bytes: u64,
    /// Bytes of the read-back ring and its extra copies.
    pub readback_bytes: u64,
    /// Retired objects (other than BLASes) waiting for the GPU.
    pub retired_pending: usize,
    /// Frames recorded.
    pub frames: u64,
}

impl LipacVkStats {
    /// All device memory lipac holds: BLAS pool, scratch, tables, data,
    /// TLASes and read-back buffers.
    pub fn device_bytes(&self) -> u64 {
        self.executor.pool.capacity_bytes
            + self.executor.scratch_capacity
            + self.table_bytes
            + self.data_bytes
            + self.tlas_bytes
            + self.readback_bytes
    }
}

/// Staging for record uploads, reusable once the GPU passed `last_value`.
#[derive(Debug)]
struct UploadSet {
    bindings: UploadBindings,
    last_value: u64,
}

/// The per-slot GPU tables (they grow together).
#[derive(Debug)]
struct SlotTables {
    capacity: u32,
    /// The instance arrays ([`lipac_core::layout::InstanceArrays`] on the
    /// GPU): hot, TLAS records, bounds.
    hot: Buffer,
    tlas_records: Buffer,
    bounds: Buffer,
    instance_hits: Buffer,
    /// The decayed rule's per-slot hit rates (kept across frames and growth).
    instance_rates: Buffer,
    data_offsets: Buffer,
    tlas_instances: Buffer,
    assembly: AssemblyBindings,
    feedback: FeedbackBindings,
    escape: EscapeBindings,
    uploads: Vec<UploadSet>,
}

impl SlotTables {
    fn instance_buffers(&self) -> InstanceBuffers<'_> {
        InstanceBuffers {
            hot: &self.hot,
            tlas: &self.tlas_records,
            bounds: &self.bounds,
        }
    }
}

/// The extra host-visible copies of one read-back ring slot.
#[derive(Debug)]
struct ReadbackExtra {
    /// `[tlas count, escape sums (4 words), hits ...]`.
    counters: Buffer,
    diagnostics: Option<Buffer>,
    frame: u64,
    slots: u32,
    hitboxes: u32,
    tlas_records: u32,
}

#[derive(Clone, Copy, Debug)]
struct FrameInProgress {
    value: u64,
    frame: u64,
    slots: u32,
    hitboxes: u32,
    tlas_records: u32,
    thresholds: Thresholds,
}

/// The engine-facing object: [`LipacVk`] executes a
/// [`Manager`]'s [`ManagerPlan`]s on the engine's device, in the engine's
/// command buffers, and never waits on the host.
///
/// One frame (the engine records both parts into its own command buffers and
/// submits them in this order; the last submission signals
/// [`LipacVk::timeline`] with [`FrameSignal::value`]):
///
/// ```text
/// manager.begin_frame(f)
/// polled = lipac.poll()            acks -> manager.handle_ack, read-backs ->
///                                  manager.ingest_readback + record_hits
/// plan = manager.plan(&budgets)
/// lipac.record_frame(rec, &plan, &manager, &geometry, &data)
///     slot-table growth, geometry-data growth and uploads, BLAS batches
///     (builds, updates, compactions), frees deferred by timeline, record
///     uploads, hit counters cleared, GPU Algorithm 1, TLAS build
/// engine: its own ray-query passes with lipac_counting.glsl, reading
///     lipac.tlas(), counting into lipac.instance_hits() / hitbox_records()
///     (with adaptive hitboxes also reading hitbox_bounds(), with the
///     frame's merged_boxes() as push constants)
/// signal = lipac.record_feedback(rec)
///     GPU Algorithm 2, read-back copies (commands, hit counters, TLAS count)
/// engine: submit, signalling (lipac.timeline(), signal.value)
/// ```
///
/// Acknowledgements and read-backs come from [`LipacVk::poll`], which reads
/// the timeline's counter (`vkGetSemaphoreCounterValue`) and returns what
/// the GPU has finished: the [`Ack`]s of builds and compactions recorded at
/// or below that value, compacted sizes whose queries are readable, and one
/// [`FrameReadback`] per finished frame. Objects replaced or freed (BLASes,
/// scratch, TLAS storage, staging, slot tables) are destroyed once the GPU
/// has passed the last frame that used them. Nothing here blocks: a resource
/// still in use is never waited for, another one is used instead.
///
/// See `docs/INTEGRATION.md` for the whole integration.
#[derive(Debug)]
pub struct LipacVk {
    ctx: DeviceContext,
    config: LipacVkConfig,
    executor: PlanExecutor,
    _cube: UnitCube,
    cube_blas: GpuBlas,
    hitbox: HitboxTables,
    tlas_counter: Buffer,
    escape: EscapeSums,
    escape_sums: Buffer,
    commands: Buffer,
    command_counter: Buffer,
    tables: Option<SlotTables>,
    data: Option<Buffer>,
    uploader: RecordUploader,
    assembly: AssemblyPipeline,
    feedback: FeedbackPipeline,
    tlas: TlasPair,
    tlas_scratch: ScratchBuffer,
    retirement: Retirement,
    ring: CommandReadbackRing,
    extras: Vec<Option<ReadbackExtra>>,
    in_progress: Option<FrameInProgress>,
    frames: u64,
    /// The merged-box parameters of the last recorded frame.
    merged: MergedBoxes,
}

fn buffer(ctx: &DeviceContext, bytes: u64, usage: vk::BufferUsageFlags) -> Result<Buffer> {
    Buffer::new(ctx, bytes.max(4), usage, MemoryLocation::GpuOnly)
}

fn copy(rec: &mut Recorder<'_>, src: &Buffer, dst: &Buffer, regions: &[vk::BufferCopy]) {
    let regions: Vec<vk::BufferCopy> = regions.iter().copied().filter(|r| r.size > 0).collect();
    if regions.is_empty() {
        return;
    }
    // SAFETY: recording on this device (Recorder contract); callers pass
    // buffers of this device with TRANSFER_SRC / TRANSFER_DST usage and
    // regions inside both, and keep them alive until the GPU has run the copy.
    unsafe {
        rec.context()
            .device()
            .cmd_copy_buffer(rec.raw(), src.raw(), dst.raw(), &regions)
    };
}

fn fill_zero(rec: &mut Recorder<'_>, buffer: &Buffer) {
    crate::compute::record_zero(rec, buffer.raw(), 0, vk::WHOLE_SIZE);
}

fn transfer_to_all(rec: &mut Recorder<'_>) {
    rec.memory_barrier(
        vk::PipelineStageFlags2::TRANSFER,
        vk::AccessFlags2::TRANSFER_WRITE,
        vk::PipelineStageFlags2::ALL_COMMANDS,
        vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE,
    );
}

fn all_to_transfer(rec: &mut Recorder<'_>) {
    rec.memory_barrier(
        vk::PipelineStageFlags2::ALL_COMMANDS,
        vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE,
        vk::PipelineStageFlags2::TRANSFER,
        vk::AccessFlags2::TRANSFER_READ | vk::AccessFlags2::TRANSFER_WRITE,
    );
}

impl LipacVk {
    /// Binds to the engine's device: creates the pipelines, the BLAS pool,
    /// the read-back ring and the timeline, the hitbox tables of `index`
    /// (the manager's hitbox structure) and builds the unit-cube BLAS of the
    /// counting boxes (one submission to the context's queue, waited for:
    /// the only wait, at set-up). Put [`LipacVk::unit_cube_address`] into
    /// [`lipac_core::manager::ManagerConfig::new`] and
    /// [`LipacVk::scratch_alignment`] into its scheduler config.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for an invalid configuration or more
    /// than 2^24 hitboxes; Vulkan errors.
    pub fn new(
        ctx: &DeviceContext,
        index: &impl HitboxIndex,
        config: LipacVkConfig,
    ) -> Result<Self> {
        config.counting.validate()?;
        if !(2..=16).contains(&config.readback_slots)
            || config.initial_slot_capacity == 0
            || config.command_capacity == 0
        {
            return Err(VkError::InvalidArgument(format!(
                "read-back slots {} (2..=16), initial slot capacity {} and command capacity {}                  (>= 1)",
                config.readback_slots, config.initial_slot_capacity, config.command_capacity
            )));
        }
        let hitbox = HitboxTables::new(ctx, index, config.initial_hitbox_capacity)?;
        let pool = AccelerationStructurePool::new(ctx, config.pool_block_size)?;
        let executor = PlanExecutor::new(ctx, pool)?;
        let cube = UnitCube::new(ctx)?;
        let mut batch = BlasBatch::new();
        batch.push(
            &[cube.geometry()],
            vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
        )?;
        let mut scratch = ScratchBuffer::new(ctx);
        let mut built = OneShot::new(ctx)?.run(|rec| batch.record(rec, &mut scratch))?;
        let cube_blas = built
            .blases
            .pop()
            .ok_or_else(|| VkError::InvalidArgument("unit cube BLAS not built".into()))?;
        Ok(Self {
            tlas_counter: buffer(ctx, 4, STORAGE | TRANSFER)?,
            escape: EscapeSums::new(ctx)?,
            escape_sums: buffer(ctx, crate::escape::SUMS_BYTES, STORAGE | TRANSFER)?,
            commands: buffer(
                ctx,
                4 * u64::from(config.command_capacity),
                STORAGE | TRANSFER,
            )?,
            command_counter: buffer(ctx, 4, STORAGE | TRANSFER)?,
            ring: CommandReadbackRing::new(ctx, config.readback_slots, config.command_capacity)?,
            extras: (0..config.readback_slots).map(|_| None).collect(),
            uploader: RecordUploader::new(ctx)?,
            assembly: AssemblyPipeline::new(ctx)?,
            feedback: FeedbackPipeline::new(ctx)?,
            tlas: TlasPair::new(ctx, 1024, config.tlas_flags)?,
            tlas_scratch: ScratchBuffer::new(ctx),
            retirement: Retirement::new(),
            ctx: ctx.clone(),
            config,
            executor,
            _cube: cube,
            cube_blas,
            hitbox,
            tables: None,
            data: None,
            in_progress: None,
            frames: 0,
            merged: MergedBoxes::OFF,
        })
    }

    /// The unit-cube BLAS address for the manager's configuration.
    pub fn unit_cube_address(&self) -> u64 {
        self.cube_blas.device_address()
    }

    /// The scratch alignment for
    /// [`lipac_core::build_plan::SchedulerConfig::scratch_alignment`].
    pub fn scratch_alignment(&self) -> u64 {
        self.executor.scratch_alignment()
    }

    /// The counting-box configuration (the engine's shaders use the same).
    pub fn counting(&self) -> &CountingBoxConfig {
        &self.config.counting
    }

    /// The timeline semaphore every frame's last submission signals.
    pub fn timeline(&self) -> &TimelineSemaphore {
        self.ring.semaphore()
    }

    /// The timeline value the next frame signals ([`FrameSignal::value`] of
    /// its [`LipacVk::record_feedback`]): known before recording, for
    /// submission helpers that take their signals up front.
    pub fn next_frame_value(&self) -> u64 {
        self.in_progress.map_or(self.ring.next_value(), |f| f.value)
    }

    /// The buffers an engine's trace binds besides the TLAS and the hitbox
    /// records: the per-slot hit counters, the geometry data and its per-slot
    /// offsets ([`LipacVk::instance_hits`], [`LipacVk::instance_data`],
    /// [`LipacVk::instance_data_offsets`]).
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] before the first
    /// [`LipacVk::record_frame`].
    pub fn trace_targets(&self) -> Result<(&Buffer, &Buffer, &Buffer)> {
        match (&self.tables, &self.data) {
            (Some(t), Some(d)) => Ok((&t.instance_hits, d, &t.data_offsets)),
            _ => Err(VkError::InvalidArgument(
                "trace targets before the first record_frame".into(),
            )),
        }
    }

    /// The TLAS of the last [`LipacVk::record_frame`] (trace it in the same
    /// frame).
    pub fn tlas(&self) -> &GpuTlas {
        self.tlas.current()
    }

    /// Per-slot `u32` hit counters (cleared by [`LipacVk::record_frame`]):
    /// `LIPAC_COUNT_INSTANCE(i)` of the engine's shaders adds to them.
    /// `None` before the first frame. The buffer changes when the tables
    /// grow ([`RecordedFrame::slot_tables_grew`]): bind it per frame.
    pub fn instance_hits(&self) -> Option<&Buffer> {
        self.tables.as_ref().map(|t| &t.instance_hits)
    }

    /// The hitbox records (`LIPAC_HITBOX_RECORDS` of the engine's shaders).
    /// The buffer changes when the hitbox index grows
    /// ([`RecordedFrame::hitbox_tables_grew`]): bind it per frame.
    pub fn hitbox_records(&self) -> &Buffer {
        self.hitbox.records()
    }

    /// The hitbox bounds (`LIPAC_HITBOX_BOUNDS` of the engine's shaders:
    /// per hitbox its cell's x/z bounds as a `vec4`, lo.x, lo.z, hi.x,
    /// hi.z), read to resolve merged boxes ([`LipacVk::merged_boxes`]).
    /// Replaced together with [`LipacVk::hitbox_records`]: bind it per frame.
    pub fn hitbox_bounds(&self) -> &Buffer {
        self.hitbox.bounds()
    }

    /// The merged-box parameters of the TLAS of the last
    /// [`LipacVk::record_frame`] (the values of `lipac_counting.glsl`'s
    /// `LIPAC_GRID_NX`, `LIPAC_GRID_NZ`, `LIPAC_ADAPTIVE_LEVELS`,
    /// `LIPAC_SBT_MERGED_BOX`, `LIPAC_MIN_BOX_EXTENT`): on when the
    /// manager's [`lipac_core::culling::CullingConfig::adaptive_hitboxes`]
    /// is, [`MergedBoxes::OFF`] otherwise and before the first frame. The
    /// engine's tracer pushes them with the frame's trace.
    pub fn merged_boxes(&self) -> MergedBoxes {
        self.merged
    }

    /// Hitboxes the hitbox tables hold now (at least the manager's
    /// [`HitboxIndex::len`] at the last [`LipacVk::record_frame`]).
    pub fn hitbox_capacity(&self) -> u32 {
        self.hitbox.capacity()
    }

    /// The geometry-data buffer (`None` before the first frame); replaced
    /// when it grows ([`RecordedFrame::data_grew`]).
    pub fn instance_data(&self) -> Option<&Buffer> {
        self.data.as_ref()
    }

    /// Per slot (= TLAS custom index) the `u32` byte offset of the
    /// instance's range in [`LipacVk::instance_data`]. `None` before the
    /// first frame; replaced when the tables grow.
    pub fn instance_data_offsets(&self) -> Option<&Buffer> {
        self.tables.as_ref().map(|t| &t.data_offsets)
    }

    /// Keeps `object` (e.g. the engine's descriptor sets of this frame)
    /// alive until the GPU has passed the frame being recorded (or, between
    /// frames, the last recorded one).
    pub fn retire_after_frame<T: Send + 'static>(&mut self, object: T) {
        let value = self
            .in_progress
            .map_or(self.ring.next_value() - 1, |f| f.value);
        self.retirement.retire(value, object);
    }

    /// Counters and memory.
    pub fn stats(&self) -> LipacVkStats {
        let mut table_bytes = self.hitbox.bytes()
            + self.escape_sums.size()
            + self.commands.size()
            + self.command_counter.size()
            + self.tlas_counter.size();
        if let Some(t) = &self.tables {
            table_bytes += t.hot.size()
                + t.tlas_records.size()
                + t.bounds.size()
                + t.instance_hits.size()
                + t.instance_rates.size()
                + t.data_offsets.size()
                + t.tlas_instances.size();
        }
        let readback_bytes = self
            .extras
            .iter()
            .flatten()
            .map(|e| e.counters.size() + e.diagnostics.as_ref().map_or(0, Buffer::size))
            .sum::<u64>()
            + self.ring.slot_count() as u64 * 4 * (u64::from(self.ring.capacity()) + 1);
        LipacVkStats {
            executor: self.executor.stats(),
            slot_capacity: self.tables.as_ref().map_or(0, |t| t.capacity),
            table_bytes,
            data_bytes: self.data.as_ref().map_or(0, Buffer::size),
            tlas_bytes: self.tlas.memory_bytes(),
            readback_bytes,
            retired_pending: self.retirement.pending(),
            frames: self.frames,
        }
    }

    /// What the GPU has finished (see [`LipacVk`]); never waits.
    ///
    /// # Errors
    ///
    /// [`VkError::Vulkan`] when the semaphore, a query or a read-back cannot
    /// be read.
    pub fn poll(&mut self) -> Result<Polled> {
        let completed = self.ring.semaphore().value()?;
        let acks = self.executor.poll(completed)?;
        let mut order: Vec<(u64, usize)> = (0..self.ring.slot_count())
            .filter_map(|s| self.ring.pending(s).map(|v| (v, s)))
            .filter(|&(v, _)| v <= completed)
            .collect();
        order.sort_unstable();
        let mut readbacks = Vec::with_capacity(order.len());
        for (_, slot) in order {
            let Some(commands) = self.ring.try_read(slot)? else {
                continue;
            };
            let extra = self.extras[slot].as_ref().ok_or_else(|| {
                VkError::InvalidArgument(format!("read-back slot {slot} without its copies"))
            })?;
            let header = COUNTER_HEADER_WORDS as usize;
            let counters: Vec<u32> = extra.counters.read(0, header + extra.slots as usize)?;
            let diagnostics = match &extra.diagnostics {
                Some(d) => {
                    let tlas_bytes = u64::from(extra.tlas_records) * TLAS_RECORD_BYTES;
                    let count = (counters[0] as usize).min(extra.tlas_records as usize);
                    Some(FrameDiagnostics {
                        tlas_instances: d.read(0, count)?,
                        hitboxes: d.read(tlas_bytes, extra.hitboxes as usize)?,
                    })
                }
                None => None,
            };
            readbacks.push(FrameReadback {
                frame: extra.frame,
                commands,
                instance_hits: counters[header..].to_vec(),
                tlas_records: counters[0],
                escape: crate::escape::sample_of([
                    counters[1],
                    counters[2],
                    counters[3],
                    counters[4],
                ]),
                diagnostics,
            });
        }
        let destroyed = self.executor.collect(completed) + self.retirement.collect(completed);
        Ok(Polled {
            completed,
            acks,
            readbacks,
            destroyed,
        })
    }

    /// Records the first part of the frame of `plan` (see [`LipacVk`]) into `rec`. `manager` is the manager that made
    /// the plan (its records, slot count, assembly configuration and
    /// thresholds are read); `geometry` gives the BLAS inputs, `data` the
    /// instances' geometry data. Then trace, then
    /// [`LipacVk::record_feedback`].
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] when the previous frame's
    /// [`LipacVk::record_feedback`] is missing, the manager's assembly
    /// configuration does not match this object's counting boxes or
    /// unit cube, its command capacity or a data offset exceeds what the
    /// GPU tables address, adaptive hitboxes are on without a dense grid
    /// (the hashed index stays leaf-only), or as [`PlanExecutor::record`];
    /// Vulkan errors.
    ///
    /// With the manager's adaptive hitboxes on, Algorithm 1 merges cold
    /// quadtree nodes into one box each
    /// ([`AssemblyPipeline::record_adaptive`] with
    /// [`Manager::hitbox_tree`]); the engine's tracer must then resolve them
    /// ([`LipacVk::merged_boxes`], [`LipacVk::hitbox_bounds`]).
    pub fn record_frame<H: HitboxIndex>(
        &mut self,
        rec: &mut Recorder<'_>,
        plan: &ManagerPlan,
        manager: &Manager<H>,
        geometry: &dyn BlasGeometrySource,
        data: &dyn InstanceDataSource,
    ) -> Result<RecordedFrame> {
        crate::accel::same_context(rec.context(), &self.ctx)?;
        if self.in_progress.is_some() {
            return Err(VkError::InvalidArgument(
                "record_frame before the previous frame's record_feedback".into(),
            ));
        }
        let culling = manager.culling_config();
        let a = &culling.assembly;
        let c = &self.config.counting;
        if a.unit_cube_blas != self.unit_cube_address()
            || a.counting_mask != c.counting_mask
            || a.omitted_box_sbt_offset != c.omitted_box_sbt_offset
            || a.hitbox_sbt_offset != c.hitbox_box_sbt_offset
        {
            return Err(VkError::InvalidArgument(format!(
                "the manager's assembly config {a:?} does not match the counting boxes {c:?} \
                 and unit cube {:#x}",
                self.unit_cube_address()
            )));
        }
        // Adaptive hitboxes: the manager's quadtree over the dense grid.
        let tree = manager.hitbox_tree();
        if culling.adaptive_hitboxes.is_on() && tree.is_none() {
            return Err(VkError::InvalidArgument(
                "adaptive hitboxes (CullingConfig::adaptive_hitboxes) need the dense grid \
                 (HitboxGrid); the hashed index (HashedHitboxes) stays leaf-only: set \
                 adaptive_hitboxes.levels = 0"
                    .into(),
            ));
        }
        let merged = MergedBoxes::new(tree, a);
        let index = manager.registry().hitbox_index();
        if merged.is_on() && merged.hitboxes_read() != u64::from(index.len()) {
            return Err(VkError::InvalidArgument(format!(
                "the adaptive hitbox tree covers {} x {} cells but the index has {} hitboxes",
                merged.grid_nx,
                merged.grid_nz,
                index.len()
            )));
        }
        if manager.hitboxes().len() != index.len() as usize {
            return Err(VkError::InvalidArgument(format!(
                "the manager has {} hitbox records for {} hitboxes",
                manager.hitboxes().len(),
                index.len()
            )));
        }
        let value = self.ring.next_value();
        let completed = self.ring.semaphore().value()?;
        let records = manager.records();
        let slots = manager.slot_count();
        let mut out = RecordedFrame {
            value,
            slots,
            ..RecordedFrame::default()
        };

        if culling.command_capacity != self.config.command_capacity {
            return Err(VkError::InvalidArgument(format!(
                "the manager's command capacity {} differs from lipac-vk's {}",
                culling.command_capacity, self.config.command_capacity
            )));
        }

        // Hitbox tables: grown with the index (records copied, bounds
        // re-uploaded), evicted records reset, new and changed bounds written.
        let hitbox = self.hitbox.record(
            &self.ctx,
            rec,
            index,
            manager.registry().evicted_hitboxes(),
            &mut self.retirement,
            value,
        )?;
        out.hitbox_tables_grew = hitbox.grew;
        out.hitbox_bounds_written = hitbox.bounds_written;

        // Slot tables: created at the first frame, grown (contents kept).
        let first = self.tables.is_none();
        if first || slots > self.tables.as_ref().map_or(0, |t| t.capacity) {
            let old_capacity = self.tables.as_ref().map_or(0, |t| t.capacity);
            let capacity = slots
                .max(self.config.initial_slot_capacity)
                .max(old_capacity.saturating_mul(2));
            let tables = self.make_tables(capacity)?;
            fill_zero(rec, &tables.hot);
            fill_zero(rec, &tables.tlas_records);
            fill_zero(rec, &tables.bounds);
            fill_zero(rec, &tables.data_offsets);
            fill_zero(rec, &tables.instance_rates);
            if let Some(old) = self.tables.take() {
                rec.memory_barrier(
                    vk::PipelineStageFlags2::ALL_COMMANDS,
                    vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE,
                    vk::PipelineStageFlags2::TRANSFER,
                    vk::AccessFlags2::TRANSFER_READ | vk::AccessFlags2::TRANSFER_WRITE,
                );
                let bytes = u64::from(old.capacity);
                for (from, to, per_slot) in [
                    (&old.hot, &tables.hot, HOT_BYTES),
                    (&old.tlas_records, &tables.tlas_records, SLOT_TLAS_BYTES),
                    (&old.bounds, &tables.bounds, BOUNDS_BYTES),
                ] {
                    copy(
                        rec,
                        from,
                        to,
                        &[vk::BufferCopy::default().size(bytes * per_slot)],
                    );
                }
                copy(
                    rec,
                    &old.data_offsets,
                    &tables.data_offsets,
                    &[vk::BufferCopy::default().size(bytes * 4)],
                );
                copy(
                    rec,
                    &old.instance_rates,
                    &tables.instance_rates,
                    &[vk::BufferCopy::default().size(bytes * 4)],
                );
                self.retirement.retire(value, old);
                out.slot_tables_grew = true;
            }
            transfer_to_all(rec);
            self.tables = Some(tables);
        } else if hitbox.grew {
            self.rebind_tables(value)?;
        }

        // Geometry data: growth, then this plan's ranges.
        out.data_grew = self.record_data(rec, plan, manager, data, value)?;
        out.data_uploads = plan.data_uploads.len();

        // BLAS builds, updates, compactions, frees.
        out.blas = self.executor.record(rec, &plan.blas, geometry, value)?;

        let tables = self
            .tables
            .as_mut()
            .ok_or_else(|| VkError::InvalidArgument("slot tables missing after creation".into()))?;
        // Record uploads through staging the GPU has finished with.
        let set = match tables
            .uploads
            .iter()
            .position(|s| s.last_value <= completed)
        {
            Some(i) => i,
            None => {
                let bindings = self.uploader.bind(&UploadTargets {
                    instances: tables.instance_buffers(),
                    hitboxes: self.hitbox.records(),
                    instance_rates: &tables.instance_rates,
                })?;
                tables.uploads.push(UploadSet {
                    bindings,
                    last_value: 0,
                });
                tables.uploads.len() - 1
            }
        };
        let up = &mut tables.uploads[set];
        up.last_value = value;
        out.uploaded_records = self
            .uploader
            .record(rec, &mut up.bindings, &plan.uploads, records)?
            .records;

        // Algorithm 1 and the TLAS.
        self.feedback
            .record_clear_instance_hits(rec, &tables.feedback)?;
        self.assembly
            .record_adaptive(rec, &tables.assembly, a, tree, slots)?;
        self.merged = merged;
        let hitboxes = self.hitbox.count();
        let tlas_records = slots + hitboxes;
        self.tlas.record_build(
            rec,
            &tables.tlas_instances,
            0,
            tlas_records,
            &mut self.tlas_scratch,
            &mut self.retirement,
            value,
        )?;
        out.tlas_records = tlas_records;
        self.in_progress = Some(FrameInProgress {
            value,
            frame: plan.frame,
            slots,
            hitboxes,
            tlas_records,
            thresholds: culling.thresholds,
        });
        Ok(out)
    }

    /// Records the end of the frame after the engine's traces: GPU
    /// Algorithm 2 and the read-back copies. The submission holding it (the
    /// frame's last) must signal the returned [`FrameSignal`].
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] without a [`LipacVk::record_frame`]
    /// first; [`VkError::ReadbackSlotBusy`] when the read-back slot is still
    /// unread (more frames in flight than [`LipacVkConfig::readback_slots`]
    /// − 1, or [`LipacVk::poll`] not called); Vulkan errors.
    pub fn record_feedback(&mut self, rec: &mut Recorder<'_>) -> Result<FrameSignal> {
        crate::accel::same_context(rec.context(), &self.ctx)?;
        let frame = self.in_progress.ok_or_else(|| {
            VkError::InvalidArgument("record_feedback without record_frame".into())
        })?;
        let slot = self.ring.next_slot();
        if let Some(value) = self.ring.pending(slot) {
            return Err(VkError::ReadbackSlotBusy { slot, value });
        }
        let tables = self.tables.as_ref().ok_or_else(|| {
            VkError::InvalidArgument("record_feedback before the first frame".into())
        })?;
        // The extra copies of this ring slot (not in use: the slot was read).
        let counters_bytes = 4 * (COUNTER_HEADER_WORDS + u64::from(tables.capacity));
        let diag_bytes = self.config.read_back_diagnostics.then(|| {
            u64::from(frame.tlas_records) * TLAS_RECORD_BYTES
                + u64::from(frame.hitboxes) * HITBOX_BYTES
        });
        let reuse = self.extras[slot].take().filter(|e| {
            e.counters.size() >= counters_bytes
                && match (&e.diagnostics, diag_bytes) {
                    (Some(d), Some(b)) => d.size() >= b,
                    (None, None) => true,
                    _ => false,
                }
        });
        let mut extra = match reuse {
            Some(e) => e,
            None => ReadbackExtra {
                counters: Buffer::new(
                    &self.ctx,
                    counters_bytes,
                    vk::BufferUsageFlags::TRANSFER_DST,
                    MemoryLocation::GpuToCpu,
                )?,
                diagnostics: diag_bytes
                    .map(|b| {
                        Buffer::new(
                            &self.ctx,
                            b.max(4),
                            vk::BufferUsageFlags::TRANSFER_DST,
                            MemoryLocation::GpuToCpu,
                        )
                    })
                    .transpose()?,
                frame: 0,
                slots: 0,
                hitboxes: 0,
                tlas_records: 0,
            },
        };
        extra.frame = frame.frame;
        extra.slots = frame.slots;
        extra.hitboxes = frame.hitboxes;
        extra.tlas_records = frame.tlas_records;

        // The traces' writes, then the copies taken before Algorithm 2.
        all_to_transfer(rec);
        copy(
            rec,
            &self.tlas_counter,
            &extra.counters,
            &[vk::BufferCopy::default().size(4)],
        );
        if let Some(d) = &extra.diagnostics {
            let tlas_bytes = u64::from(frame.tlas_records) * TLAS_RECORD_BYTES;
            copy(
                rec,
                &tables.tlas_instances,
                d,
                &[vk::BufferCopy::default().size(tlas_bytes)],
            );
            copy(
                rec,
                self.hitbox.records(),
                d,
                &[vk::BufferCopy::default()
                    .dst_offset(tlas_bytes)
                    .size(u64::from(frame.hitboxes) * HITBOX_BYTES)],
            );
        }
        // The escape fraction's sums, from the trace's counts (before
        // Algorithm 2 adds instance hits to the hitboxes).
        self.escape.record(
            rec,
            &tables.escape,
            &self.escape_sums,
            frame.slots,
            frame.hitboxes,
        )?;
        copy(
            rec,
            &self.escape_sums,
            &extra.counters,
            &[vk::BufferCopy::default()
                .dst_offset(4)
                .size(crate::escape::SUMS_BYTES)],
        );
        self.feedback
            .record(rec, &tables.feedback, &frame.thresholds, frame.slots)?;
        if frame.slots > 0 {
            copy(
                rec,
                &tables.instance_hits,
                &extra.counters,
                &[vk::BufferCopy::default()
                    .dst_offset(4 * COUNTER_HEADER_WORDS)
                    .size(4 * u64::from(frame.slots))],
            );
        }
        // The ring's copy ends with the barrier to the host for all copies.
        let ticket = self
            .ring
            .record_copy(rec, &self.commands, &self.command_counter)?;
        if ticket.value != frame.value {
            return Err(VkError::InvalidArgument(format!(
                "read-back value {} for frame value {}",
                ticket.value, frame.value
            )));
        }
        self.extras[ticket.slot] = Some(extra);
        self.in_progress = None;
        self.frames += 1;
        Ok(FrameSignal {
            semaphore: self.ring.semaphore().raw(),
            value: frame.value,
        })
    }

    fn make_tables(&self, capacity: u32) -> Result<SlotTables> {
        let ctx = &self.ctx;
        let n = u64::from(capacity);
        let hot = buffer(ctx, n * HOT_BYTES, STORAGE | TRANSFER)?;
        let tlas_records = buffer(ctx, n * SLOT_TLAS_BYTES, STORAGE | TRANSFER)?;
        let bounds = buffer(ctx, n * BOUNDS_BYTES, STORAGE | TRANSFER)?;
        let instances = InstanceBuffers {
            hot: &hot,
            tlas: &tlas_records,
            bounds: &bounds,
        };
        let instance_hits = buffer(ctx, n * 4, STORAGE | TRANSFER)?;
        let instance_rates = buffer(ctx, n * 4, STORAGE | TRANSFER)?;
        let data_offsets = buffer(ctx, n * 4, STORAGE | TRANSFER)?;
        let tlas_instances = self.tlas_instances(capacity)?;
        let (assembly, feedback, escape) =
            self.bind_tables(instances, &instance_hits, &instance_rates, &tlas_instances)?;
        Ok(SlotTables {
            capacity,
            hot,
            tlas_records,
            bounds,
            instance_hits,
            instance_rates,
            data_offsets,
            tlas_instances,
            assembly,
            feedback,
            escape,
            uploads: Vec::new(),
        })
    }

    /// The TLAS instance buffer for `capacity` slots and the hitbox
    /// capacity (Algorithm 1 emits at most one record per slot and hitbox).
    fn tlas_instances(&self, capacity: u32) -> Result<Buffer> {
        buffer(
            &self.ctx,
            (u64::from(capacity) + u64::from(self.hitbox.capacity())) * TLAS_RECORD_BYTES,
            STORAGE
                | TRANSFER
                | vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR,
        )
    }

    /// The descriptor sets of the Algorithm 1, Algorithm 2 and escape-sum
    /// passes over these per-slot buffers and the current hitbox tables.
    fn bind_tables(
        &self,
        instances: InstanceBuffers<'_>,
        instance_hits: &Buffer,
        instance_rates: &Buffer,
        tlas_instances: &Buffer,
    ) -> Result<(AssemblyBindings, FeedbackBindings, EscapeBindings)> {
        let assembly = self.assembly.bind(&AssemblyBuffers {
            instances,
            hitboxes: self.hitbox.records(),
            hitbox_bounds: self.hitbox.bounds(),
            tlas_instances,
            tlas_counter: &self.tlas_counter,
        })?;
        let feedback = self.feedback.bind(&FeedbackBuffers {
            instance_hot: instances.hot,
            instance_hits,
            hitboxes: self.hitbox.records(),
            commands: &self.commands,
            command_counter: &self.command_counter,
            instance_rates,
        })?;
        let escape = self.escape.bind(
            instances.hot,
            instance_hits,
            self.hitbox.records(),
            &self.escape_sums,
        )?;
        Ok((assembly, feedback, escape))
    }

    /// After the hitbox tables grew (and the slot tables did not): a TLAS
    /// instance buffer with room for the new hitboxes, and descriptor sets
    /// and upload staging bound to the new hitbox buffers. The replaced
    /// ones are retired until the GPU passes `value` (frames in flight
    /// still use them).
    fn rebind_tables(&mut self, value: u64) -> Result<()> {
        let Some(t) = self.tables.as_ref() else {
            return Ok(());
        };
        let tlas_instances = self.tlas_instances(t.capacity)?;
        let (assembly, feedback, escape) = self.bind_tables(
            t.instance_buffers(),
            &t.instance_hits,
            &t.instance_rates,
            &tlas_instances,
        )?;
        let Some(t) = self.tables.as_mut() else {
            return Ok(());
        };
        let old = (
            std::mem::replace(&mut t.tlas_instances, tlas_instances),
            std::mem::replace(&mut t.assembly, assembly),
            std::mem::replace(&mut t.feedback, feedback),
            std::mem::replace(&mut t.escape, escape),
            std::mem::take(&mut t.uploads),
        );
        self.retirement.retire(value, old);
        Ok(())
    }

    /// Data-buffer growth and this plan's data uploads; returns whether the
    /// buffer grew.
    fn record_data<H: HitboxIndex>(
        &mut self,
        rec: &mut Recorder<'_>,
        plan: &ManagerPlan,
        manager: &Manager<H>,
        source: &dyn InstanceDataSource,
        value: u64,
    ) -> Result<bool> {
        let wanted = manager.data_allocator().capacity();
        let mut grew = false;
        if self.data.as_ref().map_or(0, Buffer::size) < wanted.max(4) {
            let new = buffer(&self.ctx, wanted, STORAGE | TRANSFER)?;
            if let Some(old) = self.data.take() {
                all_to_transfer(rec);
                copy(
                    rec,
                    &old,
                    &new,
                    &[vk::BufferCopy::default().size(old.size())],
                );
                self.retirement.retire(value, old);
                grew = true;
            }
            self.data = Some(new);
        }
        if plan.data_uploads.is_empty() {
            if grew {
                transfer_to_all(rec);
            }
            return Ok(grew);
        }
        let (Some(data), Some(tables)) = (&self.data, &self.tables) else {
            return Err(VkError::InvalidArgument("data buffer missing".into()));
        };
        // Staging: the ranges' bytes, then one u32 offset per upload.
        let payload: u64 = plan
            .data_uploads
            .iter()
            .map(|u| u.bytes.next_multiple_of(4))
            .sum();
        let offsets_at = payload;
        let mut bytes = vec![0u8; (payload + 4 * plan.data_uploads.len() as u64) as usize];
        let mut data_regions = Vec::with_capacity(plan.data_uploads.len());
        let mut offset_regions = Vec::with_capacity(plan.data_uploads.len());
        let mut at = 0u64;
        for (i, u) in plan.data_uploads.iter().enumerate() {
            if u.offset + u.bytes > data.size() || u.slot >= tables.capacity {
                return Err(VkError::InvalidArgument(format!(
                    "data upload {u:?} outside the data buffer ({} B) or slot tables ({})",
                    data.size(),
                    tables.capacity
                )));
            }
            let offset = u32::try_from(u.offset).map_err(|_| {
                VkError::InvalidArgument(format!("data offset {} over 4 GiB", u.offset))
            })?;
            source.write_instance_data(u, &mut bytes[at as usize..(at + u.bytes) as usize]);
            if u.bytes > 0 {
                data_regions.push(
                    vk::BufferCopy::default()
                        .src_offset(at)
                        .dst_offset(u.offset)
                        .size(u.bytes),
                );
            }
            let o = offsets_at + 4 * i as u64;
            bytes[o as usize..o as usize + 4].copy_from_slice(&offset.to_ne_bytes());
            offset_regions.push(
                vk::BufferCopy::default()
                    .src_offset(o)
                    .dst_offset(4 * u64::from(u.slot))
                    .size(4),
            );
            at += u.bytes.next_multiple_of(4);
        }
        let staging = Buffer::with_data(
            &self.ctx,
            vk::BufferUsageFlags::TRANSFER_SRC,
            MemoryLocation::CpuToGpu,
            &bytes,
        )?;
        if !grew {
            all_to_transfer(rec);
        }
        copy(rec, &staging, data, &data_regions);
        copy(rec, &staging, &tables.data_offsets, &offset_regions);
        transfer_to_all(rec);
        self.retirement.retire(value, staging);
        Ok(grew)
    }
}
