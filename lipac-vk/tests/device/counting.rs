//! Counting boxes pass rays through: a ray counts at most one box, the
//! nearest, and only when it lies before the closest real hit.

use crate::common::*;
use glam::{Affine3A, Vec3};
use lipac_core::layout::{TlasInstance, VK_INSTANCE_CULL_DISABLE, VK_INSTANCE_FORCE_OPAQUE};
use lipac_vk::{counting_box_instance, CountingBoxConfig, CountingBoxKind, GpuRay, OneShot};

const REAL_MASK: u8 = 0x01;

/// Lane `k` runs along +z at x = 10 k.
fn lane_x(k: u32) -> f32 {
    10.0 * k as f32
}

fn lane_box(k: u32, z0: f32, z1: f32) -> ([f32; 3], [f32; 3]) {
    ([lane_x(k) - 0.5, -0.5, z0], [lane_x(k) + 0.5, 0.5, z1])
}

pub fn counting_boxes_count_once_and_let_rays_through() {
    let h = headless("counting_boxes_count_once_and_let_rays_through");
    let ctx = h.context();
    let cfg = CountingBoxConfig {
        omitted_box_sbt_offset: 3,
        hitbox_box_sbt_offset: 5,
        counting_mask: 0x80,
    };

    let QuadAndCube {
        quad, cube, built, ..
    } = quad_and_cube(&h, &mut OneShot::new(ctx).unwrap());
    let (quad_blas, cube_blas) = (&built.blases[0], &built.blases[1]);
    assert!(built.compaction.is_none());

    let mut scene = Vec::new();
    let mut records: Vec<TlasInstance> = Vec::new();
    let mut real = |k: u32, z: f32, custom_index: u32, records: &mut Vec<TlasInstance>| {
        let inst = SceneInstance {
            mesh: Mesh::quad(),
            transform: Affine3A::from_scale_rotation_translation(
                Vec3::splat(0.5),
                glam::Quat::IDENTITY,
                Vec3::new(lane_x(k), 0.0, z),
            ),
            custom_index,
            sbt_offset: 0,
            active: true,
        };
        records.push(tlas_record(&inst, quad_blas, REAL_MASK));
        scene.push(inst);
    };
    let boxed = |k: u32, z0: f32, z1: f32, kind, index: u32, records: &mut Vec<TlasInstance>| {
        let (min, max) = lane_box(k, z0, z1);
        records.push(
            counting_box_instance(min, max, kind, index, &cfg, cube_blas.device_address()).unwrap(),
        );
    };
    use CountingBoxKind::{Hitbox, OmittedInstance};
    // Lane 0: omitted box (slot 5) at z 2..3, then a real quad (slot 3) at z 5.
    boxed(0, 2.0, 3.0, OmittedInstance, 5, &mut records);
    real(0, 5.0, 3, &mut records);
    // Lane 1: hitboxes 7 (z 2..3) and 8 (z 4..5), nothing real: only 7 counts.
    boxed(1, 4.0, 5.0, Hitbox, 8, &mut records);
    boxed(1, 2.0, 3.0, Hitbox, 7, &mut records);
    // Lane 2: real quad (slot 4) at z 2 before hitbox 9 at z 4..5: no count.
    real(2, 2.0, 4, &mut records);
    boxed(2, 4.0, 5.0, Hitbox, 9, &mut records);
    // Lane 3: an opaque box (hitbox 10, z 2..3) and a non-opaque one
    // (hitbox 11, z 3.5..4), then a real quad (slot 6) at z 6: 10 counts,
    // the ray continues past it and hits the quad.
    boxed(3, 2.0, 3.0, Hitbox, 10, &mut records);
    if let Some(last) = records.last_mut() {
        let flags = VK_INSTANCE_CULL_DISABLE | VK_INSTANCE_FORCE_OPAQUE;
        last.sbt_offset_and_flags =
            (last.sbt_offset_and_flags & 0x00FF_FFFF) | (u32::from(flags) << 24);
    }
    boxed(3, 3.5, 4.0, Hitbox, 11, &mut records);
    real(3, 6.0, 6, &mut records);
    // Lane 4: the ray starts inside hitbox 12 (z -1..1): it counts.
    boxed(4, -1.0, 1.0, Hitbox, 12, &mut records);

    let ray = |k: u32| GpuRay {
        origin: [lane_x(k), 0.1, 0.0],
        t_min: 0.0,
        direction: [0.0, 0.0, 1.0],
        t_max: 100.0,
    };
    let rays: Vec<GpuRay> = (0..5).map(ray).collect();
    // The same counts on every tracing path the device has.
    for path in paths(&h) {
        let pipeline = TestTracer::new(&h, &cfg, path);

        let (tlas, out) = trace(&h, &pipeline, &records, 4, &rays, 0xFF, 16);
        let hits = &out.hits;
        // Real hits are the CPU reference's (boxes are not geometry).
        let (compared, n_hits) = compare_with_cpu(&scene, &rays, hits);
        assert_eq!((compared, n_hits), (5, 3), "{path:?}");
        assert_eq!((hits[0].custom_index, hits[0].t), (3, 5.0));
        assert_eq!(hits[0].sbt_offset, 0);
        assert!(hits[0].counted_box());
        assert!(!hits[1].is_hit() && hits[1].counted_box());
        assert_eq!((hits[2].custom_index, hits[2].t), (4, 2.0));
        assert!(!hits[2].counted_box());
        assert_eq!((hits[3].custom_index, hits[3].t), (6, 6.0));
        assert!(hits[3].counted_box());
        assert!(!hits[4].is_hit() && hits[4].counted_box());

        let mut want_instance = vec![0u32; 16];
        want_instance[5] = 1; // omitted box of lane 0
        want_instance[3] = 1; // real hits (committed hits are counted too)
        want_instance[4] = 1;
        want_instance[6] = 1;
        assert_eq!(out.instance_hits, want_instance);
        let mut want_hitbox = vec![0u32; 16];
        want_hitbox[7] = 1;
        want_hitbox[10] = 1;
        want_hitbox[12] = 1;
        assert_eq!(out.hitbox_hits, want_hitbox);
        drop(tlas);

        // The same rays with the counting bit outside the cull mask count nothing
        // and hit the same real geometry.
        let (tlas, masked) = trace(&h, &pipeline, &records, 16, &rays, REAL_MASK, 16);
        assert!(masked.hitbox_hits.iter().all(|&n| n == 0));
        assert_eq!(masked.instance_hits.iter().sum::<u32>(), 3);
        for (a, b) in masked.hits.iter().zip(hits) {
            assert_eq!((a.custom_index, a.t), (b.custom_index, b.t));
            assert!(!a.counted_box());
        }
        drop((tlas, pipeline));
    }
    drop((built, cube, quad));
    assert_no_validation_errors(&h);
}
