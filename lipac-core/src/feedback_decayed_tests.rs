//! Algorithm 2 under the decayed rule ([`DecisionRule::Decayed`]): rates,
//! hysteresis, cost-aware activation, the per-slot rates.

use super::*;
use crate::layout::InstanceState;
use crate::thresholds::{DecayedRule, RATE_ONE};

const RULE: DecayedRule = DecayedRule {
    shift: 2,
    activate: 4 * RATE_ONE,
    deactivate: RATE_ONE,
    instance_activate: 3 * RATE_ONE,
    instance_omit: RATE_ONE / 2,
    per_shared: RATE_ONE / 2,
    per_unique: 2 * RATE_ONE,
};

fn th() -> Thresholds {
    Thresholds::paper().with_rule(DecisionRule::Decayed(RULE))
}

fn inst(state: InstanceState, unique: bool, blas: u64) -> InstanceRecord {
    let mut r = InstanceRecord {
        packed: instance_bits::ALIVE
            | if unique {
                instance_bits::UNIQUE_BLAS
            } else {
                0
            },
        blas,
        ..Default::default()
    };
    r.set_state(state);
    r
}

/// One frame: the hitbox gets `box_hits` (counting box) with `cost`
/// inactive instances, then Algorithm 2.
fn frame(
    instances: &mut [InstanceRecord],
    hits: &[u32],
    rates: &mut [u32],
    hitbox: &mut HitboxRecord,
    box_hits: u32,
    cost: u32,
) -> FeedbackStats {
    crate::assembly::begin_frame(std::slice::from_mut(hitbox));
    hitbox.cost = cost;
    hitbox.add_hits(box_hits);
    let mut buf = CommandBuffer::new(16);
    process_feedback_with_rates(
        instances,
        hits,
        rates,
        std::slice::from_mut(hitbox),
        &th(),
        &mut buf,
    )
    .unwrap()
}

#[test]
fn hitbox_activates_on_sustained_rate_and_keeps_it_within_the_band() {
    let mut i = [inst(InstanceState::Inactive, false, 0)];
    let mut rates = [0];
    let mut h = HitboxRecord::default();
    // 5 hits a frame: the rate climbs 1.25, 2.19, 2.89, 3.42, 3.81, 4.11 > 4.
    let mut activated_at = None;
    for f in 0..10 {
        let s = frame(&mut i, &[0], &mut rates, &mut h, 5, 0);
        if s.hitboxes_activated == 1 {
            activated_at = Some(f);
            break;
        }
    }
    assert_eq!(activated_at, Some(5));
    assert!(h.is_active() && h.streak() == 0);
    assert_eq!(i[0].state(), InstanceState::Active, "its instance with it");
    // Hysteresis: 2 hits a frame (rate -> 2, between θd and θa) keeps it on.
    for _ in 0..40 {
        let s = frame(&mut i, &[2], &mut rates, &mut h, 0, 0);
        assert_eq!(s.hitboxes_deactivated, 0);
    }
    assert!(h.rate >= 2 * RATE_ONE && h.rate < 2 * RATE_ONE + 4);
    // No hits: the rate halves about every 2.4 frames and falls below θd.
    let mut off_after = 0;
    while h.is_active() {
        frame(&mut i, &[0], &mut rates, &mut h, 0, 0);
        off_after += 1;
        assert!(off_after < 20);
    }
    assert_eq!(off_after, 3, "2 -> 1.5 -> 1.13 -> 0.84 (< 1) at the 3rd");
    assert_eq!(i[0].state(), InstanceState::Inactive);
}

#[test]
fn a_burst_activates_in_one_frame() {
    let mut i = [inst(InstanceState::Inactive, false, 0)];
    let mut h = HitboxRecord::default();
    // rate = hits / 4 > 4 needs more than 16 hits.
    frame(&mut i, &[0], &mut [0], &mut h, 16, 0);
    assert!(!h.is_active());
    let mut h = HitboxRecord::default();
    frame(&mut i, &[0], &mut [0], &mut h, 17, 0);
    assert!(h.is_active());
}

#[test]
fn activation_needs_more_evidence_the_more_it_brings_in() {
    // Threshold 4 + 0.5 per shared + 2 per unique instance.
    let cases = [
        (0u32, 17u32, true),
        (2, 17, false), // needs 5: hits/4 > 5 -> 21
        (2, 21, true),
        (hitbox_bits::COST_UNIQUE, 24, false), // needs 6 -> 25
        (hitbox_bits::COST_UNIQUE, 25, true),
        // Counts saturate at 255: 4 + 127.5 + 510 = 641.5 -> 2567 hits.
        (0xFFFF_FFFF, 2566, false),
        (0xFFFF_FFFF, 2567, true),
    ];
    for (cost, hits, on) in cases {
        let mut h = HitboxRecord::default();
        let mut i = [inst(InstanceState::Inactive, false, 0)];
        frame(&mut i, &[0], &mut [0], &mut h, hits, cost);
        assert_eq!(h.is_active(), on, "cost {cost:#x} hits {hits}");
    }
}

