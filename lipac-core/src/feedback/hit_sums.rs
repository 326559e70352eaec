//! Lines 1–6 of Algorithm 2 on the CPU: every live omitted or active,
//! unpinned instance's hits added to its hitbox, and the frame's hit sums
//! ([`super::FeedbackStats::box_hits`], [`super::FeedbackStats::traced_hits`]).
//!
//! Most slots have no hits, so [`HIT_CHUNK`] counters at once give a mask of
//! those with hits and only those are visited; adds to one hitbox from
//! consecutive slots are summed first ([`HitRun`]) into one `u32` per
//! hitbox, which the hitbox pass of lines 7–13 adds to the records
//! ([`merge_hits`]). The counts are those of one add per slot
//! (`feedback/tests/chunks.rs`).

use crate::layout::{hitbox_bits, instance_bits, InstanceHot, InstanceState};

/// Hit counters tested together by the fast path of lines 1–6.
pub(super) const HIT_CHUNK: usize = 32;

/// `packed & (ALIVE | PINNED | STATE_MASK)` of a live, active, unpinned
/// instance: the common slot with hits.
pub(super) const LIVE_ACTIVE: u32 = instance_bits::ALIVE | InstanceState::Active as u32;
/// The same for a live, omitted instance.
pub(super) const LIVE_OMITTED: u32 = instance_bits::ALIVE | InstanceState::Omitted as u32;
const _: () = assert!(LIVE_ACTIVE == LIVE_OMITTED + 1);

/// Lines 1–6 over every slot: adds each live omitted or active, unpinned
/// instance's hits to its hitbox's entry of `added` (line 4; one entry per
/// hitbox, zero at first, a saturating sum) and returns the hits of live
/// omitted instances and this frame's `traced_hits` ([`FeedbackStats`]).
/// The hitbox records are not touched: [`merge_hits`] adds `added` to
/// them in the pass of lines 7–13, which reads each record once, in order,
/// instead of here where the records of scattered slots are far apart in
/// memory.
///
/// Most slots have no hits (inactive ones are never hit): [`HIT_CHUNK`]
/// counters at once give a mask of those with hits ([`nonzero_mask`]), and
/// only those are visited. Consecutive adds to the same hitbox are summed
/// first ([`HitRun`]), which gives the same count: adds saturate at
/// [`hitbox_bits::HITS_MAX`] and never subtract. Not inlined: its loop
/// keeps its values in registers.
///
/// [`FeedbackStats`]: super::FeedbackStats
#[inline(never)]
pub(super) fn accumulate_hits(
    instances: &[InstanceHot],
    instance_hits: &[u32],
    added: &mut [u32],
) -> (u64, u64) {
    let mut box_hits: u64 = 0;
    let mut live_hits: u64 = 0;
    let mut run = HitRun { hitbox: 0, hits: 0 };
    // Opaque to the optimiser: with the constants in sight it turns some
    // lanes into scalar shifts instead of one vector AND per four lanes.
    let bits = std::hint::black_box(&HIT_BITS);
    let hot_chunks = instances.chunks_exact(HIT_CHUNK);
    let hit_chunks = instance_hits.chunks_exact(HIT_CHUNK);
    let (hot_tail, hit_tail) = (hot_chunks.remainder(), hit_chunks.remainder());
    for (ms, hs) in hot_chunks.zip(hit_chunks) {
        let mut nonzero = nonzero_mask(hs, bits);
        while nonzero != 0 {
            let i = nonzero.trailing_zeros() as usize;
            nonzero &= nonzero - 1;
            add_instance_hits(
                &ms[i],
                hs[i],
                added,
                &mut run,
                &mut box_hits,
                &mut live_hits,
            );
        }
    }
    for (m, &hits) in hot_tail.iter().zip(hit_tail) {
        add_instance_hits(m, hits, added, &mut run, &mut box_hits, &mut live_hits);
    }
    run.flush(added);
    // Omitted slots are live: `live_hits` holds `box_hits`.
    (box_hits, live_hits - box_hits)
}

