//! Range allocator throughput: lipac's `TlsfAllocator` side by side with
//! `offset-allocator` (good-fit TLSF over offsets) and `rlsf` (a TLSF memory
//! allocator over a byte arena, CPU reference), on the same seeded traces.
//!
//! Each sample replays a trace's timed operations on an allocator that was
//! brought to the trace's working state in the (untimed) setup.
//! `Throughput::Elements` counts allocate+free pairs, so ns per pair is
//! `1e9 / elements-per-second`.
//!
//! Run: `cargo bench -p lipac-core --bench allocator`
//!
//! Criterion measures the allocators one after the other; on a machine whose
//! speed drifts, compare them with the paired replay too:
//! `cargo run -p lipac-core --release --example allocator_replay -- pair all 1000`
//! (see docs/BENCHMARKS.md).

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};

mod support;
use support::{all_traces, run_ops, Arena, Lipac, OffsetAlloc, RangeAlloc, Rlsf, Trace};

/// Setup: a fresh allocator after the trace's setup ops, and its slot table.
fn prepared<A: RangeAlloc>(mut a: A, t: &Trace) -> (A, Vec<Option<A::Id>>) {
    let mut slots = vec![None; t.slots];
    run_ops(&mut a, &t.setup, &mut slots);
    (a, slots)
}

fn replay<A: RangeAlloc>(
    (mut a, mut slots): (A, Vec<Option<A::Id>>),
    t: &Trace,
) -> (A, Vec<Option<A::Id>>) {
    black_box(run_ops(&mut a, &t.ops, &mut slots));
    // Returned so that dropping happens outside the timing.
    (a, slots)
}

fn allocators(c: &mut Criterion) {
    for t in all_traces() {
        let mut group = c.benchmark_group(format!("allocator/{}", t.name));
        group.throughput(Throughput::Elements(t.pairs()));
        group.bench_function("lipac_tlsf", |b| {
            b.iter_batched(
                || prepared(Lipac::new(t.capacity), &t),
                |s| replay(s, &t),
                BatchSize::PerIteration,
            )
        });
        group.bench_function("offset_allocator", |b| {
            b.iter_batched(
                || prepared(OffsetAlloc::new(t.capacity), &t),
                |s| replay(s, &t),
                BatchSize::PerIteration,
            )
        });
        let mut arena = Arena::new(t.capacity);
        group.bench_function("rlsf", |b| {
            // PerIteration: exactly one `Rlsf` lives on the arena at a time.
            b.iter_batched(
                // SAFETY: `arena` outlives this closure; the previous
                // iteration's `Rlsf` is dropped before the next setup runs.
                || prepared(unsafe { Rlsf::new(&mut arena) }, &t),
                |s| replay(s, &t),
                BatchSize::PerIteration,
            )
        });
        group.finish();
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_millis(1500));
    targets = allocators
}
criterion_main!(benches);