#[test]
fn instance_rate_drives_omitted_and_active_and_is_held_without_blas() {
    let mut h = HitboxRecord {
        packed: hitbox_bits::ACTIVE,
        rate: 100 * RATE_ONE,
        ..Default::default()
    };
    let mut i = [inst(InstanceState::Omitted, true, 0)];
    let mut rates = [0];
    // 4 own hits a frame: 1, 1.75, 2.31, 2.73, 3.05 > 3 at the 5th frame.
    let mut frames = 0;
    while i[0].state() == InstanceState::Omitted {
        frame(&mut i, &[4], &mut rates, &mut h, 1000, 0);
        frames += 1;
        assert!(frames < 10);
    }
    assert_eq!(frames, 5);
    assert_eq!(i[0].state(), InstanceState::Active);
    let held = rates[0];
    // (The hitbox's own rate is kept up by 1000 hits a frame throughout.)
    // Active without a BLAS: not traced, no hits, the rate is held.
    for _ in 0..10 {
        frame(&mut i, &[0], &mut rates, &mut h, 1000, 0);
    }
    assert_eq!(rates[0], held);
    assert_eq!(i[0].state(), InstanceState::Active);
    // The BLAS arrives and the instance is no longer hit: back to omitted
    // once the rate is below 0.5.
    i[0].blas = 0xB1A5;
    let mut frames = 0;
    while i[0].state() == InstanceState::Active {
        frame(&mut i, &[0], &mut rates, &mut h, 1000, 0);
        frames += 1;
        assert!(frames < 20);
    }
    assert_eq!(frames, 7, "3.05 * 0.75^7 = 0.41 < 0.5 < 0.54");
    // Its hitbox deactivates: inactive, rate 0.
    h.rate = 0;
    frame(&mut i, &[0], &mut rates, &mut h, 0, 0);
    assert_eq!(i[0].state(), InstanceState::Inactive);
    assert_eq!(rates[0], 0);
}

#[test]
fn rates_of_shared_dead_and_inactive_slots_are_zeroed() {
    let mut h = HitboxRecord {
        packed: hitbox_bits::ACTIVE,
        rate: 100 * RATE_ONE,
        ..Default::default()
    };
    let mut i = [
        inst(InstanceState::Active, false, 1),
        InstanceRecord::default(), // dead
        inst(InstanceState::Omitted, true, 0),
    ];
    let mut rates = [7, 8, 9];
    frame(&mut i, &[5, 5, 0], &mut rates, &mut h, 0, 0);
    assert_eq!(rates[..2], [0, 0]);
    assert_eq!(rates[2], decay_rate(9, 0, RULE.shift));
    let mut h = HitboxRecord::default();
    let mut i = [inst(InstanceState::Inactive, true, 0)];
    let mut rates = [1234];
    frame(&mut i, &[0], &mut rates, &mut h, 0, 0);
    assert_eq!(rates, [0]);
}

#[test]
fn paper_rule_leaves_rates_alone_and_the_paper_entry_point_refuses_the_decayed_rule() {
    let mut i = vec![inst(InstanceState::Omitted, true, 0)];
    let mut h = vec![HitboxRecord {
        packed: hitbox_bits::ACTIVE,
        rate: 77,
        ..Default::default()
    }];
    let mut rates = vec![55];
    let mut b = CommandBuffer::new(4);
    process_feedback_with_rates(
        &mut i,
        &[5000],
        &mut rates,
        &mut h,
        &Thresholds::paper(),
        &mut b,
    )
    .unwrap();
    assert_eq!((rates[0], h[0].rate), (55, 77));
    assert_eq!(i[0].state(), InstanceState::Active, "paper: 5000 > σa");
    assert!(matches!(
        process_feedback(&mut i, &[0], &mut h, &th(), &mut b),
        Err(FeedbackError::RatesRequired)
    ));
    let e = process_feedback_with_rates(&mut i, &[0], &mut [], &mut h, &th(), &mut b).unwrap_err();
    assert!(matches!(
        e,
        FeedbackError::RateCountMismatch {
            rates: 0,
            instances: 1
        }
    ));
    assert!(e.to_string().contains("rate buffer"));
}
