//! LiPaC driven as an engine drives a GPU backend, over lipac-core.
//!
//! Per frame (`f`), in order:
//!
//! 1. **Algorithm 2 of frame `f − 1`** on the "GPU" copy of the instance
//!    records: the tracer's hitbox counts go into the hitbox records, then
//!    [`process_feedback`] with the instance counters; its bounded command
//!    buffer goes into the readback ring (`k` frames of latency).
//! 2. **CPU frame start**: registry and scheduler frames, animated units'
//!    transforms, the CPU mirror follows the GPU's state bits.
//! 3. **Latency mitigation** (optional, paper §3.6): instances newly in the
//!    frustum that pass the [`ActivationHeuristic`] become active now and
//!    get their BLAS requested.
//! 4. **Commands of frame `f − k`** from the ring into the [`CommandQueue`];
//!    at most `command_budget` are processed: `add` requests the BLAS from
//!    the [`BlasAccounting`] scheduler, `remove` releases it.
//! 5. **BLAS builds** under the per-frame budgets, acknowledged at once;
//!    new addresses go into the registry; dirty records are uploaded.
//! 6. **Algorithm 1** ([`assemble_tlas`]) over the uploaded records: active
//!    instances with a BLAS, omitted instances' boxes, inactive hitboxes'
//!    boxes. The caller traces these records (counting boxes count by
//!    custom index: slot or hitbox index) and hands the counters back as
//!    `previous` next frame.
//!
//! Registry slots are assigned in scene order and checked to equal scene
//! slots, so custom indices, counters and commands all speak scene slots.

use std::collections::VecDeque;

use lipac_core::assembly::{assemble_tlas, AssemblyConfig};
use lipac_core::build_plan::BuildBudgets;
use lipac_core::command::{CommandBuffer, CommandKind, CommandQueue};
use lipac_core::feedback::process_feedback;
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::instance::{InstanceDesc, InstanceFlags, MeshId};
use lipac_core::latency::{ActivationHeuristic, Frustum, LatencyMitigation};
use lipac_core::layout::{HitboxRecord, InstanceRecord, InstanceState, TlasInstance};
use lipac_core::registry::{InstanceHandle, InstanceRegistry, RegistryConfig};
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
    /// Hitbox cell size, metres (paper: 16).
    pub cell_size: f64,
    /// Latency mitigation with this heuristic, or none.
    pub latency: Option<ActivationHeuristic>,
    /// Commands processed per frame; the rest wait (highest hits first).
    pub command_budget: usize,
    /// Capacity of the GPU command buffer per frame.
    pub command_capacity: u32,
    /// Frames between Algorithm 2 and the CPU reading its commands.
    pub readback_latency: usize,
    /// BLAS build budgets per frame.
    pub build_budgets: BuildBudgets,
}

