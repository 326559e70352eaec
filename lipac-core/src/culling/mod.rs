//! **Low-level.** [`Culling`], the culling half of the per-frame loop over one
//! scene: registry, hitbox records, hit counters, Algorithms 1 and 2, command
//! buffer and queue, latency mitigation. Engines and backends drive
//! [`crate::Manager`], which owns one; [`Culling`] is public for tests,
//! benches and as the CPU reference of the GPU algorithms. It is sans-IO and
//! polled: [`Culling::process_commands`] returns the BLAS work as
//! [`CommandEvent`]s for the caller to carry out. [`ReadbackRing`] models the
//! read-back latency; [`Uploads`] / [`apply_uploads`] are the upload contract.
//!
//! # One frame
//!
//! | step | call | paper |
//! | --- | --- | --- |
//! | 1 | [`Culling::begin_frame`]: slot quarantine, hitbox reset, hit counters cleared | |
//! | 2 | [`Culling::mitigate_latency`] (optional): instances newly in the frustum become active now | §3.6 |
//! | 3 | [`Culling::ingest_readback`]: the commands of frame `N - k` | §3.4 |
//! | 4 | [`Culling::process_commands`]: budgeted BLAS work as [`CommandEvent`]s | §3.4 |
//! | 5 | [`Culling::take_uploads`] (GPU backends): what to upload | |
//! | 6 | [`Culling::assemble`]: the TLAS instances | Alg. 1 |
//! | 7 | trace; write [`Culling::instance_hits_mut`] and hitbox hits ([`Culling::hitboxes_mut`]) | §3.3 |
//! | 8 | [`Culling::process_feedback`]: states and commands | Alg. 2 |
//! | 9 | [`Culling::take_commands`] → the backend's read-back ring ([`ReadbackRing`]) | |
//!
//! # The rules a caller must know
//!
//! * **State bits belong to Algorithm 2.** The CPU writes an instance's state
//!   bits only at registration (→ inactive) and in latency mitigation
//!   (→ active, and its hitbox active); a GPU backend uploads
//!   [`Uploads`] with [`apply_uploads`]'s semantics.
//! * **Commands are hints; the commanded state decides.** Processing a
//!   command reconciles the instance's BLAS with the loop's commanded state
//!   (the newest ingested command per slot, or the loop's own later
//!   decision), never with the records' state bits:
//!
//! | commanded state | BLAS | action ([`BlasAction`]) |
//! | --- | --- | --- |
//! | active | none, no build pending | [`BlasAction::Acquire`]: provide it with [`Culling::set_blas`] (at once when cached, else once built) |
//! | active | held or build pending | nothing |
//! | not active | held | [`BlasAction::Release`]: the record's BLAS is cleared, the caller releases it |
//! | not active | build pending | [`BlasAction::CancelBuild`] |
//! | not active | none | nothing |
//!
//! Commands for dead slots are dropped and counted ([`IngestSummary::dead`],
//! [`ProcessStats::dead`]); stale ones in [`ProcessStats::stale_kind`].
//! [`CullingConfig::validate`] requires the slot quarantine to exceed the
//! read-back latency. Why it is built this way (no command lost, the newest
//! command per slot, latency mitigation and hitboxes): `docs/ARCHITECTURE.md`,
//! "The command loop".

use std::collections::HashMap;

use glam::{Affine3A, Vec3};

use crate::assembly::{assemble_tlas_adaptive, AssemblyConfig, AssemblyStats};
use crate::command::{Command, CommandBuffer, CommandKind, CommandQueue, IngestSummary};
use crate::error::CoreError;
use crate::feedback::{process_feedback_with_rates, FeedbackStats};
use crate::grid::HitboxGrid;
use crate::hitbox_extents::{ExtentTracker, HitboxExtent};
use crate::hitbox_index::HitboxIndex;
use crate::hitbox_tree::{AdaptiveHitboxes, HitboxTree};
use crate::instance::{InstanceDesc, InstanceFlags, MeshId};
use crate::latency::{ActivationHeuristic, Frustum, LatencyMitigation, LatencySummary};
use crate::layout::{
    hitbox_bits, instance_bits, HitboxRecord, InstanceState, TlasInstance, MAX_SLOTS,
};
use crate::math::Aabb;
use crate::memory::MemoryUsage;
use crate::registry::{InstanceHandle, InstanceRegistry, RegistryConfig, RemovedInstance};
use crate::slot_table::SlotTable;
use crate::thresholds::{DecisionRule, Thresholds};

/// Settings of a [`Culling`]; checked by [`CullingConfig::validate`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CullingConfig {
    /// Slot quarantine and limits of the instance registry.
    pub registry: RegistryConfig,
    /// θa, θd, σa, σo, n_a, n_d.
    pub thresholds: Thresholds,
    /// Backend constants of Algorithm 1 (unit-cube BLAS, masks, SBT offsets).
    pub assembly: AssemblyConfig,
    /// Capacity of the bounded command buffer Algorithm 2 appends to
    /// (1..=[`MAX_SLOTS`]; more than one command per slot and frame never
    /// happens). Transitions that do not fit are retried next frame. (The
    /// per-frame *processing* budget is not a setting: it is an argument of
    /// [`Culling::process_commands`], [`crate::FrameBudgets::commands`] for
    /// the manager.)
    pub command_capacity: u32,
    /// Latency mitigation (§3.6) with this heuristic, or `None` to disable it.
    pub latency_mitigation: Option<ActivationHeuristic>,
    /// Frames between a frame's feedback and the ingestion of its commands
    /// (the read-back ring's depth, at least 1). Must be below
    /// [`RegistryConfig::quarantine_frames`].
    pub readback_latency: u32,
    /// Who decides which instances are active: LiPaC's hit feedback (the
    /// default) or the engine alone, through the pinned flag.
    pub selection: Selection,
    /// Adaptive hitboxes: merged counting boxes for cold regions
    /// ([`crate::hitbox_tree`]); off by default (one box per inactive
    /// hitbox, the paper's rule). Dense grids only.
    pub adaptive_hitboxes: AdaptiveHitboxes,
    /// Frames of Algorithm 2 without a hit that what a warm start
    /// ([`Culling::warm_start`]) activates survives, under the decayed rule:
    /// its hitboxes' rates and its unique-BLAS instances' rates are raised
    /// to [`crate::thresholds::DecayedRule::hold_rate`] of the deactivation
    /// and omit thresholds, so that hit feedback culls the view down only
    /// after that many frames of evidence, not after the first frame's few
    /// rays. 0 (the default): no hold, the first feedback decides. The
    /// paper's rule has no rates; there it changes nothing. The rates are
    /// computed from the thresholds at the warm start: thresholds the
    /// manager's closed loop raises afterwards (a memory target) shorten
    /// the hold, lowered ones lengthen it.
    pub warm_start_hold: u32,
}

