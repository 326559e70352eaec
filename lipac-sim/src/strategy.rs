//! Culling strategies compared side by side.
//!
//! Every frame a [`Strategy`] gets the scene in that frame's animated state,
//! the camera, the frame number and the hit counters its own previous frame
//! traced, and produces the TLAS records to trace: real instance records
//! (BLAS references of the frame's geometry) and, where the strategy has
//! them, counting boxes. It also reports its BLAS work and memory.
//!
//! | strategy | TLAS holds |
//! | --- | --- |
//! | [`Full`] | every instance (the ground truth's TLAS) |
//! | [`FrustumRadius`] | instances in the view frustum or within a radius (800 m) |
//! | [`Heuristic`] | instances near the camera or large on screen ([`ActivationHeuristic`]) |
//! | [`lipac::Lipac`] | what LiPaC's hit feedback keeps, plus counting boxes; optionally with latency mitigation |
//! | [`Oracle`] | exactly the instances the ground-truth paths hit this frame |
//!
//! # BLAS accounting
//!
//! Every baseline keeps its BLASes in its own
//! [`lipac_core::build_plan::BuildScheduler`] ([`BlasAccounting`]); LiPaC's
//! are its Manager's scheduler ([`crate::cpu_backend`]), with the same
//! settings. Both share BLASes per (mesh, LOD), give animated units unique
//! BLASes (refit every frame, rebuilt every 16th, only while the instance is
//! in the set), and terrain tiles and terrain-adapted buildings per-instance
//! static BLASes (shared keys with a per-instance variant: built once, never
//! refit). Builds are acknowledged immediately: the CPU backend builds
//! synchronously. Sizes come from [`crate::memory`]. The baselines get unlimited per-frame build
//! budgets (their set is always complete); LiPaC gets the budgets an engine
//! would set.
//!
//! # Geometry traced
//!
//! All strategies trace the same BLASes as the ground truth (one shared
//! [`crate::blas::BlasStore`], geometry at the frame's distance LOD and
//! animation pose): a strategy decides *which* instances are traced, the
//! error therefore measures culling alone. The BLAS work each strategy
//! would pay is what its scheduler reports.

pub mod lipac;

use std::collections::HashMap;

use glam::Vec3;
use lipac_core::blas_ids::{InstanceKey, Lod};
use lipac_core::build_plan::{
    BlasGeometry, BuildBudgets, BuildEstimate, BuildScheduler, FramePlan, InstanceBlasRequest,
    SchedulerConfig, UpdateMode,
};
use lipac_core::latency::ActivationHeuristic;
use lipac_core::layout::TlasInstance;
use lipac_core::manager::MeshCatalog;
use lipac_core::math::Aabb;
use lipac_core::MeshId;

use crate::camera::Camera;
use crate::error::SimError;
use crate::memory::{build_estimate, mesh_lod};
use crate::mesh::{LOD_COUNT, TERRAIN_RESOLUTION};
use crate::scene::{flags, Scene, SceneInstance};
use crate::traversal::Counters;

/// How an instance's BLAS is owned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlasOwnership {
    /// Shared by every instance of its (mesh, LOD).
    Shared,
    /// The instance's own, static (terrain tile, terrain-adapted building):
    /// built once per LOD, never refit.
    OwnStatic,
    /// The instance's own, animated: refit every frame, rebuilt periodically.
    Animated,
}

/// Per-instance facts the strategies need: triangle counts per LOD and BLAS
/// ownership. Computed once per scene.
#[derive(Clone, Debug)]
pub struct InstanceCatalog {
    triangles: Vec<[u32; LOD_COUNT]>,
    kinds: Vec<BlasOwnership>,
    meshes: Vec<MeshId>,
}

