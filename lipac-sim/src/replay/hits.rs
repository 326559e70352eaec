//! Hits-only replay: no geometry, no tracer. LiPaC's state machine is driven
//! by the hit counts the engine recorded.
//!
//! Per frame `f`:
//!
//! 1. The hits recorded with frame `f − 1` are LiPaC's feedback
//!    (Algorithm 2): an instance that is in the TLAS as geometry or as an
//!    omitted box (active or omitted, in an active hitbox) gets its own
//!    hits; an inactive one, or one in an inactive hitbox, has only its
//!    hitbox's counting box in the TLAS, so its hits count for its hitbox. Commands go through the read-back ring as in
//!    [`crate::strategy::lipac`].
//! 2. The frame's events: `add` registers, `update` moves (or re-describes),
//!    `remove` removes (the BLAS is released).
//! 3. LiPaC runs on one [`CpuBackend`] (a
//!    [`lipac_core::manager::Manager`] with the header's meshes, triangle
//!    counts per LOD): latency mitigation (optional), commands under the
//!    budget, BLAS builds under the budgets at the recorded LODs,
//!    Algorithm 1.
//! 4. Metrics: TLAS records, memory (same model as `compare`), BLAS work,
//!    state changes and cycles; latency and needed-but-missing against the
//!    instances the frame's recorded hits name (the engine's paths needed
//!    them). The error is not available (`NaN`).
//!
//! A frame without recorded hit counts counts as a frame without hits; a
//! trace none of whose frames carries them is refused.
//!
//! The `full` baseline keeps every live instance, with unlimited budgets,
//! on a [`CpuBackend`] too: every instance pinned on a Manager without hit
//! feedback ([`CpuBackend::engine_selected`]).
//!
//! BLAS ownership follows the flags (the Manager's rule): `unique_blas` and
//! `static` — one static BLAS per instance; `unique_blas` alone — an
//! animated BLAS (refit every frame); otherwise shared per (mesh, LOD), one
//! BLAS for `static` instances and one for the rest. An update that changes
//! `unique_blas` or `static` re-registers the instance in LiPaC (the
//! Manager ties the BLAS kind to the registration).

use std::collections::HashMap;
use std::io::Read;
use std::time::Instant;

use lipac_core::instance::{InstanceDesc, InstanceFlags, MeshId};
use lipac_core::layout::{InstanceState, TlasInstance};
use lipac_core::manager::MeshCatalog;
use lipac_core::math::rows_to_affine;
use lipac_core::registry::InstanceHandle;
use lipac_core::trace::{InstanceEvent, TraceHeader};
use lipac_core::WorldHitboxes;

use super::{empty_frame, ReplayConfig, TraceInput};
use crate::camera::FlyCamera;
use crate::compare::{CompareReport, StrategyRun};
use crate::cpu_backend::CpuBackend;
use crate::error::SimError;
use crate::memory::{lipac_overhead_bytes, MemoryModel};
use crate::metrics::{summarize, summarize_with, FrameMetrics, Summary, Tracker};
use crate::record::from_trace_camera;
use crate::strategy::lipac::LipacConfig;
use crate::strategy::{BlasWork, StrategyKind};
use crate::tlas::CountingBoxes;
use crate::traversal::SlotSet;

/// Rays per frame the LiPaC thresholds are scaled to in hits-only mode:
/// those of a `width` x `height` image (one sample per pixel).
fn rays(config: &ReplayConfig) -> u64 {
    u64::from(config.width) * u64::from(config.height)
}

fn core<E: std::fmt::Display>(e: E) -> SimError {
    SimError::core(e)
}

/// One live instance of the trace.
#[derive(Clone, Copy, Debug)]
struct Live {
    /// Dense slot of the replay (reused after removal).
    slot: u32,
    desc: InstanceDesc,
    lod: u32,
}

