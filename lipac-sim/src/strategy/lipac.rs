//! LiPaC driven as an engine drives a GPU backend: one
//! [`lipac_core::culling::Culling`] per-frame loop, a [`ReadbackRing`] of
//! `k` frames, and a [`BlasAccounting`] build scheduler as the backend's BLAS
//! manager.
//!
//! Per frame `f`, in order:
//!
//! 1. **End of frame `f − 1`**: the tracer's counters of frame `f − 1` are
//!    written into the loop's hit buffers, [`Culling::process_feedback`]
//!    runs Algorithm 2 and [`Culling::take_commands`] goes into the ring.
//! 2. [`Culling::begin_frame`]; animated units' transforms.
//! 3. [`Culling::mitigate_latency`] (optional, paper §3.6): its BLAS
//!    requests go to the scheduler.
//! 4. [`Culling::ingest_readback`] of the commands of frame `f − k`, then
//!    [`Culling::process_commands`] under the command budget; its events
//!    request BLASes from the scheduler (or release them).
//! 5. The scheduler plans this frame's builds under its budgets; they are
//!    acknowledged at once (the CPU backend builds synchronously), and the
//!    addresses go back through [`Culling::set_blas`].
//! 6. [`Culling::assemble`] (Algorithm 1). Geometry records get this frame's
//!    BLAS from the shared geometry; the caller traces the records (counting
//!    boxes count by custom index: slot or hitbox index) and hands the
//!    counters back as `previous` next frame.
//!
//! Registry slots are assigned in scene order and checked to equal scene
//! slots, so custom indices, counters and commands all speak scene slots.

use lipac_core::build_plan::BuildBudgets;
use lipac_core::culling::{BlasAction, Culling, CullingConfig, ReadbackRing};
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::instance::{InstanceDesc, InstanceFlags, MeshId};
use lipac_core::latency::{ActivationHeuristic, Frustum};
use lipac_core::layout::{InstanceRecord, InstanceState, TlasInstance};
use lipac_core::registry::{InstanceHandle, RegistryConfig};
use lipac_core::thresholds::Thresholds;

use super::{BlasAccounting, FrameContext, Strategy, StrategyFrame};
use crate::error::SimError;
use crate::memory::{blas_bytes, lipac_overhead_bytes};
use crate::scene::{flags, Scene};
use crate::scene_blas::instance_mask;
use crate::tlas::CountingConfig;
use crate::trace::Counters;

/// Settings of [`Lipac`].
#[derive(Clone, Debug, PartialEq)]
pub struct LipacConfig {
    /// Culling thresholds (scale them with
    /// [`Thresholds::for_rays_per_frame`]).
    pub thresholds: Thresholds,
    /// Hitbox cell size, metres (paper: 16; default here
    /// [`LipacConfig::DEFAULT_CELL_SIZE`]).
    pub cell_size: f64,
    /// Latency mitigation with this heuristic, or none.
    pub latency: Option<ActivationHeuristic>,
    /// Commands processed per frame; the rest wait (highest hits first).
    pub command_budget: usize,
    /// Capacity of the GPU command buffer per frame.
    pub command_capacity: u32,
    /// Frames between Algorithm 2 and the CPU reading its commands.
    pub readback_latency: u32,
    /// BLAS build budgets per frame.
    pub build_budgets: BuildBudgets,
}

impl LipacConfig {
    /// Default hitbox cell size, metres: 32, not the paper's 16. At the
    /// comparison's ray counts (9,216 camera rays per frame against the
    /// paper's 2 M) a 16 m cell collects too few hits to rise above noise,
    /// and the 2 km city's ~12.6k 16 m counting boxes cost ~2.2 MiB of TLAS.
    /// `lipac sweep` on the 270-frame fly-through (docs/EVALUATION.md, "Run
    /// time against error"): 32 m cells gave error 0.144 at 9.24 MiB against
    /// 0.217 at 10.11 MiB for 16 m (city; the mirror city alike), the
    /// lowest memory of 16–128 m; coarser cells trade a little memory for
    /// less error.
    pub const DEFAULT_CELL_SIZE: f64 = 32.0;

    /// Paper settings for `rays_per_frame` camera rays: scaled thresholds,
    /// [`Self::DEFAULT_CELL_SIZE`] cells, readback after 2 frames, 4096 commands per frame,
    /// the scheduler's default build budgets (64 builds, 4 Mi triangles).
    pub fn for_rays_per_frame(rays_per_frame: u64) -> Result<Self, SimError> {
        Ok(Self {
            thresholds: Thresholds::for_rays_per_frame(rays_per_frame as f64)
                .map_err(SimError::core)?,
            cell_size: Self::DEFAULT_CELL_SIZE,
            latency: None,
            command_budget: 4096,
            command_capacity: 1 << 16,
            readback_latency: 2,
            build_budgets: BuildBudgets::default(),
        })
    }
    /// The same with latency mitigation (lipac-core's default heuristic).
    pub fn with_latency_mitigation(mut self) -> Self {
        self.latency = Some(ActivationHeuristic::default());
        self
    }
}

