//! The decayed rule: the fixed-point update ([`decay_rate`]) and the
//! validation of rules and settings.

use super::*;
use proptest::prelude::*;

/// [`decay_rate`] in exact 64-bit arithmetic.
fn reference(rate: u32, hits: u32, k: u32) -> u64 {
    let (r, h) = (u64::from(rate), u64::from(hits.min(RATE_HITS_MAX)));
    r - (r >> k) + ((h << 16) >> k)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn update_is_exact_and_never_overflows(rate: u32, hits: u32, k in 1u32..=16) {
        let exact = reference(rate, hits, k);
        prop_assert!(exact <= u64::from(u32::MAX));
        prop_assert_eq!(u64::from(decay_rate(rate, hits, k)), exact);
    }

    #[test]
    fn update_is_monotone(a: u32, b: u32, h1: u32, h2: u32, k in 1u32..=MAX_DECAY_SHIFT) {
        let (lo, hi) = (a.min(b), a.max(b));
        let (hl, hh) = (h1.min(h2), h1.max(h2));
        prop_assert!(decay_rate(lo, hl, k) <= decay_rate(hi, hl, k));
        prop_assert!(decay_rate(lo, hl, k) <= decay_rate(lo, hh, k));
    }

    #[test]
    fn constant_hits_converge_to_the_hit_rate(
        start: u32,
        hits in prop_oneof![0u32..64, 0u32..=RATE_HITS_MAX, Just(u32::MAX)],
        k in 1u32..=MAX_DECAY_SHIFT,
    ) {
        let target = hits.min(RATE_HITS_MAX) << 16;
        let mut r = start;
        // (1 − 2^−k)^n · 2^32 < 1 after 23·2^k frames.
        for _ in 0..(24u32 << k) {
            r = decay_rate(r, hits, k);
        }
        prop_assert!(r >= target && r - target < (1 << k), "rate {} target {}", r, target);
        // And it stays there.
        prop_assert_eq!(decay_rate(r, hits, k), r);
    }
}

#[test]
fn saturating_inputs() {
    assert_eq!(decay_rate(u32::MAX, u32::MAX, 1), u32::MAX - (1 << 15) + 1);
    assert_eq!(decay_rate(u32::MAX, u32::MAX, 16), u32::MAX);
    assert_eq!(decay_rate(0, u32::MAX, 8), 0xFFFF << 8);
    // Out-of-range shifts are clamped, not a panic.
    assert_eq!(decay_rate(100, 0, 0), decay_rate(100, 0, 1));
    assert_eq!(decay_rate(100, 0, 99), decay_rate(100, 0, 16));
}

const SETTINGS: DecayedSettings = DecayedSettings {
    half_life_frames: 5.0,
    activate: 300.0,
    deactivate: 60.0,
    instance_activate: 300.0,
    instance_omit: 60.0,
    per_shared: 10.0,
    per_unique: 0.0,
};

#[test]
fn settings_scale_to_fixed_point() {
    let r = SETTINGS
        .rule_for_rays_per_frame(REFERENCE_RAYS_PER_FRAME)
        .unwrap();
    assert_eq!(r.shift, 3, "half-life 5.19 frames");
    assert_eq!((r.activate, r.deactivate), (300 * RATE_ONE, 60 * RATE_ONE));
    assert_eq!((r.per_shared, r.per_unique), (10 * RATE_ONE, 0));
    // A 64th of the rays: a 64th of the rates.
    let small = SETTINGS
        .rule_for_rays_per_frame(REFERENCE_RAYS_PER_FRAME / 64.0)
        .unwrap();
    assert_eq!(small.activate, 300 * RATE_ONE / 64);
    // Tiny ray counts: the lower rates stop at the decay floor 2^k.
    let tiny = SETTINGS.rule_for_rays_per_frame(1.0).unwrap();
    assert_eq!((tiny.deactivate, tiny.activate), (8, 9));
    assert!(tiny.validate().is_ok());
    for (hl, k) in [
        (1.0, 1),
        (2.4, 2),
        (11.0, 4),
        (44.0, 6),
        (177.0, 8),
        (400.0, 8),
    ] {
        assert_eq!(DecayedSettings::shift_for_half_life(hl), Ok(k), "{hl}");
    }
}