/// The trace's instances as dense slots, shared by every strategy.
#[derive(Debug, Default)]
struct World {
    triangles: HashMap<u32, Vec<u32>>,
    live: HashMap<u64, Live>,
    slot_ids: Vec<Option<u64>>,
    free: Vec<u32>,
    hits: Vec<u32>,
}

impl World {
    fn new(h: &TraceHeader) -> Self {
        Self {
            triangles: h
                .meshes
                .iter()
                .map(|m| (m.id.0, m.lods.iter().map(|l| l.triangles).collect()))
                .collect(),
            ..Self::default()
        }
    }
    fn slots(&self) -> usize {
        self.slot_ids.len()
    }
    /// The Manager's catalog: the header's meshes, one
    /// [`MemoryModel::mesh_lod`] per LOD.
    fn mesh_catalog(&self, memory: &MemoryModel) -> Result<MeshCatalog, SimError> {
        let mut meshes: Vec<(&u32, &Vec<u32>)> = self.triangles.iter().collect();
        meshes.sort_unstable();
        let mut catalog = MeshCatalog::new();
        for (&mesh, lods) in meshes {
            let lods = lods
                .iter()
                .map(|&t| memory.mesh_lod(u64::from(t)))
                .collect();
            catalog.insert(MeshId(mesh), lods).map_err(core)?;
        }
        Ok(catalog)
    }
    /// The capacity of every per-instance structure (for bounded-memory
    /// checks).
    fn footprint(&self) -> usize {
        self.live.capacity()
            + self.slot_ids.capacity()
            + self.free.capacity()
            + self.hits.capacity()
    }
}

/// LiPaC on recorded hits, or the `full` baseline (`baseline`: every live
/// instance pinned, no feedback), on one [`CpuBackend`].
#[derive(Debug)]
struct LipacReplay {
    backend: CpuBackend<WorldHitboxes>,
    /// The unit cube's BLAS (LiPaC's counting boxes), bytes.
    unit_cube_bytes: u64,
    /// The `full` baseline ([`CpuBackend::engine_selected`]).
    baseline: bool,
    /// Handle per dense slot.
    handles: Vec<Option<InstanceHandle>>,
    /// Dense slot per registry slot.
    dense: Vec<u32>,
    records: Vec<TlasInstance>,
}

#[derive(Debug)]
enum Runner {
    Full(Box<LipacReplay>),
    Lipac(Box<LipacReplay>),
}

struct Run {
    runner: Runner,
    tracker: Tracker,
    frames: Vec<FrameMetrics>,
    /// The down-sampling of `frames` when not every frame is kept.
    series: Series,
    summary_frames: u32,
    totals: FrameTotals,
}

/// Running sums of a strategy's metrics when per-frame metrics are not kept.
#[derive(Clone, Debug, Default)]
struct FrameTotals {
    sum_instances: f64,
    peak_instances: u64,
    sum_mib: f64,
    peak_mib: f64,
    sum_blas_mib: f64,
    builds: u64,
    refits: u64,
    primitives_built: u64,
    primitives_refit: u64,
    state_changes: u64,
    cycles: u64,
    sum_needed_missing: f64,
    sum_strategy_ms: f64,
}

const MIB: f64 = 1024.0 * 1024.0;

impl FrameTotals {
    fn add(&mut self, m: &FrameMetrics) {
        let mib = m.total_bytes() as f64 / MIB;
        self.sum_instances += m.tlas_instances as f64;
        self.peak_instances = self.peak_instances.max(m.tlas_instances);
        self.sum_mib += mib;
        self.peak_mib = self.peak_mib.max(mib);
        self.sum_blas_mib += m.blas_bytes as f64 / MIB;
        self.builds += m.builds;
        self.refits += m.refits;
        self.primitives_built += m.primitives_built;
        self.primitives_refit += m.primitives_refit;
        self.state_changes += m.state_changes;
        self.cycles += m.cycles;
        self.sum_needed_missing += m.needed_missing as f64;
        self.sum_strategy_ms += m.strategy_ms;
    }
}

