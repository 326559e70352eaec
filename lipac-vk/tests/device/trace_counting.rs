//! `trace_counting.comp` counts hitbox boxes straight into the hitbox
//! records (saturating 24-bit, like `HitboxRecord::add_hits`) and instance
//! boxes and real hits into the per-slot `u32` counters, as a CPU
//! computation of the nearest box before the closest real hit says.

use crate::common::*;
use ash::vk;
use glam::{Affine3A, Quat, Vec3};
use lipac_core::layout::{hitbox_bits, HitboxRecord, TlasInstance};
use lipac_test_support::{Rng64, SplitMix64};
use lipac_vk::{
    counting_box_instance, Buffer, CountingBoxConfig, CountingBoxKind, GpuHit, GpuRay, GpuTlas,
    MemoryLocation, MergedBoxes, OneShot,
};

const MAX: u32 = hitbox_bits::HITS_MAX;
const HITBOXES: usize = 8;
const SLOTS: usize = 8;

fn lane_x(k: u32) -> f32 {
    10.0 * k as f32
}

/// A counting box across lane `k` from `z0` to `z1`.
struct CpuBox {
    min: [f32; 3],
    max: [f32; 3],
    kind: CountingBoxKind,
    index: u32,
}

/// Entry distance of a ray into an AABB (slab test), clamped to `t_min`.
fn slab(ray: &GpuRay, b: &CpuBox) -> Option<f64> {
    let (mut lo, mut hi) = (f64::from(ray.t_min), f64::from(ray.t_max));
    for a in 0..3 {
        let (o, d) = (f64::from(ray.origin[a]), f64::from(ray.direction[a]));
        let (bmin, bmax) = (f64::from(b.min[a]), f64::from(b.max[a]));
        if d == 0.0 {
            if o < bmin || o > bmax {
                return None;
            }
            continue;
        }
        let (t0, t1) = ((bmin - o) / d, (bmax - o) / d);
        lo = lo.max(t0.min(t1));
        hi = hi.min(t0.max(t1));
    }
    (lo <= hi).then_some(lo)
}

