//! The engine-facing per-frame API: one [`Manager`] that owns the command
//! loop ([`Culling`]), the BLAS [`BuildScheduler`] (and its cache) and a
//! [`TlsfAllocator`] for per-instance geometry-data ranges, and keeps them
//! consistent. It is sans-IO and polled: the engine and the backend call in,
//! take one [`ManagerPlan`] out per frame ([`Manager::plan`]) and hand results
//! back as [`Ack`]s ([`Manager::handle_ack`]). It never calls back; every
//! error comes from the call that caused it, and a failed call changes
//! nothing it did not document.
//!
//! # One frame
//!
//! | step | call | what happens |
//! | --- | --- | --- |
//! | 1 | [`Manager::begin_frame`] | slot quarantine, hitbox reset, deferred BLAS frees become due |
//! | 2 | [`Manager::mitigate_latency`] (optional) | instances newly in the frustum become active; their BLASes are requested |
//! | 3 | [`Manager::ingest_readback`] | the commands Algorithm 2 wrote frames ago (one read-back rule, [`crate::command::CommandQueue`]) |
//! | 4 | [`Manager::plan`] | BLAS work ([`FramePlan`]), uploads, geometry-data changes and buffer growth |
//! | 5 | backend | executes the plan; [`Manager::handle_ack`] with [`Ack::Built`], [`Ack::CompactedSize`], [`Ack::Compacted`] whenever results arrive |
//! | 6 | [`Manager::assemble`] (CPU backends) | Algorithm 1: TLAS instances (a GPU backend runs it as a shader) |
//! | 7 | trace | hits into [`Manager::instance_hits_mut`] / [`Manager::hitboxes_mut`] |
//! | 8 | [`Manager::process_feedback`] + [`Manager::take_commands`] (CPU backends) | Algorithm 2; its commands go to the read-back ring |
//!
//! Instances change between frames: [`Manager::register`],
//! [`Manager::update`], [`Manager::set_transform`], [`Manager::set_lod`],
//! [`Manager::remove`]. The flags decide the BLAS once, at registration:
//!
//! | flags | BLAS |
//! | --- | --- |
//! | neither `UNIQUE_BLAS` nor `STATIC` | shared per (mesh, LOD) |
//! | `STATIC` | shared per (mesh, LOD), compactable (a separate BLAS from the non-static one) |
//! | `UNIQUE_BLAS` | the instance's own, refit every frame and rebuilt periodically (animated, deformed) |
//! | `UNIQUE_BLAS \| STATIC` | the instance's own, static (terrain tile): built once per LOD, never refit, compactable |
//!
//! What the manager guarantees (addresses follow acknowledgements, the traced
//! LOD, slots and the scheduler, the geometry-data buffer, errors and limits):
//! `docs/MANAGER.md`.
//!
//! # Example
//!
//! A tiny synthetic backend that "builds" BLASes by handing out fake
//! addresses and acknowledges them one frame later (the same program is
//! `lipac-core/examples/manager_frame.rs`):
//!
//! ```
#![doc = include_str!("../../examples/manager_frame.rs")]
//! ```

mod ack;
mod catalog;
mod control;
mod error;
pub mod recorder;
mod stats;

pub use ack::Ack;
pub use catalog::{MeshCatalog, MeshLod, MAX_LODS, MAX_LOD_DATA_BYTES};
pub use error::ManagerError;
pub use recorder::{FinishedTrace, RecorderError, RecorderOptions, TraceRecorder, DEFAULT_CAMERA};
pub use stats::{InstanceCounts, ManagerStats, MemoryStats};

use std::collections::VecDeque;
use std::ops::Range;

use glam::{Affine3A, Vec3};

use crate::allocator::{AllocError, AllocHandle, TlsfAllocator};
use crate::assembly::AssemblyStats;
use crate::blas_ids::{InstanceKey, Lod};
use crate::build_plan::{
    BlasGeometry, BuildBudgets, BuildScheduler, FramePlan, InstanceBlasRequest, SchedulerConfig,
};
use crate::command::{Command, IngestSummary};
use crate::controller::{ControlTarget, ControllerConfig, EscapeSample, ThresholdController};
use crate::culling::{
    BlasAction, CommandEvent, Culling, CullingConfig, LatencyOutcome, ProcessStats, Readback,
    Uploads,
};
use crate::feedback::FeedbackStats;
use crate::grid::HitboxGrid;
use crate::hitbox_index::HitboxIndex;
use crate::instance::{InstanceDesc, InstanceFlags, MeshId};
use crate::latency::{ActivationHeuristic, Frustum};
use crate::layout::{HitboxRecord, InstanceArrays, InstanceState, TlasInstance};
use crate::math::Aabb;
use crate::memory::MemoryUsage;
use crate::registry::{InstanceHandle, InstanceRegistry, RemovedInstance};
use crate::thresholds::Thresholds;

/// The geometry-data buffer's allocator settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DataConfig {
    /// Initial capacity in bytes (0 allowed: the first registration grows).
    pub initial_capacity: u64,
    /// Alignment of every range (a power of two, e.g. 16 or 256).
    pub alignment: u64,
}

impl Default for DataConfig {
    /// 1 MiB, 16-byte ranges.
    fn default() -> Self {
        Self {
            initial_capacity: 1 << 20,
            alignment: 16,
        }
    }
}

/// Settings of a [`Manager`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ManagerConfig {
    /// The command loop (registry, thresholds, assembly, command buffer,
    /// latency mitigation, read-back latency). The per-frame command budget
    /// is [`FrameBudgets::commands`].
    pub culling: CullingConfig,
    /// The BLAS scheduler and cache.
    pub scheduler: SchedulerConfig,
    /// The geometry-data allocator.
    pub data: DataConfig,
    /// A target the closed-loop controller holds by scaling
    /// [`CullingConfig::thresholds`] every frame ([`crate::controller`]):
    /// a memory budget or an escape fraction; `None` (the default) keeps
    /// the thresholds fixed.
    pub target: Option<ControlTarget>,
    /// The controller's gains, scale range and TLAS record size (used only
    /// with a `target`).
    pub controller: ControllerConfig,
}

impl ManagerConfig {
    /// Defaults around the backend's unit-cube BLAS ([`CullingConfig::new`],
    /// [`SchedulerConfig::default`], [`DataConfig::default`]).
    pub fn new(unit_cube_blas: u64) -> Self {
        Self {
            culling: CullingConfig::new(unit_cube_blas),
            scheduler: SchedulerConfig::default(),
            data: DataConfig::default(),
            target: None,
            controller: ControllerConfig::default(),
        }
    }
}

