//! Unit and property tests of the TLSF range allocator.

use proptest::prelude::*;

use lipac_test_support::{Rng64, SplitMix64};

use super::*;

#[test]
fn first_allocations_are_packed_from_zero() {
    let mut a = TlsfAllocator::new(1000);
    let x = a.allocate(100).unwrap();
    let y = a.allocate(300).unwrap();
    assert_eq!((x.offset, x.size), (0, 100));
    assert_eq!((y.offset, y.size), (100, 300));
    a.check_invariants();
    assert_eq!(a.used_bytes(), 400);
    assert_eq!(a.free_bytes(), 600);
}

#[test]
fn alignment_is_honoured_and_padding_stays_free() {
    let mut a = TlsfAllocator::new(4096);
    let x = a.allocate(3).unwrap();
    let y = a.allocate_aligned(100, 256).unwrap();
    assert_eq!(y.offset, 256);
    a.check_invariants();
    // The 253 padding bytes are a free block that a small request can use.
    let z = a.allocate(200).unwrap();
    assert!(z.offset >= x.end() && z.end() <= y.offset, "{z:?}");
    for align in [1u64, 2, 4, 64, 1024] {
        let r = a.allocate_aligned(17, align).unwrap();
        assert_eq!(r.offset % align, 0);
    }
    a.check_invariants();
}

#[test]
fn invalid_requests_are_errors() {
    let mut a = TlsfAllocator::new(100);
    assert_eq!(a.allocate(0), Err(AllocError::ZeroSize));
    assert_eq!(
        a.allocate_aligned(8, 3),
        Err(AllocError::InvalidAlignment { align: 3 })
    );
    assert_eq!(
        a.allocate_aligned(8, 0),
        Err(AllocError::InvalidAlignment { align: 0 })
    );
    // The free tail starts at 0, so u64::MAX bytes is a (huge) growth request.
    assert_eq!(
        a.allocate(u64::MAX).unwrap_err().required_capacity(),
        Some(u64::MAX)
    );
    a.allocate(1).unwrap();
    assert_eq!(a.allocate(u64::MAX), Err(AllocError::CapacityOverflow));
    assert_eq!(
        a.grow(50),
        Err(AllocError::CannotShrinkCapacity {
            capacity: 100,
            requested: 50
        })
    );
    a.check_invariants();
}

#[test]
fn split_and_merge_with_both_neighbours() {
    let mut a = TlsfAllocator::new(300);
    let x = a.allocate(100).unwrap();
    let y = a.allocate(100).unwrap();
    let z = a.allocate(100).unwrap();
    assert_eq!(a.stats().free_block_count, 0);
    a.free(x.handle).unwrap();
    a.free(z.handle).unwrap();
    assert_eq!(a.stats().free_block_count, 2);
    assert_eq!(a.largest_free_block(), 100);
    a.free(y.handle).unwrap();
    a.check_invariants();
    let s = a.stats();
    assert_eq!((s.free_block_count, s.largest_free_block), (1, 300));
    assert_eq!(s.fragmentation, 0.0);
    // The whole buffer is usable again.
    assert_eq!(a.allocate(300).unwrap().offset, 0);
}

#[test]
fn double_free_and_stale_handles_are_errors() {
    let mut a = TlsfAllocator::new(1000);
    let x = a.allocate(10).unwrap();
    a.free(x.handle).unwrap();
    assert_eq!(a.free(x.handle), Err(AllocError::StaleHandle));
    // The slot is reused; the old handle still must not free the new range.
    let y = a.allocate(10).unwrap();
    assert_eq!(y.offset, x.offset);
    assert_eq!(a.free(x.handle), Err(AllocError::StaleHandle));
    assert_eq!(a.get(x.handle), Err(AllocError::StaleHandle));
    assert_eq!(a.resize(x.handle, 5), Err(AllocError::StaleHandle));
    assert!(!a.is_live(x.handle));
    assert!(a.is_live(y.handle));
    assert_eq!(a.get(y.handle), Ok(y));
    a.check_invariants();
    assert_eq!(a.allocation_count(), 1);
}