/// Who decides which instances are active ([`CullingConfig::selection`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Selection {
    /// LiPaC: Algorithm 2's hit feedback, and the pinned instances
    /// ([`InstanceFlags::PINNED`]), which are always active.
    #[default]
    HitFeedback,
    /// The engine alone, without hit feedback: exactly the pinned instances
    /// are active. Every hitbox is active from the start (so Algorithm 1
    /// emits no counting box: the TLAS holds the pinned instances with a
    /// BLAS), [`Culling::process_feedback`] changes nothing and writes no
    /// command (a GPU backend skips Algorithm 2 and the read-back), and
    /// clearing [`InstanceFlags::PINNED`] makes the instance inactive at
    /// once, its BLAS released by the next command processing. For an
    /// engine (or a baseline) that chooses its own set each frame and lets
    /// lipac own the BLASes. Latency mitigation must be off.
    EngineSelected,
}

impl CullingConfig {
    /// Defaults around the backend's unit-cube BLAS: the registry's defaults
    /// (quarantine 4 frames), the paper's thresholds, [`AssemblyConfig::new`],
    /// 65 536 commands per frame in the buffer, latency mitigation with the
    /// default heuristic, readback latency 2.
    pub fn new(unit_cube_blas: u64) -> Self {
        Self {
            registry: RegistryConfig::default(),
            thresholds: Thresholds::paper(),
            assembly: AssemblyConfig::new(unit_cube_blas),
            command_capacity: 1 << 16,
            latency_mitigation: Some(ActivationHeuristic::default()),
            readback_latency: 2,
            selection: Selection::HitFeedback,
            adaptive_hitboxes: AdaptiveHitboxes::OFF,
            warm_start_hold: 0,
        }
    }

    /// Checks every field; the error names the offending value. (The
    /// registry's own fields and the heuristic are checked again when
    /// [`Culling::new`] builds them.)
    pub fn validate(&self) -> Result<(), CoreError> {
        let invalid = |what: String| Err(CoreError::InvalidConfig { what });
        if let Err(e) = self.thresholds.validate() {
            return invalid(format!("thresholds: {e}"));
        }
        if self.command_capacity == 0 || self.command_capacity > MAX_SLOTS {
            return invalid(format!(
                "command_capacity = {} must be in 1..={MAX_SLOTS}",
                self.command_capacity
            ));
        }
        if self.readback_latency == 0 {
            return invalid(
                "readback_latency = 0: commands are read back at least one frame later".into(),
            );
        }
        if self.registry.quarantine_frames <= self.readback_latency {
            return invalid(format!(
                "registry.quarantine_frames = {} must exceed readback_latency = {} so that a late \
                 command never reaches a reused slot",
                self.registry.quarantine_frames, self.readback_latency
            ));
        }
        let a = &self.assembly;
        if a.unit_cube_blas == 0 {
            return invalid("assembly.unit_cube_blas = 0: 0 means \"no BLAS\"".into());
        }
        if !a.min_box_extent.is_finite() || a.min_box_extent < 0.0 {
            return invalid(format!(
                "assembly.min_box_extent = {} must be finite and >= 0",
                a.min_box_extent
            ));
        }
        for (name, v) in [
            ("omitted_box_sbt_offset", a.omitted_box_sbt_offset),
            ("hitbox_sbt_offset", a.hitbox_sbt_offset),
        ] {
            if v >= 1 << 24 {
                return invalid(format!("assembly.{name} = {v} does not fit 24 bits"));
            }
        }
        let ad = &self.adaptive_hitboxes;
        if ad.is_on()
            && (ad.merged_box_sbt_offset == a.omitted_box_sbt_offset
                || ad.merged_box_sbt_offset == a.hitbox_sbt_offset)
        {
            return invalid(format!(
                "adaptive_hitboxes.merged_box_sbt_offset = {} must differ from the other \
                 counting SBT offsets",
                ad.merged_box_sbt_offset
            ));
        }
        if let Some(h) = self.latency_mitigation {
            if self.selection == Selection::EngineSelected {
                return invalid(
                    "latency_mitigation must be None with Selection::EngineSelected: nothing \
                     would deactivate what it activates"
                        .into(),
                );
            }
            LatencyMitigation::new(h)?;
        }
        Ok(())
    }
}

/// What the caller of [`Culling::process_commands`] is asked to do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlasAction {
    /// The instance is active and has no BLAS: it now waits for one
    /// ([`Culling::awaiting_blas`]). Provide it with [`Culling::set_blas`]:
    /// at once if one is ready (a shared BLAS in the cache), else once it is
    /// built.
    Acquire,
    /// The instance is no longer active: its record's BLAS was cleared,
    /// release this address.
    Release {
        /// The BLAS address the record held (nonzero).
        blas: u64,
    },
    /// The instance is no longer active and the BLAS it waited for (an
    /// earlier [`BlasAction::Acquire`] or latency-mitigation request not yet
    /// answered by [`Culling::set_blas`]) is not wanted any more.
    CancelBuild,
}

/// One unit of BLAS work returned by [`Culling::process_commands`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CommandEvent {
    /// The instance.
    pub handle: InstanceHandle,
    /// Its GPU slot.
    pub slot: u32,
    /// Its mesh.
    pub mesh: MeshId,
    /// Its LOD.
    pub lod: u32,
    /// Its flags ([`InstanceFlags::UNIQUE_BLAS`] selects a unique BLAS).
    pub flags: InstanceFlags,
    /// The command's priority (quantised hit count).
    pub priority: u8,
    /// The command's kind as the GPU wrote it (informational; the action
    /// follows the commanded state, see the [module docs](self)).
    pub command: CommandKind,
    /// What to do.
    pub action: BlasAction,
}

/// A request to provide a BLAS, from [`Culling::mitigate_latency`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BlasRequest {
    /// The instance (now active, no BLAS yet).
    pub handle: InstanceHandle,
    /// Its GPU slot.
    pub slot: u32,
    /// Its mesh.
    pub mesh: MeshId,
    /// Its LOD.
    pub lod: u32,
    /// Its flags.
    pub flags: InstanceFlags,
}

/// Result of [`Culling::mitigate_latency`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LatencyOutcome {
    /// The frustum test's counts.
    pub summary: LatencySummary,
    /// Instances made active that need a BLAS: provide one with
    /// [`Culling::set_blas`] (this frame if it is to be traced this frame).
    /// Each is marked as waiting for its BLAS.
    pub requests: Vec<BlasRequest>,
    /// Instances made active that already held a BLAS or had a build
    /// pending.
    pub already_provided: u32,
    /// Hitboxes of the activated instances set active with their streak
    /// zeroed (so that the instances survive Algorithm 2), each counted once
    /// until the next [`Culling::take_uploads`]. Whether a hitbox was active
    /// already is not read: a GPU backend's CPU hitbox records do not carry
    /// Algorithm 2's bits.
    pub hitboxes_activated: u32,
}

