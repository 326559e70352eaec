use super::*;

fn key(mesh: u32, lod: u8) -> BlasKey {
    BlasKey {
        mesh: MeshId(mesh),
        lod: Lod(lod),
        variant: 0,
    }
}

fn cache(budget: u64, fif: u32) -> BlasCache {
    let mut c = BlasCache::new(CacheConfig {
        memory_budget: budget,
        frames_in_flight: fif,
        max_unused_frames: 1000,
    })
    .unwrap();
    c.begin_frame(1).unwrap();
    c
}

/// Acquires `k`, builds it with `bytes` (estimate = actual) and returns it.
fn built(c: &mut BlasCache, k: BlasKey, bytes: u64, op: u64) -> BlasId {
    let id = c.acquire_shared(k, false).unwrap().id();
    assert!(c.try_reserve_build(id, bytes, 64, BuildId(op)).unwrap());
    c.ack_built(BuildId(op), bytes, 0x1000 * op).unwrap();
    id
}

#[test]
fn refcount_acquire_release() {
    let mut c = cache(1 << 20, 2);
    let a = c.acquire_shared(key(1, 0), false).unwrap();
    let Lookup::Miss(id) = a else {
        panic!("first acquire must miss")
    };
    assert_eq!(c.acquire_shared(key(1, 0), false).unwrap(), Lookup::Hit(id));
    assert_eq!(c.get(id).unwrap().refs, 2);
    assert!(c.try_reserve_build(id, 100, 10, BuildId(1)).unwrap());
    c.ack_built(BuildId(1), 90, 0xA0).unwrap();
    c.release(id).unwrap();
    assert_eq!(c.get(id).unwrap().refs, 1);
    c.release(id).unwrap();
    // Unreferenced shared entries stay cached.
    assert_eq!(c.get(id).unwrap().refs, 0);
    assert_eq!(c.address(id), Some(0xA0));
    assert_eq!(c.release(id), Err(BlasError::NotReferenced(id)));
    let s = c.stats();
    assert_eq!((s.hits, s.misses, s.shared_bytes), (1, 1, 90));
}

#[test]
fn requested_entry_without_users_is_dropped() {
    let mut c = cache(1 << 20, 2);
    let id = c.acquire_shared(key(1, 0), false).unwrap().id();
    c.release(id).unwrap();
    assert!(c.get(id).is_none());
    assert!(c.lookup(&key(1, 0)).is_none());
    assert_eq!(c.release(id), Err(BlasError::StaleBlas(id)));
    assert_eq!(c.begin_frame(5).unwrap(), vec![], "nothing was allocated");
}

#[test]
fn eviction_is_lru_then_largest() {
    let mut c = cache(1000, 0);
    let a = built(&mut c, key(1, 0), 300, 1);
    c.release(a).unwrap(); // last used frame 1
    c.begin_frame(2).unwrap();
    let b = built(&mut c, key(2, 0), 200, 2);
    let cc = built(&mut c, key(3, 0), 400, 3);
    c.release(b).unwrap(); // both last used frame 2
    c.release(cc).unwrap();
    c.begin_frame(3).unwrap();
    assert_eq!(c.live_bytes(), 900);
    // 500 more: evict A (oldest, 300) -> 600 + 500 > 1000, then the larger of
    // the two frame-2 entries, C (400) -> 200 + 500 fits; B survives.
    let d = c.acquire_shared(key(4, 0), false).unwrap().id();
    assert!(c.try_reserve_build(d, 500, 0, BuildId(4)).unwrap());
    assert!(c.get(a).is_none());
    assert!(c.get(cc).is_none());
    assert!(c.get(b).is_some());
    assert_eq!(c.live_bytes(), 700);
    assert_eq!(c.stats().evictions, 2);
}

