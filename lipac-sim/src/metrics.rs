//! Per-frame metrics of a strategy and their summary.
//!
//! * **Instances in the TLAS**: records traced (real instances plus counting
//!   boxes).
//! * **Memory**: modelled BLAS and TLAS bytes ([`crate::memory`]) plus
//!   LiPaC's own buffers.
//! * **BLAS work**: builds (new and periodic rebuilds), refits, primitives.
//! * **State changes**: instances entering or leaving the TLAS as real
//!   geometry. A **cycle** is an instance re-entering within
//!   [`CYCLE_WINDOW`] frames of leaving (active → inactive → active).
//! * **Latency**: for every instance the ground-truth paths hit, frames from
//!   the first frame they hit it to the first frame (from then on) it is in
//!   the strategy's TLAS as real geometry; instances never in it by the end
//!   are counted as `never_active` instead.
//! * **Needed but missing**: instances the ground-truth paths hit this frame
//!   that the strategy's TLAS lacks.
//! * **Error**: relative RMSE of the indirect light against the ground truth.
//! * **Run time** (measured on this CPU): BLAS builds and refits
//!   (`blas_build_ms`, `blas_refit_ms`: the strategy's counted triangles
//!   charged at the obvhs throughput measured once per run,
//!   [`crate::blas::BuildThroughput`]), its TLAS build (`tlas_build_ms`, a
//!   real [`crate::tlas::CpuTlas`] build over its records) and its
//!   traversal (`trace_ms`); `frame_ms` is their sum.
//! * **Modelled GPU time** (`gpu_*`): the same work at published GPU
//!   throughput ([`GpuModel`]); a model, not a measurement.

use serde::{Deserialize, Serialize};

use crate::blas::BuildThroughput;
use crate::memory::MemoryModel;
use crate::strategy::{BlasWork, StrategyFrame};

/// How the times of the reports are made (one paragraph of Markdown, for
/// `report.md` and `sweep.md`).
pub const TIMING_NOTE: &str = "Frame time (CPU, measured) = BLAS builds + BLAS refits + TLAS \
build + trace. Every strategy traces one shared set of BLASes, so its BLAS work is its plan's \
triangles built and refit charged at the obvhs build and refit throughput measured once per \
run on the scene's meshes; its TLAS build is a real CPU build over its own records; trace \
times are the CPU time (summed over threads) of the bounce and shadow rays traced against its \
TLAS, on whatever else the machine ran (primary hits and the rasterized-shadow fallback stand \
in for rasterization and are excluded; the full-scene strategy's is the ground truth's). \
Modelled GPU time (a model, not a measurement) = triangles built / 0.31 G/s + triangles \
refit / 3.03 G/s (NVIDIA's vk_animated_clusters sample, RTX 6000 Ada) + TLAS instances / \
0.31 G/s (assumed: an instance costs a triangle of a full build) + bounce and shadow rays / \
1 G/s (assumed); docs/EVALUATION.md, \"Run time against error\".";

/// Frames within which leaving and re-entering the TLAS counts as a cycle.
pub const CYCLE_WINDOW: u32 = 30;