/// Most frames of the per-frame series a streaming replay keeps
/// ([`ReplayConfig::keep_frames`] off): beyond it, every other kept frame is
/// dropped and the stride doubles, so the series stays evenly spaced over the
/// whole trace in at most this many frames.
pub const MAX_SERIES_FRAMES: usize = 2048;

/// Down-sampling of a streaming replay's per-frame series: every
/// `stride`-th frame, the stride doubling whenever the series is full.
#[derive(Debug)]
struct Series {
    stride: u64,
    seen: u64,
}

impl Default for Series {
    fn default() -> Self {
        Self { stride: 1, seen: 0 }
    }
}

impl Series {
    fn push(&mut self, frames: &mut Vec<FrameMetrics>, m: FrameMetrics) {
        let index = self.seen;
        self.seen += 1;
        if index % self.stride != 0 {
            return;
        }
        if frames.len() == MAX_SERIES_FRAMES {
            // Keep frames 0, 2·stride, 4·stride, ...
            let mut i = 0;
            frames.retain(|_| {
                i += 1;
                i % 2 == 1
            });
            self.stride *= 2;
            if index % self.stride != 0 {
                return;
            }
        }
        frames.push(m);
    }
}

/// Bounded-memory evidence of a hits-only replay: the largest capacities
/// its per-instance structures reached.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct HitsFootprint {
    /// Most instances live at once (the trace validator's count).
    pub peak_live: usize,
    /// Largest total capacity of the replay's per-instance tables (slots,
    /// ids, hits, trackers, LiPaC's slot maps), in elements.
    pub peak_capacity: usize,
    /// Largest event vector capacity of the reused frame.
    pub peak_frame_events: usize,
}

/// Replays `input` in hits-only mode (module docs).
pub fn replay_hits<R: Read>(
    input: &mut TraceInput<R>,
    config: &ReplayConfig,
    progress: &mut dyn FnMut(u64),
) -> Result<CompareReport, SimError> {
    replay_hits_with(input, config, progress).map(|(r, _)| r)
}

