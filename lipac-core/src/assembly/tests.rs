use super::*;
use crate::hitbox_extents::write_extents;
use crate::layout::{hitbox_bits, instance_bits, InstanceRecord};
use glam::Vec2;
use lipac_test_support::{Rng64, XorShift64};

/// A row of `n` cells of `size` along x, spanning z in [0, size).
pub(crate) struct Row {
    pub n: u32,
    pub size: f32,
    pub origin: f32,
}

impl HitboxIndex for Row {
    fn len(&self) -> u32 {
        self.n
    }
    fn hitbox_at(&self, p: Vec3) -> Option<u32> {
        let i = ((p.x - self.origin) / self.size).floor();
        (i >= 0.0 && i < self.n as f32).then_some(i as u32)
    }
    fn xz_bounds(&self, i: u32) -> Option<(Vec2, Vec2)> {
        (i < self.n).then(|| {
            let x0 = self.origin + i as f32 * self.size;
            (Vec2::new(x0, 0.0), Vec2::new(x0 + self.size, self.size))
        })
    }
}

const CUBE: u64 = 0xC0BE;

fn cfg() -> AssemblyConfig {
    AssemblyConfig {
        unit_cube_blas: CUBE,
        counting_mask: 0x40,
        omitted_box_sbt_offset: 5,
        hitbox_sbt_offset: 6,
        min_box_extent: 0.01,
    }
}

fn inst(state: InstanceState, hitbox: u32, min: [f32; 3], max: [f32; 3]) -> InstanceRecord {
    let mut r = InstanceRecord {
        transform: [
            1.0, 0.0, 0.0, min[0], 0.0, 1.0, 0.0, min[1], 0.0, 0.0, 1.0, min[2],
        ],
        aabb_min: min,
        aabb_max: max,
        hitbox,
        packed: instance_bits::ALIVE
            | (0x0F << instance_bits::MASK_SHIFT)
            | (u32::from(crate::layout::VK_INSTANCE_FLIP_FACING) << instance_bits::VK_FLAGS_SHIFT),
        blas: 0,
        sbt_offset: 3,
        lod: 0,
    };
    r.set_state(state);
    r
}

fn active_hitbox() -> HitboxRecord {
    HitboxRecord {
        packed: hitbox_bits::ACTIVE,
        ..Default::default()
    }
}

/// Transforms the unit cube's corners as the hardware would (f32, row-major).
fn cube_bounds(m: &[f32; 12]) -> (Vec3, Vec3) {
    let lo = Vec3::new(m[3], m[7], m[11]);
    let hi = Vec3::new(m[0] + m[3], m[5] + m[7], m[10] + m[11]);
    (lo, hi)
}

fn run(
    instances: &[InstanceRecord],
    hitboxes: &mut [HitboxRecord],
) -> (AssemblyStats, Vec<TlasInstance>) {
    let index = Row {
        n: hitboxes.len() as u32,
        size: 16.0,
        origin: 0.0,
    };
    let mut out = vec![TlasInstance::default(); 3]; // stale content must be cleared
    let instances = InstanceArrays::from_records(instances);
    write_extents(&instances, hitboxes);
    let stats = assemble_tlas(&instances, hitboxes, &index, &cfg(), &mut out).unwrap();
    (stats, out)
}

#[test]
fn active_with_blas_is_emitted_with_its_own_fields() {
    let mut m = inst(InstanceState::Active, 0, [1.0, 0.0, 1.0], [2.0, 1.0, 2.0]);
    m.blas = 0xABCD;
    let mut hb = [active_hitbox()];
    let (stats, out) = run(&[InstanceRecord::default(), m], &mut hb);
    assert_eq!(stats.active, 1);
    assert_eq!(
        out,
        vec![TlasInstance::new(
            m.transform,
            1,
            0x0F,
            3,
            crate::layout::VK_INSTANCE_FLIP_FACING,
            0xABCD
        )]
    );
}

