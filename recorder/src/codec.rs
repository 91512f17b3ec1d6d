//! Exact, compressible tick columns (codecs `stylet-columns-v1` and `-v2`).
//!
//! - f64 columns: each value's bit pattern minus a linear prediction from the two before it
//!   (`2·b[i−1] − b[i−2]`, wrapping u64 arithmetic), zigzag-coded. For a smooth signal sampled at
//!   1 kHz sign, exponent and leading mantissa bits cancel, so the residuals are small integers.
//! - Integer columns (buttons, labels): each value XOR-ed with the one before it.
//!
//! - Integer steps of rounded outputs (`-v2`, [`crate::outputs`]): the residual of the same linear
//!   prediction on the integers, zigzag-coded.
//!
//! Then the bytes are transposed into planes (all first bytes, then all second bytes …), so zstd
//! sees long runs of zeros. Lossless for every bit pattern (NaN payloads and −0 included).

/// The codec name of blocks whose columns hold every value exactly.
pub const CODEC: &str = "stylet-columns-v1";
/// The codec name of blocks whose force and torque columns hold rounded outputs (integer steps,
/// [`crate::outputs`]) and whose exact outputs are pinned by a digest.
pub const CODEC_ROUNDED_OUTPUTS: &str = "stylet-columns-v2";

fn shuffle(words: impl ExactSizeIterator<Item = u64>, width: usize) -> Vec<u8> {
    let n = words.len();
    let mut out = vec![0u8; n * width];
    for (i, x) in words.enumerate() {
        for b in 0..width {
            out[b * n + i] = (x >> (8 * b)) as u8;
        }
    }
    out
}

fn unshuffle(bytes: &[u8], width: usize, count: usize) -> Option<Vec<u64>> {
    if !matches!(width, 1 | 2 | 4 | 8) || bytes.len() != count.checked_mul(width)? {
        return None;
    }
    Some(
        (0..count)
            .map(|i| (0..width).fold(0u64, |x, b| x | (bytes[b * count + i] as u64) << (8 * b)))
            .collect(),
    )
}

/// Encodes integer words of `width` bytes (1, 2, 4 or 8) given as u64s: XOR with the previous.
pub fn encode(values: &[u64], width: usize) -> Vec<u8> {
    debug_assert!(matches!(width, 1 | 2 | 4 | 8));
    let mut prev = 0u64;
    shuffle(
        values.iter().map(|&v| {
            let x = v ^ prev;
            prev = v;
            x
        }),
        width,
    )
}

/// Decodes `count` integer words of `width` bytes; `None` if the byte count does not match.
pub fn decode(bytes: &[u8], width: usize, count: usize) -> Option<Vec<u64>> {
    let mut prev = 0u64;
    Some(
        unshuffle(bytes, width, count)?
            .into_iter()
            .map(|x| {
                prev ^= x;
                prev
            })
            .collect(),
    )
}

fn predict(b1: u64, b2: u64) -> u64 {
    b1.wrapping_mul(2).wrapping_sub(b2)
}

/// Encodes f64s: zigzag residuals of the linear prediction of their bit patterns (as u64).
pub fn encode_f64(values: &[f64]) -> Vec<u8> {
    encode_predicted(values.iter().map(|v| v.to_bits()))
}

/// Decodes `count` f64s; `None` if the byte count does not match.
pub fn decode_f64(bytes: &[u8], count: usize) -> Option<Vec<f64>> {
    Some(decode_predicted(bytes, count)?.map(f64::from_bits).collect())
}

/// Encodes signed integers: zigzag residuals of the linear prediction `2·v[i−1] − v[i−2]`
/// (wrapping). Integer steps of a smooth signal leave residuals of a few units.
pub fn encode_i64(values: &[i64]) -> Vec<u8> {
    encode_predicted(values.iter().map(|&v| v as u64))
}

/// Decodes `count` integers of [`encode_i64`]; `None` if the byte count does not match.
pub fn decode_i64(bytes: &[u8], count: usize) -> Option<Vec<i64>> {
    Some(decode_predicted(bytes, count)?.map(|v| v as i64).collect())
}

/// Zigzag residuals of `2·w[i−1] − w[i−2]` (wrapping u64 arithmetic), in byte planes.
fn encode_predicted(words: impl ExactSizeIterator<Item = u64>) -> Vec<u8> {
    let (mut w1, mut w2) = (0u64, 0u64);
    shuffle(
        words.map(|w| {
            let r = w.wrapping_sub(predict(w1, w2)) as i64;
            (w2, w1) = (w1, w);
            ((r << 1) ^ (r >> 63)) as u64
        }),
        8,
    )
}

/// The words of [`encode_predicted`]; `None` if the byte count does not match.
fn decode_predicted(bytes: &[u8], count: usize) -> Option<impl Iterator<Item = u64>> {
    let (mut w1, mut w2) = (0u64, 0u64);
    Some(unshuffle(bytes, 8, count)?.into_iter().map(move |z| {
        let r = (z >> 1) as i64 ^ -((z & 1) as i64);
        let w = predict(w1, w2).wrapping_add(r as u64);
        (w2, w1) = (w1, w);
        w
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn round_trips_every_bit(values in prop::collection::vec(any::<u64>(), 0..300), w in prop::sample::select(vec![1usize, 2, 4, 8])) {
            let mask = if w == 8 { u64::MAX } else { (1u64 << (8 * w)) - 1 };
            let values: Vec<u64> = values.into_iter().map(|v| v & mask).collect();
            let enc = encode(&values, w);
            prop_assert_eq!(decode(&enc, w, values.len()).unwrap(), values);
        }

        #[test]
        fn integers_round_trip(values in prop::collection::vec(any::<i64>(), 0..300)) {
            prop_assert_eq!(decode_i64(&encode_i64(&values), values.len()).unwrap(), values);
        }

        #[test]
        fn floats_keep_their_bits(values in prop::collection::vec(any::<f64>(), 0..300)) {
            let back = decode_f64(&encode_f64(&values), values.len()).unwrap();
            prop_assert!(back.iter().zip(&values).all(|(a, b)| a.to_bits() == b.to_bits()));
        }
    }

    #[test]
    fn smooth_signals_become_small_residuals() {
        let v: Vec<f64> = (0..1000).map(|i| 50.0 + (i as f64 * 1e-3).sin()).collect();
        let enc = encode_f64(&v);
        // After the first two values, the top bytes (sign, exponent, leading mantissa) are zero.
        let top = &enc[7 * 1000 + 2..];
        assert!(top.iter().all(|&b| b == 0));
        assert_eq!(decode_f64(&enc, 1000).unwrap(), v);
    }

    #[test]
    fn wrong_sizes_are_refused() {
        assert!(decode(&[0; 7], 8, 1).is_none());
        assert!(decode(&[0; 8], 3, 1).is_none());
        assert!(decode(&[0; 8], 8, usize::MAX).is_none());
        assert!(decode_f64(&[0; 15], 2).is_none());
        assert!(decode_i64(&[0; 17], 2).is_none());
    }
}
