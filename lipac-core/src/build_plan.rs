//! BLAS build scheduler: turns per-instance BLAS needs into per-frame,
//! budgeted [`BuildBatch`]es (thesis §3.3.1: batching, compaction, unique
//! BLAS updates, budgeted LOD switches).
//!
//! **Low-level**: [`crate::Manager`] owns a [`BuildScheduler`] and drives it;
//! its plan reaches the backend as [`crate::ManagerPlan::blas`] and the
//! acknowledgements go back through [`crate::Manager::handle_ack`].
//!
//! Sans-IO: [`BuildScheduler::plan`] hands out a [`FramePlan`]; the backend
//! records it and reports back, frames later, with
//! [`BuildScheduler::ack_built`], [`BuildScheduler::ack_compacted_size`] and
//! [`BuildScheduler::ack_compacted`]. Nothing ever waits for the GPU.
//!
//! # Per-frame loop
//!
//! ```text
//! begin_frame(f)                       frees that no frame in flight can use
//! activate / deactivate / request_lod / set_feedback
//! plan(&budgets) -> FramePlan          batches (builds + updates), compactions, frees
//! ack_built / ack_compacted_size / ack_compacted     (whenever they arrive)
//! take_address_changes(), blas_address(inst)         for TLAS instance records
//! ```
//!
//! # What a caller must know
//!
//! * A [`BuildBatch`] is recorded without barriers inside and one barrier
//!   after it; each operation has its own non-overlapping slice of one
//!   scratch buffer, and the batches of a frame reuse that buffer.
//! * Builds are taken by priority until the first that does not fit the
//!   frame's [`BuildBudgets`]; one that fits no frame is in
//!   [`FramePlan::oversized`], one the memory budget refuses in
//!   [`FramePlan::memory_blocked`] (retried). Ageing makes every request win
//!   eventually.
//! * An instance keeps its old, valid BLAS until its new one (LOD switch,
//!   compaction) is acknowledged.
//!
//! Policies (batches, budgets, priority with ageing, unique refit/rebuild,
//! LOD switches, compaction) and why: `docs/BLAS.md`.
//!
//! ```
//! use lipac_core::blas_ids::{InstanceKey, Lod};
//! use lipac_core::MeshId;
//! use lipac_core::build_plan::*;
//!
//! let mut s = BuildScheduler::new(SchedulerConfig::default())?;
//! s.begin_frame(1)?;
//! let estimate = BuildEstimate { primitives: 1000, result_bytes: 64 << 10,
//!                                build_scratch_bytes: 32 << 10, update_scratch_bytes: 0 };
//! s.activate(InstanceKey(5), InstanceBlasRequest {
//!     geometry: BlasGeometry::Shared { mesh: MeshId(1), variant: 0, compactable: true },
//!     lod: Lod(0), estimate, hits: 0, in_frustum: true,
//! })?;
//! let plan = s.plan(&BuildBudgets::default())?;
//! let build = plan.builds().next().unwrap();
//! assert_eq!(s.blas_address(InstanceKey(5)), None); // not built yet
//! s.ack_built(build.id, 60 << 10, 0xB000)?;          // frames later
//! assert_eq!(s.blas_address(InstanceKey(5)), Some(0xB000));
//! assert_eq!(s.take_address_changes(), vec![InstanceKey(5)]);
//! # Ok::<(), BuildPlanError>(())
//! ```

use std::collections::{BTreeSet, HashMap};
use std::fmt;

use crate::blas_cache::{
    BlasCache, BlasError, BlasFree, BlasOwner, BlasState, CacheConfig, CacheStats, MAX_BLAS_BYTES,
};
use crate::blas_ids::{BlasId, BlasKey, BuildId, InstanceKey, Lod, MeshId};
use crate::manager::Ack;

/// Priority weights (see `docs/BLAS.md`, "Priority with ageing").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PriorityConfig {
    /// Hit counts above this count as this.
    pub hit_cap: u32,
    /// Added when a waiting instance is in the view frustum.
    pub frustum_bonus: u64,
    /// Added per frame waited.
    pub ageing_per_frame: u64,
    /// Added when a waiting instance has no BLAS yet: until this build is
    /// done it is not traced at all, while an instance waiting for a LOD
    /// switch is traced with its current BLAS meanwhile.
    pub first_build_bonus: u64,
}

impl Default for PriorityConfig {
    /// `hit_cap` 100 000, `frustum_bonus` 100 000, `ageing_per_frame` 10 000,
    /// `first_build_bonus` 200 000: a first build outranks every LOD switch
    /// up to 20 frames older, and any request outranks every newer one after
    /// at most 41 frames.
    fn default() -> Self {
        Self {
            hit_cap: 100_000,
            frustum_bonus: 100_000,
            ageing_per_frame: 10_000,
            first_build_bonus: 200_000,
        }
    }
}

/// Configuration of a [`BuildScheduler`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SchedulerConfig {
    /// The BLAS cache (memory budget, frames in flight, age eviction).
    pub cache: CacheConfig,
    /// Scratch slice offset alignment, a power of two
    /// (`minAccelerationStructureScratchOffsetAlignment`, e.g. 128).
    pub scratch_alignment: u64,
    /// Unique BLASes are rebuilt every this many frames (≥ 1) and refit otherwise.
    pub unique_rebuild_interval: u32,
    /// Frames a requested LOD must persist before a switch.
    pub lod_hysteresis_frames: u32,
    /// Priority weights.
    pub priority: PriorityConfig,
}