#[test]
fn active_without_blas_is_left_out_and_counted() {
    let m = inst(InstanceState::Active, 0, [1.0, 0.0, 1.0], [2.0, 1.0, 2.0]);
    let mut hb = [active_hitbox()];
    let (stats, out) = run(&[m], &mut hb);
    assert_eq!((stats.active, stats.active_without_blas), (0, 1));
    assert!(out.is_empty());
    // Its hitbox's extent counts it (a live, unpinned member), but an active
    // hitbox emits no box.
    assert_eq!((hb[0].min_y, hb[0].max_y), (0.0, 1.0));
}

#[test]
fn omitted_becomes_counting_box_over_its_aabb() {
    let m = inst(InstanceState::Omitted, 0, [1.0, -2.0, 3.0], [4.0, 5.0, 3.5]);
    let mut hb = [active_hitbox()];
    let (stats, out) = run(&[m, m], &mut hb);
    assert_eq!(stats.omitted_boxes, 2);
    assert_eq!(out.len(), 2);
    let r = out[1];
    assert_eq!(r.custom_index(), 1);
    assert_eq!(r.mask(), 0x40);
    assert_eq!(r.sbt_offset(), 5);
    assert_eq!(
        r.flags(),
        VK_INSTANCE_FORCE_OPAQUE | VK_INSTANCE_CULL_DISABLE
    );
    assert_eq!(r.acceleration_structure_reference, CUBE);
    let (lo, hi) = cube_bounds(&r.transform);
    assert_eq!(lo, Vec3::new(1.0, -2.0, 3.0));
    assert_eq!(hi, Vec3::new(4.0, 5.0, 3.5)); // exactly representable: no growth
}

#[test]
fn inactive_instances_reduce_their_hitbox_height() {
    let a = inst(
        InstanceState::Inactive,
        1,
        [17.0, 2.0, 1.0],
        [18.0, 3.0, 2.0],
    );
    let b = inst(
        InstanceState::Inactive,
        1,
        [20.0, -1.0, 1.0],
        [21.0, 2.5, 2.0],
    );
    let c = inst(InstanceState::Inactive, 0, [1.0, 7.0, 1.0], [2.0, 9.0, 2.0]);
    // Stale heights from last frame must not survive.
    let mut hb = [HitboxRecord {
        min_y: -100.0,
        max_y: 100.0,
        packed: 0,
        rate: 0,
        cost: 0x0303_0303,
    }; 3];
    hb[2].packed = hitbox_bits::ACTIVE;
    let (stats, out) = run(&[a, b, c], &mut hb);
    assert_eq!(stats.inactive, 3);
    // The cost words are rebuilt: one shared-BLAS inactive instance in
    // hitbox 0, two in 1, none in 2.
    assert_eq!(hb.map(|h| h.cost), [1, 2, 0]);
    assert_eq!((hb[1].inactive_shared(), hb[1].inactive_unique()), (2, 0));
    assert_eq!((hb[0].min_y, hb[0].max_y), (7.0, 9.0));
    assert_eq!((hb[1].min_y, hb[1].max_y), (-1.0, 3.0));
    assert!(hb[2].min_y > hb[2].max_y);
    assert!(out
        .iter()
        .all(|r| r.acceleration_structure_reference == CUBE));
}

#[test]
fn inactive_hitbox_gets_box_over_cell_and_height() {
    let a = inst(
        InstanceState::Inactive,
        1,
        [17.0, 2.0, 1.0],
        [18.0, 3.0, 2.0],
    );
    let b = inst(
        InstanceState::Inactive,
        1,
        [20.0, -1.0, 1.0],
        [21.0, 2.5, 2.0],
    );
    let mut hb = [HitboxRecord::default(); 2];
    let (stats, out) = run(&[a, b], &mut hb);
    assert_eq!((stats.hitbox_boxes, stats.flat_hitbox_boxes), (1, 0));
    assert_eq!(out.len(), 1, "hitbox 0 has no inactive instance: no box");
    let r = out[0];
    assert_eq!((r.custom_index(), r.mask(), r.sbt_offset()), (1, 0x40, 6));
    assert_eq!(r.flags(), COUNTING_BOX_FLAGS);
    let (lo, hi) = cube_bounds(&r.transform);
    assert_eq!(lo, Vec3::new(16.0, -1.0, 0.0));
    assert_eq!(hi, Vec3::new(32.0, 3.0, 16.0));
}