#[test]
fn referenced_and_in_flight_entries_are_never_evicted() {
    let mut c = cache(1000, 0);
    let a = built(&mut c, key(1, 0), 600, 1); // referenced
    let b = c.acquire_shared(key(2, 0), false).unwrap().id();
    assert!(c.try_reserve_build(b, 300, 0, BuildId(2)).unwrap());
    c.release(b).unwrap(); // unreferenced but building
    let d = c.acquire_shared(key(3, 0), false).unwrap().id();
    assert!(!c.try_reserve_build(d, 200, 0, BuildId(3)).unwrap());
    assert_eq!(c.get(d).unwrap().state, BlasState::Requested);
    assert!(c.get(a).is_some() && c.get(b).is_some());
    assert_eq!(
        c.stats().evictions,
        0,
        "a refused reservation evicts nothing"
    );
    // Once built, the unreferenced entry becomes evictable.
    c.ack_built(BuildId(2), 300, 0xB0).unwrap();
    assert!(c.try_reserve_build(d, 200, 0, BuildId(3)).unwrap());
    assert!(c.get(b).is_none());
}

#[test]
fn budget_holds_within_a_burst() {
    let budget = 10_000;
    let mut c = cache(budget, 2);
    // Fill the cache with unreferenced entries.
    for m in 0..20u32 {
        let id = built(&mut c, key(m, 0), 500, u64::from(m) + 1);
        c.release(id).unwrap();
        assert!(c.live_bytes() <= budget);
    }
    // A burst in the same frame, some of them referenced.
    let mut held = Vec::new();
    for m in 100..140u32 {
        let id = c.acquire_shared(key(m, 1), false).unwrap().id();
        let op = BuildId(u64::from(m) + 1000);
        if c.try_reserve_build(id, 700, 0, op).unwrap() {
            c.ack_built(op, 650, u64::from(m) * 16).unwrap();
            held.push(id);
        } else {
            c.release(id).unwrap();
        }
        assert!(c.live_bytes() <= budget, "budget broken within the burst");
    }
    // Every successful reservation needs 700 on top of what is held (650
    // each after its ack); unreferenced entries all yield.
    assert_eq!(held.len(), ((budget - 700) / 650 + 1) as usize);
}

#[test]
fn evicted_entry_needed_again_is_a_miss() {
    let mut c = cache(1000, 1);
    let a = built(&mut c, key(1, 0), 800, 1);
    c.release(a).unwrap();
    let b = c.acquire_shared(key(2, 0), false).unwrap().id();
    assert!(c.try_reserve_build(b, 800, 0, BuildId(2)).unwrap());
    assert!(c.lookup(&key(1, 0)).is_none());
    let again = c.acquire_shared(key(1, 0), false).unwrap();
    let Lookup::Miss(a2) = again else {
        panic!("must be a miss after eviction")
    };
    assert_ne!(a, a2, "handles are versioned");
    assert_eq!(c.get(a2).unwrap().state, BlasState::Requested);
    assert_eq!(c.get(a), None);
}

#[test]
fn frees_wait_for_frames_in_flight() {
    let mut c = cache(1 << 20, 2);
    c.begin_frame(5).unwrap();
    let u = c.create_unique(InstanceKey(3), MeshId(1), Lod(0));
    assert!(c.try_reserve_build(u, 100, 0, BuildId(1)).unwrap());
    c.ack_built(BuildId(1), 100, 0xC0).unwrap();
    c.release(u).unwrap(); // released during frame 5: frame 5 may still use it
    assert!(c.get(u).is_none(), "unique BLASes are not cached");
    assert_eq!(c.stats().pending_frees, 1);
    assert_eq!(c.stats().pending_free_bytes, 100);
    assert!(c.begin_frame(6).unwrap().is_empty());
    let frees = c.begin_frame(7).unwrap();
    assert_eq!(
        frees,
        vec![BlasFree {
            blas: u,
            created_by: BuildId(1),
            address: 0xC0,
            bytes: 100
        }]
    );
    assert_eq!(c.stats().pending_frees, 0);
    assert_eq!(c.stats().pending_free_bytes, 0);
}

