//! Culling thresholds (paper §3.5) and their scaling with rays per frame.
//!
//! The paper's values θa = 1000, θd = 100, σa = 1000, σo = 100 with
//! n_a = 4 and n_d = 15 were tuned for its path tracer at 1080p with one
//! sample per pixel, i.e. [`REFERENCE_RAYS_PER_FRAME`] = 1920 · 1080 camera
//! rays per frame. Hit counts grow linearly with the number of rays traced, so
//! [`Thresholds::for_rays_per_frame`] scales the four hit thresholds linearly
//! from that reference (rounded to the nearest integer, at least 1, and with
//! θd < θa, σo < σa kept) and leaves the streak lengths alone (they count
//! frames, not rays).
//!
//! How the thresholds are applied (Algorithm 2, see [`crate::feedback`]):
//!
//! * an **inactive** hitbox activates when its hit count is above θa for
//!   `n_a` consecutive frames, or above 2·θa in a single frame;
//! * an **active** hitbox deactivates when its hit count is below θd for
//!   `n_d` consecutive frames;
//! * an **omitted** instance (one needing a unique BLAS) activates when its
//!   own hit count is above σa, an **active** one falls back to omitted when
//!   its hit count is below σo.
//!
//! All comparisons are strict, as in the paper.
//!
//! That is the paper's rule, [`DecisionRule::Paper`]. The other rule,
//! [`DecisionRule::Decayed`] ([`DecayedRule`]), decides from an
//! exponentially decayed hit rate per hitbox and per unique-BLAS instance
//! instead of raw per-frame counts and streaks, with hysteresis (activate
//! above one rate, deactivate below a lower one) and cost-aware activation
//! (a hitbox needs more evidence the more inactive instances activating it
//! would bring in). The rate is a `u32` in 16.16 fixed point (hits per frame
//! · 2^16) updated by [`rise_decay_rate`], the exact integer rule the
//! shaders use:
//!
//! ```text
//! h     = min(hits, 65535)
//! j     = k_up if (h << 16) > rate else k    (k = DecayedRule::shift,
//!                                             k_up = DecayedRule::rise_shift)
//! rate' = rate − (rate >> j) + ((h << 16) >> j)
//! ```
//!
//! i.e. `rate' ≈ (1 − 2^−j)·rate + 2^−j·hits`, a half-life of about
//! `0.69·2^k` frames while falling and `0.69·2^k_up` while rising, never
//! overflowing (see [`rise_decay_rate`]). `k_up = k` is the symmetric
//! [`decay_rate`].

use std::fmt;

use crate::layout::hitbox_bits;

/// Camera rays per frame the paper's thresholds were tuned for (1080p, 1 spp).
pub const REFERENCE_RAYS_PER_FRAME: f64 = 1920.0 * 1080.0;

/// Thresholds of the culling heuristic; see the [module docs](self).
///
/// Build one with [`Thresholds::paper`] or [`Thresholds::for_rays_per_frame`],
/// or fill the fields yourself and call [`Thresholds::validate`] (the
/// algorithms assume validated thresholds; invalid ones do not panic but
/// behave as the comparisons say).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Thresholds {
    /// θa: a hitbox with more hits than this is a candidate for activation.
    pub theta_a: u32,
    /// θd: an active hitbox with fewer hits than this is a candidate for
    /// deactivation.
    pub theta_d: u32,
    /// σa: an omitted instance with more hits than this is activated.
    pub sigma_a: u32,
    /// σo: an active instance needing a unique BLAS with fewer hits than this
    /// is omitted again.
    pub sigma_o: u32,
    /// n_a: consecutive frames above θa that activate a hitbox (1..=127).
    pub n_a: u32,
    /// n_d: consecutive frames below θd that deactivate a hitbox (1..=127).
    pub n_d: u32,
    /// Which rule decides: the paper's ([`DecisionRule::Paper`], the fields
    /// above) or the decayed hit rate ([`DecisionRule::Decayed`], whose own
    /// rates replace θa…n_d).
    pub rule: DecisionRule,
}

