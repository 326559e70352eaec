//! LiPaC driven as an engine drives a GPU backend: the scene's instances
//! registered in one [`CpuBackend`] (a [`lipac_core::manager::Manager`], its
//! read-back ring of `k` frames and the plan execution).
//!
//! Per frame `f`, in order:
//!
//! 1. **End of frame `f − 1`**: the tracer's counters of frame `f − 1` go
//!    into the Manager's hit buffers, [`CpuBackend::end_frame`] runs
//!    Algorithm 2 and puts its commands into the ring.
//! 2. [`CpuBackend::begin_frame`]; animated units' transforms; the frame's
//!    distance LOD of every instance whose LOD changed
//!    ([`lipac_core::manager::Manager::set_lod`]).
//! 3. [`CpuBackend::run`]: latency mitigation (optional, paper §3.6), the
//!    commands of frame `f − k` under the command budget, the BLAS builds
//!    under the build budgets (acknowledged at once), Algorithm 1. Geometry
//!    records get this frame's BLAS from the shared geometry; the caller
//!    traces the records (counting boxes count by custom index: slot or
//!    hitbox index) and hands the counters back as `previous` next frame.
//!
//! Registry slots are assigned in scene order and checked to equal scene
//! slots, so custom indices, counters and commands all speak scene slots.

use lipac_core::build_plan::{BuildBudgets, PriorityConfig};
use lipac_core::controller::{ControlTarget, ControllerConfig};
use lipac_core::grid::HitboxGrid;
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::hitbox_tree::AdaptiveHitboxes;
use lipac_core::instance::{InstanceDesc, InstanceFlags, MeshId};
use lipac_core::latency::ActivationHeuristic;
use lipac_core::layout::{InstanceState, TlasInstance};
use lipac_core::manager::Manager;
use lipac_core::registry::InstanceHandle;
use lipac_core::thresholds::{DecayedSettings, DecisionRule, Thresholds};

use super::{ControlFrame, FrameContext, InstanceCatalog, Strategy, StrategyFrame};
use crate::cpu_backend::CpuBackend;
use crate::error::SimError;
use crate::memory::{decayed_rate_bytes, lipac_overhead_bytes, MemoryModel};
use crate::scene::{Scene, SceneInstance};
use crate::scene_blas::instance_mask;
use crate::tlas::{CountingBoxes, MergedBoxes};
use crate::tlas_map::HitboxCell;
use crate::traversal::Counters;

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
    /// Build priorities of the BLAS scheduler.
    pub build_priority: PriorityConfig,
    /// A closed-loop target for the Manager ([`lipac_core::controller`]):
    /// a memory budget or an escape fraction; `None` keeps the thresholds.
    pub target: Option<ControlTarget>,
    /// The controller's settings (with a `target`).
    pub controller: ControllerConfig,
    /// Adaptive hitboxes (merged counting boxes for cold regions,
    /// [`lipac_core::hitbox_tree`]); [`Self::DEFAULT_ADAPTIVE_LEVELS`] by
    /// default.
    pub adaptive_hitboxes: AdaptiveHitboxes,
    /// A warm start at the first frame, the level load: the Manager
    /// activates the instances in view that this heuristic accepts
    /// ([`lipac_core::manager::Manager::warm_start`]) and that frame's builds
    /// are not budgeted, as a load's are not; hit feedback culls the set
    /// down from the read-back on. `None`: the paper's cold start (every
    /// hitbox inactive, nothing traced but the pinned instances until the
    /// first read-back, the first frame budgeted like any other).
    pub warm_start: Option<ActivationHeuristic>,
    /// Also warm-start at every camera cut
    /// ([`crate::strategy::FrameContext::camera_cut`]), with
    /// [`LipacConfig::warm_start`]'s heuristic and that frame's builds
    /// unbudgeted, as at the load. Off by default: on the sim's jump it
    /// lowers the error after the cut but adds a peak of memory and builds
    /// (docs/EVALUATION.md, "Cold start, and the levers together").
    pub warm_start_at_cuts: bool,
    /// Frames without a hit that what a warm start activates is held
    /// ([`lipac_core::culling::CullingConfig::warm_start_hold`]): hit
    /// feedback culls the view down only after that many frames of
    /// evidence. 0 (the default): the first frame's feedback decides; a
    /// hold lowers the error after a load or cut for memory over those
    /// frames (docs/EVALUATION.md, "A warm start around the camera, held").
    pub warm_start_hold: u32,
    /// Register the scene's pinned instances (the terrain tiles) pinned:
    /// always traced, never culled, never a counting box (the paper's
    /// choice; on by default). `false` culls them like any other
    /// instance: less memory for more error, the far end of a sweep
    /// (`lipac sweep --decayed` with `!`; docs/EVALUATION.md, "A default
    /// within 1.15x the oracle"). The oracle keeps the pins either way.
    pub honour_pins: bool,
    /// The device's acceleration-structure sizes: the Manager's build
    /// estimates, the unit cube and the controller's bytes per TLAS record
    /// ([`MemoryModel`]; the built-in one by default, a device profile's
    /// with [`LipacConfig::with_memory`]).
    pub memory: MemoryModel,
}

