//! Out of device memory at every allocation of a frame loop
//! (`FailingAllocator`): for each n, the n-th allocation and every later
//! one fail until memory is back. The lipac-vk call that hit it returns
//! `ERROR_OUT_OF_DEVICE_MEMORY` (no panic), everything lipac held is freed
//! once the engine drops what it had (the allocator's live allocations and
//! the context's statistics back to zero), and with memory back the
//! engine's recovery (docs/INTEGRATION.md, "Errors": recreate `LipacVk`
//! and the `Manager`) runs every frame again, GPU Algorithm 1 equal to the
//! manager's CPU assembly each frame.

use std::sync::Arc;

use crate::common::*;
use ash::vk;
use glam::{Affine3A, Vec3};
use lipac_core::blas_cache::BlasOwner;
use lipac_core::build_plan::{BuildEstimate, SchedulerConfig};
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::instance::{InstanceDesc, MeshId};
use lipac_core::layout::tlas_multiset;
use lipac_core::manager::{DataUpload, FrameBudgets, Manager, ManagerConfig, MeshCatalog, MeshLod};
use lipac_core::math::Aabb;
use lipac_vk::{
    Buffer, FailingAllocator, FrameSubmitter, GpuAllocator, GpuBlas, HeadlessContext, LipacVk,
    LipacVkConfig, MemoryLocation, Polled, TriangleGeometry, VkError,
};

type Probe = Arc<FailingAllocator<GpuAllocator>>;

const DATA_BYTES: u64 = 24;
const FRAMES: u64 = 4;

/// A headless context whose allocator can be made to fail (the harness
/// runs the test only on a machine with a device).
fn failing_headless(test: &str) -> (HeadlessContext, Probe) {
    let mut probe = None;
    let made = HeadlessContext::with_allocator(validation(), |instance, device, pd| {
        // SAFETY: the handles belong together and the device has buffer
        // device address; the context drops the allocator before the device.
        let inner = unsafe { GpuAllocator::new(instance, device, pd) }?;
        let failing = Arc::new(FailingAllocator::new(inner));
        probe = Some(failing.clone());
        Ok(Box::new(failing))
    });
    match (made, probe) {
        (Ok(h), Some(p)) => (h, p),
        (Err(e), _) => panic!("{test}: no Vulkan context: {e}"),
        (Ok(_), None) => panic!("{test}: the allocator was not made"),
    }
}

fn desc(i: u32) -> InstanceDesc {
    let at = Vec3::new(4.0 + 9.0 * i as f32, 1.0, 6.0 + 5.0 * (i % 3) as f32);
    InstanceDesc::new(
        MeshId(1),
        Affine3A::from_translation(at),
        Aabb::new(at - Vec3::splat(1.0), at + Vec3::splat(1.0)),
    )
}

/// Where the loop stopped.
#[derive(Debug)]
enum Stage {
    /// Uploading the mesh (the engine's own buffers, through lipac).
    Mesh,
    /// `LipacVk::new`.
    Setup,
    /// A frame (its number).
    Frame(u64),
}

