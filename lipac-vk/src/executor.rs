//! Records lipac-core's BLAS build plans: [`PlanExecutor`].
//!
//! Per frame the backend hands the [`FramePlan`] (the `blas` part of a
//! [`lipac_core::manager::ManagerPlan`]) to [`PlanExecutor::record`], which
//! records
//!
//! 1. every [`lipac_core::build_plan::BuildBatch`] as one [`BlasBatch`]
//!    (builds and in-place updates in one `vkCmdBuildAccelerationStructuresKHR`,
//!    scratch slices of one [`ScratchBuffer`] from its base, one barrier after
//!    the batch; a batch with updates also gets a barrier before it) with the
//!    new BLASes in an [`AccelerationStructurePool`];
//! 2. the compaction copies (into the pool, one barrier);
//! 3. the frees: each freed structure goes to the [`Retirement`] queue until
//!    this frame's timeline value.
//!
//! Nothing is acknowledged at recording time. [`PlanExecutor::poll`] takes
//! the timeline value the GPU has reached (read without waiting) and returns
//! the [`Ack`]s of the work it has passed: [`Ack::Built`] (real size and
//! address) and [`Ack::Compacted`] for the builds and copies of frames at or
//! below it, and [`Ack::CompactedSize`] for the compacted-size queries of
//! those batches. Hand them to
//! [`Manager::handle_ack`](lipac_core::manager::Manager::handle_ack), in the
//! order given. [`PlanExecutor::collect`] destroys what the GPU has passed.

use crate::as_pool::{AccelerationStructurePool, PoolStats};
use crate::blas::record_compactions_pooled;
use crate::blas::{BlasBatch, BlasUpdateMode, CompactionQuery, GpuBlas, TriangleGeometry};
use crate::commands::Recorder;
use crate::context::DeviceContext;
use crate::error::{Result, VkError};
use crate::lifetimes::Retirement;
use crate::memory::ScratchBuffer;
use ash::vk;
use lipac_core::blas_cache::BlasOwner;
use lipac_core::blas_ids::BuildId;
use lipac_core::build_plan::{FramePlan, UpdateMode};
use lipac_core::manager::Ack;
use std::collections::HashMap;

/// Where the executor gets the triangles of a BLAS: the engine's vertex and
/// index buffers for an owner (shared mesh, LOD and variant, or a unique
/// instance's current, possibly deformed, geometry).
pub trait BlasGeometrySource {
    /// The geometries of `owner`'s BLAS, or `None` if the engine has none.
    fn geometries(&self, owner: &BlasOwner) -> Option<Vec<TriangleGeometry>>;
}

impl<F: Fn(&BlasOwner) -> Option<Vec<TriangleGeometry>>> BlasGeometrySource for F {
    fn geometries(&self, owner: &BlasOwner) -> Option<Vec<TriangleGeometry>> {
        self(owner)
    }
}

/// A live BLAS the executor created.
#[derive(Debug)]
struct LiveBlas {
    blas: GpuBlas,
    owner: BlasOwner,
}

#[derive(Debug)]
struct PendingQuery {
    /// Timeline value of the submission holding the batch.
    value: u64,
    query: CompactionQuery,
    /// Batch index -> build.
    builds: Vec<(usize, BuildId)>,
}

/// What [`PlanExecutor::record`] recorded for one frame.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ExecutedFrame {
    /// Batches recorded.
    pub batches: usize,
    /// Builds recorded (acknowledged by a later [`PlanExecutor::poll`]).
    pub builds: usize,
    /// In-place updates recorded (refits and rebuilds).
    pub updates: usize,
    /// Compaction copies recorded (acknowledged by a later poll).
    pub compactions: usize,
    /// Acceleration structures retired (freed once the GPU passes this frame).
    pub retired: Vec<BuildId>,
    /// Largest scratch a batch used.
    pub scratch_bytes: u64,
    /// Bytes of the BLASes built this frame.
    pub built_bytes: u64,
}

/// Counters of a [`PlanExecutor`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ExecutorStats {
    /// Live BLASes (built or compacted, not yet freed by the plan).
    pub live_blases: usize,
    /// Their bytes.
    pub live_bytes: u64,
    /// BLASes freed by plans and waiting for the GPU (they still hold
    /// their pool ranges).
    pub retired_pending: usize,
    /// Other retired objects (scratch, and what the engine retired into
    /// [`PlanExecutor::retirement_mut`]).
    pub other_retired_pending: usize,
    /// Compacted-size queries not yet read.
    pub queries_pending: usize,
    /// Acknowledgements waiting for the GPU to pass their frame.
    pub acks_pending: usize,
    /// The pool's occupancy (live + retired structures).
    pub pool: PoolStats,
    /// Scratch buffer capacity.
    pub scratch_capacity: u64,
}