/// The rule Algorithm 2 decides with; see the [module docs](self).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DecisionRule {
    /// The paper's: this frame's hit counts against θa, θd, σa, σo and the
    /// streaks n_a, n_d.
    #[default]
    Paper,
    /// Exponentially decayed hit rates with hysteresis and cost-aware
    /// activation.
    Decayed(DecayedRule),
}

/// One in the 16.16 fixed point of hit rates: a rate of one hit per frame.
pub const RATE_ONE: u32 = 1 << 16;
/// Hits per frame beyond this count as this many in [`decay_rate`].
pub const RATE_HITS_MAX: u32 = 0xFFFF;
/// Largest [`DecayedRule::shift`].
pub const MAX_DECAY_SHIFT: u32 = 8;
/// Largest activation threshold (with its cost terms) a rate can exceed:
/// 65 520 hits per frame.
pub const MAX_RATE_THRESHOLD: u32 = 0xFFF0_0000;
/// Inactive instances of one kind a hitbox's cost counts at most.
pub const MAX_COST_COUNT: u32 = 255;

/// One frame of the decayed hit rate: `rate − (rate >> k) + ((min(hits,
/// 65535) << 16) >> k)` with `k = shift` clamped to `1..=16`.
///
/// Never overflows: `rate − ⌊rate/2^k⌋` grows with `rate`, and at
/// `rate = 2^32 − 1` the sum is `2^32 − 2^(16−k) < 2^32`. It is monotone in
/// `rate` and in `hits`, and a constant `hits = h` drives any rate to within
/// `2^k` units of `h·2^16` (the truncation of the two shifts). The shaders
/// compute the same expression in `uint` arithmetic (`lipacDecayRate`).
///
/// ```
/// use lipac_core::thresholds::{decay_rate, RATE_ONE};
/// let mut r = 0;
/// for _ in 0..200 { r = decay_rate(r, 3, 4); }
/// assert!((3 * RATE_ONE - r) <= 16);
/// assert_eq!(decay_rate(u32::MAX, u32::MAX, 1), u32::MAX - (1 << 15) + 1); // 2^32 − 2^15
/// ```
pub fn decay_rate(rate: u32, hits: u32, shift: u32) -> u32 {
    let k = shift.clamp(1, 16);
    let h = hits.min(RATE_HITS_MAX);
    rate - (rate >> k) + ((h << 16) >> k)
}

/// One frame of the decayed hit rate that rises faster than it decays:
/// [`decay_rate`] with `rise_shift` when this frame's hits in 16.16
/// (`min(hits, 65535) << 16`) exceed `rate`, else with `shift`. `shift` is
/// clamped to `1..=16`, `rise_shift` to `1..=shift`; `rise_shift == shift`
/// is [`decay_rate`] exactly.
///
/// Each branch is [`decay_rate`] with a valid shift, so it never overflows.
/// It is monotone in `hits` and in `rate`: the rising branch never passes
/// the hit rate and the falling one never drops below it (`x − ⌊x/2^j⌋` is
/// non-decreasing), so results of the rising branch (hits above the rate)
/// are at least `rate` and those of the falling one at most `rate`. A
/// constant `hits = h` drives any rate to within `2^rise_shift` below or
/// `2^shift` above `h·2^16`. The shaders compute the same expression
/// (`lipacRiseDecayRate`).
///
/// ```
/// use lipac_core::thresholds::{decay_rate, rise_decay_rate, RATE_ONE};
/// // From 0 to 4 hits per frame: one frame at k_up = 1 gets half way.
/// assert_eq!(rise_decay_rate(0, 4, 3, 1), 2 * RATE_ONE);
/// // Falling, it decays with k = 3 as before.
/// assert_eq!(rise_decay_rate(8 * RATE_ONE, 0, 3, 1), 7 * RATE_ONE);
/// assert_eq!(rise_decay_rate(123_456, 9, 4, 4), decay_rate(123_456, 9, 4));
/// ```
pub fn rise_decay_rate(rate: u32, hits: u32, shift: u32, rise_shift: u32) -> u32 {
    let k = shift.clamp(1, 16);
    let k_up = rise_shift.clamp(1, k);
    let target = hits.min(RATE_HITS_MAX) << 16;
    decay_rate(rate, hits, if target > rate { k_up } else { k })
}

