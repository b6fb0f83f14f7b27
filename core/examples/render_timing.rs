//! Time the simulator: the render cache of a scene and its full capture (`ris simulate`'s
//! work without the files), for the scene given as the first argument.
fn main() {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "config/scenes/session-objects.toml".into());
    let scene = ris_core::sim::Scene::load(std::path::Path::new(&path)).expect("scene");
    for _ in 0..3 {
        let t = std::time::Instant::now();
        let sim = ris_core::sim::Simulator::new(scene.clone());
        let built = t.elapsed();
        let capture = sim.capture(&sim.layout(), 0, &|_, _| {});
        let sum: u64 = capture
            .frames
            .values()
            .map(|f| f.to_u16().iter().map(|&v| u64::from(v)).sum::<u64>())
            .sum();
        println!(
            "cache {:.3} s, capture of {} frames {:.3} s (checksum {sum})",
            built.as_secs_f64(),
            capture.frames.len(),
            (t.elapsed() - built).as_secs_f64()
        );
    }
}