#[test]
fn active_hitbox_gets_no_box() {
    let a = inst(InstanceState::Inactive, 0, [1.0, 2.0, 1.0], [2.0, 3.0, 2.0]);
    let mut hb = [active_hitbox()];
    let (stats, out) = run(&[a], &mut hb);
    assert_eq!(stats.inactive, 1);
    assert_eq!(stats.hitbox_boxes, 0);
    assert!(out.is_empty());
    // The reduction still ran (the GPU does not look at the hitbox state there).
    assert_eq!((hb[0].min_y, hb[0].max_y), (2.0, 3.0));
}

#[test]
fn active_and_omitted_in_inactive_hitbox_fold_into_its_box() {
    let mut a = inst(InstanceState::Active, 0, [1.0, 1.0, 1.0], [2.0, 6.0, 2.0]);
    a.blas = 0xABCD;
    let o = inst(InstanceState::Omitted, 0, [3.0, -2.0, 1.0], [4.0, 0.0, 2.0]);
    let mut b = inst(InstanceState::Active, 1, [17.0, 0.0, 1.0], [18.0, 1.0, 2.0]);
    b.blas = 0xBEEF;
    let mut hb = [HitboxRecord::default(), active_hitbox()];
    let (stats, out) = run(&[a, o, b], &mut hb);
    assert_eq!((stats.in_inactive_hitbox, stats.inactive), (2, 2));
    assert_eq!(
        (stats.active, stats.omitted_boxes, stats.hitbox_boxes),
        (1, 0, 1)
    );
    // Only b's own record and hitbox 0's box, which spans both folded instances.
    assert_eq!(out.len(), 2);
    assert_eq!(out[0].acceleration_structure_reference, 0xBEEF);
    assert_eq!((out[1].custom_index(), out[1].sbt_offset()), (0, 6));
    assert_eq!((hb[0].min_y, hb[0].max_y), (-2.0, 6.0));
}

#[test]
fn pinned_is_traced_whatever_its_state_and_hitbox() {
    let pinned = |state| {
        let mut m = inst(state, 0, [1.0, 0.0, 1.0], [2.0, 9.0, 2.0]);
        m.packed |= instance_bits::PINNED;
        m.blas = 0xABCD;
        m
    };
    let mut no_blas = pinned(InstanceState::Inactive);
    no_blas.blas = 0;
    let other = inst(InstanceState::Inactive, 0, [3.0, 1.0, 1.0], [4.0, 2.0, 2.0]);
    let mut hb = [HitboxRecord::default()]; // inactive
    let instances = [
        pinned(InstanceState::Active),
        pinned(InstanceState::Omitted),
        pinned(InstanceState::Inactive),
        no_blas,
        other,
    ];
    let (stats, out) = run(&instances, &mut hb);
    assert_eq!((stats.active, stats.active_without_blas), (3, 1));
    assert_eq!((stats.omitted_boxes, stats.in_inactive_hitbox), (0, 0));
    assert_eq!((stats.inactive, stats.hitbox_boxes), (1, 1));
    // Own records for slots 0..3, then the hitbox's box over `other` only.
    let own: Vec<u32> = out[..3].iter().map(TlasInstance::custom_index).collect();
    assert_eq!(own, vec![0, 1, 2]);
    assert!(out[..3]
        .iter()
        .all(|r| r.acceleration_structure_reference == 0xABCD));
    assert_eq!(out[3].acceleration_structure_reference, CUBE);
    assert_eq!((hb[0].min_y, hb[0].max_y), (1.0, 2.0));
}

#[test]
fn flat_hitbox_still_gets_a_padded_box() {
    let a = inst(InstanceState::Inactive, 0, [1.0, 4.0, 1.0], [2.0, 4.0, 2.0]);
    let mut hb = [HitboxRecord::default()];
    let (stats, out) = run(&[a], &mut hb);
    assert_eq!((stats.hitbox_boxes, stats.flat_hitbox_boxes), (1, 1));
    let (lo, hi) = cube_bounds(&out[0].transform);
    assert!(lo.y < 4.0 && hi.y > 4.0);
    assert!((hi.y - lo.y - cfg().min_box_extent).abs() < 1e-5);
}