/// Issue 12: the serial was a `u32` that wrapped, so after 2^32
/// allocations a long-freed handle was live again and `free(stale)` freed
/// an unrelated allocation. (`skip_serials_to` stands in for the 2^32
/// allocations in between.)
#[test]
fn stale_handle_stays_stale_when_the_serial_wraps() {
    let mut a = TlsfAllocator::new(1024);
    let old = a.allocate(100).unwrap();
    a.free(old.handle).unwrap();
    a.skip_serials_to(u32::MAX);
    let last = a.allocate(100).unwrap(); // the last serial before the wrap
    a.free(last.handle).unwrap();
    let new = a.allocate(100).unwrap(); // serials wrapped: same record, serial 0
    assert_eq!(new.offset, old.offset);
    assert_eq!(a.free(old.handle), Err(AllocError::StaleHandle));
    assert_eq!(a.free(last.handle), Err(AllocError::StaleHandle));
    assert!(
        a.is_live(new.handle),
        "a stale free freed a live allocation"
    );
    assert_eq!(a.get(new.handle).unwrap(), new);
    a.check_invariants();
}

/// Allocations live across a serial wrap keep working (get, resize,
/// defragment, free), are listed with their own handles, and go stale once
/// freed.
#[test]
fn allocations_live_across_serial_wraps_stay_valid() {
    let mut a = TlsfAllocator::new(1 << 16);
    let mut rng = SplitMix64::new(12);
    let mut live: Vec<Allocation> = Vec::new();
    let mut dead: Vec<AllocHandle> = Vec::new();
    for round in 0..4 {
        for _ in 0..40 {
            if live.len() > 10 && rng.below(3) == 0 {
                let x = live.swap_remove(rng.below(live.len() as u64) as usize);
                a.free(x.handle).unwrap();
                dead.push(x.handle);
            } else {
                live.push(a.allocate(1 + rng.below(300)).unwrap());
            }
        }
        // Wrap the serials (twice in the last rounds).
        a.skip_serials_to(u32::MAX - rng.below(3) as u32);
        for _ in 0..5 {
            let x = a.allocate(8).unwrap();
            a.free(x.handle).unwrap();
            dead.push(x.handle);
        }
        if round % 2 == 1 {
            let x = live.swap_remove(0);
            let resized = a.resize(x.handle, 1).unwrap();
            assert_eq!(resized.handle, x.handle);
            live.push(resized);
        }
        let mut moves = Vec::new();
        a.defragment(1 << 12, &mut moves).unwrap();
        for m in &moves {
            let x = live.iter_mut().find(|x| x.handle == m.handle).unwrap();
            x.offset = m.to;
        }
        for x in &live {
            assert_eq!(a.get(x.handle).unwrap(), *x);
        }
        for &h in &dead {
            assert_eq!(a.get(h), Err(AllocError::StaleHandle));
        }
        let mut listed: Vec<Allocation> = a.allocations().collect();
        let mut expected = live.clone();
        listed.sort_by_key(|x| x.offset);
        expected.sort_by_key(|x| x.offset);
        assert_eq!(listed, expected);
        a.check_invariants();
    }
    for x in live.drain(..) {
        a.free(x.handle).unwrap();
        assert_eq!(a.free(x.handle), Err(AllocError::StaleHandle));
    }
    assert_eq!(a.allocation_count(), 0);
    a.check_invariants();
    let other = TlsfAllocator::new(64).allocate(8).unwrap();
    assert_eq!(a.free(other.handle), Err(AllocError::ForeignHandle));
}

