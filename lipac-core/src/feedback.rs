//! Algorithm 2 (thesis Algorithm 5): process hit feedback, CPU reference.
//!
//! Runs once per frame after path tracing, over the buffers a GPU backend
//! holds: instance records, the per-instance hit counters (one `u32` per slot,
//! the paper's 4 bytes), the hitbox records and the bounded command buffer.
//! Line numbers below are those of the paper's Algorithm 2 / thesis
//! Algorithm 5.
//!
//! It adds instance hits to their hitboxes (lines 1–6), moves hitbox states
//! (7–13) and instance states (14–38), appending `add`/`remove` commands to
//! the bounded [`CommandBuffer`].
//!
//! * **The overflow rule.** A transition that emits a command takes effect
//!   only if the command fits ([`CommandBuffer::push`] returns `true`; on the
//!   GPU the `atomicAdd` index is below the capacity); otherwise the instance
//!   keeps its state and the transition is retried next frame: nothing lost,
//!   nothing duplicated ([`FeedbackStats::overflowed`]).
//! * **Pinned instances** ([`instance_bits::PINNED`]) are skipped by every
//!   decision: their hits are not added to their hitbox (line 4) and no
//!   transition or command is made for them (lines 14–38), whatever their
//!   hitbox does.
//! * **Who resets what.** Hit counts are this frame's; the hitbox counts stay
//!   readable after this call and are zeroed by
//!   [`crate::assembly::begin_frame`] next frame; the backend clears the
//!   per-instance hit buffer before tracing. A live instance whose hitbox
//!   index is out of range is skipped ([`FeedbackStats::invalid_instances`]).
//!
//! Every line, the deviations from the pseudocode and why:
//! `docs/ALGORITHMS.md`.

use std::fmt;

use crate::command::{priority_from_hits, Command, CommandBuffer, CommandKind};
use crate::layout::{
    hitbox_bits, instance_bits, HitboxRecord, InstanceRecord, InstanceState, MAX_SLOTS,
};
use crate::thresholds::{decay_rate, DecayedRule, DecisionRule, ThresholdError, Thresholds};

/// What one run of [`process_feedback`] did, by line of Algorithm 2.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FeedbackStats {
    /// Line 9: hitboxes activated.
    pub hitboxes_activated: u32,
    /// Line 11: hitboxes deactivated.
    pub hitboxes_deactivated: u32,
    /// Lines 17/18: active → inactive with a `remove` command.
    pub active_to_inactive: u32,
    /// Lines 19/20: omitted → inactive.
    pub omitted_to_inactive: u32,
    /// Line 23: inactive → omitted (needs a unique BLAS).
    pub inactive_to_omitted: u32,
    /// Lines 25/26: inactive → active with an `add` command.
    pub inactive_to_active: u32,
    /// Lines 31/32: omitted → active with an `add` command.
    pub omitted_to_active: u32,
    /// Lines 34/35: active → omitted with a `remove` command.
    pub active_to_omitted: u32,
    /// Transitions not taken because the command buffer was full; they are
    /// retried next frame.
    pub overflowed: u32,
    /// Live instances skipped because their hitbox index is out of range.
    pub invalid_instances: u32,
}

/// Inputs of [`process_feedback`] that do not fit together.
#[derive(Clone, Debug, PartialEq)]
pub enum FeedbackError {
    /// The hit buffer must have one counter per instance slot.
    HitCountMismatch {
        /// `instance_hits.len()`.
        hits: usize,
        /// `instances.len()`.
        instances: usize,
    },
    /// More instance records than 24-bit slots.
    TooManySlots(usize),
    /// The thresholds failed [`Thresholds::validate`].
    Thresholds(ThresholdError),
    /// The rate buffer must have one rate per instance slot.
    RateCountMismatch {
        /// `instance_rates.len()`.
        rates: usize,
        /// `instances.len()`.
        instances: usize,
    },
    /// [`process_feedback`] has no rate buffer: the decayed rule needs
    /// [`process_feedback_with_rates`].
    RatesRequired,
}

impl fmt::Display for FeedbackError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::HitCountMismatch { hits, instances } => write!(
                f,
                "hit buffer has {hits} counters but there are {instances} instance slots"
            ),
            Self::TooManySlots(n) => {
                write!(f, "{n} instance slots exceed the 24-bit limit {MAX_SLOTS}")
            }
            Self::Thresholds(e) => write!(f, "invalid thresholds: {e}"),
            Self::RateCountMismatch { rates, instances } => write!(
                f,
                "rate buffer has {rates} rates but there are {instances} instance slots"
            ),
            Self::RatesRequired => write!(
                f,
                "the decayed rule keeps a rate per slot: call process_feedback_with_rates"
            ),
        }
    }
}

impl std::error::Error for FeedbackError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Thresholds(e) => Some(e),
            _ => None,
        }
    }
}

/// Lines 7–13 for one hitbox: returns the new `packed` word (hits kept) and
/// `+1` for an activation, `-1` for a deactivation, `0` otherwise.
fn hitbox_step(packed: u32, th: &Thresholds) -> (u32, i8) {
    let hits = packed >> hitbox_bits::HITS_SHIFT;
    let active = packed & hitbox_bits::ACTIVE != 0;
    let streak = (packed >> hitbox_bits::STREAK_SHIFT) & hitbox_bits::STREAK_MAX;
    let (active, streak, change) = if !active {
        if u64::from(hits) > 2 * u64::from(th.theta_a) {
            (true, 0, 1) // line 9, single-frame path
        } else if hits > th.theta_a {
            let s = (streak + 1).min(hitbox_bits::STREAK_MAX);
            if s >= th.n_a {
                (true, 0, 1) // line 9, n_a consecutive frames
            } else {
                (false, s, 0)
            }
        } else {
            (false, 0, 0)
        }
    } else if hits < th.theta_d {
        let s = (streak + 1).min(hitbox_bits::STREAK_MAX);
        if s >= th.n_d {
            (false, 0, -1) // line 11
        } else {
            (true, s, 0)
        }
    } else {
        (true, 0, 0)
    };
    let packed = (hits << hitbox_bits::HITS_SHIFT)
        | (streak << hitbox_bits::STREAK_SHIFT)
        | u32::from(active);
    (packed, change)
}

