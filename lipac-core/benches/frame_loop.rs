//! One full CPU frame of the per-frame loop ([`lipac_core::culling::Culling`]):
//! `begin_frame`, ingest of the read-back from `k = 2` frames ago,
//! `process_commands` (budget 4096) with `set_blas` for every acquire, `assemble` (Algorithm 1), a stub tracer
//! writing hits for every TLAS record, `process_feedback` (Algorithm 2) and
//! `take_commands`. Latency mitigation is not included (see the `registry`
//! bench for its cost).
//!
//! Scene: `n` instances, ~16 per 16 m hitbox on a square grid, 15 % needing a
//! unique BLAS. A band of hitbox columns a quarter of the world wide is hot
//! (2500 hits per counting box, 1500 per traced instance; elsewhere 10 and
//! 5); it moves by one column every 8 frames, so hitboxes keep activating and
//! deactivating and frames carry commands. Warmed up for 64 frames first.
//! Scene and frame: `benches/synthetic_loop` (shared with the `scale` bench).
//!
//! `cargo bench -p lipac-core --bench frame_loop`

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

mod synthetic_loop;
use synthetic_loop::{build, frame, Loop, Scene};

fn setup(n: u32) -> Loop {
    let mut l = build(
        n,
        &Scene {
            unique_fraction: 0.15,
            hot_divisor: 4,
            random_meshes: true,
            reserve: false,
        },
    );
    for _ in 0..64 {
        frame(&mut l);
    }
    l.commands = 0;
    l
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