#[test]
fn foreign_and_unknown_handles_are_errors() {
    let mut a = TlsfAllocator::new(1000);
    let mut b = TlsfAllocator::new(1000);
    let xa = a.allocate(10).unwrap();
    let xb = b.allocate(10).unwrap();
    assert_eq!(b.free(xa.handle), Err(AllocError::ForeignHandle));
    assert_eq!(a.free(xb.handle), Err(AllocError::ForeignHandle));
    // A handle whose index a never issued (from a bigger allocator's index).
    let mut c = TlsfAllocator::new(1000);
    let mut last = None;
    for _ in 0..20 {
        last = Some(c.allocate(1).unwrap());
    }
    let mut forged = last.unwrap().handle;
    forged.owner = xa.handle.owner;
    assert_eq!(a.free(forged), Err(AllocError::UnknownHandle));
    assert!(a.is_live(xa.handle) && b.is_live(xb.handle));
}

#[test]
fn out_of_space_reports_growth_and_grow_continues() {
    let mut a = TlsfAllocator::new(1000);
    let x = a.allocate(900).unwrap();
    let err = a.allocate(300).unwrap_err();
    // The free tail starts at 900, so 1200 is exactly enough.
    assert_eq!(err.required_capacity(), Some(1200));
    assert_eq!(err.additional_bytes(), Some(200));
    assert!(err.to_string().contains("1200"));
    a.grow(1200).unwrap();
    let y = a.allocate(300).unwrap();
    assert_eq!((y.offset, y.end()), (900, 1200));
    a.check_invariants();

    // With a used last block, growth appends a new free block.
    let err = a.allocate_aligned(10, 512).unwrap_err();
    assert_eq!(err.required_capacity(), Some(1536 + 10));
    a.grow(1546).unwrap();
    let z = a.allocate_aligned(10, 512).unwrap();
    assert_eq!(z.offset, 1536);
    a.check_invariants();
    a.free(x.handle).unwrap();
    a.free(y.handle).unwrap();
    a.free(z.handle).unwrap();
    a.check_invariants();
    assert_eq!(a.stats().free_block_count, 1);

    // Starting from nothing.
    let mut e = TlsfAllocator::new(0);
    let err = e.allocate(64).unwrap_err();
    assert_eq!(err.required_capacity(), Some(64));
    e.grow(64).unwrap();
    assert_eq!(e.allocate(64).unwrap().offset, 0);
}

#[test]
fn resize_in_place_both_directions_and_refusal() {
    let mut a = TlsfAllocator::new(1000);
    let x = a.allocate(100).unwrap();
    let y = a.allocate(100).unwrap();
    // Shrink with a used right neighbour: a new free block appears.
    let x2 = a.resize(x.handle, 60).unwrap();
    assert_eq!((x2.offset, x2.size, x2.handle), (0, 60, x.handle));
    assert_eq!(a.stats().free_block_count, 2);
    a.check_invariants();
    // Grow back into that free block, exactly consuming it.
    let x3 = a.resize(x.handle, 100).unwrap();
    assert_eq!(x3.size, 100);
    assert_eq!(a.stats().free_block_count, 1);
    // Refuse: right neighbour is used.
    assert_eq!(
        a.resize(x.handle, 101),
        Err(AllocError::CannotGrowInPlace {
            requested: 101,
            available: 100
        })
    );
    // y's right neighbour is the 800-byte free tail.
    assert_eq!(a.resize(y.handle, 900).unwrap().end(), 1000);
    assert_eq!(
        a.resize(y.handle, 901),
        Err(AllocError::CannotGrowInPlace {
            requested: 901,
            available: 900
        })
    );
    // Shrink next to a free neighbour merges into it.
    a.resize(y.handle, 150).unwrap();
    let s = a.stats();
    assert_eq!((s.free_block_count, s.largest_free_block), (1, 750));
    assert_eq!(a.resize(y.handle, 0), Err(AllocError::ZeroSize));
    a.check_invariants();
    assert_eq!(a.used_bytes(), 250);
}

#[test]
fn high_water_and_peak_are_tracked() {
    let mut a = TlsfAllocator::new(1000);
    let x = a.allocate(400).unwrap();
    let y = a.allocate(400).unwrap();
    a.free(x.handle).unwrap();
    a.free(y.handle).unwrap();
    let _ = a.allocate(100).unwrap();
    let s = a.stats();
    assert_eq!(s.high_water_mark, 800);
    assert_eq!(s.peak_used_bytes, 800);
    assert_eq!(s.used_bytes, 100);
}

