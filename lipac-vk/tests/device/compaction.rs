//! Compaction: queried sizes are no larger than the built BLASes, and the
//! compacted copies still trace like the CPU reference.

use crate::common::*;
use ash::vk;
use glam::{Affine3A, Quat, Vec3};
use lipac_test_support::{Rng64, SplitMix64};
use lipac_vk::{
    record_compactions, BlasBatch, CountingBoxConfig, GpuRay, OneShot, ScratchBuffer, UnitCube,
    VkError,
};

pub fn compacted_blases_are_no_larger_and_trace_the_same() {
    let h = headless("compacted_blases_are_no_larger_and_trace_the_same");
    let ctx = h.context();
    let grid = GpuMesh::new(&h, Mesh::bumpy_grid(16));
    let quad = GpuMesh::new(&h, Mesh::quad());
    let cube = UnitCube::new(ctx).unwrap();
    let compact = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE
        | vk::BuildAccelerationStructureFlagsKHR::ALLOW_COMPACTION;
    // Three builds in one batch, sharing one scratch buffer; the quad is not
    // compactable and gets no query.
    let mut batch = BlasBatch::new();
    assert_eq!(batch.push(&[grid.geometry()], compact).unwrap(), 0);
    assert_eq!(
        batch
            .push(
                &[quad.geometry()],
                vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE
            )
            .unwrap(),
        1
    );
    assert_eq!(batch.push(&[cube.geometry()], compact).unwrap(), 2);
    let mut scratch = ScratchBuffer::new(ctx);
    let mut one_shot = OneShot::new(ctx).unwrap();
    let built = one_shot.run(|rec| batch.record(rec, &mut scratch)).unwrap();
    let need: u64 = built
        .blases
        .iter()
        .map(|b| b.build_sizes().build_scratch)
        .sum();
    assert!(scratch.capacity() >= need);
    assert_eq!(scratch.base_address() % scratch.alignment(), 0);
    let query = built
        .compaction
        .as_ref()
        .expect("two builds allow compaction");
    assert_eq!(query.indices(), &[0, 2]);
    let sizes = query.read_sizes().unwrap();
    for &(i, size) in &sizes {
        let blas = &built.blases[i];
        assert!(
            size > 0 && size <= blas.size(),
            "BLAS {i}: compacted {size} of {}",
            blas.size()
        );
    }

    // The uncompactable quad is refused.
    let err = one_shot
        .run(|rec| built.blases[1].record_compact(rec, 64))
        .unwrap_err();
    assert!(matches!(err, VkError::InvalidArgument(_)), "{err}");

    let items: Vec<_> = sizes.iter().map(|&(i, s)| (&built.blases[i], s)).collect();
    let compacted = one_shot.run(|rec| record_compactions(rec, &items)).unwrap();
    assert!(compacted.iter().all(|b| b.is_compacted()));
    for (c, (src, size)) in compacted.iter().zip(&items) {
        assert_eq!(c.size(), *size);
        assert_eq!(c.triangle_count(), src.triangle_count());
        assert_ne!(c.device_address(), src.device_address());
    }
    let (grid_blas, _cube_blas) = (&compacted[0], &compacted[1]);
    // The originals can go once the copies have executed.
    drop(built);

    let scene: Vec<SceneInstance> = (0..3)
        .map(|k| SceneInstance {
            mesh: Mesh::bumpy_grid(16),
            transform: Affine3A::from_scale_rotation_translation(
                Vec3::splat(1.5),
                Quat::from_rotation_y(0.4 * k as f32),
                Vec3::new(4.0 * k as f32 - 4.0, 0.0, 6.0),
            ),
            custom_index: 20 + k,
            sbt_offset: 0,
            active: true,
        })
        .collect();
    let records: Vec<_> = scene
        .iter()
        .map(|i| tlas_record(i, grid_blas, 0x01))
        .collect();
    let mut rng = SplitMix64::new(11);
    let rays: Vec<GpuRay> = (0..192)
        .map(|_| GpuRay {
            origin: [0.0, 0.0, 0.0],
            t_min: 0.0,
            direction: [12.0 * rng.unit_f32() - 6.0, 3.0 * rng.unit_f32() - 1.5, 6.0],
            t_max: 100.0,
        })
        .collect();
    let pipeline = TestTracer::preferred(&h, &CountingBoxConfig::default());
    let (tlas, out) = trace(&h, &pipeline, &records, 8, &rays, 0xFF, 32);
    let (compared, hits) = compare_with_cpu(&scene, &rays, &out.hits);
    assert!(
        compared >= rays.len() * 9 / 10,
        "only {compared} unambiguous rays"
    );
    assert!(hits >= rays.len() / 3, "only {hits} hits");
    drop((tlas, pipeline, compacted));
    assert_no_validation_errors(&h);
}
