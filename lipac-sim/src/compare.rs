//! The comparison: a camera path through a scene, the ground truth rendered
//! once per frame, and every strategy rendered against it.
//!
//! Per frame: animate the scene, build the full-scene TLAS at distance LODs
//! (this is also the rasterization stand-in of every render), render the
//! ground truth (every instance traced), then for each strategy: its
//! records, its TLAS, its render with the same random numbers, the error of
//! its indirect light against the ground truth's, its metrics.
//!
//! The full-scene strategy's TLAS *is* the ground truth's, and the hybrid
//! renderer of a TLAS equal to the full scene gives exactly the ground
//! truth (see [`crate::pathtrace`]); with
//! [`CompareConfig::share_ground_truth`] its render is reused instead of
//! traced again (its trace time is then the ground truth's).
//!
//! **Shared work.** What the renders of a frame have in common is done
//! once: the primary hits (every render's primary rays trace the full TLAS,
//! [`crate::pathtrace::PrimaryHits`]), and the render of a TLAS that an
//! earlier strategy of the frame traces too (the same records, merged boxes
//! and hit counters: LiPaC with latency mitigation where the mitigation
//! changed nothing), whose figures, times included, are then that
//! strategy's. The strategies of a frame run side by side, each with its
//! own records and TLAS, and the rows of each render and the animated
//! BLAS refits in parallel, all in one pool of [`CompareConfig::threads`]
//! workers; the figures do not depend on the thread count (timings aside).
//!
//! **Run time.** Every strategy traces the comparison's one shared set of
//! BLASes, so its own BLAS work is counted (triangles built and refit, from
//! its plan) and charged at the obvhs build and refit throughput measured
//! once per run on the scene's meshes ([`crate::blas::BuildThroughput`],
//! [`CompareReport::blas_throughput`]); its TLAS build is a real
//! [`CpuTlas`] build over its own records, its trace time the traversal's.
//! Beside these, the modelled GPU time of the same work
//! ([`crate::metrics::GpuModel::PUBLISHED`], or the rates of
//! [`CompareConfig::device`]'s profile; see [`crate::metrics`]). The memory
//! axis is the profile's sizes ([`crate::memory::MemoryModel`]).

use std::time::Instant;

use glam::Vec3;

use serde::{Deserialize, Serialize};

use crate::blas::{BlasStore, BuildThroughput};
use crate::camera::{CameraPath, FlyCamera};
use crate::device_profile::DeviceProfile;
use crate::error::SimError;
use crate::memory::MemoryModel;
use crate::metrics::{
    apply_strategy_frame, summarize_with, FrameMetrics, GpuModel, Summary, Tracker,
};
use crate::pathtrace::{
    primary_hits, relative_rmse, render_with_primary, worker_threads, FrameOutput, FrameScene,
    PathTraceConfig,
};
use crate::scene::{LodPolicy, Scene, SceneConfig};
use crate::scene_blas::{full_scene_records_at, SceneBlases, UniqueUpdate};
use crate::snapshot::{Snapshot, StrategySnapshot};
use crate::strategy::hindsight::Hindsight;
use crate::strategy::lipac::{Lipac, LipacConfig};
use crate::strategy::{
    FrameContext, FrustumRadius, Full, Heuristic, InstanceCatalog, Oracle, Strategy, StrategyKind,
};
use crate::tlas::{CountingBoxes, CpuTlas};
use crate::tlas_map::TlasMap;
use crate::traversal::{Counters, SlotSet};
use lipac_core::latency::ActivationHeuristic;
use lipac_core::layout::TlasInstance;
use lipac_core::thresholds::DecayedSettings;
use rayon::prelude::*;

/// Which scene to compare on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum SceneChoice {
    /// The default city ([`SceneConfig::city`]).
    City,
    /// The small test scene ([`SceneConfig::small`]).
    Small,
    /// The city with an 80 m mirror block.
    Mirror,
    /// The paper-scale city ([`SceneConfig::paper_city`]): ~120k
    /// instances, 8,000 units, half the buildings fitted to the terrain.
    PaperCity,
}

impl SceneChoice {
    /// The scene's configuration with `seed` (or its own default seed).
    pub fn config(self, seed: Option<u64>) -> SceneConfig {
        let mut c = match self {
            Self::City => SceneConfig::city(),
            Self::Small => SceneConfig::small(),
            Self::Mirror => SceneConfig::city().with_mirror(80.0),
            Self::PaperCity => SceneConfig::paper_city(),
        };
        if let Some(s) = seed {
            c.seed = s;
        }
        c
    }
    /// Every built-in scene.
    pub const ALL: [Self; 4] = [Self::City, Self::Small, Self::Mirror, Self::PaperCity];

    /// Name.
    pub fn name(self) -> &'static str {
        match self {
            Self::City => "city",
            Self::Small => "small",
            Self::Mirror => "mirror",
            Self::PaperCity => "paper-city",
        }
    }

    /// The scene of name `name` ([`SceneChoice::name`]), if any.
    ///
    /// ```
    /// use lipac_sim::compare::SceneChoice;
    /// for s in SceneChoice::ALL {
    ///     assert_eq!(SceneChoice::from_name(s.name()), Some(s));
    /// }
    /// assert_eq!(SceneChoice::from_name("town"), None);
    /// ```
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }
}

