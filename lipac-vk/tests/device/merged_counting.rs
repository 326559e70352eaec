//! Adaptive hitboxes in the GPU tracer: `trace_merged.comp` (the counting
//! include resolving merged boxes to their leaf boxes) traced against the
//! TLAS with merged boxes counts per hitbox what a CPU slab reference counts
//! with one box per hitbox (as `trace_counting.comp` does against the
//! leaf-only TLAS), and finds the same real hits as the leaf-only trace.

use crate::common::*;
use ash::vk;
use glam::{Affine3A, Quat, Vec3};
use lipac_core::assembly::{assemble_tlas_adaptive, AssemblyConfig};
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::hitbox_tree::{AdaptiveHitboxes, HitboxTree};
use lipac_core::layout::{
    hitbox_bits, instance_bits, HitboxRecord, InstanceArrays, InstanceRecord, InstanceState,
    TlasInstance,
};
use lipac_core::math::Aabb;
use lipac_test_support::{Rng64, SplitMix64};
use lipac_vk::{
    hitbox_bounds, Buffer, CountingBoxConfig, GpuHit, GpuRay, MemoryLocation, MergedBoxes, OneShot,
};

const STORAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::STORAGE_BUFFER;

fn hits_of(records: &[HitboxRecord]) -> Vec<u32> {
    records.iter().map(HitboxRecord::hits).collect()
}

