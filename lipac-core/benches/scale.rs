//! Scale: the core's per-frame CPU cost at 10k, 100k, 1M and 10M instances.
//!
//! One frame of [`lipac_core::culling::Culling`]: `begin_frame`, ingest of
//! the read-back from `k = 2` frames ago, `process_frame_commands` under a
//! budget of 4096, `assemble` (Algorithm 1), synthetic hits for every TLAS
//! record, `process_feedback` (Algorithm 2) and `take_commands`. Latency
//! mitigation is off (its cost is in the `registry` bench).
//!
//! Scene: ~16 instances per 16 m hitbox on a square grid, 10 % needing a
//! unique BLAS. A band of hitbox columns an eighth of the world wide is hot
//! (2500 hits per counting box, 1500 per traced instance; elsewhere 10 and
//! 5) and moves one column every 8 frames. Setup reserves room for the `n`
//! instances (`Culling::reserve`, as a level load of known size would) and
//! registers them one by one through `Culling::register` (its time and the
//! CPU memory from `Culling::memory_usage` are printed), then warms up
//! without a budget for 16 frames or until the hot band's first activation
//! has drained (at most 64), so it is not a backlog.
//!
//! `cargo bench -p lipac-core --bench scale` (`LIPAC_SCALE_MAX=1000000`
//! leaves out 10M).

use std::hint::black_box;
use std::time::{Duration, Instant};

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
    last_counter: u32,
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
    let start = Instant::now();
    culling.reserve(n as usize);
    for i in 0..n {
        let c = Vec3::new(unit() * side as f32, 0.0, unit() * side as f32);
        let aabb = Aabb::new(c - Vec3::new(2.0, 0.0, 2.0), c + Vec3::new(2.0, 6.0, 2.0));
        let mut d = InstanceDesc::new(MeshId(i % 64), Affine3A::from_translation(c), aabb);
        if unit() < 0.1 {
            d.flags = InstanceFlags::UNIQUE_BLAS;
        }
        culling.register(d).unwrap();
    }
    let reg = start.elapsed();
    let mut l = Loop {
        culling,
        ring: ReadbackRing::new(2).unwrap(),
        tlas: Vec::new(),
        frame: 0,
        columns: w,
        next_blas: 0x10_0000,
        commands: 0,
        last_counter: 0,
    };
    // Warm-up with no budget, so the initial activation of the hot band
    // (an eighth of the world at once) is not measured as a backlog; then
    // the budget of 4096 commands per frame applies.
    let start = Instant::now();
    l.culling.set_command_budget(usize::MAX);
    // At 10M the first activation (1.25M adds) overflows the 65,536-command
    // buffer for ~20 frames: warm up until it has drained (at most 64).
    for i in 0..64 {
        frame(&mut l);
        if i >= 15 && l.culling.pending_commands() == 0 && l.last_counter < 1 << 16 {
            break;
        }
    }
    l.culling.set_command_budget(4096);
    let warm = start.elapsed();
    l.culling.take_uploads();
    let m = l.culling.memory_usage();
    println!(
        "n = {n}: registration {:.2} s ({:.0} ns/instance), {} warm-up frames {:.2} s; \
         CPU memory {:.1} MB per-slot ({:.1} B/instance) + {:.1} MB hitboxes and command buffer",
        reg.as_secs_f64(),
        reg.as_nanos() as f64 / f64::from(n),
        l.frame,
        warm.as_secs_f64(),
        m.per_slot() as f64 / 1e6,
        m.per_slot() as f64 / f64::from(n),
        (m.hitboxes + m.command_buffer) as f64 / 1e6,
    );
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
    // Synthetic hits: a band of columns, 1/8 of the world wide, is hot.
    let (w, shift) = (l.columns, (l.frame / 8) as u32);
    let hot = |hitbox: u32| (hitbox % w + shift) % w < w.div_ceil(8);
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
    l.last_counter = rb.counter;
    l.ring.push(rb).unwrap();
    l.frame += 1;
}

fn bench(c: &mut Criterion) {
    let max: u32 = std::env::var("LIPAC_SCALE_MAX")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000_000);
    let mut g = c.benchmark_group("scale");
    g.sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3));
    for n in [10_000u32, 100_000, 1_000_000, 10_000_000] {
        if n > max {
            continue;
        }
        let mut l = setup(n);
        let start = l.frame;
        g.throughput(Throughput::Elements(u64::from(n)));
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| {
                frame(&mut l);
                black_box(l.tlas.len())
            })
        });
        let frames = (l.frame - start).max(1);
        println!(
            "n = {n}: {frames} frames measured, {:.0} commands per frame, TLAS {} records, {} pending",
            l.commands as f64 / frames as f64,
            l.tlas.len(),
            l.culling.pending_commands()
        );
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