/// What [`Culling::process_commands`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ProcessStats {
    /// Commands taken from the queue (at most the budget).
    pub drained: u32,
    /// [`BlasAction::Acquire`]s served at once from the BLAS cache. Filled by
    /// [`crate::Manager::plan`]; [`Culling::process_commands`] cannot know
    /// and counts every acquire in `requested`.
    pub acquired: u32,
    /// [`BlasAction::Acquire`]s that wait for a build.
    pub requested: u32,
    /// [`BlasAction::Release`]s.
    pub released: u32,
    /// [`BlasAction::CancelBuild`]s.
    pub builds_cancelled: u32,
    /// Commands whose instance's BLAS already agreed with its state.
    pub no_op: u32,
    /// Commands whose kind disagreed with the instance's commanded state
    /// (written before a latency-mitigation override or before the slot's
    /// registration); they are also counted as what reconciliation did.
    pub stale_kind: u32,
    /// Commands for dead slots, dropped.
    pub dead: u32,
    /// Commands still pending after this call.
    pub remaining: u32,
}

/// What [`Culling::remove`] hands back.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Removal {
    /// The registry's account: slot, description, state and the BLAS to
    /// release (`instance.blas`, 0 = none).
    pub instance: RemovedInstance,
    /// The instance was waiting for a requested build: cancel it.
    pub build_was_pending: bool,
    /// Its pending command, now cancelled.
    pub cancelled_command: Option<Command>,
}

/// The LiPaC per-frame loop over one scene; see the [module docs](self).
///
/// A full frame, with a read-back latency of one frame:
///
/// ```
/// use glam::{Affine3A, Vec3};
/// use lipac_core::culling::{BlasAction, Culling, CullingConfig, ReadbackRing};
/// use lipac_core::InstanceDesc;
/// use lipac_core::grid::{GridConfig, HitboxGrid};
/// use lipac_core::layout::InstanceState;
/// use lipac_core::{Aabb, MeshId};
///
/// let grid = HitboxGrid::new(GridConfig { min: [0.0, 0.0], max: [64.0, 64.0], cell_size: 16.0 })?;
/// let mut config = CullingConfig::new(0xC0BE); // unit-cube BLAS address
/// config.readback_latency = 1;
/// config.latency_mitigation = None;
/// let mut culling = Culling::new(grid, config)?;
/// let mut ring = ReadbackRing::new(1)?;
///
/// let aabb = Aabb::new(Vec3::new(7.0, 0.0, 7.0), Vec3::new(9.0, 2.0, 9.0));
/// let house = culling.register(InstanceDesc::new(MeshId(1), Affine3A::IDENTITY, aabb))?;
///
/// let (mut tlas, mut events) = (Vec::new(), Vec::new());
/// for frame in 0..2 {
///     culling.begin_frame(frame)?;
///     while let Some(r) = ring.pop_ready(frame) {
///         culling.ingest_readback(r.frame, r.counter, &r.words);
///     }
///     culling.process_commands(usize::MAX, &mut events);
///     for e in &events {
///         if e.action == BlasAction::Acquire {
///             culling.set_blas(e.handle, 0xB1A5)?; // the shared BLAS of mesh 1
///         }
///     }
///     culling.assemble(&mut tlas)?;
///     // "Trace": 2500 rays hit hitbox 0's counting box (> 2·θa).
///     if frame == 0 {
///         assert_eq!(tlas.len(), 1); // only the hitbox's counting box
///         culling.hitboxes_mut()[tlas[0].custom_index() as usize].add_hits(2500);
///     }
///     culling.process_feedback()?;
///     ring.push(culling.take_commands().expect("feedback ran"))?;
/// }
/// // Frame 0's feedback activated the hitbox and the house; frame 1 processed
/// // its `add` and traced the house with its own BLAS.
/// assert_eq!(culling.registry().state(house)?, InstanceState::Active);
/// assert_eq!(tlas.len(), 1);
/// assert_eq!((tlas[0].custom_index(), tlas[0].acceleration_structure_reference), (0, 0xB1A5));
/// # Ok::<(), lipac_core::error::CoreError>(())
/// ```
#[derive(Clone, Debug)]
pub struct Culling<H: HitboxIndex = HitboxGrid> {
    config: CullingConfig,
    registry: InstanceRegistry<H>,
    hitboxes: Vec<HitboxRecord>,
    instance_hits: Vec<u32>,
    /// Decayed hit rates of unique-BLAS instances (16.16, one per slot; the
    /// decayed rule's, kept across frames).
    instance_rates: Vec<u32>,
    commands: CommandBuffer,
    /// Algorithm 2 ran and its commands were not taken yet.
    untaken: bool,
    /// Algorithm 2 ran in the current frame.
    fed_back: bool,
    queue: CommandQueue,
    latency: Option<LatencyMitigation>,
    state_overrides: StateOverrides,
    hitbox_overrides: HashMap<u32, bool>,
    /// Rate floors of a held warm start ([`CullingConfig::warm_start_hold`])
    /// not yet taken for the GPU: by hitbox index and by slot.
    hitbox_rate_floors: HashMap<u32, u32>,
    instance_rate_floors: HashMap<u32, u32>,
    scratch: Vec<u32>,
    /// Adaptive hitboxes' quadtree (`None`: off).
    tree: Option<HitboxTree>,
    /// The hitboxes' member lists ([`crate::hitbox_extents`]).
    extents: ExtentTracker,
    /// Extents that changed and were not yet taken for the GPU, by index.
    extent_uploads: HashMap<u32, HitboxExtent>,
    /// Reused buffer of [`ExtentTracker::refresh`]'s changes.
    extent_changes: Vec<(u32, HitboxExtent)>,
}

