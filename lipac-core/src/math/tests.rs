use lipac_test_support::{Rng64, SplitMix64};

use super::*;

#[test]
fn rows_round_trip_and_apply() {
    let a = Affine3A::from_scale_rotation_translation(
        Vec3::new(2.0, 3.0, 4.0),
        glam::Quat::from_rotation_y(0.5),
        Vec3::new(10.0, -5.0, 7.0),
    );
    let r = affine_to_rows(&a);
    let p = Vec3::new(1.0, 2.0, 3.0);
    let by_rows = Vec3::new(
        r[0] * p.x + r[1] * p.y + r[2] * p.z + r[3],
        r[4] * p.x + r[5] * p.y + r[6] * p.z + r[7],
        r[8] * p.x + r[9] * p.y + r[10] * p.z + r[11],
    );
    assert!((by_rows - a.transform_point3(p)).length() < 1e-5);
    assert_eq!(rows_to_affine(&r), a);
}

/// The registry keeps an instance's transform only as the rows of its
/// GPU record and rebuilds the `Affine3A` from them, so the round trip
/// must be exact for every bit pattern (signed zeros, subnormals, NaN
/// payloads included), not just within a tolerance.
#[test]
fn rows_round_trip_is_bit_exact() {
    let bits = |a: &Affine3A| -> Vec<u32> {
        let c = a.to_cols_array();
        c.iter().map(|v| v.to_bits()).collect()
    };
    let mut rng = SplitMix64::new(0x2545_F491_4F6C_DD1D);
    let special = [
        0.0,
        -0.0,
        f32::MIN_POSITIVE / 2.0,
        -1e-45,
        f32::MAX,
        f32::MIN,
    ];
    for case in 0..10_000u32 {
        let mut r = [0f32; 12];
        for (i, v) in r.iter_mut().enumerate() {
            let state = rng.next_u64();
            *v = if case % 4 == 0 {
                special[(state % special.len() as u64) as usize]
            } else {
                f32::from_bits((state >> 32) as u32 ^ i as u32)
            };
        }
        let a = rows_to_affine(&r);
        let back = affine_to_rows(&a);
        let same: Vec<u32> = back.iter().map(|v| v.to_bits()).collect();
        let want: Vec<u32> = r.iter().map(|v| v.to_bits()).collect();
        assert_eq!(same, want, "rows -> affine -> rows, case {case}");
        assert_eq!(bits(&rows_to_affine(&affine_to_rows(&a))), bits(&a));
    }
}

#[test]
fn aabb_validity() {
    assert!(Aabb::new(Vec3::ZERO, Vec3::ZERO).is_valid());
    assert!(!Aabb::new(Vec3::ONE, Vec3::ZERO).is_valid());
    assert!(!Aabb::new(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::ONE).is_valid());
}
