//! Closed-loop thresholds (the paper's future work): a
//! [`ThresholdController`] that adjusts one scale factor on the culling
//! thresholds every frame so that a target the engine chooses is held.
//!
//! * [`ControlTarget::MemoryBudget`]: the acceleration-structure bytes the
//!   [`Manager`](crate::Manager) accounts (BLASes, TLAS records, LiPaC's own
//!   buffers; [`ControllerStats::measured`]). Higher thresholds activate less
//!   and deactivate sooner, so memory falls as the scale rises.
//! * [`ControlTarget::EscapeFraction`]: the share of counted hits that ended
//!   in counting boxes (hitbox boxes and omitted instances' boxes) among all
//!   counted hits, which the hit counters hold without any ground truth
//!   ([`EscapeSample`]). Higher thresholds let more rays escape into boxes.
//!
//! The output is one factor `s`: the Manager runs Algorithm 2 with
//! [`Thresholds::scaled`](crate::thresholds::Thresholds::scaled)`(s)` of its
//! configured thresholds, on the CPU and (through
//! [`crate::culling::CullingConfig::thresholds`], which a GPU backend uploads
//! each frame) on the GPU alike, so both stay bit-exact.
//!
//! # The control law
//!
//! The state is `u = ln s`. Each frame with a measurement `y` (smoothed by an
//! exponential moving average `ȳ ← ȳ + α (y − ȳ)`, [`ControllerConfig::smoothing`]):
//!
//! 1. the error is `e = ln(ȳ / r)` for a memory budget `r` and `e = ln(r / ȳ)`
//!    for an escape target `r` (positive: thresholds must rise), clamped to
//!    ±[`ControllerConfig::max_error`] and shrunk by the dead band
//!    ([`ControllerConfig::deadband`]: `e ← sign(e)·max(|e| − d, 0)`);
//! 2. velocity-form PI: `Δu = k_p (e − e_prev) + k_i e`, an error above the
//!    target (`e > 0`, over budget) weighted by
//!    [`ControllerConfig::over_gain`];
//! 3. rate limit: `|Δu| ≤` [`ControllerConfig::max_step`];
//! 4. `u ← clamp(u + Δu, ln s_min, ln s_max)`.
//!
//! Anti-windup is structural: the integrator *is* `u`, which is clamped, so
//! saturation never stores error to unwind later. During the first
//! [`ControllerConfig::warmup_frames`] frames (the scene is still filling
//! the caches) `u` stays at its start and only the filter runs. A frame
//! without hits holds `u` for an escape target.
//!
//! When `u` sits at a bound and the error still pushes beyond it for
//! [`ControllerConfig::unreachable_frames`] frames, the target is reported
//! unreachable ([`ControllerStats::unreachable`]): a budget below what the
//! scene needs at the highest thresholds (pinned geometry, the counting
//! boxes themselves), or an escape fraction below what the lowest thresholds
//! reach. The controller then holds the bound (never oscillates); the flag
//! clears as soon as the error turns.
//!
//! Stability: with `k_i ≤ max_step` and the dead band, `u` moves at most
//! `max_step` per frame and only while the smoothed error is outside the
//! band, so a step response settles without limit cycles as long as
//! `k_i` is small against the plant's delay (hysteresis `n_d`, read-back
//! latency, BLAS cache retention; defaults measured in docs/EVALUATION.md,
//! "Closed-loop thresholds").

use std::fmt;

/// What the controller holds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ControlTarget {
    /// Acceleration-structure bytes (see [`ControllerStats::measured`]).
    MemoryBudget {
        /// The budget, bytes (> 0).
        bytes: u64,
    },
    /// Share of counted hits ending in counting boxes.
    EscapeFraction {
        /// The target share, in (0, 1).
        fraction: f64,
    },
}

impl ControlTarget {
    /// The target as a number (bytes or fraction).
    pub fn value(&self) -> f64 {
        match *self {
            Self::MemoryBudget { bytes } => bytes as f64,
            Self::EscapeFraction { fraction } => fraction,
        }
    }
}

