//! The tests' random numbers: SplitMix64 (the generator behind the breathing cycles,
//! [`crate::motion::signal::mix64`]), so a failing case is the same on every machine.

/// The next number in [0, 1) of the SplitMix64 stream whose state is `state`.
pub(crate) fn unit(state: &mut u64) -> f64 {
    let z = crate::motion::signal::mix64(*state);
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    (z >> 11) as f64 / (1u64 << 53) as f64
}
