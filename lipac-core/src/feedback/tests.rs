use super::*;
use super::{busy::*, hit_sums::*};
use crate::command::CommandQueue;
use crate::layout::InstanceRecord;

const TH: Thresholds = Thresholds::paper();

fn inst(state: InstanceState, hitbox: u32, unique: bool) -> InstanceHot {
    let mut r = InstanceRecord {
        hitbox,
        packed: instance_bits::ALIVE
            | if unique {
                instance_bits::UNIQUE_BLAS
            } else {
                0
            },
        blas: 0xB1A5,
        ..Default::default()
    };
    r.set_state(state);
    r.hot()
}

fn hitbox(active: bool) -> HitboxRecord {
    HitboxRecord {
        packed: u32::from(active),
        ..Default::default()
    }
}

/// One frame: reset hitbox hits, add this frame's counting-box hits,
/// run Algorithm 2 with a fresh command buffer of `capacity`.
struct Frame {
    instances: Vec<InstanceHot>,
    hits: Vec<u32>,
    hitboxes: Vec<HitboxRecord>,
}

impl Frame {
    fn new(instances: Vec<InstanceHot>, hitboxes: Vec<HitboxRecord>) -> Self {
        Self {
            hits: vec![0; instances.len()],
            instances,
            hitboxes,
        }
    }

    fn run(&mut self, box_hits: &[u32], capacity: u32) -> (FeedbackStats, Vec<Command>) {
        crate::assembly::begin_frame(&mut self.hitboxes);
        for (h, &n) in self.hitboxes.iter_mut().zip(box_hits) {
            h.add_hits(n);
        }
        let mut buf = CommandBuffer::new(capacity);
        let stats = process_feedback(
            &mut self.instances,
            &self.hits,
            &mut self.hitboxes,
            &TH,
            &mut buf,
        )
        .unwrap();
        let cmds = buf
            .words()
            .iter()
            .map(|&w| Command::decode(w, MAX_SLOTS).unwrap())
            .collect();
        (stats, cmds)
    }

    fn state(&self, slot: usize) -> InstanceState {
        self.instances[slot].state()
    }
}

fn remove(slot: u32, hits: u32) -> Command {
    Command {
        slot,
        kind: CommandKind::Remove,
        priority: priority_from_hits(hits),
    }
}

fn add(slot: u32, hits: u32) -> Command {
    Command {
        slot,
        kind: CommandKind::Add,
        priority: priority_from_hits(hits),
    }
}

#[test]
fn line_4_active_and_omitted_hits_accumulate_into_hitbox() {
    let mut f = Frame::new(
        vec![
            inst(InstanceState::Active, 0, false),
            inst(InstanceState::Omitted, 0, true),
            inst(InstanceState::Inactive, 0, false),
            inst(InstanceState::Active, 1, false),
        ],
        vec![hitbox(true), hitbox(true)],
    );
    f.hits = vec![300, 40, 5000, hitbox_bits::HITS_MAX];
    f.run(&[7, 10], 8);
    // Box hits + active + omitted; the inactive instance's counter is not added.
    assert_eq!(f.hitboxes[0].hits(), 7 + 300 + 40);
    // Saturates instead of wrapping.
    assert_eq!(f.hitboxes[1].hits(), hitbox_bits::HITS_MAX);
}

#[test]
fn line_9_activates_after_n_a_frames_not_before() {
    let mut f = Frame::new(vec![], vec![hitbox(false)]);
    for frame in 1..TH.n_a {
        let (s, _) = f.run(&[TH.theta_a + 1], 0);
        assert_eq!(s.hitboxes_activated, 0);
        assert!(!f.hitboxes[0].is_active(), "activated after {frame} frames");
        assert_eq!(f.hitboxes[0].streak(), frame);
    }
    let (s, _) = f.run(&[TH.theta_a + 1], 0);
    assert_eq!(s.hitboxes_activated, 1);
    assert!(f.hitboxes[0].is_active());
    assert_eq!(f.hitboxes[0].streak(), 0);
}

#[test]
fn line_9_streak_needs_consecutive_frames() {
    let mut f = Frame::new(vec![], vec![hitbox(false)]);
    for _ in 1..TH.n_a {
        f.run(&[TH.theta_a + 1], 0);
    }
    f.run(&[TH.theta_a], 0); // not above θa: run broken
    assert_eq!(f.hitboxes[0].streak(), 0);
    f.run(&[TH.theta_a + 1], 0);
    assert!(!f.hitboxes[0].is_active());
}

#[test]
fn line_9_activates_in_one_frame_above_twice_theta_a() {
    let mut f = Frame::new(vec![], vec![hitbox(false), hitbox(false)]);
    let (s, _) = f.run(&[2 * TH.theta_a + 1, 2 * TH.theta_a], 0);
    assert_eq!(s.hitboxes_activated, 1);
    assert!(f.hitboxes[0].is_active());
    // Exactly 2·θa is not above it: only a streak of one.
    assert!(!f.hitboxes[1].is_active());
    assert_eq!(f.hitboxes[1].streak(), 1);
}