impl<H: HitboxIndex> Culling<H> {
    /// A loop over the hitbox structure `index` with all hitboxes inactive
    /// (active with [`Selection::EngineSelected`]) and no instances, at
    /// frame 0. Fails for an invalid `config`.
    pub fn new(index: H, config: CullingConfig) -> Result<Self, CoreError> {
        config.validate()?;
        let hitbox_count = index.len() as usize;
        let latency = config
            .latency_mitigation
            .map(LatencyMitigation::new)
            .transpose()?;
        let engine_selected = config.selection == Selection::EngineSelected;
        let hitbox = HitboxRecord {
            packed: if engine_selected {
                hitbox_bits::ACTIVE
            } else {
                0
            },
            ..HitboxRecord::default()
        };
        // A GPU backend learns the active hitboxes from the first upload.
        let mut hitbox_overrides = HashMap::new();
        if engine_selected {
            hitbox_overrides
                .try_reserve(hitbox_count)
                .map_err(|_| CoreError::OutOfMemory {
                    what: "hitbox overrides",
                    additional: hitbox_count,
                })?;
            hitbox_overrides.extend((0..hitbox_count as u32).map(|i| (i, true)));
        }
        let mut hitboxes = Vec::new();
        crate::memory::try_reserve_exact(&mut hitboxes, hitbox_count, "hitbox records")?;
        hitboxes.resize(hitbox_count, hitbox);
        let tree = HitboxTree::for_index(&index, config.adaptive_hitboxes)?;
        Ok(Self {
            registry: InstanceRegistry::new(index, config.registry)?,
            hitboxes,
            instance_hits: Vec::new(),
            instance_rates: Vec::new(),
            commands: CommandBuffer::try_new(config.command_capacity)?,
            untaken: false,
            fed_back: false,
            queue: CommandQueue::new(MAX_SLOTS),
            latency,
            state_overrides: StateOverrides::default(),
            hitbox_overrides,
            hitbox_rate_floors: HashMap::new(),
            instance_rate_floors: HashMap::new(),
            scratch: Vec::new(),
            tree,
            extents: ExtentTracker::default(),
            extent_uploads: HashMap::new(),
            extent_changes: Vec::new(),
            config,
        })
    }

    /// The settings.
    pub fn config(&self) -> &CullingConfig {
        &self.config
    }

    /// The adaptive hitboxes' quadtree, `None` when the option is off.
    pub fn hitbox_tree(&self) -> Option<&HitboxTree> {
        self.tree.as_ref()
    }

    /// Replaces the thresholds Algorithm 2 runs with (the Manager's
    /// closed-loop controller, [`crate::controller`]); a GPU backend reads
    /// them from [`Culling::config`] when it records the frame. Fails,
    /// changing nothing, for thresholds [`Thresholds::validate`] rejects.
    pub fn set_thresholds(&mut self, thresholds: Thresholds) -> Result<(), CoreError> {
        thresholds
            .validate()
            .map_err(|e| CoreError::InvalidConfig {
                what: format!("thresholds: {e}"),
            })?;
        self.config.thresholds = thresholds;
        Ok(())
    }

    /// The instance registry (read-only; change instances through
    /// [`Culling`] so that commands, hit counters and uploads follow).
    pub fn registry(&self) -> &InstanceRegistry<H> {
        &self.registry
    }

    /// The slot table ([`crate::slot_table`]), through the registry that
    /// owns it.
    pub(crate) fn table(&self) -> &SlotTable {
        self.registry.table()
    }

    /// The slot table, for the Manager's column.
    pub(crate) fn table_mut(&mut self) -> &mut SlotTable {
        self.registry.table_mut()
    }

    /// The current frame.
    pub fn frame(&self) -> u64 {
        self.registry.frame()
    }

    /// The hitbox records, one per hitbox of the index.
    pub fn hitboxes(&self) -> &[HitboxRecord] {
        &self.hitboxes
    }

    /// The hitbox records, for the tracer to add its counting-box hits
    /// ([`HitboxRecord::add_hits`], index = the box's custom index).
    pub fn hitboxes_mut(&mut self) -> &mut [HitboxRecord] {
        &mut self.hitboxes
    }

    /// The per-slot hit counters (length = the registry's slot count).
    pub fn instance_hits(&self) -> &[u32] {
        &self.instance_hits
    }

    /// The per-slot hit counters, for the tracer (index = the custom index
    /// of an instance's own record or of its omitted box).
    pub fn instance_hits_mut(&mut self) -> &mut [u32] {
        &mut self.instance_hits
    }

    /// The per-slot decayed hit rates (16.16) Algorithm 2 keeps under
    /// [`crate::thresholds::DecisionRule::Decayed`] (all 0 under the
    /// paper's rule); a GPU backend keeps its own copy on the GPU.
    pub fn instance_rates(&self) -> &[u32] {
        &self.instance_rates
    }

    /// Commands waiting for processing.
    pub fn pending_commands(&self) -> usize {
        self.queue.len()
    }

    /// The pending command for `slot`, if any.
    pub fn pending_command(&self, slot: u32) -> Option<Command> {
        self.queue.pending(slot)
    }

    /// Whether the instance waits for a BLAS it was promised (a
    /// [`BlasAction::Acquire`] or a latency-mitigation request not yet
    /// answered by [`Culling::set_blas`]).
    pub fn awaiting_blas(&self, handle: InstanceHandle) -> Result<bool, CoreError> {
        let slot = self.registry.slot(handle)?;
        Ok(self.registry.table()[slot as usize].view.awaiting)
    }

    /// Latency mitigation's tracker, if enabled.
    pub fn latency_mitigation(&self) -> Option<&LatencyMitigation> {
        self.latency.as_ref()
    }

    /// CPU bytes held by the loop's containers, computed from their
    /// capacities (see [`crate::memory`]).
    ///
    /// ```
    /// use lipac_core::culling::{Culling, CullingConfig};
    /// use lipac_core::grid::{GridConfig, HitboxGrid};
    /// let culling = Culling::new(HitboxGrid::new(GridConfig::default())?, CullingConfig::new(1))?;
    /// let m = culling.memory_usage();
    /// assert_eq!(m.hitboxes, 512 * 512 * 20); // 5 MiB of hitbox records
    /// assert_eq!(m.records, 0); // no instances yet
    /// # Ok::<(), lipac_core::error::CoreError>(())
    /// ```
    pub fn memory_usage(&self) -> MemoryUsage {
        use crate::memory::{hash_map_bytes, vec_bytes};
        let (records, handles, slot_occupants, free_lists, dirty) = self.registry.heap_bytes();
        MemoryUsage {
            records,
            handles,
            slot_occupants,
            free_lists,
            dirty,
            // The hit counters and the decayed rates, 4 bytes a slot each.
            instance_hits: vec_bytes::<u32>(self.instance_hits.capacity())
                + vec_bytes::<u32>(self.instance_rates.capacity()),
            // In the slot table (`slot_occupants`).
            awaiting: 0,
            latency_bits: self
                .latency
                .as_ref()
                .map_or(0, LatencyMitigation::heap_bytes),
            hitboxes: vec_bytes::<HitboxRecord>(self.hitboxes.capacity()),
            command_buffer: self.commands.heap_bytes(),
            command_queue: self.queue.heap_bytes(),
            overrides: self.state_overrides.heap_bytes()
                + hash_map_bytes(&self.hitbox_overrides)
                + hash_map_bytes(&self.hitbox_rate_floors)
                + hash_map_bytes(&self.instance_rate_floors),
            scratch: vec_bytes::<u32>(self.scratch.capacity()),
            extent_lists: self.extents.heap_bytes()
                + hash_map_bytes(&self.extent_uploads)
                + vec_bytes::<(u32, HitboxExtent)>(self.extent_changes.capacity()),
        }
    }

