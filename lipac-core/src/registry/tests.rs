use super::*;
use crate::grid::GridConfig;
use glam::Vec3;
use proptest::prelude::*;
use std::collections::{BTreeSet, HashMap, HashSet};

/// 128 x 128 m world, 16 m cells: 8 x 8 hitboxes.
fn grid() -> HitboxGrid {
    HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [128.0, 128.0],
        cell_size: 16.0,
    })
    .unwrap()
}

fn registry(quarantine_frames: u32) -> InstanceRegistry {
    InstanceRegistry::new(
        grid(),
        RegistryConfig {
            quarantine_frames,
            ..RegistryConfig::default()
        },
    )
    .unwrap()
}

/// A 2 m box centred at (x, 1, z) with a matching translation.
fn desc_at(mesh: u32, x: f32, z: f32) -> InstanceDesc {
    let c = Vec3::new(x, 1.0, z);
    InstanceDesc::new(
        MeshId(mesh),
        Affine3A::from_translation(c),
        Aabb::new(c - Vec3::ONE, c + Vec3::ONE),
    )
}

/// Everything observable about a registry, for "nothing changed" checks.
fn snapshot(r: &InstanceRegistry) -> (Vec<InstanceRecord>, Vec<(InstanceHandle, u32)>, usize) {
    let mut live: Vec<_> = r.iter().collect();
    live.sort();
    (r.records().to_vec(), live, r.free_slots() as usize)
}

#[test]
fn new_instances_are_inactive_alive_and_match_their_description() {
    let mut r = registry(4);
    let d = InstanceDesc {
        lod: 3,
        flags: InstanceFlags::UNIQUE_BLAS | InstanceFlags::VEGETATION,
        mask: 0x81,
        sbt_offset: 0x12_3456,
        vk_flags: crate::layout::VK_INSTANCE_FORCE_OPAQUE,
        ..desc_at(9, 40.0, 20.0)
    };
    let h = r.register(d).unwrap();
    let rec = r.record(h).unwrap();
    assert!(rec.is_alive());
    assert_eq!(rec.state(), InstanceState::Inactive);
    assert_eq!(rec.blas, 0);
    assert!(rec.needs_unique_blas());
    assert_eq!(
        rec.packed & instance_bits::VEGETATION,
        instance_bits::VEGETATION
    );
    assert_eq!(rec.packed & instance_bits::STATIC, 0);
    assert_eq!(rec.mask(), 0x81);
    assert_eq!(rec.vk_flags(), crate::layout::VK_INSTANCE_FORCE_OPAQUE);
    assert_eq!(rec.sbt_offset, 0x12_3456);
    assert_eq!(rec.lod, 3);
    // Centre (40, 20) is in cell (2, 1) of an 8-wide grid.
    assert_eq!(rec.hitbox, 2 + 8);
    assert_eq!(rec.transform[3], 40.0);
    assert_eq!(rec.transform[7], 1.0);
    assert_eq!(rec.transform[11], 20.0);
    assert_eq!(rec.aabb_min, [39.0, 0.0, 19.0]);
    assert_eq!(rec.aabb_max, [41.0, 2.0, 21.0]);
    assert_eq!(r.mesh(h).unwrap(), MeshId(9));
    assert_eq!(r.lod(h).unwrap(), 3);
    assert_eq!(r.flags(h).unwrap(), d.flags);
    assert_eq!(r.desc(h).unwrap(), d);
}

#[test]
fn stale_handles_are_errors_everywhere() {
    let mut r = registry(4);
    let h = r.register(desc_at(1, 8.0, 8.0)).unwrap();
    let keep = r.register(desc_at(1, 24.0, 8.0)).unwrap();
    r.remove(h).unwrap();
    let is_stale = |e: CoreError| {
        matches!(
            e,
            CoreError::StaleHandle {
                kind: "instance",
                ..
            }
        )
    };
    assert!(!r.contains(h));
    assert!(is_stale(r.slot(h).unwrap_err()));
    assert!(is_stale(r.record(h).unwrap_err()));
    assert!(is_stale(r.desc(h).unwrap_err()));
    assert!(is_stale(r.mesh(h).unwrap_err()));
    assert!(is_stale(r.state(h).unwrap_err()));
    assert!(is_stale(r.remove(h).unwrap_err()));
    assert!(is_stale(r.update(h, desc_at(1, 8.0, 8.0)).unwrap_err()));
    assert!(is_stale(r.set_lod(h, 2).unwrap_err()));
    assert!(is_stale(r.set_blas(h, 5).unwrap_err()));
    assert!(is_stale(
        r.set_state_of(h, InstanceState::Active).unwrap_err()
    ));
    // A stale handle stays stale after its slot is reused.
    r.begin_frame(4).unwrap();
    let n = r.register(desc_at(2, 8.0, 8.0)).unwrap();
    assert_eq!(r.slot(n).unwrap(), 0);
    assert!(is_stale(r.slot(h).unwrap_err()));
    assert_eq!(r.slot(keep).unwrap(), 1);
}

