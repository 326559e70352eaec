//! Profiling driver for the range allocator bench: replays the timed part of
//! one seeded trace (see `benches/support/mod.rs`) on one allocator, `reps`
//! times, each on a fresh allocator brought to the trace's working state, and
//! prints the best and median wall time per allocate+free pair. The timed
//! part runs in the non-inlined `timed_ops`, so instruction and cache-miss
//! counts of just that part can be taken with
//! `valgrind --tool=callgrind --toggle-collect='*timed_ops*'` (or cachegrind).
//!
//! Run: `cargo run -p lipac-core --release --example allocator_replay -- lipac churn_50 20`
//! (allocator `lipac`, `offset` or `rlsf`; trace name as in the bench; reps).

#[path = "../benches/support/mod.rs"]
mod support;

use std::hint::black_box;
use std::time::Instant;

use support::{all_traces, run_ops, Arena, Lipac, OffsetAlloc, RangeAlloc, Rlsf, Trace};

#[inline(never)]
fn timed_ops<A: RangeAlloc>(a: &mut A, t: &Trace, slots: &mut [Option<A::Id>]) -> usize {
    run_ops(a, &t.ops, slots)
}

fn replay<A: RangeAlloc>(mut make: impl FnMut() -> A, t: &Trace, reps: usize) -> Vec<f64> {
    (0..reps)
        .map(|_| {
            let mut a = make();
            let mut slots = vec![None; t.slots];
            run_ops(&mut a, &t.setup, &mut slots);
            let start = Instant::now();
            black_box(timed_ops(&mut a, t, &mut slots));
            let ns = start.elapsed().as_nanos() as f64;
            drop(black_box((a, slots)));
            ns / t.pairs() as f64
        })
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let which = args.first().map_or("lipac", String::as_str);
    let name = args.get(1).map_or("churn_50", String::as_str);
    let reps: usize = args.get(2).and_then(|r| r.parse().ok()).unwrap_or(20);
    let traces = all_traces();
    let Some(t) = traces.iter().find(|t| t.name == name) else {
        eprintln!("unknown trace {name}");
        std::process::exit(2);
    };
    let mut ns = match which {
        "lipac" => replay(|| Lipac::new(t.capacity), t, reps),
        "offset" => replay(|| OffsetAlloc::new(t.capacity), t, reps),
        "rlsf" => {
            let mut arena = Arena::new(t.capacity);
            let arena: *mut Arena = &mut arena;
            // SAFETY: the arena outlives every `Rlsf`, and each one is
            // dropped inside `replay` before the next is built.
            replay(|| unsafe { Rlsf::new(&mut *arena) }, t, reps)
        }
        _ => {
            eprintln!("unknown allocator {which} (lipac, offset, rlsf)");
            std::process::exit(2);
        }
    };
    ns.sort_by(f64::total_cmp);
    println!(
        "{which:<7} {name:<19} best {:7.1} ns/pair  median {:7.1} ns/pair",
        ns[0],
        ns[ns.len() / 2]
    );
}