/// Lines 7–13 under the decayed rule for one hitbox: updates its rate and
/// state (streak bits cleared, hits kept); `+1` activation, `-1`
/// deactivation.
fn hitbox_step_decayed(h: &mut HitboxRecord, r: &DecayedRule) -> i8 {
    let rate = decay_rate(h.rate, h.hits(), r.shift);
    h.rate = rate;
    let active = h.is_active();
    let (active, change) = if !active {
        if rate > r.activation_threshold(h.inactive_shared(), h.inactive_unique()) {
            (true, 1)
        } else {
            (false, 0)
        }
    } else if rate < r.deactivate {
        (false, -1)
    } else {
        (true, 0)
    };
    h.packed = (h.packed & !((hitbox_bits::STREAK_MAX << hitbox_bits::STREAK_SHIFT) | 1))
        | u32::from(active);
    change
}

/// Algorithm 2 under the paper's rule ([`DecisionRule::Paper`]); the same
/// as [`process_feedback_with_rates`] without a rate buffer, which the
/// decayed rule needs ([`FeedbackError::RatesRequired`]).
///
/// ```
/// use lipac_core::command::{Command, CommandBuffer, CommandKind};
/// use lipac_core::feedback::process_feedback;
/// use lipac_core::layout::{instance_bits, HitboxRecord, InstanceRecord, InstanceState};
/// use lipac_core::thresholds::Thresholds;
///
/// // One inactive instance in an inactive hitbox whose counting box was hit
/// // by 2500 rays (> 2·θa): the hitbox activates and the instance with it.
/// let mut instances = [InstanceRecord { packed: instance_bits::ALIVE, ..Default::default() }];
/// let mut hitboxes = [HitboxRecord::default()];
/// hitboxes[0].add_hits(2500);
/// let mut commands = CommandBuffer::new(16);
/// let stats = process_feedback(&mut instances, &[0], &mut hitboxes, &Thresholds::paper(), &mut commands)
///     .unwrap();
/// assert_eq!((stats.hitboxes_activated, stats.inactive_to_active), (1, 1));
/// assert_eq!(instances[0].state(), InstanceState::Active);
/// let cmd = Command::decode(commands.words()[0], 1).unwrap();
/// assert_eq!((cmd.slot, cmd.kind), (0, CommandKind::Add));
/// ```
pub fn process_feedback(
    instances: &mut [InstanceRecord],
    instance_hits: &[u32],
    hitboxes: &mut [HitboxRecord],
    th: &Thresholds,
    commands: &mut CommandBuffer,
) -> Result<FeedbackStats, FeedbackError> {
    if th.rule != DecisionRule::Paper {
        return Err(FeedbackError::RatesRequired);
    }
    process(instances, instance_hits, None, hitboxes, th, commands)
}

/// Algorithm 2: accumulates instance hits into hitboxes, updates hitbox and
/// instance states and appends commands to `commands` (which is not cleared:
/// the caller clears it per frame, as the GPU resets its counter). See the
/// [module docs](self) for the overflow rule, `docs/ALGORITHMS.md` for the
/// lines and the deviations.
///
/// `instance_rates` (one `u32` per slot, kept across frames, zero at first)
/// holds the decayed hit rates of unique-BLAS instances under
/// [`DecisionRule::Decayed`]; under the paper's rule it is left alone.
pub fn process_feedback_with_rates(
    instances: &mut [InstanceRecord],
    instance_hits: &[u32],
    instance_rates: &mut [u32],
    hitboxes: &mut [HitboxRecord],
    th: &Thresholds,
    commands: &mut CommandBuffer,
) -> Result<FeedbackStats, FeedbackError> {
    if instance_rates.len() != instances.len() {
        return Err(FeedbackError::RateCountMismatch {
            rates: instance_rates.len(),
            instances: instances.len(),
        });
    }
    process(
        instances,
        instance_hits,
        Some(instance_rates),
        hitboxes,
        th,
        commands,
    )
}

fn process(
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
                    _ => decay_rate(rates[slot], hits, r.shift),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::command::CommandQueue;

    const TH: Thresholds = Thresholds::paper();

    fn inst(state: InstanceState, hitbox: u32, unique: bool) -> InstanceRecord {
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
        r
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
        instances: Vec<InstanceRecord>,
        hits: Vec<u32>,
        hitboxes: Vec<HitboxRecord>,
    }

    impl Frame {
        fn new(instances: Vec<InstanceRecord>, hitboxes: Vec<HitboxRecord>) -> Self {
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
        no_blas.blas = 0;
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

    fn pinned(state: InstanceState, hitbox: u32, unique: bool) -> InstanceRecord {
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
            let s = process_feedback(&mut f.instances, &f.hits, &mut f.hitboxes, &TH, &mut buf)
                .unwrap();
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
}

#[cfg(test)]
#[path = "feedback_decayed_tests.rs"]
mod decayed_tests;
