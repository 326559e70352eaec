//! The CPU backend: one [`lipac_core::manager::Manager`] driven the way an
//! engine drives its GPU backend, with the BLAS work accounted instead of
//! run. Every strategy of the comparison runs on it: LiPaC
//! ([`crate::strategy::lipac`], and the hits-only replay
//! [`crate::replay::hits`]) with hit feedback ([`CpuBackend::new`]), the
//! baselines with the set they choose each frame
//! ([`CpuBackend::engine_selected`], [`CpuBackend::set_pinned`]).
//!
//! Per frame `f` a caller does, in order:
//!
//! 1. **End of frame `f − 1`** (not before the first frame): the traced hit
//!    counters into [`CpuBackend::instance_hits_mut`] /
//!    [`CpuBackend::hitboxes_mut`], then [`CpuBackend::end_frame`]:
//!    Algorithm 2 ([`Manager::process_feedback`]) and its commands
//!    ([`Manager::take_commands`]) into a read-back ring of
//!    [`LipacConfig::readback_latency`] frames.
//! 2. [`CpuBackend::begin_frame`], then the frame's instance changes
//!    (register, update, move, LOD, remove).
//! 3. [`CpuBackend::run`]: at the first run (and after
//!    [`CpuBackend::warm_start_again`]) the warm start, if configured
//!    ([`LipacConfig::warm_start`]; that frame's builds unbudgeted), latency
//!    mitigation (if configured), the commands
//!    of frame `f − k` ([`Manager::ingest_readback`]), [`Manager::plan`]
//!    under the frame's budgets, the plan executed, and Algorithm 1
//!    ([`Manager::assemble`]) into the caller's TLAS records.
//!
//! # Executing a plan
//!
//! The sim traces one shared set of BLASes for every strategy
//! ([`crate::blas::BlasStore`]), so the backend does not build on obvhs: it
//! accounts what a GPU backend would do (builds, refits and rebuilds by
//! triangle count; frees) and acknowledges every operation at once through
//! [`Manager::handle_ack`], as a synchronous backend would:
//!
//! * builds: [`Ack::Built`] with the planned size at a fresh token address;
//! * compactable builds: [`Ack::CompactedSize`] with the full size (lavapipe
//!   compaction gains nothing, [`crate::memory`]);
//! * compactions: [`Ack::Compacted`] at a fresh token address;
//! * data uploads and buffer growth: nothing to do (the records live in the
//!   Manager; no GPU buffer exists).
//!
//! # Frame numbers
//!
//! The Manager sees frame `f + 1` for the caller's frame `f`: its BLAS
//! scheduler starts at frame 0, and unique-BLAS rebuilds fall on
//! `(frame + slot) % interval == 0`, as in the comparison's earlier runs.

use lipac_core::blas_ids::BuildId;
use lipac_core::build_plan::{PriorityConfig, SchedulerConfig};
use lipac_core::controller::ControllerConfig;
use lipac_core::culling::{CullingConfig, ReadbackRing, Selection};
use lipac_core::grid::HitboxGrid;
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::instance::InstanceDesc;
use lipac_core::latency::{ActivationHeuristic, Frustum};
use lipac_core::layout::{HitboxRecord, InstanceRecord, TlasInstance};
use lipac_core::manager::{
    Ack, DataConfig, FrameBudgets, InstanceView, Manager, ManagerConfig, ManagerPlan, MeshCatalog,
};
use lipac_core::math::Aabb;
use lipac_core::registry::{InstanceHandle, RegistryConfig};

use crate::camera::FlyCamera;
use crate::error::SimError;
use crate::strategy::lipac::LipacConfig;
use crate::strategy::BlasWork;
use crate::tlas::CountingBoxes;

fn core<E: std::fmt::Display>(e: E) -> SimError {
    SimError::core(e)
}

/// What one [`CpuBackend::run`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BackendFrame {
    /// BLAS work of the plan.
    pub work: BlasWork,
    /// Commands accepted from the read-back this frame.
    pub commands_ingested: u32,
    /// Commands processed this frame.
    pub commands_processed: u32,
    /// Commands still pending after this frame.
    pub commands_pending: u32,
    /// Instances activated by latency mitigation or the warm start.
    pub latency_activations: u32,
}

/// The scheduler settings of the comparison: memory is measured, not
/// limited; unreferenced shared BLASes stay cached for 8 frames (then are
/// freed after the frames in flight); LOD switches wait 8 frames.
fn scheduler_config(priority: PriorityConfig) -> SchedulerConfig {
    let mut config = SchedulerConfig::default();
    config.cache.memory_budget = u64::MAX / 4;
    config.cache.max_unused_frames = 8;
    config.lod_hysteresis_frames = 8;
    config.priority = priority;
    config
}