/// The decayed rule's settings in 16.16 fixed point (hits per frame ·
/// [`RATE_ONE`]); build one from hits per frame with
/// [`DecayedSettings::rule_for_rays_per_frame`].
///
/// * A hitbox's rate is updated every frame from its hits (counting box and
///   instances). An **inactive** hitbox activates when its rate is above
///   `activate + per_shared·S + per_unique·U`, with `S` and `U` its inactive
///   shared- and unique-BLAS instances this frame (each at most 255,
///   [`crate::layout::HitboxRecord::cost`]): the evidence needed grows with
///   what activation brings in. An **active** one deactivates when its rate
///   is below `deactivate`.
/// * A unique-BLAS instance's rate (the per-slot rate buffer) is updated
///   from its own hits while it is omitted or active with a BLAS (held while
///   active without one, 0 while inactive). An **omitted** one activates
///   above `instance_activate`; an **active** one with a BLAS is omitted
///   again below `instance_omit`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DecayedRule {
    /// k: the rate keeps `1 − 2^−k` of itself each frame (1..=8; half-life
    /// about `0.69·2^k` frames).
    pub shift: u32,
    /// k_up: the shift used instead of `shift` in frames whose hits exceed
    /// the rate (1..=`shift`; [`rise_decay_rate`]): a rate that rises
    /// faster than it decays. `rise_shift == shift` is the symmetric rule.
    pub rise_shift: u32,
    /// Hitbox activation rate (plus the cost terms).
    pub activate: u32,
    /// Hitbox deactivation rate (below `activate`, at least `2^shift`).
    pub deactivate: u32,
    /// Omitted → active rate of a unique-BLAS instance.
    pub instance_activate: u32,
    /// Active → omitted rate (below `instance_activate`, at least `2^shift`).
    pub instance_omit: u32,
    /// Extra activation rate per inactive shared-BLAS instance of the hitbox.
    pub per_shared: u32,
    /// Extra activation rate per inactive unique-BLAS instance of the hitbox.
    pub per_unique: u32,
}

impl DecayedRule {
    /// This frame's rate from the last one and this frame's hits:
    /// [`rise_decay_rate`] with this rule's shifts.
    pub fn update_rate(&self, rate: u32, hits: u32) -> u32 {
        rise_decay_rate(rate, hits, self.shift, self.rise_shift)
    }

    /// The least rate that is still at least `threshold` after `frames`
    /// frames without a hit ([`DecayedRule::update_rate`] with 0 hits,
    /// exactly): a hitbox given it (`threshold` = [`DecayedRule::deactivate`])
    /// or a unique-BLAS instance (`threshold` =
    /// [`DecayedRule::instance_omit`]) stays active through that many
    /// frames of Algorithm 2 that do not hit it. Saturates at `u32::MAX`;
    /// takes at most a few thousand steps whatever `frames` is.
    ///
    /// ```
    /// use lipac_core::thresholds::DecayedRule;
    /// let rule = DecayedRule {
    ///     shift: 3, // keeps 7/8 of itself per frame
    ///     rise_shift: 1,
    ///     activate: 100,
    ///     deactivate: 8,
    ///     instance_activate: 100,
    ///     instance_omit: 8,
    ///     per_shared: 0,
    ///     per_unique: 0,
    /// };
    /// assert_eq!(rule.hold_rate(8, 0), 8);
    /// assert_eq!(rule.hold_rate(8, 1), 9); // 9 - 9/8 = 8
    /// assert_eq!(rule.hold_rate(8, 3), 11); // 11 → 10 → 9 → 8
    /// assert_eq!(rule.hold_rate(u32::MAX, 1), u32::MAX);
    /// // Below 2^shift a rate does not decay: it holds for ever, at once.
    /// assert_eq!(rule.hold_rate(5, u32::MAX), 5);
    /// assert_eq!(rule.hold_rate(8, u32::MAX), u32::MAX);
    /// ```
    pub fn hold_rate(&self, threshold: u32, frames: u32) -> u32 {
        let mut rate = threshold;
        for _ in 0..frames {
            if rate == u32::MAX {
                break;
            }
            // The least r with update_rate(r, 0) >= rate: the update is
            // non-decreasing in r (see `rise_decay_rate`).
            let (mut lo, mut hi) = (u64::from(rate), u64::from(u32::MAX));
            if u64::from(self.update_rate(u32::MAX, 0)) < u64::from(rate) {
                return u32::MAX;
            }
            while lo < hi {
                let mid = (lo + hi) / 2;
                if self.update_rate(mid as u32, 0) >= rate {
                    hi = mid;
                } else {
                    lo = mid + 1;
                }
            }
            if lo == u64::from(rate) {
                // A rate too small to decay (below 2^shift) stays: so do
                // all further frames.
                break;
            }
            rate = lo as u32;
        }
        rate
    }