/// Records [`FramePlan`]s; see the module docs.
#[derive(Debug)]
pub struct PlanExecutor {
    ctx: DeviceContext,
    pool: AccelerationStructurePool,
    scratch: ScratchBuffer,
    retirement: Retirement,
    retired_blases: Retirement,
    live: HashMap<BuildId, LiveBlas>,
    by_address: HashMap<u64, BuildId>,
    queries: Vec<PendingQuery>,
    /// (timeline value, acknowledgement) in recording order.
    acks: Vec<(u64, Ack)>,
    base_flags: vk::BuildAccelerationStructureFlagsKHR,
}

impl PlanExecutor {
    /// An executor creating BLASes in `pool`, with `PREFER_FAST_TRACE`
    /// builds (plus `ALLOW_COMPACTION` / `ALLOW_UPDATE` as the plan says).
    ///
    /// # Errors
    ///
    /// [`VkError::WrongContext`] for a pool of another context.
    pub fn new(ctx: &DeviceContext, pool: AccelerationStructurePool) -> Result<Self> {
        crate::accel::same_context(ctx, pool.context())?;
        Ok(Self {
            ctx: ctx.clone(),
            pool,
            scratch: ScratchBuffer::new(ctx),
            retirement: Retirement::new(),
            retired_blases: Retirement::new(),
            live: HashMap::new(),
            by_address: HashMap::new(),
            queries: Vec::new(),
            acks: Vec::new(),
            base_flags: vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
        })
    }

    /// The pool.
    pub fn pool(&self) -> &AccelerationStructurePool {
        &self.pool
    }

    /// The deferred-destruction queue (engines may retire their own objects
    /// into it).
    pub fn retirement_mut(&mut self) -> &mut Retirement {
        &mut self.retirement
    }

    /// Scratch alignment to put in
    /// [`lipac_core::build_plan::SchedulerConfig::scratch_alignment`]
    /// (`minAccelerationStructureScratchOffsetAlignment`, a power of two).
    pub fn scratch_alignment(&self) -> u64 {
        self.scratch.alignment().next_power_of_two()
    }

    /// The live BLAS at `address` (what an acknowledged address names), if any.
    pub fn blas_at(&self, address: u64) -> Option<&GpuBlas> {
        let id = self.by_address.get(&address)?;
        self.live.get(id).map(|l| &l.blas)
    }

    /// The live BLAS created by build or compaction `op`.
    pub fn blas_of(&self, op: BuildId) -> Option<&GpuBlas> {
        self.live.get(&op).map(|l| &l.blas)
    }

    /// Counters.
    pub fn stats(&self) -> ExecutorStats {
        ExecutorStats {
            live_blases: self.live.len(),
            live_bytes: self.live.values().map(|l| l.blas.size()).sum(),
            retired_pending: self.retired_blases.pending(),
            other_retired_pending: self.retirement.pending(),
            queries_pending: self.queries.len(),
            acks_pending: self.acks.len(),
            pool: self.pool.stats(),
            scratch_capacity: self.scratch.capacity(),
        }
    }

    fn geometries(
        source: &dyn BlasGeometrySource,
        owner: &BlasOwner,
    ) -> Result<Vec<TriangleGeometry>> {
        source
            .geometries(owner)
            .filter(|g| !g.is_empty())
            .ok_or_else(|| VkError::InvalidArgument(format!("no geometry for {owner:?}")))
    }

