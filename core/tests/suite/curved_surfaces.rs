//! Curved surfaces measured without bias (issue 41): seeded spheres of 20–60 mm diameter and
//! cylinders lying in any direction, anywhere in the demo sensor's view, are rendered, decoded
//! with the default settings and reconstructed by the parallax model, then compared with the
//! shapes the simulator drew. The sub-pixel line fit across three stripe edges on either side
//! must not pull them inwards, and the flat table must keep its noise.
//!
//! Each family is decoded twice, with and without the bend correction, so the test also shows
//! that it measures the bias it guards against.
//!
//! With the crossing's phase bias removed (see `crossing_bias.rs`) the table's height error
//! is 0.019 mm (SD; 0.057 mm with the moiré of the pixel grids left in), and most spheres' PS
//! lies within a few hundredths of a millimetre. The smallest spheres (about 22 mm, some 25
//! pixels across on this 800x600 sensor) are the exception: a free sphere fit to the ~340
//! points of their cap (65 degrees from the view at most) multiplies a radial error that varies
//! by a hundredth from top to flank into PS of a tenth. Without any noise (`cargo run --profile
//! ci -p ris-core --example sphere_ps` with `NOISELESS=1`) a 21.9 mm sphere reads PS −0.046,
//! −0.008 and −0.048 mm at three places of the view (−0.095, +0.062, −0.031 with the crossing
//! bias as harmonics of the phase), a 40 mm one −0.004 mm. The family's median and mean are
//! held tight, and each shape only within that scatter. With noise the family (12 spheres)
//! reads a median |PS| of 0.028 mm, a mean of −0.006 mm and the worst 0.109 mm (the 21.9 mm
//! sphere); its spheres of 50–55 mm read +0.025…+0.031 mm, where noise-free a 40 mm one reads
//! −0.004: the bounds below keep that margin and no more.

use crate::common;

use std::path::Path;

use common::Rng;

use ris_core::capture::CaptureSet;
use ris_core::decode::{decode, DecodeParams, Decoded};
use ris_core::geometry::Vec3;
use ris_core::sensor::Reconstructor;
use ris_core::sim::{Scene, SceneFile, Simulator, Truth};
use ris_core::verify::fit::fit_sphere;

/// The demo sensor (1600 mm standoff, 500 mm baseline, 800x600 camera at about 0.9 mm/px),
/// its textured table, a uniform matte material `ball` (as artefacts are) and `objects`.
fn scene(objects: &str) -> Scene {
    let optics = common::demo_optics();
    let text = format!(
        "{optics}\n[material.ball]\nalbedo = 0.6\n\n\
         [[object]]\nshape = \"plane\"\nmaterial = \"table\"\n{objects}"
    );
    let file: SceneFile = toml::from_str(&text).expect("scene");
    Scene::from_file(file, Path::new("."), "curved-surface scene").expect("scene")
}

/// Decoded reference plane of the demo sensor (every scene here has the same optics).
fn reference(scene: &Scene) -> Decoded {
    let sim = Simulator::new(scene.reference());
    let capture = sim.capture(&sim.layout(), 1000, &|_, _| {});
    decode(&capture, &DecodeParams::default()).expect("decode reference")
}

/// Rendered frames and the truth of a scene.
fn render(scene: &Scene, seed: u64) -> (CaptureSet, Truth) {
    let sim = Simulator::new(scene.clone());
    let capture = sim.capture(&sim.layout(), seed, &|_, _| {});
    (capture, sim.cache.truth.clone())
}

/// Reconstructed points and the true surface point of each one's pixel (fully lit pixels),
/// decoded with or without the bend correction.
fn measure(
    scene: &Scene,
    rendered: &(CaptureSet, Truth),
    reference: &Decoded,
    bend_correction: bool,
) -> Vec<(Vec3, Vec3)> {
    let params = DecodeParams {
        bend_correction,
        ..DecodeParams::default()
    };
    let decoded = decode(&rendered.0, &params).expect("decode");
    let rec = Reconstructor::parallax(&scene.camera, scene.projector.center(), reference)
        .expect("parallax model");
    let cloud = rec.reconstruct(&decoded).expect("reconstruct");
    let truth = &rendered.1;
    let v = |p: [f32; 3]| Vec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
    cloud
        .points
        .iter()
        .zip(&cloud.pixels)
        .filter_map(|(p, &px)| {
            let i = px as usize;
            (truth.lit[i] >= 0.999 && truth.xyz[i][0].is_finite()).then(|| (v(*p), v(truth.xyz[i])))
        })
        .collect()
}