/// Gains, range and timing of the [control law](self#the-control-law).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControllerConfig {
    /// Smallest scale factor (> 0, ≤ 1).
    pub min_scale: f64,
    /// Largest scale factor (≥ 1; the thresholds scaled by it must stay
    /// valid, which [`crate::Manager::new`] checks).
    pub max_scale: f64,
    /// Proportional gain `k_p` (≥ 0).
    pub kp: f64,
    /// Integral gain `k_i` (> 0).
    pub ki: f64,
    /// Factor on both gains while the measurement is above the target
    /// (`e > 0`; ≥ 1: a budget overrun is corrected faster than spare
    /// budget is spent).
    pub over_gain: f64,
    /// Largest change of `ln s` per frame (> 0).
    pub max_step: f64,
    /// Dead band on `|e|` (≥ 0, below `max_error`).
    pub deadband: f64,
    /// Clamp on `|e|` (> 0).
    pub max_error: f64,
    /// Weight `α` of the newest measurement in the moving average (0, 1].
    pub smoothing: f64,
    /// Frames before the controller moves the scale.
    pub warmup_frames: u32,
    /// Frames saturated against the error before the target is reported
    /// unreachable (≥ 1).
    pub unreachable_frames: u32,
    /// Bytes one TLAS record costs on the backend (lavapipe: 176), for the
    /// memory a [`ControlTarget::MemoryBudget`] measures.
    pub tlas_record_bytes: u64,
    /// The second lever of a [`ControlTarget::MemoryBudget`]: in a frame
    /// whose memory is over the budget, the Manager evicts every BLAS no
    /// instance uses from its cache at once
    /// ([`crate::Manager::trim_blas_cache`]) instead of waiting for the
    /// cache's retention (`max_unused_frames`). That memory does not depend
    /// on the thresholds and is what overshoots after a camera jump (the
    /// old view's BLASes). Nothing in use is evicted; an evicted BLAS needed
    /// again is rebuilt.
    pub evict_cached_over_budget: bool,
    /// The third lever of a [`ControlTarget::MemoryBudget`]: in a frame
    /// whose memory is over the budget or within the dead band below it
    /// ([`ThresholdController::wants_coarsening`]), the Manager makes every requested
    /// switch to a coarser LOD at once instead of after the scheduler's LOD
    /// hysteresis ([`crate::build_plan::BuildScheduler::expedite_coarser_lods`]).
    /// After a camera jump the old view's instances, still in use from the
    /// new one, keep the near view's LODs for the whole hysteresis, which no
    /// threshold reaches (docs/EVALUATION.md, "Closed-loop thresholds").
    /// Finer switches keep their hysteresis; a coarser BLAS not cached is
    /// built first, the instance keeps its current one until then.
    pub coarsen_over_budget: bool,
}

impl Default for ControllerConfig {
    /// Scale in [1/32, 32], `k_p` = 0.3, `k_i` = 0.03, over-gain 2, step
    /// 0.1, dead band 0.01, error clamp 1, smoothing 0.3, 30 warm-up frames,
    /// unreachable after 30 saturated frames, 176-byte TLAS records
    /// (lavapipe), cached BLASes evicted and coarser LODs switched at once
    /// at the budget. Measured in docs/EVALUATION.md, "Closed-loop
    /// thresholds".
    fn default() -> Self {
        Self {
            min_scale: 1.0 / 32.0,
            max_scale: 32.0,
            kp: 0.3,
            ki: 0.03,
            over_gain: 2.0,
            max_step: 0.1,
            deadband: 0.01,
            max_error: 1.0,
            smoothing: 0.3,
            warmup_frames: 30,
            unreachable_frames: 30,
            tlas_record_bytes: 176,
            evict_cached_over_budget: true,
            coarsen_over_budget: true,
        }
    }
}

