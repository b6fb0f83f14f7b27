//! Simulate → decode → reconstruct, checked against the simulator's ground truth.

use std::path::Path;

use ris_core::decode::{decode, DecodeParams};
use ris_core::sensor::Reconstructor;
use ris_core::sim::accuracy::evaluate;
use ris_core::sim::{Scene, Simulator};

fn demo_scene() -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/demo.toml");
    Scene::load(&path).expect("demo scene")
}

#[test]
fn demo_scene_parallax_accuracy() {
    let scene = demo_scene();
    let t0 = std::time::Instant::now();
    let sim = Simulator::new(scene.clone());
    let layout = sim.layout();
    let capture = sim.capture(&layout, 0, &|_, _| {});
    let reference = Simulator::new(scene.reference()).capture(&layout, 1000, &|_, _| {});
    eprintln!("render {:?}", t0.elapsed());
    let mut params = DecodeParams::default();
    if let Ok(v) = std::env::var("RIS_WINDOW") {
        params.edge_window = v.parse().expect("window");
    }
    if let Ok(v) = std::env::var("RIS_CELLTOL") {
        params.cell_tolerance = v.parse().expect("tol");
    }
    if std::env::var("RIS_EXTRAP").is_ok() {
        params.extrapolate = true;
    }
    if let Ok(v) = std::env::var("RIS_EROSION") {
        params.edge_erosion = v.parse().expect("erosion");
    }
    if let Ok(v) = std::env::var("RIS_POWER") {
        params.albedo_weight_power = v.parse().expect("power");
    }
    let dec = decode(&capture, &params).expect("decode");
    let dec_ref = decode(&reference, &params).expect("decode ref");
    let rec =
        Reconstructor::parallax(&scene.camera, scene.projector.center(), &dec_ref).expect("model");
    let cloud = rec.reconstruct(&dec).expect("reconstruct");
    let acc = evaluate(&cloud, &sim.cache.truth, 0.999);
    eprintln!("parallax: {acc}");
    let rec_c = Reconstructor::classical(&scene.camera, &scene.projector);
    let acc_c = evaluate(
        &rec_c.reconstruct(&dec).expect("classical"),
        &sim.cache.truth,
        0.999,
    );
    eprintln!("classical: {acc_c}");
    assert!(acc.completeness >= 0.97, "{acc}");
    assert!(acc.mean_abs_error_mm <= 0.06, "{acc}");
    assert!(acc.rms_error_mm <= 0.10, "{acc}");
    assert!(acc.outlier_fraction <= 0.005, "{acc}");
}

/// Diagnostic dump for error analysis: `RIS_DUMP=dir cargo test ... dump -- --ignored`.
#[test]
#[ignore = "diagnostic: writes error maps to $RIS_DUMP"]
fn dump() {
    let Ok(dir) = std::env::var("RIS_DUMP") else {
        return;
    };
    let dir = Path::new(&dir);
    let scene = demo_scene();
    let sim = Simulator::new(scene.clone());
    let layout = sim.layout();
    let capture = sim.capture(&layout, 0, &|_, _| {});
    let reference = Simulator::new(scene.reference()).capture(&layout, 1000, &|_, _| {});
    let mut params = DecodeParams::default();
    if let Ok(v) = std::env::var("RIS_EROSION") {
        params.edge_erosion = v.parse().expect("erosion");
    }
    let dec = decode(&capture, &params).expect("decode");
    let dec_ref = decode(&reference, &params).expect("decode ref");
    dec.save(&dir.join("dec")).expect("save");
    dec_ref.save(&dir.join("ref")).expect("save");
    let rec =
        Reconstructor::parallax(&scene.camera, scene.projector.center(), &dec_ref).expect("model");
    let cloud = rec.reconstruct(&dec).expect("reconstruct");
    let mut dense = vec![f32::NAN; dec.col.len() * 3];
    for (p, &i) in cloud.points.iter().zip(&cloud.pixels) {
        dense[i as usize * 3..i as usize * 3 + 3].copy_from_slice(p);
    }
    ris_core::io::npy::write(&dir.join("points.npy"), &[600, 800, 3], &dense).expect("w");
    ris_core::sim::write_truth(&sim.cache.truth, &scene, &dir.join("truth")).expect("truth");
    // Projector truth: project the true point into the projector.
    let mut pcol = vec![f32::NAN; dec.col.len()];
    for (i, t) in sim.cache.truth.xyz.iter().enumerate() {
        if t[0].is_finite() {
            let p = ris_core::geometry::Vec3::new(t[0].into(), t[1].into(), t[2].into());
            if let Some((u, _)) = scene.projector.project(&p) {
                pcol[i] = u as f32;
            }
        }
    }
    ris_core::io::npy::write(&dir.join("true_col.npy"), &[600, 800], &pcol).expect("w");
}
