//! The chunked fast paths of [`process`](super::super::process) (32 hit
//! counters tested at once and runs of adds to one hitbox in lines 1–6, the
//! per-hitbox codes and the [`BUSY`] table deciding 64 slots at once in
//! lines 14–38, the rates of skipped slots zeroed per chunk under the
//! decayed rule) against the verbatim pre-split reference, under both
//! rules.

use super::*;
use crate::thresholds::{DecayedRule, RATE_ONE};
use lipac_test_support::{Rng64, XorShift64};

/// The decayed rule at the scale of the paper's thresholds (hits per frame
/// in the hundreds), so that the scenes below keep inactive hitboxes; its
/// rates rise faster than they decay (`rise_shift` < `shift`).
const RULE: DecayedRule = DecayedRule {
    shift: 2,
    rise_shift: 1,
    activate: 1500 * RATE_ONE,
    deactivate: 100 * RATE_ONE,
    instance_activate: 150 * RATE_ONE,
    instance_omit: 30 * RATE_ONE,
    per_shared: 8 * RATE_ONE,
    per_unique: 32 * RATE_ONE,
};

fn rules() -> [Thresholds; 2] {
    [TH, TH.with_rule(DecisionRule::Decayed(RULE))]
}

/// Runs the split version and the reference on the same frame and asserts
/// that everything they write is equal; returns the split version's stats.
#[allow(clippy::too_many_arguments)]
fn assert_matches_reference(
    records: &mut [InstanceRecord],
    hot: &mut [InstanceHot],
    hits: &[u32],
    rates: (&mut [u32], &mut [u32]),
    hitboxes: (&mut [HitboxRecord], &mut [HitboxRecord]),
    th: &Thresholds,
    capacity: u32,
    what: &str,
) -> FeedbackStats {
    let decayed = matches!(th.rule, DecisionRule::Decayed(_));
    let escape = reference_escape(records, hits, hitboxes.0);
    let mut ref_cmds = CommandBuffer::new(capacity);
    let want = reference_process_records(
        records,
        hits,
        decayed.then_some(&mut *rates.0),
        hitboxes.0,
        th,
        &mut ref_cmds,
    )
    .unwrap();
    let mut cmds = CommandBuffer::new(capacity);
    let got = if decayed {
        process_feedback_with_rates(hot, hits, rates.1, hitboxes.1, th, &mut cmds).unwrap()
    } else {
        process_feedback(hot, hits, hitboxes.1, th, &mut cmds).unwrap()
    };
    assert_eq!((got.box_hits, got.traced_hits), escape, "{what}");
    let without_sums = FeedbackStats {
        box_hits: 0,
        traced_hits: 0,
        ..got
    };
    assert_eq!(without_sums, want, "{what}");
    let ref_hot: Vec<InstanceHot> = records.iter().map(InstanceRecord::hot).collect();
    assert_eq!(hot, &ref_hot[..], "{what}");
    assert_eq!(cmds.words(), ref_cmds.words(), "{what}");
    assert_eq!(cmds.requested(), ref_cmds.requested(), "{what}");
    assert_eq!(rates.1, rates.0, "{what}");
    assert_eq!(
        bytemuck::cast_slice::<_, u32>(hitboxes.1),
        bytemuck::cast_slice::<_, u32>(hitboxes.0),
        "{what}"
    );
    got
}

