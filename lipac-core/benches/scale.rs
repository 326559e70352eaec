//! Scale: the core's per-frame CPU cost at 10k, 100k, 1M and 10M instances.
//!
//! One frame of [`lipac_core::culling::Culling`]: `begin_frame`, ingest of
//! the read-back from `k = 2` frames ago, `process_commands` under a
//! budget of 4096, `assemble` (Algorithm 1), synthetic hits for every TLAS
//! record, `process_feedback` (Algorithm 2) and `take_commands`. Latency
//! mitigation is off (its cost is in the `registry` bench).
//!
//! Scene: ~16 instances per 16 m hitbox on a square grid, 10 % needing a
//! unique BLAS. A band of hitbox columns an eighth of the world wide is hot
//! (2500 hits per counting box, 1500 per traced instance; elsewhere 10 and
//! 5) and moves one column every 8 frames. Setup reserves room for the `n`
//! instances (`Culling::reserve`, as a level load of known size would) and
//! registers them one by one through `Culling::register` (the time of grid
//! set-up, reserve and registration, and the CPU memory from
//! `Culling::memory_usage` are printed), then warms up without a budget for
//! 16 frames or until the hot band's first activation has drained (at most
//! 64), so it is not a backlog. Scene and frame: `benches/synthetic_loop`.
//!
//! `cargo bench -p lipac-core --bench scale` (`LIPAC_SCALE_MAX=1000000`
//! leaves out 10M).
//!
//! The full `Manager` frame (plan, Algorithms 1 and 2 timed apart), the
//! sparse hashed hitbox index and worlds of any size (the 100 km × 100 km
//! world with 1M instances) are in `examples/scale_frame.rs`, a `--release`
//! example run under `/usr/bin/time` and callgrind (docs/BENCHMARKS.md,
//! "The Manager frame at scale").

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

mod synthetic_loop;
use synthetic_loop::{build, frame, Loop, Scene};

fn setup(n: u32) -> Loop {
    let start = Instant::now();
    let mut l = build(
        n,
        &Scene {
            unique_fraction: 0.1,
            hot_divisor: 8,
            random_meshes: false,
            reserve: true,
        },
    );
    let reg = start.elapsed();
    // Warm-up with no budget, so the initial activation of the hot band
    // (an eighth of the world at once) is not measured as a backlog; then
    // the budget of 4096 commands per frame applies.
    let start = Instant::now();
    l.budget = usize::MAX;
    // At 10M the first activation (1.25M adds) overflows the 65,536-command
    // buffer for ~20 frames: warm up until it has drained (at most 64).
    for i in 0..64 {
        frame(&mut l);
        if i >= 15 && l.culling.pending_commands() == 0 && l.last_counter < 1 << 16 {
            break;
        }
    }
    l.budget = 4096;
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