/// Per-frame budgets of [`Manager::plan`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameBudgets {
    /// Commands processed per frame (the rest wait, highest priority first).
    pub commands: usize,
    /// BLAS builds, compactions and scratch per frame.
    pub builds: BuildBudgets,
}

impl Default for FrameBudgets {
    /// 4096 commands, [`BuildBudgets::default`].
    fn default() -> Self {
        Self {
            commands: 4096,
            builds: BuildBudgets::default(),
        }
    }
}

/// One geometry-data range to (re)write: the instance in `slot` now uses
/// `bytes` bytes at `offset` for LOD `lod` of `mesh`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DataUpload {
    /// The GPU slot.
    pub slot: u32,
    /// The instance.
    pub handle: InstanceHandle,
    /// Its mesh.
    pub mesh: MeshId,
    /// Its traced LOD.
    pub lod: u32,
    /// Byte offset in the geometry-data buffer.
    pub offset: u64,
    /// Byte size ([`MeshLod::data_bytes`]).
    pub bytes: u64,
}

/// The geometry-data buffer grew (see the [module docs](self)).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DataGrowth {
    /// The capacity the backend had.
    pub from: u64,
    /// The capacity it must have now (contents `0..from` kept).
    pub to: u64,
}

/// Everything the backend does for one frame, from [`Manager::plan`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ManagerPlan {
    /// The frame.
    pub frame: u64,
    /// What command processing did this frame.
    pub commands: ProcessStats,
    /// BLAS builds and updates (batches with scratch slices), compactions and
    /// frees; acknowledge builds and compactions with [`Manager::handle_ack`].
    pub blas: FramePlan,
    /// Instance records to upload (keeping the GPU's state bits) and the
    /// CPU's state-bit overrides ([`Uploads`]).
    pub uploads: Uploads,
    /// Geometry-data ranges that changed since the last plan (registrations
    /// and traced-LOD changes), by ascending slot, one per slot.
    pub data_uploads: Vec<DataUpload>,
    /// Growth of the geometry-data buffer since the last plan, if any: apply
    /// it before writing [`ManagerPlan::data_uploads`].
    pub data_growth: Option<DataGrowth>,
}

/// A read-only view of one instance, from [`Manager::instance`].
#[derive(Clone, Debug, PartialEq)]
pub struct InstanceView {
    /// The GPU slot (= the scheduler's [`InstanceKey`]).
    pub slot: u32,
    /// Its commanded state, the Manager's view of the device state:
    /// [`InstanceState::Active`] if the newest ingested command said `add`
    /// or latency mitigation activated it since, else
    /// [`InstanceState::Inactive`] (registration, `remove`; an omitted
    /// instance shows as inactive). The same for CPU and GPU backends; the
    /// state bits Algorithm 2 wrote are in the records (CPU backends:
    /// [`Manager::registry`]).
    pub state: InstanceState,
    /// The BLAS address in its record (0 = none).
    pub blas: u64,
    /// The LOD the engine asked for.
    pub requested_lod: u32,
    /// The LOD of the BLAS it is traced with (= its record's `lod`).
    pub traced_lod: u32,
    /// Its geometry-data range.
    pub data: Range<u64>,
    /// Whether it waits for a BLAS build.
    pub awaiting_blas: bool,
    /// Whether the scheduler knows it (holds or waits for a BLAS).
    pub scheduled: bool,
}

/// The Manager's column of the slot table ([`crate::slot_table`]): its
/// state of one GPU slot.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct ManagedSlot {
    /// The live instance's state, if any.
    instance: Option<Managed>,
    /// The hits of the last frame whose feedback was seen.
    last_hits: u32,
    /// Listed in `data_dirty`: the geometry-data range changed since the
    /// last plan.
    data_dirty: bool,
}

/// What the Manager alone knows of a live instance (its handle and mesh
/// are the registry's column, its BLAS the scheduler's).
#[derive(Clone, Copy, Debug)]
struct Managed {
    /// The variant of its own static BLAS ([`geometry_of`]).
    own_variant: u32,
    requested_lod: u8,
    traced_lod: u8,
    range: AllocHandle,
}

/// A live instance's manager state as one value, assembled by
/// [`Manager::instance_at`] from its row of the slot table (handle, mesh,
/// [`Managed`]), its flags and the scheduler (a copy: nothing here is
/// stored twice).
#[derive(Clone, Copy, Debug)]
struct Slot {
    handle: InstanceHandle,
    mesh: MeshId,
    geometry: BlasGeometry,
    requested_lod: u8,
    traced_lod: u8,
    range: AllocHandle,
    scheduled: bool,
}

/// The per-frame manager; see the [module docs](self).
#[derive(Debug)]
pub struct Manager<H: HitboxIndex = HitboxGrid> {
    culling: Culling<H>,
    scheduler: BuildScheduler,
    data: TlsfAllocator,
    data_config: DataConfig,
    catalog: MeshCatalog,
    /// Slots whose geometry-data range changed since the last plan.
    data_dirty: Vec<u32>,
    /// The buffer capacity the backend was last told about.
    reported_capacity: u64,
    frame: Option<u64>,
    planned: Option<u64>,
    /// The command loop's BLAS work of the current plan (kept for its
    /// allocation).
    events: Vec<CommandEvent>,
    /// The variant of the next own static BLAS ([`geometry_of`]).
    next_own_variant: u32,
    /// The attached trace recorder ([`recorder`]).
    recorder: Option<Box<TraceRecorder>>,
    /// The closed-loop controller ([`control`]) and the thresholds it
    /// scales (the configured ones).
    controller: Option<ThresholdController>,
    base_thresholds: Thresholds,
    /// The newest counted hits, and whether the controller has not seen
    /// them yet.
    escape: Option<EscapeSample>,
    escape_fresh: bool,
    /// TLAS records of the last [`Manager::assemble`].
    tlas_records: Option<u64>,
    /// CPU backends: the per-slot hits of each frame [`Manager::process_feedback`]
    /// ran, oldest first, until that frame's commands are ingested
    /// ([`Manager::ingest_readback`]): build priorities see a frame's hits
    /// when its commands come back, as on a GPU backend
    /// ([`Manager::record_hits`]). At most [`HELD_HITS_MAX`] frames.
    held_hits: VecDeque<(u64, Vec<u32>)>,
    /// Buffers of held hits whose frame was released or dropped, reused by
    /// the next [`Manager::process_feedback`] (no allocation per frame).
    spare_hits: Vec<Vec<u32>>,
}

