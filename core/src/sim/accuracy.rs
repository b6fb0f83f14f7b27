//! Accuracy of a reconstruction against simulator ground truth, per camera pixel.

use serde::Serialize;

use super::Truth;
use crate::cloud::PointCloud;

/// Figures of merit of one reconstruction (SPEC/issue acceptance quantities).
#[derive(Clone, Debug, Serialize)]
pub struct Accuracy {
    /// Pixels fully lit by the projector with a surface behind them.
    pub lit_pixels: usize,
    /// Of those, pixels with a reconstructed point.
    pub reconstructed_lit: usize,
    /// reconstructed_lit / lit_pixels.
    pub completeness: f64,
    /// Points compared (every point with truth at its pixel).
    pub points: usize,
    /// Mean 3D distance to the true surface point of the same pixel, mm.
    pub mean_abs_error_mm: f64,
    /// RMS of that distance, mm.
    pub rms_error_mm: f64,
    /// Fraction of points off by more than 1 mm.
    pub outlier_fraction: f64,
    /// Largest error, mm.
    pub max_error_mm: f64,
}

/// Compare `cloud` (organised: `pixels` set) with `truth`. A pixel counts as lit when all its
/// sub-samples are lit (`lit_threshold` = 0.999 by default in callers).
pub fn evaluate(cloud: &PointCloud, truth: &Truth, lit_threshold: f32) -> Accuracy {
    evaluate_where(cloud, truth, lit_threshold, |_| true)
}

/// [`evaluate`] restricted to the camera pixels `keep` accepts (e.g. one material's).
pub fn evaluate_where(
    cloud: &PointCloud,
    truth: &Truth,
    lit_threshold: f32,
    keep: impl Fn(usize) -> bool,
) -> Accuracy {
    let lit = |i: usize| truth.lit[i] >= lit_threshold && truth.xyz[i][0].is_finite() && keep(i);
    let lit_pixels = (0..truth.lit.len()).filter(|&i| lit(i)).count();
    let mut reconstructed_lit = 0;
    let (mut n, mut sum, mut sum2, mut outliers, mut max) =
        (0usize, 0.0f64, 0.0f64, 0usize, 0.0f64);
    for (p, &px) in cloud.points.iter().zip(&cloud.pixels) {
        let i = px as usize;
        if !keep(i) {
            continue;
        }
        let t = truth.xyz[i];
        if !t[0].is_finite() {
            outliers += 1;
            n += 1;
            continue;
        }
        if lit(i) {
            reconstructed_lit += 1;
        }
        let e = (0..3)
            .map(|k| f64::from(p[k] - t[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        n += 1;
        sum += e;
        sum2 += e * e;
        max = max.max(e);
        outliers += usize::from(e > 1.0);
    }
    let nf = n.max(1) as f64;
    Accuracy {
        lit_pixels,
        reconstructed_lit,
        completeness: reconstructed_lit as f64 / lit_pixels.max(1) as f64,
        points: n,
        mean_abs_error_mm: sum / nf,
        rms_error_mm: (sum2 / nf).sqrt(),
        outlier_fraction: outliers as f64 / nf,
        max_error_mm: max,
    }
}

impl std::fmt::Display for Accuracy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "completeness {:.2} % of {} lit pixels, {} points, mean |error| {:.4} mm, RMS {:.4} mm, > 1 mm {:.3} %, max {:.2} mm",
            100.0 * self.completeness,
            self.lit_pixels,
            self.points,
            self.mean_abs_error_mm,
            self.rms_error_mm,
            100.0 * self.outlier_fraction,
            self.max_error_mm
        )
    }
}