pub fn trace_counts_into_hitbox_records_saturating() {
    let h = headless("trace_counts_into_hitbox_records_saturating");
    let ctx = h.context();
    let cfg = CountingBoxConfig {
        omitted_box_sbt_offset: 3,
        hitbox_box_sbt_offset: 5,
        counting_mask: 0x80,
    };
    let mut one_shot = OneShot::new(ctx).unwrap();
    let QuadAndCube {
        quad,
        cube,
        built,
        mut scratch,
    } = quad_and_cube(&h, &mut one_shot);
    let flags = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE;
    let (quad_blas, cube_blas) = (&built.blases[0], &built.blases[1]);

    use CountingBoxKind::{Hitbox, OmittedInstance};
    let lane_box = |k: u32, z0: f32, z1: f32, kind, index| CpuBox {
        min: [lane_x(k) - 0.5, -0.5, z0],
        max: [lane_x(k) + 0.5, 0.5, z1],
        kind,
        index,
    };
    let boxes = [
        // Lane 0: hitbox 0 alone, starting 3 below saturation.
        lane_box(0, 2.0, 3.0, Hitbox, 0),
        // Lane 1: hitbox 2 (already saturated) before hitbox 1: only 2 counts.
        lane_box(1, 2.0, 3.0, Hitbox, 2),
        lane_box(1, 4.0, 5.0, Hitbox, 1),
        // Lane 2: a real quad (slot 4) at z 2 hides hitbox 3.
        lane_box(2, 4.0, 5.0, Hitbox, 3),
        // Lane 3: omitted slot 5 before hitbox 4: the instance counts.
        lane_box(3, 2.0, 3.0, OmittedInstance, 5),
        lane_box(3, 4.0, 5.0, Hitbox, 4),
        // Lane 4: hitbox 5 far from saturation, full low byte.
        lane_box(4, 2.0, 3.0, Hitbox, 5),
    ];
    let scene = vec![SceneInstance {
        mesh: Mesh::quad(),
        transform: Affine3A::from_scale_rotation_translation(
            Vec3::splat(0.5),
            Quat::IDENTITY,
            Vec3::new(lane_x(2), 0.0, 2.0),
        ),
        custom_index: 4,
        sbt_offset: 0,
        active: true,
    }];
    let mut records: Vec<TlasInstance> = boxes
        .iter()
        .map(|b| {
            counting_box_instance(
                b.min,
                b.max,
                b.kind,
                b.index,
                &cfg,
                cube_blas.device_address(),
            )
            .unwrap()
        })
        .collect();
    records.push(tlas_record(&scene[0], quad_blas, 0x01));

    // Rays per lane: 8, 5, 4, 6, 7, spread over the boxes' cross-section.
    let per_lane = [8u32, 5, 4, 6, 7];
    let mut rng = SplitMix64::new(7);
    let mut rays = Vec::new();
    for (k, &n) in per_lane.iter().enumerate() {
        for _ in 0..n {
            rays.push(GpuRay {
                origin: [
                    lane_x(k as u32) + 0.6 * (rng.unit_f32() - 0.5),
                    0.6 * (rng.unit_f32() - 0.5),
                    0.0,
                ],
                t_min: 0.0,
                direction: [0.0, 0.0, 1.0],
                t_max: 100.0,
            });
        }
    }

    // Initial hitbox records: near saturation, saturated, arbitrary low bytes.
    let record = |hits: u32, low: u32| HitboxRecord {
        min_y: -1.0,
        max_y: 2.0,
        packed: (hits << hitbox_bits::HITS_SHIFT) | low,
        rate: 0x1234_5678,
        cost: 0x0009_0007,
    };
    let mut initial = vec![record(0, 0); HITBOXES];
    initial[0] = record(MAX - 3, 0xAB);
    initial[1] = record(5, 0x01);
    initial[2] = record(MAX, 0x7E);
    initial[3] = record(9, 0x00);
    initial[4] = record(MAX - 1, 0x03);
    initial[5] = record(100, 0xFF);

    // CPU: each ray counts the nearest box before its closest real hit.
    let mut want_hitboxes = initial.clone();
    let mut want_instances = vec![0u32; SLOTS];
    for ray in &rays {
        let real = cpu_trace(&scene, ray);
        assert!(real.is_none_or(|c| !c.ambiguous), "{ray:?}");
        let nearest = boxes
            .iter()
            .filter_map(|b| slab(ray, b).map(|t| (t, b)))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        if let Some((t, b)) = nearest {
            if real.is_none_or(|c| t <= c.t) {
                match b.kind {
                    Hitbox => want_hitboxes[b.index as usize].add_hits(1),
                    OmittedInstance => want_instances[b.index as usize] += 1,
                }
            }
        }
        if let Some(c) = real {
            want_instances[c.custom_index as usize] += 1;
        }
    }
    // The independent expectations the CPU computation must agree with.
    assert_eq!(want_hitboxes[0].hits(), MAX);
    assert_eq!(want_hitboxes[5].hits(), 107);
    assert_eq!((want_instances[4], want_instances[5]), (4, 6));

    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let instances =
        Buffer::with_data(ctx, BUILD_INPUT, MemoryLocation::CpuToGpu, &records).unwrap();
    let ray_buf = Buffer::with_data(ctx, storage, MemoryLocation::CpuToGpu, &rays).unwrap();
    let bounds = Buffer::with_data(
        ctx,
        storage,
        MemoryLocation::CpuToGpu,
        &[[0f32; 4]; HITBOXES],
    )
    .unwrap();
    let mut tlas = GpuTlas::new(ctx, 16, flags).unwrap();
    let _retired = one_shot
        .run(|rec| tlas.record_build(rec, &instances, 0, records.len() as u32, &mut scratch))
        .unwrap();
    // The same counts on every tracing path the device has (ray queries:
    // trace_counting.comp; pipelines: pipeline_trace.rgen and its hit groups).
    for path in paths(&h) {
        let pipeline = TestTracer::new(&h, &cfg, path);
        let results = Buffer::new(
            ctx,
            (rays.len() * 16) as u64,
            storage,
            MemoryLocation::GpuToCpu,
        )
        .unwrap();
        let instance_hits =
            Buffer::with_data(ctx, storage, MemoryLocation::GpuToCpu, &[0u32; SLOTS]).unwrap();
        let hitboxes = Buffer::with_data(ctx, storage, MemoryLocation::GpuToCpu, &initial).unwrap();
        let run = || {
            pipeline.run(
                &h,
                &tlas,
                &ray_buf,
                rays.len() as u32,
                &results,
                &instance_hits,
                &hitboxes,
                &bounds,
                &MergedBoxes::OFF,
                0xFF,
                0,
            )
        };
        run();
        let hits: Vec<GpuHit> = results.read(0, rays.len()).unwrap();
        let (compared, n_hits) = compare_with_cpu(&scene, &rays, &hits);
        assert_eq!((compared, n_hits), (rays.len(), 4), "{path:?}");
        let got_hitboxes: Vec<HitboxRecord> = hitboxes.read(0, HITBOXES).unwrap();
        for (i, (got, want)) in got_hitboxes.iter().zip(&want_hitboxes).enumerate() {
            assert_eq!(
                bytemuck::bytes_of(got),
                bytemuck::bytes_of(want),
                "{path:?}: hitbox {i}: {got:?} vs {want:?}"
            );
        }
        let got_instances: Vec<u32> = instance_hits.read(0, SLOTS).unwrap();
        assert_eq!(got_instances, want_instances, "{path:?}");

        // A second trace of the same rays: every touched count saturates or
        // grows by the same amounts again.
        run();
        let again: Vec<HitboxRecord> = hitboxes.read(0, HITBOXES).unwrap();
        for (i, (got, (first, init))) in again
            .iter()
            .zip(want_hitboxes.iter().zip(&initial))
            .enumerate()
        {
            let mut want = *first;
            want.add_hits(first.hits() - init.hits());
            assert_eq!(
                got.packed, want.packed,
                "{path:?}: hitbox {i}, second trace"
            );
        }
        assert_eq!(again[5].hits(), 114);
    }
    drop((tlas, built, cube, quad));
    assert_no_validation_errors(&h);
}
