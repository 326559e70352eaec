//! Algorithm 2 (thesis Algorithm 5): process hit feedback, CPU reference.
//!
//! Runs once per frame after path tracing, over the buffers a GPU backend
//! holds: the hot instance array ([`InstanceHot`], 8 bytes per slot: hitbox
//! and packed bits; the cold part is never read, the BLAS test is
//! [`instance_bits::HAS_BLAS`]), the per-instance hit counters (one `u32` per slot,
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
//! `docs/ALGORITHMS.md`. The CPU decides the common cases many slots at a
//! time (hit counters tested 32 at once, slots past the fast path found 64
//! at once), with the same output as slot by slot: `docs/HOT_COLD.md`,
//! "Instructions per slot".

use std::fmt;

use crate::command::{priority_from_hits, Command, CommandBuffer, CommandKind};
use crate::layout::{
    hitbox_bits, instance_bits, HitboxRecord, InstanceHot, InstanceState, MAX_SLOTS,
};
use crate::thresholds::{DecayedRule, DecisionRule, ThresholdError, Thresholds};

mod busy;
mod hit_sums;

use busy::{
    busy_masks, zero_rates_but, BLOCK, CHUNK, CODE_ACTIVE, CODE_INACTIVE, CODE_OUT_OF_RANGE,
};
use hit_sums::{accumulate_hits, merge_hits};

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
    /// This frame's hits on counting boxes, summed as lines 1–6 read them:
    /// the hitboxes' counts before line 4 adds instance hits, plus the hits
    /// of live omitted instances (their boxes).
    pub box_hits: u64,
    /// This frame's hits on traced instances: live instances not omitted.
    pub traced_hits: u64,
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
    let rate = r.update_rate(h.rate, h.hits());
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
/// use lipac_core::layout::{instance_bits, HitboxRecord, InstanceHot, InstanceState};
/// use lipac_core::thresholds::Thresholds;
///
/// // One inactive instance in an inactive hitbox whose counting box was hit
/// // by 2500 rays (> 2·θa): the hitbox activates and the instance with it.
/// let mut instances = [InstanceHot { packed: instance_bits::ALIVE, ..Default::default() }];
/// let mut hitboxes = [HitboxRecord::default()];
/// hitboxes[0].add_hits(2500);
/// let mut commands = CommandBuffer::new(16);
/// let stats = process_feedback(&mut instances, &[0], &mut hitboxes, &Thresholds::paper(), &mut commands)
///     .unwrap();
/// assert_eq!((stats.hitboxes_activated, stats.inactive_to_active), (1, 1));
/// assert_eq!((stats.box_hits, stats.traced_hits), (2500, 0));
/// assert_eq!(instances[0].state(), InstanceState::Active);
/// let cmd = Command::decode(commands.words()[0], 1).unwrap();
/// assert_eq!((cmd.slot, cmd.kind), (0, CommandKind::Add));
/// ```
pub fn process_feedback(
    instances: &mut [InstanceHot],
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
    instances: &mut [InstanceHot],
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
    instances: &mut [InstanceHot],
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

    // Lines 1–6: one thread per slot ([`accumulate_hits`]), the hits for
    // each hitbox summed in `added`, added to the records by the hitbox
    // pass below.
    let mut added = vec![0u32; hitboxes.len()];
    let (omitted_hits, traced_hits) = accumulate_hits(instances, instance_hits, &mut added);
    stats.traced_hits = traced_hits;

    // Lines 7–13: one thread per hitbox. Each hitbox's new active bit also
    // goes into `codes` for the fast path of lines 14–38.
    let mut decayed = match (&th.rule, rates) {
        (DecisionRule::Decayed(r), Some(rates)) => Some((*r, rates)),
        _ => None,
    };
    let (codes, activated, deactivated, counted_hits) =
        step_hitboxes(hitboxes, &added, decayed.as_ref().map(|(r, _)| r), th);
    stats.box_hits = counted_hits + omitted_hits;
    stats.hitboxes_activated = activated;
    stats.hitboxes_deactivated = deactivated;

    // Lines 14–38: one thread per slot. The common case (dead or pinned;
    // inactive in an inactive hitbox; shared-BLAS active or omitted in an
    // active hitbox) is decided for CHUNK slots at once from the packed
    // bits and the hitbox codes ([`busy_masks`], BLOCK slots per call);
    // only the other slots run
    // [`slot_step`], in slot order, so that commands keep their order.
    // Under the decayed rule the skipped slots' rates are set to 0 (dead,
    // pinned and fast-path slots have no rate).
    let mut masks = [0u64; BLOCK / CHUNK];
    for block_base in (0..instances.len()).step_by(BLOCK) {
        let end = (block_base + BLOCK).min(instances.len());
        busy_masks(&instances[block_base..end], &codes, &mut masks);
        for (c, &mask) in masks.iter().enumerate() {
            let base = block_base + c * CHUNK;
            let mut busy = mask;
            if let Some((_, rates)) = decayed.as_mut() {
                let end = (base + CHUNK).min(rates.len());
                if let Some(chunk) = rates.get_mut(base..end) {
                    zero_rates_but(chunk, busy);
                }
            }
            while busy != 0 {
                let slot = base + busy.trailing_zeros() as usize;
                busy &= busy - 1;
                slot_step(
                    slot,
                    instances,
                    instance_hits,
                    &mut decayed,
                    hitboxes,
                    th,
                    commands,
                    &mut stats,
                );
            }
        }
    }
    Ok(stats)
}

