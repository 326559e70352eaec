use super::*;

#[test]
fn small_sizes_are_exact_bins() {
    for s in 1..SL_COUNT as u64 {
        assert_eq!(
            bin_floor_of(s),
            Bin {
                fl: 0,
                sl: s as usize
            }
        );
        assert!(is_bin_boundary(s));
        assert_eq!(bin_ceil_of(s), Some(bin_floor_of(s)));
    }
}

#[test]
fn floor_bin_contains_size_and_ceil_bin_guarantees_fit() {
    let mut sizes: Vec<u64> = (1..5000).collect();
    for shift in 5..63 {
        let p = 1u64 << shift;
        sizes.extend([p - 1, p, p + 1, p + p / 3, p + p / 2 + 7]);
    }
    sizes.push(u64::MAX);
    for s in sizes {
        let b = bin_floor_of(s);
        assert!(b.fl < FL_COUNT && b.sl < SL_COUNT, "{s}: {b:?}");
        let lo = bin_min_size(b);
        assert!(lo <= s, "{s}: floor bin starts at {lo}");
        // The next bin starts above s.
        let next = if b.sl + 1 < SL_COUNT {
            Bin {
                fl: b.fl,
                sl: b.sl + 1,
            }
        } else {
            Bin {
                fl: b.fl + 1,
                sl: 0,
            }
        };
        if next.fl < FL_COUNT {
            assert!(bin_min_size(next) > s, "{s}");
        }
        match bin_ceil_of(s) {
            Some(c) => {
                assert!(bin_min_size(c) >= s, "{s}");
                assert!(c.flat() == b.flat() || c.flat() == b.flat() + 1);
                assert_eq!(c == b, is_bin_boundary(s));
            }
            None => assert!(s > u64::MAX - (1 << 58)),
        }
    }
}

#[test]
fn flat_floor_ceil_agrees_with_floor_and_ceil_bins() {
    let mut sizes: Vec<u64> = (1..5000).collect();
    for shift in 5..64 {
        let p = 1u64 << shift;
        sizes.extend([p - 1, p, p + 1, p + p / 3, p | (p - 1)]);
    }
    for s in sizes {
        let (floor, ceil) = flat_floor_ceil(s);
        assert_eq!(floor, bin_floor_of(s).flat(), "{s}");
        assert_eq!(flat_floor(s), floor, "{s}");
        match bin_ceil_of(s) {
            Some(c) => assert_eq!(ceil, c.flat(), "{s}"),
            None => assert_eq!(ceil, BIN_COUNT, "{s}"),
        }
    }
}

#[test]
fn bin_width_is_an_eighth_of_the_octave() {
    // Between 1024 and 2048 bins are 1024 / 8 = 128 bytes wide.
    assert!(is_bin_boundary(1024 + 128 * 5));
    assert!(!is_bin_boundary(1024 + 128 * 5 + 1));
    assert!(!is_bin_boundary(1024 + 32 * 5));
    assert_eq!(bin_min_size(bin_floor_of(1100)), 1024);
    assert_eq!(bin_min_size(bin_floor_of(1200)), 1152);
}