/// One strategy, one frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FrameMetrics {
    /// Frame number.
    pub frame: u32,
    /// TLAS records traced (real instances plus counting boxes).
    pub tlas_instances: u64,
    /// Of those, counting boxes.
    pub counting_boxes: u64,
    /// Modelled BLAS bytes held.
    pub blas_bytes: u64,
    /// Modelled TLAS bytes.
    pub tlas_bytes: u64,
    /// LiPaC's hitbox records and hit counters, bytes.
    pub overhead_bytes: u64,
    /// BLAS builds (new and rebuilds).
    pub builds: u64,
    /// BLAS refits.
    pub refits: u64,
    /// Triangles built.
    pub primitives_built: u64,
    /// Triangles refit.
    pub primitives_refit: u64,
    /// Instances entering or leaving the TLAS as real geometry.
    pub state_changes: u64,
    /// Of the entries, re-entries within [`CYCLE_WINDOW`] frames.
    pub cycles: u64,
    /// Latency samples completed this frame.
    pub latency_samples: u64,
    /// Sum of those latencies, frames.
    pub latency_sum: u64,
    /// Instances hit by this frame's ground-truth paths missing from the TLAS.
    pub needed_missing: u64,
    /// Relative RMSE of the indirect light against the ground truth.
    #[serde(with = "crate::json_float")]
    pub error: f64,
    /// CPU time (summed over threads) of the bounce and shadow rays traced
    /// against the strategy's TLAS, ms. Primary hits and the rasterized-shadow
    /// fallback stand in for rasterization, which every strategy pays alike,
    /// and are excluded (see `pathtrace::FrameOutput::traced_ns`).
    pub trace_ms: f64,
    /// Wall time of its TLAS build, ms.
    pub tlas_build_ms: f64,
    /// Wall time of the strategy's own frame logic, ms.
    pub strategy_ms: f64,
    /// LiPaC: escape fraction of the hits the Manager counted this frame
    /// (those of the previous frame's trace; [`lipac_core::controller`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub escape_fraction: Option<f64>,
    /// LiPaC: the scale on the thresholds (1 without a closed-loop target).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threshold_scale: Option<f64>,
    /// LiPaC: the bytes a memory budget holds, as the Manager accounts them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub controlled_bytes: Option<u64>,
    /// LiPaC with a closed-loop target: the target (bytes or fraction).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub control_target: Option<f64>,
    /// LiPaC with a target: the controller reports it unreachable.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub control_unreachable: bool,
    /// Bounce and shadow rays traced against the strategy's TLAS.
    #[serde(default)]
    pub traced_rays: u64,
    /// Its BLAS builds on obvhs, ms: `primitives_built` at the run's
    /// measured build throughput.
    #[serde(default)]
    pub blas_build_ms: f64,
    /// Its BLAS refits on obvhs, ms: `primitives_refit` at the run's
    /// measured refit throughput.
    #[serde(default)]
    pub blas_refit_ms: f64,
    /// `blas_build_ms + blas_refit_ms + tlas_build_ms + trace_ms`.
    #[serde(default)]
    pub frame_ms: f64,
    /// Modelled GPU BLAS build time, ms ([`GpuModel`]).
    #[serde(default)]
    pub gpu_blas_build_ms: f64,
    /// Modelled GPU BLAS refit time, ms.
    #[serde(default)]
    pub gpu_blas_refit_ms: f64,
    /// Modelled GPU TLAS build time, ms.
    #[serde(default)]
    pub gpu_tlas_build_ms: f64,
    /// Modelled GPU trace time of `traced_rays`, ms.
    #[serde(default)]
    pub gpu_trace_ms: f64,
    /// Sum of the four modelled GPU times, ms.
    #[serde(default)]
    pub gpu_frame_ms: f64,
    /// `blas_bytes` by what holds them ([`BlasSplit`]).
    #[serde(default)]
    pub blas_split: BlasSplit,
    /// `needed_missing` by the instance's kind ([`MissingKind`], in its
    /// order: terrain, shared BLAS, own BLAS).
    #[serde(default)]
    pub missing_by_kind: [u64; 3],
    /// Ground-truth hits (bounce rays) on the instances missing this frame.
    #[serde(default)]
    pub missing_hits: u64,
    /// Ground-truth hits on every instance this frame.
    #[serde(default)]
    pub needed_hits: u64,
}

/// A strategy's BLAS bytes by what holds them (sums to its BLAS bytes but
/// for the counting-box unit cube; builds in flight count their reserved
/// estimate; scratch is none in the sim, whose builds complete at once).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct BlasSplit {
    /// Terrain tiles' own BLASes in use.
    pub terrain: u64,
    /// Other instances' own BLASes in use (animated units,
    /// terrain-adapted buildings).
    pub unique: u64,
    /// Shared BLASes with at least one active instance.
    pub shared_used: u64,
    /// BLASes no active instance uses (shared ones, and own static ones of
    /// deactivated instances), kept by the BLAS cache's retention
    /// (`max_unused_frames`) for reuse.
    pub shared_cached: u64,
}

impl BlasSplit {
    /// The sum of the four.
    pub fn total(&self) -> u64 {
        self.terrain + self.unique + self.shared_used + self.shared_cached
    }
}