impl InstanceCatalog {
    /// Catalog of every instance of `scene`.
    pub fn new(scene: &Scene) -> Result<Self, SimError> {
        let n = scene.instances().len();
        let mut triangles = Vec::with_capacity(n);
        let mut kinds = Vec::with_capacity(n);
        let mut meshes = Vec::with_capacity(n);
        for inst in scene.instances() {
            let kind = if inst.is_animated() {
                BlasOwnership::Animated
            } else if inst.is_unique() {
                BlasOwnership::OwnStatic
            } else {
                BlasOwnership::Shared
            };
            let mut t = [0u32; LOD_COUNT];
            for (lod, c) in t.iter_mut().enumerate() {
                *c = if inst.flags & flags::TERRAIN != 0 {
                    2 * TERRAIN_RESOLUTION[lod] * TERRAIN_RESOLUTION[lod]
                } else {
                    scene.library().triangle_count(inst.mesh, lod)? as u32
                };
            }
            triangles.push(t);
            kinds.push(kind);
            meshes.push(MeshId(inst.mesh));
        }
        Ok(Self {
            triangles,
            kinds,
            meshes,
        })
    }
    /// Number of instances.
    pub fn len(&self) -> usize {
        self.kinds.len()
    }
    /// Whether the scene is empty.
    pub fn is_empty(&self) -> bool {
        self.kinds.is_empty()
    }
    /// Triangles of instance `slot` at `lod` (0 for unknown slots).
    pub fn triangles(&self, slot: u32, lod: usize) -> u32 {
        self.triangles
            .get(slot as usize)
            .and_then(|t| t.get(lod))
            .copied()
            .unwrap_or(0)
    }
    /// BLAS ownership of instance `slot`.
    pub fn kind(&self, slot: u32) -> Option<BlasOwnership> {
        self.kinds.get(slot as usize).copied()
    }
    /// The scheduler request for instance `slot` at `lod`.
    pub fn request(&self, slot: u32, lod: usize) -> Result<InstanceBlasRequest, SimError> {
        let kind = self.kind(slot).ok_or(SimError::UnknownInstance(slot))?;
        let mesh = self.meshes[slot as usize];
        let geometry = match kind {
            BlasOwnership::Shared => BlasGeometry::Shared {
                mesh,
                variant: 0,
                compactable: false,
            },
            BlasOwnership::OwnStatic => BlasGeometry::Shared {
                mesh,
                variant: slot + 1,
                compactable: false,
            },
            BlasOwnership::Animated => BlasGeometry::Unique { mesh },
        };
        Ok(InstanceBlasRequest {
            geometry,
            lod: Lod(lod as u8),
            estimate: self.estimate(slot, lod),
            hits: 0,
            in_frustum: false,
        })
    }
    /// Build sizes of instance `slot` at `lod` ([`crate::memory`]).
    pub fn estimate(&self, slot: u32, lod: usize) -> BuildEstimate {
        build_estimate(u64::from(self.triangles(slot, lod)))
    }
    /// The Manager's mesh catalog: every mesh of the scene with its
    /// [`LOD_COUNT`] LODs ([`crate::memory::mesh_lod`]). Fails if two
    /// instances of one mesh disagree on a triangle count.
    pub fn mesh_catalog(&self) -> Result<MeshCatalog, SimError> {
        let mut first: HashMap<MeshId, usize> = HashMap::new();
        for (slot, &mesh) in self.meshes.iter().enumerate() {
            let f = *first.entry(mesh).or_insert(slot);
            if self.triangles[f] != self.triangles[slot] {
                return Err(SimError::Core(format!(
                    "mesh {} has different triangle counts in slots {f} and {slot}",
                    mesh.0
                )));
            }
        }
        let mut meshes: Vec<(MeshId, usize)> = first.into_iter().collect();
        meshes.sort_unstable();
        let mut catalog = MeshCatalog::new();
        for (mesh, slot) in meshes {
            let lods = self.triangles[slot]
                .iter()
                .map(|&t| mesh_lod(u64::from(t)))
                .collect();
            catalog.insert(mesh, lods).map_err(SimError::core)?;
        }
        Ok(catalog)
    }
}

/// BLAS work of one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BlasWork {
    /// Full builds (new BLASes and periodic rebuilds of animated ones).
    pub builds: u64,
    /// Refits of animated BLASes.
    pub refits: u64,
    /// Triangles processed by builds.
    pub primitives_built: u64,
    /// Triangles processed by refits.
    pub primitives_refit: u64,
    /// BLASes freed.
    pub frees: u64,
}

impl BlasWork {
    /// The work `plan` asks for: its builds, its updates (refits, or
    /// rebuilds counted as builds) with their triangles, and its frees.
    pub fn of_plan(plan: &FramePlan) -> Self {
        let mut work = BlasWork {
            frees: plan.frees.len() as u64,
            ..BlasWork::default()
        };
        for u in plan.updates() {
            match u.mode {
                UpdateMode::Refit => {
                    work.refits += 1;
                    work.primitives_refit += u.primitives;
                }
                UpdateMode::Rebuild => {
                    work.builds += 1;
                    work.primitives_built += u.primitives;
                }
            }
        }
        for b in plan.builds() {
            work.builds += 1;
            work.primitives_built += b.primitives;
        }
        work
    }