    // ---- instances ------------------------------------------------------

    /// Reserves room for at least `additional` more instances in the
    /// registry ([`InstanceRegistry::reserve`]) and in the per-slot buffers
    /// and upload overrides that registration fills, so that registering a
    /// scene of known size allocates each container once.
    ///
    /// ```
    /// use glam::{Affine3A, Vec3};
    /// use lipac_core::culling::{Culling, CullingConfig};
    /// use lipac_core::grid::{GridConfig, HitboxGrid};
    /// use lipac_core::instance::{InstanceDesc, MeshId};
    /// use lipac_core::math::Aabb;
    ///
    /// let grid = HitboxGrid::new(GridConfig::default())?;
    /// let mut culling = Culling::new(grid, CullingConfig::new(1))?;
    /// culling.reserve(100)?;
    /// let reserved = culling.memory_usage();
    /// let aabb = Aabb::new(Vec3::ZERO, Vec3::ONE);
    /// for i in 0..100 {
    ///     culling.register(InstanceDesc::new(MeshId(i), Affine3A::IDENTITY, aabb))?;
    /// }
    /// assert_eq!(culling.memory_usage(), reserved); // nothing grew
    /// # Ok::<(), lipac_core::error::CoreError>(())
    /// ```
    pub fn reserve(&mut self, additional: usize) -> Result<(), CoreError> {
        self.reserve_slots(additional).map(|_| ())
    }

    /// [`Culling::reserve`]; returns the number of slots it covers.
    pub(crate) fn reserve_slots(&mut self, additional: usize) -> Result<usize, CoreError> {
        use crate::memory::try_reserve_exact;
        let slots = self.registry.reserve_slots(additional)?;
        let n = slots.saturating_sub(self.instance_hits.len());
        try_reserve_exact(&mut self.instance_hits, n, "instance hit counters")?;
        let n = slots.saturating_sub(self.instance_rates.len());
        try_reserve_exact(&mut self.instance_rates, n, "instance hit rates")?;
        // Each registration writes a state override (until the next take).
        self.state_overrides.reserve(additional.min(slots))?;
        self.extents.reserve_slots(slots)?;
        Ok(slots)
    }

    /// Registers an instance ([`InstanceRegistry::register`]): inactive, no
    /// BLAS. Its state write is an upload override. A pinned instance
    /// ([`InstanceFlags::PINNED`]) starts active and waiting for its BLAS
    /// ([`Culling::awaiting_blas`]): provide it with [`Culling::set_blas`].
    pub fn register(&mut self, desc: InstanceDesc) -> Result<InstanceHandle, CoreError> {
        let handle = self.registry.register(desc)?;
        self.sync_hitbox_count();
        let slot = self.registry.slot(handle)?;
        let n = self.registry.slot_count() as usize;
        if self.instance_hits.len() < n {
            self.instance_hits.resize(n, 0);
            self.instance_rates.resize(n, 0);
        }
        self.instance_hits[slot as usize] = 0;
        self.instance_rates[slot as usize] = 0;
        // A floor for the slot's previous occupant is not this one's.
        self.instance_rate_floors.remove(&slot);
        // The Manager's decision at this frame: inactive, no BLAS promised.
        // (Field by field: a pending state override of the slot stays
        // listed, see `StateOverrides`.)
        let frame = self.registry.frame();
        let view = &mut self.registry.table_mut()[slot as usize].view;
        view.commanded_active = false;
        view.awaiting = false;
        view.decided_at = frame;
        // Nothing can be pending for a fresh slot (see `remove` and
        // `ingest_readback`); make sure.
        self.queue.cancel_slot(slot);
        self.state_overrides
            .insert(self.registry.table_mut(), slot, InstanceState::Inactive);
        if desc.flags.contains(InstanceFlags::PINNED) {
            self.pin(slot);
        }
        Ok(handle)
    }

    /// [`Selection::EngineSelected`]: the instance in `slot` (live) was
    /// unpinned, so it is inactive now; a queued `remove` makes the next
    /// [`Culling::process_commands`] release its BLAS or cancel its build.
    fn unpin(&mut self, slot: u32) -> Result<(), CoreError> {
        let frame = self.registry.frame();
        self.registry.set_state(slot, InstanceState::Inactive)?;
        self.state_overrides
            .insert(self.registry.table_mut(), slot, InstanceState::Inactive);
        let view = &mut self.registry.table_mut()[slot as usize].view;
        view.commanded_active = false;
        view.decided_at = frame;
        let remove = Command {
            slot,
            kind: CommandKind::Remove,
            priority: 0,
        };
        self.queue.push(remove, &mut IngestSummary::default());
        Ok(())
    }

    /// The loop's decision for a pinned instance in `slot` (live): active
    /// now (record, upload override, commanded state), waiting for its BLAS
    /// unless it holds one or one is promised.
    fn pin(&mut self, slot: u32) {
        let frame = self.registry.frame();
        // The registry wrote the state (register / update of a pinned desc).
        self.state_overrides
            .insert(self.registry.table_mut(), slot, InstanceState::Active);
        let blas = self.registry.records().tlas()[slot as usize]
            .record
            .acceleration_structure_reference;
        let view = &mut self.registry.table_mut()[slot as usize].view;
        if !view.commanded_active {
            view.commanded_active = true;
            view.decided_at = frame;
        }
        view.awaiting |= blas == 0;
    }

    /// Replaces an instance's description ([`InstanceRegistry::update`]);
    /// state and BLAS stay. If the mesh, LOD or
    /// [`InstanceFlags::UNIQUE_BLAS`] changed, provide the new BLAS with
    /// [`Culling::set_blas`] and release the old one it returns. Setting
    /// [`InstanceFlags::PINNED`] makes the instance active as at a pinned
    /// registration ([`Culling::awaiting_blas`] if it has no BLAS);
    /// clearing it changes nothing here: Algorithm 2's normal rule decides
    /// from the next feedback on.
    pub fn update(
        &mut self,
        handle: InstanceHandle,
        desc: InstanceDesc,
    ) -> Result<InstanceDesc, CoreError> {
        let old = self.registry.update(handle, desc)?;
        self.sync_hitbox_count();
        let slot = self.registry.slot(handle)?;
        if desc.flags.contains(InstanceFlags::PINNED) {
            let view = self.registry.table()[slot as usize].view;
            if !old.flags.contains(InstanceFlags::PINNED) || !view.commanded_active {
                self.pin(slot);
            }
        } else if old.flags.contains(InstanceFlags::PINNED)
            && self.config.selection == Selection::EngineSelected
        {
            self.unpin(slot)?;
        }
        Ok(old)
    }