/// The kinds of instances [`Tracker`] splits missing instances by.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum MissingKind {
    /// A terrain tile.
    Terrain,
    /// An instance of a shared BLAS.
    #[default]
    Shared,
    /// An instance with its own BLAS (animated, terrain-adapted).
    Unique,
}

/// Classes of [`MissingTail`]: an instance is counted in the first class
/// whose bound is at least the number of frames it was missing while the
/// ground truth hit it (1–2: the read-back latency; 3–10; 11–30; more).
pub const MISSING_CLASS_BOUNDS: [u32; 4] = [2, 10, 30, u32::MAX];

/// How long needed instances stayed missing over a run: per
/// [`MISSING_CLASS_BOUNDS`] class, the instances and the ground-truth hits
/// on them in the frames they were missing.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct MissingTail {
    /// Instances per class.
    pub instances: [u64; 4],
    /// Their ground-truth hits while missing, per class.
    pub hits: [u64; 4],
}

impl FrameMetrics {
    /// BLAS + TLAS + overhead bytes.
    pub fn total_bytes(&self) -> u64 {
        self.blas_bytes + self.tlas_bytes + self.overhead_bytes
    }
    /// Fills `blas_build_ms` and `blas_refit_ms` from the triangles counted
    /// at `throughput`, `frame_ms` as the sum of the four CPU times (so
    /// `trace_ms` and `tlas_build_ms` must be set first), and the `gpu_*`
    /// times from `gpu`.
    pub fn charge_time(&mut self, throughput: &BuildThroughput, gpu: &GpuModel) {
        self.blas_build_ms = throughput.build_ms(self.primitives_built);
        self.blas_refit_ms = throughput.refit_ms(self.primitives_refit);
        self.frame_ms =
            self.blas_build_ms + self.blas_refit_ms + self.tlas_build_ms + self.trace_ms;
        let g = gpu.frame(
            self.primitives_built,
            self.builds,
            self.primitives_refit,
            self.tlas_instances,
            self.traced_rays,
        );
        self.gpu_blas_build_ms = g.blas_build_ms;
        self.gpu_blas_refit_ms = g.blas_refit_ms;
        self.gpu_tlas_build_ms = g.tlas_build_ms;
        self.gpu_trace_ms = g.trace_ms;
        self.gpu_frame_ms = g.frame_ms;
    }

    /// The same metrics with the wall-clock timings zeroed (for
    /// determinism checks; the modelled GPU times are kept: they follow
    /// from counts).
    pub fn without_timings(&self) -> Self {
        Self {
            trace_ms: 0.0,
            tlas_build_ms: 0.0,
            strategy_ms: 0.0,
            blas_build_ms: 0.0,
            blas_refit_ms: 0.0,
            frame_ms: 0.0,
            ..self.clone()
        }
    }
}