#[test]
fn line_11_deactivates_after_n_d_frames_and_a_good_frame_resets() {
    let mut f = Frame::new(vec![], vec![hitbox(true)]);
    for _ in 1..TH.n_d {
        f.run(&[TH.theta_d - 1], 0);
    }
    assert!(f.hitboxes[0].is_active());
    assert_eq!(f.hitboxes[0].streak(), TH.n_d - 1);
    f.run(&[TH.theta_d], 0); // not below θd
    assert_eq!(f.hitboxes[0].streak(), 0);
    for _ in 1..TH.n_d {
        f.run(&[0], 0);
    }
    assert!(f.hitboxes[0].is_active());
    let (s, _) = f.run(&[0], 0);
    assert_eq!(s.hitboxes_deactivated, 1);
    assert!(!f.hitboxes[0].is_active());
    assert_eq!(f.hitboxes[0].streak(), 0);
}

#[test]
fn lines_17_18_active_in_inactive_hitbox_is_removed() {
    let mut f = Frame::new(
        vec![inst(InstanceState::Active, 0, false)],
        vec![hitbox(false)],
    );
    f.hits[0] = 3;
    let (s, cmds) = f.run(&[20], 4);
    assert_eq!(s.active_to_inactive, 1);
    assert_eq!(f.state(0), InstanceState::Inactive);
    // Priority from the hitbox's count (20 box hits + 3 instance hits).
    assert_eq!(cmds, vec![remove(0, 23)]);
}

#[test]
fn lines_19_20_omitted_in_inactive_hitbox_becomes_inactive_silently() {
    let mut f = Frame::new(
        vec![inst(InstanceState::Omitted, 0, true)],
        vec![hitbox(false)],
    );
    let (s, cmds) = f.run(&[0], 4);
    assert_eq!(s.omitted_to_inactive, 1);
    assert_eq!(f.state(0), InstanceState::Inactive);
    assert!(cmds.is_empty());
}

#[test]
fn line_23_inactive_unique_in_active_hitbox_becomes_omitted() {
    let mut f = Frame::new(
        vec![inst(InstanceState::Inactive, 0, true)],
        vec![hitbox(true)],
    );
    let (s, cmds) = f.run(&[500], 4);
    assert_eq!(s.inactive_to_omitted, 1);
    assert_eq!(f.state(0), InstanceState::Omitted);
    assert!(cmds.is_empty());
}

#[test]
fn lines_25_26_inactive_shared_in_active_hitbox_is_added() {
    let mut f = Frame::new(
        vec![
            inst(InstanceState::Inactive, 0, false),
            inst(InstanceState::Inactive, 1, false),
        ],
        vec![hitbox(true), hitbox(false)],
    );
    let (s, cmds) = f.run(&[500, 0], 4);
    assert_eq!(s.inactive_to_active, 1);
    assert_eq!(f.state(0), InstanceState::Active);
    assert_eq!(f.state(1), InstanceState::Inactive);
    assert_eq!(cmds, vec![add(0, 500)]);
}

#[test]
fn lines_31_32_omitted_above_sigma_a_is_added() {
    let mut f = Frame::new(
        vec![
            inst(InstanceState::Omitted, 0, true),
            inst(InstanceState::Omitted, 0, true),
        ],
        vec![hitbox(true)],
    );
    f.hits = vec![TH.sigma_a + 1, TH.sigma_a];
    let (s, cmds) = f.run(&[0], 4);
    assert_eq!(s.omitted_to_active, 1);
    assert_eq!(f.state(0), InstanceState::Active);
    assert_eq!(
        f.state(1),
        InstanceState::Omitted,
        "σa itself is not above σa"
    );
    assert_eq!(cmds, vec![add(0, TH.sigma_a + 1)]);
}

#[test]
fn lines_34_35_active_unique_below_sigma_o_is_omitted() {
    let mut no_blas = inst(InstanceState::Active, 0, true);
    no_blas.packed &= !instance_bits::HAS_BLAS;
    let mut f = Frame::new(
        vec![
            inst(InstanceState::Active, 0, true),
            inst(InstanceState::Active, 0, true),
            no_blas,
        ],
        vec![hitbox(true)],
    );
    f.hits = vec![TH.sigma_o - 1, TH.sigma_o, 0];
    let (s, cmds) = f.run(&[5000], 4);
    assert_eq!(s.active_to_omitted, 1);
    assert_eq!(f.state(0), InstanceState::Omitted);
    assert_eq!(f.state(1), InstanceState::Active);
    // Not yet built, so not in the TLAS: its zero hits do not demote it.
    assert_eq!(f.state(2), InstanceState::Active);
    assert_eq!(cmds, vec![remove(0, TH.sigma_o - 1)]);
}