#[test]
fn invalid_input_is_rejected_and_changes_nothing() {
    let mut r = registry(4);
    let h = r.register(desc_at(1, 8.0, 8.0)).unwrap();
    r.take_dirty();
    let before = snapshot(&r);

    let mut nan_t = desc_at(1, 8.0, 8.0);
    nan_t.transform.translation.y = f32::NAN;
    match r.update(h, nan_t).unwrap_err() {
        CoreError::NonFiniteTransform { element, value } => {
            assert_eq!(element, 7); // row 1, column 3 = translation.y
            assert!(value.is_nan());
        }
        e => panic!("{e}"),
    }
    assert!(r.register(nan_t).is_err());

    let mut inf_t = desc_at(1, 8.0, 8.0);
    inf_t.transform.matrix3.x_axis.z = f32::INFINITY;
    assert!(matches!(
        r.register(inf_t),
        Err(CoreError::NonFiniteTransform { element: 8, .. })
    ));

    let mut nan_box = desc_at(1, 8.0, 8.0);
    nan_box.aabb.max.z = f32::NAN;
    assert!(matches!(
        r.register(nan_box),
        Err(CoreError::InvalidAabb { .. })
    ));
    assert!(matches!(
        r.set_transform(h, nan_box.transform, nan_box.aabb),
        Err(CoreError::InvalidAabb { .. })
    ));

    let mut inverted = desc_at(1, 8.0, 8.0);
    inverted.aabb.min.y = 5.0;
    match r.register(inverted).unwrap_err() {
        CoreError::InvalidAabb { reason, .. } => assert!(reason.contains("min.y = 5"), "{reason}"),
        e => panic!("{e}"),
    }

    let mut huge = desc_at(1, 8.0, 8.0);
    huge.aabb.min.x = -2.0e6;
    huge.aabb.max.x = 2.0e6;
    match r.register(huge).unwrap_err() {
        CoreError::InvalidAabb { reason, .. } => assert!(reason.contains("along x"), "{reason}"),
        e => panic!("{e}"),
    }
    // Finite corners whose difference overflows f32.
    huge.aabb.min.x = -3.0e38;
    huge.aabb.max.x = 3.0e38;
    assert!(matches!(
        r.register(huge),
        Err(CoreError::InvalidAabb { .. })
    ));

    let outside = desc_at(1, 130.0, 8.0);
    assert_eq!(
        r.register(outside).unwrap_err(),
        CoreError::OutsideWorld {
            center: Vec3::new(130.0, 1.0, 8.0)
        }
    );
    assert!(matches!(
        r.update(h, outside),
        Err(CoreError::OutsideWorld { .. })
    ));

    let big_sbt = InstanceDesc {
        sbt_offset: 1 << 24,
        ..desc_at(1, 8.0, 8.0)
    };
    assert!(matches!(
        r.update(h, big_sbt),
        Err(CoreError::FieldOutOfRange {
            field: "sbt_offset",
            ..
        })
    ));

    assert_eq!(snapshot(&r), before);
    assert_eq!(r.len(), 1);
    assert_eq!(r.registration_count(), 1);
    assert!(!r.has_dirty(), "a failed call marked slots dirty");
    assert_eq!(r.desc(h).unwrap(), desc_at(1, 8.0, 8.0));
    // The next valid registration gets the next slot: nothing was reserved.
    let n = r.register(desc_at(1, 8.0, 8.0)).unwrap();
    assert_eq!(r.slot(n).unwrap(), 1);
}

