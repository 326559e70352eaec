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
//!
//! `... -- pair <trace|all> 200` instead times lipac and offset-allocator in
//! alternation, `reps` rounds of one replay each (the order swapping every
//! round), and prints the median of the per-round ratios lipac /
//! offset-allocator with its interquartile range. On a shared machine whose
//! speed drifts by tens of percent from second to second, the two replays of a
//! round run under nearly the same conditions, so this ratio is far steadier
//! than a ratio of separately taken bests or medians.

#[path = "../benches/support/mod.rs"]
mod support;

use std::hint::black_box;
use std::time::Instant;

use support::{all_traces, run_ops, Arena, Lipac, OffsetAlloc, RangeAlloc, Rlsf, Trace};

#[inline(never)]
fn timed_ops<A: RangeAlloc>(a: &mut A, t: &Trace, slots: &mut [Option<A::Id>]) -> usize {
    run_ops(a, &t.ops, slots)
}

/// One replay of `t`'s timed part on a fresh allocator brought to the
/// trace's working state: ns per allocate+free pair.
fn replay_once<A: RangeAlloc>(mut a: A, t: &Trace) -> f64 {
    let mut slots = vec![None; t.slots];
    run_ops(&mut a, &t.setup, &mut slots);
    let start = Instant::now();
    black_box(timed_ops(&mut a, t, &mut slots));
    let ns = start.elapsed().as_nanos() as f64;
    drop(black_box((a, slots)));
    ns / t.pairs() as f64
}

fn replay<A: RangeAlloc>(mut make: impl FnMut() -> A, t: &Trace, reps: usize) -> Vec<f64> {
    (0..reps).map(|_| replay_once(make(), t)).collect()
}

/// The value at quantile `q` of sorted `v`.
fn quantile(v: &[f64], q: f64) -> f64 {
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// Paired rounds of lipac and offset-allocator on `t`; prints the median
/// per-pair times and the median (and quartiles) of the per-round ratios.
fn pair(t: &Trace, rounds: usize) {
    let (mut lipac, mut offset, mut ratio) = (Vec::new(), Vec::new(), Vec::new());
    for round in 0..rounds {
        let (l, o) = if round % 2 == 0 {
            let l = replay_once(Lipac::new(t.capacity), t);
            (l, replay_once(OffsetAlloc::new(t.capacity), t))
        } else {
            let o = replay_once(OffsetAlloc::new(t.capacity), t);
            (replay_once(Lipac::new(t.capacity), t), o)
        };
        lipac.push(l);
        offset.push(o);
        ratio.push(l / o);
    }
    for v in [&mut lipac, &mut offset, &mut ratio] {
        v.sort_by(f64::total_cmp);
    }
    println!(
        "{:<19} lipac {:6.1}  offset {:6.1} ns/pair (medians)  ratio median {:.3} (IQR {:.3}..{:.3}, {rounds} rounds)",
        t.name,
        quantile(&lipac, 0.5),
        quantile(&offset, 0.5),
        quantile(&ratio, 0.5),
        quantile(&ratio, 0.25),
        quantile(&ratio, 0.75),
    );
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let which = args.first().map_or("lipac", String::as_str);
    let name = args.get(1).map_or("churn_50", String::as_str);
    let reps: usize = args.get(2).and_then(|r| r.parse().ok()).unwrap_or(20);
    let traces = all_traces();
    if which == "pair" {
        let mut any = false;
        for t in traces.iter().filter(|t| name == "all" || t.name == name) {
            pair(t, reps);
            any = true;
        }
        if !any {
            eprintln!("unknown trace {name}");
            std::process::exit(2);
        }
        return;
    }
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
            eprintln!("unknown allocator {which} (lipac, offset, rlsf, pair)");
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
