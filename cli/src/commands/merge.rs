//! `ris merge`: sensor clouds into the cell frame, overlaps de-duplicated by confidence.

use std::path::Path;

use anyhow::{bail, Context, Result};
use ris_core::cloud::{merge, PointCloud};
use ris_core::sensor::Sensor;

/// Merge `inputs` (each `SENSOR.toml:CLOUD.ply`) with duplicate `radius` mm into `out`.
pub fn run(inputs: &[String], radius: f64, out: &Path) -> Result<PointCloud> {
    anyhow::ensure!(
        radius.is_finite() && radius >= 0.0,
        "--radius must be a finite number ≥ 0, got {radius}"
    );
    let mut clouds = Vec::new();
    for arg in inputs {
        let (sensor, cloud) = super::parse_sensor_cloud(arg)?;
        let s = Sensor::load(&sensor)
            .with_context(|| format!("reading sensor file {}", sensor.display()))?;
        let Some(m) = s.to_common else {
            bail!(
                "{}: no [to_common] transform; calibrate the cell (ris calibrate cell) first",
                sensor.display()
            );
        };
        let c =
            PointCloud::read_ply(&cloud).with_context(|| format!("reading {}", cloud.display()))?;
        clouds.push((c, m));
    }
    anyhow::ensure!(
        !clouds.is_empty(),
        "give at least one SENSOR.toml:CLOUD.ply"
    );
    let (merged, stats) = merge(&clouds, radius);
    merged
        .write_ply(out)
        .with_context(|| format!("writing {}", out.display()))?;
    for (i, arg) in inputs.iter().enumerate() {
        println!(
            "{arg}: {} points kept, {} overlap duplicates dropped",
            stats.kept[i], stats.dropped[i]
        );
    }
    println!(
        "merged {} points into the cell frame; wrote {}",
        merged.len(),
        out.display()
    );
    Ok(merged)
}