#[test]
fn zero_extent_boxes_are_accepted() {
    let mut r = registry(4);
    let c = Vec3::new(20.0, 3.0, 20.0);
    let d = InstanceDesc::new(MeshId(0), Affine3A::from_translation(c), Aabb::new(c, c));
    let h = r.register(d).unwrap();
    assert_eq!(r.record(h).unwrap().aabb_min, r.record(h).unwrap().aabb_max);
}

#[test]
fn slots_are_reused_only_after_quarantine_lowest_first() {
    let mut r = registry(4);
    let hs: Vec<_> = (0..6)
        .map(|i| r.register(desc_at(i, 8.0 + i as f32, 8.0)).unwrap())
        .collect();
    r.begin_frame(10).unwrap();
    // Removed at frame 10 (slots 3, 5) and 11 (slot 1).
    r.remove(hs[5]).unwrap();
    r.remove(hs[3]).unwrap();
    r.begin_frame(11).unwrap();
    r.remove(hs[1]).unwrap();
    assert_eq!(r.quarantined_slots(), 3);
    for s in [1, 3, 5] {
        assert_eq!(r.handle_at(s), None);
        assert!(!r.record_at(s).unwrap().is_alive());
        assert_eq!(
            r.set_state(s, InstanceState::Active),
            Err(CoreError::NoInstanceAtSlot { slot: s })
        );
    }
    assert_eq!(r.begin_frame(13).unwrap(), 0);
    // Still quarantined: a new instance gets a new slot at the end.
    let a = r.register(desc_at(10, 8.0, 8.0)).unwrap();
    assert_eq!(r.slot(a).unwrap(), 6);
    // Frame 14 = 10 + 4 releases 3 and 5, not 1.
    assert_eq!(r.begin_frame(14).unwrap(), 2);
    assert_eq!(r.free_slots(), 2);
    let b = r.register(desc_at(11, 8.0, 8.0)).unwrap();
    assert_eq!(r.slot(b).unwrap(), 3);
    assert_eq!(r.begin_frame(15).unwrap(), 1);
    let c = r.register(desc_at(12, 8.0, 8.0)).unwrap();
    let d = r.register(desc_at(13, 8.0, 8.0)).unwrap();
    let e = r.register(desc_at(14, 8.0, 8.0)).unwrap();
    assert_eq!(
        [r.slot(c).unwrap(), r.slot(d).unwrap(), r.slot(e).unwrap()],
        [1, 5, 7]
    );
    assert_eq!(r.handle_at(1), Some(c));
    assert_eq!(r.slot_count(), 8);
}

#[test]
fn zero_quarantine_reuses_immediately() {
    let mut r = registry(0);
    let a = r.register(desc_at(0, 8.0, 8.0)).unwrap();
    r.register(desc_at(0, 8.0, 8.0)).unwrap();
    r.remove(a).unwrap();
    let c = r.register(desc_at(0, 8.0, 8.0)).unwrap();
    assert_eq!(r.slot(c).unwrap(), 0);
}

#[test]
fn frames_must_not_go_backwards() {
    let mut r = registry(4);
    r.begin_frame(7).unwrap();
    r.begin_frame(7).unwrap();
    assert_eq!(
        r.begin_frame(6),
        Err(CoreError::FrameOrder {
            current: 7,
            given: 6
        })
    );
    assert_eq!(r.frame(), 7);
}

#[test]
fn slot_limit_counts_quarantined_slots() {
    let mut r = InstanceRegistry::new(
        grid(),
        RegistryConfig {
            max_slots: 2,
            ..RegistryConfig::default()
        },
    )
    .unwrap();
    let a = r.register(desc_at(0, 8.0, 8.0)).unwrap();
    r.register(desc_at(0, 8.0, 8.0)).unwrap();
    r.remove(a).unwrap();
    assert_eq!(
        r.register(desc_at(0, 8.0, 8.0)),
        Err(CoreError::TooManyInstances {
            limit: 2,
            quarantined: 1
        })
    );
    r.begin_frame(4).unwrap();
    assert!(r.register(desc_at(0, 8.0, 8.0)).is_ok());
}