impl Default for SchedulerConfig {
    fn default() -> Self {
        Self {
            cache: CacheConfig::default(),
            scratch_alignment: 128,
            unique_rebuild_interval: 16,
            lod_hysteresis_frames: 16,
            priority: PriorityConfig::default(),
        }
    }
}

/// Per-frame budgets of [`BuildScheduler::plan`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BuildBudgets {
    /// Full builds per frame (new BLASes and unique rebuilds).
    pub max_builds: u32,
    /// Primitives of those builds per frame.
    pub max_primitives: u64,
    /// Estimated result bytes of new BLASes per frame.
    pub max_result_bytes: u64,
    /// Size of the scratch buffer one batch uses.
    pub max_scratch_bytes: u64,
    /// Batches per frame (each reuses the scratch buffer after a barrier).
    pub max_batches: u32,
    /// Compaction copies per frame.
    pub max_compactions: u32,
}

impl Default for BuildBudgets {
    /// 64 builds, 4 Mi primitives, 256 MiB results, 128 MiB scratch, one
    /// batch, 64 compactions.
    fn default() -> Self {
        Self {
            max_builds: 64,
            max_primitives: 4 << 20,
            max_result_bytes: 256 << 20,
            max_scratch_bytes: 128 << 20,
            max_batches: 1,
            max_compactions: 64,
        }
    }
}

/// Sizes of one BLAS build, from the caller's build-sizes query.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BuildEstimate {
    /// Primitives (triangles or AABBs).
    pub primitives: u64,
    /// Result size (`accelerationStructureSize`), in
    /// `1..=`[`MAX_BLAS_BYTES`].
    pub result_bytes: u64,
    /// Scratch for a full build (`buildScratchSize`), at most
    /// [`MAX_BLAS_BYTES`].
    pub build_scratch_bytes: u64,
    /// Scratch for a refit (`updateScratchSize`; unique BLASes only), at
    /// most [`MAX_BLAS_BYTES`].
    pub update_scratch_bytes: u64,
}

/// What kind of BLAS an instance uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlasGeometry {
    /// A BLAS shared by all instances of `(mesh, lod, variant)`.
    Shared {
        /// Source mesh.
        mesh: MeshId,
        /// Geometry variant (see [`BlasKey::variant`]).
        variant: u32,
        /// Static geometry: compact after building.
        compactable: bool,
    },
    /// A BLAS of this instance alone (animated / deformed), refit every
    /// frame and rebuilt periodically; never compacted.
    Unique {
        /// Source mesh.
        mesh: MeshId,
    },
}

/// An instance's need for a BLAS ([`BuildScheduler::activate`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InstanceBlasRequest {
    /// Shared or unique, and which mesh.
    pub geometry: BlasGeometry,
    /// Level of detail.
    pub lod: Lod,
    /// Build sizes at that LOD.
    pub estimate: BuildEstimate,
    /// Hit feedback (priority).
    pub hits: u32,
    /// Whether the instance is in the view frustum (priority).
    pub in_frustum: bool,
}

/// A slice of the scratch buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ScratchSlice {
    /// Byte offset (aligned).
    pub offset: u64,
    /// Byte size.
    pub size: u64,
}

impl ScratchSlice {
    /// One past the last byte.
    pub fn end(&self) -> u64 {
        self.offset + self.size
    }
}

/// A full build of a new BLAS.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BlasBuild {
    /// Operation id to quote in [`BuildScheduler::ack_built`].
    pub id: BuildId,
    /// The cache entry.
    pub blas: BlasId,
    /// Owner and geometry (mesh, LOD, variant or instance).
    pub owner: BlasOwner,
    /// Primitives.
    pub primitives: u64,
    /// Reserved result size (the estimate).
    pub result_bytes: u64,
    /// Scratch slice.
    pub scratch: ScratchSlice,
    /// Build with `ALLOW_COMPACTION` and query the compacted size afterwards.
    pub allow_compaction: bool,
    /// Build with `ALLOW_UPDATE` (unique BLASes).
    pub allow_update: bool,
}

/// How a unique BLAS is updated in place.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpdateMode {
    /// `BUILD_MODE_UPDATE` (refit).
    Refit,
    /// Full build into the same acceleration structure.
    Rebuild,
}

/// An in-place update of a unique BLAS (no acknowledgement needed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BlasUpdate {
    /// The cache entry.
    pub blas: BlasId,
    /// The instance whose geometry it holds.
    pub instance: InstanceKey,
    /// Its address (unchanged by the update).
    pub address: u64,
    /// Refit or rebuild.
    pub mode: UpdateMode,
    /// Primitives.
    pub primitives: u64,
    /// Scratch slice.
    pub scratch: ScratchSlice,
}

/// Operations recorded back to back without barriers, then one barrier.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BuildBatch {
    /// In-place updates of unique BLASes.
    pub updates: Vec<BlasUpdate>,
    /// Builds of new BLASes.
    pub builds: Vec<BlasBuild>,
    /// Scratch bytes this batch needs (end of its last slice).
    pub scratch_bytes: u64,
}