fn pinned(state: InstanceState, hitbox: u32, unique: bool) -> InstanceHot {
    let mut r = inst(state, hitbox, unique);
    r.packed |= instance_bits::PINNED;
    r
}

#[test]
fn pinned_instances_are_never_moved_and_their_hits_stay_out() {
    let mut f = Frame::new(
        vec![
            pinned(InstanceState::Active, 0, false),
            pinned(InstanceState::Active, 0, true),
            pinned(InstanceState::Active, 1, true),
            inst(InstanceState::Active, 0, false),
        ],
        vec![hitbox(true), hitbox(true)],
    );
    // Pinned hits far above θd do not keep hitbox 0 alive; zero hits on
    // a pinned unique instance do not omit it (σo).
    f.hits = vec![100_000, 0, 100_000, 0];
    let mut deactivated = false;
    for _ in 0..1000 {
        let (s, cmds) = f.run(&[0, 0], 8);
        deactivated |= s.hitboxes_deactivated > 0;
        for slot in 0..3 {
            assert_eq!(f.state(slot), InstanceState::Active);
            assert!(cmds.iter().all(|c| c.slot != slot as u32), "{cmds:?}");
        }
        assert_eq!(f.hitboxes[0].hits(), 0);
    }
    assert!(deactivated);
    assert!(!f.hitboxes[0].is_active() && !f.hitboxes[1].is_active());
    // The unpinned instance of hitbox 0 followed the normal rule.
    assert_eq!(f.state(3), InstanceState::Inactive);

    // Unpinned, slot 0 returns to its (inactive) hitbox's state.
    f.instances[0].packed &= !instance_bits::PINNED;
    f.hits[0] = 0; // (its hits would now count: 100k would activate hitbox 0)
    let (s, cmds) = f.run(&[0, 0], 8);
    assert_eq!(s.active_to_inactive, 1);
    assert_eq!(cmds, vec![remove(0, 0)]);
    assert_eq!(f.state(0), InstanceState::Inactive);
}

#[test]
fn overflow_keeps_state_and_retries_next_frame() {
    let mut f = Frame::new(
        vec![
            inst(InstanceState::Inactive, 0, false),
            inst(InstanceState::Inactive, 0, false),
            inst(InstanceState::Active, 1, false),
        ],
        vec![hitbox(true), hitbox(false)],
    );
    let (s, cmds) = f.run(&[5000, 0], 1);
    assert_eq!(cmds, vec![add(0, 5000)]);
    assert_eq!(
        (s.inactive_to_active, s.active_to_inactive, s.overflowed),
        (1, 0, 2)
    );
    assert_eq!(f.state(0), InstanceState::Active);
    assert_eq!(
        f.state(1),
        InstanceState::Inactive,
        "did not fit: unchanged"
    );
    assert_eq!(f.state(2), InstanceState::Active, "did not fit: unchanged");

    let (s, cmds) = f.run(&[5000, 0], 8);
    assert_eq!(s.overflowed, 0);
    assert_eq!(cmds, vec![add(1, 5000), remove(2, 0)]);
    assert_eq!(f.state(1), InstanceState::Active);
    assert_eq!(f.state(2), InstanceState::Inactive);

    // And nothing is emitted twice afterwards.
    let (_, cmds) = f.run(&[5000, 0], 8);
    assert!(cmds.is_empty());
}

#[test]
fn overflow_after_line_23_keeps_the_omitted_state() {
    // Inactive unique instance, hitbox active, own hits above σa (e.g.
    // activated by latency mitigation): line 23 then line 31 in one frame.
    let mut f = Frame::new(
        vec![inst(InstanceState::Inactive, 0, true)],
        vec![hitbox(true)],
    );
    f.hits[0] = TH.sigma_a + 1;
    let (s, cmds) = f.run(&[5000], 0);
    assert!(cmds.is_empty());
    assert_eq!(
        (s.inactive_to_omitted, s.omitted_to_active, s.overflowed),
        (1, 0, 1)
    );
    assert_eq!(f.state(0), InstanceState::Omitted);
    let (s, cmds) = f.run(&[5000], 1);
    assert_eq!((s.omitted_to_active, s.overflowed), (1, 0));
    assert_eq!(cmds, vec![add(0, TH.sigma_a + 1)]);
    assert_eq!(f.state(0), InstanceState::Active);
}