/// The most frames of CPU feedback hits held for their read-back (a CPU
/// backend that never ingests keeps only the newest).
const HELD_HITS_MAX: usize = 64;

/// The first variant of an instance's own static BLAS (`UNIQUE_BLAS |
/// STATIC`); variants 0 and 1 are the mesh's shared BLASes.
const OWN_STATIC_VARIANT: u32 = 2;

/// The BLAS an instance uses. `own` is the variant of its own static BLAS
/// (at least [`OWN_STATIC_VARIANT`], one per registration), used only for
/// `UNIQUE_BLAS | STATIC`.
fn geometry_of(mesh: MeshId, flags: InstanceFlags, own: u32) -> BlasGeometry {
    if flags.contains(InstanceFlags::UNIQUE_BLAS) {
        if flags.contains(InstanceFlags::STATIC) {
            // Its own geometry that never moves or deforms (a terrain tile,
            // a terrain-adapted building): built once per LOD, never refit,
            // compactable. A cache key of its own (the variant is unique
            // per registration) so that no other instance shares it.
            BlasGeometry::Shared {
                mesh,
                variant: own.max(OWN_STATIC_VARIANT),
                compactable: true,
            }
        } else {
            // Animated or deformed: refit every frame, rebuilt periodically.
            BlasGeometry::Unique { mesh }
        }
    } else {
        let compactable = flags.contains(InstanceFlags::STATIC);
        // Static and non-static instances of a mesh use different shared
        // BLASes: compaction is a property of the BLAS.
        BlasGeometry::Shared {
            mesh,
            variant: u32::from(compactable),
            compactable,
        }
    }
}

/// A hit count of the order a command priority stands for
/// ([`crate::command::priority_from_hits`] inverted, rounded down).
fn hits_from_priority(priority: u8) -> u32 {
    let p = u32::from(priority.min(124));
    (1u32 << (p / 4)).saturating_sub(1)
}

impl<H: HitboxIndex> Manager<H> {
    /// A manager over the hitbox structure `index`, with the meshes of
    /// `catalog`. Fails for an invalid configuration.
    pub fn new(
        index: H,
        config: ManagerConfig,
        catalog: MeshCatalog,
    ) -> Result<Self, ManagerError> {
        if !config.data.alignment.is_power_of_two() {
            return Err(ManagerError::InvalidConfig {
                what: format!(
                    "data.alignment = {} must be a power of two",
                    config.data.alignment
                ),
            });
        }
        let controller =
            control::controller_of(config.target, config.controller, &config.culling.thresholds)?;
        let culling = Culling::new(index, config.culling)?;
        let scheduler = BuildScheduler::new(config.scheduler)?;
        let data = TlsfAllocator::new(config.data.initial_capacity);
        Ok(Self {
            culling,
            scheduler,
            reported_capacity: data.capacity(),
            data,
            data_config: config.data,
            catalog,
            data_dirty: Vec::new(),
            frame: None,
            planned: None,
            events: Vec::new(),
            next_own_variant: OWN_STATIC_VARIANT,
            recorder: None,
            controller,
            base_thresholds: config.culling.thresholds,
            escape: None,
            escape_fresh: false,
            tlas_records: None,
            held_hits: VecDeque::new(),
            spare_hits: Vec::new(),
        })
    }

    // ---- read access ------------------------------------------------------

    /// The command loop, for lipac-core's own tests; callers outside use the
    /// Manager's queries ([`Manager::memory_usage`],
    /// [`Manager::pending_command`], [`Manager::thresholds`],
    /// [`Manager::culling_config`], [`Manager::hitboxes`]).
    #[cfg(test)]
    pub(crate) fn culling(&self) -> &Culling<H> {
        &self.culling
    }

    /// CPU bytes held by the command loop's containers (registry, the slot
    /// table, hit counters, hitboxes, command buffer and queue, overrides),
    /// from their capacities ([`Culling::memory_usage`],
    /// [`crate::memory`]). The scheduler's and the geometry-data
    /// allocator's share is in [`Manager::stats`].
    pub fn memory_usage(&self) -> MemoryUsage {
        self.culling.memory_usage()
    }

    /// Read-only: the command waiting for processing in GPU slot `slot`, if
    /// any (the newest ingested one per live slot, or one the Manager
    /// queued itself: an unpin, a BLAS that arrived for an inactive
    /// instance). [`Manager::plan`] takes them, highest priority first, up
    /// to [`FrameBudgets::commands`]; [`ManagerStats::commands_pending`]
    /// counts them.
    pub fn pending_command(&self, slot: u32) -> Option<Command> {
        self.culling.pending_command(slot)
    }

    /// The adaptive hitboxes' quadtree ([`crate::hitbox_tree`]), when
    /// [`CullingConfig::adaptive_hitboxes`] is on.
    pub fn hitbox_tree(&self) -> Option<&crate::hitbox_tree::HitboxTree> {
        self.culling.hitbox_tree()
    }

    /// The leaf counting boxes (hitbox index, unit-cube transform) that the
    /// merged counting box of tree node `node` stands for, appended to `out`:
    /// what a CPU tracer counts a hit on a merged box as. Returns `false`
    /// (and appends nothing) when adaptive hitboxes are off; an unknown node
    /// appends nothing.
    pub fn merged_leaf_boxes(&self, node: u32, out: &mut Vec<(u32, [f32; 12])>) -> bool {
        let Some(tree) = self.culling.hitbox_tree() else {
            return false;
        };
        tree.leaf_boxes(
            node,
            self.culling.hitboxes(),
            self.culling.registry().hitbox_index(),
            &self.culling.config().assembly,
            out,
        );
        true
    }

    /// Low-level, read-only: the instance registry (records, slots, dirty
    /// ranges), for inspection.
    pub fn registry(&self) -> &InstanceRegistry<H> {
        self.culling.registry()
    }

    /// Low-level, read-only: the BLAS build scheduler (and through it the
    /// cache), for inspection.
    pub fn scheduler(&self) -> &BuildScheduler {
        &self.scheduler
    }

    /// The command loop's settings: Algorithm 1's constants
    /// ([`CullingConfig::assembly`]), the command buffer's capacity and the
    /// thresholds Algorithm 2 runs with this frame (the controller's, with a
    /// [`ManagerConfig::target`]). What a GPU backend checks and records
    /// its shaders with.
    pub fn culling_config(&self) -> &CullingConfig {
        self.culling.config()
    }

