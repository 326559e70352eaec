//! Fragmentation report: for lipac's `TlsfAllocator`, `offset-allocator` and
//! `rlsf`, replays each seeded trace (setup, steady phase, then a ramp biased
//! to allocation) until the first failed allocation and prints the
//! utilisation (live requested bytes / capacity) at that point, largest free
//! block / total free bytes, and the high-water mark (highest end offset /
//! capacity).
//!
//! Run: `cargo run -p lipac-core --release --example fragmentation`

#[path = "../benches/support/mod.rs"]
mod support;

use lipac_core::allocator::TlsfAllocator;
use support::{
    all_traces, first_failure, offset_allocator_between_bins, run_ops, Arena, FirstFailure, Lipac,
    OffsetAlloc, RangeAlloc, Rlsf, Trace, BETWEEN_BINS_SIZE,
};

fn print_row(name: &str, f: &FirstFailure, timed_failures: usize) {
    let ratio = match f.free_report {
        Some((largest, total)) if total > 0 => format!("{:.3}", largest as f64 / total as f64),
        Some(_) => "-".to_string(),
        None => "n/a".to_string(),
    };
    println!(
        "  {name:<17} {:>6.1} %  {:<5}  {:>8}  {:>8.1} %  {:>8.1} %  {:>11}",
        f.utilisation * 100.0,
        f.phase,
        ratio,
        f.steady_high_water * 100.0,
        f.high_water * 100.0,
        timed_failures
    );
}

/// Failed allocations in the timed part alone (setup + ops), as the bench
/// replays it.
fn timed_failures<A: RangeAlloc>(mut a: A, t: &Trace) -> usize {
    let mut slots = vec![None; t.slots];
    run_ops(&mut a, &t.setup, &mut slots) + run_ops(&mut a, &t.ops, &mut slots)
}

fn main() {
    assert!(
        TlsfAllocator::size_class_floor(u64::from(BETWEEN_BINS_SIZE))
            < u64::from(BETWEEN_BINS_SIZE)
            && offset_allocator_between_bins(BETWEEN_BINS_SIZE),
        "the between-bins trace must fall between bins of both allocators"
    );
    println!(
        "  {:<17} {:>8}  {:<5}  {:>8}  {:>10}  {:>10}  {:>11}",
        "allocator", "util@1st", "phase", "lf/free", "hw@steady", "hw@1st", "bench-fails"
    );
    println!(
        "  (util@1st: live bytes / capacity at the first failed allocation; phase: where it \
         failed;\n   lf/free: largest free / total free there; hw: highest end offset / capacity \
         after the steady\n   phase and at the failure; bench-fails: failed allocations in \
         setup + timed ops)"
    );
    for t in all_traces() {
        println!(
            "{} (capacity {} MiB, {} setup / {} timed / {} ramp ops)",
            t.name,
            t.capacity >> 20,
            t.setup.len(),
            t.ops.len(),
            t.ramp.len()
        );
        print_row(
            "lipac_tlsf",
            &first_failure(&mut Lipac::new(t.capacity), &t),
            timed_failures(Lipac::new(t.capacity), &t),
        );
        print_row(
            "offset_allocator",
            &first_failure(&mut OffsetAlloc::new(t.capacity), &t),
            timed_failures(OffsetAlloc::new(t.capacity), &t),
        );
        let mut arena = Arena::new(t.capacity);
        // SAFETY: each `Rlsf` is dropped (end of statement) before the next
        // is built on the same arena, and the arena outlives both.
        let f = first_failure(&mut unsafe { Rlsf::new(&mut arena) }, &t);
        let n = timed_failures(unsafe { Rlsf::new(&mut arena) }, &t);
        print_row("rlsf", &f, n);
    }
}