    /// The rate an inactive hitbox must exceed with `shared` and `unique`
    /// inactive instances (each saturated at [`MAX_COST_COUNT`]); fits a
    /// `u32` for a validated rule.
    pub fn activation_threshold(&self, shared: u32, unique: u32) -> u32 {
        let t = u64::from(self.activate)
            + u64::from(self.per_shared) * u64::from(shared.min(MAX_COST_COUNT))
            + u64::from(self.per_unique) * u64::from(unique.min(MAX_COST_COUNT));
        t.min(u64::from(u32::MAX)) as u32
    }

    /// The same rule with every rate multiplied by `factor` (rounded, at
    /// least 1, the order of each pair kept), then validated.
    pub fn scaled(&self, factor: f64) -> Result<Self, ThresholdError> {
        if !factor.is_finite() || factor <= 0.0 {
            return Err(ThresholdError::InvalidScale(factor));
        }
        let s = |v: u32| -> u32 { ((f64::from(v) * factor).round() as u32).max(1) };
        let floor = 1u32 << self.shift.min(31);
        let deactivate = s(self.deactivate).max(floor);
        let instance_omit = s(self.instance_omit).max(floor);
        let r = Self {
            shift: self.shift,
            rise_shift: self.rise_shift,
            activate: s(self.activate).max(deactivate.saturating_add(1)),
            deactivate,
            instance_activate: s(self.instance_activate).max(instance_omit.saturating_add(1)),
            instance_omit,
            per_shared: if self.per_shared == 0 {
                0
            } else {
                s(self.per_shared)
            },
            per_unique: if self.per_unique == 0 {
                0
            } else {
                s(self.per_unique)
            },
        };
        r.validate()?;
        Ok(r)
    }

    /// Checks `1 ≤ shift ≤ 8`, `1 ≤ rise_shift ≤ shift`,
    /// `2^shift ≤ deactivate < activate`,
    /// `2^shift ≤ instance_omit < instance_activate`, and that the largest
    /// activation threshold (255 instances of each kind) and
    /// `instance_activate` stay at most [`MAX_RATE_THRESHOLD`].
    pub fn validate(&self) -> Result<(), ThresholdError> {
        if self.shift == 0 || self.shift > MAX_DECAY_SHIFT {
            return Err(ThresholdError::DecayShiftOutOfRange(self.shift));
        }
        if self.rise_shift == 0 || self.rise_shift > self.shift {
            return Err(ThresholdError::RiseShiftOutOfRange {
                rise_shift: self.rise_shift,
                shift: self.shift,
            });
        }
        let floor = 1u32 << self.shift;
        for (name, value) in [
            ("deactivate", self.deactivate),
            ("instance_omit", self.instance_omit),
        ] {
            if value < floor {
                return Err(ThresholdError::RateBelowDecayFloor { name, value, floor });
            }
        }
        if self.deactivate >= self.activate {
            return Err(ThresholdError::DeactivationNotBelowActivation {
                theta_d: self.deactivate,
                theta_a: self.activate,
            });
        }
        if self.instance_omit >= self.instance_activate {
            return Err(ThresholdError::OmitNotBelowActivation {
                sigma_o: self.instance_omit,
                sigma_a: self.instance_activate,
            });
        }
        let most = u64::from(self.activate)
            + u64::from(MAX_COST_COUNT) * (u64::from(self.per_shared) + u64::from(self.per_unique));
        for (name, value) in [
            ("activate + 255·(per_shared + per_unique)", most),
            ("instance_activate", u64::from(self.instance_activate)),
        ] {
            if value > u64::from(MAX_RATE_THRESHOLD) {
                return Err(ThresholdError::RateTooLarge { name, value });
            }
        }
        Ok(())
    }
}