#[test]
fn overflowed_transitions_reach_the_queue_exactly_once() {
    // Ten instances activate while the buffer holds three per frame.
    let instances = (0..10)
        .map(|_| inst(InstanceState::Inactive, 0, false))
        .collect();
    let mut f = Frame::new(instances, vec![hitbox(true)]);
    let mut q = CommandQueue::new(10);
    let mut total = 0;
    for _ in 0..5 {
        let mut buf = CommandBuffer::new(3);
        crate::assembly::begin_frame(&mut f.hitboxes);
        f.hitboxes[0].add_hits(5000);
        let s =
            process_feedback(&mut f.instances, &f.hits, &mut f.hitboxes, &TH, &mut buf).unwrap();
        total += s.inactive_to_active;
        let i = q.ingest_buffer(&buf);
        assert_eq!(i.superseded + i.replaced, 0);
    }
    assert_eq!(total, 10);
    let mut slots: Vec<u32> = q.drain(100).iter().map(|c| c.slot).collect();
    slots.sort_unstable();
    assert_eq!(slots, (0..10).collect::<Vec<_>>());
}

#[test]
fn dead_and_invalid_slots_are_skipped() {
    let mut dead = inst(InstanceState::Active, 0, false);
    dead.packed &= !instance_bits::ALIVE;
    let mut f = Frame::new(
        vec![dead, inst(InstanceState::Active, 9, false)],
        vec![hitbox(false)],
    );
    f.hits = vec![4000, 4000];
    let (s, cmds) = f.run(&[0], 4);
    assert!(cmds.is_empty());
    assert_eq!(s.invalid_instances, 1);
    assert_eq!(
        f.hitboxes[0].hits(),
        0,
        "dead slot's hits are not accumulated"
    );
    assert_eq!(f.state(0), InstanceState::Active);
}

#[test]
fn mismatched_inputs_are_errors() {
    let mut i = vec![inst(InstanceState::Active, 0, false)];
    let mut h = vec![hitbox(false)];
    let mut b = CommandBuffer::new(1);
    assert!(matches!(
        process_feedback(&mut i, &[], &mut h, &TH, &mut b),
        Err(FeedbackError::HitCountMismatch {
            hits: 0,
            instances: 1
        })
    ));
    let bad = Thresholds {
        theta_d: TH.theta_a,
        ..TH
    };
    let e = process_feedback(&mut i, &[0], &mut h, &bad, &mut b).unwrap_err();
    assert!(matches!(e, FeedbackError::Thresholds(_)));
    assert!(std::error::Error::source(&e).is_some());
    assert_eq!(i[0].state(), InstanceState::Active, "nothing ran");
}