/// One [`Manager`], its read-back ring and the plan execution (module docs).
/// `H` is the Manager's hitbox structure (the dense grid by default; a
/// trace replay uses [`lipac_core::WorldHitboxes`]).
#[derive(Debug)]
pub struct CpuBackend<H: HitboxIndex = HitboxGrid> {
    manager: Manager<H>,
    ring: ReadbackRing,
    budgets: FrameBudgets,
    latency_mitigation: bool,
    /// The warm start still to make at the next [`CpuBackend::run`].
    warm_start: Option<ActivationHeuristic>,
    /// The configured warm start ([`LipacConfig::warm_start`]).
    warm_start_heuristic: Option<ActivationHeuristic>,
    next_address: u64,
    /// The Manager frame of the last `begin_frame` whose feedback is due.
    open_frame: Option<u64>,
}

impl<H: HitboxIndex> CpuBackend<H> {
    /// A Manager over `grid` with the meshes of `catalog`, configured from
    /// `config` (thresholds, latency mitigation, command capacity and budget,
    /// read-back latency, build budgets and priorities). Fails for an
    /// invalid configuration, or if the Manager's counting boxes differ from
    /// the tracer's ([`CountingBoxes`]).
    pub fn new(grid: H, config: &LipacConfig, catalog: MeshCatalog) -> Result<Self, SimError> {
        config.thresholds.validate().map_err(core)?;
        if config.readback_latency == 0 || config.command_budget == 0 {
            return Err(SimError::BadConfig(
                "readback latency and command budget must be positive",
            ));
        }
        // The tracer's unit cube: BlasStore::new() puts it at index 0.
        let unit_cube = crate::blas::BlasStore::new().unit_cube().reference();
        let culling = CullingConfig {
            registry: RegistryConfig {
                quarantine_frames: config.readback_latency + 2,
                ..RegistryConfig::default()
            },
            thresholds: config.thresholds,
            command_capacity: config.command_capacity,
            latency_mitigation: config.latency,
            readback_latency: config.readback_latency,
            adaptive_hitboxes: config.adaptive_hitboxes,
            warm_start_hold: config.warm_start_hold,
            ..CullingConfig::new(unit_cube)
        };
        let counting = CountingBoxes::default();
        if culling.assembly.omitted_box_sbt_offset != counting.instance_box_sbt
            || culling.assembly.hitbox_sbt_offset != counting.hitbox_box_sbt
            || culling.assembly.counting_mask != counting.counting_mask
            || (culling.adaptive_hitboxes.is_on()
                && culling.adaptive_hitboxes.merged_box_sbt_offset != counting.merged_box_sbt)
        {
            return Err(SimError::BadConfig(
                "assembly and tracer disagree on counting boxes",
            ));
        }
        let manager_config = ManagerConfig {
            culling,
            scheduler: scheduler_config(config.build_priority),
            data: DataConfig::default(),
            target: config.target,
            controller: config.controller,
        };
        Ok(Self {
            manager: Manager::new(grid, manager_config, catalog).map_err(core)?,
            ring: ReadbackRing::new(config.readback_latency).map_err(core)?,
            budgets: FrameBudgets {
                commands: config.command_budget,
                builds: config.build_budgets,
            },
            latency_mitigation: config.latency.is_some(),
            warm_start: config.warm_start,
            warm_start_heuristic: config.warm_start,
            next_address: 0x1000,
            open_frame: None,
        })
    }

    /// A Manager over `grid` with the meshes of `catalog` whose set the
    /// caller chooses ([`Selection::EngineSelected`]: exactly the pinned
    /// instances are active, no counting boxes, no hit feedback): the
    /// baselines of [`crate::strategy`]. Commands and builds are not
    /// budgeted (the set is complete every frame), build priorities are the
    /// scheduler's defaults, the read-back latency is 2 frames.
    pub fn engine_selected(grid: H, catalog: MeshCatalog) -> Result<Self, SimError> {
        let readback_latency = 2;
        let culling = CullingConfig {
            registry: RegistryConfig {
                quarantine_frames: readback_latency + 2,
                ..RegistryConfig::default()
            },
            latency_mitigation: None,
            readback_latency,
            selection: Selection::EngineSelected,
            ..CullingConfig::new(crate::blas::BlasStore::new().unit_cube().reference())
        };
        let manager_config = ManagerConfig {
            culling,
            scheduler: scheduler_config(PriorityConfig::default()),
            data: DataConfig::default(),
            target: None,
            controller: ControllerConfig::default(),
        };
        Ok(Self {
            manager: Manager::new(grid, manager_config, catalog).map_err(core)?,
            ring: ReadbackRing::new(readback_latency).map_err(core)?,
            budgets: FrameBudgets {
                commands: usize::MAX,
                builds: crate::strategy::unlimited_budgets(),
            },
            latency_mitigation: false,
            warm_start: None,
            warm_start_heuristic: None,
            next_address: 0x1000,
            open_frame: None,
        })
    }

