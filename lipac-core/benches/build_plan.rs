//! Per-frame cost of `BuildScheduler::plan` in steady state: N instances on
//! shared BLASes (all built) plus N/10 unique BLASes refit every frame.
use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use lipac_core::blas_ids::{InstanceKey, Lod};
use lipac_core::build_plan::*;
use lipac_core::MeshId;

fn steady(n: u32) -> BuildScheduler {
    let mut cfg = SchedulerConfig::default();
    cfg.cache.memory_budget = u64::MAX / 4;
    let mut s = BuildScheduler::new(cfg).unwrap();
    s.begin_frame(1).unwrap();
    let e = BuildEstimate {
        primitives: 100,
        result_bytes: 4096,
        build_scratch_bytes: 1024,
        update_scratch_bytes: 256,
    };
    for k in 0..n {
        let geometry = if k % 10 == 0 {
            BlasGeometry::Unique { mesh: MeshId(k) }
        } else {
            BlasGeometry::Shared {
                mesh: MeshId(k % 500),
                variant: 0,
                compactable: false,
            }
        };
        let r = InstanceBlasRequest {
            geometry,
            lod: Lod(0),
            estimate: e,
            hits: k,
            in_frustum: false,
        };
        s.activate(InstanceKey(k), r).unwrap();
    }
    let all = BuildBudgets {
        max_builds: u32::MAX,
        max_primitives: u64::MAX,
        max_result_bytes: u64::MAX,
        max_scratch_bytes: u64::MAX / 4,
        max_batches: 1,
        max_compactions: 0,
    };
    let p = s.plan(&all).unwrap();
    for b in p.builds() {
        s.ack_built(b.id, 4096, 0x1000 * b.id.0).unwrap();
    }
    s
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("build_plan_steady_frame");
    g.sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    for n in [1_000u32, 10_000] {
        let mut s = steady(n);
        let mut frame = 1u64;
        let budgets = BuildBudgets::default();
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| {
                frame += 1;
                s.begin_frame(frame).unwrap();
                black_box(s.plan(&budgets).unwrap())
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