/// Algorithm 2 under the decayed rule ([`DecisionRule::Decayed`]): rates,
/// hysteresis, cost-aware activation, the per-slot rates.
/// Algorithm 2 as it was before the hot/cold split, over whole 96-byte
/// records (`blas != 0` instead of `HAS_BLAS`), copied verbatim: the split
/// version must make the same transitions, commands, hitboxes and rates.
#[allow(clippy::too_many_lines)]
fn reference_process_records(
    instances: &mut [InstanceRecord],
    instance_hits: &[u32],
    rates: Option<&mut [u32]>,
    hitboxes: &mut [HitboxRecord],
    th: &Thresholds,
    commands: &mut CommandBuffer,
) -> Result<FeedbackStats, FeedbackError> {
    if instance_hits.len() != instances.len() {
        return Err(FeedbackError::HitCountMismatch {
            hits: instance_hits.len(),
            instances: instances.len(),
        });
    }
    if instances.len() > MAX_SLOTS as usize {
        return Err(FeedbackError::TooManySlots(instances.len()));
    }
    th.validate().map_err(FeedbackError::Thresholds)?;
    let mut stats = FeedbackStats::default();

    // Lines 1–6: one thread per slot.
    const LIVE_OMITTED: u32 = instance_bits::ALIVE | InstanceState::Omitted as u32;
    const LIVE_ACTIVE: u32 = instance_bits::ALIVE | InstanceState::Active as u32;
    for (m, &hits) in instances.iter().zip(instance_hits) {
        let key = m.packed & (instance_bits::ALIVE | instance_bits::STATE_MASK);
        // Pinned instances are not the hitbox's to decide on: their hits stay out.
        if (key == LIVE_OMITTED || key == LIVE_ACTIVE) && m.packed & instance_bits::PINNED == 0 {
            if let Some(h) = hitboxes.get_mut(m.hitbox as usize) {
                h.add_hits(hits); // line 4
            }
        }
    }

    // Lines 7–13: one thread per hitbox.
    let mut decayed = match (&th.rule, rates) {
        (DecisionRule::Decayed(r), Some(rates)) => Some((*r, rates)),
        _ => None,
    };
    for h in hitboxes.iter_mut() {
        let change = match &decayed {
            Some((r, _)) => hitbox_step_decayed(h, r),
            None => {
                let (packed, change) = hitbox_step(h.packed, th);
                h.packed = packed;
                change
            }
        };
        stats.hitboxes_activated += u32::from(change > 0);
        stats.hitboxes_deactivated += u32::from(change < 0);
    }

    // Lines 14–38: one thread per slot.
    for (slot, (m, &hits)) in instances.iter_mut().zip(instance_hits).enumerate() {
        // Dead, or pinned: Algorithm 2 never moves a pinned instance. The
        // rate of either is 0 (a dead slot is reused only after quarantine).
        if m.packed & (instance_bits::ALIVE | instance_bits::PINNED) != instance_bits::ALIVE {
            if let Some((_, rates)) = decayed.as_mut() {
                rates[slot] = 0;
            }
            continue;
        }
        let Some(h) = hitboxes.get(m.hitbox as usize) else {
            stats.invalid_instances += 1;
            continue;
        };
        let old = m.state();
        let h_active = h.is_active();
        let unique = m.packed & instance_bits::UNIQUE_BLAS != 0;
        // Fast path: nothing in lines 16–37 can fire (and the rate of an
        // inactive or shared-BLAS instance is 0).
        match (old, h_active) {
            (InstanceState::Inactive, false) => {
                if let Some((_, rates)) = decayed.as_mut() {
                    rates[slot] = 0;
                }
                continue;
            }
            (InstanceState::Active, true) | (InstanceState::Omitted, true) if !unique => {
                if let Some((_, rates)) = decayed.as_mut() {
                    rates[slot] = 0;
                }
                continue;
            }
            _ => {}
        }
        let slot = slot as u32;
        let command = |kind, hits| Command {
            slot,
            kind,
            priority: priority_from_hits(hits),
        };
        let mut state = old;
        let mut overflow = false;

        match (state, h_active) {
            (InstanceState::Active, false) => {
                // Lines 17/18.
                if commands.push(command(CommandKind::Remove, h.hits())) {
                    state = InstanceState::Inactive;
                    stats.active_to_inactive += 1;
                } else {
                    overflow = true;
                }
            }
            (InstanceState::Omitted, false) => {
                // Lines 19/20.
                state = InstanceState::Inactive;
                stats.omitted_to_inactive += 1;
            }
            (InstanceState::Inactive, true) => {
                if unique {
                    // Line 23.
                    state = InstanceState::Omitted;
                    stats.inactive_to_omitted += 1;
                } else if commands.push(command(CommandKind::Add, h.hits())) {
                    // Lines 25/26.
                    state = InstanceState::Active;
                    stats.inactive_to_active += 1;
                } else {
                    overflow = true;
                }
            }
            _ => {}
        }

        // Lines 29–37 under the decayed rule: this frame's rate decides.
        if let Some((r, rates)) = decayed.as_mut() {
            let slot = slot as usize;
            if !unique {
                rates[slot] = 0;
            } else {
                let rate = match state {
                    InstanceState::Inactive => 0,
                    // Not in the TLAS until its BLAS exists: no evidence, held.
                    InstanceState::Active if m.blas == 0 => rates[slot],
                    _ => r.update_rate(rates[slot], hits),
                };
                rates[slot] = rate;
                if !overflow {
                    if state == InstanceState::Omitted && rate > r.instance_activate {
                        if commands.push(command(CommandKind::Add, hits)) {
                            state = InstanceState::Active;
                            stats.omitted_to_active += 1;
                        } else {
                            overflow = true;
                        }
                    } else if state == InstanceState::Active
                        && m.blas != 0
                        && rate < r.instance_omit
                    {
                        if commands.push(command(CommandKind::Remove, hits)) {
                            state = InstanceState::Omitted;
                            stats.active_to_omitted += 1;
                        } else {
                            overflow = true;
                        }
                    }
                }
            }
        } else if unique && !overflow {
            // Lines 29–37 (M needs a unique BLAS).
            if state == InstanceState::Omitted && hits > th.sigma_a {
                // Lines 31/32.
                if commands.push(command(CommandKind::Add, hits)) {
                    state = InstanceState::Active;
                    stats.omitted_to_active += 1;
                } else {
                    overflow = true;
                }
            } else if state == InstanceState::Active && m.blas != 0 && hits < th.sigma_o {
                // Lines 34/35 (only once the BLAS exists; see docs/ALGORITHMS.md).
                if commands.push(command(CommandKind::Remove, hits)) {
                    state = InstanceState::Omitted;
                    stats.active_to_omitted += 1;
                } else {
                    overflow = true;
                }
            }
        }

        stats.overflowed += u32::from(overflow);
        if state != old {
            m.set_state(state);
        }
    }
    Ok(stats)
}