#[test]
fn invalid_configs_are_rejected() {
    for config in [
        RegistryConfig {
            max_slots: 0,
            ..RegistryConfig::default()
        },
        RegistryConfig {
            max_slots: MAX_SLOTS + 1,
            ..RegistryConfig::default()
        },
        RegistryConfig {
            max_aabb_extent: f32::NAN,
            ..RegistryConfig::default()
        },
        RegistryConfig {
            max_aabb_extent: 0.0,
            ..RegistryConfig::default()
        },
    ] {
        assert!(matches!(
            InstanceRegistry::new(grid(), config),
            Err(CoreError::InvalidConfig { .. })
        ));
    }
}

#[test]
fn dirty_ranges_cover_exactly_the_changed_slots() {
    let mut r = registry(4);
    let hs: Vec<_> = (0..8)
        .map(|i| r.register(desc_at(i, 8.0, 8.0)).unwrap())
        .collect();
    assert_eq!(r.take_dirty(), vec![0..8]);
    assert!(r.take_dirty().is_empty());

    r.set_state(1, InstanceState::Active).unwrap();
    r.set_blas(hs[2], 77).unwrap();
    r.remove(hs[4]).unwrap();
    r.set_lod(hs[7], 1).unwrap();
    // Writing the current value again is not a change.
    r.set_state(3, InstanceState::Inactive).unwrap();
    r.set_blas(hs[5], 0).unwrap();
    assert_eq!(r.take_dirty(), vec![1..3, 4..5, 7..8]);

    r.set_blas_at(6, 9).unwrap();
    r.set_flags(hs[2], InstanceFlags::STATIC).unwrap();
    assert_eq!(r.take_dirty_merged(3), vec![2..7]);
    // The removed slot is a zeroed, dead record.
    assert_eq!(r.records().get(4).unwrap(), InstanceRecord::default());
}

#[test]
fn updates_keep_slot_state_and_blas_and_report_the_old_values() {
    let mut r = registry(4);
    let h = r.register(desc_at(1, 8.0, 8.0)).unwrap();
    r.set_blas(h, 0xAB).unwrap();
    r.set_state_of(h, InstanceState::Active).unwrap();
    let moved = desc_at(2, 100.0, 120.0);
    let old = r.update(h, moved).unwrap();
    assert_eq!(old, desc_at(1, 8.0, 8.0));
    let rec = r.record(h).unwrap();
    assert_eq!(rec.blas, 0xAB);
    assert_eq!(rec.state(), InstanceState::Active);
    assert_eq!(rec.hitbox, 6 + 7 * 8);
    assert_eq!(r.set_lod(h, 4).unwrap(), 0);
    assert_eq!(r.set_lod(h, 5).unwrap(), 4);
    assert_eq!(
        r.set_flags(h, InstanceFlags::UNIQUE_BLAS).unwrap(),
        InstanceFlags::empty()
    );
    assert!(r.record(h).unwrap().needs_unique_blas());
    assert_eq!(r.state(h).unwrap(), InstanceState::Active);
    let removed = r.remove(h).unwrap();
    assert_eq!(
        (removed.slot, removed.blas, removed.state, removed.hitbox),
        (0, 0xAB, InstanceState::Active, 62)
    );
    assert_eq!(removed.desc.lod, 5);
    assert_eq!(removed.desc.mesh, MeshId(2));
}

#[test]
fn replacing_the_hitbox_index_is_all_or_nothing() {
    let mut r = registry(4);
    let a = r.register(desc_at(0, 8.0, 8.0)).unwrap();
    let b = r.register(desc_at(0, 100.0, 8.0)).unwrap();
    r.take_dirty();
    let small = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [64.0, 64.0],
        cell_size: 32.0,
    })
    .unwrap();
    assert!(matches!(
        r.set_hitbox_index(small),
        Err(CoreError::OutsideWorld { .. })
    ));
    assert_eq!(r.record(b).unwrap().hitbox, 6);
    assert!(!r.has_dirty());
    let coarse = HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [128.0, 128.0],
        cell_size: 64.0,
    })
    .unwrap();
    let old = r.set_hitbox_index(coarse).unwrap();
    assert_eq!(old.dims(), (8, 8));
    assert_eq!(r.record(a).unwrap().hitbox, 0);
    assert_eq!(r.record(b).unwrap().hitbox, 1);
    // Only b's hitbox changed (a stays in hitbox 0).
    assert_eq!(r.take_dirty(), vec![1..2]);
}