#[test]
fn dead_slots_are_skipped() {
    let mut dead = inst(InstanceState::Active, 0, [1.0, 0.0, 1.0], [2.0, 1.0, 2.0]);
    dead.blas = 99;
    dead.packed &= !instance_bits::ALIVE;
    let mut dead_inactive = inst(InstanceState::Inactive, 0, [1.0, 0.0, 1.0], [2.0, 1.0, 2.0]);
    dead_inactive.packed &= !instance_bits::ALIVE;
    let mut hb = [HitboxRecord::default()];
    let (stats, out) = run(&[dead, dead_inactive], &mut hb);
    assert_eq!(stats, AssemblyStats::default());
    assert!(out.is_empty());
    assert!(hb[0].min_y > hb[0].max_y);
}

#[test]
fn frame_reset_clears_hits_keeps_state() {
    let mut hb = [HitboxRecord {
        min_y: 1.0,
        max_y: 2.0,
        packed: hitbox_bits::ACTIVE | (5 << 1),
        rate: 0xDEAD,
        cost: 77,
    }];
    hb[0].add_hits(1234);
    begin_frame(&mut hb);
    assert_eq!(hb[0].hits(), 0);
    assert_eq!((hb[0].rate, hb[0].cost), (0xDEAD, 77), "rate and cost kept");
    assert!(hb[0].is_active());
    assert_eq!(hb[0].streak(), 5);
    assert_eq!(
        (hb[0].min_y, hb[0].max_y),
        (1.0, 2.0),
        "the extent is the CPU's"
    );
}

#[test]
fn bad_inputs_are_errors_or_counted() {
    let mut hb = [HitboxRecord::default()];
    let index = Row {
        n: 2,
        size: 16.0,
        origin: 0.0,
    };
    let mut out = Vec::new();
    assert!(matches!(
        assemble_tlas(&InstanceArrays::new(), &mut hb, &index, &cfg(), &mut out),
        Err(AssemblyError::HitboxCountMismatch {
            index: 2,
            records: 1
        })
    ));
    let bad_hitbox = inst(InstanceState::Inactive, 7, [1.0, 0.0, 1.0], [2.0, 1.0, 2.0]);
    let nan_box = inst(
        InstanceState::Omitted,
        0,
        [f32::NAN, 0.0, 1.0],
        [2.0, 1.0, 2.0],
    );
    hb[0] = active_hitbox(); // the omitted NaN box is judged, not folded into an inactive hitbox
    let (stats, out) = run(&[bad_hitbox, nan_box], &mut hb);
    assert_eq!(stats.invalid_instances, 2);
    assert!(out.is_empty());
}

