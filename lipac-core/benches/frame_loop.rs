//! One full CPU frame of the per-frame loop ([`lipac_core::culling::Culling`]):
//! `begin_frame`, ingest of the read-back from `k = 2` frames ago,
//! `process_commands` (budget 4096), `assemble` (Algorithm 1), a stub tracer
//! writing hits for every TLAS record, `process_feedback` (Algorithm 2) and
//! `take_commands`. Latency mitigation is not included (see the `registry`
//! bench for its cost).
//!
//! Scene: `n` instances, ~16 per 16 m hitbox on a square grid, 15 % needing a
//! unique BLAS. A band of hitbox columns a quarter of the world wide is hot
//! (2500 hits per counting box, 1500 per traced instance; elsewhere 10 and
//! 5); it moves by one column every 8 frames, so hitboxes keep activating and
//! deactivating and frames carry commands. Warmed up for 64 frames first.
//!
//! `cargo bench -p lipac-core --bench frame_loop`

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::{Affine3A, Vec3};
use lipac_core::culling::{BlasAction, Culling, CullingConfig, ReadbackRing};
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::instance::{InstanceDesc, InstanceFlags, MeshId};
use lipac_core::layout::TlasInstance;
use lipac_core::math::Aabb;

const CELL: f64 = 16.0;
const CUBE: u64 = 0xC0BE;

struct Loop {
    culling: Culling,
    ring: ReadbackRing,
    tlas: Vec<TlasInstance>,
    frame: u64,
    columns: u32,
    next_blas: u64,
    commands: u64,
}

fn setup(n: u32) -> Loop {
    let w = ((f64::from(n) / 16.0).sqrt().ceil() as u32).max(1);
    let side = f64::from(w) * CELL;
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [side, side],
        cell_size: CELL,
    })
    .unwrap();
    let mut cfg = CullingConfig::new(CUBE);
    cfg.latency_mitigation = None;
    let mut culling = Culling::new(grid, cfg).unwrap();
    let mut rng = 0x9E37_79B9_7F4A_7C15u64 ^ u64::from(n);
    let mut unit = || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 40) as f32 / (1u64 << 24) as f32
    };
    for _ in 0..n {
        let c = Vec3::new(unit() * side as f32, 0.0, unit() * side as f32);
        let aabb = Aabb::new(c - Vec3::new(2.0, 0.0, 2.0), c + Vec3::new(2.0, 6.0, 2.0));
        let mut d = InstanceDesc::new(
            MeshId((unit() * 64.0) as u32),
            Affine3A::from_translation(c),
            aabb,
        );
        if unit() < 0.15 {
            d.flags = InstanceFlags::UNIQUE_BLAS;
        }
        culling.register(d).unwrap();
    }
    let mut l = Loop {
        culling,
        ring: ReadbackRing::new(2).unwrap(),
        tlas: Vec::new(),
        frame: 0,
        columns: w,
        next_blas: 0x10_0000,
        commands: 0,
    };
    for _ in 0..64 {
        frame(&mut l);
    }
    l.commands = 0;
    l
}

fn frame(l: &mut Loop) {
    let c = &mut l.culling;
    c.begin_frame(l.frame).unwrap();
    while let Some(r) = l.ring.pop_ready(l.frame) {
        c.ingest_readback(r.counter, &r.words);
    }
    let next = &mut l.next_blas;
    c.process_frame_commands(&mut |e| match e.action {
        BlasAction::Acquire => {
            *next += 1;
            Some(*next)
        }
        _ => None,
    });
    c.assemble(&mut l.tlas).unwrap();
    // Stub tracer: a band of columns, 1/4 of the world wide, is hot.
    let (w, shift) = (l.columns, (l.frame / 8) as u32);
    let hot = |hitbox: u32| (hitbox % w + shift) % w < w.div_ceil(4);
    for r in &l.tlas {
        let i = r.custom_index();
        if r.acceleration_structure_reference == CUBE && r.sbt_offset() == 2 {
            c.hitboxes_mut()[i as usize].add_hits(if hot(i) { 2500 } else { 10 });
        } else {
            let hitbox = c.registry().record_at(i).unwrap().hitbox;
            c.instance_hits_mut()[i as usize] = if hot(hitbox) { 1500 } else { 5 };
        }
    }
    c.process_feedback().unwrap();
    let rb = c.take_commands().unwrap();
    l.commands += u64::from(rb.counter);
    l.ring.push(rb).unwrap();
    l.frame += 1;
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("frame_loop");
    g.sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(4));
    for n in [10_000u32, 100_000, 1_000_000] {
        let mut l = setup(n);
        g.throughput(Throughput::Elements(u64::from(n)));
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| {
                frame(&mut l);
                black_box(l.tlas.len())
            })
        });
        println!(
            "n = {n}: {} frames measured, {:.0} commands per frame, TLAS {} records, {} pending",
            l.frame - 64,
            l.commands as f64 / (l.frame - 64).max(1) as f64,
            l.tlas.len(),
            l.culling.pending_commands()
        );
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
