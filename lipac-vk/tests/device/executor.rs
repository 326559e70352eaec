//! The plan executor on a device: lipac-core's BuildScheduler plans BLAS
//! builds, refits, rebuilds, LOD switches, compactions and frees for twelve
//! frames; PlanExecutor records them (submissions in flight, never waiting)
//! and acknowledges them once the timeline passed their frame; every
//! acknowledged address is a live BLAS of the acknowledged size,
//! and frees come only after the frames in flight that may reference them.

use crate::common::*;
use ash::vk;
use lipac_core::blas_cache::{BlasOwner, BlasState, CacheConfig};
use lipac_core::blas_ids::{InstanceKey, Lod};
use lipac_core::build_plan::{
    BlasGeometry, BuildBudgets, BuildEstimate, BuildScheduler, InstanceBlasRequest, SchedulerConfig,
};
use lipac_core::layout::{TlasInstance, VK_INSTANCE_CULL_DISABLE};
use lipac_core::manager::Ack;
use lipac_core::MeshId;
use lipac_vk::{
    AccelerationStructurePool, Buffer, FrameSubmitter, GpuBlas, MemoryLocation, PlanExecutor,
    ScratchBuffer, TimelineSemaphore, TlasPair, TriangleGeometry,
};
use std::collections::HashMap;

const SHARED: MeshId = MeshId(1);
const UNIQUE: MeshId = MeshId(2);
const FRAMES_IN_FLIGHT: u32 = 2;

/// Hands the executor's acknowledgements to the scheduler; returns how many
/// compacted sizes came back.
fn deliver(acks: Vec<Ack>, sched: &mut BuildScheduler) -> usize {
    let mut sizes = 0;
    for ack in acks {
        match ack {
            Ack::Built {
                build,
                result_bytes,
                address,
            } => sched.ack_built(build, result_bytes, address).unwrap(),
            Ack::CompactedSize {
                build,
                compacted_bytes,
            } => {
                sizes += 1;
                sched.ack_compacted_size(build, compacted_bytes).unwrap()
            }
            Ack::Compacted { op, address } => sched.ack_compacted(op, address).unwrap(),
        }
    }
    sched.take_address_changes();
    sizes
}

fn bytes_of(state: BlasState) -> Option<u64> {
    match state {
        BlasState::Built { bytes, .. }
        | BlasState::SizeQueried { bytes, .. }
        | BlasState::Compacting { bytes, .. }
        | BlasState::Compacted { bytes, .. } => Some(bytes),
        _ => None,
    }
}