    /// Adds `o`.
    pub fn add(&mut self, o: &BlasWork) {
        self.builds += o.builds;
        self.refits += o.refits;
        self.primitives_built += o.primitives_built;
        self.primitives_refit += o.primitives_refit;
        self.frees += o.frees;
    }
}

/// Plans this frame's BLAS work on `scheduler` under `budgets` and
/// acknowledges every build at once with a fresh fake address (a CPU backend
/// builds synchronously), counting the builds, refits and primitives.
fn plan_and_ack(
    scheduler: &mut BuildScheduler,
    budgets: &BuildBudgets,
    next_address: &mut u64,
) -> Result<BlasWork, SimError> {
    let plan = scheduler.plan(budgets).map_err(SimError::core)?;
    let work = BlasWork::of_plan(&plan);
    for b in plan.builds() {
        *next_address += 0x100;
        scheduler
            .ack_built(b.id, b.result_bytes, *next_address)
            .map_err(SimError::core)?;
    }
    Ok(work)
}

/// Budgets that never limit a frame (the baselines' sets are always built).
pub fn unlimited_budgets() -> BuildBudgets {
    BuildBudgets {
        max_builds: u32::MAX,
        max_primitives: u64::MAX / 4,
        max_result_bytes: u64::MAX / 4,
        max_scratch_bytes: u64::MAX / 4,
        max_batches: 1,
        max_compactions: 0,
    }
}

/// A baseline's BLASes (the set strategies here, the hits-only replay's
/// `full`): a [`BuildScheduler`] whose builds are acknowledged immediately,
/// with addresses that are tokens (the tracer substitutes the frame's
/// geometry, see the module docs). LiPaC's BLASes are its Manager's
/// ([`crate::cpu_backend`]).
#[derive(Debug)]
pub struct BlasAccounting {
    scheduler: BuildScheduler,
    budgets: BuildBudgets,
    active: Vec<bool>,
    active_list: Vec<u32>,
    next_address: u64,
    frame: u64,
}