/// A coherent scene where the fast paths fire (runs of 32 slots per
/// hitbox, mostly agreeing with it, no hits on inactive slots) with every
/// exception mixed in: dead, pinned, state value 3, scattered slots,
/// indices out of range (just past the end and `u32::MAX`), hits that
/// saturate the hitbox counts, a slot count that leaves a partial chunk of
/// 64 and of 32, and command buffers that overflow. Frames carry states,
/// rates and hitboxes forward, under both rules.
#[test]
fn coherent_scene_matches_the_reference_under_both_rules() {
    for (r, th) in rules().iter().enumerate() {
        let mut rng = XorShift64::new(0xC4_0C4 + r as u64);
        let n_hitboxes = 40u32;
        let n = 32 * n_hitboxes as usize + 13; // 1293: 20 chunks of 64 and 40 of 32, + 13
        let mut ref_hb: Vec<HitboxRecord> = (0..n_hitboxes)
            .map(|_| {
                let mut h = hitbox(rng.below_u32(4) == 0);
                h.rate = rng.below_u32(2000) * RATE_ONE;
                h
            })
            .collect();
        let mut records: Vec<InstanceRecord> = (0..n)
            .map(|slot| {
                let hb = match rng.below_u32(40) {
                    0 => u32::MAX,
                    1..=3 => rng.below_u32(n_hitboxes + 1), // some just past the end
                    _ => (slot / 32) as u32 % n_hitboxes,
                };
                let unique = rng.below_u32(7) == 0;
                let active_hb = ref_hb.get(hb as usize).is_some_and(|h| h.is_active());
                let agree = rng.below_u32(50) != 0;
                let state = match (active_hb == agree, unique, rng.below_u32(2)) {
                    (true, true, 0) => InstanceState::Omitted,
                    (true, _, _) => InstanceState::Active,
                    (false, _, _) => InstanceState::Inactive,
                };
                let mut packed = instance_bits::ALIVE | (rng.next_u32() & 0xFFFF_FF30);
                if unique {
                    packed |= instance_bits::UNIQUE_BLAS;
                }
                if rng.below_u32(4) != 0 {
                    packed |= instance_bits::HAS_BLAS;
                }
                match rng.below_u32(100) {
                    0 => packed &= !instance_bits::ALIVE,
                    1 => packed |= instance_bits::PINNED,
                    2 => packed |= instance_bits::STATE_MASK, // the unused value 3
                    _ => {}
                }
                let mut rec = InstanceRecord {
                    hitbox: hb,
                    packed,
                    blas: if packed & instance_bits::HAS_BLAS != 0 {
                        0xB1A5
                    } else {
                        0
                    },
                    ..Default::default()
                };
                if packed & instance_bits::STATE_MASK != instance_bits::STATE_MASK {
                    rec.set_state(state);
                }
                rec
            })
            .collect();
        let mut hot: Vec<InstanceHot> = records.iter().map(InstanceRecord::hot).collect();
        let mut split_hb = ref_hb.clone();
        let mut ref_rates: Vec<u32> = (0..n).map(|_| rng.below_u32(200) * RATE_ONE).collect();
        let mut split_rates = ref_rates.clone();
        let (mut quiet_chunks, mut moved, mut overflowed, mut saturated) = (0, 0, 0, 0);
        for frame in 0..12u32 {
            let hits: Vec<u32> = records
                .iter()
                .map(|rec| match rec.state() {
                    InstanceState::Inactive => 0,
                    _ => match rng.below_u32(40) {
                        0 => u32::MAX - rng.below_u32(4),
                        1 => hitbox_bits::HITS_MAX - rng.below_u32(4),
                        2..=3 => rng.below_u32(2000),
                        _ => rng.below_u32(2 * TH.sigma_o),
                    },
                })
                .collect();
            quiet_chunks += hits
                .chunks_exact(HIT_CHUNK)
                .filter(|c| c.iter().all(|&h| h == 0))
                .count();
            crate::assembly::begin_frame(&mut ref_hb);
            crate::assembly::begin_frame(&mut split_hb);
            for (i, (a, b)) in ref_hb.iter_mut().zip(split_hb.iter_mut()).enumerate() {
                let x = (i as u32 + frame).wrapping_mul(2_654_435_761) >> 22; // 0..1024
                let box_hits = if x < 30 { 2500 } else { x };
                a.add_hits(box_hits);
                b.add_hits(box_hits);
            }
            let capacity = [1000, 2][frame as usize % 2];
            let before = hot.clone();
            let got = assert_matches_reference(
                &mut records,
                &mut hot,
                &hits,
                (&mut ref_rates, &mut split_rates),
                (&mut ref_hb, &mut split_hb),
                th,
                capacity,
                &format!("rule {r} frame {frame}"),
            );
            moved += before.iter().zip(&hot).filter(|(a, b)| a != b).count();
            overflowed += got.overflowed;
            saturated += ref_hb
                .iter()
                .filter(|h| h.hits() == hitbox_bits::HITS_MAX)
                .count();
        }
        assert!(quiet_chunks > 20, "{quiet_chunks} chunks without hits");
        assert!(moved > 50, "{moved} transitions");
        assert!(overflowed > 0, "no overflow");
        assert!(saturated > 10, "{saturated} saturated hitboxes");
    }
}