#[test]
fn settings_that_cannot_be_met_are_errors() {
    for hl in [f64::NAN, -1.0, 0.0, 0.4, f64::INFINITY, 401.0] {
        let s = DecayedSettings {
            half_life_frames: hl,
            ..SETTINGS
        };
        let e = s.rule_for_rays_per_frame(9216.0).unwrap_err();
        assert!(matches!(e, ThresholdError::InvalidHalfLife(_)), "{hl}");
        assert!(e.to_string().contains("half-life"));
    }
    for v in [f64::NAN, -3.0, 0.0, f64::INFINITY] {
        let s = DecayedSettings {
            activate: v,
            ..SETTINGS
        };
        assert!(matches!(
            s.rule_for_rays_per_frame(9216.0),
            Err(ThresholdError::InvalidRate {
                name: "activate",
                ..
            })
        ));
    }
    // Zero cost terms are fine, negative ones are not.
    let s = DecayedSettings {
        per_unique: -1.0,
        ..SETTINGS
    };
    assert!(s.rule_for_rays_per_frame(9216.0).is_err());
    // A threshold no rate can reach.
    let s = DecayedSettings {
        activate: 1e9,
        ..SETTINGS
    };
    assert!(matches!(
        s.rule_for_rays_per_frame(REFERENCE_RAYS_PER_FRAME),
        Err(ThresholdError::RateTooLarge { .. })
    ));
    assert!(SETTINGS.rule_for_rays_per_frame(f64::NAN).is_err());
}

#[test]
fn rule_validation_names_each_problem() {
    let r = SETTINGS
        .rule_for_rays_per_frame(REFERENCE_RAYS_PER_FRAME)
        .unwrap();
    assert!(matches!(
        DecayedRule { shift: 0, ..r }.validate(),
        Err(ThresholdError::DecayShiftOutOfRange(0))
    ));
    assert!(matches!(
        DecayedRule { shift: 9, ..r }.validate(),
        Err(ThresholdError::DecayShiftOutOfRange(9))
    ));
    assert!(matches!(
        DecayedRule { deactivate: 7, ..r }.validate(),
        Err(ThresholdError::RateBelowDecayFloor { floor: 8, .. })
    ));
    assert!(matches!(
        DecayedRule {
            deactivate: r.activate,
            ..r
        }
        .validate(),
        Err(ThresholdError::DeactivationNotBelowActivation { .. })
    ));
    assert!(matches!(
        DecayedRule {
            instance_omit: r.instance_activate,
            ..r
        }
        .validate(),
        Err(ThresholdError::OmitNotBelowActivation { .. })
    ));
    let e = DecayedRule {
        per_unique: u32::MAX / 255,
        ..r
    }
    .validate()
    .unwrap_err();
    assert!(matches!(e, ThresholdError::RateTooLarge { .. }));
    // The thresholds carry the rule's validation.
    let t = Thresholds::paper().with_rule(DecisionRule::Decayed(DecayedRule { shift: 0, ..r }));
    assert!(t.validate().is_err());
    // The largest threshold fits a u32: the shader's sum cannot wrap.
    assert_eq!(
        u64::from(r.activation_threshold(u32::MAX, u32::MAX)),
        u64::from(r.activate) + 255 * u64::from(r.per_shared)
    );
}

#[test]
fn scaling_by_one_factor() {
    let r = SETTINGS
        .rule_for_rays_per_frame(REFERENCE_RAYS_PER_FRAME)
        .unwrap();
    let t = Thresholds::paper().with_rule(DecisionRule::Decayed(r));
    let half = t.scaled(0.5).unwrap();
    assert_eq!((half.theta_a, half.theta_d, half.n_a), (500, 50, 4));
    let DecisionRule::Decayed(h) = half.rule else {
        panic!("rule kept")
    };
    assert_eq!(
        (h.activate, h.deactivate, h.shift),
        (150 * RATE_ONE, 30 * RATE_ONE, 3)
    );
    assert_eq!(h.per_shared, 5 * RATE_ONE);
    assert_eq!(t.scaled(1.0).unwrap(), t);
    // Tiny factors keep each band open and above the floor.
    let tiny = t.scaled(1e-9).unwrap();
    let DecisionRule::Decayed(x) = tiny.rule else {
        panic!("rule kept")
    };
    assert!(x.deactivate == 8 && x.activate > x.deactivate);
    assert!(tiny.theta_d < tiny.theta_a);
    for f in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(matches!(t.scaled(f), Err(ThresholdError::InvalidScale(_))));
    }
    // Too large to reach: an error, not a saturated threshold.
    assert!(t.scaled(1e6).is_err());
}