/// As [`replay_hits`], also returning the [`HitsFootprint`].
pub fn replay_hits_with<R: Read>(
    input: &mut TraceInput<R>,
    config: &ReplayConfig,
    progress: &mut dyn FnMut(u64),
) -> Result<(CompareReport, HitsFootprint), SimError> {
    let start = Instant::now();
    let header = input.header().clone();
    let kinds = if config.strategies.is_empty() {
        vec![
            StrategyKind::Full,
            StrategyKind::Lipac,
            StrategyKind::LipacLatency,
        ]
    } else {
        config.strategies.clone()
    };
    // Leaf hitboxes only: the recorded hits already name the instance or
    // cell a path met, so merged counting boxes would decide nothing
    // differently, and the hashed index of an unbounded world is leaf-only.
    let memory = config.device.memory_model();
    let mut lipac_config = LipacConfig::for_rays_per_frame(rays(config))?
        .with_adaptive_hitboxes(0)
        .with_memory(memory.clone());
    config.lipac_start.apply(&mut lipac_config);
    // A bounded world's grid (its occupied cells only if it is large: memory
    // follows the cells the trace uses, not those it declares), or the
    // hashed grid of an unbounded one (the readers checked the grid's size).
    let grid = WorldHitboxes::for_world(&header.world, u64::MAX).map_err(core)?;
    let mut world = World::new(&header);
    let mut runs = Vec::with_capacity(kinds.len());
    for k in &kinds {
        let runner = match k {
            StrategyKind::Full => Runner::Full(Box::new(LipacReplay::full(
                grid.clone(),
                world.mesh_catalog(&memory)?,
                &memory,
            )?)),
            StrategyKind::Lipac | StrategyKind::LipacLatency => {
                let c = if *k == StrategyKind::Lipac {
                    lipac_config.clone()
                } else {
                    lipac_config.clone().with_latency_mitigation()
                };
                Runner::Lipac(Box::new(LipacReplay::new(
                    grid.clone(),
                    &c,
                    world.mesh_catalog(&memory)?,
                )?))
            }
            other => {
                return Err(SimError::Replay(format!(
                    "strategy `{}` needs the scene's geometry; a hits-only replay runs \
                     full, lipac and lipac-latency",
                    other.name()
                )))
            }
        };
        runs.push(Run {
            runner,
            tracker: Tracker::new(0),
            frames: Vec::new(),
            summary_frames: 0,
            series: Series::default(),
            totals: FrameTotals::default(),
        });
    }
    let mut frame = empty_frame();
    let mut prev_hits: Vec<(u32, u32)> = Vec::new();
    let mut fp = HitsFootprint::default();
    let mut read = 0u64;
    let mut with_hits = 0u64;
    let counting = CountingBoxes::default();
    while input.next_frame_into(&mut frame)? {
        let number = u32::try_from(frame.number).map_err(|_| {
            SimError::Replay(format!(
                "frame record {read}: frame number {} above 2^32 - 1",
                frame.number
            ))
        })?;
        with_hits += u64::from(frame.hits.is_some());
        let camera = from_trace_camera(&frame.camera)?;
        // Feedback of the previous frame, before this frame's events.
        for run in &mut runs {
            match &mut run.runner {
                Runner::Full(l) | Runner::Lipac(l) => l.feedback(&prev_hits)?,
            }
        }
        // Events.
        for e in &frame.events {
            apply_event(&mut world, &mut runs, e, number)?;
        }
        // This frame's hits per dense slot.
        world.hits.clear();
        world.hits.resize(world.slots(), 0);
        prev_hits.clear();
        for h in frame.hits.iter().flatten() {
            if let Some(l) = world.live.get(&h.id) {
                world.hits[l.slot as usize] = h.hits;
                prev_hits.push((l.slot, h.hits));
            }
        }
        for run in &mut runs {
            let t = Instant::now();
            let mut m = FrameMetrics {
                frame: number,
                error: f64::NAN,
                ..FrameMetrics::default()
            };
            let geometry = match &mut run.runner {
                Runner::Full(l) | Runner::Lipac(l) => {
                    l.frame(number, &camera, &counting, &mut m)?
                }
            };
            m.strategy_ms = t.elapsed().as_secs_f64() * 1e3;
            m.tlas_bytes = memory.tlas_bytes(m.tlas_instances);
            run.tracker.resize(world.slots());
            run.tracker
                .observe(number, geometry.into_iter(), &world.hits, &mut m);
            run.totals.add(&m);
            run.summary_frames += 1;
            if config.keep_frames {
                run.frames.push(m);
            } else {
                run.series.push(&mut run.frames, m);
            }
        }
        read += 1;
        fp.peak_live = fp.peak_live.max(input.live_instances());
        fp.peak_frame_events = fp.peak_frame_events.max(frame.events.capacity());
        let cap = world.footprint()
            + runs
                .iter()
                .map(|r| {
                    r.tracker.capacity()
                        + match &r.runner {
                            Runner::Full(l) | Runner::Lipac(l) => {
                                l.handles.capacity() + l.dense.capacity() + l.records.capacity()
                            }
                        }
                })
                .sum::<usize>();
        fp.peak_capacity = fp.peak_capacity.max(cap);
        progress(read);
    }
    if read == 0 {
        return Err(SimError::Replay("the trace has no frames".into()));
    }
    if with_hits == 0 {
        return Err(SimError::Replay(format!(
            "none of the {read} frames carries hit counts; a trace without them replays \
             only in geometry mode (recorded from a built-in scene)"
        )));
    }
    let th = lipac_config.thresholds;
    let strategies = kinds
        .iter()
        .zip(runs)
        .map(|(k, run)| {
            let mut summary = if config.keep_frames {
                summarize_with(k.name(), &run.frames, &run.tracker, &memory)
            } else {
                summary_of(k.name(), &run)
            };
            summary.mean_error = f64::NAN;
            summary.max_error = f64::NAN;
            summary.mean_trace_ms = 0.0;
            summary.mean_tlas_build_ms = 0.0;
            StrategyRun {
                name: k.name().to_string(),
                summary,
                frames: run.frames,
                last_geometry: Vec::new(),
            }
        })
        .collect();
    Ok((
        CompareReport {
            scene: header.scene_name.clone(),
            instances: fp.peak_live as u64,
            frames: read.min(u64::from(u32::MAX)) as u32,
            width: config.width,
            height: config.height,
            rays_per_frame: rays(config),
            thresholds: [
                th.theta_a, th.theta_d, th.sigma_a, th.sigma_o, th.n_a, th.n_d,
            ],
            rule: crate::report::rule_description(&th),
            start: crate::report::start_description(&lipac_config),
            ground_truth_ms: 0.0,
            full_tlas_ms: 0.0,
            geometry_ms: 0.0,
            // Hits-only replay traces no rays.
            traced_rays_per_frame: 0.0,
            wall_s: start.elapsed().as_secs_f64(),
            // No BLAS is built or timed: BLAS and frame times stay 0.
            blas_throughput: Default::default(),
            gpu_model: Default::default(),
            strategies,
            camera_cuts: Vec::new(),
            device_profile: config.device.clone(),
        },
        fp,
    ))
}