/// [`DecayedRule`] in hits per frame at [`REFERENCE_RAYS_PER_FRAME`] (the
/// paper's scale, like θa = 1000) and a half-life in frames; what a
/// configuration holds. [`Self::rule_for_rays_per_frame`] scales and
/// converts it, rejecting what cannot be met.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DecayedSettings {
    /// Frames for a rate to halve without hits (0.5..=400; rounded to the
    /// nearest `0.69·2^k`, k in 1..=8).
    pub half_life_frames: f64,
    /// [`DecayedRule::activate`], hits per frame at the reference.
    pub activate: f64,
    /// [`DecayedRule::deactivate`].
    pub deactivate: f64,
    /// [`DecayedRule::instance_activate`].
    pub instance_activate: f64,
    /// [`DecayedRule::instance_omit`].
    pub instance_omit: f64,
    /// [`DecayedRule::per_shared`].
    pub per_shared: f64,
    /// [`DecayedRule::per_unique`].
    pub per_unique: f64,
    /// [`DecayedRule::rise_shift`] (1..=the decay shift), or `None` for the
    /// decay shift itself: the symmetric rule.
    pub rise_shift: Option<u32>,
}

impl DecayedSettings {
    /// The decay shift whose half-life `ln 2 / −ln(1 − 2^−k)` is nearest
    /// (in ratio) to `half_life_frames`.
    pub fn shift_for_half_life(half_life_frames: f64) -> Result<u32, ThresholdError> {
        if !half_life_frames.is_finite() || !(0.5..=400.0).contains(&half_life_frames) {
            return Err(ThresholdError::InvalidHalfLife(half_life_frames));
        }
        let half_life = |k: u32| std::f64::consts::LN_2 / -(1.0 - 0.5f64.powi(k as i32)).ln();
        let mut best = 1;
        for k in 2..=MAX_DECAY_SHIFT {
            if (half_life(k) / half_life_frames).ln().abs()
                < (half_life(best) / half_life_frames).ln().abs()
            {
                best = k;
            }
        }
        Ok(best)
    }

