use super::*;
use crate::layout::{InstanceRecord, InstanceState};
use proptest::prelude::*;

/// Heights that exercise the order: NaN, ±0, ±∞, ordinary values.
const HEIGHTS: [f32; 9] = [
    f32::NAN,
    -0.0,
    0.0,
    f32::INFINITY,
    f32::NEG_INFINITY,
    -3.5,
    1.0,
    7.25,
    1.0e30,
];

/// One generated record: liveness, pin, unique bit, state, hitbox (may be
/// out of range), heights.
fn record(bits: u8, state: u8, hitbox: u32, lo: usize, hi: usize) -> InstanceRecord {
    let mut packed = 0;
    if bits & 1 != 0 {
        packed |= instance_bits::ALIVE;
    }
    if bits & 2 != 0 {
        packed |= instance_bits::PINNED;
    }
    if bits & 4 != 0 {
        packed |= instance_bits::UNIQUE_BLAS;
    }
    let mut r = InstanceRecord {
        aabb_min: [0.0, HEIGHTS[lo % HEIGHTS.len()], 0.0],
        aabb_max: [1.0, HEIGHTS[hi % HEIGHTS.len()], 1.0],
        hitbox,
        packed,
        ..Default::default()
    };
    r.set_state(InstanceState::from_bits(u32::from(state & 3)));
    r
}

fn arb_record(hitboxes: u32) -> impl Strategy<Value = InstanceRecord> {
    (
        any::<u8>(),
        any::<u8>(),
        0..hitboxes + 2,
        0..9usize,
        0..9usize,
    )
        .prop_map(|(b, s, h, lo, hi)| record(b, s, h, lo, hi))
}

fn words(hitboxes: &[HitboxRecord]) -> Vec<[u32; 5]> {
    hitboxes
        .iter()
        .map(|h| {
            [
                h.min_y.to_bits(),
                h.max_y.to_bits(),
                h.packed,
                h.rate,
                h.cost,
            ]
        })
        .collect()
}

#[test]
fn write_extents_reduces_live_unpinned_members_whatever_their_state() {
    let mut active = record(1 | 4, 0, 0, 5, 8); // unique, -3.5 .. 1e30
    active.set_state(InstanceState::Active);
    let rows = [
        active,
        record(1, 0, 0, 6, 6),     // shared, 1 .. 1
        record(1 | 2, 0, 0, 4, 3), // pinned: not a member
        record(0, 0, 0, 4, 3),     // dead: not a member
        record(1, 0, 0, 0, 0),     // NaN heights: counted, never the range
        record(1, 0, 9, 4, 3),     // hitbox out of range
    ];
    let instances = InstanceArrays::from_records(&rows);
    let mut hitboxes = [HitboxRecord {
        packed: 0xABCD_EF01,
        rate: 77,
        ..Default::default()
    }];
    write_extents(&instances, &mut hitboxes);
    let h = hitboxes[0];
    assert_eq!((h.min_y, h.max_y), (-3.5, 1.0e30));
    assert_eq!(
        h.cost,
        hitbox_bits::COST_UNIQUE + 2 * hitbox_bits::COST_SHARED
    );
    assert_eq!(
        (h.packed, h.rate),
        (0xABCD_EF01, 77),
        "GPU-owned words kept"
    );
}

#[test]
fn only_nan_heights_leave_the_extent_empty_but_counted() {
    let instances = InstanceArrays::from_records(&[record(1, 0, 0, 0, 0)]);
    let mut hitboxes = [HitboxRecord::default()];
    write_extents(&instances, &mut hitboxes);
    let e = HitboxExtent::of(&hitboxes[0]);
    assert!(e.is_empty());
    assert_eq!(e.cost, hitbox_bits::COST_SHARED);
}

#[test]
fn negative_zero_is_below_positive_zero() {
    let instances = InstanceArrays::from_records(&[record(1, 0, 0, 2, 2), record(1, 0, 0, 1, 1)]);
    let mut hitboxes = [HitboxRecord::default()];
    write_extents(&instances, &mut hitboxes);
    assert_eq!(hitboxes[0].min_y.to_bits(), (-0.0f32).to_bits());
    assert_eq!(hitboxes[0].max_y.to_bits(), 0.0f32.to_bits());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    /// After every batch of record writes (each written slot touched, plus
    /// some untouched ones listed), the tracker's extents equal a full
    /// `write_extents`, `changed` lists exactly the hitboxes whose extent
    /// words changed, and the GPU-owned words are never written.
    #[test]
    fn tracker_equals_a_full_recompute(
        hitbox_count in 1u32..12,
        initial in prop::collection::vec(arb_record(12), 0..40),
        batches in prop::collection::vec(
            (
                prop::collection::vec((0usize..48, arb_record(12)), 0..12),
                prop::collection::vec(0u32..48, 0..4),
                0usize..4,
            ),
            1..8,
        ),
    ) {
        let mut instances = InstanceArrays::from_records(&initial);
        let mut hitboxes: Vec<HitboxRecord> = (0..hitbox_count)
            .map(|i| HitboxRecord { packed: i * 0x101, rate: i, ..Default::default() })
            .collect();
        let mut tracker = ExtentTracker::default();
        let mut changed = Vec::new();
        tracker.refresh(&instances, 0..initial.len() as u32, &mut hitboxes, &mut changed);
        let mut want = hitboxes.clone();
        write_extents(&instances, &mut want);
        prop_assert_eq!(words(&hitboxes), words(&want));

        for (writes, extra, grow) in batches {
            let before = hitboxes.clone();
            let mut touched: Vec<u32> = extra;
            for (slot, r) in writes {
                if slot >= instances.len() {
                    instances.resize(slot + 1);
                }
                instances.set(slot, &r);
                touched.push(slot as u32);
            }
            // Hitboxes appear (a hashed index grows) with the default record;
            // the registry writes (touches) every slot it places in one.
            let before_len = before.len();
            hitboxes.extend((0..grow).map(|_| HitboxRecord::default()));
            let new = before_len as u32..hitboxes.len() as u32;
            touched.extend((0..instances.len() as u32).filter(|&s| new.contains(&instances.hot()[s as usize].hitbox)));
            changed.clear();
            tracker.refresh(&instances, touched, &mut hitboxes, &mut changed);
            let mut want = hitboxes.clone();
            write_extents(&instances, &mut want);
            prop_assert_eq!(words(&hitboxes), words(&want));
            let mut listed: Vec<u32> = changed.iter().map(|&(h, _)| h).collect();
            listed.sort_unstable();
            let n = listed.len();
            listed.dedup();
            prop_assert_eq!(n, listed.len(), "a hitbox listed twice");
            for (i, h) in hitboxes.iter().enumerate() {
                let old = before.get(i).copied().unwrap_or_default();
                let moved = HitboxExtent::of(&old).to_words() != HitboxExtent::of(h).to_words();
                prop_assert_eq!(moved, listed.binary_search(&(i as u32)).is_ok(), "hitbox {}", i);
                if i < before_len {
                    prop_assert_eq!((h.packed, h.rate), (old.packed, old.rate));
                }
            }
            for &(h, e) in &changed {
                prop_assert_eq!(e.to_words(), HitboxExtent::of(&hitboxes[h as usize]).to_words());
            }
        }
    }
}