    /// The Manager (read-only: statistics, catalog, instance views).
    pub fn manager(&self) -> &Manager<H> {
        &self.manager
    }

    /// The Manager, e.g. to attach a trace recorder
    /// ([`Manager::attach_recorder`]) and pass it the camera. Driving its
    /// frame (begin, plan, feedback) directly bypasses this backend.
    pub fn manager_mut(&mut self) -> &mut Manager<H> {
        &mut self.manager
    }

    // ---- instances ------------------------------------------------------

    /// Reserves room for `additional` more instances (an error when the
    /// memory cannot be had).
    pub fn reserve(&mut self, additional: usize) -> Result<(), SimError> {
        self.manager.reserve(additional).map_err(core)
    }
    /// Registers an instance ([`Manager::register`]).
    pub fn register(&mut self, desc: InstanceDesc) -> Result<InstanceHandle, SimError> {
        self.manager.register(desc).map_err(core)
    }
    /// Replaces an instance's description ([`Manager::update`]).
    pub fn update(&mut self, handle: InstanceHandle, desc: InstanceDesc) -> Result<(), SimError> {
        self.manager.update(handle, desc).map(|_| ()).map_err(core)
    }
    /// Moves an instance ([`Manager::set_transform`]).
    pub fn set_transform(
        &mut self,
        handle: InstanceHandle,
        transform: glam::Affine3A,
        aabb: Aabb,
    ) -> Result<(), SimError> {
        self.manager
            .set_transform(handle, transform, aabb)
            .map_err(core)
    }
    /// Requests a LOD ([`Manager::set_lod`]).
    pub fn set_lod(&mut self, handle: InstanceHandle, lod: u32) -> Result<(), SimError> {
        self.manager.set_lod(handle, lod).map(|_| ()).map_err(core)
    }
    /// Pins or unpins an instance ([`Manager::set_pinned`]): with
    /// [`CpuBackend::engine_selected`], selects it for the TLAS or drops it.
    pub fn set_pinned(&mut self, handle: InstanceHandle, pinned: bool) -> Result<(), SimError> {
        self.manager
            .set_pinned(handle, pinned)
            .map(|_| ())
            .map_err(core)
    }
    /// Removes an instance ([`Manager::remove`]).
    pub fn remove(&mut self, handle: InstanceHandle) -> Result<(), SimError> {
        self.manager.remove(handle).map(|_| ()).map_err(core)
    }
    /// One instance's view ([`Manager::instance`]).
    pub fn instance(&self, handle: InstanceHandle) -> Result<InstanceView, SimError> {
        self.manager.instance(handle).map_err(core)
    }
    /// One instance's GPU record (state, hitbox, BLAS, LOD; a copy of
    /// [`Manager::records`] at its slot).
    pub fn record(&self, handle: InstanceHandle) -> Result<InstanceRecord, SimError> {
        let slot = self.instance(handle)?.slot;
        self.manager
            .records()
            .get(slot as usize)
            .ok_or(SimError::UnknownInstance(slot))
    }

    // ---- hits -------------------------------------------------------------

    /// The per-slot hit counters of the frame being traced.
    pub fn instance_hits_mut(&mut self) -> &mut [u32] {
        self.manager.instance_hits_mut()
    }
    /// The hitbox records, for counting-box hits.
    pub fn hitboxes_mut(&mut self) -> &mut [HitboxRecord] {
        self.manager.hitboxes_mut()
    }
    /// The hitbox records.
    pub fn hitboxes(&self) -> &[HitboxRecord] {
        self.manager.hitboxes()
    }
    /// Instance slots (live, dead or quarantined): LiPaC's per-slot buffers.
    pub fn slot_count(&self) -> u32 {
        self.manager.records().len() as u32
    }
    /// Bytes of every BLAS the Manager holds (built, building, cached,
    /// compacted).
    pub fn blas_bytes(&self) -> u64 {
        let m = self.manager.stats().memory;
        m.blas_shared + m.blas_unique + m.blas_compacted
    }

    // ---- the frame --------------------------------------------------------

