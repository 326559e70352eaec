use super::*;
use crate::grid::{GridConfig, HitboxGrid};
use proptest::prelude::*;
use std::collections::HashMap;

fn config(cell: f64) -> HashedConfig {
    HashedConfig {
        cell_size: cell,
        ..HashedConfig::default()
    }
}

/// A 0.5 m box around the centre of cell `(cx, cz)` of a 1 m grid.
fn in_cell(cx: i32, cz: i32) -> Aabb {
    let (x, z) = (cx as f32 + 0.5, cz as f32 + 0.5);
    Aabb::new(
        Vec3::new(x - 0.25, 0.0, z - 0.25),
        Vec3::new(x + 0.25, 1.0, z + 0.25),
    )
}

fn tiny(initial_buckets: u32, max_cells: u32, fingerprint_bits: u32) -> HashedHitboxes {
    HashedHitboxes::new(HashedConfig {
        cell_size: 1.0,
        max_cells,
        evict_after_frames: 2,
        initial_buckets,
        fingerprint_bits,
        ..HashedConfig::default()
    })
    .unwrap()
}

#[test]
fn rejects_invalid_configs() {
    let bad = [
        HashedConfig {
            cell_size: 0.0,
            ..HashedConfig::default()
        },
        HashedConfig {
            cell_size: f64::INFINITY,
            ..HashedConfig::default()
        },
        HashedConfig {
            origin: [f64::NAN, 0.0],
            ..HashedConfig::default()
        },
        HashedConfig {
            max_cells: 0,
            ..HashedConfig::default()
        },
        HashedConfig {
            max_cells: (1 << 24) + 1,
            ..HashedConfig::default()
        },
        HashedConfig {
            initial_buckets: 12,
            ..HashedConfig::default()
        },
        HashedConfig {
            initial_buckets: 1,
            ..HashedConfig::default()
        },
        HashedConfig {
            fingerprint_bits: 0,
            ..HashedConfig::default()
        },
        HashedConfig {
            fingerprint_bits: 33,
            ..HashedConfig::default()
        },
    ];
    for c in bad {
        match HashedHitboxes::new(c) {
            Err(CoreError::InvalidConfig { what }) => assert!(!what.is_empty()),
            other => panic!("{c:?} gave {other:?}"),
        }
    }
}

#[test]
fn cells_are_half_open_and_unbounded() {
    let mut h = HashedHitboxes::new(config(16.0)).unwrap();
    assert_eq!(h.cell_at(0.0, 0.0), Some((0, 0)));
    assert_eq!(h.cell_at(-1e-9, 16.0), Some((-1, 1)));
    assert_eq!(h.cell_at(-16.0, -16.000001), Some((-1, -2)));
    // 100 000 km out: still a cell (i32 coordinates reach 34 000 000 km).
    assert_eq!(h.cell_at(1.0e8, -1.0e8), Some((6_250_000, -6_250_000)));
    assert_eq!(h.cell_at(f64::NAN, 0.0), None);
    assert_eq!(h.cell_at(1.0e300, 0.0), None);
    let far = Aabb::new(Vec3::splat(3.0e38), Vec3::splat(3.0e38));
    assert!(matches!(
        h.occupy(&far),
        Err(CoreError::OutsideWorld { .. })
    ));
    assert_eq!(h.len(), 0);
    // Bounds of a negative cell, exact in f32.
    let i = h
        .occupy(&Aabb::new(
            Vec3::new(-20.0, 0.0, 40.0),
            Vec3::new(-18.0, 1.0, 42.0),
        ))
        .unwrap();
    assert_eq!(h.cell(i), Some((-2, 2)));
    assert_eq!(
        h.xz_bounds(i),
        Some((Vec2::new(-32.0, 32.0), Vec2::new(-16.0, 48.0)))
    );
    assert_eq!(h.xz_bounds(i + 1), None);
}

