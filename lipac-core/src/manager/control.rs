//! The Manager's side of the closed-loop thresholds ([`crate::controller`]):
//! what it measures each frame and how the controller's scale reaches
//! Algorithm 2.
//!
//! * [`Manager::process_feedback`] (CPU backends) takes an
//!   [`EscapeSample`] from the hit sums Algorithm 2 made while reading the
//!   hit counters, before it added the instance hits to the hitboxes; a GPU backend that reads back its
//!   counting-box hits hands one in with [`Manager::observe_escape`].
//! * [`Manager::plan`] feeds the controller once per frame, after the
//!   scheduler planned, with the memory and the newest escape sample, and
//!   sets the scaled thresholds in the command loop's configuration, which
//!   the CPU's Algorithm 2 uses and a GPU backend uploads when it records
//!   the frame.
//! * A memory budget has a second lever: in a frame over the budget the
//!   BLAS cache is trimmed (every BLAS no instance uses is evicted; their
//!   frees follow after the frames in flight), since that memory does not
//!   depend on the thresholds
//!   ([`ControllerConfig::evict_cached_over_budget`]).
//! * And a third: in a frame over the budget every requested switch to a
//!   coarser LOD is made at once, not after the scheduler's LOD hysteresis
//!   ([`ControllerConfig::coarsen_over_budget`]).

use crate::controller::{ControlTarget, ControllerConfig, EscapeSample, ThresholdController};
use crate::feedback::FeedbackStats;
use crate::hitbox_index::HitboxIndex;
use crate::layout::HitboxRecord;
use crate::thresholds::{DecisionRule, Thresholds};

use super::{Manager, ManagerError};

/// The controller of a configuration, checked against the thresholds it
/// scales: `None` without a target.
pub(super) fn controller_of(
    target: Option<ControlTarget>,
    config: ControllerConfig,
    base: &Thresholds,
) -> Result<Option<ThresholdController>, ManagerError> {
    let Some(target) = target else {
        return Ok(None);
    };
    let c = ThresholdController::new(target, config).map_err(|e| ManagerError::InvalidConfig {
        what: format!("target: {e}"),
    })?;
    for s in [config.min_scale, config.max_scale] {
        base.scaled(s).map_err(|e| ManagerError::InvalidConfig {
            what: format!("controller: the thresholds scaled by {s} are invalid: {e}"),
        })?;
    }
    Ok(Some(c))
}

/// This frame's counted hits: counting boxes (the hitboxes' counts before
/// Algorithm 2 adds instance hits, and omitted instances' counts) and
/// traced instances, as Algorithm 2 summed them while reading each state
/// ([`FeedbackStats::box_hits`], [`FeedbackStats::traced_hits`]).
pub(super) fn escape_sample(stats: &FeedbackStats) -> EscapeSample {
    EscapeSample {
        box_hits: stats.box_hits,
        total_hits: stats.box_hits + stats.traced_hits,
    }
}

impl<H: HitboxIndex> Manager<H> {
    /// The bytes a [`ControlTarget::MemoryBudget`] holds: BLASes (shared,
    /// unique, compacted; not those waiting to be freed), TLAS records of
    /// the last [`Manager::assemble`] (without one, a GPU backend's table:
    /// every slot plus every hitbox) times
    /// [`ControllerConfig::tlas_record_bytes`], hitbox records, hit
    /// counters and, under the decayed rule, its per-slot rates (4 bytes
    /// each).
    pub fn controlled_bytes(&self) -> u64 {
        let per_record = self
            .controller
            .as_ref()
            .map_or(ControllerConfig::default().tlas_record_bytes, |c| {
                c.config().tlas_record_bytes
            });
        let reg = self.culling.registry();
        let slots = u64::from(reg.slot_count());
        let hitboxes = self.culling.hitboxes().len() as u64;
        let records = self.tlas_records.unwrap_or(slots + hitboxes);
        self.scheduler
            .stats()
            .cache
            .live_bytes()
            .saturating_add(records.saturating_mul(per_record))
            .saturating_add(hitboxes * std::mem::size_of::<HitboxRecord>() as u64)
            .saturating_add(slots * 4)
            .saturating_add(match self.base_thresholds.rule {
                // The decayed rule's per-slot rate buffer.
                DecisionRule::Decayed(_) => slots * 4,
                DecisionRule::Paper => 0,
            })
    }

    /// For GPU backends that read back their counting-box hits: this
    /// frame's [`EscapeSample`] for a [`ControlTarget::EscapeFraction`]
    /// (CPU backends get it from [`Manager::process_feedback`]). The newest
    /// sample is used by the next [`Manager::plan`].
    pub fn observe_escape(&mut self, sample: EscapeSample) {
        self.escape = Some(sample);
        self.escape_fresh = true;
    }

    /// The thresholds Algorithm 2 runs with now: the configured ones scaled
    /// by the controller ([`crate::ManagerStats::controller`]), or the
    /// configured ones without a target.
    pub fn thresholds(&self) -> Thresholds {
        self.culling.config().thresholds
    }

    /// Step 5 of [`Manager::plan`]: feeds the controller and applies its
    /// scale.
    pub(super) fn control(&mut self) -> Result<(), ManagerError> {
        let memory = if matches!(
            self.controller.as_ref().map(|c| c.target()),
            Some(ControlTarget::MemoryBudget { .. })
        ) {
            self.controlled_bytes()
        } else {
            0
        };
        let escape = self
            .escape
            .filter(|_| std::mem::take(&mut self.escape_fresh));
        let Some(c) = self.controller.as_mut() else {
            return Ok(());
        };
        let scale = c.update(memory, escape);
        // The second lever: over budget, the memory the thresholds cannot
        // reach soon (BLASes only the cache's retention keeps) goes now.
        // The third lever: the coarser LODs the camera asks for now, not
        // after the hysteresis (before the eviction, which then takes the
        // finer BLASes a cached switch left unused).
        let mut switched = false;
        if c.wants_coarsening(memory) {
            let switches = self.scheduler.expedite_coarser_lods()?;
            c.note_coarsening(switches);
            switched = switches > 0;
        }
        if c.wants_eviction(memory) {
            let evicted = self.scheduler.trim_cache();
            c.note_eviction(evicted);
        }
        if switched {
            // This frame's records and data ranges follow the switches.
            self.sync_addresses()?;
        }
        let t = self
            .base_thresholds
            .scaled(scale)
            .map_err(|e| ManagerError::Invariant {
                what: format!("scale {scale} in the checked range gave invalid thresholds: {e}"),
            })?;
        self.culling.set_thresholds(t)?;
        Ok(())
    }
}