/// Settings of a comparison.
#[derive(Clone, Debug, PartialEq)]
pub struct CompareConfig {
    /// Frames to render (`None`: the whole camera path).
    pub frames: Option<u32>,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Strategies, in report order.
    pub strategies: Vec<StrategyKind>,
    /// Reuse the ground truth's render for the full-scene strategy.
    pub share_ground_truth: bool,
    /// Worker threads of the comparison: strategies, image rows and BLAS
    /// refits share them (0 = all cores).
    pub threads: usize,
    /// LiPaC's adaptive hitbox merge levels (`None`:
    /// [`LipacConfig::DEFAULT_ADAPTIVE_LEVELS`]; `Some(0)`: off, one
    /// counting box per inactive hitbox; [`lipac_core::hitbox_tree`]).
    pub adaptive_levels: Option<u8>,
    /// LiPaC's hitbox cell size in metres (`None`:
    /// [`LipacConfig::DEFAULT_CELL_SIZE`]).
    pub lipac_cell_size: Option<f64>,
    /// The rise shift of LiPaC's decayed rule (`None`: that of
    /// [`LipacConfig::DEFAULT_DECAYED`], 1; `Some(k)`: the rate rises with
    /// shift `k`, 1..=its decay shift, docs/EVALUATION.md "A faster rise
    /// than decay"). A shift outside that range is an error.
    pub lipac_rise_shift: Option<u32>,
    /// LiPaC's start: [`LipacConfig::warm_start`] as configured by
    /// default, cold, or warm with a given heuristic.
    pub lipac_start: LipacStart,
    /// LiPaC warm-starts at every camera cut too
    /// ([`LipacConfig::warm_start_at_cuts`]).
    pub lipac_warm_start_at_cuts: bool,
    /// Frames LiPaC holds what a warm start activates
    /// ([`LipacConfig::warm_start_hold`]; `None`: as configured, 0).
    pub lipac_warm_start_hold: Option<u32>,
    /// The device whose acceleration-structure sizes make the memory axis
    /// and whose build rates the modelled GPU time
    /// ([`crate::device_profile`]; default: the built-in profile, lavapipe's
    /// sizes and published rates).
    pub device: DeviceProfile,
}

/// How LiPaC starts in a comparison ([`LipacConfig::warm_start`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum LipacStart {
    /// [`LipacConfig::for_rays_per_frame`]'s choice.
    #[default]
    Default,
    /// The paper's cold start (no warm start).
    Cold,
    /// A warm start with this heuristic.
    Warm(ActivationHeuristic),
}

impl LipacStart {
    /// Sets `config`'s [`LipacConfig::warm_start`] to this start
    /// ([`LipacStart::Default`] leaves it as configured).
    pub fn apply(&self, config: &mut LipacConfig) {
        match *self {
            Self::Default => {}
            Self::Cold => config.warm_start = None,
            Self::Warm(h) => config.warm_start = Some(h),
        }
    }

    /// From the command line's `--warm-start` value: `off` (the paper's
    /// cold start) or `DIST:SIZE[:RADIUS]` (a warm start accepting what is
    /// in view within `DIST` metres or of projected size at least `SIZE`;
    /// `inf:0` takes the whole view; in view: in the frustum or within
    /// `RADIUS` metres in any direction).
    ///
    /// ```
    /// use lipac_sim::compare::LipacStart;
    /// assert_eq!(LipacStart::parse("off"), Ok(LipacStart::Cold));
    /// let LipacStart::Warm(h) = LipacStart::parse("inf:0").unwrap() else { panic!() };
    /// assert_eq!((h.max_distance, h.min_projected_size), (f32::INFINITY, 0.0));
    /// for bad in ["", "50", "-1:0", "50:NaN", "NaN:0.1", "50:inf", "a:b"] {
    ///     assert!(LipacStart::parse(bad).is_err(), "{bad}");
    /// }
    /// ```
    pub fn parse(spec: &str) -> Result<Self, String> {
        Self::parse_with(spec, ':')
    }

    /// [`LipacStart::parse`] with the heuristic's values split by `sep`
    /// (a sweep setting's `^DIST/SIZE[/RADIUS]` takes `/`).
    pub fn parse_with(spec: &str, sep: char) -> Result<Self, String> {
        let spec = spec.trim();
        if spec == "off" {
            return Ok(Self::Cold);
        }
        crate::heuristic_arg::parse_heuristic(spec, sep)
            .map(Self::Warm)
            .map_err(|e| format!("warm start {e}, or `off`"))
    }
}

impl Default for CompareConfig {
    /// 128 x 72, the whole path, all strategies, shared ground truth.
    fn default() -> Self {
        Self {
            frames: None,
            width: 128,
            height: 72,
            strategies: StrategyKind::DEFAULT.to_vec(),
            share_ground_truth: true,
            threads: 0,
            adaptive_levels: None,
            lipac_cell_size: None,
            lipac_rise_shift: None,
            lipac_start: LipacStart::Default,
            lipac_warm_start_at_cuts: false,
            lipac_warm_start_hold: None,
            device: DeviceProfile::builtin(),
        }
    }
}

/// One strategy's results.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StrategyRun {
    /// Strategy name.
    pub name: String,
    /// Summary over all frames.
    pub summary: Summary,
    /// Per-frame metrics.
    pub frames: Vec<FrameMetrics>,
    /// Slots traced as real geometry in the last frame (not serialized).
    #[serde(skip)]
    pub last_geometry: Vec<u32>,
}

