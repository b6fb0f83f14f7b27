//! `ris calibrate`: relating sensors to the cell frame.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use ris_core::calibrate::{fit_gauge, overlap_consistency, Gauge, GaugeFit, GaugeParams};
use ris_core::cloud::PointCloud;
use ris_core::io::{read_toml, write_atomic};
use ris_core::sensor::{SensorFile, ToCommonSection};

use super::parse_sensor_cloud;

/// `ris calibrate cell`: fit every sensor's measurement of the marker gauge, and only when all
/// of them pass, write each sensor file's `[to_common]` (atomically) and, if asked, a JSON
/// report. Returns the fits in input order.
pub fn cell(
    gauge_path: &Path,
    inputs: &[String],
    params: &GaugeParams,
    report: Option<&Path>,
) -> Result<Vec<GaugeFit>> {
    let gauge = Gauge::load(gauge_path)
        .with_context(|| format!("reading gauge {}", gauge_path.display()))?;
    anyhow::ensure!(
        !inputs.is_empty(),
        "give at least one SENSOR.toml:CLOUD.ply"
    );
    let mut fits = Vec::new();
    let mut files: Vec<(PathBuf, SensorFile)> = Vec::new();
    for arg in inputs {
        let (sensor, cloud) = parse_sensor_cloud(arg)?;
        let file: SensorFile = read_toml(&sensor)
            .with_context(|| format!("reading sensor file {}", sensor.display()))?;
        let c =
            PointCloud::read_ply(&cloud).with_context(|| format!("reading {}", cloud.display()))?;
        let fit = fit_gauge(&c, &gauge, params)
            .with_context(|| format!("{arg}: gauge fit failed; no sensor file was changed"))?;
        println!(
            "{arg}: {} markers ({} matched, {} clusters rejected), centre RMS {:.3} mm, max {:.3} mm",
            fit.markers.len(),
            fit.matched,
            fit.rejected.len(),
            fit.rms,
            fit.max
        );
        for r in &fit.rejected {
            tracing::debug!(sensor = %arg, centroid = ?r.centroid, points = r.points, reason = %r.reason, "cluster rejected");
        }
        fits.push(fit);
        files.push((sensor, file));
    }
    let checks = overlap_consistency(&fits);
    for c in &checks {
        println!(
            "overlap {} / {}: {} shared markers, centre agreement RMS {:.3} mm",
            inputs[c.sensors.0], inputs[c.sensors.1], c.shared, c.rms
        );
    }
    for ((path, mut file), fit) in files.into_iter().zip(&fits) {
        let m = fit.to_common.to_homogeneous();
        file.to_common = Some(ToCommonSection {
            matrix: std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)])),
        });
        file.save(&path)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote [to_common] of {}", path.display());
    }
    if let Some(report) = report {
        let json = serde_json::json!({
            "gauge": gauge_path.display().to_string(),
            "sensors": inputs.iter().zip(&fits).map(|(arg, f)| serde_json::json!({
                "input": arg,
                "to_common": (0..4).map(|i| (0..4).map(|j| f.to_common.to_homogeneous()[(i, j)]).collect::<Vec<_>>()).collect::<Vec<_>>(),
                "matched": f.matched,
                "rms_mm": f.rms,
                "max_mm": f.max,
                "markers": f.markers,
                "rejected": f.rejected,
            })).collect::<Vec<_>>(),
            "overlaps": checks.iter().map(|c| serde_json::json!({
                "sensors": [inputs[c.sensors.0].clone(), inputs[c.sensors.1].clone()],
                "shared": c.shared,
                "rms_mm": c.rms,
            })).collect::<Vec<_>>(),
        });
        write_atomic(report, serde_json::to_string_pretty(&json)?.as_bytes())
            .with_context(|| format!("writing {}", report.display()))?;
        println!("wrote {}", report.display());
    }
    Ok(fits)
}
