//! Shared fixture of the benchmarks: the demo scene seen by a 2048x2048 camera.

use std::path::Path;

use ris_core::capture::CaptureSet;
use ris_core::sim::{Scene, SceneFile, Simulator};

/// The demo scene with a 2 k × 2 k camera (same field of view), rendered with one sample per
/// pixel (decoding speed does not depend on footprint anti-aliasing).
pub fn scene_2k() -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/demo.toml");
    let text = std::fs::read_to_string(&path).expect("demo scene");
    let mut file: SceneFile = toml::from_str(&text).expect("parse");
    let s = 2048.0 / 800.0;
    file.camera.width = 2048;
    file.camera.height = 2048;
    file.camera.k = [
        [1778.0 * s, 0.0, 1023.5],
        [0.0, 1778.0 * s, 1023.5],
        [0.0, 0.0, 1.0],
    ];
    file.render.supersample = 1;
    Scene::from_file(file, path.parent().expect("dir"), "bench scene").expect("scene")
}

/// Capture (42 frames) and reference capture of [`scene_2k`].
pub fn captures_2k() -> (Scene, CaptureSet, CaptureSet) {
    let scene = scene_2k();
    let sim = Simulator::new(scene.clone());
    let layout = sim.layout();
    let capture = sim.capture(&layout, 0, &|_, _| {});
    let reference = Simulator::new(scene.reference()).capture(&layout, 100, &|_, _| {});
    (scene, capture, reference)
}