impl LipacConfig {
    /// Default hitbox cell size, metres: 32, not the paper's 16. With the
    /// default rule ([`Self::DEFAULT_DECAYED`]) a single hit activates a
    /// cell, so the cell size trades what an activation brings in (each
    /// instance of an active cell is a TLAS record) against how much of
    /// the neighbourhood it activates before it is hit; with adaptive
    /// hitboxes ([`Self::DEFAULT_ADAPTIVE_LEVELS`]) cold cells cost few
    /// counting boxes whatever their size. Over the 270-frame fly-through
    /// (docs/EVALUATION.md, "A default within 1.15x the oracle"): 28 m /
    /// 32 m / 36 m cells give city 12.16 / 12.27 / 12.32 MiB at error
    /// 0.0278 / 0.0264 / 0.0249; the 64 m cells of before cost 13.1 MiB
    /// for 0.0196.
    pub const DEFAULT_CELL_SIZE: f64 = 32.0;

    /// Default merge levels of adaptive hitboxes: 3 (a cold region of up
    /// to 8 x 8 hitboxes is one counting box; decisions unchanged,
    /// docs/ADAPTIVE_HITBOXES.md). At 32 m cells they halve LiPaC's TLAS
    /// records of cold cells (docs/EVALUATION.md, "A default within 1.15x
    /// the oracle").
    pub const DEFAULT_ADAPTIVE_LEVELS: u8 = 3;

    /// The default decision rule's settings (hits per frame at 1080p, 1 spp,
    /// scaled to the rays like the paper's θa = 1000): a rate that rises
    /// half way to a frame's hits in one frame (rise shift 1) and decays
    /// with a half-life of 5 frames; hitboxes and unique-BLAS instances
    /// activate above 100 hits per frame and deactivate below 0.2. At the
    /// comparison's 9,216 rays per frame that is 0.44 and 0.0009: a single
    /// hit (a rate of 0.5) activates, and a cell or instance stays for
    /// about 45 frames after its last hit. The activation rate sits just
    /// under one hit so that a controller's scale
    /// ([`LipacConfig::target`]) above 1.13 already asks for more than one
    /// hit; any activation rate from 1 to 110 decides the same here.
    /// docs/EVALUATION.md, "A default within 1.15x the oracle" (before:
    /// symmetric, 150/30, "The decayed rule").
    pub const DEFAULT_DECAYED: DecayedSettings = DecayedSettings {
        half_life_frames: 5.0,
        activate: 100.0,
        deactivate: 0.2,
        instance_activate: 100.0,
        instance_omit: 0.2,
        per_shared: 0.0,
        per_unique: 0.0,
        rise_shift: Some(1),
    };

    /// The default warm start ([`LipacConfig::warm_start`]): the whole view
    /// and everything within 800 m of the camera (the frustum + radius
    /// baseline's set: off-screen geometry shadows and reflects into the
    /// view) at the level load, culled down by hit feedback from the first
    /// read-back on (docs/EVALUATION.md, "Cold start, and the levers
    /// together", "A warm start around the camera, held").
    pub const DEFAULT_WARM_START: ActivationHeuristic = ActivationHeuristic {
        max_distance: f32::INFINITY,
        min_projected_size: 0.0,
        surround_radius: crate::strategy::FrustumRadius::DEFAULT_RADIUS,
    };