/// Line 4's adds ([`merge_hits`] of each hitbox's entry of `added`, from
/// [`accumulate_hits`]), then lines 7–13 over every hitbox, under the
/// decayed rule if `decayed` is given, else the paper's: returns each
/// hitbox's new code ([`CODE_ACTIVE`] or [`CODE_INACTIVE`]) followed by
/// [`CODE_OUT_OF_RANGE`], the counts of activations and deactivations, and
/// the sum of the hitboxes' hit counts before the adds (the counting
/// boxes' part of [`FeedbackStats::box_hits`]). Not inlined: a small loop
/// of its own.
#[inline(never)]
fn step_hitboxes(
    hitboxes: &mut [HitboxRecord],
    added: &[u32],
    decayed: Option<&DecayedRule>,
    th: &Thresholds,
) -> (Vec<u8>, u32, u32, u64) {
    let mut codes = vec![CODE_OUT_OF_RANGE; hitboxes.len() + 1];
    let (mut activated, mut deactivated) = (0, 0);
    let mut counted: u64 = 0;
    for ((h, code), &a) in hitboxes.iter_mut().zip(codes.iter_mut()).zip(added) {
        counted += u64::from(h.hits());
        h.packed = merge_hits(h.packed, a);
        let change = match decayed {
            Some(r) => hitbox_step_decayed(h, r),
            None => {
                let p = h.packed;
                let active = p & hitbox_bits::ACTIVE != 0;
                let hits = p >> hitbox_bits::HITS_SHIFT;
                // The common case, decided without `hitbox_step`: an active
                // hitbox at or above θd, an inactive one at or below θa
                // keeps its state and loses its streak.
                let quiet = if active {
                    hits >= th.theta_d
                } else {
                    hits <= th.theta_a
                };
                if quiet {
                    h.packed = p & !(hitbox_bits::STREAK_MAX << hitbox_bits::STREAK_SHIFT);
                    *code = if active { CODE_ACTIVE } else { CODE_INACTIVE };
                    continue;
                }
                let (packed, change) = hitbox_step(p, th);
                h.packed = packed;
                change
            }
        };
        activated += u32::from(change > 0);
        deactivated += u32::from(change < 0);
        *code = if h.packed & hitbox_bits::ACTIVE != 0 {
            CODE_ACTIVE
        } else {
            CODE_INACTIVE
        };
    }
    (codes, activated, deactivated, counted)
}

/// Lines 14–38 for one slot that [`busy_masks`] marked: live, not pinned
/// and not on the fast path (dead, pinned and fast-path slots return early
/// without a counter, a command or a state change, their rate 0 under the
/// decayed rule: [`zero_rates_but`]).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn slot_step(
    slot: usize,
    instances: &mut [InstanceHot],
    instance_hits: &[u32],
    decayed: &mut Option<(DecayedRule, &mut [u32])>,
    hitboxes: &[HitboxRecord],
    th: &Thresholds,
    commands: &mut CommandBuffer,
    stats: &mut FeedbackStats,
) {
    let packed = instances[slot].packed;
    let Some(h) = hitboxes.get(instances[slot].hitbox as usize) else {
        stats.invalid_instances += 1;
        return;
    };
    let h_active = h.packed & hitbox_bits::ACTIVE != 0;
    let unique = packed & instance_bits::UNIQUE_BLAS != 0;
    let m = &mut instances[slot];
    let hits = instance_hits[slot];
    let old = m.state();
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
                InstanceState::Active if !m.has_blas() => rates[slot],
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
                } else if state == InstanceState::Active && m.has_blas() && rate < r.instance_omit {
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
        } else if state == InstanceState::Active && m.has_blas() && hits < th.sigma_o {
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

#[cfg(test)]
mod tests;
