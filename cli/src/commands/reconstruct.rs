//! `ris reconstruct`: sensor file + capture set → binary PLY in the sensor world frame.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use ris_core::capture::CaptureSet;
use ris_core::cloud::PointCloud;
use ris_core::decode::{decode, DecodeParams};
use ris_core::sensor::{ModelChoice, Reconstructor, Sensor};

/// Reconstruct `capture` with `sensor` and write `out` (PLY); returns the cloud. Points outside
/// the sensor's calibrated volume are counted and flagged (`outside_volume`), or left out with
/// `drop_outside`.
pub fn run(
    sensor: &Path,
    capture: &Path,
    model: ModelChoice,
    params: &DecodeParams,
    drop_outside: bool,
    out: &Path,
) -> Result<PointCloud> {
    let s = Sensor::load(sensor)
        .with_context(|| format!("reading sensor file {}", sensor.display()))?;
    let t = Instant::now();
    let rec = Reconstructor::new(&s, model, params)
        .with_context(|| format!("preparing sensor {}", sensor.display()))?;
    let prepare = t.elapsed();
    let set = CaptureSet::load(capture)
        .with_context(|| format!("reading capture set {}", capture.display()))?;
    let t = Instant::now();
    let decoded =
        decode(&set, params).with_context(|| format!("decoding {}", capture.display()))?;
    let t_decode = t.elapsed();
    let t = Instant::now();
    let mut cloud = rec
        .reconstruct(&decoded)
        .with_context(|| format!("reconstructing {}", capture.display()))?;
    let t_rec = t.elapsed();
    let outside = cloud.outside_count();
    if drop_outside {
        cloud.drop_outside();
    }
    let volume = match (&rec.volume, drop_outside) {
        (None, _) => "the sensor file states no calibrated volume".to_string(),
        (Some(_), false) => {
            format!("{outside} outside the calibrated volume (flagged `outside_volume`)")
        }
        (Some(_), true) => format!("{outside} outside the calibrated volume left out"),
    };
    if outside > 0 {
        tracing::warn!(outside, "points outside the calibrated volume");
    }
    let not_finite = cloud.retain_finite();
    anyhow::ensure!(
        !cloud.is_empty(),
        "{}: no points reconstructed ({} of {} pixels decoded{}{}): nothing written",
        capture.display(),
        decoded.valid_count(),
        decoded.col.len(),
        if not_finite > 0 {
            format!("; {not_finite} points NaN or infinite, is the sensor file's model sound?")
        } else {
            String::new()
        },
        if drop_outside && outside > 0 {
            format!("; {outside} outside the calibrated volume left out")
        } else {
            String::new()
        }
    );
    cloud
        .write_ply(out)
        .with_context(|| format!("writing {}", out.display()))?;
    println!(
        "{} points ({} model; {volume}) from {} valid of {} pixels; prepare {:.0} ms, decode {:.0} ms, reconstruct {:.0} ms; wrote {}",
        cloud.len(),
        rec.model_name(),
        decoded.valid_count(),
        decoded.col.len(),
        prepare.as_secs_f64() * 1e3,
        t_decode.as_secs_f64() * 1e3,
        t_rec.as_secs_f64() * 1e3,
        out.display()
    );
    Ok(cloud)
}
