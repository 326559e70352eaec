//! Adaptive hitboxes on the GPU: `AssemblyPipeline::record_adaptive`
//! (`assemble_merged.comp`) emits the same TLAS records, bit for bit (as a
//! multiset), and leaves the same hitbox records as the CPU reference
//! `assemble_tlas_adaptive`, on random frames with the option on.

use crate::common::*;
use ash::vk;
use glam::Vec3;
use lipac_core::assembly::{assemble_tlas_adaptive, AssemblyConfig};
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::hitbox_tree::{AdaptiveHitboxes, HitboxTree};
use lipac_core::layout::{
    hitbox_bits, instance_bits, HitboxRecord, InstanceRecord, InstanceState, TlasInstance,
};
use lipac_test_support::{Rng64, XorShift64Star as Rng};
use lipac_vk::{
    hitbox_bounds, AssemblyBuffers, AssemblyPipeline, Buffer, MemoryLocation, OneShot, VkError,
};

const STORAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::STORAGE_BUFFER;

fn random_instance(
    rng: &mut Rng,
    grid: &HitboxGrid,
    lo: [f32; 2],
    size: [f32; 2],
) -> InstanceRecord {
    let x = lo[0] + rng.unit_f32() * size[0];
    let z = lo[1] + rng.unit_f32() * size[1];
    let (w, h) = (rng.range_f32(0.0, 3.0), rng.range_f32(0.0, 40.0));
    let y0 = rng.range_f32(-5.0, 5.0);
    let mut aabb_min = [x - w, y0, z - w];
    let aabb_max = [x + w, if rng.chance(0.1) { y0 } else { y0 + h }, z + w];
    if rng.chance(0.01) {
        aabb_min[1] = f32::NAN;
    }
    let aabb = lipac_core::math::Aabb::new(Vec3::from_array(aabb_min), Vec3::from_array(aabb_max));
    let mut packed = rng.below_scaled(3);
    if rng.chance(0.95) {
        packed |= instance_bits::ALIVE;
    }
    if rng.chance(0.3) {
        packed |= instance_bits::UNIQUE_BLAS;
    }
    if rng.chance(0.05) {
        packed |= instance_bits::PINNED;
    }
    let mut m = InstanceRecord {
        transform: [1.0, 0.0, 0.0, x, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, z],
        aabb_min,
        hitbox: grid.hitbox_of(&aabb).unwrap_or(0),
        aabb_max,
        packed,
        blas: if rng.chance(0.2) {
            0
        } else {
            rng.next_u64() | 1
        },
        sbt_offset: rng.below_scaled(4),
        lod: 0,
    };
    if rng.chance(0.6) {
        m.set_state(InstanceState::Inactive);
    }
    m
}

