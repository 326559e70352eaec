use super::*;

/// The copy that tests and benches carried before this crate (identical in
/// every file): the stream must not change.
fn splitmix_copy(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

fn xorshift_copy(state: &mut u64) -> u64 {
    *state ^= *state >> 12;
    *state ^= *state << 25;
    *state ^= *state >> 27;
    state.wrapping_mul(0x2545_F491_4F6C_DD1D)
}

#[test]
fn splitmix_matches_published_values_and_the_old_copies() {
    // SplitMix64's reference output for seed 0 (also computed in Python).
    let mut r = SplitMix64::new(0);
    assert_eq!(r.next_u64(), 0xE220_A839_7B1D_CDAF);
    assert_eq!(r.next_u64(), 0x6E78_9E6A_A1B9_65F4);
    assert_eq!(r.next_u64(), 0x06C4_5D18_8009_454F);
    let mut r = SplitMix64::new(0x5EED);
    assert_eq!(r.next_u64(), 0x09F1_FD9D_03F0_A9B4);
    for seed in [0, 1, 2, 3, 42, 0x5EED, u64::MAX] {
        let (mut r, mut s) = (SplitMix64::new(seed), seed);
        for _ in 0..1000 {
            assert_eq!(r.next_u64(), splitmix_copy(&mut s), "seed {seed}");
        }
    }
}

#[test]
fn xorshift_matches_the_old_copies() {
    let mut r = XorShift64Star::new(77);
    assert_eq!(r.next_u64(), 0x1977_4A5E_9BF9_30A6);
    assert_eq!(r.next_u64(), 0x8314_0F7F_07C3_6432);
    for seed in [1, 3, 77, 0x9E37_79B9_7F4A_7C15 ^ 5] {
        let (mut r, mut s) = (XorShift64Star::new(seed), seed);
        for _ in 0..1000 {
            assert_eq!(r.next_u64(), xorshift_copy(&mut s));
        }
    }
    let mut s = 9u64.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut r = XorShift64Star::from_seed(9);
    assert_eq!(r.next_u64(), xorshift_copy(&mut s));
    assert_ne!(XorShift64Star::from_seed(0).next_u64(), 0);
}

/// The benches' copy (algorithms, registry, synthetic_loop).
fn xorshift64_copy(state: &mut u64) -> u64 {
    *state ^= *state << 13;
    *state ^= *state >> 7;
    *state ^= *state << 17;
    *state
}

#[test]
fn xorshift64_matches_the_benches_copies() {
    // Marsaglia's xorshift64 (13, 7, 17) from state 1: 1 ^ 1 << 13 = 0x2001,
    // ^ >> 7 (0x40) = 0x2041, ^ << 17 = 0x4082_2041.
    assert_eq!(XorShift64::new(1).next_u64(), 0x4082_2041);
    for seed in [1, 0x1234_5678_9ABC_DEF0, 0x9E37_79B9_7F4A_7C15 ^ 100_000] {
        let (mut r, mut s) = (XorShift64::new(seed), seed);
        for _ in 0..1000 {
            assert_eq!(r.next_u64(), xorshift64_copy(&mut s));
        }
    }
    // The benches' draws: top 24 bits as [0, 1), top 32 bits.
    let (mut r, mut s) = (XorShift64::new(77), 77u64);
    assert_eq!(
        r.unit_f32(),
        (xorshift64_copy(&mut s) >> 40) as f32 / (1u64 << 24) as f32
    );
    assert_eq!(r.next_u32(), (xorshift64_copy(&mut s) >> 32) as u32);
}

#[test]
fn derived_draws_match_their_formulas() {
    let (mut r, mut s) = (SplitMix64::new(7), 7u64);
    assert_eq!(r.below_u32(10), (splitmix_copy(&mut s) % 10) as u32);
    assert_eq!(r.below(0), 0);
    splitmix_copy(&mut s);
    assert_eq!(
        r.below_scaled(1000),
        (((splitmix_copy(&mut s) >> 32) * 1000) >> 32) as u32
    );
    let u = r.unit_f64();
    assert_eq!(
        u,
        (splitmix_copy(&mut s) >> 11) as f64 / (1u64 << 53) as f64
    );
    let f = r.unit_f32();
    assert_eq!(
        f,
        (splitmix_copy(&mut s) >> 40) as f32 / (1u64 << 24) as f32
    );
    assert_eq!(
        r.chance_percent(30),
        splitmix_copy(&mut s) % 100 < 30,
        "chance_percent"
    );
    assert_eq!(r.pick::<u8>(&[]), None);
    let v = [3u8, 5, 9];
    assert_eq!(r.pick(&v), Some(v[(splitmix_copy(&mut s) % 3) as usize]));
}

#[test]
fn draws_are_in_range_and_roughly_uniform() {
    let mut r = SplitMix64::new(1);
    let mean = (0..10_000).map(|_| r.unit_f64()).sum::<f64>() / 10_000.0;
    assert!((mean - 0.5).abs() < 0.02, "mean {mean}");
    assert!((0..1000).all(|_| r.below_usize(7) < 7));
    assert!((0..1000).all(|_| r.below_scaled(7) < 7));
    assert!((0..1000).all(|_| (2.0..3.0).contains(&r.range_f32(2.0, 3.0))));
    assert!((0..1000).all(|_| (16..=4096).contains(&r.log_uniform(16, 4096))));
    let hits = (0..10_000).filter(|_| r.chance(0.25)).count();
    assert!((2200..2800).contains(&hits), "{hits}");
}