/// Whether the surface at `t` with outward normal `n` faces the camera at `eye` within 60°
/// (the band the issue measured the bias over).
fn facing(t: &Vec3, n: &Vec3, eye: &Vec3) -> bool {
    n.dot(&(eye - t).normalize()) > 60f64.to_radians().cos()
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

struct Sphere {
    centre: Vec3,
    radius: f64,
}

/// Four spheres of 20–60 mm diameter at seeded places through the view, 0–150 mm above the
/// table, apart from each other.
fn spheres(seed: u64) -> Vec<Sphere> {
    let mut d = Rng(seed);
    let mut out: Vec<Sphere> = Vec::new();
    while out.len() < 4 {
        let radius = d.range(10.0, 30.0);
        let centre = Vec3::new(
            d.range(-260.0, 260.0),
            d.range(-190.0, 190.0),
            d.range(radius, 150.0 + radius),
        );
        if out.iter().all(|s| {
            let a = Vec3::new(s.centre.x - centre.x, s.centre.y - centre.y, 0.0);
            a.norm() > 2.5 * (s.radius + radius) + 40.0
        }) {
            out.push(Sphere { centre, radius });
        }
    }
    out
}

/// Mean radial error of the sphere's points facing the camera within 60°, and the error of
/// the diameter fitted to all its points (PS of VDI/VDE 2634-2).
fn sphere_errors(points: &[(Vec3, Vec3)], s: &Sphere, eye: &Vec3) -> (f64, f64, usize) {
    let on: Vec<&(Vec3, Vec3)> = points
        .iter()
        .filter(|(_, t)| ((t - s.centre).norm() - s.radius).abs() < 0.01)
        .collect();
    let band: Vec<f64> = on
        .iter()
        .filter(|(_, t)| facing(t, &((t - s.centre) / s.radius), eye))
        .map(|(p, _)| (p - s.centre).norm() - s.radius)
        .collect();
    let all: Vec<Vec3> = on.iter().map(|(p, _)| *p).collect();
    let fit = fit_sphere(&all).expect("sphere fit");
    (mean(&band), 2.0 * (fit.radius - s.radius), band.len())
}

#[test]
fn spheres_of_20_to_60_mm_are_measured_without_bias_and_flats_keep_their_noise() {
    let base = scene("");
    let reference = reference(&base);
    let eye = base.camera.center();
    let (mut bias, mut ps, mut bias_off, mut ps_off) = (vec![], vec![], vec![], vec![]);
    let (mut flat_sd, mut flat_sd_off) = (vec![], vec![]);
    for seed in 0..3u64 {
        let objects: String = spheres(seed)
            .iter()
            .map(|s| {
                format!(
                    "[[object]]\nshape = \"sphere\"\nmaterial = \"ball\"\n\
                     center = [{}, {}, {}]\nradius = {}\n",
                    s.centre.x, s.centre.y, s.centre.z, s.radius
                )
            })
            .collect();
        let sc = scene(&objects);
        let rendered = render(&sc, seed);
        for correction in [true, false] {
            let points = measure(&sc, &rendered, &reference, correction);
            let flat: Vec<f64> = points
                .iter()
                .filter(|(_, t)| t.z.abs() < 1e-3)
                .map(|(p, t)| p.z - t.z)
                .collect();
            let m = mean(&flat);
            let sd = mean(&flat.iter().map(|z| (z - m).powi(2)).collect::<Vec<_>>()).sqrt();
            eprintln!(
                "seed {seed}, correction {correction}: table {} points, mean {m:+.4} mm, SD {sd:.4} mm",
                flat.len()
            );
            assert!(m.abs() < 0.005, "the table's mean error {m:+.4} mm");
            for s in spheres(seed) {
                let (b, p, n) = sphere_errors(&points, &s, &eye);
                eprintln!(
                    "  sphere d = {:.1} mm at ({:.0}, {:.0}, {:.0}): {n} points within 60 deg, \
                     radial bias {b:+.4} mm, PS {p:+.4} mm",
                    2.0 * s.radius,
                    s.centre.x,
                    s.centre.y,
                    s.centre.z
                );
                assert!(n > 200, "too few points on the sphere: {n}");
                if correction {
                    bias.push(b);
                    ps.push(p);
                } else {
                    bias_off.push(b);
                    ps_off.push(p);
                }
            }
            if correction {
                flat_sd.push(sd);
            } else {
                flat_sd_off.push(sd);
            }
        }
    }
    let worst = |v: &[f64]| v.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    eprintln!(
        "{} spheres: radial bias mean {:+.4} mm (worst {:.4}), PS mean {:+.4} mm (worst {:.4}); \
         without the correction: {:+.4} mm, PS {:+.4} mm",
        bias.len(),
        mean(&bias),
        worst(&bias),
        mean(&ps),
        worst(&ps),
        mean(&bias_off),
        mean(&ps_off)
    );
    // The bias is there without the correction (the test sees it) and gone with it.
    assert!(
        mean(&bias_off) < -0.05,
        "bias without: {:+.4}",
        mean(&bias_off)
    );
    assert!(mean(&ps_off) < -0.12, "PS without: {:+.4}", mean(&ps_off));
    assert!(
        mean(&bias).abs() <= 0.005,
        "radial bias {:+.4} mm",
        mean(&bias)
    );
    assert!(
        worst(&bias) <= 0.02,
        "a sphere's radial bias {:.4} mm",
        worst(&bias)
    );
    // PS: most spheres within a few hundredths, the smallest ones off (see above).
    let mut sizes: Vec<f64> = ps.iter().map(|p| p.abs()).collect();
    sizes.sort_by(f64::total_cmp);
    let median = 0.5 * (sizes[sizes.len() / 2 - 1] + sizes[sizes.len() / 2]);
    assert!(median <= 0.035, "the median |PS| {median:.4} mm");
    assert!(mean(&ps).abs() <= 0.02, "PS mean {:+.4} mm", mean(&ps));
    assert!(worst(&ps) <= 0.15, "a sphere's PS {:.4} mm", worst(&ps));
    // The table: the pixel grids' moiré is gone from the decoding (it read 0.057 mm).
    for sd in &flat_sd {
        assert!(*sd <= 0.03, "the table's SD {sd:.4} mm");
    }
    // Flats: the correction stays off them (SD within 2 % of the straight line's).
    for (on, off) in flat_sd.iter().zip(&flat_sd_off) {
        assert!(
            on <= &(off * 1.02),
            "the table's SD {on:.4} mm against {off:.4} mm"
        );
    }
}

struct Cylinder {
    centre: Vec3,
    axis: Vec3,
    radius: f64,
    length: f64,
}

/// Three cylinders of 10–40 mm radius lying on the table in seeded directions.
fn cylinders(seed: u64) -> Vec<Cylinder> {
    let mut d = Rng(1000 + seed);
    let mut out: Vec<Cylinder> = Vec::new();
    while out.len() < 3 {
        let radius = d.range(10.0, 40.0);
        let angle = d.range(0.0, std::f64::consts::PI);
        let centre = Vec3::new(d.range(-220.0, 220.0), d.range(-150.0, 150.0), radius);
        if out.iter().all(|c| {
            let a = Vec3::new(c.centre.x - centre.x, c.centre.y - centre.y, 0.0);
            a.norm() > 200.0
        }) {
            out.push(Cylinder {
                centre,
                axis: Vec3::new(angle.cos(), angle.sin(), 0.0),
                radius,
                length: 160.0,
            });
        }
    }
    out
}

#[test]
fn cylinders_lying_in_any_direction_are_measured_without_bias() {
    let base = scene("");
    let reference = reference(&base);
    let eye = base.camera.center();
    let (mut bias, mut bias_off) = (vec![], vec![]);
    for seed in 0..2u64 {
        let objects: String = cylinders(seed)
            .iter()
            .map(|c| {
                format!(
                    "[[object]]\nshape = \"cylinder\"\nmaterial = \"ball\"\n\
                     center = [{}, {}, {}]\naxis = [{}, {}, 0.0]\nradius = {}\nheight = {}\n",
                    c.centre.x, c.centre.y, c.centre.z, c.axis.x, c.axis.y, c.radius, c.length
                )
            })
            .collect();
        let sc = scene(&objects);
        let rendered = render(&sc, seed);
        for correction in [true, false] {
            let points = measure(&sc, &rendered, &reference, correction);
            for c in cylinders(seed) {
                // Radial vector of a point from the axis, and its position along it.
                let radial = |p: &Vec3| {
                    let q = p - c.centre;
                    (q - c.axis * q.dot(&c.axis), q.dot(&c.axis))
                };
                let errors: Vec<f64> = points
                    .iter()
                    .filter(|(_, t)| {
                        let (r, along) = radial(t);
                        (r.norm() - c.radius).abs() < 0.01
                            && along.abs() < c.length / 2.0 - 2.0
                            && facing(t, &(r / c.radius), &eye)
                    })
                    .map(|(p, _)| radial(p).0.norm() - c.radius)
                    .collect();
                let b = mean(&errors);
                eprintln!(
                    "seed {seed}, correction {correction}: cylinder r = {:.1} mm along ({:.2}, {:.2}): \
                     {} points within 60 deg, radial bias {b:+.4} mm",
                    c.radius,
                    c.axis.x,
                    c.axis.y,
                    errors.len()
                );
                assert!(errors.len() > 1000, "too few points on the cylinder");
                if correction {
                    bias.push(b);
                } else {
                    bias_off.push(b);
                }
            }
        }
    }
    let worst = bias.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    eprintln!(
        "{} cylinders: radial bias mean {:+.4} mm (worst {worst:.4}); without the correction {:+.4} mm",
        bias.len(),
        mean(&bias),
        mean(&bias_off)
    );
    assert!(
        mean(&bias_off) < -0.02,
        "bias without: {:+.4}",
        mean(&bias_off)
    );
    assert!(
        mean(&bias).abs() <= 0.01,
        "radial bias {:+.4} mm",
        mean(&bias)
    );
    // One cylinder may sit where the sensor reads the table itself 0.02–0.05 mm high (the
    // right fifth of the image, where the camera's and projector's pixel pitches beat).
    assert!(worst <= 0.03, "a cylinder's radial bias {worst:.4} mm");
}