/// The comparison's results.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CompareReport {
    /// Scene name.
    pub scene: String,
    /// Scene instances.
    pub instances: u64,
    /// Frames rendered.
    pub frames: u32,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Camera rays per frame (thresholds are scaled to it).
    pub rays_per_frame: u64,
    /// LiPaC thresholds used `[θa, θd, σa, σo, n_a, n_d]`.
    pub thresholds: [u32; 6],
    /// Mean ground-truth render time, ms.
    pub ground_truth_ms: f64,
    /// Mean full-scene TLAS build time, ms.
    pub full_tlas_ms: f64,
    /// Mean BLAS update time of the shared geometry (unit refits), ms.
    pub geometry_ms: f64,
    /// Mean bounce plus shadow rays the ground truth traced per frame (the
    /// rays that count hits; camera rays are `rays_per_frame`).
    #[serde(default)]
    pub traced_rays_per_frame: f64,
    /// Wall time of the whole comparison, s.
    pub wall_s: f64,
    /// The obvhs build and refit throughput every strategy's BLAS work is
    /// charged at (measured once per run on the scene's meshes).
    #[serde(default)]
    pub blas_throughput: BuildThroughput,
    /// The throughput the modelled GPU times assume.
    #[serde(default)]
    pub gpu_model: GpuModel,
    /// Per strategy.
    pub strategies: Vec<StrategyRun>,
    /// Frames at which the camera path jumps ([`CameraPath::cuts`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub camera_cuts: Vec<u32>,
    /// LiPaC's decision rule in words ([`crate::report::rule_description`]):
    /// the paper's thresholds above, or the decayed rule's rates.
    #[serde(default)]
    pub rule: String,
    /// How LiPaC starts, in words ([`crate::report::start_description`]):
    /// cold, or the warm start's set, hold and cuts.
    #[serde(default)]
    pub start: String,
    /// The device profile of the memory axis and the modelled GPU time
    /// ([`CompareConfig::device`]; the built-in one in reports that predate
    /// profiles).
    #[serde(default)]
    pub device_profile: DeviceProfile,
}

impl CompareReport {
    /// The run of strategy `name`.
    pub fn strategy(&self, name: &str) -> Option<&StrategyRun> {
        self.strategies.iter().find(|s| s.name == name)
    }
}

/// A strategy under its report name (several configurations of one
/// strategy can run side by side under different names).
pub struct Contender {
    /// Report name (unique within a run).
    pub name: String,
    /// The strategy (contenders of a frame run in parallel).
    pub strategy: Box<dyn Strategy + Send>,
}

impl std::fmt::Debug for Contender {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Contender")
            .field("name", &self.name)
            .field("strategy", &self.strategy.name())
            .finish()
    }
}

/// Makes the strategy `kind` for `scene` (LiPaC with `lipac`; every
/// strategy's BLASes sized by `lipac.memory`, the comparison's device).
pub fn make_strategy(
    kind: StrategyKind,
    scene: &Scene,
    lipac: &LipacConfig,
) -> Result<Box<dyn Strategy + Send>, SimError> {
    Ok(match kind {
        StrategyKind::Full => Box::new(Full::with_memory(scene, &lipac.memory)?),
        StrategyKind::Frustum => Box::new(FrustumRadius::with_memory(
            scene,
            FrustumRadius::DEFAULT_RADIUS,
            &lipac.memory,
        )?),
        StrategyKind::Heuristic => Box::new(Heuristic::with_memory(
            scene,
            Default::default(),
            &lipac.memory,
        )?),
        StrategyKind::Lipac => Box::new(Lipac::new(scene, lipac.clone())?),
        StrategyKind::LipacLatency => {
            Box::new(Lipac::new(scene, lipac.clone().with_latency_mitigation())?)
        }
        StrategyKind::Oracle => Box::new(Oracle::with_memory(scene, &lipac.memory)?),
        StrategyKind::Hindsight => Box::new(Hindsight::with_memory(
            scene,
            Hindsight::DEFAULT_FRAMES,
            &lipac.memory,
        )?),
    })
}

/// Generates `choice`'s scene and runs the comparison along its fly-through.
/// `progress(done, total)` is called after every frame.
pub fn run_choice(
    choice: SceneChoice,
    seed: Option<u64>,
    config: &CompareConfig,
    progress: &mut dyn FnMut(u32, u32),
) -> Result<CompareReport, SimError> {
    let mut scene = Scene::generate(&choice.config(seed))?;
    let aspect = config.width as f32 / config.height.max(1) as f32;
    let path = CameraPath::flythrough(&scene, aspect);
    run(choice.name(), &mut scene, &path, config, progress)
}

/// Like [`run_choice`], also capturing a [`Snapshot`] of each frame in
/// `snapshots` (frames past the end are ignored).
pub fn run_choice_with_snapshots(
    choice: SceneChoice,
    seed: Option<u64>,
    config: &CompareConfig,
    snapshots: &[u32],
    progress: &mut dyn FnMut(u32, u32),
) -> Result<(CompareReport, Vec<Snapshot>), SimError> {
    let mut scene = Scene::generate(&choice.config(seed))?;
    let aspect = config.width as f32 / config.height.max(1) as f32;
    let path = CameraPath::flythrough(&scene, aspect);
    let contenders = contenders_of(&scene, config)?;
    run_path(
        choice.name(),
        &mut scene,
        &path,
        config,
        contenders,
        snapshots,
        progress,
    )
}

