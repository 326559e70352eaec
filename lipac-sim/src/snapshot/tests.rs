use super::*;

#[test]
fn heat_map_is_black_exactly_where_the_error_is_zero() {
    let reference = vec![Vec3::ONE; 4];
    let mut image = reference.clone();
    image[2] = Vec3::new(1.5, 1.0, 1.0);
    let h = heat_map(&image, &reference, 1.0).unwrap();
    assert_eq!(&h[..6], &[0; 6]);
    assert_ne!(&h[6..9], &[0, 0, 0]);
    assert_eq!(&h[9..], &[0; 3]);
    assert!(heat_map(&image, &reference[..3], 1.0).is_err());
}

#[test]
fn tonemap_keeps_black_and_order_and_rolls_off() {
    let px = tonemap(
        &[
            Vec3::ZERO,
            Vec3::splat(2.0),
            Vec3::splat(4.0),
            Vec3::splat(1e6),
        ],
        2.0,
    );
    assert_eq!(&px[..3], &[0, 0, 0]);
    // The exposure maps to a mid tone: 0.6 / 1.6 linear, 165 in sRGB.
    assert_eq!(&px[3..6], &[165, 165, 165]);
    // Brighter is brighter; twice the exposure is not yet white.
    assert!(px[6] > px[3] && px[6] < 255 && px[9] > px[6]);
    // The colour scale rises monotonically in brightness.
    let sum = |t: f32| heat_color(t).iter().map(|&c| u32::from(c)).sum::<u32>();
    assert!((1..=10).all(|i| sum(i as f32 / 10.0) > sum((i - 1) as f32 / 10.0)));
}

#[test]
fn file_stems_are_safe() {
    assert_eq!(file_stem("lipac ×4"), "lipac-x4");
    assert_eq!(file_stem("lipac-latency"), "lipac-latency");
    assert_eq!(file_stem("lipac n_a 1 n_d 15"), "lipac-n-a-1-n-d-15");
    assert_eq!(file_stem("../"), "x");
}