#[test]
fn desc_is_rebuilt_bit_exactly_from_the_record() {
    let mut r = registry(0);
    let t = Affine3A::from_scale_rotation_translation(
        Vec3::new(1.5, -0.0, 3.0e-39),
        glam::Quat::from_rotation_y(0.3) * glam::Quat::from_rotation_x(-1.1),
        Vec3::new(33.3, -0.0, 77.7),
    );
    let d = InstanceDesc {
        mesh: MeshId(u32::MAX),
        lod: u32::MAX,
        transform: t,
        aabb: Aabb::new(Vec3::new(30.0, -0.0, 70.0), Vec3::new(36.6, 1e-40, 85.4)),
        flags: InstanceFlags::ALL,
        mask: 0xA5,
        sbt_offset: MAX_SBT_OFFSET,
        vk_flags: 0xFF,
    };
    let h = r.register(d).unwrap();
    let got = r.desc(h).unwrap();
    assert_eq!(got, d);
    // Equality treats 0.0 and -0.0 alike: compare the bits too.
    let bits = |d: &InstanceDesc| {
        let mut v: Vec<u32> = d
            .transform
            .to_cols_array()
            .iter()
            .map(|x| x.to_bits())
            .collect();
        v.extend(
            d.aabb
                .min
                .to_array()
                .iter()
                .chain(&d.aabb.max.to_array())
                .map(|x| x.to_bits()),
        );
        v
    };
    assert_eq!(bits(&got), bits(&d));
    assert_eq!(
        (r.mesh(h).unwrap(), r.lod(h).unwrap(), r.flags(h).unwrap()),
        (d.mesh, d.lod, d.flags)
    );
    // State and BLAS share the record's words with the description.
    r.set_state_of(h, InstanceState::Active).unwrap();
    r.set_blas(h, u64::MAX).unwrap();
    assert_eq!(r.desc(h).unwrap(), d);
    let removed = r.remove(h).unwrap();
    assert_eq!(bits(&removed.desc), bits(&d));
    assert_eq!(removed.desc, d);
}

#[test]
fn handle_map_does_not_hold_the_description() {
    // The slot of the handle map holds only what the record lacks; a
    // description alone is over 100 bytes.
    assert!(std::mem::size_of::<InstanceDesc>() > 100);
    assert!(std::mem::size_of::<Entry>() <= 8);
}

#[test]
fn reserve_allocates_once_and_counts_free_slots() {
    let mut r = registry(0);
    r.reserve(200).unwrap();
    assert!(r.capacity() >= 200);
    let before = r.heap_bytes();
    let handles: Vec<_> = (0..200)
        .map(|i| r.register(desc_at(i, 8.0 + (i % 100) as f32, 8.0)).unwrap())
        .collect();
    // Registering what was reserved reallocated nothing.
    assert_eq!(r.heap_bytes(), before);
    for h in &handles[..50] {
        r.remove(*h).unwrap();
    }
    // 50 free slots: reserving 60 more adds room for 10 slots only.
    r.reserve(60).unwrap();
    assert!(r.capacity() >= 210);
    assert!((210..220).contains(&r.records.capacity()));
}

#[test]
fn reserve_stops_at_the_slot_limit() {
    let mut r = InstanceRegistry::new(
        grid(),
        RegistryConfig {
            max_slots: 1000,
            ..RegistryConfig::default()
        },
    )
    .unwrap();
    r.reserve(usize::MAX).unwrap(); // no capacity overflow, no huge allocation
    assert_eq!(r.capacity(), 1000);
    assert!(r.records.capacity() < 2000);
}

#[test]
fn serials_distinguish_reused_slots() {
    let mut r = registry(0);
    let a = r.register(desc_at(0, 8.0, 8.0)).unwrap();
    assert_eq!(r.serial_at(0), Some(0));
    r.remove(a).unwrap();
    assert_eq!(r.serial_at(0), None);
    r.register(desc_at(0, 8.0, 8.0)).unwrap();
    assert_eq!(r.serial_at(0), Some(1));
    assert_eq!(r.registration_count(), 2);
}

// ---------------------------------------------------------------------------
// Model-based property test.