#[test]
fn node_storage_grows_without_a_cap() {
    let mut a = TlsfAllocator::new(1 << 20);
    let handles: Vec<_> = (0..200_000).map(|_| a.allocate(1).unwrap()).collect();
    assert_eq!(a.allocation_count(), 200_000);
    for h in handles.iter().step_by(2) {
        a.free(h.handle).unwrap();
    }
    for h in handles.iter().skip(1).step_by(2) {
        a.free(h.handle).unwrap();
    }
    assert_eq!(a.stats().free_block_count, 1);
}

#[test]
fn reserved_block_storage_is_used_without_reallocating() {
    let mut a = TlsfAllocator::new(1 << 20);
    a.reserve_blocks(1000).unwrap();
    let storage = a.nodes.as_ptr();
    // The free tail's record and 1000 reserved ones, created up front.
    assert_eq!(a.nodes.len(), 1001);
    let hs: Vec<_> = (0..1000).map(|_| a.allocate(16).unwrap()).collect();
    // 1000 allocations and the free tail: no new record, no reallocation.
    assert_eq!(a.nodes.len(), 1001);
    assert_eq!(a.nodes.as_ptr(), storage);
    // Reserving what is already there adds nothing.
    a.reserve_blocks(0).unwrap();
    assert_eq!(a.nodes.len(), 1001);
    for h in &hs {
        a.free(h.handle).unwrap();
    }
    a.check_invariants();
    assert_eq!(a.stats().free_block_count, 1);
}

#[test]
fn reserving_counts_vacant_records_and_keeps_invariants() {
    let mut a = TlsfAllocator::new(1 << 20);
    let hs: Vec<_> = (0..10).map(|_| a.allocate(64).unwrap()).collect();
    // Free every other one: 5 holes, no merges, no record released.
    for h in hs.iter().step_by(2) {
        a.free(h.handle).unwrap();
    }
    // Freeing the rest merges everything back: records become vacant.
    for h in hs.iter().skip(1).step_by(2) {
        a.free(h.handle).unwrap();
    }
    a.check_invariants();
    let (records, vacant) = (a.nodes.len(), a.nodes.len() - 1);
    // Enough vacant records already: nothing added.
    a.reserve_blocks(vacant).unwrap();
    assert_eq!(a.nodes.len(), records);
    // Only the missing ones are added.
    a.reserve_blocks(vacant + 5).unwrap();
    assert_eq!(a.nodes.len(), records + 5);
    a.check_invariants();
    let hs: Vec<_> = (0..vacant + 5).map(|_| a.allocate(8).unwrap()).collect();
    assert_eq!(a.nodes.len(), records + 5);
    a.check_invariants();
    for h in hs {
        a.free(h.handle).unwrap();
    }
    a.check_invariants();
    assert_eq!(a.stats().free_block_count, 1);
}

/// Utilisation at the first failure for a churn that ramps up occupancy
/// (60 % allocate, 40 % free a random live range) with one size.
fn ramp_utilisation(size: u64, capacity: u64, seed: u64) -> f64 {
    let mut a = TlsfAllocator::new(capacity);
    let mut rng = SplitMix64::new(seed);
    let mut live = Vec::new();
    loop {
        if live.is_empty() || rng.below(10) < 6 {
            match a.allocate(size) {
                Ok(x) => live.push(x.handle),
                Err(e) => {
                    assert!(e.required_capacity().is_some());
                    return a.used_bytes() as f64 / capacity as f64;
                }
            }
        } else {
            let i = rng.below(live.len() as u64) as usize;
            a.free(live.swap_remove(i)).unwrap();
        }
    }
}