/// Why a target or a controller configuration was rejected.
#[derive(Clone, Debug, PartialEq)]
pub enum ControllerError {
    /// A memory budget of 0 bytes.
    ZeroBudget,
    /// An escape fraction that is NaN or outside (0, 1).
    InvalidFraction(f64),
    /// A [`ControllerConfig`] field out of its range.
    InvalidConfig {
        /// The field.
        field: &'static str,
        /// Its value.
        value: f64,
    },
}

impl fmt::Display for ControllerError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::ZeroBudget => write!(f, "a memory budget of 0 bytes cannot be met"),
            Self::InvalidFraction(v) => {
                write!(f, "escape fraction {v} must be a number in (0, 1)")
            }
            Self::InvalidConfig { field, value } => {
                write!(f, "controller setting {field} = {value} is out of range")
            }
        }
    }
}

impl std::error::Error for ControllerError {}

/// One frame's counted hits for the escape fraction.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EscapeSample {
    /// Hits on counting boxes: inactive hitboxes' boxes and omitted
    /// instances' boxes.
    pub box_hits: u64,
    /// All counted hits: `box_hits` plus the hits on traced instances.
    pub total_hits: u64,
}

impl EscapeSample {
    /// `box_hits / total_hits`, `None` without hits.
    pub fn fraction(&self) -> Option<f64> {
        (self.total_hits > 0)
            .then(|| self.box_hits.min(self.total_hits) as f64 / self.total_hits as f64)
    }
}

/// What the controller did, for [`crate::ManagerStats::controller`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ControllerStats {
    /// The scale factor on the thresholds now.
    pub scale: f64,
    /// The target (bytes or fraction).
    pub target: f64,
    /// The last measurement (bytes or fraction; for a budget: BLAS bytes +
    /// TLAS records × [`ControllerConfig::tlas_record_bytes`] + hitbox
    /// records + hit counters).
    pub measured: f64,
    /// Its moving average, what the law compares.
    pub smoothed: f64,
    /// The last error `e` after clamp and dead band.
    pub error: f64,
    /// Frames fed.
    pub frames: u64,
    /// The scale sits at a bound and the error pushes beyond it.
    pub saturated: bool,
    /// Saturated for [`ControllerConfig::unreachable_frames`] frames: the
    /// target cannot be met with the scale range ("budget unreachable";
    /// for a memory budget only at the largest scale and over budget:
    /// under budget at the smallest scale is spare budget).
    pub unreachable: bool,
    /// Times the scale's direction of change reversed.
    pub reversals: u64,
    /// Frames over a memory budget in which cached BLASes no instance uses
    /// were evicted ([`ControllerConfig::evict_cached_over_budget`]).
    pub evicting_frames: u64,
    /// BLASes evicted so.
    pub evicted: u64,
    /// Frames at or over a memory budget in which waiting coarser LOD switches
    /// were made at once ([`ControllerConfig::coarsen_over_budget`]).
    pub coarsening_frames: u64,
    /// LOD switches made so.
    pub coarsened: u64,
}

/// The closed-loop controller; see the [module docs](self).
#[derive(Clone, Debug)]
pub struct ThresholdController {
    target: ControlTarget,
    config: ControllerConfig,
    log_scale: f64,
    prev_error: f64,
    smoothed: Option<f64>,
    saturated_for: u32,
    last_direction: i8,
    stats: ControllerStats,
}

fn check(field: &'static str, value: f64, ok: bool) -> Result<(), ControllerError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(ControllerError::InvalidConfig { field, value })
    }
}

