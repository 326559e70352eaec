//! Dev-only helpers shared by lipac's tests and benches.
//!
//! Seeded, dependency-free random numbers: [`SplitMix64`],
//! [`XorShift64Star`] and [`XorShift64`] produce the exact streams the tests were written
//! against (the same seed gives the same sequence as the per-file copies
//! they replace), and [`Rng64`] derives every draw the tests use from
//! `next_u64`.
//!
//! ```
//! use lipac_test_support::{Rng64, SplitMix64};
//!
//! let mut rng = SplitMix64::new(42);
//! let die = 1 + rng.below(6);
//! assert!((1..=6).contains(&die));
//! assert!((0.0..1.0).contains(&rng.unit_f64()));
//! ```
//!
//! [`synthetic`] holds a synthetic backend for `Manager` and
//! `BuildScheduler` tests (structures live from their acknowledgement until
//! freed, every plan checked), [`scene`] seeded random scenes, their grid
//! and cameras. Those speak lipac-core's types: lipac-core's integration
//! tests and benches can use them (they link the same lipac-core this crate
//! does), its unit tests cannot (they are a second copy of lipac-core) and
//! use only the generators.
//!
//! This crate is `publish = false`; depend on it as a path dev-dependency
//! without a `version`, which `cargo package` strips from published
//! manifests.

pub mod scene;
pub mod synthetic;

/// Draws derived from a source of 64 random bits.
///
/// Every method consumes exactly one `next_u64` (so streams stay aligned
/// with the hand-written copies this replaces), except
/// [`log_uniform`](Rng64::log_uniform) (one [`unit_f64`](Rng64::unit_f64)).
pub trait Rng64 {
    /// The next 64 random bits.
    fn next_u64(&mut self) -> u64;

    /// The high 32 bits of the next draw.
    fn next_u32(&mut self) -> u32 {
        (self.next_u64() >> 32) as u32
    }
    /// `next_u64() % n`, in `0..n` (0 when `n == 0`).
    fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n.max(1)
    }
    /// [`below`](Rng64::below) for a `u32` bound (`next_u64() % n`).
    fn below_u32(&mut self, n: u32) -> u32 {
        // Lossless: the remainder is below `n`.
        (self.next_u64() % u64::from(n.max(1))) as u32
    }
    /// [`below`](Rng64::below) for a `usize` bound, e.g. an index.
    fn below_usize(&mut self, n: usize) -> usize {
        (self.next_u64() % (n.max(1) as u64)) as usize
    }
    /// `(next_u32() * n) >> 32`, in `0..n` (0 when `n == 0`): Lemire's
    /// multiply-shift, a different mapping from [`below`](Rng64::below).
    fn below_scaled(&mut self, n: u32) -> u32 {
        ((u64::from(self.next_u32()) * u64::from(n)) >> 32) as u32
    }
    /// Uniform in `[0, 1)` from the top 53 bits.
    fn unit_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in `[0, 1)` from the top 24 bits.
    fn unit_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
    /// Uniform in `[lo, hi)` (from [`unit_f64`](Rng64::unit_f64)).
    fn range_f64(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit_f64()
    }
    /// Uniform in `[lo, hi)` (from [`unit_f32`](Rng64::unit_f32)).
    fn range_f32(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.unit_f32()
    }
    /// True with probability `p` (`unit_f64() <= p`).
    fn chance(&mut self, p: f64) -> bool {
        self.unit_f64() <= p
    }
    /// True with probability `percent`/100 (`below(100) < percent`).
    fn chance_percent(&mut self, percent: u64) -> bool {
        self.below(100) < percent
    }
    /// A uniformly chosen element, `None` for an empty slice.
    fn pick<T: Copy>(&mut self, v: &[T]) -> Option<T> {
        if v.is_empty() {
            None
        } else {
            Some(v[self.below_usize(v.len())])
        }
    }
    /// Log-uniform integer in `[lo, hi]` (`lo >= 1`).
    fn log_uniform(&mut self, lo: u32, hi: u32) -> u32 {
        let (l, h) = (f64::from(lo).ln(), f64::from(hi).ln());
        ((l + (h - l) * self.unit_f64()).exp().round() as u32).clamp(lo, hi)
    }
}

/// SplitMix64 (Steele, Lea, Flood 2014): the state advances by the golden
/// gamma and is mixed on output. Any seed, including 0, is fine.
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator whose state is `seed` (the first draw mixes
    /// `seed + 0x9E37_79B9_7F4A_7C15`).
    pub const fn new(seed: u64) -> Self {
        Self(seed)
    }
}

impl Rng64 for SplitMix64 {
    #[inline]
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}

/// xorshift64* (Vigna 2016). The state must not be 0 (0 stays 0): use
/// [`XorShift64Star::from_seed`] for an arbitrary seed.
#[derive(Clone, Debug)]
pub struct XorShift64Star(u64);

impl XorShift64Star {
    /// A generator whose state is exactly `state` (callers pass a non-zero
    /// value, e.g. `seed | 1`).
    pub const fn new(state: u64) -> Self {
        Self(state)
    }
    /// A generator for any seed: the state is
    /// `seed * 0x9E37_79B9_7F4A_7C15 | 1`, never 0.
    pub const fn from_seed(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
}

impl Rng64 for XorShift64Star {
    #[inline]
    fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
}

/// xorshift64 (Marsaglia 2003, shifts 13, 7, 17): the generator of the
/// benches' workloads (the same state gives the same stream as the copies
/// they carried). The state must not be 0 (0 stays 0).
#[derive(Clone, Debug)]
pub struct XorShift64(u64);

impl XorShift64 {
    /// A generator whose state is exactly `state` (non-zero).
    pub const fn new(state: u64) -> Self {
        Self(state)
    }
}

impl Rng64 for XorShift64 {
    #[inline]
    fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

#[cfg(test)]
mod tests;
