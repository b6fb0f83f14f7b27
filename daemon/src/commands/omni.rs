//! `ris omni --analyse`: the omnidirectional sensor's resolution and depth error (Sec. 6.3) for
//! wall points at given ranges and heights.

use std::path::Path;

use anyhow::{Context, Result};
use ris_core::omni::{analyse, ErrorPoint, OmniSensor};

/// Analyse the sensor file at `sensor` for `ranges` × `heights` (mm).
pub fn analyse_file(sensor: &Path, ranges: &[f64], heights: &[f64]) -> Result<Vec<ErrorPoint>> {
    anyhow::ensure!(
        !ranges.is_empty() && ranges.iter().all(|r| r.is_finite() && *r > 0.0),
        "--ranges: positive distances in mm"
    );
    anyhow::ensure!(
        !heights.is_empty() && heights.iter().all(|h| h.is_finite()),
        "--heights: heights in mm"
    );
    let s = OmniSensor::load(sensor)
        .with_context(|| format!("reading sensor file {}", sensor.display()))?;
    analyse(&s, ranges, heights).with_context(|| format!("analysing {}", sensor.display()))
}

/// Heights FROM,TO,STEP (mm) as a list.
pub fn heights(spec: &str) -> Result<Vec<f64>> {
    let v: Vec<f64> = spec
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .with_context(|| format!("--heights {spec:?}: expected FROM,TO,STEP in mm"))?;
    let [from, to, step] = v[..] else {
        anyhow::bail!("--heights {spec:?}: expected FROM,TO,STEP in mm");
    };
    anyhow::ensure!(
        from.is_finite()
            && to.is_finite()
            && step.is_finite()
            && step > 0.0
            && (to - from) / step <= 10_000.0,
        "--heights {spec:?}: a positive STEP and at most 10000 heights"
    );
    let n = ((to - from) / step).floor().max(0.0) as usize;
    Ok((0..=n).map(|k| from + k as f64 * step).collect())
}

/// The analysis as a table.
pub fn print(points: &[ErrorPoint]) {
    println!(
        "{:>8} {:>8} {:>9} {:>9} | {:>10} {:>10} | {:>10} {:>10} {:>10}",
        "range", "height", "elev.", "radius", "camera", "projector", "Δd cam", "Δd proj", "Δd"
    );
    println!(
        "{:>8} {:>8} {:>9} {:>9} | {:>10} {:>10} | {:>10} {:>10} {:>10}",
        "mm", "mm", "deg", "px", "mm/px", "mm/px", "mm", "mm", "mm"
    );
    for p in points {
        println!(
            "{:>8.0} {:>8.0} {:>9.1} {:>9.1} | {:>10.1} {:>10.1} | {:>10.1} {:>10.1} {:>10.1}",
            p.range_mm,
            p.height_mm,
            p.elevation_deg,
            p.camera_radius_px,
            p.camera_mm_per_px,
            p.projector_mm_per_px,
            p.depth_error_camera_mm,
            p.depth_error_projector_mm,
            p.depth_error_mm
        );
    }
}
