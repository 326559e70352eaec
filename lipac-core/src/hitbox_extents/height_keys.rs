//! Integer keys under which the hitbox extents reduce the heights of a
//! hitbox's members ([`super`]): the order of the ordered keys the shaders
//! reduced with before the extents moved to the CPU.
//!
//! That key, `lipacOrderedKey(bits)` (`sign ? !bits : bits | 1 << 31`), is
//! an unsigned key that orders the non-NaN floats as `<` does and puts −0
//! below +0. Here it is shifted by a constant (mod 2³²) so that both NaN
//! ranges land where the reduction never picks them, without a test:
//!
//! * [`min_key`] = key − key(−∞): −∞ … +∞ map to `0 ..= 0xFF00_0001`, every
//!   NaN above that, so a `min` starting at `min_key(+∞)` never takes one;
//! * [`max_key`] = key − key(+∞) − 1 = key + key(−∞): every NaN maps below
//!   `max_key(−∞)`, so a `max` starting at `max_key(−∞)` never takes one.
//!
//! Between −∞ and +∞ both are the ordered key plus a constant without
//! wrapping, so the smallest (largest) key is the smallest (largest)
//! height, bit for bit. `f32::min`/`max` agree except that they leave open
//! which of ±0 wins.

/// The ordered key (`lipacOrderedKey` of the shaders before): `!bits` for a set sign bit, else
/// `bits | 1 << 31` (branch-free).
#[inline(always)]
fn ordered_key(bits: u32) -> u32 {
    bits ^ ((((bits as i32) >> 31) as u32) | 0x8000_0000)
}

/// Inverse of [`ordered_key`] (`lipacFromOrderedKey`).
#[inline(always)]
fn from_ordered_key(key: u32) -> u32 {
    key ^ ((((!key as i32) >> 31) as u32) | 0x8000_0000)
}

/// `ordered_key(−∞)`; [`min_key`] subtracts it, [`max_key`] adds it.
const NEG_INF_KEY: u32 = 0x007F_FFFF;

/// Key of a height (f32 bits) for the `min` reduction; NaN sorts above +∞.
#[inline(always)]
pub(crate) fn min_key(bits: u32) -> u32 {
    ordered_key(bits).wrapping_sub(NEG_INF_KEY)
}

/// Key of a height (f32 bits) for the `max` reduction; NaN sorts below −∞.
#[inline(always)]
pub(crate) fn max_key(bits: u32) -> u32 {
    ordered_key(bits).wrapping_add(NEG_INF_KEY)
}

/// The f32 bits of a [`min_key`] that is not a NaN's.
#[inline(always)]
pub(crate) fn from_min_key(key: u32) -> u32 {
    from_ordered_key(key.wrapping_add(NEG_INF_KEY))
}

/// The f32 bits of a [`max_key`] that is not a NaN's.
#[inline(always)]
pub(crate) fn from_max_key(key: u32) -> u32 {
    from_ordered_key(key.wrapping_sub(NEG_INF_KEY))
}

/// [`min_key`] of +∞: the empty `min` reduction.
pub(crate) const MIN_KEY_EMPTY: u32 = 0xFF00_0001;
/// [`max_key`] of −∞: the empty `max` reduction.
pub(crate) const MAX_KEY_EMPTY: u32 = 0x00FF_FFFE;

#[cfg(test)]
mod tests {
    use super::*;

    /// The shader's `lipacOrderedKey`, branch for branch.
    fn shader_key(bits: u32) -> u32 {
        if bits & 0x8000_0000 != 0 {
            !bits
        } else {
            bits | 0x8000_0000
        }
    }

    fn is_nan(bits: u32) -> bool {
        f32::from_bits(bits).is_nan()
    }

    /// Edge values and every `stride`-th of the 2³² bit patterns.
    fn samples(stride: usize) -> impl Iterator<Item = u32> {
        let edges = [
            0u32,
            1,
            0x007F_FFFF,
            0x0080_0000,
            0x3F80_0000,
            0x7F7F_FFFF,
            0x7F80_0000,
            0x7F80_0001,
            0x7FC0_0000,
            0x7FFF_FFFF,
        ];
        let signed = edges.into_iter().flat_map(|b| [b, b | 0x8000_0000]);
        signed.chain((0..=u32::MAX).step_by(stride))
    }

    #[test]
    fn constants_are_the_keys_of_the_infinities() {
        assert_eq!(ordered_key(f32::NEG_INFINITY.to_bits()), NEG_INF_KEY);
        assert_eq!(min_key(f32::INFINITY.to_bits()), MIN_KEY_EMPTY);
        assert_eq!(max_key(f32::NEG_INFINITY.to_bits()), MAX_KEY_EMPTY);
        assert_eq!(min_key(f32::NEG_INFINITY.to_bits()), 0);
        assert_eq!(max_key(f32::INFINITY.to_bits()), u32::MAX);
    }

    #[test]
    fn keys_are_the_shader_order_and_round_trip() {
        for b in samples(65_521) {
            assert_eq!(ordered_key(b), shader_key(b), "{b:#x}");
            assert_eq!(from_ordered_key(ordered_key(b)), b, "{b:#x}");
            if is_nan(b) {
                assert!(min_key(b) > MIN_KEY_EMPTY, "NaN {b:#x} could win a min");
                assert!(max_key(b) < MAX_KEY_EMPTY, "NaN {b:#x} could win a max");
            } else {
                assert_eq!(from_min_key(min_key(b)), b, "{b:#x}");
                assert_eq!(from_max_key(max_key(b)), b, "{b:#x}");
                assert!(min_key(b) <= MIN_KEY_EMPTY && max_key(b) >= MAX_KEY_EMPTY);
            }
        }
    }

    #[test]
    fn non_nan_keys_order_as_the_shader_keys() {
        let v: Vec<u32> = samples(6_700_417).filter(|&b| !is_nan(b)).collect();
        for &a in &v {
            for &b in &v {
                let want = shader_key(a).cmp(&shader_key(b));
                assert_eq!(min_key(a).cmp(&min_key(b)), want, "{a:#x} {b:#x}");
                assert_eq!(max_key(a).cmp(&max_key(b)), want, "{a:#x} {b:#x}");
            }
        }
        // -0 below +0, as atomicMin/atomicMax on the shader keys decide.
        assert!(min_key((-0.0f32).to_bits()) < min_key(0.0f32.to_bits()));
        assert!(max_key((-0.0f32).to_bits()) < max_key(0.0f32.to_bits()));
    }
}