    /// Ends the frame begun last (step 1 of the module docs): Algorithm 2
    /// over the hits written since, its commands into the read-back ring.
    /// Does nothing before the first frame.
    pub fn end_frame(&mut self) -> Result<(), SimError> {
        if self.open_frame.take().is_none() {
            return Ok(());
        }
        self.manager.process_feedback().map_err(core)?;
        if let Some(r) = self.manager.take_commands() {
            self.ring.push(r).map_err(core)?;
        }
        Ok(())
    }

    /// Whether a frame was begun and not yet ended.
    pub fn frame_open(&self) -> bool {
        self.open_frame.is_some()
    }

    /// Makes the configured warm start ([`LipacConfig::warm_start`]) again at
    /// the next [`CpuBackend::run`], with that frame's builds unbudgeted: at
    /// a camera cut. Does nothing without one.
    pub fn warm_start_again(&mut self) {
        self.warm_start = self.warm_start_heuristic;
    }

    /// Starts frame `frame` (the Manager's `frame + 1`, module docs). The
    /// previous frame must have been ended.
    pub fn begin_frame(&mut self, frame: u32) -> Result<(), SimError> {
        if self.open_frame.is_some() {
            return Err(SimError::Core(
                "CpuBackend::begin_frame before end_frame".into(),
            ));
        }
        let f = u64::from(frame) + 1;
        self.manager.begin_frame(f).map_err(core)?;
        self.open_frame = Some(f);
        Ok(())
    }

    /// Step 3 of the module docs: latency mitigation from `camera` (used
    /// only if configured), the ready read-backs, the plan, its execution
    /// and Algorithm 1 into `out` (cleared first).
    pub fn run(
        &mut self,
        camera: &FlyCamera,
        out: &mut Vec<TlasInstance>,
    ) -> Result<BackendFrame, SimError> {
        let frame = self
            .open_frame
            .ok_or_else(|| SimError::Core("CpuBackend::run before begin_frame".into()))?;
        let mut stats = BackendFrame::default();
        let warm = self.warm_start.take();
        if let Some(h) = warm {
            let frustum = Frustum::from_view_projection(camera.view_proj()).map_err(core)?;
            let outcome = self
                .manager
                .warm_start(camera.position, &frustum, h)
                .map_err(core)?;
            stats.latency_activations += outcome.summary.accepted;
        }
        if self.latency_mitigation {
            let frustum = Frustum::from_view_projection(camera.view_proj()).map_err(core)?;
            let outcome = self
                .manager
                .mitigate_latency(camera.position, &frustum)
                .map_err(core)?;
            stats.latency_activations += outcome.summary.accepted;
        }
        while let Some(r) = self.ring.pop_ready(frame) {
            stats.commands_ingested += self
                .manager
                .ingest_readback(r.frame, r.counter, &r.words)
                .accepted;
        }
        // A warm start's frame is a load: its builds are not budgeted.
        let load;
        let budgets = if warm.is_some() {
            load = FrameBudgets {
                commands: self.budgets.commands,
                builds: crate::strategy::unlimited_budgets(),
            };
            &load
        } else {
            &self.budgets
        };
        let plan = self.manager.plan(budgets).map_err(core)?;
        stats.commands_processed = plan.commands.drained;
        stats.commands_pending = plan.commands.remaining;
        stats.work = self.execute(&plan)?;
        self.manager.assemble(out).map_err(core)?;
        Ok(stats)
    }

    /// Executes `plan` synchronously (module docs) and returns its work.
    fn execute(&mut self, plan: &ManagerPlan) -> Result<BlasWork, SimError> {
        let blas = &plan.blas;
        let work = BlasWork::of_plan(blas);
        let mut queried: Vec<(BuildId, u64)> = Vec::new();
        for b in blas.builds() {
            let address = self.fresh_address();
            self.ack(Ack::Built {
                build: b.id,
                result_bytes: b.result_bytes,
                address,
            })?;
            if b.allow_compaction {
                queried.push((b.id, b.result_bytes));
            }
        }
        for (build, bytes) in queried {
            self.ack(Ack::CompactedSize {
                build,
                compacted_bytes: bytes,
            })?;
        }
        for c in &blas.compactions {
            let address = self.fresh_address();
            self.ack(Ack::Compacted { op: c.id, address })?;
        }
        Ok(work)
    }

    fn fresh_address(&mut self) -> u64 {
        self.next_address += 0x100;
        self.next_address
    }

    fn ack(&mut self, ack: Ack) -> Result<(), SimError> {
        self.manager.handle_ack(ack).map_err(core)
    }

    /// Read-backs in the ring (written, not yet ingested).
    pub fn readbacks_in_flight(&self) -> usize {
        self.ring.len()
    }
}

#[cfg(test)]
mod tests;