/// Summary of one strategy over a run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Strategy name.
    pub strategy: String,
    /// Frames.
    pub frames: u32,
    /// Mean TLAS records.
    pub mean_instances: f64,
    /// Peak TLAS records.
    pub peak_instances: u64,
    /// Mean total memory, MiB.
    pub mean_mib: f64,
    /// Peak total memory, MiB.
    pub peak_mib: f64,
    /// Mean BLAS memory, MiB.
    pub mean_blas_mib: f64,
    /// Total builds.
    pub builds: u64,
    /// Total refits.
    pub refits: u64,
    /// Total triangles built.
    pub primitives_built: u64,
    /// Total triangles refit.
    pub primitives_refit: u64,
    /// Total state changes.
    pub state_changes: u64,
    /// Total cycles.
    pub cycles: u64,
    /// Mean latency over completed samples, frames (0 without samples).
    pub mean_latency: f64,
    /// 95th percentile latency, frames.
    pub p95_latency: u32,
    /// Latency samples.
    pub latency_samples: u64,
    /// Needed instances never in the TLAS by the end.
    pub never_active: u64,
    /// Mean needed-but-missing instances per frame.
    pub mean_needed_missing: f64,
    /// Mean error.
    #[serde(with = "crate::json_float")]
    pub mean_error: f64,
    /// Largest error of a frame.
    #[serde(with = "crate::json_float")]
    pub max_error: f64,
    /// Mean trace time, ms.
    pub mean_trace_ms: f64,
    /// Mean TLAS build time, ms.
    pub mean_tlas_build_ms: f64,
    /// Mean strategy logic time, ms.
    pub mean_strategy_ms: f64,
    /// Mean bounce and shadow rays traced per frame.
    #[serde(default)]
    pub mean_traced_rays: f64,
    /// Mean BLAS build time on obvhs, ms.
    #[serde(default)]
    pub mean_blas_build_ms: f64,
    /// Mean BLAS refit time on obvhs, ms.
    #[serde(default)]
    pub mean_blas_refit_ms: f64,
    /// Mean frame time (BLAS builds, refits, TLAS build, trace), ms.
    #[serde(default)]
    pub mean_frame_ms: f64,
    /// Median frame time, ms.
    #[serde(default)]
    pub median_frame_ms: f64,
    /// Mean modelled GPU BLAS build time, ms.
    #[serde(default)]
    pub mean_gpu_blas_build_ms: f64,
    /// Mean modelled GPU BLAS refit time, ms.
    #[serde(default)]
    pub mean_gpu_blas_refit_ms: f64,
    /// Mean modelled GPU TLAS build time, ms.
    #[serde(default)]
    pub mean_gpu_tlas_build_ms: f64,
    /// Mean modelled GPU trace time, ms.
    #[serde(default)]
    pub mean_gpu_trace_ms: f64,
    /// Mean modelled GPU frame time, ms.
    #[serde(default)]
    pub mean_gpu_frame_ms: f64,
    /// Mean memory by term, MiB: terrain BLASes, other own BLASes, shared
    /// BLASes in use, shared BLASes only cached ([`BlasSplit`]), TLAS
    /// records of geometry, TLAS records of counting boxes, LiPaC's own
    /// buffers.
    #[serde(default)]
    pub mean_split_mib: [f64; 7],
    /// Mean needed-but-missing instances per frame by [`MissingKind`].
    #[serde(default)]
    pub mean_missing_by_kind: [f64; 3],
    /// Share of the ground-truth hits that fell on missing instances.
    #[serde(default)]
    pub missing_hit_share: f64,
    /// How long missing instances stayed missing.
    #[serde(default)]
    pub missing_tail: MissingTail,
}

/// Modelled GPU time of acceleration-structure work and tracing: each
/// count divided by a throughput, plus a fixed cost per BLAS build
/// ([`GpuModel::PUBLISHED`] gives the figures and their sources; a device
/// profile its own, [`crate::device_profile::DeviceProfile::gpu_model`]).
/// A second, clearly labelled figure beside the measured CPU times, not a
/// measurement.
///
/// ```
/// use lipac_sim::metrics::GpuModel;
/// let m = GpuModel { build_triangles_per_s: 1e8, build_s_per_blas: 0.0,
///     refit_triangles_per_s: 1e9, tlas_instances_per_s: 1e7, rays_per_s: 1e9 };
/// let t = m.frame(100_000, 10, 1_000_000, 10_000, 2_000_000);
/// assert_eq!((t.blas_build_ms, t.blas_refit_ms, t.tlas_build_ms, t.trace_ms), (1.0, 1.0, 1.0, 2.0));
/// assert_eq!(t.frame_ms, 5.0);
/// // With a cost per build: 10 builds of 10 µs each on top.
/// let m = GpuModel { build_s_per_blas: 1e-5, ..m };
/// assert!((m.frame(100_000, 10, 0, 0, 0).blas_build_ms - 1.1).abs() < 1e-12);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GpuModel {
    /// Triangles a full BLAS build processes per second.
    pub build_triangles_per_s: f64,
    /// Seconds every BLAS build costs besides its triangles (0 for the
    /// published rates; a device profile's timed batches of small and
    /// large meshes give it).
    #[serde(default)]
    pub build_s_per_blas: f64,
    /// Triangles a BLAS refit processes per second.
    pub refit_triangles_per_s: f64,
    /// Instances a TLAS build processes per second.
    pub tlas_instances_per_s: f64,
    /// Bounce and shadow rays traced per second.
    pub rays_per_s: f64,
}