impl ControllerConfig {
    /// Checks every field's range (see the field docs).
    pub fn validate(&self) -> Result<(), ControllerError> {
        let c = self;
        check(
            "min_scale",
            c.min_scale,
            c.min_scale > 0.0 && c.min_scale <= 1.0,
        )?;
        check("max_scale", c.max_scale, c.max_scale >= 1.0)?;
        check("kp", c.kp, c.kp >= 0.0)?;
        check("ki", c.ki, c.ki > 0.0)?;
        check("over_gain", c.over_gain, c.over_gain >= 1.0)?;
        check("max_step", c.max_step, c.max_step > 0.0)?;
        check("max_error", c.max_error, c.max_error > 0.0)?;
        check(
            "deadband",
            c.deadband,
            c.deadband >= 0.0 && c.deadband < c.max_error,
        )?;
        check(
            "smoothing",
            c.smoothing,
            c.smoothing > 0.0 && c.smoothing <= 1.0,
        )?;
        check(
            "unreachable_frames",
            f64::from(c.unreachable_frames),
            c.unreachable_frames >= 1,
        )?;
        Ok(())
    }
}

impl ControlTarget {
    /// Checks the target: a budget above 0 bytes, a fraction in (0, 1).
    pub fn validate(&self) -> Result<(), ControllerError> {
        match *self {
            Self::MemoryBudget { bytes: 0 } => Err(ControllerError::ZeroBudget),
            Self::MemoryBudget { .. } => Ok(()),
            Self::EscapeFraction { fraction } => {
                if fraction.is_finite() && fraction > 0.0 && fraction < 1.0 {
                    Ok(())
                } else {
                    Err(ControllerError::InvalidFraction(fraction))
                }
            }
        }
    }
}

impl ThresholdController {
    /// A controller holding `target` with `config`, at scale 1. Fails for an
    /// invalid target or configuration.
    pub fn new(target: ControlTarget, config: ControllerConfig) -> Result<Self, ControllerError> {
        target.validate()?;
        config.validate()?;
        Ok(Self {
            target,
            config,
            log_scale: 0.0,
            prev_error: 0.0,
            smoothed: None,
            saturated_for: 0,
            last_direction: 0,
            stats: ControllerStats {
                scale: 1.0,
                target: target.value(),
                ..ControllerStats::default()
            },
        })
    }

    /// The target.
    pub fn target(&self) -> ControlTarget {
        self.target
    }

    /// Changes the target value at run time (a new budget), keeping the
    /// scale: the law continues from where it is. The kind of target cannot
    /// change ([`ControllerError::InvalidConfig`]); an invalid target is
    /// refused and nothing changes.
    pub fn set_target(&mut self, target: ControlTarget) -> Result<(), ControllerError> {
        target.validate()?;
        if std::mem::discriminant(&target) != std::mem::discriminant(&self.target) {
            return Err(ControllerError::InvalidConfig {
                field: "target kind",
                value: target.value(),
            });
        }
        self.target = target;
        self.stats.target = target.value();
        self.saturated_for = 0;
        Ok(())
    }

    /// The configuration.
    pub fn config(&self) -> &ControllerConfig {
        &self.config
    }

    /// The scale factor on the thresholds now.
    pub fn scale(&self) -> f64 {
        self.stats.scale
    }

    /// What the controller did so far.
    pub fn stats(&self) -> ControllerStats {
        self.stats
    }

    /// Whether a memory budget's second lever should act on a frame that
    /// measured `memory_bytes`: the budget is exceeded and
    /// [`ControllerConfig::evict_cached_over_budget`] is set.
    pub fn wants_eviction(&self, memory_bytes: u64) -> bool {
        self.config.evict_cached_over_budget
            && matches!(self.target, ControlTarget::MemoryBudget { bytes } if memory_bytes > bytes)
    }

    /// Whether a memory budget's third lever should act on a frame that
    /// measured `memory_bytes`: [`ControllerConfig::coarsen_over_budget`]
    /// is set and the memory is not clearly under the budget (above
    /// `budget · e^−deadband`, the dead band below it, where a held budget
    /// sits: a camera jump is seen only once the new view's builds land,
    /// two frames after the LODs it asks for).
    pub fn wants_coarsening(&self, memory_bytes: u64) -> bool {
        self.config.coarsen_over_budget
            && matches!(self.target, ControlTarget::MemoryBudget { bytes }
                if memory_bytes as f64 > bytes as f64 * (-self.config.deadband).exp())
    }

