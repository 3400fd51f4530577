//! A small deterministic random number generator (SplitMix64 seeding
//! xoshiro256**), so that neither SynthNOCS nor the runtime's point sampler
//! (`pose::preprocess`, mirrored by tools' `tricons_rng.py`) depends on a crate's
//! RNG version.

/// One SplitMix64 step: advances `state` and returns the next output.
pub fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Mixes several words into one well-scrambled 64-bit seed.
pub fn mix_seed(words: &[u64]) -> u64 {
    let mut state = 0x5EED_5EED_5EED_5EEDu64;
    let mut acc = 0u64;
    for &w in words {
        state ^= w;
        acc = splitmix64(&mut state) ^ acc.rotate_left(17);
    }
    acc
}

/// xoshiro256** generator.
#[derive(Clone, Debug)]
pub struct Rng {
    s: [u64; 4],
}

impl Rng {
    /// A generator whose state is expanded from `seed` with SplitMix64.
    pub fn new(seed: u64) -> Rng {
        let mut st = seed;
        let mut s = [0u64; 4];
        for v in &mut s {
            *v = splitmix64(&mut st);
        }
        if s == [0; 4] {
            s[0] = 1;
        }
        Rng { s }
    }

    /// A generator for one independent stream identified by `words`.
    pub fn from_words(words: &[u64]) -> Rng {
        Rng::new(mix_seed(words))
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        let result = self.s[1].wrapping_mul(5).rotate_left(7).wrapping_mul(9);
        let t = self.s[1] << 17;
        self.s[2] ^= self.s[0];
        self.s[3] ^= self.s[1];
        self.s[1] ^= self.s[2];
        self.s[0] ^= self.s[3];
        self.s[2] ^= t;
        self.s[3] = self.s[3].rotate_left(45);
        result
    }

    /// Uniform in [0, 1), 53 bits.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }

    /// Uniform integer in [0, n); 0 when n is 0.
    pub fn below(&mut self, n: usize) -> usize {
        ((u128::from(self.next_u64()) * n as u128) >> 64) as usize
    }

    /// Uniform integer in [lo, hi] (inclusive).
    pub fn int_incl(&mut self, lo: usize, hi: usize) -> usize {
        lo + self.below(hi.saturating_sub(lo) + 1)
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        self.uniform() < p
    }

    /// Standard normal sample (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.uniform();
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Approximately standard normal (sum of four 16-bit uniforms, rescaled):
    /// one 64-bit draw, much cheaper than [`Rng::normal`], for per-pixel noise.
    pub fn approx_normal(&mut self) -> f32 {
        let x = self.next_u64();
        let sum = (x & 0xFFFF) + ((x >> 16) & 0xFFFF) + ((x >> 32) & 0xFFFF) + (x >> 48);
        // mean 2 * 65535, variance 4 / 12 in units of 65535
        (sum as f32 / 65535.0 - 2.0) * 1.732_050_8
    }

    /// One element of a non-empty slice, chosen uniformly.
    pub fn pick<T: Copy>(&mut self, items: &[T]) -> T {
        items[self.below(items.len())]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_are_deterministic_and_distinct() {
        let a: Vec<u64> = (0..4).map(|_| Rng::from_words(&[1, 2]).next_u64()).collect();
        assert!(a.iter().all(|&v| v == a[0]));
        assert_ne!(Rng::from_words(&[1, 2]).next_u64(), Rng::from_words(&[2, 1]).next_u64());
        let mut r = Rng::new(7);
        let mean: f64 = (0..20000).map(|_| r.uniform()).sum::<f64>() / 20000.0;
        assert!((mean - 0.5).abs() < 0.01);
        let mut hist = [0usize; 6];
        for _ in 0..6000 {
            hist[r.below(6)] += 1;
        }
        assert!(hist.iter().all(|&h| h > 850 && h < 1150), "{hist:?}");
        let var: f64 = (0..20000).map(|_| r.normal().powi(2)).sum::<f64>() / 20000.0;
        assert!((var - 1.0).abs() < 0.05);
    }
}