/// Runs the comparison on `scene` along `path` (see the module docs).
pub fn run(
    scene_name: &str,
    scene: &mut Scene,
    path: &CameraPath,
    config: &CompareConfig,
    progress: &mut dyn FnMut(u32, u32),
) -> Result<CompareReport, SimError> {
    let contenders = contenders_of(scene, config)?;
    run_contenders(scene_name, scene, path, config, contenders, progress)
}

/// LiPaC's configuration of a comparison: the defaults for its rays, with
/// `config`'s adaptive hitboxes, cell size, rise shift, start and device.
pub(crate) fn lipac_config_of(config: &CompareConfig) -> Result<LipacConfig, SimError> {
    let rays_per_frame = u64::from(config.width) * u64::from(config.height);
    let mut lipac_config =
        LipacConfig::for_rays_per_frame(rays_per_frame)?.with_memory(config.device.memory_model());
    if let Some(levels) = config.adaptive_levels {
        lipac_config = lipac_config.with_adaptive_hitboxes(levels);
    }
    if let Some(cell) = config.lipac_cell_size {
        lipac_config.cell_size = cell;
    }
    if let Some(k) = config.lipac_rise_shift {
        let settings = DecayedSettings {
            rise_shift: Some(k),
            ..LipacConfig::DEFAULT_DECAYED
        };
        lipac_config = lipac_config.with_decayed_rule(&settings, rays_per_frame)?;
    }
    config.lipac_start.apply(&mut lipac_config);
    lipac_config.warm_start_at_cuts = config.lipac_warm_start_at_cuts;
    if let Some(frames) = config.lipac_warm_start_hold {
        lipac_config.warm_start_hold = frames;
    }
    Ok(lipac_config)
}

/// The strategies of `config.strategies`, under their own names.
pub(crate) fn contenders_of(
    scene: &Scene,
    config: &CompareConfig,
) -> Result<Vec<Contender>, SimError> {
    let lipac_config = lipac_config_of(config)?;
    config
        .strategies
        .iter()
        .map(|&k| {
            Ok(Contender {
                name: k.name().to_string(),
                strategy: make_strategy(k, scene, &lipac_config)?,
            })
        })
        .collect()
}

/// Runs the comparison on `scene` along `path` with `contenders` instead of
/// `config.strategies` (which is ignored): the ground truth is rendered once
/// per frame and every contender against it. Names must be unique. The
/// report's `thresholds` are the default LiPaC thresholds for the image
/// size; a contender's own may differ.
pub fn run_contenders(
    scene_name: &str,
    scene: &mut Scene,
    path: &CameraPath,
    config: &CompareConfig,
    contenders: Vec<Contender>,
    progress: &mut dyn FnMut(u32, u32),
) -> Result<CompareReport, SimError> {
    run_path(scene_name, scene, path, config, contenders, &[], progress).map(|(r, _)| r)
}

pub(crate) fn run_path(
    scene_name: &str,
    scene: &mut Scene,
    path: &CameraPath,
    config: &CompareConfig,
    contenders: Vec<Contender>,
    snapshots: &[u32],
    progress: &mut dyn FnMut(u32, u32),
) -> Result<(CompareReport, Vec<Snapshot>), SimError> {
    let frames = config.frames.unwrap_or(path.frames()).min(path.frames());
    if frames == 0 {
        return Err(SimError::BadConfig("no frames to render"));
    }
    let mut c = Comparison::with_contenders(scene_name, scene, config, contenders)?;
    c.capture_frames(snapshots);
    c.set_camera_cuts(path.cuts());
    for frame in 0..frames {
        scene.set_frame(frame);
        c.frame(scene, frame, &path.camera_at(frame))?;
        progress(frame + 1, frames);
    }
    let (mut report, snaps) = c.finish_with_snapshots()?;
    report.camera_cuts = path
        .cuts()
        .iter()
        .copied()
        .filter(|&f| f < frames)
        .collect();
    Ok((report, snaps))
}

/// The comparison one frame at a time, for callers whose frames come from
/// elsewhere than a [`CameraPath`] (a recorded trace: `crate::replay`).
/// [`run`] is [`Comparison::new`], [`Comparison::frame`] per frame and
/// [`Comparison::finish`].
pub struct Comparison {
    start: Instant,
    scene_name: String,
    config: CompareConfig,
    rays_per_frame: u64,
    lipac_config: LipacConfig,
    pt: PathTraceConfig,
    n: usize,
    catalog: InstanceCatalog,
    lanes: Vec<Lane>,
    pool: rayon::ThreadPool,
    policy: LodPolicy,
    counting: CountingBoxes,
    store: BlasStore,
    unit_cube: u64,
    blases: SceneBlases,
    full_records: Vec<TlasInstance>,
    full_tlas: CpuTlas,
    lods: Vec<u8>,
    all: SlotSet,
    gt_ms: f64,
    full_tlas_ms: f64,
    geometry_ms: f64,
    traced_rays: u64,
    throughput: BuildThroughput,
    gpu: GpuModel,
    memory: MemoryModel,
    frames: u32,
    capture: Vec<u32>,
    cuts: Vec<u32>,
    snapshots: Vec<Snapshot>,
}

/// One contender in a [`Comparison`]: its strategy, its per-frame state and
/// its own scratch (records, TLAS), so that the contenders of a frame run
/// side by side.
struct Lane {
    name: String,
    strategy: Box<dyn Strategy + Send>,
    tracker: Tracker,
    metrics: Vec<FrameMetrics>,
    /// The hit counters its previous frame traced.
    previous: Option<Counters>,
    last_geometry: Vec<u32>,
    records: Vec<TlasInstance>,
    tlas: CpuTlas,
}