    /// The number of GPU slots (the length of [`Manager::records`] and of
    /// the per-slot hit counters): what a GPU backend sizes its per-slot
    /// tables by.
    pub fn slot_count(&self) -> u32 {
        self.culling.registry().slot_count()
    }

    /// The instance records, indexed by GPU slot: what a GPU backend uploads
    /// the [`ManagerPlan::uploads`] ranges from.
    pub fn records(&self) -> &InstanceArrays {
        self.culling.registry().records()
    }

    /// The hitbox records, indexed by hitbox.
    pub fn hitboxes(&self) -> &[HitboxRecord] {
        self.culling.hitboxes()
    }

    /// The geometry-data allocator.
    pub fn data_allocator(&self) -> &TlsfAllocator {
        &self.data
    }

    /// The mesh catalog.
    pub fn catalog(&self) -> &MeshCatalog {
        &self.catalog
    }

    /// The current frame (`None` before the first [`Manager::begin_frame`]).
    pub fn frame(&self) -> Option<u64> {
        self.frame
    }

    /// One instance: slot, state, BLAS, LODs, data range.
    pub fn instance(&self, handle: InstanceHandle) -> Result<InstanceView, ManagerError> {
        let (slot, s) = self.slot_of(handle)?;
        let record = self.registry().record(handle)?;
        let range = self.data.get(s.range)?;
        Ok(InstanceView {
            slot,
            state: if self.culling.commanded_active(handle)? {
                InstanceState::Active
            } else {
                InstanceState::Inactive
            },
            blas: record.blas,
            requested_lod: s.requested_lod.into(),
            traced_lod: s.traced_lod.into(),
            data: range.range(),
            awaiting_blas: self.culling.awaiting_blas(handle)?,
            scheduled: s.scheduled,
        })
    }

    /// The hitbox records, for the tracer's counting-box hits.
    pub fn hitboxes_mut(&mut self) -> &mut [HitboxRecord] {
        self.culling.hitboxes_mut()
    }

    /// The per-slot hit counters, for the tracer.
    pub fn instance_hits_mut(&mut self) -> &mut [u32] {
        self.culling.instance_hits_mut()
    }

    // ---- meshes and instances -------------------------------------------

    /// Adds a mesh to the catalog ([`MeshCatalog::insert`]).
    pub fn register_mesh(&mut self, mesh: MeshId, lods: Vec<MeshLod>) -> Result<(), ManagerError> {
        self.catalog.insert(mesh, lods)
    }

    /// Reserves room for at least `additional` more instances in the
    /// command loop ([`Culling::reserve`], the slot table with it) and in
    /// the manager's list of changed data ranges, so that registering a
    /// scene of known size allocates each container once.
    ///
    /// An error ([`CoreError::OutOfMemory`](crate::error::CoreError::OutOfMemory))
    /// when the memory cannot be had: at most [`MAX_SLOTS`](crate::layout::MAX_SLOTS)
    /// slots are reserved, about 220 bytes each (`reserve(usize::MAX)` asks
    /// for 2^24 slots, 3.7 GB). What was reserved before the refusal stays
    /// reserved; nothing else changes.
    pub fn reserve(&mut self, additional: usize) -> Result<(), ManagerError> {
        let slots = self.culling.reserve_slots(additional)?;
        let n = additional.min(slots);
        crate::memory::try_reserve(&mut self.data_dirty, n, "changed data ranges")?;
        Ok(())
    }

    /// Registers an instance: inactive, no BLAS, a geometry-data range for
    /// its mesh's LOD `desc.lod`. A [`InstanceFlags::PINNED`] instance is
    /// active at once and its BLAS requested from the scheduler (under the
    /// normal build budgets). Fails, changing nothing but possibly the
    /// buffer's capacity, for a mesh or LOD not in the catalog or an invalid
    /// description.
    pub fn register(&mut self, desc: InstanceDesc) -> Result<InstanceHandle, ManagerError> {
        let bytes = self.catalog.lod(desc.mesh, desc.lod)?.data_bytes;
        let lod = u8::try_from(desc.lod).map_err(|_| ManagerError::Invariant {
            what: format!("catalog accepted LOD {} over 255", desc.lod),
        })?;
        let range = self.allocate(bytes)?;
        let handle = match self.culling.register(desc) {
            Ok(h) => h,
            Err(e) => {
                self.data.free(range)?;
                return Err(e.into());
            }
        };
        let slot = self.culling.registry().slot(handle)?;
        // (`data_dirty` stays: the slot may still be listed.)
        let row = &mut self.culling.table_mut()[slot as usize].managed;
        row.instance = Some(Managed {
            own_variant: self.next_own_variant,
            requested_lod: lod,
            traced_lod: lod,
            range,
        });
        row.last_hits = 0;
        if desc
            .flags
            .contains(InstanceFlags::UNIQUE_BLAS | InstanceFlags::STATIC)
        {
            // Wraps after 2^32 - 2 own static registrations; a reused
            // variant only matters if the old BLAS is still cached then.
            self.next_own_variant = self
                .next_own_variant
                .checked_add(1)
                .unwrap_or(OWN_STATIC_VARIANT);
        }
        self.mark_data(slot);
        if desc.flags.contains(InstanceFlags::PINNED) {
            // Active from registration: its BLAS is requested at once.
            self.activate(slot, 0, false)?;
        }
        self.record(|r| r.on_register(slot, &desc));
        Ok(handle)
    }

    /// Replaces an instance's description and returns the previous one
    /// (with the requested LOD). The mesh and the `UNIQUE_BLAS` / `STATIC`
    /// flags cannot change ([`ManagerError::GeometryChange`]); a new
    /// `desc.lod` is a [`Manager::set_lod`]. Setting
    /// [`InstanceFlags::PINNED`] activates the instance and requests its
    /// BLAS; clearing it hands the instance back to its hitbox (Algorithm
    /// 2's normal rule, from the next feedback on). On error nothing
    /// changes.
    pub fn update(
        &mut self,
        handle: InstanceHandle,
        desc: InstanceDesc,
    ) -> Result<InstanceDesc, ManagerError> {
        let (_, s) = self.slot_of(handle)?;
        if desc.mesh != s.mesh {
            return Err(ManagerError::GeometryChange { what: "the mesh" });
        }
        let own = match s.geometry {
            BlasGeometry::Shared { variant, .. } => variant,
            BlasGeometry::Unique { .. } => OWN_STATIC_VARIANT,
        };
        if geometry_of(desc.mesh, desc.flags, own) != s.geometry {
            return Err(ManagerError::GeometryChange {
                what: "the UNIQUE_BLAS or STATIC flag",
            });
        }
        self.catalog.lod(desc.mesh, desc.lod)?;
        let requested = u32::from(s.requested_lod);
        let mut old = self.culling.update(
            handle,
            InstanceDesc {
                lod: s.traced_lod.into(),
                ..desc
            },
        )?;
        old.lod = requested;
        if desc.flags.contains(InstanceFlags::PINNED) {
            // Pinned now: active (the command loop decided), its BLAS
            // requested unless it is scheduled already.
            let (slot, s) = self.slot_of(handle)?;
            if !s.scheduled {
                let hits = self.last_hits(slot);
                self.activate(slot, hits, self.visible(slot))?;
            }
        }
        if desc.lod != requested {
            self.set_lod(handle, desc.lod)?;
        }
        self.record_slot(handle, |r, slot| r.on_update(slot, &desc, &old));
        Ok(old)
    }