    /// Grows the hitbox records to the index's [`HitboxIndex::len`] (a
    /// structure that creates hitboxes on demand may have made one).
    fn sync_hitbox_count(&mut self) {
        let n = self.registry.hitbox_index().len() as usize;
        if self.hitboxes.len() < n {
            self.hitboxes.resize(n, HitboxRecord::default());
        }
    }

    /// Moves an instance ([`InstanceRegistry::set_transform`]). An active
    /// instance moved into an inactive hitbox leaves the TLAS at once
    /// ([`crate::assembly`]) and is removed by the next feedback pass.
    pub fn set_transform(
        &mut self,
        handle: InstanceHandle,
        transform: Affine3A,
        aabb: Aabb,
    ) -> Result<(), CoreError> {
        self.registry.set_transform(handle, transform, aabb)?;
        self.sync_hitbox_count();
        Ok(())
    }

    /// Removes an instance: its slot is quarantined, its pending command
    /// cancelled; release `instance.blas` and cancel a pending build.
    pub fn remove(&mut self, handle: InstanceHandle) -> Result<Removal, CoreError> {
        let instance = self.registry.remove(handle)?;
        let slot = instance.slot as usize;
        let view = &mut self.registry.table_mut()[slot].view;
        let build_was_pending = std::mem::take(&mut view.awaiting);
        view.commanded_active = false;
        self.instance_hits[slot] = 0;
        self.state_overrides
            .remove(self.registry.table_mut(), instance.slot);
        Ok(Removal {
            instance,
            build_was_pending,
            cancelled_command: self.queue.cancel_slot(instance.slot),
        })
    }

    /// Sets the BLAS address of an instance (a finished build, or a LOD
    /// switch) and returns the previous one, which the caller releases if it
    /// is nonzero and different. Ends a pending build. If the instance is no
    /// longer active and `address` is nonzero, a command is queued so that
    /// processing hands the BLAS back ([`BlasAction::Release`]).
    pub fn set_blas(&mut self, handle: InstanceHandle, address: u64) -> Result<u64, CoreError> {
        let slot = self.registry.slot(handle)?;
        let old = self.registry.set_blas(handle, address)?;
        let view = &mut self.registry.table_mut()[slot as usize].view;
        view.awaiting = false;
        if address != 0 && !view.commanded_active {
            let remove = Command {
                slot,
                kind: CommandKind::Remove,
                priority: 0,
            };
            self.queue.push(remove, &mut IngestSummary::default());
        }
        Ok(old)
    }

    // ---- the frame ------------------------------------------------------

    /// Starts frame `frame`: releases quarantined slots, resets the hitboxes'
    /// hits ([`crate::assembly::begin_frame`]) and clears the
    /// instance hit counters. Fails if frames go backwards or the last
    /// frame's commands were not taken ([`Culling::take_commands`]).
    pub fn begin_frame(&mut self, frame: u64) -> Result<(), CoreError> {
        if self.untaken {
            return Err(CoreError::CallOrder {
                what: format!(
                    "the commands of frame {} were not taken (take_commands) before frame {frame}",
                    self.registry.frame()
                ),
            });
        }
        self.registry.begin_frame(frame)?;
        crate::assembly::begin_frame(&mut self.hitboxes);
        // Hitboxes the index dropped (empty cells) start over, inactive, on
        // the GPU too (an override clears the active bit and streak).
        for &index in self.registry.evicted_hitboxes() {
            if let Some(h) = self.hitboxes.get_mut(index as usize) {
                *h = HitboxRecord::default();
                self.hitbox_overrides.insert(index, false);
                self.hitbox_rate_floors.remove(&index);
            }
        }
        self.instance_hits.fill(0);
        self.fed_back = false;
        Ok(())
    }

    /// Latency mitigation (§3.6): every live instance newly in `frustum` that
    /// passes the heuristic and is not active becomes active now, and its
    /// hitbox active too (why: `docs/ARCHITECTURE.md`, "The state machine").
    /// Those without a BLAS are returned as [`LatencyOutcome::requests`]. With
    /// latency mitigation disabled, does nothing. Fails only for a non-finite
    /// camera.
    pub fn mitigate_latency(
        &mut self,
        camera: Vec3,
        frustum: &Frustum,
    ) -> Result<LatencyOutcome, CoreError> {
        let Some(mut lm) = self.latency.take() else {
            return Ok(LatencyOutcome::default());
        };
        let out = self.activate_newly_visible(&mut lm, camera, frustum, None);
        self.latency = Some(lm);
        out
    }

    /// A warm start, at a level load or a camera cut, when no hit feedback
    /// speaks for the view yet: every live instance in `frustum` that
    /// `heuristic` accepts from `camera` and that is not active becomes
    /// active now, as [`Culling::mitigate_latency`] activates the newly
    /// visible ones (hitboxes too; the BLAS requests are returned), whether
    /// or not latency mitigation is configured and without touching its
    /// memory of what was visible. Hit feedback then deactivates what the
    /// paths do not reach (Algorithm 2 from this frame on; the BLASes go
    /// after the read-back latency): LiPaC starts from the view and culls
    /// down instead of starting from nothing.
    /// `ActivationHeuristic { max_distance: f32::INFINITY, .. }` takes the
    /// whole frustum, a [`ActivationHeuristic::surround_radius`] also what
    /// is near the camera off screen. Under the decayed rule
    /// [`CullingConfig::warm_start_hold`] holds what it activates for that
    /// many frames without hits (their rates raised on the CPU records now
    /// and on the GPU's through [`Uploads::hitbox_rate_floors`] and
    /// [`Uploads::instance_rate_floors`]). Fails for a non-finite camera or
    /// a heuristic with NaN or negative values, changing nothing.
    pub fn warm_start(
        &mut self,
        camera: Vec3,
        frustum: &Frustum,
        heuristic: ActivationHeuristic,
    ) -> Result<LatencyOutcome, CoreError> {
        // A fresh tracker has seen nothing: everything in view is new to it.
        let mut once = LatencyMitigation::new(heuristic)?;
        let hold = match &self.config.thresholds.rule {
            DecisionRule::Decayed(r) if self.config.warm_start_hold > 0 => Some((
                r.hold_rate(r.deactivate, self.config.warm_start_hold),
                r.hold_rate(r.instance_omit, self.config.warm_start_hold),
            )),
            _ => None,
        };
        self.activate_newly_visible(&mut once, camera, frustum, hold)
    }

