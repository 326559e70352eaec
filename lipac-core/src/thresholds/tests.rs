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
        assert!(matches!(p.scaled(f), Err(ThresholdError::InvalidScale(_))));
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

/// The decayed rule: the fixed-point update ([`decay_rate`]) and the
/// validation of rules and settings.
mod decay {
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

    fn rule_with_shift(k: u32) -> DecayedRule {
        DecayedRule {
            shift: k,
            rise_shift: 1,
            activate: 1000,
            deactivate: 1 << k,
            instance_activate: 1000,
            instance_omit: 1 << k,
            per_shared: 0,
            per_unique: 0,
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        /// `hold_rate(t, n)` survives `n` frames without hits at `t` or
        /// above, and is the least rate that does.
        #[test]
        fn hold_rate_is_the_least_rate_that_survives(
            t in prop_oneof![1u32..1000, any::<u32>()],
            n in 0u32..40,
            k in 1u32..=MAX_DECAY_SHIFT,
        ) {
            let rule = rule_with_shift(k);
            let after = |r: u32| (0..n).fold(r, |r, _| rule.update_rate(r, 0));
            let h = rule.hold_rate(t, n);
            prop_assert!(h >= t);
            if h < u32::MAX {
                prop_assert!(after(h) >= t, "hold {} after {} frames: {}", h, n, after(h));
                if h > t {
                    prop_assert!(after(h - 1) < t, "{} is not the least", h);
                }
            } else {
                // Saturated: no smaller rate survives (u32::MAX is the least
                // that does, or none does).
                prop_assert!(after(u32::MAX - 1) < t);
            }
        }
    }

    /// [`rise_decay_rate`] in exact 64-bit arithmetic, from its definition.
    fn rise_reference(rate: u32, hits: u32, k: u32, k_up: u32) -> u64 {
        let target = u64::from(hits.min(RATE_HITS_MAX)) << 16;
        let j = if target > u64::from(rate) { k_up } else { k };
        reference(rate, hits, j)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        #[test]
        fn rise_update_is_exact_and_never_overflows(
            rate in prop_oneof![any::<u32>(), Just(u32::MAX), Just(u32::MAX - 1), Just(0)],
            hits in prop_oneof![any::<u32>(), Just(u32::MAX), Just(RATE_HITS_MAX)],
            k in 1u32..=16,
            k_up_raw in 1u32..=16,
        ) {
            let k_up = k_up_raw.min(k);
            let exact = rise_reference(rate, hits, k, k_up);
            prop_assert!(exact <= u64::from(u32::MAX));
            prop_assert_eq!(u64::from(rise_decay_rate(rate, hits, k, k_up)), exact);
            // k_up == k is the symmetric rule; k_up above k is clamped to it.
            prop_assert_eq!(rise_decay_rate(rate, hits, k, k), decay_rate(rate, hits, k));
            prop_assert_eq!(rise_decay_rate(rate, hits, k, k + 1), decay_rate(rate, hits, k));
        }

        #[test]
        fn rise_update_is_monotone_in_hits_and_rate(
            a: u32,
            b: u32,
            h1 in prop_oneof![0u32..200, any::<u32>()],
            h2 in prop_oneof![0u32..200, any::<u32>()],
            k in 1u32..=MAX_DECAY_SHIFT,
            k_up_raw in 1u32..=MAX_DECAY_SHIFT,
        ) {
            let k_up = k_up_raw.min(k);
            let (lo, hi) = (a.min(b), a.max(b));
            let (hl, hh) = (h1.min(h2), h1.max(h2));
            let f = |r, h| rise_decay_rate(r, h, k, k_up);
            prop_assert!(f(lo, hl) <= f(lo, hh), "hits {} {} rate {}", hl, hh, lo);
            prop_assert!(f(lo, hl) <= f(hi, hl), "rates {} {} hits {}", lo, hi, hl);
            // Rates near the hit rate, where the branch switches.
            let t = hl.min(RATE_HITS_MAX) << 16;
            for (x, y) in [(t.saturating_sub(1), t), (t, t.saturating_add(1))] {
                prop_assert!(f(x, hl) <= f(y, hl));
            }
            prop_assert!(f(t, hl) <= f(t, hl.saturating_add(1)));
        }

        #[test]
        fn rise_converges_to_the_hit_rate_from_below_and_above(
            hits in prop_oneof![1u32..64, 0u32..=RATE_HITS_MAX, Just(u32::MAX)],
            k in 1u32..=MAX_DECAY_SHIFT,
            k_up_raw in 1u32..=MAX_DECAY_SHIFT,
        ) {
            let k_up = k_up_raw.min(k);
            let target = hits.min(RATE_HITS_MAX) << 16;
            // From below (0): rises with k_up, never overshoots, ends within
            // 2^k_up below, after 23·2^k_up frames at most.
            let mut r = 0u32;
            let mut from_below = 0;
            while r < target && target - r >= (1 << k_up) {
                let next = rise_decay_rate(r, hits, k, k_up);
                prop_assert!(next >= r && next <= target);
                r = next;
                from_below += 1;
                prop_assert!(from_below <= 24 << k_up, "stuck at {} of {}", r, target);
            }
            prop_assert!(target - r < (1 << k_up));
            // From above (u32::MAX): falls with k, never undershoots, ends
            // within 2^k above, after 23·2^k frames at most.
            let mut r = u32::MAX;
            for _ in 0..(24u32 << k) {
                let next = rise_decay_rate(r, hits, k, k_up);
                prop_assert!(next <= r && next >= target);
                r = next;
            }
            prop_assert!(r - target < (1 << k), "rate {} target {}", r, target);
            prop_assert_eq!(rise_decay_rate(r, hits, k, k_up), r, "and stays");
        }
    }

    /// A rise at k_up = 1 reaches a step's threshold in fewer frames than
    /// the symmetric rule, and the decay afterwards is the same.
    #[test]
    fn a_fast_rise_crosses_a_threshold_sooner_and_decays_as_before() {
        let frames_to = |k_up: u32| {
            let mut r = 0;
            (1..100)
                .find(|_| {
                    r = rise_decay_rate(r, 5, 3, k_up);
                    r > 4 * RATE_ONE
                })
                .unwrap()
        };
        // 5 hits a frame, threshold 4: k = 3 needs 13 frames (1 − (7/8)^n > 0.8),
        // k_up = 2 six (1 − (3/4)^n), k_up = 1 three (1 − 2^−n).
        assert_eq!([frames_to(3), frames_to(2), frames_to(1)], [13, 6, 3]);
        let r = 5 * RATE_ONE;
        assert_eq!(rise_decay_rate(r, 0, 3, 1), decay_rate(r, 0, 3));
        assert_eq!(rise_decay_rate(r, 2, 3, 1), decay_rate(r, 2, 3));
    }

    #[test]
    fn saturating_inputs() {
        assert_eq!(decay_rate(u32::MAX, u32::MAX, 1), u32::MAX - (1 << 15) + 1);
        assert_eq!(decay_rate(u32::MAX, u32::MAX, 16), u32::MAX);
        assert_eq!(decay_rate(0, u32::MAX, 8), 0xFFFF << 8);
        // Out-of-range shifts are clamped, not a panic.
        assert_eq!(decay_rate(100, 0, 0), decay_rate(100, 0, 1));
        assert_eq!(decay_rate(100, 0, 99), decay_rate(100, 0, 16));
        assert_eq!(rise_decay_rate(0, 9, 3, 0), rise_decay_rate(0, 9, 3, 1));
        assert_eq!(rise_decay_rate(0, 9, 0, 5), decay_rate(0, 9, 1));
        assert_eq!(
            rise_decay_rate(u32::MAX - 1, u32::MAX, 8, 1),
            (u32::MAX - 1) - ((u32::MAX - 1) >> 8) + (0xFFFF << 8)
        );
    }

    const SETTINGS: DecayedSettings = DecayedSettings {
        half_life_frames: 5.0,
        activate: 300.0,
        deactivate: 60.0,
        instance_activate: 300.0,
        instance_omit: 60.0,
        per_shared: 10.0,
        per_unique: 0.0,
        rise_shift: None,
    };

    #[test]
    fn settings_scale_to_fixed_point() {
        let r = SETTINGS
            .rule_for_rays_per_frame(REFERENCE_RAYS_PER_FRAME)
            .unwrap();
        assert_eq!(r.shift, 3, "half-life 5.19 frames");
        assert_eq!(r.rise_shift, 3, "no rise shift: the symmetric rule");
        for k_up in 1..=3 {
            let s = DecayedSettings {
                rise_shift: Some(k_up),
                ..SETTINGS
            };
            let u = s.rule_for_rays_per_frame(REFERENCE_RAYS_PER_FRAME).unwrap();
            assert_eq!(
                u,
                DecayedRule {
                    rise_shift: k_up,
                    ..r
                }
            );
        }
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
        // A rise slower than the decay (or a zero shift).
        for k_up in [0, 4, 99] {
            let s = DecayedSettings {
                rise_shift: Some(k_up),
                ..SETTINGS
            };
            let e = s.rule_for_rays_per_frame(9216.0).unwrap_err();
            assert_eq!(
                e,
                ThresholdError::RiseShiftOutOfRange {
                    rise_shift: k_up,
                    shift: 3
                }
            );
            assert!(e.to_string().contains("rise shift"), "{e}");
        }
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
            DecayedRule { rise_shift: 0, ..r }.validate(),
            Err(ThresholdError::RiseShiftOutOfRange {
                rise_shift: 0,
                shift: 3
            })
        ));
        assert!(matches!(
            DecayedRule { rise_shift: 4, ..r }.validate(),
            Err(ThresholdError::RiseShiftOutOfRange {
                rise_shift: 4,
                shift: 3
            })
        ));
        assert!(DecayedRule { rise_shift: 1, ..r }.validate().is_ok());
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
        // The rise shift stays.
        let fast = Thresholds::paper()
            .with_rule(DecisionRule::Decayed(DecayedRule { rise_shift: 1, ..r }));
        let DecisionRule::Decayed(f) = fast.scaled(0.5).unwrap().rule else {
            panic!("rule kept")
        };
        assert_eq!((f.shift, f.rise_shift, f.activate), (3, 1, h.activate));
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
}
