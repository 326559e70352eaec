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
    // 100 hits per frame at 1080p is 100 · 9216 / 2073600 = 0.44 here,
    // and the rate rises with shift 1: one hit (0.5) activates, two are
    // needed at a scale of 1.2.
    let expect = (100.0 * 9216.0 / 2_073_600.0 * f64::from(RATE_ONE)).round() as u32;
    assert_eq!((r.activate, r.rise_shift, r.shift), (expect, 1, 3));
    assert!(r.update_rate(0, 1) > r.activate);
    assert!(r.update_rate(0, 1) <= r.scaled(1.2).unwrap().activate);
    // 32 m cells with adaptive hitboxes of 3 merge levels.
    assert_eq!(c.cell_size, 32.0);
    assert_eq!(c.adaptive_hitboxes.levels, 3);
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