/// One frame of [`GpuModel`] time, ms.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GpuFrame {
    /// BLAS builds.
    pub blas_build_ms: f64,
    /// BLAS refits.
    pub blas_refit_ms: f64,
    /// TLAS build.
    pub tlas_build_ms: f64,
    /// Tracing.
    pub trace_ms: f64,
    /// The sum of the four.
    pub frame_ms: f64,
}

impl GpuModel {
    /// NVIDIA's vk_animated_clusters sample (README, "Preliminary
    /// Performance Results": 8.43 M animated triangles, fast-build BLASes,
    /// RTX 6000 Ada, 2560 x 1440): refit only, 2.78 ms for the AS update:
    /// 8.43 M / 2.78 ms = 3.03 G triangles/s; 10 % rebuilds, 5.22 ms: the
    /// rebuilt 0.843 M triangles took 5.22 − 0.9 · 2.78 = 2.718 ms, 0.310 G
    /// triangles/s. TLAS: an assumption, an instance costs what a
    /// triangle of a full build does (0.310 G/s). Rays: an assumption,
    /// 1 G incoherent bounce and shadow rays/s (the sample publishes its
    /// render time but not its ray count). docs/EVALUATION.md, "Run time
    /// against error".
    pub const PUBLISHED: GpuModel = GpuModel {
        build_triangles_per_s: 0.843e6 / 2.718e-3,
        build_s_per_blas: 0.0,
        refit_triangles_per_s: 8.43e6 / 2.78e-3,
        tlas_instances_per_s: 0.843e6 / 2.718e-3,
        rays_per_s: 1e9,
    };

    /// The modelled time of `built` triangles in `builds` BLAS builds,
    /// `refit` triangles, a TLAS of `instances` records and `rays` rays:
    /// each count divided by its throughput, plus
    /// [`GpuModel::build_s_per_blas`] per build, in ms.
    pub fn frame(
        &self,
        built: u64,
        builds: u64,
        refit: u64,
        instances: u64,
        rays: u64,
    ) -> GpuFrame {
        let ms = |n: u64, per_s: f64| n as f64 / per_s * 1e3;
        let blas_build_ms =
            ms(built, self.build_triangles_per_s) + builds as f64 * self.build_s_per_blas * 1e3;
        let blas_refit_ms = ms(refit, self.refit_triangles_per_s);
        let tlas_build_ms = ms(instances, self.tlas_instances_per_s);
        let trace_ms = ms(rays, self.rays_per_s);
        GpuFrame {
            blas_build_ms,
            blas_refit_ms,
            tlas_build_ms,
            trace_ms,
            frame_ms: blas_build_ms + blas_refit_ms + tlas_build_ms + trace_ms,
        }
    }

    /// The paragraph saying how the reports' times are made: [`TIMING_NOTE`]
    /// for [`GpuModel::PUBLISHED`], else the same with this model's rates
    /// and `device` (a device profile's description) as their source.
    pub fn timing_note(&self, device: &str) -> String {
        if *self == Self::PUBLISHED {
            return TIMING_NOTE.to_owned();
        }
        let g = |per_s: f64| format!("{:.3} G/s", per_s / 1e9);
        format!(
            "{} Modelled GPU time (a model, not a measurement) = BLAS builds x {:.2} µs + \
             triangles built / {} + triangles refit / {} + TLAS instances / {} + bounce and \
             shadow rays / {}; builds and TLAS from the device profile {device}, refits and \
             rays at the published and assumed rates (docs/MEMORY_MODEL.md, \"Device profiles\").",
            TIMING_NOTE
                .split(" Modelled GPU time")
                .next()
                .unwrap_or(TIMING_NOTE),
            self.build_s_per_blas * 1e6,
            g(self.build_triangles_per_s),
            g(self.refit_triangles_per_s),
            g(self.tlas_instances_per_s),
            g(self.rays_per_s),
        )
    }
}

impl Default for GpuModel {
    /// [`GpuModel::PUBLISHED`].
    fn default() -> Self {
        Self::PUBLISHED
    }
}

const MIB: f64 = 1024.0 * 1024.0;