pub fn scheduler_plans_recorded_by_the_executor_stay_consistent() {
    let h = headless("scheduler_plans_recorded_by_the_executor_stay_consistent");
    let ctx = h.context();
    let lod0 = GpuMesh::new(&h, Mesh::bumpy_grid(12));
    let lod1 = GpuMesh::new(&h, Mesh::bumpy_grid(4));
    let unique = GpuMesh::new(&h, Mesh::bumpy_grid(6));
    let source = |owner: &BlasOwner| -> Option<Vec<TriangleGeometry>> {
        match *owner {
            BlasOwner::Shared(k) if k.mesh == SHARED && k.lod == Lod(0) => {
                Some(vec![lod0.geometry()])
            }
            BlasOwner::Shared(k) if k.mesh == SHARED && k.lod == Lod(1) => {
                Some(vec![lod1.geometry()])
            }
            BlasOwner::Unique { mesh, .. } if mesh == UNIQUE => Some(vec![unique.geometry()]),
            _ => None,
        }
    };
    let fast = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE;
    let estimate = |m: &GpuMesh, flags| {
        let s = GpuBlas::query_sizes(ctx, &[m.geometry()], fast | flags).unwrap();
        BuildEstimate {
            primitives: u64::from(m.mesh.triangle_count()),
            result_bytes: s.acceleration_structure,
            build_scratch_bytes: s.build_scratch,
            update_scratch_bytes: s.update_scratch,
        }
    };
    let compact = vk::BuildAccelerationStructureFlagsKHR::ALLOW_COMPACTION;
    let (e0, e1) = (estimate(&lod0, compact), estimate(&lod1, compact));
    let eu = estimate(
        &unique,
        vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE,
    );

    let pool = AccelerationStructurePool::new(ctx, 256 << 10).unwrap();
    let mut exec = PlanExecutor::new(ctx, pool.clone()).unwrap();
    let mut sched = BuildScheduler::new(SchedulerConfig {
        cache: CacheConfig {
            memory_budget: 64 << 20,
            frames_in_flight: FRAMES_IN_FLIGHT,
            max_unused_frames: 1000,
        },
        scratch_alignment: exec.scratch_alignment(),
        unique_rebuild_interval: 3,
        lod_hysteresis_frames: 2,
        ..SchedulerConfig::default()
    })
    .unwrap();
    let budgets = BuildBudgets {
        max_builds: 2,
        max_batches: 2,
        max_scratch_bytes: 1 << 20,
        ..BuildBudgets::default()
    };
    let frames = TimelineSemaphore::new(ctx, 0).unwrap();
    let mut submitter = FrameSubmitter::new(ctx, 3).unwrap();
    let mut tlas = TlasPair::new(ctx, 4, fast).unwrap();
    let mut tlas_scratch = ScratchBuffer::new(ctx);

    let shared_keys: Vec<InstanceKey> = (0..4).map(InstanceKey).collect();
    let unique_keys = [InstanceKey(10), InstanceKey(11)];
    let mut active: Vec<InstanceKey> = Vec::new();
    // Last frame whose TLAS referenced each address.
    let mut last_ref: HashMap<u64, u64> = HashMap::new();
    let (mut builds, mut updates, mut compactions, mut frees, mut acked_sizes) = (0, 0, 0, 0, 0);
    let mut rebuilds = 0;

    for f in 1..=14u64 {
        sched.begin_frame(f).unwrap();
        match f {
            1 => {
                for &k in &shared_keys {
                    let geometry = BlasGeometry::Shared {
                        mesh: SHARED,
                        variant: 0,
                        compactable: true,
                    };
                    sched
                        .activate(
                            k,
                            InstanceBlasRequest {
                                geometry,
                                lod: Lod(0),
                                estimate: e0,
                                hits: 5,
                                in_frustum: true,
                            },
                        )
                        .unwrap();
                }
                for &k in &unique_keys {
                    let geometry = BlasGeometry::Unique { mesh: UNIQUE };
                    let request = InstanceBlasRequest {
                        geometry,
                        lod: Lod(0),
                        estimate: eu,
                        hits: 1,
                        in_frustum: false,
                    };
                    sched.activate(k, request).unwrap();
                }
                active.extend(shared_keys.iter().chain(&unique_keys));
            }
            // Two instances move away: LOD 1 (after the hysteresis).
            4..=7 => {
                for &k in &shared_keys[..2] {
                    sched.request_lod(k, Lod(1), e1).unwrap();
                }
            }
            _ => {}
        }
        if f == 8 {
            sched.deactivate(unique_keys[1]).unwrap();
            active.retain(|&k| k != unique_keys[1]);
        }
        acked_sizes += deliver(exec.poll(frames.value().unwrap()).unwrap(), &mut sched);
        let plan = sched.plan(&budgets).unwrap();
        assert!(plan.oversized.is_empty() && plan.memory_blocked.is_empty());
        rebuilds += plan
            .updates()
            .filter(|u| u.mode == lipac_core::build_plan::UpdateMode::Rebuild)
            .count();
        for free in &plan.frees {
            let last = last_ref.get(&free.address).copied().unwrap_or(0);
            assert!(
                f >= last + u64::from(FRAMES_IN_FLIGHT),
                "frame {f}: {free:?} last referenced in frame {last}"
            );
        }

        let report = submitter
            .submit(&[], &[(&frames, f)], |rec| {
                let report = exec.record(rec, &plan, &source, f)?;
                let mut records: Vec<TlasInstance> = active
                    .iter()
                    .filter_map(|&k| {
                        let addr = sched.blas_address(k)?;
                        Some(TlasInstance::new(
                            [
                                1.0, 0.0, 0.0, k.0 as f32, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0,
                            ],
                            k.0,
                            0xFF,
                            0,
                            VK_INSTANCE_CULL_DISABLE,
                            addr,
                        ))
                    })
                    .collect();
                if records.is_empty() {
                    records.push(TlasInstance::new([0.0; 12], 0, 0, 0, 0, 0));
                }
                let buf = Buffer::with_data(ctx, BUILD_INPUT, MemoryLocation::CpuToGpu, &records)?;
                let n = records.len() as u32;
                let (retirement, tlas, scratch) =
                    (exec.retirement_mut(), &mut tlas, &mut tlas_scratch);
                tlas.record_build(rec, &buf, 0, n, scratch, retirement, f)?;
                retirement.retire(f, buf);
                Ok(report)
            })
            .unwrap();
        assert_eq!(report.builds, plan.builds().count());
        assert_eq!(report.updates, plan.updates().count());
        assert_eq!(report.compactions, plan.compactions.len());
        assert!(report.batches <= budgets.max_batches as usize);
        builds += report.builds;
        updates += report.updates;
        compactions += report.compactions;
        frees += report.retired.len();
        assert_eq!(
            report.retired.len(),
            plan.frees.len(),
            "every free was live"
        );

        // Every address the scheduler hands out is a live BLAS of the
        // acknowledged size.
        for &k in &active {
            let Some(addr) = sched.blas_address(k) else {
                continue;
            };
            let blas = exec
                .blas_at(addr)
                .unwrap_or_else(|| panic!("frame {f}: {k:?} -> {addr:#x} is not live"));
            let id = sched.current_blas(k).unwrap();
            let info = sched.cache().get(id).unwrap();
            assert_eq!(bytes_of(info.state), Some(blas.size()), "frame {f} {k:?}");
            last_ref.insert(addr, f);
        }
        for b in plan.builds() {
            let blas = exec.blas_of(b.id).unwrap();
            assert!(
                blas.size() <= b.result_bytes,
                "estimate = query, so it fits"
            );
        }
        // Retired structures still hold their pool ranges until collected.
        let stats = exec.stats();
        exec.collect(frames.value().unwrap());
        let after = exec.stats();
        assert_eq!(
            stats.pool.allocation_count,
            stats.live_blases + stats.retired_pending,
        );
        assert!(after.retired_pending <= stats.retired_pending);
    }
    submitter.wait_idle().unwrap();
    acked_sizes += deliver(exec.poll(frames.value().unwrap()).unwrap(), &mut sched);
    exec.collect(u64::MAX);
    let stats = exec.stats();
    assert_eq!((stats.retired_pending, stats.other_retired_pending), (0, 0));
    assert_eq!(stats.pool.allocation_count, stats.live_blases);
    assert_eq!(stats.pool.used_bytes, stats.live_bytes);

    // LOD 0, LOD 1 and two unique BLASes were built; both shared ones were
    // compacted after their sizes came back; the unique ones were refit and
    // rebuilt; compaction originals and the deactivated unique BLAS were freed.
    assert_eq!(builds, 4, "LOD0, LOD1, 2 unique");
    assert_eq!(acked_sizes, 2);
    assert_eq!(compactions, 2);
    assert!(updates >= 10, "{updates} updates");
    assert!(rebuilds >= 2, "{rebuilds} rebuilds");
    assert_eq!(frees, 3, "2 compaction originals + 1 unique");
    assert_eq!(sched.current_lod(shared_keys[0]), Some(Lod(1)));
    assert_eq!(sched.current_lod(shared_keys[3]), Some(Lod(0)));
    drop((tlas, submitter));
    assert_no_validation_errors(&h);
}