#[test]
fn frame_jump_releases_everything_due() {
    let mut c = cache(1 << 20, 3);
    let u = c.create_unique(InstanceKey(3), MeshId(1), Lod(0));
    assert!(c.try_reserve_build(u, 100, 0, BuildId(1)).unwrap());
    c.ack_built(BuildId(1), 100, 0xC0).unwrap();
    c.release(u).unwrap();
    assert!(c.begin_frame(3).unwrap().is_empty());
    assert_eq!(c.begin_frame(100).unwrap().len(), 1);
    assert_eq!(
        c.begin_frame(100),
        Err(BlasError::NonMonotonicFrame {
            previous: 100,
            got: 100
        })
    );
}

#[test]
fn unique_released_while_building_is_freed_at_ack() {
    let mut c = cache(1 << 20, 1);
    let u = c.create_unique(InstanceKey(1), MeshId(1), Lod(0));
    assert!(c.try_reserve_build(u, 100, 32, BuildId(7)).unwrap());
    assert_eq!(c.stats().scratch_in_use, 32);
    c.release(u).unwrap();
    assert!(c.get(u).is_some(), "kept until its build is acknowledged");
    c.ack_built(BuildId(7), 90, 0xD0).unwrap();
    assert!(c.get(u).is_none());
    assert_eq!(c.stats().scratch_in_use, 0);
    assert_eq!(c.live_bytes(), 0);
    // Removed during frame 1 with one frame in flight: safe at frame 2.
    let frees = c.begin_frame(2).unwrap();
    assert_eq!(frees.len(), 1);
    assert_eq!((frees[0].address, frees[0].bytes), (0xD0, 90));
}

#[test]
fn unused_entries_are_evicted_after_max_unused_frames() {
    let mut c = BlasCache::new(CacheConfig {
        memory_budget: 1 << 20,
        frames_in_flight: 0,
        max_unused_frames: 10,
    })
    .unwrap();
    c.begin_frame(1).unwrap();
    let a = built(&mut c, key(1, 0), 100, 1);
    let b = built(&mut c, key(2, 0), 100, 2);
    c.release(a).unwrap();
    c.begin_frame(11).unwrap();
    assert!(c.get(a).is_some(), "10 unused frames are allowed");
    let frees = c.begin_frame(12).unwrap();
    assert!(c.get(a).is_none());
    assert_eq!(frees.len(), 1, "frames_in_flight = 0 frees at once");
    assert!(c.get(b).is_some(), "referenced entries never age out");
}

#[test]
fn compaction_flow() {
    let mut c = cache(1 << 20, 2);
    let k = key(1, 0);
    let id = c.acquire_shared(k, true).unwrap().id();
    assert!(c.try_reserve_build(id, 1000, 0, BuildId(1)).unwrap());
    c.ack_built(BuildId(1), 1000, 0xE0).unwrap();
    assert_eq!(c.compaction_candidates().count(), 0);
    c.begin_frame(3).unwrap();
    assert_eq!(c.ack_compacted_size(BuildId(1), 400).unwrap(), Some(id));
    assert_eq!(c.compaction_candidates().collect::<Vec<_>>(), vec![id]);
    assert!(c.try_begin_compaction(id, BuildId(2)).unwrap());
    // During the copy the old BLAS is used; both are accounted.
    assert_eq!(c.address(id), Some(0xE0));
    assert_eq!(
        (c.stats().shared_bytes, c.stats().compacted_bytes),
        (1000, 400)
    );
    c.begin_frame(4).unwrap();
    c.ack_compacted(BuildId(2), 0xF0).unwrap();
    assert_eq!(c.address(id), Some(0xF0));
    assert_eq!(c.created_by(id), Some(BuildId(2)));
    assert_eq!(
        c.get(id).unwrap().state,
        BlasState::Compacted {
            address: 0xF0,
            bytes: 400
        }
    );
    assert_eq!(
        (c.stats().shared_bytes, c.stats().compacted_bytes),
        (0, 400)
    );
    assert!(c.begin_frame(5).unwrap().is_empty());
    let frees = c.begin_frame(6).unwrap();
    assert_eq!(frees.len(), 1);
    assert_eq!((frees[0].address, frees[0].bytes), (0xE0, 1000));
    // Repeated or bogus acknowledgements are errors.
    assert_eq!(
        c.ack_compacted(BuildId(2), 0xF0),
        Err(BlasError::UnknownBuild(BuildId(2)))
    );
    assert_eq!(
        c.ack_compacted_size(BuildId(1), 400),
        Err(BlasError::UnknownBuild(BuildId(1)))
    );
}