/// Where a lane's render of a frame comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum RenderSource {
    /// Its records are the full scene's: the ground truth's render.
    GroundTruth,
    /// Its own TLAS and render.
    Own,
    /// Lane `i` (earlier in the frame) traced exactly the same TLAS: its
    /// render, which would be identical.
    SameAs(usize),
}

/// What a lane's own render of a frame left.
struct Rendered {
    out: FrameOutput,
    tlas_build_ms: f64,
    tlas_len: usize,
    box_count: usize,
}

impl std::fmt::Debug for Comparison {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Comparison")
            .field("scene", &self.scene_name)
            .field("instances", &self.n)
            .field("frames", &self.frames)
            .finish_non_exhaustive()
    }
}

/// How long [`Comparison::new`] spends measuring obvhs BLAS builds, and
/// refits, at least (ms each; [`BuildThroughput::measure`]).
pub const THROUGHPUT_MEASURE_MS: f64 = 30.0;

/// Most pixels an image may have (`width * height`): 2^24, a 4096 x 4096
/// image (the tracer keeps several buffers per pixel; 100000 x 100000 would
/// ask for about 120 GB).
pub const MAX_IMAGE_PIXELS: u64 = 1 << 24;

/// Checks an image size: both sides at least 1 and at most
/// [`MAX_IMAGE_PIXELS`] pixels in all; the error names the values given.
pub fn check_image_size(width: u32, height: u32) -> Result<(), SimError> {
    let pixels = u64::from(width) * u64::from(height);
    if width == 0 || height == 0 || pixels > MAX_IMAGE_PIXELS {
        return Err(SimError::BadValue(format!(
            "image size {width} x {height} ({pixels} pixels): width and height must be at \
             least 1 and width x height at most {MAX_IMAGE_PIXELS} pixels (e.g. 4096 x 4096)"
        )));
    }
    Ok(())
}

impl Comparison {
    /// Sets up the strategies of `config` on `scene` (its instance set is
    /// fixed from now on; only animated transforms change between frames).
    pub fn new(scene_name: &str, scene: &Scene, config: &CompareConfig) -> Result<Self, SimError> {
        let contenders = contenders_of(scene, config)?;
        Self::with_contenders(scene_name, scene, config, contenders)
    }

    /// Like [`Comparison::new`] with `contenders` instead of
    /// `config.strategies` (which is ignored); names must be unique.
    pub fn with_contenders(
        scene_name: &str,
        scene: &Scene,
        config: &CompareConfig,
        contenders: Vec<Contender>,
    ) -> Result<Self, SimError> {
        let start = Instant::now();
        if contenders.is_empty() {
            return Err(SimError::BadConfig("no strategy to compare"));
        }
        for (i, c) in contenders.iter().enumerate() {
            if contenders[..i].iter().any(|d| d.name == c.name) {
                return Err(SimError::BadConfig("two strategies share a report name"));
            }
        }
        check_image_size(config.width, config.height)?;
        let rays_per_frame = u64::from(config.width) * u64::from(config.height);
        let lipac_config = lipac_config_of(config)?;
        let pt = PathTraceConfig {
            width: config.width,
            height: config.height,
            threads: config.threads,
            ..PathTraceConfig::default()
        };
        let n = scene.instances().len();
        let memory = config.device.memory_model();
        let catalog = InstanceCatalog::with_memory(scene, &memory)?;
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(worker_threads(config.threads))
            .build()
            .map_err(|e| SimError::BadValue(format!("comparison threads: {e}")))?;
        let store = BlasStore::new();
        let unit_cube = store.unit_cube().reference();
        let mut all = SlotSet::new();
        (0..n as u32).for_each(|s| all.insert(s));
        let library = scene.library();
        let meshes = (0..library.len())
            .filter_map(|i| library.mesh(i as crate::mesh::MeshIndex).ok())
            .flat_map(|m| m.lods.iter());
        let throughput = BuildThroughput::measure(meshes, THROUGHPUT_MEASURE_MS)?;
        let kinds = catalog.missing_kinds();
        let lanes = contenders
            .into_iter()
            .map(|c| {
                let mut tracker = Tracker::new(n);
                tracker.set_kinds(kinds.clone());
                Lane {
                    name: c.name,
                    strategy: c.strategy,
                    tracker,
                    metrics: Vec::new(),
                    previous: None,
                    last_geometry: Vec::new(),
                    records: Vec::new(),
                    tlas: CpuTlas::default(),
                }
            })
            .collect();
        Ok(Self {
            start,
            scene_name: scene_name.to_string(),
            config: config.clone(),
            rays_per_frame,
            lipac_config,
            pt,
            n,
            catalog,
            lanes,
            pool,
            policy: LodPolicy::default(),
            counting: CountingBoxes::default(),
            store,
            unit_cube,
            blases: SceneBlases::new(),
            full_records: Vec::new(),
            full_tlas: CpuTlas::default(),
            lods: vec![0u8; n],
            all,
            gt_ms: 0.0,
            full_tlas_ms: 0.0,
            geometry_ms: 0.0,
            traced_rays: 0,
            throughput,
            gpu: config.device.gpu_model(),
            memory,
            frames: 0,
            capture: Vec::new(),
            cuts: Vec::new(),
            snapshots: Vec::new(),
        })
    }