impl LipacConfig {
    /// Paper settings for `rays_per_frame` camera rays: scaled thresholds,
    /// 16 m cells, readback after 2 frames, 4096 commands per frame,
    /// the scheduler's default build budgets (64 builds, 4 Mi triangles).
    pub fn for_rays_per_frame(rays_per_frame: u64) -> Result<Self, SimError> {
        Ok(Self {
            thresholds: Thresholds::for_rays_per_frame(rays_per_frame as f64)
                .map_err(SimError::core)?,
            cell_size: 16.0,
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
    /// Commands decoded from the readback this frame.
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
    registry: InstanceRegistry<HitboxGrid>,
    handles: Vec<InstanceHandle>,
    units: Vec<u32>,
    gpu: Vec<InstanceRecord>,
    hitboxes: Vec<HitboxRecord>,
    commands: CommandBuffer,
    ring: VecDeque<CommandBuffer>,
    queue: CommandQueue,
    latency: Option<LatencyMitigation>,
    blas: BlasAccounting,
    activate: Vec<u32>,
    stats: LipacFrameStats,
}

fn core<E: std::fmt::Display>(e: E) -> SimError {
    SimError::core(e)
}

impl Lipac {
    /// Registers every instance of `scene` (frame 0 state) in a registry
    /// whose hitbox grid covers the scene.
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
        let hitbox_count = grid.len() as usize;
        let mut registry = InstanceRegistry::new(
            grid,
            RegistryConfig {
                quarantine_frames: config.readback_latency as u32 + 2,
                ..RegistryConfig::default()
            },
        )
        .map_err(core)?;
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
            let h = registry.register(desc).map_err(core)?;
            // Registry slots must equal scene slots: counters, custom indices
            // and commands are all indexed by them.
            let got = registry.slot(h).map_err(core)?;
            if got != slot as u32 {
                return Err(SimError::Core(format!(
                    "registry slot {got} for scene slot {slot}"
                )));
            }
            handles.push(h);
        }
        let n = handles.len();
        let latency = match config.latency {
            Some(h) => Some(LatencyMitigation::new(h).map_err(core)?),
            None => None,
        };
        Ok(Self {
            name: if config.latency.is_some() {
                "lipac-latency"
            } else {
                "lipac"
            },
            commands: CommandBuffer::new(config.command_capacity),
            queue: CommandQueue::new(n as u32),
            blas: BlasAccounting::new(n, config.build_budgets)?,
            config,
            registry,
            handles,
            units,
            gpu: vec![InstanceRecord::default(); n],
            hitboxes: vec![HitboxRecord::default(); hitbox_count],
            ring: VecDeque::new(),
            latency,
            activate: Vec::new(),
            stats: LipacFrameStats::default(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &LipacConfig {
        &self.config
    }
    /// The state of instance `slot` as the GPU records hold it.
    pub fn state(&self, slot: u32) -> Option<InstanceState> {
        self.gpu.get(slot as usize).map(InstanceRecord::state)
    }
    /// The hitbox records (after the last frame's Algorithm 2).
    pub fn hitbox_records(&self) -> &[HitboxRecord] {
        &self.hitboxes
    }
    /// Counts of the last frame.
    pub fn last_stats(&self) -> LipacFrameStats {
        self.stats
    }

    /// Step 1: Algorithm 2 over the previous frame's counters.
    fn feedback(&mut self, previous: &Counters) -> Result<(), SimError> {
        if previous.instances.len() != self.gpu.len() {
            return Err(SimError::SizeMismatch {
                a: previous.instances.len(),
                b: self.gpu.len(),
            });
        }
        for (h, &c) in self.hitboxes.iter_mut().zip(&previous.hitboxes) {
            h.add_hits(c);
        }
        self.commands.clear();
        process_feedback(
            &mut self.gpu,
            &previous.instances,
            &mut self.hitboxes,
            &self.config.thresholds,
            &mut self.commands,
        )
        .map_err(core)?;
        self.ring.push_back(self.commands.clone());
        Ok(())
    }
}

impl Strategy for Lipac {
    fn name(&self) -> &str {
        self.name
    }
    fn hitboxes(&self) -> usize {
        self.hitboxes.len()
    }
    fn frame(
        &mut self,
        ctx: &FrameContext<'_>,
        previous: Option<&Counters>,
        out: &mut Vec<TlasInstance>,
    ) -> Result<StrategyFrame, SimError> {
        if ctx.full_records.len() != self.gpu.len() {
            return Err(SimError::SizeMismatch {
                a: ctx.full_records.len(),
                b: self.gpu.len(),
            });
        }
        self.stats = LipacFrameStats::default();
        if let Some(p) = previous {
            self.feedback(p)?;
        }

        // 2. Frame start; the CPU mirror follows the GPU's states.
        self.registry
            .begin_frame(u64::from(ctx.frame))
            .map_err(core)?;
        self.blas.begin_frame(ctx.frame)?;
        for &slot in &self.units {
            let inst = ctx.scene.instance(slot)?;
            self.registry
                .set_transform(self.handles[slot as usize], inst.transform, inst.aabb)
                .map_err(core)?;
        }
        for (slot, g) in self.gpu.iter().enumerate() {
            let slot = slot as u32;
            if self.registry.record_at(slot).map(InstanceRecord::state) != Some(g.state()) {
                self.registry.set_state(slot, g.state()).map_err(core)?;
            }
        }

        // 3. Latency mitigation.
        if let Some(lm) = self.latency.as_mut() {
            let frustum = Frustum::from_view_projection(ctx.camera.view_proj()).map_err(core)?;
            lm.update(
                &self.registry,
                ctx.camera.position,
                &frustum,
                &mut self.activate,
            )
            .map_err(core)?;
            for &slot in &self.activate {
                self.registry
                    .set_state(slot, InstanceState::Active)
                    .map_err(core)?;
                let lod = usize::from(ctx.lods[slot as usize]);
                self.blas.activate(ctx.catalog, slot, lod)?;
            }
            self.stats.latency_activations = self.activate.len() as u32;
        }

        // 4. Commands of frame f - k.
        while self.ring.len() >= self.config.readback_latency {
            if let Some(buf) = self.ring.pop_front() {
                self.stats.commands_ingested += self.queue.ingest_buffer(&buf).accepted;
            }
        }
        let commands = self.queue.drain(self.config.command_budget);
        self.stats.commands_processed = commands.len() as u32;
        for c in commands {
            match c.kind {
                CommandKind::Add => {
                    let lod = usize::from(ctx.lods[c.slot as usize]);
                    self.blas.activate(ctx.catalog, c.slot, lod)?;
                }
                CommandKind::Remove => {
                    self.blas.deactivate(c.slot)?;
                    self.registry.set_blas_at(c.slot, 0).map_err(core)?;
                }
            }
        }
        self.stats.commands_pending = self.queue.len() as u32;

        // 5. Builds, addresses, upload.
        let work = self.blas.build(ctx.catalog, ctx.lods)?;
        for slot in self.blas.take_address_changes() {
            let address = self.blas.address(slot).unwrap_or(0);
            self.registry.set_blas_at(slot, address).map_err(core)?;
        }
        let dirty = self.registry.take_dirty();
        let records = self.registry.records();
        for range in dirty {
            let (a, b) = (range.start as usize, range.end as usize);
            self.gpu[a..b].copy_from_slice(&records[a..b]);
        }

        // 6. Algorithm 1; geometry records get this frame's BLAS.
        let cfg = AssemblyConfig::new(ctx.unit_cube);
        let counting = CountingConfig::default();
        if cfg.omitted_box_sbt_offset != counting.instance_box_sbt
            || cfg.hitbox_sbt_offset != counting.hitbox_box_sbt
            || cfg.counting_mask != counting.counting_mask
        {
            return Err(SimError::BadConfig(
                "assembly and tracer disagree on counting boxes",
            ));
        }
        assemble_tlas(
            &self.gpu,
            &mut self.hitboxes,
            self.registry.hitbox_index(),
            &cfg,
            out,
        )
        .map_err(core)?;
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
        self.stats.active_hitboxes = self.hitboxes.iter().filter(|h| h.is_active()).count() as u32;
        Ok(StrategyFrame {
            work,
            blas_bytes: self.blas.memory_bytes() + blas_bytes(12),
            overhead_bytes: lipac_overhead_bytes(self.hitboxes.len() as u64, self.gpu.len() as u64),
        })
    }
}