    /// Records `plan` (see the module docs). Its builds and compactions are
    /// acknowledged by the first [`PlanExecutor::poll`] that sees the GPU at
    /// or past `frame_value` (the timeline value this recording's submission
    /// signals, not below an earlier call's). Objects freed by the plan, and
    /// scratch replaced by growth, are retired until `frame_value`.
    ///
    /// # Errors
    ///
    /// [`VkError::InvalidArgument`] for a missing geometry, an update or
    /// compaction of an unknown BLAS, or a `frame_value` below an earlier
    /// one; recording errors. Batches recorded before the error stay
    /// recorded and will be acknowledged: submit the recording or drop the
    /// executor.
    pub fn record(
        &mut self,
        rec: &mut Recorder<'_>,
        plan: &FramePlan,
        source: &dyn BlasGeometrySource,
        frame_value: u64,
    ) -> Result<ExecutedFrame> {
        if let Some(&(last, _)) = self.acks.last() {
            if frame_value < last {
                return Err(VkError::InvalidArgument(format!(
                    "frame value {frame_value} below an earlier recording's {last}"
                )));
            }
        }
        crate::accel::same_context(rec.context(), &self.ctx)?;
        let mut report = ExecutedFrame::default();
        for batch in &plan.batches {
            if batch.builds.is_empty() && batch.updates.is_empty() {
                continue;
            }
            let mut update_geoms = Vec::with_capacity(batch.updates.len());
            for u in &batch.updates {
                let id = self.by_address.get(&u.address).ok_or_else(|| {
                    VkError::InvalidArgument(format!("update of unknown BLAS {:#x}", u.address))
                })?;
                let live = &self.live[id];
                update_geoms.push((*id, Self::geometries(source, &live.owner)?, u.mode));
            }
            let mut build_geoms = Vec::with_capacity(batch.builds.len());
            for b in &batch.builds {
                build_geoms.push(Self::geometries(source, &b.owner)?);
            }
            let mut blas_batch = BlasBatch::new();
            for (b, g) in batch.builds.iter().zip(&build_geoms) {
                let mut flags = self.base_flags;
                if b.allow_compaction {
                    flags |= vk::BuildAccelerationStructureFlagsKHR::ALLOW_COMPACTION;
                }
                if b.allow_update {
                    flags |= vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE;
                }
                blas_batch.push(g, flags)?;
            }
            for (id, g, mode) in &update_geoms {
                let mode = match mode {
                    UpdateMode::Refit => BlasUpdateMode::Refit,
                    UpdateMode::Rebuild => BlasUpdateMode::Rebuild,
                };
                blas_batch.push_update(&self.live[id].blas, g, mode)?;
            }
            let out = blas_batch.record_pooled(rec, &mut self.scratch, &self.pool)?;
            drop(blas_batch);
            self.retirement.retire_opt(frame_value, out.retired_scratch);
            report.batches += 1;
            report.updates += batch.updates.len();
            report.scratch_bytes = report.scratch_bytes.max(out.scratch_bytes);
            let mut query_builds = Vec::new();
            if let Some(q) = &out.compaction {
                for &i in q.indices() {
                    query_builds.push((i, batch.builds[i].id));
                }
            }
            for (b, blas) in batch.builds.iter().zip(out.blases) {
                report.builds += 1;
                report.built_bytes += blas.size();
                self.acks.push((
                    frame_value,
                    Ack::Built {
                        build: b.id,
                        result_bytes: blas.size(),
                        address: blas.device_address(),
                    },
                ));
                self.by_address.insert(blas.device_address(), b.id);
                self.live.insert(
                    b.id,
                    LiveBlas {
                        blas,
                        owner: b.owner,
                    },
                );
            }
            if let Some(query) = out.compaction {
                self.queries.push(PendingQuery {
                    value: frame_value,
                    query,
                    builds: query_builds,
                });
            }
        }

        if !plan.compactions.is_empty() {
            let mut items = Vec::with_capacity(plan.compactions.len());
            for c in &plan.compactions {
                let src = self.live.get(&c.source_build).ok_or_else(|| {
                    VkError::InvalidArgument(format!(
                        "compaction of unknown build {:?}",
                        c.source_build
                    ))
                })?;
                items.push((&src.blas, c.compacted_bytes));
            }
            let copies = record_compactions_pooled(rec, &items, &self.pool)?;
            for (c, blas) in plan.compactions.iter().zip(copies) {
                report.compactions += 1;
                self.acks.push((
                    frame_value,
                    Ack::Compacted {
                        op: c.id,
                        address: blas.device_address(),
                    },
                ));
                let owner = self.live[&c.source_build].owner;
                self.by_address.insert(blas.device_address(), c.id);
                self.live.insert(c.id, LiveBlas { blas, owner });
            }
        }

        for f in &plan.frees {
            if let Some(live) = self.live.remove(&f.created_by) {
                let addr = live.blas.device_address();
                if self.by_address.get(&addr) == Some(&f.created_by) {
                    self.by_address.remove(&addr);
                }
                self.retired_blases.retire(frame_value, live.blas);
                report.retired.push(f.created_by);
            }
        }
        Ok(report)
    }

    /// The acknowledgements of the work the GPU has passed (`completed` =
    /// the timeline value it reached, read without waiting, e.g.
    /// [`crate::TimelineSemaphore::value`]): builds and compactions recorded
    /// at values up to `completed`, in recording order, then the
    /// compacted-size queries of those batches. Never waits: a query that is
    /// not readable yet stays for a later poll.
    ///
    /// # Errors
    ///
    /// [`VkError::Vulkan`] when a query read fails.
    pub fn poll(&mut self, completed: u64) -> Result<Vec<Ack>> {
        let due = self.acks.partition_point(|&(v, _)| v <= completed);
        let mut acks: Vec<Ack> = self.acks.drain(..due).map(|(_, a)| a).collect();
        let mut i = 0;
        while i < self.queries.len() {
            if self.queries[i].value > completed {
                i += 1;
                continue;
            }
            match self.queries[i].query.read_sizes() {
                Ok(sizes) => {
                    let q = self.queries.remove(i);
                    for (batch_index, size) in sizes {
                        if let Some(&(_, build)) =
                            q.builds.iter().find(|(bi, _)| *bi == batch_index)
                        {
                            acks.push(Ack::CompactedSize {
                                build,
                                compacted_bytes: size,
                            });
                        }
                    }
                }
                Err(VkError::QueryNotReady) => i += 1,
                Err(e) => return Err(e),
            }
        }
        Ok(acks)
    }

    /// Destroys retired objects the GPU has passed (`completed` = the
    /// timeline value it reached); returns how many.
    pub fn collect(&mut self, completed: u64) -> usize {
        self.retired_blases.collect(completed) + self.retirement.collect(completed)
    }
}