    /// The frames at which the camera jumps (a cut the engine knows of,
    /// [`CameraPath::cuts`]): the strategies see them as
    /// [`FrameContext::camera_cut`].
    pub fn set_camera_cuts(&mut self, cuts: &[u32]) {
        self.cuts = cuts.to_vec();
    }

    /// Marks `frame` (not compared yet) as a cut, as
    /// [`Comparison::set_camera_cuts`] does for a whole path: for callers
    /// that find cuts as frames come (a replay,
    /// [`FlyCamera::is_cut_from`]). The report lists the marked cuts.
    pub fn mark_camera_cut(&mut self, frame: u32) {
        if !self.cuts.contains(&frame) {
            self.cuts.push(frame);
        }
    }

    /// Captures a [`Snapshot`] of each of `frames` when it is compared
    /// (the images and TLAS maps of [`crate::snapshot`]); the snapshots come
    /// back from [`Comparison::finish_with_snapshots`].
    pub fn capture_frames(&mut self, frames: &[u32]) {
        self.capture = frames.to_vec();
    }

    /// Frames compared so far.
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// Compares one frame: `scene` animated to `frame` (frame numbers
    /// strictly increase), seen from `camera`.
    pub fn frame(&mut self, scene: &Scene, frame: u32, camera: &FlyCamera) -> Result<(), SimError> {
        self.frame_at(scene, frame, camera, None)
    }

    /// Like [`Comparison::frame`] with each instance's LOD given
    /// (`lods[slot]`, below [`crate::mesh::LOD_COUNT`]) instead of the
    /// distance policy's: a recorded trace's LODs ([`crate::trace_scene`]).
    pub fn frame_with_lods(
        &mut self,
        scene: &Scene,
        frame: u32,
        camera: &FlyCamera,
        lods: &[u8],
    ) -> Result<(), SimError> {
        self.frame_at(scene, frame, camera, Some(lods))
    }

    /// Replaces the sun and sky of every later frame's renders (default:
    /// [`PathTraceConfig::default`]'s); `sun_direction` need not be unit
    /// length but must be finite and non-zero.
    pub fn set_lighting(
        &mut self,
        sun_direction: Vec3,
        sun_irradiance: Vec3,
        sky_radiance: Vec3,
    ) -> Result<(), SimError> {
        let pt = PathTraceConfig {
            sun_direction,
            sun_irradiance,
            sky_radiance,
            ..self.pt
        };
        pt.validate()?;
        self.pt = pt;
        Ok(())
    }