/// Tracks TLAS membership over frames: state changes, cycles, latency.
#[derive(Clone, Debug, Default)]
pub struct Tracker {
    in_tlas: Vec<bool>,
    now: Vec<bool>,
    last_exit: Vec<Option<u32>>,
    /// First frame the ground truth hit the instance while it was missing
    /// (an open latency sample); `Some(u32::MAX)` once sampled.
    need: Vec<Option<u32>>,
    latencies: Vec<u32>,
    /// Per slot: its kind (empty: every slot [`MissingKind::Shared`]).
    kinds: Vec<MissingKind>,
    /// Per slot: frames it was needed and missing, and the ground-truth
    /// hits on it in those frames.
    missing: Vec<(u32, u64)>,
}

const SAMPLED: u32 = u32::MAX;

impl Tracker {
    /// For `instances` instances.
    pub fn new(instances: usize) -> Self {
        Self {
            in_tlas: vec![false; instances],
            now: vec![false; instances],
            last_exit: vec![None; instances],
            need: vec![None; instances],
            latencies: Vec::new(),
            kinds: Vec::new(),
            missing: vec![(0, 0); instances],
        }
    }

    /// Splits missing instances by `kinds` (one per slot; slots beyond
    /// count as [`MissingKind::Shared`]).
    pub fn set_kinds(&mut self, kinds: Vec<MissingKind>) {
        self.kinds = kinds;
    }

    /// How long needed instances stayed missing so far.
    pub fn missing_tail(&self) -> MissingTail {
        let mut t = MissingTail::default();
        for &(frames, hits) in &self.missing {
            if frames == 0 {
                continue;
            }
            let c = MISSING_CLASS_BOUNDS
                .iter()
                .position(|&b| frames <= b)
                .unwrap_or(MISSING_CLASS_BOUNDS.len() - 1);
            t.instances[c] += 1;
            t.hits[c] += hits;
        }
        t
    }

    /// Records frame `frame`: `geometry` are the custom indices of the real
    /// instances in the TLAS, `needed` the ground truth's hits per slot.
    /// Fills the membership fields of `m`.
    pub fn observe(
        &mut self,
        frame: u32,
        geometry: impl Iterator<Item = u32>,
        needed: &[u32],
        m: &mut FrameMetrics,
    ) {
        self.now.iter_mut().for_each(|v| *v = false);
        for s in geometry {
            if let Some(v) = self.now.get_mut(s as usize) {
                *v = true;
            }
        }
        for i in 0..self.now.len() {
            let (was, is) = (self.in_tlas[i], self.now[i]);
            if was != is {
                m.state_changes += 1;
                if is {
                    if self.last_exit[i].is_some_and(|e| frame - e <= CYCLE_WINDOW) {
                        m.cycles += 1;
                    }
                } else {
                    self.last_exit[i] = Some(frame);
                }
            }
            let h = needed.get(i).copied().unwrap_or(0);
            let hit = h > 0;
            m.needed_hits += u64::from(h);
            if hit && !is {
                m.needed_missing += 1;
                m.missing_hits += u64::from(h);
                let kind = self.kinds.get(i).copied().unwrap_or_default();
                m.missing_by_kind[kind as usize] += 1;
                if let Some(e) = self.missing.get_mut(i) {
                    e.0 += 1;
                    e.1 += u64::from(h);
                }
            }
            match self.need[i] {
                None if hit => {
                    if is {
                        self.sample(0, m);
                        self.need[i] = Some(SAMPLED);
                    } else {
                        self.need[i] = Some(frame);
                    }
                }
                Some(f0) if f0 != SAMPLED && is => {
                    self.sample(frame - f0, m);
                    self.need[i] = Some(SAMPLED);
                }
                _ => {}
            }
        }
        std::mem::swap(&mut self.in_tlas, &mut self.now);
    }

    fn sample(&mut self, latency: u32, m: &mut FrameMetrics) {
        self.latencies.push(latency);
        m.latency_samples += 1;
        m.latency_sum += u64::from(latency);
    }

    /// Grows to `instances` slots (new slots start empty; never shrinks).
    pub fn resize(&mut self, instances: usize) {
        if instances > self.in_tlas.len() {
            self.in_tlas.resize(instances, false);
            self.now.resize(instances, false);
            self.last_exit.resize(instances, None);
            self.need.resize(instances, None);
            self.missing.resize(instances, (0, 0));
        }
    }