/// A compaction copy for the backend to record
/// (`vkCmdCopyAccelerationStructureKHR` with mode `COMPACT`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CompactionPlan {
    /// Operation id to quote in [`BuildScheduler::ack_compacted`].
    pub id: BuildId,
    /// The cache entry.
    pub blas: BlasId,
    /// The build whose acceleration structure is the source.
    pub source_build: BuildId,
    /// Address of the source.
    pub src_address: u64,
    /// Size to allocate for the copy.
    pub compacted_bytes: u64,
}

/// Everything the backend does for one frame.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FramePlan {
    /// The frame.
    pub frame: u64,
    /// Build batches, in recording order.
    pub batches: Vec<BuildBatch>,
    /// Compaction copies (after the batches).
    pub compactions: Vec<CompactionPlan>,
    /// Acceleration structures to destroy now.
    pub frees: Vec<BlasFree>,
    /// Queued builds larger than a whole frame's budgets (never built until
    /// the budgets grow).
    pub oversized: Vec<BlasId>,
    /// Queued builds the memory budget refused this frame.
    pub memory_blocked: Vec<BlasId>,
    /// Unique BLASes whose refit did not fit this frame's scratch.
    pub skipped_updates: Vec<InstanceKey>,
}

impl FramePlan {
    /// All builds of all batches.
    pub fn builds(&self) -> impl Iterator<Item = &BlasBuild> {
        self.batches.iter().flat_map(|b| b.builds.iter())
    }
    /// All updates of all batches.
    pub fn updates(&self) -> impl Iterator<Item = &BlasUpdate> {
        self.batches.iter().flat_map(|b| b.updates.iter())
    }
}

/// Scheduler counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SchedulerStats {
    /// The cache's statistics; its pending frees also count those due and
    /// held for the next [`BuildScheduler::plan`].
    pub cache: CacheStats,
    /// Builds waiting to be handed out.
    pub queued_builds: usize,
    /// Builds and compactions handed out and not yet acknowledged.
    pub in_flight: usize,
    /// Active instances.
    pub instances: usize,
    /// LOD switches done instantly (target cached).
    pub instant_switches: u64,
    /// LOD switches completed by a build acknowledgement.
    pub built_switches: u64,
}

/// Errors of the scheduler.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BuildPlanError {
    /// A configuration value is out of range.
    InvalidConfig(&'static str),
    /// `activate` of an instance that is already active.
    AlreadyActive(InstanceKey),
    /// The instance is not active.
    UnknownInstance(InstanceKey),
    /// `activate` of a key at or above [`MAX_SLOTS`](crate::layout::MAX_SLOTS):
    /// keys are GPU slots (the scheduler's table is dense by key).
    KeyOutOfRange(InstanceKey),
    /// `plan` before the first `begin_frame`.
    FrameNotStarted,
    /// `plan` twice in one frame.
    PlanAlreadyIssued(u64),
    /// A build estimate is unusable.
    InvalidEstimate(&'static str),
    /// From the cache (stale handles, unknown acknowledgements, ...).
    Cache(BlasError),
}

impl fmt::Display for BuildPlanError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BuildPlanError::InvalidConfig(w) => write!(f, "invalid scheduler configuration: {w}"),
            BuildPlanError::AlreadyActive(i) => write!(f, "instance {} is already active", i.0),
            BuildPlanError::UnknownInstance(i) => write!(f, "instance {} is not active", i.0),
            BuildPlanError::KeyOutOfRange(i) => write!(
                f,
                "instance key {} is not a GPU slot (keys are below {})",
                i.0,
                crate::layout::MAX_SLOTS
            ),
            BuildPlanError::FrameNotStarted => write!(f, "plan() before begin_frame()"),
            BuildPlanError::PlanAlreadyIssued(fr) => write!(f, "frame {fr} was already planned"),
            BuildPlanError::InvalidEstimate(w) => write!(f, "invalid build estimate: {w}"),
            BuildPlanError::Cache(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for BuildPlanError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            BuildPlanError::Cache(e) => Some(e),
            _ => None,
        }
    }
}

impl From<BlasError> for BuildPlanError {
    fn from(e: BlasError) -> Self {
        BuildPlanError::Cache(e)
    }
}

#[derive(Clone, Copy, Debug)]
struct Held {
    blas: BlasId,
    lod: Lod,
    estimate: BuildEstimate,
}

#[derive(Clone, Copy, Debug)]
struct Desired {
    lod: Lod,
    estimate: BuildEstimate,
    since: u64,
}

#[derive(Clone, Debug)]
struct Slot {
    geometry: BlasGeometry,
    current: Option<Held>,
    pending: Option<Held>,
    desired: Option<Desired>,
    hits: u32,
    in_frustum: bool,
    rebuild_overdue: bool,
    last_update: u64,
}

#[derive(Clone, Copy, Debug)]
struct Queued {
    since: u64,
    estimate: BuildEstimate,
}

/// Packs scratch slices into batches.
struct ScratchPacker {
    align: u64,
    cap: u64,
    max_batches: usize,
    batches: Vec<BuildBatch>,
}