/// The escape sample as the Manager took it before Algorithm 2 summed it
/// (a second walk over the records and hit counters).
fn reference_escape(
    records: &[InstanceRecord],
    hits: &[u32],
    hitboxes: &[HitboxRecord],
) -> (u64, u64) {
    let mut boxes: u64 = hitboxes.iter().map(|h| u64::from(h.hits())).sum();
    let mut traced = 0u64;
    for (r, &h) in records.iter().zip(hits) {
        if !r.is_alive() {
            continue;
        }
        match r.state() {
            InstanceState::Omitted => boxes += u64::from(h),
            _ => traced += u64::from(h),
        }
    }
    (boxes, traced)
}

#[test]
fn split_hot_array_gives_the_records_outcome_and_the_escape_sums() {
    use crate::thresholds::{DecayedRule, RATE_ONE};
    use lipac_test_support::{Rng64, XorShift64};
    let decayed = Thresholds::paper().with_rule(DecisionRule::Decayed(DecayedRule {
        shift: 2,
        rise_shift: 1,
        activate: 4 * RATE_ONE,
        deactivate: RATE_ONE,
        instance_activate: 3 * RATE_ONE,
        instance_omit: RATE_ONE / 2,
        per_shared: RATE_ONE / 2,
        per_unique: 2 * RATE_ONE,
    }));
    let mut rng = XorShift64::new(0x15_F33D);
    let n_hitboxes = 30;
    let mut moved = 0;
    for round in 0..24 {
        let th = if round % 2 == 0 { TH } else { decayed };
        let records: Vec<InstanceRecord> = (0..2000)
            .map(|_| {
                let mut packed = rng.below_u32(4) | (rng.next_u32() & 0xFFFF_FF30);
                for (p, bit) in [
                    (90, instance_bits::ALIVE),
                    (40, instance_bits::UNIQUE_BLAS),
                    (10, instance_bits::PINNED),
                    (50, instance_bits::HAS_BLAS), // contradicts `blas` at times
                ] {
                    if rng.below_u32(100) < p {
                        packed |= bit;
                    }
                }
                InstanceRecord {
                    hitbox: rng.below_u32(n_hitboxes + 2), // some out of range
                    packed,
                    blas: if rng.below_u32(4) == 0 {
                        0
                    } else {
                        rng.next_u64() | 1
                    },
                    ..Default::default()
                }
            })
            .collect();
        let hits: Vec<u32> = (0..records.len())
            .map(|_| match rng.below_u32(4) {
                0 => 0,
                1 => rng.below_u32(2 * TH.sigma_a),
                2 => rng.next_u32(),
                _ => rng.below_u32(20),
            })
            .collect();
        let hitboxes: Vec<HitboxRecord> = (0..n_hitboxes)
            .map(|_| {
                let mut h = HitboxRecord {
                    packed: rng.next_u32() & 0xFF,
                    rate: rng.below_u32(8 * RATE_ONE),
                    cost: rng.next_u32(),
                    ..Default::default()
                };
                h.add_hits(rng.below_u32(3 * TH.theta_a));
                h
            })
            .collect();
        let rates: Vec<u32> = (0..records.len())
            .map(|_| rng.below_u32(6 * RATE_ONE))
            .collect();
        let capacity = [5, 100, 2000][round % 3];

        let (mut ref_records, mut ref_hb, mut ref_rates) =
            (records.clone(), hitboxes.clone(), rates.clone());
        let mut ref_cmds = CommandBuffer::new(capacity);
        let want = reference_process_records(
            &mut ref_records,
            &hits,
            Some(&mut ref_rates),
            &mut ref_hb,
            &th,
            &mut ref_cmds,
        )
        .unwrap();
        let escape = reference_escape(&records, &hits, &hitboxes);

        let arrays = crate::layout::InstanceArrays::from_records(&records);
        let mut hot = arrays.hot().to_vec();
        let (mut hb, mut new_rates) = (hitboxes.clone(), rates.clone());
        let mut cmds = CommandBuffer::new(capacity);
        let got =
            process_feedback_with_rates(&mut hot, &hits, &mut new_rates, &mut hb, &th, &mut cmds)
                .unwrap();
        let what = format!("round {round}");
        assert_eq!((got.box_hits, got.traced_hits), escape, "{what}");
        assert_eq!(
            FeedbackStats {
                box_hits: 0,
                traced_hits: 0,
                ..got
            },
            want,
            "{what}"
        );
        let ref_hot: Vec<InstanceHot> = ref_records.iter().map(InstanceRecord::hot).collect();
        assert_eq!(hot, ref_hot, "{what}");
        assert_eq!(cmds.words(), ref_cmds.words(), "{what}");
        assert_eq!(cmds.requested(), ref_cmds.requested(), "{what}");
        assert_eq!(new_rates, ref_rates, "{what}");
        assert_eq!(
            bytemuck::cast_slice::<_, u32>(&hb),
            bytemuck::cast_slice::<_, u32>(&ref_hb),
            "{what}"
        );
        moved += records
            .iter()
            .zip(&ref_records)
            .filter(|(a, b)| a.state() != b.state())
            .count();
        assert!(want.overflowed > 0 || capacity == 2000, "{what}");
    }
    assert!(moved > 1000, "{moved} transitions");
}