    /// Forgets slot `slot` (its instance was removed and the slot now holds
    /// a new one): not in the TLAS, no open latency sample, no exit.
    pub fn reset(&mut self, slot: u32) {
        let i = slot as usize;
        if i < self.in_tlas.len() {
            self.in_tlas[i] = false;
            self.last_exit[i] = None;
            self.need[i] = None;
            self.missing[i] = (0, 0);
        }
    }

    /// Capacity of the per-slot tables, in elements (latency samples not
    /// counted).
    pub fn capacity(&self) -> usize {
        self.in_tlas.capacity()
            + self.now.capacity()
            + self.last_exit.capacity()
            + self.need.capacity()
            + self.missing.capacity()
    }

    /// All latency samples so far.
    pub fn latencies(&self) -> &[u32] {
        &self.latencies
    }

    /// Needed instances whose latency sample is still open.
    pub fn never_active(&self) -> u64 {
        self.need
            .iter()
            .filter(|n| matches!(n, Some(f) if *f != SAMPLED))
            .count() as u64
    }
}

/// Fills the strategy-reported fields of `m`.
pub fn apply_strategy_frame(m: &mut FrameMetrics, f: &StrategyFrame) {
    let BlasWork {
        builds,
        refits,
        primitives_built,
        primitives_refit,
        ..
    } = f.work;
    m.builds = builds;
    m.refits = refits;
    m.primitives_built = primitives_built;
    m.primitives_refit = primitives_refit;
    m.blas_bytes = f.blas_bytes;
    m.blas_split = f.blas_split;
    m.overhead_bytes = f.overhead_bytes;
    if let Some(c) = f.control {
        m.escape_fraction = c.escape_fraction;
        m.threshold_scale = Some(c.threshold_scale);
        m.controlled_bytes = Some(c.controlled_bytes);
        m.control_target = c.target;
        m.control_unreachable = c.unreachable;
    }
}

/// Nearest-rank percentile `p` (0..=100) of `v` (0 for none).
///
/// ```
/// use lipac_sim::metrics::percentile;
/// assert_eq!(percentile(&[5, 1, 3, 2, 4], 95.0), 5);
/// assert_eq!(percentile(&[5, 1, 3, 2, 4], 50.0), 3);
/// assert_eq!(percentile(&[], 95.0), 0);
/// ```
pub fn percentile(v: &[u32], p: f64) -> u32 {
    if v.is_empty() {
        return 0;
    }
    let mut s = v.to_vec();
    s.sort_unstable();
    let rank = ((p / 100.0) * s.len() as f64).ceil().max(1.0) as usize;
    s[rank.min(s.len()) - 1]
}

/// The median of `v` (the mean of the middle two for an even count; 0 for
/// none; ordered by [`f64::total_cmp`]).
///
/// ```
/// use lipac_sim::metrics::median;
/// assert_eq!(median([3.0, 1.0, 2.0].into_iter()), 2.0);
/// assert_eq!(median([4.0, 1.0, 2.0, 3.0].into_iter()), 2.5);
/// assert_eq!(median(std::iter::empty()), 0.0);
/// ```
pub fn median(v: impl Iterator<Item = f64>) -> f64 {
    let mut s: Vec<f64> = v.collect();
    if s.is_empty() {
        return 0.0;
    }
    s.sort_by(f64::total_cmp);
    let h = s.len() / 2;
    if s.len() % 2 == 1 {
        s[h]
    } else {
        (s[h - 1] + s[h]) / 2.0
    }
}

/// Summarises a strategy's frames (TLAS shares under the built-in memory
/// model; [`summarize_with`] for a device profile's).
pub fn summarize(strategy: &str, frames: &[FrameMetrics], tracker: &Tracker) -> Summary {
    summarize_with(strategy, frames, tracker, &MemoryModel::default())
}

