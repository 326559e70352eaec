//! Unique-BLAS updates: a deformed mesh is refit in place (source =
//! destination, same address), then rebuilt in place, and rays hit the
//! *deformed* geometry as a CPU reference computes it.

use crate::common::*;
use ash::vk;
use glam::{Affine3A, Quat, Vec3};
use lipac_test_support::{Rng64, SplitMix64};
use lipac_vk::{
    AccelerationStructurePool, BlasBatch, BlasUpdateMode, CountingBoxConfig, GpuRay, OneShot,
    ScratchBuffer, VkError,
};

/// The grid with its vertices displaced along z by `amp * wave(x, y)`.
fn deformed(base: &Mesh, amp: f32, phase: f32) -> Mesh {
    let mut m = base.clone();
    for v in &mut m.vertices {
        v[2] += amp * (2.0 * v[0] + phase).sin() * (1.5 * v[1]).cos();
    }
    m
}

fn scene_of(mesh: &Mesh) -> Vec<SceneInstance> {
    (0..2)
        .map(|k| SceneInstance {
            mesh: mesh.clone(),
            transform: Affine3A::from_scale_rotation_translation(
                Vec3::splat(2.0),
                Quat::from_rotation_y(0.25 * k as f32),
                Vec3::new(4.5 * k as f32 - 2.25, 0.0, 7.0),
            ),
            custom_index: 40 + k,
            sbt_offset: 0,
            active: true,
        })
        .collect()
}

fn rays() -> Vec<GpuRay> {
    let mut rng = SplitMix64::new(23);
    (0..256)
        .map(|_| GpuRay {
            origin: [0.0, 0.0, 0.0],
            t_min: 0.0,
            direction: [9.0 * rng.unit_f32() - 4.5, 3.0 * rng.unit_f32() - 1.5, 7.0],
            t_max: 100.0,
        })
        .collect()
}

pub fn refit_and_rebuild_in_place_trace_the_deformed_mesh() {
    let h = headless("refit_and_rebuild_in_place_trace_the_deformed_mesh");
    let ctx = h.context();
    let base = Mesh::bumpy_grid(12);
    let mut gpu = GpuMesh::new(&h, base.clone());
    let cube = GpuMesh::new(&h, Mesh::quad());
    let updatable = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE
        | vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE;
    let pool = AccelerationStructurePool::new(ctx, 1 << 20).unwrap();
    let mut scratch = ScratchBuffer::new(ctx);
    let mut one_shot = OneShot::new(ctx).unwrap();
    let mut batch = BlasBatch::new();
    batch.push(&[gpu.geometry()], updatable).unwrap();
    batch
        .push(
            &[cube.geometry()],
            vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
        )
        .unwrap();
    let built = one_shot
        .run(|rec| batch.record_pooled(rec, &mut scratch, &pool))
        .unwrap();
    let (blas, fixed) = (&built.blases[0], &built.blases[1]);
    let address = blas.device_address();

    // Refusals: no ALLOW_UPDATE, other counts, the same BLAS twice.
    let mut bad = BlasBatch::new();
    let err = bad
        .push_update(fixed, &[cube.geometry()], BlasUpdateMode::Refit)
        .unwrap_err();
    assert!(matches!(err, VkError::InvalidArgument(_)), "{err}");
    let other = GpuMesh::new(&h, Mesh::bumpy_grid(11));
    let err = bad
        .push_update(blas, &[other.geometry()], BlasUpdateMode::Refit)
        .unwrap_err();
    assert!(matches!(err, VkError::InvalidArgument(_)), "{err}");
    bad.push_update(blas, &[gpu.geometry()], BlasUpdateMode::Refit)
        .unwrap();
    let err = bad
        .push_update(blas, &[gpu.geometry()], BlasUpdateMode::Rebuild)
        .unwrap_err();
    assert!(matches!(err, VkError::InvalidArgument(_)), "{err}");
    drop(bad);

    let pipeline = TestTracer::preferred(&h, &CountingBoxConfig::default());
    let rays = rays();
    let trace_with = |mesh: &Mesh| {
        let scene = scene_of(mesh);
        let records: Vec<_> = scene.iter().map(|i| tlas_record(i, blas, 0x01)).collect();
        let (_tlas, out) = trace(&h, &pipeline, &records, 2, &rays, 0xFF, 64);
        (scene, out)
    };

    // Before any update the BLAS holds the base mesh.
    let (scene0, out0) = trace_with(&base);
    let (compared, hits) = compare_with_cpu(&scene0, &rays, &out0.hits);
    assert!(compared >= rays.len() * 9 / 10 && hits >= rays.len() / 3);

    for (step, mode) in [
        (1, BlasUpdateMode::Refit),
        (2, BlasUpdateMode::Refit),
        (3, BlasUpdateMode::Rebuild),
    ] {
        let mesh = deformed(&base, 0.45, step as f32);
        gpu.vertices.write(0, &mesh.vertices).unwrap();
        let mut batch = BlasBatch::new();
        // A new build in the same batch as the update.
        batch
            .push(
                &[cube.geometry()],
                vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
            )
            .unwrap();
        assert_eq!(batch.push_update(blas, &[gpu.geometry()], mode).unwrap(), 0);
        assert_eq!((batch.len(), batch.update_count()), (1, 1));
        let out = one_shot
            .run(|rec| batch.record_pooled(rec, &mut scratch, &pool))
            .unwrap();
        assert_eq!(out.blases.len(), 1, "updates create no BLAS");
        assert_eq!(out.scratch_offsets.len(), 2);
        assert_eq!(blas.device_address(), address, "updated in place");

        let (scene, traced) = trace_with(&mesh);
        let (compared, hits) = compare_with_cpu(&scene, &rays, &traced.hits);
        assert!(
            compared >= rays.len() * 9 / 10,
            "{mode:?}: only {compared} rays compared"
        );
        assert!(hits >= rays.len() / 3, "{mode:?}: only {hits} hits");
        // The deformation is visible: many hit distances moved away from
        // where the base mesh would put them.
        let moved = rays
            .iter()
            .zip(&traced.hits)
            .filter(|(ray, hit)| {
                hit.is_hit()
                    && cpu_trace(&scene0, ray)
                        .is_some_and(|c| (c.t - f64::from(hit.t)).abs() > 0.05)
            })
            .count();
        assert!(moved >= rays.len() / 4, "{mode:?}: only {moved} rays moved");
    }
    drop((built, pipeline));
    assert_no_validation_errors(&h);
}