    /// Records that the third lever made `switches` LOD switches this frame
    /// (a frame without a switch is not counted).
    pub fn note_coarsening(&mut self, switches: usize) {
        if switches > 0 {
            self.stats.coarsening_frames += 1;
            self.stats.coarsened = self.stats.coarsened.saturating_add(switches as u64);
        }
    }

    /// Records that the second lever evicted `blases` BLASes this frame.
    pub fn note_eviction(&mut self, blases: usize) {
        self.stats.evicting_frames += 1;
        self.stats.evicted = self.stats.evicted.saturating_add(blases as u64);
    }

    /// Feeds one frame: `memory_bytes` for a budget, `escape` for an escape
    /// target (the other is ignored). Returns the new scale factor.
    pub fn update(&mut self, memory_bytes: u64, escape: Option<EscapeSample>) -> f64 {
        let measured = match self.target {
            ControlTarget::MemoryBudget { .. } => Some(memory_bytes as f64),
            ControlTarget::EscapeFraction { .. } => escape.and_then(|e| e.fraction()),
        };
        self.stats.frames += 1;
        let Some(y) = measured else {
            return self.stats.scale; // no hits: hold
        };
        let c = self.config;
        let smoothed = match self.smoothed {
            None => y,
            Some(s) => s + c.smoothing * (y - s),
        };
        self.smoothed = Some(smoothed);
        self.stats.measured = y;
        self.stats.smoothed = smoothed;

        // 1. The error: positive when the thresholds must rise.
        const FLOOR: f64 = 1e-6; // keeps ln finite at 0 bytes / 0 escape
        let r = self.target.value();
        let raw = match self.target {
            ControlTarget::MemoryBudget { .. } => (smoothed.max(1.0) / r).ln(),
            ControlTarget::EscapeFraction { .. } => (r / smoothed.max(FLOOR)).ln(),
        };
        let clamped = raw.clamp(-c.max_error, c.max_error);
        let e = clamped.signum() * (clamped.abs() - c.deadband).max(0.0);
        self.stats.error = e;
        if self.stats.frames <= u64::from(c.warmup_frames) {
            self.prev_error = e;
            return self.stats.scale;
        }

        // 2.-4. Velocity-form PI, rate limit, clamp.
        let gain = if e > 0.0 { c.over_gain } else { 1.0 };
        let du = (gain * (c.kp * (e - self.prev_error) + c.ki * e)).clamp(-c.max_step, c.max_step);
        self.prev_error = e;
        let (lo, hi) = (c.min_scale.ln(), c.max_scale.ln());
        let before = self.log_scale;
        self.log_scale = (self.log_scale + du).clamp(lo, hi);
        let moved = self.log_scale - before;
        let direction = if moved > 1e-12 {
            1
        } else if moved < -1e-12 {
            -1
        } else {
            0
        };
        if direction != 0 {
            if self.last_direction != 0 && direction != self.last_direction {
                self.stats.reversals += 1;
            }
            self.last_direction = direction;
        }

        let high = self.log_scale >= hi && e > 0.0;
        let saturated = high || (self.log_scale <= lo && e < 0.0);
        // Under a budget at the lowest scale is spare budget, not a budget
        // that cannot be met.
        let unmet = match self.target {
            ControlTarget::MemoryBudget { .. } => high,
            ControlTarget::EscapeFraction { .. } => saturated,
        };
        self.saturated_for = if unmet {
            self.saturated_for.saturating_add(1)
        } else {
            0
        };
        self.stats.saturated = saturated;
        self.stats.unreachable = self.saturated_for >= c.unreachable_frames;
        self.stats.scale = self.log_scale.exp().clamp(c.min_scale, c.max_scale);
        self.stats.scale
    }
}

#[cfg(test)]
mod tests;
