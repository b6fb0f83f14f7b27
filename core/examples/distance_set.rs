//! Writes the distance bench's data as files, to time `ris inspect --pose known` beside a
//! distance tool (CloudCompare's `-C2M_DIST`) on them: a curved 1000 × 800 mm panel of
//! 482 162 triangles (`panel.stl`) and 200 000 points within ±2 mm of it (`scan.ply`).
//! `cargo run --profile ci -p ris-core --example distance_set -- DIR`.

use ris_core::cloud::PointCloud;
use ris_core::mesh::TriangleMesh;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::path::PathBuf::from(std::env::args().nth(1).ok_or("give an output directory")?);
    std::fs::create_dir_all(&dir)?;
    let surface = |x: f64, y: f64| 60.0 * (x / 400.0).sin() * (y / 300.0).cos();
    let mesh = TriangleMesh::height_field(491, 491, (-500.0, 500.0), (-400.0, 400.0), surface);
    ris_core::mesh::stl::write_binary(&dir.join("panel.stl"), &mesh)?;
    // Uniform positions over the panel (xorshift), ±2 mm off it.
    let mut state = 9u64;
    let mut u = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut cloud = PointCloud::default();
    for _ in 0..200_000 {
        let (x, y) = (-480.0 + 960.0 * u(), -380.0 + 760.0 * u());
        let z = surface(x, y) + 4.0 * (u() - 0.5);
        cloud.points.push([x as f32, y as f32, z as f32]);
        cloud.confidence.push(1.0);
    }
    cloud.write_ply(&dir.join("scan.ply"))?;
    Ok(())
}