impl ScratchPacker {
    fn slot(&self, size: u64) -> Option<(bool, u64)> {
        if let Some(last) = self.batches.last() {
            let off = last.scratch_bytes.checked_next_multiple_of(self.align)?;
            if off.checked_add(size).is_some_and(|end| end <= self.cap) {
                return Some((false, off));
            }
        }
        (self.batches.len() < self.max_batches && size <= self.cap).then_some((true, 0))
    }
    fn place(&mut self, size: u64) -> Option<(&mut BuildBatch, ScratchSlice)> {
        let (new, offset) = self.slot(size)?;
        if new {
            self.batches.push(BuildBatch::default());
        }
        let batch = self.batches.last_mut()?;
        batch.scratch_bytes = offset + size;
        Some((batch, ScratchSlice { offset, size }))
    }
}

/// The BLAS build scheduler; owns the [`BlasCache`]. See the module docs;
/// its policies are in `docs/BLAS.md`.
#[derive(Debug)]
pub struct BuildScheduler {
    config: SchedulerConfig,
    cache: BlasCache,
    started: bool,
    planned: Option<u64>,
    next_op: u64,
    /// The active instances' BLAS state ([`instances`]: dense by key).
    slots: Instances<Slot>,
    /// Requested entries waiting for a build.
    queue: HashMap<BlasId, Queued>,
    /// Instances whose pending BLAS is the key.
    waiters: HashMap<BlasId, BTreeSet<InstanceKey>>,
    /// Instances whose current BLAS is the key.
    holders: HashMap<BlasId, BTreeSet<InstanceKey>>,
    frees: Vec<BlasFree>,
    address_changes: BTreeSet<InstanceKey>,
    instant_switches: u64,
    built_switches: u64,
}

fn validate(e: &BuildEstimate) -> Result<(), BuildPlanError> {
    if e.result_bytes == 0 {
        return Err(BuildPlanError::InvalidEstimate("result_bytes must be > 0"));
    }
    if e.result_bytes
        .max(e.build_scratch_bytes)
        .max(e.update_scratch_bytes)
        > MAX_BLAS_BYTES
    {
        return Err(BuildPlanError::InvalidEstimate(
            "result and scratch sizes must be at most MAX_BLAS_BYTES",
        ));
    }
    Ok(())
}