/// The chunked fast paths (8 slots at a time: a chunk without hits skipped
/// in lines 1–6, a chunk's fast-path slots skipped in lines 14–38) on a
/// coherent scene where they fire: runs of 16 slots per hitbox, mostly in
/// agreement with it, zero hits on inactive slots, a few dead, pinned,
/// out-of-range and contradicting slots, and a slot count that leaves a
/// tail. Over frames, the state carried forward, against the verbatim
/// pre-split reference.
#[test]
fn chunked_fast_paths_match_the_reference_on_a_coherent_scene() {
    use lipac_test_support::{Rng64, XorShift64};
    let mut rng = XorShift64::new(0xC0_4E5E);
    let n_hitboxes = 70u32;
    let n = 16 * n_hitboxes as usize + 13; // not a multiple of 8
    let mut hitboxes: Vec<HitboxRecord> = (0..n_hitboxes)
        .map(|_| hitbox(rng.below_u32(4) == 0))
        .collect();
    let mut records: Vec<InstanceRecord> = (0..n)
        .map(|slot| {
            let hb = if rng.below_u32(10) == 0 {
                rng.below_u32(n_hitboxes + 1) // scattered, some out of range
            } else {
                (slot / 16) as u32 % n_hitboxes
            };
            let unique = rng.below_u32(7) == 0;
            let active_hb = hitboxes.get(hb as usize).is_some_and(|h| h.is_active());
            let agree = rng.below_u32(50) != 0;
            let state = match (active_hb == agree, unique, rng.below_u32(2)) {
                (true, true, 0) => InstanceState::Omitted,
                (true, _, _) => InstanceState::Active,
                (false, _, _) => InstanceState::Inactive,
            };
            let mut packed = instance_bits::ALIVE | instance_bits::HAS_BLAS;
            if unique {
                packed |= instance_bits::UNIQUE_BLAS;
            }
            match rng.below_u32(100) {
                0 => packed &= !instance_bits::ALIVE,
                1 => packed |= instance_bits::PINNED,
                2 => packed |= instance_bits::STATE_MASK, // the unused value 3
                _ => {}
            }
            let mut r = InstanceRecord {
                hitbox: hb,
                packed,
                blas: 0xB1A5,
                ..Default::default()
            };
            if packed & instance_bits::STATE_MASK != instance_bits::STATE_MASK {
                r.set_state(state);
            }
            r
        })
        .collect();
    let mut hot: Vec<InstanceHot> = records.iter().map(InstanceRecord::hot).collect();
    let mut split_hb = hitboxes.clone();
    let (mut quiet_chunks, mut moved) = (0, 0);
    for frame in 0..12 {
        let hits: Vec<u32> = records
            .iter()
            .map(|r| match r.state() {
                InstanceState::Inactive => 0,
                _ if rng.below_u32(20) == 0 => rng.below_u32(2000),
                _ => rng.below_u32(2 * TH.sigma_o),
            })
            .collect();
        quiet_chunks += hits
            .chunks_exact(8)
            .filter(|c| c.iter().all(|&h| h == 0))
            .count();
        crate::assembly::begin_frame(&mut hitboxes);
        crate::assembly::begin_frame(&mut split_hb);
        for (i, (a, b)) in hitboxes.iter_mut().zip(split_hb.iter_mut()).enumerate() {
            let x = (i as u32 + frame).wrapping_mul(2_654_435_761) >> 22; // 0..1024
            let box_hits = if x < 30 { 2500 } else { x };
            a.add_hits(box_hits);
            b.add_hits(box_hits);
        }
        let capacity = [1000, 7][frame as usize % 2];
        let mut ref_cmds = CommandBuffer::new(capacity);
        let want =
            reference_process_records(&mut records, &hits, None, &mut hitboxes, &TH, &mut ref_cmds)
                .unwrap();
        let mut cmds = CommandBuffer::new(capacity);
        let before: Vec<InstanceHot> = hot.clone();
        let got = process_feedback(&mut hot, &hits, &mut split_hb, &TH, &mut cmds).unwrap();
        let what = format!("frame {frame}");
        assert_eq!(
            FeedbackStats {
                box_hits: 0,
                traced_hits: 0,
                ..got
            },
            want,
            "{what}"
        );
        let ref_hot: Vec<InstanceHot> = records.iter().map(InstanceRecord::hot).collect();
        assert_eq!(hot, ref_hot, "{what}");
        assert_eq!(cmds.words(), ref_cmds.words(), "{what}");
        assert_eq!(cmds.requested(), ref_cmds.requested(), "{what}");
        assert_eq!(
            bytemuck::cast_slice::<_, u32>(&split_hb),
            bytemuck::cast_slice::<_, u32>(&hitboxes),
            "{what}"
        );
        moved += before.iter().zip(&hot).filter(|(a, b)| a != b).count();
    }
    assert!(quiet_chunks > 100, "{quiet_chunks} chunks without hits");
    assert!(moved > 50, "{moved} transitions");
}