/// Every combination of the low byte of `packed` (state, `ALIVE`,
/// `UNIQUE_BLAS`, `PINNED`, `HAS_BLAS` and the bits the table ignores) and
/// of the hitbox (inactive, active, out of range), with and without hits,
/// under both rules: every entry of [`BUSY`] is exercised.
#[test]
fn every_busy_key_matches_the_reference() {
    for (r, th) in rules().iter().enumerate() {
        for hits_per_slot in [0, 50, 5000] {
            let mut records: Vec<InstanceRecord> = (0..3 * 256u32)
                .map(|i| InstanceRecord {
                    hitbox: [0, 1, 7][(i >> 8) as usize],
                    packed: i & 0xFF,
                    blas: u64::from(i & instance_bits::HAS_BLAS),
                    ..Default::default()
                })
                .collect();
            let mut hot: Vec<InstanceHot> = records.iter().map(InstanceRecord::hot).collect();
            let hits = vec![hits_per_slot; records.len()];
            let mut ref_hb = vec![hitbox(false), hitbox(true)];
            ref_hb[1].rate = 1000 * RATE_ONE;
            let mut split_hb = ref_hb.clone();
            let mut ref_rates = vec![100 * RATE_ONE; records.len()];
            let mut split_rates = ref_rates.clone();
            assert_matches_reference(
                &mut records,
                &mut hot,
                &hits,
                (&mut ref_rates, &mut split_rates),
                (&mut ref_hb, &mut split_hb),
                th,
                10_000,
                &format!("rule {r}, {hits_per_slot} hits"),
            );
        }
    }
}

/// [`BUSY`] against the cases spelled out positively: a live, unpinned
/// slot is busy when its hitbox index is out of range, when its hitbox is
/// inactive and its state is active or omitted (lines 17–20), and when its
/// hitbox is active and it is inactive (lines 23–26) or needs a unique BLAS
/// (lines 29–37).
#[test]
fn busy_table_is_the_slots_lines_14_to_38_can_touch() {
    for code in [CODE_INACTIVE, CODE_ACTIVE, CODE_OUT_OF_RANGE] {
        for low in 0..=255u32 {
            let live = low & instance_bits::ALIVE != 0 && low & instance_bits::PINNED == 0;
            let state = InstanceState::from_bits(low);
            let unique = low & instance_bits::UNIQUE_BLAS != 0;
            let busy = live
                && match code {
                    CODE_INACTIVE => state != InstanceState::Inactive,
                    CODE_ACTIVE => state == InstanceState::Inactive || unique,
                    _ => true,
                };
            for (p, row) in BUSY_ROW[usize::from(code)].iter().enumerate() {
                assert_eq!(
                    row[low as usize],
                    u8::from(busy) << p,
                    "low byte {low:#04x}, code {code}, position {p}"
                );
            }
            let chunk = [InstanceHot {
                hitbox: [0, 1, u32::MAX][usize::from(code)],
                packed: low,
            }];
            let codes = [CODE_INACTIVE, CODE_ACTIVE, CODE_OUT_OF_RANGE];
            assert_eq!(
                busy_mask(&chunk, &codes),
                [u64::from(busy), 0, 0, 0, 0, 0, 0, 0]
            );
        }
    }
}

/// [`busy_masks`] puts each slot's bit at its place, for every block
/// length from 1 to [`BLOCK`] (whole groups of eight and a tail) and random low
/// bytes and hitbox codes, including indices out of range: the same mask
/// as [`is_busy`] slot by slot.
fn busy_mask(block: &[InstanceHot], codes: &[u8]) -> [u64; BLOCK / CHUNK] {
    let mut masks = [u64::MAX; BLOCK / CHUNK];
    busy_masks(block, codes, &mut masks);
    masks
}