#[test]
fn cells_match_the_grid_with_the_same_origin() {
    // Unaligned origin: borders are not f32 values; the cell found for
    // points and exact AABB centres is the grid's, index for index.
    let gc = GridConfig {
        min: [-100_000.3, 99_000.7],
        max: [-99_000.0, 100_000.0],
        cell_size: 16.1,
    };
    let grid = HitboxGrid::new(gc).unwrap();
    let h = HashedHitboxes::new(HashedConfig {
        origin: gc.min,
        cell_size: gc.cell_size,
        ..HashedConfig::default()
    })
    .unwrap();
    let (nx, nz) = grid.dims();
    for k in 1..nx {
        let border = gc.min[0] + f64::from(k) * gc.cell_size;
        let p = border as f32;
        for x in [
            f32::from_bits(p.to_bits() - 1),
            p,
            f32::from_bits(p.to_bits() + 1),
        ] {
            for z in [99_001.0f32, 99_500.25, 99_999.0] {
                let g = grid.cell_at(x.into(), z.into()).unwrap();
                let c = h.cell_at(x.into(), z.into()).unwrap();
                assert_eq!((g.0 as i32, g.1 as i32), c, "x = {x}, z = {z}");
                let aabb = Aabb::new(
                    Vec3::new(x, 0.0, z),
                    Vec3::new(f32::from_bits(x.to_bits() + 1), 1.0, z),
                );
                let g = grid.cell_of_aabb_center(&aabb).unwrap();
                assert_eq!(Some((g.0 as i32, g.1 as i32)), h.cell_of_aabb_center(&aabb));
            }
        }
    }
    assert!(nz > 1);
}

#[test]
fn bounds_equal_the_grids_for_the_same_cell() {
    let gc = GridConfig {
        min: [-100_000.3, 7.77],
        max: [-99_000.0, 100.0],
        cell_size: 16.1,
    };
    let grid = HitboxGrid::new(gc).unwrap();
    let mut h = HashedHitboxes::new(HashedConfig {
        origin: gc.min,
        cell_size: gc.cell_size,
        ..HashedConfig::default()
    })
    .unwrap();
    for i in 0..grid.len() {
        let (lo, hi) = grid.bounds_f64(i).unwrap();
        let centre = Vec3::new(
            ((lo[0] + hi[0]) / 2.0) as f32,
            0.0,
            ((lo[1] + hi[1]) / 2.0) as f32,
        );
        let j = h.occupy(&Aabb::new(centre, centre)).unwrap();
        assert_eq!(j, i, "cells occupied in grid order get the grid's indices");
        assert_eq!(h.bounds_f64(j), Some((lo, hi)));
        assert_eq!(h.xz_bounds(j), grid.xz_bounds(i));
    }
}

#[test]
fn probing_wraps_around_the_table_end_and_removal_keeps_runs_intact() {
    // 8 buckets (no growth up to 4 cells): three keys whose home is the
    // last bucket fill buckets 7, 0 and 1.
    let mut h = tiny(8, 4, 32);
    let keys: Vec<[i32; 2]> = (0..10_000)
        .map(|i| [i % 100 - 50, i / 100 - 50])
        .filter(|&k| hash(k) as usize & 7 == 7)
        .take(3)
        .collect();
    assert_eq!(keys.len(), 3);
    let idx: Vec<u32> = keys
        .iter()
        .map(|k| h.occupy(&in_cell(k[0], k[1])).unwrap())
        .collect();
    assert_eq!(h.buckets(), 8);
    let at = |h: &HashedHitboxes, k: [i32; 2]| h.find(k).ok();
    assert_eq!(at(&h, keys[0]), Some(7));
    assert_eq!(at(&h, keys[1]), Some(0));
    assert_eq!(at(&h, keys[2]), Some(1));
    // Evict the first: the two behind it shift back and stay reachable.
    h.vacate(idx[0]);
    let mut ev = Vec::new();
    h.begin_frame(2, &mut ev);
    assert_eq!(ev, vec![idx[0]]);
    assert_eq!(at(&h, keys[0]), None);
    assert_eq!(h.index(keys[1][0], keys[1][1]), Some(idx[1]));
    assert_eq!(h.index(keys[2][0], keys[2][1]), Some(idx[2]));
    assert_eq!(at(&h, keys[1]), Some(7));
}

