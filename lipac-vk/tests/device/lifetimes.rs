//! Lifetimes: a double-buffered TLAS keeps the previous frame's structure
//! intact, and retired storage (grown TLAS, pooled BLAS) is destroyed only
//! once the GPU has passed its timeline value, without the host waiting.

use crate::common::*;
use ash::vk;
use glam::{Affine3A, Vec3};
use lipac_core::layout::TlasInstance;
use lipac_vk::{
    AccelerationStructurePool, BlasBatch, Buffer, CountingBoxConfig, FrameSubmitter, GpuRay,
    MemoryLocation, OneShot, Retirement, ScratchBuffer, TimelineSemaphore, TlasPair,
};
use std::time::{Duration, Instant};

fn quad_at(z: f32, custom_index: u32, blas: u64) -> TlasInstance {
    let inst = SceneInstance {
        mesh: Mesh::quad(),
        transform: Affine3A::from_translation(Vec3::new(0.0, 0.0, z)),
        custom_index,
        sbt_offset: 0,
        active: true,
    };
    TlasInstance::new(
        lipac_core::math::affine_to_rows(&inst.transform),
        custom_index,
        0x01,
        0,
        lipac_core::layout::VK_INSTANCE_CULL_DISABLE,
        blas,
    )
}

/// Polls `collect_signalled` until `pending` drops to `left` (the GPU gets
/// there on its own; the host never blocks on it).
fn collect_until(r: &mut Retirement, s: &TimelineSemaphore, left: usize) {
    let start = Instant::now();
    while r.pending() > left {
        r.collect_signalled(s).unwrap();
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "GPU never got there"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
}

pub fn double_buffered_tlas_and_deferred_destruction() {
    let h = headless("double_buffered_tlas_and_deferred_destruction");
    let ctx = h.context();
    let pool = AccelerationStructurePool::new(ctx, 1 << 20).unwrap();
    let quad = GpuMesh::new(&h, Mesh::quad());
    let mut scratch = ScratchBuffer::new(ctx);
    let mut one_shot = OneShot::new(ctx).unwrap();
    let mut batch = BlasBatch::new();
    batch
        .push(
            &[quad.geometry()],
            vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
        )
        .unwrap();
    let mut built = one_shot
        .run(|rec| batch.record_pooled(rec, &mut scratch, &pool))
        .unwrap();
    let blas = built.blases.pop().unwrap();
    let addr = blas.device_address();

    let frame_sem = TimelineSemaphore::new(ctx, 0).unwrap();
    let gate = TimelineSemaphore::new(ctx, 0).unwrap();
    let mut submitter = FrameSubmitter::new(ctx, 2).unwrap();
    let mut retirement = Retirement::new();
    let mut pair = TlasPair::new(
        ctx,
        1,
        vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
    )
    .unwrap();
    let usage = BUILD_INPUT;

    // Frame 1: two records in a TLAS of capacity 1 -> it grows; the old
    // storage is retired until frame 1's value. The GPU waits on a gate the
    // host opens later.
    let frame1 = Buffer::with_data(
        ctx,
        usage,
        MemoryLocation::CpuToGpu,
        &[quad_at(5.0, 10, addr), quad_at(9.0, 11, addr)],
    )
    .unwrap();
    submitter
        .submit(&[(&gate, 1)], &[(&frame_sem, 1)], |rec| {
            pair.record_build(rec, &frame1, 0, 2, &mut scratch, &mut retirement, 1)
        })
        .unwrap();
    assert_eq!(pair.current().capacity(), 2);
    assert_eq!(pair.previous().capacity(), 1);
    assert_eq!(retirement.pending(), 1, "the capacity-1 storage");
    // The GPU has not passed frame 1: nothing is destroyed, and collecting
    // returns at once.
    let t = Instant::now();
    assert_eq!(retirement.collect_signalled(&frame_sem).unwrap(), 0);
    assert!(t.elapsed() < Duration::from_millis(500));
    assert_eq!(retirement.pending(), 1);
    gate.signal(1).unwrap();
    collect_until(&mut retirement, &frame_sem, 0);
    assert_eq!(retirement.destroyed(), 1);

    // Frame 2: one record into the other TLAS; frame 1's TLAS stays intact.
    let frame2 = Buffer::with_data(
        ctx,
        usage,
        MemoryLocation::CpuToGpu,
        &[quad_at(3.0, 20, addr)],
    )
    .unwrap();
    one_shot
        .run(|rec| pair.record_build(rec, &frame2, 0, 1, &mut scratch, &mut retirement, 2))
        .unwrap();
    assert_eq!(pair.builds(), 2);
    assert_eq!(
        (pair.current().built_count(), pair.previous().built_count()),
        (1, 2)
    );
    assert_ne!(pair.current().accel().raw(), pair.previous().accel().raw());

    let pipeline = TestTracer::preferred(&h, &CountingBoxConfig::default());
    let rays = [GpuRay {
        origin: [0.1, 0.2, 0.0],
        t_min: 0.0,
        direction: [0.0, 0.0, 1.0],
        t_max: 100.0,
    }];
    let trace = |tlas| trace_tlas(&h, &pipeline, tlas, &rays, 0xFF, 32).hits[0];
    let prev = trace(pair.previous());
    let cur = trace(pair.current());
    assert_eq!((prev.custom_index, cur.custom_index), (10, 20));
    assert!((prev.t - 5.0).abs() < 1e-4 && (cur.t - 3.0).abs() < 1e-4);

    // A pooled BLAS retired behind a gated submission keeps its range until
    // the GPU passes the value.
    assert_eq!(pool.stats().allocation_count, 1);
    submitter
        .submit(&[(&gate, 2)], &[(&frame_sem, 3)], |_| Ok(()))
        .unwrap();
    retirement.retire(3, blas);
    retirement.collect_signalled(&frame_sem).unwrap();
    assert_eq!(retirement.pending(), 1);
    assert_eq!(pool.stats().allocation_count, 1);
    gate.signal(2).unwrap();
    collect_until(&mut retirement, &frame_sem, 0);
    assert_eq!(pool.stats().allocation_count, 0);
    submitter.wait_idle().unwrap();
    drop((pair, pipeline));
    assert_no_validation_errors(&h);
}