    /// `tracker`'s newly visible instances ([`LatencyMitigation::update_with`],
    /// judged by the commanded state) made active now
    /// ([`Culling::activate_now`], with `hold`'s rate floors).
    fn activate_newly_visible(
        &mut self,
        tracker: &mut LatencyMitigation,
        camera: Vec3,
        frustum: &Frustum,
        hold: Option<(u32, u32)>,
    ) -> Result<LatencyOutcome, CoreError> {
        let mut activate = std::mem::take(&mut self.scratch);
        let registry = &self.registry;
        let summary = tracker.update_with(
            registry,
            camera,
            frustum,
            |slot| {
                registry
                    .table()
                    .get(slot as usize)
                    .is_some_and(|r| r.view.commanded_active)
            },
            &mut activate,
        );
        let out = summary.and_then(|summary| self.activate_now(&activate, summary, hold));
        self.scratch = activate;
        out
    }

    /// Makes the instances in `activate` (live slots the loop decided to
    /// activate on the CPU: latency mitigation, a warm start) active now,
    /// with their hitboxes, and returns the BLAS requests of those without
    /// one. `hold` (a held warm start): the least rates of their hitboxes
    /// and of their unique-BLAS instances, raised to on the CPU records
    /// now and on the GPU's through the upload's rate floors.
    fn activate_now(
        &mut self,
        activate: &[u32],
        summary: LatencySummary,
        hold: Option<(u32, u32)>,
    ) -> Result<LatencyOutcome, CoreError> {
        let frame = self.registry.frame();
        let mut out = LatencyOutcome {
            summary,
            ..LatencyOutcome::default()
        };
        for &slot in activate {
            let Some(handle) = self.registry.handle_at(slot) else {
                continue;
            };
            self.registry.set_state(slot, InstanceState::Active)?;
            self.state_overrides
                .insert(self.registry.table_mut(), slot, InstanceState::Active);
            let view = &mut self.registry.table_mut()[slot as usize].view;
            view.commanded_active = true;
            view.decided_at = frame;
            let record = self.registry.record_at(slot).unwrap_or_default();
            if let Some(h) = self.hitboxes.get_mut(record.hitbox as usize) {
                // Whether or not the hitbox is active: only a CPU backend's
                // records carry Algorithm 2's hitbox bits (a GPU backend's
                // never change here), so the decision may not read them.
                // Active with its streak zeroed, on the CPU records now and
                // on the GPU's through the override ([`apply_uploads`]).
                h.packed = (h.packed
                    & !((hitbox_bits::STREAK_MAX << hitbox_bits::STREAK_SHIFT)
                        | hitbox_bits::ACTIVE))
                    | hitbox_bits::ACTIVE;
                if self.hitbox_overrides.insert(record.hitbox, true) != Some(true) {
                    out.hitboxes_activated += 1;
                }
                if let Some((hitbox_floor, _)) = hold {
                    h.rate = h.rate.max(hitbox_floor);
                    let floor = self.hitbox_rate_floors.entry(record.hitbox).or_insert(0);
                    *floor = (*floor).max(hitbox_floor);
                }
            }
            if let Some((_, instance_floor)) = hold {
                // Only a unique-BLAS instance's rate decides (the others' are 0).
                if record.packed & instance_bits::UNIQUE_BLAS != 0 {
                    if let Some(r) = self.instance_rates.get_mut(slot as usize) {
                        *r = (*r).max(instance_floor);
                    }
                    let floor = self.instance_rate_floors.entry(slot).or_insert(0);
                    *floor = (*floor).max(instance_floor);
                }
            }
            if record.blas != 0 || self.registry.table()[slot as usize].view.awaiting {
                out.already_provided += 1;
            } else {
                self.registry.table_mut()[slot as usize].view.awaiting = true;
                out.requests.push(BlasRequest {
                    handle,
                    slot,
                    mesh: self.registry.mesh(handle)?,
                    lod: record.lod,
                    flags: InstanceFlags::from_bits_truncate(record.packed),
                });
            }
        }
        Ok(out)
    }

    /// Ingests one read-back: the commands Algorithm 2 wrote in frame
    /// `frame` (`counter` = the GPU's atomic counter, which may exceed
    /// `words.len()`: the overflow; `words` the stored words). The same call
    /// for CPU and GPU backends. Decodes and validates each stored word,
    /// drops commands for dead slots, sets each live slot's commanded state
    /// from the kind of its newest command (`add` → active, `remove` →
    /// inactive) unless the loop decided the slot's state itself at a frame
    /// after `frame` (registration, latency mitigation: the GPU had not seen
    /// that decision yet), and queues the commands, at most one per slot (the
    /// newest, see the [module docs](self) and [`CommandQueue`]). Never
    /// fails: bad words are counted.
    pub fn ingest_readback(&mut self, frame: u64, counter: u32, words: &[u32]) -> IngestSummary {
        let stored = (counter as usize).min(words.len());
        let limit = self.registry.slot_count();
        for &w in &words[..stored] {
            let Ok(c) = Command::decode(w, limit) else {
                continue; // counted by the queue's ingestion
            };
            if self.registry.handle_at(c.slot).is_none() {
                continue; // dead: counted by the queue's ingestion
            }
            if let Some(view) = self
                .registry
                .table_mut()
                .get_mut(c.slot as usize)
                .map(|r| &mut r.view)
            {
                if view.decided_at <= frame {
                    view.commanded_active = c.kind == CommandKind::Add;
                }
            }
        }
        let registry = &self.registry;
        self.queue
            .ingest_live(counter, words, registry.slot_count(), |slot| {
                registry.handle_at(slot).is_some()
            })
    }

    /// The commanded state of a live instance: whether the newest command
    /// ingested for it (or the loop's own decision since: registration,
    /// latency mitigation) says *active*. [`Culling::process_commands`]
    /// reconciles the BLAS against this, never against the records' state
    /// bits, which Algorithm 2 (CPU or GPU) writes (see the
    /// [module docs](self)).
    pub fn commanded_active(&self, handle: InstanceHandle) -> Result<bool, CoreError> {
        let slot = self.registry.slot(handle)?;
        Ok(self.registry.table()[slot as usize].view.commanded_active)
    }