    fn frame_at(
        &mut self,
        scene: &Scene,
        frame: u32,
        camera: &FlyCamera,
        lods: Option<&[u8]>,
    ) -> Result<(), SimError> {
        if scene.instances().len() != self.n {
            return Err(SimError::SizeMismatch {
                a: scene.instances().len(),
                b: self.n,
            });
        }
        let n = self.n;
        let eye = camera.position;
        match lods {
            Some(given) => {
                if given.len() != n {
                    return Err(SimError::SizeMismatch {
                        a: given.len(),
                        b: n,
                    });
                }
                if given
                    .iter()
                    .any(|&l| usize::from(l) >= crate::mesh::LOD_COUNT)
                {
                    return Err(SimError::BadConfig("a given LOD is out of range"));
                }
                self.lods.copy_from_slice(given);
            }
            None => {
                for (l, inst) in self.lods.iter_mut().zip(scene.instances()) {
                    *l = self.policy.lod(eye, &inst.aabb) as u8;
                }
            }
        }
        let t = Instant::now();
        // In the comparison's pool: the animated BLASes refit in parallel.
        let (blases, store, lods, full_records) = (
            &mut self.blases,
            &mut self.store,
            &self.lods,
            &mut self.full_records,
        );
        self.pool.install(|| {
            full_scene_records_at(
                scene,
                blases,
                store,
                lods,
                frame,
                UniqueUpdate::Refit,
                full_records,
            )
        })?;
        self.geometry_ms += ms(t);
        let t = Instant::now();
        self.full_tlas
            .rebuild(&self.store, &self.full_records, &self.counting)?;
        let full_ms = ms(t);
        self.full_tlas_ms += full_ms;
        let Self {
            pool,
            lanes,
            store,
            full_tlas,
            full_records,
            all,
            pt,
            counting,
            catalog,
            lods,
            throughput,
            gpu,
            memory,
            config,
            ..
        } = self;
        let (store, full_tlas, pt, counting) = (&*store, &*full_tlas, &*pt, &*counting);
        let (throughput, gpu, memory) = (&*throughput, &*gpu, &*memory);
        let capture = self.capture.contains(&frame);
        let ctx = FrameContext {
            frame,
            scene,
            camera,
            catalog,
            lods,
            full_records,
            unit_cube: self.unit_cube,
            rays_per_frame: self.rays_per_frame,
            ground_truth_hits: &[],
            camera_cut: self.cuts.contains(&frame),
        };
        let share_ground_truth = config.share_ground_truth;
        let (gt, gt_ms, snapshot) = pool.install(|| -> Result<_, SimError> {
            // The primary hits trace the full TLAS: one set for every render.
            let t = Instant::now();
            let primary = primary_hits(full_tlas, store, camera, pt)?;
            let gt = render_with_primary(
                &FrameScene {
                    store,
                    full: full_tlas,
                    traced: full_tlas,
                    traced_slots: all,
                },
                camera,
                frame,
                pt,
                n,
                0,
                &primary,
            )?;
            let gt_ms = ms(t);
            let gt_rendered = Rendered {
                out: gt,
                tlas_build_ms: full_ms,
                tlas_len: full_tlas.len(),
                box_count: full_tlas.box_count(),
            };
            let ctx = FrameContext {
                ground_truth_hits: &gt_rendered.out.counters.instances,
                ..ctx
            };
            // Each strategy's records, side by side.
            let planned: Vec<Result<FrameMetrics, SimError>> =
                lanes.par_iter_mut().map(|lane| lane.plan(&ctx)).collect();
            let mut metrics = planned.into_iter().collect::<Result<Vec<_>, _>>()?;
            let sources = render_sources(lanes, full_records, counting, share_ground_truth)?;
            // Each distinct TLAS built and rendered, side by side.
            let rendered: Vec<Option<Rendered>> = lanes
                .par_iter_mut()
                .zip(&sources)
                .map(|(lane, source)| {
                    if *source != RenderSource::Own {
                        return Ok(None);
                    }
                    let t = Instant::now();
                    lane.tlas.rebuild_with(
                        store,
                        &lane.records,
                        counting,
                        lane.strategy.merged_boxes().as_deref(),
                    )?;
                    let tlas_build_ms = ms(t);
                    let geometry = SlotSet::from_geometry_records(&lane.records, counting);
                    let out = render_with_primary(
                        &FrameScene {
                            store,
                            full: full_tlas,
                            traced: &lane.tlas,
                            traced_slots: &geometry,
                        },
                        camera,
                        frame,
                        pt,
                        n,
                        lane.strategy.hitboxes(),
                        &primary,
                    )?;
                    Ok(Some(Rendered {
                        out,
                        tlas_build_ms,
                        tlas_len: lane.tlas.len(),
                        box_count: lane.tlas.box_count(),
                    }))
                })
                .collect::<Result<_, SimError>>()?;
            // Each lane's metrics against the ground truth.
            let source_of = |i: usize| match sources[i] {
                RenderSource::GroundTruth => &gt_rendered,
                RenderSource::Own => rendered[i].as_ref().unwrap_or(&gt_rendered),
                RenderSource::SameAs(j) => rendered[j].as_ref().unwrap_or(&gt_rendered),
            };
            let shots: Vec<Option<StrategySnapshot>> = lanes
                .par_iter_mut()
                .zip(&mut metrics)
                .enumerate()
                .map(|(i, (lane, m))| {
                    let r = source_of(i);
                    let shared = sources[i] == RenderSource::GroundTruth;
                    lane.account(
                        &ctx,
                        r,
                        shared,
                        &gt_rendered.out,
                        m,
                        counting,
                        throughput,
                        gpu,
                        memory,
                        capture,
                    )
                })
                .collect::<Result<_, SimError>>()?;
            for (lane, m) in lanes.iter_mut().zip(metrics) {
                lane.metrics.push(m);
            }
            let snapshot = capture.then(|| Snapshot {
                frame,
                width: config.width,
                height: config.height,
                ground_truth: gt_rendered.out.indirect.clone(),
                strategies: shots.into_iter().flatten().collect(),
            });
            Ok((gt_rendered.out, gt_ms, snapshot))
        })?;
        self.gt_ms += gt_ms;
        self.traced_rays += gt.rays.bounce + gt.rays.shadow;
        self.snapshots.extend(snapshot);
        self.frames += 1;
        Ok(())
    }

    /// The report over the frames compared.
    pub fn finish(self) -> Result<CompareReport, SimError> {
        self.finish_with_snapshots().map(|(r, _)| r)
    }

