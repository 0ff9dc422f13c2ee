//! Deterministic pseudo-random numbers: the [`SplitMix64`] generator (Steele, Lea & Flood 2014)
//! and the seed-mixing hashes built on its output function ([`mix`], [`hash64`]).
//!
//! Tiny, fast and with a fixed output for a seed, so every draw of the engine is reproducible.
//! Not cryptographic. Written by hand to avoid a dependency. The constants and the order of the
//! operations are part of the engine's output: change them and every seeded result changes.

/// The golden-ratio increment of SplitMix64, `⌊2⁶⁴ / φ⌋`.
pub const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;

/// The output function (finalizer) of SplitMix64: a bijective 64-bit mix of `z`.
#[inline]
pub fn finalize(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Mixes a seed with two indices into a new seed: `finalize(seed ^ a·GOLDEN ^ b·C)`.
pub fn mix(seed: u64, a: u64, b: u64) -> u64 {
    finalize(seed ^ a.wrapping_mul(GOLDEN) ^ b.wrapping_mul(0xC2B2_AE3D_27D4_EB4F))
}

/// A well-mixed 64-bit hash of `seed` and `index`: the `index + 1`-th output of a SplitMix64
/// seeded with `seed`, found without stepping through the ones before it.
pub fn hash64(seed: u64, index: u64) -> u64 {
    finalize(
        seed.wrapping_add(index.wrapping_mul(GOLDEN))
            .wrapping_add(GOLDEN),
    )
}

/// A uniform number in `[0, 1)` from [`hash64`] (53 random bits).
pub fn hash_unit(seed: u64, index: u64) -> f64 {
    unit_f64_of(hash64(seed, index))
}

/// The top 53 bits of `bits` as a float in `[0, 1)`.
#[inline]
fn unit_f64_of(bits: u64) -> f64 {
    (bits >> 11) as f64 / (1u64 << 53) as f64
}

/// SplitMix64: a small seeded pseudo-random generator (not cryptographic).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// A generator with the given seed.
    pub fn new(seed: u64) -> Self {
        Self { state: seed }
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(GOLDEN);
        finalize(self.state)
    }

    /// A uniform integer in `0..n` (Lemire's multiply-shift with rejection, so exactly uniform).
    ///
    /// # Panics
    /// If `n == 0`.
    pub fn below(&mut self, n: u64) -> u64 {
        assert!(n > 0, "SplitMix64::below(0)");
        let threshold = n.wrapping_neg() % n;
        loop {
            let m = (self.next_u64() as u128) * (n as u128);
            if (m as u64) >= threshold {
                return (m >> 64) as u64;
            }
        }
    }

    /// A uniform float in `[0, 1)` (24 random bits).
    pub fn unit_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// A uniform float in `[0, 1)` (53 random bits).
    pub fn unit_f64(&mut self) -> f64 {
        unit_f64_of(self.next_u64())
    }

    /// A uniform float in `[-1, 1)`: [`unit_f64`](Self::unit_f64) `· 2 − 1`.
    pub fn signed_unit_f64(&mut self) -> f64 {
        self.unit_f64() * 2.0 - 1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference outputs of SplitMix64 for seed 0 (as published with the algorithm).
    #[test]
    fn reference_sequence() {
        let mut r = SplitMix64::new(0);
        assert_eq!(r.next_u64(), 0xE220_A839_7B1D_CDAF);
        assert_eq!(r.next_u64(), 0x6E78_9E6A_A1B9_65F4);
        assert_eq!(r.next_u64(), 0x06C4_5D18_8009_454F);
    }

    #[test]
    fn hash64_is_the_generator_without_stepping() {
        let mut r = SplitMix64::new(12345);
        for i in 0..5 {
            assert_eq!(hash64(12345, i), r.next_u64());
        }
    }

    #[test]
    fn floats_in_range() {
        let mut r = SplitMix64::new(7);
        for _ in 0..1000 {
            let (a, b, c) = (r.unit_f32(), r.unit_f64(), r.signed_unit_f64());
            assert!((0.0..1.0).contains(&a) && (0.0..1.0).contains(&b));
            assert!((-1.0..1.0).contains(&c));
        }
        assert!(hash_unit(1, 2) < 1.0);
        assert_ne!(mix(1, 2, 3), mix(1, 3, 2));
    }
}