impl BlasAccounting {
    /// Accounting for `instances` slots with `budgets` per frame.
    pub fn new(instances: usize, budgets: BuildBudgets) -> Result<Self, SimError> {
        let mut config = SchedulerConfig::default();
        // Memory is measured, not limited; unreferenced shared BLASes stay
        // cached for 8 frames (then freed after the frames in flight).
        config.cache.memory_budget = u64::MAX / 4;
        config.cache.max_unused_frames = 8;
        config.lod_hysteresis_frames = 8;
        Ok(Self {
            scheduler: BuildScheduler::new(config).map_err(SimError::core)?,
            budgets,
            active: vec![false; instances],
            active_list: Vec::new(),
            next_address: 0x1000,
            frame: 0,
        })
    }
    /// Starts a frame (frames strictly increase).
    pub fn begin_frame(&mut self, frame: u32) -> Result<(), SimError> {
        self.frame = u64::from(frame) + 1;
        self.scheduler
            .begin_frame(self.frame)
            .map_err(SimError::core)
    }
    /// Whether `slot` holds (or waits for) a BLAS.
    pub fn is_active(&self, slot: u32) -> bool {
        self.active.get(slot as usize).copied().unwrap_or(false)
    }
    /// Requests a BLAS for `slot` at `lod` (no-op if it already has one).
    pub fn activate(
        &mut self,
        catalog: &InstanceCatalog,
        slot: u32,
        lod: usize,
    ) -> Result<(), SimError> {
        if slot as usize >= self.active.len() {
            return Err(SimError::UnknownInstance(slot));
        }
        if self.is_active(slot) {
            return Ok(());
        }
        self.activate_with(slot, catalog.request(slot, lod)?)
    }
    /// Requests a BLAS for `slot` as `request` says (no-op if it already has
    /// one); slots beyond the current count are added (replays whose
    /// instances come and go).
    pub fn activate_with(
        &mut self,
        slot: u32,
        request: InstanceBlasRequest,
    ) -> Result<(), SimError> {
        if self.is_active(slot) {
            return Ok(());
        }
        if self.active.len() <= slot as usize {
            self.active.resize(slot as usize + 1, false);
        }
        self.active[slot as usize] = true;
        self.scheduler
            .activate(InstanceKey(slot), request)
            .map_err(SimError::core)
    }
    /// Requests LOD `lod` for an active `slot` (no-op otherwise).
    pub fn request_lod(
        &mut self,
        slot: u32,
        lod: Lod,
        estimate: BuildEstimate,
    ) -> Result<(), SimError> {
        if !self.is_active(slot) {
            return Ok(());
        }
        self.scheduler
            .request_lod(InstanceKey(slot), lod, estimate)
            .map_err(SimError::core)
    }
    /// Plans the frame and acknowledges every build at once (after this
    /// frame's [`Self::request_lod`]s). Returns the work done.
    pub fn plan(&mut self) -> Result<BlasWork, SimError> {
        plan_and_ack(&mut self.scheduler, &self.budgets, &mut self.next_address)
    }
    /// Capacity of the per-slot tables (bounded-memory checks).
    pub fn capacity(&self) -> usize {
        self.active.capacity() + self.active_list.capacity()
    }
    /// Releases the BLAS of `slot` (no-op if it has none).
    pub fn deactivate(&mut self, slot: u32) -> Result<(), SimError> {
        match self.active.get_mut(slot as usize) {
            Some(a) if *a => {
                *a = false;
                self.scheduler
                    .deactivate(InstanceKey(slot))
                    .map_err(SimError::core)
            }
            _ => Ok(()),
        }
    }
    /// Makes the active set equal `wanted` (a flag per slot).
    pub fn set_active(
        &mut self,
        catalog: &InstanceCatalog,
        wanted: &[bool],
        lods: &[u8],
    ) -> Result<(), SimError> {
        for (slot, &w) in wanted.iter().enumerate() {
            let slot = slot as u32;
            if w != self.is_active(slot) {
                if w {
                    let lod = usize::from(lods.get(slot as usize).copied().unwrap_or(0));
                    self.activate(catalog, slot, lod)?;
                } else {
                    self.deactivate(slot)?;
                }
            }
        }
        Ok(())
    }
    /// Requests this frame's LOD for every active instance, plans the frame
    /// and acknowledges every build at once. Returns the work done.
    pub fn build(&mut self, catalog: &InstanceCatalog, lods: &[u8]) -> Result<BlasWork, SimError> {
        self.active_list.clear();
        self.active_list.extend(
            self.active
                .iter()
                .enumerate()
                .filter(|(_, &a)| a)
                .map(|(s, _)| s as u32),
        );
        for i in 0..self.active_list.len() {
            let slot = self.active_list[i];
            let lod = usize::from(lods.get(slot as usize).copied().unwrap_or(0));
            self.request_lod(slot, Lod(lod as u8), catalog.estimate(slot, lod))?;
        }
        self.plan()
    }
    /// Instances whose BLAS address changed since the last call.
    pub fn take_address_changes(&mut self) -> Vec<u32> {
        self.scheduler
            .take_address_changes()
            .into_iter()
            .map(|k| k.0)
            .collect()
    }
    /// The (token) address of the BLAS `slot` uses, once built.
    pub fn address(&self, slot: u32) -> Option<u64> {
        self.scheduler.blas_address(InstanceKey(slot))
    }
    /// Modelled bytes of every BLAS held (built, building, cached).
    pub fn memory_bytes(&self) -> u64 {
        self.scheduler.stats().cache.live_bytes()
    }
}

/// What one frame gives a strategy.
#[derive(Clone, Copy, Debug)]
pub struct FrameContext<'a> {
    /// Frame number.
    pub frame: u32,
    /// The scene, animated to `frame`.
    pub scene: &'a Scene,
    /// The camera of this frame.
    pub camera: &'a Camera,
    /// Per-instance facts.
    pub catalog: &'a InstanceCatalog,
    /// Distance LOD of every instance this frame.
    pub lods: &'a [u8],
    /// Full-scene TLAS records, one per slot (custom index = slot), with
    /// this frame's geometry: strategies copy the records they keep.
    pub full_records: &'a [TlasInstance],
    /// TLAS reference of the counting-box unit cube.
    pub unit_cube: u64,
    /// Camera rays per frame (pixels × samples).
    pub rays_per_frame: u64,
    /// Instance hits of this frame's ground-truth paths (bounce rays), per
    /// slot. Only the [`Oracle`] may look.
    pub ground_truth_hits: &'a [u32],
}

/// What a strategy reports for one frame (besides its records).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StrategyFrame {
    /// BLAS work done this frame.
    pub work: BlasWork,
    /// Modelled bytes of the BLASes it holds.
    pub blas_bytes: u64,
    /// Modelled bytes of its own buffers (LiPaC: hitboxes, hit counters).
    pub overhead_bytes: u64,
}