#[test]
fn size_answer_for_evicted_blas_is_dropped() {
    let mut c = cache(1000, 0);
    let id = c.acquire_shared(key(1, 0), true).unwrap().id();
    assert!(c.try_reserve_build(id, 800, 0, BuildId(1)).unwrap());
    c.ack_built(BuildId(1), 800, 0xE0).unwrap();
    c.release(id).unwrap();
    assert_eq!(c.trim(), 1);
    assert_eq!(c.ack_compacted_size(BuildId(1), 300), Ok(None));
    assert_eq!(
        c.ack_compacted_size(BuildId(1), 300),
        Err(BlasError::UnknownBuild(BuildId(1))),
        "a second answer is an error"
    );
}

#[test]
fn invalid_acks_and_config_are_errors() {
    assert!(matches!(
        BlasCache::new(CacheConfig {
            memory_budget: 0,
            ..CacheConfig::default()
        }),
        Err(BlasError::InvalidConfig(_))
    ));
    let mut c = cache(1000, 0);
    let id = c.acquire_shared(key(1, 0), false).unwrap().id();
    assert!(c.try_reserve_build(id, 100, 0, BuildId(1)).unwrap());
    assert!(matches!(
        c.ack_built(BuildId(1), 100, 0),
        Err(BlasError::InvalidAck(_))
    ));
    assert!(matches!(
        c.ack_built(BuildId(1), 0, 5),
        Err(BlasError::InvalidAck(_))
    ));
    assert_eq!(
        c.ack_built(BuildId(9), 100, 5),
        Err(BlasError::UnknownBuild(BuildId(9)))
    );
    c.ack_built(BuildId(1), 100, 5).unwrap();
    assert_eq!(
        c.ack_built(BuildId(1), 100, 5),
        Err(BlasError::UnknownBuild(BuildId(1)))
    );
    assert!(matches!(
        c.try_reserve_build(id, 1, 0, BuildId(2)),
        Err(BlasError::WrongState { .. })
    ));
    assert!(matches!(
        c.try_begin_compaction(id, BuildId(2)),
        Err(BlasError::WrongState { .. })
    ));
}

#[test]
fn entries_sum_to_the_live_bytes() {
    let mut c = cache(1 << 20, 2);
    let a = built(&mut c, key(1, 0), 300, 1);
    let b = built(&mut c, key(2, 0), 500, 2);
    c.release(b).unwrap();
    let u = c.create_unique(InstanceKey(7), MeshId(3), Lod(0));
    assert!(c.try_reserve_build(u, 200, 64, BuildId(3)).unwrap());
    let mut seen: Vec<(bool, u32, u64)> = c
        .entries()
        .map(|(_, info, bytes)| (info.owner.is_shared(), info.refs, bytes))
        .collect();
    seen.sort_unstable();
    // The unique build counts its reserved estimate; the released shared
    // entry is still cached with no user.
    assert_eq!(seen, vec![(false, 1, 200), (true, 0, 500), (true, 1, 300)]);
    let total: u64 = c.entries().map(|(_, _, b)| b).sum();
    assert_eq!(total, c.live_bytes());
    assert!(c.entries().any(|(id, _, _)| id == a));
}
