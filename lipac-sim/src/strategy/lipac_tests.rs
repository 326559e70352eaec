//! The LiPaC configuration's decision rules.

use super::*;
use lipac_core::thresholds::RATE_ONE;

#[test]
fn decayed_rule_is_scaled_to_the_rays_and_bad_settings_are_errors() {
    let rays = 128 * 72;
    // The default decides with the decayed rule.
    let c = LipacConfig::for_rays_per_frame(rays).unwrap();
    let DecisionRule::Decayed(r) = c.thresholds.rule else {
        panic!("decayed rule expected");
    };
    // 150 hits per frame at 1080p is 150 · 9216 / 2073600 = 0.67 here.
    let expect = (150.0 * 9216.0 / 2_073_600.0 * f64::from(RATE_ONE)).round() as u32;
    assert_eq!(r.activate, expect);
    assert!(c.thresholds.validate().is_ok());
    assert_eq!(
        c.clone().with_paper_rule().thresholds.rule,
        DecisionRule::Paper
    );
    for half_life in [f64::NAN, -5.0, 0.0] {
        let bad = DecayedSettings {
            half_life_frames: half_life,
            ..LipacConfig::DEFAULT_DECAYED
        };
        let e = c.clone().with_decayed_rule(&bad, rays).unwrap_err();
        assert!(e.to_string().contains("half-life"), "{e}");
    }
    let bad = DecayedSettings {
        deactivate: f64::NAN,
        ..LipacConfig::DEFAULT_DECAYED
    };
    assert!(c.with_decayed_rule(&bad, rays).is_err());
}