    /// Settings for `rays_per_frame` camera rays: the paper's thresholds
    /// scaled to the rays, deciding with the decayed rule
    /// [`Self::DEFAULT_DECAYED`] ([`Self::with_paper_rule`] for the paper's),
    /// [`Self::DEFAULT_CELL_SIZE`] cells, adaptive hitboxes of
    /// [`Self::DEFAULT_ADAPTIVE_LEVELS`] merge levels, readback after 2 frames, a warm
    /// start ([`Self::DEFAULT_WARM_START`]), 4096 commands per frame,
    /// the scheduler's default build budgets (64 builds, 4 Mi triangles) but
    /// no compaction copies (lavapipe's compaction gains nothing,
    /// [`crate::memory`]), and builds ordered by waiting time alone
    /// ([`Self::age_only_priority`]).
    pub fn for_rays_per_frame(rays_per_frame: u64) -> Result<Self, SimError> {
        let rays = rays_per_frame as f64;
        let rule = Self::DEFAULT_DECAYED
            .rule_for_rays_per_frame(rays)
            .map_err(SimError::core)?;
        let thresholds = Thresholds::for_rays_per_frame(rays)
            .map_err(SimError::core)?
            .with_rule(DecisionRule::Decayed(rule));
        Ok(Self {
            thresholds,
            cell_size: Self::DEFAULT_CELL_SIZE,
            latency: None,
            command_budget: 4096,
            command_capacity: 1 << 16,
            readback_latency: 2,
            build_budgets: BuildBudgets {
                max_compactions: 0,
                ..BuildBudgets::default()
            },
            build_priority: Self::age_only_priority(),
            target: None,
            controller: ControllerConfig {
                tlas_record_bytes: crate::memory::TLAS_BYTES_PER_INSTANCE,
                ..ControllerConfig::default()
            },
            adaptive_hitboxes: AdaptiveHitboxes::with_levels(Self::DEFAULT_ADAPTIVE_LEVELS),
            warm_start: Some(Self::DEFAULT_WARM_START),
            warm_start_at_cuts: false,
            warm_start_hold: 0,
            honour_pins: true,
            memory: MemoryModel::default(),
        })
    }
    /// The same on a device of `memory`'s sizes (a device profile's,
    /// [`crate::device_profile::DeviceProfile::memory_model`]): its build
    /// estimates, and the controller's bytes per TLAS record.
    pub fn with_memory(mut self, memory: MemoryModel) -> Self {
        self.controller.tlas_record_bytes = memory.tlas_bytes_per_instance();
        self.memory = memory;
        self
    }
    /// The same with adaptive hitboxes of `levels` merge levels (0: off).
    pub fn with_adaptive_hitboxes(mut self, levels: u8) -> Self {
        self.adaptive_hitboxes = AdaptiveHitboxes::with_levels(levels);
        self
    }
    /// Build priorities by waiting time alone: the comparison's measured
    /// configuration (docs/EVALUATION.md). [`PriorityConfig::default`] also
    /// ranks waiting builds by their instances' hits and frustum visibility.
    pub fn age_only_priority() -> PriorityConfig {
        PriorityConfig {
            hit_cap: 0,
            frustum_bonus: 0,
            ..PriorityConfig::default()
        }
    }
    /// The same deciding with the paper's rule (θa, θd, σa, σo, n_a, n_d on
    /// this frame's hits) instead of the decayed rate.
    pub fn with_paper_rule(mut self) -> Self {
        self.thresholds.rule = DecisionRule::Paper;
        self
    }
    /// The same deciding with the decayed rule `settings` scaled to
    /// `rays_per_frame` camera rays; settings that cannot be met (NaN, zero
    /// or negative rates, a half-life outside 0.5..=400 frames) are an error.
    pub fn with_decayed_rule(
        mut self,
        settings: &DecayedSettings,
        rays_per_frame: u64,
    ) -> Result<Self, SimError> {
        let rule = settings
            .rule_for_rays_per_frame(rays_per_frame as f64)
            .map_err(SimError::core)?;
        self.thresholds.rule = DecisionRule::Decayed(rule);
        Ok(self)
    }
    /// Whether LiPaC registers `inst` pinned: the scene pins it and
    /// [`Self::honour_pins`] is set.
    fn pins(&self, inst: &SceneInstance) -> bool {
        self.honour_pins && inst.is_pinned()
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
    backend: CpuBackend,
    handles: Vec<InstanceHandle>,
    /// The LOD requested for each slot.
    lods: Vec<u8>,
    units: Vec<u32>,
    /// Whether each slot is registered pinned (followed from the scene:
    /// a replayed trace's flag updates).
    pinned: Vec<bool>,
    stats: LipacFrameStats,
}

impl Lipac {
    /// Registers every instance of `scene` (frame 0 state) in a
    /// [`CpuBackend`] whose hitbox grid covers the scene.
    pub fn new(scene: &Scene, config: LipacConfig) -> Result<Self, SimError> {
        let grid = super::scene_grid(scene, config.cell_size)?;
        let catalog = InstanceCatalog::with_memory(scene, &config.memory)?.mesh_catalog()?;
        let mut backend = CpuBackend::new(grid, &config, catalog)?;
        let n = scene.instances().len();
        backend.reserve(n)?;
        let mut handles = Vec::with_capacity(n);
        let mut units = Vec::new();
        for (slot, inst) in scene.instances().iter().enumerate() {
            let mut f = inst.instance_flags();
            if !config.pins(inst) {
                f.remove(InstanceFlags::PINNED);
            }
            if inst.is_animated() {
                units.push(slot as u32);
            }
            let desc = InstanceDesc {
                flags: f,
                mask: instance_mask(inst),
                ..InstanceDesc::new(MeshId(inst.mesh), inst.transform, inst.aabb)
            };
            let h = backend.register(desc)?;
            // Registry slots must equal scene slots: counters, custom indices
            // and commands are all indexed by them.
            let got = backend.instance(h)?.slot;
            if got != slot as u32 {
                return Err(SimError::Core(format!(
                    "registry slot {got} for scene slot {slot}"
                )));
            }
            handles.push(h);
        }
        let pinned = scene.instances().iter().map(|i| config.pins(i)).collect();
        Ok(Self {
            name: if config.latency.is_some() {
                "lipac-latency"
            } else {
                "lipac"
            },
            config,
            backend,
            lods: vec![0; handles.len()],
            handles,
            units,
            pinned,
            stats: LipacFrameStats::default(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &LipacConfig {
        &self.config
    }
    /// The state of instance `slot`.
    pub fn state(&self, slot: u32) -> Option<InstanceState> {
        let h = *self.handles.get(slot as usize)?;
        self.backend.instance(h).ok().map(|v| v.state)
    }
    /// The backend (its Manager: statistics, instance views).
    pub fn backend(&self) -> &CpuBackend {
        &self.backend
    }
    /// Counts of the last frame.
    pub fn last_stats(&self) -> LipacFrameStats {
        self.stats
    }

    /// Step 1: the hits of the previous frame, Algorithm 2, its commands
    /// into the ring.
    fn feedback(&mut self, previous: &Counters) -> Result<(), SimError> {
        let hits = self.backend.instance_hits_mut();
        if previous.instances.len() != hits.len() {
            return Err(SimError::SizeMismatch {
                a: previous.instances.len(),
                b: hits.len(),
            });
        }
        hits.copy_from_slice(&previous.instances);
        for (h, &c) in self
            .backend
            .hitboxes_mut()
            .iter_mut()
            .zip(&previous.hitboxes)
        {
            h.add_hits(c);
        }
        self.backend.end_frame()
    }
}

/// This frame's merged boxes of a [`Lipac`] with adaptive hitboxes: the
/// leaf boxes from its Manager's hitbox records.
struct LipacMergedBoxes<'a> {
    manager: &'a Manager<HitboxGrid>,
}

impl MergedBoxes for LipacMergedBoxes<'_> {
    fn leaf_boxes(&self, node: u32, out: &mut Vec<(u32, [f32; 12])>) {
        self.manager.merged_leaf_boxes(node, out);
    }
}

impl Strategy for Lipac {
    fn name(&self) -> &str {
        self.name
    }
    fn merged_boxes(&self) -> Option<Box<dyn MergedBoxes + '_>> {
        let manager = self.backend.manager();
        manager.hitbox_tree()?;
        Some(Box::new(LipacMergedBoxes { manager }))
    }
    fn hitboxes(&self) -> usize {
        self.backend.hitboxes().len()
    }
    fn hitbox_cells(&self) -> Option<Vec<HitboxCell>> {
        let manager = self.backend.manager();
        let index = manager.registry().hitbox_index();
        let cells = (0u32..)
            .zip(manager.hitboxes())
            .filter_map(|(i, h)| {
                let (min, max) = index.xz_bounds(i)?;
                Some(HitboxCell {
                    index: i,
                    min,
                    max,
                    active: h.is_active(),
                    hits: h.hits(),
                })
            })
            .collect();
        Some(cells)
    }
    fn frame(
        &mut self,
        ctx: &FrameContext<'_>,
        previous: Option<&Counters>,
        out: &mut Vec<TlasInstance>,
    ) -> Result<StrategyFrame, SimError> {
        let n = self.handles.len();
        if ctx.full_records.len() != n || ctx.lods.len() != n {
            return Err(SimError::SizeMismatch {
                a: ctx.full_records.len().min(ctx.lods.len()),
                b: n,
            });
        }
        self.stats = LipacFrameStats::default();
        if self.backend.frame_open() {
            // A frame whose counters are missing still runs Algorithm 2
            // (with no hits) so that the loop's call order holds.
            match previous {
                Some(p) => self.feedback(p)?,
                None => self.feedback(&Counters::new(n, 0))?,
            }
        }

        // 2. Frame start, animated units, LODs.
        self.backend.begin_frame(ctx.frame)?;
        for &slot in &self.units {
            let inst = ctx.scene.instance(slot)?;
            self.backend
                .set_transform(self.handles[slot as usize], inst.transform, inst.aabb)?;
        }
        for ((inst, was), &h) in ctx
            .scene
            .instances()
            .iter()
            .zip(&mut self.pinned)
            .zip(&self.handles)
        {
            let pinned = self.config.pins(inst);
            if pinned != *was {
                *was = pinned;
                self.backend.set_pinned(h, *was)?;
            }
        }
        for (slot, (&lod, last)) in ctx.lods.iter().zip(&mut self.lods).enumerate() {
            if lod != *last {
                *last = lod;
                self.backend.set_lod(self.handles[slot], u32::from(lod))?;
            }
        }

        // 3. Warm start (a cut), latency mitigation, commands, builds,
        // Algorithm 1.
        if ctx.camera_cut && self.config.warm_start_at_cuts {
            self.backend.warm_start_again();
        }
        let f = self.backend.run(ctx.camera, out)?;
        self.stats.commands_ingested = f.commands_ingested;
        self.stats.commands_processed = f.commands_processed;
        self.stats.commands_pending = f.commands_pending;
        self.stats.latency_activations = f.latency_activations;
        // Geometry records get this frame's BLAS.
        let counting = CountingBoxes::default();
        for r in out.iter_mut() {
            let sbt = r.sbt_offset();
            if !counting.is_box(sbt) {
                let full = ctx
                    .full_records
                    .get(r.custom_index() as usize)
                    .ok_or(SimError::UnknownInstance(r.custom_index()))?;
                r.acceleration_structure_reference = full.acceleration_structure_reference;
            }
        }
        let hitboxes = self.backend.hitboxes();
        self.stats.active_hitboxes = hitboxes.iter().filter(|h| h.is_active()).count() as u32;
        let manager = self.backend.manager();
        let stats = manager.stats();
        let control = ControlFrame {
            escape_fraction: stats.escape.and_then(|e| e.fraction()),
            threshold_scale: stats.controller.map_or(1.0, |c| c.scale),
            controlled_bytes: manager.controlled_bytes(),
            target: stats.controller.map(|c| c.target),
            unreachable: stats.controller.is_some_and(|c| c.unreachable),
        };
        Ok(StrategyFrame {
            work: f.work,
            blas_bytes: self.backend.blas_bytes() + self.config.memory.blas_bytes(12),
            blas_split: ctx.catalog.blas_split(manager.scheduler().cache()),
            overhead_bytes: lipac_overhead_bytes(hitboxes.len() as u64, n as u64)
                + decayed_rate_bytes(&self.config.thresholds, n as u64),
            control: Some(control),
        })
    }
}

#[cfg(test)]
mod tests;