pub fn merged_boxes_count_on_the_gpu_what_leaf_boxes_count() {
    let h = headless("merged_boxes_count_on_the_gpu_what_leaf_boxes_count");
    let ctx = h.context();
    let counting = CountingBoxConfig::default();
    let mut one_shot = OneShot::new(ctx).unwrap();
    let QuadAndCube { built, .. } = quad_and_cube(&h, &mut one_shot);
    let (quad_blas, cube_blas) = (&built.blases[0], &built.blases[1]);
    let cfg = AssemblyConfig::new(cube_blas.device_address());
    assert_eq!(
        (
            cfg.omitted_box_sbt_offset,
            cfg.hitbox_sbt_offset,
            cfg.counting_mask
        ),
        (
            counting.omitted_box_sbt_offset,
            counting.hitbox_box_sbt_offset,
            counting.counting_mask
        )
    );

    let (nx, nz) = (20u32, 16u32);
    let grid = HitboxGrid::new(GridConfig {
        min: [-80.0, -64.0],
        max: [80.0, 64.0],
        cell_size: 8.0,
    })
    .unwrap();
    let tree = HitboxTree::new(nx, nz, AdaptiveHitboxes::with_levels(2)).unwrap();
    let mut rng = SplitMix64::new(0x6E7);
    let instances: InstanceArrays = (0..500)
        .map(|_| {
            let (x, z) = (rng.range_f32(-79.0, 79.0), rng.range_f32(-63.0, 63.0));
            let w = rng.range_f32(0.3, 2.5);
            let aabb = Aabb::new(
                Vec3::new(x - w, -2.0, z - w),
                Vec3::new(x + w, rng.range_f32(-1.5, 12.0), z + w),
            );
            let mut m = InstanceRecord {
                aabb_min: aabb.min.to_array(),
                aabb_max: aabb.max.to_array(),
                hitbox: grid.hitbox_of(&aabb).unwrap(),
                packed: instance_bits::ALIVE,
                ..Default::default()
            };
            m.set_state(InstanceState::Inactive);
            m
        })
        .collect();
    let mut hitboxes = vec![HitboxRecord::default(); grid.len() as usize];
    for (k, hb) in hitboxes.iter_mut().enumerate() {
        let (cx, cz) = (k as u32 % nx, k as u32 / nx);
        if (cx < 5 && cz < 4) || rng.below_u32(25) == 0 {
            hb.packed |= hitbox_bits::ACTIVE;
        }
    }
    // The extents are the CPU's (uploaded with the records on a backend).
    lipac_core::hitbox_extents::write_extents(&instances, &mut hitboxes);
    let mut leaf_hb = hitboxes.clone();
    let (mut leaf_records, mut merged_records) = (Vec::new(), Vec::new());
    assemble_tlas_adaptive(
        &instances,
        &mut leaf_hb,
        &grid,
        &cfg,
        None,
        &mut leaf_records,
    )
    .unwrap();
    let stats = assemble_tlas_adaptive(
        &instances,
        &mut hitboxes,
        &grid,
        &cfg,
        Some(&tree),
        &mut merged_records,
    )
    .unwrap();
    assert_eq!(leaf_hb, hitboxes);
    assert!(stats.merged_boxes > 5, "{stats:?}");
    assert!(merged_records.len() * 2 < leaf_records.len());
    // A ground quad at y = -1 (inside the boxes, which reach down to -2):
    // real hits inside merged boxes.
    let ground = SceneInstance {
        mesh: Mesh::quad(),
        transform: Affine3A::from_scale_rotation_translation(
            Vec3::new(70.0, 50.0, 1.0),
            Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2),
            Vec3::new(0.0, -1.0, 0.0),
        ),
        custom_index: 7,
        sbt_offset: 0,
        active: true,
    };
    for r in [&mut leaf_records, &mut merged_records] {
        r.push(tlas_record(&ground, quad_blas, 0x01));
    }

    let rays: Vec<GpuRay> = (0..6000)
        .map(|_| {
            let o = Vec3::new(
                rng.range_f32(-120.0, 120.0),
                rng.range_f32(1.0, 60.0),
                rng.range_f32(-100.0, 100.0),
            );
            let target = Vec3::new(
                rng.range_f32(-80.0, 80.0),
                rng.range_f32(-3.0, 12.0),
                rng.range_f32(-64.0, 64.0),
            );
            GpuRay {
                origin: o.to_array(),
                t_min: 0.0,
                direction: (target - o).normalize().to_array(),
                t_max: 1000.0,
            }
        })
        .collect();
    let host = MemoryLocation::GpuToCpu;
    let ray_buf = Buffer::with_data(ctx, STORAGE, host, &rays).unwrap();
    let bounds = Buffer::with_data(ctx, STORAGE, host, &hitbox_bounds(&grid)).unwrap();
    let run = |records: &[TlasInstance], merged: bool, path| -> (Vec<GpuHit>, Vec<u32>) {
        let (tlas, _inputs) = build_tlas(&h, records);
        let results = Buffer::new(ctx, (rays.len() * 16) as u64, STORAGE, host).unwrap();
        let instance_hits = Buffer::with_data(ctx, STORAGE, host, &[0u32; 8]).unwrap();
        let hitbox_buf = Buffer::with_data(ctx, STORAGE, host, &hitboxes).unwrap();
        let boxes = if merged {
            MergedBoxes::new(Some(&tree), &cfg)
        } else {
            MergedBoxes::OFF
        };
        TestTracer::new(&h, &counting, path).run(
            &h,
            &tlas,
            &ray_buf,
            rays.len() as u32,
            &results,
            &instance_hits,
            &hitbox_buf,
            &bounds,
            &boxes,
            0xFF,
            0,
        );
        let hits: Vec<GpuHit> = results.read(0, rays.len()).unwrap();
        let records: Vec<HitboxRecord> = hitbox_buf.read(0, hitboxes.len()).unwrap();
        (hits, hits_of(&records))
    };
    // Every path the device has gives the same hits and counts, bit for bit.
    let mut outcomes = paths(&h)
        .into_iter()
        .map(|p| (run(&leaf_records, false, p), run(&merged_records, true, p)));
    let ((leaf_hits, leaf_counts), (merged_hits, merged_counts)) = outcomes.next().unwrap();
    for ((lh, lc), (mh, mc)) in outcomes {
        let bits = |v: &[GpuHit]| bytemuck::cast_slice::<GpuHit, u32>(v).to_vec();
        assert!(
            bits(&lh) == bits(&leaf_hits),
            "leaf-only hits differ between paths"
        );
        assert_eq!(lc, leaf_counts, "leaf-only counts differ between paths");
        assert!(
            bits(&mh) == bits(&merged_hits),
            "merged hits differ between paths"
        );
        assert_eq!(mc, merged_counts, "merged counts differ between paths");
    }

    // The same real hits, ray by ray (the ground, or nothing).
    let mut real = 0;
    for (i, (a, b)) in leaf_hits.iter().zip(&merged_hits).enumerate() {
        assert_eq!(a.is_hit(), b.is_hit(), "ray {i}: {a:?} / {b:?}");
        if a.is_hit() {
            real += 1;
            assert_eq!(a.custom_index, b.custom_index, "ray {i}");
            assert!(
                (a.t - b.t).abs() <= 1e-3 * a.t.max(1.0),
                "ray {i}: {a:?} / {b:?}"
            );
        }
    }
    assert!(real > 1000, "{real} real hits");
    // CPU: the nearest leaf box (slab, f64) before the real hit.
    let leaf_boxes: Vec<(u32, [f64; 3], [f64; 3])> = leaf_records
        .iter()
        .filter(|r| r.sbt_offset() == cfg.hitbox_sbt_offset)
        .map(|r| {
            let t = r.transform;
            let lo = [t[3], t[7], t[11]];
            let hi = [t[3] + t[0], t[7] + t[5], t[11] + t[10]];
            (r.custom_index(), lo.map(f64::from), hi.map(f64::from))
        })
        .collect();
    let mut cpu_counts = vec![0u32; hitboxes.len()];
    for (ray, hit) in rays.iter().zip(&leaf_hits) {
        let t_real = if hit.is_hit() {
            f64::from(hit.t)
        } else {
            f64::INFINITY
        };
        let mut best: Option<(f64, u32)> = None;
        for (i, lo, hi) in &leaf_boxes {
            let (mut tn, mut tf) = (0.0f64, f64::from(ray.t_max));
            for a in 0..3 {
                let (o, d) = (f64::from(ray.origin[a]), f64::from(ray.direction[a]));
                let (t0, t1) = ((lo[a] - o) / d, (hi[a] - o) / d);
                tn = tn.max(t0.min(t1));
                tf = tf.min(t0.max(t1));
            }
            if tn <= tf && best.is_none_or(|b| tn < b.0) {
                best = Some((tn, *i));
            }
        }
        if let Some((t, i)) = best {
            if t <= t_real {
                cpu_counts[i as usize] += 1;
            }
        }
    }
    let d = |a: &[u32], b: &[u32]| -> u32 { a.iter().zip(b).map(|(x, y)| x.abs_diff(*y)).sum() };
    // The same counts per hitbox, up to rays that graze a box edge or face
    // (the hardware tests the leaf-only boxes' triangles, the include and
    // the reference slabs; the include pads flat boxes itself).
    let total: u32 = cpu_counts.iter().sum();
    assert!(total > 1500, "only {total} box hits");
    let (leaf_diff, merged_diff) = (d(&leaf_counts, &cpu_counts), d(&merged_counts, &cpu_counts));
    eprintln!(
        "{total} box hits in the CPU reference; moved: leaf-only TLAS {leaf_diff}, merged TLAS \
         {merged_diff}"
    );
    assert!(
        leaf_diff * 100 <= total,
        "leaf-only TLAS: {leaf_diff} of {total} hits moved"
    );
    assert!(
        merged_diff * 100 <= total,
        "merged TLAS: {merged_diff} of {total} hits moved (leaf-only: {leaf_diff})\n\
         reference {cpu_counts:?}\nmerged {merged_counts:?}"
    );
    assert_no_validation_errors(&h);
}
