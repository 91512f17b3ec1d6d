//! Deterministic, counter-based randomness for the phantom.
//!
//! Every random number is a pure function of (seed, stream, index), so the phantom is identical
//! whatever the thread count or visiting order. SplitMix64 mixing (Steele, Lea & Flood 2014).

/// SplitMix64's output function: a bijective 64-bit mixer.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A uniform number in [0, 1) for (seed, stream, index).
#[inline]
pub fn uniform(seed: u64, stream: u64, index: u64) -> f64 {
    let h = mix64(seed ^ mix64(stream.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ mix64(index)));
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// An approximately standard-normal number (sum of four uniforms, Irwin–Hall, rescaled): no
/// transcendental functions, so it is portable bit for bit, and bounded by ±3.46.
#[inline]
pub fn gaussian(seed: u64, stream: u64, index: u64) -> f64 {
    let h = mix64(seed ^ mix64(stream.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ mix64(index)));
    let g = mix64(h);
    let s = (h & 0xFFFF_FFFF) as f64 + (h >> 32) as f64 + (g & 0xFFFF_FFFF) as f64 + (g >> 32) as f64;
    // Mean 2·2^32, variance 4·(2^64/12) for four uniforms on [0, 2^32).
    let mean = 2.0 * 4_294_967_296.0;
    let sd = (4.0 / 12.0f64).sqrt() * 4_294_967_296.0;
    (s - mean) / sd
}

/// A small deterministic generator for building the anatomy (branch angles, lengths).
#[derive(Debug, Clone)]
pub struct Rng {
    seed: u64,
    stream: u64,
    counter: u64,
}

impl Rng {
    pub fn new(seed: u64, stream: u64) -> Self {
        Rng {
            seed,
            stream,
            counter: 0,
        }
    }

    pub fn next_f64(&mut self) -> f64 {
        self.counter += 1;
        uniform(self.seed, self.stream, self.counter)
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next_f64()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_has_unit_variance() {
        let n = 200_000u64;
        let xs: Vec<f64> = (0..n).map(|i| gaussian(7, 1, i)).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n as f64;
        assert!(mean.abs() < 0.01, "{mean}");
        assert!((var - 1.0).abs() < 0.02, "{var}");
    }

    #[test]
    fn uniform_is_a_pure_function() {
        assert_eq!(uniform(1, 2, 3), uniform(1, 2, 3));
        assert_ne!(uniform(1, 2, 3), uniform(1, 2, 4));
        assert_ne!(uniform(1, 2, 3), uniform(2, 2, 3));
    }
}