    /// The rule for `rays_per_frame` camera rays: every rate scaled by
    /// `rays / (1920·1080)` into 16.16 fixed point (rounded; the lower rate
    /// of each pair raised to the decay floor `2^k` and the upper one kept
    /// above it), validated. NaN, infinite, negative or zero rates (zero is
    /// allowed for the cost terms) and half-lives are errors, and so is a
    /// rise shift outside `1..=` the decay shift.
    pub fn rule_for_rays_per_frame(
        &self,
        rays_per_frame: f64,
    ) -> Result<DecayedRule, ThresholdError> {
        if !rays_per_frame.is_finite() || rays_per_frame <= 0.0 {
            return Err(ThresholdError::InvalidRayCount(rays_per_frame));
        }
        let shift = Self::shift_for_half_life(self.half_life_frames)?;
        let factor = rays_per_frame / REFERENCE_RAYS_PER_FRAME * f64::from(RATE_ONE);
        let fixed = |name: &'static str, v: f64, zero_ok: bool| -> Result<u32, ThresholdError> {
            if !v.is_finite() || v < 0.0 || (v == 0.0 && !zero_ok) {
                return Err(ThresholdError::InvalidRate { name, value: v });
            }
            let x = (v * factor).round();
            if x > f64::from(MAX_RATE_THRESHOLD) {
                return Err(ThresholdError::RateTooLarge {
                    name,
                    value: x as u64,
                });
            }
            Ok(x as u32)
        };
        let floor = 1u32 << shift;
        let deactivate = fixed("deactivate", self.deactivate, false)?.max(floor);
        let instance_omit = fixed("instance_omit", self.instance_omit, false)?.max(floor);
        let rule = DecayedRule {
            shift,
            rise_shift: self.rise_shift.unwrap_or(shift),
            activate: fixed("activate", self.activate, false)?.max(deactivate + 1),
            deactivate,
            instance_activate: fixed("instance_activate", self.instance_activate, false)?
                .max(instance_omit + 1),
            instance_omit,
            per_shared: fixed("per_shared", self.per_shared, true)?,
            per_unique: fixed("per_unique", self.per_unique, true)?,
        };
        rule.validate()?;
        Ok(rule)
    }
}

/// Why a set of thresholds was rejected.
#[derive(Clone, Debug, PartialEq)]
pub enum ThresholdError {
    /// Rays per frame (or a scale factor) was NaN, infinite, zero or negative.
    InvalidRayCount(f64),
    /// θd must be below θa (the hysteresis band would be empty otherwise).
    DeactivationNotBelowActivation {
        /// θd.
        theta_d: u32,
        /// θa.
        theta_a: u32,
    },
    /// σo must be below σa.
    OmitNotBelowActivation {
        /// σo.
        sigma_o: u32,
        /// σa.
        sigma_a: u32,
    },
    /// A streak length is 0 or does not fit the 7-bit streak field.
    StreakOutOfRange {
        /// `"n_a"` or `"n_d"`.
        name: &'static str,
        /// The rejected value.
        value: u32,
    },
    /// 2·θa must be below the largest hit count a hitbox holds (24 bits),
    /// otherwise the single-frame activation could never trigger.
    ActivationTooLarge {
        /// θa.
        theta_a: u32,
    },
    /// A scale factor was NaN, infinite, zero or negative.
    InvalidScale(f64),
    /// [`DecayedRule::shift`] outside `1..=8`.
    DecayShiftOutOfRange(u32),
    /// [`DecayedRule::rise_shift`] outside `1..=shift`.
    RiseShiftOutOfRange {
        /// The rejected rise shift.
        rise_shift: u32,
        /// The rule's decay shift.
        shift: u32,
    },
    /// A half-life was NaN, infinite or outside `0.5..=400` frames.
    InvalidHalfLife(f64),
    /// A rate setting was NaN, infinite, negative or zero.
    InvalidRate {
        /// The setting.
        name: &'static str,
        /// The rejected value.
        value: f64,
    },
    /// A lower rate below `2^shift`: the decayed rate stops falling at
    /// about `2^shift` (truncation), so it would never get below it.
    RateBelowDecayFloor {
        /// The setting.
        name: &'static str,
        /// The rejected value (16.16).
        value: u32,
        /// `2^shift`.
        floor: u32,
    },
    /// A rate threshold above [`MAX_RATE_THRESHOLD`]: no rate could exceed it.
    RateTooLarge {
        /// The setting.
        name: &'static str,
        /// The rejected value (16.16).
        value: u64,
    },
}

