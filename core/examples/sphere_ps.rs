//! PS of one sphere through the demo sensor (X, Y, Z, R in mm; NOISELESS=1 without read and
//! shot noise; SS the render's samples a pixel side, 4 by default): where its radial error
//! lies, by angle from the view and by azimuth from the projector, with the default decoding,
//! without the bend correction and with one edge a side (diagnostic for issue 41: a free
//! sphere fit to a small cap multiplies a structured radial error of a hundredth into PS of a
//! tenth).
//!
//! It also separates where the error arises: the decoded projector column against the truth
//! point's own (projected through the true projector), by angle; the truth columns put through
//! the same reconstruction (PS of the model alone); and with `EDGES=1` a map over the sphere of
//! the one-edge-a-side decoding minus the interpolation between the exact boundaries (the
//! crossings' own error, projector pixels × 1000).
#[path = "../tests/common/mod.rs"]
mod common;

use std::path::Path;

use ris_core::decode::{decode, DecodeParams, Decoded};
use ris_core::geometry::Vec3;
use ris_core::pattern::CodeAxis;
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
    let mut text = format!("{base_text}[[object]]\nshape = \"sphere\"\nmaterial = \"ball\"\ncenter = [{x}, {y}, {z}]\nradius = {r}\n");
    if let Ok(ss) = std::env::var("SS") {
        text.push_str(&format!("[render]\nsupersample = {ss}\n"));
    }
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
    let on_sphere = |i: usize| -> Option<Vec3> {
        let t = truth.xyz[i];
        let t = Vec3::new(t[0] as f64, t[1] as f64, t[2] as f64);
        (truth.lit[i] >= 0.999 && t.x.is_finite() && ((t - centre).norm() - r).abs() <= 0.01)
            .then_some(t)
    };
    let angle_bin = |t: Vec3| {
        let n = (t - centre) / r;
        let a = n.dot(&(eye - t).normalize()).clamp(-1.0, 1.0).acos();
        ((a.to_degrees() / 15.0) as usize).min(5)
    };
    // The truth point's projector column, and the default decoding's error in it by angle.
    let truth_col: Vec<f32> = truth
        .xyz
        .iter()
        .map(|t| {
            let p = Vec3::new(t[0] as f64, t[1] as f64, t[2] as f64);
            scene
                .projector
                .project(&p)
                .map_or(f32::NAN, |(u, _)| u as f32)
        })
        .collect();
    let default = decode(&capture, &DecodeParams::default()).expect("sphere_ps");
    let mut by_angle = [(0.0, 0usize); 6];
    for (i, (&c, &t)) in default.col.iter().zip(&truth_col).enumerate() {
        if let Some(p) = on_sphere(i).filter(|_| c.is_finite()) {
            let k = angle_bin(p);
            by_angle[k].0 += f64::from(c - t);
            by_angle[k].1 += 1;
        }
    }
    println!(
        "default decoding: projector column minus the truth's by angle (projector px) {}",
        by_angle
            .iter()
            .map(|(s, n)| format!("{:+.4}({n})", s / (*n).max(1) as f64))
            .collect::<Vec<_>>()
            .join(" ")
    );
    let mut exact = default.clone();
    for (c, &t) in exact.col.iter_mut().zip(&truth_col) {
        if c.is_finite() {
            *c = t;
        }
    }
    if std::env::var("EDGES").is_ok() {
        edge_map(&scene, &capture, &on_sphere);
    }
    for (name, params, given) in [
        ("truth columns", DecodeParams::default(), Some(exact)),
        ("default", DecodeParams::default(), Some(default)),
        (
            "no bend",
            DecodeParams {
                bend_correction: false,
                ..DecodeParams::default()
            },
            None,
        ),
        (
            "window 1, no bend",
            DecodeParams {
                bend_correction: false,
                edge_window: 1,
                ..DecodeParams::default()
            },
            None,
        ),
    ] {
        let d = given.unwrap_or_else(|| decode(&capture, &params).expect("sphere_ps"));
        let rec = Reconstructor::parallax(&scene.camera, scene.projector.center(), &reference)
            .expect("sphere_ps");
        let cloud = rec.reconstruct(&d).expect("sphere_ps");
        let mut pts = Vec::new();
        let mut by_angle = [(0.0, 0usize); 6];
        let mut by_az = [(0.0, 0usize); 8];
        for (p, &px) in cloud.points.iter().zip(&cloud.pixels) {
            let Some(t) = on_sphere(px as usize) else {
                continue;
            };
            let p = Vec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            pts.push(p);
            let n = (t - centre) / r;
            let e = (p - centre).norm() - r;
            let k = angle_bin(t);
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

/// The one-edge-a-side decoding (no bend, phase or smoothing correction) minus the linear
/// interpolation between the exact boundaries around each pixel of the sphere, found by ray
/// casts along the pixel's row: what is left is the crossings' own error.
fn edge_map(
    scene: &Scene,
    capture: &ris_core::capture::CaptureSet,
    on_sphere: &dyn Fn(usize) -> Option<Vec3>,
) {
    let params = DecodeParams {
        edge_window: 1,
        bend_correction: false,
        phase_correction: false,
        cross_smoothing: false,
        ..DecodeParams::default()
    };
    let d: Decoded = decode(capture, &params).expect("sphere_ps");
    let step = f64::from(d.layout.step(CodeAxis::Column));
    let w = d.width as usize;
    let eye = scene.camera.center();
    let column = |x: f64, y: f64| -> Option<f64> {
        let ray = scene.camera.ray(x, y);
        let (t, _, _) = scene.intersect(&eye, &ray, 1e-6, f64::INFINITY)?;
        scene.projector.project(&(eye + ray * t)).map(|p| p.0)
    };
    let pixels: Vec<usize> = (0..d.col.len())
        .filter(|&i| on_sphere(i).is_some())
        .collect();
    let (Some(x0), Some(x1)) = (
        pixels.iter().map(|i| i % w).min(),
        pixels.iter().map(|i| i % w).max(),
    ) else {
        return;
    };
    let (y0, y1) = (pixels[0] / w, pixels[pixels.len() - 1] / w);
    println!("one edge a side minus the exact boundaries' interpolation, projector px x 1000:");
    for y in y0..=y1 {
        let yf = y as f64;
        let line: String = (x0..=x1)
            .map(|x| {
                let i = y * w + x;
                let decoded = f64::from(d.col[i]);
                if !decoded.is_finite() || on_sphere(i).is_none() {
                    return "    .".to_string();
                }
                let Some(u) = column(x as f64, yf) else {
                    return "    ?".to_string();
                };
                // The boundaries around u (b = k·step − 0.5) located along the row by bisection.
                let k = ((u + 0.5) / step).floor();
                let at = |b: f64| -> Option<f64> {
                    let (mut lo, mut hi) = (x as f64 - 4.0, x as f64 + 4.0);
                    let below = column(lo, yf)? < b;
                    if (column(hi, yf)? < b) == below {
                        return None;
                    }
                    for _ in 0..40 {
                        let mid = 0.5 * (lo + hi);
                        if (column(mid, yf)? < b) == below {
                            lo = mid;
                        } else {
                            hi = mid;
                        }
                    }
                    Some(0.5 * (lo + hi))
                };
                let (ba, bb) = (k * step - 0.5, (k + 1.0) * step - 0.5);
                match (at(ba), at(bb)) {
                    (Some(xa), Some(xb)) => {
                        let p = ba + (bb - ba) * (x as f64 - xa) / (xb - xa);
                        format!("{:5.0}", (decoded - p) * 1000.0)
                    }
                    _ => "    ?".to_string(),
                }
            })
            .collect();
        println!("{line}");
    }
}
