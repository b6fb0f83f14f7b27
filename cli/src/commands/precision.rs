//! `ris precision`: repeated captures of one scene → per-pixel height standard deviation, the
//! sensor figure (Eq. 3.4–3.6) and a heat map.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use ris_core::calibrate::{precision, Precision};
use ris_core::capture::CaptureSet;
use ris_core::decode::{decode, DecodeParams};
use ris_core::sensor::{ModelChoice, Reconstructor, Sensor};

/// Reconstruct every capture with `sensor`, compare the heights per pixel, print the figure and
/// write the heat map `out` (colour scale 0..`scale` mm; default three times the figure).
pub fn run(
    sensor: &Path,
    captures: &[PathBuf],
    params: &DecodeParams,
    out: &Path,
    scale: Option<f64>,
) -> Result<Precision> {
    anyhow::ensure!(
        captures.len() >= 2,
        "give at least two captures of the same scene (got {})",
        captures.len()
    );
    let s = Sensor::load(sensor)
        .with_context(|| format!("reading sensor file {}", sensor.display()))?;
    let rec = Reconstructor::new(&s, ModelChoice::Auto, params)
        .with_context(|| format!("preparing sensor {}", sensor.display()))?;
    let (w, h) = (s.camera.width, s.camera.height);
    let bar = crate::progress::bar(captures.len() as u64, "captures");
    let mut heights = Vec::with_capacity(captures.len());
    for c in captures {
        let set =
            CaptureSet::load(c).with_context(|| format!("reading capture set {}", c.display()))?;
        let decoded = decode(&set, params).with_context(|| format!("decoding {}", c.display()))?;
        let cloud = rec
            .reconstruct(&decoded)
            .with_context(|| format!("reconstructing {}", c.display()))?;
        let mut z = vec![f32::NAN; (w * h) as usize];
        for (p, &px) in cloud.points.iter().zip(&cloud.pixels) {
            z[px as usize] = p[2];
        }
        heights.push(z);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let p = precision(&heights)?;
    let scale = scale.unwrap_or(3.0 * p.figure).max(1e-6);
    anyhow::ensure!(
        scale.is_finite(),
        "--scale must be a positive number of millimetres"
    );
    p.write_heat_map(out, w, h, scale)
        .with_context(|| format!("writing {}", out.display()))?;
    println!(
        "precision over {} captures: sensor figure {:.4} mm (mean per-pixel σ over {} pixels), median {:.4} mm, 95th percentile {:.4} mm; heat map 0..{:.3} mm: {}",
        p.measurements,
        p.figure,
        p.pixels,
        p.median,
        p.p95,
        scale,
        out.display()
    );
    Ok(p)
}
