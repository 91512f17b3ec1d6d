//! Jittered ray starts (docs/rendering.md "One ray", step 1): each pixel's samples are offset by a
//! fraction of a step taken from an integer hash of the pixel, so neighbouring rays sample at
//! different depths and no wood-grain banding appears. The GPU shader runs the same hash.

/// The integer hash of docs/rendering.md (wrapping u32 arithmetic).
#[inline]
pub fn hash(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    x
}

/// j ∈ [0, 1) of pixel (`col`, `row`): hash(col + row·65 536) >> 8, divided by 2²⁴ (exact in f32).
#[inline]
pub fn jitter(col: u32, row: u32) -> f32 {
    let h = hash(col.wrapping_add(row.wrapping_mul(65_536))) >> 8;
    h as f32 / 16_777_216.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jitter_is_in_the_unit_interval_and_spread() {
        let js: Vec<f32> = (0..64).flat_map(|r| (0..64).map(move |c| jitter(c, r))).collect();
        assert!(js.iter().all(|j| (0.0..1.0).contains(j)));
        let mean = js.iter().sum::<f32>() / js.len() as f32;
        assert!((mean - 0.5).abs() < 0.02, "mean {mean}");
        assert_ne!(jitter(0, 0), jitter(1, 0));
    }
}
