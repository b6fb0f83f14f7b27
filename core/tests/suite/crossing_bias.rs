//! The crossing's phase bias (issue 41): flat surfaces at seeded heights and tilts
//! through the demo sensor's view, under seeded projector blurs, with and without texture,
//! decoded with the default settings and compared pixel by pixel with the projector
//! coordinate the simulator's truth gives each pixel.
//!
//! Without the correction the linear crossing of pattern and inverse is off by a periodic
//! function of where each edge falls between two camera pixels; where the projector's pixels
//! image at nearly a whole number of camera pixels the line fit cannot average it out, and the
//! coordinates carry a moiré of the two pixel grids, correlated over tens of pixels (which no
//! smoothing removes and which scatters a small sphere's fitted size). Each capture measures
//! its own bias, so the test plants none: it varies the optics the bias depends on.

use crate::common;

use std::path::Path;

use common::Rng;

use ris_core::decode::{decode, DecodeParams};
use ris_core::geometry::Vec3;
use ris_core::sim::{Scene, SceneFile, Simulator};

/// The demo sensor with projector blur `blur`, over a flat of `material` through (0, 0, `z`)
/// (mm) whose normal is tilted by `tilt` (degrees about x and y): the cap of a sphere of 50 m
/// radius, flat to 1.3 µm over the view, and traced exactly.
fn flat(blur: f64, material: &str, z: f64, tilt: [f64; 2]) -> Scene {
    let optics = common::demo_optics().replace("blur = 0.6", &format!("blur = {blur}"));
    assert!(optics.contains(&format!("blur = {blur}")));
    let (a, b) = (tilt[0].to_radians(), tilt[1].to_radians());
    let normal = Vec3::new(b.sin() * a.cos(), -a.sin(), a.cos() * b.cos()).normalize();
    let radius = 50_000.0;
    let centre = Vec3::new(0.0, 0.0, z) - normal * radius;
    let text = format!(
        "{optics}\n[material.uniform]\nalbedo = 0.6\n\n\
         [[object]]\nshape = \"sphere\"\nmaterial = \"{material}\"\n\
         center = [{}, {}, {}]\nradius = {radius}\n",
        centre.x, centre.y, centre.z
    );
    let file: SceneFile = toml::from_str(&text).expect("scene");
    Scene::from_file(file, Path::new("."), "flat scene").expect("scene")
}

/// Per code axis (columns, rows): the mean and SD of the decoded coordinate's error, and the
/// SD of its means over 8x8-pixel blocks (the correlated part: white noise would leave an
/// eighth of the pixel SD), projector pixels.
fn errors(scene: &Scene, seed: u64, phase_correction: bool) -> [(f64, f64, f64); 2] {
    let sim = Simulator::new(scene.clone());
    let capture = sim.capture(&sim.layout(), seed, &|_, _| {});
    let params = DecodeParams {
        phase_correction,
        ..DecodeParams::default()
    };
    let decoded = decode(&capture, &params).expect("decode");
    let truth = &sim.cache.truth;
    let (w, h) = (truth.width as usize, truth.height as usize);
    let rows = decoded.row.as_ref().expect("row codes");
    std::array::from_fn(|axis| {
        let map = if axis == 0 { &decoded.col } else { rows };
        let mut all = Vec::new();
        let mut blocks = vec![(0.0, 0usize); w.div_ceil(8) * h.div_ceil(8)];
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let p = truth.xyz[i];
                if !map[i].is_finite() || !p[0].is_finite() || truth.lit[i] < 0.999 {
                    continue;
                }
                let p = Vec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
                let (u, v) = scene.projector.project(&p).expect("in front");
                let e = f64::from(map[i]) - if axis == 0 { u } else { v };
                all.push(e);
                let b = &mut blocks[(y / 8) * w.div_ceil(8) + x / 8];
                b.0 += e;
                b.1 += 1;
            }
        }
        assert!(all.len() > w * h / 2, "only {} pixels decoded", all.len());
        let (mean, sd) = moments(&all);
        let means: Vec<f64> = blocks
            .iter()
            .filter(|(_, n)| *n == 64)
            .map(|(s, n)| s / *n as f64)
            .collect();
        (mean, sd, moments(&means).1)
    })
}

fn moments(v: &[f64]) -> (f64, f64) {
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let var = v.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / v.len() as f64;
    (mean, var.sqrt())
}

#[test]
fn flats_at_any_height_and_tilt_decode_without_the_pixel_grids_moire() {
    let mut sds = Vec::new();
    for seed in 0..4u64 {
        let mut r = Rng(seed + 11);
        let blur = [0.4, 0.6, 0.9, 0.6][seed as usize];
        let material = if seed % 2 == 0 { "uniform" } else { "table" };
        let z = r.range(-100.0, 200.0);
        let tilt = [r.range(-20.0, 20.0), r.range(-20.0, 20.0)];
        let scene = flat(blur, material, z, tilt);
        let with = errors(&scene, seed, true);
        let without = errors(&scene, seed, false);
        for (axis, name) in ["columns", "rows"].iter().enumerate() {
            let ((m, sd, block), (m0, sd0, block0)) = (with[axis], without[axis]);
            eprintln!(
                "seed {seed} (blur {blur}, {material}, z {z:.0} mm, tilt {:.0}/{:.0}) {name}: \
                 mean {m:+.4} SD {sd:.4} blocks {block:.4} px; without the correction \
                 mean {m0:+.4} SD {sd0:.4} blocks {block0:.4} px",
                tilt[0], tilt[1]
            );
            // With the correction the error is never larger, what is left is mostly the
            // noise, and the correlated part (the moiré, where the pitches beat) is small.
            assert!(
                sd <= sd0 && sd <= 0.011,
                "{name}: the pixel error's SD {sd:.4} px against {sd0:.4} px"
            );
            assert!(
                block <= block0 && block <= 0.0055,
                "{name}: the correlated error {block:.4} px against {block0:.4} px"
            );
            sds.push((sd, sd0));
            assert!(m.abs() <= 0.002, "{name}: the mean error {m:+.4} px");
        }
    }
    // Over the family the bias is there without the correction (the test sees what it guards
    // against), and the correction takes most of it.
    let rms = |f: &dyn Fn(&(f64, f64)) -> f64| {
        (sds.iter().map(|p| f(p).powi(2)).sum::<f64>() / sds.len() as f64).sqrt()
    };
    let (with, without) = (rms(&|p| p.0), rms(&|p| p.1));
    eprintln!(
        "pixel error SD over the family: {with:.4} px; without the correction {without:.4} px"
    );
    assert!(without > 0.015, "no bias to correct: {without:.4} px");
    assert!(
        with <= 0.45 * without,
        "{with:.4} px against {without:.4} px"
    );
}
