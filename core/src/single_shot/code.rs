//! The X-point code array (Eq. 4.1): a grid of symbols 0–3 in which any two distinct 3×3
//! windows differ in at least 3 places.
//!
//! The seed grows the array window by window, keeping a new symbol only when its window is at
//! Hamming distance ≥ 3 from every earlier one. That search stalls after a few hundred windows
//! (a new interior window has one free cell, so one earlier window that agrees on the other
//! eight forbids all four symbols), and no array of distance-3 windows over 4 symbols can be
//! unique over a whole 1920×1080 projector at a 14 px step: 10 125 windows are needed, the
//! sphere-packing bound allows 9 362. So RIS builds the array so that the distance holds by
//! construction and asks uniqueness only where the decoder needs it:
//!
//! `value(i, j) = x[i mod 64] + y[j mod 16]  (mod 4)`
//!
//! with `x` a De Bruijn sequence of order 3 (its 64 cyclic triples all different) and `y` a
//! sequence whose differences form a De Bruijn sequence of order 2 (its 16 cyclic triples all
//! different up to adding a constant). The difference of two windows is `σ + α[a] + β[b]`: if
//! β is not constant each of the three columns has a non-zero entry, if it is constant each
//! non-zero row has three; so two distinct windows differ in ≥ 3 places, and one wrong symbol
//! is corrected. Two windows are equal only at positions congruent modulo
//! [`PERIOD`] (64 grid columns, 16 grid rows): a decoder that knows the correspondence to
//! within fewer than that many columns and rows (the epipolar segment through the Gray-code
//! reference, for any working depth) finds it unambiguously. `seed` picks the sequences and
//! the array's origin.

/// Grid columns and rows after which windows repeat.
pub const PERIOD: [usize; 2] = [64, 16];

/// The Hamming distance that any two distinct windows keep.
pub const DISTANCE: u32 = 3;

/// A splitmix64 generator: reproducible arrays from a seed, no dependency.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// A random cyclic De Bruijn sequence over 4 symbols of the given order (length 4^order): an
/// Euler circuit of the De Bruijn graph, edges taken in a random order (Hierholzer).
fn de_bruijn(order: u32, rng: &mut SplitMix) -> Vec<u8> {
    let nodes = 4usize.pow(order - 1);
    // Unused out-edges (next symbols) of each node, shuffled.
    let mut out: Vec<Vec<u8>> = (0..nodes)
        .map(|_| {
            let mut e = vec![0u8, 1, 2, 3];
            for k in (1..4).rev() {
                e.swap(k, rng.below(k + 1));
            }
            e
        })
        .collect();
    let mut stack = vec![0usize];
    let mut symbols = Vec::with_capacity(4 * nodes);
    let mut via: Vec<u8> = vec![0];
    while let Some(&v) = stack.last() {
        if let Some(s) = out[v].pop() {
            stack.push((v * 4 + s as usize) % nodes);
            via.push(s);
        } else {
            stack.pop();
            if let Some(s) = via.pop() {
                symbols.push(s);
            }
        }
    }
    // The circuit's edge symbols in reverse order of completion, without the start marker.
    symbols.pop();
    symbols.reverse();
    symbols
}

/// The code array of a grid `columns × rows` for `seed` (row-major, symbols 0–3).
pub fn array(columns: usize, rows: usize, seed: u64) -> Vec<u8> {
    let mut rng = SplitMix(seed ^ 0x5851_f42d_4c95_7f2d);
    let x = de_bruijn(3, &mut rng);
    let d = de_bruijn(2, &mut rng);
    let mut y = Vec::with_capacity(d.len());
    let mut acc = rng.below(4) as u8;
    for step in &d {
        y.push(acc);
        acc = (acc + step) % 4;
    }
    let (i0, j0) = (rng.below(x.len()), rng.below(y.len()));
    let mut v = Vec::with_capacity(columns * rows);
    for j in 0..rows {
        for i in 0..columns {
            v.push((x[(i + i0) % x.len()] + y[(j + j0) % y.len()]) % 4);
        }
    }
    v
}

/// The 9 symbols of the window whose top-left cell is `(i, j)`, row by row.
pub fn window(values: &[u8], columns: usize, i: usize, j: usize) -> [u8; 9] {
    let mut w = [0u8; 9];
    for b in 0..3 {
        for a in 0..3 {
            w[3 * b + a] = values[(j + b) * columns + i + a];
        }
    }
    w
}

/// Places where two windows differ (Eq. 4.1).
pub fn hamming(a: &[u8; 9], b: &[u8; 9]) -> u32 {
    a.iter().zip(b).map(|(x, y)| u32::from(x != y)).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn de_bruijn_sequences_hold_every_word_once() {
        for seed in 0..20 {
            let mut rng = SplitMix(seed);
            for order in [2u32, 3] {
                let s = de_bruijn(order, &mut rng);
                let n = s.len();
                assert_eq!(n, 4usize.pow(order));
                let mut seen = std::collections::HashSet::new();
                for k in 0..n {
                    let word: Vec<u8> = (0..order as usize).map(|o| s[(k + o) % n]).collect();
                    assert!(seen.insert(word), "seed {seed}: order {order} repeats");
                }
            }
        }
    }
}
