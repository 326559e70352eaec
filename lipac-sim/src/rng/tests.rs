use super::*;

#[test]
fn splitmix_is_seeded_and_uniformish() {
    let a: Vec<u64> = (0..4)
        .scan(SplitMix64::new(7), |r, _| Some(r.next_u64()))
        .collect();
    let b: Vec<u64> = (0..4)
        .scan(SplitMix64::new(7), |r, _| Some(r.next_u64()))
        .collect();
    let c: Vec<u64> = (0..4)
        .scan(SplitMix64::new(8), |r, _| Some(r.next_u64()))
        .collect();
    assert_eq!(a, b);
    assert_ne!(a, c);
    let mut r = SplitMix64::new(1);
    let mean: f32 = (0..10_000).map(|_| r.next_f32()).sum::<f32>() / 10_000.0;
    assert!((mean - 0.5).abs() < 0.02, "mean {mean}");
    assert!((0..1000).all(|_| r.below(7) < 7));
}

#[test]
fn samples_are_in_range_and_decorrelated_by_key() {
    let mut sum = 0.0;
    for p in 0..4096 {
        let s = sample(3, p, 1, 0);
        assert!((0.0..1.0).contains(&s));
        sum += s;
    }
    assert!((sum / 4096.0 - 0.5).abs() < 0.03);
    assert_ne!(sample(0, 5, 0, 0), sample(1, 5, 0, 0));
    assert_ne!(sample(0, 5, 0, 0), sample(0, 5, 1, 0));
    assert_ne!(sample(0, 5, 0, 0), sample(0, 5, 0, 1));
}