impl fmt::Display for ThresholdError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::InvalidRayCount(v) => {
                write!(f, "rays per frame must be finite and positive, got {v}")
            }
            Self::DeactivationNotBelowActivation { theta_d, theta_a } => write!(
                f,
                "deactivation threshold θd = {theta_d} must be below activation threshold θa = {theta_a}"
            ),
            Self::OmitNotBelowActivation { sigma_o, sigma_a } => write!(
                f,
                "omit threshold σo = {sigma_o} must be below instance activation threshold σa = {sigma_a}"
            ),
            Self::StreakOutOfRange { name, value } => write!(
                f,
                "{name} = {value} must be in 1..={} (7-bit streak field)",
                hitbox_bits::STREAK_MAX
            ),
            Self::ActivationTooLarge { theta_a } => write!(
                f,
                "2·θa = {} does not fit below the 24-bit hitbox hit counter maximum {}",
                u64::from(*theta_a) * 2,
                hitbox_bits::HITS_MAX
            ),
            Self::InvalidScale(v) => {
                write!(f, "threshold scale factor must be finite and positive, got {v}")
            }
            Self::DecayShiftOutOfRange(k) => write!(
                f,
                "decay shift {k} must be in 1..={MAX_DECAY_SHIFT} (half-life 1 to 177 frames)"
            ),
            Self::RiseShiftOutOfRange { rise_shift, shift } => write!(
                f,
                "rise shift {rise_shift} must be in 1..={shift} (at most the decay shift: a rate \
                 may rise faster than it decays, not slower)"
            ),
            Self::InvalidHalfLife(v) => write!(
                f,
                "half-life must be finite and in 0.5..=400 frames, got {v}"
            ),
            Self::InvalidRate { name, value } => write!(
                f,
                "rate {name} must be finite and positive, got {value}"
            ),
            Self::RateBelowDecayFloor { name, value, floor } => write!(
                f,
                "rate {name} = {value}/65536 hits per frame is below the decay floor {floor}/65536: \
                 a decayed rate never falls below it"
            ),
            Self::RateTooLarge { name, value } => write!(
                f,
                "rate threshold {name} = {value}/65536 hits per frame exceeds the largest \
                 reachable rate {MAX_RATE_THRESHOLD}/65536"
            ),
        }
    }
}

impl std::error::Error for ThresholdError {}

impl Default for Thresholds {
    fn default() -> Self {
        Self::paper()
    }
}

impl Thresholds {
    /// The paper's values for 1080p at 1 spp: θa = 1000, θd = 100,
    /// σa = 1000, σo = 100, n_a = 4, n_d = 15.
    pub const fn paper() -> Self {
        Self {
            theta_a: 1000,
            theta_d: 100,
            sigma_a: 1000,
            sigma_o: 100,
            n_a: 4,
            n_d: 15,
            rule: DecisionRule::Paper,
        }
    }

    /// These thresholds deciding with `rule` instead.
    pub const fn with_rule(self, rule: DecisionRule) -> Self {
        Self { rule, ..self }
    }

    /// Every hit threshold (θa, θd, σa, σo and the decayed rule's rates)
    /// multiplied by `factor`, as [`Self::for_rays_per_frame`] rounds them
    /// (at least 1, each lower one below its upper one); streaks and the
    /// decay and rise shifts stay: the closed-loop controller's output
    /// ([`crate::controller`]). `scaled(1.0)` of valid thresholds is
    /// themselves; a `factor` that is NaN, infinite, zero or negative is
    /// [`ThresholdError::InvalidScale`], one that pushes a threshold past its
    /// counter an error too.
    ///
    /// ```
    /// use lipac_core::thresholds::Thresholds;
    /// let t = Thresholds::paper().scaled(0.5).unwrap();
    /// assert_eq!((t.theta_a, t.theta_d), (500, 50));
    /// assert!(Thresholds::paper().scaled(f64::NAN).is_err());
    /// ```
    pub fn scaled(&self, factor: f64) -> Result<Self, ThresholdError> {
        if !factor.is_finite() || factor <= 0.0 {
            return Err(ThresholdError::InvalidScale(factor));
        }
        let scale = |v: u32| -> u32 { ((f64::from(v) * factor).round() as u32).max(1) };
        let theta_d = scale(self.theta_d);
        let sigma_o = scale(self.sigma_o);
        let t = Self {
            theta_a: scale(self.theta_a).max(theta_d.saturating_add(1)),
            theta_d,
            sigma_a: scale(self.sigma_a).max(sigma_o.saturating_add(1)),
            sigma_o,
            rule: match self.rule {
                DecisionRule::Paper => DecisionRule::Paper,
                DecisionRule::Decayed(r) => DecisionRule::Decayed(r.scaled(factor)?),
            },
            ..*self
        };
        t.validate()?;
        Ok(t)
    }