#[test]
fn fingerprint_collisions_are_resolved_by_the_full_key() {
    // One fingerprint bit: every stored fingerprint is 1.
    let mut h = tiny(2, 64, 1);
    let mut expected = Vec::new();
    for cx in -4..4 {
        for cz in -4..4 {
            expected.push(((cx, cz), h.occupy(&in_cell(cx, cz)).unwrap()));
        }
    }
    assert!(h.table.iter().all(|b| b.fingerprint <= 1));
    assert_eq!(h.live_cells(), 64);
    for ((cx, cz), i) in expected {
        assert_eq!(h.index(cx, cz), Some(i));
        assert_eq!(h.cell(i), Some((cx, cz)));
        assert_eq!(h.occupants(i), 1);
    }
}

#[test]
fn a_full_index_refuses_a_new_cell_with_an_error() {
    let mut h = tiny(2, 3, 32);
    for cx in 0..3 {
        h.occupy(&in_cell(cx, 0)).unwrap();
    }
    let e = h.occupy(&in_cell(3, 0)).unwrap_err();
    assert!(
        matches!(e, CoreError::TooManyHitboxes { limit: 3, .. }),
        "{e:?}"
    );
    assert!(e.to_string().contains("all 3 hitboxes"), "{e}");
    // Existing cells still take instances; nothing changed.
    assert_eq!(h.occupy(&in_cell(1, 0)), Ok(1));
    assert_eq!((h.len(), h.live_cells()), (3, 3));
}

#[test]
fn empty_cells_decay_then_their_indices_are_reused() {
    let mut h = tiny(4, 16, 32);
    let a = h.occupy(&in_cell(0, 0)).unwrap();
    let b = h.occupy(&in_cell(5, 5)).unwrap();
    assert_eq!((a, b), (0, 1));
    let mut ev = Vec::new();
    h.begin_frame(10, &mut ev);
    h.vacate(a);
    h.begin_frame(11, &mut ev);
    assert!(ev.is_empty(), "kept for evict_after_frames = 2");
    // Re-occupied before it decays: the countdown is void.
    assert_eq!(h.occupy(&in_cell(0, 0)), Ok(a));
    h.begin_frame(13, &mut ev);
    assert!(ev.is_empty());
    h.vacate(a);
    h.begin_frame(15, &mut ev);
    assert_eq!(ev, vec![a]);
    assert_eq!(h.index(0, 0), None);
    assert_eq!(h.xz_bounds(a), None);
    assert_eq!(h.len(), 2, "indices stay dense: 0 is free, not gone");
    // A new cell takes the freed index.
    assert_eq!(h.occupy(&in_cell(-7, 3)), Ok(a));
    assert_eq!(h.cell(a), Some((-7, 3)));
    // Vacating an index without a cell or instances is ignored.
    h.vacate(99);
    h.vacate(b);
    h.vacate(b);
    assert_eq!(h.occupants(b), 0);
}

#[test]
fn growth_keeps_indices_and_memory_follows_the_cells() {
    let mut h = tiny(2, 1 << 20, 32);
    let mut idx = HashMap::new();
    for i in 0..5000 {
        let k = (i * 7919 % 10_007 - 5000, i * 104_729 % 10_009 - 5000);
        idx.entry(k)
            .or_insert_with(|| h.occupy(&in_cell(k.0, k.1)).unwrap());
    }
    assert!(h.buckets() >= 2 * idx.len() && h.buckets() <= 4 * idx.len());
    for (&(cx, cz), &i) in &idx {
        assert_eq!(h.index(cx, cz), Some(i));
    }
    assert_eq!(
        h.memory_bytes(),
        idx.len() as u64 * crate::grid::HITBOX_BYTES
    );
    assert!(h.heap_bytes() <= (4 * 16 + 2 * 24) * idx.len() as u64 + 4096);
}