#[test]
fn between_bins_churn_reaches_95_percent_utilisation() {
    for size in [1000u64, 1000 * 37, 3 * 1024 + 500] {
        // Sanity: the workload really falls between two bins.
        assert!(TlsfAllocator::size_class_floor(size) < size, "{size}");
        let u = ramp_utilisation(size, 4 << 20, 7);
        assert!(
            u >= 0.95,
            "size {size}: utilisation {u:.3} at first failure"
        );
    }
}

#[test]
fn defragment_moves_tail_ranges_down_within_budget() {
    let mut a = TlsfAllocator::new(1000);
    let hs: Vec<_> = (0..10).map(|_| a.allocate(100).unwrap()).collect();
    for h in hs.iter().step_by(2) {
        a.free(h.handle).unwrap();
    }
    assert_eq!(a.largest_free_block(), 100);
    let mut moves = Vec::new();
    let moved = a.defragment(250, &mut moves).unwrap();
    assert_eq!(moved, 200, "two 100-byte moves fit in a 250 budget");
    for m in &moves {
        assert!(m.to + m.len <= m.from);
        assert_eq!(a.get(m.handle).unwrap().offset, m.to);
    }
    a.check_invariants();
    moves.clear();
    a.defragment(u64::MAX, &mut moves).unwrap();
    a.check_invariants();
    // All five survivors are packed at the start.
    let s = a.stats();
    assert_eq!((s.free_block_count, s.largest_free_block), (1, 500));
    assert!(a.allocations().all(|x| x.end() <= 500));
}

// ---- property test against a brute-force model --------------------------

#[derive(Clone, Debug)]
enum Op {
    Alloc { size: u64, align_log2: u32 },
    Free(usize),
    Resize(usize, u64),
    DoubleFree(usize),
    Defrag(u64),
}

fn op_strategy() -> impl Strategy<Value = Op> {
    prop_oneof![
        4 => (1u64..3000, 0u32..9).prop_map(|(size, align_log2)| Op::Alloc { size, align_log2 }),
        3 => any::<usize>().prop_map(Op::Free),
        2 => (any::<usize>(), 1u64..4000).prop_map(|(i, s)| Op::Resize(i, s)),
        1 => any::<usize>().prop_map(Op::DoubleFree),
        1 => (0u64..5000).prop_map(Op::Defrag),
    ]
}

/// Free gaps between live ranges (the model's free blocks).
fn gaps(live: &[Allocation], capacity: u64) -> Vec<(u64, u64)> {
    let mut ranges: Vec<_> = live.iter().map(|x| (x.offset, x.end())).collect();
    ranges.sort_unstable();
    let mut out = Vec::new();
    let mut at = 0;
    for (s, e) in ranges {
        assert!(s >= at, "live ranges overlap");
        if s > at {
            out.push((at, s));
        }
        at = e;
    }
    assert!(at <= capacity, "live range beyond capacity");
    if at < capacity {
        out.push((at, capacity));
    }
    out
}

