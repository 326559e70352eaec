use lipac_test_support::{Rng64, SplitMix64};

use super::format_f32;

fn round_trip(v: f32) -> f32 {
    let s = format_f32(v);
    serde_json::from_str::<f32>(&s).unwrap_or_else(|e| panic!("{s}: {e}"))
}

#[test]
fn f32_text_parses_back_to_identical_bits() {
    let special = [
        0.0f32,
        -0.0,
        0.1,
        1.0 / 3.0,
        f32::MAX,
        f32::MIN,
        f32::MIN_POSITIVE,
        f32::EPSILON,
        f32::from_bits(1),
        -f32::from_bits(0x007F_FFFF),
        16_777_217.0,
        1e-7,
        3.4e38,
    ];
    for v in special {
        assert_eq!(round_trip(v).to_bits(), v.to_bits(), "{v:?}");
    }
    // A spread of bit patterns over every exponent.
    let mut rng = SplitMix64::new(0x1234_5678_9ABC_DEF0);
    for _ in 0..200_000 {
        let v = f32::from_bits(rng.next_u32());
        if v.is_finite() {
            assert_eq!(
                round_trip(v).to_bits(),
                v.to_bits(),
                "{v:?} bits {:#x}",
                v.to_bits()
            );
        }
    }
}

#[test]
fn short_floats_stay_short() {
    assert_eq!(format_f32(0.1), "0.1");
    assert_eq!(format_f32(16.0), "16.0");
    assert_eq!(format_f32(-0.0), "-0.0");
    assert_eq!(format_f32(1e-7), "1e-7");
}
