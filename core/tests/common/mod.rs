//! Helpers shared by the core tests: a seeded generator for families of cases.
#![allow(dead_code)] // each test binary uses part of it

/// A small seeded generator (64-bit LCG): the same seed gives the same case on every machine.
pub struct Rng(pub u64);

impl Rng {
    /// Uniform in (0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    /// Uniform in (a, b).
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.uniform()
    }
    /// Standard normal (Box–Muller).
    pub fn gauss(&mut self) -> f64 {
        (-2.0 * self.uniform().ln()).sqrt() * (std::f64::consts::TAU * self.uniform()).cos()
    }
}

/// Whether this run is the long tier (`.ci/run --long`, which sets `RIS_TIER=long`): whole
/// seeded families and surveys. The default tier runs the first cases of each family, so every
/// family is still exercised by `.ci/run`.
pub fn long_tier() -> bool {
    std::env::var("RIS_TIER").is_ok_and(|v| v == "long")
}

/// Seeds `0..default` of a family, or `0..long` in the long tier.
pub fn seeds(default: u64, long: u64) -> std::ops::Range<u64> {
    0..if long_tier() { long } else { default }
}
