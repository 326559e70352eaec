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
//! | [`Oracle`] | exactly the instances the ground-truth paths hit this frame, and the pinned ones (terrain) |
//! | [`hindsight::Hindsight`] | the instances the ground-truth paths hit in the last `k` frames, and the pinned ones (a reference, asked for by name) |
//!
//! # One loop: every strategy on the Manager
//!
//! Every strategy runs on a [`lipac_core::manager::Manager`] through the one
//! CPU backend ([`crate::cpu_backend`]), with the same scheduler settings.
//! LiPaC's set comes from its hit feedback ([`CpuBackend::new`]); a
//! baseline chooses its set each frame and tells its Manager, which runs
//! without hit feedback ([`CpuBackend::engine_selected`],
//! [`lipac_core::culling::Selection::EngineSelected`]): the chosen
//! instances are pinned, the others unpinned (inactive at once, BLAS
//! released), so its TLAS is exactly the set. All share BLASes per (mesh,
//! LOD), give animated units unique BLASes (refit every frame, rebuilt every
//! 16th, only while the instance is in the set), and terrain tiles and
//! terrain-adapted buildings per-instance static BLASes (built once, never
//! refit). Builds are acknowledged immediately: the CPU backend builds
//! synchronously. Sizes come from [`crate::memory`]. The baselines get
//! unlimited per-frame command and build budgets (their set is complete
//! every frame); LiPaC gets the budgets an engine would set. LiPaC pins the
//! terrain tiles (as the paper never culls terrain), and so does the
//! [`Oracle`], LiPaC's yardstick; the other baselines' rules decide for
//! terrain as for everything else.
//!
//! # Geometry traced
//!
//! All strategies trace the same BLASes as the ground truth (one shared
//! [`crate::blas::BlasStore`], geometry at the frame's distance LOD and
//! animation pose): a strategy decides *which* instances are traced, the
//! error therefore measures culling alone. The BLAS work each strategy
//! would pay is what its scheduler reports.

pub mod hindsight;
pub mod lipac;

use std::collections::HashMap;

use glam::Vec3;
use lipac_core::blas_cache::{BlasCache, BlasOwner};
use lipac_core::build_plan::{BuildBudgets, BuildEstimate, FramePlan, UpdateMode};
use lipac_core::grid::HitboxGrid;
use lipac_core::instance::{InstanceDesc, InstanceFlags};
use lipac_core::latency::ActivationHeuristic;
use lipac_core::layout::TlasInstance;
use lipac_core::manager::MeshCatalog;
use lipac_core::math::Aabb;
use lipac_core::registry::InstanceHandle;
use lipac_core::MeshId;

use crate::camera::FlyCamera;
use crate::cpu_backend::CpuBackend;
use crate::error::SimError;
use crate::memory::MemoryModel;
use crate::mesh::{LOD_COUNT, TERRAIN_RESOLUTION};
use crate::metrics::{BlasSplit, MissingKind};
use crate::scene::{flags, Scene, SceneInstance, TERRAIN_MESH};
use crate::scene_blas::instance_mask;
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
    terrain: Vec<bool>,
    memory: MemoryModel,
}

impl InstanceCatalog {
    /// Catalog of every instance of `scene`, its BLASes sized by the
    /// built-in memory model ([`MemoryModel::default`]).
    pub fn new(scene: &Scene) -> Result<Self, SimError> {
        Self::with_memory(scene, &MemoryModel::default())
    }

