//! Registry, grid, dirty-range and latency-mitigation costs at paper scale
//! (100k instances; the paper reports >100k instances per frame).

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use glam::camera::rh::{proj, view};
use glam::{Affine3A, Vec3};
use lipac_core::culling::{Culling, CullingConfig};
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::hitbox_index::HitboxIndex;
use lipac_core::instance::{InstanceDesc, MeshId};
use lipac_core::latency::{ActivationHeuristic, Frustum, LatencyMitigation};
use lipac_core::math::Aabb;
use lipac_core::registry::{InstanceRegistry, RegistryConfig};
use lipac_test_support::{Rng64, XorShift64};
use std::hint::black_box;
use std::time::Duration;

const N: u32 = 100_000;

/// Deterministic pseudo-random positions in the default 8 x 8 km world.
fn positions(n: u32) -> Vec<Vec3> {
    let mut s = XorShift64::new(0x9E37_79B9_7F4A_7C15);
    let mut next = || s.unit_f32();
    (0..n)
        .map(|_| Vec3::new(next() * 8000.0 - 4000.0, 0.0, next() * 8000.0 - 4000.0))
        .collect()
}

fn desc(p: Vec3, i: u32) -> InstanceDesc {
    let aabb = Aabb::new(p - Vec3::new(2.0, 0.0, 2.0), p + Vec3::new(2.0, 6.0, 2.0));
    InstanceDesc::new(MeshId(i % 64), Affine3A::from_translation(p), aabb)
}

fn filled(ps: &[Vec3]) -> InstanceRegistry {
    let grid = HitboxGrid::new(GridConfig::default()).unwrap();
    let mut r = InstanceRegistry::new(grid, RegistryConfig::default()).unwrap();
    for (i, &p) in (0u32..).zip(ps) {
        r.register(desc(p, i)).unwrap();
    }
    r
}

fn frustum(dir: Vec3) -> Frustum {
    let v = view::look_to_mat4(Vec3::new(0.0, 30.0, 0.0), dir, Vec3::Y);
    let p = proj::vulkan::perspective(60f32.to_radians(), 16.0 / 9.0, 0.1, 3000.0);
    Frustum::from_view_projection(p * v).unwrap()
}

fn benches(c: &mut Criterion) {
    let ps = positions(N);

    c.bench_function("registry/register_100k", |b| {
        b.iter_batched(
            || ps.clone(),
            |ps| black_box(filled(&ps)).len(),
            BatchSize::LargeInput,
        )
    });

    let mut reg = filled(&ps);
    reg.take_dirty();
    let handles: Vec<_> = reg.iter().map(|(h, _)| h).collect();
    c.bench_function("registry/set_transform_10k_and_take_dirty", |b| {
        b.iter(|| {
            for (k, &h) in handles.iter().step_by(10).enumerate() {
                let p = ps[k * 10] + Vec3::X * 0.5;
                reg.set_transform(h, Affine3A::from_translation(p), desc(p, 0).aabb)
                    .unwrap();
            }
            black_box(reg.take_dirty()).len()
        })
    });

    // The same moves through a Culling, whose take_uploads also brings the
    // moved instances' hitbox extents up to date (hitbox_extents): each
    // move lifts an instance by 0 or 1 m in turn, so every extent changes.
    let grid = HitboxGrid::new(GridConfig::default()).unwrap();
    let mut culling = Culling::new(grid, CullingConfig::new(1)).unwrap();
    let handles: Vec<_> = (0u32..)
        .zip(&ps)
        .map(|(i, &p)| culling.register(desc(p, i)).unwrap())
        .collect();
    culling.take_uploads();
    // Every 10th instance moved to its start plus `offset`, then the uploads.
    let move_10k = |culling: &mut Culling, offset: Vec3| {
        for (k, &h) in handles.iter().step_by(10).enumerate() {
            let p = ps[k * 10] + offset;
            culling
                .set_transform(h, Affine3A::from_translation(p), desc(p, 0).aabb)
                .unwrap();
        }
        black_box(culling.take_uploads()).records.len()
    };
    let mut lift = 0.0;
    c.bench_function("culling/set_transform_10k_and_take_uploads", |b| {
        b.iter(|| {
            lift = 1.0 - lift;
            move_10k(&mut culling, Vec3::Y * lift)
        })
    });
    // Ground units: the moves keep their heights (0.5 m along x and back).
    let mut shift = 0.0;
    c.bench_function("culling/set_transform_10k_level_and_take_uploads", |b| {
        b.iter(|| {
            shift = 0.5 - shift;
            move_10k(&mut culling, Vec3::X * shift)
        })
    });
    drop(culling);

    let grid = HitboxGrid::new(GridConfig::default()).unwrap();
    c.bench_function("grid/hitbox_at_100k", |b| {
        b.iter(|| {
            ps.iter()
                .map(|&p| grid.hitbox_at(black_box(p)).unwrap_or(0))
                .fold(0u32, u32::wrapping_add)
        })
    });

    let reg = filled(&ps);
    let (ahead, back) = (frustum(Vec3::NEG_Z), frustum(Vec3::Z));
    let mut out = Vec::new();
    let mut lm = LatencyMitigation::new(ActivationHeuristic::default()).unwrap();
    lm.update(&reg, Vec3::ZERO, &ahead, &mut out).unwrap();
    c.bench_function("latency/update_100k_steady", |b| {
        b.iter(|| {
            lm.update(&reg, Vec3::ZERO, black_box(&ahead), &mut out)
                .unwrap()
        })
    });
    let mut flip = false;
    c.bench_function("latency/update_100k_turning", |b| {
        b.iter(|| {
            flip = !flip;
            let f = if flip { &back } else { &ahead };
            lm.update(&reg, Vec3::ZERO, black_box(f), &mut out).unwrap()
        })
    });
}

criterion_group! {
    name = core;
    config = Criterion::default()
        .sample_size(20)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3));
    targets = benches
}
criterion_main!(core);