#[test]
fn busy_masks_place_every_slot_at_its_bit() {
    let mut rng = XorShift64::new(0x5EED_B05F);
    let codes = [CODE_INACTIVE, CODE_ACTIVE, CODE_ACTIVE, CODE_OUT_OF_RANGE];
    for len in 1..=BLOCK {
        for _ in 0..4 {
            let chunk: Vec<InstanceHot> = (0..len)
                .map(|_| InstanceHot {
                    hitbox: [0, 1, 2, 3, 9, u32::MAX][rng.below(6) as usize],
                    packed: rng.next_u32(),
                })
                .collect();
            let mut expected = [0u64; BLOCK / CHUNK];
            for (i, m) in chunk.iter().enumerate() {
                let code = codes[(m.hitbox as usize).min(codes.len() - 1)];
                expected[i / CHUNK] |= u64::from(is_busy(code, m.packed & 0xFF)) << (i % CHUNK);
            }
            assert_eq!(busy_mask(&chunk, &codes), expected, "{len} slots");
        }
    }
}

/// [`step_hitboxes`] under the paper's rule, whose common case (active at
/// or above θd, inactive at or below θa) skips [`hitbox_step`], gives the
/// words, codes and counts of [`hitbox_step`] on every hitbox: both states,
/// every streak, hit counts around θd, θa, 2·θa and the maximum.
#[test]
fn paper_hitbox_pass_matches_hitbox_step() {
    let th = TH;
    let mut hit_counts = vec![0, hitbox_bits::HITS_MAX];
    for t in [th.theta_d, th.theta_a, 2 * th.theta_a] {
        hit_counts.extend([t - 1, t, t + 1]);
    }
    let mut words = Vec::new();
    for hits in hit_counts {
        for streak in 0..=hitbox_bits::STREAK_MAX {
            for active in [0, hitbox_bits::ACTIVE] {
                words.push(
                    (hits << hitbox_bits::HITS_SHIFT)
                        | (streak << hitbox_bits::STREAK_SHIFT)
                        | active,
                );
            }
        }
    }
    let mut hitboxes: Vec<HitboxRecord> = words
        .iter()
        .map(|&packed| HitboxRecord {
            packed,
            ..Default::default()
        })
        .collect();
    let added = vec![0; hitboxes.len()];
    let (codes, activated, deactivated, _) = step_hitboxes(&mut hitboxes, &added, None, &th);
    let (mut up, mut down) = (0, 0);
    for (i, &word) in words.iter().enumerate() {
        let (packed, change) = hitbox_step(word, &th);
        up += u32::from(change > 0);
        down += u32::from(change < 0);
        assert_eq!(hitboxes[i].packed, packed, "word {word:#010x}");
        let code = if packed & hitbox_bits::ACTIVE != 0 {
            CODE_ACTIVE
        } else {
            CODE_INACTIVE
        };
        assert_eq!(codes[i], code, "word {word:#010x}");
    }
    assert_eq!((activated, deactivated), (up, down));
    assert!(up > 0 && down > 0, "{up} activations, {down} deactivations");
    assert!(codes[words.len()..].iter().all(|&c| c == CODE_OUT_OF_RANGE));
}

