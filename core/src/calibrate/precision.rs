//! Sensor precision (Ch. 3.1.3, Eq. 3.4–3.6): the same scene measured n times; the per-pixel
//! standard deviation of the height, and its mean over the image as the sensor's figure.

use std::path::Path;

use rayon::prelude::*;
use serde::Serialize;

use crate::decode::hue_to_rgb;
use crate::image::save_rgb_png;
use crate::{Error, Result};

/// Precision of repeated measurements.
#[derive(Clone, Debug, Serialize)]
pub struct Precision {
    /// Measurements compared.
    pub measurements: usize,
    /// Pixels measured in every one of them.
    pub pixels: usize,
    /// The sensor figure: mean per-pixel standard deviation (Eq. 3.6), mm.
    pub figure: f64,
    /// Median per-pixel standard deviation, mm.
    pub median: f64,
    /// 95th percentile, mm.
    pub p95: f64,
    /// Per-pixel standard deviation (Eq. 3.5), mm; NaN where a measurement lacks the pixel.
    #[serde(skip)]
    pub std: Vec<f32>,
}

/// Per-pixel standard deviation of `heights` (each a dense map of the same size, NaN = missing)
/// about their per-pixel mean (Eq. 3.4–3.5, population form), over pixels present in all.
pub fn precision(heights: &[Vec<f32>]) -> Result<Precision> {
    let n = heights.len();
    if n < 2 {
        return Err(Error::Insufficient(format!(
            "precision needs at least two measurements of the same scene, got {n}"
        )));
    }
    let len = heights[0].len();
    if heights.iter().any(|h| h.len() != len) {
        return Err(Error::Insufficient(
            "the measurements have different image sizes".into(),
        ));
    }
    let std: Vec<f32> = (0..len)
        .into_par_iter()
        .map(|i| {
            let mut sum = 0.0f64;
            for h in heights {
                let v = h[i];
                if !v.is_finite() {
                    return f32::NAN;
                }
                sum += f64::from(v);
            }
            let mean = sum / n as f64;
            let var = heights
                .iter()
                .map(|h| (f64::from(h[i]) - mean).powi(2))
                .sum::<f64>()
                / n as f64;
            var.sqrt() as f32
        })
        .collect();
    let mut valid: Vec<f32> = std.iter().copied().filter(|v| v.is_finite()).collect();
    if valid.is_empty() {
        return Err(Error::Insufficient(
            "no pixel was measured in every capture".into(),
        ));
    }
    let figure = valid.iter().map(|&v| f64::from(v)).sum::<f64>() / valid.len() as f64;
    valid.sort_by(f32::total_cmp);
    let at = |q: f64| f64::from(valid[((valid.len() - 1) as f64 * q) as usize]);
    Ok(Precision {
        measurements: n,
        pixels: valid.len(),
        figure,
        median: at(0.5),
        p95: at(0.95),
        std,
    })
}

impl Precision {
    /// Heat map of the per-pixel deviation (blue 0 → red at `scale` mm and above, black where
    /// unmeasured), written atomically as PNG.
    pub fn write_heat_map(&self, path: &Path, width: u32, height: u32, scale: f64) -> Result<()> {
        if self.std.len() != (width * height) as usize {
            return Err(Error::invalid(
                path.display(),
                "size",
                format!("{width}x{height} does not match {} pixels", self.std.len()),
            ));
        }
        let rgb: Vec<u8> = self
            .std
            .iter()
            .flat_map(|&s| {
                if s.is_finite() {
                    hue_to_rgb((f64::from(s) / scale) as f32, 1.0)
                } else {
                    [0, 0, 0]
                }
            })
            .collect();
        save_rgb_png(path, width, height, &rgb)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn standard_deviation_per_pixel_and_figure() {
        // Pixel 0: 1, 2, 3 (σ = √(2/3)); pixel 1: constant; pixel 2: one measurement missing.
        let h = vec![
            vec![1.0, 5.0, 1.0],
            vec![2.0, 5.0, f32::NAN],
            vec![3.0, 5.0, 1.0],
        ];
        let p = precision(&h).expect("precision");
        assert_eq!(p.pixels, 2);
        assert!((p.std[0] - (2.0f32 / 3.0).sqrt()).abs() < 1e-6);
        assert_eq!(p.std[1], 0.0);
        assert!(p.std[2].is_nan());
        assert!((p.figure - (2.0f64 / 3.0).sqrt() / 2.0).abs() < 1e-6);
        assert!(precision(&h[..1]).is_err());
    }
}