    /// Takes up to `budget` pending commands, highest priority first, and
    /// reconciles each instance's BLAS with its commanded state (see the
    /// [module docs](self) for the table). What the caller must do is
    /// written into `events` (cleared first), in processing order:
    ///
    /// * [`BlasAction::Acquire`]: the instance now waits for a BLAS; provide
    ///   it with [`Culling::set_blas`];
    /// * [`BlasAction::Release`]: the record's BLAS was cleared; release it;
    /// * [`BlasAction::CancelBuild`]: the instance no longer waits; cancel
    ///   its build.
    ///
    /// Commands the budget leaves over wait for the next call.
    pub fn process_commands(
        &mut self,
        budget: usize,
        events: &mut Vec<CommandEvent>,
    ) -> ProcessStats {
        events.clear();
        let mut st = ProcessStats::default();
        for c in self.queue.drain(budget) {
            st.drained += 1;
            let Some(handle) = self.registry.handle_at(c.slot) else {
                st.dead += 1;
                continue;
            };
            let slot = c.slot as usize;
            let record = self.registry.record_at(c.slot).unwrap_or_default();
            let Ok(mesh) = self.registry.mesh(handle) else {
                st.dead += 1;
                continue;
            };
            let active = self.registry.table()[slot].view.commanded_active;
            if active != (c.kind == CommandKind::Add) {
                st.stale_kind += 1;
            }
            let mut event = |action| {
                events.push(CommandEvent {
                    handle,
                    slot: c.slot,
                    mesh,
                    lod: record.lod,
                    flags: InstanceFlags::from_bits_truncate(record.packed),
                    priority: c.priority,
                    command: c.kind,
                    action,
                })
            };
            if active {
                if record.blas != 0 || self.registry.table()[slot].view.awaiting {
                    st.no_op += 1;
                    continue;
                }
                self.registry.table_mut()[slot].view.awaiting = true;
                st.requested += 1;
                event(BlasAction::Acquire);
            } else {
                let mut acted = false;
                if record.blas != 0 {
                    // The slot is live: cannot fail.
                    let _ = self.registry.set_blas_at(c.slot, 0);
                    event(BlasAction::Release { blas: record.blas });
                    st.released += 1;
                    acted = true;
                }
                if std::mem::take(&mut self.registry.table_mut()[slot].view.awaiting) {
                    event(BlasAction::CancelBuild);
                    st.builds_cancelled += 1;
                    acted = true;
                }
                if !acted {
                    st.no_op += 1;
                }
            }
        }
        st.remaining = self.queue.len() as u32;
        st
    }

    /// What a GPU backend uploads before Algorithm 1: the dirty record ranges
    /// and the CPU's state-bit writes since the last call (see
    /// [`Uploads`]). The CPU reference needs none of it.
    pub fn take_uploads(&mut self) -> Uploads {
        let state_overrides = self.state_overrides.take(self.registry.table_mut());
        let mut hitbox_overrides: Vec<(u32, bool)> = self.hitbox_overrides.drain().collect();
        hitbox_overrides.sort_unstable_by_key(|&(i, _)| i);
        let floors = |map: &mut HashMap<u32, u32>| {
            let mut v: Vec<(u32, u32)> = map.drain().collect();
            v.sort_unstable_by_key(|&(i, _)| i);
            v
        };
        self.refresh_extents();
        let mut hitbox_extents: Vec<(u32, HitboxExtent)> = self.extent_uploads.drain().collect();
        hitbox_extents.sort_unstable_by_key(|&(i, _)| i);
        Uploads {
            hitbox_extents,
            records: self.registry.take_dirty(),
            state_overrides,
            hitbox_overrides,
            hitbox_rate_floors: floors(&mut self.hitbox_rate_floors),
            instance_rate_floors: floors(&mut self.instance_rate_floors),
        }
    }

    /// Brings the hitboxes' extents ([`crate::hitbox_extents`]) up to the
    /// records written since the last call, noting the changed ones for the
    /// GPU.
    fn refresh_extents(&mut self) {
        let touched = self.registry.take_touched();
        if touched.is_empty() {
            return;
        }
        self.sync_hitbox_count();
        let mut changed = std::mem::take(&mut self.extent_changes);
        self.extents.refresh(
            self.registry.records(),
            touched.into_iter().flatten(),
            &mut self.hitboxes,
            &mut changed,
        );
        self.extent_uploads.extend(changed.drain(..));
        self.extent_changes = changed;
    }

    /// Algorithm 1 ([`assemble_tlas_adaptive`]) over the registry's records: fills
    /// `out` (cleared first) with this frame's TLAS instances.
    pub fn assemble(&mut self, out: &mut Vec<TlasInstance>) -> Result<AssemblyStats, CoreError> {
        self.refresh_extents();
        assemble_tlas_adaptive(
            self.registry.records(),
            &mut self.hitboxes,
            self.registry.hitbox_index(),
            &self.config.assembly,
            self.tree.as_ref(),
            out,
        )
        .map_err(CoreError::Assembly)
    }

    /// Algorithm 2 ([`process_feedback_with_rates`]) over this frame's hits: hitbox and
    /// instance transitions, commands into the bounded buffer. Once per
    /// frame, after the previous frame's commands were taken. With
    /// [`Selection::EngineSelected`] it changes nothing and writes no
    /// command (the call order still holds).
    pub fn process_feedback(&mut self) -> Result<FeedbackStats, CoreError> {
        if self.fed_back {
            return Err(CoreError::CallOrder {
                what: format!(
                    "feedback of frame {} was already processed",
                    self.registry.frame()
                ),
            });
        }
        if self.untaken {
            return Err(CoreError::CallOrder {
                what: "the previous feedback's commands were not taken (take_commands)".into(),
            });
        }
        self.commands.clear();
        if self.config.selection == Selection::EngineSelected {
            // No hit feedback: nothing moves, no command is written.
            self.fed_back = true;
            self.untaken = true;
            return Ok(FeedbackStats::default());
        }
        let stats = process_feedback_with_rates(
            self.registry.records_hot_mut(),
            &self.instance_hits,
            &mut self.instance_rates,
            &mut self.hitboxes,
            &self.config.thresholds,
            &mut self.commands,
        )
        .map_err(CoreError::Feedback)?;
        self.fed_back = true;
        self.untaken = true;
        Ok(stats)
    }

    /// The commands of this frame's feedback, for the read-back ring;
    /// `None` if there are none to take (no feedback since the last take).
    pub fn take_commands(&mut self) -> Option<Readback> {
        if !std::mem::take(&mut self.untaken) {
            return None;
        }
        let readback = Readback {
            frame: self.registry.frame(),
            counter: self.commands.requested(),
            words: self.commands.words().to_vec(),
        };
        self.commands.clear();
        Some(readback)
    }
}

/// The command loop's column of the slot table ([`crate::slot_table`]): its
/// view of one slot.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct SlotView {
    /// The commanded state: the newest ingested command said `add`, or the
    /// loop's last decision (latency mitigation) made it active.
    commanded_active: bool,
    /// An `Acquire` was answered `None` (or latency mitigation requested a
    /// BLAS) and no address has come yet.
    awaiting: bool,
    /// The frame of the loop's last decision about the state (registration,
    /// latency mitigation). Commands Algorithm 2 wrote before it do not move
    /// the commanded state: the GPU had not seen the decision.
    decided_at: u64,
    /// The CPU's state write since the last upload ([`StateOverrides`]).
    state_override: u8,
}

mod readback_ring;
mod state_overrides;
mod uploads;
pub use readback_ring::{Readback, ReadbackRing};
use state_overrides::StateOverrides;
pub use uploads::{apply_uploads, Uploads};

#[cfg(test)]
mod tests;
