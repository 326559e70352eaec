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
        }
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
        };
        t.validate()?;
        Ok(t)
    }

    /// These thresholds with the four hit thresholds multiplied by `factor`
    /// (the closed-loop controller's output, [`crate::controller`]): each of
    /// θa, θd, σa, σo becomes `round(value · factor)`, at least 1, with an
    /// upper one raised to lower + 1 where rounding made them meet; the
    /// streak lengths are frame counts and stay. `scaled(1.0)` of valid
    /// thresholds is themselves. The result is validated: a `factor` that is
    /// NaN, infinite, zero or negative is [`ThresholdError::InvalidRayCount`],
    /// one that pushes 2·θa past the 24-bit hit counter is
    /// [`ThresholdError::ActivationTooLarge`].
    ///
    /// ```
    /// use lipac_core::thresholds::Thresholds;
    /// let t = Thresholds::paper().scaled(0.5).unwrap();
    /// assert_eq!((t.theta_a, t.theta_d, t.sigma_a, t.sigma_o), (500, 50, 500, 50));
    /// assert_eq!((t.n_a, t.n_d), (4, 15));
    /// assert_eq!(Thresholds::paper().scaled(1.0).unwrap(), Thresholds::paper());
    /// assert!(Thresholds::paper().scaled(f64::NAN).is_err());
    /// ```
    pub fn scaled(&self, factor: f64) -> Result<Self, ThresholdError> {
        if !factor.is_finite() || factor <= 0.0 {
            return Err(ThresholdError::InvalidRayCount(factor));
        }
        let scale = |v: u32| -> u32 {
            // Saturating float -> int cast; validation below rejects overflow.
            ((f64::from(v) * factor).round() as u32).max(1)
        };
        let theta_d = scale(self.theta_d);
        let theta_a = scale(self.theta_a).max(theta_d.saturating_add(1));
        let sigma_o = scale(self.sigma_o);
        let sigma_a = scale(self.sigma_a).max(sigma_o.saturating_add(1));
        let t = Self {
            theta_a,
            theta_d,
            sigma_a,
            sigma_o,
            ..*self
        };
        t.validate()?;
        Ok(t)
    }

    /// Checks θd < θa, σo < σa, 1 ≤ n_a, n_d ≤ 127 and 2·θa < 2^24 − 1.
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
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_values_are_valid_and_reference_scale_reproduces_them() {
        assert!(Thresholds::paper().validate().is_ok());
        assert_eq!(
            Thresholds::for_rays_per_frame(REFERENCE_RAYS_PER_FRAME),
            Ok(Thresholds::paper())
        );
    }

    #[test]
    fn scaling_is_linear_and_rounded() {
        // 720p at 1 spp: factor 4/9 -> 444.4.. -> 444, 44.4.. -> 44.
        let t = Thresholds::for_rays_per_frame(1280.0 * 720.0).unwrap();
        assert_eq!(
            (t.theta_a, t.theta_d, t.sigma_a, t.sigma_o),
            (444, 44, 444, 44)
        );
        assert_eq!((t.n_a, t.n_d), (4, 15));
        // 1080p at 4 spp.
        let t = Thresholds::for_rays_per_frame(4.0 * REFERENCE_RAYS_PER_FRAME).unwrap();
        assert_eq!((t.theta_a, t.theta_d), (4000, 400));
    }

    #[test]
    fn tiny_ray_counts_keep_thresholds_ordered_and_positive() {
        let t = Thresholds::for_rays_per_frame(10.0).unwrap();
        assert_eq!((t.theta_d, t.theta_a, t.sigma_o, t.sigma_a), (1, 2, 1, 2));
        assert!(t.validate().is_ok());
    }

    #[test]
    fn rejects_bad_ray_counts() {
        for v in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 0.0, -5.0] {
            assert!(matches!(
                Thresholds::for_rays_per_frame(v),
                Err(ThresholdError::InvalidRayCount(_))
            ));
        }
        // So many rays that 2·θa no longer fits the 24-bit hit counter.
        let e = Thresholds::for_rays_per_frame(REFERENCE_RAYS_PER_FRAME * 10_000.0).unwrap_err();
        assert!(matches!(e, ThresholdError::ActivationTooLarge { .. }));
        assert!(e.to_string().contains("24-bit"));
    }

    #[test]
    fn scaled_multiplies_hit_thresholds_and_keeps_order() {
        let p = Thresholds::paper();
        let t = p.scaled(2.5).unwrap();
        assert_eq!(
            (t.theta_a, t.theta_d, t.sigma_a, t.sigma_o),
            (2500, 250, 2500, 250)
        );
        assert_eq!((t.n_a, t.n_d), (p.n_a, p.n_d));
        // Tiny factors keep every threshold >= 1 and the bands non-empty.
        let t = p.scaled(1e-9).unwrap();
        assert_eq!((t.theta_d, t.theta_a, t.sigma_o, t.sigma_a), (1, 2, 1, 2));
        for f in [f64::NAN, f64::INFINITY, 0.0, -1.0] {
            assert!(matches!(
                p.scaled(f),
                Err(ThresholdError::InvalidRayCount(_))
            ));
        }
        assert!(matches!(
            p.scaled(1e5),
            Err(ThresholdError::ActivationTooLarge { .. })
        ));
    }

    #[test]
    fn validate_rejects_each_rule() {
        let p = Thresholds::paper();
        assert!(matches!(
            Thresholds { sigma_o: 1000, ..p }.validate(),
            Err(ThresholdError::OmitNotBelowActivation { .. })
        ));
        assert!(matches!(
            Thresholds { n_a: 0, ..p }.validate(),
            Err(ThresholdError::StreakOutOfRange { name: "n_a", .. })
        ));
        assert!(matches!(
            Thresholds { n_d: 128, ..p }.validate(),
            Err(ThresholdError::StreakOutOfRange { name: "n_d", .. })
        ));
        assert!(Thresholds { n_d: 127, ..p }.validate().is_ok());
        let max_ok = (hitbox_bits::HITS_MAX - 1) / 2;
        assert!(Thresholds {
            theta_a: max_ok,
            ..p
        }
        .validate()
        .is_ok());
        assert!(Thresholds {
            theta_a: max_ok + 1,
            ..p
        }
        .validate()
        .is_err());
    }
}