    /// Pins (`true`) or unpins an instance: [`Manager::update`] of its
    /// flags with [`InstanceFlags::PINNED`] set or cleared, everything else
    /// kept. Returns whether it was pinned. With
    /// [`Selection::EngineSelected`](crate::culling::Selection) this is how
    /// an engine chooses its set each frame: pinned = active and traced,
    /// unpinned = inactive at once (its BLAS released in the next plan).
    pub fn set_pinned(
        &mut self,
        handle: InstanceHandle,
        pinned: bool,
    ) -> Result<bool, ManagerError> {
        let (_, s) = self.slot_of(handle)?;
        let mut desc = self.culling.registry().desc(handle)?;
        let was = desc.flags.contains(InstanceFlags::PINNED);
        if was == pinned {
            return Ok(was);
        }
        if pinned {
            desc.flags.insert(InstanceFlags::PINNED);
        } else {
            desc.flags.remove(InstanceFlags::PINNED);
        }
        desc.lod = s.requested_lod.into();
        self.update(handle, desc)?;
        Ok(was)
    }

    /// Moves an instance (new transform and world AABB).
    pub fn set_transform(
        &mut self,
        handle: InstanceHandle,
        transform: Affine3A,
        aabb: Aabb,
    ) -> Result<(), ManagerError> {
        self.culling.set_transform(handle, transform, aabb)?;
        self.record_slot(handle, |r, slot| r.on_pose(slot, &transform, aabb));
        Ok(())
    }

    /// Requests LOD `lod` for an instance and returns the previously
    /// requested one. An instance without a BLAS switches at once (record
    /// and data range); one with a BLAS asks the scheduler, which switches
    /// after its hysteresis and once the new BLAS is built (see the
    /// [module docs](self)). Unknown LOD → [`ManagerError::UnknownLod`],
    /// nothing changed.
    pub fn set_lod(&mut self, handle: InstanceHandle, lod: u32) -> Result<u32, ManagerError> {
        let (slot, s) = self.slot_of(handle)?;
        let estimate = self.catalog.lod(s.mesh, lod)?.estimate;
        let lod8 = u8::try_from(lod).map_err(|_| ManagerError::Invariant {
            what: format!("catalog accepted LOD {lod} over 255"),
        })?;
        let old = s.requested_lod;
        if s.scheduled {
            self.scheduler
                .request_lod(InstanceKey(slot), Lod(lod8), estimate)?;
        }
        if let Some(m) = self.managed_mut(slot) {
            m.requested_lod = lod8;
        }
        self.sync_addresses()?;
        self.sync_lod(slot)?;
        self.record(|r| r.on_lod(slot, lod));
        Ok(old.into())
    }

    /// Removes an instance: its slot is quarantined, its pending command
    /// cancelled, its BLAS released through the scheduler (freed in a later
    /// plan's [`FramePlan::frees`] once no frame in flight uses it, a shared
    /// one stays cached), a pending build cancelled, its data range freed.
    /// Returns the registry's account of it.
    pub fn remove(&mut self, handle: InstanceHandle) -> Result<RemovedInstance, ManagerError> {
        let (slot, s) = self.slot_of(handle)?;
        let removal = self.culling.remove(handle)?;
        let row = &mut self.culling.table_mut()[slot as usize].managed;
        row.instance = None;
        row.last_hits = 0;
        if s.scheduled {
            self.scheduler.deactivate(InstanceKey(slot))?;
        }
        self.data.free(s.range)?;
        self.record(|r| r.on_remove(slot));
        Ok(removal.instance)
    }

    /// Evicts every unreferenced cached BLAS (e.g. at a level change); the
    /// frees follow in later plans. Returns how many were evicted.
    pub fn trim_blas_cache(&mut self) -> usize {
        self.scheduler.trim_cache()
    }

    // ---- the frame --------------------------------------------------------

    /// Starts frame `frame` (strictly after the previous one). Fails,
    /// changing nothing, if frames do not increase or the last frame's
    /// commands were not taken ([`Manager::take_commands`]), or if `frame`
    /// is above [`MAX_FRAME`](crate::blas_cache::MAX_FRAME).
    pub fn begin_frame(&mut self, frame: u64) -> Result<(), ManagerError> {
        if frame > crate::blas_cache::MAX_FRAME {
            let e = crate::blas_cache::BlasError::FrameOutOfRange {
                frame,
                max: crate::blas_cache::MAX_FRAME,
            };
            return Err(crate::build_plan::BuildPlanError::Cache(e).into());
        }
        if let Some(prev) = self.frame {
            if frame <= prev {
                return Err(ManagerError::CallOrder {
                    what: format!("frame {frame} does not follow frame {prev}"),
                });
            }
        }
        self.culling.begin_frame(frame)?;
        self.scheduler.begin_frame(frame)?;
        self.frame = Some(frame);
        self.record_begin(frame);
        Ok(())
    }

    /// Latency mitigation (§3.6, [`Culling::mitigate_latency`]): instances
    /// newly in `frustum` become active now, and their BLASes are requested
    /// from the scheduler at once (in the frustum: high priority). A cached
    /// BLAS is in the record when this returns.
    pub fn mitigate_latency(
        &mut self,
        camera: Vec3,
        frustum: &Frustum,
    ) -> Result<LatencyOutcome, ManagerError> {
        let out = self.culling.mitigate_latency(camera, frustum)?;
        self.take_cpu_activations(out)
    }