/// Summarises a strategy's frames, splitting TLAS bytes with `memory`
/// (the model the frames were measured with).
pub fn summarize_with(
    strategy: &str,
    frames: &[FrameMetrics],
    tracker: &Tracker,
    memory: &MemoryModel,
) -> Summary {
    let n = frames.len().max(1) as f64;
    let mean = |f: &dyn Fn(&FrameMetrics) -> f64| frames.iter().map(f).sum::<f64>() / n;
    let lat = tracker.latencies();
    Summary {
        strategy: strategy.to_string(),
        frames: frames.len() as u32,
        mean_instances: mean(&|m| m.tlas_instances as f64),
        peak_instances: frames.iter().map(|m| m.tlas_instances).max().unwrap_or(0),
        mean_mib: mean(&|m| m.total_bytes() as f64 / MIB),
        peak_mib: frames
            .iter()
            .map(|m| m.total_bytes() as f64 / MIB)
            .fold(0.0, f64::max),
        mean_blas_mib: mean(&|m| m.blas_bytes as f64 / MIB),
        builds: frames.iter().map(|m| m.builds).sum(),
        refits: frames.iter().map(|m| m.refits).sum(),
        primitives_built: frames.iter().map(|m| m.primitives_built).sum(),
        primitives_refit: frames.iter().map(|m| m.primitives_refit).sum(),
        state_changes: frames.iter().map(|m| m.state_changes).sum(),
        cycles: frames.iter().map(|m| m.cycles).sum(),
        mean_latency: if lat.is_empty() {
            0.0
        } else {
            lat.iter().map(|&l| f64::from(l)).sum::<f64>() / lat.len() as f64
        },
        p95_latency: percentile(lat, 95.0),
        latency_samples: lat.len() as u64,
        never_active: tracker.never_active(),
        mean_needed_missing: mean(&|m| m.needed_missing as f64),
        mean_error: mean(&|m| m.error),
        max_error: frames.iter().map(|m| m.error).fold(0.0, f64::max),
        mean_trace_ms: mean(&|m| m.trace_ms),
        mean_tlas_build_ms: mean(&|m| m.tlas_build_ms),
        mean_strategy_ms: mean(&|m| m.strategy_ms),
        mean_traced_rays: mean(&|m| m.traced_rays as f64),
        mean_blas_build_ms: mean(&|m| m.blas_build_ms),
        mean_blas_refit_ms: mean(&|m| m.blas_refit_ms),
        mean_frame_ms: mean(&|m| m.frame_ms),
        median_frame_ms: median(frames.iter().map(|m| m.frame_ms)),
        mean_gpu_blas_build_ms: mean(&|m| m.gpu_blas_build_ms),
        mean_gpu_blas_refit_ms: mean(&|m| m.gpu_blas_refit_ms),
        mean_gpu_tlas_build_ms: mean(&|m| m.gpu_tlas_build_ms),
        mean_gpu_trace_ms: mean(&|m| m.gpu_trace_ms),
        mean_gpu_frame_ms: mean(&|m| m.gpu_frame_ms),
        mean_split_mib: [
            mean(&|m| m.blas_split.terrain as f64 / MIB),
            mean(&|m| m.blas_split.unique as f64 / MIB),
            mean(&|m| m.blas_split.shared_used as f64 / MIB),
            mean(&|m| m.blas_split.shared_cached as f64 / MIB),
            mean(&|m| {
                memory.tlas_bytes(m.tlas_instances.saturating_sub(m.counting_boxes)) as f64 / MIB
            }),
            mean(&|m| {
                (memory.tlas_bytes(m.tlas_instances).saturating_sub(
                    memory.tlas_bytes(m.tlas_instances.saturating_sub(m.counting_boxes)),
                )) as f64
                    / MIB
            }),
            mean(&|m| m.overhead_bytes as f64 / MIB),
        ],
        mean_missing_by_kind: [0, 1, 2].map(|k| mean(&|m| m.missing_by_kind[k] as f64)),
        missing_hit_share: {
            let needed: u64 = frames.iter().map(|m| m.needed_hits).sum();
            let missing: u64 = frames.iter().map(|m| m.missing_hits).sum();
            if needed == 0 {
                0.0
            } else {
                missing as f64 / needed as f64
            }
        },
        missing_tail: tracker.missing_tail(),
    }
}

#[cfg(test)]
mod tests;