fn summary_of(name: &str, run: &Run) -> Summary {
    // The summary of `summarize` with an empty frame list supplies the
    // latency fields; the rest comes from the running totals.
    let base = summarize(name, &[], &run.tracker);
    let t = &run.totals;
    let n = f64::from(run.summary_frames.max(1));
    Summary {
        frames: run.summary_frames,
        mean_instances: t.sum_instances / n,
        peak_instances: t.peak_instances,
        mean_mib: t.sum_mib / n,
        peak_mib: t.peak_mib,
        mean_blas_mib: t.sum_blas_mib / n,
        builds: t.builds,
        refits: t.refits,
        primitives_built: t.primitives_built,
        primitives_refit: t.primitives_refit,
        state_changes: t.state_changes,
        cycles: t.cycles,
        mean_needed_missing: t.sum_needed_missing / n,
        mean_strategy_ms: t.sum_strategy_ms / n,
        ..base
    }
}

fn apply_event(
    world: &mut World,
    runs: &mut [Run],
    e: &InstanceEvent,
    frame: u32,
) -> Result<(), SimError> {
    match e {
        InstanceEvent::Add(a) => {
            let slot = match world.free.pop() {
                Some(s) => s,
                None => {
                    world.slot_ids.push(None);
                    (world.slot_ids.len() - 1) as u32
                }
            };
            let l = Live {
                slot,
                desc: a.desc(),
                lod: a.lod,
            };
            world.slot_ids[slot as usize] = Some(a.id);
            world.live.insert(a.id, l);
            for run in runs.iter_mut() {
                run.tracker.resize(world.slot_ids.len());
                run.tracker.reset(slot);
                match &mut run.runner {
                    Runner::Full(lp) | Runner::Lipac(lp) => lp.register(slot, &l)?,
                }
            }
        }
        InstanceEvent::Update(u) => {
            let l = world.live.get_mut(&u.id).ok_or(SimError::Replay(format!(
                "update of unknown instance {}",
                u.id
            )))?;
            let old_flags = l.desc.flags;
            let mut redescribe = false;
            if let Some(p) = &u.pose {
                l.desc.transform = rows_to_affine(&p.transform);
                l.desc.aabb = p.aabb;
            }
            if let Some(lod) = u.lod {
                l.lod = lod;
            }
            if let Some(f) = u.flags {
                redescribe |= f != l.desc.flags;
                l.desc.flags = f;
            }
            if let Some(m) = u.mask {
                redescribe |= m != l.desc.mask;
                l.desc.mask = m;
            }
            let l = *l;
            let change = Change {
                moved: u.pose.is_some(),
                redescribe,
                lod: u.lod.is_some(),
                blas_kind: blas_kind(old_flags) != blas_kind(l.desc.flags),
            };
            for run in runs.iter_mut() {
                match &mut run.runner {
                    Runner::Full(lp) | Runner::Lipac(lp) => lp.update(&l, change)?,
                }
            }
        }
        InstanceEvent::Remove { id } => {
            let l = world
                .live
                .remove(id)
                .ok_or(SimError::Replay(format!("remove of unknown instance {id}")))?;
            world.slot_ids[l.slot as usize] = None;
            world.free.push(l.slot);
            for run in runs.iter_mut() {
                match &mut run.runner {
                    Runner::Full(lp) | Runner::Lipac(lp) => lp.remove(l.slot)?,
                }
            }
        }
    }
    let _ = frame;
    Ok(())
}

