//! Acceleration-structure pool: BLASes and compacted copies live at 256-byte
//! aligned, disjoint ranges of a few large blocks, trace like the CPU
//! reference, and return their ranges when dropped.

use crate::common::*;
use ash::vk;
use glam::{Affine3A, Quat, Vec3};
use lipac_test_support::{Rng64, SplitMix64};
use lipac_vk::{
    record_compactions_pooled, AccelerationStructurePool, BlasBatch, CountingBoxConfig, GpuRay,
    OneShot, ScratchBuffer, VkError, AS_OFFSET_ALIGNMENT,
};

/// Asserts that the structures' address ranges do not overlap.
fn assert_disjoint(ranges: &[(u64, u64)]) {
    let mut r = ranges.to_vec();
    r.sort();
    for w in r.windows(2) {
        assert!(
            w[0].0 + w[0].1 <= w[1].0,
            "ranges overlap: {:#x}+{} and {:#x}",
            w[0].0,
            w[0].1,
            w[1].0
        );
    }
}

pub fn pooled_blases_share_blocks_trace_correctly_and_free_their_ranges() {
    let h = headless("pooled_blases_share_blocks_trace_correctly_and_free_their_ranges");
    let ctx = h.context();
    assert!(matches!(
        AccelerationStructurePool::new(ctx, 100),
        Err(VkError::InvalidArgument(_))
    ));
    // 256 KiB blocks: a 16x16 grid (~53 KB on lavapipe) and small quads fit
    // several to a block; a 48x48 grid (~480 KB) needs a block of its own.
    let block = 256 << 10;
    let pool = AccelerationStructurePool::new(ctx, block).unwrap();
    assert_eq!(pool.stats().blocks, 0);
    assert!(matches!(
        pool.create(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL, 0),
        Err(VkError::InvalidArgument(_))
    ));

    let grid = GpuMesh::new(&h, Mesh::bumpy_grid(16));
    let quad = GpuMesh::new(&h, Mesh::quad());
    let big = GpuMesh::new(&h, Mesh::bumpy_grid(48));
    let flags = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE
        | vk::BuildAccelerationStructureFlagsKHR::ALLOW_COMPACTION;
    let mut batch = BlasBatch::new();
    for _ in 0..6 {
        batch.push(&[grid.geometry()], flags).unwrap();
        batch.push(&[quad.geometry()], flags).unwrap();
    }
    batch.push(&[big.geometry()], flags).unwrap();
    let mut scratch = ScratchBuffer::new(ctx);
    let mut one_shot = OneShot::new(ctx).unwrap();
    let built = one_shot
        .run(|rec| batch.record_pooled(rec, &mut scratch, &pool))
        .unwrap();
    let blases = &built.blases;
    assert_eq!(blases.len(), 13);
    let used: u64 = blases.iter().map(|b| b.size()).sum();
    let stats = pool.stats();
    assert_eq!(stats.used_bytes, used);
    assert_eq!(stats.allocation_count, 13);
    assert_eq!(stats.used_bytes + stats.free_bytes, stats.capacity_bytes);
    // Independent lower bound: the small ones need ceil(sum / block) blocks,
    // the big one (over a block) one more.
    let big_size = blases[12].size();
    assert!(big_size > block, "the big grid must exceed a block");
    let small: u64 = blases[..12].iter().map(|b| b.size()).sum();
    assert!(stats.blocks as u64 > small.div_ceil(block));
    assert!(stats.blocks <= 6, "{stats:?}");
    assert!(pool.memory_bytes() >= stats.capacity_bytes);
    for b in blases {
        let off = b.accel().pool_offset().expect("pooled");
        assert_eq!(off % AS_OFFSET_ALIGNMENT, 0);
        assert_eq!(b.device_address() % AS_OFFSET_ALIGNMENT, 0);
        assert_eq!(b.accel().memory_bytes(), b.size());
    }
    let ranges: Vec<_> = blases
        .iter()
        .map(|b| (b.device_address(), b.size()))
        .collect();
    assert_disjoint(&ranges);

    // Compacted copies go into the pool too.
    let sizes = built.compaction.as_ref().unwrap().read_sizes().unwrap();
    let items: Vec<_> = sizes
        .iter()
        .filter(|&&(i, _)| i < 2)
        .map(|&(i, s)| (&blases[i], s))
        .collect();
    let compacted = one_shot
        .run(|rec| record_compactions_pooled(rec, &items, &pool))
        .unwrap();
    assert!(compacted.iter().all(|c| c.accel().pool_offset().is_some()));
    assert_eq!(pool.stats().allocation_count, 15);

    // Trace three grid instances through the compacted pooled grid BLAS.
    let scene: Vec<SceneInstance> = (0..3)
        .map(|k| SceneInstance {
            mesh: Mesh::bumpy_grid(16),
            transform: Affine3A::from_scale_rotation_translation(
                Vec3::splat(1.5),
                Quat::from_rotation_y(0.3 * k as f32),
                Vec3::new(4.0 * k as f32 - 4.0, 0.0, 6.0),
            ),
            custom_index: 30 + k,
            sbt_offset: 0,
            active: true,
        })
        .collect();
    let records: Vec<_> = scene
        .iter()
        .map(|i| tlas_record(i, &compacted[0], 0x01))
        .collect();
    let mut rng = SplitMix64::new(5);
    let rays: Vec<GpuRay> = (0..160)
        .map(|_| GpuRay {
            origin: [0.0, 0.0, 0.0],
            t_min: 0.0,
            direction: [12.0 * rng.unit_f32() - 6.0, 3.0 * rng.unit_f32() - 1.5, 6.0],
            t_max: 100.0,
        })
        .collect();
    let pipeline = TestTracer::preferred(&h, &CountingBoxConfig::default());
    let (tlas, out) = trace(&h, &pipeline, &records, 4, &rays, 0xFF, 32);
    let (compared, hits) = compare_with_cpu(&scene, &rays, &out.hits);
    assert!(compared >= rays.len() * 9 / 10, "{compared}");
    assert!(hits >= rays.len() / 3, "{hits}");
    drop(tlas);

    // Freed ranges come back; the next structure reuses the lowest fit.
    let grid_size = built.blases[2].size();
    drop(built);
    let stats = pool.stats();
    assert_eq!(stats.allocation_count, 2);
    assert_eq!(
        stats.used_bytes,
        compacted.iter().map(|c| c.size()).sum::<u64>()
    );
    assert!((0.0..1.0).contains(&stats.fragmentation), "{stats:?}");
    assert!(stats.free_ranges >= 1);
    // Blocks without structures are released by trim, the others stay.
    let blocks_before = stats.blocks;
    let released = pool.trim();
    assert!(released >= 1, "the big grid's block is empty now");
    assert_eq!(pool.stats().blocks, blocks_before - released);
    let again = pool
        .create(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL, grid_size)
        .unwrap();
    assert_eq!(
        again.pool_offset().map(|o| o % AS_OFFSET_ALIGNMENT),
        Some(0)
    );
    let live: Vec<_> = compacted
        .iter()
        .map(|c| (c.device_address(), c.size()))
        .chain([(again.device_address(), again.size())])
        .collect();
    assert_disjoint(&live);
    drop((again, compacted, pipeline));
    assert_eq!(pool.stats().allocation_count, 0);
    assert_eq!(pool.stats().used_bytes, 0);
    assert_no_validation_errors(&h);
}