pub fn merged_assembly_matches_cpu_reference() {
    let h = headless("merged_assembly_matches_cpu_reference");
    let ctx = h.context();
    let pipeline = AssemblyPipeline::new(ctx).unwrap();
    let mut one_shot = OneShot::new(ctx).unwrap();
    let host = MemoryLocation::GpuToCpu;
    let xfer = vk::BufferUsageFlags::TRANSFER_DST | vk::BufferUsageFlags::TRANSFER_SRC;
    // (seed, nx, nz, cell, origin, levels, active share in percent, min extent)
    let cases = [
        (
            1u64,
            37u32,
            29u32,
            16.0f64,
            [-300.0f64, 40.0f64],
            2u8,
            5u64,
            1e-3f32,
        ),
        (2, 64, 64, 16.0, [0.0, 0.0], 3, 0, 1e-3),
        (3, 21, 50, 3.3, [99_000.0, -100_200.0], 4, 20, 0.25),
        (4, 1, 40, 16.0, [-8.0, -8.0], 1, 10, 0.0),
        (5, 45, 33, 32.0, [-1.0e6, 1.0e6], 2, 50, 1e-3),
    ];
    for (seed, nx, nz, cell, origin, levels, active, min_extent) in cases {
        let what = format!("case {seed}: {nx} x {nz}, {levels} levels");
        let mut rng = Rng::from_seed(seed);
        let grid = HitboxGrid::new(GridConfig {
            min: origin,
            max: [
                origin[0] + cell * f64::from(nx),
                origin[1] + cell * f64::from(nz),
            ],
            cell_size: cell,
        })
        .unwrap();
        // (Rounding may add a cell: 21 x 3.3 m is 22 cells of 3.3 m.)
        let (nx, nz) = grid.dims();
        let tree = HitboxTree::for_index(&grid, AdaptiveHitboxes::with_levels(levels))
            .unwrap()
            .unwrap();
        let lo = [origin[0] as f32, origin[1] as f32];
        let size = [
            (cell * f64::from(nx)) as f32 * 0.999,
            (cell * f64::from(nz)) as f32 * 0.999,
        ];
        let instances: Vec<InstanceRecord> = (0..2500)
            .map(|_| random_instance(&mut rng, &grid, lo, size))
            .collect();
        // Active bits: scattered, plus an active corner block; stale heights
        // and hits that pass 0 must reset.
        let mut hitboxes: Vec<HitboxRecord> = (0..grid.len())
            .map(|k| {
                let (cx, cz) = (k % nx, k / nx);
                let mut h = HitboxRecord {
                    min_y: rng.range_f32(-3.0, 3.0),
                    max_y: rng.range_f32(-3.0, 3.0),
                    packed: rng.next_u32() & !hitbox_bits::ACTIVE,
                    rate: rng.next_u32(),
                    cost: rng.next_u32(),
                };
                if rng.chance_percent(active) || (cx < nx / 4 && cz < nz / 4 && active > 0) {
                    h.packed |= hitbox_bits::ACTIVE;
                }
                h
            })
            .collect();
        let cfg = AssemblyConfig {
            min_box_extent: min_extent,
            ..AssemblyConfig::new(rng.next_u64() | 1)
        };

        let tlas_capacity = instances.len() + hitboxes.len();
        let mut tlas_out =
            Buffer::new(ctx, (tlas_capacity * 64) as u64, STORAGE | xfer, host).unwrap();
        tlas_out
            .write(0, &vec![0xA5A5_A5A5u32; tlas_capacity * 16])
            .unwrap();
        let instances = lipac_core::layout::InstanceArrays::from_records(&instances);
        // The extents are the CPU's: computed here, uploaded with the records.
        lipac_core::hitbox_extents::write_extents(&instances, &mut hitboxes);
        let hot = Buffer::with_data(ctx, STORAGE, host, instances.hot()).unwrap();
        let slot_tlas = Buffer::with_data(ctx, STORAGE, host, instances.tlas()).unwrap();
        let slot_bounds = Buffer::with_data(ctx, STORAGE, host, instances.bounds()).unwrap();
        let hitbox_buf = Buffer::with_data(ctx, STORAGE, host, &hitboxes).unwrap();
        let bounds = Buffer::with_data(ctx, STORAGE, host, &hitbox_bounds(&grid)).unwrap();
        let counter = Buffer::with_data(ctx, STORAGE | xfer, host, &[7u32]).unwrap();
        let bindings = pipeline
            .bind(&AssemblyBuffers {
                instances: lipac_vk::InstanceBuffers {
                    hot: &hot,
                    tlas: &slot_tlas,
                    bounds: &slot_bounds,
                },
                hitboxes: &hitbox_buf,
                hitbox_bounds: &bounds,
                tlas_instances: &tlas_out,
                tlas_counter: &counter,
            })
            .unwrap();

        let mut cpu_out = Vec::new();
        let stats = assemble_tlas_adaptive(
            &instances,
            &mut hitboxes,
            &grid,
            &cfg,
            Some(&tree),
            &mut cpu_out,
        )
        .unwrap();
        assert!(stats.merged_boxes > 0, "{what}: nothing merged");
        if active > 0 {
            assert!(stats.hitbox_boxes > 0, "{what}: no leaf box");
        }

        // A tree of another grid is refused.
        let other = HitboxTree::new(nx + 1, nz, AdaptiveHitboxes::with_levels(levels)).unwrap();
        let e = one_shot.run(|rec| {
            pipeline.record_adaptive(rec, &bindings, &cfg, Some(&other), instances.len() as u32)
        });
        assert!(
            matches!(e, Err(VkError::InvalidArgument(_))),
            "{what}: {e:?}"
        );

        one_shot
            .run(|rec| {
                pipeline.record_adaptive(rec, &bindings, &cfg, Some(&tree), instances.len() as u32)
            })
            .unwrap();
        let n = counter.read::<u32>(0, 1).unwrap()[0] as usize;
        let all: Vec<TlasInstance> = tlas_out.read(0, tlas_capacity).unwrap();
        assert_eq!(n, cpu_out.len(), "{what}: counter");
        assert!(
            all[n..]
                .iter()
                .all(|r| bytemuck::bytes_of(r).iter().all(|&b| b == 0)),
            "{what}: records past the counter are zero"
        );
        assert_tlas_equal(all[..n].to_vec(), cpu_out, &what);
        let gpu_hitboxes: Vec<HitboxRecord> = hitbox_buf.read(0, hitboxes.len()).unwrap();
        assert!(
            bytemuck::cast_slice::<_, u8>(&gpu_hitboxes)
                == bytemuck::cast_slice::<_, u8>(&hitboxes),
            "{what}: hitbox records differ"
        );
    }
    assert_no_validation_errors(&h);
}