/// Runs of adds to one hitbox (line 4) give the count that one saturating
/// add per slot gives: near and past `HITS_MAX`, with `u32::MAX` hits, runs
/// broken by other hitboxes, by indices out of range and by slots whose
/// hits do not count, across chunk borders.
#[test]
fn hit_runs_saturate_like_one_add_per_slot() {
    let mut rng = XorShift64::new(0x5A70);
    for round in 0..40 {
        let n = 16 * 9 + round;
        let records: Vec<InstanceRecord> = (0..n)
            .map(|slot| {
                let hitbox = match rng.below_u32(12) {
                    0 => u32::MAX,
                    1 => 4,
                    2 => rng.below_u32(4),
                    _ => (slot / 20) as u32 % 4,
                };
                let mut rec = InstanceRecord {
                    hitbox,
                    packed: instance_bits::ALIVE,
                    ..Default::default()
                };
                rec.set_state(match rng.below_u32(5) {
                    0 => InstanceState::Inactive,
                    1 => InstanceState::Omitted,
                    _ => InstanceState::Active,
                });
                if rng.below_u32(15) == 0 {
                    rec.packed |= instance_bits::PINNED;
                }
                rec
            })
            .collect();
        let hits: Vec<u32> = (0..n)
            .map(|_| match rng.below_u32(8) {
                0 => 0,
                1 => u32::MAX,
                2 => hitbox_bits::HITS_MAX / 3,
                _ => rng.below_u32(1 << 20),
            })
            .collect();
        let mut want: Vec<HitboxRecord> = (0..4)
            .map(|_| {
                let mut h = hitbox(rng.below_u32(4) == 0);
                h.add_hits(rng.below_u32(hitbox_bits::HITS_MAX));
                h
            })
            .collect();
        let mut got = want.clone();
        for (rec, &h) in records.iter().zip(&hits) {
            let counts = rec.packed & instance_bits::PINNED == 0
                && matches!(rec.state(), InstanceState::Active | InstanceState::Omitted);
            if let Some(hb) = want.get_mut(rec.hitbox as usize).filter(|_| counts) {
                hb.add_hits(h);
            }
        }
        let hot: Vec<InstanceHot> = records.iter().map(InstanceRecord::hot).collect();
        let mut added = vec![0; got.len()];
        accumulate_hits(&hot, &hits, &mut added);
        hit_sums::merge_all(&mut got, &added);
        assert_eq!(
            bytemuck::cast_slice::<_, u32>(&got),
            bytemuck::cast_slice::<_, u32>(&want),
            "round {round}"
        );
    }
}

#[test]
fn nonzero_mask_has_a_bit_per_counter_with_hits() {
    let mut rng = XorShift64::new(0x0B17);
    for _ in 0..200 {
        let hs: Vec<u32> = (0..HIT_CHUNK)
            .map(|_| match rng.below_u32(3) {
                0 => 0,
                1 => 1 << rng.below_u32(32),
                _ => rng.next_u32(),
            })
            .collect();
        let want = hs
            .iter()
            .enumerate()
            .fold(0, |m, (i, &h)| m | u32::from(h != 0) << i);
        assert_eq!(nonzero_mask(&hs, &HIT_BITS), want, "{hs:?}");
    }
}

#[test]
fn zero_rates_but_keeps_exactly_the_marked_rates() {
    let mut rng = XorShift64::new(0x2E40);
    for len in [1, 7, 45, CHUNK] {
        for _ in 0..20 {
            let rates: Vec<u32> = (0..len).map(|_| rng.next_u32() | 1).collect();
            let keep = rng.next_u64() & (u64::MAX >> (64 - len));
            let mut got = rates.clone();
            zero_rates_but(&mut got, keep);
            for (i, (&g, &r)) in got.iter().zip(&rates).enumerate() {
                assert_eq!(g, if keep >> i & 1 == 1 { r } else { 0 }, "slot {i}");
            }
        }
    }
}

/// Without hitboxes every index is out of range: the code table is the
/// sentinel alone.
#[test]
fn no_hitboxes_makes_every_live_slot_invalid() {
    for (r, th) in rules().iter().enumerate() {
        let mut records: Vec<InstanceRecord> = (0..100u32)
            .map(|i| InstanceRecord {
                hitbox: i % 3,
                packed: (i * 37) & 0xFF,
                ..Default::default()
            })
            .collect();
        let mut hot: Vec<InstanceHot> = records.iter().map(InstanceRecord::hot).collect();
        let hits: Vec<u32> = (0..100).map(|i| i * 11).collect();
        let mut ref_rates = vec![RATE_ONE; 100];
        let mut split_rates = ref_rates.clone();
        let got = assert_matches_reference(
            &mut records,
            &mut hot,
            &hits,
            (&mut ref_rates, &mut split_rates),
            (&mut [], &mut []),
            th,
            100,
            &format!("rule {r}"),
        );
        let live = records
            .iter()
            .filter(|rec| {
                rec.packed & (instance_bits::ALIVE | instance_bits::PINNED) == instance_bits::ALIVE
            })
            .count();
        assert_eq!(got.invalid_instances as usize, live, "rule {r}");
        assert!(live > 10);
    }
}