    /// A warm start ([`Culling::warm_start`]), at a level load or a camera
    /// cut: every instance in `frustum` (or within the heuristic's
    /// `surround_radius`) that `heuristic` accepts from `camera` becomes
    /// active now, and its BLAS is requested from the scheduler at once (in
    /// the frustum: high priority); hit feedback culls the set down from
    /// this frame's Algorithm 2 on, under the decayed rule only after
    /// [`crate::culling::CullingConfig::warm_start_hold`] frames without a
    /// hit. Call it between
    /// [`Manager::begin_frame`] and [`Manager::plan`], and give that frame's
    /// plan the build budget of a load (the builds of the whole view) if
    /// the view should be traced from this frame on. A cached BLAS is in
    /// the record when this returns.
    pub fn warm_start(
        &mut self,
        camera: Vec3,
        frustum: &Frustum,
        heuristic: ActivationHeuristic,
    ) -> Result<LatencyOutcome, ManagerError> {
        let out = self.culling.warm_start(camera, frustum, heuristic)?;
        self.take_cpu_activations(out)
    }

    /// The BLAS requests of instances the loop activated on the CPU
    /// (latency mitigation, a warm start) handed to the scheduler at once
    /// (in the frustum: high priority), and cached BLASes put in the records.
    fn take_cpu_activations(
        &mut self,
        out: LatencyOutcome,
    ) -> Result<LatencyOutcome, ManagerError> {
        for r in &out.requests {
            let hits = self.last_hits(r.slot);
            self.activate(r.slot, hits, true)?;
        }
        self.sync_addresses()?;
        Ok(out)
    }

    /// Ingests one read-back of commands, the ones Algorithm 2 wrote in
    /// frame `frame`: `counter` is the GPU's atomic counter (it may exceed
    /// `words.len()`: the overflow), `words` the stored command words. The
    /// one entry for CPU backends (a [`Readback`]
    /// of [`Manager::take_commands`] from `readback_latency` frames ago) and
    /// GPU backends (the read-back buffer of frame `frame`): the newest
    /// command per slot sets the Manager's commanded state of that slot
    /// (unless the Manager decided the slot's state itself after `frame`:
    /// registration, latency mitigation) and is queued; commands for slots
    /// without a live instance are dropped ([`Culling::ingest_readback`]).
    /// [`Manager::plan`] reconciles BLAS residency against the commanded
    /// state, never against the records' state bits. Never fails; bad words
    /// are counted.
    ///
    /// On a CPU backend this is also when frame `frame`'s hits (held since
    /// its [`Manager::process_feedback`]) become the build priorities, the
    /// point where a GPU backend hands them over with
    /// [`Manager::record_hits`]: both paths prioritise with the hits of the
    /// newest frame whose commands came back.
    pub fn ingest_readback(&mut self, frame: u64, counter: u32, words: &[u32]) -> IngestSummary {
        let summary = self.culling.ingest_readback(frame, counter, words);
        self.release_held_hits(frame);
        summary
    }

    /// For GPU backends, right after [`Manager::ingest_readback`] of the
    /// same read-back: the per-slot hit counters of that finished frame,
    /// used to prioritise builds. A CPU backend does not call it: its
    /// feedback's hits are held and used at the same point
    /// ([`Manager::ingest_readback`]).
    pub fn record_hits(&mut self, hits: &[u32]) {
        self.set_last_hits(hits);
        self.record_frame_hits(Some(hits));
    }

    /// The build priorities: `hits` per slot (a frame's hit counters).
    fn set_last_hits(&mut self, hits: &[u32]) {
        for (row, &h) in self.culling.table_mut().iter_mut().zip(hits) {
            row.managed.last_hits = h;
        }
    }

    /// CPU backends: the held hits of frame `frame` become the build
    /// priorities; older held frames (never ingested) are dropped.
    fn release_held_hits(&mut self, frame: u64) {
        while self.held_hits.front().is_some_and(|(f, _)| *f < frame) {
            if let Some((_, hits)) = self.held_hits.pop_front() {
                self.spare_hits.push(hits);
            }
        }
        if self.held_hits.front().is_some_and(|(f, _)| *f == frame) {
            if let Some((_, hits)) = self.held_hits.pop_front() {
                self.set_last_hits(&hits);
                self.spare_hits.push(hits);
            }
        }
        self.spare_hits.truncate(HELD_HITS_MAX);
    }

    /// Plans the frame, once per frame after [`Manager::begin_frame`]:
    ///
    /// 1. up to `budgets.commands` pending commands are reconciled: an
    ///    active instance without a BLAS is activated in the scheduler (a
    ///    cached BLAS is assigned at once, else a build is queued), a
    ///    non-active one with a BLAS or a pending build is deactivated;
    /// 2. the last hits and frustum visibility of instances waiting for a
    ///    build become their build priority;
    /// 3. the scheduler plans (due LOD switches, unique updates, budgeted
    ///    batches, compactions, frees);
    /// 4. the uploads, the geometry-data changes and growth are collected;
    /// 5. with a [`ManagerConfig::target`], the controller is fed (memory
    ///    after this plan, the newest escape sample) and the scaled
    ///    thresholds are set for this frame's Algorithm 2 ([`crate::controller`]).
    pub fn plan(&mut self, budgets: &FrameBudgets) -> Result<ManagerPlan, ManagerError> {
        let frame = self.frame.ok_or_else(|| ManagerError::CallOrder {
            what: "plan before the first begin_frame".into(),
        })?;
        if self.planned == Some(frame) {
            return Err(ManagerError::CallOrder {
                what: format!("frame {frame} was already planned"),
            });
        }
        self.planned = Some(frame);

        // 1. Commands: the command loop reconciles, the scheduler follows.
        let mut events = std::mem::take(&mut self.events);
        let mut commands = self.culling.process_commands(budgets.commands, &mut events);
        let result = self.apply_command_events(&events, &mut commands);
        self.events = events;
        result?;

        // 2. Priorities of waiting instances (only those: a scheduler lookup
        // per slot was ~20 % of a steady frame at 100k instances).
        let waiting: Vec<InstanceKey> = self.scheduler.waiting_instances().collect();
        for key in waiting {
            let slot = key.0;
            let Some(row) = self.culling.table().get(slot as usize).map(|r| r.managed) else {
                continue;
            };
            // (waiting_instances lists exactly those with a pending LOD.)
            if row.instance.is_some() && self.scheduler.is_active(key) {
                let visible = self.visible(slot);
                self.scheduler.set_feedback(key, row.last_hits, visible)?;
            }
        }

        // 3. The scheduler.
        let blas = self.scheduler.plan(&budgets.builds)?;
        self.sync_addresses()?;
        // 5. The closed-loop thresholds for this frame's Algorithm 2.
        self.control()?;

        // 4. Uploads.
        let uploads = self.culling.take_uploads();
        let mut data_uploads = Vec::with_capacity(self.data_dirty.len());
        self.data_dirty.sort_unstable();
        for &slot in &self.data_dirty {
            if let Some(row) = self.culling.table_mut().get_mut(slot as usize) {
                row.managed.data_dirty = false;
            }
            let Some(s) = self.instance_at(slot) else {
                continue;
            };
            let a = self.data.get(s.range)?;
            data_uploads.push(DataUpload {
                slot,
                handle: s.handle,
                mesh: s.mesh,
                lod: s.traced_lod.into(),
                offset: a.offset,
                bytes: a.size,
            });
        }
        self.data_dirty.clear();
        let capacity = self.data.capacity();
        let data_growth = (capacity != self.reported_capacity).then_some(DataGrowth {
            from: self.reported_capacity,
            to: capacity,
        });
        self.reported_capacity = capacity;
        self.record(TraceRecorder::on_plan);
        Ok(ManagerPlan {
            frame,
            commands,
            blas,
            uploads,
            data_uploads,
            data_growth,
        })
    }