fn fill_work(m: &mut FrameMetrics, w: &BlasWork) {
    m.builds = w.builds;
    m.refits = w.refits;
    m.primitives_built = w.primitives_built;
    m.primitives_refit = w.primitives_refit;
}

/// What an `update` event changed.
#[derive(Clone, Copy, Debug)]
struct Change {
    moved: bool,
    redescribe: bool,
    lod: bool,
    /// `unique_blas` or `static` changed.
    blas_kind: bool,
}

fn blas_kind(f: InstanceFlags) -> InstanceFlags {
    f & (InstanceFlags::UNIQUE_BLAS | InstanceFlags::STATIC)
}

impl LipacReplay {
    /// The `full` baseline: every live instance pinned on a Manager without
    /// feedback.
    fn full(
        grid: WorldHitboxes,
        catalog: MeshCatalog,
        memory: &MemoryModel,
    ) -> Result<Self, SimError> {
        Ok(Self {
            backend: CpuBackend::engine_selected(grid, catalog)?,
            unit_cube_bytes: memory.blas_bytes(12),
            baseline: true,
            handles: Vec::new(),
            dense: Vec::new(),
            records: Vec::new(),
        })
    }

    fn new(
        grid: WorldHitboxes,
        config: &LipacConfig,
        catalog: MeshCatalog,
    ) -> Result<Self, SimError> {
        Ok(Self {
            backend: CpuBackend::new(grid, config, catalog)?,
            unit_cube_bytes: config.memory.blas_bytes(12),
            baseline: false,
            handles: Vec::new(),
            dense: Vec::new(),
            records: Vec::new(),
        })
    }

    /// The instance's description as the Manager gets it (the recorded
    /// LOD; the baseline pins it).
    fn desc(&self, l: &Live) -> InstanceDesc {
        let mut flags = l.desc.flags;
        if self.baseline {
            flags |= InstanceFlags::PINNED;
        }
        InstanceDesc {
            lod: l.lod,
            flags,
            ..l.desc
        }
    }

    fn register(&mut self, slot: u32, l: &Live) -> Result<(), SimError> {
        let h = self.backend.register(self.desc(l))?;
        let reg = self.backend.instance(h)?.slot as usize;
        if self.handles.len() <= slot as usize {
            self.handles.resize(slot as usize + 1, None);
        }
        self.handles[slot as usize] = Some(h);
        if self.dense.len() <= reg {
            self.dense.resize(reg + 1, u32::MAX);
        }
        self.dense[reg] = slot;
        Ok(())
    }

    fn handle(&self, slot: u32) -> Result<InstanceHandle, SimError> {
        self.handles
            .get(slot as usize)
            .copied()
            .flatten()
            .ok_or(SimError::UnknownInstance(slot))
    }

