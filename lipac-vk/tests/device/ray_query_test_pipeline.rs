//! Rays traced on the device hit the instance and distance a CPU reference
//! computes, through a TLAS that grew and holds an inactive record.

use crate::common::*;
use ash::vk;
use glam::{Affine3A, Quat, Vec3};
use lipac_test_support::{Rng64, SplitMix64};
use lipac_vk::{CountingBoxConfig, GpuRay};

fn scene() -> Vec<SceneInstance> {
    let inst = |mesh: Mesh, transform, custom_index, active| SceneInstance {
        mesh,
        transform,
        custom_index,
        sbt_offset: 0,
        active,
    };
    vec![
        inst(
            Mesh::quad(),
            Affine3A::from_translation(Vec3::new(0.0, 0.0, 5.0)),
            10,
            true,
        ),
        inst(
            Mesh::quad(),
            Affine3A::from_scale_rotation_translation(
                Vec3::splat(2.0),
                Quat::from_rotation_y(std::f32::consts::FRAC_PI_2),
                Vec3::new(5.0, 0.0, 0.0),
            ),
            11,
            true,
        ),
        inst(
            Mesh::bumpy_grid(8),
            Affine3A::from_scale_rotation_translation(
                Vec3::splat(3.0),
                Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2),
                Vec3::new(0.0, -4.0, 0.0),
            ),
            12,
            true,
        ),
        inst(
            Mesh::bumpy_grid(8),
            Affine3A::from_scale_rotation_translation(
                Vec3::new(1.0, 2.0, 1.0),
                Quat::from_rotation_z(0.5) * Quat::from_rotation_y(1.2),
                Vec3::new(-6.0, 1.0, 1.0),
            ),
            13,
            true,
        ),
        // Inactive (reference 0): would hide most of instance 10 if it were hit.
        inst(
            Mesh::quad(),
            Affine3A::from_scale_rotation_translation(
                Vec3::splat(3.0),
                Quat::IDENTITY,
                Vec3::new(0.0, 0.0, 2.0),
            ),
            14,
            false,
        ),
    ]
}

pub fn traced_rays_hit_the_right_instance_at_the_right_distance() {
    let h = headless("traced_rays_hit_the_right_instance_at_the_right_distance");
    let _ctx = h.context();
    let scene = scene();
    let quad = GpuMesh::new(&h, Mesh::quad());
    let grid = GpuMesh::new(&h, Mesh::bumpy_grid(8));
    let blases = build_blases(
        &h,
        &[&quad, &grid],
        vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
    );
    assert_eq!(blases[0].triangle_count(), 2);
    assert_eq!(blases[1].triangle_count(), 128);
    let records: Vec<_> = scene
        .iter()
        .map(|i| {
            let blas = if i.mesh.indices.len() == 6 {
                &blases[0]
            } else {
                &blases[1]
            };
            tlas_record(i, blas, 0x01)
        })
        .collect();

    // Rays from near the origin aimed at random points around each instance.
    let mut rng = SplitMix64::new(7);
    let mut rays = Vec::new();
    for k in 0..320 {
        let inst = &scene[k % scene.len()];
        let local = Vec3::new(2.4 * rng.unit_f32() - 1.2, 2.4 * rng.unit_f32() - 1.2, 0.0);
        let target = inst.transform.transform_point3(local);
        let origin = Vec3::new(
            rng.unit_f32() - 0.5,
            rng.unit_f32() - 0.5,
            rng.unit_f32() - 0.5,
        ) * 0.5;
        rays.push(GpuRay {
            origin: origin.into(),
            t_min: 0.0,
            direction: (target - origin).into(),
            t_max: 1.0e3,
        });
    }

    let pipeline = TestTracer::preferred(&h, &CountingBoxConfig::default());
    // Capacity 3 for 5 records: the TLAS grows to max(5, 2 * 3) = 6.
    let (tlas, out) = trace(&h, &pipeline, &records, 3, &rays, 0xFF, 16);
    assert_eq!(tlas.capacity(), 6);
    assert_eq!(tlas.built_count(), 5);

    let (compared, hits) = compare_with_cpu(&scene, &rays, &out.hits);
    assert!(
        compared >= rays.len() * 9 / 10,
        "only {compared} rays unambiguous"
    );
    assert!(
        hits >= rays.len() / 2,
        "only {hits} hits: the scene setup is off"
    );
    // Every instance is hit at least once, and the inactive one never.
    for c in 10..=13 {
        assert!(
            out.hits.iter().any(|g| g.is_hit() && g.custom_index == c),
            "instance {c} never hit"
        );
    }
    assert!(out.hits.iter().all(|g| g.custom_index != 14));
    // Committed real hits are counted per custom index (LIPAC_COUNT_COMMITTED_HITS).
    for c in 10..=14u32 {
        let n = out
            .hits
            .iter()
            .filter(|g| g.is_hit() && g.custom_index == c)
            .count() as u32;
        assert_eq!(out.instance_hits[c as usize], n, "counter of instance {c}");
    }
    assert!(out.hits.iter().all(|g| !g.counted_box()));
    assert!(out.hitbox_hits.iter().all(|&n| n == 0));
    drop((tlas, pipeline, blases, quad, grid));
    assert_no_validation_errors(&h);
}