    /// Takes one acknowledgement from the backend
    /// ([`BuildScheduler::handle_ack`]): the instances waiting for a built or
    /// compacted BLAS get its address in their records before this returns.
    /// An acknowledgement the manager never planned (or one acknowledged
    /// twice) is an error and changes nothing.
    pub fn handle_ack(&mut self, ack: Ack) -> Result<(), ManagerError> {
        self.scheduler.handle_ack(ack)?;
        self.sync_addresses()
    }

    /// Algorithm 1 over the records ([`Culling::assemble`]): this frame's
    /// TLAS instances into `out` (cleared first). For CPU backends; a GPU
    /// backend runs it as a shader over the uploaded records.
    pub fn assemble(&mut self, out: &mut Vec<TlasInstance>) -> Result<AssemblyStats, ManagerError> {
        let stats = self.culling.assemble(out)?;
        self.tlas_records = Some(out.len() as u64);
        Ok(stats)
    }

    /// Algorithm 2 over this frame's hits ([`Culling::process_feedback`]),
    /// for CPU backends. The hits are held until this frame's commands are
    /// ingested ([`Manager::ingest_readback`]), then prioritise builds.
    pub fn process_feedback(&mut self) -> Result<FeedbackStats, ManagerError> {
        self.record_frame_hits(None); // before Algorithm 2 changes states
        let stats = self.culling.process_feedback();
        self.record(|r| r.settle_hits(stats.is_ok())); // a refused call records no hits
        let stats = stats?;
        // Only once Algorithm 2 ran: a refused call changes nothing.
        self.observe_escape(control::escape_sample(&stats));
        let frame = self.culling.frame();
        let mut held = if self.held_hits.len() >= HELD_HITS_MAX {
            self.held_hits.pop_front().map(|(_, v)| v)
        } else {
            self.spare_hits.pop()
        }
        .unwrap_or_default();
        held.clear();
        held.extend_from_slice(self.culling.instance_hits());
        self.held_hits.push_back((frame, held));
        Ok(stats)
    }

    /// The commands of this frame's feedback, for the read-back ring
    /// ([`Culling::take_commands`]).
    pub fn take_commands(&mut self) -> Option<Readback> {
        self.culling.take_commands()
    }

    /// Statistics: memory by category, instances by state, commands and
    /// builds waiting. O(slots).
    pub fn stats(&self) -> ManagerStats {
        let sched = self.scheduler.stats();
        let cache = sched.cache;
        let data = self.data.stats();
        let reg = self.culling.registry();
        let slot_count = u64::from(reg.slot_count());
        let mut inst = InstanceCounts {
            quarantined_slots: reg.quarantined_slots(),
            ..InstanceCounts::default()
        };
        for (handle, slot) in reg.iter() {
            let Some(r) = reg.record_at(slot) else {
                continue;
            };
            inst.live += 1;
            // Active = the commanded state (the same for CPU and GPU
            // backends); omitted is known only where the records carry
            // Algorithm 2's state bits (CPU backends).
            if self.culling.commanded_active(handle).unwrap_or(false) {
                inst.active += 1;
            } else if r.state() == InstanceState::Omitted {
                inst.omitted += 1;
            } else {
                inst.inactive += 1;
            }
            inst.with_blas += usize::from(r.blas != 0);
            inst.awaiting_blas += usize::from(self.culling.awaiting_blas(handle).unwrap_or(false));
            inst.scheduled += usize::from(self.scheduler.is_active(InstanceKey(slot)));
        }
        ManagerStats {
            memory: MemoryStats {
                blas_shared: cache.shared_bytes,
                blas_unique: cache.unique_bytes,
                blas_compacted: cache.compacted_bytes,
                blas_scratch: cache.scratch_in_use,
                blas_pending_free: cache.pending_free_bytes,
                data_capacity: data.capacity,
                data_used: data.used_bytes,
                data_free: data.free_bytes,
                data_largest_free: data.largest_free_block,
                data_fragmentation: data.fragmentation,
                hitbox_bytes: self.culling.hitboxes().len() as u64
                    * std::mem::size_of::<HitboxRecord>() as u64,
                feedback_bytes: slot_count * 4,
                instance_record_bytes: slot_count * crate::layout::INSTANCE_SLOT_BYTES,
            },
            instances: inst,
            commands_pending: self.culling.pending_commands(),
            builds_queued: sched.queued_builds,
            builds_in_flight: sched.in_flight,
            blas_entries: cache.entries,
            blas_pending_frees: cache.pending_frees,
            data_ranges: data.allocation_count,
            data_free_blocks: data.free_block_count,
            controller: self.controller.as_ref().map(|c| c.stats()),
            escape: self.escape,
        }
    }

    // ---- internals ----------------------------------------------------

    fn slot_of(&self, handle: InstanceHandle) -> Result<(u32, Slot), ManagerError> {
        let slot = self.culling.registry().slot(handle)?;
        match self.instance_at(slot) {
            Some(s) if s.handle == handle => Ok((slot, s)),
            _ => Err(ManagerError::Invariant {
                what: format!("live instance in slot {slot} has no manager record"),
            }),
        }
    }

    fn visible(&self, slot: u32) -> bool {
        self.culling
            .latency_mitigation()
            .is_some_and(|lm| lm.was_visible(slot))
    }