mod decayed {
    use super::*;
    use crate::layout::InstanceState;
    use crate::thresholds::{DecayedRule, RATE_ONE};

    const RULE: DecayedRule = DecayedRule {
        shift: 2,
        rise_shift: 2,
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

    fn inst(state: InstanceState, unique: bool, blas: u64) -> InstanceHot {
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
        r.hot()
    }

    /// One frame: the hitbox gets `box_hits` (counting box) with `cost`
    /// inactive instances, then Algorithm 2.
    fn frame(
        instances: &mut [InstanceHot],
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
        i[0].packed |= instance_bits::HAS_BLAS;
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
            InstanceHot::default(), // dead
            inst(InstanceState::Omitted, true, 0),
        ];
        let mut rates = [7, 8, 9];
        frame(&mut i, &[5, 5, 0], &mut rates, &mut h, 0, 0);
        assert_eq!(rates[..2], [0, 0]);
        assert_eq!(rates[2], RULE.update_rate(9, 0));
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
        let e =
            process_feedback_with_rates(&mut i, &[0], &mut [], &mut h, &th(), &mut b).unwrap_err();
        assert!(matches!(
            e,
            FeedbackError::RateCountMismatch {
                rates: 0,
                instances: 1
            }
        ));
        assert!(e.to_string().contains("rate buffer"));
    }

    /// A fast rise with a slow decay (k_up = 1, k = 3, activation 4 and
    /// deactivation 1 hit per frame) does not flip a hitbox that is hit
    /// every other frame: a hit frame and an empty one move the rate by one
    /// decay step at most (×7/8), far inside the activate/deactivate band,
    /// whatever the hits. The rise only brings the activation forward (and
    /// activates at 5 hits every other frame, a mean of 2.5 whose peaks
    /// the symmetric rate never lifts above 4).
    #[test]
    fn a_fast_rise_does_not_flip_a_hitbox_hit_every_other_frame() {
        let run = |k_up: u32, hits: u32| -> (u32, Option<u32>, u32, u32) {
            let rule = DecayedRule {
                shift: 3,
                rise_shift: k_up,
                ..RULE
            };
            let th = Thresholds::paper().with_rule(DecisionRule::Decayed(rule));
            let mut i = [inst(InstanceState::Inactive, false, 0)];
            let mut h = HitboxRecord::default();
            let (mut changes, mut first_on) = (0, None);
            let (mut lo, mut hi) = (u32::MAX, 0);
            for f in 0..200u32 {
                crate::assembly::begin_frame(std::slice::from_mut(&mut h));
                h.add_hits(if f % 2 == 0 { hits } else { 0 });
                let mut buf = CommandBuffer::new(16);
                let s = process_feedback_with_rates(
                    &mut i,
                    &[0],
                    &mut [0],
                    std::slice::from_mut(&mut h),
                    &th,
                    &mut buf,
                )
                .unwrap();
                changes += s.hitboxes_activated + s.hitboxes_deactivated;
                if h.is_active() && first_on.is_none() {
                    first_on = Some(f);
                }
                if f >= 198 {
                    (lo, hi) = (lo.min(h.rate), hi.max(h.rate));
                }
            }
            (changes, first_on, lo, hi)
        };
        for hits in [5u32, 9, 16, 40, 1000, 70_000] {
            let mut on_at = Vec::new();
            for k_up in [1, 2, 3] {
                let (changes, first_on, lo, hi) = run(k_up, hits);
                let ctx = format!("k_up {k_up}, {hits} hits every other frame");
                assert!(changes <= 1, "{ctx}: {changes} changes");
                assert_eq!(changes == 1, first_on.is_some(), "{ctx}: on and never off");
                // The swing in steady state (the last hit frame and the
                // empty one after it): one decay step, lo = ⌈hi · 7/8⌉.
                assert!(u64::from(hi) * 7 <= u64::from(lo) * 8, "{ctx}: {lo}..{hi}");
                on_at.push(first_on.unwrap_or(u32::MAX));
            }
            assert!(
                on_at[0] <= on_at[1] && on_at[1] <= on_at[2],
                "{hits}: {on_at:?}"
            );
            if hits == 5 {
                // 2.5, 2.19, 3.59, 3.14, 4.07 > 4 with k_up = 1.
                assert_eq!(on_at, [4, u32::MAX, u32::MAX], "never with k_up 2 or 3");
            } else {
                assert_eq!(on_at[0], 0, "{hits}: k_up = 1 activates at once");
            }
        }
    }
}

mod chunks;
