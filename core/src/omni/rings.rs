//! The omnidirectional projector's ring pattern (Eq. 6.8–6.11, SPEC §13): concentric rings about
//! the projector's principal point, each with its own angular frequency, so that a ring is known
//! by the frequency of the intensity along it and a point on it by the phase angle, which the
//! vertical epipolar geometry preserves.

use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// The golden angle, radians: successive multiples spread evenly around the circle.
const GOLDEN_ANGLE: f64 = 2.399_963_229_728_653;

/// The radial profile of a ring.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Profile {
    /// exp(−x²/2), `width` the standard deviation.
    Gaussian,
    /// 1 for |x| ≤ 1/2, `width` the full width.
    Box,
}

/// The image the rings are drawn on.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PatternSection {
    /// Projector width, pixels.
    pub width: u32,
    /// Projector height, pixels.
    pub height: u32,
    /// Centre of the rings (the principal point), pixels.
    pub center: [f64; 2],
    /// Radial profile of every ring.
    pub profile: Profile,
}

/// One ring: `intensity · g((ρ − radius)/width) · (1 + cos(frequency · θ + phase)) / 2`.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Ring {
    /// Radius, projector pixels.
    pub radius: f64,
    /// Profile width, pixels.
    pub width: f64,
    /// Periods per turn.
    pub frequency: u32,
    /// Phase, radians.
    pub phase: f64,
    /// Peak intensity, 0 … 1.
    pub intensity: f64,
}

/// A ring pattern as `rings.toml` states it: enough to rebuild `rings.png` exactly.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RingPattern {
    /// The image.
    pub pattern: PatternSection,
    /// The rings, innermost first.
    pub ring: Vec<Ring>,
}

impl RingPattern {
    /// The default design for a `width × height` projector centred on `center`: rings every
    /// 8 px from a tenth of the inscribed radius to 95 % of it, Gaussian profile of σ = 1.2 px,
    /// full intensity, ring k with k + 3 periods per turn (every ring its own frequency; at
    /// least 3 so each ring's phase is measurable), and phases a golden angle apart, so that
    /// no azimuth finds all rings at their crest together (there, rings would look alike).
    pub fn design(width: u32, height: u32, center: [f64; 2]) -> Result<RingPattern> {
        let inscribed = center[0]
            .min(center[1])
            .min(f64::from(width) - 1.0 - center[0])
            .min(f64::from(height) - 1.0 - center[1]);
        if !(inscribed.is_finite() && inscribed >= 40.0) {
            return Err(Error::invalid(
                "ring pattern",
                "center",
                format!(
                    "({}, {}) leaves {inscribed:.1} px to the nearest edge of {width}x{height}; rings need at least 40",
                    center[0], center[1]
                ),
            ));
        }
        let (first, last, step) = (0.1 * inscribed, 0.95 * inscribed, 8.0);
        let n = ((last - first) / step).floor() as usize + 1;
        Ok(RingPattern {
            pattern: PatternSection {
                width,
                height,
                center,
                profile: Profile::Gaussian,
            },
            ring: (0..n)
                .map(|k| Ring {
                    radius: first + step * k as f64,
                    width: 1.2,
                    frequency: k as u32 + 3,
                    phase: (k as f64 * GOLDEN_ANGLE).rem_euclid(std::f64::consts::TAU),
                    intensity: 1.0,
                })
                .collect(),
        })
    }

    /// The pattern's value (0 … 1, clipped) at projector pixel (u, v).
    pub fn value(&self, u: f64, v: f64) -> f64 {
        let (dx, dy) = (u - self.pattern.center[0], v - self.pattern.center[1]);
        let (rho, theta) = ((dx * dx + dy * dy).sqrt(), dy.atan2(dx));
        let mut sum = 0.0;
        for r in &self.ring {
            let x = (rho - r.radius) / r.width;
            let g = match self.pattern.profile {
                Profile::Gaussian if x.abs() < 6.0 => (-0.5 * x * x).exp(),
                Profile::Box if x.abs() <= 0.5 => 1.0,
                _ => continue,
            };
            sum += r.intensity * g * 0.5 * (1.0 + (f64::from(r.frequency) * theta + r.phase).cos());
        }
        sum.clamp(0.0, 1.0)
    }

    /// The 8-bit image, row-major (value · 255, rounded).
    pub fn render(&self) -> Vec<u8> {
        use rayon::prelude::*;
        let (w, h) = (self.pattern.width as usize, self.pattern.height as usize);
        let mut out = vec![0u8; w * h];
        out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, o) in row.iter_mut().enumerate() {
                *o = (255.0 * self.value(x as f64, y as f64)).round() as u8;
            }
        });
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_ring_has_its_own_frequency_and_lies_inside_the_image() {
        let p = RingPattern::design(1024, 768, [511.5, 383.5]).expect("design");
        assert!(p.ring.len() > 20);
        let mut f: Vec<u32> = p.ring.iter().map(|r| r.frequency).collect();
        f.dedup();
        assert_eq!(f.len(), p.ring.len());
        let last = p.ring.last().expect("ring");
        assert!(last.radius + 4.0 * last.width < 383.5);
        // On a ring the intensity follows its cosine: peak where f θ + phase = 0, zero half a
        // period on.
        let r = &p.ring[4];
        let (cx, cy) = (511.5, 383.5);
        let crest = -r.phase / f64::from(r.frequency);
        let (u, v) = (cx + r.radius * crest.cos(), cy + r.radius * crest.sin());
        assert!((p.value(u, v) - 1.0).abs() < 0.02);
        let half = crest + std::f64::consts::PI / f64::from(r.frequency);
        let (u, v) = (cx + r.radius * half.cos(), cy + r.radius * half.sin());
        assert!(p.value(u, v) < 0.02, "{}", p.value(u, v));
        assert!(RingPattern::design(100, 100, [10.0, 50.0]).is_err());
    }
}