/// A hitbox's `packed` word with `added` (its entry from
/// [`accumulate_hits`]) added to its hit count, saturating at
/// [`hitbox_bits::HITS_MAX`] as one
/// [`crate::layout::HitboxRecord::add_hits`] per slot
/// would (a saturated `added`, `u32::MAX`, is above `HITS_MAX`).
#[inline(always)]
pub(super) fn merge_hits(packed: u32, added: u32) -> u32 {
    let total = (u64::from(packed >> hitbox_bits::HITS_SHIFT) + u64::from(added))
        .min(u64::from(hitbox_bits::HITS_MAX));
    (packed & ((1 << hitbox_bits::HITS_SHIFT) - 1)) | ((total as u32) << hitbox_bits::HITS_SHIFT)
}

/// [`merge_hits`] over every hitbox: the records as lines 1–6 leave them
/// (for tests; [`super::step_hitboxes`] merges as it goes).
#[cfg(test)]
pub(super) fn merge_all(hitboxes: &mut [crate::layout::HitboxRecord], added: &[u32]) {
    for (h, &a) in hitboxes.iter_mut().zip(added) {
        h.packed = merge_hits(h.packed, a);
    }
}

/// Bit `i` set where `hs[i] != 0`, for the first [`HIT_CHUNK`] counters of
/// `hs`, given `bits` = [`HIT_BITS`]: an OR of per-lane bits, which the
/// compiler vectorises (compare, AND, OR).
#[inline(always)]
pub(super) fn nonzero_mask(hs: &[u32], bits: &[u32; HIT_CHUNK]) -> u32 {
    hs.iter()
        .zip(bits)
        .fold(0, |m, (&h, &bit)| m | if h != 0 { bit } else { 0 })
}

/// `1 << i` for lane `i` of [`nonzero_mask`].
pub(super) const HIT_BITS: [u32; HIT_CHUNK] = {
    let mut t = [0; HIT_CHUNK];
    let mut i = 0;
    while i < HIT_CHUNK {
        t[i] = 1 << i;
        i += 1;
    }
    t
};

/// Hits not yet added to hitbox `hitbox`'s entry of `added` (line 4),
/// summed over a run of slots that add to the same hitbox (a `u64` holds
/// the sum of 2^24 slots' `u32` hits).
pub(super) struct HitRun {
    hitbox: u32,
    hits: u64,
}

impl HitRun {
    /// Adds `hits` to `hitbox`'s run, flushing the run of another hitbox.
    #[inline(always)]
    fn add(&mut self, hitbox: u32, hits: u32, added: &mut [u32]) {
        if hitbox != self.hitbox {
            self.flush(added);
            self.hitbox = hitbox;
        }
        self.hits += u64::from(hits);
    }

    /// Adds the run's hits to its hitbox's entry of `added` (none if its
    /// index is out of range), saturating at `u32::MAX`: above
    /// [`hitbox_bits::HITS_MAX`], so [`merge_hits`] still saturates there.
    #[inline(always)]
    fn flush(&mut self, added: &mut [u32]) {
        if let Some(a) = added.get_mut(self.hitbox as usize) {
            *a = a.saturating_add(u32::try_from(self.hits).unwrap_or(u32::MAX));
        }
        self.hits = 0;
    }
}

/// Lines 1–6 for one slot: adds its hits to `box_hits` if it is live and
/// omitted, to `live_hits` if it is live (the traced hits are their
/// difference) and, for a live omitted or active instance that is not
/// pinned, to its hitbox's run.
#[inline(always)]
pub(super) fn add_instance_hits(
    m: &InstanceHot,
    hits: u32,
    added: &mut [u32],
    run: &mut HitRun,
    box_hits: &mut u64,
    live_hits: &mut u64,
) {
    // No test for zero hits: they add nothing, to the sums or to a run. The
    // sums take their hits by selection, not by branch (the omitted slots
    // among the active ones are not predictable).
    let key = m.packed & (instance_bits::ALIVE | instance_bits::PINNED | instance_bits::STATE_MASK);
    let state = key & (instance_bits::ALIVE | instance_bits::STATE_MASK);
    let omitted = state == LIVE_OMITTED;
    let alive = state & instance_bits::ALIVE != 0;
    let h = u64::from(hits);
    *box_hits += if omitted { h } else { 0 };
    // All live slots' hits here; the omitted ones are taken out at the end.
    *live_hits += if alive { h } else { 0 };
    // Pinned instances are not the hitbox's to decide on: their hits stay
    // out. `LIVE_OMITTED` and `LIVE_ACTIVE` are consecutive keys.
    if key.wrapping_sub(LIVE_OMITTED) < 2 {
        run.add(m.hitbox, hits, added); // line 4
    }
}