    /// The paper's thresholds scaled linearly to `rays_per_frame` (camera
    /// rays, i.e. pixels × samples per pixel).
    ///
    /// Each of θa, θd, σa, σo becomes `round(paper · rays / (1920·1080))`,
    /// at least 1; if rounding made a lower threshold reach its upper one
    /// (tiny ray counts) the upper one is raised to lower + 1. Streak lengths
    /// are frame counts and stay at 4 and 15.
    ///
    /// ```
    /// use lipac_core::thresholds::Thresholds;
    /// let t = Thresholds::for_rays_per_frame(3840.0 * 2160.0).unwrap(); // 4K, 1 spp
    /// assert_eq!((t.theta_a, t.theta_d, t.sigma_a, t.sigma_o), (4000, 400, 4000, 400));
    /// assert_eq!(Thresholds::for_rays_per_frame(1920.0 * 1080.0).unwrap(), Thresholds::paper());
    /// assert!(Thresholds::for_rays_per_frame(f64::NAN).is_err());
    /// ```
    pub fn for_rays_per_frame(rays_per_frame: f64) -> Result<Self, ThresholdError> {
        if !rays_per_frame.is_finite() || rays_per_frame <= 0.0 {
            return Err(ThresholdError::InvalidRayCount(rays_per_frame));
        }
        let factor = rays_per_frame / REFERENCE_RAYS_PER_FRAME;
        let p = Self::paper();
        let scale = |v: u32| -> u32 {
            // Saturating float -> int cast; validation below rejects overflow.
            let s = (f64::from(v) * factor).round();
            (s as u32).max(1)
        };
        let theta_d = scale(p.theta_d);
        let theta_a = scale(p.theta_a).max(theta_d.saturating_add(1));
        let sigma_o = scale(p.sigma_o);
        let sigma_a = scale(p.sigma_a).max(sigma_o.saturating_add(1));
        let t = Self {
            theta_a,
            theta_d,
            sigma_a,
            sigma_o,
            n_a: p.n_a,
            n_d: p.n_d,
            rule: DecisionRule::Paper,
        };
        t.validate()?;
        Ok(t)
    }

    /// Checks θd < θa, σo < σa, 1 ≤ n_a, n_d ≤ 127 and 2·θa < 2^24 − 1, and
    /// a decayed rule with [`DecayedRule::validate`].
    ///
    /// ```
    /// use lipac_core::thresholds::{Thresholds, ThresholdError};
    /// let bad = Thresholds { theta_d: 2000, ..Thresholds::paper() };
    /// assert!(matches!(bad.validate(), Err(ThresholdError::DeactivationNotBelowActivation { .. })));
    /// ```
    pub fn validate(&self) -> Result<(), ThresholdError> {
        if self.theta_d >= self.theta_a {
            return Err(ThresholdError::DeactivationNotBelowActivation {
                theta_d: self.theta_d,
                theta_a: self.theta_a,
            });
        }
        if self.sigma_o >= self.sigma_a {
            return Err(ThresholdError::OmitNotBelowActivation {
                sigma_o: self.sigma_o,
                sigma_a: self.sigma_a,
            });
        }
        for (name, value) in [("n_a", self.n_a), ("n_d", self.n_d)] {
            if value == 0 || value > hitbox_bits::STREAK_MAX {
                return Err(ThresholdError::StreakOutOfRange { name, value });
            }
        }
        if u64::from(self.theta_a) * 2 >= u64::from(hitbox_bits::HITS_MAX) {
            return Err(ThresholdError::ActivationTooLarge {
                theta_a: self.theta_a,
            });
        }
        if let DecisionRule::Decayed(r) = &self.rule {
            r.validate()?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
