//! Reflected binary Gray code: g(c) = c XOR (c >> 1).

/// Gray code of `c`.
///
/// ```
/// assert_eq!(ris_core::pattern::binary_to_gray(5), 0b111);
/// ```
#[inline]
pub fn binary_to_gray(c: u32) -> u32 {
    c ^ (c >> 1)
}

/// Inverse of [`binary_to_gray`] (prefix XOR).
///
/// ```
/// assert_eq!(ris_core::pattern::gray_to_binary(0b111), 5);
/// ```
#[inline]
pub fn gray_to_binary(g: u32) -> u32 {
    let mut b = g;
    b ^= b >> 1;
    b ^= b >> 2;
    b ^= b >> 4;
    b ^= b >> 8;
    b ^= b >> 16;
    b
}

/// The Gray-code bit (counted from the least significant, 0) that flips at the boundary between
/// cells `b - 1` and `b`; `b` must be ≥ 1. Every boundary is an edge in exactly one pattern.
#[inline]
pub fn flipped_bit(b: u32) -> u32 {
    b.trailing_zeros()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_single_bit_steps() {
        for c in 0..5000u32 {
            assert_eq!(gray_to_binary(binary_to_gray(c)), c);
            if c > 0 {
                let diff = binary_to_gray(c) ^ binary_to_gray(c - 1);
                assert_eq!(diff, 1 << flipped_bit(c), "boundary {c}");
            }
        }
    }
}