#[derive(Clone, Debug)]
enum Op {
    Register {
        mesh: u32,
        x: f32,
        z: f32,
        half: f32,
    },
    /// Invalid: the transform has a NaN.
    RegisterNan,
    /// Invalid: centre outside the world.
    RegisterOutside,
    Remove(usize),
    Move {
        pick: usize,
        x: f32,
        z: f32,
    },
    SetLod(usize, u32),
    SetState(usize, u8),
    SetBlas(usize, u64),
    Advance(u8),
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        4 => (0u32..5, 0.0f32..128.0, 0.0f32..128.0, 0.0f32..3.0)
            .prop_map(|(mesh, x, z, half)| Op::Register { mesh, x, z, half }),
        1 => Just(Op::RegisterNan),
        1 => Just(Op::RegisterOutside),
        3 => any::<usize>().prop_map(Op::Remove),
        2 => (any::<usize>(), 0.0f32..128.0, 0.0f32..128.0)
            .prop_map(|(pick, x, z)| Op::Move { pick, x, z }),
        1 => (any::<usize>(), 0u32..4).prop_map(|(p, l)| Op::SetLod(p, l)),
        1 => (any::<usize>(), 0u8..3).prop_map(|(p, s)| Op::SetState(p, s)),
        1 => (any::<usize>(), any::<u64>()).prop_map(|(p, b)| Op::SetBlas(p, b)),
        2 => (0u8..4).prop_map(Op::Advance),
    ]
}

fn box_desc(mesh: u32, x: f32, z: f32, half: f32) -> InstanceDesc {
    let c = Vec3::new(x, 2.0, z);
    InstanceDesc {
        flags: InstanceFlags::from_bits_truncate(mesh << 3),
        ..InstanceDesc::new(
            MeshId(mesh),
            Affine3A::from_translation(c),
            Aabb::new(c - Vec3::splat(half), c + Vec3::splat(half)),
        )
    }
}

