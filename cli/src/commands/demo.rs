//! `ris demo`: one sensor pair end to end: simulate the built-in scene, reconstruct it
//! with the parallax model, write the cloud and an accuracy summary against ground truth.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use ris_core::decode::{decode, DecodeParams};
use ris_core::sensor::{ModelChoice, Reconstructor, Sensor};
use ris_core::sim::accuracy::{evaluate, Accuracy};
use ris_core::sim::{Scene, Simulator};

use crate::commands::simulate;

/// The built-in demo scene (config/scenes/demo.toml).
pub const DEMO_SCENE: &str = include_str!("../../../config/scenes/demo.toml");

/// Paths and figures of a demo run.
pub struct DemoResult {
    /// The reconstructed cloud.
    pub cloud: PathBuf,
    /// The accuracy summary (JSON).
    pub summary: PathBuf,
    /// The figures.
    pub accuracy: Accuracy,
}

/// Run the demo into `out` (which must not exist or be empty), using `scene` or the built-in one.
pub fn run(scene: Option<&Path>, out: &Path) -> Result<DemoResult> {
    let scene_path = match scene {
        Some(p) => p.to_path_buf(),
        None => {
            std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
            let p = out.join("scene.toml");
            std::fs::write(&p, DEMO_SCENE).with_context(|| format!("writing {}", p.display()))?;
            p
        }
    };
    let sim_dir = out.join("sim");
    let simulate::Simulated::Scene(o) = simulate::run(&scene_path, &sim_dir, None)? else {
        anyhow::bail!(
            "{}: a calibration-session scene cannot be demonstrated; give an object scene",
            scene_path.display()
        );
    };
    let t = Instant::now();
    let params = DecodeParams::default();
    let sensor = Sensor::load(&o.sensor)?;
    let rec = Reconstructor::new(&sensor, ModelChoice::Parallax, &params)?;
    let set = ris_core::capture::CaptureSet::load(&o.capture)?;
    let decoded = decode(&set, &params)?;
    let cloud = rec.reconstruct(&decoded)?;
    let elapsed = t.elapsed();
    let cloud_path = out.join("cloud.ply");
    cloud
        .write_ply(&cloud_path)
        .with_context(|| format!("writing {}", cloud_path.display()))?;
    // Ground truth comes from the same scene, ray-cast again (cheap) rather than re-read.
    let s = Scene::load(&scene_path)?;
    let truth = Simulator::new(s).cache.truth;
    let accuracy = evaluate(&cloud, &truth, 0.999);
    let summary = out.join("accuracy.json");
    let json = serde_json::to_string_pretty(&accuracy)?;
    ris_core::io::write_atomic(&summary, json.as_bytes())?;
    println!(
        "reconstructed {} points in {:.2} s (reference fit, decode, parallax model)",
        cloud.len(),
        elapsed.as_secs_f64()
    );
    println!("accuracy against ground truth: {accuracy}");
    println!("wrote {} and {}", cloud_path.display(), summary.display());
    Ok(DemoResult {
        cloud: cloud_path,
        summary,
        accuracy,
    })
}
