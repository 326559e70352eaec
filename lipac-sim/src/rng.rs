//! Deterministic random numbers: a sequential generator for scene building and
//! a stateless hash for per-pixel/per-bounce samples.

/// SplitMix64: a tiny, fast, seeded sequential generator (scene generation).
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator seeded with `seed`.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in `[0, 1)`.
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }
    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next_f32()
    }
    /// Uniform integer in `0..n` (`n > 0`; returns 0 for `n == 0`).
    pub fn below(&mut self, n: u32) -> u32 {
        if n == 0 {
            return 0;
        }
        (((self.next_u64() >> 32) * u64::from(n)) >> 32) as u32
    }
}

/// PCG hash of one 32-bit word (Jarzynski & Olano 2020).
#[inline]
pub fn pcg_hash(v: u32) -> u32 {
    let state = v.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// A stateless uniform sample in `[0, 1)` for `(frame, pixel, bounce, dimension)`.
///
/// The same four keys always give the same number, which is what lets a culled
/// render and its ground truth use identical random numbers.
#[inline]
pub fn sample(frame: u32, pixel: u32, bounce: u32, dim: u32) -> f32 {
    let h = pcg_hash(
        pcg_hash(pcg_hash(pcg_hash(frame) ^ pixel) ^ bounce.wrapping_mul(0x9E37_79B9)) ^ dim,
    );
    (h >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

#[cfg(test)]
mod tests;