    /// The live instance in `slot`, if any, assembled from the slot table
    /// (see [`Slot`]).
    fn instance_at(&self, slot: u32) -> Option<Slot> {
        let registry = self.culling.registry();
        let row = registry.table().get(slot as usize)?;
        let m = row.managed.instance?;
        let handle = registry.handle_at(slot)?;
        let mesh = row.occupant.mesh();
        let flags = registry.flags(handle).ok()?;
        Some(Slot {
            handle,
            mesh,
            geometry: geometry_of(mesh, flags, m.own_variant),
            requested_lod: m.requested_lod,
            traced_lod: m.traced_lod,
            range: m.range,
            scheduled: self.scheduler.is_active(InstanceKey(slot)),
        })
    }

    /// The Manager's state of the live instance in `slot`, for writing.
    fn managed_mut(&mut self, slot: u32) -> Option<&mut Managed> {
        self.culling
            .table_mut()
            .get_mut(slot as usize)?
            .managed
            .instance
            .as_mut()
    }

    /// The hits of `slot` in the last frame whose feedback was seen.
    fn last_hits(&self, slot: u32) -> u32 {
        self.culling
            .table()
            .get(slot as usize)
            .map_or(0, |r| r.managed.last_hits)
    }

    fn mark_data(&mut self, slot: u32) {
        if !std::mem::replace(
            &mut self.culling.table_mut()[slot as usize].managed.data_dirty,
            true,
        ) {
            self.data_dirty.push(slot);
        }
    }

    /// Carries out the command loop's BLAS work in the scheduler: an acquire
    /// activates the slot (a cached BLAS reaches the record at once, counted
    /// in [`ProcessStats::acquired`]), a release or a cancelled build
    /// deactivates it. All events are applied; the first error is returned.
    fn apply_command_events(
        &mut self,
        events: &[CommandEvent],
        stats: &mut ProcessStats,
    ) -> Result<(), ManagerError> {
        let mut result = Ok(());
        for e in events {
            let r = match e.action {
                BlasAction::Acquire => {
                    let last = self.last_hits(e.slot);
                    let hits = last.max(hits_from_priority(e.priority));
                    let visible = self.visible(e.slot);
                    self.activate(e.slot, hits, visible).map(|()| {
                        if self.culling.awaiting_blas(e.handle) == Ok(false) {
                            stats.acquired += 1;
                            stats.requested = stats.requested.saturating_sub(1);
                        }
                    })
                }
                BlasAction::Release { .. } | BlasAction::CancelBuild => self.deactivate(e.slot),
            };
            if r.is_err() && result.is_ok() {
                result = r;
            }
        }
        result
    }

    /// Allocates a data range, growing the buffer (at least doubling) when
    /// the allocator asks for it.
    fn allocate(&mut self, bytes: u64) -> Result<AllocHandle, ManagerError> {
        let align = self.data_config.alignment;
        match self.data.allocate_aligned(bytes, align) {
            Ok(a) => Ok(a.handle),
            Err(e) => {
                let Some(required) = e.required_capacity() else {
                    return Err(e.into());
                };
                let doubled = self.data.capacity().saturating_mul(2);
                self.data.grow(required.max(doubled))?;
                Ok(self.data.allocate_aligned(bytes, align)?.handle)
            }
        }
    }

    /// Activates `slot` in the scheduler at its requested LOD (no-op if it
    /// is already known); a cached BLAS goes into the record at once.
    fn activate(&mut self, slot: u32, hits: u32, in_frustum: bool) -> Result<(), ManagerError> {
        let Some(s) = self.instance_at(slot) else {
            return Err(ManagerError::Invariant {
                what: format!("BLAS requested for slot {slot} without an instance"),
            });
        };
        let key = InstanceKey(slot);
        if !s.scheduled {
            let estimate = self.catalog.lod(s.mesh, s.requested_lod.into())?.estimate;
            self.scheduler.activate(
                key,
                InstanceBlasRequest {
                    geometry: s.geometry,
                    lod: Lod(s.requested_lod),
                    estimate,
                    hits,
                    in_frustum,
                },
            )?;
        }
        if let Some(address) = self.scheduler.blas_address(key) {
            self.culling.set_blas(s.handle, address)?;
        }
        self.sync_lod(slot)
    }

    /// Takes `slot` out of the scheduler (its record's BLAS was cleared or
    /// its build is no longer wanted).
    fn deactivate(&mut self, slot: u32) -> Result<(), ManagerError> {
        if self.managed_mut(slot).is_none() {
            return Ok(());
        }
        let key = InstanceKey(slot);
        if self.scheduler.is_active(key) {
            self.scheduler.deactivate(key)?;
        }
        self.sync_lod(slot)
    }

    /// Writes the scheduler's address changes into the records.
    fn sync_addresses(&mut self) -> Result<(), ManagerError> {
        for key in self.scheduler.take_address_changes() {
            let slot = key.0;
            let Some(s) = self.instance_at(slot) else {
                return Err(ManagerError::Invariant {
                    what: format!("BLAS address change for empty slot {slot}"),
                });
            };
            if let Some(address) = self.scheduler.blas_address(key) {
                self.culling.set_blas(s.handle, address)?;
            }
            self.sync_lod(slot)?;
        }
        Ok(())
    }

    /// Makes the record's LOD and the data range follow the traced LOD.
    fn sync_lod(&mut self, slot: u32) -> Result<(), ManagerError> {
        let Some(s) = self.instance_at(slot) else {
            return Ok(());
        };
        let traced = if s.scheduled {
            self.scheduler
                .current_lod(InstanceKey(slot))
                .map_or(s.requested_lod, |l| l.0)
        } else {
            s.requested_lod
        };
        if traced == s.traced_lod {
            return Ok(());
        }
        let bytes = self.catalog.lod(s.mesh, traced.into())?.data_bytes;
        let range = match self.data.resize(s.range, bytes) {
            Ok(a) => a.handle,
            Err(AllocError::CannotGrowInPlace { .. }) => {
                let new = self.allocate(bytes)?;
                self.data.free(s.range)?;
                new
            }
            Err(e) => return Err(e.into()),
        };
        let desc = InstanceDesc {
            lod: traced.into(),
            ..self.culling.registry().desc(s.handle)?
        };
        self.culling.update(s.handle, desc)?;
        if let Some(m) = self.managed_mut(slot) {
            m.traced_lod = traced;
            m.range = range;
        }
        self.mark_data(slot);
        Ok(())
    }
}

#[cfg(test)]
mod tests;