    /// Catalog of every instance of `scene`, its BLASes sized by `memory`
    /// (a device profile's, [`crate::device_profile`]).
    pub fn with_memory(scene: &Scene, memory: &MemoryModel) -> Result<Self, SimError> {
        let n = scene.instances().len();
        let mut triangles = Vec::with_capacity(n);
        let mut kinds = Vec::with_capacity(n);
        let mut meshes = Vec::with_capacity(n);
        let mut terrain = Vec::with_capacity(n);
        for inst in scene.instances() {
            terrain.push(inst.flags & flags::TERRAIN != 0);
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
            terrain,
            memory: memory.clone(),
        })
    }
    /// The memory model sizing the catalog's BLASes.
    pub fn memory(&self) -> &MemoryModel {
        &self.memory
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
    /// Whether instance `slot` is a terrain tile.
    pub fn is_terrain(&self, slot: u32) -> bool {
        self.terrain.get(slot as usize).copied().unwrap_or(false)
    }
    /// Every instance's kind for the missing-instance split
    /// ([`crate::metrics::Tracker::set_kinds`]).
    pub fn missing_kinds(&self) -> Vec<MissingKind> {
        self.kinds
            .iter()
            .zip(&self.terrain)
            .map(|(&k, &t)| match (t, k) {
                (true, _) => MissingKind::Terrain,
                (false, BlasOwnership::Shared) => MissingKind::Shared,
                (false, _) => MissingKind::Unique,
            })
            .collect()
    }
    /// The BLAS bytes `cache` holds by [`BlasSplit`] term. An own static
    /// BLAS (terrain tile, terrain-adapted building) is a shared cache
    /// entry of its own variant (2 and up, one per registration: the
    /// Manager's rule); terrain tiles' mesh is [`TERRAIN_MESH`].
    pub fn blas_split(&self, cache: &BlasCache) -> BlasSplit {
        let mut split = BlasSplit::default();
        for (_, info, bytes) in cache.entries() {
            let term = match info.owner {
                _ if info.refs == 0 => &mut split.shared_cached,
                BlasOwner::Shared(k) if k.mesh.0 == TERRAIN_MESH => &mut split.terrain,
                BlasOwner::Shared(k) if k.variant >= 2 => &mut split.unique,
                BlasOwner::Shared(_) => &mut split.shared_used,
                BlasOwner::Unique { .. } => &mut split.unique,
            };
            *term += bytes;
        }
        split
    }
    /// Build sizes of instance `slot` at `lod` (the catalog's
    /// [`MemoryModel`]).
    pub fn estimate(&self, slot: u32, lod: usize) -> BuildEstimate {
        self.memory
            .build_estimate(u64::from(self.triangles(slot, lod)))
    }
    /// The Manager's mesh catalog: every mesh of the scene with its
    /// [`LOD_COUNT`] LODs ([`MemoryModel::mesh_lod`]). Fails if two
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
                .map(|&t| self.memory.mesh_lod(u64::from(t)))
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

/// Hitbox cell size of the baselines' Manager, metres: it only needs to
/// cover the scene (every hitbox is active, no counting box is emitted).
const BASELINE_CELL_SIZE: f64 = 256.0;

/// The hitbox grid over `scene` with cells of `cell` metres (LiPaC's and
/// the baselines', [`crate::record::hitbox_grid`]).
pub fn scene_grid(scene: &Scene, cell: f64) -> Result<HitboxGrid, SimError> {
    HitboxGrid::new(crate::record::hitbox_grid(&scene.bounds(), cell)).map_err(SimError::core)
}
/// What one frame gives a strategy.
#[derive(Clone, Copy, Debug)]
pub struct FrameContext<'a> {
    /// Frame number.
    pub frame: u32,
    /// The scene, animated to `frame`.
    pub scene: &'a Scene,
    /// The camera of this frame.
    pub camera: &'a FlyCamera,
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
    /// Whether the camera jumped to this frame (a cut the engine knows of:
    /// LiPaC warm-starts there, [`lipac::LipacConfig::warm_start_at_cuts`]).
    pub camera_cut: bool,
}

/// What a strategy reports for one frame (besides its records).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StrategyFrame {
    /// BLAS work done this frame.
    pub work: BlasWork,
    /// Modelled bytes of the BLASes it holds.
    pub blas_bytes: u64,
    /// Those bytes by what holds them.
    pub blas_split: BlasSplit,
    /// Modelled bytes of its own buffers (LiPaC: hitboxes, hit counters).
    pub overhead_bytes: u64,
    /// LiPaC: the closed-loop view of the frame ([`ControlFrame`]).
    pub control: Option<ControlFrame>,
}

/// LiPaC's closed-loop thresholds in one frame ([`lipac_core::controller`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ControlFrame {
    /// Escape fraction of the hits the Manager counted last (the previous
    /// frame's trace), `None` without hits.
    pub escape_fraction: Option<f64>,
    /// The scale on the thresholds (1 without a target).
    pub threshold_scale: f64,
    /// The bytes a memory budget holds, as the Manager accounts them.
    pub controlled_bytes: u64,
    /// The target (bytes or fraction), `None` without one.
    pub target: Option<f64>,
    /// The controller reports its target unreachable.
    pub unreachable: bool,
}

/// A culling strategy (see the module docs).
pub trait Strategy {
    /// Short name (report key).
    fn name(&self) -> &str;
    /// Hitbox counters it needs from the tracer (0: none).
    fn hitboxes(&self) -> usize {
        0
    }
    /// Its hitbox cells with their state, for the TLAS map
    /// ([`crate::tlas_map::TlasMap::new`]); `None` without hitboxes.
    fn hitbox_cells(&self) -> Option<Vec<crate::tlas_map::HitboxCell>> {
        None
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
    /// The resolver of this frame's merged counting boxes (adaptive
    /// hitboxes, [`crate::tlas::MergedBoxes`]), `None` without them.
    fn merged_boxes(&self) -> Option<Box<dyn crate::tlas::MergedBoxes + '_>> {
        None
    }
    /// Whether this frame's records are exactly `ctx.full_records` (then the
    /// ground truth's render can be reused).
    fn is_full_scene(&self) -> bool {
        false
    }
}

