//! A tiny counter-seeded random number generator (SplitMix64).
//!
//! Streams are keyed by `(seed, a, b, c)` (e.g. seed, view, pixel), so results do not
//! depend on thread count or scheduling, and the sequence is fixed by this code alone
//! (no dependency whose algorithm could change between versions).

/// SplitMix64 finaliser.
#[inline]
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// SplitMix64 generator (passes BigCrush; one `u64` of state).
#[derive(Clone, Debug)]
pub struct Rng {
    state: u64,
}

impl Rng {
    /// A stream keyed by four integers.
    pub fn new(seed: u64, a: u64, b: u64, c: u64) -> Rng {
        let mut h = mix(seed ^ 0x9E37_79B9_7F4A_7C15);
        h = mix(h ^ a.wrapping_mul(0xD1B5_4A32_D192_ED03));
        h = mix(h ^ b.wrapping_mul(0xABC9_8388_FB8F_AC03));
        h = mix(h ^ c.wrapping_mul(0x8CB9_2BA7_2F3D_8DD7));
        Rng { state: h }
    }

    /// Next 64 random bits.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix(self.state)
    }

    /// Uniform in `[0, 1)` with 24 bits of resolution.
    #[inline]
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }
}