fn check_against_model(a: &TlsfAllocator, live: &[Allocation]) {
    a.check_invariants();
    let capacity = a.capacity();
    let g = gaps(live, capacity);
    let used: u64 = live.iter().map(|x| x.size).sum();
    let s = a.stats();
    assert_eq!(s.capacity, capacity);
    assert_eq!(s.used_bytes, used);
    assert_eq!(s.free_bytes, capacity - used);
    assert_eq!(s.allocation_count, live.len());
    assert_eq!(s.free_block_count, g.len());
    let largest = g.iter().map(|(s, e)| e - s).max().unwrap_or(0);
    assert_eq!(s.largest_free_block, largest);
    for x in live {
        assert_eq!(a.get(x.handle), Ok(*x));
    }
    let mut from_alloc: Vec<_> = a.allocations().collect();
    let mut from_model = live.to_vec();
    from_alloc.sort_by_key(|x| x.offset);
    from_model.sort_by_key(|x| x.offset);
    assert_eq!(from_alloc, from_model);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    #[test]
    fn random_sequences_match_brute_force_model(
        capacity in 0u64..40_000,
        ops in prop::collection::vec(op_strategy(), 1..120),
    ) {
        let mut a = TlsfAllocator::new(capacity);
        let mut live: Vec<Allocation> = Vec::new();
        let mut freed: Vec<AllocHandle> = Vec::new();
        let mut peak = 0u64;
        let mut high = 0u64;
        for op in ops {
            match op {
                Op::Alloc { size, align_log2 } => {
                    let align = 1u64 << align_log2;
                    match a.allocate_aligned(size, align) {
                        Ok(x) => {
                            prop_assert_eq!(x.size, size);
                            prop_assert_eq!(x.offset % align, 0);
                            live.push(x);
                        }
                        Err(AllocError::OutOfSpace { required_capacity, .. }) => {
                            // Growing to the reported capacity must suffice.
                            a.grow(required_capacity).unwrap();
                            let x = a.allocate_aligned(size, align).unwrap();
                            prop_assert_eq!(x.offset % align, 0);
                            live.push(x);
                        }
                        Err(e) => prop_assert!(false, "unexpected {e}"),
                    }
                }
                Op::Free(i) if !live.is_empty() => {
                    let x = live.swap_remove(i % live.len());
                    a.free(x.handle).unwrap();
                    freed.push(x.handle);
                }
                Op::Resize(i, new_size) if !live.is_empty() => {
                    let i = i % live.len();
                    let x = live[i];
                    // Model: room in place = size + free gap right after.
                    let next_start = live
                        .iter()
                        .map(|y| y.offset)
                        .filter(|&o| o >= x.end())
                        .min()
                        .unwrap_or(a.capacity());
                    let available = x.size + (next_start - x.end());
                    match a.resize(x.handle, new_size) {
                        Ok(y) => {
                            prop_assert!(new_size <= available);
                            prop_assert_eq!((y.offset, y.size, y.handle), (x.offset, new_size, x.handle));
                            live[i] = y;
                        }
                        Err(AllocError::CannotGrowInPlace { requested, available: av }) => {
                            prop_assert!(new_size > available);
                            prop_assert_eq!((requested, av), (new_size, available));
                        }
                        Err(e) => prop_assert!(false, "unexpected {e}"),
                    }
                }
                Op::DoubleFree(i) if !freed.is_empty() => {
                    let h = freed[i % freed.len()];
                    prop_assert_eq!(a.free(h), Err(AllocError::StaleHandle));
                }
                Op::Defrag(budget) => {
                    let mut moves = Vec::new();
                    let moved = a.defragment(budget, &mut moves).unwrap();
                    prop_assert!(moved <= budget);
                    prop_assert_eq!(moved, moves.iter().map(|m| m.len).sum::<u64>());
                    for m in moves {
                        let k = live.iter().position(|x| x.handle == m.handle).unwrap();
                        prop_assert_eq!((live[k].offset, live[k].size), (m.from, m.len));
                        prop_assert!(m.to + m.len <= m.from);
                        // The destination is free when the copy happens.
                        for (j, y) in live.iter().enumerate() {
                            prop_assert!(j == k || y.end() <= m.to || y.offset >= m.to + m.len);
                        }
                        live[k].offset = m.to;
                    }
                }
                _ => {}
            }
            let used: u64 = live.iter().map(|x| x.size).sum();
            peak = peak.max(used);
            high = high.max(live.iter().map(|x| x.end()).max().unwrap_or(0));
            check_against_model(&a, &live);
            let s = a.stats();
            prop_assert_eq!((s.peak_used_bytes, s.high_water_mark), (peak, high));
            prop_assert!(s.high_water_mark <= a.capacity());
        }
        // Freeing everything coalesces back to one block of the capacity.
        for x in live.drain(..) {
            a.free(x.handle).unwrap();
        }
        check_against_model(&a, &live);
        let s = a.stats();
        let expected_blocks = usize::from(a.capacity() > 0);
        prop_assert_eq!(s.free_block_count, expected_blocks);
        prop_assert_eq!(s.largest_free_block, a.capacity());
    }
}