/// What the model expects of each live instance.
#[derive(Clone, Debug)]
struct Expected {
    desc: InstanceDesc,
    state: InstanceState,
    blas: u64,
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]
    #[test]
    fn slot_invariants_hold_under_random_operations(
        quarantine in 0u32..4,
        ops in prop::collection::vec(op(), 1..120),
    ) {
        let mut r = registry(quarantine);
        let g = grid();
        let mut live: Vec<InstanceHandle> = Vec::new();
        let mut expected: HashMap<InstanceHandle, Expected> = HashMap::new();
        let mut dead: Vec<InstanceHandle> = Vec::new();
        // Slot model: free slots, quarantine (release frame, slot), fresh end.
        let mut free: BTreeSet<u32> = BTreeSet::new();
        let mut quarantined: Vec<(u64, u32)> = Vec::new();
        let mut frame = 0u64;
        let mut dirty: HashSet<u32> = HashSet::new();

        for op in ops {
            let before = snapshot(&r);
            match op {
                Op::Register { mesh, x, z, half } => {
                    let d = box_desc(mesh, x, z, half);
                    let h = r.register(d).unwrap();
                    let want = free.pop_first().unwrap_or(r.slot_count() - 1);
                    prop_assert_eq!(r.slot(h).unwrap(), want);
                    live.push(h);
                    expected.insert(h, Expected { desc: d, state: InstanceState::Inactive, blas: 0 });
                    dirty.insert(want);
                }
                Op::RegisterNan => {
                    let mut d = box_desc(0, 1.0, 1.0, 1.0);
                    d.transform.matrix3.y_axis.y = f32::NAN;
                    prop_assert!(r.register(d).is_err());
                    prop_assert_eq!(snapshot(&r), before);
                }
                Op::RegisterOutside => {
                    prop_assert!(r.register(box_desc(0, -1.0, 5.0, 0.5)).is_err());
                    prop_assert_eq!(snapshot(&r), before);
                }
                Op::Remove(pick) if !live.is_empty() => {
                    let h = live.swap_remove(pick % live.len());
                    let slot = r.slot(h).unwrap();
                    let e = expected.remove(&h).unwrap();
                    let removed = r.remove(h).unwrap();
                    prop_assert_eq!(removed.slot, slot);
                    prop_assert_eq!(removed.desc, e.desc);
                    prop_assert_eq!(removed.blas, e.blas);
                    prop_assert_eq!(removed.state, e.state);
                    if quarantine == 0 {
                        free.insert(slot);
                    } else {
                        quarantined.push((frame + u64::from(quarantine), slot));
                    }
                    dead.push(h);
                    dirty.insert(slot);
                }
                Op::Move { pick, x, z } if !live.is_empty() => {
                    let h = live[pick % live.len()];
                    let e = expected.get_mut(&h).unwrap();
                    let d = box_desc(e.desc.mesh.0, x, z, 1.0);
                    r.set_transform(h, d.transform, d.aabb).unwrap();
                    e.desc.transform = d.transform;
                    e.desc.aabb = d.aabb;
                    dirty.insert(r.slot(h).unwrap());
                }
                Op::SetLod(pick, lod) if !live.is_empty() => {
                    let h = live[pick % live.len()];
                    let e = expected.get_mut(&h).unwrap();
                    prop_assert_eq!(r.set_lod(h, lod).unwrap(), e.desc.lod);
                    e.desc.lod = lod;
                    dirty.insert(r.slot(h).unwrap());
                }
                Op::SetState(pick, s) if !live.is_empty() => {
                    let h = live[pick % live.len()];
                    let state = InstanceState::from_bits(s.into());
                    let e = expected.get_mut(&h).unwrap();
                    let slot = r.slot(h).unwrap();
                    prop_assert_eq!(r.set_state(slot, state).unwrap(), e.state);
                    if e.state != state {
                        dirty.insert(slot);
                    }
                    e.state = state;
                }
                Op::SetBlas(pick, b) if !live.is_empty() => {
                    let h = live[pick % live.len()];
                    let e = expected.get_mut(&h).unwrap();
                    prop_assert_eq!(r.set_blas(h, b).unwrap(), e.blas);
                    if e.blas != b {
                        dirty.insert(r.slot(h).unwrap());
                    }
                    e.blas = b;
                }
                Op::Advance(n) => {
                    frame += u64::from(n);
                    let released = r.begin_frame(frame).unwrap();
                    let (done, wait): (Vec<_>, Vec<_>) =
                        quarantined.iter().partition(|(at, _)| *at <= frame);
                    prop_assert_eq!(released as usize, done.len());
                    free.extend(done.iter().map(|(_, s)| *s));
                    quarantined = wait;
                }
                _ => {}
            }

            // Invariants.
            prop_assert_eq!(r.len(), live.len());
            prop_assert_eq!(r.quarantined_slots() as usize, quarantined.len());
            let mut seen = HashSet::new();
            for (h, slot) in r.iter() {
                prop_assert!(seen.insert(slot), "slot {} used twice", slot);
                prop_assert_eq!(r.handle_at(slot), Some(h));
                prop_assert_eq!(r.slot(h).unwrap(), slot);
                let e = &expected[&h];
                let rec = r.records().get(slot as usize).unwrap();
                let want = build_record(
                    &e.desc,
                    affine_to_rows(&e.desc.transform),
                    g.hitbox_of(&e.desc.aabb).unwrap(),
                    e.state,
                    e.blas,
                );
                prop_assert_eq!(rec, InstanceRecord::from_parts(&want.hot(), &want.tlas(slot), &want.bounds()));
                prop_assert_eq!(r.desc(h).unwrap(), e.desc);
            }
            prop_assert_eq!(seen.len(), live.len());
            for s in 0..r.slot_count() {
                if !seen.contains(&s) {
                    prop_assert_eq!(r.handle_at(s), None);
                    prop_assert_eq!(r.records().get(s as usize).unwrap(), InstanceRecord::default());
                }
                // A slot is never both live and free/quarantined.
                let parked = free.contains(&s) || quarantined.iter().any(|q| q.1 == s);
                prop_assert_eq!(parked, !seen.contains(&s));
            }
            for h in &dead {
                let stale = matches!(r.slot(*h), Err(CoreError::StaleHandle { .. }));
                prop_assert!(stale);
            }
        }
        // Dirty ranges cover exactly the slots the model saw change.
        let ranges = r.take_dirty();
        let covered: HashSet<u32> = ranges.iter().flat_map(|rg| rg.clone()).collect();
        prop_assert_eq!(covered, dirty);
        for w in ranges.windows(2) {
            prop_assert!(w[0].end < w[1].start, "ranges not coalesced: {:?}", ranges);
        }
    }
}
