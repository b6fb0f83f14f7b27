//! PS of one sphere through the demo sensor (X, Y, Z, R in mm; NOISELESS=1 without read and
//! shot noise): where its radial error lies, by angle from the view and by azimuth from the
//! projector, with the default decoding, without the bend correction and with one edge a side
//! (diagnostic for issue 41: a free sphere fit to a small cap multiplies a structured radial
//! error of a hundredth into PS of a tenth).
#[path = "../tests/common/mod.rs"]
mod common;

use std::path::Path;

use ris_core::decode::{decode, DecodeParams};
use ris_core::geometry::Vec3;
use ris_core::sensor::Reconstructor;
use ris_core::sim::{Scene, SceneFile, Simulator};
use ris_core::verify::fit::fit_sphere;

fn arg(name: &str, default: f64) -> f64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    let mut optics = common::demo_optics();
    if std::env::var("NOISELESS").is_ok() {
        optics = common::noiseless(&optics);
    }
    let (x, y, z, r) = (
        arg("X", -209.0),
        arg("Y", 157.0),
        arg("Z", 41.0),
        arg("R", 10.95),
    );
    let base_text = format!("{optics}\n[material.ball]\nalbedo = 0.6\n\n[[object]]\nshape = \"plane\"\nmaterial = \"table\"\n");
    let text = format!("{base_text}[[object]]\nshape = \"sphere\"\nmaterial = \"ball\"\ncenter = [{x}, {y}, {z}]\nradius = {r}\n");
    let scene = Scene::from_file(
        toml::from_str::<SceneFile>(&text).expect("sphere_ps"),
        Path::new("."),
        "s",
    )
    .expect("sphere_ps");
    let refsim = Simulator::new(scene.reference());
    let reference = decode(
        &refsim.capture(&refsim.layout(), 1000, &|_, _| {}),
        &DecodeParams::default(),
    )
    .expect("sphere_ps");
    let sim = Simulator::new(scene.clone());
    let capture = sim.capture(&sim.layout(), 3, &|_, _| {});
    let truth = &sim.cache.truth;
    let eye = scene.camera.center();
    let centre = Vec3::new(x, y, z);
    let light = scene.projector.center();
    for (name, params) in [
        ("default", DecodeParams::default()),
        (
            "no bend",
            DecodeParams {
                bend_correction: false,
                ..DecodeParams::default()
            },
        ),
        (
            "window 1, no bend",
            DecodeParams {
                bend_correction: false,
                edge_window: 1,
                ..DecodeParams::default()
            },
        ),
    ] {
        let d = decode(&capture, &params).expect("sphere_ps");
        let rec = Reconstructor::parallax(&scene.camera, scene.projector.center(), &reference)
            .expect("sphere_ps");
        let cloud = rec.reconstruct(&d).expect("sphere_ps");
        let mut pts = Vec::new();
        let mut by_angle = [(0.0, 0usize); 6];
        let mut by_az = [(0.0, 0usize); 8];
        for (p, &px) in cloud.points.iter().zip(&cloud.pixels) {
            let i = px as usize;
            let t = truth.xyz[i];
            if truth.lit[i] < 0.999 || !t[0].is_finite() {
                continue;
            }
            let t = Vec3::new(t[0] as f64, t[1] as f64, t[2] as f64);
            if ((t - centre).norm() - r).abs() > 0.01 {
                continue;
            }
            let p = Vec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            pts.push(p);
            let n = (t - centre) / r;
            let e = (p - centre).norm() - r;
            let a = n
                .dot(&(eye - t).normalize())
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees();
            let k = ((a / 15.0) as usize).min(5);
            by_angle[k].0 += e;
            by_angle[k].1 += 1;
            // Azimuth about the view, 0 = towards the projector.
            let to_light = (light - centre).normalize();
            let az = n.y.atan2(n.x) - to_light.y.atan2(to_light.x);
            let k = (((az.to_degrees() + 720.0) % 360.0) / 45.0) as usize;
            by_az[k.min(7)].0 += e;
            by_az[k.min(7)].1 += 1;
        }
        let fit = fit_sphere(&pts).expect("sphere_ps");
        let show = |b: &[(f64, usize)]| {
            b.iter()
                .map(|(s, n)| format!("{:+.4}({n})", s / (*n).max(1) as f64))
                .collect::<Vec<_>>()
                .join(" ")
        };
        println!(
            "{name}: {} points, PS {:+.4} mm; by angle {}; by azimuth from the projector {}",
            pts.len(),
            2.0 * (fit.radius - r),
            show(&by_angle),
            show(&by_az)
        );
    }
}