impl BuildScheduler {
    /// Creates a scheduler with an empty cache.
    pub fn new(config: SchedulerConfig) -> Result<Self, BuildPlanError> {
        if !config.scratch_alignment.is_power_of_two() {
            return Err(BuildPlanError::InvalidConfig(
                "scratch_alignment must be a power of two",
            ));
        }
        if config.unique_rebuild_interval == 0 {
            return Err(BuildPlanError::InvalidConfig(
                "unique_rebuild_interval must be >= 1",
            ));
        }
        Ok(Self {
            cache: BlasCache::new(config.cache)?,
            config,
            started: false,
            planned: None,
            next_op: 1,
            slots: Instances::default(),
            queue: HashMap::new(),
            waiters: HashMap::new(),
            holders: HashMap::new(),
            frees: Vec::new(),
            address_changes: BTreeSet::new(),
            instant_switches: 0,
            built_switches: 0,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SchedulerConfig {
        &self.config
    }

    /// The cache (read-only).
    pub fn cache(&self) -> &BlasCache {
        &self.cache
    }

    /// The current frame.
    pub fn frame(&self) -> u64 {
        self.cache.frame()
    }

    /// Starts frame `frame` (strictly increasing). Frees that became safe are
    /// returned by this frame's [`BuildScheduler::plan`].
    pub fn begin_frame(&mut self, frame: u64) -> Result<(), BuildPlanError> {
        let frees = self.cache.begin_frame(frame)?;
        self.frees.extend(frees);
        self.started = true;
        Ok(())
    }

    /// An instance becomes active and needs a BLAS. A shared BLAS that is
    /// cached and built is assigned at once; otherwise a build is queued
    /// (the instance has no BLAS until it is acknowledged). Keys are GPU
    /// slots: one at or above [`MAX_SLOTS`](crate::layout::MAX_SLOTS) is
    /// [`BuildPlanError::KeyOutOfRange`].
    pub fn activate(
        &mut self,
        instance: InstanceKey,
        request: InstanceBlasRequest,
    ) -> Result<(), BuildPlanError> {
        validate(&request.estimate)?;
        if !Instances::<Slot>::in_range(instance) {
            return Err(BuildPlanError::KeyOutOfRange(instance));
        }
        if self.slots.contains_key(&instance) {
            return Err(BuildPlanError::AlreadyActive(instance));
        }
        self.slots.insert(
            instance,
            Slot {
                geometry: request.geometry,
                current: None,
                pending: None,
                desired: None,
                hits: request.hits,
                in_frustum: request.in_frustum,
                rebuild_overdue: false,
                last_update: self.cache.frame(),
            },
        );
        if let Err(e) = self.assign(instance, request.lod, request.estimate) {
            self.slots.remove(&instance);
            return Err(e);
        }
        Ok(())
    }

    /// The instance is no longer active: its BLASes (current and pending) are
    /// released (a unique one is freed after the frames in flight; a shared
    /// one stays cached).
    pub fn deactivate(&mut self, instance: InstanceKey) -> Result<(), BuildPlanError> {
        let slot = self
            .slots
            .remove(&instance)
            .ok_or(BuildPlanError::UnknownInstance(instance))?;
        if let Some(cur) = slot.current {
            self.unhold(instance, cur.blas)?;
        }
        if let Some(p) = slot.pending {
            self.cancel_pending(instance, p.blas)?;
        }
        self.address_changes.remove(&instance);
        Ok(())
    }

    /// Updates the hit feedback and frustum flag that prioritise the
    /// instance's builds.
    pub fn set_feedback(
        &mut self,
        instance: InstanceKey,
        hits: u32,
        in_frustum: bool,
    ) -> Result<(), BuildPlanError> {
        let slot = self
            .slots
            .get_mut(&instance)
            .ok_or(BuildPlanError::UnknownInstance(instance))?;
        slot.hits = hits;
        slot.in_frustum = in_frustum;
        Ok(())
    }

    /// Requests LOD `lod` (with its build sizes) for an active instance.
    /// Call it every frame or only on change: the hysteresis timer starts
    /// when the requested LOD changes. Before the instance's first BLAS is
    /// built, the request replaces the pending one at once.
    pub fn request_lod(
        &mut self,
        instance: InstanceKey,
        lod: Lod,
        estimate: BuildEstimate,
    ) -> Result<(), BuildPlanError> {
        validate(&estimate)?;
        let frame = self.cache.frame();
        let slot = self
            .slots
            .get(&instance)
            .ok_or(BuildPlanError::UnknownInstance(instance))?;
        let Some(current) = slot.current else {
            // First assignment: no hysteresis.
            if slot.pending.map(|p| p.lod) != Some(lod) {
                if let Some(p) = slot.pending {
                    self.cancel_pending(instance, p.blas)?;
                }
                self.slot_mut(instance)?.pending = None;
                self.assign(instance, lod, estimate)?;
            }
            return Ok(());
        };
        let pending = slot.pending;
        if lod == current.lod {
            if let Some(p) = pending {
                self.cancel_pending(instance, p.blas)?;
            }
            let slot = self.slot_mut(instance)?;
            slot.pending = None;
            slot.desired = None;
            return Ok(());
        }
        let slot = self.slot_mut(instance)?;
        if pending.map(|p| p.lod) == Some(lod) {
            slot.desired = None;
            return Ok(());
        }
        match &mut slot.desired {
            Some(d) if d.lod == lod => d.estimate = estimate,
            _ => {
                slot.desired = Some(Desired {
                    lod,
                    estimate,
                    since: frame,
                })
            }
        }
        Ok(())
    }

    /// Plans this frame: due LOD switches, unique BLAS updates, budgeted build
    /// batches, compactions and the frees that became safe. Once per frame.
    pub fn plan(&mut self, budgets: &BuildBudgets) -> Result<FramePlan, BuildPlanError> {
        if !self.started {
            return Err(BuildPlanError::FrameNotStarted);
        }
        let frame = self.cache.frame();
        if self.planned == Some(frame) {
            return Err(BuildPlanError::PlanAlreadyIssued(frame));
        }
        self.planned = Some(frame);
        let mut plan = FramePlan {
            frame,
            frees: std::mem::take(&mut self.frees),
            ..FramePlan::default()
        };
        self.process_lod_switches(false)?;

        let mut packer = ScratchPacker {
            align: self.config.scratch_alignment,
            cap: budgets.max_scratch_bytes,
            max_batches: budgets.max_batches as usize,
            batches: Vec::new(),
        };
        let mut builds = 0u32;
        let mut prims = 0u64;
        let mut result = 0u64;

        // 1. Unique BLAS updates (refit every frame, periodic rebuild).
        let interval = u64::from(self.config.unique_rebuild_interval);
        let mut uniques: Vec<(u64, InstanceKey, Held, u64)> = self
            .slots
            .iter()
            .filter(|(_, s)| matches!(s.geometry, BlasGeometry::Unique { .. }))
            .filter_map(|(&k, s)| {
                let cur = s.current?;
                let address = self.cache.address(cur.blas)?;
                Some((s.last_update, k, cur, address))
            })
            .collect();
        uniques.sort_by_key(|&(last, k, _, _)| (last, k));
        for (_, inst, cur, address) in uniques {
            let overdue = self.slots.get(&inst).is_some_and(|s| s.rebuild_overdue);
            // Exact: frames are at most MAX_FRAME = 2^63 - 1.
            let due = overdue || (frame + u64::from(inst.0)) % interval == 0;
            let e = cur.estimate;
            let mut mode = None;
            if due {
                let fits = builds < budgets.max_builds
                    && prims.saturating_add(e.primitives) <= budgets.max_primitives
                    && packer.slot(e.build_scratch_bytes).is_some();
                if fits {
                    mode = Some((UpdateMode::Rebuild, e.build_scratch_bytes));
                    builds += 1;
                    prims += e.primitives;
                }
            }
            let mode = mode.unwrap_or((UpdateMode::Refit, e.update_scratch_bytes));
            let placed = packer.place(mode.1).map(|(batch, scratch)| {
                batch.updates.push(BlasUpdate {
                    blas: cur.blas,
                    instance: inst,
                    address,
                    mode: mode.0,
                    primitives: e.primitives,
                    scratch,
                });
            });
            let slot = self.slot_mut(inst)?;
            if placed.is_some() {
                slot.last_update = frame;
                slot.rebuild_overdue = due && mode.0 == UpdateMode::Refit;
            } else {
                slot.rebuild_overdue |= due;
                plan.skipped_updates.push(inst);
            }
        }

        // 2. Queued builds by priority.
        let mut candidates: Vec<(u64, u64, BlasId, BuildEstimate)> = self
            .queue
            .iter()
            .map(|(&id, q)| (self.priority(id, q), q.since, id, q.estimate))
            .collect();
        candidates.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        let empty_fits = |e: &BuildEstimate| {
            budgets.max_builds > 0
                && budgets.max_batches > 0
                && e.primitives <= budgets.max_primitives
                && e.result_bytes <= budgets.max_result_bytes
                && e.build_scratch_bytes <= budgets.max_scratch_bytes
        };
        let mut full = false;
        for (_, _, id, e) in candidates {
            if !empty_fits(&e) {
                plan.oversized.push(id);
                continue;
            }
            if full {
                continue;
            }
            let fits = builds < budgets.max_builds
                && prims.saturating_add(e.primitives) <= budgets.max_primitives
                && result.saturating_add(e.result_bytes) <= budgets.max_result_bytes
                && packer.slot(e.build_scratch_bytes).is_some();
            if !fits {
                // Stop filling (but keep reporting oversized requests): the
                // head of the queue gets the next frame's budget first.
                full = true;
                continue;
            }
            let op = BuildId(self.next_op);
            if !self
                .cache
                .try_reserve_build(id, e.result_bytes, e.build_scratch_bytes, op)?
            {
                plan.memory_blocked.push(id);
                continue;
            }
            self.next_op += 1;
            let Some(info) = self.cache.get(id) else {
                continue;
            };
            let (owner, compactable) = (info.owner, info.compactable);
            if let Some((batch, scratch)) = packer.place(e.build_scratch_bytes) {
                batch.builds.push(BlasBuild {
                    id: op,
                    blas: id,
                    owner,
                    primitives: e.primitives,
                    result_bytes: e.result_bytes,
                    scratch,
                    allow_compaction: compactable,
                    allow_update: !owner.is_shared(),
                });
            }
            self.queue.remove(&id);
            builds += 1;
            prims += e.primitives;
            result += e.result_bytes;
        }
        plan.batches = packer.batches;

        // 3. Compactions.
        let ready: Vec<BlasId> = self
            .cache
            .compaction_candidates()
            .take(budgets.max_compactions as usize)
            .collect();
        for id in ready {
            let Some(info) = self.cache.get(id) else {
                continue;
            };
            let BlasState::SizeQueried {
                address,
                compacted_bytes,
                ..
            } = info.state
            else {
                continue;
            };
            let op = BuildId(self.next_op);
            let Some(source_build) = self.cache.created_by(id) else {
                continue;
            };
            if self.cache.try_begin_compaction(id, op)? {
                self.next_op += 1;
                plan.compactions.push(CompactionPlan {
                    id: op,
                    blas: id,
                    source_build,
                    src_address: address,
                    compacted_bytes,
                });
            }
        }
        Ok(plan)
    }

    /// Takes one acknowledgement ([`Ack`], the one type every backend hands
    /// back): [`BuildScheduler::ack_built`],
    /// [`BuildScheduler::ack_compacted_size`] or
    /// [`BuildScheduler::ack_compacted`]. An acknowledgement never planned
    /// (or given twice) is an error and changes nothing.
    ///
    /// ```
    /// # use lipac_core::blas_ids::{InstanceKey, Lod};
    /// # use lipac_core::{Ack, MeshId};
    /// # use lipac_core::build_plan::*;
    /// let mut s = BuildScheduler::new(SchedulerConfig::default())?;
    /// s.begin_frame(1)?;
    /// let estimate = BuildEstimate { primitives: 10, result_bytes: 1024,
    ///                                build_scratch_bytes: 512, update_scratch_bytes: 0 };
    /// s.activate(InstanceKey(0), InstanceBlasRequest {
    ///     geometry: BlasGeometry::Shared { mesh: MeshId(1), variant: 0, compactable: false },
    ///     lod: Lod(0), estimate, hits: 0, in_frustum: false,
    /// })?;
    /// let build = s.plan(&BuildBudgets::default())?.builds().next().unwrap().id;
    /// s.handle_ack(Ack::Built { build, result_bytes: 1000, address: 0xB000 })?;
    /// assert_eq!(s.blas_address(InstanceKey(0)), Some(0xB000));
    /// assert!(s.handle_ack(Ack::Built { build, result_bytes: 1000, address: 0xB000 }).is_err());
    /// # Ok::<(), BuildPlanError>(())
    /// ```
    pub fn handle_ack(&mut self, ack: Ack) -> Result<(), BuildPlanError> {
        match ack {
            Ack::Built {
                build,
                result_bytes,
                address,
            } => self.ack_built(build, result_bytes, address),
            Ack::CompactedSize {
                build,
                compacted_bytes,
            } => self.ack_compacted_size(build, compacted_bytes),
            Ack::Compacted { op, address } => self.ack_compacted(op, address),
        }
    }

    /// Acknowledges build `build` (`result_bytes` at `address`). Instances
    /// waiting for it switch to it now (their old BLAS is released).
    pub fn ack_built(
        &mut self,
        build: BuildId,
        result_bytes: u64,
        address: u64,
    ) -> Result<(), BuildPlanError> {
        let id = self.cache.ack_built(build, result_bytes, address)?;
        let frame = self.cache.frame();
        for inst in self.waiters.remove(&id).unwrap_or_default() {
            let Some(slot) = self.slots.get_mut(&inst) else {
                continue;
            };
            let Some(p) = slot.pending.filter(|p| p.blas == id) else {
                continue;
            };
            let old = slot.current.replace(p);
            slot.pending = None;
            slot.last_update = frame;
            slot.rebuild_overdue = false;
            if old.is_some() {
                self.built_switches += 1;
            }
            self.holders.entry(id).or_default().insert(inst);
            if let Some(old) = old {
                self.unhold(inst, old.blas)?;
            }
            self.address_changes.insert(inst);
        }
        Ok(())
    }

    /// Acknowledges the compacted-size query that followed build `build`; a
    /// [`CompactionPlan`] follows in a later [`BuildScheduler::plan`]. An
    /// answer for a BLAS evicted meanwhile is dropped.
    pub fn ack_compacted_size(
        &mut self,
        build: BuildId,
        compacted_bytes: u64,
    ) -> Result<(), BuildPlanError> {
        self.cache.ack_compacted_size(build, compacted_bytes)?;
        Ok(())
    }

    /// Acknowledges compaction `op`: the compacted copy is at `address`; the
    /// instances using it get the new address (see
    /// [`BuildScheduler::take_address_changes`]).
    pub fn ack_compacted(&mut self, op: BuildId, address: u64) -> Result<(), BuildPlanError> {
        let id = self.cache.ack_compacted(op, address)?;
        if let Some(h) = self.holders.get(&id) {
            self.address_changes.extend(h.iter().copied());
        }
        Ok(())
    }

    /// Whether `instance` is active (activated and not deactivated since):
    /// it holds or waits for a BLAS. O(1).
    pub fn is_active(&self, instance: InstanceKey) -> bool {
        self.slots.contains_key(&instance)
    }

    /// Address of the BLAS an instance currently uses (for its TLAS
    /// instance record), or `None` while its first BLAS is not built.
    pub fn blas_address(&self, instance: InstanceKey) -> Option<u64> {
        let cur = self.slots.get(&instance)?.current?;
        self.cache.address(cur.blas)
    }

    /// The LOD of the BLAS an instance currently uses.
    pub fn current_lod(&self, instance: InstanceKey) -> Option<Lod> {
        Some(self.slots.get(&instance)?.current?.lod)
    }

    /// The cache entry an instance currently uses.
    pub fn current_blas(&self, instance: InstanceKey) -> Option<BlasId> {
        Some(self.slots.get(&instance)?.current?.blas)
    }

    /// The LOD an instance waits for (a build is queued or in flight).
    pub fn pending_lod(&self, instance: InstanceKey) -> Option<Lod> {
        Some(self.slots.get(&instance)?.pending?.lod)
    }

    /// The instances that wait for a build (those with a
    /// [`BuildScheduler::pending_lod`]), in no particular order: O(waiting)
    /// rather than a [`BuildScheduler::pending_lod`] lookup per instance.
    pub fn waiting_instances(&self) -> impl Iterator<Item = InstanceKey> + '_ {
        self.waiters.values().flatten().copied()
    }

    /// Instances whose BLAS address changed since the last call (first BLAS
    /// built, LOD switched, compacted), in key order.
    pub fn take_address_changes(&mut self) -> Vec<InstanceKey> {
        std::mem::take(&mut self.address_changes)
            .into_iter()
            .collect()
    }

    /// Statistics. The cache's pending frees include those that became due
    /// at [`BuildScheduler::begin_frame`] and wait for the next plan (the
    /// backend still holds them).
    pub fn stats(&self) -> SchedulerStats {
        let mut cache = self.cache.stats();
        cache.pending_frees += self.frees.len();
        for f in &self.frees {
            cache.pending_free_bytes = cache.pending_free_bytes.saturating_add(f.bytes);
        }
        SchedulerStats {
            cache,
            queued_builds: self.queue.len(),
            in_flight: self.cache.in_flight_ops(),
            instances: self.slots.len(),
            instant_switches: self.instant_switches,
            built_switches: self.built_switches,
        }
    }

    /// Evicts every unreferenced cached BLAS (see [`BlasCache::trim`]).
    pub fn trim_cache(&mut self) -> usize {
        self.cache.trim()
    }

    /// Performs now every requested switch to a coarser LOD that still
    /// waits for its hysteresis (`lod_hysteresis_frames`), as
    /// [`BuildScheduler::plan`] would once it elapsed: to a cached BLAS at
    /// once (free-before-allocate), otherwise the coarser BLAS is queued and
    /// the instance keeps its current one until it is built. Finer switches
    /// keep their hysteresis. Returns the switches made. A memory budget's
    /// lever ([`crate::controller::ControllerConfig::coarsen_over_budget`]):
    /// a camera jump away from a view leaves its instances at the near
    /// view's LODs for the whole hysteresis.
    pub fn expedite_coarser_lods(&mut self) -> Result<usize, BuildPlanError> {
        if !self.started {
            return Err(BuildPlanError::FrameNotStarted);
        }
        self.process_lod_switches(true)
    }

    // ---- internals ----

    fn slot_mut(&mut self, instance: InstanceKey) -> Result<&mut Slot, BuildPlanError> {
        self.slots
            .get_mut(&instance)
            .ok_or(BuildPlanError::UnknownInstance(instance))
    }

    fn priority(&self, id: BlasId, q: &Queued) -> u64 {
        let p = &self.config.priority;
        let (mut hits, mut frustum, mut untraced) = (0u32, false, false);
        if let Some(w) = self.waiters.get(&id) {
            for s in w.iter().filter_map(|k| self.slots.get(k)) {
                hits = hits.max(s.hits);
                frustum |= s.in_frustum;
                untraced |= s.current.is_none();
            }
        }
        let waited = self.cache.frame().saturating_sub(q.since);
        u64::from(hits.min(p.hit_cap))
            .saturating_add(if frustum { p.frustum_bonus } else { 0 })
            .saturating_add(if untraced { p.first_build_bonus } else { 0 })
            .saturating_add(waited.saturating_mul(p.ageing_per_frame))
    }

    /// Acquires the BLAS for `lod` and makes it current (if built) or pending.
    fn assign(
        &mut self,
        instance: InstanceKey,
        lod: Lod,
        estimate: BuildEstimate,
    ) -> Result<(), BuildPlanError> {
        let slot = self
            .slots
            .get(&instance)
            .ok_or(BuildPlanError::UnknownInstance(instance))?;
        let id = match slot.geometry {
            BlasGeometry::Shared {
                mesh,
                variant,
                compactable,
            } => {
                let key = BlasKey { mesh, lod, variant };
                self.cache.acquire_shared(key, compactable)?.id()
            }
            BlasGeometry::Unique { mesh } => self.cache.create_unique(instance, mesh, lod),
        };
        let held = Held {
            blas: id,
            lod,
            estimate,
        };
        if self.cache.address(id).is_some() {
            let old = self.slot_mut(instance)?.current.replace(held);
            self.holders.entry(id).or_default().insert(instance);
            if let Some(old) = old {
                self.unhold(instance, old.blas)?;
            }
            self.address_changes.insert(instance);
        } else {
            self.slot_mut(instance)?.pending = Some(held);
            self.waiters.entry(id).or_default().insert(instance);
            if self.cache.get(id).map(|i| i.state) == Some(BlasState::Requested) {
                let frame = self.cache.frame();
                self.queue.entry(id).or_insert(Queued {
                    since: frame,
                    estimate,
                });
            }
        }
        Ok(())
    }

    /// Drops `instance`'s hold on its current BLAS `id`.
    fn unhold(&mut self, instance: InstanceKey, id: BlasId) -> Result<(), BuildPlanError> {
        if let Some(h) = self.holders.get_mut(&id) {
            h.remove(&instance);
            if h.is_empty() {
                self.holders.remove(&id);
            }
        }
        self.cache.release(id)?;
        Ok(())
    }

    /// Drops `instance`'s wait on the pending BLAS `id`.
    fn cancel_pending(&mut self, instance: InstanceKey, id: BlasId) -> Result<(), BuildPlanError> {
        if let Some(w) = self.waiters.get_mut(&id) {
            w.remove(&instance);
            if w.is_empty() {
                self.waiters.remove(&id);
            }
        }
        self.cache.release(id)?;
        if self.cache.get(id).is_none() {
            self.queue.remove(&id);
        }
        Ok(())
    }

    /// Performs the LOD switches whose hysteresis has elapsed, coarser
    /// first, and with `coarser_now` every switch to a coarser LOD at once;
    /// returns how many.
    fn process_lod_switches(&mut self, coarser_now: bool) -> Result<usize, BuildPlanError> {
        let frame = self.cache.frame();
        let h = u64::from(self.config.lod_hysteresis_frames);
        let mut due: Vec<(bool, InstanceKey)> = self
            .slots
            .iter()
            .filter_map(|(&k, s)| {
                let d = s.desired?;
                let cur = s.current?;
                let coarser = d.lod.is_coarser_than(cur.lod);
                (frame >= d.since.saturating_add(h) || (coarser_now && coarser))
                    .then_some((!coarser, k))
            })
            .collect();
        due.sort();
        let switches = due.len();
        for (finer, inst) in due {
            let slot = self.slot_mut(inst)?;
            let (Some(d), Some(cur)) = (slot.desired.take(), slot.current) else {
                continue;
            };
            if let Some(p) = slot.pending.take() {
                self.cancel_pending(inst, p.blas)?;
            }
            let geometry = self.slot_mut(inst)?.geometry;
            let cached = match geometry {
                BlasGeometry::Shared { mesh, variant, .. } => self
                    .cache
                    .lookup(&BlasKey {
                        mesh,
                        lod: d.lod,
                        variant,
                    })
                    .filter(|&id| self.cache.address(id).is_some()),
                BlasGeometry::Unique { .. } => None,
            };
            if let Some(target) = cached {
                let held = Held {
                    blas: target,
                    lod: d.lod,
                    estimate: d.estimate,
                };
                if finer {
                    // allocate-before-free
                    self.cache.acquire(target)?;
                    self.unhold(inst, cur.blas)?;
                } else {
                    // free-before-allocate
                    self.unhold(inst, cur.blas)?;
                    self.cache.acquire(target)?;
                }
                self.slot_mut(inst)?.current = Some(held);
                self.holders.entry(target).or_default().insert(inst);
                self.address_changes.insert(inst);
                self.instant_switches += 1;
            } else {
                self.assign(inst, d.lod, d.estimate)?;
            }
        }
        Ok(switches)
    }
}

mod instances;
use instances::Instances;

#[cfg(test)]
mod tests;