/// The backend tests' frame loop in small: a 4 x 4 grid mesh, 2 instances
/// then 7 at frame 3 (slot tables and the data buffer grow), `FRAMES`
/// frames submitted and waited for, each frame's GPU Algorithm 1 (read
/// back) equal to the manager's CPU assembly. Every object is dropped on
/// return, the GPU idle.
fn frame_loop(h: &HeadlessContext) -> Result<(), (Stage, VkError)> {
    let ctx = h.context();
    let mesh = Mesh::bumpy_grid(4);
    let upload = |data: &[u8]| {
        Buffer::with_data(ctx, BUILD_INPUT, MemoryLocation::CpuToGpu, data)
            .map_err(|e| (Stage::Mesh, e))
    };
    let vertices = upload(bytemuck::cast_slice(&mesh.vertices))?;
    let indices = upload(bytemuck::cast_slice(&mesh.indices))?;
    let geometry = TriangleGeometry::indexed(
        &vertices,
        0,
        12,
        mesh.vertices.len() as u32,
        &indices,
        0,
        lipac_vk::IndexFormat::U32,
        mesh.triangle_count(),
    )
    .map_err(|e| (Stage::Mesh, e))?;
    let fast = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE;
    let s = GpuBlas::query_sizes(ctx, &[geometry], fast).map_err(|e| (Stage::Mesh, e))?;
    let mut catalog = MeshCatalog::new();
    let lod = MeshLod {
        estimate: BuildEstimate {
            primitives: u64::from(mesh.triangle_count()),
            result_bytes: s.acceleration_structure,
            build_scratch_bytes: s.build_scratch,
            update_scratch_bytes: s.update_scratch,
        },
        data_bytes: DATA_BYTES,
    };
    catalog.insert(MeshId(1), vec![lod]).unwrap();
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [64.0, 64.0],
        cell_size: 16.0,
    })
    .unwrap();
    let config = LipacVkConfig {
        initial_slot_capacity: 2,
        readback_slots: 3,
        command_capacity: 64,
        pool_block_size: 1 << 20,
        read_back_diagnostics: true,
        ..LipacVkConfig::default()
    };
    let mut lipac = LipacVk::new(ctx, &grid, config).map_err(|e| (Stage::Setup, e))?;
    let mut mc = ManagerConfig::new(lipac.unit_cube_address());
    mc.culling.latency_mitigation = None;
    mc.culling.command_capacity = 64;
    mc.scheduler = SchedulerConfig {
        scratch_alignment: lipac.scratch_alignment(),
        ..SchedulerConfig::default()
    };
    mc.data.initial_capacity = 32;
    let mut manager = Manager::new(grid, mc, catalog).unwrap();
    for i in 0..2 {
        manager.register(desc(i)).unwrap();
    }
    let source = |_: &BlasOwner| -> Option<Vec<TriangleGeometry>> { Some(vec![geometry]) };
    let data = |u: &DataUpload, out: &mut [u8]| out.fill(u.slot as u8);
    let timeline = lipac.timeline().clone();
    // Declared last: dropped first, waiting for the GPU.
    let mut submitter = FrameSubmitter::new(ctx, 2).map_err(|e| (Stage::Setup, e))?;
    let mut last: Option<Polled> = None;
    for f in 1..=FRAMES {
        let at = |e| (Stage::Frame(f), e);
        if f == 3 {
            for i in 2..7 {
                manager.register(desc(i)).unwrap();
            }
        }
        manager.begin_frame(f).unwrap();
        if let Some(p) = last.take() {
            p.deliver(&mut manager).unwrap();
        }
        let plan = manager.plan(&FrameBudgets::default()).unwrap();
        let value = lipac.next_frame_value();
        submitter
            .submit(&[], &[(&timeline, value)], |rec| {
                lipac.record_frame(rec, &plan, &manager, &source, &data)?;
                lipac.record_feedback(rec).map(|_| ())
            })
            .map_err(at)?;
        submitter.wait_idle().map_err(at)?;
        while timeline.value().map_err(at)? < value {
            std::thread::yield_now();
        }
        let polled = lipac.poll().map_err(at)?;
        assert_eq!(polled.readbacks.len(), 1, "frame {f}");
        let r = &polled.readbacks[0];
        let mut cpu = Vec::new();
        manager.assemble(&mut cpu).unwrap();
        let diag = r.diagnostics.as_ref().expect("diagnostics");
        assert!(
            tlas_multiset(&cpu) == tlas_multiset(&diag.tlas_instances),
            "frame {f}: GPU Algorithm 1 differs from the CPU's"
        );
        last = Some(polled);
    }
    Ok(())
}

fn is_out_of_memory(e: &VkError) -> bool {
    matches!(
        e,
        VkError::Vulkan {
            result: vk::Result::ERROR_OUT_OF_DEVICE_MEMORY,
            ..
        }
    )
}

/// Nothing lipac allocated is still held.
fn assert_all_freed(h: &HeadlessContext, probe: &Probe, what: &str) {
    let stats = h.context().memory_stats();
    assert_eq!(
        (probe.live(), stats.buffers, stats.bytes),
        (0, 0, 0),
        "{what}: allocations still live"
    );
}

pub fn out_of_memory_at_every_allocation_of_a_frame_loop() {
    let name = "out_of_memory_at_every_allocation_of_a_frame_loop";
    let (h, probe) = failing_headless(name);
    // A clean run counts the loop's allocations.
    let before = probe.attempts();
    frame_loop(&h).expect("the loop runs with memory");
    let total = probe.attempts() - before;
    assert!(total >= 20, "only {total} allocations");
    assert_all_freed(&h, &probe, "clean run");

    let mut stages = std::collections::BTreeMap::<String, u64>::new();
    for n in 1..=total {
        probe.fail_from(probe.attempts() + n);
        let err = frame_loop(&h);
        let failures = probe.failures();
        probe.restore();
        let (stage, e) = match err {
            Err(x) => x,
            Ok(()) => panic!("allocation {n} of {total} failed but the loop did not notice"),
        };
        assert!(failures > 0, "allocation {n}: nothing failed");
        assert!(
            is_out_of_memory(&e),
            "allocation {n} ({stage:?}): {e} is not the out-of-memory error"
        );
        // The call unwound and the engine dropped what it had: nothing leaks.
        assert_all_freed(&h, &probe, &format!("allocation {n} ({stage:?})"));
        let key = match stage {
            Stage::Frame(f) => format!("frame {f}"),
            s => format!("{s:?}"),
        };
        let count = stages.entry(key).or_default();
        *count += 1;
        // Memory is back: the loop runs again, every frame equal to the CPU
        // (after the first failure of each stage and the last one: every
        // run starts from the same state, the checks above being per n).
        if *count == 1 || n == total {
            frame_loop(&h).unwrap_or_else(|(s, e)| panic!("after allocation {n}: {s:?}: {e}"));
            assert_all_freed(&h, &probe, &format!("recovery after allocation {n}"));
        }
    }
    eprintln!("{name}: {total} allocations failed one by one; where: {stages:?}");
    // Setup and frames each met failures (the loop's allocations are spread).
    assert!(
        stages.contains_key("Setup") && stages.contains_key("frame 1"),
        "{stages:?}"
    );
    assert_no_validation_errors(&h);
}