/// A culling strategy (see the module docs).
pub trait Strategy {
    /// Short name (report key).
    fn name(&self) -> &str;
    /// Hitbox counters it needs from the tracer (0: none).
    fn hitboxes(&self) -> usize {
        0
    }
    /// Produces this frame's TLAS records into `out` (cleared first).
    /// `previous` holds the hit counters its previous frame traced (`None`
    /// in the first frame).
    fn frame(
        &mut self,
        ctx: &FrameContext<'_>,
        previous: Option<&Counters>,
        out: &mut Vec<TlasInstance>,
    ) -> Result<StrategyFrame, SimError>;
    /// Whether this frame's records are exactly `ctx.full_records` (then the
    /// ground truth's render can be reused).
    fn is_full_scene(&self) -> bool {
        false
    }
}

/// Shared part of the set-based baselines: choose a set, account its
/// BLASes, copy its records.
#[derive(Debug)]
struct SetStrategy {
    blas: BlasAccounting,
    wanted: Vec<bool>,
}

impl SetStrategy {
    fn new(instances: usize) -> Result<Self, SimError> {
        Ok(Self {
            blas: BlasAccounting::new(instances, unlimited_budgets())?,
            wanted: vec![false; instances],
        })
    }
    /// Marks scene instance `slot` wanted where `keep(slot, instance)` holds,
    /// then [`SetStrategy::run`]s.
    fn run_selected(
        &mut self,
        ctx: &FrameContext<'_>,
        out: &mut Vec<TlasInstance>,
        mut keep: impl FnMut(usize, &SceneInstance) -> bool,
    ) -> Result<StrategyFrame, SimError> {
        let instances = ctx.scene.instances();
        self.wanted.clear();
        self.wanted.extend(
            instances
                .iter()
                .enumerate()
                .map(|(slot, inst)| keep(slot, inst)),
        );
        self.run(ctx, out)
    }

    fn run(
        &mut self,
        ctx: &FrameContext<'_>,
        out: &mut Vec<TlasInstance>,
    ) -> Result<StrategyFrame, SimError> {
        self.blas.begin_frame(ctx.frame)?;
        self.blas.set_active(ctx.catalog, &self.wanted, ctx.lods)?;
        let work = self.blas.build(ctx.catalog, ctx.lods)?;
        self.blas.take_address_changes();
        out.clear();
        for (slot, r) in ctx.full_records.iter().enumerate() {
            if self.wanted[slot] && self.blas.address(slot as u32).is_some() {
                out.push(*r);
            }
        }
        Ok(StrategyFrame {
            work,
            blas_bytes: self.blas.memory_bytes(),
            overhead_bytes: 0,
        })
    }
}

/// Every instance, every frame: the unculled scene.
#[derive(Debug)]
pub struct Full(SetStrategy);

impl Full {
    /// For a scene of `instances` instances.
    pub fn new(instances: usize) -> Result<Self, SimError> {
        let mut s = SetStrategy::new(instances)?;
        s.wanted.fill(true);
        Ok(Self(s))
    }
}

impl Strategy for Full {
    fn name(&self) -> &str {
        "full"
    }
    fn frame(
        &mut self,
        ctx: &FrameContext<'_>,
        _previous: Option<&Counters>,
        out: &mut Vec<TlasInstance>,
    ) -> Result<StrategyFrame, SimError> {
        self.0.wanted.resize(ctx.full_records.len(), true);
        let f = self.0.run(ctx, out)?;
        if out.len() != ctx.full_records.len() {
            return Err(SimError::BadConfig("full scene strategy lost instances"));
        }
        Ok(f)
    }
    fn is_full_scene(&self) -> bool {
        true
    }
}

/// Closest distance from `p` to `aabb` (0 inside).
fn distance_to(p: Vec3, aabb: &Aabb) -> f32 {
    p.clamp(aabb.min, aabb.max).distance(p)
}

/// Instances whose AABB touches the view frustum, plus every instance
/// within `radius` of the camera (for off-screen shadows and reflections).
#[derive(Debug)]
pub struct FrustumRadius {
    set: SetStrategy,
    radius: f32,
}

impl FrustumRadius {
    /// The usual radius: 800 m.
    pub const DEFAULT_RADIUS: f32 = 800.0;
    /// For `instances` instances and a keep-radius of `radius` metres.
    pub fn new(instances: usize, radius: f32) -> Result<Self, SimError> {
        if !radius.is_finite() || radius < 0.0 {
            return Err(SimError::BadConfig("radius must be finite and >= 0"));
        }
        Ok(Self {
            set: SetStrategy::new(instances)?,
            radius,
        })
    }
}