    /// The report over the frames compared, and the snapshots captured
    /// ([`Comparison::capture_frames`]) in frame order.
    pub fn finish_with_snapshots(self) -> Result<(CompareReport, Vec<Snapshot>), SimError> {
        let frames = self.frames;
        if frames == 0 {
            return Err(SimError::BadConfig("no frames to render"));
        }
        let th = self.lipac_config.thresholds;
        let nf = f64::from(frames);
        let strategies = self
            .lanes
            .into_iter()
            .map(|lane| StrategyRun {
                summary: summarize_with(&lane.name, &lane.metrics, &lane.tracker, &self.memory),
                name: lane.name,
                frames: lane.metrics,
                last_geometry: lane.last_geometry,
            })
            .collect();
        let report = CompareReport {
            scene: self.scene_name,
            instances: self.n as u64,
            frames,
            width: self.config.width,
            height: self.config.height,
            rays_per_frame: self.rays_per_frame,
            thresholds: [
                th.theta_a, th.theta_d, th.sigma_a, th.sigma_o, th.n_a, th.n_d,
            ],
            ground_truth_ms: self.gt_ms / nf,
            full_tlas_ms: self.full_tlas_ms / nf,
            geometry_ms: self.geometry_ms / nf,
            traced_rays_per_frame: self.traced_rays as f64 / nf,
            wall_s: self.start.elapsed().as_secs_f64(),
            blas_throughput: self.throughput,
            gpu_model: self.gpu,
            strategies,
            camera_cuts: self.cuts.clone(),
            rule: crate::report::rule_description(&th),
            start: crate::report::start_description(&self.lipac_config),
            device_profile: self.config.device.clone(),
        };
        Ok((report, self.snapshots))
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Where each lane's render comes from this frame: the ground truth's when
/// its records are the full scene's (and `share_ground_truth`), an earlier
/// lane's when it traces exactly the same TLAS (the same records, the same
/// merged boxes' leaves and hitbox counters: the render depends on nothing
/// else), its own otherwise.
fn render_sources(
    lanes: &[Lane],
    full_records: &[TlasInstance],
    counting: &CountingBoxes,
    share_ground_truth: bool,
) -> Result<Vec<RenderSource>, SimError> {
    let mut sources: Vec<RenderSource> = Vec::with_capacity(lanes.len());
    for (i, lane) in lanes.iter().enumerate() {
        let source = if lane.strategy.is_full_scene() && share_ground_truth {
            if lane.records != full_records {
                return Err(SimError::BadConfig(
                    "full-scene strategy's records differ from the ground truth's",
                ));
            }
            RenderSource::GroundTruth
        } else {
            (0..i)
                .find(|&j| sources[j] == RenderSource::Own && same_tlas(&lanes[j], lane, counting))
                .map_or(RenderSource::Own, RenderSource::SameAs)
        };
        sources.push(source);
    }
    Ok(sources)
}

/// Whether lanes `a` and `b` trace the same TLAS with the same counters.
fn same_tlas(a: &Lane, b: &Lane, counting: &CountingBoxes) -> bool {
    if a.records != b.records || a.strategy.hitboxes() != b.strategy.hitboxes() {
        return false;
    }
    let merged = |r: &&TlasInstance| {
        r.acceleration_structure_reference != 0
            && r.mask() != 0
            && r.sbt_offset() == counting.merged_box_sbt
    };
    if !a.records.iter().any(|r| merged(&r)) {
        return true;
    }
    let (Some(ma), Some(mb)) = (a.strategy.merged_boxes(), b.strategy.merged_boxes()) else {
        return false;
    };
    let (mut la, mut lb) = (Vec::new(), Vec::new());
    a.records.iter().filter(merged).all(|r| {
        la.clear();
        lb.clear();
        ma.leaf_boxes(r.custom_index(), &mut la);
        mb.leaf_boxes(r.custom_index(), &mut lb);
        la == lb
    })
}

impl Lane {
    /// The strategy's frame: its records into `self.records`, its BLAS work
    /// and memory into the frame's metrics.
    fn plan(&mut self, ctx: &FrameContext<'_>) -> Result<FrameMetrics, SimError> {
        let t = Instant::now();
        let sf = self
            .strategy
            .frame(ctx, self.previous.as_ref(), &mut self.records)?;
        let mut m = FrameMetrics {
            frame: ctx.frame,
            strategy_ms: ms(t),
            ..FrameMetrics::default()
        };
        apply_strategy_frame(&mut m, &sf);
        Ok(m)
    }

    /// The frame's render `r` (`shared`: the ground truth's, reused)
    /// accounted against the ground truth `gt`: TLAS and trace figures,
    /// error, tracker; the counters for the next frame; a snapshot when
    /// `capture`.
    #[allow(clippy::too_many_arguments)]
    fn account(
        &mut self,
        ctx: &FrameContext<'_>,
        r: &Rendered,
        shared: bool,
        gt: &FrameOutput,
        m: &mut FrameMetrics,
        counting: &CountingBoxes,
        throughput: &BuildThroughput,
        gpu: &GpuModel,
        memory: &MemoryModel,
        capture: bool,
    ) -> Result<Option<StrategySnapshot>, SimError> {
        let n = ctx.full_records.len() as u32;
        let geometry = SlotSet::from_geometry_records(&self.records, counting);
        m.tlas_build_ms = r.tlas_build_ms;
        m.trace_ms = r.out.traced_ns as f64 * 1e-6;
        m.traced_rays = r.out.rays.bounce + r.out.rays.shadow;
        m.tlas_instances = r.tlas_len as u64;
        m.counting_boxes = r.box_count as u64;
        m.tlas_bytes = memory.tlas_bytes(m.tlas_instances);
        m.charge_time(throughput, gpu);
        let geometry_slots = (0..n).filter(|&s| geometry.contains(s));
        self.tracker
            .observe(ctx.frame, geometry_slots, &gt.counters.instances, m);
        m.error = if shared {
            0.0
        } else {
            relative_rmse(&r.out.indirect, &gt.indirect)?
        };
        let counters = match self.previous.take() {
            Some(mut c)
                if c.instances.len() == r.out.counters.instances.len()
                    && c.hitboxes.len() == r.out.counters.hitboxes.len() =>
            {
                c.instances.copy_from_slice(&r.out.counters.instances);
                c.hitboxes.copy_from_slice(&r.out.counters.hitboxes);
                c.dropped = r.out.counters.dropped;
                c
            }
            _ => r.out.counters.clone(),
        };
        let counters = self.previous.insert(counters);
        let snapshot = if capture {
            Some(StrategySnapshot {
                name: self.name.clone(),
                indirect: r.out.indirect.clone(),
                error: m.error,
                map: TlasMap::new(
                    ctx.scene,
                    &self.records,
                    counting,
                    counters,
                    ctx.camera,
                    self.strategy.hitbox_cells().as_deref(),
                )?,
            })
        } else {
            None
        };
        self.last_geometry.clear();
        self.last_geometry
            .extend((0..n).filter(|&s| geometry.contains(s)));
        Ok(snapshot)
    }
}