/// The reference: a HashMap from cell to (index, occupants, empty since).
#[derive(Default)]
struct Model {
    cells: HashMap<[i32; 2], (u32, u32, u64)>,
    free: Vec<u32>,
    len: u32,
    frame: u64,
}

#[derive(Clone, Debug)]
enum Op {
    Occupy(i32, i32),
    Vacate(usize),
    Frame(u64),
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        4 => (-6i32..6, -6i32..6).prop_map(|(x, z)| Op::Occupy(x, z)),
        3 => (0usize..64).prop_map(Op::Vacate),
        1 => (0u64..4).prop_map(Op::Frame),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]
    #[test]
    fn matches_a_hash_map_model(
        ops in proptest::collection::vec(op(), 1..200),
        initial in prop_oneof![Just(2u32), Just(4), Just(64)],
        bits in prop_oneof![Just(1u32), Just(2), Just(32)],
        max_cells in 1u32..40,
    ) {
        let evict_after = 2u64;
        let mut h = HashedHitboxes::new(HashedConfig {
            cell_size: 1.0,
            max_cells,
            evict_after_frames: evict_after as u32,
            initial_buckets: initial,
            fingerprint_bits: bits,
            ..HashedConfig::default()
        }).unwrap();
        let mut m = Model::default();
        let mut occupied: Vec<u32> = Vec::new(); // one entry per occupant
        for op in ops {
            match op {
                Op::Occupy(x, z) => {
                    let got = h.occupy(&in_cell(x, z));
                    let live = m.cells.len() as u32;
                    let want = match m.cells.get_mut(&[x, z]) {
                        Some(c) => { c.1 += 1; Ok(c.0) }
                        None if live >= max_cells => Err(()),
                        None => {
                            m.free.sort_unstable_by(|a, b| b.cmp(a));
                            let i = m.free.pop().unwrap_or_else(|| { m.len += 1; m.len - 1 });
                            m.cells.insert([x, z], (i, 1, 0));
                            Ok(i)
                        }
                    };
                    match (got, want) {
                        (Ok(g), Ok(w)) => { prop_assert_eq!(g, w); occupied.push(g); }
                        (Err(CoreError::TooManyHitboxes { limit, .. }), Err(())) => {
                            prop_assert_eq!(limit, max_cells);
                        }
                        (g, w) => prop_assert!(false, "got {:?}, model {:?}", g, w),
                    }
                }
                Op::Vacate(k) => {
                    if occupied.is_empty() { continue; }
                    let i = occupied.swap_remove(k % occupied.len());
                    h.vacate(i);
                    let frame = m.frame;
                    let c = m.cells.values_mut().find(|c| c.0 == i).unwrap();
                    c.1 -= 1;
                    if c.1 == 0 { c.2 = frame; }
                }
                Op::Frame(d) => {
                    m.frame += d;
                    let mut ev = Vec::new();
                    h.begin_frame(m.frame, &mut ev);
                    let frame = m.frame;
                    let mut want: Vec<u32> = m.cells.values()
                        .filter(|c| c.1 == 0 && c.2 + evict_after <= frame)
                        .map(|c| c.0).collect();
                    m.cells.retain(|_, c| !(c.1 == 0 && c.2 + evict_after <= frame));
                    m.free.extend(&want);
                    want.sort_unstable();
                    ev.sort_unstable();
                    prop_assert_eq!(ev, want);
                }
            }
            prop_assert_eq!(h.len(), m.len);
            prop_assert_eq!(h.live_cells() as usize, m.cells.len());
            for (&[x, z], &(i, n, _)) in &m.cells {
                prop_assert_eq!(h.index(x, z), Some(i));
                prop_assert_eq!(h.cell(i), Some((x, z)));
                prop_assert_eq!(h.occupants(i), n);
                prop_assert_eq!(h.hitbox_of(&in_cell(x, z)), Some(i));
            }
            for x in -6..6 {
                for z in -6..6 {
                    if !m.cells.contains_key(&[x, z]) {
                        prop_assert_eq!(h.index(x, z), None);
                    }
                }
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    /// A consumer that keeps a copy of the bounds and rewrites only the
    /// logged indices (as lipac-vk does once per frame, between frame
    /// starts) always holds the bounds of every index; one that reads the
    /// log less often either gets all it missed or `None` (re-read all).
    #[test]
    fn the_bounds_log_keeps_a_per_frame_mirror_exact(
        ops in proptest::collection::vec(op(), 1..200),
        skip in 0usize..4,
    ) {
        let mut h = tiny(2, 40, 32);
        let bounds = |h: &HashedHitboxes, i: u32| h.xz_bounds(i);
        let mut mirror: Vec<Option<(Vec2, Vec2)>> = Vec::new();
        let mut seen = 0u64;
        let mut sparse: Vec<Option<(Vec2, Vec2)>> = Vec::new();
        let mut sparse_seen = 0u64;
        let mut occupied: Vec<u32> = Vec::new();
        let mut frame = 0u64;
        let sync = |h: &HashedHitboxes, m: &mut Vec<Option<(Vec2, Vec2)>>, seen: &mut u64| -> bool {
            m.resize(h.len() as usize, None);
            let log = h.bounds_changes();
            let full = match log.since(*seen) {
                Some(changed) => {
                    for &i in changed {
                        m[i as usize] = bounds(h, i);
                    }
                    false
                }
                None => {
                    for i in 0..h.len() {
                        m[i as usize] = bounds(h, i);
                    }
                    true
                }
            };
            *seen = log.total;
            full
        };
        for op in ops {
            match op {
                Op::Occupy(x, z) => {
                    if let Ok(i) = h.occupy(&in_cell(x, z)) {
                        occupied.push(i);
                    }
                }
                Op::Vacate(k) => {
                    if !occupied.is_empty() {
                        h.vacate(occupied.swap_remove(k % occupied.len()));
                    }
                }
                Op::Frame(d) => {
                    frame += d + 1;
                    let mut ev = Vec::new();
                    h.begin_frame(frame, &mut ev);
                    // The per-frame consumer reads the log after every frame start.
                    prop_assert!(!sync(&h, &mut mirror, &mut seen), "a per-frame reader never loses changes");
                    for i in 0..h.len() {
                        prop_assert_eq!(mirror[i as usize], bounds(&h, i), "index {}", i);
                    }
                    if frame % (skip as u64 + 1) == 0 {
                        sync(&h, &mut sparse, &mut sparse_seen);
                        for i in 0..h.len() {
                            prop_assert_eq!(sparse[i as usize], bounds(&h, i));
                        }
                    }
                }
            }
        }
        // Changes since the last frame start are in the log as well.
        prop_assert!(!sync(&h, &mut mirror, &mut seen));
        for i in 0..h.len() {
            prop_assert_eq!(mirror[i as usize], bounds(&h, i));
        }
    }
}

#[test]
fn the_grid_reports_no_bounds_changes_and_a_foreign_count_rereads() {
    let grid = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [4.0, 4.0],
        cell_size: 1.0,
    })
    .unwrap();
    assert_eq!(grid.bounds_changes().total, 0);
    assert_eq!(grid.bounds_changes().since(0), Some(&[][..]));
    let mut h = tiny(4, 16, 32);
    let a = h.occupy(&in_cell(0, 0)).unwrap();
    let b = h.occupy(&in_cell(3, 1)).unwrap();
    let log = h.bounds_changes();
    assert_eq!((log.total, log.since(0)), (2, Some(&[a, b][..])));
    assert_eq!(log.since(3), None, "ahead of the log: re-read all");
    // Eviction logs the index too; two frame starts later the old entries go.
    h.vacate(a);
    let mut ev = Vec::new();
    h.begin_frame(2, &mut ev);
    assert_eq!(ev, vec![a]);
    assert_eq!(h.bounds_changes().since(2), Some(&[a][..]));
    h.begin_frame(3, &mut ev);
    h.begin_frame(4, &mut ev);
    let log = h.bounds_changes();
    assert_eq!((log.total, log.recent.len()), (3, 0));
    assert_eq!(log.since(0), None, "the first changes were dropped");
}