impl Strategy for FrustumRadius {
    fn name(&self) -> &str {
        "frustum"
    }
    fn frame(
        &mut self,
        ctx: &FrameContext<'_>,
        _previous: Option<&Counters>,
        out: &mut Vec<TlasInstance>,
    ) -> Result<StrategyFrame, SimError> {
        let frustum = ctx.camera.frustum()?;
        let eye = ctx.camera.position;
        let radius = self.radius;
        self.set.run_selected(ctx, out, |_, inst| {
            distance_to(eye, &inst.aabb) <= radius || frustum.intersects_aabb(&inst.aabb)
        })
    }
}

/// Instances near the camera or large in projection, in any direction
/// (lipac-core's [`ActivationHeuristic`] rule applied to the whole scene).
#[derive(Debug)]
pub struct Heuristic {
    set: SetStrategy,
    rule: ActivationHeuristic,
}

impl Heuristic {
    /// For `instances` instances with `rule` (default: within 50 m, or
    /// `radius / distance >= 0.1`).
    pub fn new(instances: usize, rule: ActivationHeuristic) -> Result<Self, SimError> {
        if rule.max_distance.is_nan()
            || rule.max_distance < 0.0
            || rule.min_projected_size.is_nan()
            || rule.min_projected_size < 0.0
        {
            return Err(SimError::BadConfig("heuristic values must be >= 0"));
        }
        Ok(Self {
            set: SetStrategy::new(instances)?,
            rule,
        })
    }
}

impl Strategy for Heuristic {
    fn name(&self) -> &str {
        "heuristic"
    }
    fn frame(
        &mut self,
        ctx: &FrameContext<'_>,
        _previous: Option<&Counters>,
        out: &mut Vec<TlasInstance>,
    ) -> Result<StrategyFrame, SimError> {
        let eye = ctx.camera.position;
        let rule = self.rule;
        self.set
            .run_selected(ctx, out, |_, inst| rule.accepts(eye, &inst.aabb))
    }
}

/// Exactly the instances this frame's ground-truth bounce rays hit.
///
/// Shadow rays need nothing: the rasterized-shadow fallback of
/// [`crate::pathtrace`] covers every culled caster, so sun visibility is
/// exact for any set. Primary hits come from the full scene (rasterization).
/// Every bounce ray therefore finds the same closest hit as in the ground
/// truth (ties between coplanar instances go to the lower slot in every
/// TLAS, [`crate::traversal`]), and the image is identical: error 0.
#[derive(Debug)]
pub struct Oracle(SetStrategy);

impl Oracle {
    /// For `instances` instances.
    pub fn new(instances: usize) -> Result<Self, SimError> {
        Ok(Self(SetStrategy::new(instances)?))
    }
}

impl Strategy for Oracle {
    fn name(&self) -> &str {
        "oracle"
    }
    fn frame(
        &mut self,
        ctx: &FrameContext<'_>,
        _previous: Option<&Counters>,
        out: &mut Vec<TlasInstance>,
    ) -> Result<StrategyFrame, SimError> {
        let n = ctx.scene.instances().len();
        if ctx.ground_truth_hits.len() != n {
            return Err(SimError::SizeMismatch {
                a: ctx.ground_truth_hits.len(),
                b: n,
            });
        }
        let hits = ctx.ground_truth_hits;
        self.0.run_selected(ctx, out, |slot, _| hits[slot] > 0)
    }
}

/// The strategies the comparison knows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum StrategyKind {
    /// [`Full`].
    Full,
    /// [`FrustumRadius`] with 800 m.
    Frustum,
    /// [`Heuristic`] with the default rule.
    Heuristic,
    /// [`lipac::Lipac`] without latency mitigation.
    Lipac,
    /// [`lipac::Lipac`] with latency mitigation (§3.6).
    LipacLatency,
    /// [`Oracle`].
    Oracle,
}

impl StrategyKind {
    /// All, in report order.
    pub const ALL: [StrategyKind; 6] = [
        StrategyKind::Full,
        StrategyKind::Frustum,
        StrategyKind::Heuristic,
        StrategyKind::Lipac,
        StrategyKind::LipacLatency,
        StrategyKind::Oracle,
    ];
    /// The report name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Full => "full",
            Self::Frustum => "frustum",
            Self::Heuristic => "heuristic",
            Self::Lipac => "lipac",
            Self::LipacLatency => "lipac-latency",
            Self::Oracle => "oracle",
        }
    }
    /// The kind named `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }
}