    fn update(&mut self, l: &Live, change: Change) -> Result<(), SimError> {
        let h = self.handle(l.slot)?;
        if change.blas_kind {
            self.remove(l.slot)?;
            return self.register(l.slot, l);
        }
        if change.redescribe {
            self.backend.update(h, self.desc(l))?;
        } else {
            if change.moved {
                self.backend
                    .set_transform(h, l.desc.transform, l.desc.aabb)?;
            }
            if change.lod {
                self.backend.set_lod(h, l.lod)?;
            }
        }
        Ok(())
    }

    fn remove(&mut self, slot: u32) -> Result<(), SimError> {
        let h = self.handle(slot)?;
        let reg = self.backend.instance(h)?.slot as usize;
        self.backend.remove(h)?;
        self.handles[slot as usize] = None;
        if let Some(d) = self.dense.get_mut(reg) {
            *d = u32::MAX;
        }
        Ok(())
    }

    /// Algorithm 2 on the hits recorded with the previous frame (dense slot,
    /// hits).
    fn feedback(&mut self, hits: &[(u32, u32)]) -> Result<(), SimError> {
        if !self.backend.frame_open() {
            return Ok(());
        }
        if self.baseline {
            return self.backend.end_frame(); // no feedback: the call order
        }
        self.backend.instance_hits_mut().fill(0);
        for &(slot, n) in hits {
            let Some(Some(h)) = self.handles.get(slot as usize).copied() else {
                continue;
            };
            let reg = self.backend.instance(h)?.slot;
            let record = self.backend.record(h)?;
            // Reduced into its hitbox's counting box (Algorithm 1): not
            // pinned, and inactive or in an inactive hitbox.
            let b = record.hitbox as usize;
            let culled = !record.is_pinned()
                && (record.state() == InstanceState::Inactive
                    || self
                        .backend
                        .hitboxes()
                        .get(b)
                        .is_some_and(|hb| !hb.is_active()));
            if culled {
                if let Some(b) = self.backend.hitboxes_mut().get_mut(b) {
                    b.add_hits(n);
                }
            } else if let Some(c) = self.backend.instance_hits_mut().get_mut(reg as usize) {
                *c = n;
            }
        }
        self.backend.end_frame()
    }

    fn frame(
        &mut self,
        frame: u32,
        camera: &FlyCamera,
        counting: &CountingBoxes,
        m: &mut FrameMetrics,
    ) -> Result<Vec<u32>, SimError> {
        self.backend.begin_frame(frame)?;
        let f = self.backend.run(camera, &mut self.records)?;
        let geometry = SlotSet::from_geometry_records(&self.records, counting);
        let mut slots = Vec::new();
        for r in &self.records {
            let reg = r.custom_index();
            // A counting box's custom index is a hitbox's (or its omitted
            // instance's) index, not a traced slot, even where it equals one.
            let is_box = counting.is_box(r.sbt_offset());
            if !is_box && geometry.contains(reg) {
                if let Some(&s) = self.dense.get(reg as usize) {
                    if s != u32::MAX {
                        slots.push(s);
                    }
                }
            }
        }
        fill_work(m, &f.work);
        m.tlas_instances = self.records.len() as u64;
        m.counting_boxes = self.records.len() as u64 - slots.len() as u64;
        // The hitbox records of the world's structure as the paper's GPU
        // backend holds them (every cell of a bounded world's grid, also
        // when the replay holds only the cells used).
        let hitboxes = self
            .backend
            .manager()
            .registry()
            .hitbox_index()
            .modelled_hitboxes();
        if self.baseline {
            m.blas_bytes = self.backend.blas_bytes();
        } else {
            m.blas_bytes = self.backend.blas_bytes() + self.unit_cube_bytes;
            let slots = u64::from(self.backend.slot_count());
            m.overhead_bytes = lipac_overhead_bytes(hitboxes, slots)
                + crate::memory::decayed_rate_bytes(&self.backend.manager().thresholds(), slots);
        }
        Ok(slots)
    }
}