/// Shared part of the set-based baselines: the scene's instances in one
/// [`CpuBackend`] whose set the baseline chooses each frame
/// ([`CpuBackend::engine_selected`]: pinned = selected; see the module
/// docs); its records carry this frame's geometry.
#[derive(Debug)]
struct SetStrategy {
    backend: CpuBackend,
    handles: Vec<InstanceHandle>,
    /// The LOD requested for each slot.
    lods: Vec<u8>,
    /// The set the Manager was told (pinned).
    selected: Vec<bool>,
    /// This frame's choice.
    wanted: Vec<bool>,
    records: Vec<TlasInstance>,
}

impl SetStrategy {
    /// Registers every instance of `scene` (frame 0 state, none selected;
    /// registry slots = scene slots).
    fn new(scene: &Scene, memory: &MemoryModel) -> Result<Self, SimError> {
        let catalog = InstanceCatalog::with_memory(scene, memory)?.mesh_catalog()?;
        let mut backend =
            CpuBackend::engine_selected(scene_grid(scene, BASELINE_CELL_SIZE)?, catalog)?;
        let n = scene.instances().len();
        backend.reserve(n)?;
        let mut handles = Vec::with_capacity(n);
        for (slot, inst) in scene.instances().iter().enumerate() {
            let mut flags = inst.instance_flags();
            // The baseline's rule alone decides, for terrain too.
            flags.remove(InstanceFlags::PINNED);
            let desc = InstanceDesc {
                flags,
                mask: instance_mask(inst),
                ..InstanceDesc::new(MeshId(inst.mesh), inst.transform, inst.aabb)
            };
            let h = backend.register(desc)?;
            let got = backend.instance(h)?.slot;
            if got != slot as u32 {
                return Err(SimError::Core(format!(
                    "registry slot {got} for scene slot {slot}"
                )));
            }
            handles.push(h);
        }
        Ok(Self {
            backend,
            lods: vec![0; n],
            selected: vec![false; n],
            wanted: vec![false; n],
            records: Vec::new(),
            handles,
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

    /// One frame on the Manager: the frame's LODs, the set's changes as
    /// pins and unpins, the plan (builds acknowledged at once), Algorithm 1;
    /// the traced records are this frame's full-scene records of the set.
    fn run(
        &mut self,
        ctx: &FrameContext<'_>,
        out: &mut Vec<TlasInstance>,
    ) -> Result<StrategyFrame, SimError> {
        let n = self.handles.len();
        if ctx.full_records.len() != n || ctx.lods.len() != n || self.wanted.len() != n {
            return Err(SimError::SizeMismatch {
                a: ctx.full_records.len().min(ctx.lods.len()),
                b: n,
            });
        }
        // No hit feedback: ends the previous frame (the call order).
        self.backend.end_frame()?;
        self.backend.begin_frame(ctx.frame)?;
        for (slot, (&lod, last)) in ctx.lods.iter().zip(&mut self.lods).enumerate() {
            if lod != *last {
                *last = lod;
                self.backend.set_lod(self.handles[slot], u32::from(lod))?;
            }
        }
        for (slot, (&w, sel)) in self.wanted.iter().zip(&mut self.selected).enumerate() {
            if w != *sel {
                *sel = w;
                self.backend.set_pinned(self.handles[slot], w)?;
            }
        }
        let f = self.backend.run(ctx.camera, &mut self.records)?;
        out.clear();
        for r in &self.records {
            let slot = r.custom_index();
            let full = ctx
                .full_records
                .get(slot as usize)
                .ok_or(SimError::UnknownInstance(slot))?;
            out.push(*full);
        }
        Ok(StrategyFrame {
            work: f.work,
            blas_bytes: self.backend.blas_bytes(),
            blas_split: ctx
                .catalog
                .blas_split(self.backend.manager().scheduler().cache()),
            overhead_bytes: 0,
            control: None,
        })
    }
}

/// Every instance, every frame: the unculled scene.
#[derive(Debug)]
pub struct Full(SetStrategy);

impl Full {
    /// For the instances of `scene` (the built-in memory model).
    pub fn new(scene: &Scene) -> Result<Self, SimError> {
        Self::with_memory(scene, &MemoryModel::default())
    }
    /// For the instances of `scene`, its BLASes sized by `memory`.
    pub fn with_memory(scene: &Scene, memory: &MemoryModel) -> Result<Self, SimError> {
        let mut s = SetStrategy::new(scene, memory)?;
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
    /// For the instances of `scene` and a keep-radius of `radius` metres
    /// (the built-in memory model).
    pub fn new(scene: &Scene, radius: f32) -> Result<Self, SimError> {
        Self::with_memory(scene, radius, &MemoryModel::default())
    }
    /// As [`FrustumRadius::new`], its BLASes sized by `memory`.
    pub fn with_memory(scene: &Scene, radius: f32, memory: &MemoryModel) -> Result<Self, SimError> {
        if !radius.is_finite() || radius < 0.0 {
            return Err(SimError::BadConfig("radius must be finite and >= 0"));
        }
        Ok(Self {
            set: SetStrategy::new(scene, memory)?,
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
    /// For the instances of `scene` with `rule` (default: within 50 m, or
    /// `radius / distance >= 0.1`; the built-in memory model).
    pub fn new(scene: &Scene, rule: ActivationHeuristic) -> Result<Self, SimError> {
        Self::with_memory(scene, rule, &MemoryModel::default())
    }
    /// As [`Heuristic::new`], its BLASes sized by `memory`.
    pub fn with_memory(
        scene: &Scene,
        rule: ActivationHeuristic,
        memory: &MemoryModel,
    ) -> Result<Self, SimError> {
        if rule.max_distance.is_nan()
            || rule.max_distance < 0.0
            || rule.min_projected_size.is_nan()
            || rule.min_projected_size < 0.0
        {
            return Err(SimError::BadConfig("heuristic values must be >= 0"));
        }
        Ok(Self {
            set: SetStrategy::new(scene, memory)?,
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

/// Exactly the instances this frame's ground-truth bounce rays hit, plus
/// the pinned ones (terrain tiles), which LiPaC keeps too: the yardstick of
/// LiPaC's memory compares like with like (docs/EVALUATION.md, "Where
/// LiPaC's memory goes").
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
    /// For the instances of `scene` (the built-in memory model).
    pub fn new(scene: &Scene) -> Result<Self, SimError> {
        Self::with_memory(scene, &MemoryModel::default())
    }
    /// For the instances of `scene`, its BLASes sized by `memory`.
    pub fn with_memory(scene: &Scene, memory: &MemoryModel) -> Result<Self, SimError> {
        Ok(Self(SetStrategy::new(scene, memory)?))
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
        let hits = ground_truth_hits(ctx)?;
        self.0
            .run_selected(ctx, out, |slot, inst| hits[slot] > 0 || inst.is_pinned())
    }
}

/// This frame's ground-truth hits, one counter per scene instance (the
/// references' input: [`Oracle`], [`hindsight::Hindsight`]).
fn ground_truth_hits<'a>(ctx: &FrameContext<'a>) -> Result<&'a [u32], SimError> {
    let n = ctx.scene.instances().len();
    if ctx.ground_truth_hits.len() != n {
        return Err(SimError::SizeMismatch {
            a: ctx.ground_truth_hits.len(),
            b: n,
        });
    }
    Ok(ctx.ground_truth_hits)
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
    /// [`hindsight::Hindsight`] with
    /// [`hindsight::Hindsight::DEFAULT_FRAMES`] (a reference: only when
    /// named, not in [`StrategyKind::DEFAULT`]).
    Hindsight,
}

impl StrategyKind {
    /// What a comparison runs when none are named, in report order: every
    /// kind but the [`StrategyKind::Hindsight`] reference.
    pub const DEFAULT: [StrategyKind; 6] = [
        StrategyKind::Full,
        StrategyKind::Frustum,
        StrategyKind::Heuristic,
        StrategyKind::Lipac,
        StrategyKind::LipacLatency,
        StrategyKind::Oracle,
    ];
    /// Every kind, in report order: [`StrategyKind::DEFAULT`], then the
    /// hindsight reference.
    pub const ALL: [StrategyKind; 7] = {
        let mut all = [StrategyKind::Hindsight; 7];
        let mut i = 0;
        while i < Self::DEFAULT.len() {
            all[i] = Self::DEFAULT[i];
            i += 1;
        }
        all
    };

    /// Whether it reads the ground truth's hits (the oracle and hindsight):
    /// a yardstick, never on a sweep's fronts.
    pub fn is_reference(self) -> bool {
        matches!(self, Self::Oracle | Self::Hindsight)
    }
    /// The report name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Full => "full",
            Self::Frustum => "frustum",
            Self::Heuristic => "heuristic",
            Self::Lipac => "lipac",
            Self::LipacLatency => "lipac-latency",
            Self::Oracle => "oracle",
            Self::Hindsight => "hindsight",
        }
    }
    /// The kind named `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }
}