/// Exhaustive-ish containment check of the conservative transform, near
/// and far (±100 km) from the origin, with awkward non-representable sizes.
#[test]
fn unit_cube_transform_contains_target_far_from_origin() {
    let mut rng = XorShift64::new(0x1234_5678_9ABC_DEF0);
    let mut next = || (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
    for &centre in &[0.0f64, 1.0, -3.3, 1.0e5, -1.0e5, 99_999.99, -65_536.0] {
        for _ in 0..2000 {
            let c = Vec3::new(
                (centre + next() * 10.0) as f32,
                (centre * 0.5 + next()) as f32,
                (-centre + next() * 10.0) as f32,
            );
            let size = Vec3::new(
                (next() * 20.0) as f32,
                (next() * 0.1) as f32,
                (next() * 1e-3) as f32,
            );
            let min = c;
            let max = c + size; // rounded in f32: still min <= max
            let m = unit_cube_transform(min, max, 1e-3).unwrap();
            let (lo, hi) = cube_bounds(&m);
            assert!(
                lo.cmple(min).all() && hi.cmpge(max).all(),
                "{min} {max} -> {lo} {hi}"
            );
            // Never degenerate, and not grossly larger than needed.
            assert!(hi.cmpgt(lo).all());
            let slack = (max - min).max(Vec3::splat(1e-3)) * 1.001 + Vec3::splat(0.02);
            assert!((hi - lo).cmple(slack).all(), "{min} {max} -> {lo} {hi}");
            // Also with FMA-style evaluation (exact 1·s + t, one rounding).
            assert_eq!(1.0f32.mul_add(m[0], m[3]), hi.x);
        }
    }
}

#[test]
fn tiny_extent_far_away_is_at_least_one_step_thick() {
    let y = 100_000.0f32; // f32 step here is 1/128
    let m = unit_cube_transform(Vec3::splat(y), Vec3::splat(y), 1e-4).unwrap();
    let (lo, hi) = cube_bounds(&m);
    assert!(lo.cmple(Vec3::splat(y)).all() && hi.cmpge(Vec3::splat(y)).all());
    assert!(hi.cmpgt(lo).all());
}

#[test]
fn canonical_sort_makes_order_irrelevant() {
    let a = inst(InstanceState::Omitted, 0, [1.0, 0.0, 1.0], [2.0, 1.0, 2.0]);
    let b = inst(
        InstanceState::Inactive,
        1,
        [17.0, 0.0, 1.0],
        [18.0, 1.0, 2.0],
    );
    let mut hb = [active_hitbox(), HitboxRecord::default()];
    let (_, mut out) = run(&[a, b, a], &mut hb);
    let mut shuffled = out.clone();
    shuffled.reverse();
    shuffled.swap(0, 1);
    assert_ne!(shuffled, out);
    sort_canonical(&mut out);
    sort_canonical(&mut shuffled);
    assert_eq!(shuffled, out);
}

/// Pass 1 of Algorithm 1 as it was before the hot/cold split, over whole
/// 96-byte records (`blas != 0` instead of `HAS_BLAS`); pass 2 is shared.
/// The split version must give the same output, hitboxes and counts.
fn reference_assemble_records(
    instances: &[InstanceRecord],
    hitboxes: &mut [HitboxRecord],
    index: &impl HitboxIndex,
    cfg: &AssemblyConfig,
) -> (AssemblyStats, Vec<TlasInstance>) {
    let mut out = Vec::new();
    let mut stats = AssemblyStats::default();
    begin_frame(hitboxes);
    for (slot, m) in instances.iter().enumerate() {
        if !m.is_alive() {
            continue;
        }
        let slot = slot as u32;
        let pinned = m.is_pinned();
        let mut state = if pinned {
            InstanceState::Active
        } else {
            m.state()
        };
        if !pinned
            && state != InstanceState::Inactive
            && hitboxes
                .get(m.hitbox as usize)
                .is_some_and(|h| !h.is_active())
        {
            stats.in_inactive_hitbox += 1;
            state = InstanceState::Inactive;
        }
        match state {
            InstanceState::Active => {
                if m.blas == 0 {
                    stats.active_without_blas += 1;
                    continue;
                }
                out.push(TlasInstance::new(
                    m.transform,
                    slot,
                    m.mask(),
                    m.sbt_offset,
                    m.vk_flags(),
                    m.blas,
                ));
                stats.active += 1;
            }
            InstanceState::Omitted => {
                let Some(transform) = unit_cube_transform(
                    Vec3::from_array(m.aabb_min),
                    Vec3::from_array(m.aabb_max),
                    cfg.min_box_extent,
                ) else {
                    stats.invalid_instances += 1;
                    continue;
                };
                out.push(TlasInstance::new(
                    transform,
                    slot,
                    cfg.counting_mask,
                    cfg.omitted_box_sbt_offset,
                    COUNTING_BOX_FLAGS,
                    cfg.unit_cube_blas,
                ));
                stats.omitted_boxes += 1;
            }
            InstanceState::Inactive => {
                let Some(h) = hitboxes.get_mut(m.hitbox as usize) else {
                    stats.invalid_instances += 1;
                    continue;
                };
                h.min_y = h.min_y.min(m.aabb_min[1]);
                h.max_y = h.max_y.max(m.aabb_max[1]);
                h.cost = h.cost.wrapping_add(if m.needs_unique_blas() {
                    hitbox_bits::COST_UNIQUE
                } else {
                    hitbox_bits::COST_SHARED
                });
                stats.inactive += 1;
            }
        }
    }
    // Pass 2 as before (unchanged by the split).
    let kept: Vec<HitboxRecord> = hitboxes.to_vec();
    let mut boxes = Vec::new();
    let mut stats2 = AssemblyStats::default();
    for (i, h) in kept.iter().enumerate() {
        if h.is_active() || h.min_y > h.max_y {
            continue;
        }
        let i = i as u32;
        let Some((lo, hi)) = index.xz_bounds(i) else {
            stats2.invalid_hitboxes += 1;
            continue;
        };
        let min = Vec3::new(lo.x, h.min_y, lo.y);
        let max = Vec3::new(hi.x, h.max_y, hi.y);
        let Some(transform) = unit_cube_transform(min, max, cfg.min_box_extent) else {
            stats2.invalid_hitboxes += 1;
            continue;
        };
        boxes.push(TlasInstance::new(
            transform,
            i,
            cfg.counting_mask,
            cfg.hitbox_sbt_offset,
            COUNTING_BOX_FLAGS,
            cfg.unit_cube_blas,
        ));
        stats2.hitbox_boxes += 1;
        stats2.flat_hitbox_boxes += u32::from(h.min_y == h.max_y);
    }
    stats.hitbox_boxes = stats2.hitbox_boxes;
    stats.flat_hitbox_boxes = stats2.flat_hitbox_boxes;
    stats.invalid_hitboxes = stats2.invalid_hitboxes;
    out.extend(boxes);
    (stats, out)
}

/// A random record: every state value (3 included), dead slots, pinned,
/// unique, hitboxes out of range, odd AABBs (NaN, inf, swapped y), BLAS or
/// none, and a `HAS_BLAS` bit that may contradict the BLAS address (the
/// arrays derive it from the address).
fn random_record(rng: &mut XorShift64, hitboxes: u32) -> InstanceRecord {
    let f = |rng: &mut XorShift64| (rng.next_u32() % 20_000) as f32 / 100.0 - 100.0;
    let mut min = [f(rng), f(rng), f(rng)];
    let mut max = [min[0] + 2.0, min[1] + f(rng).abs(), min[2] + 2.0];
    match rng.below_u32(40) {
        0 => min[1] = f32::NAN,
        1 => max[0] = f32::INFINITY,
        2 => std::mem::swap(&mut min[1], &mut max[1]),
        _ => {}
    }
    let mut transform = [0.0f32; 12];
    for v in &mut transform {
        *v = f(rng);
    }
    let mut packed = rng.below_u32(4) | (rng.next_u32() & 0xFFFF_FFB0);
    for (p, bit) in [
        (90, instance_bits::ALIVE),
        (30, instance_bits::UNIQUE_BLAS),
        (10, instance_bits::PINNED),
    ] {
        if rng.below_u32(100) < p {
            packed |= bit;
        } else {
            packed &= !bit;
        }
    }
    InstanceRecord {
        transform,
        aabb_min: min,
        hitbox: if rng.below_u32(50) == 0 {
            hitboxes + rng.below_u32(3)
        } else {
            rng.below_u32(hitboxes)
        },
        aabb_max: max,
        packed,
        blas: if rng.below_u32(5) == 0 {
            0
        } else {
            rng.next_u64() | 1
        },
        sbt_offset: rng.next_u32() & 0xFF_FFFF,
        lod: rng.below_u32(4),
    }
}

#[test]
fn split_arrays_give_the_records_output_bit_for_bit() {
    let mut rng = XorShift64::new(0x15_407C);
    let index = Row {
        n: 24,
        size: 16.0,
        origin: -100.0,
    };
    for round in 0..20 {
        let records: Vec<InstanceRecord> = (0..1500)
            .map(|_| random_record(&mut rng, index.n))
            .collect();
        let hitboxes: Vec<HitboxRecord> = (0..index.n)
            .map(|_| HitboxRecord {
                packed: rng.next_u32() & 0xFF,
                rate: rng.next_u32(),
                ..Default::default()
            })
            .collect();
        let (mut ref_hb, mut new_hb) = (hitboxes.clone(), hitboxes);
        let (ref_stats, ref_out) =
            reference_assemble_records(&records, &mut ref_hb, &index, &cfg());
        let mut new_out = Vec::new();
        let arrays = InstanceArrays::from_records(&records);
        write_extents(&arrays, &mut new_hb);
        let new_stats = assemble_tlas(&arrays, &mut new_hb, &index, &cfg(), &mut new_out).unwrap();
        assert_eq!(new_stats, ref_stats, "round {round}");
        // Same order too (slot order, then hitbox order), bit for bit.
        let bits = |v: &[TlasInstance]| v.iter().map(TlasInstance::to_bits).collect::<Vec<_>>();
        assert_eq!(bits(&new_out), bits(&ref_out), "round {round}");
        // The GPU-owned words alike; the extents of inactive hitboxes (the
        // only ones read) alike: the reference reduces them per frame over
        // the instances that count as inactive, `write_extents` over all
        // live unpinned members, which in an inactive hitbox are the same.
        for (i, (n, r)) in new_hb.iter().zip(&ref_hb).enumerate() {
            assert_eq!(
                (n.packed, n.rate),
                (r.packed, r.rate),
                "round {round} hitbox {i}"
            );
            if !r.is_active() {
                let words = |h: &HitboxRecord| [h.min_y.to_bits(), h.max_y.to_bits(), h.cost];
                assert_eq!(words(n), words(r), "round {round} hitbox {i}");
            }
        }
        assert!(ref_stats.active > 50 && ref_stats.omitted_boxes > 50 && ref_stats.inactive > 50);
        assert!(ref_stats.active_without_blas > 0 && ref_stats.hitbox_boxes > 0);
    }
}

/// Interesting f32 bit patterns for the fast paths: zeros of both signs,
/// subnormals, the extremes, infinities and NaNs (quiet, signalling, negative).
const ODD_BITS: [u32; 16] = [
    0x0000_0000,
    0x8000_0000,
    0x0000_0001,
    0x8000_0001,
    0x007F_FFFF,
    0x3F80_0000,
    0xBF80_0000,
    0x4B80_0000, // 2^24
    0x7F7F_FFFF,
    0xFF7F_FFFF,
    0x7F80_0000,
    0xFF80_0000,
    0x7FC0_0000,
    0xFFC0_0000,
    0x7F80_0001,
    0xFF80_0001,
];

#[test]
fn unit_cube_transform_fast_path_gives_the_general_bits() {
    let mut rng = XorShift64::new(0xA11_C0BE);
    let extents = [
        0.0,
        1e-3,
        0.5,
        16.0,
        1e30,
        f32::from_bits(1),
        -1.0,
        f32::NAN,
        f32::INFINITY,
    ];
    let value = |rng: &mut XorShift64| -> f32 {
        match rng.below_u32(4) {
            0 => f32::from_bits(ODD_BITS[rng.below_u32(16) as usize]),
            1 => f32::from_bits(rng.next_u32()),
            _ => (rng.next_u32() % 200_000) as f32 / 64.0 - 1000.0,
        }
    };
    let mut fast = 0;
    for i in 0..200_000 {
        let lo = Vec3::new(value(&mut rng), value(&mut rng), value(&mut rng));
        let mut hi = Vec3::new(value(&mut rng), value(&mut rng), value(&mut rng));
        if i % 2 == 0 {
            // Mostly ordered boxes, some of them near-flat or rounding-prone.
            let d = Vec3::new(value(&mut rng), value(&mut rng), value(&mut rng)).abs() * 1e-3;
            hi = lo + d;
        }
        let e = extents[i % extents.len()];
        let got = unit_cube_transform(lo, hi, e).map(|m| m.map(f32::to_bits));
        let want = unit_cube_transform_general(lo, hi, e).map(|m| m.map(f32::to_bits));
        assert_eq!(got, want, "{lo:?} {hi:?} {e}");
        fast += usize::from(got.is_some());
    }
    assert!(fast > 50_000, "the boxes should mostly be valid: {fast}");
}

/// The height reduction as `assemble_instances.comp` did it before the
/// extents moved to the CPU: `atomicMin`/`atomicMax` on `lipacOrderedKey`,
/// NaN heights skipped (the order `write_extents` keeps).
fn shader_height_range(heights: &[(u32, u32)]) -> (u32, u32) {
    let key = |b: u32| {
        if b & 0x8000_0000 != 0 {
            !b
        } else {
            b | 0x8000_0000
        }
    };
    let from_key = |k: u32| {
        if k & 0x8000_0000 != 0 {
            k & 0x7FFF_FFFF
        } else {
            !k
        }
    };
    let is_nan = |b: u32| f32::from_bits(b).is_nan();
    let (mut lo, mut hi) = (key(0x7F80_0000), key(0xFF80_0000));
    for &(a, b) in heights {
        if !is_nan(a) {
            lo = lo.min(key(a));
        }
        if !is_nan(b) {
            hi = hi.max(key(b));
        }
    }
    (from_key(lo), from_key(hi))
}

#[test]
fn heights_reduce_with_the_shader_rule_for_signed_zeros_and_nan() {
    let mut rng = XorShift64::new(0x0_5160);
    let index = Row {
        n: 7,
        size: 16.0,
        origin: 0.0,
    };
    for round in 0..200 {
        // Up to 600 inactive instances (crossing pass 1's chunks), heights
        // drawn mostly from the odd patterns; hitbox 6 gets none.
        let count = 1 + rng.below_u32(600) as usize;
        let mut records = Vec::new();
        let mut per_hitbox: Vec<Vec<(u32, u32)>> = vec![Vec::new(); 7];
        for _ in 0..count {
            let mut pick = || {
                if rng.below_u32(3) == 0 {
                    rng.next_u32()
                } else {
                    ODD_BITS[rng.below_u32(16) as usize]
                }
            };
            let (a, b) = (pick(), pick());
            let hb = rng.below_u32(6);
            let mut r = inst(
                InstanceState::Inactive,
                hb,
                [1.0, f32::from_bits(a), 1.0],
                [2.0, f32::from_bits(b), 2.0],
            );
            if round % 2 == 1 && rng.below_u32(4) == 0 {
                // An omitted instance in an inactive hitbox reduces too.
                r.set_state(InstanceState::Omitted);
            }
            records.push(r);
            per_hitbox[hb as usize].push((a, b));
        }
        let mut hitboxes = vec![HitboxRecord::default(); 7];
        let mut out = Vec::new();
        let arrays = InstanceArrays::from_records(&records);
        write_extents(&arrays, &mut hitboxes);
        let stats = assemble_tlas(&arrays, &mut hitboxes, &index, &cfg(), &mut out).unwrap();
        assert_eq!(stats.inactive as usize, count, "round {round}");
        for (i, h) in hitboxes.iter().enumerate() {
            let want = shader_height_range(&per_hitbox[i]);
            assert_eq!(
                (h.min_y.to_bits(), h.max_y.to_bits()),
                want,
                "round {round} hitbox {i}"
            );
        }
    }
    // The case f32::min/max left open: -0 is the lower, +0 the upper bound.
    let records = [
        inst(
            InstanceState::Inactive,
            0,
            [1.0, 0.0, 1.0],
            [2.0, -0.0, 2.0],
        ),
        inst(
            InstanceState::Inactive,
            0,
            [1.0, -0.0, 1.0],
            [2.0, 0.0, 2.0],
        ),
        inst(
            InstanceState::Inactive,
            0,
            [1.0, f32::NAN, 1.0],
            [2.0, -f32::NAN, 2.0],
        ),
    ];
    for order in [[0, 1, 2], [1, 0, 2], [2, 1, 0]] {
        let recs: Vec<_> = order.iter().map(|&k| records[k]).collect();
        let mut hitboxes = [HitboxRecord::default()];
        let index = Row {
            n: 1,
            size: 16.0,
            origin: 0.0,
        };
        let mut out = Vec::new();
        let arrays = InstanceArrays::from_records(&recs);
        write_extents(&arrays, &mut hitboxes);
        assemble_tlas(&arrays, &mut hitboxes, &index, &cfg(), &mut out).unwrap();
        assert_eq!(hitboxes[0].min_y.to_bits(), (-0.0f32).to_bits());
        assert_eq!(hitboxes[0].max_y.to_bits(), 0.0f32.to_bits());
    }
}