/// Counts of LiPaC's own state, per frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LipacFrameStats {
    /// Commands accepted from the read-back this frame.
    pub commands_ingested: u32,
    /// Commands processed this frame.
    pub commands_processed: u32,
    /// Commands still pending after this frame.
    pub commands_pending: u32,
    /// Instances activated by latency mitigation.
    pub latency_activations: u32,
    /// Active hitboxes.
    pub active_hitboxes: u32,
}

/// The LiPaC strategy (see the module docs).
#[derive(Debug)]
pub struct Lipac {
    name: &'static str,
    config: LipacConfig,
    culling: Culling<HitboxGrid>,
    ring: ReadbackRing,
    handles: Vec<InstanceHandle>,
    units: Vec<u32>,
    blas: BlasAccounting,
    stats: LipacFrameStats,
    started: bool,
}

fn core<E: std::fmt::Display>(e: E) -> SimError {
    SimError::core(e)
}

impl Lipac {
    /// Registers every instance of `scene` (frame 0 state) in a
    /// [`Culling`] loop whose hitbox grid covers the scene.
    pub fn new(scene: &Scene, config: LipacConfig) -> Result<Self, SimError> {
        config.thresholds.validate().map_err(core)?;
        if config.readback_latency == 0 || config.command_budget == 0 {
            return Err(SimError::BadConfig(
                "readback latency and command budget must be positive",
            ));
        }
        let b = scene.bounds();
        let c = config.cell_size;
        let grid = HitboxGrid::new(GridConfig {
            min: [
                (f64::from(b.min.x) / c).floor() * c,
                (f64::from(b.min.z) / c).floor() * c,
            ],
            max: [
                ((f64::from(b.max.x) / c).floor() + 1.0) * c,
                ((f64::from(b.max.z) / c).floor() + 1.0) * c,
            ],
            cell_size: c,
        })
        .map_err(core)?;
        // The tracer's unit cube: BlasStore::new() puts it at index 0.
        let unit_cube = crate::blas::BlasStore::new().unit_cube().reference();
        let cc = CullingConfig {
            registry: RegistryConfig {
                quarantine_frames: config.readback_latency + 2,
                ..RegistryConfig::default()
            },
            thresholds: config.thresholds,
            command_capacity: config.command_capacity,
            latency_mitigation: config.latency,
            readback_latency: config.readback_latency,
            ..CullingConfig::new(unit_cube)
        };
        let counting = CountingConfig::default();
        if cc.assembly.omitted_box_sbt_offset != counting.instance_box_sbt
            || cc.assembly.hitbox_sbt_offset != counting.hitbox_box_sbt
            || cc.assembly.counting_mask != counting.counting_mask
        {
            return Err(SimError::BadConfig(
                "assembly and tracer disagree on counting boxes",
            ));
        }
        let mut culling = Culling::new(grid, cc).map_err(core)?;
        let mut handles = Vec::with_capacity(scene.instances().len());
        let mut units = Vec::new();
        for (slot, inst) in scene.instances().iter().enumerate() {
            let mut f = InstanceFlags::empty();
            if inst.is_unique() {
                f |= InstanceFlags::UNIQUE_BLAS;
            }
            if inst.is_vegetation() {
                f |= InstanceFlags::VEGETATION;
            }
            if inst.flags & flags::STATIC != 0 {
                f |= InstanceFlags::STATIC;
            }
            if inst.is_animated() {
                units.push(slot as u32);
            }
            let desc = InstanceDesc {
                flags: f,
                mask: instance_mask(inst),
                ..InstanceDesc::new(MeshId(inst.mesh), inst.transform, inst.aabb)
            };
            let h = culling.register(desc).map_err(core)?;
            // Registry slots must equal scene slots: counters, custom indices
            // and commands are all indexed by them.
            let got = culling.registry().slot(h).map_err(core)?;
            if got != slot as u32 {
                return Err(SimError::Core(format!(
                    "registry slot {got} for scene slot {slot}"
                )));
            }
            handles.push(h);
        }
        let n = handles.len();
        Ok(Self {
            name: if config.latency.is_some() {
                "lipac-latency"
            } else {
                "lipac"
            },
            ring: ReadbackRing::new(config.readback_latency).map_err(core)?,
            blas: BlasAccounting::new(n, config.build_budgets)?,
            config,
            culling,
            handles,
            units,
            stats: LipacFrameStats::default(),
            started: false,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &LipacConfig {
        &self.config
    }
    /// The state of instance `slot`.
    pub fn state(&self, slot: u32) -> Option<InstanceState> {
        self.culling
            .registry()
            .record_at(slot)
            .map(InstanceRecord::state)
    }
    /// The per-frame loop (registry, hitboxes, commands).
    pub fn culling(&self) -> &Culling<HitboxGrid> {
        &self.culling
    }
    /// Counts of the last frame.
    pub fn last_stats(&self) -> LipacFrameStats {
        self.stats
    }

    /// Step 1: the hits of the previous frame, Algorithm 2, its commands
    /// into the ring.
    fn feedback(&mut self, previous: &Counters) -> Result<(), SimError> {
        let hits = self.culling.instance_hits_mut();
        if previous.instances.len() != hits.len() {
            return Err(SimError::SizeMismatch {
                a: previous.instances.len(),
                b: hits.len(),
            });
        }
        hits.copy_from_slice(&previous.instances);
        for (h, &c) in self
            .culling
            .hitboxes_mut()
            .iter_mut()
            .zip(&previous.hitboxes)
        {
            h.add_hits(c);
        }
        self.culling.process_feedback().map_err(core)?;
        if let Some(r) = self.culling.take_commands() {
            self.ring.push(r).map_err(core)?;
        }
        Ok(())
    }
}

impl Strategy for Lipac {
    fn name(&self) -> &str {
        self.name
    }
    fn hitboxes(&self) -> usize {
        self.culling.hitboxes().len()
    }
    fn frame(
        &mut self,
        ctx: &FrameContext<'_>,
        previous: Option<&Counters>,
        out: &mut Vec<TlasInstance>,
    ) -> Result<StrategyFrame, SimError> {
        if ctx.full_records.len() != self.handles.len() {
            return Err(SimError::SizeMismatch {
                a: ctx.full_records.len(),
                b: self.handles.len(),
            });
        }
        self.stats = LipacFrameStats::default();
        if self.started {
            // A frame whose counters are missing still runs Algorithm 2
            // (with no hits) so that the loop's call order holds.
            match previous {
                Some(p) => self.feedback(p)?,
                None => self.feedback(&Counters::new(self.handles.len(), 0))?,
            }
        }
        self.started = true;

        // 2. Frame start, animated units.
        let frame = u64::from(ctx.frame);
        self.culling.begin_frame(frame).map_err(core)?;
        self.blas.begin_frame(ctx.frame)?;
        for &slot in &self.units {
            let inst = ctx.scene.instance(slot)?;
            self.culling
                .set_transform(self.handles[slot as usize], inst.transform, inst.aabb)
                .map_err(core)?;
        }

        // 3. Latency mitigation.
        if self.config.latency.is_some() {
            let frustum = Frustum::from_view_projection(ctx.camera.view_proj()).map_err(core)?;
            let outcome = self
                .culling
                .mitigate_latency(ctx.camera.position, &frustum)
                .map_err(core)?;
            self.stats.latency_activations = outcome.summary.accepted;
            for r in outcome.requests {
                let lod = usize::from(ctx.lods[r.slot as usize]);
                self.blas.activate(ctx.catalog, r.slot, lod)?;
                // A BLAS the scheduler already holds (cached shared, or one
                // whose release is still queued) is attached now.
                if let Some(address) = self.blas.address(r.slot) {
                    self.culling.set_blas(r.handle, address).map_err(core)?;
                }
            }
        }

        // 4. Commands of frame f - k, processed under the budget.
        while let Some(r) = self.ring.pop_ready(frame) {
            self.stats.commands_ingested +=
                self.culling.ingest_readback(r.counter, &r.words).accepted;
        }
        let mut events = Vec::new();
        let st = self
            .culling
            .process_commands(self.config.command_budget, &mut events);
        for event in events {
            match event.action {
                BlasAction::Acquire => {
                    let lod = usize::from(ctx.lods[event.slot as usize]);
                    self.blas.activate(ctx.catalog, event.slot, lod)?;
                    // A BLAS the scheduler already holds is attached now.
                    if let Some(address) = self.blas.address(event.slot).filter(|&a| a != 0) {
                        self.culling.set_blas(event.handle, address).map_err(core)?;
                    }
                }
                BlasAction::Release { .. } | BlasAction::CancelBuild => {
                    self.blas.deactivate(event.slot)?;
                }
            }
        }
        self.stats.commands_processed = st.drained;
        self.stats.commands_pending = st.remaining;

        // 5. Builds; new addresses.
        let work = self.blas.build(ctx.catalog, ctx.lods)?;
        for slot in self.blas.take_address_changes() {
            let address = self.blas.address(slot).unwrap_or(0);
            self.culling
                .set_blas(self.handles[slot as usize], address)
                .map_err(core)?;
        }
        self.culling.take_uploads();

        // 6. Algorithm 1; geometry records get this frame's BLAS.
        self.culling.assemble(out).map_err(core)?;
        let counting = CountingConfig::default();
        for r in out.iter_mut() {
            let sbt = r.sbt_offset();
            if sbt != counting.instance_box_sbt && sbt != counting.hitbox_box_sbt {
                let full = ctx
                    .full_records
                    .get(r.custom_index() as usize)
                    .ok_or(SimError::UnknownInstance(r.custom_index()))?;
                r.acceleration_structure_reference = full.acceleration_structure_reference;
            }
        }
        let hitboxes = self.culling.hitboxes();
        self.stats.active_hitboxes = hitboxes.iter().filter(|h| h.is_active()).count() as u32;
        Ok(StrategyFrame {
            work,
            blas_bytes: self.blas.memory_bytes() + blas_bytes(12),
            overhead_bytes: lipac_overhead_bytes(hitboxes.len() as u64, self.handles.len() as u64),
        })
    }
}
