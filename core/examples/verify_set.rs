//! Writes the seeded acceptance set of `ris_core::verify::synthetic` (the verify bench's) as
//! PLY files and its artefacts file into a directory, to time `ris verify` on it:
//! `cargo run --profile ci -p ris-core --example verify_set -- DIR`.

use ris_core::cloud::PointCloud;
use ris_core::verify::synthetic::{acceptance_set, artefacts};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::path::PathBuf::from(std::env::args().nth(1).ok_or("give an output directory")?);
    std::fs::create_dir_all(&dir)?;
    let (bars, planes, spheres) = acceptance_set(2634, 0.008, 1.0);
    for c in bars.iter().chain(&planes).chain(&spheres) {
        let cloud = PointCloud {
            points: c
                .points
                .iter()
                .map(|p| [p.x as f32, p.y as f32, p.z as f32])
                .collect(),
            confidence: vec![1.0; c.points.len()],
            ..PointCloud::default()
        };
        cloud.write_ply(&dir.join(&c.name))?;
    }
    ris_core::io::write_toml(&dir.join("artefacts.toml"), &artefacts())?;
    Ok(())
}
